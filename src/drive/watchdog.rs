//! The command watchdog, as a pure state machine: it is armed by each fresh command and
//! says "stop" once no fresh command came for the period. After it fired it stays quiet
//! until the next fresh command (the motors are already stopped).

use std::time::Duration;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Watchdog {
    period: Duration,
    /// When the last fresh command was written; `None` while disarmed.
    last_fresh: Option<Duration>,
}

impl Watchdog {
    pub fn new(period: Duration) -> Self {
        Self {
            period,
            last_fresh: None,
        }
    }

    pub fn period(&self) -> Duration {
        self.period
    }

    /// A fresh command was written at `now`.
    pub fn feed(&mut self, now: Duration) {
        self.last_fresh = Some(now);
    }

    /// The motors were stopped for another reason; nothing to watch until the next feed.
    pub fn disarm(&mut self) {
        self.last_fresh = None;
    }

    /// When the watchdog fires if it is not fed before; `None` while disarmed.
    pub fn deadline(&self) -> Option<Duration> {
        self.last_fresh.map(|t| t + self.period)
    }

    /// True once, when `now` is at or past the deadline; then disarms.
    pub fn expired(&mut self, now: Duration) -> bool {
        match self.deadline() {
            Some(d) if now >= d => {
                self.last_fresh = None;
                true
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: fn(u64) -> Duration = Duration::from_millis;

    #[test]
    fn fires_once_a_period_after_the_last_feed() {
        let mut w = Watchdog::new(MS(250));
        assert!(!w.expired(MS(10_000)), "disarmed before the first command");
        w.feed(MS(100));
        w.feed(MS(200));
        assert_eq!(w.deadline(), Some(MS(450)));
        assert!(!w.expired(MS(449)));
        assert!(w.expired(MS(450)));
        assert!(!w.expired(MS(900)), "fires once");
        w.feed(MS(1000));
        assert!(w.expired(MS(1300)));
    }

    #[test]
    fn disarm_silences_it() {
        let mut w = Watchdog::new(MS(250));
        w.feed(MS(0));
        w.disarm();
        assert!(!w.expired(MS(1000)));
    }
}
