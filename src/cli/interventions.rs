//! `jetpilot interventions summary`: the interventions log of real test drives read back,
//! with the paper's autonomy value `(1 - interventions * 6 s / test_seconds) * 100`.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::drive::interventions::{LogSummary, read};

#[derive(Debug, clap::Subcommand)]
pub enum InterventionsCommand {
    /// Count the interventions in a log (JSON lines written by `jetpilot run`), add up the
    /// test time and print the autonomy value with its formula. A torn last line left by a
    /// crash is reported as a warning.
    Summary {
        /// The interventions log (`.jsonl`).
        file: PathBuf,
        /// Print the summary as JSON (sessions, each intervention, warnings).
        #[arg(long)]
        json: bool,
    },
}

pub fn main(cmd: InterventionsCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        InterventionsCommand::Summary { file, json } => {
            let summary = read(&file).with_context(|| {
                format!("cannot summarise the interventions log {}", file.display())
            })?;
            if json {
                let text = serde_json::to_string_pretty(&summary)
                    .context("cannot encode the summary as JSON")?;
                println!("{text}");
            } else {
                print!("{}", render(&summary));
            }
            for w in &summary.warnings {
                eprintln!("warning: {w}");
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// The human-readable summary: one line per session, then the totals and the formula.
fn render(s: &LogSummary) -> String {
    let mut out = String::new();
    for (i, session) in s.sessions.iter().enumerate() {
        let end = match session.end_s {
            Some(_) => String::new(),
            None => " (no end line)".to_string(),
        };
        let autonomy = session
            .autonomy_percent
            .map(|a| format!("{a:.1} %"))
            .unwrap_or_else(|| "n/a".into());
        out.push_str(&format!(
            "session {} {}: model {} ({}), {} interventions in {:.1} s{end}, autonomy {autonomy}\n",
            i + 1,
            session.info.session,
            session.info.model,
            session.info.model_hash,
            session.interventions.len(),
            session.test_seconds,
        ));
    }
    out.push_str(&format!(
        "{}: {} session(s), {} interventions in {:.1} s of testing\n",
        s.path.display(),
        s.sessions.len(),
        s.interventions,
        s.test_seconds
    ));
    match s.autonomy_percent {
        Some(a) => out.push_str(&format!(
            "autonomy = (1 - {} * {} s / {:.1} s) * 100 = {a:.1} %\n",
            s.interventions, s.seconds_per_intervention, s.test_seconds
        )),
        None => out.push_str(&format!(
            "autonomy = (1 - interventions * {} s / test_seconds) * 100: n/a (no test time in the log)\n",
            s.seconds_per_intervention
        )),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetpilot::drive::interventions::{InterventionLog, InterventionRecord, SessionInfo};

    #[test]
    fn renders_the_formula_with_the_numbers() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("i.jsonl");
        let mut log = InterventionLog::open(
            &p,
            SessionInfo::new("m.onnx".into(), "fnv1a64:0000000000000001".into()),
        )
        .unwrap();
        for i in 0..95 {
            let t = f64::from(i) * 6.0;
            log.record(&InterventionRecord {
                start_s: t,
                end_s: t + 1.0,
                duration_s: 1.0,
                frame_seq: i as u64,
                gains: Default::default(),
                model_hash: "fnv1a64:0000000000000001".into(),
                mode_before: "auto".into(),
                cause: None,
            })
            .unwrap();
        }
        log.end(600.0).unwrap();
        let text = render(&read(&p).unwrap());
        assert!(
            text.contains("95 interventions in 600.0 s of testing"),
            "{text}"
        );
        assert!(
            text.contains("autonomy = (1 - 95 * 6 s / 600.0 s) * 100 = 5.0 %"),
            "{text}"
        );
    }
}
