//! The driving-mode state machine: who drives (the human, the autopilot, or nobody), and
//! when the human intervened. Pure: times are injected (`Duration` since the start of the
//! run), inputs come from [`GamepadState`] and the autopilot, outputs are a [`Drive`] per
//! tick and a list of [`ModeEvent`]s.
//!
//! ```text
//!            ToggleAutopilot                       EmergencyStop (any mode)
//!   Manual ------------------> Auto      Manual/Auto ----------------------> Stopped
//!          <------------------                      <----------------------
//!   ToggleAutopilot, or a stick past takeover_threshold   ClearEmergencyStop (to Manual)
//! ```
//!
//! Rules:
//! - The run starts in **Manual**. Output: the sticks' command ([`GamepadState::manual_command`]),
//!   except while the input is stale (no event for `heartbeat_ms`) or the pad is
//!   disconnected: then [`Drive::Stop`], resuming with the next event (JetBot's teleop
//!   heartbeat).
//! - **Auto**: the autopilot's command; `None` from the autopilot (no fresh command) gives
//!   [`Drive::Stop`]. An idle pad is normal here: staleness does not matter in Auto.
//! - **Stopped** (emergency stop) is latched: only [`Drive::Stop`] goes out, and every
//!   action but `ClearEmergencyStop` and the gain buttons is ignored (reported as
//!   [`ModeEvent::ActionIgnored`]). Clearing goes to Manual, never straight to Auto.
//! - **Gamepad lost** ([`InputEvent::Disconnected`]): in Manual -> Stopped (latched: after
//!   reconnecting, press clear first). In Auto -> Stopped, unless
//!   `autopilot_without_gamepad = true`, where the autopilot drives on. An idle or
//!   out-of-range wireless pad whose receiver stays plugged in is not "lost"; in Manual its
//!   silence is caught by the heartbeat rule above.
//! - **Intervention**: the human takes control while in Auto: ToggleAutopilot, a stick past
//!   `takeover_threshold`, or an emergency stop. It ends when Auto resumes
//!   ([`ModeEvent::InterventionEnded`] with its duration), or at [`Modes::finish`]. Losing the
//!   gamepad in Auto stops the car but is not an intervention (no human acted).
//! - Stick takeover is edge-triggered: after entering Auto with a stick still deflected,
//!   the stick must come back inside the threshold before pushing it takes over again.
//! - Gain buttons change the autopilot's [`SteeringGains`] in any mode: `speed_gain` by
//!   ±0.05 within 0..=1, `steering_gain` by ±0.05 within 0..=2
//!   ([`ModeEvent::GainsChanged`]; the daemon passes them to `SteeringLaw::set_gains`).
//! - `ToggleRecording` and `EraseLast` are not mode matters: [`Modes::handle_event`] returns
//!   every action, and the daemon routes those two to the recorder.
//!
//! Entering Auto is reported as a [`ModeEvent::ModeChanged`]; the daemon should reset the
//! steering law's state then (`SteeringLaw::reset`), so no stale derivative or integral
//! carries over from before the intervention.

use std::time::Duration;

use crate::control::{SteeringGains, WheelCommand};
use crate::hw::gamepad::{Action, GamepadConfig, GamepadState, InputEvent, PadSnapshot};

/// Step of the speed/steering gain buttons.
pub const GAIN_STEP: f32 = 0.05;
/// Allowed range of `speed_gain` for the gain buttons.
pub const SPEED_GAIN_RANGE: (f32, f32) = (0.0, 1.0);
/// Allowed range of `steering_gain` for the gain buttons.
pub const STEERING_GAIN_RANGE: (f32, f32) = (0.0, 2.0);
/// Allowed range of `steering_kd` (the config's; JetBot's slider is 0..0.5).
pub const STEERING_KD_RANGE: (f32, f32) = (0.0, 1.0);
/// Allowed range of `steering_bias` (the config's; JetBot's slider is -0.3..0.3).
pub const STEERING_BIAS_RANGE: (f32, f32) = (-0.5, 0.5);
/// Allowed range of `steering_ki` (the config's).
pub const STEERING_KI_RANGE: (f32, f32) = (0.0, 2.0);

/// The machine's settings (from `[gamepad]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModeParams {
    /// Stick deflection (after the dead zone, 0..1) that takes control in Auto.
    pub takeover_threshold: f32,
    /// Let the autopilot drive on when the gamepad disconnects.
    pub autopilot_without_gamepad: bool,
}

impl Default for ModeParams {
    fn default() -> Self {
        Self {
            takeover_threshold: 0.3,
            autopilot_without_gamepad: false,
        }
    }
}

impl ModeParams {
    pub fn from_gamepad(cfg: &GamepadConfig) -> Self {
        Self {
            takeover_threshold: cfg.takeover_threshold,
            autopilot_without_gamepad: cfg.autopilot_without_gamepad,
        }
    }
}

/// Who drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// The human, with the sticks.
    Manual,
    /// The autopilot (model + steering law).
    Auto,
    /// Emergency stop, latched until `ClearEmergencyStop`.
    Stopped,
}

impl Mode {
    /// `"manual"`, `"auto"`, `"stopped"` (as written in the interventions log).
    pub fn as_str(&self) -> &'static str {
        match self {
            Mode::Manual => "manual",
            Mode::Auto => "auto",
            Mode::Stopped => "stopped",
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why the mode changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cause {
    /// A button (ToggleAutopilot, EmergencyStop, ClearEmergencyStop).
    Button(Action),
    /// A stick pushed past the takeover threshold in Auto.
    Stick,
    /// The gamepad disconnected.
    GamepadLost,
    /// The web page holding the controls closed or fell silent (its dead-man).
    RemoteLost,
}

impl Cause {
    /// `"toggle_autopilot"`, `"emergency_stop"`, `"stick"`, `"gamepad_lost"`, ...
    pub fn as_str(&self) -> &'static str {
        match self {
            Cause::Button(a) => a.name(),
            Cause::Stick => "stick",
            Cause::GamepadLost => "gamepad_lost",
            Cause::RemoteLost => "browser_lost",
        }
    }
}

/// What goes to the motors on this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Drive {
    Stop,
    Command(WheelCommand),
}

/// Something the daemon may want to log or act on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ModeEvent {
    ModeChanged {
        at: Duration,
        from: Mode,
        to: Mode,
        cause: Cause,
    },
    InterventionStarted {
        at: Duration,
        cause: Cause,
    },
    InterventionEnded {
        at: Duration,
        /// When it started.
        started: Duration,
        duration: Duration,
        /// What started it.
        cause: Cause,
    },
    GainsChanged {
        at: Duration,
        gains: SteeringGains,
    },
    GamepadLost {
        at: Duration,
        mode: Mode,
    },
    GamepadReconnected {
        at: Duration,
    },
    /// Manual mode, and no gamepad event for the heartbeat period: the car stops. Also
    /// normal while the pad simply lies idle (at start-up, before the first event, too).
    InputStale {
        at: Duration,
    },
    /// Events again after [`ModeEvent::InputStale`].
    InputResumed {
        at: Duration,
    },
    /// An action that does nothing in this mode (for example ToggleAutopilot while Stopped).
    ActionIgnored {
        at: Duration,
        action: Action,
        mode: Mode,
    },
}

/// The mode machine.
#[derive(Debug, Clone)]
pub struct Modes {
    params: ModeParams,
    mode: Mode,
    gains: SteeringGains,
    /// The open intervention: when and why it started.
    intervention: Option<(Duration, Cause)>,
    interventions: u64,
    /// Stick takeover allowed (the stick was inside the threshold since Auto began).
    takeover_armed: bool,
    last_deflection: f32,
    /// The gamepad is disconnected (a Disconnected event, no event since).
    lost: bool,
    /// Manual and stale on the previous tick.
    stale: bool,
    events: Vec<ModeEvent>,
}

fn round_gain(v: f32) -> f32 {
    (v * 10_000.0).round() / 10_000.0
}

impl Modes {
    /// Starts in Manual with the autopilot's gains.
    pub fn new(params: ModeParams, gains: SteeringGains) -> Self {
        Self {
            params,
            mode: Mode::Manual,
            gains,
            intervention: None,
            interventions: 0,
            takeover_armed: false,
            last_deflection: 0.0,
            lost: false,
            stale: false,
            events: Vec::new(),
        }
    }

    /// The same machine with the autopilot engaged from the start (the simulator's demo);
    /// the stick can take over at once.
    pub fn engaged(mut self) -> Self {
        self.mode = Mode::Auto;
        self.takeover_armed = true;
        self
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    pub fn params(&self) -> ModeParams {
        self.params
    }

    /// The autopilot's gains, as changed by the gain buttons.
    pub fn gains(&self) -> SteeringGains {
        self.gains
    }

    /// Interventions started so far.
    pub fn interventions(&self) -> u64 {
        self.interventions
    }

    /// When the open intervention started, if one is open.
    pub fn intervention_started(&self) -> Option<Duration> {
        self.intervention.map(|(t, _)| t)
    }

    /// The events since the last call, oldest first.
    pub fn take_events(&mut self) -> Vec<ModeEvent> {
        std::mem::take(&mut self.events)
    }

    fn set_mode(&mut self, to: Mode, cause: Cause, now: Duration) {
        let from = self.mode;
        if from == to {
            return;
        }
        self.mode = to;
        self.events.push(ModeEvent::ModeChanged {
            at: now,
            from,
            to,
            cause,
        });
        if to == Mode::Auto {
            // Edge-triggered takeover: a stick still pushed must come back first.
            self.takeover_armed = self.last_deflection <= self.params.takeover_threshold;
            self.end_intervention(now);
        }
    }

    fn start_intervention(&mut self, cause: Cause, now: Duration) {
        if self.mode == Mode::Auto && self.intervention.is_none() {
            self.intervention = Some((now, cause));
            self.interventions += 1;
            self.events
                .push(ModeEvent::InterventionStarted { at: now, cause });
        }
    }

    fn end_intervention(&mut self, now: Duration) {
        if let Some((started, cause)) = self.intervention.take() {
            self.events.push(ModeEvent::InterventionEnded {
                at: now,
                started,
                duration: now.saturating_sub(started),
                cause,
            });
        }
    }

    fn ignore(&mut self, action: Action, now: Duration) {
        self.events.push(ModeEvent::ActionIgnored {
            at: now,
            action,
            mode: self.mode,
        });
    }

    fn change_gain(&mut self, action: Action, now: Duration) {
        let mut g = self.gains;
        let step = |v: f32, d: f32, (lo, hi): (f32, f32)| round_gain(v + d).clamp(lo, hi);
        match action {
            Action::SpeedGainUp => g.speed_gain = step(g.speed_gain, GAIN_STEP, SPEED_GAIN_RANGE),
            Action::SpeedGainDown => {
                g.speed_gain = step(g.speed_gain, -GAIN_STEP, SPEED_GAIN_RANGE)
            }
            Action::SteeringGainUp => {
                g.steering_gain = step(g.steering_gain, GAIN_STEP, STEERING_GAIN_RANGE)
            }
            Action::SteeringGainDown => {
                g.steering_gain = step(g.steering_gain, -GAIN_STEP, STEERING_GAIN_RANGE)
            }
            _ => return,
        }
        if g == self.gains {
            self.ignore(action, now);
        } else {
            self.gains = g;
            self.events
                .push(ModeEvent::GainsChanged { at: now, gains: g });
        }
    }

    /// Gains set from outside (the web page's sliders) at `now`, each clamped to its range
    /// (a non-finite value keeps the old one); `integral_limit` is kept.
    pub fn set_gains(&mut self, wanted: SteeringGains, now: Duration) {
        let old = self.gains;
        let fit = |v: f32, was: f32, (lo, hi): (f32, f32)| {
            if v.is_finite() {
                round_gain(v).clamp(lo, hi)
            } else {
                was
            }
        };
        let g = SteeringGains {
            speed_gain: fit(wanted.speed_gain, old.speed_gain, SPEED_GAIN_RANGE),
            steering_gain: fit(wanted.steering_gain, old.steering_gain, STEERING_GAIN_RANGE),
            steering_kd: fit(wanted.steering_kd, old.steering_kd, STEERING_KD_RANGE),
            steering_bias: fit(wanted.steering_bias, old.steering_bias, STEERING_BIAS_RANGE),
            steering_ki: fit(wanted.steering_ki, old.steering_ki, STEERING_KI_RANGE),
            integral_limit: old.integral_limit,
            mixing: old.mixing,
        };
        if g != old {
            self.gains = g;
            self.events
                .push(ModeEvent::GainsChanged { at: now, gains: g });
        }
    }

    /// The web page holding the controls closed or fell silent at `now`: Manual and Auto
    /// end in Stopped (latched, like a lost gamepad; not an intervention: nobody acted).
    pub fn on_remote_lost(&mut self, now: Duration) {
        if matches!(self.mode, Mode::Manual | Mode::Auto) {
            self.set_mode(Mode::Stopped, Cause::RemoteLost, now);
        }
    }

    /// A button action at `now`.
    pub fn on_action(&mut self, action: Action, now: Duration) {
        let cause = Cause::Button(action);
        match (action, self.mode) {
            (Action::EmergencyStop, Mode::Stopped) => self.ignore(action, now),
            (Action::EmergencyStop, _) => {
                self.start_intervention(cause, now);
                self.set_mode(Mode::Stopped, cause, now);
            }
            (Action::ClearEmergencyStop, Mode::Stopped) => self.set_mode(Mode::Manual, cause, now),
            (Action::ClearEmergencyStop, _) => self.ignore(action, now),
            (Action::ToggleAutopilot, Mode::Stopped) => self.ignore(action, now),
            (Action::ToggleAutopilot, Mode::Auto) => {
                self.start_intervention(cause, now);
                self.set_mode(Mode::Manual, cause, now);
            }
            (Action::ToggleAutopilot, Mode::Manual) => {
                if self.lost && !self.params.autopilot_without_gamepad {
                    self.ignore(action, now);
                } else {
                    self.set_mode(Mode::Auto, cause, now);
                }
            }
            (
                Action::SpeedGainUp
                | Action::SpeedGainDown
                | Action::SteeringGainUp
                | Action::SteeringGainDown,
                _,
            ) => self.change_gain(action, now),
            // The recorder's business.
            (Action::ToggleRecording | Action::EraseLast(_), _) => {}
        }
    }

    /// The gamepad disconnected at `now` (idempotent until it is back).
    pub fn on_gamepad_lost(&mut self, now: Duration) {
        if self.lost {
            return;
        }
        self.lost = true;
        self.events.push(ModeEvent::GamepadLost {
            at: now,
            mode: self.mode,
        });
        let stop = match self.mode {
            Mode::Manual => true,
            Mode::Auto => !self.params.autopilot_without_gamepad,
            Mode::Stopped => false,
        };
        if stop {
            self.set_mode(Mode::Stopped, Cause::GamepadLost, now);
        }
        self.last_deflection = 0.0;
    }

    /// The gamepad sent an event again after being lost.
    pub fn on_gamepad_back(&mut self, now: Duration) {
        if self.lost {
            self.lost = false;
            self.events.push(ModeEvent::GamepadReconnected { at: now });
        }
    }

    /// The sticks' deflection (0..1, after the dead zone) at `now`: in Auto, past the
    /// threshold (and armed), the human takes over.
    pub fn on_deflection(&mut self, deflection: f32, now: Duration) {
        self.last_deflection = deflection;
        if self.mode != Mode::Auto {
            return;
        }
        if deflection > self.params.takeover_threshold {
            if self.takeover_armed {
                self.start_intervention(Cause::Stick, now);
                self.set_mode(Mode::Manual, Cause::Stick, now);
            }
        } else {
            self.takeover_armed = true;
        }
    }

    /// Feeds one gamepad event through `pad` and into the machine; returns the pad's action
    /// (the daemon handles `ToggleRecording` and `EraseLast`).
    pub fn handle_event(
        &mut self,
        pad: &mut GamepadState,
        event: &InputEvent,
        now: Duration,
    ) -> Option<Action> {
        let action = pad.handle(event, now);
        match event {
            InputEvent::Disconnected => self.on_gamepad_lost(now),
            _ => self.on_gamepad_back(now),
        }
        if let Some(a) = action {
            self.on_action(a, now);
        }
        self.on_deflection(pad.deflection(), now);
        action
    }

    /// What goes out for this pad state and autopilot command (no state change).
    pub fn output(&self, pad: &PadSnapshot, autopilot: Option<WheelCommand>) -> Drive {
        match self.mode {
            Mode::Stopped => Drive::Stop,
            Mode::Manual if !pad.connected || pad.stale => Drive::Stop,
            Mode::Manual => Drive::Command(pad.manual),
            Mode::Auto => autopilot.map_or(Drive::Stop, Drive::Command),
        }
    }

    /// One control tick at `now`: checks the pad (lost, stick takeover, heartbeat) and
    /// returns what goes to the motors. `autopilot` is the autopilot's fresh command, or
    /// `None` when it has none.
    pub fn tick(
        &mut self,
        now: Duration,
        pad: &GamepadState,
        autopilot: Option<WheelCommand>,
    ) -> Drive {
        self.tick_snapshot(now, pad.snapshot(now), autopilot)
    }

    /// [`Modes::tick`] on a snapshot (the daemon merges a web page's sticks into it).
    pub fn tick_snapshot(
        &mut self,
        now: Duration,
        snap: PadSnapshot,
        autopilot: Option<WheelCommand>,
    ) -> Drive {
        if !snap.connected {
            self.on_gamepad_lost(now);
        }
        self.on_deflection(snap.deflection, now);
        let stale = self.mode == Mode::Manual && snap.connected && snap.stale;
        if stale != self.stale {
            self.stale = stale;
            self.events.push(if stale {
                ModeEvent::InputStale { at: now }
            } else {
                ModeEvent::InputResumed { at: now }
            });
        }
        self.output(&snap, autopilot)
    }

    /// The run ends at `now`: closes an open intervention.
    pub fn finish(&mut self, now: Duration) {
        self.end_intervention(now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hw::gamepad::{GamepadMap, Profile};
    use evdev::{AbsoluteAxisCode, KeyCode};

    fn s(secs: f64) -> Duration {
        Duration::from_secs_f64(secs)
    }

    fn pad(cfg: GamepadConfig) -> GamepadState {
        GamepadState::new(GamepadMap::from_config(&cfg).unwrap())
    }

    /// Xbox-style events: axes -32768..=32767.
    fn axis(code: AbsoluteAxisCode, value: i32) -> InputEvent {
        InputEvent::Axis {
            code,
            value,
            min: -32768,
            max: 32767,
        }
    }

    fn press(code: KeyCode) -> [InputEvent; 2] {
        [
            InputEvent::Button {
                code,
                pressed: true,
            },
            InputEvent::Button {
                code,
                pressed: false,
            },
        ]
    }

    /// A pad, a machine, and helpers to feed them.
    struct Rig {
        pad: GamepadState,
        modes: Modes,
    }

    impl Rig {
        fn new(cfg: GamepadConfig) -> Self {
            let params = ModeParams::from_gamepad(&cfg);
            Self {
                pad: pad(cfg),
                modes: Modes::new(params, SteeringGains::default()),
            }
        }

        fn feed(&mut self, t: f64, events: &[InputEvent]) {
            for e in events {
                self.modes.handle_event(&mut self.pad, e, s(t));
            }
        }

        fn tick(&mut self, t: f64, auto: Option<WheelCommand>) -> Drive {
            self.modes.tick(s(t), &self.pad, auto)
        }
    }

    const AUTO: WheelCommand = WheelCommand {
        left: 0.3,
        right: 0.2,
    };

    #[test]
    fn stick_push_in_auto_is_an_intervention() {
        let mut r = Rig::new(GamepadConfig::default());
        assert_eq!(r.modes.mode(), Mode::Manual);
        // A (BTN_SOUTH) at 1 s: Auto; the autopilot drives.
        r.feed(1.0, &press(KeyCode::BTN_SOUTH));
        assert_eq!(r.modes.mode(), Mode::Auto);
        assert_eq!(r.tick(1.05, Some(AUTO)), Drive::Command(AUTO));
        // Small stick noise (0.1 of full, inside the dead zone + threshold): no takeover.
        r.feed(2.0, &[axis(AbsoluteAxisCode::ABS_Y, -3277)]);
        assert_eq!(r.modes.mode(), Mode::Auto);
        // No autopilot command: stop. An idle pad in Auto is not stale.
        assert_eq!(r.tick(4.0, None), Drive::Stop);
        assert_eq!(r.tick(4.9, Some(AUTO)), Drive::Command(AUTO));
        let ev = r.modes.take_events();
        assert_eq!(
            ev,
            vec![ModeEvent::ModeChanged {
                at: s(1.0),
                from: Mode::Manual,
                to: Mode::Auto,
                cause: Cause::Button(Action::ToggleAutopilot)
            }]
        );
        // Left stick fully up at 5 s: takeover.
        r.feed(5.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        assert_eq!(r.modes.mode(), Mode::Manual);
        assert_eq!(r.modes.intervention_started(), Some(s(5.0)));
        // The manual command goes out, not the autopilot's: left wheel at throttle_scale.
        assert_eq!(
            r.tick(5.05, Some(AUTO)),
            Drive::Command(WheelCommand::new(0.5, 0.0))
        );
        let ev = r.modes.take_events();
        assert_eq!(
            ev,
            vec![
                ModeEvent::InterventionStarted {
                    at: s(5.0),
                    cause: Cause::Stick
                },
                ModeEvent::ModeChanged {
                    at: s(5.0),
                    from: Mode::Auto,
                    to: Mode::Manual,
                    cause: Cause::Stick
                },
            ]
        );
        // Stick back at 6 s, A at 8 s: Auto again, the intervention lasted 3 s.
        r.feed(6.0, &[axis(AbsoluteAxisCode::ABS_Y, 0)]);
        r.feed(8.0, &press(KeyCode::BTN_SOUTH));
        assert_eq!(r.modes.mode(), Mode::Auto);
        let ev = r.modes.take_events();
        assert_eq!(
            ev[1],
            ModeEvent::InterventionEnded {
                at: s(8.0),
                started: s(5.0),
                duration: s(3.0),
                cause: Cause::Stick
            }
        );
        assert_eq!(r.modes.interventions(), 1);
        assert_eq!(r.tick(8.1, Some(AUTO)), Drive::Command(AUTO));
    }

    #[test]
    fn toggle_button_intervention_and_edge_triggered_takeover() {
        let mut r = Rig::new(GamepadConfig::default());
        r.feed(0.5, &press(KeyCode::BTN_SOUTH));
        // A in Auto at 10 s: intervention by button.
        r.feed(10.0, &press(KeyCode::BTN_SOUTH));
        assert_eq!(r.modes.mode(), Mode::Manual);
        // The human drives with the right stick, then re-engages Auto at 12.5 s while still
        // holding it: the intervention ends (2.5 s) and the held stick does not take over
        // again at once.
        r.feed(11.0, &[axis(AbsoluteAxisCode::ABS_RY, -32768)]);
        r.feed(12.5, &press(KeyCode::BTN_SOUTH));
        r.feed(12.6, &[axis(AbsoluteAxisCode::ABS_RY, -32000)]);
        assert_eq!(r.tick(12.7, Some(AUTO)), Drive::Command(AUTO));
        assert_eq!(r.modes.mode(), Mode::Auto);
        let ended: Vec<_> = r
            .modes
            .take_events()
            .into_iter()
            .filter(|e| matches!(e, ModeEvent::InterventionEnded { .. }))
            .collect();
        assert_eq!(
            ended,
            vec![ModeEvent::InterventionEnded {
                at: s(12.5),
                started: s(10.0),
                duration: s(2.5),
                cause: Cause::Button(Action::ToggleAutopilot)
            }]
        );
        // Released, then pushed again: a second intervention.
        r.feed(13.0, &[axis(AbsoluteAxisCode::ABS_RY, 0)]);
        assert_eq!(r.modes.mode(), Mode::Auto);
        r.feed(14.0, &[axis(AbsoluteAxisCode::ABS_RY, 32767)]);
        assert_eq!(r.modes.mode(), Mode::Manual);
        assert_eq!(r.modes.interventions(), 2);
        // finish() closes it.
        r.modes.finish(s(20.0));
        let ev = r.modes.take_events();
        assert_eq!(
            ev.last(),
            Some(&ModeEvent::InterventionEnded {
                at: s(20.0),
                started: s(14.0),
                duration: s(6.0),
                cause: Cause::Stick
            })
        );
        assert_eq!(r.modes.intervention_started(), None);
    }

    #[test]
    fn emergency_stop_latches_until_cleared() {
        let mut r = Rig::new(GamepadConfig::default());
        r.feed(1.0, &press(KeyCode::BTN_SOUTH));
        // B in Auto at 3 s: Stopped, and an intervention starts.
        r.feed(3.0, &press(KeyCode::BTN_EAST));
        assert_eq!(r.modes.mode(), Mode::Stopped);
        assert_eq!(r.modes.intervention_started(), Some(s(3.0)));
        assert_eq!(r.tick(3.1, Some(AUTO)), Drive::Stop);
        // Toggles, sticks and a second stop change nothing.
        r.feed(4.0, &press(KeyCode::BTN_SOUTH));
        r.feed(4.5, &press(KeyCode::BTN_SOUTH));
        r.feed(5.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        r.feed(5.2, &press(KeyCode::BTN_EAST));
        assert_eq!(r.modes.mode(), Mode::Stopped);
        assert_eq!(r.tick(5.5, Some(AUTO)), Drive::Stop);
        let ignored = r
            .modes
            .take_events()
            .iter()
            .filter(|e| matches!(e, ModeEvent::ActionIgnored { .. }))
            .count();
        assert_eq!(ignored, 3);
        // Start clears to Manual (not Auto); the held stick now drives.
        r.feed(6.0, &press(KeyCode::BTN_START));
        assert_eq!(r.modes.mode(), Mode::Manual);
        assert_eq!(
            r.tick(6.1, Some(AUTO)),
            Drive::Command(WheelCommand::new(0.5, 0.0))
        );
        // Clear outside Stopped is ignored.
        r.feed(6.5, &press(KeyCode::BTN_START));
        assert_eq!(r.modes.mode(), Mode::Manual);
        // Auto again at 9 s: the intervention (3 s .. 9 s) ends.
        r.feed(8.0, &[axis(AbsoluteAxisCode::ABS_Y, 0)]);
        r.feed(9.0, &press(KeyCode::BTN_SOUTH));
        let ev = r.modes.take_events();
        assert!(
            ev.contains(&ModeEvent::InterventionEnded {
                at: s(9.0),
                started: s(3.0),
                duration: s(6.0),
                cause: Cause::Button(Action::EmergencyStop)
            }),
            "{ev:?}"
        );
        assert_eq!(r.modes.interventions(), 1);
        // An emergency stop from Auto is an intervention; from Manual it is not.
        r.feed(10.0, &press(KeyCode::BTN_SOUTH));
        r.feed(11.0, &press(KeyCode::BTN_EAST));
        r.feed(12.0, &press(KeyCode::BTN_START));
        r.feed(13.0, &press(KeyCode::BTN_EAST));
        assert_eq!(r.modes.mode(), Mode::Stopped);
        assert_eq!(r.modes.interventions(), 2);
    }

    #[test]
    fn gamepad_lost_in_manual_stops_and_latches() {
        let mut r = Rig::new(GamepadConfig::default());
        r.feed(1.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        assert_eq!(
            r.tick(1.1, None),
            Drive::Command(WheelCommand::new(0.5, 0.0))
        );
        r.feed(1.2, &[InputEvent::Disconnected]);
        assert_eq!(r.modes.mode(), Mode::Stopped);
        assert_eq!(r.tick(1.3, None), Drive::Stop);
        // Reconnected, stick pushed: still stopped until cleared.
        r.feed(3.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        assert_eq!(r.tick(3.1, None), Drive::Stop);
        r.feed(3.2, &press(KeyCode::BTN_START));
        assert_eq!(
            r.tick(3.3, None),
            Drive::Command(WheelCommand::new(0.5, 0.0))
        );
        let ev = r.modes.take_events();
        assert!(ev.contains(&ModeEvent::GamepadLost {
            at: s(1.2),
            mode: Mode::Manual
        }));
        assert!(ev.contains(&ModeEvent::GamepadReconnected { at: s(3.0) }));
        assert_eq!(r.modes.interventions(), 0);
    }

    #[test]
    fn stale_input_in_manual_stops_until_the_next_event() {
        let mut r = Rig::new(GamepadConfig::default());
        r.feed(1.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        assert_eq!(
            r.tick(1.4, None),
            Drive::Command(WheelCommand::new(0.5, 0.0))
        );
        // 500 ms without any event: stop (not latched).
        assert_eq!(r.tick(1.5, None), Drive::Stop);
        assert_eq!(r.modes.mode(), Mode::Manual);
        // The stick moves a little (noise): events again.
        r.feed(2.0, &[axis(AbsoluteAxisCode::ABS_Y, -32700)]);
        r.feed(2.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        assert_eq!(
            r.tick(2.01, None),
            Drive::Command(WheelCommand::new(0.5, 0.0))
        );
        let ev = r.modes.take_events();
        assert_eq!(
            ev,
            vec![
                ModeEvent::InputStale { at: s(1.5) },
                ModeEvent::InputResumed { at: s(2.01) }
            ]
        );
    }

    #[test]
    fn gamepad_lost_in_auto() {
        // Default: the autopilot stops too (JetBot's heartbeat rule); no intervention.
        let mut r = Rig::new(GamepadConfig::default());
        r.feed(1.0, &press(KeyCode::BTN_SOUTH));
        r.feed(2.0, &[InputEvent::Disconnected]);
        assert_eq!(r.modes.mode(), Mode::Stopped);
        assert_eq!(r.tick(2.1, Some(AUTO)), Drive::Stop);
        assert_eq!(r.modes.interventions(), 0);
        // autopilot_without_gamepad: drives on, and a lost pad in Auto is not stale.
        let mut r = Rig::new(GamepadConfig {
            autopilot_without_gamepad: true,
            ..GamepadConfig::default()
        });
        r.feed(1.0, &press(KeyCode::BTN_SOUTH));
        r.feed(2.0, &[InputEvent::Disconnected]);
        assert_eq!(r.modes.mode(), Mode::Auto);
        assert_eq!(r.tick(30.0, Some(AUTO)), Drive::Command(AUTO));
        // A lost pad discovered by tick (no event): same rule.
        let mut r = Rig::new(GamepadConfig::default());
        r.feed(1.0, &press(KeyCode::BTN_SOUTH));
        r.pad.handle(&InputEvent::Disconnected, s(2.0));
        assert_eq!(r.tick(2.05, Some(AUTO)), Drive::Stop);
        assert_eq!(r.modes.mode(), Mode::Stopped);
    }

    #[test]
    fn gain_buttons_step_within_ranges() {
        let mut r = Rig::new(GamepadConfig {
            profile: Profile::Xbox,
            ..GamepadConfig::default()
        });
        let hat = |code, value| InputEvent::Axis {
            code,
            value,
            min: -1,
            max: 1,
        };
        let up = [
            hat(AbsoluteAxisCode::ABS_HAT0Y, -1),
            hat(AbsoluteAxisCode::ABS_HAT0Y, 0),
        ];
        let down = [
            hat(AbsoluteAxisCode::ABS_HAT0Y, 1),
            hat(AbsoluteAxisCode::ABS_HAT0Y, 0),
        ];
        let right = [
            hat(AbsoluteAxisCode::ABS_HAT0X, 1),
            hat(AbsoluteAxisCode::ABS_HAT0X, 0),
        ];
        let left = [
            hat(AbsoluteAxisCode::ABS_HAT0X, -1),
            hat(AbsoluteAxisCode::ABS_HAT0X, 0),
        ];
        // speed_gain 0 -> 0.05 -> 0.1 (exact steps, no drift).
        r.feed(1.0, &up);
        r.feed(1.1, &up);
        assert_eq!(r.modes.gains().speed_gain, 0.1);
        // 25 more presses: capped at 1.
        for i in 0..25 {
            r.feed(2.0 + f64::from(i) * 0.1, &up);
        }
        assert_eq!(r.modes.gains().speed_gain, 1.0);
        r.feed(5.0, &down);
        assert_eq!(r.modes.gains().speed_gain, 0.95);
        for i in 0..30 {
            r.feed(6.0 + f64::from(i) * 0.1, &down);
        }
        assert_eq!(r.modes.gains().speed_gain, 0.0);
        // steering_gain 0.2 -> 0.25, then capped at 2 and floored at 0.
        r.feed(10.0, &right);
        assert_eq!(r.modes.gains().steering_gain, 0.25);
        for i in 0..50 {
            r.feed(11.0 + f64::from(i) * 0.1, &right);
        }
        assert_eq!(r.modes.gains().steering_gain, 2.0);
        r.feed(20.0, &left);
        assert_eq!(r.modes.gains().steering_gain, 1.95);
        for i in 0..50 {
            r.feed(21.0 + f64::from(i) * 0.1, &left);
        }
        assert_eq!(r.modes.gains().steering_gain, 0.0);
        // Every step in range, and each change reported; at a limit it is ignored.
        let ev = r.modes.take_events();
        let changes: Vec<SteeringGains> = ev
            .iter()
            .filter_map(|e| match e {
                ModeEvent::GainsChanged { gains, .. } => Some(*gains),
                _ => None,
            })
            .collect();
        assert_eq!(changes.len(), 2 + 18 + 20 + 1 + 35 + 40);
        for g in &changes {
            assert!((0.0..=1.0).contains(&g.speed_gain));
            assert!((0.0..=2.0).contains(&g.steering_gain));
        }
        // Other gains untouched.
        let g = r.modes.gains();
        assert_eq!(g.steering_kd, 0.0);
        assert_eq!(g.integral_limit, 0.3);
        // Gains change in Stopped too (set the speed before releasing the stop).
        r.feed(40.0, &press(KeyCode::BTN_EAST));
        r.feed(40.5, &up);
        assert_eq!(r.modes.gains().speed_gain, 0.05);
    }

    #[test]
    fn recording_actions_are_returned_not_consumed() {
        let mut r = Rig::new(GamepadConfig::default());
        let a = r.modes.handle_event(
            &mut r.pad,
            &InputEvent::Button {
                code: KeyCode::BTN_NORTH,
                pressed: true,
            },
            s(1.0),
        );
        assert_eq!(a, Some(Action::EraseLast(100)));
        let a = r.modes.handle_event(
            &mut r.pad,
            &InputEvent::Button {
                code: KeyCode::BTN_WEST,
                pressed: true,
            },
            s(1.1),
        );
        assert_eq!(a, Some(Action::ToggleRecording));
        assert!(r.modes.take_events().is_empty());
        assert_eq!(r.modes.mode(), Mode::Manual);
    }

    #[test]
    fn steer_mode_takeover_uses_the_steering_stick() {
        let mut r = Rig::new(GamepadConfig {
            drive_mode: crate::hw::gamepad::DriveMode::Steer,
            ..GamepadConfig::default()
        });
        r.feed(1.0, &press(KeyCode::BTN_SOUTH));
        // Left Y does nothing in steer mode; left X past 0.3 takes over.
        r.feed(2.0, &[axis(AbsoluteAxisCode::ABS_Y, -32768)]);
        assert_eq!(r.modes.mode(), Mode::Auto);
        r.feed(3.0, &[axis(AbsoluteAxisCode::ABS_X, 20000)]);
        assert_eq!(r.modes.mode(), Mode::Manual);
        assert_eq!(r.modes.intervention_started(), Some(s(3.0)));
    }
}
