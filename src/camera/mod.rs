//! Where frames come from. A [`FrameSource`] yields RGB8 frames stamped with their capture
//! time and sequence number; the daemon keeps only the newest one ([`LatestFrame`]), so a
//! slow model never works on a stale frame.
//!
//! Sources: a folder of images replayed at a set rate ([`folder::FolderSource`]). V4L2 and
//! the simulator implement the same trait.

pub mod convert;
pub mod folder;
pub mod latest;
pub mod pipe;
pub mod synthetic;
#[cfg(feature = "v4l2")]
pub mod v4l2;

use std::sync::Arc;
use std::time::Duration;

pub use latest::LatestFrame;

/// One RGB8 frame, row-major, `width * height * 3` bytes.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Sequence number from the source, counting from 0 with no gaps: a gap seen
    /// downstream is a skipped frame.
    pub seq: u64,
    /// Time of capture on the daemon's clock.
    pub captured_at: Duration,
    pub width: u32,
    pub height: u32,
    /// Shared so the latest-frame slot and the consumer never copy pixels.
    pub rgb: Arc<Vec<u8>>,
}

/// Errors from frame sources.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("frame folder {path}: {reason}")]
    Folder { path: String, reason: String },
    #[error("frame {path}: cannot decode image: {source}")]
    Decode {
        path: String,
        #[source]
        source: image::ImageError,
    },
    #[error("frame source failed: {0}")]
    Other(String),
}

pub type Result<T> = std::result::Result<T, CameraError>;

/// A camera or anything that stands in for one.
///
/// `next_frame` blocks until a frame is ready (pacing itself to its frame rate) and returns
/// `Ok(None)` when the stream has ended for good. It is called from a dedicated capture
/// thread, never from the async runtime.
pub trait FrameSource: Send {
    fn next_frame(&mut self) -> Result<Option<Frame>>;
    /// A short description for logs, e.g. `folder samples/ (48 frames, 15 fps)`.
    fn describe(&self) -> String;
    /// True when an error from `next_frame` is transient: the source recovers by itself
    /// (a V4L2 camera reopening after an unplug), so the daemon stops the motors and keeps
    /// asking for frames instead of ending.
    fn recoverable(&self) -> bool {
        false
    }
}
