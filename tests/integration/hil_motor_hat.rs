//! Hardware-in-the-loop tests of the motor HAT driver on a mocked I2C bus
//! (embedded-hal-mock): the exact register bytes for init, forward, reverse, turn and stop
//! on each layout, and the retry/fault behaviour on bus errors.
//!
//! The register map below is this test's own copy (PCA9685 datasheet), so a wrong constant
//! in `src` is caught here.

use embedded_hal::i2c::ErrorKind;
use embedded_hal_mock::eh1::delay::NoopDelay;
use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};
use jetpilot::control::WheelCommand;
use jetpilot::hw::motor_hat::{HatSettings, MotorHat};
use jetpilot::hw::{HatLayout, MotorError, MotorOutput};

const MODE1: u8 = 0x00;
const MODE2: u8 = 0x01;
const PRESCALE: u8 = 0xFE;
/// MODE1 bits.
const SLEEP: u8 = 0x10;
const ALLCALL: u8 = 0x01;
const AUTO_INC: u8 = 0x20;
/// MODE2: totem-pole outputs.
const OUTDRV: u8 = 0x04;

/// LEDn_ON_L of channel n; OFF_L is two registers on.
fn on_l(ch: u8) -> u8 {
    0x06 + 4 * ch
}
fn off_l(ch: u8) -> u8 {
    on_l(ch) + 2
}

/// A channel forced low: the full-off bit (OFF_H bit 4).
fn full_off(addr: u8, ch: u8) -> Vec<T> {
    vec![T::write(addr, vec![off_l(ch), 0x00, 0x10])]
}
/// A channel forced high: clear full-off, then set the full-on bit (ON_H bit 4).
fn full_on(addr: u8, ch: u8) -> Vec<T> {
    vec![
        T::write(addr, vec![off_l(ch), 0x00, 0x00]),
        T::write(addr, vec![on_l(ch), 0x00, 0x10]),
    ]
}
/// ON = 0, OFF = duty.
fn duty(addr: u8, ch: u8, d: u16) -> Vec<T> {
    vec![T::write(
        addr,
        vec![on_l(ch), 0x00, 0x00, (d & 0xFF) as u8, (d >> 8) as u8],
    )]
}

/// Sleep, totem-pole, prescale 3 (1600 Hz), wake.
fn chip_init(addr: u8) -> Vec<T> {
    vec![
        T::write(addr, vec![MODE1, SLEEP | ALLCALL]),
        T::write(addr, vec![MODE2, OUTDRV]),
        T::write(addr, vec![PRESCALE, 0x03]),
        T::write(addr, vec![MODE1, ALLCALL]),
    ]
}

/// Every channel in `chans` forced low, in order.
fn all_off(addr: u8, chans: &[u8]) -> Vec<T> {
    chans.iter().flat_map(|&c| full_off(addr, c)).collect()
}

/// Init, then the first channel write turns auto-increment on, then every motor channel off.
fn init_then_release(addr: u8, chans: &[u8]) -> Vec<T> {
    let mut t = chip_init(addr);
    t.push(T::write(addr, vec![MODE1, ALLCALL | AUTO_INC]));
    t.extend(all_off(addr, chans));
    t
}

/// Runs `commands` on a fresh HAT, then destroys it; the mock checks every byte.
fn check(layout: HatLayout, commands: &[WheelCommand], expected: Vec<T>) {
    let mut bus = Mock::new(&expected);
    let mut hat =
        MotorHat::init(bus.clone(), HatSettings::for_layout(layout), &mut NoopDelay).expect("init");
    for &c in commands {
        hat.drive(c).expect("drive");
    }
    let _ = hat.destroy();
    bus.done();
}

// Adafruit (NVIDIA JetBot): 0x60; left PWM 8, IN1 10, IN2 9; right PWM 13, IN1 11, IN2 12.
// Stock JetBot wiring: both motors inverted, so "forward" is the HAT's BACKWARD (IN2 high).
const ADA: u8 = 0x60;
const ADA_ORDER: [u8; 6] = [8, 10, 9, 13, 11, 12];

#[test]
fn adafruit_init_bytes_are_literal() {
    // The same sequence spelled out byte for byte, as a logic analyser would show it.
    let expected = vec![
        T::write(0x60, vec![0x00, 0x11]),
        T::write(0x60, vec![0x01, 0x04]),
        T::write(0x60, vec![0xFE, 0x03]),
        T::write(0x60, vec![0x00, 0x01]),
        T::write(0x60, vec![0x00, 0x21]),
        T::write(0x60, vec![0x28, 0x00, 0x10]),
        T::write(0x60, vec![0x30, 0x00, 0x10]),
        T::write(0x60, vec![0x2C, 0x00, 0x10]),
        T::write(0x60, vec![0x3C, 0x00, 0x10]),
        T::write(0x60, vec![0x34, 0x00, 0x10]),
        T::write(0x60, vec![0x38, 0x00, 0x10]),
        // destroy(): release again, whatever was written before
        T::write(0x60, vec![0x28, 0x00, 0x10]),
        T::write(0x60, vec![0x30, 0x00, 0x10]),
        T::write(0x60, vec![0x2C, 0x00, 0x10]),
        T::write(0x60, vec![0x3C, 0x00, 0x10]),
        T::write(0x60, vec![0x34, 0x00, 0x10]),
        T::write(0x60, vec![0x38, 0x00, 0x10]),
    ];
    check(HatLayout::Adafruit, &[], expected);
}

#[test]
fn adafruit_forward_reverse_turn_stop() {
    let mut t = init_then_release(ADA, &ADA_ORDER);
    // forward 0.5: int(255 * 0.5) = 127 -> inverted -> HAT backward, duty 127 * 16 = 2032.
    // IN1 is already low (cached), so only PWM and IN2 are written.
    t.extend(duty(ADA, 8, 2032));
    t.extend(full_on(ADA, 9));
    t.extend(duty(ADA, 13, 2032));
    t.extend(full_on(ADA, 12));
    // reverse 0.5: the same duty (cached), IN2 lowered before IN1 is raised.
    t.extend(full_off(ADA, 9));
    t.extend(full_on(ADA, 10));
    t.extend(full_off(ADA, 12));
    t.extend(full_on(ADA, 11));
    // turn right: left 0.6 -> 153 -> 2448; right 0.2 -> 51 -> 816; both forward again.
    t.extend(duty(ADA, 8, 2448));
    t.extend(full_off(ADA, 10));
    t.extend(full_on(ADA, 9));
    t.extend(duty(ADA, 13, 816));
    t.extend(full_off(ADA, 11));
    t.extend(full_on(ADA, 12));
    // stop: every motor channel low, written even where the cache says it already is.
    t.extend(all_off(ADA, &ADA_ORDER));
    // destroy(): released once more.
    t.extend(all_off(ADA, &ADA_ORDER));
    let mut bus = Mock::new(&t);
    let mut hat = MotorHat::init(
        bus.clone(),
        HatSettings::for_layout(HatLayout::Adafruit),
        &mut NoopDelay,
    )
    .unwrap();
    hat.drive(WheelCommand::new(0.5, 0.5)).unwrap();
    hat.drive(WheelCommand::new(-0.5, -0.5)).unwrap();
    hat.drive(WheelCommand::new(0.6, 0.2)).unwrap();
    hat.stop().unwrap();
    let _ = hat.destroy();
    bus.done();
}

#[test]
fn adafruit_zero_command_releases_the_motor() {
    let mut t = init_then_release(ADA, &ADA_ORDER);
    t.extend(duty(ADA, 8, 2032));
    t.extend(full_on(ADA, 9));
    // right wheel 0: nothing to write, it is released already.
    // then left 0 too: PWM and IN2 go low (IN1 is low already).
    t.extend(full_off(ADA, 8));
    t.extend(full_off(ADA, 9));
    t.extend(all_off(ADA, &ADA_ORDER));
    check(
        HatLayout::Adafruit,
        &[WheelCommand::new(0.5, 0.0), WheelCommand::STOP],
        t,
    );
}

// Waveshare: 0x60, duty straight on the bridge inputs; left IN A 1 / IN B 0, right 2 / 3.
const WS: u8 = 0x60;
const WS_ORDER: [u8; 4] = [1, 0, 2, 3];

#[test]
fn waveshare_forward_reverse_turn_stop() {
    let mut t = init_then_release(WS, &WS_ORDER);
    // forward 0.5 -> 127 -> duty 2032 on IN A (IN B already low)
    t.extend(duty(WS, 1, 2032));
    t.extend(duty(WS, 2, 2032));
    // reverse 0.5: IN A low first, then the duty on IN B
    t.extend(full_off(WS, 1));
    t.extend(duty(WS, 0, 2032));
    t.extend(full_off(WS, 2));
    t.extend(duty(WS, 3, 2032));
    // turn: left 0.6 forward (2448), right 0.2 forward (816)
    t.extend(full_off(WS, 0));
    t.extend(duty(WS, 1, 2448));
    t.extend(full_off(WS, 3));
    t.extend(duty(WS, 2, 816));
    t.extend(all_off(WS, &WS_ORDER));
    check(
        HatLayout::Waveshare,
        &[
            WheelCommand::new(0.5, 0.5),
            WheelCommand::new(-0.5, -0.5),
            WheelCommand::new(0.6, 0.2),
        ],
        t,
    );
}

// Yahboom: 0x40; left IN A 10 / IN B 11, right IN A 8 / IN B 9.
const YB: u8 = 0x40;
const YB_ORDER: [u8; 4] = [10, 11, 8, 9];

#[test]
fn yahboom_forward_reverse_turn_stop() {
    let mut t = init_then_release(YB, &YB_ORDER);
    t.extend(duty(YB, 10, 2032));
    t.extend(duty(YB, 8, 2032));
    t.extend(full_off(YB, 10));
    t.extend(duty(YB, 11, 2032));
    t.extend(full_off(YB, 8));
    t.extend(duty(YB, 9, 2032));
    // turn in place: left forward full (255 -> 4080), right backward full
    t.extend(full_off(YB, 11));
    t.extend(duty(YB, 10, 4080));
    t.extend(duty(YB, 9, 4080));
    t.extend(all_off(YB, &YB_ORDER));
    check(
        HatLayout::Yahboom,
        &[
            WheelCommand::new(0.5, 0.5),
            WheelCommand::new(-0.5, -0.5),
            WheelCommand::new(1.0, -1.0),
        ],
        t,
    );
}

#[test]
fn trims_and_address_override_change_the_bytes() {
    let mut settings = HatSettings::for_layout(HatLayout::Waveshare);
    settings.address = 0x61;
    settings.left.alpha = 0.5; // 255 * 0.5 * 0.5 = 63.75 -> 63 -> 1008
    settings.right.invert = true;
    let mut t = init_then_release(0x61, &WS_ORDER);
    t.extend(duty(0x61, 1, 1008));
    t.extend(duty(0x61, 3, 2032)); // inverted: forward command drives IN B
    t.extend(all_off(0x61, &WS_ORDER));
    let mut bus = Mock::new(&t);
    let mut hat = MotorHat::init(bus.clone(), settings, &mut NoopDelay).unwrap();
    hat.drive(WheelCommand::new(0.5, 0.5)).unwrap();
    let _ = hat.destroy();
    bus.done();
}

#[test]
fn a_failed_write_is_retried_then_succeeds() {
    let mut t = init_then_release(WS, &WS_ORDER);
    t.push(T::write(WS, vec![on_l(1), 0, 0, 0xF0, 0x07]).with_error(ErrorKind::Other));
    t.extend(duty(WS, 1, 2032)); // the retry
    t.extend(duty(WS, 2, 2032));
    t.extend(all_off(WS, &WS_ORDER));
    check(HatLayout::Waveshare, &[WheelCommand::new(0.5, 0.5)], t);
}

#[test]
fn persistent_bus_errors_become_a_fault_naming_the_address() {
    let mut settings = HatSettings::for_layout(HatLayout::Waveshare);
    settings.retries = 2;
    let mut t = init_then_release(WS, &WS_ORDER);
    for _ in 0..3 {
        t.push(T::write(WS, vec![on_l(1), 0, 0, 0xF0, 0x07]).with_error(ErrorKind::Other));
    }
    // The daemon's stop after the fault: written in full (the failed channel is unknown now).
    t.extend(all_off(WS, &WS_ORDER));
    t.extend(all_off(WS, &WS_ORDER)); // destroy()
    let mut bus = Mock::new(&t);
    let mut hat = MotorHat::init(bus.clone(), settings, &mut NoopDelay).unwrap();
    let err = hat.drive(WheelCommand::new(0.5, 0.5)).unwrap_err();
    assert!(
        matches!(
            err,
            MotorError::Bus {
                address: 0x60,
                attempts: 3,
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("0x60"), "{err}");
    hat.stop().unwrap();
    let _ = hat.destroy();
    bus.done();
}

#[test]
fn dropping_the_driver_releases_the_motors() {
    let mut t = init_then_release(YB, &YB_ORDER);
    t.extend(duty(YB, 10, 2032));
    t.extend(duty(YB, 8, 2032));
    t.extend(all_off(YB, &YB_ORDER));
    let mut bus = Mock::new(&t);
    {
        let mut hat = MotorHat::init(
            bus.clone(),
            HatSettings::for_layout(HatLayout::Yahboom),
            &mut NoopDelay,
        )
        .unwrap();
        hat.drive(WheelCommand::new(0.5, 0.5)).unwrap();
    } // dropped here, e.g. while a panic unwinds
    bus.done();
}
