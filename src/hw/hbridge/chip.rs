//! The pure half of the GPIO H-bridge drivers: which level each bridge input takes for a
//! mapped motor speed, per chip. No I/O here; [`super::HBridge`] writes what these say.
//!
//! Facts from the chips' truth tables (see REFERENCE.md):
//! - **L298N**: IN1/IN2 pick the direction, ENA carries the speed as PWM. IN1 = IN2 with
//!   EN high is a fast stop (brake); EN low lets the motor run free (coast).
//! - **TB6612FNG**: AIN1/AIN2 pick the direction, PWMA carries the speed, STBY must be high
//!   to run. IN1 = IN2 = high is a short brake whatever PWM says; IN1 = IN2 = low is off
//!   (high impedance: coast).
//! - **DRV8833**: no enable pin: the PWM goes on the inputs themselves. IN1 = PWM, IN2 = 0
//!   is forward with fast decay (the motor coasts between pulses); both 0 coasts, both 1
//!   brakes. nSLEEP (optional) must be high to run.

use serde::{Deserialize, Serialize};

/// An H-bridge chip on the board's GPIO and PWM pins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BridgeChip {
    /// L298N modules: IN1/IN2 direction pins and an ENA/ENB PWM per motor.
    L298n,
    /// TB6612FNG breakouts: AIN1/AIN2 direction pins, PWMA/PWMB, and STBY.
    Tb6612fng,
    /// DRV8833 breakouts: PWM on both inputs of each motor, and nSLEEP.
    Drv8833,
}

impl BridgeChip {
    pub fn as_str(self) -> &'static str {
        match self {
            BridgeChip::L298n => "l298n",
            BridgeChip::Tb6612fng => "tb6612fng",
            BridgeChip::Drv8833 => "drv8833",
        }
    }

    /// Whether the speed goes on a separate enable pin (L298N, TB6612FNG) or on the bridge
    /// inputs themselves (DRV8833).
    pub fn has_enable_pwm(self) -> bool {
        !matches!(self, BridgeChip::Drv8833)
    }

    /// The name the chip's data sheet gives its run/standby pin, if it has one.
    pub fn standby_pin_name(self) -> Option<&'static str> {
        match self {
            BridgeChip::L298n => None,
            BridgeChip::Tb6612fng => Some("STBY"),
            BridgeChip::Drv8833 => Some("nSLEEP"),
        }
    }
}

/// What a stopped motor does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StopMode {
    /// The bridge lets go: the motor runs down freely. All PWMs at 0 on every chip.
    #[default]
    Coast,
    /// The bridge shorts the motor: it stops within a few centimetres. TB6612FNG: IN1 = IN2
    /// = high, PWM 0. L298N: IN1 = IN2 = low with EN at 100 %. DRV8833: both inputs at 100 %.
    Brake,
}

/// The levels of one motor's bridge inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BridgeState {
    /// Direction pins plus an enable PWM (L298N, TB6612FNG); `duty` in 0..=1.
    DirPwm { in1: bool, in2: bool, duty: f32 },
    /// PWM on both inputs (DRV8833); each duty in 0..=1.
    InPwm { in1: f32, in2: f32 },
}

/// The bridge state for a mapped speed in -255..=255 (from
/// [`crate::hw::motor_hat::mapped_value`]: trims and `invert` already applied). Positive is
/// the bridge's forward: OUT1 driven high. Zero is the `stop` state.
pub fn bridge_state(chip: BridgeChip, mapped: i32, stop: StopMode) -> BridgeState {
    let duty = mapped.unsigned_abs().min(255) as f32 / 255.0;
    match (chip.has_enable_pwm(), mapped.signum()) {
        (true, 1) => BridgeState::DirPwm {
            in1: true,
            in2: false,
            duty,
        },
        (true, -1) => BridgeState::DirPwm {
            in1: false,
            in2: true,
            duty,
        },
        (false, 1) => BridgeState::InPwm {
            in1: duty,
            in2: 0.0,
        },
        (false, -1) => BridgeState::InPwm {
            in1: 0.0,
            in2: duty,
        },
        _ => stopped_state(chip, stop),
    }
}

/// A stopped motor's bridge state on `chip`.
pub fn stopped_state(chip: BridgeChip, stop: StopMode) -> BridgeState {
    match (chip, stop) {
        (BridgeChip::Drv8833, StopMode::Coast) => BridgeState::InPwm { in1: 0.0, in2: 0.0 },
        (BridgeChip::Drv8833, StopMode::Brake) => BridgeState::InPwm { in1: 1.0, in2: 1.0 },
        (BridgeChip::Tb6612fng, StopMode::Brake) => BridgeState::DirPwm {
            in1: true,
            in2: true,
            duty: 0.0,
        },
        (BridgeChip::L298n, StopMode::Brake) => BridgeState::DirPwm {
            in1: false,
            in2: false,
            duty: 1.0,
        },
        (_, StopMode::Coast) => BridgeState::DirPwm {
            in1: false,
            in2: false,
            duty: 0.0,
        },
    }
}

/// The motor's signed drive in -1..=1 as the bridge delivers it: what the simulator's
/// virtual bridge feeds the motor model. Brake and coast both give 0; a TB6612FNG or
/// DRV8833 whose standby pin is low gives 0 whatever its inputs say.
pub fn delivered_drive(state: BridgeState, awake: bool) -> f32 {
    if !awake {
        return 0.0;
    }
    match state {
        BridgeState::DirPwm { in1, in2, duty } => match (in1, in2) {
            (true, false) => duty,
            (false, true) => -duty,
            _ => 0.0,
        },
        BridgeState::InPwm { in1, in2 } => in1 - in2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn l298n_and_tb6612_take_the_direction_on_pins_and_the_speed_on_pwm() {
        for chip in [BridgeChip::L298n, BridgeChip::Tb6612fng] {
            assert_eq!(
                bridge_state(chip, 102, StopMode::Coast),
                BridgeState::DirPwm {
                    in1: true,
                    in2: false,
                    duty: 0.4
                }
            );
            assert_eq!(
                bridge_state(chip, -255, StopMode::Coast),
                BridgeState::DirPwm {
                    in1: false,
                    in2: true,
                    duty: 1.0
                }
            );
            assert_eq!(
                bridge_state(chip, 0, StopMode::Coast),
                BridgeState::DirPwm {
                    in1: false,
                    in2: false,
                    duty: 0.0
                }
            );
        }
    }

    #[test]
    fn drv8833_puts_the_duty_on_one_input_and_holds_the_other_low() {
        assert_eq!(
            bridge_state(BridgeChip::Drv8833, 51, StopMode::Coast),
            BridgeState::InPwm { in1: 0.2, in2: 0.0 }
        );
        assert_eq!(
            bridge_state(BridgeChip::Drv8833, -51, StopMode::Brake),
            BridgeState::InPwm { in1: 0.0, in2: 0.2 }
        );
        assert_eq!(
            bridge_state(BridgeChip::Drv8833, 0, StopMode::Coast),
            BridgeState::InPwm { in1: 0.0, in2: 0.0 }
        );
    }

    #[test]
    fn brake_follows_each_chips_truth_table() {
        assert_eq!(
            stopped_state(BridgeChip::Tb6612fng, StopMode::Brake),
            BridgeState::DirPwm {
                in1: true,
                in2: true,
                duty: 0.0
            }
        );
        assert_eq!(
            stopped_state(BridgeChip::L298n, StopMode::Brake),
            BridgeState::DirPwm {
                in1: false,
                in2: false,
                duty: 1.0
            }
        );
        assert_eq!(
            stopped_state(BridgeChip::Drv8833, StopMode::Brake),
            BridgeState::InPwm { in1: 1.0, in2: 1.0 }
        );
    }

    #[test]
    fn speeds_beyond_full_scale_are_limited() {
        assert_eq!(
            bridge_state(BridgeChip::L298n, 400, StopMode::Coast),
            BridgeState::DirPwm {
                in1: true,
                in2: false,
                duty: 1.0
            }
        );
    }

    #[test]
    fn a_stopped_or_sleeping_bridge_delivers_nothing() {
        for chip in [
            BridgeChip::L298n,
            BridgeChip::Tb6612fng,
            BridgeChip::Drv8833,
        ] {
            for stop in [StopMode::Coast, StopMode::Brake] {
                assert_eq!(delivered_drive(stopped_state(chip, stop), true), 0.0);
            }
            assert_eq!(
                delivered_drive(bridge_state(chip, 255, StopMode::Coast), false),
                0.0
            );
            assert_eq!(
                delivered_drive(bridge_state(chip, -102, StopMode::Coast), true),
                -0.4
            );
        }
    }
}
