//! Labelled frames from any data set folder: what both `train il` and `score` read.
//!
//! Owns the listing of a tub (a folder with `manifest.json`) or a JetBot xy folder into
//! image paths with their labels and capture times, and [`LabelMap`], the rule that turns
//! a recorded step into a label for one output kind:
//!
//! ```text
//! xy:              JetBot's target point: from the file name (xy folder) or target/x,y (tub)
//! speed_steering:  the steering law inverted on the wheels that were sent:
//!                  speed    = clamp(((left + right) / 2) / speed_gain, 0, 1)
//!                  steering = ((left - right) / 2) / steering_gain
//!                  (with `control.mixing = "car"`: `left + right`, `left - right`); a
//!                  DonkeyCar record without wheels: user/throttle and user/angle in their
//!                  place
//! ```
//!
//! Only the human's steps (`user/mode = user`) of a tub are demonstrations; the autopilot's
//! are left out. Listing opens no image: a file that cannot be decoded is found, and
//! reported by name, where the frames are read.

use std::path::{Path, PathBuf};

use super::jetbot_xy::{self, XyFolder};
use super::tub::{DriveMode, TubReader, TubRecord};
use super::{DatasetError, Result};
use crate::control::{Mixing, SteeringGains, WheelCommand};
use crate::policy::OutputKind;

/// How labels are made for one output kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelMap {
    pub output: OutputKind,
    pub speed_gain: f32,
    pub steering_gain: f32,
    /// How the recorded wheels were mixed from speed and steering.
    pub mixing: Mixing,
}

impl LabelMap {
    pub fn new(output: OutputKind, gains: &SteeringGains) -> Self {
        Self {
            output,
            speed_gain: gains.speed_gain,
            steering_gain: gains.steering_gain,
            mixing: gains.mixing,
        }
    }

    /// `[speed, steering]` for wheel commands, inverting the `speed_steering` law (the
    /// derivative and integral terms are left out: a demonstration has no PID state).
    pub fn speed_steering(&self, left: f32, right: f32) -> [f32; 2] {
        let (speed, steering) = self.mixing.unmix(WheelCommand::new(left, right));
        self.label_of_speed_steering(speed, steering)
    }

    /// `[speed, steering]` for the law's speed and steering before mixing (a DonkeyCar's
    /// throttle and angle): each divided by its gain, the speed clamped to 0..=1.
    fn label_of_speed_steering(&self, speed: f32, steering: f32) -> [f32; 2] {
        let speed = if self.speed_gain > 1e-6 {
            (speed / self.speed_gain).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let steering = if self.steering_gain > 1e-6 {
            steering / self.steering_gain
        } else {
            0.0
        };
        [speed, steering]
    }

    /// The label of a tub record, or `None` when it carries nothing to learn from.
    pub fn for_record(&self, rec: &TubRecord) -> Option<[f32; 2]> {
        match self.output {
            OutputKind::Xy => rec.target.map(|(x, y)| [x, y]),
            OutputKind::SpeedSteering => Some(match rec.wheels {
                Some((l, r)) => self.speed_steering(l, r),
                None => self.label_of_speed_steering(rec.user_throttle, rec.user_angle),
            }),
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

/// A frame's label as the folder stores it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Label {
    /// A pixel of the image (a JetBot xy file name): the value needs the image's size.
    Pixel(u32, u32),
    /// The label itself.
    Value([f32; 2]),
}

impl Label {
    /// The label for an image of `width` x `height`.
    pub fn value(self, width: u32, height: u32) -> [f32; 2] {
        match self {
            Self::Pixel(px, py) => {
                let (x, y) = jetbot_xy::label(px, py, width, height);
                [x, y]
            }
            Self::Value(v) => v,
        }
    }
}

/// One labelled image, not yet opened.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelledFrame {
    pub path: PathBuf,
    pub label: Label,
    /// When it was captured, seconds since the Unix epoch: a tub record's timestamp, the
    /// uuid1 in a JetBot file name; `None` when the folder does not say.
    pub time_s: Option<f64>,
}

/// A folder's labelled frames and what was left out, and why.
#[derive(Debug, Clone, Default)]
pub struct Listing {
    pub frames: Vec<LabelledFrame>,
    pub warnings: Vec<String>,
}

/// Lists a tub or a JetBot xy folder for `map`'s output kind.
pub fn list(dir: &Path, map: &LabelMap) -> Result<Listing> {
    let format_err = |reason: String| DatasetError::Format {
        path: dir.display().to_string(),
        reason,
    };
    let mut out = Listing::default();
    if dir.join("manifest.json").is_file() {
        let tub = TubReader::open(dir)?;
        out.warnings.extend(tub.warnings().iter().cloned());
        let (mut autopilot, mut unlabelled) = (0usize, 0usize);
        for rec in tub.records() {
            if rec.mode != DriveMode::User {
                autopilot += 1;
                continue;
            }
            match map.for_record(rec) {
                Some(label) => out.frames.push(LabelledFrame {
                    path: tub.image_path(rec),
                    label: Label::Value(label),
                    time_s: Some(rec.timestamp_ms as f64 / 1000.0),
                }),
                None => unlabelled += 1,
            }
        }
        if autopilot > 0 {
            out.warnings.push(format!(
                "{}: {autopilot} autopilot records left out (only user/mode = user is a demonstration)",
                dir.display()
            ));
        }
        if unlabelled > 0 {
            out.warnings.push(format!(
                "{}: {unlabelled} records without target/x, target/y left out",
                dir.display()
            ));
        }
        return Ok(out);
    }
    if !dir.is_dir() {
        return Err(format_err("not a folder".into()));
    }
    if map.output != OutputKind::Xy {
        // An xy folder has target points only; say so rather than fail on the listing.
        return Err(format_err(
            "a JetBot xy folder has target-point labels: use an xy model (train with --head xy); \
             speed_steering needs a tub with wheels or user/angle, user/throttle"
                .into(),
        ));
    }
    let subfolders = data_subfolders(dir)?;
    if !subfolders.is_empty() {
        // A folder of data folders (e.g. one per recording session or camera tilt): one
        // level down, in name order.
        for sub in subfolders {
            let part = list(&sub, map)?;
            out.frames.extend(part.frames);
            out.warnings.extend(part.warnings);
        }
        return Ok(out);
    }
    let folder = XyFolder::open(dir)?;
    out.warnings.extend(folder.warnings().iter().cloned());
    for s in folder.samples() {
        let name = s.path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        out.frames.push(LabelledFrame {
            path: s.path.clone(),
            label: Label::Pixel(s.px, s.py),
            time_s: jetbot_xy::capture_time_s(name),
        });
    }
    Ok(out)
}

/// The subfolders of `dir` when it holds no image files of its own, else none.
fn data_subfolders(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut subs = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(super::io_err(dir))? {
        let path = entry.map_err(super::io_err(dir))?.path();
        if path.is_dir() {
            subs.push(path);
        } else if path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("jpg") || e.eq_ignore_ascii_case("jpeg"))
        {
            return Ok(Vec::new());
        }
    }
    subs.sort();
    Ok(subs)
}

/// Splits frames by capture time: the earliest `1 - test_fraction` of them train, the
/// latest `test_fraction` test, so near-duplicate neighbours never straddle the split.
/// Frames without a time are an error naming the first.
pub fn split_by_time(
    frames: Vec<LabelledFrame>,
    test_fraction: f32,
) -> Result<(Vec<LabelledFrame>, Vec<LabelledFrame>)> {
    if let Some(f) = frames.iter().find(|f| f.time_s.is_none()) {
        return Err(DatasetError::Format {
            path: f.path.display().to_string(),
            reason: "no capture time (a tub record's timestamp or a uuid1 file name) to split by"
                .into(),
        });
    }
    let mut frames = frames;
    frames.sort_by(|a, b| {
        a.time_s
            .partial_cmp(&b.time_s)
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let n_test = ((frames.len() as f32) * test_fraction.clamp(0.0, 1.0)).round() as usize;
    let test = frames.split_off(frames.len() - n_test.min(frames.len()));
    Ok((frames, test))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t: Option<f64>) -> LabelledFrame {
        LabelledFrame {
            path: PathBuf::from(format!("{t:?}.jpg")),
            label: Label::Value([0.0, 0.0]),
            time_s: t,
        }
    }

    #[test]
    fn pixel_labels_need_the_image_size() {
        // JetBot: (px - 112) / 112 at 224x224; (160 - 112) / 112 = 0.428_571.
        let v = Label::Pixel(160, 56).value(224, 224);
        assert!(
            (v[0] - 0.428_571).abs() < 1e-5 && (v[1] + 0.5).abs() < 1e-6,
            "{v:?}"
        );
        assert_eq!(Label::Value([0.1, 0.2]).value(224, 224), [0.1, 0.2]);
    }

    #[test]
    fn speed_steering_labels_invert_the_mixing_the_wheels_went_through() {
        let gains = SteeringGains {
            speed_gain: 0.5,
            steering_gain: 0.25,
            ..SteeringGains::default()
        };
        let jetbot = LabelMap::new(OutputKind::SpeedSteering, &gains);
        // (0.4 + 0.2) / 2 / 0.5 = 0.6; (0.4 - 0.2) / 2 / 0.25 = 0.4.
        let [s, t] = jetbot.speed_steering(0.4, 0.2);
        assert!((s - 0.6).abs() < 1e-6 && (t - 0.4).abs() < 1e-6, "{s} {t}");
        let car = LabelMap::new(
            OutputKind::SpeedSteering,
            &SteeringGains {
                mixing: Mixing::Car,
                ..gains
            },
        );
        // Car channels (0.3, 0.1): throttle 0.4, angle 0.2 -> 0.4 / 0.5 = 0.8, 0.2 / 0.25 = 0.8.
        let [s, t] = car.speed_steering(0.3, 0.1);
        assert!((s - 0.8).abs() < 1e-6 && (t - 0.8).abs() < 1e-6, "{s} {t}");
        // A DonkeyCar record (no wheels): its throttle and angle, whatever the mixing; full
        // lock at throttle 0.25 is not clipped.
        let rec = TubRecord::new(0, -1.0, 0.25, DriveMode::User);
        for map in [jetbot, car] {
            let [s, t] = map.for_record(&rec).unwrap();
            assert!((s - 0.5).abs() < 1e-6 && (t + 4.0).abs() < 1e-6, "{s} {t}");
        }
    }

    #[test]
    fn the_split_by_time_keeps_the_latest_frames_for_testing() {
        let frames = [5.0, 1.0, 3.0, 2.0, 4.0].map(|t| frame(Some(t))).to_vec();
        let (train, test) = split_by_time(frames, 0.4).unwrap();
        let times = |v: &[LabelledFrame]| v.iter().map(|f| f.time_s.unwrap()).collect::<Vec<_>>();
        assert_eq!(times(&train), [1.0, 2.0, 3.0]);
        assert_eq!(times(&test), [4.0, 5.0]);
        let err = split_by_time(vec![frame(Some(1.0)), frame(None)], 0.5).unwrap_err();
        assert!(err.to_string().contains("no capture time"), "{err}");
    }
}
