//! A virtual GPIO H-bridge: the simulator's end of the `gpio` motor backend. It hands out
//! embedded-hal output pins and PWMs keyed by the configured GPIO line and PWM channel, so
//! the daemon's own [`crate::hw::hbridge::HBridge`] driver writes to it exactly as it
//! would to gpio-cdev lines and sysfs PWM; the world reads back what each motor receives
//! through the chip's truth table ([`crate::hw::hbridge::chip::delivered_drive`]).

use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::{Arc, Mutex, MutexGuard};

use embedded_hal::digital::{ErrorType as PinErrorType, OutputPin};
use embedded_hal::pwm::{ErrorType as PwmErrorType, SetDutyCycle};

use crate::hw::hbridge::chip::{BridgeState, delivered_drive};
use crate::hw::hbridge::{GpioMotorPins, GpioMotorsConfig, PwmChannel};

/// PWM resolution of the virtual channels.
const MAX_DUTY: u16 = 10_000;

#[derive(Debug, Default)]
struct Levels {
    lines: HashMap<u32, bool>,
    pwms: HashMap<PwmChannel, u16>,
}

/// The virtual bridge: levels of every line and PWM channel, shared with its pins.
#[derive(Debug, Clone)]
pub struct VirtualBridge {
    cfg: GpioMotorsConfig,
    levels: Arc<Mutex<Levels>>,
}

/// One virtual GPIO line.
#[derive(Debug)]
pub struct VirtualPin {
    line: u32,
    levels: Arc<Mutex<Levels>>,
}

/// One virtual PWM channel.
#[derive(Debug)]
pub struct VirtualPwm {
    channel: PwmChannel,
    levels: Arc<Mutex<Levels>>,
}

fn lock(levels: &Mutex<Levels>) -> MutexGuard<'_, Levels> {
    // A panic while holding the lock cannot leave the maps half-written: use them as they are.
    levels.lock().unwrap_or_else(|p| p.into_inner())
}

impl VirtualBridge {
    /// A bridge wired as `cfg` says; every line low and every duty 0.
    pub fn new(cfg: GpioMotorsConfig) -> Self {
        Self {
            cfg,
            levels: Arc::default(),
        }
    }

    pub fn config(&self) -> &GpioMotorsConfig {
        &self.cfg
    }

    /// The output pin for GPIO line `line`.
    pub fn pin(&self, line: u32) -> VirtualPin {
        VirtualPin {
            line,
            levels: self.levels.clone(),
        }
    }

    /// The PWM for `channel`.
    pub fn pwm(&self, channel: PwmChannel) -> VirtualPwm {
        VirtualPwm {
            channel,
            levels: self.levels.clone(),
        }
    }

    /// Whether line `line` is high now.
    pub fn line(&self, line: u32) -> bool {
        lock(&self.levels)
            .lines
            .get(&line)
            .copied()
            .unwrap_or(false)
    }

    /// Channel `channel`'s duty now, 0..=1.
    pub fn duty(&self, channel: PwmChannel) -> f32 {
        let d = lock(&self.levels).pwms.get(&channel).copied().unwrap_or(0);
        f32::from(d) / f32::from(MAX_DUTY)
    }

    fn motor_state(&self, p: &GpioMotorPins) -> BridgeState {
        let line = |l: Option<u32>| l.is_some_and(|l| self.line(l));
        let duty = |c: Option<PwmChannel>| c.map_or(0.0, |c| self.duty(c));
        if self.cfg.chip.has_enable_pwm() {
            BridgeState::DirPwm {
                in1: line(p.in1),
                in2: line(p.in2),
                duty: duty(p.pwm),
            }
        } else {
            BridgeState::InPwm {
                in1: duty(p.in1_pwm),
                in2: duty(p.in2_pwm),
            }
        }
    }

    /// Each motor's signed drive (left, right) in -1..=1 in the bridge's own sense: a
    /// standby pin that is low, a brake and a coast all give 0.
    pub fn bridge_duties(&self) -> (f32, f32) {
        let awake = match (self.cfg.standby, self.cfg.chip.standby_pin_name()) {
            (Some(l), Some(_)) => self.line(l),
            _ => true,
        };
        (
            delivered_drive(self.motor_state(&self.cfg.left), awake),
            delivered_drive(self.motor_state(&self.cfg.right), awake),
        )
    }
}

impl PinErrorType for VirtualPin {
    type Error = Infallible;
}

impl OutputPin for VirtualPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        lock(&self.levels).lines.insert(self.line, false);
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Infallible> {
        lock(&self.levels).lines.insert(self.line, true);
        Ok(())
    }
}

impl PwmErrorType for VirtualPwm {
    type Error = Infallible;
}

impl SetDutyCycle for VirtualPwm {
    fn max_duty_cycle(&self) -> u16 {
        MAX_DUTY
    }
    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Infallible> {
        lock(&self.levels)
            .pwms
            .insert(self.channel, duty.min(MAX_DUTY));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::WheelCommand;
    use crate::hw::MotorOutput;
    use crate::hw::hbridge::{BridgeChip, assemble};
    use crate::hw::motor_hat::MotorTrim;

    fn cfg(chip: BridgeChip) -> GpioMotorsConfig {
        let ch = |c| {
            Some(PwmChannel {
                chip: 0,
                channel: c,
            })
        };
        let (left, right) = if chip.has_enable_pwm() {
            (
                GpioMotorPins {
                    in1: Some(1),
                    in2: Some(2),
                    pwm: ch(0),
                    ..Default::default()
                },
                GpioMotorPins {
                    in1: Some(3),
                    in2: Some(4),
                    pwm: ch(2),
                    ..Default::default()
                },
            )
        } else {
            (
                GpioMotorPins {
                    in1_pwm: ch(0),
                    in2_pwm: ch(1),
                    ..Default::default()
                },
                GpioMotorPins {
                    in1_pwm: ch(2),
                    in2_pwm: ch(3),
                    ..Default::default()
                },
            )
        };
        GpioMotorsConfig {
            chip,
            standby: (chip != BridgeChip::L298n).then_some(9),
            left,
            right,
            ..GpioMotorsConfig::default()
        }
    }

    #[test]
    fn the_drivers_commands_come_back_as_signed_duties_on_every_chip() {
        for chip in [
            BridgeChip::L298n,
            BridgeChip::Tb6612fng,
            BridgeChip::Drv8833,
        ] {
            let bridge = VirtualBridge::new(cfg(chip));
            let mut m = assemble(
                bridge.config(),
                (MotorTrim::default(), MotorTrim::default()),
                "virtual".into(),
                |l, _| Ok(bridge.pin(l)),
                |c, _| Ok(bridge.pwm(c)),
            )
            .unwrap();
            m.drive(WheelCommand::new(0.4, -1.0)).unwrap();
            assert_eq!(bridge.bridge_duties(), (0.4, -1.0), "{chip:?}");
            m.stop().unwrap();
            assert_eq!(bridge.bridge_duties(), (0.0, 0.0), "{chip:?}");
            m.drive(WheelCommand::new(0.2, 0.2)).unwrap();
            drop(m);
            assert_eq!(bridge.bridge_duties(), (0.0, 0.0), "{chip:?}: dropped");
        }
    }

    #[test]
    fn a_sleeping_chip_delivers_nothing() {
        let bridge = VirtualBridge::new(cfg(BridgeChip::Tb6612fng));
        bridge.pin(1).set_high().unwrap();
        bridge
            .pwm(PwmChannel {
                chip: 0,
                channel: 0,
            })
            .set_duty_cycle(MAX_DUTY)
            .unwrap();
        assert_eq!(bridge.bridge_duties().0, 0.0, "STBY low");
        bridge.pin(9).set_high().unwrap();
        assert_eq!(bridge.bridge_duties().0, 1.0);
    }
}
