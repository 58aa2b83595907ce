//! The daemon as a process, faulted at random moments the way a robot meets them: SIGTERM
//! (`systemctl stop`), SIGKILL followed by `jetpilot stop` (what the systemd unit's
//! `ExecStopPost` runs after every exit, a kill included), the camera's command dying
//! mid-run (a CSI pipeline that crashes), and a real ONNX Runtime error mid-run (a model
//! that fails on bright frames). Each round measures how long after the fault the motors
//! were stopped for good: the virtual motors' log is polled every millisecond, and the
//! moment counts when the stop that follows the last drive command is on it (for the
//! runtime error, on the daemon's clock, from the last good command).
//!
//! The tests check what must always hold (the run ends stopped, the daemon's own stop on
//! SIGTERM and on a dead camera, a bound of 1 s on a loaded test machine);
//! `scripts/faults-under-load.sh` runs 50 rounds of each kind under CPU and I/O load and
//! holds the worst time to the watchdog period. Environment:
//! - `JETPILOT_FAULT_ROUNDS`: rounds per kind (default 2);
//! - `JETPILOT_FAULT_TIMES=FILE`: append `kind,round,delay_ms,stop_ms,drove,last_drive_ms`
//!   per round;
//! - `JETPILOT_BIN`: the binary to run (default: the test build's).
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};

/// The daemon's watchdog period in these runs (the shipped default).
const WATCHDOG_MS: u64 = 250;
/// What a test asserts: far above the watchdog, so a loaded CI machine does not flake;
/// the script holds the measured worst to `WATCHDOG_MS`.
const BOUND: Duration = Duration::from_secs(1);
/// Frames of the pipe camera.
const SIDE: u32 = 64;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Fault {
    /// SIGTERM to the daemon; systemd's ExecStopPost (`jetpilot stop`) afterwards.
    Term,
    /// SIGKILL to the daemon; then `jetpilot stop`, as ExecStopPost.
    Kill,
    /// SIGKILL to the camera's command: the daemon must stop the motors itself.
    CameraGone,
}

impl Fault {
    fn name(self) -> &'static str {
        match self {
            Fault::Term => "sigterm",
            Fault::Kill => "sigkill",
            Fault::CameraGone => "camera_gone",
        }
    }
}

struct Rig {
    _dir: tempfile::TempDir,
    config: PathBuf,
    log: PathBuf,
    camera_pid: PathBuf,
    stderr: PathBuf,
}

/// A model, one raw frame and a config: the pipe camera repeats the frame at 30 fps and
/// writes its shell's pid to `camera.pid`; motors are the log backend. The camera ends
/// when a write fails (its reader, the daemon, is gone), as a GStreamer pipeline does; a
/// `while :` loop would outlive a killed daemon and load the machine round after round.
fn rig() -> Rig {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), SIDE, 5);
    let frame = dir.path().join("frame.rgb");
    let rgb = jetpilot::camera::synthetic::render_road(
        SIDE,
        SIDE,
        jetpilot::camera::synthetic::sample_view(3, 10),
    );
    std::fs::write(&frame, rgb).unwrap();
    let camera_pid = dir.path().join("camera.pid");
    let command = format!(
        "echo $$ > {pid}; exec sh -c 'while cat {frame}; do sleep 0.033; done'",
        pid = camera_pid.display(),
        frame = frame.display()
    );
    rig_in(dir, &model, &command, camera_pid)
}

/// The config for `model` and the pipe camera's `command`, in `dir`.
fn rig_in(dir: tempfile::TempDir, model: &Path, command: &str, camera_pid: PathBuf) -> Rig {
    let log = dir.path().join("motors.jsonl");
    let config = dir.path().join("run.toml");
    std::fs::write(
        &config,
        format!(
            "[camera]\nsource = \"pipe\"\nformat = \"rgb3\"\nwidth = {SIDE}\nheight = {SIDE}\n\
             command = {command:?}\n\
             [model]\npath = {model:?}\n\
             [runtime]\nintra_threads = 1\n\
             [control]\nspeed_gain = 0.3\n\
             [motors]\nbackend = \"log\"\nlog_path = {log:?}\n\
             [log]\nprint_commands = false\nstats_interval_s = 0.0\n\
             [safety]\nwatchdog_ms = {WATCHDOG_MS}\n"
        ),
    )
    .unwrap();
    let stderr = dir.path().join("stderr.txt");
    Rig {
        _dir: dir,
        config,
        log,
        camera_pid,
        stderr,
    }
}

impl Rig {
    /// `jetpilot run` on this rig's config, its standard error to `stderr.txt`.
    fn start(&self) -> Child {
        jetpilot()
            .args(["run", "--config"])
            .arg(&self.config)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&self.stderr).unwrap())
            .spawn()
            .expect("start jetpilot run")
    }

    /// The camera's shell, from its pid file, if it wrote one.
    fn camera(&self) -> Option<u32> {
        std::fs::read_to_string(&self.camera_pid)
            .ok()
            .and_then(|s| s.trim().parse().ok())
    }

    /// Kills what is left of the camera (it ends by itself once its reader is gone).
    fn kill_camera(&self) {
        if let Some(p) = self.camera() {
            let _ = Command::new("kill")
                .args(["-KILL", &p.to_string()])
                .stderr(Stdio::null())
                .status();
        }
    }
}

/// The binary under test: `JETPILOT_BIN` (the script passes the release build, the one a
/// robot runs: a 250 MB debug binary takes far longer to start under disk load), else the
/// test build's.
fn jetpilot() -> Command {
    match std::env::var_os("JETPILOT_BIN") {
        Some(bin) => Command::new(bin),
        None => Command::new(env!("CARGO_BIN_EXE_jetpilot")),
    }
}

fn log_len(path: &Path) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len())
}

fn signal(pid: u32, sig: &str) {
    let ok = Command::new("kill")
        .args([sig, &pid.to_string()])
        .status()
        .expect("run kill");
    assert!(ok.success(), "kill {sig} {pid}");
}

/// Polls the motors' log every millisecond while `child` runs: (time since `from`, bytes).
fn watch(
    child: &mut Child,
    log: &Path,
    from: Instant,
    trace: &mut Vec<(Duration, u64)>,
) -> ExitStatus {
    loop {
        trace.push((from.elapsed(), log_len(log)));
        if let Some(s) = child.try_wait().expect("wait") {
            trace.push((from.elapsed(), log_len(log)));
            return s;
        }
        assert!(
            from.elapsed() < Duration::from_secs(20),
            "still running 20 s after the fault"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// What one round saw.
struct Round {
    /// From the fault to the stop after the last drive on the log (zero when that stop came
    /// before the fault); `None` when the motors never drove.
    stop: Option<Duration>,
    /// The stop after the last drive was the daemon's own (before `jetpilot stop` ran).
    own_stop: bool,
    /// When the last drive command was on the log, ms from the fault (negative: before).
    last_drive_ms: Option<f64>,
    exit: ExitStatus,
}

/// When a round's fault comes.
#[derive(Clone, Copy, Debug)]
enum Moment {
    /// This long after the daemon started (it may still be loading the model).
    AfterStart(Duration),
    /// This long after its first command reached the motors.
    AfterFirstDrive(Duration),
}

fn run_round(rig: &Rig, fault: Fault, moment: Moment) -> Round {
    let _ = std::fs::remove_file(&rig.log);
    let _ = std::fs::remove_file(&rig.camera_pid);
    let mut child = rig.start();
    let started = Instant::now();
    let delay = match moment {
        Moment::AfterStart(d) => d,
        Moment::AfterFirstDrive(d) => {
            while !std::fs::read_to_string(&rig.log).is_ok_and(|t| t.contains("\"left\"")) {
                assert!(child.try_wait().unwrap().is_none(), "exited before driving");
                assert!(started.elapsed() < Duration::from_secs(30), "never drove");
                std::thread::sleep(Duration::from_millis(1));
            }
            d
        }
    };
    std::thread::sleep(delay);
    let pid = match fault {
        Fault::Term | Fault::Kill => child.id(),
        Fault::CameraGone => loop {
            // The camera must be up to die: wait for its pid.
            if let Some(p) = rig.camera() {
                break p;
            }
            assert!(
                child.try_wait().unwrap().is_none(),
                "exited before its camera started"
            );
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "the camera never started"
            );
            std::thread::sleep(Duration::from_millis(1));
        },
    };
    let at = Instant::now();
    signal(
        pid,
        if fault == Fault::Term {
            "-TERM"
        } else {
            "-KILL"
        },
    );
    let mut trace = Vec::new();
    let exit = watch(&mut child, &rig.log, at, &mut trace);
    let daemon_bytes = log_len(&rig.log);
    // systemd runs ExecStopPost after every exit; do the same (it is what saves a SIGKILL).
    let mut post = jetpilot()
        .args(["-q", "stop", "--config"])
        .arg(&rig.config)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start jetpilot stop");
    let post_exit = watch(&mut post, &rig.log, at, &mut trace);
    // Whatever happened, no camera outlives its round.
    rig.kill_camera();
    assert!(post_exit.success(), "jetpilot stop failed: {post_exit:?}");

    let text = std::fs::read_to_string(&rig.log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    assert!(
        lines.last().is_some_and(|l| l.contains("\"stop\":true")),
        "{fault:?}: the log does not end with a stop: {:?}",
        lines.iter().rev().take(3).collect::<Vec<_>>()
    );
    let Some(last_drive) = lines.iter().rposition(|l| l.contains("\"left\"")) else {
        return Round {
            stop: None,
            own_stop: true,
            last_drive_ms: None,
            exit,
        };
    };
    // The byte where the stop after the last drive ends.
    let stop_end: u64 = lines[..=last_drive + 1]
        .iter()
        .map(|l| l.len() as u64 + 1)
        .sum();
    let seen = trace
        .iter()
        .find(|(_, bytes)| *bytes >= stop_end)
        .map_or(trace.last().map_or(Duration::ZERO, |t| t.0), |t| t.0);
    // The same for the last drive; the trace starts at the fault, so a drive already on
    // the log then counts as "before" (its time is not known: -0).
    let drive_end = stop_end - lines[last_drive + 1].len() as u64 - 1;
    let before = trace.first().is_some_and(|(_, b)| *b >= drive_end);
    let last_drive_ms = if before {
        -0.0
    } else {
        trace
            .iter()
            .find(|(_, b)| *b >= drive_end)
            .map_or(0.0, |t| t.0.as_secs_f64() * 1e3)
    };
    Round {
        stop: Some(seen),
        own_stop: stop_end <= daemon_bytes,
        last_drive_ms: Some(last_drive_ms),
        exit,
    }
}

fn rounds() -> usize {
    std::env::var("JETPILOT_FAULT_ROUNDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2)
}

/// Rounds of one fault at random moments, seeded per kind: four in five from 0 to 1 s
/// after the first command reached the motors, one in five from 0 to 0.5 s after the
/// start, while the daemon may still be loading the model (`KIND_at_startup` in the times).
fn rounds_of(fault: Fault, seed: u64) {
    let rig = rig();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut drove = 0;
    for round in 0..rounds() {
        let at_startup = round % 5 == 4;
        let (moment, delay, kind) = if at_startup {
            let d = Duration::from_millis(rng.random_range(0..500));
            (
                Moment::AfterStart(d),
                d,
                format!("{}_at_startup", fault.name()),
            )
        } else {
            let d = Duration::from_millis(rng.random_range(0..1000));
            (Moment::AfterFirstDrive(d), d, fault.name().to_string())
        };
        let r = run_round(&rig, fault, moment);
        common::record_fault_time(&kind, round, delay, r.stop, r.last_drive_ms);
        if let Some(stop) = r.stop {
            drove += 1;
            assert!(
                stop <= BOUND,
                "{fault:?} round {round}: stopped {stop:?} after the fault"
            );
        }
        match fault {
            // Once driving, the daemon's own stop comes first, and the run ends cleanly
            // (a TERM early in start-up, before the handler is set, kills it; nothing
            // drove then, and ExecStopPost stops the motors all the same).
            Fault::Term => {
                if !at_startup || (r.stop.is_some() && r.exit.code().is_some()) {
                    assert!(r.exit.success(), "round {round}: {:?}", r.exit);
                    assert!(
                        r.own_stop,
                        "round {round}: only ExecStopPost stopped the motors"
                    );
                }
            }
            Fault::Kill => assert!(r.exit.code().is_none(), "round {round}: not killed"),
            // A camera that dies is a fault: the daemon stops the motors and says so.
            Fault::CameraGone => {
                assert!(
                    !r.exit.success(),
                    "round {round}: a dead camera ended cleanly"
                );
                assert!(
                    r.own_stop || r.stop.is_none(),
                    "round {round}: only ExecStopPost stopped the motors"
                );
                let err = std::fs::read_to_string(&rig.stderr).unwrap_or_default();
                assert!(err.contains("camera"), "round {round}: {err}");
            }
        }
    }
    // Four rounds in five come after the first command: they all drove.
    assert!(
        drove >= rounds() - rounds() / 5,
        "{fault:?}: only {drove} rounds drove"
    );
}

#[test]
fn sigterm_at_random_moments_ends_with_the_motors_stopped() {
    rounds_of(Fault::Term, 1);
}

#[test]
fn sigkill_at_random_moments_then_exec_stop_post_stops_the_motors() {
    rounds_of(Fault::Kill, 2);
}

#[test]
fn the_camera_command_dying_mid_run_stops_the_motors() {
    rounds_of(Fault::CameraGone, 3);
}

/// A 64x64 model that ONNX Runtime runs on a dark frame and fails on a bright one, as a
/// real runtime error comes mid-run: `Gather` of row `Cast(mean(input), INT64)` from a
/// 2-row table. A black frame's normalised mean is about -2.0 (row -2, the first); a white
/// one's about +2.4, row 2: "indices element out of data bounds".
fn model_failing_on_bright_frames(dir: &Path) -> PathBuf {
    use jetpilot::policy::ModelContract;
    use jetpilot::policy::onnx::{self, Dim, GraphBuilder, attr_int};
    let contract = ModelContract {
        input_size: SIDE,
        ..ModelContract::default()
    };
    let side = SIDE as i64;
    let mut g = GraphBuilder::new("fails_on_bright_frames");
    g.input_f32("input", &[1, 3, side, side].map(Dim::Fixed));
    g.initializer_f32("table", &[2, 2], &[0.1, 0.2, 0.1, 0.2])
        .unwrap();
    g.initializer_i64("shape", &[2], &[1, 2]).unwrap();
    g.node(
        "ReduceMean",
        &["input"],
        &["mean"],
        vec![attr_int("keepdims", 0)],
    );
    g.node("Cast", &["mean"], &["row"], vec![attr_int("to", 7)]); // INT64
    g.node(
        "Gather",
        &["table", "row"],
        &["picked"],
        vec![attr_int("axis", 0)],
    );
    g.node("Reshape", &["picked", "shape"], &["output"], vec![]);
    g.output_f32("output", &[1, 2].map(Dim::Fixed));
    let model = g.finish("test", "0", &contract.to_metadata()).unwrap();
    let path = dir.join("fails_on_bright_frames.onnx");
    onnx::write_model(&path, &model).unwrap();
    path
}

#[test]
fn an_onnx_runtime_error_mid_run_stops_the_motors() {
    // The camera sends K black frames, then white ones: ONNX Runtime fails on the first
    // white frame it runs, after K - (frames dropped) good commands. K is random per round.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    for round in 0..rounds() {
        let dir = tempfile::tempdir().unwrap();
        let model = model_failing_on_bright_frames(dir.path());
        let (black, white) = (dir.path().join("black.rgb"), dir.path().join("white.rgb"));
        let n = (SIDE * SIDE * 3) as usize;
        std::fs::write(&black, vec![0u8; n]).unwrap();
        std::fs::write(&white, vec![255u8; n]).unwrap();
        let camera_pid = dir.path().join("camera.pid");
        let k: u32 = rng.random_range(10..40);
        let command = format!(
            "echo $$ > {pid}; i=0; while [ $i -lt {k} ] && cat {black}; do sleep 0.033; i=$((i + 1)); done; \
             while cat {white}; do sleep 0.033; done",
            pid = camera_pid.display(),
            black = black.display(),
            white = white.display()
        );
        let rig = rig_in(dir, &model, &command, camera_pid);
        let mut child = rig.start();
        let started = Instant::now();
        let exit = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "round {round}: still running"
            );
            std::thread::sleep(Duration::from_millis(5));
        };
        let err = std::fs::read_to_string(&rig.stderr).unwrap_or_default();
        assert!(
            !exit.success(),
            "round {round}: a runtime error ended cleanly"
        );
        assert!(
            err.contains("out of data bounds") || err.contains("indices"),
            "round {round}: {err}"
        );
        // On the daemon's own clock: the stop after the last good command.
        let text = std::fs::read_to_string(&rig.log).unwrap();
        let t = |l: &str| -> f64 {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            v["t"].as_f64().unwrap()
        };
        let lines: Vec<&str> = text.lines().collect();
        let last = lines
            .iter()
            .rposition(|l| l.contains("\"left\""))
            .unwrap_or_else(|| panic!("round {round}: never drove: {err}"));
        let stop = lines
            .get(last + 1)
            .filter(|l| l.contains("\"stop\":true"))
            .unwrap_or_else(|| panic!("round {round}: no stop after the last command"));
        assert!(
            lines[last + 1..]
                .iter()
                .all(|l| l.contains("\"stop\":true")),
            "round {round}: drove after the stop"
        );
        let gap = Duration::from_secs_f64(t(stop) - t(lines[last]));
        common::record_fault_time("onnx_runtime_error", round, Duration::ZERO, Some(gap), None);
        assert!(
            gap <= BOUND,
            "round {round}: stopped {gap:?} after the last command"
        );
        rig.kill_camera();
    }
}
