//! Motor HAT layouts: which PCA9685 channels drive which motor, and how.
//!
//! Facts from the boards' own drivers (see REFERENCE.md):
//! - **Adafruit** DC & Stepper Motor HAT, as on the NVIDIA JetBot: PCA9685 at 0x60, PWM
//!   1600 Hz, TB6612 bridges. Motor 1 (left) PWM 8, IN2 9, IN1 10; motor 2 (right) PWM 13,
//!   IN2 12, IN1 11. Speed is the duty on the PWM pin; IN1/IN2 are logic levels (forced fully
//!   on or off). On the JetBot the motors are wired so that the HAT's BACKWARD direction
//!   drives the robot forward: that is the per-motor `invert` flag.
//! - **Waveshare** JetBot boards: the same chip and address, but the duty goes straight to the
//!   H-bridge inputs: left IN A 1 / IN B 0, right IN A 2 / IN B 3.
//! - **Yahboom** JetBot: PCA9685 at 0x40; right motor on channels 8/9, left on 10/11 (the
//!   camera lift uses 12/13, which this driver never touches).

use pwm_pca9685::Channel;
use serde::{Deserialize, Serialize};

/// How one motor is wired to the PCA9685.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotorPins {
    /// A PWM pin carries the speed; two logic pins select the direction (TB6612 style).
    /// Forward (as the HAT names it) is IN1 high, IN2 low.
    PwmDir {
        pwm: Channel,
        in1: Channel,
        in2: Channel,
    },
    /// The duty goes to one of two bridge inputs; forward is IN A, backward IN B.
    DirectPwm { in_a: Channel, in_b: Channel },
}

impl MotorPins {
    /// Every channel this motor uses, for the stop sequence.
    pub fn channels(&self) -> Vec<Channel> {
        match *self {
            MotorPins::PwmDir { pwm, in1, in2 } => vec![pwm, in1, in2],
            MotorPins::DirectPwm { in_a, in_b } => vec![in_a, in_b],
        }
    }
}

/// A motor HAT model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HatLayout {
    /// Adafruit DC & Stepper Motor HAT (NVIDIA JetBot, SparkFun JetBot kit).
    Adafruit,
    /// Waveshare JetBot expansion boards.
    Waveshare,
    /// Yahboom JetBot.
    Yahboom,
}

impl HatLayout {
    pub fn as_str(self) -> &'static str {
        match self {
            HatLayout::Adafruit => "adafruit",
            HatLayout::Waveshare => "waveshare",
            HatLayout::Yahboom => "yahboom",
        }
    }

    /// The board's factory I2C address (7-bit).
    pub fn default_address(self) -> u8 {
        match self {
            HatLayout::Adafruit | HatLayout::Waveshare => 0x60,
            HatLayout::Yahboom => 0x40,
        }
    }

    /// The PWM frequency the board's own driver uses.
    pub fn default_pwm_hz(self) -> f32 {
        1600.0
    }

    /// Whether the stock robot needs the direction flipped on each motor (left, right) so
    /// that a positive command drives it forward. True for the NVIDIA JetBot's Adafruit
    /// wiring, whose software sends BACKWARD for a positive value.
    pub fn default_invert(self) -> (bool, bool) {
        match self {
            HatLayout::Adafruit => (true, true),
            HatLayout::Waveshare | HatLayout::Yahboom => (false, false),
        }
    }

    /// (left, right) motor wiring.
    pub fn pins(self) -> (MotorPins, MotorPins) {
        match self {
            HatLayout::Adafruit => (
                MotorPins::PwmDir {
                    pwm: Channel::C8,
                    in1: Channel::C10,
                    in2: Channel::C9,
                },
                MotorPins::PwmDir {
                    pwm: Channel::C13,
                    in1: Channel::C11,
                    in2: Channel::C12,
                },
            ),
            HatLayout::Waveshare => (
                MotorPins::DirectPwm {
                    in_a: Channel::C1,
                    in_b: Channel::C0,
                },
                MotorPins::DirectPwm {
                    in_a: Channel::C2,
                    in_b: Channel::C3,
                },
            ),
            HatLayout::Yahboom => (
                MotorPins::DirectPwm {
                    in_a: Channel::C10,
                    in_b: Channel::C11,
                },
                MotorPins::DirectPwm {
                    in_a: Channel::C8,
                    in_b: Channel::C9,
                },
            ),
        }
    }
}

/// PCA9685 prescale for a PWM frequency with its 25 MHz internal oscillator, rounded as
/// the datasheet (and Adafruit's driver) do: `round(25e6 / (4096 * f)) - 1`, limited to
/// the chip's 3..=255. 1600 Hz gives 3.
pub fn prescale_for(freq_hz: f32) -> u8 {
    let raw = (25_000_000.0 / (4096.0 * freq_hz as f64)).round() - 1.0;
    raw.clamp(3.0, 255.0) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prescale_matches_the_datasheet() {
        assert_eq!(prescale_for(1600.0), 3);
        // 25e6 / (4096 * 50) = 122.07 -> 122 - 1
        assert_eq!(prescale_for(50.0), 121);
        assert_eq!(prescale_for(60.0), 101);
        assert_eq!(prescale_for(10.0), 255);
        assert_eq!(prescale_for(10_000.0), 3);
    }

    #[test]
    fn layouts_use_disjoint_channels() {
        for layout in [
            HatLayout::Adafruit,
            HatLayout::Waveshare,
            HatLayout::Yahboom,
        ] {
            let (l, r) = layout.pins();
            let mut all: Vec<u8> = l
                .channels()
                .into_iter()
                .chain(r.channels())
                .map(|c| c as u8)
                .collect();
            let n = all.len();
            all.sort();
            all.dedup();
            assert_eq!(all.len(), n, "{layout:?}");
        }
    }
}
