//! Replays a folder of JPEG/PNG images (in file-name order) as a camera at a set rate:
//! the frame source for trying the daemon without a camera, and for tests.
//!
//! Decoded frames are cached up to a memory budget, so a looping replay decodes each
//! file once.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{CameraError, Frame, FrameSource, Result};
use crate::clock::Clock;

/// Decoded frames kept in memory at most (bytes of RGB8).
const CACHE_BUDGET: usize = 256 << 20;

/// A decoded frame: width, height, RGB8 pixels.
type Decoded = (u32, u32, Arc<Vec<u8>>);

pub struct FolderSource {
    dir: PathBuf,
    files: Vec<PathBuf>,
    cache: Vec<Option<Decoded>>,
    cached_bytes: usize,
    period: Duration,
    repeat: bool,
    clock: Arc<dyn Clock>,
    next_index: usize,
    seq: u64,
    next_due: Option<Instant>,
}

/// The image files of a folder, sorted by name.
pub fn list_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let folder_err = |reason: String| CameraError::Folder {
        path: dir.display().to_string(),
        reason,
    };
    let entries = std::fs::read_dir(dir).map_err(|e| folder_err(e.to_string()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .map(|e| matches!(e.to_ascii_lowercase().as_str(), "jpg" | "jpeg" | "png"))
                .unwrap_or(false)
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(folder_err("no .jpg, .jpeg or .png files in it".into()));
    }
    Ok(files)
}

impl FolderSource {
    pub fn open(dir: &Path, fps: f32, repeat: bool, clock: Arc<dyn Clock>) -> Result<Self> {
        let files = list_images(dir)?;
        if !(fps.is_finite() && fps > 0.0) {
            return Err(CameraError::Folder {
                path: dir.display().to_string(),
                reason: format!("fps must be positive, got {fps}"),
            });
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            cache: vec![None; files.len()],
            files,
            cached_bytes: 0,
            period: Duration::from_secs_f64(1.0 / fps as f64),
            repeat,
            clock,
            next_index: 0,
            seq: 0,
            next_due: None,
        })
    }

    pub fn len(&self) -> usize {
        self.files.len()
    }

    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    fn load(&mut self, index: usize) -> Result<Decoded> {
        if let Some(hit) = &self.cache[index] {
            return Ok(hit.clone());
        }
        let path = &self.files[index];
        let img = image::open(path)
            .map_err(|source| CameraError::Decode {
                path: path.display().to_string(),
                source,
            })?
            .to_rgb8();
        let (w, h) = img.dimensions();
        let data = Arc::new(img.into_raw());
        if self.cached_bytes + data.len() <= CACHE_BUDGET {
            self.cached_bytes += data.len();
            self.cache[index] = Some((w, h, data.clone()));
        }
        Ok((w, h, data))
    }
}

impl FrameSource for FolderSource {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        if self.next_index >= self.files.len() {
            if !self.repeat {
                return Ok(None);
            }
            self.next_index = 0;
        }
        let (width, height, rgb) = self.load(self.next_index)?;
        let due = self.next_due.unwrap_or_else(Instant::now);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        // Pace from the schedule, not from when we woke, so the rate does not drift; after
        // a long stall, restart the schedule instead of bursting to catch up.
        let next = due + self.period;
        self.next_due = Some(if next + self.period < Instant::now() {
            Instant::now() + self.period
        } else {
            next
        });
        let frame = Frame {
            seq: self.seq,
            captured_at: self.clock.now(),
            width,
            height,
            rgb,
        };
        self.seq += 1;
        self.next_index += 1;
        Ok(Some(frame))
    }

    fn describe(&self) -> String {
        format!(
            "folder {} ({} frames, {:.1} fps{})",
            self.dir.display(),
            self.files.len(),
            1.0 / self.period.as_secs_f64(),
            if self.repeat { ", looping" } else { "" }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::MonotonicClock;

    fn write_frames(dir: &Path, n: usize) {
        for i in 0..n {
            let img = image::RgbImage::from_pixel(8, 6, image::Rgb([i as u8 * 10, 0, 0]));
            img.save(dir.join(format!("f{i:03}.png"))).unwrap();
        }
        std::fs::write(dir.join("notes.txt"), "not a frame").unwrap();
    }

    #[test]
    fn replays_in_name_order_then_ends_or_loops() {
        let dir = tempfile::tempdir().unwrap();
        write_frames(dir.path(), 3);
        let clock = Arc::new(MonotonicClock::new());
        let mut src = FolderSource::open(dir.path(), 1000.0, false, clock.clone()).unwrap();
        assert_eq!(src.len(), 3);
        let reds: Vec<u8> = std::iter::from_fn(|| src.next_frame().unwrap())
            .map(|f| f.rgb[0])
            .collect();
        assert_eq!(reds, vec![0, 10, 20]);

        let mut src = FolderSource::open(dir.path(), 1000.0, true, clock).unwrap();
        let seqs: Vec<(u64, u8)> = (0..5)
            .map(|_| src.next_frame().unwrap().unwrap())
            .map(|f| (f.seq, f.rgb[0]))
            .collect();
        assert_eq!(seqs, vec![(0, 0), (1, 10), (2, 20), (3, 0), (4, 10)]);
    }

    #[test]
    fn missing_or_empty_folder_is_named() {
        let clock = Arc::new(MonotonicClock::new());
        let err = FolderSource::open(Path::new("/no/such/dir"), 10.0, false, clock.clone())
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("/no/such/dir"), "{err}");
        let dir = tempfile::tempdir().unwrap();
        let err = FolderSource::open(dir.path(), 10.0, false, clock)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("no .jpg"), "{err}");
    }

    #[test]
    fn corrupt_image_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("bad.jpg"), b"definitely not a jpeg").unwrap();
        let clock = Arc::new(MonotonicClock::new());
        let mut src = FolderSource::open(dir.path(), 10.0, false, clock).unwrap();
        let err = src.next_frame().unwrap_err().to_string();
        assert!(err.contains("bad.jpg"), "{err}");
    }
}
