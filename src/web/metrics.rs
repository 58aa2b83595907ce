//! `/metrics`: the daemon's counters and stage latency histograms in Prometheus' text
//! format (version 0.0.4), from the status the daemon publishes twice a second. Pure.

use std::fmt::Write;

use crate::drive::DaemonStatus;
use crate::drive::stats::BUCKETS_MS;

/// The exposition text for `s`.
pub fn render(s: &DaemonStatus) -> String {
    let mut out = String::new();
    let mut counter = |name: &str, help: &str, v: u64| {
        let _ = writeln!(
            out,
            "# HELP jetpilot_{name} {help}\n# TYPE jetpilot_{name} counter\njetpilot_{name} {v}"
        );
    };
    counter(
        "frames_captured_total",
        "Frames the camera delivered.",
        s.frames_captured,
    );
    counter(
        "frames_skipped_total",
        "Frames replaced by a newer one before inference.",
        s.frames_skipped,
    );
    counter(
        "commands_written_total",
        "Commands written to the motors.",
        s.commands_written,
    );
    counter(
        "stale_commands_dropped_total",
        "Commands dropped because their frame was too old.",
        s.stale_dropped,
    );
    counter(
        "watchdog_stops_total",
        "Motor stops by the watchdog (no fresh command in time).",
        s.watchdog_stops,
    );
    counter(
        "interventions_total",
        "Human takeovers from the autopilot.",
        s.interventions,
    );
    counter(
        "records_written_total",
        "Demonstration records written.",
        s.records,
    );
    let _ = writeln!(
        out,
        "# HELP jetpilot_mode The driving mode (1 for the current one).\n# TYPE jetpilot_mode gauge"
    );
    for m in ["manual", "auto", "stopped"] {
        let _ = writeln!(
            out,
            "jetpilot_mode{{mode=\"{m}\"}} {}",
            u8::from(s.mode == m)
        );
    }
    let _ = writeln!(
        out,
        "# HELP jetpilot_recording 1 while recording demonstrations.\n# TYPE jetpilot_recording gauge\njetpilot_recording {}",
        u8::from(s.recording)
    );
    let _ = writeln!(
        out,
        "# HELP jetpilot_uptime_seconds Seconds since the run started.\n# TYPE jetpilot_uptime_seconds gauge\njetpilot_uptime_seconds {}",
        s.elapsed_s
    );
    let name = "jetpilot_stage_latency_seconds";
    let _ = writeln!(
        out,
        "# HELP {name} Per-frame time of each pipeline stage, and the frame's age when its command was written (frame_age).\n# TYPE {name} histogram"
    );
    for (stage, h) in s.histograms.named() {
        for (bound, n) in BUCKETS_MS.iter().zip(h.le) {
            let _ = writeln!(
                out,
                "{name}_bucket{{stage=\"{stage}\",le=\"{}\"}} {n}",
                bound / 1000.0
            );
        }
        let _ = writeln!(
            out,
            "{name}_bucket{{stage=\"{stage}\",le=\"+Inf\"}} {}",
            h.count
        );
        let _ = writeln!(out, "{name}_sum{{stage=\"{stage}\"}} {}", h.sum_ms / 1000.0);
        let _ = writeln!(out, "{name}_count{{stage=\"{stage}\"}} {}", h.count);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn counters_mode_and_histograms() {
        let mut s = DaemonStatus {
            mode: "auto".into(),
            commands_written: 42,
            frames_captured: 50,
            frames_skipped: 3,
            watchdog_stops: 1,
            interventions: 2,
            ..Default::default()
        };
        s.histograms.inference.observe(Duration::from_millis(8));
        s.histograms.inference.observe(Duration::from_millis(25));
        let t = render(&s);
        assert!(t.contains("jetpilot_commands_written_total 42\n"), "{t}");
        assert!(t.contains("jetpilot_frames_captured_total 50\n"));
        assert!(t.contains("jetpilot_frames_skipped_total 3\n"));
        assert!(t.contains("jetpilot_watchdog_stops_total 1\n"));
        assert!(t.contains("jetpilot_interventions_total 2\n"));
        assert!(t.contains("jetpilot_mode{mode=\"auto\"} 1\n"));
        assert!(t.contains("jetpilot_mode{mode=\"manual\"} 0\n"));
        let b = "jetpilot_stage_latency_seconds_bucket{stage=\"inference\"";
        assert!(t.contains(&format!("{b},le=\"0.005\"}} 0\n")));
        assert!(t.contains(&format!("{b},le=\"0.01\"}} 1\n")));
        assert!(t.contains(&format!("{b},le=\"0.03\"}} 2\n")));
        assert!(t.contains(&format!("{b},le=\"+Inf\"}} 2\n")));
        assert!(t.contains("jetpilot_stage_latency_seconds_sum{stage=\"inference\"} 0.033\n"));
        assert!(t.contains("jetpilot_stage_latency_seconds_count{stage=\"inference\"} 2\n"));
        // Every sample line is `name{labels} value` or `name value`.
        for line in t.lines().filter(|l| !l.starts_with('#')) {
            let value = line.rsplit(' ').next().unwrap();
            assert!(value.parse::<f64>().is_ok(), "{line}");
        }
    }
}
