//! The latest-frame slot between the capture thread and the inference stage.
//!
//! It holds at most one frame: a new frame replaces an unread one (counted as skipped), so
//! a slow model always gets the newest frame and never a queue of stale ones. The capture
//! side closes the slot when its source ends or fails; a guard closes it if the capture
//! thread dies without saying so (a panic), so the consumer never waits forever.

use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::Duration;

use super::Frame;

/// Why the slot was closed.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceEnd {
    /// The source has no more frames (end of a replay).
    Finished,
    /// The source failed; the message says how.
    Failed(String),
}

/// What [`LatestFrame::wait`] found.
#[derive(Debug)]
pub enum Wait {
    Frame(Frame),
    Timeout,
    Closed(SourceEnd),
    /// The source failed but goes on (it is recovering); reported once per error.
    Error(String),
}

#[derive(Debug, Default)]
struct State {
    frame: Option<Frame>,
    error: Option<String>,
    closed: Option<SourceEnd>,
    produced: u64,
    skipped: u64,
}

/// A one-frame mailbox; share it with `Arc`.
#[derive(Debug, Default)]
pub struct LatestFrame {
    state: Mutex<State>,
    ready: Condvar,
}

/// Counters of a [`LatestFrame`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SlotCounts {
    pub produced: u64,
    /// Frames replaced before anyone took them.
    pub skipped: u64,
}

impl LatestFrame {
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A poisoned lock only means another thread panicked while holding it; the state
        // (a frame and counters) is still consistent, so carry on.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Offers a frame, replacing (and counting as skipped) any unread one.
    pub fn put(&self, frame: Frame) {
        let mut s = self.lock();
        if s.closed.is_some() {
            return;
        }
        s.produced += 1;
        if s.frame.replace(frame).is_some() {
            s.skipped += 1;
        }
        drop(s);
        self.ready.notify_all();
    }

    /// Closes the slot. The first reason wins. A pending frame is still delivered after
    /// `Finished`, but dropped after `Failed`.
    pub fn close(&self, end: SourceEnd) {
        let mut s = self.lock();
        if s.closed.is_none() {
            if matches!(end, SourceEnd::Failed(_)) {
                s.frame = None;
            }
            s.closed = Some(end);
        }
        drop(s);
        self.ready.notify_all();
    }

    /// Reports a transient source error (the source keeps going); any unread frame is
    /// dropped, since it predates the failure.
    pub fn put_error(&self, message: String) {
        let mut s = self.lock();
        s.frame = None;
        s.error = Some(message);
        drop(s);
        self.ready.notify_all();
    }

    /// Takes the newest unread frame, waiting up to `timeout` for one.
    pub fn wait(&self, timeout: Duration) -> Wait {
        let s = self.lock();
        let (mut s, _) = self
            .ready
            .wait_timeout_while(s, timeout, |s| {
                s.frame.is_none() && s.closed.is_none() && s.error.is_none()
            })
            .unwrap_or_else(|p| p.into_inner());
        if let Some(e) = s.error.take() {
            return Wait::Error(e);
        }
        if let Some(f) = s.frame.take() {
            return Wait::Frame(f);
        }
        match &s.closed {
            Some(end) => Wait::Closed(end.clone()),
            None => Wait::Timeout,
        }
    }

    pub fn counts(&self) -> SlotCounts {
        let s = self.lock();
        SlotCounts {
            produced: s.produced,
            skipped: s.skipped,
        }
    }
}

/// Closes the slot with `Failed` when dropped without [`CloseGuard::disarm`]: put one on
/// the capture thread's stack so a panic there still wakes the consumer.
pub struct CloseGuard<'a> {
    slot: &'a LatestFrame,
    armed: bool,
}

impl<'a> CloseGuard<'a> {
    pub fn new(slot: &'a LatestFrame) -> Self {
        Self { slot, armed: true }
    }
    pub fn disarm(mut self) {
        self.armed = false;
    }
}

impl Drop for CloseGuard<'_> {
    fn drop(&mut self) {
        if self.armed {
            self.slot.close(SourceEnd::Failed(
                "the capture thread ended unexpectedly (panic)".into(),
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    fn frame(seq: u64) -> Frame {
        Frame {
            seq,
            captured_at: Duration::from_millis(seq),
            width: 1,
            height: 1,
            rgb: Arc::new(vec![0, 0, 0]),
        }
    }

    #[test]
    fn newest_frame_wins_and_skips_are_counted() {
        let slot = LatestFrame::new();
        slot.put(frame(0));
        slot.put(frame(1));
        slot.put(frame(2));
        match slot.wait(Duration::ZERO) {
            Wait::Frame(f) => assert_eq!(f.seq, 2),
            other => panic!("{other:?}"),
        }
        assert!(matches!(slot.wait(Duration::ZERO), Wait::Timeout));
        assert_eq!(
            slot.counts(),
            SlotCounts {
                produced: 3,
                skipped: 2
            }
        );
    }

    #[test]
    fn finished_still_delivers_the_last_frame_failed_does_not() {
        let slot = LatestFrame::new();
        slot.put(frame(5));
        slot.close(SourceEnd::Finished);
        assert!(matches!(slot.wait(Duration::ZERO), Wait::Frame(f) if f.seq == 5));
        assert!(matches!(
            slot.wait(Duration::ZERO),
            Wait::Closed(SourceEnd::Finished)
        ));

        let slot = LatestFrame::new();
        slot.put(frame(5));
        slot.close(SourceEnd::Failed("unplugged".into()));
        assert!(matches!(
            slot.wait(Duration::ZERO),
            Wait::Closed(SourceEnd::Failed(m)) if m == "unplugged"
        ));
    }

    #[test]
    fn guard_closes_on_panic() {
        let slot = Arc::new(LatestFrame::new());
        let s2 = slot.clone();
        let h = std::thread::spawn(move || {
            let _guard = CloseGuard::new(&s2);
            panic!("capture died");
        });
        assert!(h.join().is_err());
        assert!(matches!(
            slot.wait(Duration::from_secs(1)),
            Wait::Closed(SourceEnd::Failed(_))
        ));
    }

    #[test]
    fn a_waiting_consumer_is_woken_by_put() {
        let slot = Arc::new(LatestFrame::new());
        let s2 = slot.clone();
        let h = std::thread::spawn(move || s2.wait(Duration::from_secs(10)));
        std::thread::sleep(Duration::from_millis(20));
        slot.put(frame(9));
        assert!(matches!(h.join().unwrap(), Wait::Frame(f) if f.seq == 9));
    }
}
