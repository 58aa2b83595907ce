//! The simulator's motor hardware, of whichever kind `[motors]` names: the virtual PCA9685
//! motor HAT (`i2c`, `rppal` and `log` backends: the simulator always drives a HAT for
//! them) or the virtual GPIO H-bridge (`gpio`). [`VirtualMotors`] is the world's end (what
//! each wheel receives); [`SimMotors`] is the daemon's own driver on it.

use crate::control::WheelCommand;
use crate::hw::hbridge::HBridge;
use crate::hw::{HatLayout, MotorError, MotorHat, MotorOutput};

use super::virtual_bridge::{VirtualBridge, VirtualPin, VirtualPwm};
use super::virtual_hat::VirtualPca9685;

/// The virtual hardware the world reads the wheel duties from.
#[derive(Debug, Clone)]
pub enum VirtualMotors {
    /// A PCA9685 HAT wired as `layout`.
    Hat {
        hat: VirtualPca9685,
        layout: HatLayout,
    },
    /// An H-bridge on GPIO lines and PWM channels.
    Bridge(VirtualBridge),
}

impl VirtualMotors {
    /// The duty reaching each wheel (left, right) in the robot's sense (positive drives it
    /// forward): the hardware's own sense, negated where the motor is wired inverted.
    pub fn wheel_duties(&self, invert: (bool, bool)) -> (f32, f32) {
        match self {
            VirtualMotors::Hat { hat, layout } => hat.wheel_duties(*layout, invert.0, invert.1),
            VirtualMotors::Bridge(b) => {
                let (l, r) = b.bridge_duties();
                (flip(l, invert.0), flip(r, invert.1))
            }
        }
    }
}

/// Negates `x` when `invert` is set, without producing -0.0.
fn flip(x: f32, invert: bool) -> f32 {
    if invert && x != 0.0 { -x } else { x }
}

/// The daemon's motor driver on the virtual hardware.
pub enum SimMotors {
    Hat(MotorHat<VirtualPca9685>),
    Bridge(Box<HBridge<VirtualPin, VirtualPwm>>),
}

impl MotorOutput for SimMotors {
    fn drive(&mut self, cmd: WheelCommand) -> Result<(), MotorError> {
        match self {
            SimMotors::Hat(m) => m.drive(cmd),
            SimMotors::Bridge(m) => m.drive(cmd),
        }
    }
    fn stop(&mut self) -> Result<(), MotorError> {
        match self {
            SimMotors::Hat(m) => m.stop(),
            SimMotors::Bridge(m) => m.stop(),
        }
    }
    fn describe(&self) -> String {
        match self {
            SimMotors::Hat(m) => m.describe(),
            SimMotors::Bridge(m) => m.describe(),
        }
    }
}
