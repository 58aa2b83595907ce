//! `jetpilot train probe`: a pretrained backbone as it is, its output layer fitted by
//! ridge regression on the frames' pooled features (`fit::probe`), in seconds.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::dataset::labelled::{self, LabelMap, LabelledFrame};
use jetpilot::fit::probe::{self, FeatureSession, Pooling};
use jetpilot::policy::onnx::{NetWeights, write_model};
use jetpilot::policy::{ModelContract, OutputKind, pytorch};

#[derive(Debug, clap::Args)]
pub struct ProbeArgs {
    /// A JetBot xy folder or a tub (repeat for several).
    #[arg(long, value_name = "DIR", required = true)]
    data: Vec<PathBuf>,
    /// Output folder (created): probe.onnx and probe_cv.csv.
    #[arg(short, long, value_name = "DIR")]
    out: PathBuf,
    /// Config giving the steering gains (speed_steering labels) and `[model]`.
    #[arg(short, long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// The backbone: `imagenet` (see `train il --init`), a PyTorch state dict (.pth) or an
    /// ONNX file (its own output layer is replaced).
    #[arg(long, value_name = "imagenet|FILE", default_value = "imagenet")]
    init: PathBuf,
    /// The network of `imagenet` or a .pth (default: efficientnet-lite0 for imagenet, else
    /// resnet18).
    #[arg(long, value_enum)]
    arch: Option<super::model::ArchArg>,
    /// Network input size (default: the config's `model.input_size`). The ImageNet
    /// backbones were trained at 224.
    #[arg(long, value_parser = clap::value_parser!(u32).range(32..=1024))]
    input_size: Option<u32>,
    /// What the outputs mean (default: the config's `model.output`).
    #[arg(long, value_enum)]
    head: Option<super::train::Head>,
    /// The ridge strength (on standardised features). Default: chosen among 13, from
    /// 10^-3 to 10^3 times the head's width, by cross-validation over blocks of capture
    /// time (--folds).
    #[arg(long, value_name = "LAMBDA")]
    strength: Option<f64>,
    /// Pool the backbone's final feature map into GRID x GRID cells, not into one: the
    /// head then sees where in the picture things are (1: the network's own global
    /// pooling; at most the map's side, 7 at 224). `auto`: 1, 2 and 3, the one with the
    /// lowest cross-validated error. A grid above 1 writes a head on the whole map (for
    /// `score`, `run`, and an EfficientNet-Lite0's for `train il --init` at the same
    /// `--input-size`: a probe, then a fine-tune; `train ddpg --init` takes 1x1 pooled
    /// heads only).
    #[arg(long, default_value = "auto", value_name = "auto|GRID")]
    grid: GridArg,
    /// Fit on the frames' mirror images too (x or steering negated): `on`, `off`, or
    /// `auto`, both ways, the one with the lower cross-validated error. (Globally pooled
    /// ImageNet features hardly change when a picture is mirrored, so mirrored copies with
    /// the opposite x teach a pooled head to answer x = 0.)
    #[arg(long, value_enum, default_value = "auto")]
    mirror: MirrorArg,
    /// How the cross-validation picks the pooling and strength: `lowest` error, or
    /// `one-se`, the simplest within one standard error of the lowest (more cautious; in
    /// docs/results/pretrained-backbones.md it scored worse at 50 to 246 frames). Either
    /// way a pick that does not beat the mean label by its standard error is replaced by
    /// the mean label, with a warning.
    #[arg(long, value_enum, default_value = "lowest")]
    choose: ChooseArg,
    /// Cross-validation folds: contiguous blocks of the frames in capture time.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(2..=50))]
    folds: u64,
    /// Leave the latest FRACTION of the frames by capture time out of the fit: the frames
    /// `jetpilot score --split-by-time FRACTION` scores.
    #[arg(long, value_name = "FRACTION")]
    leave_latest: Option<f32>,
    /// ONNX Runtime intra-op threads (0: ONNX Runtime decides).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum GridArg {
    Auto,
    Cells(usize),
}

impl std::str::FromStr for GridArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(GridArg::Auto),
            n => match n.parse::<usize>() {
                Ok(g) if g >= 1 => Ok(GridArg::Cells(g)),
                _ => Err(format!(
                    "`{n}`: auto or a number of cells a side (1 or more)"
                )),
            },
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ChooseArg {
    Lowest,
    OneSe,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum MirrorArg {
    Auto,
    On,
    Off,
}

/// The poolings to try: `grid` (auto: 1, 2, 3 where the map has room) by `mirror`.
fn poolings(grid: GridArg, mirror: MirrorArg, side: usize) -> Vec<Pooling> {
    let grids = match grid {
        GridArg::Auto => (1..=3.min(side)).collect(),
        GridArg::Cells(g) => vec![g],
    };
    let mirrors: &[bool] = match mirror {
        MirrorArg::Auto => &[false, true],
        MirrorArg::On => &[true],
        MirrorArg::Off => &[false],
    };
    grids
        .into_iter()
        .flat_map(|grid| mirrors.iter().map(move |&mirror| Pooling { grid, mirror }))
        .collect()
}

pub fn main(args: ProbeArgs) -> anyhow::Result<ExitCode> {
    let cfg = super::train::config(args.config.as_ref())?;
    let mut contract: ModelContract = cfg.model.fallback_contract();
    let start = super::train_init::resolve(Some(&args.init), args.arch.map(Into::into))?;
    super::train_init::adopt_normalisation(&start, &mut contract);
    if let Some(s) = args.input_size {
        contract.input_size = s;
    }
    if let Some(h) = args.head {
        contract.output = h.into();
    }
    if let Some(f) = args.leave_latest {
        anyhow::ensure!(
            f > 0.0 && f < 1.0,
            "--leave-latest must be between 0 and 1 (exclusive), got {f}"
        );
    }
    if let Some(s) = args.strength {
        anyhow::ensure!(
            s.is_finite() && s > 0.0,
            "--strength must be positive, got {s}"
        );
    }
    let init = start
        .init
        .clone()
        .context("train probe needs a backbone (--init)")?;
    let weights: NetWeights = match &start.contract {
        Some(_) => jetpilot::policy::onnx::read_net_weights(&init)?.0,
        None => pytorch::read_state_dict(&init, start.arch)?,
    };

    let map = LabelMap::new(contract.output, &cfg.control.gains());
    let frames = list_in_time_order(&args.data, &map, args.leave_latest)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let t0 = std::time::Instant::now();
    let mut session = FeatureSession::new(&weights, &contract, args.threads)?;
    let (channels, side) = (session.channels(), session.map_side());
    let candidates = poolings(args.grid, args.mirror, side);
    let mirror = candidates
        .iter()
        .any(|p| p.mirror)
        .then(|| map.mirrored_component());
    let data = probe::extract(&mut session, &frames, mirror, |done, total| {
        if done % 100 == 0 || done == total {
            tracing::info!("features of {done} / {total} frames");
        }
    })?;
    for w in &data.warnings {
        tracing::warn!("{w}");
    }
    let read = data.original.iter().filter(|o| **o).count();
    println!(
        "{} final maps ({channels}x{side}x{side}) of {read} frames{} at {s}x{s} in {:.1} s",
        weights.arch().title(),
        if mirror.is_some() {
            " and their mirror images"
        } else {
            ""
        },
        t0.elapsed().as_secs_f64(),
        s = contract.input_size,
    );
    let rule = match args.choose {
        ChooseArg::Lowest => probe::Rule::Lowest,
        ChooseArg::OneSe => probe::Rule::OneStandardError,
    };
    let chosen = probe::choose(
        &data,
        (channels, side),
        &candidates,
        contract.output,
        args.folds as usize,
        args.strength,
        rule,
    )?;
    let tried = &chosen.tried;
    let best = tried.first().context("no pooling to try")?;
    let (pooling, fitted) = (best.pooling, &best.probe);
    let out_model = args.out.join("probe.onnx");
    let head = probe::unpool_head(&fitted.head, channels, side, pooling.grid);
    let proto = probe::with_head(&weights, &head).model(
        contract.input_size,
        &contract,
        env!("CARGO_PKG_VERSION"),
    )?;
    write_model(&out_model, &proto)?;

    let describe = |p: Pooling| {
        format!(
            "grid {g}x{g}, {}",
            if p.mirror {
                "mirrored too"
            } else {
                "as recorded"
            },
            g = p.grid
        )
    };
    if !fitted.validated.is_empty() {
        let unit = match contract.output {
            OutputKind::Xy => "mean px error",
            OutputKind::SpeedSteering => "mean squared error",
        };
        println!(
            "{}-fold cross-validation over capture time ({unit} +- its standard error, each \
             at its best strength):",
            args.folds
        );
        let mut csv = String::from("grid,mirror,strength,cv_error\n");
        if let Some(c) = &chosen.constant {
            println!(
                "  {:<28} {:>9.3} +- {:<7.3}",
                "the mean label (constant)", c.error, c.standard_error
            );
        }
        for (i, t) in tried.iter().enumerate() {
            if chosen.fell_back && i == 0 {
                continue;
            }
            let mark = if i == 0 { "  <- chosen" } else { "" };
            let (error, se) = t
                .validated()
                .map_or((f64::NAN, f64::NAN), |v| (v.error, v.standard_error));
            println!(
                "  {:<28} {error:>9.3} +- {se:<7.3} (strength {:.4}){mark}",
                describe(t.pooling),
                t.probe.strength
            );
            for v in &t.probe.validated {
                let _ = writeln!(
                    csv,
                    "{},{},{},{}",
                    t.pooling.grid, t.pooling.mirror, v.strength, v.error
                );
            }
        }
        let path = args.out.join("probe_cv.csv");
        std::fs::write(&path, csv).with_context(|| format!("writing {}", path.display()))?;
        if chosen.fell_back {
            tracing::warn!(
                "no pooling beats the mean label by more than its standard error on these \
                 frames: the head written answers the mean label (more frames, or frames that \
                 vary more, give the probe something to learn)"
            );
        } else if fitted.at_strength_edge() {
            tracing::warn!(
                strength = fitted.strength,
                "the chosen strength is at the end of the grid: try --strength beyond it"
            );
        }
    }
    if chosen.fell_back {
        println!("the mean label -> {}", out_model.display());
    } else {
        println!(
            "{}, ridge strength {} -> {}",
            describe(pooling),
            fitted.strength,
            out_model.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Every folder's frames, in capture time order when they all have a time (else in the
/// listing order, with a warning), without the latest `leave_latest` of them.
fn list_in_time_order(
    dirs: &[PathBuf],
    map: &LabelMap,
    leave_latest: Option<f32>,
) -> anyhow::Result<Vec<LabelledFrame>> {
    let mut frames = Vec::new();
    for dir in dirs {
        let listing =
            labelled::list(dir, map).with_context(|| format!("data {}", dir.display()))?;
        for w in &listing.warnings {
            tracing::warn!("{w}");
        }
        frames.extend(listing.frames);
    }
    anyhow::ensure!(
        !frames.is_empty(),
        "no labelled frames in {}",
        dirs.iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let timed = frames.iter().all(|f| f.time_s.is_some());
    match (timed, leave_latest) {
        (_, Some(f)) => {
            let (train, test) = labelled::split_by_time(frames, f)?;
            println!(
                "split by capture time: fitting on the earliest {} frames, leaving the latest {} out",
                train.len(),
                test.len()
            );
            Ok(train)
        }
        (true, None) => Ok(labelled::split_by_time(frames, 0.0)?.0),
        (false, None) => {
            tracing::warn!(
                "some frames have no capture time: the cross-validation folds follow the listing order"
            );
            Ok(frames)
        }
    }
}
