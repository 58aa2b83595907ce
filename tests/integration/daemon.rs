//! The daemon end to end: real frames + a real ONNX model on ONNX Runtime + the steering
//! law + a virtual or mocked motor output, and fault injection (stalled source, source
//! error, NaN output, model error, panic, I2C error) asserting that the motors are stopped.
//!
//! Needs the ONNX Runtime library (scripts/install-onnxruntime.sh; the test command runs it).

use crate::common;

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use crate::common::{FlakyBus, ScriptedPolicy, ScriptedSource, Step};
use embedded_hal_mock::eh1::delay::NoopDelay;
use jetpilot::camera::folder::FolderSource;
use jetpilot::clock::{Clock, MonotonicClock};
use jetpilot::control::{SteeringGains, SteeringLaw, WheelCommand};
use jetpilot::drive::{self, DriveError, DriveParams, Outcome, Parts, RunEnd};
use jetpilot::hw::motor_hat::{HatSettings, MotorHat};
use jetpilot::hw::motors::{MotorEvent, MotorRecord};
use jetpilot::hw::{HatLayout, LogMotors, MotorOutput};
use jetpilot::policy::{Policy, Preprocessor};

const WATCHDOG: Duration = Duration::from_millis(200);
/// Timer and scheduling slack allowed on top of the watchdog period on a busy 2-core machine.
const SLACK: Duration = Duration::from_millis(150);

fn params(gains: SteeringGains) -> DriveParams {
    DriveParams {
        gains,
        watchdog: WATCHDOG,
        max_frame_age: Duration::from_secs(5),
        max_abs_output: 10.0,
        stats_interval: Duration::ZERO,
    }
}

fn gains() -> SteeringGains {
    SteeringGains {
        speed_gain: 0.3,
        steering_gain: 0.25,
        steering_kd: 0.1,
        ..SteeringGains::default()
    }
}

fn block_on<F: std::future::Future>(f: F) -> F::Output {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
        .block_on(f)
}

/// Runs the daemon with log motors until `shutdown_after` (or the end of the source).
fn run_logged(
    source: Box<dyn jetpilot::camera::FrameSource>,
    policy: Box<dyn Policy>,
    clock: Arc<dyn Clock>,
    shutdown_after: Duration,
) -> (Outcome, MotorRecord) {
    let motors = LogMotors::new(clock.clone());
    let record = motors.record();
    let parts = Parts {
        source,
        policy,
        motors: Box::new(motors),
        clock,
        teleop: None,
        status: None,
        live: None,
    };
    let out = block_on(async {
        drive::run(parts, params(gains()), tokio::time::sleep(shutdown_after)).await
    });
    (out, record)
}

fn drives(record: &MotorRecord) -> Vec<(Duration, WheelCommand)> {
    record
        .lock()
        .unwrap()
        .iter()
        .filter_map(|(t, e)| match e {
            MotorEvent::Drive(c) => Some((*t, *c)),
            MotorEvent::Stop => None,
        })
        .collect()
}

/// The first stop after the last drive, and how long after it came.
fn stop_after_last_drive(record: &MotorRecord) -> Duration {
    let rec = record.lock().unwrap();
    let last_drive = rec
        .iter()
        .rposition(|(_, e)| matches!(e, MotorEvent::Drive(_)))
        .expect("at least one drive");
    let (t_drive, _) = rec[last_drive];
    let (t_stop, _) = rec[last_drive..]
        .iter()
        .find(|(_, e)| *e == MotorEvent::Stop)
        .expect("a stop after the last drive");
    *t_stop - t_drive
}

#[test]
fn motor_commands_follow_the_model_through_the_steering_law() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 64, 3);
    let frames = common::write_frames(dir.path(), 12);
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    // 10 fps against a ~2 ms model: no frame is skipped, so every frame gets a command.
    let source = FolderSource::open(&frames, 10.0, false, clock.clone()).unwrap();
    let (outcome, record) = run_logged(
        Box::new(source),
        Box::new(common::load_ort(&model)),
        clock,
        Duration::from_secs(30),
    );
    let (end, report) = outcome.expect("clean run");
    assert_eq!(end, RunEnd::SourceFinished);
    assert_eq!(report.frames_skipped, 0, "{report}");
    let got = drives(&record);
    assert_eq!(got.len(), 12, "{report}");

    // The same frames through a second session and the law, by hand.
    let mut policy = common::load_ort(&model);
    let mut pre = Preprocessor::new(policy.contract());
    let mut law = SteeringLaw::new(gains(), policy.contract().output);
    let files = jetpilot::camera::folder::list_images(&frames).unwrap();
    let mut steering_seen = Vec::new();
    for (file, (_, cmd)) in files.iter().zip(&got) {
        let img = image::open(file).unwrap().to_rgb8();
        let input = pre.run(img.width(), img.height(), img.as_raw()).unwrap();
        let out = policy.infer(input).unwrap();
        let want = law.step(out, 0.1).wheels;
        assert!(
            (want.left - cmd.left).abs() < 1e-5 && (want.right - cmd.right).abs() < 1e-5,
            "{file:?}: model {out:?} -> expected {want:?}, motors got {cmd:?}"
        );
        steering_seen.push(((cmd.left - cmd.right) * 1e4).round() as i64);
    }
    steering_seen.dedup();
    assert!(
        steering_seen.len() > 3,
        "commands should vary with the frames: {steering_seen:?}"
    );
    assert_eq!(
        record.lock().unwrap().last().unwrap().1,
        MotorEvent::Stop,
        "ends stopped"
    );
}

#[test]
fn a_stalled_camera_stops_the_motors_within_the_watchdog_period() {
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let source = ScriptedSource::new(5, Duration::from_millis(20), false, clock.clone());
    let release = source.release.clone();
    let policy = ScriptedPolicy::new(|_| Step::Out([0.2, 0.3]));
    let (outcome, record) = run_logged(
        Box::new(source),
        Box::new(policy),
        clock,
        Duration::from_millis(900),
    );
    release.store(true, Ordering::Relaxed);
    let (end, report) = outcome.expect("a stall is not a fault");
    assert_eq!(end, RunEnd::Shutdown);
    assert_eq!(report.watchdog_stops, 1);
    assert_eq!(drives(&record).len(), 5);
    let gap = stop_after_last_drive(&record);
    // The watchdog stops a stalled camera at the end of its period: the time past it.
    common::record_fault_time(
        "stalled_camera_past_watchdog",
        0,
        Duration::ZERO,
        Some(gap.saturating_sub(WATCHDOG)),
        None,
    );
    assert!(
        gap >= WATCHDOG && gap <= WATCHDOG + SLACK,
        "stop {gap:?} after the last command"
    );
}

/// Runs a fault scenario and checks: the run ends with the fault, and the motors were
/// stopped within the watchdog period of the last command.
fn assert_fault_stops(
    kind: &str,
    source: ScriptedSource,
    policy: ScriptedPolicy,
    expect: impl Fn(&DriveError) -> bool,
) {
    let clock = source.clock.clone();
    let (outcome, record) = run_logged(
        Box::new(source),
        Box::new(policy),
        clock,
        Duration::from_secs(10),
    );
    let (err, _) = outcome.expect_err("the fault ends the run");
    assert!(expect(&err), "unexpected error: {err}");
    let gap = stop_after_last_drive(&record);
    common::record_fault_time(kind, 0, Duration::ZERO, Some(gap), None);
    assert!(
        gap <= WATCHDOG + SLACK,
        "stop {gap:?} after the last command"
    );
}

fn source(frames: u64, then_fail: bool) -> ScriptedSource {
    ScriptedSource::new(
        frames,
        Duration::from_millis(10),
        then_fail,
        Arc::new(MonotonicClock::new()),
    )
}

#[test]
fn a_nan_model_output_stops_the_motors() {
    let policy =
        ScriptedPolicy::new(|n| Step::Out(if n < 3 { [0.1, 0.2] } else { [f32::NAN, 0.2] }));
    // The policy's fourth call sees frame 3 unless the daemon dropped a stale frame
    // (latest frame wins when inference lags, as on a loaded CI machine): then it is a
    // later frame. Either way the first NaN ends the run.
    assert_fault_stops("nan_output", source(20, false), policy, |e| {
        matches!(e, DriveError::BadOutput { seq, .. } if *seq >= 3) && e.to_string().contains("NaN")
    });
}

#[test]
fn an_out_of_range_model_output_stops_the_motors() {
    let policy = ScriptedPolicy::new(|n| Step::Out(if n < 2 { [0.1, 0.2] } else { [0.1, 1e9] }));
    assert_fault_stops("out_of_range_output", source(20, false), policy, |e| {
        matches!(e, DriveError::BadOutput { .. }) && e.to_string().contains("max_abs_output")
    });
}

#[test]
fn an_inference_error_stops_the_motors() {
    let policy = ScriptedPolicy::new(|n| {
        if n < 3 {
            Step::Out([0.1, 0.2])
        } else {
            Step::Fail("device lost")
        }
    });
    assert_fault_stops("inference_error", source(20, false), policy, |e| {
        matches!(e, DriveError::Policy(_)) && e.to_string().contains("device lost")
    });
}

#[test]
fn a_panicking_model_stops_the_motors() {
    let policy = ScriptedPolicy::new(|n| {
        if n < 3 {
            Step::Out([0.1, 0.2])
        } else {
            Step::Panic
        }
    });
    assert_fault_stops("model_panic", source(20, false), policy, |e| {
        matches!(e, DriveError::StageDied("inference"))
    });
}

#[test]
fn a_frame_source_error_stops_the_motors() {
    let policy = ScriptedPolicy::new(|_| Step::Out([0.1, 0.2]));
    assert_fault_stops(
        "camera_error",
        source(4, true),
        policy,
        |e| matches!(e, DriveError::Camera(m) if m.contains("unplugged")),
    );
}

/// Drives an Adafruit HAT on a bus whose transactions `fail` (counted from the first after
/// init) fail, from `frames` scripted frames (then a stall), until `shutdown`; returns the
/// run's outcome, the bus, and the number of init transactions.
fn drive_hat_on_flaky_bus(
    fail: std::ops::Range<usize>,
    frames: ScriptedSource,
    shutdown: Duration,
) -> (Outcome, FlakyBus, usize) {
    let bus = FlakyBus::default();
    let hat = MotorHat::init(
        bus.clone(),
        HatSettings::for_layout(HatLayout::Adafruit),
        &mut NoopDelay,
    )
    .unwrap();
    let init_writes = bus.writes.lock().unwrap().len();
    *bus.fail.lock().unwrap() = init_writes + fail.start..init_writes + fail.end;
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let parts = Parts {
        source: Box::new(frames),
        policy: Box::new(ScriptedPolicy::new(|n| {
            Step::Out(if n % 2 == 0 { [0.3, 0.2] } else { [-0.3, 0.2] })
        })),
        motors: Box::new(hat) as Box<dyn MotorOutput>,
        clock,
        teleop: None,
        status: None,
        live: None,
    };
    let outcome =
        block_on(async { drive::run(parts, params(gains()), tokio::time::sleep(shutdown)).await });
    (outcome, bus, init_writes)
}

#[test]
fn an_i2c_error_stops_the_motors() {
    // Adafruit HAT on a bus that fails 3 transactions in a row (1 try + 2 retries) once the
    // robot is driving, then recovers: the daemon faults and its stop reaches the chip.
    // The first drive writes 4 transactions per motor (PWM, IN low cached, IN high = 2);
    // fail from the 10th transaction after init, i.e. during the second or third command.
    let (outcome, bus, _) =
        drive_hat_on_flaky_bus(10..13, source(50, false), Duration::from_secs(10));
    let (err, report) = outcome.expect_err("I2C failure is a fault");
    assert!(matches!(err, DriveError::Motor(_)), "{err}");
    assert!(err.to_string().contains("after 3 attempts"), "{err}");
    assert!(report.commands_written >= 1);
    // After the failures, the last six writes release every motor channel
    // (full-off bit on OFF_H of channels 8, 10, 9, 13, 11, 12).
    let writes = bus.writes.lock().unwrap();
    let tail: Vec<&Vec<u8>> = writes.iter().rev().take(6).map(|(_, b, _)| b).collect();
    let mut regs: Vec<u8> = tail.iter().map(|b| b[0]).collect();
    regs.sort();
    assert_eq!(regs, vec![0x28, 0x2C, 0x30, 0x34, 0x38, 0x3C]);
    assert!(tail.iter().all(|b| b[1..] == [0x00, 0x10]));
    assert!(writes.iter().rev().take(6).all(|(_, _, failed)| !failed));
}

#[test]
fn one_i2c_error_is_retried_and_driving_goes_on() {
    // One failed transaction (a glitch on the bus): the retry writes it again, no fault,
    // every command reaches the chip and the run ends normally, stopped. 20 frames, then
    // the source stalls until released (the watchdog stops the motors).
    let frames = source(20, false);
    let release = frames.release.clone();
    let (outcome, bus, init_writes) =
        drive_hat_on_flaky_bus(10..11, frames, Duration::from_secs(1));
    release.store(true, Ordering::Relaxed);
    let (end, report) = outcome.expect("one I2C error is retried, not a fault");
    assert_eq!(end, RunEnd::Shutdown);
    assert!(report.commands_written >= 15, "{report}");
    let writes = bus.writes.lock().unwrap();
    let failed: Vec<usize> = (0..writes.len()).filter(|&i| writes[i].2).collect();
    assert_eq!(failed, vec![init_writes + 10]);
    // The failed transaction was written again at once: the same bytes, next.
    assert_eq!(writes[init_writes + 10].1, writes[init_writes + 11].1);
    // It ends released: the last six writes set the full-off bit of every motor channel.
    assert!(
        writes
            .iter()
            .rev()
            .take(6)
            .all(|(_, b, _)| b[1..] == [0x00, 0x10])
    );
}

/// Fails (recoverably, like an unplugged USB camera) after `fail_at` frames, `failures`
/// times, then delivers frames again.
struct FlakyCamera {
    inner: ScriptedSource,
    fail_at: u64,
    failures: u32,
}

impl jetpilot::camera::FrameSource for FlakyCamera {
    fn next_frame(
        &mut self,
    ) -> Result<Option<jetpilot::camera::Frame>, jetpilot::camera::CameraError> {
        if self.inner_seq() == self.fail_at && self.failures > 0 {
            self.failures -= 1;
            std::thread::sleep(Duration::from_millis(100));
            return Err(jetpilot::camera::CameraError::Other(
                "/dev/video0: No such device (unplugged)".into(),
            ));
        }
        self.inner.next_frame()
    }
    fn describe(&self) -> String {
        "flaky camera".into()
    }
    fn recoverable(&self) -> bool {
        true
    }
}

impl FlakyCamera {
    fn inner_seq(&self) -> u64 {
        self.inner.produced()
    }
}

#[test]
fn an_unplugged_camera_stops_the_motors_then_driving_resumes() {
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let cam = FlakyCamera {
        inner: ScriptedSource::new(30, Duration::from_millis(10), false, clock.clone()),
        fail_at: 5,
        failures: 3,
    };
    let release = cam.inner.release.clone();
    let (outcome, record) = run_logged(
        Box::new(cam),
        Box::new(ScriptedPolicy::new(|_| Step::Out([0.1, 0.2]))),
        clock,
        Duration::from_millis(1200),
    );
    release.store(true, Ordering::Relaxed);
    let (end, report) = outcome.expect("a recovering camera is not fatal");
    assert_eq!(end, RunEnd::Shutdown);
    assert_eq!(report.source_errors, 3, "{report}");
    let events = record.lock().unwrap().clone();
    // Drives, then a stop when the camera fails, then drives again once it is back.
    let first_stop = events
        .iter()
        .position(|(_, e)| *e == MotorEvent::Stop)
        .expect("a stop");
    // The camera takes 100 ms to fail (FlakyCamera): time the stop from its error.
    let gap = events[first_stop].0 - events[first_stop - 1].0;
    common::record_fault_time(
        "camera_unplugged",
        0,
        Duration::ZERO,
        Some(gap.saturating_sub(Duration::from_millis(100))),
        None,
    );
    assert!(
        gap <= WATCHDOG + SLACK,
        "stop {gap:?} after the last command"
    );
    assert_eq!(
        events[..first_stop]
            .iter()
            .filter(|(_, e)| matches!(e, MotorEvent::Drive(_)))
            .count(),
        5
    );
    assert!(
        events[first_stop..]
            .iter()
            .any(|(_, e)| matches!(e, MotorEvent::Drive(_))),
        "driving resumed"
    );
    assert_eq!(drives(&record).len(), 30);
}

#[test]
fn a_gamepad_takeover_is_an_intervention_and_logged() {
    use evdev::{AbsoluteAxisCode, KeyCode};
    use jetpilot::drive::interventions::{InterventionLog, SessionInfo, read};
    use jetpilot::drive::modes::{ModeParams, Modes};
    use jetpilot::drive::teleop::TeleopParts;
    use jetpilot::hw::gamepad::{GamepadConfig, GamepadMap, GamepadState, InputEvent};

    let dir = tempfile::tempdir().unwrap();
    let log_path = dir.path().join("interventions.jsonl");
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let motors = LogMotors::new(clock.clone());
    let record = motors.record();
    let cfg = GamepadConfig::default(); // xbox profile, tank drive, heartbeat 500 ms
    let (tx, events) = tokio::sync::mpsc::channel(64);
    let teleop = TeleopParts {
        events: Some(events),
        remote: None,
        remote_rx: None,
        pad: GamepadState::new(GamepadMap::from_config(&cfg).unwrap()),
        modes: Modes::new(ModeParams::from_gamepad(&cfg), gains()),
        autopilot_available: true,
        log: Some(
            InterventionLog::open(
                &log_path,
                SessionInfo::new("test.onnx".into(), "fnv1a64:0".into()),
            )
            .unwrap(),
        ),
        model_hash: "fnv1a64:0".into(),
        recorder: None,
        open_recorder: None,
        recording: false,
    };
    let source = ScriptedSource::new(1000, Duration::from_millis(20), false, clock.clone());
    let release = source.release.clone();
    let parts = Parts {
        source: Box::new(source),
        policy: Box::new(ScriptedPolicy::new(|_| Step::Out([0.0, 0.5]))),
        motors: Box::new(motors),
        clock,
        teleop: Some(teleop),
        status: None,
        live: None,
    };
    let press = |code| InputEvent::Button {
        code,
        pressed: true,
    };
    let lift = |code| InputEvent::Button {
        code,
        pressed: false,
    };
    let stick = |value| InputEvent::Axis {
        code: AbsoluteAxisCode::ABS_Y,
        value,
        min: -32768,
        max: 32767,
    };
    let outcome = block_on(async move {
        let run = tokio::spawn(drive::run(parts, params(gains()), async {
            tokio::time::sleep(Duration::from_millis(1500)).await
        }));
        let pause = |ms| tokio::time::sleep(Duration::from_millis(ms));
        // Autopilot on (A), then the human pushes the left stick forward: takeover.
        for e in [
            stick(0),
            press(KeyCode::BTN_SOUTH),
            lift(KeyCode::BTN_SOUTH),
        ] {
            tx.send(e).await.unwrap();
        }
        pause(300).await;
        tx.send(stick(-32768)).await.unwrap();
        pause(300).await;
        // Stick back to centre, autopilot on again: the intervention ends.
        for e in [
            stick(0),
            press(KeyCode::BTN_SOUTH),
            lift(KeyCode::BTN_SOUTH),
        ] {
            tx.send(e).await.unwrap();
        }
        let out = run.await.unwrap();
        drop(tx);
        out
    });
    release.store(true, Ordering::Relaxed);
    let (_, report) = outcome.expect("clean run");
    assert!(report.commands_written > 10);
    // The takeover drove the left wheel at the full manual scale (tank mode, scale 0.5).
    let manual = drives(&record)
        .iter()
        .any(|(_, c)| (c.left - 0.5).abs() < 1e-3 && c.right.abs() < 1e-3);
    assert!(manual, "{:?}", drives(&record));
    // The autopilot's command (speed 0.3 straight) before and after.
    assert!(
        drives(&record)
            .iter()
            .any(|(_, c)| (c.left - 0.3).abs() < 1e-3 && (c.right - 0.3).abs() < 1e-3)
    );
    let summary = read(&log_path).unwrap();
    assert_eq!(summary.interventions, 1, "{summary:?}");
    let d = summary.sessions[0].clone();
    assert!(format!("{d:?}").contains("stick"), "{d:?}");
}
