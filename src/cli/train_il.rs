//! `jetpilot train il`: imitation learning (behaviour cloning) on demonstrations, with the
//! cargo feature `train`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::policy::ModelContract;
use jetpilot::train::TrainDevice;
use jetpilot::train::augment::Augment;
use jetpilot::train::data::{self, LabelMap};
use jetpilot::train::il::{self, IlOptions};

use super::train::{Head, config};

#[derive(Debug, clap::Args)]
pub struct IlArgs {
    /// A tub or JetBot xy folder (repeat for several).
    #[arg(long, value_name = "DIR", required = true)]
    data: Vec<PathBuf>,
    /// Output folder (created).
    #[arg(short, long, value_name = "DIR")]
    out: PathBuf,
    /// Config giving the steering gains (labels of speed_steering models are the law
    /// inverted on the recorded wheels) and the model contract (`[model]`).
    #[arg(short, long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Start from `imagenet` (ImageNet weights: EfficientNet-Lite0 from
    /// scripts/install-imagenet-weights.sh, or with --arch resnet18 torchvision's
    /// resnet18-f37072fd.pth from torch's cache), an ONNX file (our export, or torchvision's
    /// or the Lite0 port's layout from PyTorch) or a PyTorch state dict (.pth); a head of
    /// another size (an ImageNet classifier's 1000) is replaced by a fresh 2-output one.
    /// Default: random weights.
    #[arg(long, value_name = "imagenet|FILE")]
    init: Option<PathBuf>,
    /// The network: of a random start, or of a .pth --init (an ONNX file says its own).
    /// Default: efficientnet-lite0 for --init imagenet, else resnet18.
    #[arg(long, value_enum)]
    arch: Option<super::model::ArchArg>,
    /// BatchNorm momentum while training (PyTorch's convention, the batch statistic's
    /// weight; default 0.1).
    #[arg(long, value_name = "M")]
    bn_momentum: Option<f64>,
    /// Keep every BatchNorm's running statistics (the start's, ImageNet's for a pretrained
    /// start) and normalise with them in training too; their scale and shift still learn.
    /// `--freeze-bn false` lets them follow the batches. Default: on for `--init imagenet`
    /// or a .pth (the pretrained starts' recipe, docs/results/pretrained-backbones.md),
    /// off otherwise.
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL")]
    freeze_bn: Option<bool>,
    /// The backbone's learning rate as a share of --lr (the output layer always has --lr);
    /// below 1 keeps more of a pretrained backbone; 0 freezes it, BatchNorm statistics
    /// included, and trains the output layer alone (a linear probe, several times faster).
    #[arg(long, default_value_t = 1.0, value_name = "SHARE")]
    backbone_lr: f64,
    /// Network input size (default: an ONNX --init's own, as a probe on cells needs;
    /// otherwise the config's `model.input_size`).
    #[arg(long, value_parser = clap::value_parser!(u32).range(32..=1024))]
    input_size: Option<u32>,
    /// What the outputs mean (default: the config's `model.output`).
    #[arg(long, value_enum)]
    head: Option<Head>,
    #[arg(long, default_value_t = 50)]
    epochs: usize,
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u64).range(2..=4096))]
    batch: u64,
    /// Adam learning rate (default 1e-3; 1e-4 for `--init imagenet` or a .pth, the
    /// pretrained starts' recipe). From a `train probe` model give a low rate, e.g. 1e-5:
    /// 1e-3 throws its fitted head away.
    #[arg(long)]
    lr: Option<f64>,
    /// Share of the demonstrations held out to pick the best epoch.
    #[arg(long, default_value_t = 0.1)]
    test_fraction: f32,
    /// Leave the latest FRACTION of --data's frames by capture time out of training
    /// altogether (the frames `jetpilot score --split-by-time FRACTION` scores); the best
    /// epoch is then picked among the earlier ones.
    #[arg(long, value_name = "FRACTION")]
    leave_latest: Option<f32>,
    /// Seed of the split, the shuffles, the augmentation and a random initialisation.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// No flip and no colour jitter.
    #[arg(long)]
    no_augment: bool,
    /// xy heads: shift each picture by up to this fraction of its side, the target with it
    /// (0: off, JetBot's notebook; 0.25: up to a quarter of the frame).
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    shift: f32,
    /// Share of the images (0..1) given a random convolution (RandConv: a random 1x1 to 7x7
    /// colour filter blended with the picture, so textures and colours vary and shapes
    /// stay); 0: off.
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    rand_conv: f32,
    /// Frames mixed into every epoch (repeat for several folders): sim demonstrations while
    /// fine-tuning on real frames, say. Never held out: the best epoch is picked on --data.
    #[arg(long, value_name = "DIR")]
    mix: Vec<PathBuf>,
    /// The --mix frames' share of each epoch's images, 0..0.95 (default 0.5: as many as
    /// --data's training frames).
    #[arg(long, value_name = "FRACTION")]
    mix_share: Option<f32>,
    /// Continue after the last finished epoch in --out (last.onnx and Adam's state
    /// il_optim.bpk).
    #[arg(long)]
    resume: bool,
    /// Threads decoding images (default: the number of cores).
    #[arg(long)]
    decode_threads: Option<usize>,
    #[command(flatten)]
    target: DeviceArg,
}

/// `--device`, shared by `train il`, `train ddpg` and `train bench`.
#[derive(Debug, clap::Args)]
pub struct DeviceArg {
    /// Where the networks train: flex (burn's CPU backend) or, with the build feature
    /// `train-wgpu`, wgpu (a GPU through Vulkan, Metal or DX12; NVIDIA's too) or one
    /// adapter: wgpu:discrete[:N], wgpu:integrated[:N], wgpu:cpu (a software driver).
    #[arg(long, default_value = "flex", value_name = "DEVICE")]
    pub device: TrainDevice,
}

/// Fewer held-out frames than this make `best.onnx` a noisy pick (`train il` warns).
const FEW_HELD_OUT: usize = 25;

pub fn main(args: IlArgs) -> anyhow::Result<ExitCode> {
    let cfg = config(args.config.as_ref())?;
    let mut contract: ModelContract = cfg.model.fallback_contract();
    let start = super::train_init::resolve(args.init.as_deref(), args.arch.map(Into::into))?;
    super::train_init::adopt_normalisation(&start, &mut contract);
    match (args.input_size, &start.contract) {
        (Some(s), _) => contract.input_size = s,
        (None, Some(own)) if own.input_size != contract.input_size => {
            tracing::info!(
                "input size {} from the --init model (the config says {}; --input-size overrides)",
                own.input_size,
                contract.input_size
            );
            contract.input_size = own.input_size;
        }
        _ => {}
    }
    if let Some(h) = args.head {
        contract.output = h.into();
    }
    if !(0.0..1.0).contains(&args.test_fraction) {
        anyhow::bail!(
            "--test-fraction must be in 0..1, got {}",
            args.test_fraction
        );
    }
    if let Some(f) = args.leave_latest {
        anyhow::ensure!(
            f > 0.0 && f < 1.0,
            "--leave-latest must be between 0 and 1 (exclusive), got {f}"
        );
    }
    il::check_rand_conv(args.rand_conv, &args.out)?;
    let labels = LabelMap::new(contract.output, &cfg.control.gains());
    let threads = args.decode_threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(2)
    });
    let t0 = std::time::Instant::now();
    let mix_share = args.mix_share.unwrap_or(0.5);
    il::check_mix_share(mix_share, &args.out)?;
    if args.mix.is_empty() && args.mix_share.is_some() {
        tracing::warn!("--mix-share without --mix: there is nothing to mix in");
    }
    let mut dataset = data::load(&args.data, &contract, &labels, threads, args.leave_latest)?;
    if !args.mix.is_empty() {
        let mix = data::load(&args.mix, &contract, &labels, threads, None).context("--mix")?;
        dataset.mix_in(mix)?;
    }
    const SHOWN: usize = 20;
    for w in dataset.warnings.iter().take(SHOWN) {
        tracing::warn!("{w}");
    }
    if dataset.warnings.len() > SHOWN {
        tracing::warn!("... and {} more warnings", dataset.warnings.len() - SHOWN);
    }
    if let Some(f) = args.leave_latest {
        tracing::info!(
            "split by capture time: learning from the earliest frames, leaving the latest {} ({f}) out",
            dataset.left_out
        );
    }
    tracing::info!(
        samples = dataset.own(),
        mixed_in = dataset.samples.len() - dataset.own(),
        size = contract.input_size,
        output = contract.output.as_str(),
        seconds = format!("{:.1}", t0.elapsed().as_secs_f64()),
        "demonstrations decoded"
    );
    let mut opts = IlOptions::paper(args.out.clone(), contract, labels);
    // A state dict (ImageNet's, or a .pth) is a pretrained classifier whose head is
    // replaced: its recipe, chosen on real frames, is frozen statistics and a low rate.
    let pretrained = start.init.is_some() && start.contract.is_none();
    opts.init = start.init;
    opts.arch = start.arch;
    if let Some(m) = args.bn_momentum {
        anyhow::ensure!(
            (0.0..=1.0).contains(&m),
            "--bn-momentum must be in 0..1, got {m}"
        );
        opts.bn_momentum = m;
    }
    anyhow::ensure!(
        args.backbone_lr.is_finite() && args.backbone_lr >= 0.0,
        "--backbone-lr must be 0 or more (a share of --lr), got {}",
        args.backbone_lr
    );
    opts.freeze_bn = args.freeze_bn.unwrap_or(pretrained);
    opts.lr = args.lr.unwrap_or(if pretrained { 1e-4 } else { 1e-3 });
    if pretrained && (args.freeze_bn.is_none() || args.lr.is_none()) {
        tracing::info!(
            freeze_bn = opts.freeze_bn,
            lr = opts.lr,
            "a pretrained start: its fine-tuning recipe (--freeze-bn and --lr override)"
        );
    }
    if start.contract.is_some() && args.lr.is_none() {
        tracing::warn!(
            lr = opts.lr,
            "an ONNX start keeps its output layer, and --lr defaults to 1e-3: that suits a model `train il` made, but throws away the head of a `train probe` model (scripts/lp-ft.sh chose 1e-5 or 1e-4 on the real sets); give --lr to choose"
        );
    }
    opts.backbone_lr = args.backbone_lr;
    opts.epochs = args.epochs;
    opts.batch = args.batch as usize;
    opts.test_fraction = args.test_fraction;
    opts.seed = args.seed;
    opts.resume = args.resume;
    opts.device = args.target.device;
    opts.progress = !cfg!(test);
    if args.no_augment {
        opts.augment = Augment::NONE;
    }
    opts.augment.shift = args.shift;
    opts.augment.rand_conv = args.rand_conv;
    opts.mix_share = mix_share;
    let report = il::train(&dataset, &opts, |e| {
        tracing::info!(
            epoch = e.epoch,
            train_loss = format!("{:.5}", e.train_loss),
            test_loss = format!("{:.5}", e.test_loss),
            images_per_s = format!("{:.1}", e.images_per_s),
            "epoch done"
        );
    })?;
    if let Some(w) = &report.plot_warning {
        tracing::warn!("{w}");
    }
    println!(
        "imitation learning: {} epochs on {} train / {} test frames; best test loss {:.5} at epoch {} -> {}",
        report.state.epochs_done,
        report.train_samples,
        report.test_samples,
        report.state.best_test_loss,
        report.state.best_epoch,
        report.best_path.display()
    );
    if report.test_samples == 0 {
        tracing::warn!(
            "no frames held out (--test-fraction 0): best.onnx is the epoch with the lowest \
             training loss{}",
            if report.mixed_pool > 0 {
                ", mixed-in frames included"
            } else {
                ""
            }
        );
    } else if report.test_samples < FEW_HELD_OUT {
        tracing::warn!(
            "best.onnx is the epoch with the lowest loss on only {} held-out frame(s), a noisy pick; \
             last.onnx is the whole budget's result (docs/results/sim-to-real.md, \"Seeds, the picked epoch\")",
            report.test_samples
        );
    }
    if report.mixed_pool > 0 {
        println!(
            "mixed in: {} frames an epoch from {} (--mix, {:.0} % of each epoch's images)",
            report.mixed_per_epoch,
            report.mixed_pool,
            100.0 * report.mixed_per_epoch as f64
                / (report.mixed_per_epoch + report.train_samples).max(1) as f64
        );
    }
    println!(
        "log: {}  curve: {}",
        il::csv_path(&args.out).display(),
        il::png_path(&args.out).display()
    );
    if dataset.skipped > 0 {
        println!(
            "skipped {} unreadable image(s): empty, truncated or missing files (named in the warnings above)",
            dataset.skipped
        );
    }
    Ok(ExitCode::SUCCESS)
}
