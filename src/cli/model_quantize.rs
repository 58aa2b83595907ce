//! `jetpilot model quantize`: an int8 QDQ copy of a float model, calibrated on frames from
//! tubs or JetBot xy folders, refused when its outputs stray too far from the original's.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::control::SteeringGains;
use jetpilot::dataset::labelled::{self, LabelMap, LabelledFrame};
use jetpilot::policy::onnx::{self, ModelProto};
use jetpilot::policy::quantize::calibrate::{self, Runner};
use jetpilot::policy::quantize::{ActivationType, FloatConvs, Prepared, QdqOptions, RangeMethod};
use jetpilot::policy::{ModelContract, OutputKind, Preprocessor};
use prost::Message;

#[derive(Debug, clap::Args)]
pub struct QuantizeArgs {
    /// The float32 model (ResNet-18 or EfficientNet-Lite0, from `train il`, `train probe`, `train ddpg` or `model init`).
    input: PathBuf,
    /// Where to write the int8 model.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// Frames to calibrate on: a tub or a JetBot xy folder (repeat for several). Use frames
    /// like those the robot will see.
    #[arg(long, value_name = "DIR", required = true)]
    calibration: Vec<PathBuf>,
    /// How each activation's range is chosen.
    #[arg(long, value_enum, default_value = "percentile")]
    method: Method,
    /// For `--method percentile`: the share of values inside the range, in percent.
    #[arg(long, default_value_t = 99.99, value_name = "PERCENT")]
    percentile: f64,
    /// Calibration frames, picked evenly by capture time.
    #[arg(long, default_value_t = 200, value_name = "N")]
    frames: usize,
    /// Hold out the latest FRACTION of the frames by capture time: not calibrated on, used
    /// to report the difference on frames calibration never saw.
    #[arg(long, default_value_t = 0.2, value_name = "FRACTION")]
    holdout: f32,
    /// Refuse the model (write nothing) if any output differs from the float model's by
    /// more than this on a calibration frame.
    #[arg(long, default_value_t = 0.1)]
    tolerance: f32,
    /// Integer type of the activations: uint8 suits ONNX Runtime's x86 kernels, int8 some
    /// ARM ones. Weights are always int8.
    #[arg(long, value_enum, default_value = "u8")]
    activations: Activations,
    /// 7-bit weights, for x86 CPUs whose int8 kernels can saturate (no AVX-VNNI).
    #[arg(long)]
    reduce_range: bool,
    /// Leave the last N convolutions in float32 (weights and outputs), the rest int8. For
    /// EfficientNet-Lite0, 1 is `_conv_head` (1280 channels, 5 % of its multiply-adds at 224); for
    /// ResNet-18, `layer4.1.conv2`.
    #[arg(long, default_value_t = 0, value_name = "N")]
    float_last: usize,
    /// Leave the first N convolutions in float32, the input unquantized too. For both
    /// networks 1 is the stem (`_conv_stem`, `conv1`).
    #[arg(long, default_value_t = 0, value_name = "N")]
    float_first: usize,
    /// ONNX Runtime intra-op threads (0: ONNX Runtime decides).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Method {
    Minmax,
    Percentile,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Activations {
    U8,
    S8,
}

/// Up to `n` frames spread evenly over `frames`.
fn evenly(frames: Vec<LabelledFrame>, n: usize) -> Vec<LabelledFrame> {
    if frames.len() <= n || n == 0 {
        return frames;
    }
    let step = frames.len() as f64 / n as f64;
    (0..n)
        .map(|i| frames[(i as f64 * step) as usize].clone())
        .collect()
}

/// Decodes and preprocesses frames; unreadable ones are skipped with a warning naming each.
fn load(frames: &[LabelledFrame], contract: &ModelContract) -> anyhow::Result<Vec<Vec<f32>>> {
    let mut pre = Preprocessor::new(contract);
    let mut out = Vec::with_capacity(frames.len());
    for f in frames {
        match jetpilot::dataset::load_rgb(&f.path) {
            Ok((w, h, rgb)) => out.push(
                pre.run(w, h, &rgb)
                    .with_context(|| format!("preprocessing {}", f.path.display()))?
                    .to_vec(),
            ),
            Err(e) => tracing::warn!(
                "{}: skipped, {}",
                f.path.display(),
                jetpilot::dataset::short_reason(&e)
            ),
        }
    }
    Ok(out)
}

fn read_model(path: &Path) -> anyhow::Result<(ModelProto, ModelContract)> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut model = ModelProto::decode(&bytes[..])
        .with_context(|| format!("not an ONNX model: {}", path.display()))?;
    let metadata = model
        .metadata_props
        .iter()
        .map(|e| (e.key.clone(), e.value.clone()))
        .collect();
    let contract = ModelContract::from_metadata(&metadata)
        .with_context(|| format!("model {}", path.display()))?
        .with_context(|| {
            format!(
                "model {}: no jetpilot contract in its metadata (input size, normalisation): quantize a model from `train il`, `train ddpg` or `model init`",
                path.display()
            )
        })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    onnx::external::inline(&mut model, dir)?;
    Ok((model, contract))
}

pub fn main(args: QuantizeArgs) -> anyhow::Result<ExitCode> {
    if !(args.holdout >= 0.0 && args.holdout < 1.0) {
        anyhow::bail!("--holdout must be in [0, 1), got {}", args.holdout);
    }
    if !(args.percentile > 50.0 && args.percentile <= 100.0) {
        anyhow::bail!("--percentile must be in (50, 100], got {}", args.percentile);
    }
    let (model, contract) = read_model(&args.input)?;
    let prepared = Prepared::new(
        &model,
        FloatConvs {
            first: args.float_first,
            last: args.float_last,
        },
    )
    .with_context(|| format!("model {}", args.input.display()))?;

    // Calibration reads the frames only, so a folder labelled for the other head serves too
    // (a JetBot xy folder for a speed_steering model, a tub for an xy one).
    let gains = SteeringGains::default();
    let other = match contract.output {
        OutputKind::Xy => OutputKind::SpeedSteering,
        OutputKind::SpeedSteering => OutputKind::Xy,
    };
    let (map, other_map) = (
        LabelMap::new(contract.output, &gains),
        LabelMap::new(other, &gains),
    );
    let mut frames = Vec::new();
    for dir in &args.calibration {
        let listing = labelled::list(dir, &map)
            .or_else(|first| labelled::list(dir, &other_map).map_err(|_| first))
            .with_context(|| format!("calibration data {}", dir.display()))?;
        for w in &listing.warnings {
            tracing::warn!("{w}");
        }
        frames.extend(listing.frames);
    }
    if frames.is_empty() {
        anyhow::bail!("no frames in the calibration data");
    }
    let (calib, held) = if frames.iter().all(|f| f.time_s.is_some()) {
        labelled::split_by_time(frames, args.holdout)?
    } else {
        tracing::warn!("some frames have no capture time: the held-out frames are the last listed");
        let n_held = (frames.len() as f32 * args.holdout).round() as usize;
        let held = frames.split_off(frames.len() - n_held.min(frames.len()));
        (frames, held)
    };
    let calib = load(&evenly(calib, args.frames), &contract)?;
    let held = load(&evenly(held, args.frames / 2), &contract)?;
    if calib.is_empty() {
        anyhow::bail!("none of the calibration frames could be read (see the warnings above)");
    }
    let method = match args.method {
        Method::Minmax => RangeMethod::MinMax,
        Method::Percentile => RangeMethod::Percentile(args.percentile / 100.0),
    };
    let opts = QdqOptions {
        activations: match args.activations {
            Activations::U8 => ActivationType::U8,
            Activations::S8 => ActivationType::S8,
        },
        weight_max: if args.reduce_range { 63 } else { 127 },
    };
    println!(
        "{}: {} batch norms folded, {} activations to quantize; calibrating on {} frames ({} held out)",
        args.input.display(),
        prepared.folded_batch_norms,
        prepared.plan.len(),
        calib.len(),
        held.len()
    );
    let size = contract.input_size;
    let ranges = calibrate::ranges(&prepared, size, &calib, method, args.threads)?;
    let method_text = match method {
        RangeMethod::MinMax => "min-max".to_string(),
        RangeMethod::Percentile(_) => format!("percentile {}", args.percentile),
    };
    let float_text = match (args.float_first, args.float_last) {
        (0, 0) => String::new(),
        (0, n) => format!(", the last {n} convolution(s) float32"),
        (n, 0) => format!(", the first {n} convolution(s) float32"),
        (f, l) => format!(", the first {f} and the last {l} convolution(s) float32"),
    };
    let note = format!(
        "int8 QDQ: per-channel symmetric {}-bit weights, {} activations{float_text}, {method_text} ranges from {} frames of {}",
        if args.reduce_range { 7 } else { 8 },
        opts.activations.as_str(),
        calib.len(),
        args.calibration
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let quantized = prepared.quantize(&ranges, opts, &note)?;

    let mut float = Runner::new(&model, size, args.threads, "the float model")?;
    let mut int8 = Runner::new(&quantized, size, args.threads, "the quantized model")?;
    let on_calib = calibrate::compare(&mut float, &mut int8, &calib)?;
    println!(
        "output difference on the calibration frames: max {:.4}, mean {:.4} ({} frames)",
        on_calib.max, on_calib.mean, on_calib.frames
    );
    if !held.is_empty() {
        let on_held = calibrate::compare(&mut float, &mut int8, &held)?;
        println!(
            "output difference on the held-out frames:    max {:.4}, mean {:.4} ({} frames)",
            on_held.max, on_held.mean, on_held.frames
        );
    }
    if on_calib.max.is_nan() || on_calib.max > args.tolerance {
        anyhow::bail!(
            "refused: the quantized outputs differ from the float model's by up to {:.4} (mean {:.4}) on {} calibration frames, more than --tolerance {}; nothing written to {}. Try --method percentile with a lower --percentile, --reduce-range, or calibration frames closer to what the robot sees",
            on_calib.max,
            on_calib.mean,
            on_calib.frames,
            args.tolerance,
            args.output.display()
        );
    }
    let bytes = |p: &Path| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
    onnx::write_model(&args.output, &quantized)?;
    let fused = calibrate::optimized_op_counts(&quantized)?;
    let count = |op: &str| fused.get(op).copied().unwrap_or(0);
    println!(
        "wrote {} ({:.1} MB, the float model {:.1} MB); ONNX Runtime runs {} convolutions as QLinearConv ({} left in float), {} additions as QLinearAdd",
        args.output.display(),
        bytes(&args.output) as f64 / 1e6,
        bytes(&args.input) as f64 / 1e6,
        count("QLinearConv"),
        count("Conv") + count("FusedConv"),
        count("QLinearAdd"),
    );
    Ok(ExitCode::SUCCESS)
}
