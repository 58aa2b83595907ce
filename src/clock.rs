//! Time as the daemon sees it. The daemon never reads the wall clock itself: it is handed a
//! [`Clock`], so the simulator and tests can run on a clock of their own.

use std::time::{Duration, Instant};

/// A monotonic clock; `now()` is the time since the clock's own epoch.
pub trait Clock: Send + Sync {
    fn now(&self) -> Duration;
}

/// The real monotonic clock, with its epoch at construction.
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    epoch: Instant,
}

impl MonotonicClock {
    pub fn new() -> Self {
        Self {
            epoch: Instant::now(),
        }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now(&self) -> Duration {
        self.epoch.elapsed()
    }
}

/// A clock that only moves when told to: the simulator's time. Shared with `Arc`.
#[derive(Debug, Default)]
pub struct SimClock {
    nanos: std::sync::atomic::AtomicU64,
}

impl SimClock {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn advance(&self, dt: Duration) {
        self.nanos.fetch_add(
            dt.as_nanos().min(u64::MAX as u128) as u64,
            std::sync::atomic::Ordering::SeqCst,
        );
    }
}

impl Clock for SimClock {
    fn now(&self) -> Duration {
        Duration::from_nanos(self.nanos.load(std::sync::atomic::Ordering::SeqCst))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_clock_moves_only_when_advanced() {
        let c = SimClock::new();
        assert_eq!(c.now(), Duration::ZERO);
        c.advance(Duration::from_millis(33));
        c.advance(Duration::from_millis(33));
        assert_eq!(c.now(), Duration::from_millis(66));
    }
}
