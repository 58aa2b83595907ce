//! `jetpilot train bench`: the trainer's speed targets, measured.
//!
//! - burn's raw training step (forward + backward + Adam on one constant batch) against
//!   imitation learning's images/s with its whole data pipeline (cached frames, augmentation
//!   on the prefetch thread, batches built per step); target >= 90 %.
//! - DDPG with the frozen backbone: environment steps/s, updates included; target >= 50
//!   at 96x96.
//! - DDPG with trainable backbones (`--train-backbone`): seconds per update (no target; it
//!   says what a run costs on this machine).

use std::path::PathBuf;
use std::process::ExitCode;

use jetpilot::policy::onnx::Resnet18Weights;
use jetpilot::policy::{ModelContract, OutputKind};
use jetpilot::train::TrainDevice;
use jetpilot::train::augment::Augment;
use jetpilot::train::data::{Dataset, LabelMap};
use jetpilot::train::ddpg::agent::{Agent, AgentConfig};
use jetpilot::train::ddpg::replay::{Replay, Transition};
use jetpilot::train::ddpg::{self, DdpgOptions};
use jetpilot::train::il::{self, IlOptions};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[derive(Debug, clap::Args)]
pub struct TrainBenchArgs {
    /// Simulator config for the DDPG measurement.
    #[arg(long, value_name = "FILE", default_value = "config/sim.toml")]
    sim: PathBuf,
    /// Network input size.
    #[arg(long, default_value_t = 96)]
    input_size: u32,
    /// The network of the imitation-learning measurements.
    #[arg(long, value_enum, default_value = "resnet18")]
    arch: super::model::ArchArg,
    /// Imitation-learning batch size.
    #[arg(long, default_value_t = 64)]
    batch: usize,
    /// Timed raw training steps.
    #[arg(long, default_value_t = 8)]
    steps: usize,
    /// Imitation-learning epochs over `4 x batch` synthetic frames.
    #[arg(long, default_value_t = 2)]
    epochs: usize,
    /// DDPG training episodes (300 steps at most each).
    #[arg(long, default_value_t = 6)]
    episodes: usize,
    /// Batch of the trainable-backbone DDPG update measurement.
    #[arg(long, default_value_t = 32)]
    backbone_batch: usize,
    /// Timed trainable-backbone DDPG updates (after one untimed); the actor trains on every
    /// second one (TD3's delay), so keep it even.
    #[arg(long, default_value_t = 4)]
    backbone_updates: usize,
    /// Skip parts: any of `il`, `ddpg`, `backbone` (comma-separated or repeated).
    #[arg(long, value_delimiter = ',')]
    skip: Vec<String>,
    #[command(flatten)]
    target: super::train_il::DeviceArg,
}

pub fn main(args: TrainBenchArgs) -> anyhow::Result<ExitCode> {
    let scratch = tempfile_dir()?;
    if !skips(&args, "il") {
        let raw = il::raw_throughput(
            args.target.device,
            args.arch.into(),
            args.input_size,
            args.batch,
            args.steps,
        )?;
        let contract = ModelContract {
            input_size: args.input_size,
            output: OutputKind::SpeedSteering,
            ..ModelContract::default()
        };
        let data = Dataset::random(args.input_size, 4 * args.batch, 0);
        let labels = LabelMap::new(OutputKind::SpeedSteering, &Default::default());
        let mut opts = IlOptions::paper(scratch.join("il"), contract, labels);
        opts.arch = args.arch.into();
        opts.epochs = args.epochs;
        opts.batch = args.batch;
        opts.test_fraction = 0.0;
        opts.augment = Augment::JETBOT;
        opts.progress = false;
        opts.device = args.target.device;
        let mut rates = Vec::new();
        il::train(&data, &opts, |e| rates.push(e.images_per_s))?;
        let pipeline = rates.iter().sum::<f64>() / rates.len().max(1) as f64;
        println!(
            "imitation learning {s}x{s} batch {b} on {d}: raw step {raw:.1} img/s, with the data pipeline {pipeline:.1} img/s = {:.1} % (target >= 90 %)",
            100.0 * pipeline / raw,
            s = args.input_size,
            b = args.batch,
            d = args.target.device,
        );
    }
    if !skips(&args, "ddpg") {
        let cfg = super::train::config(Some(&args.sim))?;
        let mut opts = DdpgOptions::new(scratch.join("ddpg"), cfg);
        opts.input_size = args.input_size;
        opts.max_episodes = args.episodes;
        opts.episode_steps = 300;
        opts.eval_every = 0;
        opts.eval_seconds = 1.0;
        opts.warmup_updates = 0;
        opts.device = args.target.device;
        let report = ddpg::train(&opts, |_| {}, |_, _| {})?;
        println!(
            "DDPG frozen backbone {s}x{s}, heads on {d}: {} environment steps in {} episodes, {:.1} steps/s with {} updates (batch {}, {} per step) (target >= 50)",
            report.env_steps,
            report.episodes,
            report.steps_per_s,
            report.updates,
            opts.agent.batch,
            opts.updates_per_step,
            s = args.input_size,
            d = args.target.device,
        );
    }
    if !skips(&args, "backbone") {
        let secs = backbone_update_seconds(
            args.target.device,
            args.input_size,
            args.backbone_batch,
            args.backbone_updates,
        )?;
        println!(
            "DDPG trainable backbones {s}x{s} batch {b} on {d}: {secs:.2} s per update (actor + twin critics + targets, each its own ResNet-18)",
            s = args.input_size,
            b = args.backbone_batch,
            d = args.target.device,
        );
    }
    let _ = std::fs::remove_dir_all(&scratch);
    Ok(ExitCode::SUCCESS)
}

fn skips(args: &TrainBenchArgs, part: &str) -> bool {
    args.skip.iter().any(|s| s == part)
}

/// Mean seconds of one [`Agent::update`] with trainable backbones, on random frames.
fn backbone_update_seconds(
    device: TrainDevice,
    size: u32,
    batch: usize,
    updates: usize,
) -> anyhow::Result<f64> {
    let weights = Resnet18Weights::random(2, 0);
    let cfg = AgentConfig {
        batch,
        ..AgentConfig::default()
    };
    let mut agent = Agent::trainable(cfg, &weights, 0, &device.open()?)?;
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let px = (3 * size * size) as usize;
    let mut replay = Replay::new(2 * batch);
    for _ in 0..2 * batch {
        replay.push(Transition {
            features: (0..px).map(|_| rng.random_range(-2.0..2.0)).collect(),
            action: [rng.random_range(0.0..1.0), rng.random_range(-1.0..1.0)],
            reward: rng.random(),
            next_features: (0..px).map(|_| rng.random_range(-2.0..2.0)).collect(),
            discount: 0.98,
            demo: false,
        });
    }
    agent.update(&replay, true, &mut rng)?;
    let t = std::time::Instant::now();
    for _ in 0..updates.max(1) {
        agent.update(&replay, true, &mut rng)?;
    }
    Ok(t.elapsed().as_secs_f64() / updates.max(1) as f64)
}

fn tempfile_dir() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("jetpilot-train-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}
