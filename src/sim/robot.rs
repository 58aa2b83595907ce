//! The simulated robot: a differential-drive JetBot with a motor model.
//!
//! Each wheel's speed follows its motor's duty through a dead band and a first-order lag
//! ([`MotorModel`]); the body then moves as a unicycle, integrated exactly over the step
//! (a circular arc, not an Euler step), so the path does not depend on the step size when
//! the wheel speeds are constant. Optional multiplicative speed noise (wheel slip) draws
//! from the caller's seeded RNG only when it is enabled.
//!
//! A robot made with [`Robot::car`] is a car-like vehicle instead (a DonkeyCar: Ackermann
//! steering as a bicycle, [`CarParams`]): the two motor channels carry DonkeyCar's throttle
//! and angle ([`Mixing::Car`]), the throttle sets a speed reached through a first-order lag
//! and the angle a curvature, clamped to full lock. It moves along the same exact arcs.

use rand::Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::odometry::ackermann::{CarParams, lagged_distance};
use super::{Pose2, Result, SimError, wrap_angle};
use crate::control::{Mixing, WheelCommand};

/// Duty -> wheel speed: a dead band, a linear range up to `top_speed_mps`, and a first-order
/// lag with time constant `time_constant_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotorModel {
    /// Wheel speed at full duty (m/s).
    pub top_speed_mps: f32,
    /// Duty fraction below which the wheel does not turn.
    pub dead_band: f32,
    /// Time constant of the first-order lag (s); 0 follows the target at once.
    pub time_constant_s: f32,
}

impl Default for MotorModel {
    fn default() -> Self {
        Self {
            top_speed_mps: 0.5,
            dead_band: 0.08,
            time_constant_s: 0.08,
        }
    }
}

impl MotorModel {
    /// The steady wheel speed for a signed duty (clamped to -1..=1):
    /// `sign * top * (|d| - db) / (1 - db)` beyond the dead band, else 0.
    pub fn target_speed(&self, duty: f32) -> f32 {
        let d = if duty.is_nan() {
            0.0
        } else {
            duty.clamp(-1.0, 1.0)
        };
        let db = self.dead_band;
        if d.abs() <= db || db >= 1.0 {
            return 0.0;
        }
        d.signum() * self.top_speed_mps * (d.abs() - db) / (1.0 - db)
    }

    /// The fraction of the way to the target covered in `dt`: `1 - exp(-dt/tau)`.
    pub fn lag_fraction(&self, dt: f32) -> f32 {
        if self.time_constant_s <= 0.0 {
            1.0
        } else {
            1.0 - (-dt / self.time_constant_s).exp()
        }
    }
}

/// The robot's physical parameters; can sit in a config section (every key optional).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotParams {
    /// Distance between the wheels' contact points (m).
    pub wheel_base_m: f32,
    pub motor: MotorModel,
    /// Standard deviation of the multiplicative wheel-speed noise, as a fraction of the
    /// wheel speed (0: none).
    pub speed_noise: f32,
}

impl Default for RobotParams {
    fn default() -> Self {
        Self {
            wheel_base_m: 0.12,
            motor: MotorModel::default(),
            speed_noise: 0.0,
        }
    }
}

impl RobotParams {
    /// Checks every value against its allowed range, naming the key.
    pub fn validate(&self) -> Result<()> {
        let check = |key: &str, v: f32, lo: f32, hi: f32| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(SimError::Invalid(format!(
                    "robot key `{key}` = {v} is out of range: allowed {lo} ..= {hi}"
                )))
            }
        };
        check("wheel_base_m", self.wheel_base_m, 0.01, 2.0)?;
        check("motor.top_speed_mps", self.motor.top_speed_mps, 0.0, 20.0)?;
        check("motor.dead_band", self.motor.dead_band, 0.0, 0.95)?;
        check(
            "motor.time_constant_s",
            self.motor.time_constant_s,
            0.0,
            10.0,
        )?;
        check("speed_noise", self.speed_noise, 0.0, 1.0)?;
        Ok(())
    }
}

/// A differential-drive robot on the mat (or a car, [`Robot::car`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Robot {
    pub pose: Pose2,
    /// Left wheel's ground speed (m/s), forward positive. A car: the speed a wheel at
    /// `wheel_base_m / 2` left of its centre line would have.
    pub v_left: f32,
    /// Right wheel's ground speed (m/s), forward positive.
    pub v_right: f32,
    params: RobotParams,
    car: Option<Car>,
}

/// A car's command response and its body speed, which lags the throttle.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Car {
    params: CarParams,
    speed: f32,
}

impl Robot {
    /// A robot at rest at `pose`.
    pub fn new(params: RobotParams, pose: Pose2) -> Self {
        Self {
            pose,
            v_left: 0.0,
            v_right: 0.0,
            params,
            car: None,
        }
    }

    /// A car-like vehicle at rest at `pose`, driven by DonkeyCar's throttle and angle on
    /// the two motor channels ([`Mixing::Car`]). Of `params` only `speed_noise` (and the
    /// nominal `wheel_base_m` of [`Robot::v_left`]) apply.
    pub fn car(params: RobotParams, car: CarParams, pose: Pose2) -> Self {
        Self {
            car: Some(Car {
                params: car,
                speed: 0.0,
            }),
            ..Self::new(params, pose)
        }
    }

    /// The car's params, `None` for differential drive.
    pub fn car_params(&self) -> Option<&CarParams> {
        self.car.as_ref().map(|c| &c.params)
    }

    pub fn params(&self) -> &RobotParams {
        &self.params
    }

    /// Puts the robot at `pose`, at rest.
    pub fn reset(&mut self, pose: Pose2) {
        self.pose = pose;
        self.v_left = 0.0;
        self.v_right = 0.0;
        if let Some(car) = &mut self.car {
            car.speed = 0.0;
        }
    }

    /// Forward speed of the body (m/s).
    pub fn speed(&self) -> f32 {
        (self.v_left + self.v_right) / 2.0
    }

    /// Yaw rate (rad/s, counter-clockwise positive).
    pub fn yaw_rate(&self) -> f32 {
        (self.v_right - self.v_left) / self.params.wheel_base_m
    }

    /// Advances `dt` seconds with signed wheel duties (-1..=1, forward positive).
    ///
    /// Each wheel speed moves toward its target by the exact first-order-lag fraction
    /// `1 - exp(-dt/tau)`; with `speed_noise` > 0 the speeds used for this step's motion are
    /// multiplied by `1 + speed_noise * N(0, 1)` (slip; the motor state itself stays clean);
    /// then the pose moves along the exact arc for those constant speeds.
    pub fn step(&mut self, duty_left: f32, duty_right: f32, dt: f32, rng: &mut impl Rng) {
        if !(dt > 0.0 && dt.is_finite()) {
            return;
        }
        if let Some(car) = self.car {
            self.step_car(car, duty_left, duty_right, dt, rng);
            return;
        }
        let m = &self.params.motor;
        let k = m.lag_fraction(dt);
        self.v_left += (m.target_speed(duty_left) - self.v_left) * k;
        self.v_right += (m.target_speed(duty_right) - self.v_right) * k;

        let (mut vl, mut vr) = (f64::from(self.v_left), f64::from(self.v_right));
        let sigma = f64::from(self.params.speed_noise);
        if sigma > 0.0 {
            let nl: f64 = rng.sample(StandardNormal);
            let nr: f64 = rng.sample(StandardNormal);
            vl *= 1.0 + sigma * nl;
            vr *= 1.0 + sigma * nr;
        }
        self.move_along(vl, vr, dt);
    }

    /// The pose moved along the exact arc of constant wheel speeds `vl`, `vr` (m/s) at the
    /// configured base for `dt` seconds.
    fn move_along(&mut self, vl: f64, vr: f64, dt: f32) {
        let (x, y, h) = integrate(
            f64::from(self.pose.x),
            f64::from(self.pose.y),
            f64::from(self.pose.heading),
            vl,
            vr,
            f64::from(self.params.wheel_base_m),
            f64::from(dt),
        );
        self.pose = Pose2::new(x as f32, y as f32, wrap_angle(h as f32));
    }
}

impl Robot {
    /// [`Robot::step`] for a car: throttle and angle from the channels, the speed's lag over
    /// `dt` (its distance exact), the noise on that distance, the arc of the angle's
    /// curvature.
    fn step_car(&mut self, mut car: Car, left: f32, right: f32, dt: f32, rng: &mut impl Rng) {
        let finite = |v: f32| {
            if v.is_finite() {
                v.clamp(-1.0, 1.0)
            } else {
                0.0
            }
        };
        let (throttle, angle) = Mixing::Car.unmix(WheelCommand::new(left, right));
        let (throttle, angle) = (finite(throttle), finite(angle));
        let p = car.params;
        let target = throttle * p.speed_per_throttle_mps;
        let (distance, speed) = lagged_distance(car.speed, target, p.time_constant_s, dt);
        car.speed = speed;
        self.car = Some(car);
        let mut v = f64::from(distance / dt);
        let sigma = f64::from(self.params.speed_noise);
        if sigma > 0.0 {
            let n: f64 = rng.sample(StandardNormal);
            v *= 1.0 + sigma * n;
        }
        // The arc of a unicycle with the equivalent wheel speeds at the nominal base.
        let k = f64::from(p.curvature(angle));
        let b = f64::from(self.params.wheel_base_m);
        let (vl, vr) = (v * (1.0 - k * b / 2.0), v * (1.0 + k * b / 2.0));
        self.v_left = speed * (1.0 - (k * b / 2.0) as f32);
        self.v_right = speed * (1.0 + (k * b / 2.0) as f32);
        self.move_along(vl, vr, dt);
    }
}

/// Exact unicycle motion over `dt` with constant wheel speeds: the body moves along the
/// chord of its arc, of length `v dt sinc(w dt / 2)` at heading `th + w dt / 2` (the same
/// as `x += v/w (sin(th + w dt) - sin th)`, without the cancellation for small `w`).
fn integrate(x: f64, y: f64, th: f64, vl: f64, vr: f64, b: f64, dt: f64) -> (f64, f64, f64) {
    let v = (vl + vr) / 2.0;
    let w = (vr - vl) / b;
    let half = w * dt / 2.0;
    let sinc = if half.abs() < 1e-4 {
        1.0 - half * half / 6.0
    } else {
        half.sin() / half
    };
    let chord = v * dt * sinc;
    let mid = th + half;
    (x + chord * mid.cos(), y + chord * mid.sin(), th + w * dt)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn rng() -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(42)
    }

    /// Duty giving `v` m/s with the default motor.
    fn duty_for(v: f32) -> f32 {
        let m = MotorModel::default();
        v.signum() * (m.dead_band + v.abs() / m.top_speed_mps * (1.0 - m.dead_band))
    }

    #[test]
    fn target_speed_has_a_dead_band_and_clamps() {
        let m = MotorModel::default();
        assert_eq!(m.target_speed(0.0), 0.0);
        assert_eq!(m.target_speed(0.08), 0.0);
        assert_eq!(m.target_speed(-0.05), 0.0);
        assert!((m.target_speed(1.0) - 0.5).abs() < 1e-7);
        assert!((m.target_speed(2.0) - 0.5).abs() < 1e-7);
        assert!((m.target_speed(-1.0) + 0.5).abs() < 1e-7);
        assert!((m.target_speed(0.54) - 0.25).abs() < 1e-6);
        assert!((m.target_speed(-0.54) + 0.25).abs() < 1e-6);
        assert_eq!(m.target_speed(f32::NAN), 0.0);
    }

    #[test]
    fn straight_line_at_a_known_speed() {
        let mut r = Robot::new(RobotParams::default(), Pose2::new(0.5, 0.5, 0.3));
        let d = duty_for(0.25);
        let dt = 0.01;
        let mut g = rng();
        for _ in 0..200 {
            r.step(d, d, dt, &mut g);
        }
        assert!((r.speed() - 0.25).abs() < 1e-6, "{}", r.speed());
        assert_eq!(r.yaw_rate(), 0.0);
        let start = r.pose;
        for _ in 0..400 {
            r.step(d, d, dt, &mut g);
        }
        let dist = (r.pose.x - start.x).hypot(r.pose.y - start.y);
        assert!((dist - 0.25 * 4.0).abs() < 1e-4, "{dist}");
        assert!((r.pose.heading - 0.3).abs() < 1e-6);
        let along = ((r.pose.y - start.y).atan2(r.pose.x - start.x) - 0.3).abs();
        assert!(along < 1e-5);
    }

    #[test]
    fn full_circle_with_the_expected_radius() {
        let p = RobotParams::default();
        let (vl, vr) = (0.15f32, 0.25f32);
        let radius = p.wheel_base_m / 2.0 * (vl + vr) / (vr - vl);
        assert!((radius - 0.24).abs() < 1e-6);
        let mut r = Robot::new(p, Pose2::new(0.9, 1.3, 0.0));
        let mut g = rng();
        let (dl, dr) = (duty_for(vl), duty_for(vr));
        for _ in 0..300 {
            r.step(dl, dr, 0.01, &mut g);
        }
        assert!((r.v_left - vl).abs() < 1e-6 && (r.v_right - vr).abs() < 1e-6);
        let start = r.pose;
        let w = r.yaw_rate();
        let period = std::f32::consts::TAU / w;
        // The circle's centre is `radius` to the left of the robot.
        let (cx, cy) = (
            start.x - radius * start.heading.sin(),
            start.y + radius * start.heading.cos(),
        );
        let dt = 0.01f32;
        let mut t = 0.0;
        let mut worst = 0.0f32;
        while t < period {
            let step = dt.min(period - t);
            r.step(dl, dr, step, &mut g);
            t += step;
            let off = ((r.pose.x - cx).hypot(r.pose.y - cy) - radius).abs();
            worst = worst.max(off);
        }
        assert!(worst < 1e-4, "left the circle by {worst}");
        let gap = (r.pose.x - start.x).hypot(r.pose.y - start.y);
        assert!(gap < 1e-3, "{gap}");
        assert!(wrap_angle(r.pose.heading - start.heading).abs() < 1e-3);
    }

    #[test]
    fn exact_integration_does_not_depend_on_the_step() {
        let mut a = Robot::new(RobotParams::default(), Pose2::new(0.5, 0.5, 1.0));
        a.v_left = 0.1;
        a.v_right = 0.3;
        let mut b = a.clone();
        let (dl, dr) = (duty_for(0.1), duty_for(0.3));
        let mut g = rng();
        a.step(dl, dr, 0.5, &mut g);
        for _ in 0..50 {
            b.step(dl, dr, 0.01, &mut g);
        }
        assert!((a.pose.x - b.pose.x).abs() < 1e-5 && (a.pose.y - b.pose.y).abs() < 1e-5);
        assert!((a.pose.heading - b.pose.heading).abs() < 1e-5);
    }

    #[test]
    fn spin_in_place() {
        let mut r = Robot::new(RobotParams::default(), Pose2::new(1.0, 1.0, 0.0));
        let d = duty_for(0.06);
        let mut g = rng();
        let mut turned = 0.0;
        for _ in 0..300 {
            let before = r.pose.heading;
            r.step(-d, d, 0.01, &mut g);
            turned += wrap_angle(r.pose.heading - before);
        }
        assert_eq!(r.speed(), 0.0);
        assert!((r.pose.x - 1.0).abs() < 1e-6 && (r.pose.y - 1.0).abs() < 1e-6);
        assert!((r.yaw_rate() - 1.0).abs() < 1e-5, "{}", r.yaw_rate());
        assert!(turned > 2.5 && turned < 3.0, "{turned}");
    }

    #[test]
    fn dead_band_gives_no_motion() {
        let mut r = Robot::new(RobotParams::default(), Pose2::new(1.0, 1.0, 0.5));
        let mut g = rng();
        for _ in 0..500 {
            r.step(0.07, -0.079, 0.01, &mut g);
        }
        assert_eq!(r.pose, Pose2::new(1.0, 1.0, 0.5));
        assert_eq!((r.v_left, r.v_right), (0.0, 0.0));
    }

    #[test]
    fn lag_reaches_63_percent_at_tau() {
        let p = RobotParams::default();
        let tau = p.motor.time_constant_s;
        for n in [1usize, 8, 80] {
            let mut r = Robot::new(p, Pose2::default());
            let mut g = rng();
            for _ in 0..n {
                r.step(1.0, 1.0, tau / n as f32, &mut g);
            }
            let frac = r.v_left / 0.5;
            assert!((frac - (1.0 - (-1.0f32).exp())).abs() < 1e-5, "{n}: {frac}");
            assert!((frac - 0.632).abs() < 1e-3);
        }
    }

    #[test]
    fn noise_is_seeded() {
        let p = RobotParams {
            speed_noise: 0.1,
            ..RobotParams::default()
        };
        let run = |seed: u64| {
            let mut r = Robot::new(p, Pose2::new(0.5, 0.5, 0.0));
            let mut g = ChaCha8Rng::seed_from_u64(seed);
            for _ in 0..300 {
                r.step(0.5, 0.55, 0.01, &mut g);
            }
            r.pose
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
        // Without noise the RNG is not used and the path is the noise-free one.
        let quiet = |seed: u64| {
            let mut r = Robot::new(RobotParams::default(), Pose2::new(0.5, 0.5, 0.0));
            let mut g = ChaCha8Rng::seed_from_u64(seed);
            for _ in 0..300 {
                r.step(0.5, 0.55, 0.01, &mut g);
            }
            r.pose
        };
        assert_eq!(quiet(3), quiet(4));
        let noisy = run(3);
        let clean = quiet(3);
        assert!((noisy.x - clean.x).hypot(noisy.y - clean.y) < 0.1);
    }

    fn car_no_lag() -> CarParams {
        CarParams {
            speed_per_throttle_mps: 4.0,
            curvature_per_unit: -2.0,
            curvature_offset: 0.0,
            time_constant_s: 0.0,
        }
    }

    /// The motor channels for DonkeyCar's throttle and angle.
    fn car_duties(throttle: f32, angle: f32) -> (f32, f32) {
        let w = Mixing::Car.mix(throttle, angle);
        (w.left, w.right)
    }

    #[test]
    fn a_car_at_full_lock_drives_a_circle_of_its_turning_radius() {
        // Throttle 0.25: 1 m/s; angle -1: curvature 2 /m to the left, radius 0.5 m. Pi
        // seconds at 240 Hz: once round, back at the start, never more than 1 m from it.
        let start = Pose2::new(1.0, 2.0, 0.0);
        let mut car = Robot::car(RobotParams::default(), car_no_lag(), start);
        let (l, r) = car_duties(0.25, -1.0);
        let n = (std::f32::consts::PI * 240.0).round() as usize;
        let dt = std::f32::consts::PI / n as f32;
        let mut far = 0.0f32;
        for _ in 0..n {
            car.step(l, r, dt, &mut rng());
            far = far.max((car.pose.x - 1.0).hypot(car.pose.y - 2.0));
            // It turns left: y never below the start.
            assert!(car.pose.y >= 2.0 - 1e-4);
        }
        let gap = (car.pose.x - 1.0).hypot(car.pose.y - 2.0);
        assert!(gap < 2e-3, "{:?}", car.pose);
        assert!((far - 1.0).abs() < 1e-3, "diameter {far}");
        assert!((car.speed() - 1.0).abs() < 1e-6);
        assert!((car.yaw_rate() - 2.0).abs() < 1e-5, "{}", car.yaw_rate());
        // Past full lock the angle is clamped: channels asking for angle 1.5 turn as 1.
        let mut a = Robot::car(RobotParams::default(), car_no_lag(), Pose2::default());
        let mut b = a.clone();
        a.step(0.25 / 2.0 + 0.75, 0.25 / 2.0 - 0.75, 0.1, &mut rng());
        let (l, r) = car_duties(0.25, 1.0);
        b.step(l, r, 0.1, &mut rng());
        assert_eq!(a.pose, b.pose);
        assert!(a.pose.heading < 0.0, "angle +1 turns right");
    }

    #[test]
    fn a_cars_speed_lags_its_throttle() {
        // tau 0.3 s from rest at throttle 0.25 (target 1 m/s): after 0.3 s, 1 - e^-1 =
        // 0.6321 m/s and 0.3 e^-1 = 0.1104 m covered, in 72 steps as in one.
        let p = CarParams {
            time_constant_s: 0.3,
            ..car_no_lag()
        };
        let mut car = Robot::car(RobotParams::default(), p, Pose2::default());
        let (l, r) = car_duties(0.25, 0.0);
        for _ in 0..72 {
            car.step(l, r, 0.3 / 72.0, &mut rng());
        }
        assert!((car.pose.x - 0.110_364).abs() < 1e-5, "{:?}", car.pose);
        assert!((car.speed() - 0.632_12).abs() < 1e-5);
        assert_eq!(car.pose.y, 0.0);
        // Reset: at rest again.
        car.reset(Pose2::default());
        assert_eq!(car.speed(), 0.0);
        assert_eq!(car.car_params(), Some(&p));
        // Not a number on a channel: no throttle, no motion from it.
        let mut c = Robot::car(RobotParams::default(), car_no_lag(), Pose2::default());
        c.step(f32::NAN, f32::NAN, 0.1, &mut rng());
        assert_eq!(c.pose, Pose2::default());
        assert!(
            Robot::new(RobotParams::default(), Pose2::default())
                .car_params()
                .is_none()
        );
    }

    #[test]
    fn reset_stops_and_moves() {
        let mut r = Robot::new(RobotParams::default(), Pose2::default());
        let mut g = rng();
        r.step(1.0, 0.5, 0.1, &mut g);
        assert!(r.speed() > 0.0);
        r.reset(Pose2::new(1.0, 2.0, 3.0));
        assert_eq!(r.pose, Pose2::new(1.0, 2.0, 3.0));
        assert_eq!(r.speed(), 0.0);
    }

    #[test]
    fn params_parse_from_a_config_section() {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Doc {
            robot: RobotParams,
        }
        let d: Doc =
            toml::from_str("[robot]\nwheel_base_m = 0.15\n[robot.motor]\ndead_band = 0.1\n")
                .unwrap();
        assert_eq!(d.robot.wheel_base_m, 0.15);
        assert_eq!(d.robot.motor.dead_band, 0.1);
        assert_eq!(d.robot.motor.top_speed_mps, 0.5);
        assert_eq!(d.robot.speed_noise, 0.0);
        assert!(toml::from_str::<Doc>("[robot]\nwheelbase = 0.15\n").is_err());
        assert!(d.robot.validate().is_ok());
        let bad = RobotParams {
            wheel_base_m: 0.0,
            ..RobotParams::default()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("wheel_base_m"), "{err}");
    }
}
