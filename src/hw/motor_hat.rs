//! The PCA9685 motor HAT driver, written against `embedded_hal::i2c::I2c` through the
//! pwm-pca9685 crate, so the same code drives the Jetson's `/dev/i2c-1`, a Raspberry Pi's
//! bus, embedded-hal-mock in tests and the simulator's virtual PCA9685.
//!
//! A command becomes register writes in two pure steps: [`mapped_value`] (JetBot's
//! `int(255 * (alpha * value + beta))`, then the per-motor `invert`) and [`pin_states`]
//! (which channel is fully on, fully off, or at which duty). The driver keeps its own copy
//! of what each channel was last set to and writes only the channels that change; a stop
//! always writes every motor channel. Motors are released on [`MotorHat::destroy`] and on
//! drop.

use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;
use pwm_pca9685::{Channel, OutputDriver, Pca9685};

use super::layout::{HatLayout, MotorPins, prescale_for};
use super::motors::{MotorError, MotorOutput, Result};
use crate::control::WheelCommand;

/// Per-motor calibration, as in JetBot's `Motor` (alpha, beta) plus the wiring flag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorTrim {
    /// Scale on the command (1.0: none). Use it to match a slower motor to a faster one.
    pub alpha: f32,
    /// Offset added after scaling (0.0: none).
    pub beta: f32,
    /// Flip the direction: the stock NVIDIA JetBot needs this on both motors.
    pub invert: bool,
}

impl Default for MotorTrim {
    fn default() -> Self {
        Self {
            alpha: 1.0,
            beta: 0.0,
            invert: false,
        }
    }
}

/// Everything the driver needs to know about the board.
#[derive(Debug, Clone, PartialEq)]
pub struct HatSettings {
    pub layout: HatLayout,
    /// 7-bit I2C address.
    pub address: u8,
    pub pwm_hz: f32,
    pub left: MotorTrim,
    pub right: MotorTrim,
    /// Extra attempts after a failed I2C transaction before it becomes a fault.
    pub retries: u32,
    /// Bus name for messages, e.g. `/dev/i2c-1`.
    pub bus_name: String,
}

impl HatSettings {
    /// The board's own defaults (address, frequency, the stock robot's wiring).
    pub fn for_layout(layout: HatLayout) -> Self {
        let (li, ri) = layout.default_invert();
        Self {
            layout,
            address: layout.default_address(),
            pwm_hz: layout.default_pwm_hz(),
            left: MotorTrim {
                invert: li,
                ..MotorTrim::default()
            },
            right: MotorTrim {
                invert: ri,
                ..MotorTrim::default()
            },
            retries: 2,
            bus_name: "i2c".to_string(),
        }
    }
}

/// What one PCA9685 channel is set to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PinState {
    /// ON = 4096 (the full-on bit), OFF = 0: a logic high.
    FullOn,
    /// The full-off bit: a logic low, whatever the ON register says.
    FullOff,
    /// ON = 0, OFF = duty, of 4096 ticks (1..=4080 here).
    Duty(u16),
}

/// JetBot's mapping of a command in -1..=1 to a signed 8-bit speed:
/// `int(255 * (alpha * value + beta))`, truncated toward zero, limited to -255..=255, then
/// negated when the motor is inverted. Positive means the HAT's own "forward".
pub fn mapped_value(value: f32, trim: MotorTrim) -> i32 {
    let v = if value.is_finite() {
        value.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let raw = (255.0 * (trim.alpha * v + trim.beta)).clamp(-255.0, 255.0) as i32;
    if trim.invert { -raw } else { raw }
}

/// The channel states for one motor at a mapped speed, in the order they must be written.
/// A direction pin is always lowered before the other is raised, so the bridge never sees
/// both inputs high; zero releases the motor (all of its channels off).
pub fn pin_states(pins: MotorPins, mapped: i32) -> Vec<(Channel, PinState)> {
    let duty = PinState::Duty((mapped.unsigned_abs().min(255) * 16) as u16);
    match pins {
        MotorPins::PwmDir { pwm, in1, in2 } => match mapped.signum() {
            0 => vec![
                (pwm, PinState::FullOff),
                (in1, PinState::FullOff),
                (in2, PinState::FullOff),
            ],
            1 => vec![
                (pwm, duty),
                (in2, PinState::FullOff),
                (in1, PinState::FullOn),
            ],
            _ => vec![
                (pwm, duty),
                (in1, PinState::FullOff),
                (in2, PinState::FullOn),
            ],
        },
        MotorPins::DirectPwm { in_a, in_b } => match mapped.signum() {
            0 => vec![(in_a, PinState::FullOff), (in_b, PinState::FullOff)],
            1 => vec![(in_b, PinState::FullOff), (in_a, duty)],
            _ => vec![(in_a, PinState::FullOff), (in_b, duty)],
        },
    }
}

/// A PCA9685 motor HAT on an embedded-hal I2C bus.
pub struct MotorHat<I2C: I2c> {
    /// `None` only after [`MotorHat::destroy`] took the bus back.
    pca: Option<Pca9685<I2C>>,
    settings: HatSettings,
    left: MotorPins,
    right: MotorPins,
    /// What each channel was last set to; `None` = unknown (never written, or a write failed).
    written: [Option<PinState>; 16],
}

impl<I2C: I2c> MotorHat<I2C> {
    /// Takes the bus, initialises the chip and releases both motors:
    /// MODE1 sleep (prescale is only writable asleep), MODE2 totem-pole outputs, PRESCALE,
    /// MODE1 awake, 500 us for the oscillator, then every motor channel fully off.
    pub fn init(bus: I2C, settings: HatSettings, delay: &mut impl DelayNs) -> Result<Self> {
        // Prescale 255..=3 spans 24..=1526 Hz; 1600 Hz (Adafruit's setting) rounds to prescale 3.
        if !(24.0..=1600.0).contains(&settings.pwm_hz) {
            return Err(MotorError::Invalid(format!(
                "pwm frequency {} Hz is outside 24..=1600 Hz",
                settings.pwm_hz
            )));
        }
        let pca = Pca9685::new(bus, settings.address).map_err(|_| {
            MotorError::Invalid(format!(
                "I2C address {:#04x} is not a valid PCA9685 address",
                settings.address
            ))
        })?;
        let (left, right) = settings.layout.pins();
        let mut hat = Self {
            pca: Some(pca),
            settings,
            left,
            right,
            written: [None; 16],
        };
        let prescale = prescale_for(hat.settings.pwm_hz);
        hat.with_retry(|p| p.disable())?;
        hat.with_retry(|p| p.set_output_driver(OutputDriver::TotemPole))?;
        hat.with_retry(|p| p.set_prescale(prescale))?;
        hat.with_retry(|p| p.enable())?;
        delay.delay_us(500);
        hat.release()?;
        Ok(hat)
    }

    pub fn settings(&self) -> &HatSettings {
        &self.settings
    }

    /// Releases the motors and hands the bus back.
    pub fn destroy(mut self) -> Option<I2C> {
        if let Err(e) = self.release() {
            tracing::warn!(error = %e, "could not release the motors before giving the bus back");
        }
        self.pca.take().map(Pca9685::destroy)
    }

    /// Runs one bus operation, retrying up to `settings.retries` more times.
    fn with_retry<T>(
        &mut self,
        mut op: impl FnMut(&mut Pca9685<I2C>) -> std::result::Result<T, pwm_pca9685::Error<I2C::Error>>,
    ) -> Result<T> {
        let address = self.settings.address;
        let Some(pca) = self.pca.as_mut() else {
            return Err(MotorError::Invalid("the bus was already given back".into()));
        };
        let attempts = self.settings.retries + 1;
        let mut last = String::new();
        for attempt in 1..=attempts {
            match op(pca) {
                Ok(v) => return Ok(v),
                Err(pwm_pca9685::Error::I2C(e)) => {
                    last = format!("{:?}", embedded_hal::i2c::Error::kind(&e));
                    tracing::debug!(attempt, error = %last, "I2C write failed");
                }
                Err(pwm_pca9685::Error::InvalidInputData) => {
                    return Err(MotorError::Invalid("register value out of range".into()));
                }
            }
        }
        Err(MotorError::Bus {
            address,
            attempts,
            reason: last,
        })
    }

    fn write_pin(&mut self, ch: Channel, state: PinState, force: bool) -> Result<()> {
        let idx = ch as usize;
        if !force && self.written[idx] == Some(state) {
            return Ok(());
        }
        self.written[idx] = None;
        match state {
            PinState::FullOff => self.with_retry(|p| p.set_channel_full_off(ch))?,
            PinState::FullOn => {
                // Clear the full-off bit first: it takes precedence over full-on.
                self.with_retry(|p| p.set_channel_off(ch, 0))?;
                self.with_retry(|p| p.set_channel_full_on(ch, 0))?;
            }
            PinState::Duty(d) => self.with_retry(|p| p.set_channel_on_off(ch, 0, d.min(4095)))?,
        }
        self.written[idx] = Some(state);
        Ok(())
    }

    /// Writes "off" to every channel of both motors, whatever was written before. Tries
    /// both motors even if the first fails, then reports the first error.
    pub fn release(&mut self) -> Result<()> {
        let (l, r) = (self.left, self.right);
        let a = self.write_motor(l, 0, true);
        let b = self.write_motor(r, 0, true);
        a.and(b)
    }

    fn write_motor(&mut self, pins: MotorPins, mapped: i32, force: bool) -> Result<()> {
        for (ch, state) in pin_states(pins, mapped) {
            self.write_pin(ch, state, force)?;
        }
        Ok(())
    }
}

impl<I2C: I2c + Send> MotorOutput for MotorHat<I2C> {
    fn drive(&mut self, cmd: WheelCommand) -> Result<()> {
        let l = mapped_value(cmd.left, self.settings.left);
        let r = mapped_value(cmd.right, self.settings.right);
        self.write_motor(self.left, l, false)?;
        self.write_motor(self.right, r, false)
    }

    fn stop(&mut self) -> Result<()> {
        self.release()
    }

    fn describe(&self) -> String {
        format!(
            "{} motor HAT (PCA9685 at {:#04x} on {}, {} Hz)",
            self.settings.layout.as_str(),
            self.settings.address,
            self.settings.bus_name,
            self.settings.pwm_hz
        )
    }
}

impl<I2C: I2c> Drop for MotorHat<I2C> {
    fn drop(&mut self) {
        if self.pca.is_some() {
            if let Err(e) = self.release() {
                tracing::error!(error = %e, "could not release the motors on shutdown");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PLAIN: MotorTrim = MotorTrim {
        alpha: 1.0,
        beta: 0.0,
        invert: false,
    };

    #[test]
    fn mapping_follows_jetbot() {
        assert_eq!(mapped_value(1.0, PLAIN), 255);
        assert_eq!(mapped_value(0.5, PLAIN), 127); // int(127.5) truncates
        assert_eq!(mapped_value(-0.5, PLAIN), -127);
        assert_eq!(mapped_value(0.003, PLAIN), 0);
        assert_eq!(mapped_value(2.0, PLAIN), 255);
        assert_eq!(mapped_value(f32::NAN, PLAIN), 0);
        let inv = MotorTrim {
            invert: true,
            ..PLAIN
        };
        assert_eq!(mapped_value(0.5, inv), -127);
        let trimmed = MotorTrim {
            alpha: 0.9,
            beta: 0.05,
            invert: false,
        };
        // 255 * (0.9 * 0.5 + 0.05) = 127.5 -> 127
        assert_eq!(mapped_value(0.5, trimmed), 127);
    }

    #[test]
    fn adafruit_pins_for_each_direction() {
        let (left, _) = HatLayout::Adafruit.pins();
        assert_eq!(
            pin_states(left, 100),
            vec![
                (Channel::C8, PinState::Duty(1600)),
                (Channel::C9, PinState::FullOff),
                (Channel::C10, PinState::FullOn),
            ]
        );
        assert_eq!(
            pin_states(left, -255),
            vec![
                (Channel::C8, PinState::Duty(4080)),
                (Channel::C10, PinState::FullOff),
                (Channel::C9, PinState::FullOn),
            ]
        );
        assert!(
            pin_states(left, 0)
                .iter()
                .all(|(_, s)| *s == PinState::FullOff)
        );
    }

    #[test]
    fn direct_pwm_pins_lower_before_raise() {
        let (_, right) = HatLayout::Waveshare.pins();
        assert_eq!(
            pin_states(right, 10),
            vec![
                (Channel::C3, PinState::FullOff),
                (Channel::C2, PinState::Duty(160))
            ]
        );
        assert_eq!(
            pin_states(right, -10),
            vec![
                (Channel::C2, PinState::FullOff),
                (Channel::C3, PinState::Duty(160))
            ]
        );
    }
}
