//! The car-like prior (Ackermann steering, as a bicycle): the motion between two frames
//! predicted from a DonkeyCar's recorded `user/angle` and `user/throttle`. The steering
//! angle sets a curvature, not a wheel-speed difference; the throttle sets a speed that the
//! car reaches through a first-order lag. Pure.
//!
//! ```text
//! curvature = angle * curvature_per_unit + curvature_offset      (1/m, positive: left)
//! target    = throttle * speed_per_throttle_mps                   (m/s)
//! speed     : target + (speed0 - target) * exp(-t / time_constant_s)
//! ```
//!
//! The steering is taken as instant (a servo settles in a frame or two at 20 Hz) and held
//! between frames, so each frame's motion is an exact circular arc whose length is the
//! lagged speed's integral.
//!
//! The defaults are a 1/16-1/10 scale DonkeyCar's, not measured on any car: about 1 m/s at
//! throttle 0.25 and a 0.5 m turning radius at full lock. [`super::calibrate::fit_car`]
//! corrects the speed, the curvature per unit angle and the steering offset from the
//! frames themselves.

use serde::{Deserialize, Serialize};

use super::register::Motion;
use crate::sim::SimError;

/// A car-like vehicle's command response; a config section (`[sim.car]`, every key
/// optional).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CarParams {
    /// Steady speed per unit throttle, m/s (throttle 0.25 -> a quarter of it).
    pub speed_per_throttle_mps: f32,
    /// Curvature per unit steering angle, 1/m. Negative for DonkeyCar, whose angle -1
    /// steers left while curvature is positive to the left; 1 / this is the radius at full
    /// lock.
    pub curvature_per_unit: f32,
    /// Curvature at angle 0, 1/m (a steering trim that is off).
    pub curvature_offset: f32,
    /// The speed's first-order lag, seconds (0: none).
    pub time_constant_s: f32,
}

impl Default for CarParams {
    /// A DonkeyCar's, roughly: 4 m/s per unit throttle, 0.5 m radius at full lock, no trim
    /// error, a 0.3 s speed lag.
    fn default() -> Self {
        Self {
            speed_per_throttle_mps: 4.0,
            curvature_per_unit: -2.0,
            curvature_offset: 0.0,
            time_constant_s: 0.3,
        }
    }
}

impl CarParams {
    /// Checks every value against its allowed range, naming the key.
    pub fn validate(&self) -> Result<(), SimError> {
        let check = |key: &str, v: f32, lo: f32, hi: f32| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(SimError::Invalid(format!(
                    "car key `{key}` = {v} is out of range: allowed {lo} ..= {hi}"
                )))
            }
        };
        check(
            "speed_per_throttle_mps",
            self.speed_per_throttle_mps,
            0.01,
            50.0,
        )?;
        check("curvature_per_unit", self.curvature_per_unit, -20.0, 20.0)?;
        check("curvature_offset", self.curvature_offset, -5.0, 5.0)?;
        check("time_constant_s", self.time_constant_s, 0.0, 5.0)
    }

    /// The same car with its steering's sign the other way (`poses`' reversed turn, read
    /// back in the recording's own angle convention): the curvature per unit angle negated.
    pub fn reversed(self) -> Self {
        Self {
            curvature_per_unit: -self.curvature_per_unit,
            ..self
        }
    }

    /// The curvature commanded by `angle` (1/m, positive to the left).
    pub fn curvature(&self, angle: f32) -> f32 {
        angle * self.curvature_per_unit + self.curvature_offset
    }
}

/// The motion along a circular arc of length `length` (m) and curvature `curvature`
/// (1/m), in the frame at its start.
pub fn arc(length: f32, curvature: f32) -> Motion {
    let yaw = length * curvature;
    if curvature.abs() < 1e-6 {
        return Motion::new(length, 0.0, yaw);
    }
    Motion::new(yaw.sin() / curvature, (1.0 - yaw.cos()) / curvature, yaw)
}

/// The distance covered in `dt` seconds by a speed that starts at `v0` and approaches
/// `target` with time constant `tau` (0: at once), and the speed at the end.
pub fn lagged_distance(v0: f32, target: f32, tau: f32, dt: f32) -> (f32, f32) {
    if tau <= 0.0 {
        return (target * dt, target);
    }
    let k = 1.0 - (-dt / tau).exp();
    (
        target * dt + (v0 - target) * tau * k,
        v0 + (target - v0) * k,
    )
}

/// Integrates `(angle, throttle)` commands, keeping the speed between frames.
#[derive(Debug, Clone)]
pub struct CarOdometry {
    params: CarParams,
    speed: f32,
    /// Calibration's corrections: the distance times `speed`, the commanded curvature
    /// times `turn`, plus `offset` radians per metre of the uncorrected distance.
    speed_scale: f32,
    turn_scale: f32,
    offset: f32,
}

impl CarOdometry {
    /// Starts at rest.
    pub fn new(params: CarParams) -> Self {
        Self {
            params,
            speed: 0.0,
            speed_scale: 1.0,
            turn_scale: 1.0,
            offset: 0.0,
        }
    }

    /// Calibration's corrections ([`super::calibrate::fit_car`]): the distance is scaled by
    /// `speed`, the yaw is `turn` times the commanded one plus `offset` radians per metre
    /// the uncorrected model travels.
    pub fn with_scales(mut self, speed: f32, turn: f32, offset: f32) -> Self {
        self.speed_scale = speed;
        self.turn_scale = turn;
        self.offset = offset;
        self
    }

    /// The params with the corrections folded in: what the recording says the car does.
    pub fn calibrated(&self) -> CarParams {
        let s = self.speed_scale.max(1e-6);
        CarParams {
            speed_per_throttle_mps: self.params.speed_per_throttle_mps * self.speed_scale,
            curvature_per_unit: self.params.curvature_per_unit * self.turn_scale / s,
            curvature_offset: (self.params.curvature_offset * self.turn_scale + self.offset) / s,
            ..self.params
        }
    }

    /// The motion while `(angle, throttle)` is held for `dt` seconds, in the frame of the
    /// pose at the start.
    pub fn advance(&mut self, angle: f32, throttle: f32, dt: f32) -> Motion {
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (angle, throttle) = (finite_or_zero(angle), finite_or_zero(throttle));
        let target = throttle * self.params.speed_per_throttle_mps;
        let (raw, speed) = lagged_distance(self.speed, target, self.params.time_constant_s, dt);
        self.speed = speed;
        let yaw = raw * (self.params.curvature(angle) * self.turn_scale + self.offset);
        let length = raw * self.speed_scale;
        if length.abs() < 1e-9 {
            return Motion::new(0.0, 0.0, yaw);
        }
        arc(length, yaw / length)
    }
}

fn finite_or_zero(v: f32) -> f32 {
    if v.is_finite() { v } else { 0.0 }
}

/// DonkeyCar's `(angle, throttle)` from wheel duties (the inverse of
/// [`super::wheels::wheels_from_angle_throttle`]): a differential-drive recording driven
/// through the car model.
pub fn angle_throttle_from_wheels(left: f32, right: f32) -> (f32, f32) {
    ((left - right) / 2.0, (left + right) / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn no_lag() -> CarParams {
        CarParams {
            speed_per_throttle_mps: 4.0,
            curvature_per_unit: -2.0,
            curvature_offset: 0.0,
            time_constant_s: 0.0,
        }
    }

    #[test]
    fn a_held_angle_drives_a_circle_of_the_stated_radius() {
        // Angle -1: curvature 2 /m to the left, radius 0.5 m. Throttle 0.25: 1 m/s.
        let mut car = CarOdometry::new(no_lag());
        // 0.5 s: 0.5 m of arc, 1 rad: (0.5 sin 1, 0.5 (1 - cos 1)) = (0.4207, 0.2298).
        let m = car.advance(-1.0, 0.25, 0.5);
        assert!((m.forward - 0.420_735).abs() < 1e-5, "{m:?}");
        assert!((m.left - 0.229_849).abs() < 1e-5, "{m:?}");
        assert!((m.yaw - 1.0).abs() < 1e-6, "{m:?}");
        // pi seconds at 1 m/s round a 0.5 m circle: back where it started, heading 2 pi,
        // frame by frame at 20 Hz too.
        let mut car = CarOdometry::new(no_lag());
        let (mut x, mut y, mut h) = (0.0f32, 0.0f32, 0.0f32);
        let n = (std::f32::consts::PI / 0.05).round() as usize; // 63 frames of 50 ms
        let dt = std::f32::consts::PI / n as f32;
        let mut far = 0.0f32;
        for _ in 0..n {
            let m = car.advance(-1.0, 0.25, dt);
            let (s, c) = h.sin_cos();
            x += c * m.forward - s * m.left;
            y += s * m.forward + c * m.left;
            h += m.yaw;
            far = far.max(x.hypot(y));
        }
        assert!(x.hypot(y) < 1e-4, "({x}, {y})");
        assert!((h - 2.0 * std::f32::consts::PI).abs() < 1e-4);
        assert!((far - 1.0).abs() < 1e-3, "the diameter: {far}");
        // Angle +0.5: radius 1 m to the right; angle 0: straight.
        let m = car.advance(0.5, 0.25, 0.1);
        assert!(m.left < 0.0 && (m.yaw + 0.1).abs() < 1e-6, "{m:?}");
        let m = car.advance(0.0, 0.25, 0.1);
        assert_eq!(m, Motion::new(0.1, 0.0, 0.0));
    }

    #[test]
    fn the_speed_lag_reaches_63_percent_after_one_time_constant() {
        let p = CarParams {
            time_constant_s: 0.3,
            ..no_lag()
        };
        // From rest, throttle 0.25 (target 1 m/s) for tau = 0.3 s: speed 1 - e^-1 = 0.6321
        // m/s; distance 1 * (0.3 - 0.3 (1 - e^-1)) = 0.3 e^-1 = 0.1104 m.
        let mut car = CarOdometry::new(p);
        let m = car.advance(0.0, 0.25, 0.3);
        assert!((m.forward - 0.110_364).abs() < 1e-5, "{m:?}");
        assert!((car.speed - 0.632_12).abs() < 1e-5, "{}", car.speed);
        // Split into 6 frames of 50 ms: the same distance and speed.
        let mut car = CarOdometry::new(p);
        let d: f32 = (0..6).map(|_| car.advance(0.0, 0.25, 0.05).forward).sum();
        assert!((d - 0.110_364).abs() < 1e-5, "{d}");
        assert!((car.speed - 0.632_12).abs() < 1e-5);
        // Throttle off: the speed decays, the car coasts 0.6321 * 0.3 (1 - e^-1) = 0.1199 m.
        let m = car.advance(0.0, 0.0, 0.3);
        assert!((m.forward - 0.119_87).abs() < 1e-4, "{m:?}");
    }

    #[test]
    fn corrections_and_the_calibrated_params() {
        // Speed x0.8, turn x1.1, offset 0.05 rad per uncorrected metre.
        let mut car = CarOdometry::new(no_lag()).with_scales(0.8, 1.1, 0.05);
        // Angle 0 for 1 s at 1 m/s: 0.8 m of arc, yaw 1 m x 0.05 = 0.05 rad: curvature
        // 0.0625 /m, forward sin(0.05) / 0.0625 = 0.79967 m.
        let m = car.advance(0.0, 0.25, 1.0);
        assert!((m.yaw - 0.05).abs() < 1e-6, "{m:?}");
        assert!((m.forward - 0.799_667).abs() < 1e-5, "{m:?}");
        let c = car.calibrated();
        // 4 x 0.8 = 3.2 m/s per unit; -2 x 1.1 / 0.8 = -2.75 /m; 0.05 / 0.8 = 0.0625 /m.
        assert!((c.speed_per_throttle_mps - 3.2).abs() < 1e-6);
        assert!((c.curvature_per_unit + 2.75).abs() < 1e-6);
        assert!((c.curvature_offset - 0.0625).abs() < 1e-6);
        // Not a number: no motion, no panic.
        assert_eq!(car.advance(f32::NAN, 0.0, 0.1).yaw, 0.0);
        assert_eq!(car.advance(0.0, 0.0, f32::INFINITY), Motion::default());
        let (a, t) = angle_throttle_from_wheels(0.4, 0.2);
        assert!((a - 0.1).abs() < 1e-6 && (t - 0.3).abs() < 1e-6);
        assert!(CarParams::default().validate().is_ok());
        let bad = CarParams {
            speed_per_throttle_mps: -1.0,
            ..CarParams::default()
        };
        assert!(bad.validate().is_err());
    }
}
