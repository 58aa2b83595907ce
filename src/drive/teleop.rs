//! The human side of the daemon: gamepad events into the mode machine (Manual / Auto /
//! Stopped), interventions into their log, the record button into the recorder.
//!
//! The actuator owns a [`Teleop`] and asks it, for every autopilot command and on a 20 Hz
//! tick, what goes to the motors ([`Drive`]). Gamepad events arrive from a reader thread
//! ([`spawn_reader`]) over a channel, so tests feed synthetic events the same way.

use std::path::PathBuf;
use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

use super::interventions::{InterventionLog, InterventionRecord};
use super::modes::{Drive, Mode, ModeEvent, Modes};
use super::recorder::{RecordStep, Recorder};
use super::stages::Command;
use crate::control::{SteeringGains, WheelCommand};
use crate::dataset::tub::DriveMode;
use crate::hw::gamepad::{Action, GamepadConfig, GamepadReader, GamepadState, InputEvent};

/// What the daemon's human interface starts with.
pub struct TeleopParts {
    pub events: mpsc::Receiver<InputEvent>,
    pub pad: GamepadState,
    pub modes: Modes,
    /// False without a model (`jetpilot record`): Auto is refused.
    pub autopilot_available: bool,
    pub log: Option<InterventionLog>,
    pub model_hash: String,
    pub recorder: Option<Recorder>,
    /// Record from the start (`jetpilot record`); the record button toggles it.
    pub recording: bool,
}

pub struct Teleop {
    pub events: mpsc::Receiver<InputEvent>,
    pad: GamepadState,
    modes: Modes,
    autopilot_available: bool,
    log: Option<InterventionLog>,
    model_hash: String,
    recorder: Option<Recorder>,
    recording: bool,
    last_seq: u64,
    gains_tx: watch::Sender<SteeringGains>,
}

impl Teleop {
    pub fn new(parts: TeleopParts, gains_tx: watch::Sender<SteeringGains>) -> Self {
        Self {
            events: parts.events,
            pad: parts.pad,
            modes: parts.modes,
            autopilot_available: parts.autopilot_available,
            log: parts.log,
            model_hash: parts.model_hash,
            recorder: parts.recorder,
            recording: parts.recording,
            last_seq: 0,
            gains_tx,
        }
    }

    pub fn mode(&self) -> Mode {
        self.modes.mode()
    }

    pub fn interventions(&self) -> u64 {
        self.modes.interventions()
    }

    /// A gamepad event; returns what goes to the motors now.
    pub fn on_event(&mut self, event: &InputEvent, now: Duration) -> Drive {
        let action = self.modes.handle_event(&mut self.pad, event, now);
        if self.modes.mode() == Mode::Auto && !self.autopilot_available {
            tracing::warn!("no model loaded: the autopilot is not available");
            self.modes.on_action(Action::ToggleAutopilot, now);
        }
        match action {
            Some(Action::ToggleRecording) => {
                self.recording = !self.recording && self.recorder.is_some();
                tracing::info!(recording = self.recording, "record button");
            }
            Some(Action::EraseLast(n)) => {
                tracing::warn!(
                    n,
                    "erasing records while driving is not supported yet; use the tub tools after the run"
                );
            }
            _ => {}
        }
        self.after(now);
        self.modes.tick(now, &self.pad, None)
    }

    /// The control tick (Manual commands, heartbeat, gamepad loss), or an autopilot command.
    pub fn tick(&mut self, now: Duration, autopilot: Option<WheelCommand>) -> Drive {
        let d = self.modes.tick(now, &self.pad, autopilot);
        self.after(now);
        d
    }

    /// Records the step for `cmd` if recording, with what actually went out.
    pub fn record(&mut self, cmd: &Command, sent: WheelCommand) {
        self.last_seq = cmd.seq;
        if !self.recording {
            return;
        }
        if let Some(r) = &self.recorder {
            let mode = match self.modes.mode() {
                Mode::Auto => DriveMode::Local,
                Mode::Manual | Mode::Stopped => DriveMode::User,
            };
            r.offer(RecordStep {
                time_ms: cmd.captured_at.as_millis() as u64,
                width: cmd.width,
                height: cmd.height,
                rgb: cmd.frame.clone(),
                wheels: sent,
                mode,
                pilot: Some(cmd.wheels),
                steering_gain: self.modes.gains().steering_gain,
            });
        }
    }

    /// Logs mode events, writes finished interventions, forwards gain changes.
    fn after(&mut self, _now: Duration) {
        for e in self.modes.take_events() {
            match &e {
                ModeEvent::ModeChanged {
                    from, to, cause, ..
                } => {
                    tracing::info!(from = %from, to = %to, cause = cause.as_str(), "mode")
                }
                ModeEvent::GainsChanged { gains, .. } => {
                    tracing::info!(
                        speed_gain = gains.speed_gain,
                        steering_gain = gains.steering_gain,
                        "gains"
                    );
                    let _ = self.gains_tx.send(*gains);
                }
                ModeEvent::GamepadLost { mode, .. } => {
                    tracing::warn!(mode = %mode, "gamepad lost")
                }
                ModeEvent::InterventionStarted { cause, .. } => {
                    tracing::info!(cause = cause.as_str(), "intervention started")
                }
                ModeEvent::InterventionEnded { duration, .. } => {
                    tracing::info!(seconds = duration.as_secs_f32(), "intervention ended")
                }
                _ => tracing::debug!(event = ?e, "mode event"),
            }
            if let Some(log) = self.log.as_mut()
                && let Some(rec) = InterventionRecord::from_event(
                    &e,
                    self.last_seq,
                    self.modes.gains(),
                    &self.model_hash,
                )
                && let Err(err) = log.record(&rec)
            {
                tracing::error!(error = %err, "cannot write the interventions log");
            }
        }
    }

    /// Closes an open intervention, ends the log session, flushes the recording.
    pub fn finish(mut self, now: Duration) {
        self.modes.finish(now);
        self.after(now);
        if let Some(log) = self.log.take()
            && let Err(e) = log.end(now.as_secs_f64())
        {
            tracing::error!(error = %e, "cannot close the interventions log");
        }
        if let Some(r) = self.recorder.take() {
            let n = r.finish();
            tracing::info!(records = n, "recording closed");
        }
    }
}

/// Reads the gamepad on a thread until `cancel`: events go to `tx`; when the device goes
/// away a `Disconnected` is sent and the device is looked for again every second.
pub fn spawn_reader(
    cfg: GamepadConfig,
    tx: mpsc::Sender<InputEvent>,
    cancel: CancellationToken,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("gamepad".into())
        .spawn(move || {
            let mut reader: Option<GamepadReader> = None;
            let mut announced: Option<PathBuf> = None;
            while !cancel.is_cancelled() {
                let Some(r) = reader.as_mut() else {
                    match GamepadReader::open(&cfg) {
                        Ok(r) => {
                            tracing::info!(device = %r.path().display(), name = r.name(), "gamepad");
                            announced = Some(r.path().to_path_buf());
                            for e in r.initial_events() {
                                if tx.blocking_send(e).is_err() {
                                    return;
                                }
                            }
                            reader = Some(r);
                        }
                        Err(e) => {
                            if announced.take().is_some() || reader.is_none() {
                                tracing::debug!(error = %e, "no gamepad yet");
                            }
                            std::thread::sleep(Duration::from_secs(1));
                        }
                    }
                    continue;
                };
                match r.read_batch() {
                    Ok(events) => {
                        for e in events {
                            if tx.blocking_send(e).is_err() {
                                return;
                            }
                        }
                    }
                    Err(e) => {
                        tracing::warn!(error = %e, "gamepad read failed");
                        reader = None;
                        if tx.blocking_send(InputEvent::Disconnected).is_err() {
                            return;
                        }
                    }
                }
            }
        })
}

/// `Drive` as a wheel command (a stop is zero on both wheels).
pub fn drive_wheels(d: Drive) -> WheelCommand {
    match d {
        Drive::Stop => WheelCommand::STOP,
        Drive::Command(w) => w,
    }
}
