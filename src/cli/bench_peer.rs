//! `jetpilot bench --model FILE --peer DIR`: jetpilot's half of `benches/peer_python_loop.py`,
//! which compares it with a JetBot-style Python loop in one run.
//!
//! Why a long-lived server rather than one `jetpilot bench` per block: both loops stay
//! loaded and warm for the whole comparison, so the Python script can alternate short
//! blocks of its own loop with blocks of this one, frame for frame on the same frames, and
//! the machine's slow and fast phases fall on both. A fresh `bench` per block would reload
//! the model, redo its warm-up and time all five measurements each time.
//!
//! Protocol (one JSON object a line on standard output; logs go to standard error):
//! 1. the bench's synthetic frames are written to `DIR/frame_<i>.rgb` (raw RGB8, row
//!    major), then a line `{"ready": true, "frames": [...], "width", "height",
//!    "input_size", "channel_order", "mean", "std", "output", "threads", "spinning",
//!    "onnxruntime"}`;
//! 2. for each line `N` read from standard input: one untimed frame, then N timed frames of
//!    the daemon's per-frame path (as `bench`'s end-to-end measurement), answered with
//!    `{"e2e_ms": [...], "infer_ms": [...]}` (`infer_ms`: `policy.infer` inside each);
//! 3. an empty line, `0` or the end of input ends it.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, bail};
use jetpilot::config::{RuntimeConfig, SafetyConfig};
use jetpilot::control::{SteeringGains, SteeringLaw};
use jetpilot::hw::MotorOutput;
use jetpilot::policy::ort_policy::OrtOptions;
use jetpilot::policy::{ModelContract, OrtPolicy, Policy, Preprocessor};

use super::bench::{FRAME_H, FRAME_W, null_hat};

/// Serves timing blocks of `model` on `frames` until standard input ends.
pub fn serve(
    model: &Path,
    threads: usize,
    frames: &[Vec<u8>],
    dir: &Path,
    ort_version: &str,
) -> anyhow::Result<ExitCode> {
    let fallback = ModelContract::default();
    let spinning = RuntimeConfig::default().allow_spinning;
    let mut policy = OrtPolicy::load(model, &OrtOptions::cpu(threads, spinning, &fallback))?;
    let contract = policy.contract().clone();
    let mut pre = Preprocessor::new(&contract);
    let gains = SteeringGains {
        speed_gain: 0.3, // as `bench`: the robot moves, so both motors get duty writes
        ..SteeringGains::default()
    };
    let mut law = SteeringLaw::new(gains, contract.output);
    let mut hat = null_hat(&Arc::default())?;
    let max_abs = SafetyConfig::default().max_abs_output;

    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut paths: Vec<PathBuf> = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        let p = dir.join(format!("frame_{i}.rgb"));
        std::fs::write(&p, f).with_context(|| format!("writing {}", p.display()))?;
        paths.push(p);
    }
    let ready = serde_json::json!({
        "ready": true,
        "frames": paths,
        "width": FRAME_W,
        "height": FRAME_H,
        "input_size": contract.input_size,
        "channel_order": contract.channel_order.as_str(),
        "mean": contract.mean,
        "std": contract.std,
        "output": contract.output.as_str(),
        "threads": threads,
        "spinning": spinning,
        "onnxruntime": ort_version,
    });
    let mut out = std::io::stdout().lock();
    writeln!(out, "{ready}")?;
    out.flush()?;

    let mut i = 0usize;
    for line in std::io::stdin().lock().lines() {
        let line = line.context("reading standard input")?;
        let n: usize = match line.trim() {
            "" | "0" => break,
            s => s
                .parse()
                .with_context(|| format!("expected a frame count, got `{s}`"))?,
        };
        let mut e2e = Vec::with_capacity(n);
        let mut infer = Vec::with_capacity(n);
        for k in 0..=n {
            let frame = &frames[i % frames.len()];
            i += 1;
            let t0 = Instant::now();
            let input = pre.run(FRAME_W, FRAME_H, frame)?;
            let t1 = Instant::now();
            let outputs = policy.infer(input)?;
            let t2 = Instant::now();
            if outputs.iter().any(|v| !v.is_finite() || v.abs() > max_abs) {
                bail!("the model's outputs {outputs:?} would be rejected by the daemon");
            }
            let wheels = law.step(outputs, 1.0 / 30.0).wheels;
            hat.drive(wheels)?;
            if k > 0 {
                // The first frame of a block is untimed: caches and threads come back.
                e2e.push(t0.elapsed().as_secs_f64() * 1e3);
                infer.push((t2 - t1).as_secs_f64() * 1e3);
            }
        }
        let reply = serde_json::json!({ "e2e_ms": e2e, "infer_ms": infer });
        writeln!(out, "{reply}")?;
        out.flush()?;
    }
    Ok(ExitCode::SUCCESS)
}
