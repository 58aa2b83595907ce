//! JetBot's road-following data set: one folder of `xy_XXX_YYY_<uuid>.jpg` files, where
//! `XXX`/`YYY` are the pixel coordinates (zero-padded to 3 digits) of the target point the
//! human clicked in the saved image. The label is that point normalised to -1..1:
//! `x = (px - W/2) / (W/2)`, `y = (py - H/2) / (H/2)` (for JetBot's 224x224 images,
//! `(px - 112) / 112`).
//!
//! The file name is the only label store, exactly as in JetBot's notebooks, so a folder
//! collected with a JetBot trains here unchanged and the other way round.

use std::path::{Path, PathBuf};

use super::{DatasetError, Result, io_err, looks_like_jpeg, temp_path};

/// The file name JetBot gives a sample: `xy_{px:03}_{py:03}_{uuid}.jpg`.
///
/// Coordinates of 1000 or more widen the field to 4 digits: [`parse_file_name`] reads them,
/// JetBot's own loader (fixed character positions) does not.
pub fn file_name(px: u32, py: u32, uuid: &str) -> String {
    format!("xy_{px:03}_{py:03}_{uuid}.jpg")
}

/// The pixel coordinates in a JetBot file name, `None` when `name` does not follow the
/// pattern `xy_<digits>_<digits>_<id>.jpg` (at least 3 digits each, a non-empty id;
/// `.jpeg` and upper-case extensions are accepted too).
pub fn parse_file_name(name: &str) -> Option<(u32, u32)> {
    let rest = name.strip_prefix("xy_")?;
    let lower = rest.to_ascii_lowercase();
    let stem_len = if lower.ends_with(".jpg") {
        rest.len() - 4
    } else if lower.ends_with(".jpeg") {
        rest.len() - 5
    } else {
        return None;
    };
    let stem = rest.get(..stem_len)?;
    let mut parts = stem.splitn(3, '_');
    let px = parse_coord(parts.next()?)?;
    let py = parse_coord(parts.next()?)?;
    let id = parts.next()?;
    if id.is_empty() {
        return None;
    }
    Some((px, py))
}

fn parse_coord(s: &str) -> Option<u32> {
    if s.len() < 3 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

/// The training label of pixel `(px, py)` in a `width` x `height` image, each in -1..1
/// (`-1` at the left/top edge, `0` at the centre).
pub fn label(px: u32, py: u32, width: u32, height: u32) -> (f32, f32) {
    let half_w = width as f32 / 2.0;
    let half_h = height as f32 / 2.0;
    ((px as f32 - half_w) / half_w, (py as f32 - half_h) / half_h)
}

/// The pixel for label `(x, y)`: the inverse of [`label`], rounded to the nearest pixel and
/// clamped to the image (a NaN label maps to 0).
pub fn pixel_for_label(x: f32, y: f32, width: u32, height: u32) -> (u32, u32) {
    (to_pixel(x, width), to_pixel(y, height))
}

fn to_pixel(v: f32, size: u32) -> u32 {
    let half = size as f64 / 2.0;
    let p = (v as f64 * half + half).round();
    let max = size.saturating_sub(1) as f64;
    // `as` saturates and maps NaN to 0; clamp first so the result stays inside the image.
    p.clamp(0.0, max) as u32
}

/// The capture time of a sample named with a version-1 UUID (JetBot's `uuid1()`), in
/// seconds since the Unix epoch; `None` for other names (a v4 UUID carries no time).
///
/// A uuid1 is `time_low-time_mid-1time_hi-clock-node` (hex): the timestamp is
/// `time_hi << 48 | time_mid << 32 | time_low` in 100 ns steps since 1582-10-15.
pub fn capture_time_s(name: &str) -> Option<f64> {
    let stem = name.rsplit_once('.').map_or(name, |(s, _)| s);
    let uuid = stem.strip_prefix("xy_")?.splitn(3, '_').nth(2)?;
    let mut parts = uuid.split('-');
    let (low, mid, hi) = (parts.next()?, parts.next()?, parts.next()?);
    if low.len() != 8 || mid.len() != 4 || hi.len() != 4 || !hi.starts_with('1') {
        return None;
    }
    let low = u64::from_str_radix(low, 16).ok()?;
    let mid = u64::from_str_radix(mid, 16).ok()?;
    let hi = u64::from_str_radix(hi, 16).ok()? & 0x0fff;
    let ticks = (hi << 48) | (mid << 32) | low;
    // Subtract in integers: as f64, 1.4e17 ticks would lose the 100 ns steps.
    Some((ticks as i64 - UNIX_EPOCH_TICKS as i64) as f64 / 1e7)
}

/// 100 ns steps from the Gregorian reform (1582-10-15, a version-1 UUID's epoch) to the
/// Unix epoch.
pub const UNIX_EPOCH_TICKS: u64 = 0x01B2_1DD2_1381_4000;

/// A version-1 UUID string (`uuid1()`, as JetBot's notebooks name their samples), for
/// `unix_ticks` 100 ns steps since the Unix epoch, a 14-bit `clock_seq` and a 48-bit `node`
/// (a random node should have its multicast bit, `node[0] & 1`, set, as RFC 4122 says for
/// nodes that are no network card's address). [`capture_time_s`] reads the time back.
pub fn uuid1(unix_ticks: u64, clock_seq: u16, node: [u8; 6]) -> String {
    let t = unix_ticks.saturating_add(UNIX_EPOCH_TICKS);
    let node: String = node.iter().map(|b| format!("{b:02x}")).collect();
    format!(
        "{:08x}-{:04x}-{:04x}-{:02x}{:02x}-{node}",
        t & 0xffff_ffff,
        (t >> 32) & 0xffff,
        ((t >> 48) & 0x0fff) | 0x1000,
        0x80 | ((clock_seq >> 8) & 0x3f),
        clock_seq & 0xff,
    )
}

/// Makes version-1 UUIDs that never repeat within one process: a random node and clock
/// sequence, and a time that moves on by at least one step per UUID (two samples saved in
/// the same 100 ns, or a clock stepped back, still get distinct names).
#[derive(Debug, Clone)]
pub struct Uuid1Clock {
    last: u64,
    clock_seq: u16,
    node: [u8; 6],
}

impl Uuid1Clock {
    pub fn new(rng: &mut impl rand::Rng) -> Self {
        let mut node = [0u8; 6];
        rng.fill(&mut node);
        node[0] |= 0x01;
        Self {
            last: 0,
            clock_seq: rng.random::<u16>() & 0x3fff,
            node,
        }
    }

    /// The UUID for `now` (time since the Unix epoch).
    pub fn next(&mut self, now: std::time::Duration) -> String {
        let ticks = (now.as_nanos() / 100) as u64;
        self.last = ticks.max(self.last.saturating_add(1));
        uuid1(self.last, self.clock_seq, self.node)
    }
}

/// A random v4-style UUID string (`xxxxxxxx-xxxx-4xxx-[89ab]xxx-xxxxxxxxxxxx`), as JetBot
/// names its samples with `uuid1()`/`uuid4()`. The caller owns the generator, so tests are
/// deterministic.
pub fn uuid_from_rng(rng: &mut impl rand::Rng) -> String {
    let mut b = [0u8; 16];
    rng.fill(&mut b);
    b[6] = (b[6] & 0x0F) | 0x40;
    b[8] = (b[8] & 0x3F) | 0x80;
    let hex: String = b.iter().map(|x| format!("{x:02x}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}

/// One sample of the folder.
#[derive(Debug, Clone, PartialEq)]
pub struct XySample {
    pub path: PathBuf,
    pub px: u32,
    pub py: u32,
}

impl XySample {
    /// The training label, given the image size (JetBot: 224x224).
    pub fn label(&self, width: u32, height: u32) -> (f32, f32) {
        label(self.px, self.py, width, height)
    }

    /// Decodes the image into RGB8: `(width, height, pixels)`.
    pub fn load_rgb(&self) -> Result<(u32, u32, Vec<u8>)> {
        super::load_rgb(&self.path)
    }
}

/// A JetBot road-following folder, listed and parsed.
#[derive(Debug, Clone)]
pub struct XyFolder {
    dir: PathBuf,
    samples: Vec<XySample>,
    warnings: Vec<String>,
}

impl XyFolder {
    /// Lists the folder. Files whose names do not follow the pattern are reported in
    /// [`warnings`](Self::warnings) and left out; a folder without any sample is an error.
    pub fn open(dir: &Path) -> Result<Self> {
        let entries = std::fs::read_dir(dir).map_err(io_err(dir))?;
        let mut samples = Vec::new();
        let mut warnings = Vec::new();
        for entry in entries {
            let entry = entry.map_err(io_err(dir))?;
            let path = entry.path();
            let Some(name) = entry.file_name().to_str().map(str::to_owned) else {
                warnings.push(format!(
                    "{}: skipped, the name is not UTF-8",
                    path.display()
                ));
                continue;
            };
            if path.is_dir() {
                warnings.push(format!("{}: skipped, a folder", path.display()));
                continue;
            }
            match parse_file_name(&name) {
                Some((px, py)) => samples.push(XySample { path, px, py }),
                None => warnings.push(format!(
                    "{}: skipped, the name does not follow xy_XXX_YYY_<uuid>.jpg",
                    path.display()
                )),
            }
        }
        if samples.is_empty() {
            return Err(DatasetError::Format {
                path: dir.display().to_string(),
                reason: "no xy_XXX_YYY_<uuid>.jpg samples in this folder".into(),
            });
        }
        samples.sort_by(|a, b| a.path.file_name().cmp(&b.path.file_name()));
        warnings.sort();
        Ok(Self {
            dir: dir.to_path_buf(),
            samples,
            warnings,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The samples, sorted by file name.
    pub fn samples(&self) -> &[XySample] {
        &self.samples
    }

    /// Files that were left out, and why.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }
}

/// Saves one sample as `dir/xy_{px:03}_{py:03}_{uuid}.jpg` and returns its path. The bytes
/// go to a temporary name first and are renamed into place, so a crash never leaves a
/// truncated sample. An existing file of that name is never overwritten (an error).
pub fn write_sample(
    dir: &Path,
    px: u32,
    py: u32,
    jpeg_bytes: &[u8],
    uuid: &str,
) -> Result<PathBuf> {
    let invalid = |reason: String| DatasetError::InvalidInput {
        path: dir.display().to_string(),
        reason,
    };
    if uuid.is_empty()
        || !uuid
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(invalid(format!(
            "sample id {uuid:?} must be non-empty ASCII letters, digits, '-' or '_'"
        )));
    }
    if !looks_like_jpeg(jpeg_bytes) {
        return Err(invalid(format!(
            "the image for sample {uuid} is not JPEG data ({} bytes)",
            jpeg_bytes.len()
        )));
    }
    let path = dir.join(file_name(px, py, uuid));
    if path.exists() {
        return Err(invalid(format!(
            "{} already exists; a sample is never overwritten",
            path.display()
        )));
    }
    write_new(&path, jpeg_bytes)?;
    Ok(path)
}

/// Writes `bytes` to the new file `path` through a temporary name and a rename; on a
/// failure (a full disk) the temporary file is removed, so no partial file is left.
pub(crate) fn write_new(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_path(path);
    let written = std::fs::write(&tmp, bytes)
        .map_err(io_err(&tmp))
        .and_then(|()| std::fs::rename(&tmp, path).map_err(io_err(path)));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn tiny_jpeg() -> Vec<u8> {
        let img =
            image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([x as u8 * 30, y as u8 * 30, 7]));
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    }

    #[test]
    fn labels_worked_numbers() {
        assert_eq!(label(112, 112, 224, 224), (0.0, 0.0));
        let (x, y) = label(223, 0, 224, 224);
        assert!((x - 111.0 / 112.0).abs() < 1e-7, "{x}");
        assert!((x - 0.991_071_4).abs() < 1e-6);
        assert_eq!(y, -1.0);
        assert_eq!(label(0, 224, 224, 224), (-1.0, 1.0));
        // non-square image
        assert_eq!(label(320, 60, 640, 480), (0.0, -0.75));
    }

    #[test]
    fn file_names() {
        assert_eq!(file_name(57, 101, "abc"), "xy_057_101_abc.jpg");
        assert_eq!(
            parse_file_name("xy_057_101_0b7e5f4c-2d1a-11ea-9c3a-00044be5a7c1.jpg"),
            Some((57, 101))
        );
        assert_eq!(parse_file_name("xy_000_223_x.JPG"), Some((0, 223)));
        assert_eq!(parse_file_name("xy_1000_005_u_v.jpeg"), Some((1000, 5)));
        for bad in [
            "xy_57_101_abc.jpg",
            "xy_057_101_.jpg",
            "xy_057_101.jpg",
            "xy_057_1a1_abc.jpg",
            "xy_057_101_abc.png",
            "ab_057_101_abc.jpg",
            "xy_+57_101_abc.jpg",
            "",
            "xy_",
        ] {
            assert_eq!(parse_file_name(bad), None, "{bad}");
        }
        let name = file_name(5, 222, "id-1");
        assert_eq!(parse_file_name(&name), Some((5, 222)));
    }

    #[test]
    fn pixel_round_trip() {
        for px in 0..224 {
            for py in [0, 1, 57, 112, 223] {
                let (x, y) = label(px, py, 224, 224);
                assert_eq!(pixel_for_label(x, y, 224, 224), (px, py));
            }
        }
        for (w, h) in [(640, 480), (7, 5)] {
            for px in 0..w {
                let (x, y) = label(px, h - 1, w, h);
                assert_eq!(pixel_for_label(x, y, w, h), (px, h - 1));
            }
        }
        // clamped to the image
        assert_eq!(pixel_for_label(1.0, -1.0, 224, 224), (223, 0));
        assert_eq!(pixel_for_label(5.0, -3.0, 224, 224), (223, 0));
        assert_eq!(pixel_for_label(f32::NAN, f32::INFINITY, 224, 224), (0, 223));
        assert_eq!(pixel_for_label(0.0, 0.0, 224, 224), (112, 112));
    }

    #[test]
    fn uuids_are_v4_and_deterministic() {
        let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut b = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let u = uuid_from_rng(&mut a);
        assert_eq!(u, uuid_from_rng(&mut b));
        assert_ne!(u, uuid_from_rng(&mut a));
        assert_eq!(u.len(), 36);
        let groups: Vec<&str> = u.split('-').collect();
        assert_eq!(
            groups.iter().map(|g| g.len()).collect::<Vec<_>>(),
            [8, 4, 4, 4, 12]
        );
        assert!(groups[2].starts_with('4'));
        assert!(matches!(groups[3].as_bytes()[0], b'8' | b'9' | b'a' | b'b'));
        assert!(
            u.chars()
                .all(|c| c == '-' || c.is_ascii_hexdigit() && !c.is_ascii_uppercase())
        );
    }

    #[test]
    fn folder_write_and_open() {
        let dir = tempfile::tempdir().unwrap();
        let err = XyFolder::open(dir.path()).unwrap_err();
        assert!(matches!(err, DatasetError::Format { .. }));
        assert!(err.to_string().contains(&dir.path().display().to_string()));

        let jpeg = tiny_jpeg();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let u1 = uuid_from_rng(&mut rng);
        let p1 = write_sample(dir.path(), 200, 10, &jpeg, &u1).unwrap();
        let p2 = write_sample(dir.path(), 57, 101, &jpeg, "b").unwrap();
        assert_eq!(p2, dir.path().join("xy_057_101_b.jpg"));
        assert_eq!(std::fs::read(&p1).unwrap(), jpeg);
        // never overwritten
        let err = write_sample(dir.path(), 57, 101, &[0xFF, 0xD8, 0xFF, 0], "b").unwrap_err();
        assert!(err.to_string().contains("already exists"), "{err}");
        assert_eq!(std::fs::read(&p2).unwrap(), jpeg);
        // bad input
        assert!(write_sample(dir.path(), 1, 1, b"not a jpeg", "c").is_err());
        assert!(write_sample(dir.path(), 1, 1, &jpeg, "../x").is_err());
        assert!(write_sample(dir.path(), 1, 1, &jpeg, "").is_err());
        std::fs::write(dir.path().join("notes.txt"), "hi").unwrap();
        std::fs::create_dir(dir.path().join("sub")).unwrap();

        let folder = XyFolder::open(dir.path()).unwrap();
        assert_eq!(
            folder.samples(),
            &[
                XySample {
                    path: p2.clone(),
                    px: 57,
                    py: 101
                },
                XySample {
                    path: p1.clone(),
                    px: 200,
                    py: 10
                },
            ]
        );
        assert_eq!(folder.warnings().len(), 2, "{:?}", folder.warnings());
        assert!(folder.warnings().iter().any(|w| w.contains("notes.txt")));
        let (w, h, rgb) = folder.samples()[0].load_rgb().unwrap();
        assert_eq!((w, h, rgb.len()), (8, 8, 192));
        assert_eq!(
            folder.samples()[0].label(224, 224),
            label(57, 101, 224, 224)
        );
    }

    #[test]
    fn uuid1_worked_number_and_round_trip() {
        // 2026-12-04 00:00:00 UTC = 1_796_342_400 s after the Unix epoch; Python's
        // uuid.UUID(fields=...) for the same time, clock_seq 0x1234 and node 0123456789ab
        // prints a5f98000-ef75-11f1-9234-0123456789ab.
        let ticks = 1_796_342_400 * 10_000_000;
        let u = uuid1(ticks, 0x1234, [0x01, 0x23, 0x45, 0x67, 0x89, 0xab]);
        assert_eq!(u, "a5f98000-ef75-11f1-9234-0123456789ab");
        let name = file_name(150, 60, &u);
        assert_eq!(parse_file_name(&name), Some((150, 60)));
        assert_eq!(capture_time_s(&name), Some(1_796_342_400.0));
        // The clock never repeats, even for one instant asked twice or a clock stepped back.
        let mut clock = Uuid1Clock::new(&mut rand_chacha::ChaCha8Rng::seed_from_u64(3));
        let now = std::time::Duration::from_secs(1_796_342_400);
        let a = clock.next(now);
        let b = clock.next(now);
        let c = clock.next(now - std::time::Duration::from_secs(5));
        assert!(a != b && b != c && a != c, "{a} {b} {c}");
        let t = |u: &str| capture_time_s(&file_name(1, 1, u)).unwrap();
        assert_eq!(t(&a), 1_796_342_400.0);
        // One 100 ns step apart (seconds as f64 cannot show it: read time_low).
        let low = |u: &str| u64::from_str_radix(&u[..8], 16).unwrap();
        assert_eq!((low(&b) - low(&a), low(&c) - low(&b)), (1, 1));
        // Variant bits 10xx and a multicast (random) node.
        assert!(matches!(&a[19..20], "8" | "9" | "a" | "b"), "{a}");
        assert_eq!(u8::from_str_radix(&a[24..26], 16).unwrap() & 1, 1, "{a}");
    }

    #[test]
    fn uuid1_names_carry_their_capture_time() {
        // 2bef-11f0 ... : May 2025 (JetBot's notebook, shared/realdata).
        let t = capture_time_s("xy_010_171_af415624-2bef-11f0-a827-e0e1a91dc0f8.jpg").unwrap();
        // time_hi 0x1f0, time_mid 0x2bef, time_low 0xaf415624:
        // ticks = 0x01f0_2bef_af41_5624 = 139_659_896_885_958_180 (100 ns since 1582-10-15)
        // unix = (ticks - 122_192_928_000_000_000) / 1e7 = 1_746_696_888.595818 (2025-05-08)
        assert!((t - 1_746_696_888.595_818).abs() < 1e-3, "{t}");
        let later = capture_time_s("xy_012_154_add2983e-2bef-11f0-a827-e0e1a91dc0f8.jpg").unwrap();
        assert!(later < t, "add2983e comes before af415624 in time_low");
        // A v4 UUID (version nibble 4) and other names carry no time.
        assert_eq!(
            capture_time_s("xy_010_171_af415624-2bef-41f0-a827-e0e1a91dc0f8.jpg"),
            None
        );
        assert_eq!(capture_time_s("xy_010_171_nouuid.jpg"), None);
        assert_eq!(capture_time_s("photo.jpg"), None);
    }
}
