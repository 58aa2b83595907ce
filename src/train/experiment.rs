//! The paper's experiment summarised: owns turning the runs of `scripts/paper-experiment.sh`
//! (pure DDPG, IL, IL + DDPG; several seeds; several tracks) into the Markdown table and
//! the Fig. 4-style figure of `jetpilot train report`.
//!
//! ```text
//! manifest (TOML): [[run]] method, seed, track, offset_s, and either
//!                  eval_json  (one `jetpilot eval --json`, e.g. the imitation policy), or
//!                  evals_csv  (a `train ddpg` run's ddpg_eval.csv)
//! a run's points: (offset_s + wall_s, interventions, autonomy, rewards) per evaluation
//! value after a budget B = the best point (autonomy, then rewards) with time <= B: the
//!                          policy best.onnx holds at that moment, as the trainer keeps it
//! table cell  = mean ± sd over the seeds that have a value (n shown when some have none)
//! ```
//!
//! `offset_s` is the wall time spent before the run's own clock started: the imitation
//! training that IL + DDPG builds on, so every method is charged its whole wall time.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::TrainError;
use super::curve::{Band, Series, plot_png_with_bands, read_csv};
use super::ddpg::eval::improves_on;

/// One evaluation (the paper's 600 s test) at a wall time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Wall seconds since the method started (its imitation training included).
    pub wall_s: f64,
    pub interventions: f64,
    pub autonomy: f64,
    pub rewards: f64,
}

/// One method's run on one track with one seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub method: String,
    pub seed: u64,
    pub track: String,
    pub points: Vec<Point>,
}

/// The best point at or before `t` (highest autonomy, then most rewards; the earlier on a
/// tie; never one with under half the first point's rewards), as the trainer's best.onnx is
/// chosen ([`improves_on`]); `None` before the first evaluation.
pub fn best_by(points: &[Point], t: f64) -> Option<Point> {
    let score = |p: &Point| (p.autonomy, p.rewards);
    let start = points.first().map(score);
    let mut best: Option<Point> = None;
    for p in points.iter().filter(|p| p.wall_s <= t) {
        // The first point passes the start's test against itself.
        if improves_on(score(p), best.as_ref().map(score), start) {
            best = Some(*p);
        }
    }
    best
}

/// Mean and sample standard deviation (0 for one value); `None` for none.
pub fn mean_sd(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let sd = if values.len() > 1 {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    Some((mean, sd))
}

/// A method's numbers on a track after one budget, over its seeds.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// Seeds with an evaluation by then / seeds run.
    pub n: usize,
    pub of: usize,
    pub interventions: Option<(f64, f64)>,
    pub autonomy: Option<(f64, f64)>,
    pub rewards: Option<(f64, f64)>,
}

/// The cell of `runs` (one method, one track, its seeds) after `budget_s`.
pub fn cell(runs: &[&Run], budget_s: f64) -> Cell {
    let best: Vec<Point> = runs
        .iter()
        .filter_map(|r| best_by(&r.points, budget_s))
        .collect();
    let of = |f: fn(&Point) -> f64| mean_sd(&best.iter().map(f).collect::<Vec<_>>());
    Cell {
        n: best.len(),
        of: runs.len(),
        interventions: of(|p| p.interventions),
        autonomy: of(|p| p.autonomy),
        rewards: of(|p| p.rewards),
    }
}

fn pm(v: Option<(f64, f64)>, decimals: usize) -> String {
    match v {
        Some((m, s)) => format!("{m:.decimals$} ± {s:.decimals$}"),
        None => "–".into(),
    }
}

/// One method's runs (its seeds) on one track.
type MethodRuns<'a> = (String, Vec<&'a Run>);

/// Runs grouped by track, then method, in the order they first appear.
fn grouped(runs: &[Run]) -> Vec<(String, Vec<MethodRuns<'_>>)> {
    let mut tracks: Vec<(String, Vec<MethodRuns<'_>>)> = Vec::new();
    for r in runs {
        let t = match tracks.iter().position(|(t, _)| *t == r.track) {
            Some(i) => i,
            None => {
                tracks.push((r.track.clone(), Vec::new()));
                tracks.len() - 1
            }
        };
        let methods = &mut tracks[t].1;
        match methods.iter_mut().find(|(m, _)| *m == r.method) {
            Some((_, v)) => v.push(r),
            None => methods.push((r.method.clone(), vec![r])),
        }
    }
    tracks
}

/// The Markdown tables: per track, one row per method and budget.
pub fn markdown(runs: &[Run], budgets_min: &[f64], test_seconds: f64) -> String {
    let mut out = String::new();
    for (track, methods) in grouped(runs) {
        let _ = writeln!(out, "**{track}**\n");
        let _ = writeln!(
            out,
            "| method | wall budget | seeds | interventions in {test_seconds} s | autonomy % | rewards |"
        );
        let _ = writeln!(out, "|---|---|---|---|---|---|");
        for (method, rs) in &methods {
            for &b in budgets_min {
                let c = cell(rs, b * 60.0);
                let _ = writeln!(
                    out,
                    "| {method} | {b} min | {}/{} | {} | {} | {} |",
                    c.n,
                    c.of,
                    pm(c.interventions, 1),
                    pm(c.autonomy, 1),
                    pm(c.rewards, 0),
                );
            }
        }
        out.push('\n');
    }
    out
}

/// Mean line and ± sd band of one metric over `runs` on a grid of wall times (minutes).
fn curve(runs: &[&Run], grid_min: &[f64], metric: fn(&Point) -> f64) -> (Vec<(f64, f64)>, Band) {
    let mut line = Vec::with_capacity(grid_min.len());
    let mut band = Vec::with_capacity(grid_min.len());
    for &t in grid_min {
        let values: Vec<f64> = runs
            .iter()
            .filter_map(|r| best_by(&r.points, t * 60.0))
            .map(|p| metric(&p))
            .collect();
        match mean_sd(&values) {
            Some((m, s)) => {
                line.push((t, m));
                band.push((t, m - s, m + s));
            }
            None => line.push((t, f64::NAN)),
        }
    }
    (line, band)
}

/// Per track, `experiment_<track>.png`: rewards (left) and autonomy (right) against wall
/// minutes, one line per method (the seeds' mean of the best policy so far) in a ± sd band.
/// Returns the files written and any plotting warning.
pub fn figures(
    runs: &[Run],
    max_min: f64,
    test_seconds: f64,
    out: &Path,
) -> Result<(Vec<PathBuf>, Option<String>), TrainError> {
    let rewards_unit = format!("rewards in {test_seconds} s");
    let steps = 120;
    let grid: Vec<f64> = (0..=steps)
        .map(|i| max_min * f64::from(i) / f64::from(steps))
        .collect();
    let mut written = Vec::new();
    let mut warning = None;
    for (track, methods) in grouped(runs) {
        let slug: String = track
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let path = out.join(format!("experiment_{slug}.png"));
        let mut panels = Vec::new();
        for (name, metric, unit) in [
            (
                "rewards",
                (|p: &Point| p.rewards) as fn(&Point) -> f64,
                rewards_unit.as_str(),
            ),
            ("autonomy", |p: &Point| p.autonomy, "autonomy %"),
        ] {
            let (mut series, mut bands) = (Vec::new(), Vec::new());
            for (method, rs) in &methods {
                let (line, band) = curve(rs, &grid, metric);
                series.push(Series {
                    name: match rs.len() {
                        1 => format!("{method} (1 seed)"),
                        n => format!("{method} ({n} seeds)"),
                    },
                    points: line,
                });
                bands.push(band);
            }
            let panel = out.join(format!(".experiment_{slug}_{name}.png"));
            let w = plot_png_with_bands(
                &panel,
                (&format!("{track}: {name}"), "wall minutes", unit),
                &series,
                &bands,
                (700, 450),
            )?;
            warning = warning.or(w);
            panels.push(panel);
        }
        side_by_side(&panels, &path)?;
        for p in &panels {
            let _ = std::fs::remove_file(p);
        }
        written.push(path);
    }
    Ok((written, warning))
}

/// Joins PNGs of equal height left to right into `path`.
fn side_by_side(parts: &[PathBuf], path: &Path) -> Result<(), TrainError> {
    let err = |p: &Path, e: image::ImageError| TrainError::Data {
        path: p.display().to_string(),
        reason: e.to_string(),
    };
    let images = parts
        .iter()
        .map(|p| image::open(p).map(|i| i.to_rgb8()).map_err(|e| err(p, e)))
        .collect::<Result<Vec<_>, _>>()?;
    let width = images.iter().map(|i| i.width()).sum();
    let height = images.iter().map(|i| i.height()).max().unwrap_or(1);
    let mut joined = image::RgbImage::from_pixel(width, height, image::Rgb([255, 255, 255]));
    let mut x = 0;
    for i in &images {
        image::imageops::replace(&mut joined, i, i64::from(x), 0);
        x += i.width();
    }
    joined.save(path).map_err(|e| err(path, e))
}

// ----------------------------------------------------------------------------------------
// The manifest

fn paper_test_seconds() -> f64 {
    600.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    /// Budgets of the table, wall minutes.
    budgets_min: Vec<f64>,
    /// Length of each evaluation, simulated seconds (the paper: 600).
    #[serde(default = "paper_test_seconds")]
    test_seconds: f64,
    #[serde(default)]
    run: Vec<RunSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RunSpec {
    method: String,
    seed: u64,
    track: String,
    #[serde(default)]
    offset_s: f64,
    eval_json: Option<PathBuf>,
    evals_csv: Option<PathBuf>,
}

/// `jetpilot eval --json`'s fields used here.
#[derive(Debug, Deserialize)]
struct EvalJson {
    interventions: f64,
    autonomy_percent: f64,
    rewards: f64,
}

/// A loaded experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct Experiment {
    pub runs: Vec<Run>,
    /// The table's budgets, wall minutes.
    pub budgets_min: Vec<f64>,
    /// Length of each evaluation, simulated seconds.
    pub test_seconds: f64,
}

/// Reads a manifest and every log it names (relative paths: relative to the manifest's
/// folder).
pub fn load(manifest: &Path) -> Result<Experiment, TrainError> {
    let data_err = |p: &Path, reason: String| TrainError::Data {
        path: p.display().to_string(),
        reason,
    };
    let text = std::fs::read_to_string(manifest).map_err(|e| data_err(manifest, e.to_string()))?;
    let m: Manifest = toml::from_str(&text).map_err(|e| data_err(manifest, e.to_string()))?;
    let base = manifest.parent().unwrap_or(Path::new("."));
    let mut runs = Vec::with_capacity(m.run.len());
    for (i, spec) in m.run.into_iter().enumerate() {
        let points = match (&spec.eval_json, &spec.evals_csv) {
            (Some(json), None) => {
                let p = base.join(json);
                let text = std::fs::read_to_string(&p).map_err(|e| data_err(&p, e.to_string()))?;
                let e: EvalJson = serde_json::from_str(&text)
                    .map_err(|e| data_err(&p, format!("not `jetpilot eval --json` output: {e}")))?;
                vec![Point {
                    wall_s: spec.offset_s,
                    interventions: e.interventions,
                    autonomy: e.autonomy_percent,
                    rewards: e.rewards,
                }]
            }
            (None, Some(csv)) => {
                let p = base.join(csv);
                let (header, rows) = read_csv(&p)?;
                let col = |name: &str| {
                    header.iter().position(|h| h == name).ok_or_else(|| {
                        data_err(&p, format!("no `{name}` column: not a ddpg_eval.csv"))
                    })
                };
                let (w, n, a, r) = (
                    col("wall_s")?,
                    col("interventions")?,
                    col("autonomy_percent")?,
                    col("rewards")?,
                );
                rows.iter()
                    .map(|row| Point {
                        wall_s: spec.offset_s + row[w],
                        interventions: row[n],
                        autonomy: row[a],
                        rewards: row[r],
                    })
                    .collect()
            }
            _ => {
                return Err(data_err(
                    manifest,
                    format!("run[{i}]: give exactly one of `eval_json` and `evals_csv`"),
                ));
            }
        };
        runs.push(Run {
            method: spec.method,
            seed: spec.seed,
            track: spec.track,
            points,
        });
    }
    Ok(Experiment {
        runs,
        budgets_min: m.budgets_min,
        test_seconds: m.test_seconds,
    })
}

/// Seeds per (track, method), for the report's header.
pub fn seeds(runs: &[Run]) -> BTreeMap<(String, String), Vec<u64>> {
    let mut out: BTreeMap<(String, String), Vec<u64>> = BTreeMap::new();
    for r in runs {
        out.entry((r.track.clone(), r.method.clone()))
            .or_default()
            .push(r.seed);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(wall_s: f64, interventions: f64, rewards: f64) -> Point {
        Point {
            wall_s,
            interventions,
            autonomy: 100.0 - interventions,
            rewards,
        }
    }

    fn run(method: &str, seed: u64, points: Vec<Point>) -> Run {
        Run {
            method: method.into(),
            seed,
            track: "cw".into(),
            points,
        }
    }

    #[test]
    fn the_best_so_far_is_what_best_onnx_holds() {
        let pts = [
            p(60.0, 40.0, 900.0),
            p(120.0, 3.0, 800.0),
            p(180.0, 3.0, 850.0),
        ];
        assert_eq!(best_by(&pts, 30.0), None);
        assert_eq!(best_by(&pts, 60.0), Some(pts[0]));
        assert_eq!(best_by(&pts, 150.0), Some(pts[1]));
        // Same autonomy, more rewards: the later one.
        assert_eq!(best_by(&pts, 1e9), Some(pts[2]));
        // A policy that stands still (under half the first point's 900 rewards) is never
        // the best, however few its interventions.
        let stopped = [pts[0], p(120.0, 1.0, 449.0), p(180.0, 5.0, 450.0)];
        assert_eq!(best_by(&stopped, 150.0), Some(pts[0]));
        assert_eq!(best_by(&stopped, 1e9), Some(stopped[2]));
    }

    #[test]
    fn mean_and_sample_sd() {
        assert_eq!(mean_sd(&[]), None);
        assert_eq!(mean_sd(&[4.0]), Some((4.0, 0.0)));
        let (m, s) = mean_sd(&[2.0, 4.0, 6.0]).unwrap();
        assert_eq!(m, 4.0);
        assert!((s - 2.0).abs() < 1e-12);
    }

    #[test]
    fn cells_and_table_over_seeds() {
        let runs = vec![
            run("IL", 1, vec![p(600.0, 40.0, 9000.0)]),
            run("IL", 2, vec![p(620.0, 38.0, 9100.0)]),
            run(
                "IL + DDPG",
                1,
                vec![p(600.0, 40.0, 9000.0), p(1200.0, 0.0, 12000.0)],
            ),
            run(
                "IL + DDPG",
                2,
                vec![p(620.0, 38.0, 9100.0), p(1300.0, 2.0, 11000.0)],
            ),
        ];
        let refs: Vec<&Run> = runs[2..].iter().collect();
        let c = cell(&refs, 20.0 * 60.0);
        // Seed 1 has its 0-intervention evaluation by 20 min, seed 2 only its start.
        assert_eq!((c.n, c.of), (2, 2));
        let (m, sd) = c.interventions.unwrap();
        assert_eq!(m, 19.0);
        assert!((sd - 19.0 * 2f64.sqrt()).abs() < 1e-9, "{sd}");
        let c = cell(&refs, 5.0);
        assert_eq!((c.n, c.interventions), (0, None));
        let md = markdown(&runs, &[10.0, 30.0], 600.0);
        assert!(md.contains("| interventions in 600 s |"), "{md}");
        assert!(md.contains("**cw**"), "{md}");
        // IL seed 1 finished at exactly 10 min, seed 2 after it.
        assert!(md.contains("| IL | 10 min | 1/2 | 40.0 ± 0.0 |"), "{md}");
        assert!(
            md.contains("| IL + DDPG | 30 min | 2/2 | 1.0 ± 1.4 | 99.0 ± 1.4 | 11500 ± 707 |"),
            "{md}"
        );
    }

    #[test]
    fn report_from_a_manifest() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(
            d.join("il.json"),
            r#"{"pilot":"x","interventions":40,"autonomy_percent":60.0,"rewards":9000}"#,
        )
        .unwrap();
        std::fs::write(
            d.join("ddpg_eval.csv"),
            "episode,env_steps,wall_s,interventions,autonomy_percent,rewards,mean_reward,laps\n\
             0,0,30,40,60,9000,0.5,10\n10,9000,400,0,100,12000,0.6,12\n",
        )
        .unwrap();
        std::fs::write(
            d.join("m.toml"),
            "budgets_min = [10, 20]\n\
             [[run]]\nmethod = \"IL\"\nseed = 1\ntrack = \"cw\"\noffset_s = 480\neval_json = \"il.json\"\n\
             [[run]]\nmethod = \"IL + DDPG\"\nseed = 1\ntrack = \"cw\"\noffset_s = 480\nevals_csv = \"ddpg_eval.csv\"\n",
        )
        .unwrap();
        let Experiment {
            runs,
            budgets_min: budgets,
            test_seconds,
        } = load(&d.join("m.toml")).unwrap();
        assert_eq!(budgets, [10.0, 20.0]);
        assert_eq!(test_seconds, 600.0);
        assert_eq!(runs[1].points[1].wall_s, 880.0);
        let md = markdown(&runs, &budgets, test_seconds);
        assert!(
            md.contains("| IL + DDPG | 10 min | 1/1 | 40.0 ± 0.0 |"),
            "{md}"
        );
        assert!(
            md.contains("| IL + DDPG | 20 min | 1/1 | 0.0 ± 0.0 |"),
            "{md}"
        );
        let (files, _) = figures(&runs, 20.0, test_seconds, d).unwrap();
        assert_eq!(files, [d.join("experiment_cw.png")]);
        let img = image::open(&files[0]).unwrap();
        assert_eq!((img.width(), img.height()), (1400, 450));

        std::fs::write(
            d.join("bad.toml"),
            "budgets_min = [10]\n[[run]]\nmethod = \"IL\"\nseed = 1\ntrack = \"cw\"\n",
        )
        .unwrap();
        let e = load(&d.join("bad.toml")).unwrap_err().to_string();
        assert!(e.contains("bad.toml") && e.contains("exactly one"), "{e}");
    }
}
