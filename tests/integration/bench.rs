//! `jetpilot bench` as a user and `benches/peer_python_loop.py` run it: the JSON has the paced
//! CPU figures (spinning off and on) and the peak RSS, and `--peer` answers frame counts
//! with per-frame times. Tiny model and runs: this checks the plumbing, not the numbers.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use crate::common;

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};

use serde_json::Value;

fn jetpilot() -> Command {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
}

#[test]
fn json_has_paced_cpu_with_spinning_off_and_on_and_peak_rss() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 32, 1);
    let json = dir.path().join("bench.json");
    let out = jetpilot()
        .args([
            "-q",
            "bench",
            "--threads",
            "1",
            "--iterations",
            "2",
            "--warmup",
            "1",
        ])
        .args(["--paced-seconds", "0.2", "--paced-fps", "30", "--model"])
        .arg(&model)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("30 fps, spinning on"), "{stdout}");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let records = v["results"].as_array().unwrap();
    let paced: Vec<&Value> = records
        .iter()
        .filter(|r| r["measurement"] == "paced")
        .collect();
    let spinning: Vec<bool> = paced.iter().map(|r| r["spinning"] == true).collect();
    assert_eq!(spinning.len(), 2, "{paced:?}");
    assert!(spinning.contains(&true) && spinning.contains(&false));
    for r in &paced {
        assert_eq!(r["fps"], 30);
        assert!(r["frames"].as_u64().unwrap() >= 2, "{r}");
        assert!(r["cpu_percent_of_one_core"].as_f64().unwrap() >= 0.0, "{r}");
    }
    let mem = records
        .iter()
        .find(|r| r["measurement"] == "memory")
        .unwrap();
    let (policy, end) = (
        mem["peak_rss_policy_mib"].as_f64().unwrap(),
        mem["peak_rss_mib"].as_f64().unwrap(),
    );
    assert!(policy > 0.0 && end >= policy, "{mem}");
}

#[test]
fn peer_mode_writes_the_frames_and_times_the_blocks_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 32, 1);
    let frames = dir.path().join("frames");
    let mut child = jetpilot()
        .args(["-q", "bench", "--threads", "1", "--model"])
        .arg(&model)
        .arg("--peer")
        .arg(&frames)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut next = || -> Value { serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap() };

    let ready = next();
    assert_eq!(ready["ready"], true);
    assert_eq!(
        (ready["input_size"].as_u64(), ready["output"].as_str()),
        (Some(32), Some("xy"))
    );
    assert_eq!(ready["spinning"], false);
    let paths = ready["frames"].as_array().unwrap();
    assert!(!paths.is_empty());
    for p in paths {
        let len = std::fs::metadata(p.as_str().unwrap()).unwrap().len();
        assert_eq!(len, 640 * 480 * 3);
    }

    writeln!(stdin, "3").unwrap();
    let reply = next();
    assert_eq!(reply["e2e_ms"].as_array().unwrap().len(), 3, "{reply}");
    assert_eq!(reply["infer_ms"].as_array().unwrap().len(), 3, "{reply}");
    writeln!(stdin, "0").unwrap();
    assert!(child.wait().unwrap().success());
}
