//! `scripts/lp-ft.sh` end to end (issue 48 5a): a linear probe of the ImageNet
//! EfficientNet-Lite0, then fine-tunes from it, one chosen on the selection split and run
//! again for the test frames. On 40 simulator frames in JetBot's xy layout at 64x64, one
//! epoch each: `--lr 0` keeps the probe, so its selection row must equal the probe's; the
//! split sizes must be the ones `score --split-by-time 0.2` uses twice over. One more run
//! checks `PROBE_DATA` (two alternatives, chosen on the selection split) and `TEST_SEEDS`
//! (a row per seed and one for their ensemble).
//! Needs the `train` feature, ONNX Runtime and python3 with pip (the script installs the
//! weights).
#![cfg(feature = "train")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::{log_of, scattered_xy_views};

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// 40 scattered views of the default track, a second apart (see the helper).
fn stand_in_realdata(dir: &Path) -> PathBuf {
    let out = dir.join("real");
    scattered_xy_views(&repo("config/sim.toml"), 40, &out);
    out
}

fn lp_ft(real: &Path, out: &Path, candidates: &str) -> Output {
    lp_ft_env(real, out, candidates, &[])
}

fn lp_ft_env(real: &Path, out: &Path, candidates: &str, env: &[(&str, &str)]) -> Output {
    Command::new("bash")
        .arg(repo("scripts/lp-ft.sh"))
        .arg(real)
        .arg(out)
        .env("BIN", env!("CARGO_BIN_EXE_jetpilot"))
        .env("CANDIDATES", candidates)
        .env("EPOCHS", "1")
        .env("INPUT_SIZE", "64")
        .env_remove("SEED")
        .env_remove("PROBE_DATA")
        .env_remove("TEST_SEEDS")
        .envs(env.iter().copied())
        .output()
        .unwrap()
}

/// The CSV's rows after its header, each split at its commas (names are quoted, without
/// commas).
fn rows(path: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .map(|c| c.trim_matches('"').to_string())
                .collect()
        })
        .collect()
}

/// The CSV's first column (the row names).
fn names(path: &Path) -> Vec<String> {
    rows(path)
        .into_iter()
        .map(|mut r| r.swap_remove(0))
        .collect()
}

/// `score`'s text on the stand-in's 32 earlier frames: the latest 6 scored, as the script
/// splits them.
fn assert_selection_split(scored: &str) {
    assert!(
        scored.contains("the latest 6 frames are scored, the earlier 26"),
        "{scored}"
    );
}

fn px(cell: &str) -> f64 {
    cell.parse()
        .unwrap_or_else(|_| panic!("not a number: {cell:?}"))
}

#[test]
fn lp_ft_sh_chooses_on_the_selection_split_and_reports_the_choice_on_the_test_frames() {
    let dir = tempfile::tempdir().unwrap();
    let real = stand_in_realdata(dir.path());
    let out = dir.path().join("out");
    let o = lp_ft(
        &real,
        &out,
        "--lr 0 --batch 8;--lr 1e-3 --batch 8 --no-augment",
    );
    let log = log_of(&o);
    assert!(o.status.success(), "{log}");

    // 40 frames: the latest 8 are the test; of the earlier 32, 26 fit and 6 choose.
    assert!(
        log.contains("selection: fit on the earliest 26, choose on the next 6"),
        "{log}"
    );
    assert!(
        log.contains("test: fit on the earliest 32, score the latest 8"),
        "{log}"
    );
    let probe_log = |d: &str| std::fs::read_to_string(out.join(d).join("probe.log")).unwrap();
    assert!(
        probe_log("sel").contains("of 26 frames"),
        "{}",
        probe_log("sel")
    );
    assert!(
        probe_log("test").contains("of 32 frames"),
        "{}",
        probe_log("test")
    );
    // `score` itself splits the selection's 32 frames the same way.
    assert_selection_split(&std::fs::read_to_string(out.join("sel/probe_score.txt")).unwrap());

    // The probe alone and both candidates on the selection's latest 6 frames; `--lr 0`
    // leaves the probe's weights as they were.
    let sel = rows(&out.join("selection.csv"));
    assert_eq!(
        names(&out.join("selection.csv")),
        [
            "probe alone",
            "fine-tune --lr 0 --batch 8",
            "fine-tune --lr 1e-3 --batch 8 --no-augment"
        ],
        "{sel:?}"
    );
    assert!(
        (px(&sel[0][1]) - px(&sel[1][1])).abs() <= 0.11,
        "a fine-tune at --lr 0 is the probe: {sel:?}"
    );
    for r in &sel {
        assert_eq!(r[2], sel[0][2], "one baseline for every row: {sel:?}");
    }
    let chosen = if px(&sel[1][1]) <= px(&sel[2][1]) {
        1
    } else {
        2
    };
    assert!(
        log.contains(&format!(
            "chosen: {} ({} px",
            sel[chosen][0], sel[chosen][1]
        )),
        "{sel:?}\n{log}"
    );

    // The test: a new probe and the chosen fine-tune, scored with the x correlation.
    let test = rows(&out.join("test.csv"));
    assert_eq!(test.len(), 2, "{test:?}");
    assert_eq!(test[0][0], "probe alone");
    assert_eq!(test[1][0], sel[chosen][0]);
    for r in &test {
        assert!(px(&r[1]) > 0.0 && px(&r[2]) > 0.0, "{r:?}");
    }
    // `score` writes "-" for a constant answer's correlation (a probe may fall back to
    // the mean label on 32 frames, and `--lr 0` keeps it).
    for r in &test {
        assert!(r[3] == "-" || (-1.0..=1.0).contains(&px(&r[3])), "{test:?}");
    }
    if chosen == 1 {
        assert!(
            (px(&test[0][1]) - px(&test[1][1])).abs() <= 0.11,
            "a fine-tune at --lr 0 is the probe: {test:?}"
        );
    }
    assert!(out.join("test/ft/last.onnx").is_file());
}

#[test]
fn probe_data_alternatives_are_chosen_with_the_candidate_and_test_seeds_add_rows() {
    let dir = tempfile::tempdir().unwrap();
    let real = stand_in_realdata(dir.path());
    let other = dir.path().join("other");
    scattered_xy_views(&repo("config/sim.toml"), 10, &other);
    let out = dir.path().join("out");
    // Two alternatives: the stand-in's own frames alone, and with the other folder's 10.
    let alternatives = format!("-;{}", other.display());
    let o = lp_ft_env(
        &real,
        &out,
        "--lr 1e-3 --batch 8",
        &[("PROBE_DATA", alternatives.as_str()), ("TEST_SEEDS", "2")],
    );
    let log = log_of(&o);
    assert!(o.status.success(), "{log}");
    assert!(log.contains("the probes also fit on:"), "{log}");
    let read = |p: &str| std::fs::read_to_string(out.join(p)).unwrap();

    // One probe per alternative, on the 26 selection frames alone and with the other 10;
    // the fine-tunes read the 26 only, and the scores are on the stand-in's own split.
    assert!(
        read("sel/pool0/probe.log").contains("of 26 frames"),
        "{}",
        read("sel/pool0/probe.log")
    );
    assert!(
        read("sel/pool1/probe.log").contains("of 36 frames"),
        "{}",
        read("sel/pool1/probe.log")
    );
    for k in 0..2 {
        let ft = read(&format!("sel/pool{k}/ft0.log"));
        assert!(ft.contains("samples=26 "), "{ft}");
        assert_selection_split(&read(&format!("sel/pool{k}/probe_score.txt")));
    }
    let sel = rows(&out.join("selection.csv"));
    assert_eq!(
        names(&out.join("selection.csv")),
        [
            "probe alone (probe data: own)",
            "fine-tune --lr 1e-3 --batch 8 (probe data: own)",
            "probe alone (probe data: other)",
            "fine-tune --lr 1e-3 --batch 8 (probe data: other)"
        ],
        "{sel:?}"
    );

    // The lower fine-tune row picks the alternative; the test's probe fits on its frames.
    let (label, test_frames) = if px(&sel[1][1]) <= px(&sel[3][1]) {
        ("own", 32)
    } else {
        ("other", 42)
    };
    let chosen = format!("fine-tune --lr 1e-3 --batch 8 (probe data: {label})");
    assert!(
        log.contains(&format!("chosen: {chosen} (")),
        "{sel:?}\n{log}"
    );
    assert!(
        read("test/probe.log").contains(&format!("of {test_frames} frames")),
        "{}",
        read("test/probe.log")
    );

    // TEST_SEEDS: the chosen fine-tune once more from the test's probe, with seed 2.
    let test = rows(&out.join("test.csv"));
    assert_eq!(
        names(&out.join("test.csv")),
        [
            format!("probe alone (probe data: {label})"),
            chosen.clone(),
            format!("{chosen} (seed 2)"),
            format!("{chosen} (ensemble of seeds 1 2)")
        ],
        "{test:?}"
    );
    // The ensemble answers the mean of the two seeds' answers, and a distance is convex:
    // on every frame it misses by no more than the seeds' mean miss (rows round to 0.1 px).
    assert!(out.join("test/ensemble.onnx").is_file());
    assert!(
        px(&test[3][1]) <= (px(&test[1][1]) + px(&test[2][1])) / 2.0 + 0.1,
        "{test:?}"
    );
    assert!(
        read("test/ft_seed2.log").contains("samples=32 "),
        "{}",
        read("test/ft_seed2.log")
    );
    let weights = |p: &str| std::fs::read(out.join(p)).unwrap();
    assert_ne!(
        weights("test/ft/last.onnx"),
        weights("test/ft_seed2/last.onnx"),
        "seed 2 trained the same model as seed 1"
    );
}

#[test]
fn a_probe_data_folder_that_is_missing_is_refused() {
    for probe_data in ["/no/such/folder", "-;/no/such/folder"] {
        let dir = tempfile::tempdir().unwrap();
        let o = lp_ft_env(
            dir.path(),
            &dir.path().join("out"),
            "--lr 0",
            &[("PROBE_DATA", probe_data)],
        );
        let log = log_of(&o);
        assert_eq!(o.status.code(), Some(2), "{probe_data}: {log}");
        assert!(
            log.contains("PROBE_DATA: '/no/such/folder' is not a folder"),
            "{log}"
        );
    }
}

#[test]
fn a_candidate_that_fails_names_its_step_and_log() {
    let dir = tempfile::tempdir().unwrap();
    let real = stand_in_realdata(dir.path());
    let out = dir.path().join("out");
    let o = lp_ft(&real, &out, "--no-such-flag");
    let log = log_of(&o);
    assert_eq!(o.status.code(), Some(1), "{log}");
    assert!(
        log.contains("train il --no-such-flag failed; the end of") && log.contains("sel/ft0.log"),
        "{log}"
    );
    assert!(!out.join("test.csv").exists(), "{log}");
}

#[test]
fn a_missing_folder_is_refused_with_the_usage() {
    let dir = tempfile::tempdir().unwrap();
    let o = lp_ft(
        &dir.path().join("nowhere"),
        &dir.path().join("out"),
        "--lr 0",
    );
    let log = log_of(&o);
    assert_eq!(o.status.code(), Some(2), "{log}");
    assert!(
        log.contains("usage: scripts/lp-ft.sh REALDATA [OUT]"),
        "{log}"
    );
    assert!(log.contains("nowhere"), "{log}");
}
