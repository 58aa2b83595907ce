//! The buzzer: short beep patterns on a GPIO line (the Yahboom JetBot's buzzer on 40-pin
//! header pin 31, active low), written against embedded-hal's `OutputPin` so tests run on
//! embedded-hal-mock; the Linux backend is a GPIO character-device line through
//! linux-embedded-hal's `CdevPin` (feature `linux-hal`). [`NoBuzzer`] is the robot without
//! one (the default: `[buzzer] enabled = false`).
//!
//! # Timing: the caller's scheduler
//! [`Buzzer::beep`] never blocks: it switches the buzzer on and remembers the pattern; the
//! later edges happen in [`Buzzer::poll`], which the caller runs from its own loop (the
//! daemon's control loop or its status tick) every 10-50 ms while [`Buzzer::is_busy`]. Each
//! on/off segment lasts at least its nominal time and at most one poll period more; a
//! pattern is never cut short by a late poll. Time comes from the crate's [`Clock`], so
//! tests and the simulator run on a clock of their own. A buzzer that is dropped while
//! sounding is switched off.
//!
//! Pin errors never reach the caller (a buzzer is not worth stopping the robot for): the
//! first one is logged as a warning, later ones at debug level.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use embedded_hal::digital::OutputPin;
use serde::{Deserialize, Serialize};

use crate::clock::Clock;

/// A beep pattern: alternating on/off segments, starting and ending with "on".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BeepPattern {
    /// One 80 ms beep: acknowledge (a mode change, a button).
    Short,
    /// Two 80 ms beeps 80 ms apart: recording started or stopped.
    Double,
    /// One 400 ms beep: ready to drive.
    Long,
    /// Three 150 ms beeps 100 ms apart: a fault or an emergency stop.
    Alarm,
}

impl BeepPattern {
    /// Segment lengths in milliseconds: on, off, on, ... (odd count, first and last on).
    pub fn steps_ms(self) -> &'static [u32] {
        match self {
            BeepPattern::Short => &[80],
            BeepPattern::Double => &[80, 80, 80],
            BeepPattern::Long => &[400],
            BeepPattern::Alarm => &[150, 100, 150, 100, 150],
        }
    }

    /// The pattern's nominal length.
    pub fn duration(self) -> Duration {
        Duration::from_millis(self.steps_ms().iter().map(|&ms| u64::from(ms)).sum())
    }
}

/// Something that beeps. See the module documentation for the timing contract.
pub trait Buzzer: Send {
    /// Starts `pattern` now, replacing one in progress. Never blocks.
    fn beep(&mut self, pattern: BeepPattern);
    /// Advances a pattern in progress; call every 10-50 ms while [`Buzzer::is_busy`].
    fn poll(&mut self) {}
    /// Whether a pattern is still playing (the caller must keep polling).
    fn is_busy(&self) -> bool {
        false
    }
    /// Stops any sound now.
    fn silence(&mut self) {}
}

/// A robot without a buzzer: every call does nothing.
#[derive(Debug, Default, Clone, Copy)]
pub struct NoBuzzer;

impl Buzzer for NoBuzzer {
    fn beep(&mut self, _pattern: BeepPattern) {}
}

/// The `[buzzer]` config section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BuzzerConfig {
    /// Off by default: only the Yahboom JetBot has a buzzer.
    pub enabled: bool,
    /// GPIO character device.
    pub chip: PathBuf,
    /// Line offset on `chip`. The Yahboom's buzzer is on header pin 31, which is GPIO 200
    /// (GPIO_PZ0) on gpiochip0 of a Jetson Nano: verify with `gpioinfo` (libgpiod), which
    /// lists each chip's lines; other carrier boards and modules number them differently.
    pub line: u32,
    /// The buzzer sounds while the line is low (the Yahboom's does).
    pub active_low: bool,
}

impl Default for BuzzerConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            chip: PathBuf::from("/dev/gpiochip0"),
            line: 200,
            active_low: true,
        }
    }
}

/// Errors from opening a buzzer.
#[derive(Debug, thiserror::Error)]
pub enum BuzzerError {
    #[error("buzzer: GPIO line {line} on {chip}: {reason}")]
    Open {
        chip: String,
        line: u32,
        reason: String,
    },
    #[error("buzzer: cannot switch the GPIO line off: {0}")]
    Pin(String),
}

/// A pattern in progress.
#[derive(Debug, Clone, Copy)]
struct Playing {
    steps: &'static [u32],
    /// The segment now playing (even: on, odd: off).
    index: usize,
    /// When it ends.
    until: Duration,
}

/// A buzzer on one output pin.
pub struct GpioBuzzer<P: OutputPin> {
    /// `None` only after [`GpioBuzzer::destroy`] took it back.
    pin: Option<P>,
    active_low: bool,
    clock: Arc<dyn Clock>,
    playing: Option<Playing>,
    warned: bool,
}

impl<P: OutputPin> GpioBuzzer<P> {
    /// Takes the pin and switches the buzzer off (high when `active_low`).
    pub fn new(pin: P, active_low: bool, clock: Arc<dyn Clock>) -> Result<Self, BuzzerError> {
        let mut b = Self {
            pin: Some(pin),
            active_low,
            clock,
            playing: None,
            warned: false,
        };
        b.write(false)
            .map_err(|e| BuzzerError::Pin(format!("{e:?}")))?;
        Ok(b)
    }

    /// Switches the buzzer off and hands the pin back.
    pub fn destroy(mut self) -> Option<P> {
        self.playing = None;
        self.set(false);
        self.pin.take()
    }

    fn write(&mut self, on: bool) -> Result<(), P::Error> {
        match self.pin.as_mut() {
            Some(pin) if on != self.active_low => pin.set_high(),
            Some(pin) => pin.set_low(),
            None => Ok(()),
        }
    }

    fn set(&mut self, on: bool) {
        if let Err(e) = self.write(on) {
            if self.warned {
                tracing::debug!(error = ?e, on, "buzzer pin write failed");
            } else {
                tracing::warn!(error = ?e, on, "buzzer pin write failed; the buzzer may be silent");
                self.warned = true;
            }
        }
    }
}

impl<P: OutputPin + Send> Buzzer for GpioBuzzer<P> {
    fn beep(&mut self, pattern: BeepPattern) {
        let steps = pattern.steps_ms();
        let Some(&first) = steps.first() else {
            return;
        };
        self.set(true);
        self.playing = Some(Playing {
            steps,
            index: 0,
            until: self.clock.now() + Duration::from_millis(u64::from(first)),
        });
    }

    fn poll(&mut self) {
        let Some(mut p) = self.playing else {
            return;
        };
        let now = self.clock.now();
        if now < p.until {
            return;
        }
        p.index += 1;
        match p.steps.get(p.index) {
            Some(&ms) => {
                // At most one edge per poll: a late poll stretches a segment, never skips one.
                p.until = now + Duration::from_millis(u64::from(ms));
                self.set(p.index % 2 == 0);
                self.playing = Some(p);
            }
            None => {
                self.set(false);
                self.playing = None;
            }
        }
    }

    fn is_busy(&self) -> bool {
        self.playing.is_some()
    }

    fn silence(&mut self) {
        self.playing = None;
        self.set(false);
    }
}

impl<P: OutputPin> Drop for GpioBuzzer<P> {
    fn drop(&mut self) {
        if self.playing.take().is_some() {
            let _ = self.write(false);
        }
    }
}

/// Turns a GPIO open error into advice.
#[cfg_attr(not(feature = "linux-hal"), allow(dead_code))]
pub(crate) fn open_advice(err: &str) -> String {
    if err.contains("Permission denied") {
        format!(
            "{err}: add the user to the `gpio` group (`sudo usermod -aG gpio $USER`) and install the udev rule systemd/99-jetpilot.rules, which gives the group /dev/gpiochip*"
        )
    } else if err.contains("No such file") {
        format!("{err}: no such GPIO chip; `ls /dev/gpiochip*` lists them")
    } else if err.contains("busy") || err.contains("EBUSY") {
        format!(
            "{err}: the line is held by another program or exported in /sys/class/gpio; `gpioinfo` shows its consumer"
        )
    } else if err.contains("out of range") || err.contains("EINVAL") {
        format!("{err}: no such line on this chip; `gpioinfo` lists the lines")
    } else {
        err.to_string()
    }
}

/// Requests `cfg.line` on `cfg.chip` as an output, initially off, as consumer `jetpilot`.
#[cfg(feature = "linux-hal")]
pub fn open_cdev(
    cfg: &BuzzerConfig,
    clock: Arc<dyn Clock>,
) -> Result<GpioBuzzer<linux_embedded_hal::CdevPin>, BuzzerError> {
    use gpio_cdev::{Chip, LineRequestFlags};
    let err = |e: gpio_cdev::Error| BuzzerError::Open {
        chip: cfg.chip.display().to_string(),
        line: cfg.line,
        reason: open_advice(&e.to_string()),
    };
    let mut chip = Chip::new(&cfg.chip).map_err(err)?;
    let line = chip.get_line(cfg.line).map_err(err)?;
    // The request's initial value is the raw level: off is high for an active-low buzzer,
    // so opening the line makes no click.
    let off_level = u8::from(cfg.active_low);
    let handle = line
        .request(LineRequestFlags::OUTPUT, off_level, "jetpilot")
        .map_err(err)?;
    let pin = linux_embedded_hal::CdevPin::new(handle).map_err(err)?;
    GpioBuzzer::new(pin, cfg.active_low, clock)
}

/// The buzzer `cfg` asks for: [`NoBuzzer`] when disabled, else the GPIO line (an error the
/// caller should log as a warning and go on with [`NoBuzzer`]).
pub fn open(cfg: &BuzzerConfig, clock: Arc<dyn Clock>) -> Result<Box<dyn Buzzer>, BuzzerError> {
    if !cfg.enabled {
        return Ok(Box::new(NoBuzzer));
    }
    #[cfg(feature = "linux-hal")]
    {
        Ok(Box::new(open_cdev(cfg, clock)?))
    }
    #[cfg(not(feature = "linux-hal"))]
    {
        let _ = clock;
        Err(BuzzerError::Open {
            chip: cfg.chip.display().to_string(),
            line: cfg.line,
            reason: "this build has no GPIO backend (feature `linux-hal`)".into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::SimClock;
    use embedded_hal_mock::eh1::MockError;
    use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction as T};

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn buzzer(expect: &[T], active_low: bool) -> (GpioBuzzer<PinMock>, PinMock, Arc<SimClock>) {
        let pin = PinMock::new(expect);
        let clock = Arc::new(SimClock::new());
        let b = GpioBuzzer::new(pin.clone(), active_low, clock.clone()).expect("new");
        (b, pin, clock)
    }

    #[test]
    fn patterns_start_and_end_on() {
        for p in [
            BeepPattern::Short,
            BeepPattern::Double,
            BeepPattern::Long,
            BeepPattern::Alarm,
        ] {
            let s = p.steps_ms();
            assert_eq!(s.len() % 2, 1, "{p:?}");
        }
        assert_eq!(BeepPattern::Alarm.duration(), ms(650));
        assert_eq!(BeepPattern::Double.duration(), ms(240));
    }

    #[test]
    fn short_beep_active_low() {
        // new: off (high); beep: on (low); after 80 ms: off (high).
        let (mut b, mut pin, clock) = buzzer(
            &[T::set(State::High), T::set(State::Low), T::set(State::High)],
            true,
        );
        b.beep(BeepPattern::Short);
        assert!(b.is_busy());
        clock.advance(ms(79));
        b.poll(); // too early: no write
        assert!(b.is_busy());
        clock.advance(ms(1));
        b.poll();
        assert!(!b.is_busy());
        b.poll(); // idle: no write
        drop(b); // not sounding: no write
        pin.done();
    }

    #[test]
    fn double_beep_active_high_with_a_late_poll() {
        let (mut b, mut pin, clock) = buzzer(
            &[
                T::set(State::Low),  // new: off
                T::set(State::High), // on
                T::set(State::Low),  // off at 80
                T::set(State::High), // on at 180 (poll 20 ms late)
                T::set(State::Low),  // off at 260: the on segment keeps its 80 ms
            ],
            false,
        );
        b.beep(BeepPattern::Double);
        clock.advance(ms(80));
        b.poll();
        clock.advance(ms(100));
        b.poll();
        clock.advance(ms(79));
        b.poll();
        assert!(b.is_busy());
        clock.advance(ms(1));
        b.poll();
        assert!(!b.is_busy());
        drop(b);
        pin.done();
    }

    #[test]
    fn one_edge_per_poll_even_when_very_late() {
        let (mut b, mut pin, clock) = buzzer(
            &[
                T::set(State::High),
                T::set(State::Low),
                T::set(State::High), // the gap, however late
                T::set(State::Low),  // the second beep still sounds
                T::set(State::High),
            ],
            true,
        );
        b.beep(BeepPattern::Double);
        clock.advance(ms(1000));
        b.poll();
        b.poll(); // same instant: the gap has 80 ms to run
        clock.advance(ms(80));
        b.poll();
        clock.advance(ms(80));
        b.poll();
        assert!(!b.is_busy());
        drop(b);
        pin.done();
    }

    #[test]
    fn beep_restarts_and_silence_and_drop_switch_off() {
        let (mut b, mut pin, clock) = buzzer(
            &[
                T::set(State::High),
                T::set(State::Low),  // Long
                T::set(State::Low),  // Short replaces it: on again
                T::set(State::High), // silence
                T::set(State::Low),  // Alarm
                T::set(State::High), // dropped while sounding
            ],
            true,
        );
        b.beep(BeepPattern::Long);
        clock.advance(ms(200));
        b.beep(BeepPattern::Short);
        clock.advance(ms(79));
        b.poll(); // 279 ms after the Long started, 79 after the Short: still on
        b.silence();
        assert!(!b.is_busy());
        b.beep(BeepPattern::Alarm);
        drop(b);
        pin.done();
    }

    #[test]
    fn destroy_switches_off_and_returns_the_pin() {
        let (mut b, _pin, _clock) = buzzer(
            &[T::set(State::High), T::set(State::Low), T::set(State::High)],
            true,
        );
        b.beep(BeepPattern::Long);
        let mut pin = b.destroy().expect("the pin");
        pin.done();
    }

    #[test]
    fn pin_errors_are_not_the_callers_problem() {
        let err = MockError::Io(std::io::ErrorKind::Other);
        let (mut b, mut pin, clock) = buzzer(
            &[
                T::set(State::High),
                T::set(State::Low).with_error(err.clone()),
                T::set(State::High).with_error(err),
                T::set(State::Low),
                T::set(State::High),
            ],
            true,
        );
        b.beep(BeepPattern::Short);
        clock.advance(ms(80));
        b.poll();
        assert!(!b.is_busy());
        b.beep(BeepPattern::Short);
        b.silence();
        drop(b);
        pin.done();
    }

    #[test]
    fn new_fails_when_the_pin_cannot_be_switched_off() {
        let mut pin = PinMock::new(&[
            T::set(State::High).with_error(MockError::Io(std::io::ErrorKind::Other))
        ]);
        let r = GpioBuzzer::new(pin.clone(), true, Arc::new(SimClock::new()));
        assert!(matches!(r, Err(BuzzerError::Pin(_))));
        pin.done();
    }

    #[test]
    fn config_defaults_and_unknown_keys() {
        let c: BuzzerConfig = toml::from_str("").expect("empty");
        assert_eq!(c, BuzzerConfig::default());
        assert!(!c.enabled);
        assert_eq!(c.chip, PathBuf::from("/dev/gpiochip0"));
        assert_eq!(c.line, 200);
        assert!(c.active_low);
        let c: BuzzerConfig = toml::from_str("enabled = true\nline = 79").expect("partial");
        assert!(c.enabled && c.line == 79 && c.active_low);
        let e = toml::from_str::<BuzzerConfig>("enable = true").expect_err("unknown key");
        assert!(e.to_string().contains("enable"), "{e}");
    }

    #[test]
    fn open_disabled_is_no_buzzer_and_a_missing_chip_says_so() {
        let clock: Arc<dyn Clock> = Arc::new(SimClock::new());
        let mut b = open(&BuzzerConfig::default(), clock.clone()).expect("disabled");
        b.beep(BeepPattern::Alarm);
        b.poll();
        assert!(!b.is_busy());
        let cfg = BuzzerConfig {
            enabled: true,
            chip: PathBuf::from("/nonexistent/gpiochip9"),
            ..BuzzerConfig::default()
        };
        let e = open(&cfg, clock).err().expect("no such chip");
        let msg = e.to_string();
        assert!(
            msg.contains("/nonexistent/gpiochip9") && msg.contains("200"),
            "{msg}"
        );
    }

    #[test]
    fn advice_for_common_gpio_errors() {
        assert!(open_advice("Permission denied (os error 13)").contains("gpio` group"));
        assert!(open_advice("No such file or directory (os error 2)").contains("ls /dev/gpiochip"));
        assert!(open_advice("Ioctl to get line handle failed: EBUSY").contains("gpioinfo"));
    }
}
