//! `jetpilot train plot`: a line chart from a CSV with a header row, one line per value of
//! a grouping column (scripts write such CSVs: the fine-tuning study's error against the
//! number of real frames, say).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use jetpilot::train::curve::{Series, plot_png};

#[derive(Debug, clap::Args)]
pub struct PlotArgs {
    /// The CSV: a header row naming the columns, then one row per point.
    #[arg(long, value_name = "FILE")]
    csv: PathBuf,
    /// Column for the x axis.
    #[arg(long)]
    x: String,
    /// Column for the y axis.
    #[arg(long)]
    y: String,
    /// Column whose values name the lines (default: one line).
    #[arg(long)]
    series: Option<String>,
    /// The PNG to write.
    #[arg(short, long, value_name = "FILE")]
    out: PathBuf,
    #[arg(long, default_value = "")]
    title: String,
    /// Logarithmic y axis.
    #[arg(long)]
    log_y: bool,
}

/// Reads the CSV's columns `x`, `y` and `series`: `(series value, x, y)` per row.
fn read_points(args: &PlotArgs) -> anyhow::Result<Vec<(String, f64, f64)>> {
    let path = &args.csv;
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        bail!("{}: empty, expected a header row", path.display());
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let column = |name: &str| {
        names.iter().position(|n| *n == name).with_context(|| {
            format!(
                "{}: no column `{name}` (the header has: {})",
                path.display(),
                names.join(", ")
            )
        })
    };
    let (ix, iy) = (column(&args.x)?, column(&args.y)?);
    let is = args.series.as_deref().map(column).transpose()?;
    let mut out = Vec::new();
    for (n, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let cell = |i: usize, name: &str| {
            cells
                .get(i)
                .copied()
                .with_context(|| format!("{}:{}: no value for `{name}`", path.display(), n + 1))
        };
        let num = |i: usize, name: &str| -> anyhow::Result<f64> {
            let c = cell(i, name)?;
            c.parse().with_context(|| {
                format!(
                    "{}:{}: `{name}` = {c:?} is not a number",
                    path.display(),
                    n + 1
                )
            })
        };
        let group = match (is, &args.series) {
            (Some(i), Some(name)) => cell(i, name)?.to_string(),
            _ => args.y.clone(),
        };
        out.push((group, num(ix, &args.x)?, num(iy, &args.y)?));
    }
    if out.is_empty() {
        bail!("{}: no rows after the header", path.display());
    }
    Ok(out)
}

pub fn main(args: PlotArgs) -> anyhow::Result<ExitCode> {
    let points = read_points(&args)?;
    let mut series: Vec<Series> = Vec::new();
    for (group, x, y) in points {
        match series.iter_mut().find(|s| s.name == group) {
            Some(s) => s.points.push((x, y)),
            None => series.push(Series {
                name: group,
                points: vec![(x, y)],
            }),
        }
    }
    for s in &mut series {
        s.points.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    let warning = plot_png(
        &args.out,
        &args.title,
        &args.x,
        &args.y,
        &series,
        args.log_y,
        (900, 560),
    )?;
    if let Some(w) = warning {
        eprintln!("warning: {w}");
    }
    println!(
        "wrote {}: {} line(s), {} point(s)",
        args.out.display(),
        series.len(),
        series.iter().map(|s| s.points.len()).sum::<usize>()
    );
    Ok(ExitCode::SUCCESS)
}
