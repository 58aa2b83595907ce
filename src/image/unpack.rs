//! Compressed SD images (JetBot's ship as .zip; others as .xz, .gz or .zst) unpacked next to
//! themselves by streaming through the system's own tool (unzip, xz, gzip, zstd) into a
//! temporary file in the same folder, renamed into place once complete: an interrupted
//! unpack leaves no half image behind, and the compressed file is never changed.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use super::ImageError;

fn tool_err(tool: &str, reason: impl Into<String>) -> ImageError {
    ImageError::Tool {
        tool: tool.to_string(),
        reason: reason.into(),
    }
}

/// The image file inside a zip archive: its one `.img` entry.
fn zip_entry(path: &Path) -> Result<String, ImageError> {
    let out = Command::new("unzip")
        .arg("-Z1")
        .arg(path)
        .output()
        .map_err(|e| tool_err("unzip", format!("{e} (`sudo apt install unzip`)")))?;
    if !out.status.success() {
        return Err(ImageError::Input {
            path: path.display().to_string(),
            reason: format!(
                "unzip cannot list it: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        });
    }
    let list = String::from_utf8_lossy(&out.stdout);
    let imgs: Vec<&str> = list.lines().filter(|l| l.ends_with(".img")).collect();
    match imgs.as_slice() {
        [one] => Ok(one.to_string()),
        [] => Err(ImageError::Input {
            path: path.display().to_string(),
            reason: "the archive holds no .img file".into(),
        }),
        many => Err(ImageError::Input {
            path: path.display().to_string(),
            reason: format!(
                "the archive holds several images ({}): unzip the one you want",
                many.join(", ")
            ),
        }),
    }
}

/// Where [`unpack`] puts the image of `path` (compressed as `kind`).
pub fn target(path: &Path, kind: &str) -> Result<PathBuf, ImageError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    Ok(dir.join(target_name(path, kind)?))
}

fn target_name(path: &Path, kind: &str) -> Result<String, ImageError> {
    if kind == "zip" {
        let entry = zip_entry(path)?;
        return Ok(Path::new(&entry)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or(entry));
    }
    let file = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let stem = [".xz", ".gz", ".zst"]
        .iter()
        .find_map(|ext| file.strip_suffix(ext))
        .unwrap_or(&file)
        .to_string();
    Ok(if stem.ends_with(".img") {
        stem
    } else {
        format!("{stem}.img")
    })
}

/// Unpacks `path`, compressed as `kind` ("zip", "xz", "gzip", "zstd"), into a new image
/// file beside it ([`target`]), and returns that file's path. Refuses to overwrite an
/// existing file.
pub fn unpack(path: &Path, kind: &str) -> Result<PathBuf, ImageError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = target_name(path, kind)?;
    let mut cmd = match kind {
        "zip" => {
            let mut c = Command::new("unzip");
            c.arg("-p").arg(path).arg(zip_entry(path)?);
            c
        }
        "xz" | "gzip" | "zstd" => {
            let mut c = Command::new(kind);
            c.arg("-dc").arg(path);
            c
        }
        other => {
            return Err(ImageError::Input {
                path: path.display().to_string(),
                reason: format!("cannot unpack {other} archives"),
            });
        }
    };
    let target = dir.join(&name);
    if target.exists() {
        return Err(ImageError::Input {
            path: target.display().to_string(),
            reason: format!(
                "exists already (unpacked before?): install into it with --image {}",
                target.display()
            ),
        });
    }
    let part = dir.join(format!(".{name}.part"));
    let out = std::fs::File::create(&part).map_err(|e| ImageError::Input {
        path: part.display().to_string(),
        reason: e.to_string(),
    })?;
    let status = cmd
        .stdout(Stdio::from(out))
        .stderr(Stdio::piped())
        .output()
        .map_err(|e| tool_err(kind, e.to_string()));
    let ok = match status {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => Err(tool_err(
            kind,
            String::from_utf8_lossy(&o.stderr).trim().to_string(),
        )),
        Err(e) => Err(e),
    };
    if let Err(e) = ok {
        let _ = std::fs::remove_file(&part);
        return Err(e);
    }
    std::fs::rename(&part, &target).map_err(|e| ImageError::Input {
        path: target.display().to_string(),
        reason: e.to_string(),
    })?;
    Ok(target)
}
