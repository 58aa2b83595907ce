//! Hardware seams and their drivers: motor outputs (PCA9685 motor HATs over embedded-hal
//! I2C, GPIO H-bridges in [`hbridge`], or a virtual output that records commands) and I2C
//! bus backends.
//!
//! # Troubleshooting
//! - `Permission denied` on `/dev/i2c-1`: add the user to the `i2c` group
//!   (`sudo usermod -aG i2c $USER`, then log in again).
//! - `No such file or directory`: the bus number is wrong or I2C is disabled. On a Jetson
//!   Nano the 40-pin header's I2C is bus 1 (`/dev/i2c-1`); on a Raspberry Pi enable it with
//!   `raspi-config`. `i2cdetect -y -r 1` should show the HAT at 0x60 (Adafruit/Waveshare)
//!   or 0x40 (Yahboom).
//! - Remote I/O error (`EREMOTEIO`): nothing answers at that address: check the HAT's
//!   address jumpers and the `motors.address` key.

pub mod bus;
pub mod buzzer;
pub mod gamepad;
pub mod hbridge;
pub mod layout;
pub mod motor_hat;
pub mod motors;
pub mod oled;

pub use layout::{HatLayout, MotorPins};
pub use motor_hat::MotorHat;
pub use motors::{LogMotors, MotorError, MotorOutput};
