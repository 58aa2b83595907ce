//! `scripts/layouts-ilddpg.sh` (issue 48 5d): IL + DDPG from ImageNet on random layouts,
//! picked in the stress world, then judged on unseen tracks. Its every step with a tiny
//! budget (6 s of demonstrations, 2 short DDPG episodes, 2 s tests on two tracks), and a
//! config it cannot make the stress world from, refused before any work. Needs the `train`
//! feature, ONNX Runtime and python3 with pip (the script installs the ImageNet weights).
#![cfg(feature = "train")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::log_of;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// The script's settings, none inherited from the caller's environment.
const SETTINGS: [&str; 16] = [
    "CFG",
    "SEED",
    "EPISODES",
    "MINUTES",
    "EVAL_SECONDS",
    "EVAL_EVERY",
    "DEMO_SECONDS",
    "FLOAT_FIRST",
    "QUANTIZE",
    "TESTS",
    "TRACKS",
    "DDPG_FLAGS",
    "SECONDS_PER_TEST",
    "CAMERA",
    "ONLY",
    "BIN",
];

/// The script into `out` with `extra` variables in its environment.
fn layouts_ilddpg(out: &Path, extra: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new("bash");
    for name in SETTINGS {
        cmd.env_remove(name);
    }
    cmd.arg(repo("scripts/layouts-ilddpg.sh"))
        .arg(out)
        .env("BIN", env!("CARGO_BIN_EXE_jetpilot"))
        .envs(extra.iter().copied())
        .output()
        .unwrap()
}

/// Asserts the script exited with `code` and said `text`; its output.
fn exits_saying(o: &Output, code: i32, text: &str) -> String {
    let log = log_of(o);
    assert_eq!(o.status.code(), Some(code), "{log}");
    assert!(log.contains(text), "{text}: {log}");
    log
}

/// The report's section for one model: its heading's count, and its table rows.
fn section<'a>(report: &'a str, model: &str) -> (&'a str, Vec<&'a str>) {
    let start = report
        .find(&format!("## {model}: "))
        .unwrap_or_else(|| panic!("no section for {model}: {report}"));
    let body = &report[start..];
    let end = body[3..].find("\n## ").map_or(body.len(), |e| e + 3);
    let body = &body[..end];
    let heading = body.lines().next().unwrap_or_default();
    let rows = body
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| track"))
        .collect();
    (heading, rows)
}

#[test]
fn the_chain_runs_from_demonstrations_to_the_int8_copys_tests() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = layouts_ilddpg(
        &out,
        &[
            ("TRACKS", "jetbot_mat narrow"),
            ("DEMO_SECONDS", "6"),
            ("EPISODES", "2"),
            (
                "DDPG_FLAGS",
                "--episode-steps 60 --warmup-updates 10 --batch 16",
            ),
            ("EVAL_SECONDS", "2"),
            ("EVAL_EVERY", "1"),
            ("SECONDS_PER_TEST", "2"),
        ],
    );
    let log = log_of(&o);
    assert!(o.status.success(), "{log}");

    // The selection world: the config with the stress world's seed and layouts, and
    // nothing else changed (the appearance stays off, the path road keeps its lane).
    let stress: toml::Table = std::fs::read_to_string(out.join("stress.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let mut want: toml::Table = std::fs::read_to_string(repo("config/sim.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let sim = want["sim"].as_table_mut().unwrap();
    sim.insert("seed".into(), 303.into());
    let layouts = sim["layouts"].as_table_mut().unwrap();
    layouts.insert("enabled".into(), true.into());
    layouts.insert("lane_width_m".into(), vec![0.07, 0.10].into());
    layouts.insert("corner_radius_m".into(), vec![0.20, 0.30].into());
    assert_eq!(stress, want);
    assert_eq!(
        stress["sim"]["appearance"]["enabled"].as_bool(),
        Some(false)
    );

    for file in [
        "probe/probe.onnx",
        "ddpg/best.onnx",
        "ddpg/ddpg_eval.csv",
        "int8.onnx",
    ] {
        assert!(out.join(file).is_file(), "no {file}: {log}");
    }
    assert!(
        log.contains("43 convolutions as QLinearConv (6 left in float)"),
        "{log}"
    );

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("best in "), "{report}");
    for model in ["float", "int8"] {
        let (heading, rows) = section(&report, model);
        assert!(
            heading.contains("of 4 tests with 0 interventions"),
            "{heading}"
        );
        assert_eq!(rows.len(), 4, "{report}");
        for (track, direction) in [
            ("jetbot_mat", "as built"),
            ("narrow", "as built"),
            ("jetbot_mat", "reversed"),
            ("narrow", "reversed"),
        ] {
            let row = rows
                .iter()
                .find(|r| r.starts_with(&format!("| {track} | {direction} |")))
                .unwrap_or_else(|| panic!("no {track} {direction} row: {report}"));
            let interventions = row.split('|').nth(3).unwrap_or_default().trim();
            assert!(interventions.parse::<u32>().is_ok(), "{row}");
        }
    }
}

#[test]
fn bad_settings_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("old.toml");
    let sim = std::fs::read_to_string(repo("config/sim.toml")).unwrap();
    let start = sim.find("[sim.layouts]").unwrap();
    let end = start + sim[start + 1..].find("\n[").unwrap() + 1;
    std::fs::write(&cfg, format!("{}{}", &sim[..start], &sim[end..])).unwrap();
    let out = dir.path().join("out");
    // BIN is a file that is not there: a refusal must come before the binary runs.
    let o = layouts_ilddpg(
        &out,
        &[
            ("CFG", cfg.to_str().unwrap()),
            ("BIN", "/nonexistent/jetpilot"),
        ],
    );
    let log = exits_saying(
        &o,
        1,
        &format!(
            "{}: could not set 'enabled = true' in its [sim.layouts] table",
            cfg.display()
        ),
    );
    assert!(!out.join("demos").exists(), "{log}");

    let o = layouts_ilddpg(&out, &[("TRACKS", "jetbot_mat no_such_track")]);
    exits_saying(
        &o,
        2,
        "TRACKS: no track 'no_such_track' (config/tracks/no_such_track.toml)",
    );

    let o = layouts_ilddpg(Path::new("--help"), &[]);
    let log = exits_saying(&o, 0, "SEED (`train ddpg --seed`, default 1)");
    assert!(!log.contains("set -euo"), "{log}");
    let o = layouts_ilddpg(Path::new("--out"), &[]);
    exits_saying(&o, 2, "usage: scripts/layouts-ilddpg.sh [OUT]");
    assert!(!repo("--out").exists());

    let o = layouts_ilddpg(&out, &[("CFG", "/nonexistent/sim.toml")]);
    exits_saying(&o, 2, "CFG: no sim config at '/nonexistent/sim.toml'");
}
