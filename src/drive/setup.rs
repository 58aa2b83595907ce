//! Building the daemon's parts from a [`Config`]: the frame source, the policy and the
//! motor output. The CLI, the simulator and the integration tests all go through here.

use std::path::Path;
use std::sync::Arc;

use crate::camera::folder::FolderSource;
use crate::camera::{CameraError, FrameSource};
use crate::clock::Clock;
use crate::config::{CameraSource, Config, MotorBackend};
use crate::hw::{LogMotors, MotorError, MotorOutput};
use crate::policy::ort_policy::OrtOptions;
use crate::policy::{OrtPolicy, PolicyError};

/// The configured frame source.
pub fn open_source(
    cfg: &Config,
    clock: Arc<dyn Clock>,
) -> Result<Box<dyn FrameSource>, CameraError> {
    match cfg.camera.source {
        CameraSource::Folder => Ok(Box::new(FolderSource::open(
            &cfg.camera.path,
            cfg.camera.fps,
            cfg.camera.repeat,
            clock,
        )?)),
        #[cfg(feature = "v4l2")]
        CameraSource::V4l2 => Ok(Box::new(crate::camera::v4l2::V4l2Source::open(
            &cfg.camera,
            clock,
        )?)),
        #[cfg(not(feature = "v4l2"))]
        CameraSource::V4l2 => Err(CameraError::Other(
            "camera.source = \"v4l2\" needs a build with the `v4l2` feature".into(),
        )),
        CameraSource::Pipe => Ok(Box::new(crate::camera::pipe::PipeSource::open(
            &cfg.camera,
            clock,
        )?)),
    }
}

/// The configured model on ONNX Runtime; `model` overrides `model.path`.
pub fn load_policy(cfg: &Config, model: Option<&Path>) -> Result<OrtPolicy, PolicyError> {
    let fallback = cfg.model.fallback_contract();
    OrtPolicy::load(
        model.unwrap_or(&cfg.model.path),
        &OrtOptions {
            library: cfg.runtime.library.as_deref(),
            providers: &cfg.runtime.providers,
            gpu: cfg.runtime.gpu(),
            intra_threads: cfg.runtime.intra_threads,
            allow_spinning: cfg.runtime.allow_spinning,
            fallback_contract: &fallback,
        },
    )
}

/// The configured motor output to drive with: [`open_motors`], refused where the law's
/// commands would reach real motors in a form they do not take (`control.mixing = "car"`
/// puts a DonkeyCar's throttle and angle on the channels, which only the simulator's car
/// reads).
pub fn open_motors_to_drive(
    cfg: &Config,
    clock: Arc<dyn Clock>,
) -> Result<Box<dyn MotorOutput>, MotorError> {
    if cfg.control.mixing == crate::control::Mixing::Car && cfg.motors.backend != MotorBackend::Log
    {
        return Err(MotorError::Invalid(
            "control.mixing = \"car\" puts a DonkeyCar's throttle and angle on the motor channels, which only the simulator's car reads: no driver for a steering servo and an ESC exists yet (motors.backend = \"log\" records them)".into(),
        ));
    }
    open_motors(cfg, clock)
}

/// The configured motor output, initialised and stopped (whatever the mixing: `jetpilot
/// stop` must always release the motors).
pub fn open_motors(
    cfg: &Config,
    clock: Arc<dyn Clock>,
) -> Result<Box<dyn MotorOutput>, MotorError> {
    let m = &cfg.motors;
    match m.backend {
        MotorBackend::Log => {
            let mut out = LogMotors::new(clock).with_print(cfg.log.print_commands);
            if let Some(p) = &m.log_path {
                out = out.with_file(p)?;
            }
            Ok(Box::new(out))
        }
        MotorBackend::I2c => open_linux(cfg),
        MotorBackend::Rppal => open_rpi(cfg),
        MotorBackend::Gpio => open_gpio(cfg),
    }
}

#[cfg(feature = "linux-hal")]
fn open_gpio(cfg: &Config) -> Result<Box<dyn MotorOutput>, MotorError> {
    let gpio = cfg.motors.gpio.as_ref().ok_or_else(|| {
        MotorError::Invalid("motors.backend = \"gpio\" needs a [motors.gpio] section".into())
    })?;
    let trims = cfg.motors.trims();
    match gpio.pwm_backend {
        crate::hw::hbridge::PwmBackend::Sysfs => {
            Ok(Box::new(crate::hw::hbridge::open_linux(gpio, trims)?))
        }
        #[cfg(feature = "rpi")]
        crate::hw::hbridge::PwmBackend::Rppal => {
            Ok(Box::new(crate::hw::hbridge::open_rppal(gpio, trims)?))
        }
        #[cfg(not(feature = "rpi"))]
        crate::hw::hbridge::PwmBackend::Rppal => Err(MotorError::Invalid(
            "motors.gpio.pwm_backend = \"rppal\" needs a build with the `rpi` feature (cargo build --features rpi)".into(),
        )),
    }
}

#[cfg(not(feature = "linux-hal"))]
fn open_gpio(_cfg: &Config) -> Result<Box<dyn MotorOutput>, MotorError> {
    Err(MotorError::Invalid(
        "motors.backend = \"gpio\" needs a build with the `linux-hal` feature".into(),
    ))
}

#[cfg(feature = "linux-hal")]
fn open_linux(cfg: &Config) -> Result<Box<dyn MotorOutput>, MotorError> {
    let bus = crate::hw::bus::open_linux(cfg.motors.i2c_bus)?;
    let hat = crate::hw::MotorHat::init(
        bus,
        cfg.motors.hat_settings(),
        &mut crate::hw::bus::StdDelay,
    )?;
    Ok(Box::new(hat))
}

#[cfg(not(feature = "linux-hal"))]
fn open_linux(_cfg: &Config) -> Result<Box<dyn MotorOutput>, MotorError> {
    Err(MotorError::Invalid(
        "motors.backend = \"i2c\" needs a build with the `linux-hal` feature".into(),
    ))
}

#[cfg(feature = "rpi")]
fn open_rpi(cfg: &Config) -> Result<Box<dyn MotorOutput>, MotorError> {
    let bus = crate::hw::bus::open_rpi(cfg.motors.i2c_bus)?;
    let hat = crate::hw::MotorHat::init(
        bus,
        cfg.motors.hat_settings(),
        &mut crate::hw::bus::StdDelay,
    )?;
    Ok(Box::new(hat))
}

#[cfg(not(feature = "rpi"))]
fn open_rpi(_cfg: &Config) -> Result<Box<dyn MotorOutput>, MotorError> {
    Err(MotorError::Invalid(
        "motors.backend = \"rppal\" needs a build with the `rpi` feature (cargo build --features rpi)".into(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::MonotonicClock;

    #[test]
    fn a_cars_mixing_opens_no_real_motors() {
        // The DonkeyCar replay's config on a robot: its throttle and angle would reach a
        // JetBot's wheels as wheel duties, so no real backend opens with it.
        let cfg = Config::parse(
            "[control]\nmixing = \"car\"\n[sim]\nvehicle = \"car\"\n[motors]\nbackend = \"i2c\"\n",
            "car.toml",
        )
        .unwrap();
        let err = open_motors_to_drive(&cfg, Arc::new(MonotonicClock::new()))
            .err()
            .expect("refused");
        assert!(err.to_string().contains("control.mixing"), "{err}");
        // Stopping is never refused for it: the same config gets as far as the bus (which
        // this machine does not have, or a build without the `linux-hal` feature names).
        let stop = open_motors(&cfg, Arc::new(MonotonicClock::new())).err();
        assert!(
            stop.as_ref()
                .is_none_or(|e| !e.to_string().contains("control.mixing")),
            "{stop:?}"
        );
        // The log backend records them.
        let log = Config {
            motors: crate::config::MotorsConfig {
                backend: MotorBackend::Log,
                ..cfg.motors.clone()
            },
            ..cfg
        };
        assert!(open_motors_to_drive(&log, Arc::new(MonotonicClock::new())).is_ok());
    }
}
