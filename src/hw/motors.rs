//! The motor-output seam. [`MotorOutput`] is what the daemon drives: the PCA9685 motor HAT
//! on a robot ([`super::MotorHat`]), the simulator's virtual HAT, or [`LogMotors`], a
//! virtual output that records every command (the `log` backend).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::control::WheelCommand;

/// Errors from a motor output.
#[derive(Debug, thiserror::Error)]
pub enum MotorError {
    #[error("I2C bus {bus}: cannot open: {reason}")]
    Open { bus: String, reason: String },
    #[error("motor HAT at {address:#04x}: I2C write failed after {attempts} attempts: {reason}")]
    Bus {
        address: u8,
        attempts: u32,
        reason: String,
    },
    #[error("motors: invalid setting: {0}")]
    Invalid(String),
    #[error("H-bridge {pin}: {reason}")]
    Gpio { pin: String, reason: String },
    #[error("motor command log {path}: {source}")]
    Log {
        path: String,
        #[source]
        source: std::io::Error,
    },
}

pub type Result<T> = std::result::Result<T, MotorError>;

/// Something that turns wheel commands into motion.
///
/// Implementations must make [`MotorOutput::stop`] safe to call at any time and repeatedly,
/// and must stop the motors when dropped.
pub trait MotorOutput: Send {
    /// Drive both wheels; each value in -1..=1 (values outside are clamped).
    fn drive(&mut self, cmd: WheelCommand) -> Result<()>;
    /// Release both motors (both bridge inputs off). Always writes, whatever was sent before.
    fn stop(&mut self) -> Result<()>;
    /// For logs: backend, bus, address.
    fn describe(&self) -> String;
}

/// One entry of a [`LogMotors`] record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotorEvent {
    Drive(WheelCommand),
    Stop,
}

/// A shared, clonable view of what a [`LogMotors`] received, each event with the time it
/// arrived (on the clock the recorder was given).
pub type MotorRecord = Arc<Mutex<Vec<(std::time::Duration, MotorEvent)>>>;

/// The `log` backend: a virtual motor output that keeps every command in memory once
/// someone asked for the [`LogMotors::record`] (tests), and, when given a path, appends each
/// as a JSON line and flushes it (so a test or a person can follow it from outside the
/// process). Without a record taken nothing grows: a soak at 240 commands a second found
/// the daemon's RSS climbing by 28 MB an hour when every event was kept.
pub struct LogMotors {
    record: MotorRecord,
    /// Set by [`LogMotors::record`]: keep events in memory from then on.
    keep: std::sync::atomic::AtomicBool,
    clock: Arc<dyn crate::clock::Clock>,
    file: Option<(PathBuf, BufWriter<File>)>,
    print: bool,
}

impl LogMotors {
    pub fn new(clock: Arc<dyn crate::clock::Clock>) -> Self {
        Self {
            record: Arc::default(),
            keep: std::sync::atomic::AtomicBool::new(false),
            clock,
            file: None,
            print: false,
        }
    }

    /// Also append each event to `path` as a JSON line.
    pub fn with_file(mut self, path: &Path) -> Result<Self> {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|source| MotorError::Log {
                path: path.display().to_string(),
                source,
            })?;
        self.file = Some((path.to_path_buf(), BufWriter::new(file)));
        Ok(self)
    }

    /// Also log each event at INFO level (what `jetpilot run` shows with the log backend).
    pub fn with_print(mut self, print: bool) -> Self {
        self.print = print;
        self
    }

    /// A handle on the recorded events that stays valid after the output is dropped; events
    /// are kept in memory from this call on.
    pub fn record(&self) -> MotorRecord {
        self.keep.store(true, std::sync::atomic::Ordering::Relaxed);
        self.record.clone()
    }

    fn push(&mut self, event: MotorEvent) -> Result<()> {
        let t = self.clock.now();
        if self.keep.load(std::sync::atomic::Ordering::Relaxed)
            && let Ok(mut rec) = self.record.lock()
        {
            rec.push((t, event));
        }
        if self.print {
            match event {
                MotorEvent::Drive(c) => {
                    tracing::info!(left = %format!("{:+.3}", c.left), right = %format!("{:+.3}", c.right), "motors")
                }
                MotorEvent::Stop => tracing::info!("motors: stop"),
            }
        }
        if let Some((path, w)) = &mut self.file {
            let line = match event {
                MotorEvent::Drive(c) => format!(
                    "{{\"t\":{:.6},\"left\":{},\"right\":{}}}\n",
                    t.as_secs_f64(),
                    c.left,
                    c.right
                ),
                MotorEvent::Stop => format!("{{\"t\":{:.6},\"stop\":true}}\n", t.as_secs_f64()),
            };
            w.write_all(line.as_bytes())
                .and_then(|_| w.flush())
                .map_err(|source| MotorError::Log {
                    path: path.display().to_string(),
                    source,
                })?;
        }
        Ok(())
    }
}

impl MotorOutput for LogMotors {
    fn drive(&mut self, cmd: WheelCommand) -> Result<()> {
        let c = WheelCommand::new(cmd.left.clamp(-1.0, 1.0), cmd.right.clamp(-1.0, 1.0));
        self.push(MotorEvent::Drive(c))
    }

    fn stop(&mut self) -> Result<()> {
        self.push(MotorEvent::Stop)
    }

    fn describe(&self) -> String {
        match &self.file {
            Some((p, _)) => format!("log backend (virtual motors, writing {})", p.display()),
            None => "log backend (virtual motors)".to_string(),
        }
    }
}

impl Drop for LogMotors {
    fn drop(&mut self) {
        self.print = false;
        if let Err(e) = self.stop() {
            tracing::warn!(error = %e, "could not record the final stop");
        }
    }
}

impl<M: MotorOutput + ?Sized> MotorOutput for Box<M> {
    fn drive(&mut self, cmd: WheelCommand) -> Result<()> {
        (**self).drive(cmd)
    }
    fn stop(&mut self) -> Result<()> {
        (**self).stop()
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_are_kept_in_memory_only_once_a_record_is_taken() {
        let mut m = LogMotors::new(Arc::new(crate::clock::MonotonicClock::new()));
        m.drive(WheelCommand::new(0.1, 0.2)).unwrap();
        m.stop().unwrap();
        let rec = m.record();
        assert!(rec.lock().unwrap().is_empty(), "kept before anyone asked");
        m.drive(WheelCommand::new(0.3, 1.5)).unwrap();
        let events: Vec<MotorEvent> = rec.lock().unwrap().iter().map(|(_, e)| *e).collect();
        assert_eq!(events, vec![MotorEvent::Drive(WheelCommand::new(0.3, 1.0))]);
    }
}
