//! Crash test for the interventions log: a child process appends interventions in a tight
//! loop and is killed with SIGKILL at a random moment, 30 times over on the same file.
//! After each kill the log must read back: every complete line parses, at most the line
//! being written is torn (a warning, not an error), no complete line is lost (each
//! session's `frame_seq`s are 0, 1, 2, ... without gaps) and the count never goes down.
//!
//! The child is this test binary run again with `JETPILOT_KILL_CHILD=<log path>`: the
//! `kill_child_entry` test then runs the writer loop instead of returning at once.
//!
//! Note: on Linux a single small `write` to a regular file is not split by SIGKILL, so
//! real torn lines are rare here; the end of the test tears the last line by hand (as a
//! power cut could) and checks that the next session appends after it and the reader
//! reports it.

use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use jetpilot::control::SteeringGains;
use jetpilot::drive::interventions::{
    InterventionLog, InterventionRecord, LogSummary, SessionInfo, read,
};
use rand::{Rng, SeedableRng};

const CHILD_ENV: &str = "JETPILOT_KILL_CHILD";
const HASH: &str = "fnv1a64:00000000deadbeef";

/// The child's entry point; a no-op in a normal test run.
#[test]
fn kill_child_entry() {
    let Some(path) = std::env::var_os(CHILD_ENV) else {
        return;
    };
    let path = Path::new(&path);
    let mut log = InterventionLog::open(path, SessionInfo::new("model.onnx".into(), HASH.into()))
        .expect("child: open the log");
    let started = Instant::now();
    for i in 0u64.. {
        let t = i as f64 * 0.25;
        log.record(&InterventionRecord {
            start_s: t,
            end_s: t + 0.125,
            duration_s: 0.125,
            frame_seq: i,
            gains: SteeringGains::default(),
            model_hash: HASH.into(),
            mode_before: "auto".into(),
            cause: Some("stick".into()),
        })
        .expect("child: record");
        // Never outlive a parent that died before killing us.
        if i % 256 == 0 && started.elapsed() > Duration::from_secs(20) {
            break;
        }
    }
}

/// Runs one child until it has written past `min_len` bytes, lets it write for `delay`,
/// then SIGKILLs it.
fn run_and_kill(path: &Path, min_len: u64, delay: Duration) {
    let exe = std::env::current_exe().expect("current_exe");
    let mut child = Command::new(exe)
        .args([
            "interventions_kill::kill_child_entry",
            "--exact",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, path)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn the child");
    let deadline = Instant::now() + Duration::from_secs(5);
    while std::fs::metadata(path).map(|m| m.len()).unwrap_or(0) <= min_len {
        if let Ok(Some(status)) = child.try_wait() {
            panic!("the child exited by itself before writing: {status}");
        }
        assert!(Instant::now() < deadline, "the child wrote nothing in 5 s");
        std::thread::sleep(Duration::from_micros(200));
    }
    std::thread::sleep(delay);
    child.kill().expect("SIGKILL the child");
    let status = child.wait().expect("wait for the child");
    assert_eq!(
        status.signal(),
        Some(9),
        "the child must die from SIGKILL, not exit on its own: {status}"
    );
}

/// Every complete line is there: each session's frame_seqs are 0..n.
fn check_contiguous(s: &LogSummary) {
    for (k, session) in s.sessions.iter().enumerate() {
        for (i, r) in session.interventions.iter().enumerate() {
            assert_eq!(
                r.frame_seq, i as u64,
                "session {k}: intervention {i} has frame_seq {} (a lost line?)",
                r.frame_seq
            );
        }
    }
}

fn check_warnings(s: &LogSummary) {
    for w in &s.warnings {
        assert!(
            w.contains("torn line ignored") || w.contains("has no end line"),
            "unexpected warning: {w}"
        );
    }
}

#[test]
fn sigkill_never_corrupts_the_log() {
    if std::env::var_os(CHILD_ENV).is_some() {
        return;
    }
    let t0 = Instant::now();
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("interventions.jsonl");
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(1);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    eprintln!("seed {seed}");

    const ROUNDS: usize = 30;
    let mut prev_count = 0;
    let mut prev_torn = 0;
    for round in 0..ROUNDS {
        let len = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        let delay = Duration::from_millis(rng.random_range(5..=50));
        run_and_kill(&path, len, delay);
        let s = read(&path).unwrap_or_else(|e| panic!("round {round} (seed {seed}): {e}"));
        assert_eq!(s.sessions.len(), round + 1, "round {round}");
        assert!(
            s.interventions >= prev_count,
            "round {round}: count went from {prev_count} to {}",
            s.interventions
        );
        // At most the line being written when the child died is torn.
        assert!(
            s.torn_lines.len() <= prev_torn + 1,
            "round {round}: torn lines {:?}",
            s.torn_lines
        );
        check_contiguous(&s);
        check_warnings(&s);
        prev_count = s.interventions;
        prev_torn = s.torn_lines.len();
    }
    eprintln!(
        "{ROUNDS} kills: {prev_count} interventions read back, {prev_torn} torn lines seen, {:.1} s",
        t0.elapsed().as_secs_f64()
    );

    // A torn last line, as a power cut would leave it: cut the file inside its last line.
    // That line is the last session's own line when its child was killed before its first
    // intervention (its header's sync took longer than the delay): that session is then lost
    // with it, as it should be.
    let last_session_empty = read(&path)
        .expect("read the log")
        .sessions
        .last()
        .is_some_and(|x| x.interventions.is_empty());
    let bytes = std::fs::read(&path).expect("read the log");
    let cut = bytes.len() - 20;
    std::fs::write(&path, &bytes[..cut]).expect("tear the last line");
    let torn_line = bytes[..cut].iter().filter(|b| **b == b'\n').count() + 1;
    let s = read(&path).expect("a torn last line is tolerated");
    assert!(s.torn_lines.contains(&torn_line), "{:?}", s.torn_lines);
    assert!(s.interventions <= prev_count);
    check_contiguous(&s);
    let sessions_after_cut = if last_session_empty {
        ROUNDS - 1
    } else {
        ROUNDS
    };
    assert_eq!(
        s.sessions.len(),
        sessions_after_cut,
        "the cut took only the last line"
    );
    let before = s.interventions;

    // One more session after it: the torn line stays a warning, the new lines count.
    run_and_kill(&path, cut as u64, Duration::from_millis(10));
    let s = read(&path).expect("read after appending to a torn log");
    assert_eq!(s.sessions.len(), sessions_after_cut + 1);
    assert!(s.torn_lines.contains(&torn_line), "{:?}", s.torn_lines);
    assert!(s.interventions >= before);
    check_contiguous(&s);
    check_warnings(&s);
    assert!(
        t0.elapsed() < Duration::from_secs(30),
        "took {:?}",
        t0.elapsed()
    );
}
