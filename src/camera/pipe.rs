//! (in progress)
use std::sync::Arc;

use super::{Frame, FrameSource, Result};
use crate::clock::Clock;
use crate::config::CameraConfig;

pub struct PipeSource;

impl PipeSource {
    pub fn open(_cfg: &CameraConfig, _clock: Arc<dyn Clock>) -> Result<Self> {
        Err(super::CameraError::Other("pipe source: not yet".into()))
    }
}

impl FrameSource for PipeSource {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        Ok(None)
    }
    fn describe(&self) -> String {
        "pipe".into()
    }
}
