//! A remote driver (the web page): who holds the controls, their dead-man heartbeat, and
//! their stick command. Pure: times are injected, messages come from the web server over a
//! channel ([`RemoteMsg`]), and [`Teleop`](super::teleop::Teleop) turns the outcome into
//! mode changes.
//!
//! Rules:
//! - Any number of clients watch; **one** holds the controls. A client claims them with
//!   its first control message (drive, mode, gains, record) while nobody holds them; the
//!   messages of the others are refused ([`Outcome::Refused`]) until the holder leaves.
//! - An emergency stop is accepted from every client.
//! - **Dead-man:** the holder sends at least every `heartbeat` (the page: 10 Hz). Silence
//!   for `heartbeat`, or its socket closing, ends its hold at once ([`Outcome::Lost`]); the
//!   daemon then stops the motors (see `Teleop`).
//! - The stick command is `(throttle, steering)` in -1..=1 each, scaled into wheels by
//!   [`RemoteScales`]: `left = t*throttle_scale + s*steering_scale`, `right = t*throttle_scale
//!   - s*steering_scale`, clamped to -1..=1.

use std::time::Duration;

use crate::control::{SteeringGains, WheelCommand};

use super::modes::Mode;

/// A web client's id (unique for the daemon's lifetime).
pub type ClientId = u64;

/// What a web client asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RemoteRequest {
    /// Sticks, -1..=1: throttle forward positive, steering right positive. Also the heartbeat.
    Drive {
        throttle: f32,
        steering: f32,
    },
    /// Keeps the hold without driving (the page while it shows Auto).
    Heartbeat,
    /// Manual, Auto, or Stopped (an emergency stop); Manual from Stopped clears the stop.
    Mode(Mode),
    /// An emergency stop (accepted from any client).
    EmergencyStop,
    Gains(SteeringGains),
    Record(bool),
    /// The socket closed.
    Closed,
}

/// One message from the web server to the daemon.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemoteMsg {
    pub client: ClientId,
    pub request: RemoteRequest,
}

/// How remote sticks become wheel commands.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemoteScales {
    pub throttle_scale: f32,
    pub steering_scale: f32,
}

impl RemoteScales {
    /// The wheels for `(throttle, steering)`, each clamped to -1..=1 first.
    pub fn wheels(&self, throttle: f32, steering: f32) -> WheelCommand {
        let finite = |v: f32| {
            if v.is_finite() {
                v.clamp(-1.0, 1.0)
            } else {
                0.0
            }
        };
        let t = finite(throttle) * self.throttle_scale;
        let s = finite(steering) * self.steering_scale;
        WheelCommand::new(
            (t + s).clamp(-1.0, 1.0) + 0.0,
            (t - s).clamp(-1.0, 1.0) + 0.0,
        )
    }
}

/// What a message did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Outcome {
    /// Accepted; the request is for the daemon to carry out.
    Accepted(RemoteRequest),
    /// Another client holds the controls.
    Refused { holder: ClientId },
    /// The holder left (socket closed) or fell silent: stop.
    Lost { client: ClientId },
    /// Nothing to do (a watcher closed its socket).
    Ignored,
}

/// The remote controls' state.
#[derive(Debug, Clone)]
pub struct RemoteControl {
    heartbeat: Duration,
    scales: RemoteScales,
    holder: Option<ClientId>,
    last_heard: Duration,
    sticks: (f32, f32),
}

impl RemoteControl {
    pub fn new(heartbeat: Duration, scales: RemoteScales) -> Self {
        Self {
            heartbeat,
            scales,
            holder: None,
            last_heard: Duration::ZERO,
            sticks: (0.0, 0.0),
        }
    }

    /// The client holding the controls.
    pub fn holder(&self) -> Option<ClientId> {
        self.holder
    }

    /// One message at `now`.
    pub fn on_message(&mut self, msg: &RemoteMsg, now: Duration) -> Outcome {
        match msg.request {
            RemoteRequest::Closed => {
                if self.holder == Some(msg.client) {
                    self.release();
                    Outcome::Lost { client: msg.client }
                } else {
                    Outcome::Ignored
                }
            }
            RemoteRequest::EmergencyStop => Outcome::Accepted(msg.request),
            req => match self.holder {
                Some(h) if h != msg.client => Outcome::Refused { holder: h },
                _ => {
                    self.holder = Some(msg.client);
                    self.last_heard = now;
                    match req {
                        RemoteRequest::Drive { throttle, steering } => {
                            self.sticks = (throttle, steering)
                        }
                        RemoteRequest::Mode(_) => self.sticks = (0.0, 0.0),
                        _ => {}
                    }
                    Outcome::Accepted(req)
                }
            },
        }
    }

    /// The dead-man check at `now`: the holder's hold ends after `heartbeat` of silence.
    pub fn check(&mut self, now: Duration) -> Option<Outcome> {
        let h = self.holder?;
        if now.saturating_sub(self.last_heard) >= self.heartbeat {
            self.release();
            Some(Outcome::Lost { client: h })
        } else {
            None
        }
    }

    /// The holder's stick command, while someone holds the controls.
    pub fn command(&self) -> Option<WheelCommand> {
        self.holder
            .map(|_| self.scales.wheels(self.sticks.0, self.sticks.1))
    }

    /// The holder's stick deflection, 0..=1 (for a takeover in Auto).
    pub fn deflection(&self) -> f32 {
        if self.holder.is_none() {
            return 0.0;
        }
        let f = |v: f32| if v.is_finite() { v.abs().min(1.0) } else { 0.0 };
        f(self.sticks.0).max(f(self.sticks.1))
    }

    fn release(&mut self) {
        self.holder = None;
        self.sticks = (0.0, 0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCALES: RemoteScales = RemoteScales {
        throttle_scale: 0.5,
        steering_scale: 0.25,
    };

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    fn msg(client: ClientId, request: RemoteRequest) -> RemoteMsg {
        RemoteMsg { client, request }
    }

    fn drive(t: f32, s: f32) -> RemoteRequest {
        RemoteRequest::Drive {
            throttle: t,
            steering: s,
        }
    }

    #[test]
    fn wheels_mix_throttle_and_steering_with_the_scales() {
        // t 0.8 * 0.5 = 0.4, s 0.4 * 0.25 = 0.1: left 0.5, right 0.3.
        let w = SCALES.wheels(0.8, 0.4);
        assert!((w.left - 0.5).abs() < 1e-6 && (w.right - 0.3).abs() < 1e-6);
        // Out of range and non-finite inputs are clamped or zeroed.
        assert_eq!(SCALES.wheels(3.0, 0.0), WheelCommand::new(0.5, 0.5));
        assert_eq!(SCALES.wheels(f32::NAN, f32::INFINITY), WheelCommand::STOP);
        let full = RemoteScales {
            throttle_scale: 1.0,
            steering_scale: 1.0,
        };
        assert_eq!(full.wheels(1.0, 1.0), WheelCommand::new(1.0, 0.0));
    }

    #[test]
    fn the_first_controller_holds_and_others_are_refused_until_it_leaves() {
        let mut r = RemoteControl::new(ms(500), SCALES);
        assert_eq!(r.command(), None);
        assert_eq!(
            r.on_message(&msg(1, drive(1.0, 0.0)), ms(0)),
            Outcome::Accepted(drive(1.0, 0.0))
        );
        assert_eq!(r.holder(), Some(1));
        assert_eq!(r.command(), Some(WheelCommand::new(0.5, 0.5)));
        assert_eq!(
            r.on_message(&msg(2, drive(0.0, 1.0)), ms(100)),
            Outcome::Refused { holder: 1 }
        );
        // A watcher closing changes nothing; anyone may press the emergency stop.
        assert_eq!(
            r.on_message(&msg(2, RemoteRequest::Closed), ms(150)),
            Outcome::Ignored
        );
        assert_eq!(
            r.on_message(&msg(3, RemoteRequest::EmergencyStop), ms(160)),
            Outcome::Accepted(RemoteRequest::EmergencyStop)
        );
        assert_eq!(r.holder(), Some(1));
        // The holder's socket closes: lost at once, and client 2 may take over.
        assert_eq!(
            r.on_message(&msg(1, RemoteRequest::Closed), ms(200)),
            Outcome::Lost { client: 1 }
        );
        assert_eq!(r.command(), None);
        assert_eq!(
            r.on_message(&msg(2, RemoteRequest::Heartbeat), ms(210)),
            Outcome::Accepted(RemoteRequest::Heartbeat)
        );
        assert_eq!(r.holder(), Some(2));
        // A fresh holder starts from centred sticks.
        assert_eq!(r.command(), Some(WheelCommand::STOP));
    }

    #[test]
    fn silence_for_the_heartbeat_period_ends_the_hold() {
        let mut r = RemoteControl::new(ms(500), SCALES);
        r.on_message(&msg(7, drive(0.6, -0.2)), ms(1000));
        assert!((r.deflection() - 0.6).abs() < 1e-6);
        assert_eq!(r.check(ms(1499)), None);
        r.on_message(&msg(7, RemoteRequest::Heartbeat), ms(1400));
        assert_eq!(r.check(ms(1899)), None);
        assert_eq!(r.check(ms(1900)), Some(Outcome::Lost { client: 7 }));
        assert_eq!(r.check(ms(2000)), None, "reported once");
        assert_eq!(r.holder(), None);
        assert_eq!(r.deflection(), 0.0);
    }

    #[test]
    fn a_mode_request_centres_the_sticks() {
        let mut r = RemoteControl::new(ms(500), SCALES);
        r.on_message(&msg(1, drive(1.0, 1.0)), ms(0));
        r.on_message(&msg(1, RemoteRequest::Mode(Mode::Auto)), ms(10));
        assert_eq!(r.command(), Some(WheelCommand::STOP));
    }
}
