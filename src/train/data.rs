//! Demonstrations as training samples: owns reading JetBot xy folders and our tubs into
//! frames cached at the network's input size, the label each frame gets, and the seeded
//! train/test split.
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
//! ```
//!
//! Only the human's steps (`user/mode = user`) of a tub are demonstrations; the autopilot's
//! are left out.

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::TrainError;
use crate::control::SteeringGains;
use crate::dataset::jetbot_xy::XyFolder;
use crate::dataset::tub::{DriveMode, TubReader, TubRecord};
use crate::policy::{ModelContract, OutputKind, Preprocessor};

/// How labels are made for one output kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelMap {
    pub output: OutputKind,
    pub speed_gain: f32,
    pub steering_gain: f32,
}

impl LabelMap {
    pub fn new(output: OutputKind, gains: &SteeringGains) -> Self {
        Self {
            output,
            speed_gain: gains.speed_gain,
            steering_gain: gains.steering_gain,
        }
    }

    /// `[speed, steering]` for wheel commands, inverting the `speed_steering` law (the
    /// derivative and integral terms are left out: a demonstration has no PID state).
    pub fn speed_steering(&self, left: f32, right: f32) -> [f32; 2] {
        let speed = if self.speed_gain > 1e-6 {
            ((left + right) / 2.0 / self.speed_gain).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let steering = if self.steering_gain > 1e-6 {
            (left - right) / 2.0 / self.steering_gain
        } else {
            0.0
        };
        [speed, steering]
    }

    /// The label of a tub record, or `None` when it carries nothing to learn from.
    pub fn for_record(&self, rec: &TubRecord) -> Option<[f32; 2]> {
        match self.output {
            OutputKind::Xy => rec.target.map(|(x, y)| [x, y]),
            OutputKind::SpeedSteering => {
                let (l, r) = rec.wheels.unwrap_or((
                    rec.user_throttle + rec.user_angle,
                    rec.user_throttle - rec.user_angle,
                ));
                Some(self.speed_steering(l, r))
            }
        }
    }

    /// Which label component a horizontal flip negates: JetBot's x, or the steering.
    pub fn mirrored_component(&self) -> usize {
        match self.output {
            OutputKind::Xy => 0,
            OutputKind::SpeedSteering => 1,
        }
    }
}

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
        }
    }
}

/// What one folder contributes before decoding: image paths with labels, which are pixel
/// positions (a JetBot xy folder: the label needs each image's size) or final values.
struct Listing {
    items: Vec<(PathBuf, [f32; 2])>,
    pixel_labels: bool,
}

/// Lists a tub (a folder with `manifest.json`) or a JetBot xy folder.
fn list(dir: &Path, map: &LabelMap, warnings: &mut Vec<String>) -> Result<Listing, TrainError> {
    let data_err = |reason: String| TrainError::Data {
        path: dir.display().to_string(),
        reason,
    };
    if dir.join("manifest.json").is_file() {
        let tub = TubReader::open(dir).map_err(|e| data_err(e.to_string()))?;
        warnings.extend(tub.warnings().iter().cloned());
        let mut out = Vec::new();
        let (mut autopilot, mut unlabelled) = (0usize, 0usize);
        for rec in tub.records() {
            if rec.mode != DriveMode::User {
                autopilot += 1;
                continue;
            }
            match map.for_record(rec) {
                Some(label) => out.push((tub.image_path(rec), label)),
                None => unlabelled += 1,
            }
        }
        if autopilot > 0 {
            warnings.push(format!(
                "{}: {autopilot} autopilot records left out (only user/mode = user is a demonstration)",
                dir.display()
            ));
        }
        if unlabelled > 0 {
            warnings.push(format!(
                "{}: {unlabelled} records without target/x, target/y left out",
                dir.display()
            ));
        }
        return Ok(Listing {
            items: out,
            pixel_labels: false,
        });
    }
    if map.output != OutputKind::Xy {
        // An xy folder has target points only; say so rather than fail on the listing.
        if !dir.is_dir() {
            return Err(data_err("not a folder".into()));
        }
        return Err(data_err(
            "a JetBot xy folder has target-point labels: train it with --head xy (speed_steering \
             needs a tub with wheels or user/angle, user/throttle)"
                .into(),
        ));
    }
    let folder = XyFolder::open(dir).map_err(|e| data_err(e.to_string()))?;
    warnings.extend(folder.warnings().iter().cloned());
    // The label needs the image size: JetBot's files are 224x224, but read it to be sure.
    let mut out = Vec::with_capacity(folder.samples().len());
    for s in folder.samples() {
        out.push((s.path.clone(), [s.px as f32, s.py as f32]));
    }
    Ok(Listing {
        items: out,
        pixel_labels: true,
    })
}

/// Reads every folder in `dirs` into frames resized for `contract`, decoding on `threads`
/// threads. Labels of xy folders are made from the pixel position and each image's size.
pub fn load(
    dirs: &[PathBuf],
    contract: &ModelContract,
    map: &LabelMap,
    threads: usize,
) -> Result<Dataset, TrainError> {
    let mut warnings = Vec::new();
    let mut jobs: Vec<(PathBuf, [f32; 2], bool)> = Vec::new();
    for dir in dirs {
        let listing = list(dir, map, &mut warnings)?;
        for (path, label) in listing.items {
            jobs.push((path, label, listing.pixel_labels));
        }
    }
    if jobs.is_empty() {
        return Err(nothing_in(dirs, "no demonstrations to learn from"));
    }
    let threads = threads.clamp(1, jobs.len());
    let chunk = jobs.len().div_ceil(threads);
    let results: Vec<Result<Vec<Sample>, TrainError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = jobs
            .chunks(chunk)
            .map(|part| scope.spawn(|| decode_part(part, contract)))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or_else(|_| {
                    Err(TrainError::Data {
                        path: "(decoder thread)".into(),
                        reason: "panicked".into(),
                    })
                })
            })
            .collect()
    });
    let mut samples = Vec::with_capacity(jobs.len());
    for r in results {
        samples.extend(r?);
    }
    Ok(Dataset {
        size: contract.input_size,
        samples,
        warnings,
    })
}

/// The error for folders that gave nothing to train on, naming them all.
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

fn decode_part(
    part: &[(PathBuf, [f32; 2], bool)],
    contract: &ModelContract,
) -> Result<Vec<Sample>, TrainError> {
    let mut pre = Preprocessor::new(contract);
    let mut out = Vec::with_capacity(part.len());
    for (path, label, pixel_label) in part {
        let data_err = |reason: String| TrainError::Data {
            path: path.display().to_string(),
            reason,
        };
        let (w, h, rgb) = crate::dataset::load_rgb(path).map_err(|e| data_err(e.to_string()))?;
        let label = if *pixel_label {
            let (x, y) = crate::dataset::jetbot_xy::label(label[0] as u32, label[1] as u32, w, h);
            [x, y]
        } else {
            *label
        };
        let pixels = pre
            .resize(w, h, &rgb)
            .map_err(|e| data_err(e.to_string()))?
            .to_vec();
        out.push(Sample { pixels, label });
    }
    Ok(out)
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

    fn map(output: OutputKind) -> LabelMap {
        LabelMap {
            output,
            speed_gain: 0.5,
            steering_gain: 0.25,
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
}
