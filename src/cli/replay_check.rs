//! `jetpilot eval --compare-render WORLD`: how faithful a replay is, measured where the
//! truth is known (a drive recorded in the simulator). The car is put at the same poses
//! around the recorded path in the replay and in the rendered world the drive was recorded
//! in, shifted sideways and turned as a policy's mistakes would put it, and the model's
//! outputs on the two views are compared. A replay that hides the corrections a policy
//! would make (re-projection errors, camera effects carried along with the floor) cannot
//! teach DDPG anything that holds on fresh frames.

use std::path::Path;
use std::process::ExitCode;

use anyhow::{Context, bail};
use jetpilot::config::Config;
use jetpilot::policy::Policy;
use jetpilot::policy::contract::OutputKind;
use jetpilot::policy::preprocess::Preprocessor;
use jetpilot::score::agreement::mean_abs_difference;
use jetpilot::score::contact::contact_sheet;
use jetpilot::sim::Pose2;
use jetpilot::sim::setup::{self, FrameMode};
use jetpilot::sim::world::World;

use super::sim::WorldArgs;

/// The offsets from each recorded pose: sideways (m, left positive) and turned (degrees,
/// left positive). The first is the recorded pose itself.
const OFFSETS: [(f32, f32); 11] = [
    (0.0, 0.0),
    (0.0, 10.0),
    (0.0, -10.0),
    (0.0, 20.0),
    (0.0, -20.0),
    (0.0, 28.0),
    (0.0, -28.0),
    (0.05, 0.0),
    (-0.05, 0.0),
    (0.05, 15.0),
    (-0.05, -15.0),
];

/// The offset rows `--png` shows: the recorded pose, turned 28 degrees left, 5 cm left.
const SHOWN_OFFSETS: [usize; 3] = [0, 5, 7];

/// About this many recorded poses, spread evenly over the recording.
const POSES: usize = 48;

/// One offset's means over the poses.
#[derive(Debug, serde::Serialize)]
pub struct OffsetRow {
    pub lateral_m: f32,
    pub turn_deg: f32,
    /// The model's steering output (`steering`, or `x` for a target-point model).
    pub rendered: f64,
    pub replayed: f64,
    /// Mean absolute difference of the steering output, and of the other one.
    pub steering_diff: f64,
    pub other_diff: f64,
    /// Mean absolute difference of the two views' pixels, in levels of 255 (every
    /// channel): what the replay shows differently, whatever the model makes of it. At the
    /// recorded pose only the recording's JPEG compression and the camera's effects are
    /// left; a pose that did not match the world's would show another piece of the track.
    pub pixel_diff: f64,
    /// Share of the replayed views' floor that a recorded frame saw.
    pub coverage: f64,
}

/// The whole comparison.
#[derive(Debug, serde::Serialize)]
pub struct Comparison {
    pub model: String,
    pub poses: usize,
    pub rows: Vec<OffsetRow>,
    /// Least-squares slope of the replayed corrections (each offset's mean minus the
    /// recorded pose's) on the rendered ones: 1 when the replay shows the model what the
    /// world would, below 1 when it hides the corrections.
    pub correction_kept: f64,
    /// Mean absolute steering difference over the offset rows.
    pub mean_steering_diff: f64,
}

/// Runs the comparison: `replay_cfg` is the replay (`sim.frames = "replay"`), `world_cfg`
/// the world its recording was made in, with `world` flags applied to it.
pub fn compare(
    replay_cfg: &Path,
    world_cfg: &Path,
    world: &WorldArgs,
    model: Option<&Path>,
    json: Option<&Path>,
    png: Option<&Path>,
) -> anyhow::Result<ExitCode> {
    let replay_config = Config::load(replay_cfg)?;
    if replay_config.sim.frames != FrameMode::Replay {
        bail!(
            "--compare-render: {} is not a replay (sim.frames = \"replay\" with sim.recording)",
            replay_cfg.display()
        );
    }
    let mut world_config = Config::load(world_cfg)?;
    world.apply(&mut world_config);
    if world_config.sim.frames != FrameMode::Render {
        bail!(
            "--compare-render: {} must render its frames (sim.frames = \"render\"): it is the world the recording was made in",
            world_cfg.display()
        );
    }
    let replay_rig = setup::build(&replay_config)
        .with_context(|| format!("cannot build the replay of {}", replay_cfg.display()))?;
    let shift = replay_rig.path_shift_m;
    let mut replay = replay_rig.world;
    let mut rendered = setup::build(&world_config)
        .with_context(|| format!("cannot build the world of {}", world_cfg.display()))?
        .world;
    // The recorded poses (the world's copy of the recording is borrowed again for each
    // pose's coverage, between moves).
    let recorded: Vec<Pose2> = replay
        .synthesizer()
        .context("the replay world has no synthesizer")?
        .recording()
        .frames
        .iter()
        .map(|f| f.pose)
        .collect();
    if replay.camera().width != rendered.camera().width
        || replay.camera().height != rendered.camera().height
    {
        bail!(
            "--compare-render: the replay's frames are {}x{}, the world's {}x{}",
            replay.camera().width,
            replay.camera().height,
            rendered.camera().width,
            rendered.camera().height
        );
    }
    let mut policy = jetpilot::drive::setup::load_policy(&replay_config, model)?;
    let mut pre = Preprocessor::new(policy.contract());
    let steer = match policy.contract().output {
        OutputKind::SpeedSteering => 1,
        OutputKind::Xy => 0,
    };
    let (w, h) = (replay.camera().width, replay.camera().height);
    let mut frame_r = vec![0u8; (w * h * 3) as usize];
    let mut frame_p = vec![0u8; (w * h * 3) as usize];
    let mut scratch = vec![0u8; (w * h * 3) as usize];
    let every = recorded.len().div_ceil(POSES).max(1);
    let picks: Vec<usize> = (0..recorded.len()).step_by(every).collect();
    // The picture: two poses, a quarter and three quarters along the recording, each at
    // the recorded pose, turned 28 degrees left and moved 5 cm left.
    let shown_poses = [picks[picks.len() / 4], picks[3 * picks.len() / 4]];
    let mut shown: Vec<(usize, usize, Vec<u8>, Vec<u8>)> = Vec::new();
    let mut rows = Vec::with_capacity(OFFSETS.len());
    for (row, &(lateral, turn_deg)) in OFFSETS.iter().enumerate() {
        let (mut sum_r, mut sum_p, mut d_steer, mut d_other) = (0.0, 0.0, 0.0, 0.0);
        let (mut d_pixels, mut cov) = (0.0, 0.0);
        for &i in &picks {
            let at = recorded[i];
            let (s, c) = at.heading.sin_cos();
            let in_replay = Pose2::new(
                at.x - s * lateral,
                at.y + c * lateral,
                at.heading + turn_deg.to_radians(),
            );
            let in_world = Pose2::new(
                in_replay.x - shift.0,
                in_replay.y - shift.1,
                in_replay.heading,
            );
            place_keeping_look(&mut rendered, in_world);
            place_keeping_look(&mut replay, in_replay);
            rendered.observe(&mut frame_r);
            replay.observe(&mut frame_p);
            d_pixels += mean_abs_difference(&frame_r, &frame_p);
            if let Some(synth) = replay.synthesizer() {
                cov += synth.synthesize_from(i, &in_replay, &mut scratch).coverage as f64;
            }
            if png.is_some() && SHOWN_OFFSETS.contains(&row) && shown_poses.contains(&i) {
                shown.push((i, row, frame_r.clone(), frame_p.clone()));
            }
            let out_r = policy.infer(pre.run(w, h, &frame_r)?)?;
            let out_p = policy.infer(pre.run(w, h, &frame_p)?)?;
            let other = 1 - steer;
            sum_r += out_r[steer] as f64;
            sum_p += out_p[steer] as f64;
            d_steer += (out_r[steer] - out_p[steer]).abs() as f64;
            d_other += (out_r[other] - out_p[other]).abs() as f64;
        }
        let n = picks.len() as f64;
        rows.push(OffsetRow {
            lateral_m: lateral,
            turn_deg,
            rendered: sum_r / n,
            replayed: sum_p / n,
            steering_diff: d_steer / n,
            other_diff: d_other / n,
            pixel_diff: d_pixels / n,
            coverage: cov / n,
        });
    }
    let comparison = Comparison {
        model: policy.describe(),
        poses: picks.len(),
        correction_kept: correction_kept(&rows),
        mean_steering_diff: rows[1..].iter().map(|r| r.steering_diff).sum::<f64>()
            / (rows.len() - 1) as f64,
        rows,
    };
    print_comparison(&comparison, steer);
    if let Some(p) = png {
        // Ordered by pose, then offset: rendered views on top, replayed below.
        shown.sort_by_key(|&(i, row, _, _)| (i, row));
        let top: Vec<&[u8]> = shown.iter().map(|(_, _, r, _)| r.as_slice()).collect();
        let bottom: Vec<image::RgbImage> = shown
            .iter()
            .filter_map(|(_, _, _, p)| image::RgbImage::from_raw(w, h, p.clone()))
            .collect();
        contact_sheet(&top, w, h, &bottom, w.max(160))
            .save(p)
            .with_context(|| format!("cannot write {}", p.display()))?;
        println!(
            "wrote {}: rendered (top) and replayed (bottom) at two poses, each as recorded, turned 28 degrees left, moved 5 cm left",
            p.display()
        );
    }
    if let Some(p) = json {
        let text = serde_json::to_string_pretty(&comparison)?;
        std::fs::write(p, text + "\n").with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Least-squares slope through the origin of the replayed corrections on the rendered
/// ones, a correction being an offset row's mean minus the first row's (the recorded
/// pose); NaN when the rendered means do not move.
fn correction_kept(rows: &[OffsetRow]) -> f64 {
    let Some(first) = rows.first() else {
        return f64::NAN;
    };
    let (mut rp, mut rr) = (0.0, 0.0);
    for row in &rows[1..] {
        let (cr, cp) = (row.rendered - first.rendered, row.replayed - first.replayed);
        rp += cr * cp;
        rr += cr * cr;
    }
    if rr > 0.0 { rp / rr } else { f64::NAN }
}

/// Puts the car at `pose` without drawing a new look (placing does, for a new episode).
fn place_keeping_look(world: &mut World, pose: Pose2) {
    let look = world.appearance().cloned();
    world.set_appearance(None);
    world.place(pose);
    world.set_appearance(look);
}

fn print_comparison(c: &Comparison, steer: usize) {
    let name = if steer == 1 { "steering" } else { "x" };
    println!(
        "{} at {} recorded poses, rendered world against replay ({name} output):",
        c.model, c.poses
    );
    println!(
        "  sideways  turned   rendered  replayed   |diff|  |other diff|  |pixel diff|  coverage"
    );
    for r in &c.rows {
        println!(
            "  {:+6.2} m  {:+5.1}°   {:+8.3}  {:+8.3}  {:7.3}  {:12.3}  {:12.1}  {:8.2}",
            r.lateral_m,
            r.turn_deg,
            r.rendered,
            r.replayed,
            r.steering_diff,
            r.other_diff,
            r.pixel_diff,
            r.coverage
        );
    }
    println!(
        "  corrections kept {:.2} (1: the replay shows what the world would), mean |diff| {:.3}",
        c.correction_kept, c.mean_steering_diff
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(rendered: f64, replayed: f64) -> OffsetRow {
        OffsetRow {
            lateral_m: 0.0,
            turn_deg: 0.0,
            rendered,
            replayed,
            steering_diff: 0.0,
            other_diff: 0.0,
            pixel_diff: 0.0,
            coverage: 1.0,
        }
    }

    #[test]
    fn corrections_kept_is_the_slope_of_replayed_on_rendered_corrections() {
        // Corrections 0.1, -0.1, 0.2 rendered; half of each replayed, on another base.
        let half = [
            row(0.0, 0.01),
            row(0.1, 0.06),
            row(-0.1, -0.04),
            row(0.2, 0.11),
        ];
        assert!((correction_kept(&half) - 0.5).abs() < 1e-12);
        let all = [row(0.3, 0.3), row(0.4, 0.4), row(0.1, 0.1)];
        assert!((correction_kept(&all) - 1.0).abs() < 1e-12);
        assert!(correction_kept(&[row(0.2, 0.1), row(0.2, 0.5)]).is_nan());
        assert!(correction_kept(&[]).is_nan());
    }
}
