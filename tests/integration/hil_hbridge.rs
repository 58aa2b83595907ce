//! Hardware-in-the-loop tests of the GPIO H-bridge driver (L298N, TB6612FNG, DRV8833):
//! the exact sequence of pin levels and PWM duties for init, forward, reverse, turn, stop,
//! brake and faults, across all pins in the order they are written (a shared log of fake
//! pins), plus the same for one motor on embedded-hal-mock's own pin and PWM mocks.

use std::sync::{Arc, Mutex};

use embedded_hal::digital::{ErrorKind as PinErrorKind, ErrorType as PinErrorType, OutputPin};
use embedded_hal::pwm::{ErrorKind as PwmErrorKind, ErrorType as PwmErrorType, SetDutyCycle};
use embedded_hal_mock::eh1::MockError;
use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction as PinT};
use embedded_hal_mock::eh1::pwm::{Mock as PwmMock, Transaction as PwmT};
use jetpilot::control::WheelCommand;
use jetpilot::hw::MotorOutput;
use jetpilot::hw::hbridge::config::{GpioMotorPins, GpioMotorsConfig, PwmChannel};
use jetpilot::hw::hbridge::{BridgeChip, BridgeMotor, HBridge, MotorWiring, Named, StopMode};
use jetpilot::hw::motor_hat::MotorTrim;

/// Every write to any fake pin, in order: `"L.IN1 1"`, `"R.PWM 400"`, ...
#[derive(Clone, Default)]
struct Log {
    events: Arc<Mutex<Vec<String>>>,
    /// Names whose next writes fail.
    failing: Arc<Mutex<Vec<String>>>,
}

impl Log {
    fn take(&self) -> Vec<String> {
        std::mem::take(&mut *self.events.lock().unwrap())
    }
    fn push(&self, name: &str, value: u32) -> bool {
        if self.failing.lock().unwrap().iter().any(|n| n == name) {
            return false;
        }
        self.events.lock().unwrap().push(format!("{name} {value}"));
        true
    }
}

struct FakePin {
    name: &'static str,
    log: Log,
}

#[derive(Debug)]
struct Broken;
impl embedded_hal::digital::Error for Broken {
    fn kind(&self) -> PinErrorKind {
        PinErrorKind::Other
    }
}
impl embedded_hal::pwm::Error for Broken {
    fn kind(&self) -> PwmErrorKind {
        PwmErrorKind::Other
    }
}

impl PinErrorType for FakePin {
    type Error = Broken;
}
impl OutputPin for FakePin {
    fn set_low(&mut self) -> Result<(), Broken> {
        self.log.push(self.name, 0).then_some(()).ok_or(Broken)
    }
    fn set_high(&mut self) -> Result<(), Broken> {
        self.log.push(self.name, 1).then_some(()).ok_or(Broken)
    }
}

/// A PWM with 1000 steps, so a duty of 0.4 logs as 400.
struct FakePwm {
    name: &'static str,
    log: Log,
}
impl PwmErrorType for FakePwm {
    type Error = Broken;
}
impl SetDutyCycle for FakePwm {
    fn max_duty_cycle(&self) -> u16 {
        1000
    }
    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Broken> {
        self.log
            .push(self.name, u32::from(duty))
            .then_some(())
            .ok_or(Broken)
    }
}

fn pin(log: &Log, name: &'static str) -> Named<FakePin> {
    Named::new(
        FakePin {
            name,
            log: log.clone(),
        },
        name,
    )
}
fn pwm(log: &Log, name: &'static str) -> Named<FakePwm> {
    Named::new(
        FakePwm {
            name,
            log: log.clone(),
        },
        name,
    )
}

fn dir_pwm(log: &Log, side: &str, trim: MotorTrim) -> BridgeMotor<FakePin, FakePwm> {
    let (a, b, p) = if side == "L" {
        ("L.IN1", "L.IN2", "L.PWM")
    } else {
        ("R.IN1", "R.IN2", "R.PWM")
    };
    BridgeMotor {
        wiring: MotorWiring::DirPwm {
            in1: pin(log, a),
            in2: pin(log, b),
            pwm: pwm(log, p),
        },
        trim,
    }
}

fn in_pwm(log: &Log, side: &str) -> BridgeMotor<FakePin, FakePwm> {
    let (a, b) = if side == "L" {
        ("L.IN1", "L.IN2")
    } else {
        ("R.IN1", "R.IN2")
    };
    BridgeMotor {
        wiring: MotorWiring::InPwm {
            in1: pwm(log, a),
            in2: pwm(log, b),
        },
        trim: MotorTrim::default(),
    }
}

fn l298n(log: &Log) -> HBridge<FakePin, FakePwm> {
    HBridge::new(
        BridgeChip::L298n,
        StopMode::Coast,
        dir_pwm(log, "L", MotorTrim::default()),
        dir_pwm(log, "R", MotorTrim::default()),
        None,
        "test L298N".into(),
    )
    .unwrap()
}

fn ev(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

#[test]
fn l298n_init_stops_every_input_pwm_first() {
    let log = Log::default();
    let _bridge = l298n(&log);
    assert_eq!(
        log.take(),
        ev(&[
            "L.PWM 0", "L.IN1 0", "L.IN2 0", // left: speed off, then both direction pins low
            "R.PWM 0", "R.IN1 0", "R.IN2 0",
        ])
    );
}

#[test]
fn l298n_forward_reverse_turn_and_stop() {
    let log = Log::default();
    let mut b = l298n(&log);
    log.take();

    // Forward at 0.4: int(255 * 0.4) = 102 -> 102/255 = 0.4 of 1000 steps. IN2 is already
    // low, so only IN1 rises, then the duty.
    b.drive(WheelCommand::new(0.4, 0.4)).unwrap();
    assert_eq!(
        log.take(),
        ev(&["L.IN1 1", "L.PWM 400", "R.IN1 1", "R.PWM 400"])
    );

    // The same command again writes nothing; a new speed writes only the duty.
    b.drive(WheelCommand::new(0.4, 0.4)).unwrap();
    assert!(log.take().is_empty());
    b.drive(WheelCommand::new(1.0, 0.4)).unwrap();
    assert_eq!(log.take(), ev(&["L.PWM 1000"]));

    // Reverse: the speed goes to 0 before the direction changes; IN1 falls before IN2 rises.
    b.drive(WheelCommand::new(-0.4, 0.4)).unwrap();
    assert_eq!(
        log.take(),
        ev(&["L.PWM 0", "L.IN1 0", "L.IN2 1", "L.PWM 400"])
    );

    // Turn on the spot: left forward, right backward. int(255 * 0.5) = 127 -> 498 of 1000.
    b.drive(WheelCommand::new(0.5, -0.5)).unwrap();
    assert_eq!(
        log.take(),
        ev(&[
            "L.PWM 0",
            "L.IN2 0",
            "L.IN1 1",
            "L.PWM 498", //
            "R.PWM 0",
            "R.IN1 0",
            "R.IN2 1",
            "R.PWM 498",
        ])
    );

    // A stop writes every input, whatever was sent before, PWM first: coast.
    b.stop().unwrap();
    assert_eq!(
        log.take(),
        ev(&[
            "L.PWM 0", "L.IN1 0", "L.IN2 0", //
            "R.PWM 0", "R.IN1 0", "R.IN2 0",
        ])
    );
    b.stop().unwrap();
    assert_eq!(log.take().len(), 6, "a second stop writes everything again");
}

#[test]
fn an_inverted_motor_runs_the_other_way_and_trims_scale_the_duty() {
    let log = Log::default();
    let trim = MotorTrim {
        alpha: 0.5,
        beta: 0.0,
        invert: true,
    };
    let mut b = HBridge::new(
        BridgeChip::L298n,
        StopMode::Coast,
        dir_pwm(&log, "L", trim),
        dir_pwm(&log, "R", MotorTrim::default()),
        None,
        "test".into(),
    )
    .unwrap();
    log.take();
    // Left: int(255 * 0.5 * 0.8) = 102, negated by invert: IN2 high at 400.
    b.drive(WheelCommand::new(0.8, 0.0)).unwrap();
    assert_eq!(log.take(), ev(&["L.IN2 1", "L.PWM 400"]));
}

#[test]
fn tb6612_raises_standby_after_the_stop_and_lowers_it_on_drop() {
    let log = Log::default();
    let b = HBridge::new(
        BridgeChip::Tb6612fng,
        StopMode::Brake,
        dir_pwm(&log, "L", MotorTrim::default()),
        dir_pwm(&log, "R", MotorTrim::default()),
        Some(pin(&log, "STBY")),
        "test TB6612".into(),
    )
    .unwrap();
    // Short brake: IN1 = IN2 = high with PWM 0; then the chip is woken.
    assert_eq!(
        log.take(),
        ev(&[
            "L.PWM 0", "L.IN1 1", "L.IN2 1", //
            "R.PWM 0", "R.IN1 1", "R.IN2 1", //
            "STBY 1",
        ])
    );
    drop(b);
    assert_eq!(
        log.take(),
        ev(&[
            "L.PWM 0", "L.IN1 1", "L.IN2 1", //
            "R.PWM 0", "R.IN1 1", "R.IN2 1", //
            "STBY 0",
        ])
    );
}

#[test]
fn tb6612_leaves_the_brake_by_lowering_the_other_pin_first() {
    let log = Log::default();
    let mut b = HBridge::new(
        BridgeChip::Tb6612fng,
        StopMode::Brake,
        dir_pwm(&log, "L", MotorTrim::default()),
        dir_pwm(&log, "R", MotorTrim::default()),
        Some(pin(&log, "STBY")),
        "test".into(),
    )
    .unwrap();
    log.take();
    b.drive(WheelCommand::new(0.2, 0.0)).unwrap();
    // int(255 * 0.2) = 51 -> 200 of 1000. Right stays braked: nothing written.
    assert_eq!(log.take(), ev(&["L.IN2 0", "L.PWM 200"]));
    b.destroy().unwrap();
    assert_eq!(log.take().last().map(String::as_str), Some("STBY 0"));
}

#[test]
fn drv8833_lowers_one_input_before_raising_the_other() {
    let log = Log::default();
    let mut b = HBridge::new(
        BridgeChip::Drv8833,
        StopMode::Coast,
        in_pwm(&log, "L"),
        in_pwm(&log, "R"),
        None,
        "test DRV8833".into(),
    )
    .unwrap();
    assert_eq!(
        log.take(),
        ev(&["L.IN1 0", "L.IN2 0", "R.IN1 0", "R.IN2 0"])
    );
    b.drive(WheelCommand::new(0.4, -0.4)).unwrap();
    assert_eq!(log.take(), ev(&["L.IN1 400", "R.IN2 400"]));
    b.drive(WheelCommand::new(-0.4, -0.4)).unwrap();
    assert_eq!(log.take(), ev(&["L.IN1 0", "L.IN2 400"]));
    // A stop writes every input, the one that was driving first.
    b.stop().unwrap();
    assert_eq!(
        log.take(),
        ev(&["L.IN2 0", "L.IN1 0", "R.IN2 0", "R.IN1 0"])
    );
}

#[test]
fn the_wrong_wiring_for_the_chip_is_refused_before_any_write() {
    let log = Log::default();
    let e = HBridge::new(
        BridgeChip::Drv8833,
        StopMode::Coast,
        dir_pwm(&log, "L", MotorTrim::default()),
        in_pwm(&log, "R"),
        None,
        "test".into(),
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("drv8833 left motor"), "{e}");
    let e = HBridge::new(
        BridgeChip::L298n,
        StopMode::Coast,
        dir_pwm(&log, "L", MotorTrim::default()),
        dir_pwm(&log, "R", MotorTrim::default()),
        Some(pin(&log, "STBY")),
        "test".into(),
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("no standby pin"), "{e}");
    assert!(log.take().is_empty());
}

#[test]
fn a_failed_write_names_the_pin_and_the_next_stop_writes_everything() {
    let log = Log::default();
    let mut b = l298n(&log);
    b.drive(WheelCommand::new(0.4, 0.4)).unwrap();
    log.take();
    log.failing.lock().unwrap().push("L.PWM".into());
    let e = b.drive(WheelCommand::new(0.6, 0.6)).unwrap_err();
    assert!(e.to_string().contains("H-bridge L.PWM"), "{e}");
    // The stop still reaches the right motor and the left motor's direction pins.
    let e = b.stop().unwrap_err();
    assert!(e.to_string().contains("L.PWM"), "{e}");
    assert_eq!(
        log.take(),
        ev(&["L.IN1 0", "L.IN2 0", "R.PWM 0", "R.IN1 0", "R.IN2 0"]),
        "every other input is still stopped when one write fails"
    );
    // Once the pin works again, a stop writes every input: nothing is assumed.
    log.failing.lock().unwrap().clear();
    b.stop().unwrap();
    assert_eq!(log.take().len(), 6);
}

#[test]
fn a_failed_direction_change_is_retried_in_full() {
    let log = Log::default();
    let mut b = l298n(&log);
    b.drive(WheelCommand::new(0.4, 0.0)).unwrap();
    log.take();
    log.failing.lock().unwrap().push("L.IN2".into());
    assert!(b.drive(WheelCommand::new(-0.4, 0.0)).is_err());
    assert_eq!(log.take(), ev(&["L.PWM 0", "L.IN1 0"]));
    log.failing.lock().unwrap().clear();
    b.drive(WheelCommand::new(-0.4, 0.0)).unwrap();
    // The driver no longer trusts what it last wrote: every left input again.
    assert_eq!(
        log.take(),
        ev(&["L.PWM 0", "L.IN1 0", "L.IN2 1", "L.PWM 400"])
    );
}

/// One motor on embedded-hal-mock's pins and PWM, with clones kept for `done()`.
struct Mocked {
    in1: PinMock,
    in2: PinMock,
    pwm: PwmMock,
}

impl Mocked {
    fn new(in1: &[PinT], in2: &[PinT], pwm: &[PwmT]) -> Self {
        Self {
            in1: PinMock::new(in1),
            in2: PinMock::new(in2),
            pwm: PwmMock::new(pwm),
        }
    }
    fn motor(&self, side: &str) -> BridgeMotor<PinMock, PwmMock> {
        BridgeMotor {
            wiring: MotorWiring::DirPwm {
                in1: Named::new(self.in1.clone(), format!("{side} IN1")),
                in2: Named::new(self.in2.clone(), format!("{side} IN2")),
                pwm: Named::new(self.pwm.clone(), format!("{side} PWM")),
            },
            trim: MotorTrim::default(),
        }
    }
    fn done(mut self) {
        self.in1.done();
        self.in2.done();
        self.pwm.done();
    }
}

#[test]
fn l298n_on_embedded_hal_mock_pins() {
    // Init (stop), forward 0.4 on the left, turn the other way on the right, destroy.
    let (lo, hi) = (PinT::set(State::Low), PinT::set(State::High));
    let left = Mocked::new(
        &[lo.clone(), hi.clone(), lo.clone()],
        &[lo.clone(), lo.clone()],
        &[
            PwmT::max_duty_cycle(255),
            PwmT::set_duty_cycle(0),
            PwmT::set_duty_cycle(102),
            PwmT::set_duty_cycle(0),
        ],
    );
    let right = Mocked::new(
        &[lo.clone(), lo.clone()],
        &[lo.clone(), hi.clone(), lo.clone()],
        &[
            PwmT::max_duty_cycle(255),
            PwmT::set_duty_cycle(0),
            PwmT::set_duty_cycle(102),
            PwmT::set_duty_cycle(0),
        ],
    );
    let mut b = HBridge::new(
        BridgeChip::L298n,
        StopMode::Coast,
        left.motor("left"),
        right.motor("right"),
        None,
        "mock".into(),
    )
    .unwrap();
    b.drive(WheelCommand::new(0.4, -0.4)).unwrap();
    b.destroy().unwrap();
    left.done();
    right.done();
}

#[test]
fn a_pwm_error_from_embedded_hal_mock_reaches_the_caller_with_the_pins_name() {
    let (lo, hi) = (PinT::set(State::Low), PinT::set(State::High));
    let left = Mocked::new(
        // Init low; forward raises IN1; the PWM write fails; the stop lowers IN1 again.
        &[lo.clone(), hi.clone(), lo.clone()],
        &[lo.clone(), lo.clone()],
        &[
            PwmT::max_duty_cycle(100),
            PwmT::set_duty_cycle(0),
            PwmT::set_duty_cycle(40).with_error(MockError::Io(std::io::ErrorKind::BrokenPipe)),
            PwmT::set_duty_cycle(0),
        ],
    );
    let right = Mocked::new(
        &[lo.clone(), lo.clone()],
        &[lo.clone(), lo.clone()],
        &[
            PwmT::max_duty_cycle(100),
            PwmT::set_duty_cycle(0),
            PwmT::set_duty_cycle(0),
        ],
    );
    let mut b = HBridge::new(
        BridgeChip::L298n,
        StopMode::Coast,
        left.motor("left"),
        right.motor("right"),
        None,
        "mock".into(),
    )
    .unwrap();
    let e = b.drive(WheelCommand::new(0.4, 0.0)).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("H-bridge left PWM") && msg.contains("BrokenPipe"),
        "{msg}"
    );
    // The right motor was never reached by the failed drive; the stop covers both.
    b.destroy().unwrap();
    left.done();
    right.done();
}

#[test]
fn the_config_wiring_becomes_the_same_driver() {
    // `assemble` opens exactly the configured lines and channels, named for errors.
    let cfg = GpioMotorsConfig {
        chip: BridgeChip::Tb6612fng,
        standby: Some(200),
        left: GpioMotorPins {
            in1: Some(76),
            in2: Some(51),
            pwm: Some(PwmChannel {
                chip: 0,
                channel: 0,
            }),
            ..GpioMotorPins::default()
        },
        right: GpioMotorPins {
            in1: Some(12),
            in2: Some(77),
            pwm: Some(PwmChannel {
                chip: 0,
                channel: 2,
            }),
            ..GpioMotorPins::default()
        },
        ..GpioMotorsConfig::default()
    };
    let opened = Arc::new(Mutex::new(Vec::new()));
    let log = Log::default();
    let (o1, o2) = (opened.clone(), opened.clone());
    let b = jetpilot::hw::hbridge::assemble(
        &cfg,
        (MotorTrim::default(), MotorTrim::default()),
        cfg.summary(),
        move |line, name| {
            o1.lock().unwrap().push(name.to_string());
            let n: &'static str = Box::leak(format!("line{line}").into_boxed_str());
            Ok(FakePin {
                name: n,
                log: log.clone(),
            })
        },
        move |ch, name| {
            o2.lock().unwrap().push(name.to_string());
            let n: &'static str = Box::leak(format!("{ch}").into_boxed_str());
            Ok(FakePwm {
                name: n,
                log: Log::default(),
            })
        },
    )
    .unwrap();
    assert_eq!(
        *opened.lock().unwrap(),
        vec![
            "left IN1 (line 76 of /dev/gpiochip0)",
            "left IN2 (line 51 of /dev/gpiochip0)",
            "left PWM (pwmchip0/pwm0)",
            "right IN1 (line 12 of /dev/gpiochip0)",
            "right IN2 (line 77 of /dev/gpiochip0)",
            "right PWM (pwmchip0/pwm2)",
            "STBY (line 200 of /dev/gpiochip0)",
        ]
    );
    assert!(b.describe().starts_with("tb6612fng H-bridge"));
}

/// The driver on sysfs PWM over a fake `/sys/class/pwm` tree (channels 0 and 2 of
/// pwmchip0 already exported, as on a Nano after jetson-io) with fake direction pins.
#[test]
fn l298n_on_a_fake_sysfs_pwm_tree() {
    use jetpilot::hw::hbridge::sysfs_pwm::SysfsPwm;
    let root = tempfile::tempdir().unwrap();
    for ch in [0, 2] {
        let dir = root.path().join(format!("pwmchip0/pwm{ch}"));
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["period", "duty_cycle", "enable"] {
            std::fs::write(dir.join(f), "0").unwrap();
        }
    }
    let read = |ch: u32, f: &str| {
        std::fs::read_to_string(root.path().join(format!("pwmchip0/pwm{ch}/{f}"))).unwrap()
    };
    let cfg = GpioMotorsConfig {
        pwm_root: root.path().to_path_buf(),
        pwm_hz: 2000.0,
        left: GpioMotorPins {
            in1: Some(76),
            in2: Some(51),
            pwm: Some(PwmChannel {
                chip: 0,
                channel: 0,
            }),
            ..GpioMotorPins::default()
        },
        right: GpioMotorPins {
            in1: Some(12),
            in2: Some(77),
            pwm: Some(PwmChannel {
                chip: 0,
                channel: 2,
            }),
            ..GpioMotorPins::default()
        },
        ..GpioMotorsConfig::default()
    };
    let log = Log::default();
    let mut b = jetpilot::hw::hbridge::assemble(
        &cfg,
        (MotorTrim::default(), MotorTrim::default()),
        cfg.summary(),
        |line, _| {
            let n: &'static str = Box::leak(format!("line{line}").into_boxed_str());
            Ok(FakePin {
                name: n,
                log: log.clone(),
            })
        },
        |ch, name| {
            SysfsPwm::open(&cfg.pwm_root, ch.chip, ch.channel, cfg.pwm_hz).map_err(|e| {
                jetpilot::hw::MotorError::Gpio {
                    pin: name.into(),
                    reason: e.to_string(),
                }
            })
        },
    )
    .unwrap();
    // 2 kHz: a 500 us period; both outputs enabled at duty 0, direction pins low.
    for ch in [0, 2] {
        assert_eq!(
            (read(ch, "period"), read(ch, "enable")),
            ("500000".into(), "1".into())
        );
        assert_eq!(read(ch, "duty_cycle"), "0");
    }
    assert_eq!(
        log.take(),
        ev(&["line76 0", "line51 0", "line12 0", "line77 0"])
    );
    // Turn: left forward at int(255 * 0.6) = 153 -> 0.6 of 65535 = 39321 -> 300000 ns;
    // right backward at 0.2: 51 -> 13107 -> 100000 ns.
    b.drive(WheelCommand::new(0.6, -0.2)).unwrap();
    assert_eq!(read(0, "duty_cycle"), "300000");
    assert_eq!(read(2, "duty_cycle"), "100000");
    assert_eq!(log.take(), ev(&["line76 1", "line77 1"]));
    b.stop().unwrap();
    assert_eq!(
        (read(0, "duty_cycle"), read(2, "duty_cycle")),
        ("0".into(), "0".into())
    );
    assert_eq!(
        log.take(),
        ev(&["line76 0", "line51 0", "line12 0", "line77 0"])
    );
    b.drive(WheelCommand::new(1.0, 1.0)).unwrap();
    assert_eq!(read(0, "duty_cycle"), "500000");
    // Dropped (the daemon exiting, a panic unwinding): stopped, outputs disabled.
    drop(b);
    for ch in [0, 2] {
        assert_eq!(
            (read(ch, "duty_cycle"), read(ch, "enable")),
            ("0".into(), "0".into())
        );
    }
}

/// A brake that cannot be completed falls back to coasting: with IN1 stuck, an L298N
/// brake must not raise EN to 100 % (IN1 high + EN 100 % is full forward).
#[test]
fn a_failed_brake_coasts_instead_of_raising_anything() {
    let log = Log::default();
    let mut b = HBridge::new(
        BridgeChip::L298n,
        StopMode::Brake,
        dir_pwm(&log, "L", MotorTrim::default()),
        dir_pwm(&log, "R", MotorTrim::default()),
        None,
        "test".into(),
    )
    .unwrap();
    b.drive(WheelCommand::new(0.4, 0.4)).unwrap();
    log.take();
    log.failing.lock().unwrap().push("L.IN1".into());
    assert!(b.stop().is_err());
    let events = log.take();
    assert_eq!(
        events,
        ev(&[
            "L.PWM 0", // brake: speed off, IN1 fails: give up the brake ...
            "L.PWM 0",
            "L.IN2 0", // ... and coast, lowering everything else
            "R.PWM 0",
            "R.IN1 0",
            "R.IN2 0",
            "R.PWM 1000", // the right motor brakes
        ])
    );
    assert!(!events.contains(&"L.PWM 1000".to_string()));
    log.failing.lock().unwrap().clear();
}

/// A DRV8833 braking out of reverse raises the input already driving first, so it never
/// passes through forward.
#[test]
fn drv8833_brakes_out_of_reverse_without_driving_forward() {
    let log = Log::default();
    let mut b = HBridge::new(
        BridgeChip::Drv8833,
        StopMode::Brake,
        in_pwm(&log, "L"),
        in_pwm(&log, "R"),
        None,
        "test".into(),
    )
    .unwrap();
    b.drive(WheelCommand::new(-0.4, 0.4)).unwrap();
    log.take();
    b.stop().unwrap();
    assert_eq!(
        log.take(),
        ev(&[
            "L.IN2 1000",
            "L.IN1 1000", // left was reversing: IN2 first
            "R.IN1 1000",
            "R.IN2 1000", // right was going forward: IN1 first
        ])
    );
}
