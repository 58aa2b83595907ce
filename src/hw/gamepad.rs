//! Gamepad input through evdev (pure Rust, no SDL): the DonkeyCar-style controls of a
//! JetBot/DonkeyCar car.
//!
//! Two layers:
//!
//! - **Mapping (pure).** [`GamepadConfig`] (the `[gamepad]` config section) resolves to a
//!   [`GamepadMap`]; [`GamepadState`] consumes [`InputEvent`]s with the time they arrived and
//!   produces normalised sticks ([`Sticks`]), a manual [`WheelCommand`]
//!   ([`GamepadState::manual_command`]) and one [`Action`] per button *press* (holding a
//!   button, or the kernel's key repeat, does not repeat it). No clock, no I/O: feed it
//!   synthetic events in tests.
//! - **Device.** [`find_gamepad`] opens the configured device (or the first device with
//!   gamepad buttons for `device = "auto"`); [`GamepadReader`] blocks on it and turns evdev
//!   events into [`InputEvent`]s (axis ranges from the device's absinfo). A vanished device
//!   yields [`InputEvent::Disconnected`]. The daemon runs the reader in its own thread.
//!
//! # Sticks
//!
//! An axis value `v` in `min..=max` is first mapped to `-1..=1` around the middle of its
//! range (`(v - (min + max) / 2) / ((max - min) / 2)`, clamped), then the dead zone is
//! applied and the rest rescaled so the output is continuous at the edge of the dead zone:
//!
//! ```text
//! |x| <= dead_zone:  0
//! otherwise:         sign(x) * (|x| - dead_zone) / (1 - dead_zone)
//! ```
//!
//! With the default dead zone 0.08: 0.08 -> 0, 0.09 -> 0.0109, 0.5 -> 0.4565, 1 -> 1.
//! Linux reports stick *up* as negative Y, so `invert_throttle = true` (the default) makes
//! stick up = forward = positive. X is positive to the right; positive steering turns right
//! (left wheel faster), as in the steering law; `invert_steering` flips it.
//!
//! # Manual commands
//!
//! ```text
//! tank  (JetBot):    left = clamp(left_y * throttle_scale), right = clamp(right_y * throttle_scale)
//! steer (DonkeyCar): throttle = right_y * throttle_scale, steering = left_x * steering_scale
//!                    left = clamp(throttle + steering), right = clamp(throttle - steering)
//! ```
//!
//! (`clamp` to -1..=1.) `throttle_scale` (default 0.5) is DonkeyCar's throttle scale: the
//! largest manual wheel speed in tank mode and the largest forward speed in steer mode.
//!
//! # Profiles (default maps)
//!
//! Codes are the kernel's evdev codes, as `evtest` prints them. Overrides in
//! `[gamepad.axes]` / `[gamepad.buttons]` take evdev code names (`"ABS_RZ"`, `"BTN_EAST"`),
//! the aliases `BTN_A`/`BTN_B`/`BTN_X`/`BTN_Y`, a hat direction (`"ABS_HAT0Y-"` = D-pad
//! up, `"ABS_HAT0X+"` = D-pad right) or `"none"` (button unused).
//!
//! | role                 | `xbox` / `f710` (xpad driver)         | `generic` (ShanWan, "Twin USB Joystick") |
//! |----------------------|---------------------------------------|------------------------------------------|
//! | left stick X / Y     | `ABS_X` / `ABS_Y`                     | `ABS_X` / `ABS_Y`                        |
//! | right stick X / Y    | `ABS_RX` / `ABS_RY`                   | `ABS_Z` / `ABS_RZ`                       |
//! | toggle autopilot     | A `BTN_SOUTH`                         | button 3 (bottom) `BTN_THUMB2`           |
//! | emergency stop       | B `BTN_EAST`                          | button 2 (right) `BTN_THUMB`             |
//! | erase last 100       | X `BTN_NORTH` (kernel alias `BTN_X`)  | button 4 (left) `BTN_TOP`                |
//! | toggle recording     | Y `BTN_WEST` (kernel alias `BTN_Y`)   | button 1 (top) `BTN_TRIGGER`             |
//! | clear emergency stop | Start `BTN_START`                     | button 10 (start) `BTN_BASE4`            |
//! | speed gain up / down | D-pad up / down `ABS_HAT0Y-` / `ABS_HAT0Y+` (also `BTN_TRIGGER_HAPPY3` / `4` on xbox) | same hat |
//! | steering gain up / down | D-pad right / left `ABS_HAT0X+` / `ABS_HAT0X-` (also `BTN_TRIGGER_HAPPY2` / `1` on xbox) | same hat |
//!
//! - xpad reports the button labelled X as `BTN_X` (= `BTN_NORTH`, 0x133) and Y as `BTN_Y`
//!   (= `BTN_WEST`, 0x134), whatever their physical places; wireless Xbox 360 receivers
//!   report the D-pad as `BTN_TRIGGER_HAPPY1..4` (left, right, up, down) instead of the hat,
//!   so the xbox map binds both.
//! - The Logitech F710 must be in XInput mode (switch on the back at **X**); it then is an
//!   xpad device with the xbox map. In DirectInput mode (**D**) use `profile = "generic"` and
//!   check the codes with `evtest`.
//! - The cheap 2.4 GHz pads shipped with JetBot kits ("ShanWan", "Twin USB Joystick") use
//!   hid-generic: axes 0..255 with the middle at 128, buttons `BTN_TRIGGER` .. `BTN_BASE6`
//!   numbered 1..12 as printed on most of them. Labels differ between clones: check with
//!   `evtest` and override.
//!
//! # Heartbeat
//!
//! evdev sends events only on change. [`GamepadState::is_stale`] is true when no event at
//! all came for `heartbeat_ms` (0 = off); the mode machine stops the car while the input is
//! stale in Manual mode (JetBot's teleop rule: no heartbeat, no motion). A wireless pad
//! that goes out of range or runs flat leaves its receiver plugged in and its last values
//! latched; the heartbeat catches that. The price: a stick held perfectly still (for
//! example pinned at full deflection) produces no events either, so the car pauses until
//! the stick moves a little.
//!
//! # Permissions
//!
//! `/dev/input/event*` belong to the `input` group: `sudo usermod -aG input $USER`, then log
//! in again.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Duration;

use evdev::{AbsoluteAxisCode, EventSummary, KeyCode};
use serde::{Deserialize, Serialize};

use crate::control::WheelCommand;

/// Errors of the gamepad layer; each names the config key or the device.
#[derive(Debug, thiserror::Error)]
pub enum GamepadError {
    #[error("key `{key}` = {value} is out of range: allowed {allowed}")]
    Config {
        key: String,
        value: String,
        allowed: String,
    },
    #[error(
        "gamepad {path}: permission denied: add the user to the `input` group (`sudo usermod -aG input $USER`, then log in again)"
    )]
    Permission { path: PathBuf },
    #[error(
        "gamepad {path}: no such device (is it plugged in and switched on? `ls -l /dev/input/by-id/` lists the devices)"
    )]
    NotFound { path: PathBuf },
    #[error("gamepad {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "no gamepad found in /dev/input ({scanned} event devices scanned{denied}); plug one in or set `gamepad.device`"
    )]
    NoneFound {
        scanned: usize,
        /// `", N could not be opened: permission denied, add the user to the `input` group ..."`.
        denied: String,
    },
    #[error("gamepad {path}: the device was disconnected")]
    Gone { path: PathBuf },
}

pub type Result<T> = std::result::Result<T, GamepadError>;

/// The default map family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// Xbox 360/One pads (xpad driver).
    Xbox,
    /// Logitech F710 in XInput mode: the xbox map.
    F710,
    /// hid-generic pads: ShanWan, "Twin USB Joystick" (JetBot kits).
    Generic,
}

/// How the sticks drive the wheels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DriveMode {
    /// JetBot: left stick Y = left wheel, right stick Y = right wheel.
    Tank,
    /// DonkeyCar: left stick X steers, right stick Y is the throttle.
    Steer,
}

/// `[gamepad.axes]`: evdev axis names replacing the profile's.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AxisOverrides {
    /// The left stick's horizontal axis, an evdev name such as `ABS_X`.
    pub left_x: Option<String>,
    /// The left stick's vertical axis (`ABS_Y` on most pads).
    pub left_y: Option<String>,
    /// The right stick's horizontal axis (`ABS_RX` on Xbox pads, `ABS_Z` on some others).
    pub right_x: Option<String>,
    /// The right stick's vertical axis (`ABS_RY` on Xbox pads, `ABS_RZ` on some others).
    pub right_y: Option<String>,
}

/// `[gamepad.buttons]`: a button name (or `"none"`) replacing every default binding of
/// that action.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ButtonOverrides {
    /// The button to switch between manual and the autopilot (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub toggle_autopilot: Option<String>,
    /// The button to start or stop recording a tub (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub toggle_recording: Option<String>,
    /// The button to stop the motors and latch the stop (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub emergency_stop: Option<String>,
    /// The button to release the latched stop (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub clear_emergency_stop: Option<String>,
    /// The button to delete the last `erase_count` records of the tub (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub erase_last: Option<String>,
    /// The button to raise `control.speed_gain` (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub speed_gain_up: Option<String>,
    /// The button to lower `control.speed_gain` (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub speed_gain_down: Option<String>,
    /// The button to raise `control.steering_gain` (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub steering_gain_up: Option<String>,
    /// The button to lower `control.steering_gain` (an evdev name such as `BTN_SOUTH`, or `"none"`).
    pub steering_gain_down: Option<String>,
}

/// The `[gamepad]` config section; every key optional.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GamepadConfig {
    /// A device node (`/dev/input/event3`, `/dev/input/by-id/...-event-joystick`) or
    /// `"auto"`: the first device with gamepad buttons.
    pub device: String,
    pub profile: Profile,
    pub axes: AxisOverrides,
    pub buttons: ButtonOverrides,
    /// Stick dead zone, 0 ..< 0.9.
    pub dead_zone: f32,
    /// Largest manual throttle, 0 ..= 1.
    pub throttle_scale: f32,
    /// Largest manual steering in steer mode, 0 ..= 1.
    pub steering_scale: f32,
    /// Stick up = forward (Linux reports up as negative).
    pub invert_throttle: bool,
    /// Flip the steering axis (positive steering turns right, as in the steering law).
    pub invert_steering: bool,
    pub drive_mode: DriveMode,
    /// No event at all for this long while in Manual mode = stale input (0 = off).
    pub heartbeat_ms: u64,
    /// Records removed by the erase button (DonkeyCar: 100).
    pub erase_count: usize,
    /// A stick past this (after the dead zone) while in Auto takes control (an intervention).
    pub takeover_threshold: f32,
    /// Let the autopilot drive on when the gamepad disconnects (JetBot's heartbeat rule says
    /// no: default false).
    pub autopilot_without_gamepad: bool,
}

impl Default for GamepadConfig {
    fn default() -> Self {
        Self {
            device: "auto".into(),
            profile: Profile::Xbox,
            axes: AxisOverrides::default(),
            buttons: ButtonOverrides::default(),
            dead_zone: 0.08,
            throttle_scale: 0.5,
            steering_scale: 0.5,
            invert_throttle: true,
            invert_steering: false,
            drive_mode: DriveMode::Tank,
            heartbeat_ms: 500,
            erase_count: 100,
            takeover_threshold: 0.3,
            autopilot_without_gamepad: false,
        }
    }
}

impl GamepadConfig {
    /// Checks the ranges and the code names (through [`GamepadMap::from_config`]).
    pub fn validate(&self) -> Result<()> {
        GamepadMap::from_config(self).map(|_| ())
    }

    /// `None` for `"auto"`.
    pub fn device_path(&self) -> Option<PathBuf> {
        let d = self.device.trim();
        if d.is_empty() || d.eq_ignore_ascii_case("auto") {
            None
        } else {
            Some(PathBuf::from(d))
        }
    }
}

/// What a button press asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Action {
    ToggleAutopilot,
    ToggleRecording,
    EmergencyStop,
    ClearEmergencyStop,
    /// Remove the last N records (DonkeyCar: 100).
    EraseLast(usize),
    SpeedGainUp,
    SpeedGainDown,
    SteeringGainUp,
    SteeringGainDown,
}

impl Action {
    /// The config key naming the action (`[gamepad.buttons]`).
    pub fn name(&self) -> &'static str {
        match self {
            Action::ToggleAutopilot => "toggle_autopilot",
            Action::ToggleRecording => "toggle_recording",
            Action::EmergencyStop => "emergency_stop",
            Action::ClearEmergencyStop => "clear_emergency_stop",
            Action::EraseLast(_) => "erase_last",
            Action::SpeedGainUp => "speed_gain_up",
            Action::SpeedGainDown => "speed_gain_down",
            Action::SteeringGainUp => "steering_gain_up",
            Action::SteeringGainDown => "steering_gain_down",
        }
    }
}

/// A physical button: a key code, or one direction of a hat axis (the D-pad).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ButtonId {
    Key(KeyCode),
    Hat {
        axis: AbsoluteAxisCode,
        positive: bool,
    },
}

impl std::fmt::Display for ButtonId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ButtonId::Key(k) => write!(f, "{k:?}"),
            ButtonId::Hat { axis, positive } => {
                write!(f, "{axis:?}{}", if *positive { '+' } else { '-' })
            }
        }
    }
}

impl ButtonId {
    /// Parses `BTN_EAST`, the aliases `BTN_A/B/X/Y`, or `ABS_HAT0Y-`-style hat directions.
    pub fn parse(name: &str) -> Option<ButtonId> {
        let name = name.trim();
        if let Some(axis) = name.strip_suffix('+') {
            return parse_axis(axis).map(|axis| ButtonId::Hat {
                axis,
                positive: true,
            });
        }
        if let Some(axis) = name.strip_suffix('-') {
            return parse_axis(axis).map(|axis| ButtonId::Hat {
                axis,
                positive: false,
            });
        }
        let key = match name {
            "BTN_A" => KeyCode::BTN_SOUTH,
            "BTN_B" => KeyCode::BTN_EAST,
            "BTN_X" => KeyCode::BTN_NORTH,
            "BTN_Y" => KeyCode::BTN_WEST,
            "BTN_GAMEPAD" => KeyCode::BTN_SOUTH,
            "BTN_JOYSTICK" => KeyCode::BTN_TRIGGER,
            other => other.parse::<KeyCode>().ok()?,
        };
        Some(ButtonId::Key(key))
    }
}

/// Parses an evdev absolute-axis name (`ABS_RZ`).
pub fn parse_axis(name: &str) -> Option<AbsoluteAxisCode> {
    name.trim().parse::<AbsoluteAxisCode>().ok()
}

/// The four stick axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StickAxes {
    pub left_x: AbsoluteAxisCode,
    pub left_y: AbsoluteAxisCode,
    pub right_x: AbsoluteAxisCode,
    pub right_y: AbsoluteAxisCode,
}

/// A resolved map: the profile's defaults with the overrides applied, ranges checked.
#[derive(Debug, Clone, PartialEq)]
pub struct GamepadMap {
    pub profile: Profile,
    pub axes: StickAxes,
    /// Button -> action; several buttons may trigger one action, one button one action.
    pub buttons: Vec<(ButtonId, Action)>,
    pub dead_zone: f32,
    pub throttle_scale: f32,
    pub steering_scale: f32,
    pub invert_throttle: bool,
    pub invert_steering: bool,
    pub drive_mode: DriveMode,
    /// `None`: no heartbeat check.
    pub heartbeat: Option<Duration>,
    pub takeover_threshold: f32,
    pub autopilot_without_gamepad: bool,
}

const HAT_X: AbsoluteAxisCode = AbsoluteAxisCode::ABS_HAT0X;
const HAT_Y: AbsoluteAxisCode = AbsoluteAxisCode::ABS_HAT0Y;

fn hat(axis: AbsoluteAxisCode, positive: bool) -> ButtonId {
    ButtonId::Hat { axis, positive }
}

/// The default stick axes of a profile.
pub fn profile_axes(profile: Profile) -> StickAxes {
    match profile {
        Profile::Xbox | Profile::F710 => StickAxes {
            left_x: AbsoluteAxisCode::ABS_X,
            left_y: AbsoluteAxisCode::ABS_Y,
            right_x: AbsoluteAxisCode::ABS_RX,
            right_y: AbsoluteAxisCode::ABS_RY,
        },
        Profile::Generic => StickAxes {
            left_x: AbsoluteAxisCode::ABS_X,
            left_y: AbsoluteAxisCode::ABS_Y,
            right_x: AbsoluteAxisCode::ABS_Z,
            right_y: AbsoluteAxisCode::ABS_RZ,
        },
    }
}

/// The default button bindings of a profile (see the module doc's table).
pub fn profile_buttons(profile: Profile, erase_count: usize) -> Vec<(ButtonId, Action)> {
    use Action::*;
    let key = ButtonId::Key;
    let dpad = [
        (hat(HAT_Y, false), SpeedGainUp),
        (hat(HAT_Y, true), SpeedGainDown),
        (hat(HAT_X, true), SteeringGainUp),
        (hat(HAT_X, false), SteeringGainDown),
    ];
    let mut v = match profile {
        Profile::Xbox | Profile::F710 => vec![
            (key(KeyCode::BTN_SOUTH), ToggleAutopilot),
            (key(KeyCode::BTN_EAST), EmergencyStop),
            (key(KeyCode::BTN_NORTH), EraseLast(erase_count)),
            (key(KeyCode::BTN_WEST), ToggleRecording),
            (key(KeyCode::BTN_START), ClearEmergencyStop),
            // Wireless Xbox 360 receivers: D-pad as buttons (left, right, up, down).
            (key(KeyCode::BTN_TRIGGER_HAPPY3), SpeedGainUp),
            (key(KeyCode::BTN_TRIGGER_HAPPY4), SpeedGainDown),
            (key(KeyCode::BTN_TRIGGER_HAPPY2), SteeringGainUp),
            (key(KeyCode::BTN_TRIGGER_HAPPY1), SteeringGainDown),
        ],
        Profile::Generic => vec![
            (key(KeyCode::BTN_THUMB2), ToggleAutopilot),
            (key(KeyCode::BTN_THUMB), EmergencyStop),
            (key(KeyCode::BTN_TOP), EraseLast(erase_count)),
            (key(KeyCode::BTN_TRIGGER), ToggleRecording),
            (key(KeyCode::BTN_BASE4), ClearEmergencyStop),
        ],
    };
    v.extend(dpad);
    v
}

impl GamepadMap {
    /// Resolves the profile and the overrides, and checks every range.
    pub fn from_config(cfg: &GamepadConfig) -> Result<Self> {
        let range = |key: &str, v: f32, lo: f32, hi: f32, hi_open: bool| {
            let ok = v.is_finite() && v >= lo && if hi_open { v < hi } else { v <= hi };
            if ok {
                Ok(())
            } else {
                Err(GamepadError::Config {
                    key: format!("gamepad.{key}"),
                    value: v.to_string(),
                    allowed: if hi_open {
                        format!("{lo} ..< {hi}")
                    } else {
                        format!("{lo} ..= {hi}")
                    },
                })
            }
        };
        range("dead_zone", cfg.dead_zone, 0.0, 0.9, true)?;
        range("throttle_scale", cfg.throttle_scale, 0.0, 1.0, false)?;
        range("steering_scale", cfg.steering_scale, 0.0, 1.0, false)?;
        range(
            "takeover_threshold",
            cfg.takeover_threshold,
            0.05,
            1.0,
            true,
        )?;
        if cfg.heartbeat_ms != 0 && !(50..=10_000).contains(&cfg.heartbeat_ms) {
            return Err(GamepadError::Config {
                key: "gamepad.heartbeat_ms".into(),
                value: cfg.heartbeat_ms.to_string(),
                allowed: "0 (off) or 50 ..= 10000".into(),
            });
        }
        if !(1..=100_000).contains(&cfg.erase_count) {
            return Err(GamepadError::Config {
                key: "gamepad.erase_count".into(),
                value: cfg.erase_count.to_string(),
                allowed: "1 ..= 100000".into(),
            });
        }

        let mut axes = profile_axes(cfg.profile);
        let o = &cfg.axes;
        for (key, slot, name) in [
            ("left_x", &mut axes.left_x, &o.left_x),
            ("left_y", &mut axes.left_y, &o.left_y),
            ("right_x", &mut axes.right_x, &o.right_x),
            ("right_y", &mut axes.right_y, &o.right_y),
        ] {
            if let Some(name) = name {
                *slot = parse_axis(name).ok_or_else(|| GamepadError::Config {
                    key: format!("gamepad.axes.{key}"),
                    value: format!("{name:?}"),
                    allowed:
                        "an evdev absolute axis name such as \"ABS_X\", \"ABS_RY\", \"ABS_RZ\""
                            .into(),
                })?;
            }
        }

        let mut buttons = profile_buttons(cfg.profile, cfg.erase_count);
        let b = &cfg.buttons;
        let overrides = [
            (Action::ToggleAutopilot, &b.toggle_autopilot),
            (Action::ToggleRecording, &b.toggle_recording),
            (Action::EmergencyStop, &b.emergency_stop),
            (Action::ClearEmergencyStop, &b.clear_emergency_stop),
            (Action::EraseLast(cfg.erase_count), &b.erase_last),
            (Action::SpeedGainUp, &b.speed_gain_up),
            (Action::SpeedGainDown, &b.speed_gain_down),
            (Action::SteeringGainUp, &b.steering_gain_up),
            (Action::SteeringGainDown, &b.steering_gain_down),
        ];
        // First drop every default binding of an overridden action, then add the new ones,
        // so swapping two buttons works.
        for (action, name) in &overrides {
            if name.is_some() {
                buttons.retain(|(_, a)| a != action);
            }
        }
        let mut overridden: HashMap<ButtonId, Action> = HashMap::new();
        for (action, name) in &overrides {
            let Some(name) = name else { continue };
            if name.trim().eq_ignore_ascii_case("none") {
                continue;
            }
            let id = ButtonId::parse(name).ok_or_else(|| GamepadError::Config {
                key: format!("gamepad.buttons.{}", action.name()),
                value: format!("{name:?}"),
                allowed: "an evdev button name such as \"BTN_SOUTH\" or \"BTN_THUMB2\", a hat direction such as \"ABS_HAT0Y-\", or \"none\"".into(),
            })?;
            // One button, one action: two overrides may not name the same button.
            if let Some(prev) = overridden.insert(id, *action) {
                return Err(GamepadError::Config {
                    key: format!("gamepad.buttons.{}", action.name()),
                    value: format!("\"{id}\""),
                    allowed: format!(
                        "a button not already bound to `gamepad.buttons.{}`",
                        prev.name()
                    ),
                });
            }
            // A button taken over from another action's default binding moves here.
            buttons.retain(|(b, _)| *b != id);
            buttons.push((id, *action));
        }

        Ok(Self {
            profile: cfg.profile,
            axes,
            buttons,
            dead_zone: cfg.dead_zone,
            throttle_scale: cfg.throttle_scale,
            steering_scale: cfg.steering_scale,
            invert_throttle: cfg.invert_throttle,
            invert_steering: cfg.invert_steering,
            drive_mode: cfg.drive_mode,
            heartbeat: (cfg.heartbeat_ms > 0).then(|| Duration::from_millis(cfg.heartbeat_ms)),
            takeover_threshold: cfg.takeover_threshold,
            autopilot_without_gamepad: cfg.autopilot_without_gamepad,
        })
    }

    /// The action bound to a button, if any.
    pub fn action_for(&self, id: ButtonId) -> Option<Action> {
        self.buttons.iter().find(|(b, _)| *b == id).map(|(_, a)| *a)
    }

    /// The buttons bound to an action.
    pub fn buttons_for(&self, action: Action) -> Vec<ButtonId> {
        self.buttons
            .iter()
            .filter(|(_, a)| *a == action)
            .map(|(b, _)| *b)
            .collect()
    }

    fn hat_axes(&self) -> impl Iterator<Item = AbsoluteAxisCode> + '_ {
        self.buttons.iter().filter_map(|(b, _)| match b {
            ButtonId::Hat { axis, .. } => Some(*axis),
            ButtonId::Key(_) => None,
        })
    }
}

/// One input event, device-independent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputEvent {
    /// An absolute axis moved to `value`, in the device's range `min..=max`.
    Axis {
        code: AbsoluteAxisCode,
        value: i32,
        min: i32,
        max: i32,
    },
    /// A key/button went down (`pressed`) or up. Key repeats come as `pressed: true` again.
    Button { code: KeyCode, pressed: bool },
    /// The device went away (unplugged, receiver removed, driver unbound).
    Disconnected,
}

/// Maps a raw axis value to -1..=1 around the middle of its range (clamped). A degenerate
/// range gives 0.
pub fn normalize_axis(value: i32, min: i32, max: i32) -> f32 {
    let (lo, hi) = (f64::from(min.min(max)), f64::from(min.max(max)));
    let half = (hi - lo) / 2.0;
    if half <= 0.0 {
        return 0.0;
    }
    let centre = (lo + hi) / 2.0;
    ((f64::from(value) - centre) / half).clamp(-1.0, 1.0) as f32
}

/// The dead zone, rescaled so the output is continuous: `|x| <= dz` -> 0, else
/// `sign(x) * (|x| - dz) / (1 - dz)`. Input and output in -1..=1.
pub fn apply_dead_zone(x: f32, dead_zone: f32) -> f32 {
    if !x.is_finite() {
        return 0.0;
    }
    let x = x.clamp(-1.0, 1.0);
    let dz = dead_zone.clamp(0.0, 0.99);
    if x.abs() <= dz {
        0.0
    } else {
        x.signum() * (x.abs() - dz) / (1.0 - dz)
    }
}

/// Normalised sticks in the driving convention: x positive = right, y positive = forward
/// (inversions and dead zone applied), each in -1..=1.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sticks {
    pub left_x: f32,
    pub left_y: f32,
    pub right_x: f32,
    pub right_y: f32,
}

/// What the mode machine needs from the pad at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PadSnapshot {
    /// The command the sticks ask for (stop when disconnected).
    pub manual: WheelCommand,
    /// The largest deflection of the sticks that drive in this drive mode (after the dead
    /// zone, before the scales), 0..=1.
    pub deflection: f32,
    pub connected: bool,
    /// No event for the heartbeat period (or none yet).
    pub stale: bool,
}

/// The pad's state, fed with events and their arrival times. Pure.
#[derive(Debug, Clone)]
pub struct GamepadState {
    map: GamepadMap,
    /// Normalised raw stick values (device sign, no dead zone): lx, ly, rx, ry.
    raw: [f32; 4],
    /// Current direction (-1, 0, 1) of each hat axis that carries buttons.
    hats: HashMap<AbsoluteAxisCode, i8>,
    pressed: HashSet<KeyCode>,
    last_event: Option<Duration>,
    connected: bool,
}

impl GamepadState {
    /// A state that assumes the pad is connected, with centred sticks and no event yet.
    pub fn new(map: GamepadMap) -> Self {
        Self {
            map,
            raw: [0.0; 4],
            hats: HashMap::new(),
            pressed: HashSet::new(),
            last_event: None,
            connected: true,
        }
    }

    pub fn map(&self) -> &GamepadMap {
        &self.map
    }

    /// Consumes one event that arrived at `now` (time since start). Returns the action of a
    /// button press (an edge: a held or repeated button gives nothing more).
    pub fn handle(&mut self, event: &InputEvent, now: Duration) -> Option<Action> {
        self.last_event = Some(now);
        match *event {
            InputEvent::Disconnected => {
                self.connected = false;
                self.raw = [0.0; 4];
                self.hats.clear();
                self.pressed.clear();
                None
            }
            InputEvent::Button { code, pressed } => {
                self.connected = true;
                let was = if pressed {
                    !self.pressed.insert(code)
                } else {
                    self.pressed.remove(&code);
                    true
                };
                if pressed && !was {
                    self.map.action_for(ButtonId::Key(code))
                } else {
                    None
                }
            }
            InputEvent::Axis {
                code,
                value,
                min,
                max,
            } => {
                self.connected = true;
                let v = normalize_axis(value, min, max);
                let a = self.map.axes;
                for (i, axis) in [a.left_x, a.left_y, a.right_x, a.right_y]
                    .into_iter()
                    .enumerate()
                {
                    if axis == code {
                        self.raw[i] = v;
                    }
                }
                if !self.map.hat_axes().any(|h| h == code) {
                    return None;
                }
                let dir: i8 = if v < -0.5 {
                    -1
                } else if v > 0.5 {
                    1
                } else {
                    0
                };
                let old = self.hats.insert(code, dir).unwrap_or(0);
                if dir != 0 && dir != old {
                    self.map.action_for(ButtonId::Hat {
                        axis: code,
                        positive: dir > 0,
                    })
                } else {
                    None
                }
            }
        }
    }

    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// When the last event (of any kind) arrived.
    pub fn last_event(&self) -> Option<Duration> {
        self.last_event
    }

    /// True when the heartbeat is on and no event came for `heartbeat_ms` (or none yet).
    pub fn is_stale(&self, now: Duration) -> bool {
        match (self.map.heartbeat, self.last_event) {
            (None, _) => false,
            (Some(_), None) => true,
            (Some(hb), Some(t)) => now.saturating_sub(t) >= hb,
        }
    }

    /// The sticks with the dead zone and the inversions applied.
    pub fn sticks(&self) -> Sticks {
        let m = &self.map;
        let dz = |v: f32| apply_dead_zone(v, m.dead_zone);
        let sx = if m.invert_steering { -1.0 } else { 1.0 };
        let sy = if m.invert_throttle { -1.0 } else { 1.0 };
        // `0.0 * -1.0` is -0.0; adding 0.0 turns it into +0.0 for tidy output.
        Sticks {
            left_x: sx * dz(self.raw[0]) + 0.0,
            left_y: sy * dz(self.raw[1]) + 0.0,
            right_x: sx * dz(self.raw[2]) + 0.0,
            right_y: sy * dz(self.raw[3]) + 0.0,
        }
    }

    /// The largest deflection of the sticks that drive in the drive mode (tank: both Y;
    /// steer: left X and right Y), 0..=1.
    pub fn deflection(&self) -> f32 {
        let s = self.sticks();
        match self.map.drive_mode {
            DriveMode::Tank => s.left_y.abs().max(s.right_y.abs()),
            DriveMode::Steer => s.left_x.abs().max(s.right_y.abs()),
        }
    }

    /// The wheel command the sticks ask for (see the module doc); stop while disconnected.
    pub fn manual_command(&self) -> WheelCommand {
        if !self.connected {
            return WheelCommand::STOP;
        }
        let s = self.sticks();
        let m = &self.map;
        let c = |v: f32| v.clamp(-1.0, 1.0) + 0.0;
        match m.drive_mode {
            DriveMode::Tank => WheelCommand::new(
                c(s.left_y * m.throttle_scale),
                c(s.right_y * m.throttle_scale),
            ),
            DriveMode::Steer => {
                let throttle = s.right_y * m.throttle_scale;
                let steering = s.left_x * m.steering_scale;
                WheelCommand::new(c(throttle + steering), c(throttle - steering))
            }
        }
    }

    /// Everything the mode machine needs at `now`.
    pub fn snapshot(&self, now: Duration) -> PadSnapshot {
        PadSnapshot {
            manual: self.manual_command(),
            deflection: if self.connected {
                self.deflection()
            } else {
                0.0
            },
            connected: self.connected,
            stale: self.is_stale(now),
        }
    }
}

// ---------------------------------------------------------------------------------------
// Device layer
// ---------------------------------------------------------------------------------------

/// `ENODEV` on Linux: what reads on an unplugged evdev node return.
const ENODEV: i32 = 19;

fn io_error(path: &Path, e: std::io::Error) -> GamepadError {
    match e.kind() {
        std::io::ErrorKind::PermissionDenied => GamepadError::Permission {
            path: path.to_path_buf(),
        },
        std::io::ErrorKind::NotFound => GamepadError::NotFound {
            path: path.to_path_buf(),
        },
        _ if e.raw_os_error() == Some(ENODEV) => GamepadError::Gone {
            path: path.to_path_buf(),
        },
        _ => GamepadError::Io {
            path: path.to_path_buf(),
            source: e,
        },
    }
}

/// True for a device with joystick/gamepad buttons (`BTN_TRIGGER` ..= `BTN_THUMBR`) and an
/// X axis: gamepads and joysticks, not keyboards, mice or touchpads.
pub fn is_gamepad(dev: &evdev::Device) -> bool {
    let has_buttons = dev.supported_keys().is_some_and(|keys| {
        keys.iter()
            .any(|k| (KeyCode::BTN_TRIGGER.0..=KeyCode::BTN_THUMBR.0).contains(&k.0))
    });
    let has_axes = dev
        .supported_absolute_axes()
        .is_some_and(|a| a.contains(AbsoluteAxisCode::ABS_X));
    has_buttons && has_axes
}

/// The `/dev/input/eventN` nodes, in N order.
fn event_nodes() -> Vec<PathBuf> {
    let mut nodes: Vec<(u32, PathBuf)> = std::fs::read_dir("/dev/input")
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| {
                    let name = e.file_name();
                    let n = name.to_str()?.strip_prefix("event")?.parse::<u32>().ok()?;
                    Some((n, e.path()))
                })
                .collect()
        })
        .unwrap_or_default();
    nodes.sort();
    nodes.into_iter().map(|(_, p)| p).collect()
}

/// Opens the configured gamepad, or for `device = "auto"` the first event device (in
/// `eventN` order) with gamepad buttons. Permission problems are named, with the `input`
/// group.
pub fn find_gamepad(cfg: &GamepadConfig) -> Result<(PathBuf, evdev::Device)> {
    if let Some(path) = cfg.device_path() {
        let dev = evdev::Device::open(&path).map_err(|e| io_error(&path, e))?;
        if !is_gamepad(&dev) {
            tracing::warn!(
                device = %path.display(),
                name = dev.name().unwrap_or("?"),
                "this device has no gamepad buttons or no ABS_X axis; using it anyway as configured"
            );
        }
        return Ok((path, dev));
    }
    let nodes = event_nodes();
    let mut denied = Vec::new();
    for path in &nodes {
        match evdev::Device::open(path) {
            Ok(dev) if is_gamepad(&dev) => {
                tracing::info!(device = %path.display(), name = dev.name().unwrap_or("?"), "gamepad found");
                return Ok((path.clone(), dev));
            }
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => {
                denied.push(path.display().to_string());
            }
            Err(e) => tracing::debug!(device = %path.display(), error = %e, "cannot open"),
        }
    }
    let denied = if denied.is_empty() {
        String::new()
    } else {
        format!(
            "; {} could not be opened ({}): permission denied, add the user to the `input` group (`sudo usermod -aG input $USER`, then log in again)",
            denied.len(),
            denied.join(", ")
        )
    };
    Err(GamepadError::NoneFound {
        scanned: nodes.len(),
        denied,
    })
}

/// Converts one evdev event; `ranges` gives `(min, max)` per absolute axis code. Sync,
/// misc and other events give `None`; an axis without a known range is taken as
/// -32768..=32767.
pub fn convert_event(
    ev: &evdev::InputEvent,
    ranges: &HashMap<AbsoluteAxisCode, (i32, i32)>,
) -> Option<InputEvent> {
    match ev.destructure() {
        EventSummary::AbsoluteAxis(_, code, value) => {
            let (min, max) = ranges.get(&code).copied().unwrap_or((-32768, 32767));
            Some(InputEvent::Axis {
                code,
                value,
                min,
                max,
            })
        }
        EventSummary::Key(_, code, value) => Some(InputEvent::Button {
            code,
            pressed: value != 0,
        }),
        _ => None,
    }
}

/// A blocking reader on one gamepad device.
pub struct GamepadReader {
    path: PathBuf,
    name: String,
    device: evdev::Device,
    ranges: HashMap<AbsoluteAxisCode, (i32, i32)>,
    gone: bool,
}

impl GamepadReader {
    /// [`find_gamepad`], then reads the axis ranges. Warns about mapped axes the device
    /// does not have.
    pub fn open(cfg: &GamepadConfig) -> Result<Self> {
        let map = GamepadMap::from_config(cfg)?;
        let (path, device) = find_gamepad(cfg)?;
        let reader = Self::from_device(path, device)?;
        let a = map.axes;
        for axis in [a.left_x, a.left_y, a.right_x, a.right_y] {
            if !reader.ranges.contains_key(&axis) {
                tracing::warn!(device = %reader.path.display(), name = %reader.name, ?axis,
                    "the gamepad has no such axis: check `gamepad.profile` or `[gamepad.axes]` (evtest lists the axes)");
            }
        }
        Ok(reader)
    }

    pub fn from_device(path: PathBuf, device: evdev::Device) -> Result<Self> {
        let ranges = device
            .get_absinfo()
            .map_err(|e| io_error(&path, e))?
            .map(|(code, info)| (code, (info.minimum(), info.maximum())))
            .collect();
        Ok(Self {
            name: device.name().unwrap_or("unnamed device").to_string(),
            path,
            device,
            ranges,
            gone: false,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The device's name (`Microsoft X-Box 360 pad`, `ShanWan PC/PS3/Android`, ...).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The `(min, max)` of each absolute axis.
    pub fn ranges(&self) -> &HashMap<AbsoluteAxisCode, (i32, i32)> {
        &self.ranges
    }

    /// Axis events for the current stick positions, to start a [`GamepadState`] from the
    /// pad's real state.
    pub fn initial_events(&self) -> Vec<InputEvent> {
        match self.device.get_absinfo() {
            Ok(it) => it
                .map(|(code, info)| InputEvent::Axis {
                    code,
                    value: info.value(),
                    min: info.minimum(),
                    max: info.maximum(),
                })
                .collect(),
            Err(_) => Vec::new(),
        }
    }

    /// Blocks until the device has events, and returns them converted. A vanished device
    /// returns `[Disconnected]` once, then [`GamepadError::Gone`].
    pub fn read_batch(&mut self) -> Result<Vec<InputEvent>> {
        if self.gone {
            return Err(GamepadError::Gone {
                path: self.path.clone(),
            });
        }
        let fetched = match self.device.fetch_events() {
            Ok(events) => Ok(events.collect::<Vec<_>>()),
            Err(e) => Err(e),
        };
        match fetched {
            Ok(events) => Ok(events
                .iter()
                .filter_map(|e| convert_event(e, &self.ranges))
                .collect()),
            Err(e) if e.raw_os_error() == Some(ENODEV) => {
                self.gone = true;
                tracing::warn!(device = %self.path.display(), name = %self.name, "gamepad disconnected");
                Ok(vec![InputEvent::Disconnected])
            }
            Err(e) => Err(io_error(&self.path, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOL: f32 = 1e-6;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= TOL
    }

    fn state(cfg: GamepadConfig) -> GamepadState {
        GamepadState::new(GamepadMap::from_config(&cfg).unwrap())
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// An axis event on a symmetric -100..=100 range, for round numbers.
    fn ax(code: AbsoluteAxisCode, value: i32) -> InputEvent {
        InputEvent::Axis {
            code,
            value,
            min: -100,
            max: 100,
        }
    }

    fn btn(code: KeyCode, pressed: bool) -> InputEvent {
        InputEvent::Button { code, pressed }
    }

    #[test]
    fn normalisation_uses_the_middle_of_the_range() {
        // Xbox: -32768..=32767, middle -0.5, half 32767.5.
        assert_eq!(normalize_axis(-32768, -32768, 32767), -1.0);
        assert_eq!(normalize_axis(32767, -32768, 32767), 1.0);
        assert!(normalize_axis(0, -32768, 32767).abs() < 2e-5);
        // Generic pads: 0..=255, rest at 128 -> (128 - 127.5) / 127.5 = 0.0039.
        assert!(close(normalize_axis(128, 0, 255), 0.5 / 127.5));
        assert_eq!(normalize_axis(0, 0, 255), -1.0);
        assert_eq!(normalize_axis(255, 0, 255), 1.0);
        // Out of range is clamped; a degenerate range gives 0.
        assert_eq!(normalize_axis(400, -100, 100), 1.0);
        assert_eq!(normalize_axis(5, 7, 7), 0.0);
    }

    #[test]
    fn dead_zone_numbers() {
        let dz = 0.08;
        assert_eq!(apply_dead_zone(0.0, dz), 0.0);
        assert_eq!(apply_dead_zone(0.05, dz), 0.0);
        assert_eq!(apply_dead_zone(0.08, dz), 0.0);
        assert_eq!(apply_dead_zone(-0.08, dz), 0.0);
        // (0.09 - 0.08) / 0.92 = 0.0108696: continuous at the edge, no jump to 0.09.
        assert!(
            close(apply_dead_zone(0.09, dz), 0.0108696),
            "{}",
            apply_dead_zone(0.09, dz)
        );
        // (0.5 - 0.08) / 0.92 = 0.4565217
        assert!(close(apply_dead_zone(0.5, dz), 0.4565217));
        assert!(close(apply_dead_zone(-0.5, dz), -0.4565217));
        assert_eq!(apply_dead_zone(1.0, dz), 1.0);
        assert_eq!(apply_dead_zone(-1.0, dz), -1.0);
        assert_eq!(apply_dead_zone(f32::NAN, dz), 0.0);
        // Monotonic and continuous over the whole range.
        let mut prev = -1.0;
        for i in -1000..=1000 {
            let y = apply_dead_zone(i as f32 / 1000.0, dz);
            assert!(y >= prev && y - prev < 0.0011 + 1e-6, "{i}: {prev} -> {y}");
            prev = y;
        }
    }

    #[test]
    fn xbox_and_f710_map() {
        for profile in [Profile::Xbox, Profile::F710] {
            let map = GamepadMap::from_config(&GamepadConfig {
                profile,
                ..GamepadConfig::default()
            })
            .unwrap();
            assert_eq!(
                map.axes,
                StickAxes {
                    left_x: AbsoluteAxisCode::ABS_X,
                    left_y: AbsoluteAxisCode::ABS_Y,
                    right_x: AbsoluteAxisCode::ABS_RX,
                    right_y: AbsoluteAxisCode::ABS_RY,
                }
            );
            let k = |c| map.action_for(ButtonId::Key(c));
            assert_eq!(k(KeyCode::BTN_SOUTH), Some(Action::ToggleAutopilot));
            assert_eq!(k(KeyCode::BTN_EAST), Some(Action::EmergencyStop));
            assert_eq!(k(KeyCode::BTN_NORTH), Some(Action::EraseLast(100)));
            assert_eq!(k(KeyCode::BTN_WEST), Some(Action::ToggleRecording));
            assert_eq!(k(KeyCode::BTN_START), Some(Action::ClearEmergencyStop));
            assert_eq!(k(KeyCode::BTN_TRIGGER_HAPPY3), Some(Action::SpeedGainUp));
            assert_eq!(
                k(KeyCode::BTN_TRIGGER_HAPPY1),
                Some(Action::SteeringGainDown)
            );
            let h = |axis, positive| map.action_for(ButtonId::Hat { axis, positive });
            assert_eq!(h(HAT_Y, false), Some(Action::SpeedGainUp));
            assert_eq!(h(HAT_Y, true), Some(Action::SpeedGainDown));
            assert_eq!(h(HAT_X, true), Some(Action::SteeringGainUp));
            assert_eq!(h(HAT_X, false), Some(Action::SteeringGainDown));
            assert_eq!(k(KeyCode::BTN_TL), None);
        }
    }

    #[test]
    fn generic_map() {
        let map = GamepadMap::from_config(&GamepadConfig {
            profile: Profile::Generic,
            ..GamepadConfig::default()
        })
        .unwrap();
        assert_eq!(map.axes.right_x, AbsoluteAxisCode::ABS_Z);
        assert_eq!(map.axes.right_y, AbsoluteAxisCode::ABS_RZ);
        let k = |c| map.action_for(ButtonId::Key(c));
        assert_eq!(k(KeyCode::BTN_THUMB2), Some(Action::ToggleAutopilot));
        assert_eq!(k(KeyCode::BTN_THUMB), Some(Action::EmergencyStop));
        assert_eq!(k(KeyCode::BTN_TOP), Some(Action::EraseLast(100)));
        assert_eq!(k(KeyCode::BTN_TRIGGER), Some(Action::ToggleRecording));
        assert_eq!(k(KeyCode::BTN_BASE4), Some(Action::ClearEmergencyStop));
        assert_eq!(k(KeyCode::BTN_SOUTH), None);
        assert_eq!(
            map.buttons_for(Action::SpeedGainUp),
            vec![ButtonId::Hat {
                axis: HAT_Y,
                positive: false
            }]
        );
        // A generic pad's right stick at rest (128 of 0..=255) is inside the dead zone.
        let mut s = GamepadState::new(map);
        for code in [AbsoluteAxisCode::ABS_Z, AbsoluteAxisCode::ABS_RZ] {
            s.handle(
                &InputEvent::Axis {
                    code,
                    value: 128,
                    min: 0,
                    max: 255,
                },
                ms(1),
            );
        }
        assert_eq!(s.sticks(), Sticks::default());
        // Right stick fully up (0) drives the right wheel forward at throttle_scale.
        s.handle(
            &InputEvent::Axis {
                code: AbsoluteAxisCode::ABS_RZ,
                value: 0,
                min: 0,
                max: 255,
            },
            ms(2),
        );
        assert_eq!(s.manual_command(), WheelCommand::new(0.0, 0.5));
    }

    #[test]
    fn tank_command_worked_numbers() {
        let mut s = state(GamepadConfig::default());
        // Left stick half up: raw -50 -> -0.5 -> dead zone -0.4565217 -> inverted +0.4565217
        // -> * 0.5 = 0.2282609. Right stick fully down: +100 -> 1 -> -1 -> -0.5.
        s.handle(&ax(AbsoluteAxisCode::ABS_Y, -50), ms(10));
        s.handle(&ax(AbsoluteAxisCode::ABS_RY, 100), ms(11));
        let c = s.manual_command();
        assert!(close(c.left, 0.2282609), "{c:?}");
        assert!(close(c.right, -0.5), "{c:?}");
        assert!(close(s.deflection(), 1.0));
        // X axes do not drive in tank mode.
        s.handle(&ax(AbsoluteAxisCode::ABS_X, 100), ms(12));
        assert_eq!(s.manual_command(), c);
        // Throttle scale 1: full up = 1.
        let mut s = state(GamepadConfig {
            throttle_scale: 1.0,
            ..GamepadConfig::default()
        });
        s.handle(&ax(AbsoluteAxisCode::ABS_Y, -100), ms(1));
        s.handle(&ax(AbsoluteAxisCode::ABS_RY, -100), ms(1));
        assert_eq!(s.manual_command(), WheelCommand::new(1.0, 1.0));
        // Without invert_throttle, up is backwards.
        let mut s = state(GamepadConfig {
            invert_throttle: false,
            ..GamepadConfig::default()
        });
        s.handle(&ax(AbsoluteAxisCode::ABS_Y, -100), ms(1));
        assert_eq!(s.manual_command(), WheelCommand::new(-0.5, 0.0));
    }

    #[test]
    fn steer_command_worked_numbers() {
        let mut s = state(GamepadConfig {
            drive_mode: DriveMode::Steer,
            ..GamepadConfig::default()
        });
        // Left X at 54 -> 0.54 -> (0.54 - 0.08) / 0.92 = 0.5 -> steering 0.5 * 0.5 = 0.25.
        // Right Y fully up -> throttle 1 * 0.5 = 0.5. left = 0.75, right = 0.25.
        s.handle(&ax(AbsoluteAxisCode::ABS_X, 54), ms(1));
        s.handle(&ax(AbsoluteAxisCode::ABS_RY, -100), ms(2));
        let c = s.manual_command();
        assert!(close(c.left, 0.75) && close(c.right, 0.25), "{c:?}");
        // Steering alone spins in place: left 0.25, right -0.25.
        s.handle(&ax(AbsoluteAxisCode::ABS_RY, 0), ms(3));
        let c = s.manual_command();
        assert!(close(c.left, 0.25) && close(c.right, -0.25), "{c:?}");
        // Clamped: throttle 1, steering 1 -> left 2 -> 1, right 0.
        let mut s = state(GamepadConfig {
            drive_mode: DriveMode::Steer,
            throttle_scale: 1.0,
            steering_scale: 1.0,
            ..GamepadConfig::default()
        });
        s.handle(&ax(AbsoluteAxisCode::ABS_X, 100), ms(1));
        s.handle(&ax(AbsoluteAxisCode::ABS_RY, -100), ms(1));
        assert_eq!(s.manual_command(), WheelCommand::new(1.0, 0.0));
        // invert_steering: the same stick turns left.
        let mut s = state(GamepadConfig {
            drive_mode: DriveMode::Steer,
            throttle_scale: 1.0,
            steering_scale: 1.0,
            invert_steering: true,
            ..GamepadConfig::default()
        });
        s.handle(&ax(AbsoluteAxisCode::ABS_X, 100), ms(1));
        s.handle(&ax(AbsoluteAxisCode::ABS_RY, -100), ms(1));
        assert_eq!(s.manual_command(), WheelCommand::new(0.0, 1.0));
        // In steer mode the deflection looks at left X and right Y, not left Y.
        let mut s = state(GamepadConfig {
            drive_mode: DriveMode::Steer,
            ..GamepadConfig::default()
        });
        s.handle(&ax(AbsoluteAxisCode::ABS_Y, 100), ms(1));
        assert_eq!(s.deflection(), 0.0);
        s.handle(&ax(AbsoluteAxisCode::ABS_X, -54), ms(1));
        assert!(close(s.deflection(), 0.5));
    }

    #[test]
    fn a_press_gives_one_action_and_holding_does_not_repeat() {
        let mut s = state(GamepadConfig::default());
        assert_eq!(
            s.handle(&btn(KeyCode::BTN_SOUTH, true), ms(1)),
            Some(Action::ToggleAutopilot)
        );
        // Kernel key repeat (value 2) and a held button: nothing more.
        assert_eq!(s.handle(&btn(KeyCode::BTN_SOUTH, true), ms(2)), None);
        assert_eq!(s.handle(&ax(AbsoluteAxisCode::ABS_X, 30), ms(3)), None);
        assert_eq!(s.handle(&btn(KeyCode::BTN_SOUTH, true), ms(4)), None);
        assert_eq!(s.handle(&btn(KeyCode::BTN_SOUTH, false), ms(5)), None);
        assert_eq!(
            s.handle(&btn(KeyCode::BTN_SOUTH, true), ms(6)),
            Some(Action::ToggleAutopilot)
        );
        // Unbound buttons do nothing; a release without a press is harmless.
        assert_eq!(s.handle(&btn(KeyCode::BTN_TL, true), ms(7)), None);
        assert_eq!(s.handle(&btn(KeyCode::BTN_EAST, false), ms(8)), None);
        // Hat: each new direction is one press; holding it or noise inside is not.
        let hat_y = |v| InputEvent::Axis {
            code: HAT_Y,
            value: v,
            min: -1,
            max: 1,
        };
        assert_eq!(s.handle(&hat_y(-1), ms(9)), Some(Action::SpeedGainUp));
        assert_eq!(s.handle(&hat_y(-1), ms(10)), None);
        assert_eq!(s.handle(&hat_y(1), ms(11)), Some(Action::SpeedGainDown));
        assert_eq!(s.handle(&hat_y(0), ms(12)), None);
        assert_eq!(s.handle(&hat_y(1), ms(13)), Some(Action::SpeedGainDown));
        // After a disconnect the buttons are released: a press after reconnecting counts.
        s.handle(&btn(KeyCode::BTN_EAST, true), ms(14));
        s.handle(&InputEvent::Disconnected, ms(15));
        assert_eq!(
            s.handle(&btn(KeyCode::BTN_EAST, true), ms(16)),
            Some(Action::EmergencyStop)
        );
    }

    #[test]
    fn overrides_replace_the_profile() {
        let cfg = GamepadConfig {
            profile: Profile::Xbox,
            axes: AxisOverrides {
                right_x: Some("ABS_Z".into()),
                right_y: Some("ABS_RZ".into()),
                ..AxisOverrides::default()
            },
            buttons: ButtonOverrides {
                // Swap A and B.
                toggle_autopilot: Some("BTN_EAST".into()),
                emergency_stop: Some("BTN_A".into()),
                erase_last: Some("none".into()),
                speed_gain_up: Some("BTN_TR".into()),
                ..ButtonOverrides::default()
            },
            erase_count: 50,
            ..GamepadConfig::default()
        };
        let map = GamepadMap::from_config(&cfg).unwrap();
        assert_eq!(map.axes.right_y, AbsoluteAxisCode::ABS_RZ);
        assert_eq!(map.axes.left_y, AbsoluteAxisCode::ABS_Y);
        let k = |c| map.action_for(ButtonId::Key(c));
        assert_eq!(k(KeyCode::BTN_EAST), Some(Action::ToggleAutopilot));
        assert_eq!(k(KeyCode::BTN_SOUTH), Some(Action::EmergencyStop));
        assert_eq!(k(KeyCode::BTN_NORTH), None);
        assert!(map.buttons_for(Action::EraseLast(50)).is_empty());
        // The override replaces every default binding of speed_gain_up (hat and button).
        assert_eq!(
            map.buttons_for(Action::SpeedGainUp),
            vec![ButtonId::Key(KeyCode::BTN_TR)]
        );
        let mut s = GamepadState::new(map);
        s.handle(&ax(AbsoluteAxisCode::ABS_RZ, -100), ms(1));
        assert_eq!(s.manual_command(), WheelCommand::new(0.0, 0.5));
        assert_eq!(
            s.handle(&btn(KeyCode::BTN_EAST, true), ms(2)),
            Some(Action::ToggleAutopilot)
        );

        // A hat direction and a moved default.
        let map = GamepadMap::from_config(&GamepadConfig {
            buttons: ButtonOverrides {
                toggle_recording: Some("ABS_HAT0Y-".into()),
                ..ButtonOverrides::default()
            },
            ..GamepadConfig::default()
        })
        .unwrap();
        let up = ButtonId::Hat {
            axis: HAT_Y,
            positive: false,
        };
        assert_eq!(map.action_for(up), Some(Action::ToggleRecording));
        assert_eq!(map.action_for(ButtonId::Key(KeyCode::BTN_WEST)), None);
        assert_eq!(
            map.buttons_for(Action::SpeedGainUp),
            vec![ButtonId::Key(KeyCode::BTN_TRIGGER_HAPPY3)]
        );
    }

    #[test]
    fn bad_overrides_and_ranges_name_the_key() {
        let err = |cfg: GamepadConfig| GamepadMap::from_config(&cfg).unwrap_err().to_string();
        let e = err(GamepadConfig {
            buttons: ButtonOverrides {
                emergency_stop: Some("BTN_NOPE".into()),
                ..ButtonOverrides::default()
            },
            ..GamepadConfig::default()
        });
        assert!(
            e.contains("gamepad.buttons.emergency_stop") && e.contains("BTN_NOPE"),
            "{e}"
        );
        let e = err(GamepadConfig {
            axes: AxisOverrides {
                left_x: Some("BTN_SOUTH".into()),
                ..AxisOverrides::default()
            },
            ..GamepadConfig::default()
        });
        assert!(e.contains("gamepad.axes.left_x"), "{e}");
        // Two overrides on one button.
        let e = err(GamepadConfig {
            buttons: ButtonOverrides {
                emergency_stop: Some("BTN_TL".into()),
                toggle_recording: Some("BTN_TL".into()),
                ..ButtonOverrides::default()
            },
            ..GamepadConfig::default()
        });
        assert!(e.contains("BTN_TL") && e.contains("already bound"), "{e}");
        let e = err(GamepadConfig {
            dead_zone: 0.95,
            ..GamepadConfig::default()
        });
        assert_eq!(
            e,
            "key `gamepad.dead_zone` = 0.95 is out of range: allowed 0 ..< 0.9"
        );
        let e = err(GamepadConfig {
            heartbeat_ms: 10,
            ..GamepadConfig::default()
        });
        assert!(e.contains("gamepad.heartbeat_ms"), "{e}");
        assert!(
            err(GamepadConfig {
                throttle_scale: 1.5,
                ..GamepadConfig::default()
            })
            .contains("gamepad.throttle_scale")
        );
    }

    #[test]
    fn config_from_toml() {
        let cfg: GamepadConfig = toml::from_str(
            "device = \"/dev/input/event7\"\nprofile = \"generic\"\ndrive_mode = \"steer\"\n\
             dead_zone = 0.1\n[buttons]\nemergency_stop = \"BTN_BASE2\"\n",
        )
        .unwrap();
        assert_eq!(cfg.profile, Profile::Generic);
        assert_eq!(cfg.drive_mode, DriveMode::Steer);
        assert_eq!(cfg.device_path(), Some(PathBuf::from("/dev/input/event7")));
        assert_eq!(cfg.heartbeat_ms, 500);
        assert!(cfg.validate().is_ok());
        let d: GamepadConfig = toml::from_str("").unwrap();
        assert_eq!(d, GamepadConfig::default());
        assert_eq!(d.device_path(), None);
        assert!(d.invert_throttle && !d.invert_steering);
        assert_eq!((d.dead_zone, d.throttle_scale), (0.08, 0.5));
        assert!(toml::from_str::<GamepadConfig>("profile = \"ps4\"").is_err());
        assert!(toml::from_str::<GamepadConfig>("deadzone = 0.1").is_err());
    }

    #[test]
    fn heartbeat_and_disconnect() {
        let mut s = state(GamepadConfig::default());
        assert!(s.is_stale(ms(0)), "no event yet");
        s.handle(&ax(AbsoluteAxisCode::ABS_Y, -100), ms(100));
        assert!(!s.is_stale(ms(599)));
        assert!(s.is_stale(ms(600)));
        assert_eq!(s.snapshot(ms(300)).manual, WheelCommand::new(0.5, 0.0));
        s.handle(&InputEvent::Disconnected, ms(700));
        let snap = s.snapshot(ms(701));
        assert!(!snap.connected);
        assert_eq!(snap.manual, WheelCommand::STOP);
        assert_eq!(snap.deflection, 0.0);
        // Sticks were reset: reconnecting does not resume the old command.
        s.handle(&ax(AbsoluteAxisCode::ABS_X, 0), ms(900));
        assert!(s.is_connected());
        assert_eq!(s.manual_command(), WheelCommand::STOP);
        // heartbeat_ms = 0 turns the check off.
        let s = state(GamepadConfig {
            heartbeat_ms: 0,
            ..GamepadConfig::default()
        });
        assert!(!s.is_stale(Duration::from_secs(3600)));
    }

    #[test]
    fn evdev_events_convert() {
        let mut ranges = HashMap::new();
        ranges.insert(AbsoluteAxisCode::ABS_RZ, (0, 255));
        let abs =
            evdev::InputEvent::new(evdev::EventType::ABSOLUTE.0, AbsoluteAxisCode::ABS_RZ.0, 17);
        assert_eq!(
            convert_event(&abs, &ranges),
            Some(InputEvent::Axis {
                code: AbsoluteAxisCode::ABS_RZ,
                value: 17,
                min: 0,
                max: 255
            })
        );
        let key = evdev::InputEvent::new(evdev::EventType::KEY.0, KeyCode::BTN_SOUTH.0, 1);
        assert_eq!(
            convert_event(&key, &ranges),
            Some(InputEvent::Button {
                code: KeyCode::BTN_SOUTH,
                pressed: true
            })
        );
        let repeat = evdev::InputEvent::new(evdev::EventType::KEY.0, KeyCode::BTN_SOUTH.0, 2);
        assert!(matches!(
            convert_event(&repeat, &ranges),
            Some(InputEvent::Button { pressed: true, .. })
        ));
        let up = evdev::InputEvent::new(evdev::EventType::KEY.0, KeyCode::BTN_SOUTH.0, 0);
        assert!(matches!(
            convert_event(&up, &ranges),
            Some(InputEvent::Button { pressed: false, .. })
        ));
        let syn = evdev::InputEvent::new(evdev::EventType::SYNCHRONIZATION.0, 0, 0);
        assert_eq!(convert_event(&syn, &ranges), None);
        // Unknown range: the xpad default.
        let x = evdev::InputEvent::new(evdev::EventType::ABSOLUTE.0, AbsoluteAxisCode::ABS_X.0, 5);
        assert!(matches!(
            convert_event(&x, &ranges),
            Some(InputEvent::Axis {
                min: -32768,
                max: 32767,
                ..
            })
        ));
    }

    #[test]
    fn button_names_parse() {
        assert_eq!(
            ButtonId::parse("BTN_Y"),
            Some(ButtonId::Key(KeyCode::BTN_WEST))
        );
        assert_eq!(
            ButtonId::parse(" BTN_THUMB2 "),
            Some(ButtonId::Key(KeyCode::BTN_THUMB2))
        );
        assert_eq!(
            ButtonId::parse("ABS_HAT0X+"),
            Some(ButtonId::Hat {
                axis: HAT_X,
                positive: true
            })
        );
        assert_eq!(ButtonId::parse("ABS_NOPE-"), None);
        assert_eq!(ButtonId::parse("btn_south"), None);
        assert_eq!(
            ButtonId::Hat {
                axis: HAT_Y,
                positive: false
            }
            .to_string(),
            "ABS_HAT0Y-"
        );
        assert_eq!(ButtonId::Key(KeyCode::BTN_EAST).to_string(), "BTN_EAST");
    }

    #[test]
    fn missing_device_errors_are_named() {
        let cfg = GamepadConfig {
            device: "/nonexistent/event99".into(),
            ..GamepadConfig::default()
        };
        let e = find_gamepad(&cfg)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.contains("/nonexistent/event99") && e.contains("no such device"),
            "{e}"
        );
        let e = io_error(
            Path::new("/dev/input/event3"),
            std::io::Error::from(std::io::ErrorKind::PermissionDenied),
        )
        .to_string();
        assert!(
            e.contains("/dev/input/event3") && e.contains("`input` group"),
            "{e}"
        );
    }
}
