//! `scripts/lib/frames.sh`, the shell helpers that `real-finetune.sh`, `probe-curve.sh` and
//! `lp-ft.sh` share: the frames' capture-time order must be the one `score` sorts by, and
//! `earlier` must keep for training exactly what `score --split-by-time 0.2` keeps, or a
//! study would train on frames it then scores.

use std::path::{Path, PathBuf};
use std::process::Command;

use jetpilot::dataset::jetbot_xy::{self, UNIX_EPOCH_TICKS};
use jetpilot::dataset::labelled::{Label, LabelledFrame, split_by_time};

/// stdout of `bash -c '. scripts/lib/frames.sh; SCRIPT'` run in the repository root.
fn frames_sh(script: &str) -> String {
    let o = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "set -euo pipefail; . scripts/lib/frames.sh; {script}"
        ))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{script}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

/// 12 frames a second apart across the instant where a uuid1's time_low and time_mid both
/// wrap to zero, their pixel labels falling with time (so names sort against time); an
/// empty frame and a text file beside them. Returns the frames in capture order.
fn frames_across_a_uuid_wrap(dir: &Path) -> Vec<PathBuf> {
    let wrap: u64 = 500 << 48; // ticks from 1582 to a time_mid wrap in October 2028
    let start = wrap - UNIX_EPOCH_TICKS - 6 * 10_000_000;
    let node = [0x01, 0x23, 0x45, 0x67, 0x89, 0xab];
    let mut frames = Vec::new();
    for i in 0..12u64 {
        let uuid = jetbot_xy::uuid1(start + i * 10_000_000, 0x1234, node);
        let path = dir.join(jetbot_xy::file_name(200 - i as u32 * 10, 100, &uuid));
        std::fs::write(&path, b"not decoded here").unwrap();
        frames.push(path);
    }
    let empty = jetbot_xy::uuid1(start + 3 * 10_000_000 + 1, 0x1234, node);
    std::fs::write(dir.join(jetbot_xy::file_name(5, 5, &empty)), b"").unwrap();
    std::fs::write(dir.join("notes.txt"), b"not a frame").unwrap();
    frames
}

fn lines(text: &str) -> Vec<String> {
    text.lines().map(str::to_string).collect()
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    names
}

fn name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().to_string()
}

#[test]
fn frames_by_time_sorts_by_the_uuid1_capture_time_across_a_wrap_and_skips_empty_files() {
    let dir = tempfile::tempdir().unwrap();
    let frames = frames_across_a_uuid_wrap(dir.path());
    // The fixture does straddle the wrap: a later frame's time_low is the smaller.
    let time_low = |p: &Path| name(p)[11..19].to_string();
    assert!(time_low(&frames[11]) < time_low(&frames[0]));
    let mut by_capture = frames.clone();
    by_capture.sort_by(|a, b| {
        let t = |p: &Path| jetbot_xy::capture_time_s(&name(p)).unwrap();
        t(a).partial_cmp(&t(b)).unwrap()
    });
    assert_eq!(by_capture, frames);

    let list = dir.path().join("by_time.txt");
    frames_sh(&format!(
        "frames_by_time '{}' '{}'",
        dir.path().display(),
        list.display()
    ));
    let want: Vec<String> = frames.iter().map(|p| p.display().to_string()).collect();
    assert_eq!(lines(&std::fs::read_to_string(&list).unwrap()), want);
}

#[test]
fn earlier_keeps_what_score_split_by_time_keeps_for_every_size_to_600() {
    let got = lines(&frames_sh("for n in $(seq 1 600); do earlier \"$n\"; done"));
    for (n, got) in (1..=600usize).zip(&got) {
        let frames = (0..n)
            .map(|i| LabelledFrame {
                path: PathBuf::from(format!("{i}.jpg")),
                label: Label::Value([0.0, 0.0]),
                time_s: Some(i as f64),
            })
            .collect();
        let (train, _) = split_by_time(frames, 0.2).unwrap();
        assert_eq!(got, &train.len().to_string(), "{n} frames");
    }
    assert_eq!(got.len(), 600);
    // The shared sets: the mat's 308 frames and the carpet's 501.
    assert_eq!(frames_sh("earlier 308; earlier 501"), "246\n401\n");
}

#[test]
fn link_first_and_link_spread_make_fresh_folders_of_the_listed_frames() {
    let dir = tempfile::tempdir().unwrap();
    let frames = frames_across_a_uuid_wrap(dir.path());
    let list = dir.path().join("by_time.txt");
    let first = dir.path().join("first");
    let spread = dir.path().join("spread");
    std::fs::create_dir(&first).unwrap();
    std::fs::write(first.join("stale.jpg"), b"from an earlier run").unwrap();
    frames_sh(&format!(
        "frames_by_time '{d}' '{l}'; link_first 4 '{l}' '{f}'; link_spread 3 8 '{l}' '{s}'",
        d = dir.path().display(),
        l = list.display(),
        f = first.display(),
        s = spread.display(),
    ));
    let named = |idx: &[usize]| {
        let mut v: Vec<String> = idx.iter().map(|&i| name(&frames[i])).collect();
        v.sort();
        v
    };
    assert_eq!(names_in(&first), named(&[0, 1, 2, 3]));
    // Every (8 / 3)-th of the first 8: the 1st, 4th and 7th.
    assert_eq!(names_in(&spread), named(&[0, 3, 6]));
    let link = std::fs::read_link(spread.join(name(&frames[3]))).unwrap();
    assert_eq!(link, frames[3]);
}

#[test]
fn mean_reads_the_model_and_baseline_lines_of_scores_text() {
    let dir = tempfile::tempdir().unwrap();
    let score = dir.path().join("score.txt");
    std::fs::write(
        &score,
        "pixel error in the 224x224 frame over 100 frames:\n  \
         model     mean 21.1 px, median 14.1 px, p90 44.3 px\n  \
         baseline  mean 38.0 px, median 28.5 px, p90 81.2 px   (always (-0.070, 0.299))\n  \
         model / baseline: 0.56\n",
    )
    .unwrap();
    let s = score.display();
    assert_eq!(
        frames_sh(&format!("mean model '{s}'; mean baseline '{s}'")),
        "21.1\n38.0\n"
    );
}
