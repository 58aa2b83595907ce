//! `jetpilot poses --check-views`: the estimated poses judged by the frames themselves
//! ([`views`]): frame t+k predicted from frame t through the poses and the ground
//! plane, scored against the real frame, beside the identity and the prior alone (and the
//! truth, with `--check`). Then loop closure ([`loops`]): where a view is seen
//! again, how far apart each pose set puts the two frames. Writes `check-views.csv` and
//! `check-views.png`.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use jetpilot::dataset::tub::{TubReader, TubRecord};
use jetpilot::sim::Pose2;
use jetpilot::sim::camera::CameraModel;
use jetpilot::sim::odometry::loops;
use jetpilot::sim::odometry::views::{self, PoseSet};
use jetpilot::sim::odometry::{Estimate, OdometryParams};

/// A pair is scored where at least this share of the camera's floor pixels is seen by
/// every pose set in both frames.
pub const MIN_FLOOR: f32 = 0.1;

/// The floor scored: up to this many times as far ahead as the odometry's grid reaches.
pub const FLOOR_RANGE: f32 = 1.5;

/// A view seen again counts as a loop only this long after it was first seen.
const LOOP_MIN_GAP_S: f64 = 2.0;

/// The odometer's settings with vision switched off: the prior alone, as configured.
pub fn prior_alone(params: OdometryParams) -> OdometryParams {
    let mut p = params;
    p.fusion.min_texture = f32::INFINITY;
    p.calibrate = false;
    p.flat_field = false;
    p.chassis.find = Some(false);
    p
}

/// The frames of `est`'s records, in its order (`None`: unreadable, or not the camera's
/// size).
pub fn load_frames(tub: &TubReader, camera: &CameraModel, est: &Estimate) -> Vec<views::Frame> {
    let by_index: HashMap<u64, &TubRecord> = tub.records().map(|r| (r.index, r)).collect();
    est.poses
        .iter()
        .map(|p| {
            let rec = by_index.get(&p.index)?;
            let (w, h, rgb) = tub.load_rgb(rec).ok()?;
            ((w, h) == (camera.width, camera.height)).then(|| Arc::new(rgb))
        })
        .collect()
}

/// Frames that see a view seen at least [`LOOP_MIN_GAP_S`] before ([`loops::find_loops`]).
pub fn loop_matches(
    frames: &[views::Frame],
    camera: &CameraModel,
    est: &Estimate,
) -> Vec<loops::LoopMatch> {
    let thumbs: Vec<Option<Vec<f32>>> = frames
        .iter()
        .map(|f| {
            f.as_ref()
                .and_then(|px| loops::thumbnail(px, camera.width as usize, camera.height as usize))
        })
        .collect();
    let times: Vec<f64> = est.poses.iter().map(|p| p.time_s).collect();
    loops::find_loops(&thumbs, &times, LOOP_MIN_GAP_S)
}

/// Runs the check of `est` (and `prior`, the prior alone; `truth` where known) on
/// `frames` ([`load_frames`] of `est`), with the chassis mask `est` was estimated with, and
/// writes the table and the strip into `dir`.
pub fn run(
    camera: &CameraModel,
    frames: &[views::Frame],
    params: OdometryParams,
    est: &Estimate,
    prior: &Estimate,
    truth: Option<&HashMap<u64, Pose2>>,
    dir: &Path,
) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let max_forward_m = params.grid.forward_m.1 * FLOOR_RANGE;
    let prior_poses: HashMap<u64, Pose2> = prior.poses.iter().map(|p| (p.index, p.pose)).collect();
    let mut sets = vec![PoseSet {
        name: "estimate".into(),
        poses: est.poses.iter().map(|p| p.pose).collect(),
    }];
    let aligned = |name: &str, from: &HashMap<u64, Pose2>| -> anyhow::Result<PoseSet> {
        let poses = est
            .poses
            .iter()
            .map(|p| {
                from.get(&p.index)
                    .copied()
                    .with_context(|| format!("{name}: no pose for record {}", p.index))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(PoseSet {
            name: name.into(),
            poses,
        })
    };
    sets.push(aligned("prior alone", &prior_poses)?);
    if let Some(t) = truth {
        sets.push(aligned("truth", t)?);
    }
    let check = views::check_views(
        camera,
        frames,
        est.mask.as_ref(),
        &sets,
        &views::STEPS,
        max_forward_m,
        MIN_FLOOR,
    )?;
    let csv = dir.join("check-views.csv");
    std::fs::write(&csv, check.csv()).with_context(|| format!("writing {}", csv.display()))?;
    println!(
        "view check:      frame t+k predicted from frame t through the poses and the ground plane, scored on the floor ({:.1} s)",
        started.elapsed().as_secs_f32()
    );
    println!("{}", check.table());
    for r in &check.rows {
        let beats: Vec<String> = check
            .methods
            .iter()
            .zip(&r.beats_identity)
            .skip(1)
            .map(|(m, b)| format!("{m} {:.0} %", b * 100.0))
            .collect();
        println!(
            "  k = {:>2}: pairs whose SSIM beats the identity's: {}",
            r.k,
            beats.join(", ")
        );
    }
    // The identity and the prior alone are the baselines (the truth is not one).
    let verdict = if check.beats(1, &[0, 2]) {
        "the estimate beats the identity and the prior alone by PSNR and SSIM at every k"
    } else {
        "the estimate does NOT beat the identity and the prior alone by PSNR and SSIM at every k"
    };
    println!("  {verdict}; table: {}", csv.display());
    let matches = loop_matches(frames, camera, est);
    println!(
        "loop closure:    frames that see a view seen at least {LOOP_MIN_GAP_S} s before, and how far apart the poses put them"
    );
    for set in &sets {
        println!(
            "  {:<12} {}",
            set.name,
            loops::closure(&matches, &set.poses)
        );
    }
    if let Some(strip) = &check.strip {
        let png = dir.join("check-views.png");
        strip
            .save(&png)
            .with_context(|| format!("writing {}", png.display()))?;
        let ts: Vec<String> = check
            .strip_pairs
            .iter()
            .map(|(k, t)| format!("{t}->{}", t + k))
            .collect();
        println!(
            "  strip: {} (rows: frames {}; columns: frame t, {} predicted, real t+k, then |difference| x3 for identity, {}; dark blue: not scored)",
            png.display(),
            ts.join(", "),
            check.methods[1..].join(", "),
            check.methods[1..].join(", ")
        );
    }
    Ok(())
}
