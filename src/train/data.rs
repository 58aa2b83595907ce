//! Demonstrations as training samples: owns decoding the labelled frames of JetBot xy
//! folders and our tubs (listed by [`crate::dataset::labelled`]) into frames cached at the
//! network's input size, and the seeded train/test split.
//!
//! Frames are decoded and resized once, in parallel, by the daemon's own [`Preprocessor`]
//! (same resize, same filter), so the trainer sees the pixels `jetpilot run` will feed the
//! network. Labels, per the model contract's output:
//!
//! ```text
//! xy:              JetBot's target point: from the file name (xy folder) or target/x,y (tub)
//! speed_steering:  the steering law inverted on the wheels that were sent:
//!                  speed    = clamp(((left + right) / 2) / speed_gain, 0, 1)
//!                  steering = ((left - right) / 2) / steering_gain
//!                  (`control.mixing = "car"`: `left + right` and `left - right`;
//!                  `crate::dataset::labelled::LabelMap`)
//! ```
//!
//! Only the human's steps (`user/mode = user`) of a tub are demonstrations; the autopilot's
//! are left out.

use std::path::PathBuf;

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::TrainError;
use crate::dataset::labelled::{self, LabelledFrame};
use crate::policy::{ModelContract, Preprocessor};

pub use crate::dataset::labelled::LabelMap;

/// One cached frame and its label.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// RGB8, `size * size * 3`, rows top to bottom.
    pub pixels: Vec<u8>,
    pub label: [f32; 2],
}

/// Frames at the network's input size with their labels.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub size: u32,
    pub samples: Vec<Sample>,
    /// Files or records left out, and why.
    pub warnings: Vec<String>,
    /// Images listed but not read (empty, truncated, missing): each has a warning.
    pub skipped: usize,
    /// `samples[mixed_from..]` are extra frames mixed into training (`train il --mix`, see
    /// [`Dataset::mix_in`]); `samples.len()` when there are none.
    pub mixed_from: usize,
    /// Frames left out as the latest by capture time (`load`'s `leave_latest`).
    pub left_out: usize,
}

impl Dataset {
    /// `n` frames of random pixels at `size` with random (speed, steering) labels, seeded:
    /// for benchmarks and tests that need a dataset, not a task.
    pub fn random(size: u32, n: usize, seed: u64) -> Self {
        use rand::Rng;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let px = (3 * size * size) as usize;
        Self {
            size,
            samples: (0..n)
                .map(|_| Sample {
                    pixels: (0..px).map(|_| rng.random()).collect(),
                    label: [rng.random_range(0.0..1.0), rng.random_range(-1.0..1.0)],
                })
                .collect(),
            warnings: Vec::new(),
            skipped: 0,
            mixed_from: n,
            left_out: 0,
        }
    }

    /// The frames that are this data set's own (split into train and test): all but the
    /// mixed-in ones.
    pub fn own(&self) -> usize {
        self.mixed_from.min(self.samples.len())
    }

    /// Appends `extra`'s frames (all of them) as mixed-in ones: they are never held out for the test loss
    /// (the best epoch is picked on this data set's own frames), and each epoch draws them
    /// anew as a share of its images (`train il --mix-share`). Their warnings and skipped
    /// count join this set's. Both must be decoded at the same input size.
    pub fn mix_in(&mut self, extra: Dataset) -> Result<(), TrainError> {
        if extra.size != self.size {
            return Err(TrainError::Data {
                path: "--mix".into(),
                reason: format!(
                    "mixed-in frames are {0}x{0}, the demonstrations {1}x{1}",
                    extra.size, self.size
                ),
            });
        }
        self.mixed_from = self.own();
        self.samples.extend(extra.samples);
        self.warnings.extend(extra.warnings);
        self.skipped += extra.skipped;
        Ok(())
    }
}

/// Reads every folder in `dirs` into frames resized for `contract`, decoding on `threads`
/// threads. Labels of xy folders are made from the pixel position and each image's size.
/// A file that cannot be read or decoded (a zero-byte or truncated JPEG, a missing image)
/// is skipped with a warning naming it; folders that give no usable frame are an error.
/// `leave_latest`: the latest share of all the folders' frames by capture time is left
/// out (the frames `score --split-by-time` scores); frames without a time are then an
/// error naming the first.
pub fn load(
    dirs: &[PathBuf],
    contract: &ModelContract,
    map: &LabelMap,
    threads: usize,
    leave_latest: Option<f32>,
) -> Result<Dataset, TrainError> {
    let mut warnings = Vec::new();
    let mut jobs: Vec<LabelledFrame> = Vec::new();
    let mut left_out = 0;
    for dir in dirs {
        let listing = labelled::list(dir, map).map_err(|e| TrainError::Data {
            path: dir.display().to_string(),
            reason: e.to_string(),
        })?;
        warnings.extend(listing.warnings);
        jobs.extend(listing.frames);
    }
    if let Some(share) = leave_latest {
        let (earliest, latest) =
            labelled::split_by_time(jobs, share).map_err(|e| nothing_in(dirs, &e.to_string()))?;
        left_out = latest.len();
        jobs = earliest;
    }
    if jobs.is_empty() {
        return Err(nothing_in(dirs, "no demonstrations to learn from"));
    }
    let threads = threads.clamp(1, jobs.len());
    let chunk = jobs.len().div_ceil(threads);
    let results: Vec<Option<Vec<Decoded>>> = std::thread::scope(|scope| {
        let handles: Vec<_> = jobs
            .chunks(chunk)
            .map(|part| scope.spawn(|| decode_part(part, contract)))
            .collect();
        handles.into_iter().map(|h| h.join().ok()).collect()
    });
    let mut samples = Vec::with_capacity(jobs.len());
    let mut skipped = 0usize;
    for r in results {
        let Some(part) = r else {
            return Err(TrainError::Data {
                path: "(decoder thread)".into(),
                reason: "panicked".into(),
            });
        };
        for d in part {
            match d {
                Ok(s) => samples.push(s),
                Err(w) => {
                    skipped += 1;
                    warnings.push(w);
                }
            }
        }
    }
    if samples.is_empty() {
        let unread: Vec<&str> = warnings
            .iter()
            .filter(|w| w.contains(": skipped, "))
            .take(3)
            .map(String::as_str)
            .collect();
        return Err(nothing_in(
            dirs,
            &format!(
                "none of the {skipped} images could be read ({}{})",
                unread.join("; "),
                if skipped > unread.len() { "; ..." } else { "" }
            ),
        ));
    }
    if skipped > 0 {
        warnings.push(format!(
            "{skipped} of {} images skipped: they cannot be read or decoded",
            skipped + samples.len()
        ));
    }
    Ok(Dataset {
        size: contract.input_size,
        mixed_from: samples.len(),
        left_out,
        samples,
        warnings,
        skipped,
    })
}

/// The error for folders that gave nothing to train on (or frames that cannot be split by
/// time), naming them all.
pub fn nothing_in(dirs: &[PathBuf], reason: &str) -> TrainError {
    TrainError::Data {
        path: dirs
            .iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
        reason: reason.into(),
    }
}

/// A decoded sample, or the warning that says why a file was skipped.
type Decoded = Result<Sample, String>;

fn decode_part(part: &[LabelledFrame], contract: &ModelContract) -> Vec<Decoded> {
    let mut pre = Preprocessor::new(contract);
    part.iter()
        .map(|f| {
            let skipped = |reason: String| format!("{}: skipped, {reason}", f.path.display());
            let (w, h, rgb) = crate::dataset::load_rgb(&f.path)
                .map_err(|e| skipped(crate::dataset::short_reason(&e)))?;
            let pixels = pre
                .resize(w, h, &rgb)
                .map_err(|e| skipped(e.to_string()))?
                .to_vec();
            Ok(Sample {
                pixels,
                label: f.label.value(w, h),
            })
        })
        .collect()
}

/// A seeded split of `0..n` into (train, test) indices; `test_fraction` of them (at least
/// one when `n >= 2` and the fraction is positive) go to the test set.
pub fn split(n: usize, test_fraction: f32, seed: u64) -> (Vec<usize>, Vec<usize>) {
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    let mut n_test = (n as f32 * test_fraction.clamp(0.0, 1.0)).round() as usize;
    if test_fraction > 0.0 && n >= 2 {
        n_test = n_test.clamp(1, n - 1);
    }
    let train = idx.split_off(n_test);
    (train, idx)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::tub::{DriveMode, TubRecord};
    use crate::policy::OutputKind;

    #[test]
    fn mixed_in_frames_follow_the_own_ones_and_keep_their_count() {
        let mut d = Dataset::random(8, 5, 1);
        assert_eq!((d.own(), d.samples.len()), (5, 5));
        let extra = Dataset::random(8, 3, 2);
        let first_extra = extra.samples[0].clone();
        d.mix_in(extra).unwrap();
        assert_eq!((d.own(), d.samples.len()), (5, 8));
        assert_eq!(d.samples[5], first_extra);
        // A second folder adds to the mixed-in frames; the own ones stay 5.
        d.mix_in(Dataset::random(8, 2, 3)).unwrap();
        assert_eq!((d.own(), d.samples.len()), (5, 10));
        let err = d.mix_in(Dataset::random(16, 2, 4)).unwrap_err().to_string();
        assert!(err.contains("16x16") && err.contains("8x8"), "{err}");
        assert_eq!(d.samples.len(), 10, "nothing added on an error");
    }

    fn map(output: OutputKind) -> LabelMap {
        LabelMap {
            output,
            speed_gain: 0.5,
            steering_gain: 0.25,
            mixing: crate::control::Mixing::Differential,
        }
    }

    #[test]
    fn speed_steering_labels_invert_the_law() {
        // left 0.6, right 0.4: throttle 0.5 / 0.5 = 1.0; angle 0.1 / 0.25 = 0.4.
        let l = map(OutputKind::SpeedSteering).speed_steering(0.6, 0.4);
        assert!(
            (l[0] - 1.0).abs() < 1e-6 && (l[1] - 0.4).abs() < 1e-6,
            "{l:?}"
        );
        // Faster than speed_gain allows: clamped to 1; reversing: 0.
        assert_eq!(
            map(OutputKind::SpeedSteering).speed_steering(0.9, 0.9)[0],
            1.0
        );
        assert_eq!(
            map(OutputKind::SpeedSteering).speed_steering(-0.2, -0.2)[0],
            0.0
        );
        // And the law maps the label back to the same wheels:
        // speed = 0.5 * 0.8 = 0.4, steering = 0.25 * -0.2 = -0.05 -> (0.35, 0.45).
        let l = map(OutputKind::SpeedSteering).speed_steering(0.35, 0.45);
        assert!(
            (l[0] - 0.8).abs() < 1e-6 && (l[1] + 0.2).abs() < 1e-6,
            "{l:?}"
        );
    }

    #[test]
    fn record_labels_per_output_kind() {
        let mut rec = TubRecord::new(0, 0.1, 0.5, DriveMode::User);
        assert_eq!(map(OutputKind::Xy).for_record(&rec), None);
        rec.target = Some((0.3, -0.2));
        assert_eq!(map(OutputKind::Xy).for_record(&rec), Some([0.3, -0.2]));
        // No wheels: user/angle and user/throttle give (0.6, 0.4).
        let l = map(OutputKind::SpeedSteering).for_record(&rec).unwrap();
        assert!(
            (l[0] - 1.0).abs() < 1e-6 && (l[1] - 0.4).abs() < 1e-6,
            "{l:?}"
        );
        rec.wheels = Some((0.35, 0.45));
        let l = map(OutputKind::SpeedSteering).for_record(&rec).unwrap();
        assert!(
            (l[0] - 0.8).abs() < 1e-6 && (l[1] + 0.2).abs() < 1e-6,
            "{l:?}"
        );
    }

    #[test]
    fn split_is_seeded_disjoint_and_complete() {
        let (a, b) = split(100, 0.1, 7);
        assert_eq!((a.len(), b.len()), (90, 10));
        let mut all: Vec<usize> = a.iter().chain(&b).copied().collect();
        all.sort();
        assert_eq!(all, (0..100).collect::<Vec<_>>());
        assert_eq!(split(100, 0.1, 7), (a, b));
        assert_ne!(split(100, 0.1, 8).1, split(100, 0.1, 7).1);
        assert_eq!(split(5, 0.1, 0).1.len(), 1, "at least one test sample");
        assert_eq!(split(5, 0.0, 0).1.len(), 0);
    }

    #[test]
    fn leave_latest_keeps_the_earliest_frames_by_capture_time() {
        use crate::dataset::{encode_jpeg, jetbot_xy};
        let dir = tempfile::tempdir().unwrap();
        let mut jpeg = Vec::new();
        encode_jpeg(&vec![128u8; 32 * 32 * 3], 32, 32, &mut jpeg).unwrap();
        // Four frames a second apart (uuid1 ticks are 100 ns), written latest first, their
        // x pixel 4, 8, 12, 16 in capture order: the latest quarter is the x = 16 frame.
        for (k, px) in [(3u64, 16u32), (2, 12), (1, 8), (0, 4)] {
            let name = jetbot_xy::uuid1(16_000_000_000_000_000 + k * 10_000_000, 7, [2; 6]);
            jetbot_xy::write_sample(dir.path(), px, 16, &jpeg, &name).unwrap();
        }
        let contract = ModelContract {
            input_size: 16,
            ..ModelContract::default()
        };
        let dirs = [dir.path().to_path_buf()];
        let all = load(&dirs, &contract, &map(OutputKind::Xy), 2, None).unwrap();
        assert_eq!(all.samples.len(), 4);
        let early = load(&dirs, &contract, &map(OutputKind::Xy), 2, Some(0.25)).unwrap();
        // (px - 16) / 16 for the 32-wide frames: -0.75, -0.5, -0.25 stay, 0 is left out.
        let mut xs: Vec<f32> = early.samples.iter().map(|s| s.label[0]).collect();
        xs.sort_by(f32::total_cmp);
        assert_eq!(xs, [-0.75, -0.5, -0.25]);
        assert_eq!((all.left_out, early.left_out), (0, 1));

        // A frame without a capture time cannot be placed in time: an error naming it.
        jetbot_xy::write_sample(dir.path(), 4, 4, &jpeg, "no-time").unwrap();
        let err = load(&dirs, &contract, &map(OutputKind::Xy), 2, Some(0.25))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("no-time") && err.contains("no capture time"),
            "{err}"
        );
    }

    #[test]
    fn unreadable_images_are_skipped_by_name_and_a_folder_of_them_is_an_error() {
        use crate::dataset::{encode_jpeg, jetbot_xy};
        let dir = tempfile::tempdir().unwrap();
        let mut jpeg = Vec::new();
        encode_jpeg(&vec![128u8; 32 * 32 * 3], 32, 32, &mut jpeg).unwrap();
        jetbot_xy::write_sample(dir.path(), 16, 8, &jpeg, "a").unwrap();
        jetbot_xy::write_sample(dir.path(), 8, 16, &jpeg, "b").unwrap();
        std::fs::write(dir.path().join("xy_010_010_empty.jpg"), b"").unwrap();
        std::fs::write(
            dir.path().join("xy_010_010_cut.jpg"),
            &jpeg[..jpeg.len() / 2],
        )
        .unwrap();
        let contract = ModelContract {
            input_size: 16,
            ..ModelContract::default()
        };
        let dirs = [dir.path().to_path_buf()];
        let data = load(&dirs, &contract, &map(OutputKind::Xy), 2, None).unwrap();
        assert_eq!((data.samples.len(), data.skipped), (2, 2));
        let text = data.warnings.join("\n");
        assert!(
            text.contains("xy_010_010_empty.jpg: skipped, the file is empty"),
            "{text}"
        );
        assert!(
            text.contains("xy_010_010_cut.jpg: skipped, truncated JPEG"),
            "{text}"
        );
        assert!(text.contains("2 of 4 images skipped"), "{text}");
        // (16 - 16) / 16 = 0 and (8 - 16) / 16 = -0.5 for the 32x32 frame "a".
        assert!(data.samples.iter().any(|s| s.label == [0.0, -0.5]));

        for name in ["xy_016_008_a.jpg", "xy_008_016_b.jpg"] {
            std::fs::remove_file(dir.path().join(name)).unwrap();
        }
        let err = load(&dirs, &contract, &map(OutputKind::Xy), 2, None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("none of the 2 images could be read") && err.contains("xy_010_010_"),
            "{err}"
        );
    }
}
