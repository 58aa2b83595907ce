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
