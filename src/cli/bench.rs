//! `jetpilot bench`: what one frame costs on this machine, stage by stage, beside a bare
//! ONNX Runtime run of the same model.
//!
//! For each input size S (random ResNet-18s, or `--model` at its own contract size) it times:
//! preprocessing a synthetic 640x480 frame, a plain `ort` session run (the reference),
//! `OrtPolicy::infer`, the steering law + PCA9685 register encoding on a do-nothing I2C bus,
//! and the daemon's whole per-frame path (preprocess -> infer -> output check -> law ->
//! motor HAT), without its threads. The five measurements run round-robin in blocks, so
//! noise from the rest of the machine falls on all of them alike.
//!
//! Then it paces that per-frame path at camera rates with spinning off and on
//! ([`super::bench_cpu`]) for CPU time per frame and CPU %, and reports the process's peak
//! RSS: once the policy's session has loaded and run, and at the end of the size (with the
//! reference and the spinning sessions loaded as well).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, Operation};
use jetpilot::camera::synthetic::{render_road, sample_view};
use jetpilot::config::SafetyConfig;
use jetpilot::control::{SteeringGains, SteeringLaw};
use jetpilot::drive::stats::summarise;
use jetpilot::drive::usage::{self, Memory};
use jetpilot::hw::bus::StdDelay;
use jetpilot::hw::motor_hat::HatSettings;
use jetpilot::hw::{HatLayout, MotorHat, MotorOutput};
use jetpilot::policy::onnx::{self, Resnet18Weights};
use jetpilot::policy::ort_policy::OrtOptions;
use jetpilot::policy::runtime;
use jetpilot::policy::{ModelContract, OrtPolicy, OutputKind, Policy, Preprocessor};
use ort::environment::Environment;
use ort::session::builder::GraphOptimizationLevel;
use ort::session::{Session, SessionInputValue};
use ort::value::TensorRef;

use super::bench_cpu::{self, Paced};

/// The synthetic camera frame: JetBot's usual capture size.
pub(super) const FRAME_W: u32 = 640;
pub(super) const FRAME_H: u32 = 480;
/// Distinct frames cycled through (one left-right sweep of the road).
const FRAMES: usize = 8;
/// Timed iterations per turn of the round-robin.
const BLOCK: usize = 10;
/// Time between frames given to the steering law (a 30 fps camera).
const DT_S: f32 = 1.0 / 30.0;
/// The budget for everything outside the network, per frame.
const GOAL_MS: f32 = 1.0;
/// Pause before a block that switches ONNX Runtime sessions (see [`run_interleaved`]).
const SWITCH_PAUSE: Duration = Duration::from_millis(100);
/// Seed of the random ResNet-18 weights.
const SEED: u64 = 0;

#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Timed iterations of each measurement.
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u32).range(1..))]
    iterations: u32,
    /// Untimed iterations of each measurement before timing starts.
    #[arg(long, default_value_t = 30)]
    warmup: u32,
    /// ONNX Runtime intra-op threads (0: ONNX Runtime decides).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Input sizes of the random ResNet-18s to benchmark, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [224u32, 112],
          value_parser = clap::value_parser!(u32).range(32..=1024))]
    sizes: Vec<u32>,
    /// Benchmark this .onnx model (at its own contract size) instead of random ResNet-18s;
    /// repeat to compare several (a float model and its int8 copy), one after the other.
    #[arg(long, value_name = "FILE", conflicts_with = "sizes")]
    model: Vec<PathBuf>,
    /// Seconds of the paced frame -> command loop for each rate and spinning setting
    /// (CPU per frame and CPU %); 0 skips it.
    #[arg(long, default_value_t = 4.0)]
    paced_seconds: f64,
    /// Frame rates of the paced loop, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = [15u32, 30],
          value_parser = clap::value_parser!(u32).range(1..=240))]
    paced_fps: Vec<u32>,
    /// Serve timing blocks of `--model` for `benches/peer_python_loop.py` (the JetBot-style
    /// Python loop, interleaved): write the synthetic frames into DIR, then answer frame
    /// counts on standard input with per-frame times as JSON lines.
    #[arg(long, value_name = "DIR", requires = "model")]
    peer: Option<PathBuf>,
    /// Also write the results to this file as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Measure the simulator instead: mat rendering and replayed-frame synthesis at
    /// 224x224 and 96x96 on one thread.
    #[arg(long)]
    pub sim: bool,
}

/// The five measurements, in the order of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Preprocess,
    Bare,
    Infer,
    Law,
    EndToEnd,
}

impl Kind {
    const ALL: [Kind; 5] = [
        Kind::Preprocess,
        Kind::Bare,
        Kind::Infer,
        Kind::Law,
        Kind::EndToEnd,
    ];

    fn label(self, s: u32) -> String {
        match self {
            Kind::Preprocess => format!("preprocess {FRAME_W}x{FRAME_H} -> {s}x{s}"),
            Kind::Bare => format!("bare ort run {s}x{s}"),
            Kind::Infer => format!("policy.infer {s}x{s}"),
            Kind::Law => "steering law + I2C encoding".to_string(),
            Kind::EndToEnd => format!("frame -> motor command end to end {s}x{s}"),
        }
    }

    /// Which ONNX Runtime session the measurement runs (0: the bare one, 1: the policy's).
    fn session(self) -> Option<u8> {
        match self {
            Kind::Bare => Some(0),
            Kind::Infer | Kind::EndToEnd => Some(1),
            Kind::Preprocess | Kind::Law => None,
        }
    }

    fn key(self) -> &'static str {
        match self {
            Kind::Preprocess => "preprocess",
            Kind::Bare => "bare_run",
            Kind::Infer => "policy_infer",
            Kind::Law => "law_and_i2c",
            Kind::EndToEnd => "end_to_end",
        }
    }
}

/// Nearest-rank statistics of one measurement, in milliseconds.
#[derive(Debug, Clone, Copy, Default)]
struct Stats {
    count: usize,
    median: f32,
    p90: f32,
    p99: f32,
    mean: f32,
    max: f32,
}

fn stats(samples: &mut [f32]) -> Stats {
    let s = summarise(samples); // sorts `samples`
    if s.count == 0 {
        return Stats::default();
    }
    let rank = ((0.99 * s.count as f64).ceil() as usize).clamp(1, s.count);
    let sum: f64 = samples.iter().map(|&v| f64::from(v)).sum();
    Stats {
        count: s.count,
        median: s.p50,
        p90: s.p90,
        p99: samples[rank - 1],
        mean: (sum / s.count as f64) as f32,
        max: s.max,
    }
}

/// Bytes and transactions seen by a [`NullBus`].
#[derive(Debug, Default)]
pub(super) struct BusCounters {
    bytes: AtomicU64,
    transactions: AtomicU64,
}

/// An I2C bus that accepts everything and only counts it (reads return zeros).
#[derive(Debug, Clone, Default)]
pub(super) struct NullBus(Arc<BusCounters>);

impl ErrorType for NullBus {
    type Error = ErrorKind;
}

impl I2c for NullBus {
    fn transaction(&mut self, _address: u8, ops: &mut [Operation<'_>]) -> Result<(), ErrorKind> {
        let mut written = 0;
        for op in ops.iter_mut() {
            match op {
                Operation::Write(b) => written += b.len() as u64,
                Operation::Read(b) => b.fill(0),
            }
        }
        self.0.bytes.fetch_add(written, Ordering::Relaxed);
        self.0.transactions.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }
}

pub(super) fn null_hat(counters: &Arc<BusCounters>) -> anyhow::Result<MotorHat<NullBus>> {
    let settings = HatSettings::for_layout(HatLayout::Adafruit);
    MotorHat::init(NullBus(counters.clone()), settings, &mut StdDelay)
        .context("initialising the motor HAT driver on the null bus")
}

fn ort_err<R>(e: ort::Error<R>) -> anyhow::Error {
    anyhow::anyhow!("ONNX Runtime: {e}")
}

/// A plain session as `OrtPolicy` builds it (Level3, or none for a model pre-optimised
/// by `model optimize`; same intra-op threads, spinning off, CPU).
fn bare_session(env: &Environment, threads: usize, path: &Path) -> anyhow::Result<Session> {
    let level = match jetpilot::policy::optimize::optimized_for(path) {
        Some(_) => GraphOptimizationLevel::Disable,
        None => GraphOptimizationLevel::Level3,
    };
    let mut builder = runtime::session_builder(env, level, threads, false).map_err(ort_err)?;
    // From the file, as the daemon does (and so that external weights are found).
    builder.commit_from_file(path).map_err(ort_err)
}

fn bare_run(session: &mut Session, inputs: &[SessionInputValue<'_>]) -> anyhow::Result<[f32; 2]> {
    let outputs = session.run(inputs).map_err(ort_err)?;
    let (_, data) = outputs[0].try_extract_tensor::<f32>().map_err(ort_err)?;
    match data {
        [a, b, ..] => Ok([*a, *b]),
        _ => bail!("the model's output has {} values, expected 2", data.len()),
    }
}

/// The model file of one benchmarked size; a random model's temporary file is removed on
/// drop. The bytes are not kept, so they do not count in the RSS figures.
struct ModelFile {
    path: PathBuf,
    temporary: bool,
}

impl Drop for ModelFile {
    fn drop(&mut self) {
        if self.temporary {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

fn random_model(size: u32, weights: &Resnet18Weights) -> anyhow::Result<ModelFile> {
    let contract = ModelContract {
        input_size: size,
        ..ModelContract::default()
    };
    let model = onnx::resnet18_model(size, weights, &contract, env!("CARGO_PKG_VERSION"))?;
    let path =
        std::env::temp_dir().join(format!("jetpilot-bench-{}-{size}.onnx", std::process::id()));
    let file = ModelFile {
        path,
        temporary: true,
    };
    std::fs::write(&file.path, onnx::encode_model(&model))
        .with_context(|| format!("writing {}", file.path.display()))?;
    Ok(file)
}

fn user_model(path: &Path) -> anyhow::Result<ModelFile> {
    if !path.is_file() {
        bail!("{}: no such file", path.display());
    }
    Ok(ModelFile {
        path: path.to_path_buf(),
        temporary: false,
    })
}

/// Everything the five measurements touch, with a call counter per measurement.
struct Rig<'a> {
    frames: &'a [Vec<u8>],
    /// Frame 0, preprocessed once: the input of the bare run and of `policy.infer`.
    input: &'a [f32],
    bare: Session,
    bare_inputs: [SessionInputValue<'a>; 1],
    pre: Preprocessor,
    policy: OrtPolicy,
    /// The same model with spinning allowed, for the paced runs only.
    spinning_policy: Option<OrtPolicy>,
    /// The law and HAT of the end-to-end path.
    law: SteeringLaw,
    hat: MotorHat<NullBus>,
    /// The law and HAT of the law + encoding measurement alone.
    law_alone: SteeringLaw,
    hat_alone: MotorHat<NullBus>,
    max_abs_output: f32,
    /// Frames whose outputs the daemon would reject (not finite or beyond the limit).
    rejected: usize,
    calls: [usize; 5],
}

impl Rig<'_> {
    fn step(&mut self, kind: Kind) -> anyhow::Result<()> {
        let i = self.calls[kind as usize];
        self.calls[kind as usize] += 1;
        let frame = &self.frames[i % self.frames.len()];
        match kind {
            Kind::Preprocess => {
                std::hint::black_box(self.pre.run(FRAME_W, FRAME_H, frame)?);
            }
            Kind::Bare => {
                std::hint::black_box(bare_run(&mut self.bare, &self.bare_inputs)?);
            }
            Kind::Infer => {
                std::hint::black_box(self.policy.infer(self.input)?);
            }
            Kind::Law => {
                // A new target every call, so the driver's cache never skips the writes.
                let wheels = self.law_alone.step([(i as f32).sin(), 0.3], DT_S).wheels;
                self.hat_alone.drive(wheels)?;
            }
            Kind::EndToEnd => self.frame_to_command(frame, false)?,
        }
        Ok(())
    }

    /// The daemon's per-frame work (`drive::stages::infer` and the actuator), in one thread,
    /// on the policy with spinning off or on.
    fn frame_to_command(&mut self, frame: &[u8], spinning: bool) -> anyhow::Result<()> {
        let policy = match (&mut self.spinning_policy, spinning) {
            (_, false) => &mut self.policy,
            (Some(p), true) => p,
            (None, true) => bail!("the spinning session is not loaded"),
        };
        let input = self.pre.run(FRAME_W, FRAME_H, frame)?;
        let outputs = policy.infer(input)?;
        if outputs
            .iter()
            .any(|v| !v.is_finite() || v.abs() > self.max_abs_output)
        {
            self.rejected += 1;
            return Ok(());
        }
        let wheels = self.law.step(outputs, DT_S).wheels;
        self.hat.drive(wheels)?;
        Ok(())
    }
}

/// Warm-up for each measurement, then round-robin blocks of [`BLOCK`] timed iterations,
/// each block after one untimed iteration, the starting measurement rotating every round.
/// Before a block that uses the other ONNX Runtime session than the last one, it pauses
/// [`SWITCH_PAUSE`] so that session's worker threads stop spin-waiting: with two sessions
/// in one process (the daemon has one) they would otherwise take a core from the next run.
fn run_interleaved(rig: &mut Rig<'_>, warmup: usize, n: usize) -> anyhow::Result<[Vec<f32>; 5]> {
    for kind in Kind::ALL {
        for _ in 0..warmup {
            rig.step(kind)?;
        }
    }
    let mut samples: [Vec<f32>; 5] = Default::default();
    let mut last_session = None;
    for round in 0..n.div_ceil(BLOCK) {
        for j in 0..Kind::ALL.len() {
            let kind = Kind::ALL[(round + j) % Kind::ALL.len()];
            if let Some(session) = kind.session() {
                if last_session.is_some_and(|last| last != session) {
                    std::thread::sleep(SWITCH_PAUSE);
                }
                last_session = Some(session);
            }
            let out = &mut samples[kind as usize];
            let todo = (n - out.len()).min(BLOCK);
            rig.step(kind)?; // untimed: brings caches and the thread pool back
            for _ in 0..todo {
                let t = Instant::now();
                rig.step(kind)?;
                out.push((t.elapsed().as_secs_f64() * 1e3) as f32);
            }
        }
    }
    Ok(samples)
}

/// Median over rounds of (median of a block of `a` - median of the block of `b` of the same
/// round): a paired estimate that slower phases of the machine affect much less than a
/// difference of the overall medians.
fn paired_difference(a: &[f32], b: &[f32]) -> f32 {
    let mut diffs: Vec<f32> = a
        .chunks(BLOCK)
        .zip(b.chunks(BLOCK))
        .map(|(x, y)| summarise(&mut x.to_vec()).p50 - summarise(&mut y.to_vec()).p50)
        .collect();
    summarise(&mut diffs).p50
}

/// The results for one input size.
struct SizeResult {
    size: u32,
    /// The model's file, for a `--model` run (random models are temporary files).
    file: Option<String>,
    contract: String,
    stats: [Stats; 5],
    /// [`paired_difference`] of e2e and the bare run.
    paired_overhead: f32,
    bytes_per_command: f64,
    transactions_per_command: f64,
    rejected: usize,
    outputs: [f32; 2],
    paced: Vec<Paced>,
    /// Before this size's sessions load (the process, its frames and what earlier sizes left).
    memory_start: Option<Memory>,
    /// Right after the policy's session loaded and ran, before any other session.
    memory_policy: Option<Memory>,
    /// At the end of the size.
    memory_end: Option<Memory>,
    /// Whether the peak was reset before this size (else it covers the earlier sizes too).
    peak_reset: bool,
    /// 1-minute load average at the start and at the end of the size.
    load: [Option<f32>; 2],
}

impl SizeResult {
    fn median(&self, kind: Kind) -> f32 {
        self.stats[kind as usize].median
    }

    /// e2e median minus the bare run's median.
    fn overhead(&self) -> f32 {
        self.median(Kind::EndToEnd) - self.median(Kind::Bare)
    }

    /// Preprocess + law/encoding medians.
    fn stage_sum(&self) -> f32 {
        self.median(Kind::Preprocess) + self.median(Kind::Law)
    }
}

fn bench_model(
    env: &Environment,
    args: &BenchArgs,
    model: &ModelFile,
    frames: &[Vec<u8>],
) -> anyhow::Result<SizeResult> {
    let load_start = load_average();
    let peak_reset = match usage::reset_peak_rss() {
        Ok(()) => true,
        Err(e) => {
            tracing::warn!(error = %e, "peak RSS covers the whole run so far");
            false
        }
    };
    let memory_start = memory_or_warn();
    let fallback = ModelContract::default();
    let load = |allow_spinning| {
        OrtPolicy::load(
            &model.path,
            &OrtOptions::cpu(args.threads, allow_spinning, &fallback),
        )
    };
    let mut policy = load(false)?;
    let contract = policy.contract().clone();
    let s = contract.input_size;
    let mut pre = Preprocessor::new(&contract);
    let input = pre.run(FRAME_W, FRAME_H, &frames[0])?.to_vec();
    for _ in 0..3 {
        policy.infer(&input)?; // the first runs allocate ONNX Runtime's arena
    }
    let memory_policy = memory_or_warn();
    let tensor = TensorRef::from_array_view(([1usize, 3, s as usize, s as usize], &input[..]))
        .map_err(ort_err)?;
    let gains = SteeringGains {
        speed_gain: 0.3, // the robot moves, so both motors get duty writes
        ..SteeringGains::default()
    };
    let counters_alone = Arc::new(BusCounters::default());
    let mut rig = Rig {
        frames,
        input: &input,
        bare: bare_session(env, args.threads, &model.path)?,
        bare_inputs: ort::inputs![tensor],
        pre,
        policy,
        spinning_policy: None,
        law: SteeringLaw::new(gains, contract.output),
        hat: null_hat(&Arc::default())?,
        law_alone: SteeringLaw::new(gains, OutputKind::Xy),
        hat_alone: null_hat(&counters_alone)?,
        max_abs_output: SafetyConfig::default().max_abs_output,
        rejected: 0,
        calls: [0; 5],
    };

    // The reference and the policy must compute the same thing.
    let bare_out = bare_run(&mut rig.bare, &rig.bare_inputs)?;
    let outputs = rig.policy.infer(&input)?;
    if bare_out
        .iter()
        .zip(outputs)
        .any(|(a, b)| (a - b).abs() > 1e-4 * (1.0 + b.abs()))
    {
        tracing::warn!(?bare_out, ?outputs, "bare run and policy.infer disagree");
    }

    // Count the I2C traffic of the law + encoding measurement only, from here on.
    counters_alone.bytes.store(0, Ordering::Relaxed);
    counters_alone.transactions.store(0, Ordering::Relaxed);
    tracing::info!("measuring {s}x{s}");
    let mut samples = run_interleaved(&mut rig, args.warmup as usize, args.iterations as usize)?;
    let commands = rig.calls[Kind::Law as usize].max(1) as f64;
    let paired_overhead = paired_difference(
        &samples[Kind::EndToEnd as usize],
        &samples[Kind::Bare as usize],
    );
    let paced = if args.paced_seconds > 0.0 {
        rig.spinning_policy = Some(load(true)?);
        tracing::info!("pacing {s}x{s} at {:?} fps", args.paced_fps);
        let mut i = 0;
        bench_cpu::measure(&args.paced_fps, args.paced_seconds, &mut |spinning| {
            i += 1;
            rig.frame_to_command(&frames[i % frames.len()], spinning)
        })?
    } else {
        Vec::new()
    };
    Ok(SizeResult {
        size: s,
        file: (!model.temporary).then(|| model.path.display().to_string()),
        contract: contract.to_string(),
        paired_overhead,
        stats: samples.each_mut().map(|v| stats(v)),
        bytes_per_command: counters_alone.bytes.load(Ordering::Relaxed) as f64 / commands,
        transactions_per_command: counters_alone.transactions.load(Ordering::Relaxed) as f64
            / commands,
        rejected: rig.rejected,
        outputs,
        paced,
        memory_start,
        memory_policy,
        memory_end: memory_or_warn(),
        peak_reset,
        load: [load_start, load_average()],
    })
}

fn memory_or_warn() -> Option<Memory> {
    usage::memory()
        .inspect_err(|e| tracing::warn!(error = %e, "no memory figures"))
        .ok()
}

/// The machine's 1-minute load average (`/proc/loadavg`), to read the numbers beside.
fn load_average() -> Option<f32> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The CPU as /proc/cpuinfo names it (`model name`, or `Hardware` / `Processor` on some
/// ARM kernels), the CPUs this process may use, and the board if the device tree names one
/// (Jetson, Raspberry Pi).
fn cpu_description() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |key: &str| {
        info.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            (k.trim() == key).then(|| v.trim().to_string())
        })
    };
    let cpu = ["model name", "Hardware", "Processor"]
        .into_iter()
        .find_map(field)
        .unwrap_or_else(|| "unknown CPU".into());
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    let board = std::fs::read_to_string("/proc/device-tree/model")
        .map(|s| format!(", {}", s.trim_end_matches('\0').trim()))
        .unwrap_or_default();
    format!("{cpu} ({cpus} CPUs available{board})")
}

struct Header {
    library: String,
    version: String,
    cpu: String,
    threads: String,
    /// How the numbers were taken, one line each.
    method: Vec<String>,
}

fn header(library: &Path, args: &BenchArgs) -> Header {
    Header {
        library: library.display().to_string(),
        version: runtime::ort_version(library),
        cpu: cpu_description(),
        threads: if args.threads == 0 {
            "ONNX Runtime default".into()
        } else {
            args.threads.to_string()
        },
        method: vec![
            format!(
                "{} warm-up + {} timed iterations of each measurement; nearest-rank percentiles",
                args.warmup, args.iterations
            ),
            format!(
                "the five run round-robin in blocks of {BLOCK} (the first of each block untimed, the starting one \
                 rotating), so machine noise falls on all alike"
            ),
            format!(
                "{} ms pause when switching between the bare and the policy's session, so the idle one's \
                 threads stop spin-waiting",
                SWITCH_PAUSE.as_millis()
            ),
            format!(
                "paced loop: e2e once per tick at {:?} fps, spinning off and on, {} s each in {} interleaved \
                 rounds; CPU from /proc/self/stat",
                args.paced_fps,
                args.paced_seconds,
                bench_cpu::ROUNDS
            ),
            "peak RSS: VmHWM from /proc/self/status, reset before each size".to_string(),
        ],
    }
}

fn print_header(h: &Header) {
    println!("jetpilot bench {}", env!("CARGO_PKG_VERSION"));
    println!("  ONNX Runtime  {} ({})", h.version, h.library);
    println!(
        "  session       CPU provider, graph optimisation Level3, spinning off, intra-op threads: {}",
        h.threads
    );
    println!("  CPU           {}", h.cpu);
    for (i, line) in h.method.iter().enumerate() {
        println!("  {:<13} {line}", if i == 0 { "method" } else { "" });
    }
}

fn print_result(r: &SizeResult) {
    let s = r.size;
    println!();
    if let Some(file) = &r.file {
        println!("{s}x{s}  {file}");
    }
    println!("{s}x{s}  model contract: {}", r.contract);
    println!(
        "  {:<44} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "ms", "median", "p90", "p99", "mean", "max"
    );
    for kind in Kind::ALL {
        let st = &r.stats[kind as usize];
        println!(
            "  {:<44} {:>9.4} {:>9.4} {:>9.4} {:>9.4} {:>9.4}",
            kind.label(s),
            st.median,
            st.p90,
            st.p99,
            st.mean,
            st.max
        );
    }
    println!(
        "  I2C per command: {:.1} bytes in {:.1} transactions (Adafruit layout; only changed channels are written)",
        r.bytes_per_command, r.transactions_per_command
    );
    if r.rejected > 0 {
        println!(
            "  WARNING: {} end-to-end frames had outputs the daemon rejects (not finite or beyond +-{}); law and motors skipped for them",
            r.rejected,
            SafetyConfig::default().max_abs_output
        );
    }
    let overhead = r.overhead();
    println!(
        "  overhead outside inference (e2e - bare run) median: {overhead:.3} ms (goal <= {GOAL_MS} ms): {}",
        if overhead <= GOAL_MS { "PASS" } else { "FAIL" }
    );
    println!(
        "  same overhead by stages: preprocess + law/encoding medians {:.3} ms; policy.infer - bare run medians {:.3} ms",
        r.stage_sum(),
        r.median(Kind::Infer) - r.median(Kind::Bare)
    );
    println!(
        "  e2e - bare run paired per round (median of block-median differences): {:.3} ms",
        r.paired_overhead
    );
    bench_cpu::print(&r.paced);
    let mib = |m: Option<Memory>| {
        m.map_or_else(|| "unknown".into(), |m| format!("{:.1} MiB", m.peak_mib()))
    };
    println!(
        "  peak RSS{}: {} with the policy's session loaded and run; {} at the end (reference and spinning sessions too)",
        if r.peak_reset { "" } else { " (since start)" },
        mib(r.memory_policy),
        mib(r.memory_end)
    );
    if let Some(m) = r.memory_start {
        println!(
            "  (RSS before this size's sessions: {:.1} MiB, the process, its frames and what earlier sizes left)",
            m.rss_mib()
        );
    }
    let load = |l: Option<f32>| l.map_or_else(|| "?".into(), |l| format!("{l:.2}"));
    println!(
        "  load average (1 min): {} at the start of this size, {} at the end",
        load(r.load[0]),
        load(r.load[1])
    );
}

/// A JSON string literal.
fn json_str(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c if u32::from(c) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", u32::from(c));
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A JSON number, or `null` for NaN and infinities (a broken model's outputs).
fn json_num(v: f32) -> String {
    if v.is_finite() {
        v.to_string()
    } else {
        "null".into()
    }
}

fn json(h: &Header, args: &BenchArgs, results: &[SizeResult]) -> String {
    let mut records = Vec::new();
    for r in results {
        for kind in Kind::ALL {
            let st = &r.stats[kind as usize];
            records.push(format!(
                "    {{\"size\": {}, \"measurement\": {}, \"label\": {}, \"count\": {}, \"median_ms\": {:.6}, \"p90_ms\": {:.6}, \"p99_ms\": {:.6}, \"mean_ms\": {:.6}, \"max_ms\": {:.6}}}",
                r.size,
                json_str(kind.key()),
                json_str(&kind.label(r.size)),
                st.count,
                st.median,
                st.p90,
                st.p99,
                st.mean,
                st.max
            ));
        }
        records.push(format!(
            "    {{\"size\": {}, \"measurement\": \"overhead\", \"e2e_minus_bare_median_ms\": {:.6}, \"e2e_minus_bare_paired_ms\": {:.6}, \"stage_sum_median_ms\": {:.6}, \"goal_ms\": {GOAL_MS:.1}, \"pass\": {}, \"i2c_bytes_per_command\": {:.2}, \"i2c_transactions_per_command\": {:.2}, \"rejected_frames\": {}, \"outputs\": [{}, {}]}}",
            r.size,
            r.overhead(),
            r.paired_overhead,
            r.stage_sum(),
            r.overhead() <= GOAL_MS,
            r.bytes_per_command,
            r.transactions_per_command,
            r.rejected,
            json_num(r.outputs[0]),
            json_num(r.outputs[1])
        ));
        records.extend(bench_cpu::json_records(r.size, &r.paced));
        let mib = |m: Option<Memory>, f: fn(&Memory) -> f64| {
            m.map_or_else(|| "null".into(), |m| format!("{:.2}", f(&m)))
        };
        let load = |l: Option<f32>| l.map_or_else(|| "null".into(), |l| l.to_string());
        records.push(format!(
            "    {{\"size\": {}, \"measurement\": \"memory\", \"rss_start_mib\": {}, \"peak_rss_policy_mib\": {}, \"peak_rss_mib\": {}, \"rss_end_mib\": {}, \"peak_reset_before_size\": {}, \"load_1min_start\": {}, \"load_1min_end\": {}}}",
            r.size,
            mib(r.memory_start, Memory::rss_mib),
            mib(r.memory_policy, Memory::peak_mib),
            mib(r.memory_end, Memory::peak_mib),
            mib(r.memory_end, Memory::rss_mib),
            r.peak_reset,
            load(r.load[0]),
            load(r.load[1])
        ));
    }
    format!(
        "{{\n  \"jetpilot\": {},\n  \"onnxruntime\": {},\n  \"library\": {},\n  \"cpu\": {},\n  \"intra_threads\": {},\n  \"iterations\": {},\n  \"warmup\": {},\n  \"method\": {},\n  \"results\": [\n{}\n  ]\n}}\n",
        json_str(env!("CARGO_PKG_VERSION")),
        json_str(&h.version),
        json_str(&h.library),
        json_str(&h.cpu),
        args.threads,
        args.iterations,
        args.warmup,
        json_str(&h.method.join("; ")),
        records.join(",\n")
    )
}

pub fn main(args: BenchArgs) -> anyhow::Result<ExitCode> {
    if args.sim {
        return super::bench_sim::main(args.iterations);
    }
    let (library, env) = runtime::environment(None)?;
    let frames: Vec<Vec<u8>> = (0..FRAMES)
        .map(|i| render_road(FRAME_W, FRAME_H, sample_view(i, FRAMES)))
        .collect();
    if let Some(dir) = &args.peer {
        let [model] = args.model.as_slice() else {
            anyhow::bail!("--peer takes exactly one --model");
        };
        return super::bench_peer::serve(
            model,
            args.threads,
            &frames,
            dir,
            &runtime::ort_version(library),
        );
    }
    let models: Vec<ModelFile> = match args.model.as_slice() {
        [] => {
            let weights = Resnet18Weights::random(2, SEED);
            args.sizes
                .iter()
                .map(|&s| random_model(s, &weights))
                .collect::<anyhow::Result<_>>()?
        }
        paths => paths
            .iter()
            .map(|p| user_model(p))
            .collect::<anyhow::Result<_>>()?,
    };
    let h = header(library, &args);
    print_header(&h);
    let mut results = Vec::new();
    for model in &models {
        let r = bench_model(env, &args, model, &frames)
            .with_context(|| format!("benchmarking {}", model.path.display()))?;
        print_result(&r);
        results.push(r);
    }
    if let Some(path) = &args.json {
        std::fs::write(path, json(&h, &args, &results))
            .with_context(|| format!("writing {}", path.display()))?;
        println!("\nwrote {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
