//! `jetpilot sim` (drive in the simulator) and `jetpilot eval` (the paper's test protocol).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::config::Config;
use jetpilot::drive::DriveParams;
use jetpilot::drive::stages::FrameProcessor;
use jetpilot::policy::Policy;
use jetpilot::score::contact;
use jetpilot::sim::Pose2;
use jetpilot::sim::camera::CameraModel;
use jetpilot::sim::closed_loop::{self, LoopTimes, Pilot};
use jetpilot::sim::demos::DemoRecorder;
use jetpilot::sim::render::{top_down, write_png};
use jetpilot::sim::reward::autonomy;
use jetpilot::sim::setup::{self, SimRig};
use jetpilot::sim::world::InterventionCauses;

/// Which road to drive, over the config's `[sim]` (shared by `sim`, `eval` and
/// `train ddpg`).
#[derive(Debug, Clone, clap::Args)]
pub struct WorldArgs {
    /// Track file (see config/tracks/), instead of the config's `sim.track`.
    #[arg(long, value_name = "FILE")]
    pub track: Option<PathBuf>,
    /// Drive the track the other way round (the JetBot mat: clockwise), in the right lane.
    #[arg(long)]
    pub reverse: bool,
    /// Camera instead of the config's `[sim.camera]`: `jetbot` is JetBot's 160-degree
    /// IMX219 fisheye at the mount fitted to real JetBot frames (docs/guides/simulator.md,
    /// "JetBot's camera, fitted so far"; the default), `pinhole` the simulator's first camera
    /// (120-degree pinhole tilted 25 degrees, which the pinhole results in docs/results/
    /// used); the config's image size is kept.
    #[arg(long, value_enum, value_name = "NAME")]
    pub camera: Option<CameraPreset>,
    /// Randomise the camera's look (`[sim.appearance]`: white balance with JetBot's pink
    /// cast, exposure, gamma, vignetting, noise, blur), seeded by `sim.seed`: for training
    /// data (`sim --record`) and `train ddpg`. Off by default, so `eval` stays as it was.
    #[arg(long)]
    pub randomise: bool,
    /// Drive random track layouts (`[sim.layouts]`: closed roads of lines and arcs, 5 to 8
    /// corners as tight as the mat's, lanes 0.09-0.20 m, either way round), seeded by
    /// `sim.seed`: a new one every `every_s` simulated seconds and at each `train ddpg`
    /// episode (its tests stay on the track). Rendered frames only.
    #[arg(long)]
    pub random_layouts: bool,
}

/// Cameras `--camera` can name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CameraPreset {
    /// JetBot's camera: `CameraModel::jetbot`.
    Jetbot,
    /// A 120-degree pinhole tilted 25 degrees: `CameraModel::pinhole`.
    Pinhole,
}

impl WorldArgs {
    pub fn apply(&self, cfg: &mut Config) {
        if let Some(t) = &self.track {
            cfg.sim.track = Some(t.clone());
        }
        if self.reverse {
            cfg.sim.reverse = true;
        }
        if self.randomise {
            cfg.sim.appearance.enabled = true;
        }
        if self.random_layouts {
            cfg.sim.layouts.enabled = true;
        }
        let c = &mut cfg.sim.camera;
        match self.camera {
            Some(CameraPreset::Jetbot) => *c = CameraModel::jetbot(c.width, c.height),
            Some(CameraPreset::Pinhole) => *c = CameraModel::pinhole(c.width, c.height),
            None => {}
        }
    }
}

#[derive(Debug, clap::Args)]
pub struct SimArgs {
    /// Config file: `[sim]` plus the robot's usual sections (the motor layout decides how the
    /// virtual HAT's channels reach the wheels). Default: the built-in config/sim.toml, which
    /// names no model (give --model).
    #[arg(short, long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Model to drive with (default: the config's `model.path`).
    #[arg(short, long, value_name = "FILE", conflicts_with = "expert")]
    model: Option<PathBuf>,
    /// Drive with the scripted pure-pursuit expert instead of a model.
    #[arg(long)]
    expert: bool,
    /// Simulated seconds.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Run under the real daemon (capture and inference threads, actuator, watchdog) in
    /// real time, instead of the lockstep loop on a simulated clock. Needs a model. With
    /// --png DIR it writes DIR/trace.png.
    #[arg(long, conflicts_with_all = ["expert", "record", "real"])]
    realtime: bool,
    /// With --realtime: serve the web page too (the video, the modes, the sliders, driving
    /// from the browser), as `jetpilot run --web` does; ADDR overrides `web.bind` (default
    /// 127.0.0.1:8887). The autopilot is engaged from the start; the page can take over.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "",
          requires = "realtime")]
    web: Option<String>,
    /// Record the drive as demonstrations: a DonkeyCar tub v2 (frames, wheels, angle/throttle,
    /// poses, rewards, JetBot target labels) in this folder.
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
    /// With --record or --scatter: also write JetBot's road-following folder
    /// (xy_XXX_YYY_<uuid>.jpg).
    #[arg(long, value_name = "DIR")]
    record_xy: Option<PathBuf>,
    /// Instead of driving, collect data the way JetBot's road-following notebook does: put
    /// the robot down at N random poses on the road or up to --scatter-off-road beside it,
    /// within --scatter-heading of the road's heading, one frame each (a new look and scene
    /// each with --randomise, a new road every 10 with --random-layouts), labelled with the
    /// lane point `[sim.expert] lookahead_m` past the nearest road point. Written with
    /// --record-xy DIR.
    #[arg(long, value_name = "N", requires = "record_xy",
          conflicts_with_all = ["model", "expert", "record", "realtime", "swerve_every"])]
    scatter: Option<u64>,
    /// With --scatter: the largest angle between the robot and the road, degrees, either
    /// way (real JetBot datasets show the road crossing the view at 60 degrees and more).
    #[arg(long, value_name = "DEG", default_value_t = 40.0, requires = "scatter",
          value_parser = parse_heading_deg)]
    scatter_heading: f32,
    /// With --scatter: how far beyond the road's edges the robot may be put down, metres.
    #[arg(long, value_name = "M", default_value_t = 0.05, requires = "scatter",
          value_parser = parse_off_road_m)]
    scatter_off_road: f32,
    /// With --record: keep every Nth control step only, so a fixed number of demonstrations
    /// spans more of the track (e.g. 331 frames over a whole lap: `--seconds 33.1
    /// --record-every 3`, as a human recording at 10 fps would).
    #[arg(long, value_name = "N", default_value_t = 1, requires = "record",
          value_parser = clap::value_parser!(u64).range(1..))]
    record_every: u64,
    /// With --record: stop recording after this many frames (the drive goes on).
    #[arg(long, value_name = "N", requires = "record")]
    record_frames: Option<u64>,
    /// With --expert: swerve off the lane centre every SECONDS on average (0.5x to 1.5x),
    /// for half a second, and record only the way back: recovery demonstrations, as JetBot
    /// and DonkeyCar users collect them. Overrides `[sim.expert] swerve_every_s`.
    #[arg(long, value_name = "SECONDS", requires = "expert")]
    swerve_every: Option<f32>,
    /// With --record and --swerve-every: record the swerves too (the recorder left running
    /// through the whole drive, as a continuous recording whose path is replayed with
    /// `sim.road = "path"`; not demonstrations to imitate).
    #[arg(long, requires_all = ["record", "swerve_every"])]
    record_swerves: bool,
    /// Write pictures a person can look at into this folder: `frames.png` (a strip of camera
    /// frames) and `trace.png` (the mat from above with the driven path and interventions).
    #[arg(long, value_name = "DIR")]
    png: Option<PathBuf>,
    /// With --png: also write `sim_vs_real.png`, the camera frames above real frames picked
    /// evenly from this folder (JPEG/PNG files in it or one level down, e.g.
    /// ../shared/realdata/jetbot_xy_mat), to compare sim and real at a glance.
    #[arg(long, value_name = "FOLDER", requires = "png")]
    real: Option<PathBuf>,
    #[command(flatten)]
    road: WorldArgs,
}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Config file with a `[sim]` section. Default: the built-in config/sim.toml, which names
    /// no model (give --model).
    #[arg(short, long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Model to evaluate (default: the config's `model.path`).
    #[arg(short, long, value_name = "FILE", conflicts_with = "expert")]
    model: Option<PathBuf>,
    /// Evaluate the scripted expert instead (the bar a model should reach).
    #[arg(long)]
    expert: bool,
    /// Test length in simulated seconds (default: `sim.eval_seconds`, 600 as in the paper).
    #[arg(long)]
    seconds: Option<f64>,
    /// Also write the result as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Also write the top-down trace with interventions as a PNG (with --compare-render:
    /// rendered and replayed views, one above the other).
    #[arg(long, value_name = "FILE")]
    png: Option<PathBuf>,
    /// Instead of driving: how faithful the config's replay is, where the truth is known.
    /// FILE is the world the recording was made in (rendered frames; the world flags below
    /// apply to it). The car is put at 48 recorded poses, shifted 5 cm and turned up to 28
    /// degrees, in both, and the model's outputs on the two views are compared; 1 for
    /// "corrections kept" means the replay shows the model what the world would.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["expert", "seconds"], requires = "config")]
    compare_render: Option<PathBuf>,
    #[command(flatten)]
    road: WorldArgs,
}

/// The paper's numbers for one run.
#[derive(Debug, serde::Serialize)]
pub struct EvalResult {
    pub pilot: String,
    pub test_seconds: f64,
    pub interventions: u32,
    /// What ended each intervention.
    pub intervention_causes: InterventionCauses,
    /// `(1 - interventions * 6 / test_seconds) * 100`.
    pub autonomy_percent: f32,
    /// Control steps whose reward reached the threshold ("one reward").
    pub rewards: u64,
    pub control_steps: u64,
    pub mean_reward: f64,
    pub laps: f64,
    pub distance_m: f64,
    pub mean_speed_mps: f64,
    pub wall_seconds: f64,
    pub realtime_factor: f64,
    pub wall_share: WallShare,
}

/// Fractions of the wall time per part of the loop.
#[derive(Debug, serde::Serialize)]
pub struct WallShare {
    pub frames: f64,
    pub pilot: f64,
    pub motors: f64,
    pub physics_and_scoring: f64,
}

struct Driven {
    result: EvalResult,
    /// (simulated seconds, pose), ten a second.
    trace: Vec<(f64, Pose2)>,
    /// When each intervention happened, in the order of the world's `intervention_poses`.
    intervention_times: Vec<f64>,
    strip: Vec<Vec<u8>>,
}

fn drive(
    cfg: &Config,
    model: Option<&Path>,
    expert: bool,
    seconds: f64,
    strip_every: Option<u64>,
    mut recorder: Option<(&mut DemoRecorder, u64, u64)>,
) -> anyhow::Result<(SimRig, Driven)> {
    let mut rig = setup::build(cfg)?;
    let mut policy = if expert {
        None
    } else {
        Some(jetpilot::drive::setup::load_policy(cfg, model)?)
    };
    let params = DriveParams::from_config(cfg);
    let (name, mut pilot) = match policy.as_mut() {
        Some(p) => {
            let name = p.describe();
            let processor =
                FrameProcessor::new(&p.contract().clone(), params.gains, params.max_abs_output);
            (
                name,
                Pilot::Model {
                    policy: p as &mut dyn Policy,
                    processor: Box::new(processor),
                },
            )
        }
        None => (
            "scripted expert (pure pursuit)".to_string(),
            Pilot::expert(cfg.sim.expert, cfg.sim.seed),
        ),
    };
    let mut trace = Vec::new();
    let mut intervention_times = Vec::new();
    let mut strip = Vec::new();
    let size = (cfg.sim.camera.width, cfg.sim.camera.height);
    let settings = cfg.sim.loop_settings(seconds, cfg);
    let every = (cfg.sim.control_hz / 10.0).max(1.0) as u64;
    let mut record_error = None;
    let times: LoopTimes = closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &settings,
        size,
        |step| {
            if step.seq % every == 0 {
                trace.push((step.time.as_secs_f64(), step.pose));
            }
            if step.score.intervention {
                intervention_times.push(step.time.as_secs_f64());
            }
            if let Some(n) = strip_every
                && step.seq % n == 0
                && strip.len() < 8
            {
                strip.push(step.frame.rgb.as_ref().clone());
            }
            if let Some((r, record_every, limit)) = recorder.as_mut()
                && step.seq % *record_every == 0
                && r.written() < *limit
                && record_error.is_none()
                && let Err(e) = r.append(step)
            {
                record_error = Some(e);
            }
        },
    )?;
    if let Some(e) = record_error {
        return Err(anyhow::Error::new(e).context("recording stopped (what was written is kept)"));
    }
    let s = &rig.world.stats;
    let total = times.total.max(1e-9);
    let result = EvalResult {
        pilot: name,
        test_seconds: s.time_s,
        interventions: s.interventions,
        intervention_causes: s.causes,
        autonomy_percent: autonomy(s.interventions, s.time_s as f32),
        rewards: s.rewards,
        control_steps: s.control_steps,
        mean_reward: s.reward_sum / s.control_steps.max(1) as f64,
        laps: rig.world.laps(),
        distance_m: s.distance_m,
        mean_speed_mps: s.distance_m / s.time_s.max(1e-9),
        wall_seconds: times.total,
        realtime_factor: s.time_s / total,
        wall_share: WallShare {
            frames: times.frames / total,
            pilot: times.pilot / total,
            motors: times.motors / total,
            physics_and_scoring: times.physics / total,
        },
    };
    Ok((
        rig,
        Driven {
            result,
            trace,
            intervention_times,
            strip,
        },
    ))
}

fn print_result(r: &EvalResult) {
    println!(
        "{:.0} s simulated in {:.1} s wall ({:.1}x real time), pilot: {}",
        r.test_seconds, r.wall_seconds, r.realtime_factor, r.pilot
    );
    println!(
        "  interventions  {}   autonomy {:.1} %  ((1 - n * 6 s / {:.0} s) * 100)",
        r.interventions, r.autonomy_percent, r.test_seconds
    );
    let c = &r.intervention_causes;
    if r.interventions > 0 {
        println!(
            "  ended by       off the road {}, replay bounds {} (sideways {}, heading {}), stalled {}",
            c.off_road,
            c.replay(),
            c.replay_offset,
            c.replay_heading,
            c.stalled
        );
    }
    println!(
        "  rewards        {} of {} steps with R >= threshold (mean R {:.3})",
        r.rewards, r.control_steps, r.mean_reward
    );
    println!(
        "  laps           {:.2}   distance {:.1} m   mean speed {:.3} m/s",
        r.laps, r.distance_m, r.mean_speed_mps
    );
    let w = &r.wall_share;
    println!(
        "  wall time      frames {:.0} %, pilot {:.0} %, motor driver {:.0} %, physics + scoring {:.0} %",
        w.frames * 100.0,
        w.pilot * 100.0,
        w.motors * 100.0,
        w.physics_and_scoring * 100.0
    );
}

/// The mat from above with the driven path and the interventions. With random layouts,
/// the road drawn is the last one, so only what happened on it is shown.
fn write_trace(rig: &SimRig, driven: &Driven, path: &Path) -> anyhow::Result<()> {
    draw_trace(&rig.world, &driven.trace, &driven.intervention_times, path)
}

/// The mat from above with `trace`'s path and the world's interventions (at `times`).
fn draw_trace(
    world: &jetpilot::sim::world::World,
    trace: &[(f64, Pose2)],
    times: &[f64],
    path: &Path,
) -> anyhow::Result<()> {
    let since = world.layout_drawn_at_s().unwrap_or(0.0);
    if since > 0.0 {
        println!(
            "{}: the last random layout, from {since:.1} s on (each layout lasts sim.layouts.every_s)",
            path.display()
        );
    }
    let texture = jetpilot::sim::render::MatTexture::new(
        &world.track.paint(),
        world.track.mat_size(),
        200.0,
        [96, 120, 92],
        [150, 130, 110],
    )?;
    let poses: Vec<Pose2> = trace
        .iter()
        .filter(|(t, _)| *t >= since)
        .map(|(_, p)| *p)
        .collect();
    let marks: Vec<(Pose2, [u8; 3])> = world
        .stats
        .intervention_poses
        .iter()
        .zip(times)
        .filter(|(_, t)| **t >= since)
        .map(|(p, _)| (*p, [220, 30, 30]))
        .collect();
    let (w, h, rgb) = top_down(&texture, &poses, &marks);
    write_png(path, w, h, &rgb)?;
    Ok(())
}

/// The built-in simulator config, config/sim.toml, for `sim` and `eval` without --config.
const BUILT_IN_SIM_CONFIG: &str = include_str!("../../config/sim.toml");

/// The config of `--config FILE`, else the built-in config/sim.toml. The built-in one's
/// `model.path` points into this repository's .cache, so it is cleared and a run that
/// needs a model (`has_model` false: no --model, no --expert, no --scatter) is refused,
/// naming `instead` (what else would do, e.g. "--expert") when there is something.
fn sim_config(path: Option<&Path>, has_model: bool, instead: &str) -> anyhow::Result<Config> {
    if let Some(p) = path {
        return Ok(Config::load(p)?);
    }
    if !has_model {
        let or = if instead.is_empty() {
            String::new()
        } else {
            format!(" (or {instead})")
        };
        anyhow::bail!(
            "no model to drive with: give --model FILE{or}, or --config FILE whose model.path names one; without --config the built-in config/sim.toml is used, and it names none"
        );
    }
    let mut cfg = Config::parse(BUILT_IN_SIM_CONFIG, "the built-in config/sim.toml")?;
    cfg.model.path = PathBuf::new();
    Ok(cfg)
}

pub fn sim(args: SimArgs) -> anyhow::Result<ExitCode> {
    if args.record_xy.is_some() && args.record.is_none() && args.scatter.is_none() {
        anyhow::bail!("--record-xy needs --record DIR (a drive) or --scatter N (random poses)");
    }
    let has_model = args.model.is_some() || args.expert || args.scatter.is_some();
    let instead = if args.realtime { "" } else { "--expert" };
    let mut cfg = sim_config(args.config.as_deref(), has_model, instead)?;
    args.road.apply(&mut cfg);
    if let Some(s) = args.swerve_every {
        cfg.sim.expert.swerve_every_s = s;
    }
    if args.realtime {
        let cfg = super::run::with_web(cfg, args.web.as_deref())?;
        return realtime(
            &cfg,
            args.config.as_deref(),
            args.model.as_deref(),
            args.seconds,
            args.png.as_deref(),
        );
    }
    if let (Some(n), Some(dir)) = (args.scatter, &args.record_xy) {
        let params = jetpilot::sim::scatter::ScatterParams {
            lookahead_m: cfg.sim.expert.lookahead_m,
            max_heading_rad: args.scatter_heading.to_radians(),
            off_road_m: args.scatter_off_road,
            ..Default::default()
        };
        return scatter(
            &cfg,
            &params,
            n,
            dir,
            args.png.as_deref(),
            args.real.as_deref(),
        );
    }
    let every = (args.seconds * cfg.sim.control_hz as f64 / 8.0).max(1.0) as u64;
    let mut recorder = match &args.record {
        Some(dir) => {
            let now = super::unix_now();
            Some(
                DemoRecorder::create(
                    dir,
                    args.record_xy.as_deref(),
                    now,
                    cfg.sim.seed,
                    cfg.control.mixing,
                )?
                .record_swerves(args.record_swerves),
            )
        }
        None => None,
    };
    let (rig, driven) = drive(
        &cfg,
        args.model.as_deref(),
        args.expert,
        args.seconds,
        args.png.as_ref().map(|_| every),
        recorder
            .as_mut()
            .map(|r| (r, args.record_every, args.record_frames.unwrap_or(u64::MAX))),
    )?;
    print_result(&driven.result);
    if let (Some(r), Some(dir)) = (recorder, &args.record) {
        let n = r.finish()?;
        println!("recorded {n} steps to {}", dir.display());
    }
    if let Some(dir) = &args.png {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let (w, h) = (cfg.sim.camera.width, cfg.sim.camera.height);
        if !driven.strip.is_empty() {
            write_strip(&dir.join("frames.png"), &driven.strip, (w, h))?;
        }
        write_trace(&rig, &driven, &dir.join("trace.png"))?;
        println!("wrote {0}/frames.png and {0}/trace.png", dir.display());
        if let Some(folder) = &args.real {
            write_contact_sheet(dir, folder, &driven.strip, (w, h))?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Camera frames side by side in one PNG.
fn write_strip(path: &Path, frames: &[Vec<u8>], (w, h): (u32, u32)) -> anyhow::Result<()> {
    let n = frames.len().max(1) as u32;
    let mut strip = vec![0u8; (w * n * h * 3) as usize];
    for (i, f) in frames.iter().enumerate() {
        for row in 0..h as usize {
            let src = &f[row * w as usize * 3..(row + 1) * w as usize * 3];
            let dst = (row * (w * n) as usize + i * w as usize) * 3;
            strip[dst..dst + src.len()].copy_from_slice(src);
        }
    }
    write_png(path, w * n, h, &strip)?;
    Ok(())
}

/// `sim --png DIR --real FOLDER`: the sim frames above as many real ones.
fn write_contact_sheet(
    dir: &Path,
    folder: &Path,
    frames: &[Vec<u8>],
    (w, h): (u32, u32),
) -> anyhow::Result<()> {
    let real = contact::pick_real_frames(folder, frames.len().max(1))?;
    for s in &real.skipped {
        eprintln!("warning: skipped {s}");
    }
    let sim: Vec<&[u8]> = frames.iter().map(|f| f.as_slice()).collect();
    let sheet = contact::contact_sheet(&sim, w, h, &real.frames, 224);
    let path = dir.join("sim_vs_real.png");
    sheet
        .save(&path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!(
        "wrote {}: {} sim frames above {} real frames from {}",
        path.display(),
        sim.len(),
        real.frames.len(),
        folder.display()
    );
    Ok(())
}

/// `jetpilot sim --scatter N --record-xy DIR`: JetBot-notebook-style samples from random
/// poses; with --png, the first eight with their targets marked.
fn scatter(
    cfg: &Config,
    params: &jetpilot::sim::scatter::ScatterParams,
    n: u64,
    dir: &Path,
    png: Option<&Path>,
    real: Option<&Path>,
) -> anyhow::Result<ExitCode> {
    use jetpilot::sim::scatter::write_scattered;
    let mut rig = setup::build(cfg)?;
    let (w, h) = (cfg.sim.camera.width, cfg.sim.camera.height);
    let mut shown: Vec<Vec<u8>> = Vec::new();
    let summary = write_scattered(
        &mut rig.world,
        &rig.camera,
        params,
        n,
        cfg.sim.seed,
        dir,
        |frame, (px, py)| {
            if shown.len() < 8 {
                let mut f = frame.to_vec();
                mark(&mut f, w, h, px, py);
                shown.push(f);
            }
        },
    )
    .with_context(|| format!("scattered samples into {}", dir.display()))?;
    println!(
        "wrote {} scattered samples to {} ({} poses dropped: target out of view)",
        summary.written,
        dir.display(),
        summary.out_of_view
    );
    if summary.written < n {
        anyhow::bail!(
            "only {} of {n} samples had their target in view: is the camera looking at the road?",
            summary.written
        );
    }
    if let Some(pdir) = png {
        std::fs::create_dir_all(pdir)
            .with_context(|| format!("cannot create {}", pdir.display()))?;
        write_strip(&pdir.join("frames.png"), &shown, (w, h))?;
        println!("wrote {}/frames.png (targets in green)", pdir.display());
        if let Some(folder) = real {
            write_contact_sheet(pdir, folder, &shown, (w, h))?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// A green 5x5 square at (px, py), clipped to the frame.
fn mark(rgb: &mut [u8], w: u32, h: u32, px: u32, py: u32) {
    for y in py.saturating_sub(2)..(py + 3).min(h) {
        for x in px.saturating_sub(2)..(px + 3).min(w) {
            let i = ((y * w + x) * 3) as usize;
            rgb[i..i + 3].copy_from_slice(&[40, 220, 60]);
        }
    }
}

pub fn eval(args: EvalArgs) -> anyhow::Result<ExitCode> {
    if let (Some(world), Some(config)) = (&args.compare_render, &args.config) {
        return super::replay_check::compare(
            config,
            world,
            &args.road,
            args.model.as_deref(),
            args.json.as_deref(),
            args.png.as_deref(),
        );
    }
    let has_model = args.model.is_some() || args.expert;
    let mut cfg = sim_config(args.config.as_deref(), has_model, "--expert")?;
    args.road.apply(&mut cfg);
    let seconds = args.seconds.unwrap_or(cfg.sim.eval_seconds as f64);
    let (rig, driven) = drive(
        &cfg,
        args.model.as_deref(),
        args.expert,
        seconds,
        None,
        None,
    )?;
    print_result(&driven.result);
    if let Some(p) = &args.json {
        let text = serde_json::to_string_pretty(&driven.result)?;
        std::fs::write(p, text + "\n").with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(p) = &args.png {
        write_trace(&rig, &driven, p)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// `jetpilot sim --realtime`: the unchanged daemon drives the simulated car, with the web
/// page when the config (or --web) turns it on.
fn realtime(
    cfg: &Config,
    config_path: Option<&Path>,
    model: Option<&Path>,
    seconds: f64,
    png: Option<&Path>,
) -> anyhow::Result<ExitCode> {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{Arc, Mutex};

    use jetpilot::clock::{Clock, MonotonicClock};
    use jetpilot::sim::realtime::{SimSource, spawn_physics};

    let model = model.unwrap_or(&cfg.model.path);
    let rig = setup::build(cfg)?;
    let policy = jetpilot::drive::setup::load_policy(cfg, Some(model))?;
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let world = Arc::new(Mutex::new(rig.world));
    let size = (cfg.sim.camera.width, cfg.sim.camera.height);
    let source = SimSource::new(world.clone(), clock.clone(), size, cfg.sim.control_hz);
    let stop = Arc::new(AtomicBool::new(false));
    let physics = spawn_physics(
        world.clone(),
        cfg.sim.physics_hz,
        cfg.sim.control_hz,
        stop.clone(),
    )
    .context("cannot start the physics thread")?;
    if cfg.web.enabled {
        println!(
            "web page: http://{}/ (the car drives itself; Manual on the page takes over)",
            cfg.web.bind
        );
    }
    let outcome = super::run::drive_with(
        cfg,
        config_path,
        Box::new(policy),
        Some(model),
        Box::new(source),
        Some(Box::new(rig.motors)),
        clock,
        Some(seconds),
        super::run::Start::Autopilot,
    );
    stop.store(true, Ordering::Relaxed);
    let trace = physics.join().unwrap_or_default();
    let w = world.lock().unwrap_or_else(|p| p.into_inner());
    let s = &w.stats;
    println!(
        "real time: {:.1} s, {} interventions (autonomy {:.1} %), {} rewards, {:.2} laps, {:.1} m",
        s.time_s,
        s.interventions,
        autonomy(s.interventions, s.time_s as f32),
        s.rewards,
        w.laps(),
        s.distance_m
    );
    if let Some(dir) = png {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("trace.png");
        draw_trace(&w, &trace.poses, &trace.intervention_times, &path)?;
        println!("wrote {}", path.display());
    }
    outcome
}

/// A number within `lo..=hi` (`unit` names it in the error).
fn parse_within(s: &str, lo: f32, hi: f32, unit: &str) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|e| format!("{e}"))?;
    if (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is not within {lo}..={hi} {unit}"))
    }
}

/// `--scatter-heading`: 0 to 90 degrees.
fn parse_heading_deg(s: &str) -> Result<f32, String> {
    parse_within(s, 0.0, 90.0, "degrees")
}

/// `--scatter-off-road`: 0 to 0.5 m.
fn parse_off_road_m(s: &str) -> Result<f32, String> {
    parse_within(s, 0.0, 0.5, "m")
}
