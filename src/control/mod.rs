//! From model outputs to wheel commands: the JetBot steering law (PD, optional I with
//! anti-windup) and differential-drive mixing. Everything here is pure.

pub mod steering;

pub use steering::{SteeringGains, SteeringLaw, SteeringOutput, SteeringState};

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
