//! The GPIO H-bridge motor driver: two motors on an L298N, TB6612FNG or DRV8833, written
//! against embedded-hal's `OutputPin` (direction and standby pins) and `SetDutyCycle`
//! (PWM), so the same code drives gpio-cdev lines and sysfs PWM on a robot, the
//! simulator's virtual bridge, and embedded-hal-mock in tests.
//!
//! A command becomes pin writes in two pure steps shared with the motor HAT:
//! [`mapped_value`] (JetBot's `int(255 * (alpha * value + beta))` and `invert`), then
//! [`bridge_state`]. The driver remembers what each input was last set to and writes only
//! what changes, in a safe order: when a motor changes direction its PWM goes to 0 first,
//! and a pin going low is always written before one going high. A stop writes every input
//! whatever was sent before. The motors are stopped on construction, and stopped with the
//! standby pin lowered on [`HBridge::destroy`] and on drop.

use embedded_hal::digital::OutputPin;
use embedded_hal::pwm::SetDutyCycle;

use super::chip::{BridgeChip, BridgeState, StopMode, bridge_state, stopped_state};
use crate::control::WheelCommand;
use crate::hw::motor_hat::{MotorTrim, mapped_value};
use crate::hw::motors::{MotorError, MotorOutput, Result};

/// A pin or PWM channel with the name errors give it, e.g. `left IN1 (line 76 of
/// /dev/gpiochip0)`.
pub struct Named<T> {
    pub pin: T,
    pub name: String,
}

impl<T> Named<T> {
    pub fn new(pin: T, name: impl Into<String>) -> Self {
        Self {
            pin,
            name: name.into(),
        }
    }
}

/// How one motor's bridge inputs reach the board.
pub enum MotorWiring<P, W> {
    /// Two direction pins and an enable PWM (L298N, TB6612FNG).
    DirPwm {
        in1: Named<P>,
        in2: Named<P>,
        pwm: Named<W>,
    },
    /// PWM on both inputs (DRV8833).
    InPwm { in1: Named<W>, in2: Named<W> },
}

/// One motor: its wiring and calibration.
pub struct BridgeMotor<P, W> {
    pub wiring: MotorWiring<P, W>,
    pub trim: MotorTrim,
}

struct Motor<P, W> {
    wiring: MotorWiring<P, W>,
    trim: MotorTrim,
    /// `max_duty_cycle` of each PWM (the enable PWM, or IN1 and IN2's), read once.
    max: [u16; 2],
    /// What the inputs were last set to; `None` forces every input to be written.
    last: Option<BridgeState>,
}

/// Two motors on a GPIO H-bridge.
pub struct HBridge<P: OutputPin, W: SetDutyCycle> {
    chip: BridgeChip,
    stop_mode: StopMode,
    motors: [Motor<P, W>; 2],
    /// TB6612FNG STBY or DRV8833 nSLEEP: high while the driver lives.
    standby: Option<Named<P>>,
    description: String,
    /// Set once [`HBridge::destroy`] has shut it down, so drop does not do it again.
    shut: bool,
}

fn pin_err<E: core::fmt::Debug>(name: &str, e: E) -> MotorError {
    MotorError::Gpio {
        pin: name.to_string(),
        reason: format!("{e:?}"),
    }
}

fn set_level<P: OutputPin>(p: &mut Named<P>, high: bool) -> Result<()> {
    let r = if high {
        p.pin.set_high()
    } else {
        p.pin.set_low()
    };
    r.map_err(|e| pin_err(&p.name, e))
}

fn set_duty<W: SetDutyCycle>(p: &mut Named<W>, max: u16, duty: f32) -> Result<()> {
    let ticks = (duty.clamp(0.0, 1.0) * f32::from(max)).round() as u16;
    p.pin
        .set_duty_cycle(ticks.min(max))
        .map_err(|e| pin_err(&p.name, e))
}

/// The writes of one transition: stop at the first failure, or (for a stop) go on past
/// failures so every other input still reaches its stop level. Keeps the first error.
struct Writes {
    best_effort: bool,
    first: Result<()>,
}

impl Writes {
    /// `None` when the transition must end here.
    fn take(&mut self, r: Result<()>) -> Option<()> {
        if let Err(e) = r {
            if self.first.is_ok() {
                self.first = Err(e);
            }
            if !self.best_effort {
                return None;
            }
        }
        Some(())
    }
}

/// Writes the inputs from `from` to `to`, only what changes (everything when `from` is
/// `None`): when the direction pins change, the PWM goes to 0 first and a pin that falls is
/// written before one that rises; on PWM inputs, the falling duty before the rising one.
///
/// `order` is the state the inputs are believed to be in (for the falling-before-rising
/// order when `from` is `None` because every input must be written).
fn transition<P: OutputPin, W: SetDutyCycle>(
    wiring: &mut MotorWiring<P, W>,
    max: [u16; 2],
    from: Option<BridgeState>,
    order: Option<BridgeState>,
    to: BridgeState,
    w: &mut Writes,
) -> Option<()> {
    match (wiring, to) {
        (
            MotorWiring::DirPwm { in1, in2, pwm },
            BridgeState::DirPwm {
                in1: a,
                in2: b,
                duty,
            },
        ) => {
            let (old_pins, mut duty_now) = match from {
                Some(BridgeState::DirPwm { in1, in2, duty }) => (Some((in1, in2)), Some(duty)),
                _ => (None, None),
            };
            if old_pins != Some((a, b)) {
                if duty_now != Some(0.0) {
                    w.take(set_duty(pwm, max[0], 0.0))?;
                    duty_now = Some(0.0);
                }
                let olds = old_pins.map_or([None, None], |(x, y)| [Some(x), Some(y)]);
                for want_high in [false, true] {
                    for (pin, level, old) in [(&mut *in1, a, olds[0]), (&mut *in2, b, olds[1])] {
                        if level == want_high && old != Some(level) {
                            w.take(set_level(pin, level))?;
                        }
                    }
                }
            }
            if duty_now != Some(duty) {
                w.take(set_duty(pwm, max[0], duty))?;
            }
        }
        (MotorWiring::InPwm { in1, in2 }, BridgeState::InPwm { in1: a, in2: b }) => {
            let old = match from {
                Some(BridgeState::InPwm { in1, in2 }) => Some((in1, in2)),
                _ => None,
            };
            let now = match from.or(order) {
                Some(BridgeState::InPwm { in1, in2 }) => (in1, in2),
                _ => (0.0, 0.0),
            };
            let mut inputs = [
                (&mut *in1, max[0], a, old.map(|o| o.0), a - now.0),
                (&mut *in2, max[1], b, old.map(|o| o.1), b - now.1),
            ];
            // The input whose duty falls (or rises least) first.
            inputs.sort_by(|x, y| x.4.total_cmp(&y.4));
            for (pin, m, duty, old, _) in inputs.iter_mut() {
                if *old != Some(*duty) {
                    w.take(set_duty(pin, *m, *duty))?;
                }
            }
        }
        _ => {
            w.take(Err(MotorError::Invalid(
                "H-bridge: the wiring does not match the chip".into(),
            )))?;
        }
    }
    Some(())
}

impl<P, W> Motor<P, W>
where
    P: OutputPin,
    W: SetDutyCycle,
{
    /// Moves the inputs from what was last written to `to`, writing only what changes.
    fn apply(&mut self, to: BridgeState) -> Result<()> {
        self.write(self.last, to, false)
    }

    /// Writes every input to the stopped state `to`. If a write fails, falls back to
    /// `coast` written best-effort: every input lowered, going on past failures, nothing
    /// raised (a brake that raises an input after a failed write could drive the motor).
    fn force_stop(&mut self, to: BridgeState, coast: BridgeState) -> Result<()> {
        let first = self.write(None, to, false);
        if first.is_err() {
            let _ = self.write(None, coast, true);
        }
        first
    }

    fn write(
        &mut self,
        from: Option<BridgeState>,
        to: BridgeState,
        best_effort: bool,
    ) -> Result<()> {
        let order = self.last;
        // Forget the state first: if a write fails half-way, the next call writes all.
        self.last = None;
        let mut w = Writes {
            best_effort,
            first: Ok(()),
        };
        let _ = transition(&mut self.wiring, self.max, from, order, to, &mut w);
        if w.first.is_ok() {
            self.last = Some(to);
        }
        w.first
    }
}

fn check_wiring<P, W>(chip: BridgeChip, side: &str, w: &MotorWiring<P, W>) -> Result<()> {
    let ok = matches!(
        (chip.has_enable_pwm(), w),
        (true, MotorWiring::DirPwm { .. }) | (false, MotorWiring::InPwm { .. })
    );
    if ok {
        return Ok(());
    }
    Err(MotorError::Invalid(format!(
        "{} {side} motor: {}",
        chip.as_str(),
        if chip.has_enable_pwm() {
            "needs two direction pins (in1, in2) and an enable PWM (pwm)"
        } else {
            "needs a PWM on each input (in1_pwm, in2_pwm)"
        }
    )))
}

impl<P, W> HBridge<P, W>
where
    P: OutputPin,
    W: SetDutyCycle,
{
    /// Takes the pins, stops both motors (every input written) and then raises the
    /// standby pin, if there is one. `description` is what [`MotorOutput::describe`] says.
    pub fn new(
        chip: BridgeChip,
        stop_mode: StopMode,
        left: BridgeMotor<P, W>,
        right: BridgeMotor<P, W>,
        standby: Option<Named<P>>,
        description: String,
    ) -> Result<Self> {
        check_wiring(chip, "left", &left.wiring)?;
        check_wiring(chip, "right", &right.wiring)?;
        if standby.is_some() && chip.standby_pin_name().is_none() {
            return Err(MotorError::Invalid(format!(
                "{} has no standby pin: remove `standby`",
                chip.as_str()
            )));
        }
        let motor = |m: BridgeMotor<P, W>| -> Motor<P, W> {
            let mut wiring = m.wiring;
            let max = match &mut wiring {
                MotorWiring::DirPwm { pwm, .. } => [pwm.pin.max_duty_cycle(), 0],
                MotorWiring::InPwm { in1, in2 } => {
                    [in1.pin.max_duty_cycle(), in2.pin.max_duty_cycle()]
                }
            };
            Motor {
                wiring,
                trim: m.trim,
                max,
                last: None,
            }
        };
        let mut bridge = Self {
            chip,
            stop_mode,
            motors: [motor(left), motor(right)],
            standby,
            description,
            shut: false,
        };
        bridge.stop_all()?;
        if let Some(p) = &mut bridge.standby {
            set_level(p, true)?;
        }
        Ok(bridge)
    }

    /// Stops both motors and lowers the standby pin; an error names the pin that failed.
    pub fn destroy(mut self) -> Result<()> {
        self.shut = true;
        self.shut_down()
    }

    fn shut_down(&mut self) -> Result<()> {
        let stopped = self.stop_all();
        let slept = match &mut self.standby {
            Some(p) => set_level(p, false),
            None => Ok(()),
        };
        stopped.and(slept)
    }

    /// Writes every input of both motors to the stop state. Both motors are tried even if
    /// the first fails; the first error is returned.
    fn stop_all(&mut self) -> Result<()> {
        let to = stopped_state(self.chip, self.stop_mode);
        let coast = stopped_state(self.chip, StopMode::Coast);
        let mut first = Ok(());
        for m in &mut self.motors {
            let r = m.force_stop(to, coast);
            if first.is_ok() {
                first = r;
            }
        }
        first
    }

    pub fn chip(&self) -> BridgeChip {
        self.chip
    }
}

impl<P, W> MotorOutput for HBridge<P, W>
where
    P: OutputPin + Send,
    W: SetDutyCycle + Send,
{
    fn drive(&mut self, cmd: WheelCommand) -> Result<()> {
        for (m, value) in self.motors.iter_mut().zip([cmd.left, cmd.right]) {
            let to = bridge_state(self.chip, mapped_value(value, m.trim), self.stop_mode);
            m.apply(to)?;
        }
        Ok(())
    }

    fn stop(&mut self) -> Result<()> {
        self.stop_all()
    }

    fn describe(&self) -> String {
        self.description.clone()
    }
}

impl<P: OutputPin, W: SetDutyCycle> Drop for HBridge<P, W> {
    fn drop(&mut self) {
        if self.shut {
            return;
        }
        if let Err(e) = self.shut_down() {
            tracing::warn!(error = %e, "H-bridge: could not stop the motors on shutdown");
        }
    }
}
