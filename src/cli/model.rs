//! `jetpilot model init`, `model import` (PyTorch state dicts), `model ensemble` and
//! `model info`; `quantize` and `optimize` live in `model_quantize` and `model_optimize`.

use std::path::PathBuf;
use std::process::ExitCode;

use jetpilot::policy::onnx::{self, Arch, NetWeights};
use jetpilot::policy::pytorch;
use jetpilot::policy::{ChannelOrder, ModelContract, OutputKind};

#[derive(Debug, clap::Subcommand)]
pub enum ModelCommand {
    /// Write a randomly initialised ResNet-18 (torchvision layout, fc 512 -> 2) or
    /// EfficientNet-Lite0 (fc 1280 -> 2) with the model contract in its metadata. Untrained: it steers at random, for trying the
    /// pipeline and as the trainer's starting point.
    Init {
        #[arg(long, value_enum, default_value = "resnet18")]
        arch: ArchArg,
        /// Input width and height in pixels.
        #[arg(long, default_value_t = 224, value_parser = clap::value_parser!(u32).range(32..=1024))]
        input_size: u32,
        /// Seed of the weight initialisation (same seed, same file).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Colour plane order the model expects.
        #[arg(long, value_enum, default_value = "rgb")]
        channel_order: Order,
        /// What the two outputs mean: `xy` (JetBot target point) or `speed-steering`.
        #[arg(long, value_enum, default_value = "xy")]
        head: Head,
        /// Where to write the .onnx file.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
    },
    /// Turn a PyTorch state dict (.pth: torchvision's resnet18-f37072fd.pth, JetBot's
    /// best_steering_model_xy.pth, the ImageNet EfficientNet-Lite0 of
    /// scripts/install-imagenet-weights.sh) into our ONNX: the file's backbone, a fresh
    /// seeded 2-output head where its head has another size (an ImageNet classifier's 1000),
    /// the model contract in the metadata. No Python needed.
    Import {
        /// The .pth / .pt file (ZIP or legacy pickle, as torch.save writes them).
        file: PathBuf,
        /// The network the file holds.
        #[arg(long, value_enum)]
        arch: ArchArg,
        /// Input width and height in pixels.
        #[arg(long, default_value_t = 224, value_parser = clap::value_parser!(u32).range(32..=1024))]
        input_size: u32,
        /// What the two outputs mean: `xy` (JetBot target point) or `speed-steering`.
        #[arg(long, value_enum, default_value = "xy")]
        head: Head,
        /// Seed of the fresh head (same seed, same file).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Colour plane order the model expects (JetBot's notebook models were trained on
        /// BGR frames; ImageNet weights on RGB).
        #[arg(long, value_enum, default_value = "rgb")]
        channel_order: Order,
        /// Where to write the .onnx file.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
    },
    /// Write an int8 copy of a float model (QDQ: per-channel int8 weights, uint8
    /// activations), calibrated on frames from tubs or JetBot xy folders. Refused, with
    /// nothing written, if its outputs differ from the float model's by more than
    /// --tolerance on the calibration frames.
    Quantize(super::model_quantize::QuantizeArgs),
    /// Run ONNX Runtime's graph optimisations once and save the result, weights in
    /// OUTPUT.data beside it. The daemon loads such a file with optimisations off: a lower
    /// peak RSS at start-up, the same speed. Run it on the machine that runs the model
    /// (the robot): the file is refused on any other CPU or ONNX Runtime version.
    Optimize {
        /// The .onnx model (float or int8).
        input: PathBuf,
        /// Where to write the optimised model.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
    },
    /// Average several models into one file: the same input goes to each, the output is the
    /// mean of theirs (ONNX Mean). For the seeds of one recipe: on any frame it misses the
    /// label by no more than the seeds' mean miss, at the cost of running each. The models
    /// must share the contract, input, output and opsets; the file keeps the first model's
    /// metadata.
    Ensemble {
        /// Two or more .onnx files.
        #[arg(required = true, num_args = 2.., value_name = "MODEL")]
        models: Vec<PathBuf>,
        /// Where to write the .onnx file.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
    },
    /// Print a model's contract, inputs and outputs, and graph statistics (no ONNX Runtime
    /// needed).
    Info {
        /// The .onnx file.
        file: PathBuf,
    },
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ArchArg {
    Resnet18,
    #[value(name = "efficientnet-lite0")]
    EfficientnetLite0,
}

impl From<ArchArg> for Arch {
    fn from(a: ArchArg) -> Arch {
        match a {
            ArchArg::Resnet18 => Arch::Resnet18,
            ArchArg::EfficientnetLite0 => Arch::EfficientNetLite0,
        }
    }
}

impl Order {
    fn order(self) -> ChannelOrder {
        match self {
            Order::Rgb => ChannelOrder::Rgb,
            Order::Bgr => ChannelOrder::Bgr,
        }
    }
}

impl Head {
    fn kind(self) -> OutputKind {
        match self {
            Head::Xy => OutputKind::Xy,
            Head::SpeedSteering => OutputKind::SpeedSteering,
        }
    }
}

/// The contract of a model of `arch` for `input_size`, with the normalisation its ImageNet
/// weights expect.
fn contract_for(arch: Arch, input_size: u32, order: Order, head: Head) -> ModelContract {
    let (mean, std) = arch.imagenet_normalisation();
    ModelContract {
        input_size,
        channel_order: order.order(),
        mean,
        std,
        output: head.kind(),
    }
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Order {
    Rgb,
    Bgr,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Head {
    Xy,
    SpeedSteering,
}

pub fn main(cmd: ModelCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        ModelCommand::Init {
            arch,
            input_size,
            seed,
            channel_order,
            head,
            output,
        } => {
            let arch = Arch::from(arch);
            let contract = contract_for(arch, input_size, channel_order, head);
            let weights = NetWeights::random(arch, 2, seed);
            let model = weights.model(input_size, &contract, env!("CARGO_PKG_VERSION"))?;
            onnx::write_model(&output, &model)?;
            println!(
                "wrote {}: {}, {:.2} M parameters, random init (seed {seed})\n  contract: {contract}",
                output.display(),
                arch.title(),
                weights.parameter_count() as f64 / 1e6
            );
            Ok(ExitCode::SUCCESS)
        }
        ModelCommand::Import {
            file,
            arch,
            input_size,
            head,
            seed,
            channel_order,
            output,
        } => {
            let arch = Arch::from(arch);
            let contract = contract_for(arch, input_size, channel_order, head);
            let weights = pytorch::read_state_dict(&file, arch)?;
            let found = weights.num_outputs()?;
            let (weights, head_note) = if found == 2 {
                (weights, "its own 2-output head".to_string())
            } else {
                (
                    weights.with_fresh_head(2, seed),
                    format!(
                        "its {found}-output head replaced by a fresh 2-output one (seed {seed})"
                    ),
                )
            };
            let model = weights.model(input_size, &contract, env!("CARGO_PKG_VERSION"))?;
            onnx::write_model(&output, &model)?;
            println!(
                "wrote {}: {} from {}, {head_note}, {:.2} M parameters\n  contract: {contract}",
                output.display(),
                arch.title(),
                file.display(),
                weights.parameter_count() as f64 / 1e6
            );
            Ok(ExitCode::SUCCESS)
        }
        ModelCommand::Quantize(args) => super::model_quantize::main(args),
        ModelCommand::Optimize { input, output } => super::model_optimize::main(&input, &output),
        ModelCommand::Ensemble { models, output } => {
            let mut members = Vec::with_capacity(models.len());
            for path in &models {
                members.push(onnx::ensemble::Member {
                    path: path.display().to_string(),
                    model: onnx::read_model(path)?,
                });
            }
            let model = onnx::ensemble::ensemble(&members)?;
            onnx::write_model(&output, &model)?;
            println!(
                "wrote {}: the mean output of {} models",
                output.display(),
                members.len()
            );
            Ok(ExitCode::SUCCESS)
        }
        ModelCommand::Info { file } => {
            let s = onnx::inspect_file(&file)?;
            println!("{}", file.display());
            let opsets: Vec<String> = s.opsets.iter().map(|(d, v)| format!("{d} {v}")).collect();
            println!(
                "  producer   {} (IR {}, opset {})",
                if s.producer.is_empty() {
                    "unknown"
                } else {
                    &s.producer
                },
                s.ir_version,
                opsets.join(", ")
            );
            let ops: Vec<String> = s
                .op_counts
                .iter()
                .map(|(k, v)| format!("{k} {v}"))
                .collect();
            println!(
                "  graph      {} nodes ({}), {} initializers, {} parameters",
                s.nodes,
                ops.join(", "),
                s.initializers,
                s.parameters
            );
            for i in &s.inputs {
                println!("  input      {i}");
            }
            for o in &s.outputs {
                println!("  output     {o}");
            }
            match s.contract() {
                Ok(Some(c)) => println!("  contract   {c} (from the model's metadata)"),
                Ok(None) => println!(
                    "  contract   none in the file: `jetpilot run` uses the config's [model] keys (channel_order, mean, std, output; input_size only where the input above is not a fixed [n,3,S,S])"
                ),
                Err(e) => println!("  contract   INVALID: {e}"),
            }
            if let Some(a) = s.metadata.get(jetpilot::policy::onnx::resnet::META_ARCH) {
                let known = Arch::from_name(a).map_or("not one this build knows", Arch::title);
                println!("  arch       {a} ({known})");
            }
            if let Some(e) = s.metadata.get(onnx::ensemble::META_ENSEMBLE) {
                println!("  ensemble   {e}");
            }
            if let Some(q) = s
                .metadata
                .get(jetpilot::policy::quantize::META_QUANTIZATION)
            {
                println!("  quantized  {q}");
            }
            for (k, v) in s
                .metadata
                .iter()
                .filter(|(k, _)| !k.starts_with("jetpilot."))
            {
                println!("  metadata   {k} = {v}");
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
