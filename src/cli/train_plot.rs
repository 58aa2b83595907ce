//! `jetpilot train plot`: a line chart from a CSV with a header row, one line per value of
//! a grouping column (scripts write such CSVs: the fine-tuning study's error against the
//! number of real frames, say).
//!
//! Rows that repeat an x within a line (one per seed, say) are drawn as their mean, in a
//! shaded band of the sample sd (drawn where a line has two x or more), and each such point
//! is printed; a row equal to the header (CSVs appended with `cat`) is skipped:
//!
//! ```text
//! line "sim", x 25: mean 32.0 ± 2.0 (3 rows: 30, 32, 34)
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use jetpilot::train::curve::{Band, Series, plot_png, plot_png_with_bands};
use jetpilot::train::experiment::mean_sd;

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
        if line.trim() == header.trim() {
            continue; // another run's CSV appended with its header (`cat a.csv b.csv`)
        }
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

/// One drawn point: the mean of the rows at `x` in a line, their sample sd, the rows.
#[derive(Debug, Clone, PartialEq)]
struct Aggregated {
    x: f64,
    mean: f64,
    sd: f64,
    values: Vec<f64>,
}

/// Groups `(line, x, y)` rows into lines (in order of first appearance) and, within a line,
/// rows of the same x into one point: their mean and sample sd (0 for one row), x ascending.
fn aggregate(points: Vec<(String, f64, f64)>) -> Vec<(String, Vec<Aggregated>)> {
    /// A line's name and its rows' y values by x, in order of first appearance.
    type Rows = (String, Vec<(f64, Vec<f64>)>);
    let mut lines: Vec<Rows> = Vec::new();
    for (group, x, y) in points {
        let i = match lines.iter().position(|(name, _)| *name == group) {
            Some(i) => i,
            None => {
                lines.push((group, Vec::new()));
                lines.len() - 1
            }
        };
        let line = &mut lines[i].1;
        match line.iter_mut().find(|(at, _)| *at == x) {
            Some((_, ys)) => ys.push(y),
            None => line.push((x, vec![y])),
        }
    }
    lines
        .into_iter()
        .map(|(name, mut xs)| {
            xs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let points = xs
                .into_iter()
                .map(|(x, values)| {
                    let (mean, sd) = mean_sd(&values).unwrap_or((f64::NAN, 0.0));
                    Aggregated {
                        x,
                        mean,
                        sd,
                        values,
                    }
                })
                .collect();
            (name, points)
        })
        .collect()
}

fn short(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

pub fn main(args: PlotArgs) -> anyhow::Result<ExitCode> {
    let lines = aggregate(read_points(&args)?);
    let repeated = lines
        .iter()
        .any(|(_, points)| points.iter().any(|p| p.values.len() > 1));
    if repeated && args.log_y {
        bail!(
            "{}: some x repeats within a line (drawn as the mean in an sd band), which needs a \
             linear y axis: drop --log-y",
            args.csv.display()
        );
    }
    for (name, points) in &lines {
        for p in points.iter().filter(|p| p.values.len() > 1) {
            let values: Vec<String> = p.values.iter().map(|&v| short(v)).collect();
            println!(
                "line {name:?}, x {}: mean {:.1} ± {:.1} ({} rows: {})",
                short(p.x),
                p.mean,
                p.sd,
                p.values.len(),
                values.join(", ")
            );
        }
    }
    let series: Vec<Series> = lines
        .iter()
        .map(|(name, points)| Series {
            name: name.clone(),
            points: points.iter().map(|p| (p.x, p.mean)).collect(),
        })
        .collect();
    let size = (900, 560);
    let warning = if repeated {
        let bands: Vec<Band> = lines
            .iter()
            .map(|(_, points)| {
                points
                    .iter()
                    .map(|p| (p.x, p.mean - p.sd, p.mean + p.sd))
                    .collect()
            })
            .collect();
        plot_png_with_bands(
            &args.out,
            (&args.title, &args.x, &args.y),
            &series,
            &bands,
            size,
        )?
    } else {
        plot_png(
            &args.out,
            &args.title,
            &args.x,
            &args.y,
            &series,
            args.log_y,
            size,
        )?
    };
    if let Some(w) = warning {
        eprintln!("warning: {w}");
    }
    let rows: usize = lines
        .iter()
        .flat_map(|(_, points)| points.iter().map(|p| p.values.len()))
        .sum();
    let drawn: usize = lines.iter().map(|(_, points)| points.len()).sum();
    println!(
        "wrote {}: {} line(s), {} point(s){}",
        args.out.display(),
        lines.len(),
        drawn,
        if rows > drawn {
            format!(" (the means of {rows} rows)")
        } else {
            String::new()
        }
    );
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(line: &str, x: f64, y: f64) -> (String, f64, f64) {
        (line.to_string(), x, y)
    }

    #[test]
    fn rows_at_the_same_x_of_a_line_become_their_mean_and_sample_sd() {
        let lines = aggregate(vec![
            row("sim", 50.0, 37.0),
            row("random", 25.0, 38.0),
            row("sim", 25.0, 30.0),
            row("sim", 25.0, 34.0),
            row("sim", 25.0, 32.0),
            row("random", 25.0, 42.0),
        ]);
        let names: Vec<&str> = lines.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["sim", "random"]);
        let sim = &lines[0].1;
        assert_eq!(sim.len(), 2);
        // x ascending: 25 before 50. Mean of 30, 34, 32 is 32; sample sd
        // sqrt((4 + 4 + 0) / 2) = 2.
        assert_eq!(sim[0].x, 25.0);
        assert!((sim[0].mean - 32.0).abs() < 1e-12 && (sim[0].sd - 2.0).abs() < 1e-12);
        assert_eq!(sim[0].values, [30.0, 34.0, 32.0]);
        assert_eq!((sim[1].x, sim[1].mean, sim[1].sd), (50.0, 37.0, 0.0));
        // 38 and 42: mean 40, sd sqrt((4 + 4) / 1) = 2.83.
        let random = &lines[1].1[0];
        assert!((random.mean - 40.0).abs() < 1e-12);
        assert!((random.sd - 8f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn numbers_print_without_trailing_zeros() {
        assert_eq!(short(25.0), "25");
        assert_eq!(short(32.25), "32.25");
        assert_eq!(short(0.1234), "0.123");
    }
}
