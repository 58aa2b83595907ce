//! The `[motors.gpio]` config section: which H-bridge chip, which GPIO lines and sysfs PWM
//! channels drive which motor, and the checks that turn a wiring mistake into an error
//! naming the key before any pin is touched.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::chip::{BridgeChip, StopMode};

/// One sysfs PWM channel: `/sys/class/pwm/pwmchip{chip}/pwm{channel}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PwmChannel {
    /// The PWM chip: `pwmchipN` under `pwm_root`.
    pub chip: u32,
    /// The channel on that chip: `pwmN`.
    pub channel: u32,
}

impl std::fmt::Display for PwmChannel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "pwmchip{}/pwm{}", self.chip, self.channel)
    }
}

/// Where the PWM comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PwmBackend {
    /// Linux's `/sys/class/pwm` (Jetson Nano, Raspberry Pi, most boards).
    #[default]
    Sysfs,
    /// rppal's PWM on a Raspberry Pi (a build with `--features rpi`): channels 0-3 of chip 0.
    Rppal,
}

/// `[motors.gpio.left]` / `[motors.gpio.right]`: one motor's pins. L298N and TB6612FNG
/// take `in1`, `in2` (GPIO line offsets on `gpiochip`) and `pwm`; DRV8833 takes `in1_pwm`
/// and `in2_pwm`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpioMotorPins {
    /// L298N, TB6612FNG: the IN1 direction line's offset on `gpiochip`.
    pub in1: Option<u32>,
    /// L298N, TB6612FNG: the IN2 direction line's offset on `gpiochip`.
    pub in2: Option<u32>,
    /// L298N, TB6612FNG: the enable (ENA/ENB, PWMA/PWMB) line's PWM channel.
    pub pwm: Option<PwmChannel>,
    /// DRV8833: the PWM channel on IN1.
    pub in1_pwm: Option<PwmChannel>,
    /// DRV8833: the PWM channel on IN2.
    pub in2_pwm: Option<PwmChannel>,
}

/// `[motors.gpio]`: a motor driver on the board's GPIO and PWM pins (`motors.backend =
/// "gpio"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpioMotorsConfig {
    pub chip: BridgeChip,
    /// The GPIO character device the direction and standby lines are on.
    pub gpiochip: PathBuf,
    /// Where the PWM chips are (tests point this at a fake tree).
    pub pwm_root: PathBuf,
    pub pwm_backend: PwmBackend,
    /// PWM frequency (10 ..= 100000 Hz).
    pub pwm_hz: f32,
    pub stop: StopMode,
    /// TB6612FNG STBY or DRV8833 nSLEEP line, held high while the daemon runs.
    pub standby: Option<u32>,
    pub left: GpioMotorPins,
    pub right: GpioMotorPins,
}

impl Default for GpioMotorsConfig {
    fn default() -> Self {
        Self {
            chip: BridgeChip::L298n,
            gpiochip: PathBuf::from("/dev/gpiochip0"),
            pwm_root: PathBuf::from(super::sysfs_pwm::SYSFS_PWM_ROOT),
            pwm_backend: PwmBackend::Sysfs,
            pwm_hz: 1000.0,
            stop: StopMode::Coast,
            standby: None,
            left: GpioMotorPins::default(),
            right: GpioMotorPins::default(),
        }
    }
}

/// A wiring mistake: the key and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WiringError {
    pub key: String,
    pub message: String,
}

impl GpioMotorsConfig {
    /// Checks that each motor has exactly the pins its chip needs, that no line or PWM
    /// channel is used twice, and the frequency.
    pub fn check(&self) -> Result<(), WiringError> {
        let err = |key: String, message: String| WiringError {
            key: format!("motors.gpio.{key}"),
            message,
        };
        if !(10.0..=100_000.0).contains(&self.pwm_hz) {
            return Err(err(
                "pwm_hz".into(),
                format!("{} is outside 10 ..= 100000", self.pwm_hz),
            ));
        }
        let chip = self.chip.as_str();
        if self.standby.is_some() && self.chip.standby_pin_name().is_none() {
            return Err(err(
                "standby".into(),
                format!("{chip} has no standby pin: remove the key"),
            ));
        }
        let mut lines: Vec<(String, u32)> = Vec::new();
        let mut pwms: Vec<(String, PwmChannel)> = Vec::new();
        if let Some(l) = self.standby {
            lines.push(("standby".into(), l));
        }
        for (side, p) in [("left", &self.left), ("right", &self.right)] {
            let (needed, unwanted): (&[&str], &[&str]) = if self.chip.has_enable_pwm() {
                (&["in1", "in2", "pwm"], &["in1_pwm", "in2_pwm"])
            } else {
                (&["in1_pwm", "in2_pwm"], &["in1", "in2", "pwm"])
            };
            let present = |k: &str| match k {
                "in1" => p.in1.is_some(),
                "in2" => p.in2.is_some(),
                "pwm" => p.pwm.is_some(),
                "in1_pwm" => p.in1_pwm.is_some(),
                _ => p.in2_pwm.is_some(),
            };
            if let Some(k) = needed.iter().find(|k| !present(k)) {
                return Err(err(
                    format!("{side}.{k}"),
                    format!("missing: {chip} needs {} for each motor", needed.join(", ")),
                ));
            }
            if let Some(k) = unwanted.iter().find(|k| present(k)) {
                return Err(err(
                    format!("{side}.{k}"),
                    format!("not used by {chip} (it takes {})", needed.join(", ")),
                ));
            }
            for (k, l) in [("in1", p.in1), ("in2", p.in2)] {
                if let Some(l) = l {
                    lines.push((format!("{side}.{k}"), l));
                }
            }
            for (k, c) in [
                ("pwm", p.pwm),
                ("in1_pwm", p.in1_pwm),
                ("in2_pwm", p.in2_pwm),
            ] {
                if let Some(c) = c {
                    pwms.push((format!("{side}.{k}"), c));
                }
            }
        }
        for (i, (k, l)) in lines.iter().enumerate() {
            if let Some((k0, _)) = lines[..i].iter().find(|(_, l0)| l0 == l) {
                return Err(err(k.clone(), format!("line {l} is already used by {k0}")));
            }
        }
        if self.pwm_backend == PwmBackend::Rppal {
            if let Some((k, c)) = pwms.iter().find(|(_, c)| c.chip != 0 || c.channel > 3) {
                return Err(err(
                    k.clone(),
                    format!("{c}: rppal drives channels 0-3 of chip 0"),
                ));
            }
        }
        for (i, (k, c)) in pwms.iter().enumerate() {
            if let Some((k0, _)) = pwms[..i].iter().find(|(_, c0)| c0 == c) {
                return Err(err(k.clone(), format!("{c} is already used by {k0}")));
            }
        }
        Ok(())
    }

    /// One line for logs and `--dry-run`.
    pub fn summary(&self) -> String {
        let side = |p: &GpioMotorPins| match (p.in1, p.in2, p.pwm, p.in1_pwm, p.in2_pwm) {
            (Some(a), Some(b), Some(c), _, _) => format!("IN1 line {a}, IN2 line {b}, PWM {c}"),
            (_, _, _, Some(a), Some(b)) => format!("IN1 PWM {a}, IN2 PWM {b}"),
            _ => "incomplete".into(),
        };
        format!(
            "{} H-bridge on {} and {}: left {}; right {}; {} Hz, stop = {}",
            self.chip.as_str(),
            self.gpiochip.display(),
            self.pwm_root.display(),
            side(&self.left),
            side(&self.right),
            self.pwm_hz,
            match self.stop {
                StopMode::Coast => "coast",
                StopMode::Brake => "brake",
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn l298n() -> GpioMotorsConfig {
        let pins = |a, b, ch| GpioMotorPins {
            in1: Some(a),
            in2: Some(b),
            pwm: Some(PwmChannel {
                chip: 0,
                channel: ch,
            }),
            ..GpioMotorPins::default()
        };
        GpioMotorsConfig {
            left: pins(76, 51, 0),
            right: pins(12, 77, 2),
            ..GpioMotorsConfig::default()
        }
    }

    #[test]
    fn a_complete_l298n_wiring_passes() {
        assert_eq!(l298n().check(), Ok(()));
        assert!(
            l298n()
                .summary()
                .contains("left IN1 line 76, IN2 line 51, PWM pwmchip0/pwm0")
        );
    }

    #[test]
    fn a_missing_pin_names_its_key_and_what_the_chip_needs() {
        let mut c = l298n();
        c.right.in2 = None;
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "motors.gpio.right.in2");
        assert!(e.message.contains("in1, in2, pwm"), "{}", e.message);
    }

    #[test]
    fn drv8833_refuses_direction_pins() {
        let mut c = l298n();
        c.chip = BridgeChip::Drv8833;
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "motors.gpio.left.in1_pwm");
        c.left = GpioMotorPins {
            in1_pwm: Some(PwmChannel {
                chip: 0,
                channel: 0,
            }),
            in2_pwm: Some(PwmChannel {
                chip: 0,
                channel: 1,
            }),
            in1: Some(3),
            ..GpioMotorPins::default()
        };
        assert_eq!(c.check().unwrap_err().key, "motors.gpio.left.in1");
    }

    #[test]
    fn a_line_or_pwm_used_twice_is_refused() {
        let mut c = l298n();
        c.right.in1 = Some(51);
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "motors.gpio.right.in1");
        assert!(e.message.contains("left.in2"), "{}", e.message);
        let mut c = l298n();
        c.right.pwm = c.left.pwm;
        assert_eq!(c.check().unwrap_err().key, "motors.gpio.right.pwm");
    }

    #[test]
    fn rppal_takes_channels_0_to_3_of_chip_0() {
        let mut c = l298n();
        c.pwm_backend = PwmBackend::Rppal;
        assert_eq!(c.check(), Ok(()));
        c.right.pwm = Some(PwmChannel {
            chip: 1,
            channel: 0,
        });
        assert_eq!(c.check().unwrap_err().key, "motors.gpio.right.pwm");
    }

    #[test]
    fn l298n_has_no_standby_pin() {
        let mut c = l298n();
        c.standby = Some(200);
        assert_eq!(c.check().unwrap_err().key, "motors.gpio.standby");
        c.chip = BridgeChip::Tb6612fng;
        assert_eq!(c.check(), Ok(()));
    }
}
