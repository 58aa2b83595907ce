//! Writing the estimate: a new tub with the poses (the original is only read), the
//! per-frame CSV, and a top-down trace PNG.
//!
//! The new tub is written into `<out>.partial` and renamed to `<out>` when complete, so an
//! interrupted run leaves the original tub as it was and no half-written tub under the
//! name asked for. With it goes `replay.toml`, the config that makes the new tub a
//! replayed-frame simulator (its path as the road), so a recording becomes one in one command.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use super::super::setup::{FrameMode, RoadSource, SimVehicle};
use super::super::{Pose2, SimError};
use super::ackermann::CarParams;
use super::{Estimate, FramePose};
use crate::config::{Config, ControlConfig};
use crate::control::Mixing;
use crate::dataset::tub::{TubInputs, TubReader, TubWriter};

fn file_err(path: &Path, reason: impl std::fmt::Display) -> SimError {
    SimError::File {
        path: path.display().to_string(),
        reason: reason.to_string(),
    }
}

/// Where a partial output is written before it is renamed.
pub fn partial_dir(out: &Path) -> PathBuf {
    let mut name = out.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    out.with_file_name(name)
}

/// An error naming `out` if it exists: nothing is overwritten (checked before the
/// estimate is run, and again before writing).
pub fn refuse_existing(out: &Path) -> Result<(), SimError> {
    if out.exists() {
        return Err(file_err(
            out,
            "exists already: give another --out (nothing is overwritten)",
        ));
    }
    Ok(())
}

/// What of a record besides its frame and commands goes into the new tub.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Labels {
    /// Everything the record has (rewards, target labels), with the estimated pose.
    Keep,
    /// Only what `jetpilot record` on a robot writes, plus the estimated pose: for a
    /// simulated tub whose rewards and target labels come from the true poses (`--check`).
    RobotOnly,
}

/// The name of the replay config written into the new tub's folder.
pub const REPLAY_CONFIG: &str = "replay.toml";

/// The two commands that drive the replay whose config is at `config`: `eval`, then
/// `train ddpg` against it.
pub fn replay_commands(config: &Path) -> [String; 2] {
    let c = config.display();
    [
        format!("jetpilot eval --config {c} --model MODEL.onnx --seconds 120"),
        format!("jetpilot train ddpg --sim {c} --init MODEL.onnx"),
    ]
}

/// The text of `replay.toml`: `base` (the config the poses were estimated with, its paths
/// made absolute) with `sim.frames = "replay"`, `sim.recording = "."` (the folder the file
/// is in) and `sim.road = "path"`, random layouts off (they are rendered only), under a
/// header that says how to use it. `made_from` names `base` in the header.
///
/// With `car` (a car-like recording: the calibrated [`CarParams`] in the tub's own angle
/// convention) the replay's vehicle is that car (`sim.vehicle = "car"`, `[sim.car]`), and
/// the law hands it the model's throttle and angle as DonkeyCar's pilot does:
/// `control.mixing = "car"`, speed and steering gains 1, no derivative, integral or bias,
/// and no motor trims.
pub fn replay_config(
    base: &Config,
    made_from: &str,
    car: Option<CarParams>,
) -> Result<String, SimError> {
    let mut cfg = base.clone();
    cfg.sim.frames = FrameMode::Replay;
    cfg.sim.recording = Some(PathBuf::from("."));
    cfg.sim.road = RoadSource::Path;
    cfg.sim.layouts.enabled = false;
    let mut car_note = String::new();
    if let Some(car) = car {
        cfg.sim.vehicle = SimVehicle::Car;
        cfg.sim.car = car;
        cfg.control = ControlConfig {
            speed_gain: 1.0,
            steering_gain: 1.0,
            steering_kd: 0.0,
            steering_bias: 0.0,
            steering_ki: 0.0,
            mixing: Mixing::Car,
            ..cfg.control
        };
        // The channels carry throttle and angle: no wheel's trim between them.
        for t in [&mut cfg.motors.left, &mut cfg.motors.right] {
            t.alpha = 1.0;
            t.beta = 0.0;
        }
        car_note = "# The car: [sim.car] is what the frames say this car does (calibrated by `poses`, in\n\
                    # the tub's own angle convention), and [control] passes a speed_steering model's\n\
                    # (throttle, angle) to it unchanged, as DonkeyCar's pilot does.\n"
            .to_string();
    }
    let body = cfg
        .to_toml()
        .map_err(|e| SimError::Invalid(format!("writing {REPLAY_CONFIG}: {e}")))?;
    let [eval, ddpg] = replay_commands(Path::new(REPLAY_CONFIG));
    Ok(format!(
        "# A replayed-frame simulator of the recording in this folder, written by `jetpilot poses`\n\
         # from {made_from}: the recorded frames re-projected around their estimated poses, with\n\
         # the recorded path as the road (docs/guides/training.md, \"Replay a real recording\"). From this folder:\n\
         #   {eval}\n\
         #   {ddpg}\n\
         # [sim.path] lanes: 1 when the path runs in a lane between two lines, 2 on the JetBot\n\
         # mat (the path is the right lane of a two-lane road). Paths are absolute, but for\n\
         # sim.recording: \".\" is this folder, so the folder can be moved as a whole.\n{car_note}\n{body}"
    ))
}

/// Writes every live record of `tub` that has a pose in `estimate`, with that pose, to a
/// new tub at `out` (which must not exist), with `files` (name, text) beside the records,
/// all or nothing. Returns the records written.
pub fn write_tub(
    tub: &TubReader,
    estimate: &Estimate,
    out: &Path,
    created_at: f64,
    labels: Labels,
    files: &[(&str, String)],
) -> Result<usize, SimError> {
    refuse_existing(out)?;
    let partial = partial_dir(out);
    if partial.exists() {
        // A previous interrupted run's output: never read as a tub, safe to replace.
        std::fs::remove_dir_all(&partial).map_err(|e| file_err(&partial, e))?;
    }
    let poses: HashMap<u64, &FramePose> = estimate.poses.iter().map(|p| (p.index, p)).collect();
    let mut inputs = TubInputs {
        pose: true,
        ..TubInputs::default()
    };
    for r in tub.records() {
        inputs.pilot |= r.pilot_angle.is_some();
        inputs.wheels |= r.wheels.is_some();
        inputs.reward |= labels == Labels::Keep && r.reward.is_some();
        inputs.target |= labels == Labels::Keep && r.target.is_some();
    }
    let mut w =
        TubWriter::create(&partial, &inputs, created_at).map_err(|e| file_err(&partial, e))?;
    let mut n = 0;
    for rec in tub.records() {
        let Some(p) = poses.get(&rec.index) else {
            continue;
        };
        let path = tub.image_path(rec);
        let Ok(jpeg) = std::fs::read(&path) else {
            continue; // reported by the estimate already
        };
        let mut copy = rec.clone();
        copy.pose = Some((p.pose.x, p.pose.y, p.pose.heading));
        if labels == Labels::RobotOnly {
            copy.reward = None;
            copy.target = None;
        }
        w.append(&copy, &jpeg).map_err(|e| file_err(&partial, e))?;
        n += 1;
    }
    w.flush_and_sync().map_err(|e| file_err(&partial, e))?;
    drop(w);
    for (name, text) in files {
        let path = partial.join(name);
        let mut f = std::fs::File::create(&path).map_err(|e| file_err(&path, e))?;
        f.write_all(text.as_bytes())
            .and_then(|()| f.sync_all())
            .map_err(|e| file_err(&path, e))?;
    }
    std::fs::rename(&partial, out).map_err(|e| file_err(out, e))?;
    Ok(n)
}

/// `index,time_s,x,y,heading,confidence,source`, one line a frame.
pub fn write_csv(estimate: &Estimate, path: &Path) -> Result<(), SimError> {
    let mut text = String::from("index,time_s,x,y,heading,confidence,source\n");
    for p in &estimate.poses {
        text.push_str(&format!(
            "{},{:.3},{:.5},{:.5},{:.5},{:.3},{}\n",
            p.index,
            p.time_s,
            p.pose.x,
            p.pose.y,
            p.pose.heading,
            p.confidence,
            p.source.as_str()
        ));
    }
    let mut f = std::fs::File::create(path).map_err(|e| file_err(path, e))?;
    f.write_all(text.as_bytes()).map_err(|e| file_err(path, e))
}

/// A top-down trace, north up: the estimate in green (red where a frame fell back to the
/// wheels), the truth in grey when given, start marked by a blue dot.
pub fn trace_png(
    estimate: &Estimate,
    truth: Option<&[Pose2]>,
    path: &Path,
) -> Result<(), SimError> {
    const SIZE: u32 = 640;
    const MARGIN: f32 = 30.0;
    let mut pts: Vec<(f32, f32)> = estimate
        .poses
        .iter()
        .map(|p| (p.pose.x, p.pose.y))
        .collect();
    if let Some(t) = truth {
        pts.extend(t.iter().map(|p| (p.x, p.y)));
    }
    let (mut x0, mut y0, mut x1, mut y1) = (f32::MAX, f32::MAX, f32::MIN, f32::MIN);
    for &(x, y) in pts.iter().filter(|(x, y)| x.is_finite() && y.is_finite()) {
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 > x1 {
        (x0, y0, x1, y1) = (0.0, 0.0, 1.0, 1.0);
    }
    let span = (x1 - x0).max(y1 - y0).max(0.1);
    let scale = (SIZE as f32 - 2.0 * MARGIN) / span;
    let to_px = |x: f32, y: f32| {
        (
            MARGIN + (x - x0) * scale,
            SIZE as f32 - MARGIN - (y - y0) * scale,
        )
    };
    let mut img = image::RgbImage::from_pixel(SIZE, SIZE, image::Rgb([250, 250, 250]));
    // A 10 cm grid.
    let step = 0.1 * scale;
    if step >= 4.0 {
        let mut gx = MARGIN;
        while gx < SIZE as f32 {
            for y in 0..SIZE {
                img.put_pixel(gx as u32, y, image::Rgb([228, 228, 228]));
                img.put_pixel(
                    y,
                    (SIZE as f32 - gx) as u32 % SIZE,
                    image::Rgb([228, 228, 228]),
                );
            }
            gx += step;
        }
    }
    let mut line = |a: (f32, f32), b: (f32, f32), c: [u8; 3], width: i32| {
        let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as i32).max(1);
        for i in 0..=n {
            let t = i as f32 / n as f32;
            let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
            for dy in -width / 2..=width / 2 {
                for dx in -width / 2..=width / 2 {
                    let (px, py) = (x as i32 + dx, y as i32 + dy);
                    if (0..SIZE as i32).contains(&px) && (0..SIZE as i32).contains(&py) {
                        img.put_pixel(px as u32, py as u32, image::Rgb(c));
                    }
                }
            }
        }
    };
    if let Some(t) = truth {
        for w in t.windows(2) {
            line(
                to_px(w[0].x, w[0].y),
                to_px(w[1].x, w[1].y),
                [150, 150, 150],
                3,
            );
        }
    }
    for w in estimate.poses.windows(2) {
        let colour = if w[1].source == super::fuse::Source::Fused {
            [20, 160, 60]
        } else {
            [220, 40, 40]
        };
        line(
            to_px(w[0].pose.x, w[0].pose.y),
            to_px(w[1].pose.x, w[1].pose.y),
            colour,
            1,
        );
    }
    if let Some(p) = estimate.poses.first() {
        let c = to_px(p.pose.x, p.pose.y);
        line((c.0 - 4.0, c.1), (c.0 + 4.0, c.1), [40, 80, 220], 7);
    }
    img.save(path).map_err(|e| file_err(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cars_replay_drives_its_calibrated_car_with_donkeycars_commands() {
        let car = CarParams {
            curvature_per_unit: 2.6,
            ..CarParams::default()
        };
        let mut trimmed = Config::default();
        trimmed.motors.right.alpha = 0.9;
        let text = replay_config(&trimmed, "a test", Some(car)).unwrap();
        let cfg = Config::parse(&text, "replay.toml").unwrap();
        assert_eq!(cfg.sim.vehicle, SimVehicle::Car);
        assert_eq!(cfg.sim.car, car);
        assert_eq!(cfg.control.mixing, Mixing::Car);
        assert_eq!(
            (cfg.control.speed_gain, cfg.control.steering_gain),
            (1.0, 1.0)
        );
        assert!(text.contains("# The car:"), "{text}");
        // A JetBot's replay keeps the wheels and the config's own law.
        let text = replay_config(&Config::default(), "a test", None).unwrap();
        let cfg = Config::parse(&text, "replay.toml").unwrap();
        assert_eq!(cfg.sim.vehicle, SimVehicle::Wheels);
        assert_eq!(cfg.control, Config::default().control);
        // `poses` reversed the turn: the car read back in the tub's convention.
        assert_eq!(car.reversed().curvature_per_unit, -2.6);
    }

    #[test]
    fn the_partial_folder_sits_beside_the_output() {
        assert_eq!(
            partial_dir(Path::new("/d/lap-poses")),
            PathBuf::from("/d/lap-poses.partial")
        );
    }
}
