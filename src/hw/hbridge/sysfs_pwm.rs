//! Linux's sysfs PWM (`/sys/class/pwm/pwmchipN/pwmM`) as an embedded-hal `SetDutyCycle`:
//! the Jetson Nano's hardware PWM on header pins 32 and 33 once they are enabled with
//! jetson-io, and the Raspberry Pi's with `dtoverlay=pwm-2chan`.
//!
//! Opening a channel exports it if it is not yet (and waits up to a second for udev to
//! hand the new files to the `gpio` group), lowers a leftover duty, disables the output,
//! sets the polarity back to normal, sets the period, a duty of 0 and enables the output. Dropping it writes a duty of 0 and disables it. The
//! root folder is a parameter, so tests run against a fake tree in a temporary directory.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use embedded_hal::pwm::{ErrorKind, ErrorType, SetDutyCycle};

/// Where Linux puts PWM chips.
pub const SYSFS_PWM_ROOT: &str = "/sys/class/pwm";

/// The duty resolution offered through `SetDutyCycle` (the ns value written is exact).
const MAX_DUTY: u16 = u16::MAX;

/// How long to wait for an exported channel's files to appear and become writable.
const EXPORT_WAIT: Duration = Duration::from_secs(1);

/// A failed sysfs PWM write, naming the file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct SysfsPwmError {
    pub path: String,
    pub reason: String,
}

impl embedded_hal::pwm::Error for SysfsPwmError {
    fn kind(&self) -> ErrorKind {
        ErrorKind::Other
    }
}

/// One exported, enabled sysfs PWM channel.
#[derive(Debug)]
pub struct SysfsPwm {
    dir: PathBuf,
    /// `dir/duty_cycle`, the file written every frame.
    duty_path: PathBuf,
    period_ns: u64,
}

fn write(path: &Path, value: impl std::fmt::Display) -> Result<(), SysfsPwmError> {
    std::fs::write(path, value.to_string()).map_err(|e| SysfsPwmError {
        path: path.display().to_string(),
        reason: advice(&e),
    })
}

fn advice(e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::PermissionDenied => format!(
            "{e}: add the user to the `gpio` group and install systemd/99-jetpilot.rules, \
             which gives the group the PWM files"
        ),
        std::io::ErrorKind::NotFound => format!(
            "{e}: no such PWM chip or channel; `ls /sys/class/pwm` lists them (on a Jetson \
             Nano, enable the header's PWM pins with `sudo /opt/nvidia/jetson-io/jetson-io.py`)"
        ),
        _ => e.to_string(),
    }
}

impl SysfsPwm {
    /// Opens channel `channel` of `root/pwmchip{chip}` at `hz`, output enabled at duty 0.
    pub fn open(root: &Path, chip: u32, channel: u32, hz: f32) -> Result<Self, SysfsPwmError> {
        let chip_dir = root.join(format!("pwmchip{chip}"));
        if !chip_dir.is_dir() {
            return Err(SysfsPwmError {
                path: chip_dir.display().to_string(),
                reason: advice(&std::io::Error::from(std::io::ErrorKind::NotFound)),
            });
        }
        if !(1.0..=1_000_000.0).contains(&hz) {
            return Err(SysfsPwmError {
                path: chip_dir.display().to_string(),
                reason: format!("PWM frequency {hz} Hz is outside 1 ..= 1000000"),
            });
        }
        let dir = chip_dir.join(format!("pwm{channel}"));
        if !dir.is_dir() {
            write(&chip_dir.join("export"), channel)?;
            let start = Instant::now();
            while !writable(&dir.join("period")) {
                if start.elapsed() > EXPORT_WAIT {
                    return Err(SysfsPwmError {
                        path: dir.display().to_string(),
                        reason: format!(
                            "exported channel {channel}, but its files did not appear (or \
                             stayed unwritable) within {} ms",
                            EXPORT_WAIT.as_millis()
                        ),
                    });
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        let period_ns = (1e9 / f64::from(hz)).round() as u64;
        let pwm = Self {
            duty_path: dir.join("duty_cycle"),
            dir,
            period_ns,
        };
        // A period shorter than a leftover duty is refused by the kernel: lower it first.
        write(&pwm.duty_path, 0)?;
        write(&pwm.dir.join("enable"), 0)?;
        // A channel another program left "inversed" would be fully on at duty 0.
        let polarity = pwm.dir.join("polarity");
        if let Ok(p) = std::fs::read_to_string(&polarity)
            && p.trim() != "normal"
        {
            write(&polarity, "normal")?;
        }
        write(&pwm.dir.join("period"), period_ns)?;
        write(&pwm.duty_path, 0)?;
        write(&pwm.dir.join("enable"), 1)?;
        Ok(pwm)
    }

    /// The channel's folder, e.g. `/sys/class/pwm/pwmchip0/pwm0`.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The period written at open, in nanoseconds.
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The duty in nanoseconds for `duty` of [`MAX_DUTY`].
    pub fn duty_ns(&self, duty: u16) -> u64 {
        (u128::from(self.period_ns) * u128::from(duty) / u128::from(MAX_DUTY)) as u64
    }
}

fn writable(path: &Path) -> bool {
    std::fs::OpenOptions::new().write(true).open(path).is_ok()
}

impl ErrorType for SysfsPwm {
    type Error = SysfsPwmError;
}

impl SetDutyCycle for SysfsPwm {
    fn max_duty_cycle(&self) -> u16 {
        MAX_DUTY
    }

    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Self::Error> {
        write(&self.duty_path, self.duty_ns(duty))
    }
}

impl Drop for SysfsPwm {
    fn drop(&mut self) {
        let off = write(&self.duty_path, 0).and(write(&self.dir.join("enable"), 0));
        if let Err(e) = off {
            tracing::warn!(error = %e, "sysfs PWM: could not switch the output off");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fake `pwmchip0` with channel `pwm0` already exported, as the kernel lays it out.
    fn fake_tree() -> tempfile::TempDir {
        let root = tempfile::tempdir().unwrap();
        let ch = root.path().join("pwmchip0/pwm0");
        std::fs::create_dir_all(&ch).unwrap();
        for f in ["period", "duty_cycle", "enable"] {
            std::fs::write(ch.join(f), "0").unwrap();
        }
        std::fs::write(root.path().join("pwmchip0/export"), "").unwrap();
        root
    }

    fn read(root: &Path, f: &str) -> String {
        std::fs::read_to_string(root.join("pwmchip0/pwm0").join(f)).unwrap()
    }

    #[test]
    fn open_sets_the_period_a_zero_duty_and_enables_the_output() {
        let t = fake_tree();
        let pwm = SysfsPwm::open(t.path(), 0, 0, 1000.0).unwrap();
        assert_eq!(pwm.period_ns(), 1_000_000);
        assert_eq!(read(t.path(), "period"), "1000000");
        assert_eq!(read(t.path(), "duty_cycle"), "0");
        assert_eq!(read(t.path(), "enable"), "1");
    }

    #[test]
    fn duty_is_written_in_nanoseconds_of_the_period() {
        let t = fake_tree();
        let mut pwm = SysfsPwm::open(t.path(), 0, 0, 20_000.0).unwrap();
        pwm.set_duty_cycle(MAX_DUTY).unwrap();
        assert_eq!(read(t.path(), "duty_cycle"), "50000");
        pwm.set_duty_cycle_fraction(1, 4).unwrap();
        // embedded-hal's fraction: 65535 / 4 = 16383 ticks; 16383 / 65535 of 50 us, floored.
        assert_eq!(read(t.path(), "duty_cycle"), "12499");
    }

    #[test]
    fn an_inversed_channel_is_set_back_to_normal_polarity() {
        let t = fake_tree();
        std::fs::write(t.path().join("pwmchip0/pwm0/polarity"), "inversed\n").unwrap();
        let _pwm = SysfsPwm::open(t.path(), 0, 0, 1000.0).unwrap();
        assert_eq!(read(t.path(), "polarity"), "normal");
    }

    #[test]
    fn drop_switches_the_output_off() {
        let t = fake_tree();
        let mut pwm = SysfsPwm::open(t.path(), 0, 0, 1000.0).unwrap();
        pwm.set_duty_cycle(MAX_DUTY / 2).unwrap();
        drop(pwm);
        assert_eq!(read(t.path(), "duty_cycle"), "0");
        assert_eq!(read(t.path(), "enable"), "0");
    }

    #[test]
    fn a_missing_chip_names_the_folder_and_jetson_io() {
        let t = fake_tree();
        let e = SysfsPwm::open(t.path(), 3, 0, 1000.0).unwrap_err();
        assert!(e.path.ends_with("pwmchip3"), "{e}");
        assert!(e.to_string().contains("jetson-io"), "{e}");
    }

    #[test]
    fn an_unexported_channel_is_exported_and_waited_for() {
        let t = fake_tree();
        let e = SysfsPwm::open(t.path(), 0, 2, 1000.0).unwrap_err();
        // The fake kernel never creates pwm2: the export was written, then the wait ran out.
        assert_eq!(
            std::fs::read_to_string(t.path().join("pwmchip0/export")).unwrap(),
            "2"
        );
        assert!(
            e.path.ends_with("pwm2") && e.reason.contains("did not appear"),
            "{e}"
        );
    }
}
