//! From model outputs to wheel commands: the JetBot steering law (PD, optional I with
//! anti-windup) and the mixing of its speed and steering onto the two motor channels
//! (differential drive, or the simulator's car). Everything here is pure.

pub mod steering;

use serde::{Deserialize, Serialize};

pub use steering::{SteeringGains, SteeringLaw, SteeringOutput, SteeringState};

/// How the law's speed and steering reach the two motor channels.
///
/// ```text
/// differential (JetBot):  left = clamp(speed + steering, 0, 1)   right = clamp(speed - steering, 0, 1)
/// car (DonkeyCar):        throttle = clamp(speed, 0, 1)          angle = clamp(steering, -1, 1)
///                         left = (throttle + angle) / 2          right = (throttle - angle) / 2
/// ```
///
/// The car's channels carry DonkeyCar's `(throttle, angle)` without loss (`throttle = left +
/// right`, `angle = left - right`, [`Mixing::unmix`]), where differential mixing would clip
/// a full-lock turn at a low throttle. Only the simulator's car (`sim.vehicle = "car"`, the
/// replay of a DonkeyCar tub) reads them so; no motor driver for a steering servo and an ESC
/// exists yet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mixing {
    #[default]
    Differential,
    Car,
}

impl Mixing {
    /// The motor channels for the law's `speed` and `steering`.
    pub fn mix(self, speed: f32, steering: f32) -> WheelCommand {
        match self {
            Mixing::Differential => WheelCommand::new(
                (speed + steering).clamp(0.0, 1.0),
                (speed - steering).clamp(0.0, 1.0),
            ),
            Mixing::Car => {
                let (t, a) = (speed.clamp(0.0, 1.0), steering.clamp(-1.0, 1.0));
                WheelCommand::new((t + a) / 2.0, (t - a) / 2.0)
            }
        }
    }

    /// `(speed, steering)` back from the channels: `((left + right) / 2, (left - right) / 2)`
    /// for differential drive (exact where the clamp did not bite), `(left + right, left -
    /// right)` for the car (DonkeyCar's throttle and angle).
    pub fn unmix(self, wheels: WheelCommand) -> (f32, f32) {
        let (l, r) = (wheels.left, wheels.right);
        match self {
            Mixing::Differential => ((l + r) / 2.0, (l - r) / 2.0),
            Mixing::Car => (l + r, l - r),
        }
    }
}

/// Normalised wheel commands, each in -1..=1 (positive drives the robot forward).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelCommand {
    pub left: f32,
    pub right: f32,
}

impl WheelCommand {
    pub const STOP: WheelCommand = WheelCommand {
        left: 0.0,
        right: 0.0,
    };

    pub fn new(left: f32, right: f32) -> Self {
        Self { left, right }
    }

    pub fn is_stop(&self) -> bool {
        self.left == 0.0 && self.right == 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: (f32, f32), b: (f32, f32)) -> bool {
        (a.0 - b.0).abs() < 1e-6 && (a.1 - b.1).abs() < 1e-6
    }

    #[test]
    fn differential_mixing_clips_a_full_lock_turn_at_low_throttle() {
        let m = Mixing::Differential;
        let w = m.mix(0.3, 0.1);
        assert!(close((w.left, w.right), (0.4, 0.2)), "{w:?}");
        assert!(close(m.unmix(m.mix(0.3, 0.1)), (0.3, 0.1)));
        // DonkeyCar's throttle 0.25 at full lock left (-1): the wheels clip to (0, 1), which
        // reads back as throttle 0.5 and half lock.
        let w = m.mix(0.25, -1.0);
        assert_eq!(w, WheelCommand::new(0.0, 1.0));
        assert!(close(m.unmix(w), (0.5, -0.5)));
    }

    #[test]
    fn car_mixing_carries_throttle_and_angle_without_loss() {
        let m = Mixing::Car;
        let w = m.mix(0.25, -1.0);
        assert_eq!(w, WheelCommand::new(-0.375, 0.625));
        assert!(close(m.unmix(w), (0.25, -1.0)));
        for (t, a) in [(0.0, 0.0), (1.0, 1.0), (1.0, -1.0), (0.4, 0.3), (0.0, -0.7)] {
            let w = m.mix(t, a);
            assert!(w.left.abs() <= 1.0 && w.right.abs() <= 1.0);
            assert!(close(m.unmix(w), (t, a)), "{t} {a}");
        }
        // Out of range: no reverse, no more than full lock.
        assert!(close(m.unmix(m.mix(-0.5, 3.0)), (0.0, 1.0)));
        assert!(close(m.unmix(m.mix(2.0, -3.0)), (1.0, -1.0)));
    }
}
