//! Click-to-label: JetBot's data-collection notebooks on the web page.
//!
//! A click on the live video saves the frame that was shown:
//! - **road** (`xy`): `xy_XXX_YYY_<uuid1>.jpg` in `web.xy_dir`, the clicked pixel in the
//!   name, as JetBot's road-following notebook does;
//! - **free** / **blocked**: `<uuid1>.jpg` in `web.collision_dir`'s `free/` or `blocked/`,
//!   as its collision-avoidance notebook does.
//!
//! "The frame that was shown": the page reads the video's parts itself and sends the
//! `X-Frame-Seq` of the picture on screen; the encoder keeps the last [`RECENT_FRAMES`]
//! frames it sent, keyed by that number, and the sample is that frame, encoded without the
//! overlay at the video's JPEG quality (with `web.overlay = false`, byte for byte the JPEG
//! the page showed).
//!
//! Limits of the folder: a missing folder whose parent exists is made (as the notebooks
//! do); a missing parent (an unmounted USB stick) or a full disk is an error for the page,
//! and nothing else stops: the daemon never waits on this disk.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::dataset::{DatasetError, jetbot_xy};
use crate::drive::LiveFrame;

/// How many sent frames are kept for labelling (2 s of video at 15 frames a second).
pub const RECENT_FRAMES: usize = 32;

/// Which folder a click saves into.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LabelKind {
    /// Road following: the clicked point is the label.
    Xy,
    /// Collision avoidance: the way ahead is free.
    Free,
    /// Collision avoidance: the way ahead is blocked.
    Blocked,
}

/// The samples in each folder.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Counts {
    pub xy: usize,
    pub free: usize,
    pub blocked: usize,
}

/// What went wrong, worded for the person at the page.
#[derive(Debug, thiserror::Error)]
pub enum LabelError {
    #[error(
        "frame {seq} is no longer held (the server keeps the last {RECENT_FRAMES} it sent): click again"
    )]
    FrameGone { seq: u64 },
    #[error("({px}, {py}) is outside the {width}x{height} picture")]
    OutsideImage {
        px: u32,
        py: u32,
        width: u32,
        height: u32,
    },
    #[error(
        "not saved: the dataset folder {dir} cannot be made, {parent} does not exist (is the drive mounted?); the run goes on"
    )]
    MissingFolder { dir: String, parent: String },
    #[error("not saved: the disk holding {dir} is full; free some space (the run goes on)")]
    DiskFull { dir: String },
    #[error(
        "not saved: {dir} is read-only for the daemon (under systemd, allow it with ReadWritePaths={dir} in a drop-in: docs/guides/web-page.md)"
    )]
    ReadOnly { dir: String },
    #[error("not saved: {0}")]
    Dataset(#[from] DatasetError),
    #[error("not saved: cannot encode frame {seq}: {why}")]
    Encode { seq: u64, why: String },
    #[error("nothing to undo")]
    NothingToUndo,
}

/// The frames the encoder sent last, for labelling.
#[derive(Debug, Default)]
pub struct RecentFrames(Mutex<VecDeque<LiveFrame>>);

impl RecentFrames {
    /// Keeps `frame` (a pointer copy), dropping the oldest beyond [`RECENT_FRAMES`].
    pub fn push(&self, frame: LiveFrame) {
        let mut q = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if q.len() == RECENT_FRAMES {
            q.pop_front();
        }
        q.push_back(frame);
    }

    pub fn get(&self, seq: u64) -> Option<LiveFrame> {
        let q = self.0.lock().unwrap_or_else(|p| p.into_inner());
        q.iter().rev().find(|f| f.seq == seq).cloned()
    }
}

/// The labelling side of the server: folders, recent frames, names.
#[derive(Debug)]
pub struct Labeller {
    pub xy_dir: PathBuf,
    pub collision_dir: PathBuf,
    quality: u8,
    pub recent: RecentFrames,
    clock: Mutex<jetbot_xy::Uuid1Clock>,
}

impl Labeller {
    pub fn new(xy_dir: PathBuf, collision_dir: PathBuf, quality: u8) -> Self {
        Self {
            xy_dir,
            collision_dir,
            quality,
            recent: RecentFrames::default(),
            clock: Mutex::new(jetbot_xy::Uuid1Clock::new(&mut rand::rng())),
        }
    }

    /// The folder `kind` saves into.
    pub fn dir(&self, kind: LabelKind) -> PathBuf {
        match kind {
            LabelKind::Xy => self.xy_dir.clone(),
            LabelKind::Free => self.collision_dir.join("free"),
            LabelKind::Blocked => self.collision_dir.join("blocked"),
        }
    }

    /// Saves frame `seq` as a `kind` sample, `(px, py)` the clicked pixel (used by `xy`);
    /// returns the new file. Blocking file I/O: call it off the async threads.
    pub fn save(&self, kind: LabelKind, seq: u64, px: u32, py: u32) -> Result<PathBuf, LabelError> {
        let frame = self.recent.get(seq).ok_or(LabelError::FrameGone { seq })?;
        if kind == LabelKind::Xy && (px >= frame.width || py >= frame.height) {
            return Err(LabelError::OutsideImage {
                px,
                py,
                width: frame.width,
                height: frame.height,
            });
        }
        let params = super::video::VideoParams {
            fps: 1.0,
            quality: self.quality,
            overlay: None,
        };
        let jpeg = super::video::encode(&frame, &params).map_err(|e| LabelError::Encode {
            seq,
            why: e.to_string(),
        })?;
        let dir = self.dir(kind);
        if kind != LabelKind::Xy {
            ensure_dir(&self.collision_dir)?;
        }
        ensure_dir(&dir)?;
        let uuid = self.next_uuid();
        let saved = match kind {
            LabelKind::Xy => jetbot_xy::write_sample(&dir, px, py, &jpeg, &uuid),
            LabelKind::Free | LabelKind::Blocked => {
                let path = dir.join(format!("{uuid}.jpg"));
                jetbot_xy::write_new(&path, &jpeg).map(|()| path)
            }
        };
        saved.map_err(|e| disk_error(e, &dir))
    }

    /// Removes a sample this page saved (the caller keeps the page's own list).
    pub fn undo(&self, path: &Path) -> Result<(), LabelError> {
        std::fs::remove_file(path).map_err(|source| {
            LabelError::Dataset(DatasetError::Io {
                path: path.display().to_string(),
                source,
            })
        })
    }

    /// The samples in each folder now (a missing folder counts 0).
    pub fn counts(&self) -> Counts {
        let count = |kind| count_samples(&self.dir(kind), kind);
        Counts {
            xy: count(LabelKind::Xy),
            free: count(LabelKind::Free),
            blocked: count(LabelKind::Blocked),
        }
    }

    fn next_uuid(&self) -> String {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        self.clock
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .next(now)
    }
}

/// Makes `dir` when its parent exists; a missing parent is [`LabelError::MissingFolder`].
fn ensure_dir(dir: &Path) -> Result<(), LabelError> {
    if dir.is_dir() {
        return Ok(());
    }
    let parent = dir
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !parent.is_dir() {
        return Err(LabelError::MissingFolder {
            dir: dir.display().to_string(),
            parent: parent.display().to_string(),
        });
    }
    match std::fs::create_dir(dir) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(source) => Err(disk_error(
            DatasetError::Io {
                path: dir.display().to_string(),
                source,
            },
            dir,
        )),
    }
}

/// A full disk (or quota) is said as such; other errors keep their file and reason.
fn disk_error(e: DatasetError, dir: &Path) -> LabelError {
    use std::io::ErrorKind;
    let kind = match &e {
        DatasetError::Io { source, .. } => Some(source.kind()),
        _ => None,
    };
    let dir = dir.display().to_string();
    match kind {
        Some(ErrorKind::StorageFull | ErrorKind::QuotaExceeded) => LabelError::DiskFull { dir },
        Some(ErrorKind::ReadOnlyFilesystem) => LabelError::ReadOnly { dir },
        _ => LabelError::Dataset(e),
    }
}

/// JetBot samples in `dir`: `xy_*` names that parse for `xy`, any visible `.jpg` for the
/// collision folders.
fn count_samples(dir: &Path, kind: LabelKind) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .filter_map(|e| e.ok())
        .filter(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            match kind {
                LabelKind::Xy => jetbot_xy::parse_file_name(&name).is_some(),
                _ => !name.starts_with('.') && name.to_ascii_lowercase().ends_with(".jpg"),
            }
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::WheelCommand;
    use std::sync::Arc;

    fn frame(seq: u64) -> LiveFrame {
        let (w, h) = (32u32, 24u32);
        let rgb = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        LiveFrame {
            seq,
            width: w,
            height: h,
            rgb: Arc::new(rgb),
            outputs: [0.3, -0.2],
            wheels: WheelCommand::new(0.2, 0.1),
        }
    }

    fn labeller(root: &Path) -> Labeller {
        let l = Labeller::new(root.join("dataset_xy"), root.join("dataset"), 70);
        for seq in 1..=40 {
            l.recent.push(frame(seq));
        }
        l
    }

    #[test]
    fn a_road_click_saves_the_frame_shown_without_the_overlay_under_its_pixel() {
        let dir = tempfile::tempdir().unwrap();
        let l = labeller(dir.path());
        let path = l.save(LabelKind::Xy, 20, 17, 5).unwrap();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        assert_eq!(path.parent().unwrap(), dir.path().join("dataset_xy"));
        assert_eq!(jetbot_xy::parse_file_name(&name), Some((17, 5)));
        assert!(
            jetbot_xy::capture_time_s(&name).is_some(),
            "{name}: a uuid1"
        );
        // The bytes are frame 20's, as the video encodes it with the overlay off.
        let plain = super::super::video::VideoParams {
            fps: 10.0,
            quality: 70,
            overlay: None,
        };
        let want = super::super::video::encode(&frame(20), &plain).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), want.as_ref());
        assert_eq!(
            l.counts(),
            Counts {
                xy: 1,
                free: 0,
                blocked: 0
            }
        );
        // Undo removes it.
        l.undo(&path).unwrap();
        assert_eq!(l.counts().xy, 0);
    }

    #[test]
    fn free_and_blocked_go_to_their_folders() {
        let dir = tempfile::tempdir().unwrap();
        let l = labeller(dir.path());
        let f = l.save(LabelKind::Free, 40, 0, 0).unwrap();
        let b = l.save(LabelKind::Blocked, 39, 0, 0).unwrap();
        let b2 = l.save(LabelKind::Blocked, 39, 0, 0).unwrap();
        assert_eq!(f.parent().unwrap(), dir.path().join("dataset/free"));
        assert_eq!(b.parent().unwrap(), dir.path().join("dataset/blocked"));
        assert_ne!(b, b2, "two saves of one frame are two samples");
        assert_eq!(
            l.counts(),
            Counts {
                xy: 0,
                free: 1,
                blocked: 2
            }
        );
    }

    #[test]
    fn an_old_frame_a_pixel_outside_and_a_missing_drive_are_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let l = labeller(dir.path());
        // 40 frames pushed, 32 kept: 1..=8 are gone.
        let e = l.save(LabelKind::Xy, 8, 1, 1).unwrap_err();
        assert!(e.to_string().contains("frame 8 is no longer held"), "{e}");
        assert!(l.save(LabelKind::Xy, 9, 1, 1).is_ok());
        let e = l.save(LabelKind::Xy, 30, 32, 1).unwrap_err();
        assert_eq!(e.to_string(), "(32, 1) is outside the 32x24 picture");
        // The stick is not mounted: its mount point is missing, nothing is made.
        let stick = dir.path().join("media/usb");
        let l = Labeller::new(stick.join("dataset_xy"), stick.join("dataset"), 70);
        l.recent.push(frame(1));
        let e = l.save(LabelKind::Xy, 1, 1, 1).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains(&stick.display().to_string())
                && msg.contains("does not exist (is the drive mounted?)")
                && msg.contains("the run goes on"),
            "{msg}"
        );
        assert!(!stick.exists());
        let e = l.save(LabelKind::Blocked, 1, 1, 1).unwrap_err();
        assert!(matches!(e, LabelError::MissingFolder { .. }), "{e}");
        assert!(matches!(
            l.undo(&stick.join("x.jpg")),
            Err(LabelError::Dataset(_))
        ));
    }

    #[test]
    fn a_full_disk_is_said_as_such() {
        // ENOSPC as the kernel reports it (a real full file system is not made in tests).
        let full = DatasetError::Io {
            path: "/media/usb/dataset_xy/.xy_001_002_u.jpg.tmp".into(),
            source: std::io::Error::from_raw_os_error(28),
        };
        let e = disk_error(full, Path::new("/media/usb/dataset_xy"));
        assert_eq!(
            e.to_string(),
            "not saved: the disk holding /media/usb/dataset_xy is full; free some space (the run goes on)"
        );
        let read_only = DatasetError::Io {
            path: "/media/usb/dataset_xy/.x.tmp".into(),
            source: std::io::Error::from_raw_os_error(30),
        };
        let e = disk_error(read_only, Path::new("/media/usb/dataset_xy"));
        assert!(
            e.to_string()
                .contains("read-only for the daemon (under systemd, allow it with ReadWritePaths=/media/usb/dataset_xy"),
            "{e}"
        );
        let denied = DatasetError::Io {
            path: "/x".into(),
            source: std::io::Error::from_raw_os_error(13),
        };
        let e = disk_error(denied, Path::new("/x"));
        assert!(
            e.to_string()
                .starts_with("not saved: /x: Permission denied"),
            "{e}"
        );
    }
}
