//! Sim-to-real at a glance: the contact sheet `jetpilot sim --png DIR --real FOLDER`
//! writes, simulated camera views in the top row and real frames from `FOLDER` in the
//! bottom row, all at the same tile size, so a person can compare geometry (horizon, how
//! the road edges bend, how wide the road is at the bottom) and appearance side by side.
//!
//! Real frames are any JPEG or PNG files in the folder or one level down (a JetBot xy
//! folder, a folder of them, a tub's `images/`), picked evenly over their sorted names.
//! Unreadable files are skipped with a warning naming each.

use std::path::{Path, PathBuf};

use image::imageops::FilterType;
use image::{Rgb, RgbImage};

use crate::dataset::{DatasetError, load_rgb, short_reason};

const GAP: u32 = 4;
const BACKGROUND: Rgb<u8> = Rgb([24, 24, 24]);

/// Real frames picked for a sheet, and the files that could not be read.
#[derive(Debug)]
pub struct RealFrames {
    pub frames: Vec<RgbImage>,
    /// `"<path>: <reason>"` for each skipped file.
    pub skipped: Vec<String>,
}

fn is_image(p: &Path) -> bool {
    matches!(
        p.extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref(),
        Some("jpg" | "jpeg" | "png")
    )
}

fn list_dir(dir: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let io = |source| DatasetError::Io {
        path: dir.display().to_string(),
        source,
    };
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        out.push(entry.map_err(io)?.path());
    }
    out.sort();
    Ok(out)
}

/// Image files in `folder` and in its subfolders (one level), sorted by path.
pub fn image_files(folder: &Path) -> Result<Vec<PathBuf>, DatasetError> {
    let mut files = Vec::new();
    for p in list_dir(folder)? {
        if p.is_dir() {
            files.extend(
                list_dir(&p)?
                    .into_iter()
                    .filter(|q| q.is_file() && is_image(q)),
            );
        } else if is_image(&p) {
            files.push(p);
        }
    }
    files.sort();
    Ok(files)
}

/// Up to `n` readable frames spread evenly over the image files of `folder`: file
/// `floor(i * len / n)` for frame `i`, or the next readable one after it.
pub fn pick_real_frames(folder: &Path, n: usize) -> Result<RealFrames, DatasetError> {
    let files = image_files(folder)?;
    if files.is_empty() {
        return Err(DatasetError::Format {
            path: folder.display().to_string(),
            reason: "no .jpg or .png files here or one level down".into(),
        });
    }
    let mut frames = Vec::new();
    let mut skipped = Vec::new();
    let mut next = 0usize;
    for i in 0..n {
        let mut k = (i * files.len() / n.max(1)).max(next);
        while k < files.len() {
            let path = &files[k];
            k += 1;
            match load_rgb(path) {
                Ok((w, h, rgb)) => {
                    if let Some(img) = RgbImage::from_raw(w, h, rgb) {
                        frames.push(img);
                        break;
                    }
                }
                Err(e) => skipped.push(format!("{}: {}", path.display(), short_reason(&e))),
            }
        }
        next = k;
    }
    if frames.is_empty() {
        return Err(DatasetError::Format {
            path: folder.display().to_string(),
            reason: format!("no readable frame ({} skipped)", skipped.len()),
        });
    }
    Ok(RealFrames { frames, skipped })
}

/// The sheet: `sim` frames (RGB8, `width x height`) in the top row, `real` in the bottom
/// row, each scaled to `tile` pixels square, `GAP` pixels apart.
pub fn contact_sheet(
    sim: &[&[u8]],
    width: u32,
    height: u32,
    real: &[RgbImage],
    tile: u32,
) -> RgbImage {
    let columns = sim.len().max(real.len()).max(1) as u32;
    let step = tile + GAP;
    let mut sheet = RgbImage::from_pixel(columns * step + GAP, 2 * step + GAP, BACKGROUND);
    let place = |sheet: &mut RgbImage, img: &RgbImage, col: u32, row: u32| {
        let scaled = if img.width() == tile && img.height() == tile {
            img.clone()
        } else {
            image::imageops::resize(img, tile, tile, FilterType::Triangle)
        };
        image::imageops::replace(
            sheet,
            &scaled,
            i64::from(GAP + col * step),
            i64::from(GAP + row * step),
        );
    };
    for (i, f) in sim.iter().enumerate() {
        if let Some(img) = RgbImage::from_raw(width, height, f.to_vec()) {
            place(&mut sheet, &img, i as u32, 0);
        }
    }
    for (i, img) in real.iter().enumerate() {
        place(&mut sheet, img, i as u32, 1);
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(path: &Path, rgb: [u8; 3]) {
        RgbImage::from_pixel(16, 16, Rgb(rgb)).save(path).unwrap();
    }

    #[test]
    fn picks_evenly_skips_bad_files_and_lays_out_two_rows() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("low_tilt");
        std::fs::create_dir(&sub).unwrap();
        write(&dir.path().join("a.png"), [200, 0, 0]);
        std::fs::write(sub.join("b.jpg"), b"").unwrap(); // zero bytes, as in the real data
        write(&sub.join("c.png"), [0, 200, 0]);
        write(&sub.join("d.png"), [0, 0, 200]);
        std::fs::write(dir.path().join("notes.txt"), b"not an image").unwrap();

        let files = image_files(dir.path()).unwrap();
        assert_eq!(files.len(), 4);
        // Two of four: files 0 and 2 (a.png, c.png); the empty b.jpg is never reached.
        let two = pick_real_frames(dir.path(), 2).unwrap();
        assert_eq!(two.frames.len(), 2);
        assert_eq!(two.frames[0].get_pixel(3, 3), &Rgb([200, 0, 0]));
        assert_eq!(two.frames[1].get_pixel(3, 3), &Rgb([0, 200, 0]));
        assert!(two.skipped.is_empty());
        // Four of four: b.jpg is skipped with its name and reason, c and d follow.
        let four = pick_real_frames(dir.path(), 4).unwrap();
        assert_eq!(four.frames.len(), 3);
        assert_eq!(four.skipped.len(), 1);
        assert!(
            four.skipped[0].contains("b.jpg") && four.skipped[0].contains("empty"),
            "{:?}",
            four.skipped
        );

        let sim = vec![90u8; 8 * 8 * 3];
        let sheet = contact_sheet(&[&sim, &sim], 8, 8, &four.frames, 10);
        // Three columns (the longer row), two rows of 10 px tiles, 4 px gaps.
        assert_eq!(sheet.dimensions(), (3 * 14 + 4, 2 * 14 + 4));
        assert_eq!(sheet.get_pixel(GAP + 5, GAP + 5), &Rgb([90, 90, 90]));
        assert_eq!(sheet.get_pixel(GAP + 5, GAP + 14 + 5), &Rgb([200, 0, 0]));
        assert_eq!(
            sheet.get_pixel(GAP + 2 * 14 + 5, GAP + 14 + 5),
            &Rgb([0, 0, 200])
        );
        // The third sim tile is empty.
        assert_eq!(sheet.get_pixel(GAP + 2 * 14 + 5, GAP + 5), &BACKGROUND);
    }

    #[test]
    fn a_folder_without_readable_frames_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let err = pick_real_frames(dir.path(), 4).unwrap_err().to_string();
        assert!(err.contains("no .jpg or .png"), "{err}");
        std::fs::write(dir.path().join("x.jpg"), b"").unwrap();
        let err = pick_real_frames(dir.path(), 4).unwrap_err().to_string();
        assert!(err.contains("no readable frame (1 skipped)"), "{err}");
    }
}
