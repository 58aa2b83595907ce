//! Command-line interface: the clap definitions, logging setup and dispatch. Each
//! subcommand lives in its own file; errors are reported here, once, with their causes.

mod bench;
mod bench_cpu;
mod bench_peer;
mod bench_sim;
mod camera;
mod check_views;
mod image;
mod interventions;
mod model;
mod model_optimize;
mod model_quantize;
mod panel;
mod poses;
mod poses_calibrate;
// The book's generated pages, as the test suite builds (with the trainer's commands).
#[cfg(all(test, feature = "train"))]
mod reference;
mod replay_check;
mod run;
mod samples;
mod score;
mod score_explain;
mod sim;
mod train;
#[cfg(feature = "train")]
mod train_bench;
#[cfg(feature = "train")]
mod train_ddpg;
#[cfg(feature = "train")]
mod train_il;
mod train_init;
#[cfg(feature = "train")]
mod train_plot;
mod train_probe;
#[cfg(feature = "train")]
mod train_report;

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// jetpilot: the runtime for JetBot-class robot cars.
///
/// camera -> ResNet-18 on ONNX Runtime -> JetBot steering law -> motor HAT over I2C, with a
/// watchdog that stops the motors whenever fresh commands stop.
///
/// Start with `jetpilot run --config config/demo.toml` (sample frames, no hardware).
#[derive(Debug, Parser)]
#[command(name = "jetpilot", version, propagate_version = true)]
pub struct Cli {
    /// More log output (-v debug, -vv trace). JETPILOT_LOG overrides (e.g. JETPILOT_LOG=jetpilot=debug).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Only warnings and errors.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Drive: capture frames, run the model, steer, write the motors (the daemon).
    Run(run::RunArgs),
    /// Drive with the gamepad and record demonstrations (DonkeyCar tub v2) for imitation
    /// learning; the record button pauses and resumes.
    Record(run::RecordArgs),
    /// Release both motors and exit (for systemd's ExecStopPost, or by hand after a crash).
    Stop {
        /// Config file naming the motor HAT (layout, bus, address).
        #[arg(short, long, value_name = "FILE")]
        config: PathBuf,
    },
    /// Find cameras (`camera list`) and take a test frame from the configured source
    /// (`camera snap`).
    #[command(subcommand)]
    Camera(camera::CameraCommand),
    /// Summarise an interventions log: count, test time, autonomy (the paper's formula).
    #[command(subcommand)]
    Interventions(interventions::InterventionsCommand),
    /// Create, inspect, quantize (int8) or pre-optimise ONNX policy models.
    #[command(subcommand)]
    Model(model::ModelCommand),
    /// Measure preprocessing, inference, the steering law + I2C encoding, and frame -> motor
    /// command end to end, beside a bare ONNX Runtime run.
    Bench(bench::BenchArgs),
    /// Drive in the replayed-frame simulator: the daemon's own per-frame work and motor
    /// driver on a virtual PCA9685 (or H-bridge), on a simulated clock.
    Sim(sim::SimArgs),
    /// Score a model with the paper's protocol: a 600 s simulated test, interventions,
    /// autonomy value, reward count, laps, mean speed.
    Eval(sim::EvalArgs),
    /// Score a model on labelled frames (JetBot xy folders, tubs): pixel error or MSE
    /// against the mean-label baseline, a per-frame CSV and a picture.
    Score(score::ScoreArgs),
    /// Poses for a recording without them (visual odometry on the floor, fused with the
    /// wheel commands), written to a new tub; or, with --check, its drift against known poses.
    Poses(poses::PosesArgs),
    /// Train policies: a pretrained backbone's output layer in closed form (`train probe`,
    /// every build); imitation learning and DDPG fine-tuning in the simulator (a build with
    /// `--features train`).
    #[command(subcommand)]
    Train(train::TrainCommand),
    /// Put jetpilot into a JetBot SD card image before flashing it.
    #[command(subcommand)]
    Image(image::ImageCommand),
    /// Write synthetic road frames (a JetBot-mat road bending left and right) to try `run`
    /// without a camera.
    Samples(samples::SamplesArgs),
}

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    init_tracing(cli.verbose, cli.quiet);
    install_panic_hook();
    if !drives_motors(&cli.command) {
        die_quietly_on_closed_pipe();
    }
    let result = match cli.command {
        Command::Run(args) => run::run(args),
        Command::Record(args) => run::record(args),
        Command::Stop { config } => run::stop(&config),
        Command::Model(cmd) => model::main(cmd),
        Command::Camera(cmd) => camera::main(cmd),
        Command::Interventions(cmd) => interventions::main(cmd),
        Command::Bench(args) => bench::main(args),
        Command::Samples(args) => samples::main(args),
        Command::Image(cmd) => image::main(cmd),
        Command::Sim(args) => sim::sim(args),
        Command::Eval(args) => sim::eval(args),
        Command::Score(args) => score::main(args),
        Command::Poses(args) => poses::main(args),
        Command::Train(cmd) => train::main(cmd),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            for cause in e.chain().skip(1) {
                eprintln!("  caused by: {cause}");
            }
            ExitCode::FAILURE
        }
    }
}

/// Seconds since the Unix epoch, for stamping recordings (the library never reads the wall
/// clock itself).
fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// Human-readable logs on a terminal; plain lines without timestamps under systemd
/// (journald adds its own), detected by `JOURNAL_STREAM`.
fn init_tracing(verbose: u8, quiet: bool) {
    use tracing_subscriber::EnvFilter;
    let level = match (quiet, verbose) {
        (true, _) => "warn",
        (false, 0) => "info",
        (false, 1) => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_env("JETPILOT_LOG")
        .unwrap_or_else(|_| EnvFilter::new(format!("{level},ort=warn")));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false);
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        builder.with_ansi(false).without_time().init();
    } else {
        builder
            .with_ansi(std::io::stderr().is_terminal())
            .compact()
            .init();
    }
}

/// The commands that drive (or release) real motors. They keep Rust's SIGPIPE setting
/// (ignored: a write to a closed pipe is an error), so a reader going away can never end the
/// process before its motors are stopped; they print through [`say`].
fn drives_motors(command: &Command) -> bool {
    matches!(
        command,
        Command::Run(_) | Command::Record(_) | Command::Stop { .. }
    )
}

/// The offline commands behave like other Unix tools when their reader goes away
/// (`jetpilot score ... | head`): the kernel ends the process quietly with SIGPIPE, instead of
/// `println!` panicking on "Broken pipe". None of them writes to a child's stdin, and sockets
/// are written with MSG_NOSIGNAL by std, so only stdout and stderr are affected.
fn die_quietly_on_closed_pipe() {
    // SAFETY: restores the default disposition of one signal before any thread that could
    // be handling it exists; no Rust invariant depends on SIGPIPE being ignored.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// One line on stdout for the daemon's commands: a closed pipe loses the line (noted at
/// debug level), it never panics.
pub(crate) fn say(line: std::fmt::Arguments<'_>) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(line).and_then(|_| out.write_all(b"\n")) {
        tracing::debug!(error = %e, "stdout closed; line not printed");
    }
}

/// Panics are logged through tracing (so they reach the journal) before the default report.
/// The motors are released by the motor output's `Drop` while the panic unwinds.
fn install_panic_hook() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        tracing::error!(panic = %info, "panic");
        default(info);
    }));
}
