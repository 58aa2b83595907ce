//! The interventions log: an append-only JSON-lines file, one line per human intervention,
//! for the paper's autonomy score.
//!
//! ```text
//! {"session":"s1718000000-4242","started_unix_s":1718000000.25,"model":"model.onnx","model_hash":"fnv1a64:8c0f..."}
//! {"start_s":12.5,"end_s":15.0,"duration_s":2.5,"frame_seq":377,"gains":{...},"model_hash":"fnv1a64:8c0f...","mode_before":"auto","cause":"stick"}
//! ...
//! {"end_s":600.0}
//! ```
//!
//! - The first line of a session describes it; times in the other lines are seconds since
//!   the session started. Opening an existing file appends a new session.
//! - An intervention line is written when the intervention ends (Auto resumes, or the test
//!   ends with it open). `cause` is what started it (`toggle_autopilot`, `stick`,
//!   `emergency_stop`).
//! - The last line, `{"end_s": ..}`, is written when the test ends.
//! - Every line is written with a single `write_all` of the whole line (newline included),
//!   then `sync_data` (fsync): a crash loses at most the line being written, which then
//!   lies torn at the end of the file. Appending to such a file first ends the torn line
//!   with a newline, so it stays the last line of its session.
//!
//! [`read`] tolerates a torn line at the end of the file or at the end of a session (a
//! warning, listed in [`LogSummary::torn_lines`]); any other bad line is an error naming the
//! file and the line. The summary's autonomy is the paper's formula
//! (`crate::sim::reward::autonomy`):
//!
//! ```text
//! autonomy = (1 - interventions * 6 s / test_seconds) * 100
//! ```
//!
//! with `test_seconds` the sum over the sessions of `end_s` (or, for a session without its
//! end line, the end of its last intervention).
//!
//! The model hash is FNV-1a 64 over the file's bytes ([`fnv1a64_file`]): enough to tell
//! models apart in a log, not a cryptographic digest.

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use super::modes::{Mode, ModeEvent};
use crate::control::SteeringGains;
use crate::sim::reward::{SECONDS_PER_INTERVENTION, autonomy};

#[derive(Debug, thiserror::Error)]
pub enum InterventionsError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path} line {line}: {message}")]
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: cannot encode a log line: {source}")]
    Encode {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
}

pub type Result<T> = std::result::Result<T, InterventionsError>;

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> InterventionsError + '_ {
    move |source| InterventionsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// FNV-1a 64 of `bytes`.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    fnv1a64_update(FNV_OFFSET, bytes)
}

fn fnv1a64_update(mut h: u64, bytes: &[u8]) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(FNV_PRIME);
    }
    h
}

/// `"fnv1a64:<16 hex digits>"` over the file's bytes (read in 64 KiB pieces).
pub fn fnv1a64_file(path: &Path) -> Result<String> {
    let mut f = File::open(path).map_err(io_err(path))?;
    let mut buf = vec![0u8; 64 * 1024];
    let mut h = FNV_OFFSET;
    loop {
        let n = match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(io_err(path)(e)),
        };
        h = fnv1a64_update(h, &buf[..n]);
    }
    Ok(format!("fnv1a64:{h:016x}"))
}

/// The session line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    pub session: String,
    pub started_unix_s: f64,
    /// The model file as given.
    pub model: String,
    pub model_hash: String,
}

impl SessionInfo {
    /// A session starting now with this model (hashed here). The id is
    /// `s<unix seconds>-<pid>`.
    pub fn for_model(model: &Path) -> Result<Self> {
        let model_hash = fnv1a64_file(model)?;
        Ok(Self::new(model.display().to_string(), model_hash))
    }

    /// A session starting now.
    pub fn new(model: String, model_hash: String) -> Self {
        let now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or(Duration::ZERO);
        Self {
            session: format!("s{}-{}", now.as_secs(), std::process::id()),
            started_unix_s: now.as_secs_f64(),
            model,
            model_hash,
        }
    }
}

/// One intervention line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InterventionRecord {
    /// Seconds since the session started.
    pub start_s: f64,
    pub end_s: f64,
    pub duration_s: f64,
    /// The newest camera frame's sequence number when it started.
    pub frame_seq: u64,
    /// The autopilot's gains when it started.
    pub gains: SteeringGains,
    pub model_hash: String,
    /// `"auto"`: interventions start in Auto by definition.
    pub mode_before: String,
    /// What started it (`toggle_autopilot`, `stick`, `emergency_stop`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cause: Option<String>,
}

impl InterventionRecord {
    /// The record for a [`ModeEvent::InterventionEnded`]; `None` for other events.
    pub fn from_event(
        event: &ModeEvent,
        frame_seq: u64,
        gains: SteeringGains,
        model_hash: &str,
    ) -> Option<Self> {
        match event {
            ModeEvent::InterventionEnded {
                at,
                started,
                duration,
                cause,
            } => Some(Self {
                start_s: started.as_secs_f64(),
                end_s: at.as_secs_f64(),
                duration_s: duration.as_secs_f64(),
                frame_seq,
                gains,
                model_hash: model_hash.to_string(),
                mode_before: Mode::Auto.as_str().to_string(),
                cause: Some(cause.as_str().to_string()),
            }),
            _ => None,
        }
    }
}

/// The last line of a session.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EndLine {
    pub end_s: f64,
}

/// The writer: appends one session to a log file.
#[derive(Debug)]
pub struct InterventionLog {
    path: PathBuf,
    file: File,
    session: SessionInfo,
    written: u64,
}

impl InterventionLog {
    /// Creates the file or opens it for appending, and writes the session line. A torn
    /// last line left by a crash is first ended with a newline.
    pub fn open(path: &Path, session: SessionInfo) -> Result<Self> {
        let existed = path.exists();
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .read(true)
            .open(path)
            .map_err(io_err(path))?;
        let len = file.metadata().map_err(io_err(path))?.len();
        let mut torn_tail = false;
        if len > 0 {
            let mut last = [0u8; 1];
            file.read_exact_at(&mut last, len - 1)
                .map_err(io_err(path))?;
            torn_tail = last[0] != b'\n';
        }
        let mut log = Self {
            path: path.to_path_buf(),
            file,
            session,
            written: 0,
        };
        let mut line = Vec::new();
        if torn_tail {
            tracing::warn!(path = %path.display(), "the log ends with a torn line (a crash while writing); appending after it");
            line.push(b'\n');
        }
        line.extend(log.encode(&log.session)?);
        log.write_line(&line)?;
        if !existed {
            // Make the new directory entry durable too (best effort).
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                if let Ok(d) = File::open(dir) {
                    let _ = d.sync_all();
                }
            }
        }
        Ok(log)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn session(&self) -> &SessionInfo {
        &self.session
    }

    /// Intervention lines written in this session.
    pub fn written(&self) -> u64 {
        self.written
    }

    fn encode<T: Serialize>(&self, value: &T) -> Result<Vec<u8>> {
        let mut v = serde_json::to_vec(value).map_err(|source| InterventionsError::Encode {
            path: self.path.clone(),
            source,
        })?;
        v.push(b'\n');
        Ok(v)
    }

    /// One `write_all` of the whole line, then fsync.
    fn write_line(&mut self, line: &[u8]) -> Result<()> {
        self.file.write_all(line).map_err(io_err(&self.path))?;
        self.file.sync_data().map_err(io_err(&self.path))
    }

    /// Appends one intervention.
    pub fn record(&mut self, rec: &InterventionRecord) -> Result<()> {
        let line = self.encode(rec)?;
        self.write_line(&line)?;
        self.written += 1;
        Ok(())
    }

    /// Writes the end line (`end_s`: seconds since the session started) and closes the log.
    pub fn end(mut self, end_s: f64) -> Result<()> {
        let line = self.encode(&EndLine { end_s })?;
        self.write_line(&line)
    }
}

/// One session read back.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SessionSummary {
    #[serde(flatten)]
    pub info: SessionInfo,
    /// 1-based line of the session line.
    pub line: usize,
    pub interventions: Vec<InterventionRecord>,
    /// From the end line; `None` when the session has none (crash, kill).
    pub end_s: Option<f64>,
    /// `end_s`, or the end of the last intervention, or 0.
    pub test_seconds: f64,
    /// The paper's formula for this session; `None` when `test_seconds` is 0.
    pub autonomy_percent: Option<f32>,
}

/// The whole log read back.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LogSummary {
    pub path: PathBuf,
    pub sessions: Vec<SessionSummary>,
    /// Interventions over all sessions.
    pub interventions: usize,
    /// Test time over all sessions (seconds).
    pub test_seconds: f64,
    /// `(1 - interventions * 6 / test_seconds) * 100`; `None` when `test_seconds` is 0.
    pub autonomy_percent: Option<f32>,
    /// Seconds charged per intervention in the formula.
    pub seconds_per_intervention: f32,
    /// 1-based lines tolerated as torn (crash while writing).
    pub torn_lines: Vec<usize>,
    pub warnings: Vec<String>,
}

fn autonomy_opt(n: usize, test_seconds: f64) -> Option<f32> {
    let a = autonomy(u32::try_from(n).unwrap_or(u32::MAX), test_seconds as f32);
    a.is_finite().then_some(a)
}

enum Parsed {
    Session(SessionInfo),
    Intervention(InterventionRecord),
    End(EndLine),
}

fn parse_line(bytes: &[u8]) -> std::result::Result<Parsed, String> {
    let value: serde_json::Value =
        serde_json::from_slice(bytes).map_err(|e| format!("not valid JSON: {e}"))?;
    let obj = value
        .as_object()
        .ok_or_else(|| "not a JSON object".to_string())?;
    let conv = |what: &str, e: serde_json::Error| format!("bad {what} line: {e}");
    if obj.contains_key("session") {
        serde_json::from_value(value)
            .map(Parsed::Session)
            .map_err(|e| conv("session", e))
    } else if obj.contains_key("start_s") {
        serde_json::from_value(value)
            .map(Parsed::Intervention)
            .map_err(|e| conv("intervention", e))
    } else if obj.contains_key("end_s") {
        serde_json::from_value(value)
            .map(Parsed::End)
            .map_err(|e| conv("end", e))
    } else {
        Err("neither a session, an intervention nor an end line".into())
    }
}

/// Reads a log back (see the module doc for what is tolerated).
pub fn read(path: &Path) -> Result<LogSummary> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let lines: Vec<&[u8]> = bytes.split(|b| *b == b'\n').collect();
    // Index of the last non-empty line.
    let last = lines
        .iter()
        .rposition(|l| !l.iter().all(u8::is_ascii_whitespace));
    let bad = |line: usize, message: String| InterventionsError::Line {
        path: path.to_path_buf(),
        line,
        message,
    };

    let mut sessions: Vec<SessionSummary> = Vec::new();
    let mut torn_lines = Vec::new();
    let mut warnings = Vec::new();
    for (i, raw) in lines.iter().enumerate() {
        let n = i + 1;
        if raw.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        let parsed = match parse_line(raw) {
            Ok(p) => p,
            Err(message) => {
                // Tolerated: the file's last line, or the last line before a new session.
                let next_is_session = lines[i + 1..]
                    .iter()
                    .find(|l| !l.iter().all(u8::is_ascii_whitespace))
                    .is_some_and(|l| matches!(parse_line(l), Ok(Parsed::Session(_))));
                if Some(i) == last || next_is_session {
                    torn_lines.push(n);
                    warnings.push(format!(
                        "{} line {n}: torn line ignored ({} bytes, {message}): the writer stopped while writing it (crash or kill)",
                        path.display(),
                        raw.len()
                    ));
                    continue;
                }
                return Err(bad(n, message));
            }
        };
        match parsed {
            Parsed::Session(info) => sessions.push(SessionSummary {
                info,
                line: n,
                interventions: Vec::new(),
                end_s: None,
                test_seconds: 0.0,
                autonomy_percent: None,
            }),
            Parsed::Intervention(rec) => {
                let s = sessions
                    .last_mut()
                    .ok_or_else(|| bad(n, "intervention line before any session line".into()))?;
                if s.end_s.is_some() {
                    return Err(bad(
                        n,
                        format!(
                            "intervention line after the end line of session {:?}",
                            s.info.session
                        ),
                    ));
                }
                if !(rec.start_s.is_finite() && rec.end_s.is_finite() && rec.start_s <= rec.end_s) {
                    return Err(bad(
                        n,
                        format!(
                            "intervention times are not in order: start_s {} end_s {}",
                            rec.start_s, rec.end_s
                        ),
                    ));
                }
                s.interventions.push(rec);
            }
            Parsed::End(end) => {
                let s = sessions
                    .last_mut()
                    .ok_or_else(|| bad(n, "end line before any session line".into()))?;
                if s.end_s.is_some() {
                    return Err(bad(
                        n,
                        format!("second end line for session {:?}", s.info.session),
                    ));
                }
                if !(end.end_s.is_finite() && end.end_s >= 0.0) {
                    return Err(bad(n, format!("end_s {} is not a time", end.end_s)));
                }
                s.end_s = Some(end.end_s);
            }
        }
    }

    for s in &mut sessions {
        let last_end = s.interventions.iter().map(|r| r.end_s).fold(0.0, f64::max);
        s.test_seconds = match s.end_s {
            Some(e) => e.max(last_end),
            None => {
                warnings.push(format!(
                    "{} line {}: session {:?} has no end line (crash or kill?): its test time is taken up to its last intervention, {:.1} s",
                    path.display(),
                    s.line,
                    s.info.session,
                    last_end
                ));
                last_end
            }
        };
        s.autonomy_percent = autonomy_opt(s.interventions.len(), s.test_seconds);
    }
    let interventions = sessions.iter().map(|s| s.interventions.len()).sum();
    let test_seconds = sessions.iter().map(|s| s.test_seconds).sum();
    Ok(LogSummary {
        path: path.to_path_buf(),
        interventions,
        test_seconds,
        autonomy_percent: autonomy_opt(interventions, test_seconds),
        seconds_per_intervention: SECONDS_PER_INTERVENTION,
        sessions,
        torn_lines,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::modes::Cause;

    fn session(id: &str) -> SessionInfo {
        SessionInfo {
            session: id.into(),
            started_unix_s: 1_700_000_000.5,
            model: "model.onnx".into(),
            model_hash: "fnv1a64:0123456789abcdef".into(),
        }
    }

    fn rec(start: f64, end: f64, seq: u64) -> InterventionRecord {
        InterventionRecord {
            start_s: start,
            end_s: end,
            duration_s: end - start,
            frame_seq: seq,
            gains: SteeringGains::default(),
            model_hash: "fnv1a64:0123456789abcdef".into(),
            mode_before: "auto".into(),
            cause: Some("stick".into()),
        }
    }

    #[test]
    fn fnv1a64_known_vectors() {
        assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.onnx");
        // Bigger than one read buffer, so the streaming path is exercised.
        let data: Vec<u8> = (0..200_000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&p, &data).unwrap();
        assert_eq!(
            fnv1a64_file(&p).unwrap(),
            format!("fnv1a64:{:016x}", fnv1a64(&data))
        );
        std::fs::write(&p, b"foobar").unwrap();
        assert_eq!(fnv1a64_file(&p).unwrap(), "fnv1a64:85944171f73967e8");
        let e = fnv1a64_file(&dir.path().join("none.onnx")).unwrap_err();
        assert!(e.to_string().contains("none.onnx"), "{e}");
    }

    #[test]
    fn write_and_read_back_with_the_paper_formula() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("interventions.jsonl");
        let mut log = InterventionLog::open(&p, session("a")).unwrap();
        log.record(&rec(10.0, 12.5, 300)).unwrap();
        log.record(&rec(100.0, 101.0, 3000)).unwrap();
        log.record(&rec(200.0, 204.0, 6000)).unwrap();
        assert_eq!(log.written(), 3);
        log.end(600.0).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5);
        assert!(lines[0].starts_with("{\"session\":\"a\""), "{}", lines[0]);
        assert!(lines[1].contains("\"mode_before\":\"auto\""));
        assert!(lines[1].contains("\"gains\":{\"speed_gain\":0.0"));
        assert_eq!(lines[4], "{\"end_s\":600.0}");

        let s = read(&p).unwrap();
        assert_eq!(s.sessions.len(), 1);
        assert_eq!(s.interventions, 3);
        assert_eq!(s.test_seconds, 600.0);
        // (1 - 3 * 6 / 600) * 100 = 97.
        assert!((s.autonomy_percent.unwrap() - 97.0).abs() < 1e-4);
        assert!(s.warnings.is_empty() && s.torn_lines.is_empty());
        assert_eq!(s.sessions[0].interventions[1], rec(100.0, 101.0, 3000));

        // Opening again appends a second session: 95 interventions in 600 s is the paper's
        // pure RL result, 5 % (over both sessions: 98 in 1200 s = 51 %).
        let mut log = InterventionLog::open(&p, session("b")).unwrap();
        for i in 0..95 {
            let t = f64::from(i) * 6.0;
            log.record(&rec(t, t + 1.0, i as u64)).unwrap();
        }
        log.end(600.0).unwrap();
        let s = read(&p).unwrap();
        assert_eq!(s.sessions.len(), 2);
        assert_eq!(s.sessions[1].line, 6);
        assert!((s.sessions[1].autonomy_percent.unwrap() - 5.0).abs() < 1e-4);
        assert_eq!(s.interventions, 98);
        assert_eq!(s.test_seconds, 1200.0);
        assert!((s.autonomy_percent.unwrap() - 51.0).abs() < 1e-3);
    }

    #[test]
    fn a_session_without_end_line_counts_up_to_its_last_intervention() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("i.jsonl");
        let mut log = InterventionLog::open(&p, session("a")).unwrap();
        log.record(&rec(10.0, 60.0, 1)).unwrap();
        drop(log);
        let s = read(&p).unwrap();
        assert_eq!(s.test_seconds, 60.0);
        assert_eq!(s.sessions[0].end_s, None);
        assert!((s.autonomy_percent.unwrap() - 90.0).abs() < 1e-4);
        assert_eq!(s.warnings.len(), 1);
        assert!(s.warnings[0].contains("no end line"), "{:?}", s.warnings);
        assert!(s.torn_lines.is_empty());
        // No interventions and no end: no test time, no autonomy value.
        let p2 = dir.path().join("j.jsonl");
        drop(InterventionLog::open(&p2, session("x")).unwrap());
        let s = read(&p2).unwrap();
        assert_eq!(s.test_seconds, 0.0);
        assert_eq!(s.autonomy_percent, None);
    }

    #[test]
    fn torn_last_line_is_a_warning_and_appending_repairs_it() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("i.jsonl");
        let mut log = InterventionLog::open(&p, session("a")).unwrap();
        log.record(&rec(1.0, 2.0, 1)).unwrap();
        drop(log);
        // A crash halfway through the next line.
        let full = serde_json::to_string(&rec(3.0, 4.0, 2)).unwrap();
        let mut f = OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(&full.as_bytes()[..full.len() / 2]).unwrap();
        drop(f);
        let s = read(&p).unwrap();
        assert_eq!(s.interventions, 1);
        assert_eq!(s.torn_lines, vec![3]);
        assert!(
            s.warnings.iter().any(|w| w.contains("line 3: torn")),
            "{:?}",
            s.warnings
        );

        // A new session after the crash: the torn line gets its newline and stays tolerated.
        let mut log = InterventionLog::open(&p, session("b")).unwrap();
        log.record(&rec(5.0, 6.0, 3)).unwrap();
        log.end(10.0).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.lines()
                .nth(3)
                .unwrap()
                .starts_with("{\"session\":\"b\"")
        );
        let s = read(&p).unwrap();
        assert_eq!(s.sessions.len(), 2);
        assert_eq!(s.interventions, 2);
        assert_eq!(s.torn_lines, vec![3]);
        assert_eq!(s.test_seconds, 2.0 + 10.0);
        // Torn bytes that are not even UTF-8 (a torn multi-byte character).
        let mut f = OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(b"{\"start_s\":1.0,\"model\":\"\xc3").unwrap();
        drop(f);
        let s = read(&p).unwrap();
        assert_eq!(s.torn_lines, vec![3, 7]);
    }

    #[test]
    fn a_bad_line_in_the_middle_is_an_error_naming_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("i.jsonl");
        let mut log = InterventionLog::open(&p, session("a")).unwrap();
        log.record(&rec(1.0, 2.0, 1)).unwrap();
        log.end(5.0).unwrap();
        let mut text = std::fs::read_to_string(&p).unwrap();
        text = text.replacen("{\"start_s\"", "{\"start_s\":oops,", 1);
        std::fs::write(&p, &text).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains("i.jsonl line 2"), "{e}");
        assert!(e.contains("not valid JSON"), "{e}");

        // Valid JSON of the wrong shape.
        let cases = [
            ("[1,2]\n{\"end_s\":1}\n", "line 1: not a JSON object"),
            ("{\"hello\":1}\n{\"end_s\":1}\n", "line 1: neither"),
            (
                "{\"start_s\":1,\"end_s\":2,\"duration_s\":1,\"frame_seq\":1}\n{\"end_s\":1}\n",
                "line 1: bad intervention line",
            ),
            (
                "{\"end_s\":1}\n{\"end_s\":1}\n",
                "line 1: end line before any session",
            ),
        ];
        for (text, want) in cases {
            std::fs::write(&p, text).unwrap();
            let e = read(&p).unwrap_err().to_string();
            assert!(e.contains(want), "{e} / {want}");
        }
        // An intervention after the end line.
        let s = serde_json::to_string(&session("a")).unwrap();
        let r = serde_json::to_string(&rec(1.0, 2.0, 1)).unwrap();
        std::fs::write(&p, format!("{s}\n{{\"end_s\":3}}\n{r}\n{{\"end_s\":4}}\n")).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(
            e.contains("line 3: intervention line after the end line"),
            "{e}"
        );
        // Missing file.
        let e = read(&dir.path().join("nope.jsonl"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.jsonl"), "{e}");
    }

    #[test]
    fn records_come_from_mode_events() {
        let ev = ModeEvent::InterventionEnded {
            at: Duration::from_millis(15_250),
            started: Duration::from_millis(12_000),
            duration: Duration::from_millis(3_250),
            cause: Cause::Stick,
        };
        let g = SteeringGains {
            speed_gain: 0.3,
            ..SteeringGains::default()
        };
        let r = InterventionRecord::from_event(&ev, 42, g, "fnv1a64:00").unwrap();
        assert_eq!((r.start_s, r.end_s, r.duration_s), (12.0, 15.25, 3.25));
        assert_eq!(r.frame_seq, 42);
        assert_eq!(r.gains.speed_gain, 0.3);
        assert_eq!(r.mode_before, "auto");
        assert_eq!(r.cause.as_deref(), Some("stick"));
        assert!(
            InterventionRecord::from_event(&ModeEvent::InputStale { at: Duration::ZERO }, 0, g, "")
                .is_none()
        );
    }

    #[test]
    fn session_for_model_hashes_it() {
        let dir = tempfile::tempdir().unwrap();
        let m = dir.path().join("m.onnx");
        std::fs::write(&m, b"a").unwrap();
        let s = SessionInfo::for_model(&m).unwrap();
        assert_eq!(s.model_hash, "fnv1a64:af63dc4c8601ec8c");
        assert!(s.session.starts_with('s') && s.session.contains('-'));
        assert!(s.started_unix_s > 1.6e9);
    }
}
