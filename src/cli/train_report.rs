//! `jetpilot train report`: the paper's experiment summarised (tables and figures).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;

#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// The manifest: `budgets_min = [..]` and one `[[run]]` per method, seed and track.
    #[arg(long, value_name = "FILE")]
    manifest: PathBuf,
    /// Folder for experiment.md and the figures (default: the manifest's folder).
    #[arg(short, long, value_name = "DIR")]
    out: Option<PathBuf>,
}

pub fn main(args: ReportArgs) -> anyhow::Result<ExitCode> {
    use jetpilot::train::experiment;
    let experiment::Experiment {
        runs,
        budgets_min: budgets,
        test_seconds,
    } = experiment::load(&args.manifest)?;
    let out = match args.out {
        Some(o) => o,
        None => args
            .manifest
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default(),
    };
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let table = experiment::markdown(&runs, &budgets, test_seconds);
    let md = out.join("experiment.md");
    std::fs::write(&md, &table).with_context(|| format!("writing {}", md.display()))?;
    let max = budgets.iter().copied().fold(1.0, f64::max);
    let (figures, warning) = experiment::figures(&runs, max, test_seconds, &out)?;
    if let Some(w) = warning {
        tracing::warn!("{w}");
    }
    println!("{table}");
    println!("wrote {}", md.display());
    for f in figures {
        println!("wrote {}", f.display());
    }
    Ok(ExitCode::SUCCESS)
}
