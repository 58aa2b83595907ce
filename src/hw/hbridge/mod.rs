//! Motor drivers for kits without a motor HAT: an L298N, TB6612FNG or DRV8833 H-bridge on
//! the board's GPIO lines (gpio-cdev) and hardware PWM (sysfs), behind the same
//! [`crate::hw::MotorOutput`] seam as the PCA9685 HAT (`motors.backend = "gpio"`).
//!
//! - [`chip`]: the pure truth tables (command -> input levels, stop, brake).
//! - [`driver`]: [`HBridge`], the driver over embedded-hal pins and PWMs.
//! - [`sysfs_pwm`]: Linux's `/sys/class/pwm` as an embedded-hal PWM.
//! - [`config`]: the `[motors.gpio]` section and its wiring checks.
//!
//! [`assemble`] turns a config into a driver with pins from any source: gpio-cdev lines
//! and sysfs PWM on a robot ([`open_linux`]), the simulator's virtual bridge, or mocks.
//!
//! On a Jetson Nano the 40-pin header's hardware PWM is on pins 32 (`pwmchip0/pwm0`) and
//! 33 (`pwmchip0/pwm2`) once enabled with `sudo /opt/nvidia/jetson-io/jetson-io.py`; a
//! Raspberry Pi's comes from `dtoverlay=pwm-2chan` (`pwmchip0/pwm0` and `pwm1`). There is
//! no software-PWM fallback: a kit needs one hardware PWM channel per motor (two per motor
//! for a DRV8833).

pub mod chip;
pub mod config;
pub mod driver;
#[cfg(feature = "rpi")]
pub mod rppal_pwm;
pub mod sysfs_pwm;

pub use chip::{BridgeChip, BridgeState, StopMode};
pub use config::{GpioMotorPins, GpioMotorsConfig, PwmBackend, PwmChannel};
pub use driver::{BridgeMotor, HBridge, MotorWiring, Named};

use embedded_hal::digital::OutputPin;
use embedded_hal::pwm::SetDutyCycle;

use super::motor_hat::MotorTrim;
use super::motors::{MotorError, Result};

/// Builds the driver `cfg` describes. `pin(line, name)` opens a GPIO line as an output, low;
/// `pwm(channel, name)` opens a PWM channel at `cfg.pwm_hz`, duty 0. The wiring is checked
/// before either is called.
pub fn assemble<P, W>(
    cfg: &GpioMotorsConfig,
    trims: (MotorTrim, MotorTrim),
    description: String,
    mut pin: impl FnMut(u32, &str) -> Result<P>,
    mut pwm: impl FnMut(PwmChannel, &str) -> Result<W>,
) -> Result<HBridge<P, W>>
where
    P: OutputPin,
    W: SetDutyCycle,
{
    cfg.check()
        .map_err(|e| MotorError::Invalid(format!("{}: {}", e.key, e.message)))?;
    let mut motor = |side: &str, p: &GpioMotorPins, trim| -> Result<BridgeMotor<P, W>> {
        let missing = |k: &str| MotorError::Invalid(format!("motors.gpio.{side}.{k}: missing"));
        let wiring = if cfg.chip.has_enable_pwm() {
            let in1 = p.in1.ok_or_else(|| missing("in1"))?;
            let in2 = p.in2.ok_or_else(|| missing("in2"))?;
            let ch = p.pwm.ok_or_else(|| missing("pwm"))?;
            let n1 = format!("{side} IN1 (line {in1} of {})", cfg.gpiochip.display());
            let n2 = format!("{side} IN2 (line {in2} of {})", cfg.gpiochip.display());
            let np = format!("{side} PWM ({ch})");
            MotorWiring::DirPwm {
                in1: Named::new(pin(in1, &n1)?, n1),
                in2: Named::new(pin(in2, &n2)?, n2),
                pwm: Named::new(pwm(ch, &np)?, np),
            }
        } else {
            let c1 = p.in1_pwm.ok_or_else(|| missing("in1_pwm"))?;
            let c2 = p.in2_pwm.ok_or_else(|| missing("in2_pwm"))?;
            let n1 = format!("{side} IN1 ({c1})");
            let n2 = format!("{side} IN2 ({c2})");
            MotorWiring::InPwm {
                in1: Named::new(pwm(c1, &n1)?, n1),
                in2: Named::new(pwm(c2, &n2)?, n2),
            }
        };
        Ok(BridgeMotor { wiring, trim })
    };
    let left = motor("left", &cfg.left, trims.0)?;
    let right = motor("right", &cfg.right, trims.1)?;
    let standby = match (cfg.standby, cfg.chip.standby_pin_name()) {
        (Some(line), Some(label)) => {
            let n = format!("{label} (line {line} of {})", cfg.gpiochip.display());
            Some(Named::new(pin(line, &n)?, n))
        }
        _ => None,
    };
    HBridge::new(cfg.chip, cfg.stop, left, right, standby, description)
}

/// Direction and standby lines through gpio-cdev, requested as outputs (initially low) with
/// consumer `jetpilot`; the PWMs from `pwm`.
#[cfg(feature = "linux-hal")]
fn open_cdev<W: SetDutyCycle>(
    cfg: &GpioMotorsConfig,
    trims: (MotorTrim, MotorTrim),
    pwm: impl FnMut(PwmChannel, &str) -> Result<W>,
) -> Result<HBridge<linux_embedded_hal::CdevPin, W>> {
    use gpio_cdev::{Chip, LineRequestFlags};
    cfg.check()
        .map_err(|e| MotorError::Invalid(format!("{}: {}", e.key, e.message)))?;
    let mut gpio = Chip::new(&cfg.gpiochip).map_err(|e| MotorError::Gpio {
        pin: cfg.gpiochip.display().to_string(),
        reason: super::buzzer::open_advice(&e.to_string()),
    })?;
    let pin = |line: u32, name: &str| -> Result<linux_embedded_hal::CdevPin> {
        let err = |e: gpio_cdev::Error| MotorError::Gpio {
            pin: name.to_string(),
            reason: super::buzzer::open_advice(&e.to_string()),
        };
        let handle = gpio
            .get_line(line)
            .and_then(|l| l.request(LineRequestFlags::OUTPUT, 0, "jetpilot"))
            .map_err(err)?;
        linux_embedded_hal::CdevPin::new(handle).map_err(err)
    };
    assemble(cfg, trims, cfg.summary(), pin, pwm)
}

/// The H-bridge on this Linux board with sysfs PWM (`pwm_backend = "sysfs"`).
#[cfg(feature = "linux-hal")]
pub fn open_linux(
    cfg: &GpioMotorsConfig,
    trims: (MotorTrim, MotorTrim),
) -> Result<HBridge<linux_embedded_hal::CdevPin, sysfs_pwm::SysfsPwm>> {
    open_cdev(cfg, trims, |ch: PwmChannel, name: &str| {
        sysfs_pwm::SysfsPwm::open(&cfg.pwm_root, ch.chip, ch.channel, cfg.pwm_hz).map_err(|e| {
            MotorError::Gpio {
                pin: name.to_string(),
                reason: e.to_string(),
            }
        })
    })
}

/// The H-bridge on a Raspberry Pi with rppal's PWM (`pwm_backend = "rppal"`).
#[cfg(all(feature = "linux-hal", feature = "rpi"))]
pub fn open_rppal(
    cfg: &GpioMotorsConfig,
    trims: (MotorTrim, MotorTrim),
) -> Result<HBridge<linux_embedded_hal::CdevPin, rppal_pwm::RppalPwm>> {
    open_cdev(cfg, trims, |ch: PwmChannel, name: &str| {
        rppal_pwm::RppalPwm::open(ch.channel, cfg.pwm_hz).map_err(|e| MotorError::Gpio {
            pin: name.to_string(),
            reason: e.to_string(),
        })
    })
}
