//! jetpilot: the runtime for JetBot-class robot cars.
//!
//! The data flow is visible in the module names:
//!
//! ```text
//! camera (FrameSource) -> policy (preprocess + ONNX Runtime) -> control (steering law)
//!     -> hw (MotorOutput: PCA9685 motor HAT over I2C, or a virtual output)
//! ```
//!
//! `drive` runs that pipeline as the daemon (`jetpilot run`) with a watchdog that stops the
//! motors whenever fresh commands stop arriving. `config` holds the typed TOML configuration.
//! `web` serves the daemon's page (video, gain sliders, modes, browser teleop).

pub mod camera;
pub mod clock;
pub mod config;
pub mod control;
pub mod dataset;
pub mod drive;
pub mod fit;
pub mod hw;
pub mod image;
pub mod policy;
pub mod score;
pub mod sim;
#[cfg(feature = "train")]
pub mod train;
pub mod web;
