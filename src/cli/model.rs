//! `jetpilot model init` and `jetpilot model info`; `quantize` and `optimize` live in
//! `model_quantize` and `model_optimize`.

use std::path::PathBuf;
use std::process::ExitCode;

use jetpilot::policy::contract::{IMAGENET_MEAN, IMAGENET_STD};
use jetpilot::policy::onnx::{self, Resnet18Weights};
use jetpilot::policy::{ChannelOrder, ModelContract, OutputKind};

#[derive(Debug, clap::Subcommand)]
pub enum ModelCommand {
    /// Write a randomly initialised ResNet-18 (torchvision layout, fc 512 -> 2) with the
    /// model contract in its metadata. Untrained: it steers at random, for trying the
    /// pipeline and as the trainer's starting point.
    Init {
        #[arg(long, value_enum, default_value = "resnet18")]
        arch: Arch,
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
    /// Print a model's contract, inputs and outputs, and graph statistics (no ONNX Runtime
    /// needed).
    Info {
        /// The .onnx file.
        file: PathBuf,
    },
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Arch {
    Resnet18,
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
            arch: Arch::Resnet18,
            input_size,
            seed,
            channel_order,
            head,
            output,
        } => {
            let contract = ModelContract {
                input_size,
                channel_order: match channel_order {
                    Order::Rgb => ChannelOrder::Rgb,
                    Order::Bgr => ChannelOrder::Bgr,
                },
                mean: IMAGENET_MEAN,
                std: IMAGENET_STD,
                output: match head {
                    Head::Xy => OutputKind::Xy,
                    Head::SpeedSteering => OutputKind::SpeedSteering,
                },
            };
            let weights = Resnet18Weights::random(2, seed);
            let model =
                onnx::resnet18_model(input_size, &weights, &contract, env!("CARGO_PKG_VERSION"))?;
            onnx::write_model(&output, &model)?;
            println!(
                "wrote {}: ResNet-18, {:.2} M parameters, random init (seed {seed})\n  contract: {contract}",
                output.display(),
                onnx::parameter_count(&weights) as f64 / 1e6
            );
            Ok(ExitCode::SUCCESS)
        }
        ModelCommand::Quantize(args) => super::model_quantize::main(args),
        ModelCommand::Optimize { input, output } => super::model_optimize::main(&input, &output),
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
