//! (in progress)
use std::sync::Arc;

use super::{Frame, FrameSource, Result};
use crate::clock::Clock;
use crate::config::CameraConfig;

pub struct V4l2Source;

impl V4l2Source {
    pub fn open(_cfg: &CameraConfig, _clock: Arc<dyn Clock>) -> Result<Self> {
        Err(super::CameraError::Other("v4l2 source: not yet".into()))
    }
}

impl FrameSource for V4l2Source {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        Ok(None)
    }
    fn describe(&self) -> String {
        "v4l2".into()
    }
}
