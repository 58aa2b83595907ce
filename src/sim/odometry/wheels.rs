//! The wheel prior: the motion between two frames predicted from the recorded wheel
//! commands, by the simulator's own differential drive and motor model (dead band, top
//! speed, first-order lag), without noise. Pure.

use super::super::robot::RobotParams;
use super::register::Motion;

/// Integration step (s), as the simulator's physics (240 Hz).
const STEP_S: f32 = 1.0 / 240.0;

/// Integrates wheel commands over time, keeping the wheels' speeds between frames.
#[derive(Debug, Clone)]
pub struct WheelOdometry {
    params: RobotParams,
    v_left: f32,
    v_right: f32,
    /// Corrections found by calibration: the speed and the turn rate are scaled by these.
    scales: (f32, f32),
}

impl WheelOdometry {
    /// Starts at rest.
    pub fn new(params: RobotParams) -> Self {
        Self {
            params,
            v_left: 0.0,
            v_right: 0.0,
            scales: (1.0, 1.0),
        }
    }

    /// Scales the predicted speed by `speed` and the turn rate by `turn` (the wheel model's
    /// corrections, from [`super::calibrate`]).
    pub fn with_scales(mut self, speed: f32, turn: f32) -> Self {
        self.scales = (speed, turn);
        self
    }

    /// The motion while `(left, right)` duty (-1..1) is held for `dt` seconds, in the frame
    /// of the pose at the start.
    pub fn advance(&mut self, left: f32, right: f32, dt: f32) -> Motion {
        let m = &self.params.motor;
        let (tl, tr) = (m.target_speed(left), m.target_speed(right));
        let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
        let mut t = 0.0;
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 1.0)
        } else {
            0.0
        };
        while t < dt {
            let h = STEP_S.min(dt - t);
            let k = m.lag_fraction(h);
            // The step's exact mean wheel speeds under the lag: target + (v0 - target) *
            // tau / h * (1 - exp(-h / tau)); the target itself without a lag.
            let tau = m.time_constant_s;
            let mean_of = |v0: f32, target: f32| {
                if tau > 0.0 {
                    target + (v0 - target) * tau / h * k
                } else {
                    target
                }
            };
            let (vl, vr) = (mean_of(self.v_left, tl), mean_of(self.v_right, tr));
            self.v_left += (tl - self.v_left) * k;
            self.v_right += (tr - self.v_right) * k;
            let v = f64::from((vl + vr) / 2.0 * self.scales.0);
            let w = f64::from((vr - vl) / self.params.wheel_base_m * self.scales.1);
            let h64 = f64::from(h);
            // Midpoint heading for the step.
            let mid = yaw + w * h64 / 2.0;
            x += v * mid.cos() * h64;
            y += v * mid.sin() * h64;
            yaw += w * h64;
            t += h;
        }
        Motion::new(x as f32, y as f32, yaw as f32)
    }
}

/// Wheel duties from DonkeyCar's `(angle, throttle)` (the inverse of the recorder's
/// `angle = (left - right) / 2`, `throttle = (left + right) / 2`).
pub fn wheels_from_angle_throttle(angle: f32, throttle: f32) -> (f32, f32) {
    (
        (throttle + angle).clamp(-1.0, 1.0),
        (throttle - angle).clamp(-1.0, 1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::robot::MotorModel;

    fn params() -> RobotParams {
        RobotParams {
            wheel_base_m: 0.12,
            motor: MotorModel {
                top_speed_mps: 0.5,
                dead_band: 0.0,
                time_constant_s: 0.0,
            },
            speed_noise: 0.0,
        }
    }

    #[test]
    fn straight_and_turning_motions() {
        let mut w = WheelOdometry::new(params());
        // Both wheels at 0.4: 0.2 m/s for 0.5 s = 0.1 m straight ahead.
        let m = w.advance(0.4, 0.4, 0.5);
        assert!(
            (m.forward - 0.1).abs() < 1e-5 && m.left.abs() < 1e-6 && m.yaw.abs() < 1e-6,
            "{m:?}"
        );
        // Spin in place: right 0.12 m/s forward, left back: yaw rate 2 rad/s for 0.25 s.
        let m = w.advance(-0.24, 0.24, 0.25);
        assert!(m.forward.abs() < 1e-5 && m.left.abs() < 1e-5, "{m:?}");
        assert!((m.yaw - 0.5).abs() < 1e-4, "{m:?}");
        // An arc: v 0.1 m/s, w 0.5 rad/s for 1 s: radius 0.2 m, chord endpoint
        // (r sin 0.5, r (1 - cos 0.5)).
        let m = w.advance(0.14, 0.26, 1.0);
        let (r, th) = (0.2f32, 0.5f32);
        assert!((m.forward - r * th.sin()).abs() < 1e-4, "{m:?}");
        assert!((m.left - r * (1.0 - th.cos())).abs() < 1e-4, "{m:?}");
        assert!((m.yaw - th).abs() < 1e-4);
    }

    #[test]
    fn the_lag_and_dead_band_are_the_simulators() {
        let mut p = params();
        p.motor.time_constant_s = 0.1;
        p.motor.dead_band = 0.1;
        let mut w = WheelOdometry::new(p);
        assert_eq!(
            w.advance(0.05, 0.05, 0.5),
            Motion::default(),
            "inside the dead band"
        );
        // From rest, 0.1 s at full: speed rises as 1 - exp(-t/tau); distance
        // 0.5 * (t - tau (1 - exp(-1))) = 0.5 * 0.1 * exp(-1).
        let m = w.advance(1.0, 1.0, 0.1);
        let want = 0.5 * 0.1 * (-1.0f32).exp();
        assert!((m.forward - want).abs() < 2e-4, "{} vs {want}", m.forward);
        let close =
            |(a, b): (f32, f32), (c, d): (f32, f32)| (a - c).abs() < 1e-6 && (b - d).abs() < 1e-6;
        assert!(close(wheels_from_angle_throttle(0.1, 0.3), (0.4, 0.2)));
        assert!(close(wheels_from_angle_throttle(0.9, 0.5), (1.0, -0.4)));
    }
}
