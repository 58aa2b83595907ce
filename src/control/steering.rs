//! The steering law: owns the step from a policy's two outputs to wheel commands.
//!
//! This is NVIDIA JetBot's live-demo road-following law, kept exactly (including its quirks:
//! the derivative term is the per-frame difference of angles, not divided by time, and
//! `angle_last` starts at 0), plus two additions that are off by default:
//!
//! - an integral term `steering_ki * integral` where `integral` accumulates `angle * dt`
//!   (dt in seconds, from frame capture times) and is clamped to
//!   `±integral_limit / steering_ki`, so `|steering_ki * integral| <= integral_limit`
//!   (anti-windup by clamping);
//! - a `speed_steering` output mode for models that output `[speed, steering]` directly.
//!
//! ```text
//! xy:              x = out[0]; y = (0.5 - out[1]) / 2; angle = atan2(x, y); speed = speed_gain
//! speed_steering:  angle = out[1]; speed = speed_gain * clamp(out[0], 0, 1)
//! pid      = angle * steering_gain + (angle - angle_last) * steering_kd + steering_ki * integral
//! steering = pid + steering_bias
//! left  = clamp(speed + steering, 0, 1);  right = clamp(speed - steering, 0, 1)
//!                  (JetBot's differential mixing; `mixing = "car"`: super::Mixing)
//! ```
//!
//! Everything here is pure: no clock, no I/O.

use serde::{Deserialize, Serialize};

use super::{Mixing, WheelCommand};
use crate::policy::contract::OutputKind;

/// The tunable gains of the steering law.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SteeringGains {
    /// Base speed, 0..1 (JetBot slider 0..1, default 0: the robot does not move).
    pub speed_gain: f32,
    /// Proportional gain on the angle (JetBot slider 0..1, default 0.2).
    pub steering_gain: f32,
    /// Gain on the per-frame change of angle (JetBot slider 0..0.5, default 0).
    pub steering_kd: f32,
    /// Constant added to the steering (JetBot slider -0.3..0.3, default 0).
    pub steering_bias: f32,
    /// Integral gain (not in JetBot; default 0 = off). The integral only runs when > 0.
    pub steering_ki: f32,
    /// Largest magnitude of the integral term `steering_ki * integral` (anti-windup).
    pub integral_limit: f32,
    /// How speed and steering reach the motor channels (differential drive by default).
    #[serde(default)]
    pub mixing: Mixing,
}

impl Default for SteeringGains {
    /// JetBot's slider defaults; the integral term off with a 0.3 limit.
    fn default() -> Self {
        Self {
            speed_gain: 0.0,
            steering_gain: 0.2,
            steering_kd: 0.0,
            steering_bias: 0.0,
            steering_ki: 0.0,
            integral_limit: 0.3,
            mixing: Mixing::Differential,
        }
    }
}

/// The memory of the law between frames, for saving and restoring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SteeringState {
    /// The angle of the previous step (0 before the first one, as in JetBot).
    pub angle_last: f32,
    /// Sum of `angle * dt` (seconds), clamped to `±integral_limit / steering_ki`.
    pub integral: f32,
}

impl Default for SteeringState {
    fn default() -> Self {
        Self {
            angle_last: 0.0,
            integral: 0.0,
        }
    }
}

/// One step of the law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SteeringOutput {
    /// The angle the law steers on: `atan2(x, y)` in radians (xy) or the model's steering
    /// output (speed_steering).
    pub angle: f32,
    /// `pid + steering_bias`, before mixing.
    pub steering: f32,
    /// The speed before mixing: `speed_gain`, scaled by the model's speed in speed_steering.
    pub speed: f32,
    /// The mixed wheel commands: each in 0..=1 (differential), -1..=1 (car).
    pub wheels: WheelCommand,
}

/// JetBot's steering law with its state (previous angle and integral).
#[derive(Debug, Clone)]
pub struct SteeringLaw {
    gains: SteeringGains,
    kind: OutputKind,
    state: SteeringState,
}

impl SteeringLaw {
    pub fn new(gains: SteeringGains, kind: OutputKind) -> Self {
        Self {
            gains,
            kind,
            state: SteeringState::default(),
        }
    }

    /// What the model outputs mean to this law.
    pub fn output_kind(&self) -> OutputKind {
        self.kind
    }

    pub fn gains(&self) -> SteeringGains {
        self.gains
    }

    /// Replaces the gains, keeping the state. The integral is brought back inside the new
    /// anti-windup bound (and cleared when the new `steering_ki` is not positive), so
    /// `|steering_ki * integral| <= integral_limit` holds at once.
    pub fn set_gains(&mut self, gains: SteeringGains) {
        self.gains = gains;
        self.state.integral = match self.integral_bound() {
            Some(bound) => self.state.integral.clamp(-bound, bound),
            None => 0.0,
        };
    }

    /// Forgets the previous angle and the integral (for example when autonomous driving
    /// restarts).
    pub fn reset(&mut self) {
        self.state = SteeringState::default();
    }

    pub fn state(&self) -> SteeringState {
        self.state
    }

    pub fn restore(&mut self, state: SteeringState) {
        self.state = state;
    }

    /// `integral_limit / steering_ki` when the integral term is on; never NaN or negative,
    /// so it is safe as a clamp bound.
    fn integral_bound(&self) -> Option<f32> {
        let ki = self.gains.steering_ki;
        // `NaN > 0.0` is false, so a NaN gain turns the integral off.
        if ki > 0.0 {
            // `f32::max` ignores a NaN operand: a NaN limit gives a bound of 0.
            Some((self.gains.integral_limit / ki).max(0.0))
        } else {
            None
        }
    }

    /// Runs the law on one pair of model outputs. `dt_s` is the time since the previous
    /// frame in seconds (from capture times); it only feeds the integral, and a value that
    /// is not finite or not positive means no integration on this step.
    ///
    /// `out` is assumed finite: the daemon rejects non-finite model outputs before they
    /// reach the law, so this function does not check them (a NaN would reach the wheels
    /// as NaN and poison `angle_last`).
    pub fn step(&mut self, out: [f32; 2], dt_s: f32) -> SteeringOutput {
        let g = self.gains;
        let (angle, speed) = match self.kind {
            OutputKind::Xy => {
                let x = out[0];
                let y = (0.5 - out[1]) / 2.0;
                (x.atan2(y), g.speed_gain)
            }
            OutputKind::SpeedSteering => (out[1], g.speed_gain * out[0].clamp(0.0, 1.0)),
        };

        let i_term = match self.integral_bound() {
            Some(bound) => {
                if dt_s.is_finite() && dt_s > 0.0 {
                    self.state.integral = (self.state.integral + angle * dt_s).clamp(-bound, bound);
                }
                g.steering_ki * self.state.integral
            }
            None => 0.0,
        };

        let pid =
            angle * g.steering_gain + (angle - self.state.angle_last) * g.steering_kd + i_term;
        self.state.angle_last = angle;
        let steering = pid + g.steering_bias;
        let wheels = g.mixing.mix(speed, steering);
        SteeringOutput {
            angle,
            steering,
            speed,
            wheels,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOL: f32 = 1e-6;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= TOL
    }

    fn gains(speed: f32, gain: f32) -> SteeringGains {
        SteeringGains {
            speed_gain: speed,
            steering_gain: gain,
            ..SteeringGains::default()
        }
    }

    #[test]
    fn defaults_are_jetbot_sliders() {
        let g = SteeringGains::default();
        assert_eq!(g.speed_gain, 0.0);
        assert_eq!(g.steering_gain, 0.2);
        assert_eq!(g.steering_kd, 0.0);
        assert_eq!(g.steering_bias, 0.0);
        assert_eq!(g.steering_ki, 0.0);
        assert_eq!(g.integral_limit, 0.3);
        // The robot does not move with the defaults.
        let mut law = SteeringLaw::new(g, OutputKind::Xy);
        assert!(law.step([0.0, 0.5], 0.033).wheels.is_stop());
    }

    #[test]
    fn straight_ahead_drives_both_wheels_at_speed_gain() {
        // out = [0, 0.5]: x = 0, y = (0.5 - 0.5) / 2 = 0, atan2(0, 0) = 0.
        let mut law = SteeringLaw::new(gains(0.3, 0.2), OutputKind::Xy);
        let o = law.step([0.0, 0.5], 0.033);
        assert_eq!(o.angle, 0.0);
        assert_eq!(o.steering, 0.0);
        assert_eq!(o.wheels, WheelCommand::new(0.3, 0.3));
        // out = [0, -1]: y = (0.5 + 1) / 2 = 0.75, atan2(0, 0.75) = 0: also straight.
        let o = law.step([0.0, -1.0], 0.033);
        assert_eq!(o.angle, 0.0);
        assert_eq!(o.wheels, WheelCommand::new(0.3, 0.3));
    }

    #[test]
    fn target_right_turns_right() {
        // out = [0.5, 0.0]: x = 0.5, y = (0.5 - 0) / 2 = 0.25,
        // angle = atan2(0.5, 0.25) = atan(2) = 1.1071487 rad.
        // steering = 1.1071487 * 0.2 = 0.2214297
        // left = 0.3 + 0.2214297 = 0.5214297, right = 0.3 - 0.2214297 = 0.0785703
        let mut law = SteeringLaw::new(gains(0.3, 0.2), OutputKind::Xy);
        let o = law.step([0.5, 0.0], 0.033);
        assert!(close(o.angle, 1.1071487), "{}", o.angle);
        assert!(close(o.steering, 0.2214297), "{}", o.steering);
        assert!(close(o.speed, 0.3));
        assert!(close(o.wheels.left, 0.5214297), "{}", o.wheels.left);
        assert!(close(o.wheels.right, 0.0785703), "{}", o.wheels.right);
        // Mirror: out = [-0.5, 0.0] gives angle -1.1071487 and the wheels swapped.
        law.reset();
        let o = law.step([-0.5, 0.0], 0.033);
        assert!(close(o.angle, -1.1071487));
        assert!(close(o.wheels.left, 0.0785703));
        assert!(close(o.wheels.right, 0.5214297));
    }

    #[test]
    fn kd_uses_the_per_frame_difference() {
        let g = SteeringGains {
            speed_gain: 0.5,
            steering_gain: 0.2,
            steering_kd: 0.1,
            ..SteeringGains::default()
        };
        let mut law = SteeringLaw::new(g, OutputKind::Xy);
        // Step 1: a1 = atan2(0.5, 0.25) = 1.1071487, angle_last = 0:
        // pid = 1.1071487 * 0.2 + (1.1071487 - 0) * 0.1 = 0.2214297 + 0.1107149 = 0.3321446
        let o1 = law.step([0.5, 0.0], 0.033);
        assert!(close(o1.steering, 0.3321446), "{}", o1.steering);
        // Step 2: out = [0.25, 0.0]: y = 0.25, a2 = atan2(0.25, 0.25) = pi/4 = 0.7853982
        // pid = 0.7853982 * 0.2 + (0.7853982 - 1.1071487) * 0.1
        //     = 0.1570796 - 0.0321751 = 0.1249046
        // dt does not matter: a step of 1 s gives the same value.
        let o2 = law.step([0.25, 0.0], 1.0);
        assert!(close(o2.angle, std::f32::consts::FRAC_PI_4));
        assert!(close(o2.steering, 0.1249046), "{}", o2.steering);
        assert!(close(o2.wheels.left, 0.5 + 0.1249046));
        assert!(close(o2.wheels.right, 0.5 - 0.1249046));
        assert_eq!(law.state().angle_last, o2.angle);
    }

    #[test]
    fn bias_shifts_the_steering() {
        let g = SteeringGains {
            speed_gain: 0.4,
            steering_bias: -0.05,
            ..SteeringGains::default()
        };
        let mut law = SteeringLaw::new(g, OutputKind::Xy);
        // Straight ahead: steering = 0 + (-0.05); left = 0.35, right = 0.45.
        let o = law.step([0.0, 0.5], 0.033);
        assert!(close(o.steering, -0.05));
        assert!(close(o.wheels.left, 0.35));
        assert!(close(o.wheels.right, 0.45));
    }

    #[test]
    fn wheels_are_clamped_to_0_and_1() {
        // Hard right with a big gain: angle = atan2(1, 0.25) = 1.3258177,
        // steering = 1.3258177 * 1.0 = 1.3258177; left = 0.8 + 1.33 -> 1, right -> 0.
        let mut law = SteeringLaw::new(gains(0.8, 1.0), OutputKind::Xy);
        let o = law.step([1.0, 0.0], 0.033);
        assert!(close(o.angle, 1.3258177), "{}", o.angle);
        assert_eq!(o.wheels, WheelCommand::new(1.0, 0.0));
        // Target behind-left: y = (0.5 - 1) / 2 = -0.25, x = -0.1: angle = atan2(-0.1, -0.25)
        // = -2.7610862; left = 0.8 - 2.76 -> 0, right = 0.8 + 2.76 -> 1.
        let o = law.step([-0.1, 1.0], 0.033);
        assert!(close(o.angle, -2.7610862), "{}", o.angle);
        assert_eq!(o.wheels, WheelCommand::new(0.0, 1.0));
    }

    #[test]
    fn integral_accumulates_angle_times_dt() {
        let g = SteeringGains {
            speed_gain: 0.5,
            steering_gain: 0.0,
            steering_ki: 1.0,
            integral_limit: 0.3,
            ..SteeringGains::default()
        };
        let mut law = SteeringLaw::new(g, OutputKind::SpeedSteering);
        // angle = 0.2 (speed_steering: angle = out[1]), dt = 0.1: integral = 0.02,
        // steering = 1.0 * 0.02 = 0.02.
        let o = law.step([1.0, 0.2], 0.1);
        assert!(close(law.state().integral, 0.02));
        assert!(close(o.steering, 0.02));
        // dt 0, negative or NaN: no integration (the term still acts).
        for dt in [0.0, -0.1, f32::NAN, f32::INFINITY] {
            let o = law.step([1.0, 0.2], dt);
            assert!(close(law.state().integral, 0.02));
            assert!(close(o.steering, 0.02));
        }
        // Another 0.05 s at 0.2: integral = 0.03.
        law.step([1.0, 0.2], 0.05);
        assert!(close(law.state().integral, 0.03));
        // ki = 0 turns it off: no accumulation and no term.
        let mut off = SteeringLaw::new(
            SteeringGains {
                steering_ki: 0.0,
                ..g
            },
            OutputKind::SpeedSteering,
        );
        let o = off.step([1.0, 0.2], 0.1);
        assert_eq!(off.state().integral, 0.0);
        assert_eq!(o.steering, 0.0);
    }

    #[test]
    fn integral_anti_windup() {
        // ki = 0.5, limit 0.3: the integral is clamped to 0.3 / 0.5 = 0.6.
        let g = SteeringGains {
            speed_gain: 0.5,
            steering_gain: 0.0,
            steering_ki: 0.5,
            integral_limit: 0.3,
            ..SteeringGains::default()
        };
        let mut law = SteeringLaw::new(g, OutputKind::SpeedSteering);
        // 100 steps at angle 1.0, dt 0.05: unclamped that is 5.0.
        for _ in 0..100 {
            let o = law.step([1.0, 1.0], 0.05);
            assert!((g.steering_ki * law.state().integral).abs() <= g.integral_limit + TOL);
            assert!(o.steering <= 0.3 + TOL);
        }
        assert!(close(law.state().integral, 0.6));
        // Sign flips: each step removes 0.05, so the integral crosses zero after 12 steps
        // (0.6 / 0.05), not after ~100 as it would with an integral wound up to 5.0.
        let mut steps = 0;
        while law.state().integral > 0.0 {
            law.step([1.0, -1.0], 0.05);
            steps += 1;
            assert!(
                steps <= 13,
                "integral still {} after {steps} steps",
                law.state().integral
            );
        }
        assert!(steps >= 12);
        // And it saturates on the other side too.
        for _ in 0..100 {
            law.step([1.0, -1.0], 0.05);
        }
        assert!(close(law.state().integral, -0.6));
        assert!(close(g.steering_ki * law.state().integral, -0.3));
    }

    #[test]
    fn set_gains_reclamps_the_integral() {
        let g = SteeringGains {
            steering_ki: 0.5,
            integral_limit: 0.3,
            ..SteeringGains::default()
        };
        let mut law = SteeringLaw::new(g, OutputKind::SpeedSteering);
        for _ in 0..100 {
            law.step([1.0, 1.0], 0.05);
        }
        assert!(close(law.state().integral, 0.6));
        // ki doubled: bound 0.3 / 1.0 = 0.3.
        law.set_gains(SteeringGains {
            steering_ki: 1.0,
            ..g
        });
        assert!(close(law.state().integral, 0.3));
        // ki off: integral cleared.
        law.set_gains(SteeringGains {
            steering_ki: 0.0,
            ..g
        });
        assert_eq!(law.state().integral, 0.0);
    }

    #[test]
    fn speed_steering_mode_scales_speed() {
        let g = SteeringGains {
            speed_gain: 0.6,
            steering_gain: 0.2,
            ..SteeringGains::default()
        };
        let mut law = SteeringLaw::new(g, OutputKind::SpeedSteering);
        // out = [0.5, 0.25]: speed = 0.6 * 0.5 = 0.3, angle = 0.25, steering = 0.05;
        // left = 0.35, right = 0.25.
        let o = law.step([0.5, 0.25], 0.033);
        assert!(close(o.speed, 0.3));
        assert!(close(o.angle, 0.25));
        assert!(close(o.steering, 0.05));
        assert!(close(o.wheels.left, 0.35));
        assert!(close(o.wheels.right, 0.25));
        // Negative speed is clamped to 0: straight ahead then means stop.
        let o = law.step([-0.7, 0.0], 0.033);
        assert_eq!(o.speed, 0.0);
        assert!(o.wheels.is_stop());
        // Speed above 1 is clamped to 1: speed = 0.6.
        let o = law.step([3.0, 0.0], 0.033);
        assert!(close(o.speed, 0.6));
        assert_eq!(o.wheels, WheelCommand::new(0.6, 0.6));
        // Positive steering turns right (left wheel faster).
        let o = law.step([1.0, 1.0], 0.033);
        assert!(o.wheels.left > o.wheels.right);
    }

    #[test]
    fn save_and_restore_give_identical_outputs() {
        let g = SteeringGains {
            speed_gain: 0.4,
            steering_gain: 0.3,
            steering_kd: 0.2,
            steering_bias: 0.01,
            steering_ki: 0.4,
            integral_limit: 0.2,
            mixing: Mixing::Differential,
        };
        let inputs = [
            [0.3, 0.1],
            [-0.2, 0.4],
            [0.7, -0.3],
            [0.0, 0.5],
            [-0.6, 0.2],
        ];
        let mut law = SteeringLaw::new(g, OutputKind::Xy);
        law.step([0.5, 0.0], 0.03);
        law.step([0.4, 0.2], 0.03);
        let saved = law.state();
        assert_ne!(saved, SteeringState::default());
        let first: Vec<SteeringOutput> = inputs.iter().map(|o| law.step(*o, 0.03)).collect();

        let mut other = SteeringLaw::new(g, OutputKind::Xy);
        other.restore(saved);
        let second: Vec<SteeringOutput> = inputs.iter().map(|o| other.step(*o, 0.03)).collect();
        assert_eq!(first, second);

        law.restore(saved);
        let third: Vec<SteeringOutput> = inputs.iter().map(|o| law.step(*o, 0.03)).collect();
        assert_eq!(first, third);

        law.reset();
        assert_eq!(law.state(), SteeringState::default());
    }
}
