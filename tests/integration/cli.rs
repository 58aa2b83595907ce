//! The `jetpilot` binary as a user runs it: SIGTERM/SIGINT end a run with the motors
//! stopped, `jetpilot stop` writes a stop, and bad inputs (config, model) give errors that
//! name the file and what is wrong.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use jetpilot::policy::ModelContract;
use jetpilot::policy::onnx::{self, Resnet18Weights};

fn jetpilot() -> Command {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
}

fn run(args: &[&str]) -> Output {
    jetpilot().args(args).output().expect("run jetpilot")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A config for the log backend, replaying `frames` in a loop, writing commands to `log`.
fn write_config(dir: &Path, model: &Path, frames: &Path, log: &Path) -> PathBuf {
    let cfg = dir.join("run.toml");
    std::fs::write(
        &cfg,
        format!(
            "[camera]\npath = {frames:?}\nfps = 30.0\nloop = true\n\
             [model]\npath = {model:?}\n\
             [runtime]\nintra_threads = 1\n\
             [control]\nspeed_gain = 0.3\n\
             [motors]\nbackend = \"log\"\nlog_path = {log:?}\n\
             [safety]\nwatchdog_ms = 250\n"
        ),
    )
    .unwrap();
    cfg
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(str::to_string)
        .collect()
}

fn signal_ends_run_with_motors_stopped(signal: &str) {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 64, 1);
    let frames = common::write_frames(dir.path(), 6);
    let log = dir.path().join("motors.jsonl");
    let cfg = write_config(dir.path(), &model, &frames, &log);
    let mut child = jetpilot()
        .args(["-q", "run", "--config"])
        .arg(&cfg)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while lines(&log).iter().filter(|l| l.contains("left")).count() < 5 {
        assert!(start.elapsed() < Duration::from_secs(20), "no commands");
        assert!(child.try_wait().unwrap().is_none(), "exited early");
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let signalled = Instant::now();
    let exit = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            signalled.elapsed() < Duration::from_secs(10),
            "did not exit"
        );
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(exit.success(), "{signal}: {exit:?}");
    let all = lines(&log);
    let first_stop = all
        .iter()
        .rposition(|l| l.contains("left"))
        .map(|i| &all[i + 1])
        .expect("a line after the last command");
    assert!(first_stop.contains("\"stop\":true"), "{all:?}");
}

#[test]
fn sigterm_ends_a_run_with_the_motors_stopped() {
    signal_ends_run_with_motors_stopped("-TERM");
}

#[test]
fn sigint_ends_a_run_with_the_motors_stopped() {
    signal_ends_run_with_motors_stopped("-INT");
}

#[test]
fn stop_command_writes_a_stop() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("m.jsonl");
    let cfg = dir.path().join("stop.toml");
    std::fs::write(
        &cfg,
        format!("[motors]\nbackend = \"log\"\nlog_path = {log:?}\n"),
    )
    .unwrap();
    let out = run(&["stop", "--config", cfg.to_str().unwrap()]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(lines(&log).iter().all(|l| l.contains("\"stop\":true")));
    assert!(!lines(&log).is_empty());
}

/// The write end of a pipe whose reader is already gone: a write to it fails with EPIPE
/// (or raises SIGPIPE), as when `jetpilot ... | head` has read its lines.
fn pipe_without_reader() -> Stdio {
    use std::os::fd::{FromRawFd, OwnedFd};
    let mut fds = [0; 2];
    // SAFETY: pipe() fills two new descriptors, each owned exactly once below.
    assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
    let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
    drop(read);
    Stdio::from(write)
}

#[test]
fn an_offline_command_ends_quietly_when_its_reader_goes_away() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let out = jetpilot()
        .args(["samples", "--count", "2", "--out"])
        .arg(dir.path())
        .stdout(pipe_without_reader())
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.signal(), Some(libc::SIGPIPE), "{err}");
    // The frames were written before the line that could not be printed.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}

#[test]
fn the_daemon_commands_stop_the_motors_and_exit_cleanly_when_stdout_is_gone() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 64, 1);
    let frames = common::write_frames(dir.path(), 6);
    let log = dir.path().join("motors.jsonl");
    let cfg = write_config(dir.path(), &model, &frames, &log);
    for args in [
        &["run", "--duration", "1", "--config"][..],
        &["stop", "--config"][..],
    ] {
        let out = jetpilot()
            .args(args)
            .arg(&cfg)
            .stdout(pipe_without_reader())
            .output()
            .unwrap();
        let err = stderr(&out);
        assert!(out.status.success(), "{args:?}: {:?} {err}", out.status);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        let all = lines(&log);
        assert!(
            all.last().is_some_and(|l| l.contains("\"stop\":true")),
            "{args:?}: {all:?}"
        );
    }
    assert!(
        lines(&log).iter().any(|l| l.contains("left")),
        "the run drove"
    );
}

#[test]
fn malformed_config_names_file_key_and_allowed_values() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, "[control]\nsteering_gain = 7.5\n").unwrap();
    let out = run(&["run", "--config", cfg.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains("bad.toml"), "{err}");
    assert!(err.contains("control.steering_gain` = 7.5"), "{err}");
    assert!(err.contains("allowed 0 ..= 2"), "{err}");

    std::fs::write(&cfg, "[motor]\nbackend = \"log\"\n").unwrap();
    let err = stderr(&run(&["run", "--config", cfg.to_str().unwrap()]));
    assert!(err.contains("unknown field `motor`"), "{err}");
    assert!(err.contains("line 1"), "{err}");
}

fn dry_run(dir: &Path, model: &Path, extra: &str) -> Output {
    let frames = common::write_frames(dir, 2);
    let cfg = dir.join("dry.toml");
    std::fs::write(
        &cfg,
        format!("[camera]\npath = {frames:?}\n[model]\npath = {model:?}\n{extra}"),
    )
    .unwrap();
    run(&["run", "--dry-run", "--config", cfg.to_str().unwrap()])
}

#[test]
fn missing_model_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = dry_run(dir.path(), &dir.path().join("nope.onnx"), "");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("nope.onnx") && err.contains("cannot read"),
        "{err}"
    );
}

#[test]
fn garbage_model_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("garbage.onnx");
    std::fs::write(&model, b"\x89PNG this is not a model at all").unwrap();
    let out = dry_run(dir.path(), &model, "");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("garbage.onnx") && err.contains("cannot load"),
        "{err}"
    );
    let info = run(&["model", "info", model.to_str().unwrap()]);
    assert!(!info.status.success());
    assert!(
        stderr(&info).contains("not an ONNX model"),
        "{}",
        stderr(&info)
    );
}

/// A ResNet-18 without jetpilot metadata, as exported from JetBot's PyTorch notebook.
fn foreign_model(dir: &Path, size: u32, outputs: usize) -> PathBuf {
    let contract = ModelContract {
        input_size: size,
        ..ModelContract::default()
    };
    let mut m =
        onnx::resnet18_model(size, &Resnet18Weights::random(outputs, 0), &contract, "t").unwrap();
    m.metadata_props.clear();
    let path = dir.join(format!("export_{size}_{outputs}.onnx"));
    onnx::write_model(&path, &m).unwrap();
    path
}

#[test]
fn wrong_input_shape_names_expected_and_found() {
    let dir = tempfile::tempdir().unwrap();
    // The model's metadata says 224; its graph takes 96.
    let mut m = onnx::resnet18_model(
        96,
        &Resnet18Weights::random(2, 0),
        &ModelContract {
            input_size: 96,
            ..ModelContract::default()
        },
        "t",
    )
    .unwrap();
    for p in &mut m.metadata_props {
        if p.key == jetpilot::policy::contract::META_INPUT_SIZE {
            p.value = "224".into();
        }
    }
    let model = dir.path().join("mislabelled.onnx");
    onnx::write_model(&model, &m).unwrap();
    let out = dry_run(dir.path(), &model, "");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains("input `input` has shape [1,3,96,96]"), "{err}");
    assert!(err.contains("expected [1,3,224,224]"), "{err}");
}

#[test]
fn wrong_output_shape_names_expected_and_found() {
    let dir = tempfile::tempdir().unwrap();
    let out = {
        let frames = common::write_frames(dir.path(), 2);
        let cfg = dir.path().join("o.toml");
        let model = foreign_model(dir.path(), 64, 3);
        std::fs::write(
            &cfg,
            format!("[camera]\npath = {frames:?}\n[model]\npath = {model:?}\ninput_size = 64\n"),
        )
        .unwrap();
        run(&["run", "--dry-run", "--config", cfg.to_str().unwrap()])
    };
    let err = stderr(&out);
    assert!(!out.status.success());
    assert!(err.contains("output `output` has shape [1,3]"), "{err}");
    assert!(err.contains("expected [1,2]"), "{err}");
}

#[test]
fn a_model_without_metadata_runs_with_the_config_contract() {
    let dir = tempfile::tempdir().unwrap();
    let frames = common::write_frames(dir.path(), 2);
    let model = foreign_model(dir.path(), 64, 2);
    let cfg = dir.path().join("c.toml");
    std::fs::write(
        &cfg,
        format!(
            "[camera]\npath = {frames:?}\n[model]\npath = {model:?}\ninput_size = 64\nchannel_order = \"bgr\"\n"
        ),
    )
    .unwrap();
    let out = run(&["run", "--dry-run", "--config", cfg.to_str().unwrap()]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("resize to 64x64, bgr planes"), "{text}");
    let info = run(&["model", "info", model.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&info.stdout).contains("none in the file"));
}

#[test]
fn a_model_without_metadata_keeps_its_fixed_input_size() {
    // JetBot's notebook exports have a fixed input and no metadata: the graph's size wins over
    // the config's model.input_size (here the default 224), the other keys stay the config's.
    let dir = tempfile::tempdir().unwrap();
    let model = foreign_model(dir.path(), 96, 2);
    let out = dry_run(dir.path(), &model, "");
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("resize to 96x96, rgb planes"), "{text}");
}

#[test]
fn help_lists_the_commands() {
    let out = run(&["--help"]);
    let text = String::from_utf8_lossy(&out.stdout);
    for cmd in ["run", "stop", "model", "bench", "samples"] {
        assert!(text.contains(cmd), "{text}");
    }
}
