//! What the whole process uses, read from Linux's `/proc/self`: CPU time (user + system, all
//! threads, ONNX Runtime's workers included) and resident memory (now and at its peak).
//!
//! Read from procfs rather than `getrusage`, which needs the libc crate (not a dependency).
//! CPU time in `/proc/self/stat` is counted in clock ticks; the tick rate is the kernel's
//! `AT_CLKTCK` from `/proc/self/auxv` (what `sysconf(_SC_CLK_TCK)` returns), so the
//! resolution is one tick, 10 ms on the usual `USER_HZ` of 100: measure over seconds.
//!
//! # Troubleshooting
//! - "cannot read /proc/self/...": not Linux, or procfs is not mounted (some containers).
//! - The peak does not reset: `/proc/self/clear_refs` needs Linux 4.0 or later; the peak
//!   then covers the whole process lifetime, which [`reset_peak_rss`]'s error says.

use std::time::Duration;

/// Why a procfs reading failed.
#[derive(Debug, thiserror::Error)]
pub enum UsageError {
    #[error("cannot read {path}: {source} (jetpilot reads process usage from Linux's procfs)")]
    Read {
        path: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot reset the peak RSS through {path}: {source} (needs Linux 4.0 or later)")]
    Reset {
        path: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: unexpected format: {reason}")]
    Format { path: &'static str, reason: String },
}

pub type Result<T> = std::result::Result<T, UsageError>;

const STAT: &str = "/proc/self/stat";
const STATUS: &str = "/proc/self/status";
const AUXV: &str = "/proc/self/auxv";
const CLEAR_REFS: &str = "/proc/self/clear_refs";
/// `AT_CLKTCK` in the auxiliary vector (linux/auxvec.h).
const AT_CLKTCK: usize = 17;
/// `USER_HZ` on every architecture jetpilot builds for, used only if auxv lacks the entry.
const DEFAULT_TICKS_PER_S: u64 = 100;

/// Resident set size now and at its peak, in KiB (`VmRSS` and `VmHWM`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Memory {
    pub rss_kib: u64,
    pub peak_kib: u64,
}

impl Memory {
    pub fn peak_mib(&self) -> f64 {
        self.peak_kib as f64 / 1024.0
    }

    pub fn rss_mib(&self) -> f64 {
        self.rss_kib as f64 / 1024.0
    }
}

fn read(path: &'static str) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| UsageError::Read { path, source })
}

/// User + system CPU time of the whole process so far (all threads, live and ended).
pub fn cpu_time() -> Result<Duration> {
    let stat = read(STAT)?;
    let ticks = parse_stat_ticks(&String::from_utf8_lossy(&stat))?;
    let per_s = read(AUXV)
        .ok()
        .and_then(|a| parse_auxv(&a, AT_CLKTCK))
        .filter(|&t| t > 0)
        .unwrap_or(DEFAULT_TICKS_PER_S);
    Ok(Duration::from_secs_f64(ticks as f64 / per_s as f64))
}

/// The process's resident memory now and its peak since start (or since [`reset_peak_rss`]).
pub fn memory() -> Result<Memory> {
    parse_status(&String::from_utf8_lossy(&read(STATUS)?))
}

/// Sets the peak RSS back to the current RSS (writes 5 to `/proc/self/clear_refs`).
pub fn reset_peak_rss() -> Result<()> {
    std::fs::write(CLEAR_REFS, b"5").map_err(|source| UsageError::Reset {
        path: CLEAR_REFS,
        source,
    })
}

/// utime + stime (fields 14 and 15) of a `/proc/<pid>/stat` line, in clock ticks. The
/// command name (field 2) is in parentheses and may itself hold spaces and parentheses,
/// so fields are counted after the last `)`.
fn parse_stat_ticks(line: &str) -> Result<u64> {
    let format = |reason: &str| UsageError::Format {
        path: STAT,
        reason: reason.to_string(),
    };
    let (_, rest) = line
        .rsplit_once(')')
        .ok_or_else(|| format("no `)` after the command name"))?;
    // rest[0] is field 3 (state), so field n is rest[n - 3].
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let field = |n: usize| -> Result<u64> {
        fields
            .get(n - 3)
            .and_then(|f| f.parse().ok())
            .ok_or_else(|| format(&format!("field {n} is missing or not a number")))
    };
    Ok(field(14)? + field(15)?)
}

/// `VmRSS` and `VmHWM` from `/proc/<pid>/status`.
fn parse_status(text: &str) -> Result<Memory> {
    let kib = |key: &str| -> Result<u64> {
        text.lines()
            .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
            .and_then(|v| v.trim().strip_suffix("kB")?.trim().parse().ok())
            .ok_or_else(|| UsageError::Format {
                path: STATUS,
                reason: format!("no `{key}: N kB` line"),
            })
    };
    Ok(Memory {
        rss_kib: kib("VmRSS")?,
        peak_kib: kib("VmHWM")?,
    })
}

/// The value of `key` in an auxiliary vector: native-endian (key, value) pairs of machine
/// words, ended by key 0.
fn parse_auxv(bytes: &[u8], key: usize) -> Option<u64> {
    const W: usize = std::mem::size_of::<usize>();
    let word = |c: &[u8]| -> Option<usize> { Some(usize::from_ne_bytes(c.try_into().ok()?)) };
    for pair in bytes.chunks_exact(2 * W) {
        let k = word(&pair[..W])?;
        if k == 0 {
            return None;
        }
        if k == key {
            return word(&pair[W..]).map(|v| v as u64);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_ticks_are_counted_after_the_command_name() {
        // A command name with a space and a `)`, then fields 3.. of a real line.
        let line = "4242 (a b) c) S 1 4242 4242 0 -1 4194560 1234 0 0 0 \
                    250 75 0 0 20 0 5 0 100 1000000 2000 18446744073709551615";
        assert_eq!(parse_stat_ticks(line).unwrap(), 325);
        assert!(parse_stat_ticks("4242 (x) S 1 2").is_err());
        assert!(parse_stat_ticks("no parenthesis").is_err());
    }

    #[test]
    fn status_gives_rss_and_peak() {
        let text =
            "Name:\tjetpilot\nVmPeak:\t  900000 kB\nVmHWM:\t  198000 kB\nVmRSS:\t  150500 kB\n";
        let m = parse_status(text).unwrap();
        assert_eq!((m.rss_kib, m.peak_kib), (150_500, 198_000));
        let err = parse_status("VmRSS:\t1 kB\n").unwrap_err().to_string();
        assert!(err.contains("VmHWM"), "{err}");
    }

    #[test]
    fn auxv_lookup_stops_at_the_end_marker() {
        let mut bytes = Vec::new();
        for (k, v) in [
            (6usize, 4096usize),
            (AT_CLKTCK, 100),
            (0, 0),
            (AT_CLKTCK, 7),
        ] {
            bytes.extend_from_slice(&k.to_ne_bytes());
            bytes.extend_from_slice(&v.to_ne_bytes());
        }
        assert_eq!(parse_auxv(&bytes, AT_CLKTCK), Some(100));
        assert_eq!(parse_auxv(&bytes, 99), None);
    }

    #[test]
    fn this_process_has_cpu_time_and_memory() {
        let m = memory().unwrap();
        assert!(m.rss_kib > 0 && m.peak_kib >= m.rss_kib, "{m:?}");
        let t0 = cpu_time().unwrap();
        let mut x = 0u64;
        let start = std::time::Instant::now();
        while start.elapsed() < Duration::from_millis(50) {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        assert!(cpu_time().unwrap() >= t0);
    }
}
