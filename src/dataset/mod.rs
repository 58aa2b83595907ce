//! Demonstration datasets on disk: what a human's driving (or the simulator's, or the
//! autopilot's) leaves behind for training.
//!
//! Two formats, both read and written here:
//!
//! - [`tub`]: DonkeyCar's tub v2, the project's episode format. One record per control step
//!   with everything known at that step: the camera frame, the human's command, the
//!   autopilot's command, the motor commands actually sent, the pose, the paper's reward and
//!   JetBot's target-point label. DonkeyCar's own tools read these tubs unchanged.
//! - [`jetbot_xy`]: JetBot's road-following folder, `xy_XXX_YYY_<uuid>.jpg` files whose names
//!   carry the target point, so JetBot users' data sets train here as they are.
//!
//! Safety rules kept by both: bad input gets an error that names the file, line and key;
//! writers never overwrite what is already recorded (files are written to a temporary name
//! and renamed into place); readers skip a record torn by a crash with a warning and keep
//! every complete record before it.

pub mod jetbot_xy;
pub mod labelled;
pub mod tub;

/// Errors from reading or writing a data set. Every variant names the file or folder.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file system operation failed.
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// A line of a text file (manifest or catalog) is malformed. `line` counts from 1.
    #[error("{path} line {line}: {reason}")]
    Parse {
        path: String,
        line: usize,
        reason: String,
    },
    /// A file or folder is not what the format expects (not a tub, an empty folder, ...).
    #[error("{path}: {reason}")]
    Format { path: String, reason: String },
    /// The caller passed something that cannot be recorded (a NaN, a bad name, ...);
    /// nothing was written.
    #[error("{path}: cannot record: {reason}")]
    InvalidInput { path: String, reason: String },
    /// An image file cannot be decoded.
    #[error("image {path}: cannot decode: {source}")]
    Image {
        path: String,
        #[source]
        source: image::ImageError,
    },
}

pub type Result<T> = std::result::Result<T, DatasetError>;

/// `io::Error` -> [`DatasetError::Io`] naming `path`.
pub(crate) fn io_err(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder (named
/// `.<name>.tmp`, so listings that skip hidden files never see it), then a rename over
/// `path`. A crash leaves either the old file or the new one, never a mix.
pub(crate) fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_path(path);
    std::fs::write(&tmp, bytes).map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_err(path))
}

/// The temporary name [`write_atomic`] uses for `path`.
pub(crate) fn temp_path(path: &std::path::Path) -> std::path::PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp"))
}

/// fsyncs a file or a folder (a folder's fsync makes the renames in it durable).
pub(crate) fn sync_path(path: &std::path::Path) -> Result<()> {
    let f = std::fs::File::open(path).map_err(io_err(path))?;
    f.sync_all().map_err(io_err(path))
}

/// Whether `bytes` start like a JPEG file (SOI marker).
pub(crate) fn looks_like_jpeg(bytes: &[u8]) -> bool {
    bytes.len() >= 3 && bytes[0] == 0xFF && bytes[1] == 0xD8 && bytes[2] == 0xFF
}

/// Whether a JPEG's last bytes hold its end-of-image marker (FF D9); a few bytes of
/// padding after it, as some encoders write, are allowed.
fn ends_like_jpeg(bytes: &[u8]) -> bool {
    let tail = &bytes[bytes.len().saturating_sub(64)..];
    tail.windows(2).any(|w| w == [0xFF, 0xD9])
}

/// Decodes an image file into RGB8: `(width, height, pixels)`.
///
/// A JPEG without its end-of-image marker (a copy or a write cut short) is an error:
/// decoders fill the missing rows in silently, which would put a grey half-frame into a
/// data set.
pub fn load_rgb(path: &std::path::Path) -> Result<(u32, u32, Vec<u8>)> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    if looks_like_jpeg(&bytes) && !ends_like_jpeg(&bytes) {
        return Err(DatasetError::Format {
            path: path.display().to_string(),
            reason: "truncated JPEG (no end-of-image marker)".into(),
        });
    }
    let img = image::load_from_memory(&bytes).map_err(|source| match source {
        image::ImageError::IoError(e) => DatasetError::Io {
            path: path.display().to_string(),
            source: e,
        },
        source => DatasetError::Image {
            path: path.display().to_string(),
            source,
        },
    })?;
    let rgb = img.to_rgb8();
    Ok((rgb.width(), rgb.height(), rgb.into_raw()))
}

/// Why an image could not be read, without the path (the caller names the file): "the file
/// is empty" for a zero-byte file, which the image crate reports only as an unknown format.
pub fn short_reason(e: &DatasetError) -> String {
    match e {
        DatasetError::Io { source, .. } => source.to_string(),
        DatasetError::Format { reason, .. } => reason.clone(),
        DatasetError::Image { path, source } => {
            let empty = std::fs::metadata(path)
                .map(|m| m.len() == 0)
                .unwrap_or(false);
            if empty {
                "the file is empty (0 bytes)".into()
            } else {
                format!("cannot decode: {source}")
            }
        }
        other => other.to_string(),
    }
}

/// JPEG-encodes an RGB8 frame into `out` (cleared first, so its allocation is reused):
/// what both the daemon's recorder and the simulator's demonstrations store.
pub fn encode_jpeg(
    rgb: &[u8],
    width: u32,
    height: u32,
    out: &mut Vec<u8>,
) -> std::result::Result<(), image::ImageError> {
    out.clear();
    image::codecs::jpeg::JpegEncoder::new_with_quality(out, 90).encode(
        rgb,
        width,
        height,
        image::ExtendedColorType::Rgb8,
    )
}
