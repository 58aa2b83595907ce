//! `jetpilot poses`: poses for a recording that has none, by visual odometry on the ground
//! plane fused with the recorded commands (a JetBot's wheels or a DonkeyCar's steering and
//! throttle); or, with `--check`, the drift of that estimate against a tub whose poses are
//! known.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::config::Config;
use jetpilot::dataset::tub::TubReader;
use jetpilot::sim::Pose2;
use jetpilot::sim::camera::CameraModel;
use jetpilot::sim::odometry::ackermann::CarParams;
use jetpilot::sim::odometry::birdseye::ViewGrid;
use jetpilot::sim::odometry::output::Labels;
use jetpilot::sim::odometry::{self, OdometryParams, ReadOptions, Vehicle, check, output};

use super::{check_views, poses_calibrate};

/// Which motion model gives the prior.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum VehicleArg {
    /// From the tub's fields: `wheels/left`, `wheels/right` -> wheels; only `user/angle`,
    /// `user/throttle` -> car.
    Auto,
    /// Differential drive (JetBot), `[sim.robot]`.
    Wheels,
    /// Car-like, Ackermann steering (DonkeyCar), `[sim.car]`.
    Car,
}

#[derive(Debug, clap::Args)]
pub struct PosesArgs {
    /// The recording (a tub, as `jetpilot record` writes it). It is only read.
    #[arg(long, value_name = "DIR")]
    tub: PathBuf,
    /// Config with the camera (`[sim.camera]`: lens, height, tilt), the robot
    /// (`[sim.robot]`: wheel base, motor model; `[sim.car]` for a car) and the chassis mask
    /// (`[sim.chassis]`); default: JetBot's, or for a car DonkeyCar's wide-angle camera at
    /// the tub's frame size (config/donkeycar.toml).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// The motion model of the prior.
    #[arg(long, value_enum, default_value_t = VehicleArg::Auto)]
    vehicle: VehicleArg,
    /// Registration's pyramid levels (the finest and this many minus one coarser; 0: 1 for
    /// the wheels, 2 for a car, whose 5 cm per frame at 20 Hz is several cells).
    #[arg(long, value_name = "N", default_value_t = 0)]
    levels: usize,
    /// Do not leave the chassis (pixels that never change, joined to the bottom edge) out
    /// of registration.
    #[arg(long)]
    no_chassis_mask: bool,
    /// The new tub, with `pose/x`, `pose/y`, `pose/heading` (default: `<tub>-poses`);
    /// `poses.csv` (per frame: pose, confidence, source) and `poses.png` (the trace) go
    /// in it too. With --check: also write the estimate there (the tub with its poses
    /// replaced by the estimate, rewards and target labels left out), to run the
    /// pipeline on estimated poses beside the true ones.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// The tub's own poses are the truth: estimate without them from its first pose, and
    /// report the drift of the estimate and of the wheels alone (writes only the trace,
    /// and the estimate's tub with --out).
    #[arg(long)]
    check: bool,
    /// With --check: use every N-th frame (a lower frame rate).
    #[arg(long, value_name = "N", default_value_t = 1, requires = "check")]
    every: usize,
    /// With --check: add Gaussian noise (grey levels) to every frame.
    #[arg(long, value_name = "SIGMA", default_value_t = 0.0, requires = "check")]
    noise: f32,
    /// With --check: box-blur every frame (radius in pixels).
    #[arg(long, value_name = "PX", default_value_t = 0, requires = "check")]
    blur: usize,
    /// With --check: where the trace goes (default: poses-check.png).
    #[arg(long, value_name = "FILE", requires = "check")]
    png: Option<PathBuf>,
    /// Where vision's own motions scatter about the wheels' by more than this (the
    /// `vision scatter` line: in units of the uncertainty vision claims), trust the wheels
    /// that much more (a low-contrast floor, glare). 0: off.
    #[arg(long, value_name = "K", default_value_t = 4.0)]
    scatter_ref: f64,
    /// Take out what the camera adds at fixed pixels (vignetting, a light gradient, glare
    /// that moves with the robot), which registration reads as standing still: fit it on
    /// a first estimate's poses and, where it explains the frames, estimate again on
    /// frames without it (about twice the time).
    #[arg(long)]
    flat_field: bool,
    /// Also judge the poses by the frames themselves: predict frame t+k (k = 1, 5, 10)
    /// from frame t through the poses and the ground plane, and score the prediction
    /// against the real frame t+k on the floor (PSNR, SSIM), beside the identity (frame t
    /// itself) and the prior alone (and the truth, with --check); then the loop closure
    /// (where a view is seen again, how far apart the poses put the two frames). Writes
    /// `check-views.csv` and `check-views.png` into --out (with --check and no --out:
    /// beside the trace).
    #[arg(long)]
    check_views: bool,
    /// Calibrate how much the prior turns from the drive's loops: where the camera sees a
    /// view again, the car has turned whole turns. The scale is fitted on the loops that
    /// lie within the first half of the drive, the estimate is run again with it, and the
    /// closure of the loops within the second half is reported before and after (the
    /// held-out check).
    #[arg(long, conflicts_with = "check")]
    turn_from_loops: bool,
    /// Keep the prior's turn sign as configured even where the frames turn the other way
    /// (the `turn agreement` line below -0.2). By default the estimate is then run again
    /// with the sign flipped, and a line says so.
    #[arg(long)]
    keep_turn_sign: bool,
}

/// The calibration's lines: the wheel model's corrections and vision's scatter.
fn print_calibration(est: &odometry::Estimate, params: &OdometryParams) {
    if let Some(n) = est.masked_pixels() {
        println!("chassis mask:    {n} pixels left out of registration");
    }
    if let (Some(sc), Some(car)) = (est.scales, replay_car(est, params)) {
        println!(
            "car model:       speed x{:.3} ({} frames), turn x{:.3} and offset {:+.3} rad/m ({} frames), calibrated from the frames",
            sc.speed, sc.speed_frames, sc.turn, sc.offset, sc.turn_frames
        );
        println!(
            "                 {:.2} m/s per unit throttle, curvature {:+.3} /m per unit angle {:+.3} /m{}",
            car.speed_per_throttle_mps,
            car.curvature_per_unit,
            car.curvature_offset,
            if params.reverse_turn {
                " (in the tub's own angle convention, its sign reversed: what replay.toml drives)"
            } else {
                " (what replay.toml drives)"
            }
        );
    } else if let Some(sc) = est.scales {
        println!(
            "wheel model:     speed x{:.3} ({} frames), turn x{:.3} ({} frames), calibrated from the frames",
            sc.speed, sc.speed_frames, sc.turn, sc.turn_frames
        );
    }
    if let Some(f) = est.flat_field {
        println!(
            "camera effects:  pairs of pixels on the same floor disagree by {:.1} levels RMS, {:.1} through the fitted field{}",
            f.mismatch.0,
            f.mismatch.1,
            if f.explains_the_pairs() {
                ": estimated again without them"
            } else {
                ": not used"
            }
        );
    }
    if let Some((slope, n)) = est.turn_agreement {
        println!(
            "turn agreement:  vision turns x{slope:.2} of the prior ({n} turning frames){}",
            if slope < poses_calibrate::REVERSED_BELOW {
                ": the frames turn the OTHER way from the commands. The steering's sign looks reversed ([sim.car] curvature_per_unit, or the wheels' left/right), or the camera's picture is mirrored"
            } else {
                ""
            }
        );
    }
    if let Some(k) = est.scatter {
        println!(
            "vision scatter:  {k:.2} x its claimed uncertainty about the wheels (median); the wheels' weight {:.1}",
            est.prior_weight
        );
    }
}

/// The config the poses are estimated with, every relative path made absolute (the
/// replay config written beside the new tub must mean the same files wherever it lies).
fn load_config(path: Option<&Path>) -> anyhow::Result<Config> {
    let mut cfg = match path {
        Some(c) => Config::load(c)?,
        None => Config::default(),
    };
    let cwd = std::env::current_dir().context("the current folder")?;
    cfg.resolve_paths(&cwd);
    Ok(cfg)
}

/// `replay.toml` for the tub at `out`, made from the config the poses were estimated with
/// (and a car's calibration, [`replay_car`]).
fn replay_file(
    args: &PosesArgs,
    cfg: &Config,
    car: Option<CarParams>,
) -> anyhow::Result<(&'static str, String)> {
    let made_from = match &args.config {
        Some(c) => c.display().to_string(),
        None => "the JetBot defaults".to_string(),
    };
    let text = output::replay_config(cfg, &made_from, car)?;
    Ok((output::REPLAY_CONFIG, text))
}

/// A car's calibrated params for its replay, in the recording's own angle convention (the
/// estimate's are in the convention it ran with, reversed where the turn sign was flipped);
/// `None` for differential drive.
fn replay_car(est: &odometry::Estimate, params: &OdometryParams) -> Option<CarParams> {
    est.car
        .map(|c| if params.reverse_turn { c.reversed() } else { c })
}

/// The vehicle `args.vehicle` names, or the tub's fields call for.
fn vehicle(args: &PosesArgs, tub: &TubReader, cfg: &Config) -> Vehicle {
    match args.vehicle {
        VehicleArg::Auto => Vehicle::for_tub(tub, cfg.sim.robot, cfg.sim.car),
        VehicleArg::Wheels => Vehicle::Wheels(cfg.sim.robot),
        VehicleArg::Car => Vehicle::Car(cfg.sim.car),
    }
}

/// The camera and the odometry settings for `vehicle`: a car without a config gets
/// DonkeyCar's wide-angle camera at the tub's frame size, and a car the grid of floor
/// that camera resolves.
fn setup(
    args: &PosesArgs,
    tub: &TubReader,
    cfg: &Config,
    vehicle: &Vehicle,
) -> (CameraModel, OdometryParams) {
    let mut camera = cfg.sim.camera;
    let mut params = OdometryParams {
        scatter_ref: args.scatter_ref,
        flat_field: args.flat_field,
        chassis: cfg.sim.chassis,
        ..OdometryParams::default()
    };
    if args.no_chassis_mask {
        params.chassis.find = Some(false);
        params.chassis.below_row = None;
    }
    if let Vehicle::Car(_) = vehicle {
        params.grid = ViewGrid::donkeycar();
        params.levels = 2;
        if args.config.is_none() {
            let size = tub.records().find_map(|r| tub.load_rgb(r).ok());
            if let Some((w, h, _)) = size {
                camera = CameraModel::donkeycar(w, h);
            }
        }
    }
    if args.levels > 0 {
        params.levels = args.levels;
    }
    (camera, params)
}

pub fn main(args: PosesArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = load_config(args.config.as_deref())?;
    let tub = TubReader::open(&args.tub)
        .with_context(|| format!("reading the tub {}", args.tub.display()))?;
    let vehicle = vehicle(&args, &tub, &cfg);
    let (camera, params) = setup(&args, &tub, &cfg, &vehicle);
    // The replay config written beside the new tub names the camera the poses used.
    cfg.sim.camera = camera;
    println!("motion model:    {}", vehicle.name());
    if args.check {
        return check_against_truth(&args, &tub, &cfg, vehicle, params);
    }
    if let Some(rec) = tub.records().find(|r| r.pose.is_some()) {
        anyhow::bail!(
            "{}: record {} already has a pose; use --check to measure the estimate against them",
            args.tub.display(),
            rec.index
        );
    }
    let out = args.out.clone().unwrap_or_else(|| {
        let mut name = args.tub.file_name().unwrap_or_default().to_os_string();
        name.push("-poses");
        args.tub.with_file_name(name)
    });
    output::refuse_existing(&out)?;
    // Made before the estimate runs too, so a config that cannot be written costs no run.
    replay_file(&args, &cfg, None)?;
    let started = std::time::Instant::now();
    let est = odometry::estimate(
        &tub,
        &cfg.sim.camera,
        vehicle,
        params,
        Pose2::default(),
        ReadOptions::default(),
    )?;
    let (est, params) = poses_calibrate::fix_turn_sign(
        args.keep_turn_sign,
        &tub,
        &cfg.sim.camera,
        vehicle,
        params,
        est,
        Pose2::default(),
        ReadOptions::default(),
    )?;
    // The records' frames, read once for the checks that need them (every re-estimate
    // keeps the same records).
    let frames = if args.turn_from_loops || args.check_views {
        check_views::load_frames(&tub, &cfg.sim.camera, &est)
    } else {
        Vec::new()
    };
    let (est, vehicle) = if args.turn_from_loops {
        poses_calibrate::turn_from_loops(&tub, &cfg.sim.camera, vehicle, params, est, &frames)?
    } else {
        (est, vehicle)
    };
    let took = started.elapsed().as_secs_f32();
    for w in &est.warnings {
        tracing::warn!("{w}");
    }
    let replay = replay_file(&args, &cfg, replay_car(&est, &params))?;
    let n = output::write_tub(&tub, &est, &out, super::unix_now(), Labels::Keep, &[replay])?;
    output::write_csv(&est, &out.join("poses.csv"))?;
    output::trace_png(&est, None, &out.join("poses.png"))?;
    print_calibration(&est, &params);
    let flagged = est.flagged().saturating_sub(1);
    let length: f32 = est
        .poses
        .windows(2)
        .map(|w| (w[1].pose.x - w[0].pose.x).hypot(w[1].pose.y - w[0].pose.y))
        .sum();
    println!(
        "{n} records with poses -> {} ({length:.2} m travelled; {flagged} of {} frames from the prior alone, see poses.csv; trace: poses.png)",
        out.display(),
        est.poses.len().saturating_sub(1)
    );
    print_sources(&est, took);
    if args.check_views {
        let prior = odometry::estimate(
            &tub,
            &cfg.sim.camera,
            vehicle,
            check_views::prior_alone(params),
            Pose2::default(),
            ReadOptions::default(),
        )?;
        check_views::run(&cfg.sim.camera, &frames, params, &est, &prior, None, &out)?;
    }
    print_replay_use(&out);
    Ok(ExitCode::SUCCESS)
}

/// Where the frames' motions came from, each reason counted, and the confidence.
fn print_sources(est: &odometry::Estimate, seconds: f32) {
    let mut counts: std::collections::BTreeMap<&str, usize> = std::collections::BTreeMap::new();
    for p in &est.poses {
        *counts.entry(p.source.as_str()).or_default() += 1;
    }
    let list: Vec<String> = counts.iter().map(|(k, v)| format!("{k} {v}")).collect();
    let mut conf: Vec<f32> = est.poses.iter().map(|p| p.confidence).collect();
    conf.sort_by(f32::total_cmp);
    let median = conf.get(conf.len() / 2).copied().unwrap_or(0.0);
    let mean = conf.iter().sum::<f32>() / conf.len().max(1) as f32;
    println!(
        "frames:          {} ({}); confidence mean {mean:.3}, median {median:.3}; {seconds:.1} s",
        est.poses.len(),
        list.join(", ")
    );
}

/// How to drive the new tub's replay.
fn print_replay_use(out: &Path) {
    let cfg = out.join(output::REPLAY_CONFIG);
    let [eval, ddpg] = output::replay_commands(&cfg);
    println!(
        "replay simulator: {} (the path as the road; [sim.path] lanes = 2 on the JetBot mat)\n  {eval}\n  {ddpg}",
        cfg.display()
    );
}

fn check_against_truth(
    args: &PosesArgs,
    tub: &TubReader,
    cfg: &Config,
    vehicle: Vehicle,
    params: OdometryParams,
) -> anyhow::Result<ExitCode> {
    let sim = &cfg.sim;
    let truth: HashMap<u64, Pose2> = tub
        .records()
        .filter_map(|r| r.pose.map(|(x, y, h)| (r.index, Pose2::new(x, y, h))))
        .collect();
    let first = tub
        .records()
        .next()
        .and_then(|r| truth.get(&r.index))
        .copied();
    let Some(start) = first else {
        anyhow::bail!(
            "{}: --check needs a tub whose records carry poses (the simulator's: jetpilot sim --record)",
            args.tub.display()
        );
    };
    if let Some(out) = &args.out {
        // Before the estimate runs, so a folder or a config that cannot be written costs
        // no run.
        output::refuse_existing(out)?;
        replay_file(args, cfg, None)?;
    }
    let opts = ReadOptions {
        every: args.every,
        noise: args.noise,
        blur: args.blur,
    };
    let est = odometry::estimate(tub, &sim.camera, vehicle, params, start, opts)?;
    let (est, params) = poses_calibrate::fix_turn_sign(
        args.keep_turn_sign,
        tub,
        &sim.camera,
        vehicle,
        params,
        est,
        start,
        opts,
    )?;
    let wheels_only = check_views::prior_alone(params);
    let base = odometry::estimate(
        tub,
        &sim.camera,
        vehicle,
        wheels_only,
        start,
        ReadOptions {
            every: args.every,
            ..ReadOptions::default()
        },
    )?;
    let d = check::drift(&est.poses, &truth);
    let b = check::drift(&base.poses, &truth);
    let png = args
        .png
        .clone()
        .unwrap_or_else(|| PathBuf::from("poses-check.png"));
    let truth_path: Vec<Pose2> = est
        .poses
        .iter()
        .filter_map(|p| truth.get(&p.index).copied())
        .collect();
    output::trace_png(&est, Some(&truth_path), &png)?;
    print_calibration(&est, &params);
    println!("visual + wheels: {d}");
    println!(
        "                 {} of {} frames from the wheels alone",
        est.flagged().saturating_sub(1),
        est.poses.len().saturating_sub(1)
    );
    println!("wheels alone:    {b}");
    println!(
        "trace: {} (grey: truth, green: estimate, red: frames from the wheels)",
        png.display()
    );
    if let Some(out) = &args.out {
        let replay = replay_file(args, cfg, replay_car(&est, &params))?;
        let n = output::write_tub(
            tub,
            &est,
            out,
            super::unix_now(),
            Labels::RobotOnly,
            &[replay],
        )?;
        output::write_csv(&est, &out.join("poses.csv"))?;
        println!("{n} records with the estimated poses -> {}", out.display());
        print_replay_use(out);
    }
    if args.check_views {
        let dir = match &args.out {
            Some(out) => {
                std::fs::create_dir_all(out)
                    .with_context(|| format!("creating {}", out.display()))?;
                out.clone()
            }
            None => png
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .map_or_else(|| PathBuf::from("."), Path::to_path_buf),
        };
        let frames = check_views::load_frames(tub, &sim.camera, &est);
        check_views::run(
            &sim.camera,
            &frames,
            params,
            &est,
            &base,
            Some(&truth),
            &dir,
        )?;
    }
    Ok(ExitCode::SUCCESS)
}
