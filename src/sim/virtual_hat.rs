//! A virtual PCA9685 on a virtual I2C bus: the simulator's end of the motor HAT.
//!
//! [`VirtualPca9685`] implements `embedded_hal::i2c::I2c`, so the daemon's own
//! [`MotorHat`](crate::hw::motor_hat::MotorHat) driver drives the simulated robot with exactly
//! the register traffic it would put on a Jetson's `/dev/i2c-1`. This module owns:
//!
//! - the chip's register file and I2C protocol as the datasheet describes them: a register
//!   pointer written as the first byte of a write, auto-increment (MODE1 AI) for multi-byte
//!   writes and reads (past LED15_OFF_H and past PRE_SCALE it rolls over to MODE1; without AI
//!   every byte goes to the same register), PRE_SCALE writable only while asleep (minimum 3),
//!   the ALL_LED registers (write to every channel, read back as zero), the read-only zero
//!   bits of MODE2 and LEDn_ON_H/OFF_H, the sticky EXTCLK bit, the RESTART flag (set when
//!   the chip is put to sleep with a channel running, cleared by writing 1 to it while
//!   awake or by a PWM register write), the LED All Call and sub-addresses when enabled in
//!   MODE1, and the general-call software reset (`0x00`, `0x06`);
//! - the bus faults a real robot sees: nothing answers at any other address
//!   ([`VirtualBusError::NoDevice`], how a wrong `motors.address` shows up), and injected
//!   bus errors for tests ([`VirtualPca9685::fail_next`]);
//! - the decoding of the outputs: each channel's level ([`VirtualPca9685::channel_level`]:
//!   full-off wins, then full-on, else `((OFF - ON) mod 4096) / 4096`; every output low while
//!   the oscillator sleeps; MODE2 INVRT flips the level), and from the levels each motor's
//!   signed duty, in the HAT's sense ([`VirtualPca9685::hat_duties`]) and at the wheels
//!   ([`VirtualPca9685::wheel_duties`]).
//!
//! The handle is cheap to clone: the driver owns one clone as its bus while the simulator
//! keeps another to read the outputs after each control step.

use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use embedded_hal::i2c::{ErrorKind, ErrorType, I2c, NoAcknowledgeSource, Operation};

use crate::hw::{HatLayout, MotorPins};

/// MODE1 register.
const MODE1: u8 = 0x00;
/// MODE2 register.
const MODE2: u8 = 0x01;
/// First sub-address register (SUBADDR1..3 are 0x02..=0x04).
const SUBADDR1: u8 = 0x02;
/// LED All Call address register.
const ALLCALLADR: u8 = 0x05;
/// LED0_ON_L; channel n's four registers start at `LED0_ON_L + 4 n`.
const LED0_ON_L: u8 = 0x06;
/// LED15_OFF_H, the last channel register.
const LED15_OFF_H: u8 = 0x45;
/// ALL_LED_ON_L; ALL_LED_ON_H, ALL_LED_OFF_L and ALL_LED_OFF_H follow.
const ALL_LED_ON_L: u8 = 0xFA;
/// ALL_LED_OFF_H.
const ALL_LED_OFF_H: u8 = 0xFD;
/// PRE_SCALE register.
const PRE_SCALE: u8 = 0xFE;

/// MODE1 bits.
const RESTART: u8 = 0x80;
const EXTCLK: u8 = 0x40;
const AI: u8 = 0x20;
const SLEEP: u8 = 0x10;
const SUB1: u8 = 0x08;
const SUB2: u8 = 0x04;
const SUB3: u8 = 0x02;
const ALLCALL: u8 = 0x01;
/// MODE2: output logic inverted.
const INVRT: u8 = 0x10;
/// The full-on (in ON_H) and full-off (in OFF_H) bit.
const FULL_BIT: u8 = 0x10;

/// The chip's internal oscillator.
const OSC_HZ: f64 = 25_000_000.0;
/// The smallest prescale the hardware accepts.
const MIN_PRESCALE: u8 = 3;
/// The software-reset byte after the general-call address.
const SWRST: u8 = 0x06;
/// The general-call address.
const GENERAL_CALL: u8 = 0x00;

/// Why a transaction on the virtual bus failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum VirtualBusError {
    /// Nothing acknowledged the address (a wrong `motors.address`, or no HAT on the bus).
    #[error("no device acknowledged address {address:#04x}")]
    NoDevice { address: u8 },
    /// A bus error injected with [`VirtualPca9685::fail_next`].
    #[error("injected bus error")]
    Injected,
}

impl embedded_hal::i2c::Error for VirtualBusError {
    fn kind(&self) -> ErrorKind {
        match self {
            VirtualBusError::NoDevice { .. } => {
                ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)
            }
            VirtualBusError::Injected => ErrorKind::Other,
        }
    }
}

/// The chip behind the handle.
#[derive(Debug)]
struct State {
    /// The 7-bit hardware address (set by the board's address pins).
    address: u8,
    /// The register file, indexed by register address.
    regs: [u8; 256],
    /// The control register: where the next data byte goes or comes from.
    pointer: u8,
    /// Transactions still to fail with an injected error.
    fail_next: usize,
    transactions: u64,
    failed: u64,
    bytes_written: u64,
}

/// Who a transaction's address reaches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Target {
    /// The chip, at its own, the All Call or an enabled sub-address.
    Chip,
    /// The general-call address (software reset).
    GeneralCall,
}

impl State {
    fn new(address: u8) -> Self {
        let mut s = Self {
            address,
            regs: [0; 256],
            pointer: 0,
            fail_next: 0,
            transactions: 0,
            failed: 0,
            bytes_written: 0,
        };
        s.power_up();
        s
    }

    /// Power-up register values (datasheet table 4); counters and fault injection are kept.
    fn power_up(&mut self) {
        self.regs = [0; 256];
        self.regs[MODE1 as usize] = SLEEP | ALLCALL; // 0x11
        self.regs[MODE2 as usize] = 0x04;
        self.regs[SUBADDR1 as usize] = 0xE2;
        self.regs[SUBADDR1 as usize + 1] = 0xE4;
        self.regs[SUBADDR1 as usize + 2] = 0xE8;
        self.regs[ALLCALLADR as usize] = 0xE0;
        for ch in 0..16 {
            // LEDn_OFF_H = 0x10: every output fully off.
            self.regs[(LED0_ON_L + 4 * ch + 3) as usize] = FULL_BIT;
        }
        self.regs[PRE_SCALE as usize] = 0x1E;
        self.pointer = 0;
    }

    fn asleep(&self) -> bool {
        self.regs[MODE1 as usize] & SLEEP != 0
    }

    fn auto_increment(&self) -> bool {
        self.regs[MODE1 as usize] & AI != 0
    }

    fn target(&self, address: u8) -> Option<Target> {
        if address == GENERAL_CALL {
            return Some(Target::GeneralCall);
        }
        if address == self.address {
            return Some(Target::Chip);
        }
        let mode1 = self.regs[MODE1 as usize];
        let alternates = [
            (ALLCALL, ALLCALLADR),
            (SUB1, SUBADDR1),
            (SUB2, SUBADDR1 + 1),
            (SUB3, SUBADDR1 + 2),
        ];
        alternates
            .iter()
            .any(|&(bit, reg)| mode1 & bit != 0 && self.regs[reg as usize] >> 1 == address)
            .then_some(Target::Chip)
    }

    /// The pointer after a byte at `p` with auto-increment on.
    fn next_pointer(p: u8) -> u8 {
        match p {
            LED15_OFF_H | PRE_SCALE | 0xFF => MODE1,
            _ => p + 1,
        }
    }

    /// The channel's output duty from its registers alone (ignoring SLEEP and INVRT).
    fn raw_level(&self, ch: u8) -> f32 {
        if ch > 15 {
            return 0.0;
        }
        let base = (LED0_ON_L + 4 * ch) as usize;
        let r = &self.regs[base..base + 4];
        if r[3] & FULL_BIT != 0 {
            return 0.0;
        }
        if r[1] & FULL_BIT != 0 {
            return 1.0;
        }
        let on = u16::from(r[0]) | (u16::from(r[1] & 0x0F) << 8);
        let off = u16::from(r[2]) | (u16::from(r[3] & 0x0F) << 8);
        let ticks = (i32::from(off) - i32::from(on)).rem_euclid(4096);
        ticks as f32 / 4096.0
    }

    /// What the output pin does, 0..=1 of each period.
    fn level(&self, ch: u8) -> f32 {
        if ch > 15 || self.asleep() {
            return 0.0;
        }
        let raw = self.raw_level(ch);
        if self.regs[MODE2 as usize] & INVRT != 0 {
            1.0 - raw
        } else {
            raw
        }
    }

    fn any_channel_running(&self) -> bool {
        (0..16).any(|ch| self.raw_level(ch) > 0.0)
    }

    fn read_reg(&self, reg: u8) -> u8 {
        match reg {
            MODE1..=LED15_OFF_H | PRE_SCALE => self.regs[reg as usize],
            // ALL_LED registers read back as zero; reserved registers and TestMode too.
            _ => 0,
        }
    }

    fn write_reg(&mut self, reg: u8, value: u8) {
        match reg {
            MODE1 => self.write_mode1(value),
            // Bits 7..5 are reserved, read-only zero.
            MODE2 => self.regs[MODE2 as usize] = value & 0x1F,
            0x02..=ALLCALLADR => self.regs[reg as usize] = value,
            LED0_ON_L..=LED15_OFF_H => {
                self.regs[reg as usize] = Self::led_byte(reg - LED0_ON_L, value);
                self.regs[MODE1 as usize] &= !RESTART;
            }
            ALL_LED_ON_L..=ALL_LED_OFF_H => {
                let offset = reg - ALL_LED_ON_L;
                let v = Self::led_byte(offset, value);
                for ch in 0..16 {
                    self.regs[(LED0_ON_L + 4 * ch + offset) as usize] = v;
                }
                self.regs[MODE1 as usize] &= !RESTART;
            }
            // Only writable while the oscillator is off.
            PRE_SCALE if self.asleep() => {
                self.regs[PRE_SCALE as usize] = value.max(MIN_PRESCALE);
            }
            // PRE_SCALE while awake, reserved registers and TestMode: ignored.
            _ => {}
        }
    }

    /// A channel register byte as stored: bits 7..5 of ON_H and OFF_H are read-only zero.
    fn led_byte(offset_in_channel: u8, value: u8) -> u8 {
        if offset_in_channel % 2 == 1 {
            value & 0x1F
        } else {
            value
        }
    }

    fn write_mode1(&mut self, value: u8) {
        let old = self.regs[MODE1 as usize];
        // EXTCLK is sticky: only a power cycle or software reset clears it.
        let mut new = (value & !RESTART) | (old & EXTCLK);
        if old & RESTART != 0 {
            // Writing 1 to RESTART with the oscillator running restarts the channels and
            // clears the flag; writing 0 has no effect.
            let restarts = value & RESTART != 0 && new & SLEEP == 0;
            if !restarts {
                new |= RESTART;
            }
        }
        if old & SLEEP == 0 && new & SLEEP != 0 && self.any_channel_running() {
            new |= RESTART;
        }
        self.regs[MODE1 as usize] = new;
    }

    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), VirtualBusError> {
        if self.fail_next > 0 {
            self.fail_next -= 1;
            self.failed += 1;
            return Err(VirtualBusError::Injected);
        }
        match self.target(address) {
            None => {
                self.failed += 1;
                Err(VirtualBusError::NoDevice { address })
            }
            Some(Target::GeneralCall) => self.general_call(address, operations),
            Some(Target::Chip) => {
                self.chip_transaction(operations);
                Ok(())
            }
        }
    }

    /// The general-call address takes writes only; `0x06` alone is a software reset.
    fn general_call(
        &mut self,
        address: u8,
        operations: &[Operation<'_>],
    ) -> Result<(), VirtualBusError> {
        let mut data = Vec::new();
        for op in operations {
            match op {
                Operation::Write(bytes) => data.extend_from_slice(bytes),
                Operation::Read(_) => {
                    self.failed += 1;
                    return Err(VirtualBusError::NoDevice { address });
                }
            }
        }
        if data == [SWRST] {
            self.power_up();
        }
        self.bytes_written += data.len() as u64;
        self.transactions += 1;
        Ok(())
    }

    /// Adjacent operations of the same kind are one transfer (embedded-hal's contract), so
    /// the register pointer is the first byte after each start of a write.
    fn chip_transaction(&mut self, operations: &mut [Operation<'_>]) {
        let mut in_write = false;
        let mut expect_pointer = true;
        for op in operations.iter_mut() {
            match op {
                Operation::Write(bytes) => {
                    if !in_write {
                        expect_pointer = true;
                    }
                    in_write = true;
                    for &b in bytes.iter() {
                        if expect_pointer {
                            self.pointer = b;
                            expect_pointer = false;
                        } else {
                            let reg = self.pointer;
                            self.write_reg(reg, b);
                            if self.auto_increment() {
                                self.pointer = Self::next_pointer(reg);
                            }
                        }
                    }
                    self.bytes_written += bytes.len() as u64;
                }
                Operation::Read(buf) => {
                    in_write = false;
                    for b in buf.iter_mut() {
                        *b = self.read_reg(self.pointer);
                        if self.auto_increment() {
                            self.pointer = Self::next_pointer(self.pointer);
                        }
                    }
                }
            }
        }
        self.transactions += 1;
    }

    /// One motor's signed duty in the HAT's sense.
    fn motor_duty(&self, pins: MotorPins) -> f32 {
        match pins {
            MotorPins::PwmDir { pwm, in1, in2 } => {
                let a = self.level(in1 as u8) > 0.5;
                let b = self.level(in2 as u8) > 0.5;
                let speed = self.level(pwm as u8);
                match (a, b) {
                    (true, false) => speed,
                    (false, true) => -speed,
                    // Both low: coast; both high: brake. Neither drives the wheel.
                    _ => 0.0,
                }
            }
            MotorPins::DirectPwm { in_a, in_b } => self.level(in_a as u8) - self.level(in_b as u8),
        }
    }
}

/// A virtual PCA9685: a cheap, cloneable handle to one chip's state.
///
/// Give one clone to the driver as its I2C bus and keep another to read the outputs.
#[derive(Debug, Clone)]
pub struct VirtualPca9685 {
    state: Arc<Mutex<State>>,
}

impl VirtualPca9685 {
    /// A chip at a 7-bit `address`, with the power-up register values (asleep, every output
    /// fully off, prescale 0x1E).
    pub fn new(address: u8) -> Self {
        Self {
            state: Arc::new(Mutex::new(State::new(address))),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // The state stays consistent between bytes, so a panic elsewhere cannot corrupt it.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The chip's own 7-bit address.
    pub fn address(&self) -> u8 {
        self.lock().address
    }

    /// Makes the next `n` transactions fail with an injected bus error
    /// ([`ErrorKind::Other`]) before they reach the chip; replaces any count still pending
    /// (`fail_next(0)` cancels).
    pub fn fail_next(&self, n: usize) {
        self.lock().fail_next = n;
    }

    /// A register as a read over the bus returns it (ALL_LED and reserved registers read 0).
    pub fn register(&self, reg: u8) -> u8 {
        self.lock().read_reg(reg)
    }

    /// The PRE_SCALE register.
    pub fn prescale(&self) -> u8 {
        self.lock().regs[PRE_SCALE as usize]
    }

    /// The PWM frequency with the internal 25 MHz oscillator: `25 MHz / (4096 (prescale + 1))`.
    pub fn pwm_hz(&self) -> f32 {
        let prescale = f64::from(self.prescale());
        (OSC_HZ / (4096.0 * (prescale + 1.0))) as f32
    }

    /// Whether MODE1's SLEEP bit is set (oscillator off, every output low).
    pub fn asleep(&self) -> bool {
        self.lock().asleep()
    }

    /// Channel `ch`'s output level, the fraction of each period it is high (0..=1): full-off
    /// wins, then full-on, else `((OFF - ON) mod 4096) / 4096`; 0 while asleep or for a
    /// channel above 15; inverted when MODE2 INVRT is set.
    pub fn channel_level(&self, ch: u8) -> f32 {
        self.lock().level(ch)
    }

    /// Transactions the chip (or the general call) acknowledged and carried out.
    pub fn transactions(&self) -> u64 {
        self.lock().transactions
    }

    /// Transactions that failed: injected errors and addresses nothing answered.
    pub fn failed_transactions(&self) -> u64 {
        self.lock().failed
    }

    /// Bytes written in acknowledged transactions, register pointers included.
    pub fn bytes_written(&self) -> u64 {
        self.lock().bytes_written
    }

    /// Each motor's signed duty (left, right) in -1..=1 in the HAT's own sense (positive =
    /// the HAT's FORWARD). TB6612 wiring ([`MotorPins::PwmDir`]): IN1 high and IN2 low gives
    /// +PWM level, IN2 high and IN1 low gives -PWM level, both low (coast) or both high
    /// (brake) give 0; "high" is a level above 0.5. Direct wiring ([`MotorPins::DirectPwm`]):
    /// level(IN A) - level(IN B).
    pub fn hat_duties(&self, layout: HatLayout) -> (f32, f32) {
        let (left, right) = layout.pins();
        let st = self.lock();
        (st.motor_duty(left), st.motor_duty(right))
    }

    /// The duty reaching each wheel (left, right) in the robot's sense (positive drives the
    /// robot forward): [`Self::hat_duties`] negated where the motor is wired inverted. The
    /// stock NVIDIA JetBot has both motors inverted: its driver sends the HAT's BACKWARD
    /// for a forward command and the wiring turns it back into forward.
    pub fn wheel_duties(
        &self,
        layout: HatLayout,
        invert_left: bool,
        invert_right: bool,
    ) -> (f32, f32) {
        let (l, r) = self.hat_duties(layout);
        (flip(l, invert_left), flip(r, invert_right))
    }
}

/// Negates `x` when `invert` is set, without producing -0.0.
fn flip(x: f32, invert: bool) -> f32 {
    if invert && x != 0.0 { -x } else { x }
}

impl ErrorType for VirtualPca9685 {
    type Error = VirtualBusError;
}

impl I2c for VirtualPca9685 {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        self.lock().transaction(address, operations)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::WheelCommand;
    use crate::hw::MotorError;
    use crate::hw::MotorOutput;
    use crate::hw::motor_hat::{HatSettings, MotorHat};
    use embedded_hal::i2c::Error as _;
    use embedded_hal_mock::eh1::delay::NoopDelay;

    const LAYOUTS: [HatLayout; 3] = [
        HatLayout::Adafruit,
        HatLayout::Waveshare,
        HatLayout::Yahboom,
    ];

    fn on_l(ch: u8) -> u8 {
        LED0_ON_L + 4 * ch
    }

    #[test]
    fn power_up_values() {
        let chip = VirtualPca9685::new(0x60);
        assert_eq!(chip.register(MODE1), 0x11);
        assert_eq!(chip.register(MODE2), 0x04);
        assert_eq!(chip.prescale(), 0x1E);
        assert!(chip.asleep());
        assert_eq!(chip.register(on_l(0) + 3), 0x10);
        assert!((0..16).all(|ch| chip.channel_level(ch) == 0.0));
        assert_eq!(chip.transactions(), 0);
        assert_eq!(chip.bytes_written(), 0);
    }

    #[test]
    fn the_real_driver_drives_each_layout() {
        for layout in LAYOUTS {
            let chip = VirtualPca9685::new(layout.default_address());
            let settings = HatSettings::for_layout(layout);
            let (il, ir) = (settings.left.invert, settings.right.invert);
            let mut hat = MotorHat::init(chip.clone(), settings, &mut NoopDelay).unwrap();
            assert_eq!(chip.prescale(), 3, "{layout:?}");
            assert!((chip.pwm_hz() - 1525.879).abs() < 0.01, "{layout:?}");
            assert!(!chip.asleep(), "{layout:?}");
            assert_eq!(chip.register(MODE1), AI | ALLCALL, "{layout:?}");
            assert_eq!(chip.register(MODE2), 0x04, "{layout:?}");
            assert_eq!(chip.wheel_duties(layout, il, ir), (0.0, 0.0), "{layout:?}");

            let half = 127.0 * 16.0 / 4096.0;
            assert_eq!(half, 0.49609375);
            hat.drive(WheelCommand::new(0.5, 0.5)).unwrap();
            assert_eq!(
                chip.wheel_duties(layout, il, ir),
                (half, half),
                "{layout:?}"
            );
            // The HAT's own sense: the stock JetBot sends BACKWARD to go forward.
            let hat_sign = if il { -1.0 } else { 1.0 };
            assert_eq!(chip.hat_duties(layout).0, hat_sign * half, "{layout:?}");

            hat.drive(WheelCommand::new(-0.5, -0.5)).unwrap();
            assert_eq!(
                chip.wheel_duties(layout, il, ir),
                (-half, -half),
                "{layout:?}"
            );

            hat.drive(WheelCommand::new(1.0, -1.0)).unwrap();
            assert_eq!(
                chip.wheel_duties(layout, il, ir),
                (0.99609375, -0.99609375),
                "{layout:?}"
            );

            hat.drive(WheelCommand::new(0.6, 0.2)).unwrap();
            assert_eq!(
                chip.wheel_duties(layout, il, ir),
                (2448.0 / 4096.0, 816.0 / 4096.0),
                "{layout:?}"
            );

            hat.stop().unwrap();
            assert_eq!(chip.wheel_duties(layout, il, ir), (0.0, 0.0), "{layout:?}");
            assert!((0..16).all(|ch| chip.channel_level(ch) == 0.0));

            hat.drive(WheelCommand::new(0.3, -0.7)).unwrap();
            assert_ne!(chip.wheel_duties(layout, il, ir), (0.0, 0.0), "{layout:?}");
            assert!(hat.destroy().is_some());
            assert_eq!(chip.wheel_duties(layout, il, ir), (0.0, 0.0), "{layout:?}");
            assert!(chip.transactions() > 0);
            assert!(chip.bytes_written() > 2 * chip.transactions());
            assert_eq!(chip.failed_transactions(), 0);
        }
    }

    #[test]
    fn dropping_the_driver_releases_the_motors() {
        let layout = HatLayout::Adafruit;
        let chip = VirtualPca9685::new(0x60);
        let mut hat = MotorHat::init(
            chip.clone(),
            HatSettings::for_layout(layout),
            &mut NoopDelay,
        )
        .unwrap();
        hat.drive(WheelCommand::new(0.8, 0.8)).unwrap();
        assert_ne!(chip.hat_duties(layout), (0.0, 0.0));
        drop(hat);
        assert_eq!(chip.hat_duties(layout), (0.0, 0.0));
    }

    #[test]
    fn a_hat_at_the_wrong_address_is_a_bus_fault() {
        let chip = VirtualPca9685::new(0x60);
        let mut settings = HatSettings::for_layout(HatLayout::Adafruit);
        settings.address = 0x41;
        match MotorHat::init(chip.clone(), settings, &mut NoopDelay) {
            Err(MotorError::Bus {
                address, attempts, ..
            }) => {
                assert_eq!(address, 0x41);
                assert_eq!(attempts, 3);
            }
            Err(e) => panic!("expected a bus error, got {e}"),
            Ok(_) => panic!("expected a bus error"),
        }
        assert_eq!(chip.transactions(), 0);
        // At least the three attempts at the first write (the driver also tries to release
        // the motors as the half-built HAT is dropped).
        assert!(chip.failed_transactions() >= 3);
        assert!(chip.asleep());

        let mut bus = chip.clone();
        let err = bus.write(0x41, &[MODE1, 0x01]).unwrap_err();
        assert_eq!(err, VirtualBusError::NoDevice { address: 0x41 });
        assert_eq!(
            err.kind(),
            ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)
        );
    }

    #[test]
    fn injected_faults_are_retried_then_reported() {
        let layout = HatLayout::Adafruit;
        let chip = VirtualPca9685::new(0x60);
        let mut hat = MotorHat::init(
            chip.clone(),
            HatSettings::for_layout(layout),
            &mut NoopDelay,
        )
        .unwrap();
        chip.fail_next(2);
        hat.drive(WheelCommand::new(0.5, 0.5)).unwrap();
        assert_eq!(
            chip.wheel_duties(layout, true, true),
            (0.49609375, 0.49609375)
        );
        assert_eq!(chip.failed_transactions(), 2);

        chip.fail_next(10);
        let err = hat.drive(WheelCommand::new(-0.5, -0.5)).unwrap_err();
        assert!(matches!(err, MotorError::Bus { attempts: 3, .. }), "{err}");
        assert!(err.to_string().contains("Other"), "{err}");

        // Once the bus recovers the driver rewrites what it could not confirm.
        chip.fail_next(0);
        hat.drive(WheelCommand::new(-0.5, -0.5)).unwrap();
        assert_eq!(
            chip.wheel_duties(layout, true, true),
            (-0.49609375, -0.49609375)
        );

        let mut bus = chip.clone();
        chip.fail_next(1);
        let err = bus.write(0x60, &[MODE1]).unwrap_err();
        assert_eq!(err, VirtualBusError::Injected);
        assert_eq!(err.kind(), ErrorKind::Other);
        bus.write(0x60, &[MODE1]).unwrap();
    }

    #[test]
    fn without_auto_increment_every_byte_goes_to_one_register() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[on_l(0), 0x11, 0x22, 0x33]).unwrap();
        assert_eq!(chip.register(on_l(0)), 0x33);
        assert_eq!(chip.register(on_l(0) + 1), 0x00);
        assert_eq!(chip.register(on_l(0) + 2), 0x00);
        assert_eq!(chip.bytes_written(), 4);
        assert_eq!(chip.transactions(), 1);

        // With AI the same write fills consecutive registers.
        bus.write(0x60, &[MODE1, SLEEP | AI | ALLCALL]).unwrap();
        bus.write(0x60, &[on_l(1), 0x11, 0x02, 0x33]).unwrap();
        assert_eq!(chip.register(on_l(1)), 0x11);
        assert_eq!(chip.register(on_l(1) + 1), 0x02);
        assert_eq!(chip.register(on_l(1) + 2), 0x33);
    }

    #[test]
    fn prescale_is_only_written_while_asleep() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[MODE1, ALLCALL]).unwrap();
        assert!(!chip.asleep());
        bus.write(0x60, &[PRE_SCALE, 0x03]).unwrap();
        assert_eq!(chip.prescale(), 0x1E);
        assert!((chip.pwm_hz() - 25e6 / (4096.0 * 31.0)).abs() < 0.01);

        bus.write(0x60, &[MODE1, SLEEP | ALLCALL]).unwrap();
        bus.write(0x60, &[PRE_SCALE, 0x79]).unwrap();
        assert_eq!(chip.prescale(), 0x79);
        assert!((chip.pwm_hz() - 50.0).abs() < 0.1);
        // The hardware forces at least 3.
        bus.write(0x60, &[PRE_SCALE, 0x01]).unwrap();
        assert_eq!(chip.prescale(), 3);
    }

    #[test]
    fn duty_decoding_wraps_around_the_period() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[MODE1, AI | ALLCALL]).unwrap();
        let (on, off) = (1000u16, 3000u16);
        bus.write(
            0x60,
            &[
                on_l(5),
                on as u8,
                (on >> 8) as u8,
                off as u8,
                (off >> 8) as u8,
            ],
        )
        .unwrap();
        assert_eq!(chip.channel_level(5), 0.48828125);
        let (on, off) = (3000u16, 1000u16);
        bus.write(
            0x60,
            &[
                on_l(5),
                on as u8,
                (on >> 8) as u8,
                off as u8,
                (off >> 8) as u8,
            ],
        )
        .unwrap();
        assert_eq!(chip.channel_level(5), 0.51171875);
        // ON == OFF: never high.
        bus.write(0x60, &[on_l(5), 0x10, 0x02, 0x10, 0x02]).unwrap();
        assert_eq!(chip.channel_level(5), 0.0);
        // Full on, unless full off is set too.
        bus.write(0x60, &[on_l(5), 0x00, 0x10, 0x00, 0x00]).unwrap();
        assert_eq!(chip.channel_level(5), 1.0);
        bus.write(0x60, &[on_l(5) + 3, 0x10]).unwrap();
        assert_eq!(chip.channel_level(5), 0.0);
        assert_eq!(chip.channel_level(16), 0.0);
    }

    #[test]
    fn reads_follow_the_pointer() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        let mut buf = [0u8; 2];
        // Without AI every byte reads the same register.
        bus.write_read(0x60, &[MODE1], &mut buf).unwrap();
        assert_eq!(buf, [0x11, 0x11]);
        bus.write(0x60, &[MODE1, SLEEP | AI | ALLCALL]).unwrap();
        bus.write_read(0x60, &[MODE1], &mut buf).unwrap();
        assert_eq!(buf, [0x31, 0x04]);
        // The pointer persists between transactions.
        bus.write(0x60, &[PRE_SCALE]).unwrap();
        let mut one = [0u8; 1];
        bus.read(0x60, &mut one).unwrap();
        assert_eq!(one, [0x1E]);
        // Past PRE_SCALE the pointer rolls over to MODE1.
        bus.read(0x60, &mut one).unwrap();
        assert_eq!(one, [0x31]);
        // Past LED15_OFF_H too.
        let mut three = [0u8; 3];
        bus.write_read(0x60, &[LED15_OFF_H], &mut three).unwrap();
        assert_eq!(three, [0x10, 0x31, 0x04]);
    }

    #[test]
    fn all_led_registers_write_every_channel_and_read_zero() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[MODE1, AI | ALLCALL]).unwrap();
        bus.write(0x60, &[ALL_LED_ON_L, 0x00, 0x00, 0x00, 0x08])
            .unwrap();
        assert!((0..16).all(|ch| chip.channel_level(ch) == 0.5));
        assert_eq!(chip.register(ALL_LED_OFF_H), 0);
    }

    #[test]
    fn sleep_turns_the_outputs_off_and_flags_a_restart() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[MODE1, AI | ALLCALL]).unwrap();
        bus.write(0x60, &[on_l(2), 0x00, 0x00, 0x00, 0x04]).unwrap();
        assert_eq!(chip.channel_level(2), 0.25);
        bus.write(0x60, &[MODE1, SLEEP | AI | ALLCALL]).unwrap();
        assert_eq!(chip.channel_level(2), 0.0);
        assert_eq!(chip.register(MODE1), RESTART | SLEEP | AI | ALLCALL);
        // Waking without writing RESTART leaves the flag; writing 1 clears it.
        bus.write(0x60, &[MODE1, AI | ALLCALL]).unwrap();
        assert_eq!(chip.register(MODE1), RESTART | AI | ALLCALL);
        assert_eq!(chip.channel_level(2), 0.25);
        bus.write(0x60, &[MODE1, RESTART | AI | ALLCALL]).unwrap();
        assert_eq!(chip.register(MODE1), AI | ALLCALL);
    }

    #[test]
    fn invrt_flips_the_outputs() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[MODE1, AI | ALLCALL]).unwrap();
        bus.write(0x60, &[MODE2, 0xF4 | INVRT]).unwrap();
        assert_eq!(chip.register(MODE2), 0x14);
        assert_eq!(chip.channel_level(0), 1.0);
    }

    #[test]
    fn all_call_and_software_reset() {
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        // LED All Call (0x70) is on at power-up.
        bus.write(0x70, &[MODE1, AI | ALLCALL]).unwrap();
        assert!(!chip.asleep());
        // Sub-address 1 (0x71) only once enabled.
        assert!(bus.write(0x71, &[MODE1, AI]).is_err());
        bus.write(0x70, &[MODE1, AI | SUB1]).unwrap();
        bus.write(0x71, &[MODE1, AI | SUB1 | SLEEP]).unwrap();
        assert!(chip.asleep());
        // All Call is off now.
        assert!(bus.write(0x70, &[MODE1]).is_err());
        // General-call software reset: power-up values again.
        bus.write(0x00, &[SWRST]).unwrap();
        assert_eq!(chip.register(MODE1), 0x11);
        assert!(bus.write(0x71, &[MODE1]).is_err());
    }

    #[test]
    fn wheel_duties_flip_only_inverted_motors() {
        let layout = HatLayout::Waveshare;
        let chip = VirtualPca9685::new(0x60);
        let mut settings = HatSettings::for_layout(layout);
        settings.left.invert = true;
        let mut hat = MotorHat::init(chip.clone(), settings, &mut NoopDelay).unwrap();
        hat.drive(WheelCommand::new(0.5, 0.5)).unwrap();
        assert_eq!(chip.hat_duties(layout), (-0.49609375, 0.49609375));
        assert_eq!(
            chip.wheel_duties(layout, true, false),
            (0.49609375, 0.49609375)
        );
        hat.stop().unwrap();
        let (l, r) = chip.wheel_duties(layout, true, true);
        assert!(l.is_sign_positive() && r.is_sign_positive());
    }

    #[test]
    fn tb6612_brake_and_coast_do_not_drive() {
        let layout = HatLayout::Adafruit;
        let chip = VirtualPca9685::new(0x60);
        let mut bus = chip.clone();
        bus.write(0x60, &[MODE1, AI | ALLCALL]).unwrap();
        // Left: PWM 8 at half, IN1 10 and IN2 9 both fully on (brake).
        bus.write(0x60, &[on_l(8), 0x00, 0x00, 0x00, 0x08]).unwrap();
        bus.write(0x60, &[on_l(9), 0x00, 0x10, 0x00, 0x00]).unwrap();
        bus.write(0x60, &[on_l(10), 0x00, 0x10, 0x00, 0x00])
            .unwrap();
        assert_eq!(chip.hat_duties(layout), (0.0, 0.0));
        // IN2 low: forward at the PWM level.
        bus.write(0x60, &[on_l(9) + 3, 0x10]).unwrap();
        assert_eq!(chip.hat_duties(layout), (0.5, 0.0));
        // Both low: coast.
        bus.write(0x60, &[on_l(10) + 3, 0x10]).unwrap();
        assert_eq!(chip.hat_duties(layout), (0.0, 0.0));
    }
}
