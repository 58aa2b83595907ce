//! `jetpilot score`: a model on labelled frames (JetBot xy folders, tubs), through the
//! daemon's own preprocessing and ONNX Runtime session, against the mean-label baseline;
//! writes a per-frame CSV and a picture of the frames with label and prediction.

use std::cmp::Ordering;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::config::Config;
use jetpilot::control::SteeringGains;
use jetpilot::dataset::labelled::{self, LabelMap, LabelledFrame};
use jetpilot::policy::contract::ChannelOrder;
use jetpilot::policy::ort_policy::{ContractSource, OrtOptions};
use jetpilot::policy::{ModelContract, OrtPolicy, OutputKind, Policy, Preprocessor};
use jetpilot::score::{self, Scorecard, agreement, sheet};

#[derive(Debug, clap::Args)]
pub struct ScoreArgs {
    /// The ONNX model to score.
    #[arg(long, value_name = "FILE")]
    model: PathBuf,
    /// Labelled frames: a JetBot xy folder (xy_XXX_YYY_<uuid>.jpg) or a tub; repeat for
    /// several.
    #[arg(long, value_name = "DIR", required = true)]
    data: Vec<PathBuf>,
    /// Score only the latest FRACTION of the frames by capture time (the uuid1 in JetBot
    /// file names, tub timestamps); the baseline's mean label comes from the earlier ones.
    /// Neighbouring frames are near-duplicates, so this is the honest test split.
    #[arg(long, value_name = "FRACTION")]
    split_by_time: Option<f32>,
    /// Where the per-frame CSV and the picture go (default: score-<model name>).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Frames in the picture, worst first.
    #[arg(long, default_value_t = 48, value_name = "N")]
    grid: usize,
    /// Config whose steering gains turn a tub's wheel commands into speed_steering labels.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// For a model without jetpilot metadata (JetBot's notebook exports feed BGR): the
    /// channel order its input expects.
    #[arg(long, value_enum, default_value = "rgb")]
    channel_order: Order,
    /// ONNX Runtime intra-op threads (0: ONNX Runtime decides).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Occlusion maps of the N worst frames (explain.png, explain.csv): a grey square laid
    /// on each part of the frame in turn shows how far the answer moves, i.e. what the
    /// policy looks at. Costs (map cells + 1) model runs per frame: 170 at the default.
    #[arg(long, default_value_t = 0, value_name = "N")]
    explain: usize,
    /// Side of --explain's grey squares in input pixels (default: a seventh of the input).
    #[arg(long, value_name = "PX", requires = "explain")]
    explain_patch: Option<usize>,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Order {
    Rgb,
    Bgr,
}

/// One scored frame.
struct Scored {
    frame: LabelledFrame,
    label: [f32; 2],
    prediction: [f32; 2],
    error: f64,
    /// Its grey thumbnail, for the labels' agreement.
    thumb: Vec<u8>,
}

pub fn main(args: ScoreArgs) -> anyhow::Result<ExitCode> {
    if let Some(f) = args.split_by_time
        && !(f > 0.0 && f < 1.0)
    {
        anyhow::bail!("--split-by-time must be between 0 and 1 (exclusive), got {f}");
    }
    let fallback = ModelContract {
        channel_order: match args.channel_order {
            Order::Rgb => ChannelOrder::Rgb,
            Order::Bgr => ChannelOrder::Bgr,
        },
        ..ModelContract::default()
    };
    let mut policy = OrtPolicy::load(
        &args.model,
        &OrtOptions::cpu(args.threads, false, &fallback),
    )?;
    let contract = policy.contract().clone();
    println!(
        "model {}: {} head, {s}x{s} {} input ({})",
        args.model.display(),
        contract.output.as_str(),
        contract.channel_order.as_str(),
        match policy.contract_source() {
            ContractSource::ModelMetadata => "contract from the model's metadata",
            ContractSource::Config =>
                "no jetpilot metadata: JetBot's defaults, the size from the model's input",
        },
        s = contract.input_size,
    );
    let gains = match &args.config {
        Some(path) => Config::load(path)?.control.gains(),
        None => SteeringGains::default(),
    };
    let map = LabelMap::new(contract.output, &gains);

    let mut frames = Vec::new();
    let mut warnings = Vec::new();
    for dir in &args.data {
        let listing =
            labelled::list(dir, &map).with_context(|| format!("data {}", dir.display()))?;
        println!(
            "data {}: {} labelled frames",
            dir.display(),
            listing.frames.len()
        );
        frames.extend(listing.frames);
        warnings.extend(listing.warnings);
    }
    let (reference, scored_frames) = match args.split_by_time {
        Some(f) => {
            let (train, test) = labelled::split_by_time(frames, f)?;
            println!(
                "split by capture time: the latest {} frames are scored, the earlier {} give the baseline's mean label",
                test.len(),
                train.len()
            );
            (Some(train), test)
        }
        None => (None, frames),
    };
    if scored_frames.is_empty() {
        anyhow::bail!("no frames to score (the split left none)");
    }

    // Run the model on every frame that can be read.
    let mut pre = Preprocessor::new(&contract);
    let mut scored = Vec::with_capacity(scored_frames.len());
    let mut skipped = 0usize;
    for frame in scored_frames {
        let (w, h, rgb) = match jetpilot::dataset::load_rgb(&frame.path) {
            Ok(img) => img,
            Err(e) => {
                skipped += 1;
                warnings.push(format!(
                    "{}: skipped, {}",
                    frame.path.display(),
                    jetpilot::dataset::short_reason(&e)
                ));
                continue;
            }
        };
        let input = pre
            .run(w, h, &rgb)
            .with_context(|| format!("preprocessing {}", frame.path.display()))?;
        let prediction = policy
            .infer(input)
            .with_context(|| format!("inference on {}", frame.path.display()))?;
        let label = frame.label.value(w, h);
        let error = score::frame_error(contract.output, label, prediction);
        let thumb = agreement::thumbnail(w, h, &rgb);
        scored.push(Scored {
            frame,
            label,
            prediction,
            error,
            thumb,
        });
    }
    for w in &warnings {
        tracing::warn!("{w}");
    }
    if scored.is_empty() {
        anyhow::bail!(
            "none of the frames could be read ({skipped} skipped: see the warnings above)"
        );
    }

    let labels: Vec<[f32; 2]> = scored.iter().map(|s| s.label).collect();
    let predictions: Vec<[f32; 2]> = scored.iter().map(|s| s.prediction).collect();
    let (baseline_label, baseline_from) = match &reference {
        Some(train) if !train.is_empty() => (
            score::mean_label(&reference_labels(train)),
            "the earlier frames' mean label",
        ),
        _ => (
            score::mean_label(&labels),
            "the scored frames' own mean label",
        ),
    };
    let card = Scorecard::new(contract.output, &labels, &predictions, baseline_label);
    let what = match contract.output {
        OutputKind::Xy => "pixel error in the 224x224 frame",
        OutputKind::SpeedSteering => "error",
    };
    println!("{what} over {} frames:", card.frames);
    println!("  model     {}", card.model);
    println!(
        "  baseline  {}   (always ({:.3}, {:.3}): {baseline_from})",
        card.baseline, baseline_label[0], baseline_label[1]
    );
    println!("  model / baseline: {:.2}", card.ratio());
    // Does the model follow the labels, or answer about the same everywhere?
    let tracking = score::Tracking::of(&labels, &predictions);
    match contract.output {
        OutputKind::Xy => println!(
            "  tracking  {:.1} (px)",
            tracking.scaled(score::JETBOT_FRAME_PX as f64 / 2.0)
        ),
        OutputKind::SpeedSteering => println!("  tracking  {tracking}"),
    }
    if reference.as_ref().is_some_and(|train| !train.is_empty()) {
        // What a constant that knew the scored frames' own mean would score: below it, a
        // model has learnt more than where the labels sit on average.
        let own = score::mean_label(&labels);
        let oracle = Scorecard::new(contract.output, &labels, &predictions, own);
        println!(
            "  constant at the scored frames' own mean label ({:.3}, {:.3}): {} ({:.2} of the baseline)",
            own[0],
            own[1],
            oracle.baseline,
            oracle.baseline.headline() / card.baseline.headline().max(1e-12)
        );
    }

    print_agreement(
        contract.output,
        reference.as_deref().unwrap_or_default(),
        &scored,
        card.baseline.headline(),
    );

    let out = args.out.clone().unwrap_or_else(|| default_out(&args.model));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let csv = out.join("frames.csv");
    std::fs::write(&csv, frames_csv(&scored))
        .with_context(|| format!("writing {}", csv.display()))?;
    // Only the frames in the picture are decoded again: a whole tub's frames are not kept
    // in memory for it.
    let mut order: Vec<&Scored> = scored.iter().collect();
    order.sort_by(|a, b| b.error.total_cmp(&a.error));
    let pictures: Vec<_> = order
        .into_iter()
        .take(args.grid)
        .filter_map(|s| Some((s, jetpilot::dataset::load_rgb(&s.frame.path).ok()?)))
        .collect();
    let tiles: Vec<sheet::Tile<'_>> = pictures
        .iter()
        .map(|(s, (w, h, rgb))| sheet::Tile {
            rgb,
            width: *w,
            height: *h,
            label: s.label,
            prediction: s.prediction,
        })
        .collect();
    let png = out.join("frames.png");
    sheet::draw(contract.output, &tiles, 8, 112)
        .save(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    println!(
        "wrote {} (every frame) and {} ({} frames, worst first; green: label, red: model)",
        csv.display(),
        png.display(),
        tiles.len()
    );
    if args.explain > 0 {
        let mut worst: Vec<&Scored> = scored.iter().collect();
        worst.sort_by(|a, b| b.error.total_cmp(&a.error));
        let frames: Vec<super::score_explain::Worst<'_>> = worst
            .into_iter()
            .take(args.explain)
            .map(|s| super::score_explain::Worst {
                path: &s.frame.path,
                label: s.label,
                prediction: s.prediction,
                error: s.error,
            })
            .collect();
        super::score_explain::write(&mut policy, &contract, &frames, args.explain_patch, &out)?;
    }
    if skipped > 0 {
        println!("skipped {skipped} unreadable image(s), named in the warnings above");
    }
    Ok(ExitCode::SUCCESS)
}

/// How far the labels of all the frames (scored or not) disagree on near-duplicates: the
/// error a model cannot be expected to beat. The scored frames' thumbnails were made while
/// scoring; only the baseline's frames are decoded here, and unreadable ones are left out.
/// Frames are compared in capture order where every frame has a time.
fn print_agreement(
    output: OutputKind,
    reference: &[LabelledFrame],
    scored: &[Scored],
    baseline: f64,
) {
    let mut views: Vec<(Option<f64>, Vec<u8>, [f32; 2])> = reference
        .iter()
        .filter_map(|f| {
            let (w, h, rgb) = jetpilot::dataset::load_rgb(&f.path).ok()?;
            Some((
                f.time_s,
                agreement::thumbnail(w, h, &rgb),
                f.label.value(w, h),
            ))
        })
        .collect();
    views.extend(
        scored
            .iter()
            .map(|s| (s.frame.time_s, s.thumb.clone(), s.label)),
    );
    if views.iter().all(|v| v.0.is_some()) {
        views.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap_or(Ordering::Equal));
    }
    let (thumbs, labels): (Vec<Vec<u8>>, Vec<[f32; 2]>) =
        views.into_iter().map(|(_, t, l)| (t, l)).unzip();
    let a = agreement::agreement(output, &thumbs, &labels);
    let Some(d) = a.disagreement else {
        println!(
            "  labels    no two neighbouring frames of the {} show the same view: their agreement cannot be checked",
            a.frames
        );
        return;
    };
    let unit = match output {
        OutputKind::Xy => format!("mean {:.1} px, median {:.1} px", d.mean, d.median),
        OutputKind::SpeedSteering => format!("mean {:.4}, median {:.4}", d.mean, d.median),
    };
    println!(
        "  labels    {} of {} frames share their view with a neighbour ({} view(s) labelled more than once); a label lies {unit} from its view's mean label ({:.2} of the baseline): about the least error a model can reach here",
        a.duplicated,
        a.frames,
        a.groups,
        d.mean / baseline.max(1e-12)
    );
}

/// The labels of the baseline's frames; xy pixel labels need each image's size, read from
/// its header (a file whose header cannot be read is left out of the mean).
fn reference_labels(frames: &[LabelledFrame]) -> Vec<[f32; 2]> {
    frames
        .iter()
        .filter_map(|f| {
            let (w, h) = image::image_dimensions(&f.path).ok()?;
            Some(f.label.value(w, h))
        })
        .collect()
}

fn default_out(model: &Path) -> PathBuf {
    let stem = model
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "model".into());
    PathBuf::from(format!("score-{stem}"))
}

fn frames_csv(scored: &[Scored]) -> String {
    let mut s = String::from("file,time_s,label_0,label_1,prediction_0,prediction_1,error\n");
    for f in scored {
        let _ = writeln!(
            s,
            "{},{},{:.5},{:.5},{:.5},{:.5},{:.4}",
            f.frame.path.display(),
            f.frame
                .time_s
                .map(|t| format!("{t:.3}"))
                .unwrap_or_default(),
            f.label[0],
            f.label[1],
            f.prediction[0],
            f.prediction[1],
            f.error
        );
    }
    s
}
