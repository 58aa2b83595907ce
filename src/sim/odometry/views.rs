//! Checking poses where there is no ground truth (`jetpilot poses --check-views`): frame
//! `t + k` is predicted from frame `t` through the two frames' poses and the ground-plane
//! re-projection the replay simulator itself uses ([`Synthesizer::synthesize_from`]), and
//! scored against the real frame `t + k` on the floor, by PSNR and SSIM of grey levels.
//! Right poses put the floor where the camera saw it; wrong ones slide or turn it.
//!
//! ```text
//! frame t --(pose set's pose t -> pose t+k, ground plane)--> predicted t+k --+
//!                                                 real frame t+k ------------+--> PSNR, SSIM
//! ```
//!
//! Two baselines give the scale: the identity (frame `t` itself: nothing moved) and any
//! other pose set passed in (the prior alone, the truth on a simulated drive). Every pose
//! set of a pair is scored on the same pixels: floor the camera sees in frame `t + k`, not
//! in the chassis mask, whose ground point every set places inside frame `t` and outside
//! its chassis, and no farther ahead than asked (the floor the odometry resolves, by
//! default: beyond it a real floor ends, walls stand and the ground plane fails). A pair
//! with less such floor than `min_floor` of the ground pixels is
//! skipped and counted. Pure: the strip is an image in memory.

use std::sync::Arc;

use image::{Rgb, RgbImage};

use super::super::camera::CameraModel;
use super::super::synth::{RecordedFrame, Recording, Synthesizer};
use super::super::{Pose2, SimError};
use super::mask::PixelMask;

/// The steps `k` (frames ahead) checked by default.
pub const STEPS: [usize; 3] = [1, 5, 10];

/// Half the side of SSIM's window: 7 x 7 pixels.
const SSIM_RADIUS: usize = 3;
/// A window counts where at least this many of its 49 pixels are scored floor.
const SSIM_MIN_PIXELS: u32 = 25;
/// SSIM's stabilisers for 8-bit grey: `(0.01 * 255)^2` and `(0.03 * 255)^2`.
const C1: f64 = 6.5025;
const C2: f64 = 58.5225;
/// A perfect prediction's PSNR is reported as this (dB) rather than infinity.
const PSNR_CAP_DB: f64 = 99.0;

/// A frame's RGB8 pixels, shared; `None` where its image is missing.
pub type Frame = Option<Arc<Vec<u8>>>;

/// A pair shown in the strip: the step, frame `t`, every method's prediction (the
/// identity first) and the scored floor.
struct Shown {
    k: usize,
    t: usize,
    predictions: Vec<Vec<u8>>,
    scored: Vec<bool>,
}

/// Poses for every frame, named (`estimate`, `prior alone`, `truth`).
#[derive(Debug, Clone)]
pub struct PoseSet {
    pub name: String,
    /// One per frame, in the frames' order.
    pub poses: Vec<Pose2>,
}

/// How well one prediction matches the real frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Score {
    pub psnr_db: f64,
    pub ssim: f64,
}

/// One step's results, a column per method: the identity first, then the pose sets.
#[derive(Debug, Clone, PartialEq)]
pub struct StepRow {
    pub k: usize,
    /// Pairs scored, and pairs skipped (an image missing, or too little common floor).
    pub pairs: usize,
    pub skipped: usize,
    /// Mean over the scored pairs (NaN with none).
    pub mean: Vec<Score>,
    /// Fraction of the scored pairs whose SSIM beats the identity's (the identity's own
    /// entry is 0).
    pub beats_identity: Vec<f64>,
}

/// What [`check_views`] found.
#[derive(Debug, Clone)]
pub struct ViewCheck {
    /// `identity`, then the pose sets' names.
    pub methods: Vec<String>,
    pub rows: Vec<StepRow>,
    /// For a person to look at: rows of pairs at the middle step; columns: frame `t`,
    /// each set's prediction, the real frame `t + k`, then the identity's and each set's
    /// absolute difference on the scored floor (x3; dark blue outside it).
    pub strip: Option<RgbImage>,
    /// The step and frame `t` of each row of the strip.
    pub strip_pairs: Vec<(usize, usize)>,
}

impl ViewCheck {
    /// Whether the method at column `m` has a higher mean PSNR and a higher mean SSIM than
    /// each of the columns `others` at every step with scored pairs (and there is one).
    pub fn beats(&self, m: usize, others: &[usize]) -> bool {
        let scored: Vec<&StepRow> = self.rows.iter().filter(|r| r.pairs > 0).collect();
        !scored.is_empty()
            && scored.iter().all(|r| {
                others.iter().all(|&o| {
                    o != m
                        && r.mean[m].psnr_db > r.mean[o].psnr_db
                        && r.mean[m].ssim > r.mean[o].ssim
                })
            })
    }

    /// The table, a line per step.
    pub fn table(&self) -> String {
        let mut out = format!("{:>4} {:>6} {:>8}", "k", "pairs", "skipped");
        for m in &self.methods {
            out += &format!("  {:>22}", format!("{m}: PSNR dB / SSIM"));
        }
        for r in &self.rows {
            out += &format!("\n{:>4} {:>6} {:>8}", r.k, r.pairs, r.skipped);
            for s in &r.mean {
                out += &format!("  {:>22}", format!("{:.2} / {:.3}", s.psnr_db, s.ssim));
            }
        }
        out
    }

    /// The table as CSV: `k,pairs,skipped,method,psnr_db,ssim,beats_identity`.
    pub fn csv(&self) -> String {
        let mut out = String::from("k,pairs,skipped,method,psnr_db,ssim,beats_identity\n");
        for r in &self.rows {
            for (m, s) in r.mean.iter().enumerate() {
                out += &format!(
                    "{},{},{},{},{:.4},{:.5},{:.4}\n",
                    r.k,
                    r.pairs,
                    r.skipped,
                    self.methods[m],
                    s.psnr_db,
                    s.ssim,
                    r.beats_identity[m]
                );
            }
        }
        out
    }
}

/// Grey level of an RGB8 pixel: the mean of its channels (as the bird's-eye views take it).
fn grey(rgb: &[u8]) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|p| (f32::from(p[0]) + f32::from(p[1]) + f32::from(p[2])) / 3.0)
        .collect()
}

/// PSNR (dB, peak 255) of `b` against `a` over the pixels where `valid`; `None` with none,
/// or where the three lengths differ.
pub fn masked_psnr(a: &[f32], b: &[f32], valid: &[bool]) -> Option<f64> {
    if a.len() != b.len() || a.len() != valid.len() {
        return None;
    }
    let (mut sum, mut n) = (0.0f64, 0usize);
    for ((x, y), _) in a.iter().zip(b).zip(valid).filter(|(_, v)| **v) {
        let d = f64::from(x - y);
        sum += d * d;
        n += 1;
    }
    if n == 0 {
        return None;
    }
    let mse = sum / n as f64;
    Some(if mse <= 0.0 {
        PSNR_CAP_DB
    } else {
        (10.0 * (255.0f64 * 255.0 / mse).log10()).min(PSNR_CAP_DB)
    })
}

/// Mean SSIM of `b` against `a` (`w` x `h` grey levels) over 7 x 7 windows, each centred
/// on a valid pixel and computed over the valid pixels in it (at least 25 of 49), with
/// the usual constants for 8-bit levels; `None` where no window qualifies. Masked-out
/// pixels take no part, whatever their values. `None` also where a length is not `w * h`.
pub fn masked_ssim(a: &[f32], b: &[f32], valid: &[bool], w: usize, h: usize) -> Option<f64> {
    if a.len() != w * h || b.len() != w * h || valid.len() != w * h {
        return None;
    }
    // Integral images of n, a, b, a^2, b^2, ab over the valid pixels, (w+1) x (h+1).
    let stride = w + 1;
    let mut sums = vec![[0.0f64; 6]; stride * (h + 1)];
    for y in 0..h {
        let mut row = [0.0f64; 6];
        for x in 0..w {
            let i = y * w + x;
            if valid[i] {
                let (p, q) = (f64::from(a[i]), f64::from(b[i]));
                for (r, v) in row.iter_mut().zip([1.0, p, q, p * p, q * q, p * q]) {
                    *r += v;
                }
            }
            let above = sums[y * stride + x + 1];
            let cell = &mut sums[(y + 1) * stride + x + 1];
            for c in 0..6 {
                cell[c] = above[c] + row[c];
            }
        }
    }
    let (mut total, mut windows) = (0.0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            if !valid[y * w + x] {
                continue;
            }
            let (x0, y0) = (x.saturating_sub(SSIM_RADIUS), y.saturating_sub(SSIM_RADIUS));
            let (x1, y1) = ((x + SSIM_RADIUS + 1).min(w), (y + SSIM_RADIUS + 1).min(h));
            let at = |xx: usize, yy: usize| sums[yy * stride + xx];
            let (s11, s01, s10, s00) = (at(x1, y1), at(x0, y1), at(x1, y0), at(x0, y0));
            let s: [f64; 6] = std::array::from_fn(|c| s11[c] - s01[c] - s10[c] + s00[c]);
            let n = s[0];
            if n < f64::from(SSIM_MIN_PIXELS) {
                continue;
            }
            let (ma, mb) = (s[1] / n, s[2] / n);
            let va = (s[3] / n - ma * ma).max(0.0);
            let vb = (s[4] / n - mb * mb).max(0.0);
            let cov = s[5] / n - ma * mb;
            total += ((2.0 * ma * mb + C1) * (2.0 * cov + C2))
                / ((ma * ma + mb * mb + C1) * (va + vb + C2));
            windows += 1;
        }
    }
    (windows > 0).then(|| total / windows as f64)
}

/// Predicts frame `t + k` from frame `t` for every `k` of `steps` and every `t`, for the
/// identity and each pose set, and scores the predictions against the real frames (see
/// the module's doc). `frames[i]` is frame `i`'s RGB8 pixels at the camera's size, `None`
/// where its image is missing; every set has a pose per frame. Only floor up to
/// `max_forward_m` ahead of the robot's origin is scored.
pub fn check_views(
    camera: &CameraModel,
    frames: &[Frame],
    mask: Option<&PixelMask>,
    sets: &[PoseSet],
    steps: &[usize],
    max_forward_m: f32,
    min_floor: f32,
) -> Result<ViewCheck, SimError> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let len = w * h * 3;
    for (i, f) in frames.iter().enumerate() {
        if let Some(px) = f
            && px.len() != len
        {
            return Err(SimError::Invalid(format!(
                "frame {i} has {} bytes, the camera ({w}x{h}) needs {len}",
                px.len()
            )));
        }
    }
    if let Some(m) = mask
        && (m.width, m.height) != (camera.width, camera.height)
    {
        return Err(SimError::Invalid(format!(
            "the chassis mask is {}x{}, the camera {w}x{h}",
            m.width, m.height
        )));
    }
    if sets.is_empty() || frames.is_empty() {
        return Err(SimError::Invalid(
            "checking views needs frames and at least one pose set".into(),
        ));
    }
    for s in sets {
        if s.poses.len() != frames.len() {
            return Err(SimError::Invalid(format!(
                "pose set `{}` has {} poses for {} frames",
                s.name,
                s.poses.len(),
                frames.len()
            )));
        }
    }
    let masked = |i: usize| mask.is_some_and(|m| m.masked.get(i).copied().unwrap_or(false));
    let blank = Arc::new(vec![0u8; len]);
    let synths = sets
        .iter()
        .map(|s| {
            let recording = Recording {
                camera: *camera,
                frames: frames
                    .iter()
                    .zip(&s.poses)
                    .map(|(f, p)| RecordedFrame {
                        pose: *p,
                        width: camera.width,
                        height: camera.height,
                        rgb: f.clone().unwrap_or_else(|| blank.clone()),
                    })
                    .collect(),
            };
            Synthesizer::new(recording, 1.0).map(|s| s.with_fill_from_earlier(false))
        })
        .collect::<Result<Vec<_>, _>>()?;
    // The pixels that see floor within `max_forward_m` (beyond it, a real floor's edge,
    // walls and the things on it break the ground plane).
    let ground: Vec<bool> = synths[0]
        .sources(0, &sets[0].poses[0])
        .iter()
        .enumerate()
        .map(|(i, at)| {
            at.is_some()
                && camera
                    .pixel_to_robot_ground((i % w) as f32 + 0.5, (i / w) as f32 + 0.5)
                    .is_some_and(|(f, _)| f <= max_forward_m)
        })
        .collect();
    let ground_pixels = ground.iter().filter(|g| **g).count().max(1);
    let methods: Vec<String> = std::iter::once("identity".to_string())
        .chain(sets.iter().map(|s| s.name.clone()))
        .collect();
    let shown_step = steps.get(steps.len() / 2).copied();
    let mut rows = Vec::with_capacity(steps.len());
    let mut shown: Vec<Shown> = Vec::new();
    let mut predicted = vec![vec![0u8; len]; sets.len()];
    for &k in steps {
        let (mut sum, mut wins) = (
            vec![Score::default(); methods.len()],
            vec![0usize; methods.len()],
        );
        let (mut pairs, mut skipped) = (0usize, 0usize);
        let mut candidates = Vec::new();
        for t in 0..frames.len().saturating_sub(k) {
            let (Some(src), Some(real)) = (&frames[t], &frames[t + k]) else {
                skipped += 1;
                continue;
            };
            let mut valid: Vec<bool> = (0..w * h).map(|i| ground[i] && !masked(i)).collect();
            for (s, set) in synths.iter().zip(sets) {
                for (v, at) in valid.iter_mut().zip(s.sources(t, &set.poses[t + k])) {
                    *v = *v
                        && at.is_some_and(|(u, vv)| {
                            let (x, y) = ((u as usize).min(w - 1), (vv as usize).min(h - 1));
                            !masked(y * w + x)
                        });
                }
            }
            if (valid.iter().filter(|v| **v).count() as f32) < min_floor * ground_pixels as f32 {
                skipped += 1;
                continue;
            }
            let real_grey = grey(real);
            let mut scores = Vec::with_capacity(methods.len());
            let mut predictions: Vec<&[u8]> = vec![src.as_slice()];
            for ((s, set), out) in synths.iter().zip(sets).zip(predicted.iter_mut()) {
                s.synthesize_from(t, &set.poses[t + k], out);
            }
            predictions.extend(predicted.iter().map(Vec::as_slice));
            for p in &predictions {
                let g = grey(p);
                let (Some(psnr_db), Some(ssim)) = (
                    masked_psnr(&real_grey, &g, &valid),
                    masked_ssim(&real_grey, &g, &valid, w, h),
                ) else {
                    break;
                };
                scores.push(Score { psnr_db, ssim });
            }
            if scores.len() != methods.len() {
                skipped += 1;
                continue;
            }
            pairs += 1;
            for (m, s) in scores.iter().enumerate() {
                sum[m].psnr_db += s.psnr_db;
                sum[m].ssim += s.ssim;
                if m > 0 && s.ssim > scores[0].ssim {
                    wins[m] += 1;
                }
            }
            if Some(k) == shown_step {
                candidates.push(Shown {
                    k,
                    t,
                    predictions: predictions.iter().map(|p| p.to_vec()).collect(),
                    scored: valid,
                });
            }
        }
        if !candidates.is_empty() {
            let n = candidates.len();
            let picks: Vec<usize> = (0..4.min(n)).map(|i| (2 * i + 1) * n / 8).collect();
            for (i, pair) in candidates.into_iter().enumerate() {
                if picks.contains(&i) {
                    shown.push(pair);
                }
            }
        }
        let per = |v: f64| {
            if pairs > 0 {
                v / pairs as f64
            } else {
                f64::NAN
            }
        };
        rows.push(StepRow {
            k,
            pairs,
            skipped,
            mean: sum
                .iter()
                .map(|s| Score {
                    psnr_db: per(s.psnr_db),
                    ssim: per(s.ssim),
                })
                .collect(),
            beats_identity: wins.iter().map(|&v| per(v as f64)).collect(),
        });
    }
    let strip_pairs = shown.iter().map(|p| (p.k, p.t)).collect();
    let strip = (!shown.is_empty()).then(|| draw_strip(camera, frames, &shown));
    Ok(ViewCheck {
        methods,
        rows,
        strip,
        strip_pairs,
    })
}

/// The strip of [`ViewCheck::strip`]: a row per shown pair `(k, t, predictions (identity
/// first), scored floor)`.
fn draw_strip(camera: &CameraModel, frames: &[Frame], shown: &[Shown]) -> RgbImage {
    const GAP: u32 = 4;
    let (w, h) = (camera.width, camera.height);
    let methods = shown.first().map_or(1, |s| s.predictions.len());
    // t, the sets' predictions, the real t+k, every method's difference.
    let columns = 1 + (methods - 1) + 1 + methods;
    let mut img = RgbImage::from_pixel(
        columns as u32 * (w + GAP),
        shown.len() as u32 * (h + GAP),
        Rgb([255, 255, 255]),
    );
    for (
        row,
        Shown {
            k,
            t,
            predictions: preds,
            scored: valid,
        },
    ) in shown.iter().enumerate()
    {
        let Some(real) = frames.get(t + k).and_then(|f| f.as_ref()) else {
            continue;
        };
        let mut tiles: Vec<Vec<u8>> = vec![preds[0].clone()];
        tiles.extend(preds[1..].iter().cloned());
        tiles.push(real.to_vec());
        for p in preds {
            let diff: Vec<u8> = p
                .chunks_exact(3)
                .zip(real.chunks_exact(3))
                .zip(valid)
                .flat_map(|((a, b), v)| {
                    if *v {
                        let d = (grey(a)[0] - grey(b)[0]).abs() * 3.0;
                        let d = d.min(255.0) as u8;
                        [d, d, d]
                    } else {
                        [0, 0, 80]
                    }
                })
                .collect();
            tiles.push(diff);
        }
        for (col, tile) in tiles.iter().enumerate() {
            let (ox, oy) = (col as u32 * (w + GAP), row as u32 * (h + GAP));
            for (i, px) in tile.chunks_exact(3).enumerate() {
                let (x, y) = (i as u32 % w, i as u32 / w);
                img.put_pixel(ox + x, oy + y, Rgb([px[0], px[1], px[2]]));
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::super::car_drive_test::{render, test_car};
    use super::super::compose;
    use super::*;

    #[test]
    fn psnr_of_an_offset_of_ten_levels_and_masked_pixels_take_no_part() {
        let a = vec![100.0f32; 12];
        let mut b = vec![110.0f32; 12];
        let mut valid = vec![true; 12];
        // MSE 100: 10 log10(255^2 / 100) = 28.1308 dB.
        let p = masked_psnr(&a, &b, &valid).expect("pixels");
        assert!((p - 28.1308).abs() < 1e-4, "{p}");
        b[3] = 0.0;
        valid[3] = false;
        assert_eq!(masked_psnr(&a, &b, &valid), Some(p));
        assert_eq!(masked_psnr(&a, &a, &valid), Some(PSNR_CAP_DB));
        assert_eq!(masked_psnr(&a, &b, &[false; 12]), None);
    }

    #[test]
    fn ssim_worked_values() {
        let (w, h) = (9, 8);
        let a: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 200) as f32).collect();
        let valid = vec![true; w * h];
        let same = masked_ssim(&a, &a, &valid, w, h).expect("windows");
        assert!((same - 1.0).abs() < 1e-12, "{same}");
        // Flat 100 against flat 110: only the luminance term,
        // (2 * 100 * 110 + C1) / (100^2 + 110^2 + C1) = 0.995476.
        let (f, g) = (vec![100.0f32; w * h], vec![110.0f32; w * h]);
        let s = masked_ssim(&f, &g, &valid, w, h).expect("windows");
        assert!((s - 0.995_476_4).abs() < 1e-6, "{s}");
        // An inverted pattern scores below zero.
        let inv: Vec<f32> = a.iter().map(|v| 200.0 - v).collect();
        assert!(masked_ssim(&a, &inv, &valid, w, h).expect("windows") < 0.0);
        // Garbage under the mask changes nothing; a window needs 25 scored pixels.
        let mut masked = valid.clone();
        let mut b = a.clone();
        for i in 0..w {
            masked[i] = false;
            b[i] = 255.0;
        }
        assert!((masked_ssim(&a, &b, &masked, w, h).expect("windows") - 1.0).abs() < 1e-12);
        let sparse: Vec<bool> = (0..w * h).map(|i| i % 3 == 0).collect();
        assert_eq!(masked_ssim(&a, &a, &sparse, w, h), None);
    }

    /// A car drive over the textured floor of the car-drive test: its frames, and the
    /// true poses.
    fn drive(camera: &CameraModel, frames: usize) -> (Vec<Frame>, Vec<Pose2>) {
        let mut car = test_car(0.3);
        let mut pose = Pose2::default();
        let (mut images, mut poses) = (Vec::new(), Vec::new());
        for k in 0..frames {
            if k > 0 {
                let angle = if k < 12 { 0.0 } else { -0.6 };
                pose = compose(&pose, &car.advance(angle, 0.25, 0.05));
            }
            images.push(Some(Arc::new(render(camera, &pose))));
            poses.push(pose);
        }
        (images, poses)
    }

    #[test]
    fn true_poses_beat_the_identity_and_wrong_poses_at_every_step() {
        let camera = CameraModel::donkeycar(160, 120);
        let (mut frames, truth) = drive(&camera, 32);
        // Wrong: 40 % too short and turning half as much, as an uncalibrated prior would.
        let wrong: Vec<Pose2> = truth
            .iter()
            .map(|p| Pose2::new(0.6 * p.x, 0.6 * p.y, 0.5 * p.heading))
            .collect();
        frames[20] = None;
        let sets = [
            PoseSet {
                name: "truth".into(),
                poses: truth.clone(),
            },
            PoseSet {
                name: "wrong".into(),
                poses: wrong,
            },
        ];
        let chassis = PixelMask::below_row(160, 120, 110);
        let check = check_views(&camera, &frames, Some(&chassis), &sets, &STEPS, 1.0, 0.05)
            .expect("a check");
        eprintln!("{}", check.table());
        assert_eq!(check.methods, ["identity", "truth", "wrong"]);
        for r in &check.rows {
            // Pairs touching the missing frame 20 are skipped, and only they.
            assert_eq!(r.pairs + r.skipped, 32 - r.k, "k = {}", r.k);
            assert_eq!(r.skipped, 2, "k = {}", r.k);
            assert!(
                r.mean[1].psnr_db > r.mean[0].psnr_db + 3.0,
                "{}",
                check.table()
            );
            assert!(r.mean[1].ssim > r.mean[2].ssim, "{}", check.table());
            assert!(r.beats_identity[1] > 0.9, "{:?}", r.beats_identity);
        }
        assert!(check.beats(1, &[0, 2]));
        assert!(!check.beats(2, &[0]));
        let strip = check.strip.as_ref().expect("a strip");
        // 4 rows of (t, truth, wrong, real, three differences), 4 px apart.
        assert_eq!((strip.width(), strip.height()), (7 * 164, 4 * 124));
        assert_eq!(check.strip_pairs.len(), 4);
        assert!(check.strip_pairs.iter().all(|&(k, _)| k == 5));
        assert!(check.csv().lines().count() == 1 + 3 * 3);
        // The chassis rows are never scored: dark blue in the difference tiles.
        assert_eq!(strip.get_pixel(4 * 164 + 5, 115).0, [0, 0, 80]);
    }

    #[test]
    fn bad_input_is_named() {
        let camera = CameraModel::donkeycar(160, 120);
        let frames = vec![Some(Arc::new(vec![0u8; 10]))];
        let set = PoseSet {
            name: "estimate".into(),
            poses: vec![Pose2::default()],
        };
        let e = check_views(
            &camera,
            &frames,
            None,
            std::slice::from_ref(&set),
            &STEPS,
            1.0,
            0.1,
        )
        .expect_err("a short frame");
        assert!(e.to_string().contains("frame 0 has 10 bytes"), "{e}");
        let frames = vec![Some(Arc::new(vec![0u8; 160 * 120 * 3])); 2];
        let e =
            check_views(&camera, &frames, None, &[set], &STEPS, 1.0, 0.1).expect_err("one pose");
        assert!(
            e.to_string()
                .contains("`estimate` has 1 poses for 2 frames"),
            "{e}"
        );
        let e = check_views(&camera, &frames, None, &[], &STEPS, 1.0, 0.1).expect_err("no sets");
        assert!(e.to_string().contains("at least one pose set"), "{e}");
    }
}
