//! A Raspberry Pi's hardware PWM through rppal (feature `rpi`), as an embedded-hal
//! `SetDutyCycle` (rppal 0.22 implements only embedded-hal 0.2's PWM traits). Channels 0-3
//! are rppal's `Pwm0`..`Pwm3`: GPIO 18 and 19 with `dtoverlay=pwm-2chan` on a Pi 4.

use embedded_hal::pwm::{ErrorKind, ErrorType, SetDutyCycle};
use rppal::pwm::{Channel, Polarity, Pwm};

/// An rppal error with the channel it came from.
#[derive(Debug, thiserror::Error)]
#[error("rppal PWM channel {channel}: {source}")]
pub struct RppalPwmError {
    pub channel: u32,
    #[source]
    pub source: rppal::pwm::Error,
}

impl embedded_hal::pwm::Error for RppalPwmError {
    fn kind(&self) -> ErrorKind {
        ErrorKind::Other
    }
}

/// One enabled PWM channel, duty 0 at open; disabled again on drop (rppal's own drop).
pub struct RppalPwm {
    pwm: Pwm,
    channel: u32,
}

impl RppalPwm {
    pub fn open(channel: u32, hz: f32) -> Result<Self, RppalPwmError> {
        let ch = match channel {
            0 => Channel::Pwm0,
            1 => Channel::Pwm1,
            2 => Channel::Pwm2,
            _ => Channel::Pwm3,
        };
        let pwm = Pwm::with_frequency(ch, f64::from(hz), 0.0, Polarity::Normal, true)
            .map_err(|source| RppalPwmError { channel, source })?;
        Ok(Self { pwm, channel })
    }
}

impl ErrorType for RppalPwm {
    type Error = RppalPwmError;
}

impl SetDutyCycle for RppalPwm {
    fn max_duty_cycle(&self) -> u16 {
        u16::MAX
    }

    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Self::Error> {
        self.pwm
            .set_duty_cycle(f64::from(duty) / f64::from(u16::MAX))
            .map_err(|source| RppalPwmError {
                channel: self.channel,
                source,
            })
    }
}
