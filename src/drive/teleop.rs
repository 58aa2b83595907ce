//! The human side of the daemon: gamepad events into the mode machine (Manual / Auto /
//! Stopped), interventions into their log, the record button into the recorder.
//!
//! The actuator owns a [`Teleop`] and asks it, for every autopilot command and on a 20 Hz
//! tick, what goes to the motors ([`Drive`]). Gamepad events arrive from a reader thread
//! ([`spawn_reader`]) over a channel, so tests feed synthetic events the same way.
//!
//! A web page is a second driver ([`super::remote`]): its sticks drive in Manual while no
//! physical gamepad is in use (a gamepad that sent an event within the last 0.5 s always
//! wins), its mode buttons act like the gamepad's, and when the page holding the controls
//! closes or falls silent the car goes to Stopped at once (unless the gamepad is in use).

use std::path::PathBuf;
use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

use super::interventions::{InterventionLog, InterventionRecord};
use super::modes::{Drive, Mode, ModeEvent, Modes};
use super::recorder::{RecordStep, Recorder};
use super::remote::{Outcome, RemoteControl, RemoteMsg, RemoteRequest};
use super::stages::Command;
use crate::control::{SteeringGains, WheelCommand};
use crate::dataset::tub::DriveMode;
use crate::hw::gamepad::{
    Action, GamepadConfig, GamepadReader, GamepadState, InputEvent, PadSnapshot,
};

/// A gamepad whose last event is younger than this is "in use" and wins over a web page.
const PAD_IN_USE: Duration = Duration::from_millis(500);

/// What the daemon's human interface starts with.
pub struct TeleopParts {
    /// Gamepad events; `None`: no gamepad configured (a web page may still drive).
    pub events: Option<mpsc::Receiver<InputEvent>>,
    /// The web page's controls; `None`: no web page.
    pub remote: Option<RemoteControl>,
    /// The web page's messages (read by the actuator's loop).
    pub remote_rx: Option<mpsc::Receiver<RemoteMsg>>,
    pub pad: GamepadState,
    pub modes: Modes,
    /// False without a model (`jetpilot record`): Auto is refused.
    pub autopilot_available: bool,
    pub log: Option<InterventionLog>,
    pub model_hash: String,
    pub recorder: Option<Recorder>,
    /// Opens the recorder at the first press of record, when `recorder` is `None` (a web
    /// page without a gamepad: no tub is made unless someone records).
    pub open_recorder: Option<OpenRecorder>,
    /// Record from the start (`jetpilot record`); the record button toggles it.
    pub recording: bool,
}

/// Makes the recorder on demand; the error names the tub.
pub type OpenRecorder = Box<dyn FnMut() -> Result<Recorder, String> + Send>;

/// A page's drive messages write the motors at most this often: a page that floods them
/// (a bug, a stuck key) must not flood the I2C bus. The 50 ms control tick writes the
/// latest sticks in between.
pub const REMOTE_WRITE_EVERY: Duration = Duration::from_millis(20);

pub struct Teleop {
    /// When a page's message last wrote the motors.
    last_remote_write: Option<Duration>,
    pad: GamepadState,
    /// When the pad last did something (a button press or a stick past the dead zone).
    pad_active_at: Option<Duration>,
    remote: Option<RemoteControl>,
    modes: Modes,
    autopilot_available: bool,
    log: Option<InterventionLog>,
    model_hash: String,
    recorder: Option<Recorder>,
    open_recorder: Option<OpenRecorder>,
    recording: bool,
    last_seq: u64,
    gains_tx: watch::Sender<SteeringGains>,
}

impl Teleop {
    /// The teleop state; take `parts.events` and `parts.remote_rx` first (the actuator's
    /// loop reads them).
    pub fn new(parts: TeleopParts, gains_tx: watch::Sender<SteeringGains>) -> Self {
        Self {
            last_remote_write: None,
            remote: parts.remote,
            pad: parts.pad,
            pad_active_at: None,
            modes: parts.modes,
            autopilot_available: parts.autopilot_available,
            log: parts.log,
            model_hash: parts.model_hash,
            recorder: parts.recorder,
            open_recorder: parts.open_recorder,
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

    /// The autopilot's gains now.
    pub fn gains(&self) -> SteeringGains {
        self.modes.gains()
    }

    /// Recording now, and records written so far. A recorder that stopped by itself (a
    /// full disk, its limit) is not recording, whatever was pressed.
    pub fn recording(&self) -> (bool, u64) {
        let (written, stopped) = self.recorder.as_ref().map_or((0, false), |r| {
            let c = r.counts();
            (
                c.written.load(std::sync::atomic::Ordering::Relaxed),
                c.stopped.load(std::sync::atomic::Ordering::Relaxed),
            )
        });
        (self.recording && !stopped, written)
    }

    /// Why recording stopped by itself, if it did: the page shows it.
    pub fn record_error(&self) -> Option<String> {
        self.recorder
            .as_ref()
            .and_then(|r| r.counts().stop_reason())
    }

    pub fn autopilot_available(&self) -> bool {
        self.autopilot_available
    }

    /// The web client holding the controls.
    pub fn remote_holder(&self) -> Option<super::remote::ClientId> {
        self.remote.as_ref().and_then(|r| r.holder())
    }

    /// The physical gamepad is connected and in use: a stick is out of its dead zone, or a
    /// button was pressed or a stick moved within [`PAD_IN_USE`] (jitter inside the dead
    /// zone and releases do not count).
    fn pad_in_use(&self, now: Duration) -> bool {
        self.pad.is_connected()
            && (self.pad.deflection() > 0.0
                || self
                    .pad_active_at
                    .is_some_and(|t| now.saturating_sub(t) < PAD_IN_USE))
    }

    /// The dead-man check of the page holding the controls (before anything is written).
    fn check_remote(&mut self, now: Duration) {
        if let Some(o) = self.remote.as_mut().and_then(|r| r.check(now)) {
            self.remote_outcome(o, now);
        }
    }

    /// What goes out after an event: in Auto nothing (the autopilot's next command
    /// drives), except a stop when Auto was just entered (nothing stale stays on the
    /// motors until the first autopilot command); otherwise the tick's output.
    fn output_after(&mut self, was: Mode, now: Duration) -> Option<Drive> {
        if self.modes.mode() == Mode::Auto {
            self.after(now);
            (was != Mode::Auto).then_some(Drive::Stop)
        } else {
            Some(self.tick(now, None))
        }
    }

    /// The pad's snapshot, or the web page's sticks while it holds the controls and the
    /// pad is not in use.
    fn snapshot(&self, now: Duration) -> PadSnapshot {
        let snap = self.pad.snapshot(now);
        match self
            .remote
            .as_ref()
            .and_then(|r| r.command().map(|c| (c, r.deflection())))
        {
            Some((manual, deflection)) if !self.pad_in_use(now) => PadSnapshot {
                manual,
                deflection,
                connected: true,
                stale: false,
            },
            _ => snap,
        }
    }

    /// A web page's message at `now`; returns what goes to the motors now, if anything
    /// (nothing while the autopilot keeps driving).
    pub fn on_remote(&mut self, msg: &RemoteMsg, now: Duration) -> Option<Drive> {
        let was = self.modes.mode();
        // The holder's silence is judged before anything else: a stream of other
        // messages must not keep a silent holder's sticks on the motors.
        self.check_remote(now);
        let outcome = self.remote.as_mut()?.on_message(msg, now);
        let due = self
            .last_remote_write
            .is_none_or(|t| now.saturating_sub(t) >= REMOTE_WRITE_EVERY);
        // What writes now: a mode change always (compared below), the holder leaving
        // always, new sticks or a repeated stop at most every REMOTE_WRITE_EVERY.
        // Heartbeats, gains and record change nothing on the wheels: the control tick
        // keeps the motors fed.
        let changed = match outcome {
            Outcome::Lost { .. } => true,
            Outcome::Accepted(RemoteRequest::Drive { .. } | RemoteRequest::EmergencyStop) => due,
            Outcome::Accepted(_) | Outcome::Refused { .. } | Outcome::Ignored => false,
        };
        self.remote_outcome(outcome, now);
        if !changed && self.modes.mode() == was {
            self.after(now);
            return None; // a refused, ignored or too frequent message writes nothing now
        }
        let drive = self.output_after(was, now);
        if drive.is_some() {
            self.last_remote_write = Some(now);
        }
        drive
    }

    /// The control tick without an autopilot command: the web page's dead-man check, then
    /// (outside Auto) what goes to the motors.
    pub fn poll(&mut self, now: Duration) -> Option<Drive> {
        let was = self.modes.mode();
        self.check_remote(now);
        self.output_after(was, now)
    }

    fn remote_outcome(&mut self, outcome: Outcome, now: Duration) {
        match outcome {
            Outcome::Accepted(req) => match req {
                RemoteRequest::Drive { .. } | RemoteRequest::Heartbeat | RemoteRequest::Closed => {}
                RemoteRequest::EmergencyStop => self.action(Action::EmergencyStop, now),
                RemoteRequest::Mode(to) if to != Mode::Stopped && self.pad_in_use(now) => {
                    tracing::info!(mode = %to, "web: the gamepad is in use; its driver decides the mode");
                }
                RemoteRequest::Mode(to) => match (self.modes.mode(), to) {
                    (Mode::Manual, Mode::Auto) | (Mode::Auto, Mode::Manual) => {
                        self.action(Action::ToggleAutopilot, now)
                    }
                    (Mode::Stopped, Mode::Manual) => self.action(Action::ClearEmergencyStop, now),
                    (Mode::Manual | Mode::Auto, Mode::Stopped) => {
                        self.action(Action::EmergencyStop, now)
                    }
                    (Mode::Stopped, Mode::Auto) => {
                        tracing::info!("web: clear the stop (Manual) before Auto");
                    }
                    _ => {}
                },
                RemoteRequest::Gains(g) => self.modes.set_gains(g, now),
                RemoteRequest::Record(on) => {
                    self.recording = on && self.ensure_recorder();
                    tracing::info!(recording = self.recording, "web: record");
                }
            },
            Outcome::Refused { holder } => {
                tracing::debug!(holder, "web: another page holds the controls")
            }
            Outcome::Lost { client } => {
                if self.pad_in_use(now) {
                    tracing::warn!(
                        client,
                        "web page holding the controls went away; the gamepad drives on"
                    );
                } else {
                    tracing::warn!(
                        client,
                        "web page holding the controls went away: motors stopped"
                    );
                    self.modes.on_remote_lost(now);
                }
            }
            Outcome::Ignored => {}
        }
    }

    /// True when there is a recorder, opening it now if it is made on demand.
    fn ensure_recorder(&mut self) -> bool {
        if self.recorder.is_none()
            && let Some(open) = self.open_recorder.as_mut()
        {
            // Kept after a failure: the next press tries again (a full card emptied, say).
            match open() {
                Ok(r) => self.recorder = Some(r),
                Err(e) => tracing::error!(error = %e, "cannot start recording"),
            }
        }
        self.recorder.is_some()
    }

    /// A mode-machine action from the web page (the same rules as the gamepad's buttons).
    fn action(&mut self, action: Action, now: Duration) {
        self.modes.on_action(action, now);
        if self.modes.mode() == Mode::Auto && !self.autopilot_available {
            tracing::warn!("no model loaded: the autopilot is not available");
            self.modes.on_action(Action::ToggleAutopilot, now);
        }
    }

    /// A gamepad event; returns what goes to the motors now, if anything (in Auto the
    /// autopilot's next command drives; a stick takeover is seen on that tick).
    pub fn on_event(&mut self, event: &InputEvent, now: Duration) -> Option<Drive> {
        let was = self.modes.mode();
        let action = self.modes.handle_event(&mut self.pad, event, now);
        if action.is_some() || self.pad.deflection() > 0.0 {
            self.pad_active_at = Some(now);
        }
        if self.modes.mode() == Mode::Auto && !self.autopilot_available {
            tracing::warn!("no model loaded: the autopilot is not available");
            self.modes.on_action(Action::ToggleAutopilot, now);
        }
        match action {
            Some(Action::ToggleRecording) => {
                self.recording = !self.recording && self.ensure_recorder();
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
        self.output_after(was, now)
    }

    /// The control tick (Manual commands, heartbeat, gamepad loss), or an autopilot command.
    pub fn tick(&mut self, now: Duration, autopilot: Option<WheelCommand>) -> Drive {
        self.check_remote(now);
        let snap = self.snapshot(now);
        let d = self.modes.tick_snapshot(now, snap, autopilot);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::modes::ModeParams;
    use crate::drive::remote::{RemoteMsg, RemoteScales};
    use crate::hw::gamepad::{GamepadMap, GamepadState};
    use evdev::AbsoluteAxisCode;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    fn teleop() -> (Teleop, watch::Receiver<SteeringGains>) {
        let cfg = GamepadConfig::default();
        let (tx, rx) = watch::channel(SteeringGains::default());
        let parts = TeleopParts {
            events: None,
            remote: Some(RemoteControl::new(
                ms(500),
                RemoteScales {
                    throttle_scale: 0.5,
                    steering_scale: 0.25,
                },
            )),
            remote_rx: None,
            pad: GamepadState::new(GamepadMap::from_config(&cfg).unwrap()),
            modes: Modes::new(ModeParams::default(), SteeringGains::default()),
            autopilot_available: true,
            log: None,
            model_hash: "t".into(),
            recorder: None,
            open_recorder: None,
            recording: false,
        };
        (Teleop::new(parts, tx), rx)
    }

    fn web(client: u64, request: RemoteRequest) -> RemoteMsg {
        RemoteMsg { client, request }
    }

    fn drive(t: f32, s: f32) -> RemoteRequest {
        RemoteRequest::Drive {
            throttle: t,
            steering: s,
        }
    }

    #[test]
    fn the_page_drives_in_manual_and_a_gamepad_in_use_wins() {
        let (mut t, _) = teleop();
        // Throttle 1, steering 0.4: 0.5 +- 0.1.
        let d = t.on_remote(&web(1, drive(1.0, 0.4)), ms(100));
        assert_eq!(d, Some(Drive::Command(WheelCommand::new(0.6, 0.4))));
        assert_eq!(t.remote_holder(), Some(1));
        // The gamepad moves (tank drive, left stick half back): it drives now.
        let ev = InputEvent::Axis {
            code: AbsoluteAxisCode::ABS_Y,
            value: 16384,
            min: -32768,
            max: 32767,
        };
        let d = t.on_event(&ev, ms(150)).unwrap();
        let Drive::Command(w) = d else {
            panic!("{d:?}")
        };
        assert!(w.left < 0.0, "the pad's command, not the page's: {w:?}");
        // Let go (centred) at 200 ms; jitter inside the dead zone later is not use.
        let at = |value| InputEvent::Axis {
            code: AbsoluteAxisCode::ABS_Y,
            value,
            min: -32768,
            max: 32767,
        };
        t.on_event(&at(0), ms(200));
        t.on_remote(&web(1, drive(1.0, 0.4)), ms(450));
        t.on_event(&at(300), ms(640));
        // 0.5 s after the pad last did something, the page's sticks drive again.
        t.on_remote(&web(1, drive(1.0, 0.4)), ms(600));
        assert_eq!(
            t.poll(ms(660)),
            Some(Drive::Command(WheelCommand::new(0.6, 0.4)))
        );
    }

    #[test]
    fn losing_the_page_stops_unless_the_gamepad_is_in_use() {
        let (mut t, _) = teleop();
        assert_eq!(
            t.on_remote(&web(1, RemoteRequest::Mode(Mode::Auto)), ms(0)),
            Some(Drive::Stop),
            "entering Auto clears the last manual command"
        );
        assert_eq!(t.mode(), Mode::Auto);
        assert_eq!(t.poll(ms(400)), None, "Auto: the autopilot drives");
        assert_eq!(t.poll(ms(500)), Some(Drive::Stop), "silent for 0.5 s");
        assert_eq!(t.mode(), Mode::Stopped);
        assert_eq!(t.interventions(), 0, "nobody acted");
        // The page comes back: Auto is refused until the stop is cleared.
        t.on_remote(&web(2, RemoteRequest::Mode(Mode::Auto)), ms(600));
        assert_eq!(t.mode(), Mode::Stopped);
        t.on_remote(&web(2, RemoteRequest::Mode(Mode::Manual)), ms(700));
        assert_eq!(t.mode(), Mode::Manual);
        // With the gamepad in use (a stick pushed), the page can neither switch to Auto
        // nor, by closing, stop the car.
        let ev = InputEvent::Axis {
            code: AbsoluteAxisCode::ABS_Y,
            value: -16384,
            min: -32768,
            max: 32767,
        };
        t.on_event(&ev, ms(750));
        t.on_remote(&web(2, RemoteRequest::Mode(Mode::Auto)), ms(760));
        assert_eq!(t.mode(), Mode::Manual);
        t.on_remote(&web(2, RemoteRequest::Closed), ms(800));
        assert_eq!(t.mode(), Mode::Manual);
        assert_eq!(t.remote_holder(), None);
        // A refused message writes nothing.
        t.on_remote(&web(3, RemoteRequest::Heartbeat), ms(810));
        assert_eq!(t.on_remote(&web(4, drive(1.0, 0.0)), ms(820)), None);
    }

    #[test]
    fn the_page_takes_over_from_auto_and_its_sliders_reach_the_law() {
        let (mut t, mut gains) = teleop();
        t.on_remote(&web(1, RemoteRequest::Mode(Mode::Auto)), ms(0));
        t.on_remote(&web(1, RemoteRequest::Heartbeat), ms(400));
        t.on_remote(&web(1, RemoteRequest::Mode(Mode::Manual)), ms(800));
        assert_eq!(t.mode(), Mode::Manual);
        assert_eq!(
            t.interventions(),
            1,
            "the page took control from the autopilot"
        );
        let g = SteeringGains {
            speed_gain: 0.35,
            steering_gain: 0.5,
            steering_kd: 0.1,
            steering_bias: 0.05,
            steering_ki: 0.0,
            integral_limit: 123.0, // not the page's to change
            ..SteeringGains::default()
        };
        t.on_remote(&web(1, RemoteRequest::Gains(g)), ms(850));
        assert!(gains.has_changed().unwrap());
        let got = *gains.borrow_and_update();
        assert_eq!(got.speed_gain, 0.35);
        assert_eq!(got.steering_bias, 0.05);
        assert_eq!(got.integral_limit, SteeringGains::default().integral_limit);
        assert_eq!(t.gains(), got);
        // A watcher cannot change them; its emergency stop works.
        t.on_remote(
            &web(2, RemoteRequest::Gains(SteeringGains::default())),
            ms(900),
        );
        assert_eq!(t.gains().speed_gain, 0.35);
        assert_eq!(
            t.on_remote(&web(2, RemoteRequest::EmergencyStop), ms(950)),
            Some(Drive::Stop)
        );
        assert_eq!(t.mode(), Mode::Stopped);
        // Record without a recorder: stays off.
        t.on_remote(&web(1, RemoteRequest::Record(true)), ms(1000));
        assert_eq!(t.recording(), (false, 0));
    }

    /// A tub on a full card: every append fails with ENOSPC.
    struct FullCard;
    impl super::super::recorder::EpisodeSink for FullCard {
        fn append(
            &mut self,
            _: &crate::dataset::tub::TubRecord,
            _: &[u8],
        ) -> Result<u64, crate::dataset::DatasetError> {
            Err(crate::dataset::DatasetError::Io {
                path: "/media/sd/tub/images/0_cam_image_array_.jpg".into(),
                source: std::io::Error::from_raw_os_error(28),
            })
        }
        fn sync(&mut self) -> Result<(), crate::dataset::DatasetError> {
            Ok(())
        }
        fn delete_last(&mut self, _: usize) -> Result<usize, crate::dataset::DatasetError> {
            Ok(0)
        }
    }

    #[test]
    fn a_full_disk_ends_recording_and_says_why() {
        let (mut t, _) = teleop();
        t.recorder = Some(Recorder::start(Box::new(FullCard), 1000, None).unwrap());
        t.on_remote(&web(1, RemoteRequest::Record(true)), ms(0));
        assert_eq!(t.recording(), (true, 0));
        assert_eq!(t.record_error(), None);
        let cmd = Command {
            seq: 1,
            captured_at: ms(10),
            frame: std::sync::Arc::new(vec![0; 8 * 8 * 3]),
            width: 8,
            height: 8,
            outputs: [0.0, 0.0],
            wheels: WheelCommand::new(0.2, 0.2),
            preprocess: Duration::ZERO,
            inference: Duration::ZERO,
            control: Duration::ZERO,
        };
        t.record(&cmd, WheelCommand::new(0.2, 0.2));
        let t0 = std::time::Instant::now();
        while t.record_error().is_none() && t0.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(ms(2));
        }
        // Pressed, but stopped: the page shows "not recording" and the reason.
        assert_eq!(t.recording(), (false, 0));
        let why = t.record_error().unwrap();
        assert!(
            why.starts_with("/media/sd/tub/images/0_cam_image_array_.jpg: No space left on device"),
            "{why}"
        );
        assert!(why.ends_with("what was written is kept"), "{why}");
    }

    #[test]
    fn a_flood_of_other_messages_does_not_keep_a_silent_holder_driving() {
        let (mut t, _) = teleop();
        let d = t.on_remote(&web(1, drive(1.0, 0.0)), ms(0));
        assert!(matches!(d, Some(Drive::Command(_))), "{d:?}");
        // Client 2 floods; client 1 (the holder) is silent: from 0.5 s on the car is
        // stopped, however many messages arrive.
        for i in 1..=100u64 {
            let d = t.on_remote(&web(2, drive(0.0, 1.0)), ms(i * 10));
            if i * 10 >= 500 {
                assert_eq!(t.mode(), Mode::Stopped, "at {} ms", i * 10);
                assert!(
                    d.is_none() || d == Some(Drive::Stop),
                    "at {} ms: {d:?}",
                    i * 10
                );
            }
        }
    }

    #[test]
    fn the_holders_flood_writes_the_motors_at_most_every_20_ms() {
        let (mut t, _) = teleop();
        assert!(t.on_remote(&web(1, drive(1.0, 0.0)), ms(0)).is_some());
        // Heartbeats and gains from the holder write nothing (the control tick feeds the
        // motors); they still keep the hold.
        assert_eq!(t.on_remote(&web(1, RemoteRequest::Heartbeat), ms(1)), None);
        assert_eq!(
            t.on_remote(
                &web(1, RemoteRequest::Gains(SteeringGains::default())),
                ms(2)
            ),
            None
        );
        // 1001 drive messages from 20 to 120 ms: a write every 20 ms after the first, no more.
        let written: Vec<u64> = (0..=1000u64)
            .filter_map(|i| {
                let at = ms(0) + Duration::from_micros(i * 100);
                t.on_remote(&web(1, drive(1.0, 0.2)), at + ms(20))
                    .map(|_| (at + ms(20)).as_millis() as u64)
            })
            .collect();
        assert_eq!(written, vec![20, 40, 60, 80, 100, 120]);
        // The sticks not written at once are the tick's: the latest ones.
        assert_eq!(
            t.poll(ms(125)),
            Some(Drive::Command(WheelCommand::new(0.55, 0.45)))
        );
        assert_eq!(t.remote_holder(), Some(1));
    }
}
