//! Opening the I2C bus the motor HAT sits on: linux-embedded-hal's `I2cdev` (default; the
//! Jetson's 40-pin header is bus 1) or rppal on a Raspberry Pi (feature `rpi`). Errors say
//! what to do about them (group membership, bus number).

use std::time::Duration;

use embedded_hal::delay::DelayNs;

#[cfg(any(feature = "linux-hal", feature = "rpi"))]
use super::motors::MotorError;

/// A `DelayNs` on `std::thread::sleep`, for the few waits of chip initialisation.
#[derive(Debug, Default, Clone, Copy)]
pub struct StdDelay;

impl DelayNs for StdDelay {
    fn delay_ns(&mut self, ns: u32) {
        std::thread::sleep(Duration::from_nanos(ns as u64));
    }
}

/// Turns an OS error on opening `/dev/i2c-N` into advice.
pub fn open_advice(path: &str, err: &std::io::Error) -> String {
    match err.kind() {
        std::io::ErrorKind::PermissionDenied => format!(
            "{err}: add this user to the `i2c` group (`sudo usermod -aG i2c $USER`, then log in again) or run as a user that can open {path}"
        ),
        std::io::ErrorKind::NotFound => format!(
            "{err}: no such bus. On a Jetson Nano the header's I2C is bus 1 (/dev/i2c-1); on a Raspberry Pi enable I2C with raspi-config. `ls /dev/i2c-*` lists the buses"
        ),
        _ => err.to_string(),
    }
}

/// Opens `/dev/i2c-<bus>` through linux-embedded-hal.
#[cfg(feature = "linux-hal")]
pub fn open_linux(bus: u8) -> Result<linux_embedded_hal::I2cdev, MotorError> {
    let path = format!("/dev/i2c-{bus}");
    linux_embedded_hal::I2cdev::new(&path).map_err(|e| {
        let io = std::io::Error::from(e);
        MotorError::Open {
            reason: open_advice(&path, &io),
            bus: path,
        }
    })
}

/// Opens I2C bus `bus` through rppal (Raspberry Pi).
#[cfg(feature = "rpi")]
pub fn open_rpi(bus: u8) -> Result<rppal::i2c::I2c, MotorError> {
    rppal::i2c::I2c::with_bus(bus).map_err(|e| MotorError::Open {
        bus: format!("rppal bus {bus}"),
        reason: match e {
            rppal::i2c::Error::Io(io) => open_advice(&format!("/dev/i2c-{bus}"), &io),
            other => other.to_string(),
        },
    })
}
