//! The daemon: capture -> infer -> control -> actuate, with a watchdog.
//!
//! ```text
//!  capture thread        inference thread (blocking)              actuator (async task)
//!  FrameSource --Frame--> LatestFrame --Frame--> preprocess -> policy -> steering law
//!                         (newest wins)          --Command{seq, captured_at, wheels}--> MotorOutput
//! ```
//!
//! The actuator owns the motors. It writes each command unless its frame is older than
//! `safety.max_frame_age_ms`, and stops the motors when:
//! - no fresh command was written for `safety.watchdog_ms` (camera stall, slow model): the
//!   watchdog; the daemon keeps running and drives again when fresh commands return;
//! - a stage reports a fault (frame source error, model error, NaN/inf/out-of-range output,
//!   I2C error after its retries) or dies (panic): the daemon ends with that error;
//! - the shutdown future completes (SIGINT/SIGTERM in `main`), or the source finished.
//!
//! Shutdown order: the actuator stops the motors first, then cancels the token that the
//! inference and capture threads watch, then waits (bounded) for them to finish. The
//! motor output also stops the motors when dropped, which covers a panic in the actuator.

pub mod interventions;
pub mod modes;
pub mod recorder;
pub mod remote;
pub mod setup;
pub mod stages;
pub mod stats;
pub mod teleop;
pub mod usage;
pub mod watchdog;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use crate::camera::{FrameSource, LatestFrame};
use crate::clock::Clock;
use crate::control::SteeringGains;
use crate::hw::{MotorError, MotorOutput};
use crate::policy::{Policy, PolicyError};
use stages::{Command, InferParams, StageMsg};
use stats::{StageHistograms, StageStats, StageSummary};
use watchdog::Watchdog;

/// A fault that ended the run. The motors were stopped before it was returned.
#[derive(Debug, thiserror::Error)]
pub enum DriveError {
    #[error("frame source failed: {0}")]
    Camera(String),
    #[error("frame {seq}: preprocessing failed: {source}")]
    Preprocess {
        seq: u64,
        #[source]
        source: crate::policy::preprocess::PreprocessError,
    },
    #[error("model failed: {0}")]
    Policy(#[from] PolicyError),
    #[error(
        "frame {seq}: model output {outputs:?} is not finite or beyond +-{limit} (safety.max_abs_output)"
    )]
    BadOutput {
        seq: u64,
        outputs: [f32; 2],
        limit: f32,
    },
    #[error("motors failed: {0}")]
    Motor(#[from] MotorError),
    #[error("the {0} stage ended unexpectedly (it panicked; see the log above)")]
    StageDied(&'static str),
}

/// The swappable ends of the pipeline: real devices, the simulator or test doubles.
pub struct Parts {
    pub source: Box<dyn FrameSource>,
    pub policy: Box<dyn Policy>,
    pub motors: Box<dyn MotorOutput>,
    pub clock: Arc<dyn Clock>,
    /// Gamepad, modes, interventions log and recording; `None`: the autopilot drives from
    /// the start and nothing else can take over (the demo, the simulator).
    pub teleop: Option<teleop::TeleopParts>,
    /// Where the daemon publishes its [`DaemonStatus`] twice a second (the OLED panel, the
    /// web page).
    pub status: Option<tokio::sync::watch::Sender<DaemonStatus>>,
    /// Where the actuator publishes each frame it acted on (the web page's video); the
    /// newest replaces the last, so a slow reader never holds the loop up.
    pub live: Option<tokio::sync::watch::Sender<Option<LiveFrame>>>,
}

/// A frame the actuator acted on, with what the model said and what went to the motors.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveFrame {
    pub seq: u64,
    pub width: u32,
    pub height: u32,
    /// RGB8, shared with the pipeline (not copied).
    pub rgb: Arc<Vec<u8>>,
    /// The model's outputs (target point or speed/steering).
    pub outputs: [f32; 2],
    /// What was written to the motors for it.
    pub wheels: crate::control::WheelCommand,
}

/// What the daemon is doing, for a status display.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DaemonStatus {
    /// `manual`, `auto` or `stopped`.
    pub mode: String,
    pub commands_written: u64,
    /// The last command sent to the motors.
    pub last: crate::control::WheelCommand,
    pub interventions: u64,
    /// Seconds since the run started.
    pub elapsed_s: f32,
    /// The autopilot's gains now.
    pub gains: SteeringGains,
    /// A model is loaded (Auto is possible).
    pub autopilot_available: bool,
    pub recording: bool,
    /// Records written by the recorder so far.
    pub records: u64,
    /// Why recording stopped by itself (a full disk, the record limit), if it did.
    pub record_error: Option<String>,
    /// The web client holding the controls.
    pub remote_holder: Option<remote::ClientId>,
    pub frames_captured: u64,
    pub frames_skipped: u64,
    pub stale_dropped: u64,
    pub watchdog_stops: u64,
    /// Model outputs (fresh autopilot commands, written or not) per second since the
    /// previous status.
    pub commands_per_s: f32,
    /// Stage latencies for the whole run (the means since the previous status are
    /// `recent_ms`): preprocess, inference and control for every fresh model output,
    /// actuate and frame age for those written to the motors.
    pub histograms: StageHistograms,
    /// Mean latency per stage since the previous status, ms (`None`: no sample).
    pub recent_ms: [Option<f32>; 5],
}

/// Daemon settings, from the config's `[control]`, `[safety]` and `[log]`.
#[derive(Debug, Clone)]
pub struct DriveParams {
    pub gains: SteeringGains,
    pub watchdog: Duration,
    pub max_frame_age: Duration,
    pub max_abs_output: f32,
    /// Zero: no periodic stats.
    pub stats_interval: Duration,
}

impl DriveParams {
    pub fn from_config(cfg: &crate::config::Config) -> Self {
        Self {
            gains: cfg.control.gains(),
            watchdog: Duration::from_millis(cfg.safety.watchdog_ms),
            max_frame_age: Duration::from_millis(cfg.safety.max_frame_age_ms),
            max_abs_output: cfg.safety.max_abs_output,
            stats_interval: Duration::from_secs_f32(cfg.log.stats_interval_s),
        }
    }
}

/// Why a run ended without a fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    Shutdown,
    SourceFinished,
}

/// What happened during a run.
#[derive(Debug, Clone, Default)]
pub struct RunReport {
    pub frames_captured: u64,
    pub frames_skipped: u64,
    pub commands_written: u64,
    /// Commands dropped because their frame was older than `max_frame_age`.
    pub stale_dropped: u64,
    pub watchdog_stops: u64,
    /// Transient frame-source failures (each stopped the motors until frames returned).
    pub source_errors: u64,
    pub elapsed: Duration,
    pub latency: StageSummary,
}

impl std::fmt::Display for RunReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let secs = self.elapsed.as_secs_f64().max(1e-9);
        writeln!(
            f,
            "{} frames captured, {} skipped (newest frame wins), {} commands written ({:.1}/s), {} stale dropped, {} watchdog stops in {:.1} s",
            self.frames_captured,
            self.frames_skipped,
            self.commands_written,
            self.commands_written as f64 / secs,
            self.stale_dropped,
            self.watchdog_stops,
            secs
        )?;
        write!(f, "{}", self.latency)
    }
}

/// The run's outcome: how it ended and what happened, or the fault (with the report so far).
pub type Outcome = Result<(RunEnd, RunReport), (DriveError, RunReport)>;

/// Runs the daemon until `shutdown` completes, the source finishes, or a fault.
/// The motors are stopped on every way out.
pub async fn run(parts: Parts, params: DriveParams, shutdown: impl Future<Output = ()>) -> Outcome {
    let Parts {
        source,
        policy,
        mut motors,
        clock,
        teleop,
        status,
        live,
    } = parts;
    let (gains_tx, gains_rx) = tokio::sync::watch::channel(params.gains);
    let (events, remote_rx, teleop) = match teleop {
        Some(mut t) => {
            let events = t.events.take();
            let remote_rx = t.remote_rx.take();
            (events, remote_rx, Some(teleop::Teleop::new(t, gains_tx)))
        }
        None => (None, None, None),
    };
    let started = clock.now();
    let cancel = CancellationToken::new();
    let slot = Arc::new(LatestFrame::new());
    tracing::info!(source = %source.describe(), policy = %policy.describe(), motors = %motors.describe(), "starting");

    let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
    let capture = {
        let (slot, cancel) = (slot.clone(), cancel.clone());
        std::thread::Builder::new()
            .name("capture".into())
            .spawn(move || {
                stages::capture(source, slot, cancel);
                let _ = done_tx.send(());
            })
    };
    if let Err(e) = capture {
        let _ = motors.stop();
        return Err((
            DriveError::Camera(format!("cannot start the capture thread: {e}")),
            RunReport::default(),
        ));
    }
    let (tx, rx) = mpsc::channel::<StageMsg>(4);
    let inference = {
        let (slot, cancel) = (slot.clone(), cancel.clone());
        let p = InferParams {
            gains: params.gains,
            gains_updates: Some(gains_rx),
            max_abs_output: params.max_abs_output,
            clock: clock.clone(),
        };
        tokio::task::spawn_blocking(move || stages::infer(policy, slot, tx, cancel, p))
    };

    let mut actuator = Actuator {
        motors: &mut motors,
        clock: clock.as_ref(),
        params: &params,
        stats: StageStats::default(),
        watchdog: Watchdog::new(params.watchdog),
        report: RunReport::default(),
        teleop,
        motors_stopped: true,
        status,
        started,
        last_sent: crate::control::WheelCommand::STOP,
        live,
        slot: slot.clone(),
        histograms: StageHistograms::default(),
        published: (started, 0, StageHistograms::default()),
        gains: params.gains,
    };
    let result = actuator.run(rx, events, remote_rx, shutdown).await;
    if let Some(t) = actuator.teleop.take() {
        t.finish(clock.now().saturating_sub(started));
    }
    let mut report = std::mem::take(&mut actuator.report);
    report.latency = actuator.stats.overall();

    // Motors are stopped; now wind the other stages down.
    cancel.cancel();
    if tokio::time::timeout(Duration::from_secs(2), inference)
        .await
        .is_err()
    {
        tracing::warn!("the inference stage did not finish within 2 s after shutdown");
    }
    if tokio::task::spawn_blocking(move || done_rx.recv_timeout(Duration::from_secs(1)))
        .await
        .map(|r| r.is_err())
        .unwrap_or(true)
    {
        tracing::warn!("the frame source did not return within 1 s after shutdown; leaving it");
    }
    let counts = slot.counts();
    report.frames_captured = counts.produced;
    report.frames_skipped = counts.skipped;
    report.elapsed = clock.now().saturating_sub(started);
    match result {
        Ok(end) => Ok((end, report)),
        Err(e) => Err((e, report)),
    }
}

/// The task that owns the motors.
struct Actuator<'a> {
    motors: &'a mut Box<dyn MotorOutput>,
    clock: &'a dyn Clock,
    params: &'a DriveParams,
    stats: StageStats,
    watchdog: Watchdog,
    report: RunReport,
    teleop: Option<teleop::Teleop>,
    /// The last thing written was a stop (so a Stop from the mode machine is not repeated).
    motors_stopped: bool,
    status: Option<tokio::sync::watch::Sender<DaemonStatus>>,
    started: Duration,
    last_sent: crate::control::WheelCommand,
    live: Option<tokio::sync::watch::Sender<Option<LiveFrame>>>,
    slot: Arc<LatestFrame>,
    histograms: StageHistograms,
    /// When the last status went out, the autopilot commands and histograms then.
    published: (Duration, u64, StageHistograms),
    /// The gains without a teleop (they never change then).
    gains: SteeringGains,
}

/// The next web page message, or never when there is no web page.
async fn next_remote(
    rx: &mut Option<mpsc::Receiver<remote::RemoteMsg>>,
) -> Option<remote::RemoteMsg> {
    match rx {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

/// The next gamepad event, or never when there is no gamepad.
async fn next_event(
    events: &mut Option<mpsc::Receiver<crate::hw::gamepad::InputEvent>>,
) -> Option<crate::hw::gamepad::InputEvent> {
    match events {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

impl Actuator<'_> {
    async fn run(
        &mut self,
        mut rx: mpsc::Receiver<StageMsg>,
        mut events: Option<mpsc::Receiver<crate::hw::gamepad::InputEvent>>,
        mut remote_rx: Option<mpsc::Receiver<remote::RemoteMsg>>,
        shutdown: impl Future<Output = ()>,
    ) -> Result<RunEnd, DriveError> {
        let mut manual_tick = tokio::time::interval(Duration::from_millis(50));
        tokio::pin!(shutdown);
        let interval = self.params.stats_interval;
        let mut stats_tick = tokio::time::interval(if interval.is_zero() {
            Duration::from_secs(3600)
        } else {
            interval
        });
        stats_tick.tick().await;
        // systemd (Type=notify): ready now; then a watchdog ping from this loop every
        // 500 ms, so a stuck actuator gets the service restarted (and ExecStopPost stops
        // the motors). Without NOTIFY_SOCKET these are no-ops.
        let mut keepalive = tokio::time::interval(Duration::from_millis(500));
        if let Err(e) = sd_notify::notify(&[sd_notify::NotifyState::Ready]) {
            tracing::warn!(error = %e, "systemd notify failed");
        }
        let outcome = loop {
            // The watchdog's deadline, as a tokio instant (the clocks run at the same rate).
            let until_deadline = self
                .watchdog
                .deadline()
                .map(|d| d.saturating_sub(self.clock.now()));
            let sleep = tokio::time::sleep(until_deadline.unwrap_or(Duration::from_secs(3600)));
            tokio::select! {
                biased;
                _ = &mut shutdown => {
                    tracing::info!("shutdown requested");
                    break Ok(RunEnd::Shutdown);
                }
                msg = rx.recv() => match msg {
                    Some(StageMsg::Command(cmd)) => {
                        if let Err(e) = self.write(cmd) {
                            break Err(e);
                        }
                    }
                    Some(StageMsg::SourceError(msg)) => {
                        self.report.source_errors += 1;
                        tracing::warn!(error = %msg, "frame source failed: motors stopped until frames return");
                        if let Err(e) = self.apply(modes::Drive::Stop) {
                            break Err(e);
                        }
                    }
                    Some(StageMsg::SourceFinished) => {
                        tracing::info!("frame source finished");
                        break Ok(RunEnd::SourceFinished);
                    }
                    Some(StageMsg::Fault(e)) => break Err(e),
                    None => break Err(DriveError::StageDied("inference")),
                },
                _ = sleep, if until_deadline.is_some() => {
                    if self.watchdog.expired(self.clock.now()) {
                        self.report.watchdog_stops += 1;
                        tracing::warn!(
                            period_ms = self.watchdog.period().as_millis() as u64,
                            "no fresh command within the watchdog period: motors stopped"
                        );
                        if let Err(e) = self.motors.stop() {
                            break Err(e.into());
                        }
                    }
                }
                _ = stats_tick.tick(), if !interval.is_zero() => self.log_window(),
                _ = keepalive.tick() => {
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
                    self.publish_status();
                }
                ev = next_event(&mut events) => {
                    let now = self.clock.now();
                    let d = match (ev, self.teleop.as_mut()) {
                        (Some(ev), Some(t)) => t.on_event(&ev, now),
                        (None, Some(t)) => {
                            events = None; // the reader is gone for good
                            t.on_event(&crate::hw::gamepad::InputEvent::Disconnected, now)
                        }
                        (_, None) => continue,
                    };
                    if let Some(d) = d
                        && let Err(e) = self.apply(d)
                    {
                        break Err(e);
                    }
                }
                msg = next_remote(&mut remote_rx) => {
                    let now = self.clock.now();
                    let d = match (msg, self.teleop.as_mut()) {
                        (Some(m), Some(t)) => t.on_remote(&m, now),
                        (None, _) => {
                            // The web server is gone: its page can no longer drive or
                            // stop the car; treat it as the page closing.
                            tracing::warn!("the web server stopped");
                            remote_rx = None;
                            self.teleop.as_mut().and_then(|t| {
                                let holder = t.remote_holder()?;
                                t.on_remote(&remote::RemoteMsg { client: holder, request: remote::RemoteRequest::Closed }, now)
                            })
                        }
                        (_, None) => continue,
                    };
                    if let Some(d) = d
                        && let Err(e) = self.apply(d)
                    {
                        break Err(e);
                    }
                    self.publish_status();
                }
                _ = manual_tick.tick(), if self.teleop.is_some() => {
                    let now = self.clock.now();
                    if let Some(d) = self.teleop.as_mut().and_then(|t| t.poll(now))
                        && let Err(e) = self.apply(d)
                    {
                        break Err(e);
                    }
                }
            }
        };
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
        if let Err(e) = self.motors.stop() {
            tracing::error!(error = %e, "could not stop the motors");
            if outcome.is_ok() {
                return Err(e.into());
            }
        } else {
            tracing::info!("motors stopped");
        }
        if let Err(e) = &outcome {
            tracing::error!(error = %e, "fault: motors stopped");
        }
        outcome
    }

    /// Writes one command unless its frame is too old.
    fn write(&mut self, cmd: Command) -> Result<(), DriveError> {
        let age = self.clock.now().saturating_sub(cmd.captured_at);
        if age > self.params.max_frame_age {
            self.report.stale_dropped += 1;
            tracing::debug!(
                seq = cmd.seq,
                age_ms = age.as_millis() as u64,
                "stale command dropped"
            );
            return Ok(());
        }
        let t0 = self.clock.now();
        // The model's stages ran whoever drives: counted for every fresh command.
        let h = &mut self.histograms;
        h.preprocess.observe(cmd.preprocess);
        h.inference.observe(cmd.inference);
        h.control.observe(cmd.control);
        let sent = match self.teleop.as_mut() {
            Some(t) => {
                let d = t.tick(t0, Some(cmd.wheels));
                t.record(&cmd, teleop::drive_wheels(d));
                if matches!(d, modes::Drive::Stop) {
                    self.publish_live(&cmd, crate::control::WheelCommand::STOP);
                    return self.apply(d);
                }
                teleop::drive_wheels(d)
            }
            None => cmd.wheels,
        };
        self.motors.drive(sent)?;
        self.motors_stopped = false;
        self.last_sent = sent;
        let t1 = self.clock.now();
        self.watchdog.feed(t1);
        self.report.commands_written += 1;
        let (actuate, age) = (t1.saturating_sub(t0), t1.saturating_sub(cmd.captured_at));
        self.stats.preprocess.push(cmd.preprocess);
        self.stats.inference.push(cmd.inference);
        self.stats.control.push(cmd.control);
        self.stats.actuate.push(actuate);
        self.stats.frame_age.push(age);
        let h = &mut self.histograms;
        h.actuate.observe(actuate);
        h.frame_age.observe(age);
        self.publish_live(&cmd, sent);
        tracing::debug!(
            seq = cmd.seq,
            x = cmd.outputs[0],
            y = cmd.outputs[1],
            left = cmd.wheels.left,
            right = cmd.wheels.right,
            age_ms = age.as_secs_f32() * 1000.0,
            "command"
        );
        Ok(())
    }

    /// Offers the frame of `cmd` and what went out for it to the web page (a pointer copy).
    fn publish_live(&self, cmd: &Command, sent: crate::control::WheelCommand) {
        if let Some(tx) = &self.live {
            tx.send_replace(Some(LiveFrame {
                seq: cmd.seq,
                width: cmd.width,
                height: cmd.height,
                rgb: cmd.frame.clone(),
                outputs: cmd.outputs,
                wheels: sent,
            }));
        }
    }

    /// Writes what the mode machine decided: a command (fresh: feeds the watchdog) or a
    /// stop (once).
    fn apply(&mut self, d: modes::Drive) -> Result<(), DriveError> {
        match d {
            modes::Drive::Command(w) => {
                self.motors.drive(w)?;
                self.motors_stopped = false;
                self.last_sent = w;
                self.watchdog.feed(self.clock.now());
                self.report.commands_written += 1;
            }
            modes::Drive::Stop => {
                if !self.motors_stopped {
                    self.motors.stop()?;
                    self.motors_stopped = true;
                    self.last_sent = crate::control::WheelCommand::STOP;
                }
                self.watchdog.disarm();
            }
        }
        Ok(())
    }

    fn publish_status(&mut self) {
        let Some(tx) = &self.status else {
            return;
        };
        let now = self.clock.now();
        let (mode, interventions, gains, (recording, records), autopilot_available, holder) =
            match &self.teleop {
                Some(t) => (
                    t.mode().as_str().to_string(),
                    t.interventions(),
                    t.gains(),
                    t.recording(),
                    t.autopilot_available(),
                    t.remote_holder(),
                ),
                None => ("auto".to_string(), 0, self.gains, (false, 0), true, None),
            };
        let record_error = self.teleop.as_ref().and_then(|t| t.record_error());
        let (then, then_cmds, then_h) = self.published;
        let autopilot_cmds = self.histograms.inference.count;
        let dt = now.saturating_sub(then).as_secs_f32();
        let h = self.histograms;
        let recent = |a: &stats::Histogram, b: &stats::Histogram| a.mean_since(b).map(|v| v as f32);
        let counts = self.slot.counts();
        // Rates and means over at least 0.4 s (a status also goes out after each web
        // request, so the page sees its change at once).
        let window = dt >= 0.4;
        let (commands_per_s, recent_ms) = if window {
            (
                autopilot_cmds.saturating_sub(then_cmds) as f32 / dt,
                [
                    recent(&h.preprocess, &then_h.preprocess),
                    recent(&h.inference, &then_h.inference),
                    recent(&h.control, &then_h.control),
                    recent(&h.actuate, &then_h.actuate),
                    recent(&h.frame_age, &then_h.frame_age),
                ],
            )
        } else {
            let last = tx.borrow();
            (last.commands_per_s, last.recent_ms)
        };
        tx.send_replace(DaemonStatus {
            mode,
            commands_written: self.report.commands_written,
            last: if self.motors_stopped {
                crate::control::WheelCommand::STOP
            } else {
                self.last_sent
            },
            interventions,
            elapsed_s: now.saturating_sub(self.started).as_secs_f32(),
            gains,
            autopilot_available,
            recording,
            records,
            record_error,
            remote_holder: holder,
            frames_captured: counts.produced,
            frames_skipped: counts.skipped,
            stale_dropped: self.report.stale_dropped,
            watchdog_stops: self.report.watchdog_stops,
            commands_per_s,
            histograms: h,
            recent_ms,
        });
        if window {
            self.published = (now, autopilot_cmds, h);
        }
    }

    fn log_window(&mut self) {
        let s = self.stats.take_window();
        tracing::info!(
            commands = s.actuate.count,
            preprocess = %s.preprocess,
            inference = %s.inference,
            control = %s.control,
            actuate = %s.actuate,
            frame_age = %s.frame_age,
            "stage latency"
        );
    }
}
