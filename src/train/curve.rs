//! Training logs: the CSV file of per-epoch / per-episode metrics and the PNG learning
//! curve drawn from it.
//!
//! - [`CsvLog`] writes one row per epoch (or episode) under a fixed header and hands each
//!   row to the OS as it is written, so a run that is killed keeps every finished row;
//!   opening the same file again with the same header appends (resume).
//! - [`read_csv`] reads such a file back (to resume, or to plot).
//! - [`plot_png`] draws [`Series`] as lines on one chart with [plotters]' bitmap backend and
//!   writes a PNG (encoded with the `image` crate).
//!
//! Text (title, axis labels, tick labels, legend) needs a TrueType font, read at run time:
//! `$JETPILOT_FONT` if set, else the first of [`FONT_PATHS`] that exists (Debian/Ubuntu:
//! `fonts-dejavu-core`). Without one the chart is still drawn (lines, grid, frame) and
//! [`plot_png`] returns a warning for the caller to log.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::backend::{BitMapBackend, RGBPixel};
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

mod legend;

/// One series of a learning curve, e.g. "train loss".
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// The legend entry.
    pub name: String,
    /// `(x, y)` points in drawing order (x: epoch or episode). Non-finite points are
    /// skipped and break the line.
    pub points: Vec<(f64, f64)>,
}

/// Errors of the training logs; each names the file it is about.
#[derive(Debug, thiserror::Error)]
pub enum CurveError {
    /// Reading, writing or creating the file failed.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    /// An existing log has another header than the one asked for (another run's log).
    #[error(
        "{}: the log's header is `{found}`, expected `{expected}` (another run's log? use another file or start afresh)",
        .path.display()
    )]
    Header {
        path: PathBuf,
        expected: String,
        found: String,
    },
    /// A row (or the header, line 1) that cannot be written or read back.
    #[error("{}:{line}: {reason}", .path.display())]
    Row {
        path: PathBuf,
        line: usize,
        reason: String,
    },
    /// Drawing or encoding the chart failed.
    #[error("{}: plot: {reason}", .path.display())]
    Plot { path: PathBuf, reason: String },
}

fn io_err(path: &Path) -> impl FnOnce(io::Error) -> CurveError + '_ {
    move |source| CurveError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// A CSV log with a fixed header; each row is flushed as it is written, so a run that is
/// killed keeps every finished row. Opening an existing file with the same header appends
/// (resume); a different header is an error naming the file and both headers.
///
/// Values are written as plain numbers: integral values below 1e15 without a fraction
/// (`3`, not `3.0`), others with up to 6 decimals and trailing zeros trimmed
/// (`1234.5678`, `0.5`), magnitudes below 1e-3 or from 1e15 up in scientific notation with
/// up to 7 significant digits (`2.5e-5`); `NaN`, `inf`, `-inf` as such.
#[derive(Debug)]
pub struct CsvLog {
    path: PathBuf,
    file: File,
    columns: usize,
    /// The 1-based line number the next row goes to.
    next_line: usize,
}

impl CsvLog {
    /// Opens `path` for logging rows of `header.len()` values, creating missing parent
    /// directories. With `append` and an existing, non-empty file whose header equals
    /// `header`, rows go after the existing ones (an unfinished last line, one without its
    /// newline, is cut off first); with another header it is a [`CurveError::Header`].
    /// Otherwise the file is created (or truncated) and the header written.
    ///
    /// Column names must be non-empty and free of `,`, `"` and line breaks.
    pub fn open(path: &Path, header: &[&str], append: bool) -> Result<Self, CurveError> {
        if header.is_empty() {
            return Err(CurveError::Row {
                path: path.to_path_buf(),
                line: 1,
                reason: "the header has no columns".into(),
            });
        }
        if let Some(bad) = header
            .iter()
            .find(|h| h.is_empty() || h.contains([',', '"', '\n', '\r']))
        {
            return Err(CurveError::Row {
                path: path.to_path_buf(),
                line: 1,
                reason: format!(
                    "header column `{bad}`: names must be non-empty and free of ',', '\"' and line breaks"
                ),
            });
        }
        let header_line = header.join(",");
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            fs::create_dir_all(parent).map_err(io_err(parent))?;
        }

        let existing = if append {
            match fs::read(path) {
                Ok(bytes) => Some(bytes),
                Err(e) if e.kind() == io::ErrorKind::NotFound => None,
                Err(e) => return Err(io_err(path)(e)),
            }
        } else {
            None
        };

        if let Some(bytes) = existing.filter(|b| !b.is_empty()) {
            // Everything up to the last newline is finished; the rest is an unfinished row.
            let complete = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            let found = match bytes[..complete].iter().position(|&b| b == b'\n') {
                Some(end) => String::from_utf8_lossy(&bytes[..end])
                    .trim_end_matches('\r')
                    .to_string(),
                // Only an unfinished first line: a header cut short is ours to rewrite.
                None => {
                    let partial = String::from_utf8_lossy(&bytes).to_string();
                    if !header_line.starts_with(partial.as_str()) {
                        return Err(CurveError::Header {
                            path: path.to_path_buf(),
                            expected: header_line,
                            found: partial,
                        });
                    }
                    return Self::create(path, &header_line, header.len());
                }
            };
            if found != header_line {
                return Err(CurveError::Header {
                    path: path.to_path_buf(),
                    expected: header_line,
                    found,
                });
            }
            let file = OpenOptions::new()
                .append(true)
                .open(path)
                .map_err(io_err(path))?;
            if complete < bytes.len() {
                file.set_len(complete as u64).map_err(io_err(path))?;
            }
            let lines = bytes[..complete].iter().filter(|&&b| b == b'\n').count();
            return Ok(Self {
                path: path.to_path_buf(),
                file,
                columns: header.len(),
                next_line: lines + 1,
            });
        }
        Self::create(path, &header_line, header.len())
    }

    fn create(path: &Path, header_line: &str, columns: usize) -> Result<Self, CurveError> {
        let mut file = File::create(path).map_err(io_err(path))?;
        file.write_all(format!("{header_line}\n").as_bytes())
            .and_then(|()| file.flush())
            .map_err(io_err(path))?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
            columns,
            next_line: 2,
        })
    }

    /// Appends one row (one value per header column) and hands it to the OS at once, in
    /// a single write.
    pub fn row(&mut self, values: &[f64]) -> Result<(), CurveError> {
        if values.len() != self.columns {
            return Err(CurveError::Row {
                path: self.path.clone(),
                line: self.next_line,
                reason: format!(
                    "{} values for {} header columns",
                    values.len(),
                    self.columns
                ),
            });
        }
        let mut line = values
            .iter()
            .map(|&v| format_value(v))
            .collect::<Vec<_>>()
            .join(",");
        line.push('\n');
        self.file
            .write_all(line.as_bytes())
            .and_then(|()| self.file.flush())
            .map_err(io_err(&self.path))?;
        self.next_line += 1;
        Ok(())
    }

    /// The file this log writes.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Formats one CSV value (see [`CsvLog`]); `str::parse::<f64>` reads every form back.
fn format_value(v: f64) -> String {
    if v.is_nan() {
        return "NaN".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf".into() } else { "-inf".into() };
    }
    let a = v.abs();
    if v.fract() == 0.0 && a < 1e15 {
        // Exact: |v| < 1e15 < 2^63. `as` maps -0.0 to 0.
        return format!("{}", v as i64);
    }
    if !(1e-3..1e15).contains(&a) {
        let s = format!("{v:.6e}");
        return match s.split_once('e') {
            Some((mantissa, exp)) => format!("{}e{exp}", trim_zeros(mantissa)),
            None => s,
        };
    }
    trim_zeros(&format!("{v:.6}")).to_string()
}

/// `1.500000` -> `1.5`, `2.000000` -> `2`.
fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

/// Reads a CSV written by CsvLog back: header and rows (for resuming and for plotting).
///
/// Empty lines are skipped; every other row must have one number per header column, or it
/// is a [`CurveError::Row`] naming its line. A last line without its newline is a row the
/// writer did not finish (killed mid-write; [`CsvLog`] writes a row and its newline in one
/// go) and is dropped, as [`CsvLog::open`] drops it on resume.
pub fn read_csv(path: &Path) -> Result<(Vec<String>, Vec<Vec<f64>>), CurveError> {
    let text = fs::read_to_string(path).map_err(io_err(path))?;
    let finished = text.ends_with('\n');
    let mut lines = text.lines().enumerate().peekable();
    let header: Vec<String> = match lines.next() {
        Some((_, h)) if !h.trim().is_empty() => {
            h.split(',').map(|c| c.trim().to_string()).collect()
        }
        _ => {
            return Err(CurveError::Row {
                path: path.to_path_buf(),
                line: 1,
                reason: "no header (empty file)".into(),
            });
        }
    };
    let mut rows = Vec::new();
    while let Some((i, line)) = lines.next() {
        if line.trim().is_empty() {
            continue;
        }
        if !finished && lines.peek().is_none() {
            break;
        }
        match parse_row(line, header.len()) {
            Ok(row) => rows.push(row),
            Err(reason) => {
                return Err(CurveError::Row {
                    path: path.to_path_buf(),
                    line: i + 1,
                    reason,
                });
            }
        }
    }
    Ok((header, rows))
}

fn parse_row(line: &str, columns: usize) -> Result<Vec<f64>, String> {
    let row = line
        .split(',')
        .map(|c| {
            let c = c.trim();
            c.parse::<f64>()
                .map_err(|_| format!("`{c}` is not a number"))
        })
        .collect::<Result<Vec<f64>, String>>()?;
    if row.len() != columns {
        return Err(format!("{} values for {columns} header columns", row.len()));
    }
    Ok(row)
}

/// Where [`plot_png`] looks for a TrueType font, in order, after `$JETPILOT_FONT`.
pub const FONT_PATHS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/truetype/liberation2/LiberationSans-Regular.ttf",
];

/// The plotters font family the font is registered under (and drawn with).
const FONT_FAMILY: &str = "sans-serif";

/// Finds and registers a font with plotters, once per process (`$JETPILOT_FONT` is read
/// then). `Ok(path)`: the font in use; `Err(what was tried)`.
fn ensure_font() -> &'static Result<PathBuf, String> {
    static FONT: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let mut candidates: Vec<PathBuf> = Vec::new();
        let env = std::env::var_os("JETPILOT_FONT").filter(|p| !p.is_empty());
        if let Some(p) = &env {
            candidates.push(PathBuf::from(p));
        }
        candidates.extend(FONT_PATHS.iter().map(PathBuf::from));
        register_first_font(&candidates).map_err(|tried| match env {
            Some(_) => tried,
            None => format!("{tried}; JETPILOT_FONT is not set"),
        })
    })
}

/// Registers the first of `candidates` that reads and parses as a font; `Err` lists them.
fn register_first_font(candidates: &[PathBuf]) -> Result<PathBuf, String> {
    for path in candidates {
        let Ok(bytes) = fs::read(path) else { continue };
        // plotters keeps `&'static` font bytes: leaked, once per process (`ensure_font`).
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        if plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, bytes).is_ok() {
            return Ok(path.clone());
        }
    }
    Err(candidates
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", "))
}

/// The warning [`plot_png`] returns when it drew `path` without text.
fn no_font_warning(path: &Path, tried: &str) -> String {
    format!(
        "{}: no font found, drawn without text (tried {tried}); install fonts-dejavu-core for labels, or set JETPILOT_FONT to a .ttf file",
        path.display()
    )
}

/// Distinct line colours (matplotlib's tab10), cycled.
const COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Values beyond this magnitude are skipped like infinities (plotters' tick placement
/// overflows on spans near `f64::MAX` and then does not finish).
const MAX_VALUE: f64 = 1e300;
/// The smallest value drawn on a logarithmic axis.
const MIN_LOG: f64 = 1e-300;
/// The most decades a logarithmic axis spans (its bottom is raised to fit).
const MAX_DECADES: i32 = 200;

fn drawable(v: f64) -> bool {
    v.is_finite() && v.abs() <= MAX_VALUE
}

/// The largest width or height [`plot_png`] draws.
const MAX_SIDE: u32 = 16384;
/// The smallest.
const MIN_SIDE: u32 = 16;

/// Draws the series as lines on one chart (title, x label, y label, legend), writes a PNG
/// of width x height. `log_y`: logarithmic y axis (for losses; non-positive values are
/// skipped). Returns Ok(Some(warning)) when drawn without text because no font was found,
/// Ok(None) otherwise.
///
/// NaN and infinite values (and magnitudes beyond 1e300) are skipped and break the line;
/// a point with no neighbour is drawn as a dot. A logarithmic axis spans at most 200
/// decades, down from the largest value. Series without points keep their legend entry. With no points at all
/// (or one x, or one y) the axes get a small range around what there is. The PNG is
/// written to a temporary file beside `path` and renamed over it, so a viewer never sees
/// half a file. Sides must be 16 to 16384 pixels.
pub fn plot_png(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log_y: bool,
    size: (u32, u32),
) -> Result<Option<String>, CurveError> {
    let (text, warning) = match ensure_font() {
        Ok(_) => (true, None),
        Err(tried) => (false, Some(no_font_warning(path, tried))),
    };
    let labels = Labels {
        title,
        x: x_label,
        y: y_label,
    };
    let drawn = Drawn {
        series,
        bands: &[],
        log_y,
    };
    plot_png_inner(path, &labels, &drawn, size, text)?;
    Ok(warning)
}

/// A shaded band around series `i` of a chart (seeds' mean ± sd): `(x, low, high)`
/// points in x order, drawn in the series' colour, lighter.
pub type Band = Vec<(f64, f64, f64)>;

/// [`plot_png`] (linear y) with a shaded band behind each series: `bands[i]` belongs to
/// `series[i]`; an empty band, or a missing one, draws none.
pub fn plot_png_with_bands(
    path: &Path,
    (title, x_label, y_label): (&str, &str, &str),
    series: &[Series],
    bands: &[Band],
    size: (u32, u32),
) -> Result<Option<String>, CurveError> {
    let (text, warning) = match ensure_font() {
        Ok(_) => (true, None),
        Err(tried) => (false, Some(no_font_warning(path, tried))),
    };
    let labels = Labels {
        title,
        x: x_label,
        y: y_label,
    };
    let drawn = Drawn {
        series,
        bands,
        log_y: false,
    };
    plot_png_inner(path, &labels, &drawn, size, text)?;
    Ok(warning)
}

/// What one chart shows.
struct Drawn<'a> {
    series: &'a [Series],
    bands: &'a [Band],
    log_y: bool,
}

struct Labels<'a> {
    title: &'a str,
    x: &'a str,
    y: &'a str,
}

/// [`plot_png`] with the font decision made: `text == false` draws no text at all.
fn plot_png_inner(
    path: &Path,
    labels: &Labels<'_>,
    drawn: &Drawn<'_>,
    (w, h): (u32, u32),
    text: bool,
) -> Result<(), CurveError> {
    let (series, log_y) = (drawn.series, drawn.log_y);
    let plot_err = |reason: String| CurveError::Plot {
        path: path.to_path_buf(),
        reason,
    };
    if !(MIN_SIDE..=MAX_SIDE).contains(&w) || !(MIN_SIDE..=MAX_SIDE).contains(&h) {
        return Err(plot_err(format!(
            "size {w}x{h}: sides must be {MIN_SIDE} to {MAX_SIDE} pixels"
        )));
    }

    // Split every series into runs of drawable points.
    let segments: Vec<Vec<Vec<(f64, f64)>>> = series
        .iter()
        .map(|s| {
            let mut runs = vec![Vec::new()];
            for &(x, y) in &s.points {
                let ok = drawable(x) && drawable(y) && (!log_y || y >= MIN_LOG);
                match runs.last_mut() {
                    Some(run) if ok => run.push((x, y)),
                    Some(run) if !run.is_empty() => runs.push(Vec::new()),
                    _ => {}
                }
            }
            runs.retain(|r| !r.is_empty());
            runs
        })
        .collect();
    let band_points: Vec<(f64, f64)> = drawn
        .bands
        .iter()
        .flatten()
        .flat_map(|&(x, lo, hi)| [(x, lo), (x, hi)])
        .filter(|&(x, y)| drawable(x) && drawable(y) && (!log_y || y >= MIN_LOG))
        .collect();
    let all = || {
        segments
            .iter()
            .flatten()
            .flatten()
            .chain(band_points.iter())
    };
    let bounds = |f: fn(&(f64, f64)) -> f64| {
        all().map(f).fold(None, |acc: Option<(f64, f64)>, v| {
            Some(acc.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))))
        })
    };
    let x_range = linear_range(bounds(|p| p.0), 0.0);
    let y_bounds = bounds(|p| p.1);

    let mut buf = vec![0u8; w as usize * h as usize * 3];
    let drawn = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let backend = BitMapBackend::<RGBPixel>::with_buffer_and_format(&mut buf, (w, h))
            .map_err(|e| e.to_string())?;
        let root = backend.into_drawing_area();
        let spec = Chart {
            labels,
            series,
            bands: drawn.bands,
            segments: &segments,
            text,
            log_y,
            scale: (f64::from(w.min(h)) / 500.0).clamp(0.5, 4.0),
        };
        if log_y {
            spec.draw(&root, x_range, log_range(y_bounds).log_scale())?;
        } else {
            spec.draw(&root, x_range, linear_range(y_bounds, 0.05))?;
        }
        root.present().map_err(|e| e.to_string())
    }));
    match drawn {
        Ok(Ok(())) => {}
        Ok(Err(reason)) => return Err(plot_err(reason)),
        Err(_) => return Err(plot_err("plotters panicked while drawing".into())),
    }

    let Some(img) = image::RgbImage::from_raw(w, h, buf) else {
        return Err(plot_err("frame buffer of the wrong size".into()));
    };
    let mut png = Vec::new();
    img.write_to(&mut io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| plot_err(format!("PNG encoding: {e}")))?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    let mut tmp_name = path.file_name().unwrap_or_default().to_os_string();
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    fs::write(&tmp, &png).map_err(io_err(&tmp))?;
    fs::rename(&tmp, path).map_err(|e| {
        let _ = fs::remove_file(&tmp);
        io_err(path)(e)
    })
}

/// A linear axis range around `bounds` with `pad` (a fraction of the span) on each side;
/// a sane range when there is no data or a single value.
fn linear_range(bounds: Option<(f64, f64)>, pad: f64) -> Range<f64> {
    let Some((lo, hi)) = bounds else {
        return 0.0..1.0;
    };
    if lo == hi {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        return (lo - d)..(hi + d);
    }
    let d = (hi - lo) * pad;
    if d.is_finite() && (lo - d).is_finite() && (hi + d).is_finite() {
        (lo - d)..(hi + d)
    } else {
        lo..hi
    }
}

/// A logarithmic axis range around positive `bounds`, a little wider; 1..10 with no data.
fn log_range(bounds: Option<(f64, f64)>) -> Range<f64> {
    let Some((lo, hi)) = bounds else {
        return 1.0..10.0;
    };
    let (lo, hi) = if lo == hi {
        (lo / 2.0, hi * 2.0)
    } else {
        (lo / 1.1, hi * 1.1)
    };
    // plotters counts decades as ln(hi / lo): keep the ratio finite and the count sane.
    let lo = lo.max(hi / 10f64.powi(MAX_DECADES));
    if lo.is_finite() && hi.is_finite() && 0.0 < lo && lo < hi {
        lo..hi
    } else {
        1.0..10.0
    }
}

/// A tick label: up to 6 significant digits without trailing zeros (`5`, `0.7`, `12.5`,
/// not `5.0` or `0.7000000000000001`), scientific from 1e6 up and below 1e-3.
fn tick_label(v: &f64) -> String {
    let v = *v;
    let a = v.abs();
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    if !(1e-3..1e6).contains(&a) {
        let s = format!("{v:.2e}");
        return match s.split_once('e') {
            Some((mantissa, exp)) => format!("{}e{exp}", trim_zeros(mantissa)),
            None => s,
        };
    }
    let decimals = (5 - a.log10().floor() as i32).clamp(0, 9) as usize;
    trim_zeros(&format!("{v:.decimals$}")).to_string()
}

/// What [`Chart::draw`] draws.
struct Chart<'a> {
    labels: &'a Labels<'a>,
    series: &'a [Series],
    bands: &'a [Band],
    /// Per series, its runs of drawable points.
    segments: &'a [Vec<Vec<(f64, f64)>>],
    text: bool,
    log_y: bool,
    /// Font and line scale: 1 for a 500 px short side.
    scale: f64,
}

/// The title's size in points: 22, or less (down to 11) where the title, `width(size)`
/// pixels wide, would not fit in `room` pixels. An unmeasurable title keeps its size.
fn fitted_title_size(room: f64, width: impl Fn(f64) -> Option<f64>) -> f64 {
    let mut size = 22.0;
    while size > 11.0 && width(size).is_some_and(|w| w > room) {
        size -= 1.0;
    }
    size
}

impl Chart<'_> {
    fn draw<Y>(
        &self,
        root: &DrawingArea<BitMapBackend<'_, RGBPixel>, Shift>,
        x_range: Range<f64>,
        y_spec: Y,
    ) -> Result<(), String>
    where
        Y: AsRangedCoord<Value = f64>,
        Y::CoordDescType: ValueFormatter<f64>,
    {
        let px = |v: f64| (v * self.scale).round().max(1.0) as u32;
        let font = |size: f64| (FONT_FAMILY, size * self.scale);
        root.fill(&WHITE).map_err(|e| e.to_string())?;

        let mut builder = ChartBuilder::on(root);
        builder.margin(px(15.0));
        if self.text {
            let room = f64::from(root.dim_in_pixel().0) - 2.0 * f64::from(px(15.0));
            let title_size = fitted_title_size(room, |size| {
                let style = TextStyle::from(font(size).into_font());
                root.estimate_text_size(self.labels.title, &style)
                    .ok()
                    .map(|(w, _)| f64::from(w))
            });
            builder
                .caption(self.labels.title, font(title_size))
                .x_label_area_size(px(45.0))
                .y_label_area_size(px(70.0));
        }
        let mut chart = builder
            .build_cartesian_2d(x_range, y_spec)
            .map_err(|e| e.to_string())?;

        let mut mesh = chart.configure_mesh();
        mesh.light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(200, 200, 200))
            .axis_style(BLACK.stroke_width(1))
            .x_label_formatter(&tick_label)
            .y_label_formatter(&tick_label);
        if self.log_y {
            // plotters' minor lines on a log axis bunch up above each decade.
            mesh.y_max_light_lines(0);
        }
        if self.text {
            mesh.x_desc(self.labels.x)
                .y_desc(self.labels.y)
                .label_style(font(13.0))
                .axis_desc_style(font(16.0));
        } else {
            // No label areas, so no labels are drawn; should one be, an unregistered
            // family makes it an error rather than a silent fallback.
            mesh.label_style(("jetpilot-no-font", 1.0))
                .axis_desc_style(("jetpilot-no-font", 1.0));
        }
        mesh.draw().map_err(|e| e.to_string())?;

        let (xs, ys) = (chart.x_range(), chart.y_range());
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(xs.start, ys.start), (xs.end, ys.end)],
                BLACK.stroke_width(1),
            )))
            .map_err(|e| e.to_string())?;

        for (i, band) in self.bands.iter().enumerate().take(self.series.len()) {
            let ok: Vec<(f64, f64, f64)> = band
                .iter()
                .copied()
                .filter(|&(x, lo, hi)| drawable(x) && drawable(lo) && drawable(hi))
                .collect();
            if ok.len() < 2 {
                continue;
            }
            let outline: Vec<(f64, f64)> = ok
                .iter()
                .map(|&(x, lo, _)| (x, lo))
                .chain(ok.iter().rev().map(|&(x, _, hi)| (x, hi)))
                .collect();
            let colour = COLOURS[i % COLOURS.len()];
            chart
                .draw_series(std::iter::once(Polygon::new(
                    outline,
                    colour.mix(0.18).filled(),
                )))
                .map_err(|e| e.to_string())?;
        }
        let width = px(2.0);
        for (i, (s, runs)) in self.series.iter().zip(self.segments).enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            let style = colour.stroke_width(width);
            let lines = chart
                .draw_series(
                    runs.iter()
                        .filter(|r| r.len() > 1)
                        .map(|r| PathElement::new(r.clone(), style)),
                )
                .map_err(|e| e.to_string())?;
            if self.text {
                let name = legend_name(s, runs);
                let len = px(20.0) as i32;
                lines
                    .label(name)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + len, y)], style));
            }
            chart
                .draw_series(
                    runs.iter()
                        .filter(|r| r.len() == 1)
                        .map(|r| Circle::new(r[0], px(3.0), colour.filled())),
                )
                .map_err(|e| e.to_string())?;
        }
        if self.text && !self.series.is_empty() {
            let corner = self.legend_corner(&chart, font(13.0));
            chart
                .configure_series_labels()
                .position(corner.position())
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(font(13.0))
                .draw()
                .map_err(|e| e.to_string())?;
        }
        Ok(())
    }

    /// The corner for the legend: where its box, sized as plotters will size it (the
    /// names in `font`, a 30 px sample line and 10 px margins), hides the fewest pixels
    /// of the drawn lines.
    fn legend_corner<X, Y>(
        &self,
        chart: &ChartContext<'_, BitMapBackend<'_, RGBPixel>, Cartesian2d<X, Y>>,
        font: (&str, f64),
    ) -> legend::Corner
    where
        X: Ranged<ValueType = f64>,
        Y: Ranged<ValueType = f64>,
    {
        let area = chart.plotting_area();
        let (w, h) = area.dim_in_pixel();
        let (bx, by) = area.get_base_pixel();
        let style = TextStyle::from(font.into_font());
        let mut text = MultiLineText::<_, String>::new((0, 0), &style);
        for (s, runs) in self.series.iter().zip(self.segments) {
            text.push_line(legend_name(s, runs));
        }
        let (tw, th) = text.estimate_dimension().unwrap_or((0, 0));
        let size = (tw + 30 + 2 * 10, th + 2 * 10);
        let runs: Vec<Vec<(f64, f64)>> = self
            .segments
            .iter()
            .flatten()
            .map(|run| {
                run.iter()
                    .map(|p| {
                        let (x, y) = chart.backend_coord(p);
                        (f64::from(x - bx), f64::from(y - by))
                    })
                    .collect()
            })
            .collect();
        let area = (
            i32::try_from(w).unwrap_or(i32::MAX),
            i32::try_from(h).unwrap_or(i32::MAX),
        );
        legend::quietest_corner(area, size, &runs)
    }
}

/// A series' legend entry: its name, marked where it has nothing drawable.
fn legend_name(s: &Series, runs: &[Vec<(f64, f64)>]) -> String {
    if runs.is_empty() {
        format!("{} (no data)", s.name)
    } else {
        s.name.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_png(path: &Path, size: (u32, u32)) {
        let bytes = fs::read(path).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{}", path.display());
        let img = image::open(path).unwrap();
        assert_eq!((img.width(), img.height()), size);
    }

    #[test]
    fn format_values() {
        assert_eq!(format_value(1.0), "1");
        assert_eq!(format_value(-3.0), "-3");
        assert_eq!(format_value(-0.0), "0");
        assert_eq!(format_value(0.5), "0.5");
        assert_eq!(format_value(1234.5678), "1234.5678");
        assert_eq!(format_value(0.1234567), "0.123457");
        assert_eq!(format_value(2.5e-5), "2.5e-5");
        assert_eq!(format_value(1e15), "1e15");
        assert_eq!(format_value(123456789012.0), "123456789012");
        assert_eq!(format_value(f64::NAN), "NaN");
        assert_eq!(format_value(f64::NEG_INFINITY), "-inf");
        for v in [2.5e-5, 1e15, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(format_value(v).parse::<f64>().unwrap(), v);
        }
        assert!(format_value(f64::NAN).parse::<f64>().unwrap().is_nan());
    }

    #[test]
    fn a_long_title_shrinks_to_fit_and_a_short_one_keeps_its_size() {
        // 0.5 px per character per point: 40 characters at 22 pt are 440 px.
        let width = |chars: f64| move |size: f64| Some(chars * size * 0.5);
        assert_eq!(fitted_title_size(870.0, width(40.0)), 22.0);
        // 100 characters fit in 870 px at 17 pt (850 px), not at 18 (900).
        assert_eq!(fitted_title_size(870.0, width(100.0)), 17.0);
        assert_eq!(
            fitted_title_size(870.0, width(1000.0)),
            11.0,
            "no smaller than 11"
        );
        assert_eq!(fitted_title_size(870.0, |_| None), 22.0);
    }

    #[test]
    fn font_lookup() {
        let dir = tempfile::tempdir().unwrap();
        let garbage = dir.path().join("garbage.ttf");
        fs::write(&garbage, b"not a font").unwrap();
        let missing = dir.path().join("missing.ttf");
        let tried = register_first_font(&[missing.clone(), garbage.clone()]).unwrap_err();
        assert!(
            tried.contains("missing.ttf") && tried.contains("garbage.ttf"),
            "{tried}"
        );
        let warning = no_font_warning(Path::new("/runs/a/loss.png"), &tried);
        assert!(
            warning.starts_with("/runs/a/loss.png: no font found"),
            "{warning}"
        );
        assert!(warning.contains("fonts-dejavu-core"), "{warning}");
        // A real font after the bad ones is taken (when this machine has one).
        if let Some(font) = FONT_PATHS.iter().map(PathBuf::from).find(|p| p.exists()) {
            let found = register_first_font(&[missing, garbage, font.clone()]).unwrap();
            assert_eq!(found, font);
        }
    }

    #[test]
    fn tick_labels() {
        let cases = [
            (5.0, "5"),
            (0.7000000000000001, "0.7"),
            (12.5, "12.5"),
            (0.0025, "0.0025"),
            (-3.0, "-3"),
            (0.0, "0"),
            (1e7, "1e7"),
            (2.5e-5, "2.5e-5"),
            (123456.0, "123456"),
        ];
        for (v, s) in cases {
            assert_eq!(tick_label(&v), s);
        }
    }

    #[test]
    fn csv_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run/log.csv");
        let mut log = CsvLog::open(&path, &["epoch", "loss", "reward"], false).unwrap();
        assert_eq!(log.path(), path);
        log.row(&[1.0, 0.5, 1234.5678]).unwrap();
        log.row(&[2.0, 0.25, -7.0]).unwrap();
        assert_eq!(
            fs::read_to_string(&path).unwrap(),
            "epoch,loss,reward\n1,0.5,1234.5678\n2,0.25,-7\n"
        );
        let (header, rows) = read_csv(&path).unwrap();
        assert_eq!(header, ["epoch", "loss", "reward"]);
        assert_eq!(rows, [vec![1.0, 0.5, 1234.5678], vec![2.0, 0.25, -7.0]]);
    }

    #[test]
    fn append_with_the_same_header_keeps_old_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.csv");
        let mut log = CsvLog::open(&path, &["epoch", "loss"], true).unwrap();
        log.row(&[1.0, 0.5]).unwrap();
        drop(log);
        let mut log = CsvLog::open(&path, &["epoch", "loss"], true).unwrap();
        log.row(&[2.0, 0.25]).unwrap();
        let err = log.row(&[3.0]).unwrap_err();
        // Rows are numbered by file line: header 1, rows 2 and 3, the rejected one 4.
        assert!(matches!(err, CurveError::Row { line: 4, .. }), "{err}");
        drop(log);
        let (_, rows) = read_csv(&path).unwrap();
        assert_eq!(rows, [vec![1.0, 0.5], vec![2.0, 0.25]]);

        // Without `append` the file starts over.
        let log = CsvLog::open(&path, &["epoch", "loss"], false).unwrap();
        drop(log);
        assert_eq!(read_csv(&path).unwrap().1.len(), 0);
    }

    #[test]
    fn append_cuts_an_unfinished_row() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.csv");
        fs::write(&path, "epoch,loss\n1,0.5\n2,0.2").unwrap();
        // read_csv drops the unfinished row ...
        assert_eq!(read_csv(&path).unwrap().1, [vec![1.0, 0.5]]);
        // ... and resuming cuts it off.
        let mut log = CsvLog::open(&path, &["epoch", "loss"], true).unwrap();
        log.row(&[2.0, 0.25]).unwrap();
        assert_eq!(
            fs::read_to_string(&path).unwrap(),
            "epoch,loss\n1,0.5\n2,0.25\n"
        );
    }

    #[test]
    fn a_different_header_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.csv");
        let mut log = CsvLog::open(&path, &["epoch", "loss"], false).unwrap();
        log.row(&[1.0, 0.5]).unwrap();
        drop(log);
        let err = CsvLog::open(&path, &["episode", "reward"], true).unwrap_err();
        assert!(matches!(err, CurveError::Header { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(
            msg.contains("epoch,loss") && msg.contains("episode,reward"),
            "{msg}"
        );
        // The old log is untouched.
        assert_eq!(read_csv(&path).unwrap().1, [vec![1.0, 0.5]]);
    }

    #[test]
    fn wrong_row_length_and_bad_headers_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.csv");
        let mut log = CsvLog::open(&path, &["a", "b"], false).unwrap();
        let err = log.row(&[1.0, 2.0, 3.0]).unwrap_err();
        assert!(matches!(err, CurveError::Row { line: 2, .. }), "{err:?}");
        assert!(
            err.to_string().contains("log.csv:2: 3 values for 2"),
            "{err}"
        );
        assert!(log.row(&[]).is_err());
        log.row(&[1.0, 2.0]).unwrap();

        assert!(CsvLog::open(&path, &[], false).is_err());
        assert!(CsvLog::open(&path, &["a,b"], false).is_err());
        assert!(CsvLog::open(&path, &[""], false).is_err());

        fs::write(&path, "a,b\n1,2\n3,x\n").unwrap();
        let err = read_csv(&path).unwrap_err();
        assert!(
            err.to_string().contains("log.csv:3: `x` is not a number"),
            "{err}"
        );
        fs::write(&path, "a,b\n1\n2,3\n").unwrap();
        assert!(matches!(
            read_csv(&path).unwrap_err(),
            CurveError::Row { line: 2, .. }
        ));
        fs::write(&path, "").unwrap();
        assert!(read_csv(&path).is_err());
        assert!(matches!(
            read_csv(&dir.path().join("missing.csv")).unwrap_err(),
            CurveError::Io { .. }
        ));
    }

    fn two_series() -> Vec<Series> {
        let train = (1..=50)
            .map(|e| (f64::from(e), 2.0 * (-0.08 * f64::from(e)).exp() + 0.02))
            .collect();
        let val = (1..=50)
            .map(|e| (f64::from(e), 2.2 * (-0.06 * f64::from(e)).exp() + 0.05))
            .collect();
        vec![
            Series {
                name: "train loss".into(),
                points: train,
            },
            Series {
                name: "validation loss".into(),
                points: val,
            },
        ]
    }

    #[test]
    fn plot_two_series_log_y() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("curves/loss.png");
        let warning = plot_png(
            &path,
            "loss",
            "epoch",
            "loss",
            &two_series(),
            true,
            (640, 400),
        )
        .unwrap();
        if let Some(w) = warning {
            eprintln!("{w}");
        }
        assert_png(&path, (640, 400));
        assert!(!dir.path().join("curves/loss.png.tmp").exists());
        // Linear too, and without text (as with no font installed).
        plot_png(
            &path,
            "loss",
            "epoch",
            "loss",
            &two_series(),
            false,
            (640, 400),
        )
        .unwrap();
        assert_png(&path, (640, 400));
        let labels = Labels {
            title: "t",
            x: "x",
            y: "y",
        };
        let drawn = Drawn {
            series: &two_series(),
            bands: &[],
            log_y: true,
        };
        plot_png_inner(&path, &labels, &drawn, (300, 200), false).unwrap();
        assert_png(&path, (300, 200));
    }

    #[test]
    fn plot_empty_and_degenerate_series() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("empty.png");
        let empty = Series {
            name: "nothing yet".into(),
            points: vec![],
        };
        for log_y in [false, true] {
            plot_png(&path, "t", "x", "y", &[], log_y, (200, 150)).unwrap();
            assert_png(&path, (200, 150));
            plot_png(
                &path,
                "t",
                "x",
                "y",
                std::slice::from_ref(&empty),
                log_y,
                (200, 150),
            )
            .unwrap();
            assert_png(&path, (200, 150));
        }
        let degenerate = [
            vec![(1.0, 0.5)],
            vec![(1.0, 0.0)],
            vec![(3.0, 2.0), (3.0, 2.0)],
            vec![(0.0, -1.0), (1.0, -1.0)],
            vec![(-1e300, 1e-300), (1e300, 1e300)],
            vec![(-1.7e308, -1.7e308), (1.7e308, 1.7e308), (0.0, 1.0)],
            vec![(0.0, 1.0), (1.0, 1.0 + 1e-15), (1.0 + 1e-15, 1.0)],
            vec![(0.0, 1e-310), (1.0, 1e-299)],
        ];
        for points in degenerate {
            for log_y in [false, true] {
                let s = Series {
                    name: "one".into(),
                    points: points.clone(),
                };
                plot_png(&path, "t", "x", "y", &[s], log_y, (200, 150))
                    .unwrap_or_else(|e| panic!("{points:?} log_y {log_y}: {e}"));
                assert_png(&path, (200, 150));
            }
        }
        assert!(matches!(
            plot_png(&path, "t", "x", "y", &[], false, (0, 100)).unwrap_err(),
            CurveError::Plot { .. }
        ));
    }

    #[test]
    fn plot_series_with_nan() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nan.png");
        let s = Series {
            name: "reward".into(),
            points: vec![
                (0.0, 1.0),
                (1.0, f64::NAN),
                (2.0, 3.0),
                (3.0, 2.0),
                (f64::INFINITY, 1.0),
                (5.0, f64::NEG_INFINITY),
                (6.0, 4.0),
                (7.0, -2.0),
                (8.0, 5.0),
            ],
        };
        for log_y in [false, true] {
            plot_png(
                &path,
                "reward",
                "episode",
                "reward",
                std::slice::from_ref(&s),
                log_y,
                (320, 240),
            )
            .unwrap();
            assert_png(&path, (320, 240));
        }
        let all_nan = Series {
            name: "nan".into(),
            points: vec![(f64::NAN, f64::NAN); 3],
        };
        plot_png(&path, "t", "x", "y", &[all_nan], false, (320, 240)).unwrap();
        assert_png(&path, (320, 240));
    }

    /// Writes `$CURVE_SAMPLE` (e.g. /tmp/curve_sample.png) for a look; skipped without it.
    #[test]
    fn sample_png() {
        let Some(path) = std::env::var_os("CURVE_SAMPLE") else {
            return;
        };
        let mut series = two_series();
        series.push(Series {
            name: "lr x 1000".into(),
            points: (1..=50)
                .map(|e| (f64::from(e), if e % 10 == 0 { f64::NAN } else { 0.3 }))
                .collect(),
        });
        series.push(Series {
            name: "empty".into(),
            points: vec![],
        });
        let warning = plot_png(
            Path::new(&path),
            "ResNet-18 steering: loss",
            "epoch",
            "MSE loss",
            &series,
            true,
            (800, 500),
        )
        .unwrap();
        assert_eq!(warning, None);
        let path = Path::new(&path);
        let labels = Labels {
            title: "reward",
            x: "episode",
            y: "return",
        };
        let reward = [Series {
            name: "return".into(),
            points: (0..200)
                .map(|e| {
                    (
                        f64::from(e),
                        (f64::from(e) / 30.0).sin() * 50.0 + f64::from(e),
                    )
                })
                .collect(),
        }];
        let linear = path.with_extension("linear.png");
        let drawn = Drawn {
            series: &reward,
            bands: &[],
            log_y: false,
        };
        plot_png_inner(&linear, &labels, &drawn, (800, 500), true).unwrap();
        let no_text = path.with_extension("notext.png");
        let drawn = Drawn {
            series: &series,
            bands: &[],
            log_y: true,
        };
        plot_png_inner(&no_text, &labels, &drawn, (800, 500), false).unwrap();
    }
}
