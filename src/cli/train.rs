//! `jetpilot train`: `train probe` (a pretrained backbone's output layer fitted in closed
//! form) is in every build; `train il` (imitation learning), `train ddpg` (fine-tuning in
//! the simulator) and their tools need the cargo feature `train` (burn).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::config::Config;
use jetpilot::policy::OutputKind;

#[derive(Debug, clap::Subcommand)]
pub enum TrainCommand {
    /// Imitation learning (behaviour cloning) on demonstrations: DonkeyCar tubs from
    /// `jetpilot record` / `jetpilot sim --record`, or JetBot road-following xy folders.
    /// Writes best.onnx (lowest test loss), last.onnx, il_log.csv, il_curve.png.
    #[cfg(feature = "train")]
    Il(super::train_il::IlArgs),
    /// DDPG fine-tuning in the replayed-frame simulator, bootstrapped with the imitation
    /// policy and the demonstrations' rewards (DDPGfD). Writes best.onnx (highest autonomy
    /// in the 600 s test among the policies that still drive).
    #[cfg(feature = "train")]
    Ddpg(super::train_ddpg::DdpgArgs),
    /// Fit a pretrained backbone's output layer in closed form (ridge regression on its
    /// final feature map, pooled into cells; the backbone kept as it is): 43 s for 755
    /// frames at 224x224 on 2 cores, where ten epochs of fine-tuning at the 4.7 images a
    /// second measured there take about 27 minutes. Writes probe.onnx (also a start for
    /// `train il --init`: an EfficientNet-Lite0's on any grid, a ResNet-18's with a 1x1
    /// pooled head; for `train ddpg --init` with a 1x1 pooled head) and probe_cv.csv.
    Probe(super::train_probe::ProbeArgs),
    /// Measure the trainer: burn's raw step against imitation learning's images/s, and
    /// DDPG's environment steps/s with the frozen backbone, updates included.
    #[cfg(feature = "train")]
    Bench(super::train_bench::TrainBenchArgs),
    /// Summarise the paper's experiment (scripts/paper-experiment.sh writes the manifest):
    /// a Markdown table per track (mean ± sd over seeds after each wall budget) and
    /// experiment_<track>.png (rewards and autonomy against wall time, seed bands).
    #[cfg(feature = "train")]
    Report(super::train_report::ReportArgs),
    /// Draw a line chart from a CSV with a header row: --y against --x, one line per value
    /// of --series; rows repeating an x within a line (seeds) are drawn as their mean in
    /// a band of their sd (scripts/real-finetune.sh plots its fine-tuning study with it).
    #[cfg(feature = "train")]
    Plot(super::train_plot::PlotArgs),
    /// il, ddpg, bench, report, plot: in a build with `--features train` only.
    #[cfg(not(feature = "train"))]
    #[command(external_subcommand)]
    NotBuilt(Vec<String>),
}

pub fn main(cmd: TrainCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        #[cfg(feature = "train")]
        TrainCommand::Il(args) => super::train_il::main(args),
        #[cfg(feature = "train")]
        TrainCommand::Ddpg(args) => super::train_ddpg::main(args),
        TrainCommand::Probe(args) => super::train_probe::main(args),
        #[cfg(feature = "train")]
        TrainCommand::Bench(args) => super::train_bench::main(args),
        #[cfg(feature = "train")]
        TrainCommand::Report(args) => super::train_report::main(args),
        #[cfg(feature = "train")]
        TrainCommand::Plot(args) => super::train_plot::main(args),
        #[cfg(not(feature = "train"))]
        TrainCommand::NotBuilt(args) => Err(anyhow::anyhow!(
            "`train {}` needs the trainer, and this jetpilot was built without it: build it with \
             `cargo build --release --features train` (`train probe` is in every build)",
            args.first().map(String::as_str).unwrap_or_default()
        )),
    }
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Head {
    /// JetBot's target point (x, y).
    Xy,
    /// The paper's (speed, steering).
    SpeedSteering,
}

impl From<Head> for OutputKind {
    fn from(h: Head) -> Self {
        match h {
            Head::Xy => OutputKind::Xy,
            Head::SpeedSteering => OutputKind::SpeedSteering,
        }
    }
}

/// The config, or the defaults when none is given.
pub fn config(path: Option<&PathBuf>) -> anyhow::Result<Config> {
    match path {
        Some(p) => Config::load(p).with_context(|| format!("loading {}", p.display())),
        None => Ok(Config::default()),
    }
}
