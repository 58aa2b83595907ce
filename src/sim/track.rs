//! The track: the JetBot mat's closed two-lane road, its file format, and every geometric
//! question the simulator asks about it.
//!
//! A track is described by its centre line: a start pose and a sequence of `line` and `arc`
//! segments (TOML, see `config/tracks/jetbot_mat.toml`). The road is two lanes wide
//! (`lane_width` each) with yellow solid edges at +-`road_half_width` and a white dashed line
//! on the centre line; the robot drives the centre of `drive_lane` ("right" by default), or
//! the centre line itself (`"centre"`: where people click in JetBot's road-following notebook).
//!
//! Loading checks that the centre line closes (end pose = start pose within 1 mm and
//! 0.1 degree), that every arc is wider than the road's half width, and that the whole road,
//! edge lines included, keeps 5 cm from the mat's sides; each error names the file, and the
//! segment, key and line where it applies.
//!
//! Queries ([`Track::query`]) find the exact nearest centre-line point on lines and arcs (no
//! sampling); they cost well under a microsecond per segment and run every simulator step.
//! [`Track::paint`] turns the road into strokes for the renderer.

use std::f64::consts::{PI, TAU};
use std::path::Path;

use serde::Deserialize;

use super::{PaintStroke, Pose2, Result, SimError, wrap_angle};

/// Width of the yellow edge lines, centred on +-`road_half_width`.
pub const EDGE_LINE_WIDTH_M: f32 = 0.02;
/// Width of the white dashed centre line.
pub const CENTRE_LINE_WIDTH_M: f32 = 0.012;
/// Dash and gap lengths of the centre line.
pub const CENTRE_DASH_M: (f32, f32) = (0.05, 0.05);
/// The road surface colour (dark grey).
pub const ROAD_RGB: [u8; 3] = [58, 58, 62];
/// The edge lines' colour (yellow).
pub const EDGE_RGB: [u8; 3] = [235, 190, 30];
/// The centre line's colour (white).
pub const CENTRE_RGB: [u8; 3] = [240, 240, 240];

/// How a road is painted: colours and line widths. The simulator's own mat is
/// [`RoadPaint::SIM`]; appearance randomisation (`sim::scene`) draws others, such as
/// JetBot's printed mat (black road, white lines on white) or tape on a floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoadPaint {
    /// The road surface; `None`: unpainted (the mat shows through, as with tape lines).
    pub road_rgb: Option<[u8; 3]>,
    /// Both edge lines, centred on the road's edges; `None`: none.
    pub edge_rgb: Option<[u8; 3]>,
    pub edge_width_m: f32,
    /// The centre line; `None`: none.
    pub centre_rgb: Option<[u8; 3]>,
    pub centre_width_m: f32,
    /// Dash and gap lengths in metres; `None`: a solid line.
    pub centre_dash_m: Option<(f32, f32)>,
    /// How each edge line is laid: `[at +half width, at -half width]` (the left and right
    /// of the track's direction).
    pub edges: [EdgeLine; 2],
}

/// How one edge line is laid: whole, missing, or broken into pieces (tape that peels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EdgeLine {
    Whole,
    Missing,
    /// Pieces of `piece_m` with gaps of `gap_m`, metres.
    Broken {
        piece_m: f32,
        gap_m: f32,
    },
}

impl RoadPaint {
    /// The simulator's own mat: dark grey road, yellow edges, white dashed centre line.
    pub const SIM: RoadPaint = RoadPaint {
        road_rgb: Some(ROAD_RGB),
        edge_rgb: Some(EDGE_RGB),
        edge_width_m: EDGE_LINE_WIDTH_M,
        centre_rgb: Some(CENTRE_RGB),
        centre_width_m: CENTRE_LINE_WIDTH_M,
        centre_dash_m: Some(CENTRE_DASH_M),
        edges: [EdgeLine::Whole; 2],
    };
}

/// The least distance between the road (edge lines included) and the mat's sides.
const MAT_MARGIN_M: f64 = 0.05;
/// Closure tolerances.
const CLOSE_POS_M: f64 = 0.001;
const CLOSE_HEADING_DEG: f64 = 0.1;
/// Largest chord error of painted arcs (well under the 1 cm asked of the renderer).
const PAINT_SAGITTA_M: f64 = 0.001;

const BUILTIN_TEXT: &str = include_str!("../../config/tracks/jetbot_mat.toml");
const BUILTIN_ORIGIN: &str = "built-in jetbot_mat (config/tracks/jetbot_mat.toml)";

/// Which lane the robot drives, relative to the direction of travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DriveLane {
    #[default]
    Right,
    Left,
    /// The road's centre line, the whole road its lane: JetBot's road-following notebook
    /// has people click the dashed centre line of its printed mat.
    Centre,
}

impl DriveLane {
    /// The name a track file gives it (serde's lowercase names).
    pub fn name(self) -> &'static str {
        match self {
            DriveLane::Right => "right",
            DriveLane::Left => "left",
            DriveLane::Centre => "centre",
        }
    }
}

/// The nearest centre-line point to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackQuery {
    /// Progress of the nearest centre-line point, `0..length`.
    pub s: f32,
    /// Signed offset from the road centre line, positive to the left of travel.
    pub lateral: f32,
    /// Centre-line heading at `s` (radians, -pi..=pi).
    pub tangent: f32,
}

// ----------------------------------------------------------------------------------------
// File format

fn default_mat() -> [f64; 2] {
    [1.83, 2.74]
}

fn default_lane_width() -> f64 {
    0.20
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TrackFile {
    name: String,
    #[serde(default = "default_mat")]
    mat: [f64; 2],
    #[serde(default = "default_lane_width")]
    lane_width: f64,
    #[serde(default)]
    drive_lane: DriveLane,
    /// x, y (m), heading (degrees).
    start: [f64; 3],
    #[serde(default)]
    segment: Vec<toml::Spanned<SegmentSpec>>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum SegmentKind {
    Line,
    Arc,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentSpec {
    kind: SegmentKind,
    length: Option<f64>,
    radius: Option<f64>,
    /// Degrees, positive turns left.
    angle: Option<f64>,
}

/// A checked segment of the centre line.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Piece {
    Line {
        length: f64,
    },
    /// `angle` in radians, positive turns left.
    Arc {
        radius: f64,
        angle: f64,
    },
}

/// The built-in layout, used only if the shipped file failed to load (the tests make sure
/// it does load and describes the same road).
const FALLBACK_START: [f64; 3] = [1.51, 1.20, 90.0];
const FALLBACK_PIECES: [(SegmentKind, f64, f64); 13] = [
    (SegmentKind::Line, 0.97, 0.0),
    (SegmentKind::Arc, 0.25, 90.0),
    (SegmentKind::Line, 0.69, 0.0),
    (SegmentKind::Arc, 0.25, 90.0),
    (SegmentKind::Line, 0.03221, 0.0),
    (SegmentKind::Arc, 0.5, 40.0),
    (SegmentKind::Arc, 0.5, -80.0),
    (SegmentKind::Arc, 0.5, 40.0),
    (SegmentKind::Line, 0.03221, 0.0),
    (SegmentKind::Arc, 0.5, 90.0),
    (SegmentKind::Line, 0.19, 0.0),
    (SegmentKind::Arc, 0.5, 90.0),
    (SegmentKind::Line, 0.38, 0.0),
];

// ----------------------------------------------------------------------------------------
// Geometry

#[derive(Debug, Clone, Copy, PartialEq)]
enum Geom {
    /// Unit direction.
    Line { dx: f64, dy: f64 },
    Arc {
        cx: f64,
        cy: f64,
        radius: f64,
        /// +1 turns left (centre on the left), -1 turns right.
        turn: f64,
        /// Angle of the start point as seen from the centre.
        a0: f64,
        /// Swept angle, positive.
        sweep: f64,
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Seg {
    /// Progress at the segment's start.
    s0: f64,
    len: f64,
    x0: f64,
    y0: f64,
    h0: f64,
    geom: Geom,
}

impl Seg {
    fn new(s0: f64, x0: f64, y0: f64, h0: f64, piece: Piece) -> Self {
        match piece {
            Piece::Line { length } => Seg {
                s0,
                len: length,
                x0,
                y0,
                h0,
                geom: Geom::Line {
                    dx: h0.cos(),
                    dy: h0.sin(),
                },
            },
            Piece::Arc { radius, angle } => {
                let turn = angle.signum();
                let (nx, ny) = (-h0.sin(), h0.cos());
                let cx = x0 + turn * radius * nx;
                let cy = y0 + turn * radius * ny;
                Seg {
                    s0,
                    len: radius * angle.abs(),
                    x0,
                    y0,
                    h0,
                    geom: Geom::Arc {
                        cx,
                        cy,
                        radius,
                        turn,
                        a0: (y0 - cy).atan2(x0 - cx),
                        sweep: angle.abs(),
                    },
                }
            }
        }
    }

    /// Point and heading at distance `u` (0..=len) along the segment.
    fn at(&self, u: f64) -> (f64, f64, f64) {
        match self.geom {
            Geom::Line { dx, dy } => (self.x0 + u * dx, self.y0 + u * dy, self.h0),
            Geom::Arc {
                cx,
                cy,
                radius,
                turn,
                a0,
                ..
            } => {
                let da = turn * u / radius;
                let a = a0 + da;
                (cx + radius * a.cos(), cy + radius * a.sin(), self.h0 + da)
            }
        }
    }

    fn end(&self) -> (f64, f64, f64) {
        self.at(self.len)
    }

    fn curvature(&self) -> f64 {
        match self.geom {
            Geom::Line { .. } => 0.0,
            Geom::Arc { radius, turn, .. } => turn / radius,
        }
    }

    /// Nearest point of this segment to (px, py) if it is closer than `best`:
    /// `(distance, u, lateral)`.
    fn nearest(&self, px: f64, py: f64, best: f64) -> Option<(f64, f64, f64)> {
        match self.geom {
            Geom::Line { dx, dy } => {
                let (vx, vy) = (px - self.x0, py - self.y0);
                let along = vx * dx + vy * dy;
                let across = dx * vy - dy * vx;
                if (0.0..=self.len).contains(&along) {
                    let d = across.abs();
                    (d < best).then_some((d, along, across))
                } else {
                    let u = along.clamp(0.0, self.len);
                    let (qx, qy) = (self.x0 + u * dx, self.y0 + u * dy);
                    let d = (px - qx).hypot(py - qy);
                    (d < best).then_some((d, u, across.signum() * d))
                }
            }
            Geom::Arc {
                cx,
                cy,
                radius,
                turn,
                a0,
                sweep,
            } => {
                let (qx, qy) = (px - cx, py - cy);
                let r = qx.hypot(qy);
                // |r - R| is the distance to the whole circle: a lower bound.
                if (r - radius).abs() >= best {
                    return None;
                }
                let phi = qy.atan2(qx);
                let ahead = (turn * (phi - a0)).rem_euclid(TAU);
                if ahead <= sweep {
                    let d = (r - radius).abs();
                    return Some((d, ahead * radius, turn * (radius - r)));
                }
                // Off the arc: the angularly nearer end is the nearer end.
                let u = if TAU - ahead <= ahead - sweep {
                    0.0
                } else {
                    self.len
                };
                let (ex, ey, eh) = self.at(u);
                let d = (px - ex).hypot(py - ey);
                if d >= best {
                    return None;
                }
                let across = eh.cos() * (py - ey) - eh.sin() * (px - ex);
                Some((d, u, across.signum() * d))
            }
        }
    }
}

/// A closed road on the mat.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    name: String,
    mat: (f64, f64),
    lane_width: f64,
    drive_lane: DriveLane,
    segs: Vec<Seg>,
    length: f64,
    /// A one-lane road centred on the centre line (a recorded path, [`Track::from_polyline`]):
    /// the robot drives the centre line and the edges are at +-`lane_width / 2`.
    single_lane: bool,
    /// The centre line closes into a loop (every track file does); an open one is a
    /// recording that does not come back to where it started.
    closed: bool,
}

impl Track {
    /// Parses and checks a track file's text; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Track> {
        let err = |reason: String| SimError::Track {
            origin: origin.to_string(),
            reason,
        };
        let de = toml::Deserializer::parse(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start));
            err(format!(
                "{}syntax: {}",
                line_prefix(line),
                e.message().trim()
            ))
        })?;
        let file: TrackFile = serde_path_to_error::deserialize(de).map_err(|e| {
            let key = clean_path(e.path());
            let inner = e.into_inner();
            let line = inner.span().map(|s| line_of(text, s.start));
            err(format!(
                "{}key `{key}`: {}",
                line_prefix(line),
                inner.message().trim()
            ))
        })?;
        let checked = check_file(&file, text).map_err(err)?;
        let track = Track::assemble(checked);
        track.check_closed().map_err(err)?;
        track
            .check_on_mat(|i| file.segment.get(i).map(|sp| line_of(text, sp.span().start)))
            .map_err(err)?;
        Ok(track)
    }

    /// Reads, parses and checks a track file.
    pub fn load(path: &Path) -> Result<Track> {
        let text = std::fs::read_to_string(path).map_err(|e| SimError::File {
            path: path.display().to_string(),
            reason: format!("cannot read the track: {e}"),
        })?;
        Track::from_toml(&text, &path.display().to_string())
    }

    /// The built-in JetBot mat (the text of `config/tracks/jetbot_mat.toml`).
    pub fn jetbot_mat() -> Track {
        match Track::from_toml(BUILTIN_TEXT, BUILTIN_ORIGIN) {
            Ok(t) => t,
            Err(e) => {
                // Unreachable while the unit tests pass; never panic in the simulator.
                tracing::error!("{e}; using the compiled-in copy of the layout");
                Track::fallback()
            }
        }
    }

    fn fallback() -> Track {
        let pieces = FALLBACK_PIECES
            .iter()
            .map(|&(kind, a, b)| match kind {
                SegmentKind::Line => Piece::Line { length: a },
                SegmentKind::Arc => Piece::Arc {
                    radius: a,
                    angle: b.to_radians(),
                },
            })
            .collect();
        Track::assemble(Checked {
            name: "jetbot_mat".into(),
            mat: (1.83, 2.74),
            lane_width: 0.20,
            drive_lane: DriveLane::Right,
            start: FALLBACK_START,
            pieces,
        })
    }

    fn assemble(c: Checked) -> Track {
        let (mut x, mut y, mut h) = (c.start[0], c.start[1], c.start[2].to_radians());
        let mut s = 0.0;
        let mut segs = Vec::with_capacity(c.pieces.len());
        for piece in c.pieces {
            let seg = Seg::new(s, x, y, h, piece);
            (x, y, h) = seg.end();
            s += seg.len;
            segs.push(seg);
        }
        Track {
            name: c.name,
            mat: c.mat,
            lane_width: c.lane_width,
            drive_lane: c.drive_lane,
            segs,
            length: s,
            single_lane: false,
            closed: true,
        }
    }

    /// A one-lane road `lane_width` wide whose centre line is the polyline through `points`
    /// (x, y in metres, at least two, consecutive points apart), closed back to the first
    /// point when `closed`. The robot drives the centre line. Each straight piece is placed
    /// where its points are (no chaining, so nothing accumulates); the heading turns at the
    /// vertices. `mat` is the area the road lies in, for the renderer's texture.
    pub fn from_polyline(
        name: &str,
        points: &[(f64, f64)],
        closed: bool,
        lane_width: f64,
        mat: (f64, f64),
    ) -> Result<Track> {
        let err = |reason: String| SimError::Track {
            origin: name.to_string(),
            reason,
        };
        if points.len() < 2 {
            return Err(err(format!(
                "a road needs at least 2 path points, got {}",
                points.len()
            )));
        }
        if !(lane_width.is_finite() && lane_width > 0.0 && lane_width <= 1.0) {
            return Err(err(format!(
                "lane width {lane_width} m: allowed 0 < lane_width <= 1 m"
            )));
        }
        let n = points.len();
        let pieces = if closed { n } else { n - 1 };
        let mut segs = Vec::with_capacity(pieces);
        let mut s = 0.0;
        for i in 0..pieces {
            let (x0, y0) = points[i];
            let (x1, y1) = points[(i + 1) % n];
            let length = (x1 - x0).hypot(y1 - y0);
            if !(length.is_finite() && length > 1e-6) {
                return Err(err(format!(
                    "path points {i} and {} coincide or are not finite: ({x0}, {y0}), ({x1}, {y1})",
                    (i + 1) % n
                )));
            }
            let h = (y1 - y0).atan2(x1 - x0);
            segs.push(Seg::new(s, x0, y0, h, Piece::Line { length }));
            s += length;
        }
        Ok(Track {
            name: name.to_string(),
            mat,
            lane_width,
            drive_lane: DriveLane::Right,
            segs,
            length: s,
            single_lane: true,
            closed,
        })
    }

    /// A road of two lanes, each `lane_width` wide, whose centre line (the dashed line
    /// between the lanes) is the polyline through `points`; the robot drives the right lane,
    /// as on the JetBot mat. Otherwise as [`Track::from_polyline`].
    pub fn two_lanes_from_polyline(
        name: &str,
        points: &[(f64, f64)],
        closed: bool,
        lane_width: f64,
        mat: (f64, f64),
    ) -> Result<Track> {
        let mut track = Self::from_polyline(name, points, closed, lane_width, mat)?;
        track.single_lane = false;
        Ok(track)
    }

    /// Whether the centre line is a loop (progress wraps at [`Track::length`]).
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// Whether the road is one lane centred on the centre line (a recorded path).
    pub fn is_single_lane(&self) -> bool {
        self.single_lane
    }

    /// The same road driven the other way round: the segments in reverse order with their
    /// turns mirrored, starting where this track starts, facing back. The drive lane stays
    /// the one on the robot's right (so a counter-clockwise layout becomes a clockwise one
    /// in the other lane).
    pub fn reversed(&self) -> Track {
        let Some(first) = self.segs.first() else {
            return self.clone();
        };
        if self.single_lane {
            // A recorded path: the same points the other way round.
            let mut points: Vec<(f64, f64)> = self.segs.iter().map(|g| (g.x0, g.y0)).collect();
            if !self.closed
                && let Some(last) = self.segs.last()
            {
                let (x, y, _) = last.end();
                points.push((x, y));
            }
            points.reverse();
            let name = format!("{} (reversed)", self.name);
            return Track::from_polyline(&name, &points, self.closed, self.lane_width, self.mat)
                .unwrap_or_else(|e| {
                    // The same points as this road's: unreachable; keep the road as it is.
                    tracing::error!("{e}; the path road is not reversed");
                    self.clone()
                });
        }
        let pieces = self
            .segs
            .iter()
            .rev()
            .map(|seg| match seg.geom {
                Geom::Line { .. } => Piece::Line { length: seg.len },
                Geom::Arc {
                    radius,
                    turn,
                    sweep,
                    ..
                } => Piece::Arc {
                    radius,
                    angle: -turn * sweep,
                },
            })
            .collect();
        Track::assemble(Checked {
            name: format!("{} (reversed)", self.name),
            mat: self.mat,
            lane_width: self.lane_width,
            drive_lane: self.drive_lane,
            start: [first.x0, first.y0, (first.h0 + PI).to_degrees()],
            pieces,
        })
    }

    fn check_closed(&self) -> std::result::Result<(), String> {
        let (Some(first), Some(last)) = (self.segs.first(), self.segs.last()) else {
            return Err("no segments".into());
        };
        let (ex, ey, eh) = last.end();
        let (gx, gy) = (ex - first.x0, ey - first.y0);
        let gap = gx.hypot(gy);
        let dh = wrap_f64(eh - first.h0).to_degrees();
        if gap > CLOSE_POS_M || dh.abs() > CLOSE_HEADING_DEG {
            return Err(format!(
                "the centre line does not close: the last segment ends at ({ex:.4}, {ey:.4}) \
                 heading {:.2} deg, {:.1} mm (dx {:+.4} m, dy {:+.4} m) and {dh:+.2} deg from \
                 the start pose ({:.4}, {:.4}) heading {:.2} deg; allowed {} mm and {} deg",
                wrap_f64(eh).to_degrees(),
                gap * 1000.0,
                gx,
                gy,
                first.x0,
                first.y0,
                wrap_f64(first.h0).to_degrees(),
                CLOSE_POS_M * 1000.0,
                CLOSE_HEADING_DEG,
            ));
        }
        Ok(())
    }

    /// Checks that the road with its edge lines keeps `MAT_MARGIN_M` from the mat's sides.
    fn check_on_mat(
        &self,
        line: impl Fn(usize) -> Option<usize>,
    ) -> std::result::Result<(), String> {
        let reach = self.lane_width + f64::from(EDGE_LINE_WIDTH_M);
        let (lo_x, hi_x) = (MAT_MARGIN_M, self.mat.0 - MAT_MARGIN_M);
        let (lo_y, hi_y) = (MAT_MARGIN_M, self.mat.1 - MAT_MARGIN_M);
        for (i, seg) in self.segs.iter().enumerate() {
            let (mut min_x, mut max_x, mut min_y, mut max_y) =
                (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            let mut add = |px: f64, py: f64| {
                min_x = min_x.min(px);
                max_x = max_x.max(px);
                min_y = min_y.min(py);
                max_y = max_y.max(py);
            };
            // The corners of the road's band at both ends...
            for u in [0.0, seg.len] {
                let (px, py, h) = seg.at(u);
                let (nx, ny) = (-h.sin(), h.cos());
                add(px + reach * nx, py + reach * ny);
                add(px - reach * nx, py - reach * ny);
            }
            // ...and, on an arc, the outer rim where it faces along an axis.
            if let Geom::Arc {
                cx,
                cy,
                radius,
                turn,
                a0,
                sweep,
            } = seg.geom
            {
                let outer = radius + reach;
                for k in 0..4 {
                    let a = f64::from(k) * PI / 2.0;
                    if (turn * (a - a0)).rem_euclid(TAU) <= sweep {
                        add(cx + outer * a.cos(), cy + outer * a.sin());
                    }
                }
            }
            let mut out = Vec::new();
            if min_x < lo_x {
                out.push(format!("x = {min_x:.3} m < {lo_x:.3}"));
            }
            if max_x > hi_x {
                out.push(format!("x = {max_x:.3} m > {hi_x:.3}"));
            }
            if min_y < lo_y {
                out.push(format!("y = {min_y:.3} m < {lo_y:.3}"));
            }
            if max_y > hi_y {
                out.push(format!("y = {max_y:.3} m > {hi_y:.3}"));
            }
            if !out.is_empty() {
                let kind = match seg.geom {
                    Geom::Line { .. } => "line",
                    Geom::Arc { .. } => "arc",
                };
                return Err(format!(
                    "{}segment {} ({kind}, key `segment[{i}]`) leaves the mat: the road with \
                     its edge lines reaches {}; it must keep {MAT_MARGIN_M} m from the sides \
                     of the {} x {} m mat",
                    line_prefix(line(i)),
                    i + 1,
                    out.join(", "),
                    self.mat.0,
                    self.mat.1,
                ));
            }
        }
        Ok(())
    }

    // ------------------------------------------------------------------------------------
    // Properties

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Length of the centre line (m).
    pub fn length(&self) -> f32 {
        self.length as f32
    }

    /// Width of one lane (m).
    pub fn lane_width(&self) -> f32 {
        self.lane_width as f32
    }

    /// Half the road's width: the lateral offset of the yellow edges (m). Two lanes, or one
    /// on a recorded path.
    pub fn road_half_width(&self) -> f32 {
        if self.single_lane {
            (self.lane_width / 2.0) as f32
        } else {
            self.lane_width as f32
        }
    }

    /// The mat's size (x, y) in metres.
    pub fn mat_size(&self) -> (f32, f32) {
        (self.mat.0 as f32, self.mat.1 as f32)
    }

    pub fn drive_lane(&self) -> DriveLane {
        self.drive_lane
    }

    /// Lateral offset of the driving lane's centre from the road centre line
    /// (-lane_width/2 for the right lane).
    pub fn lane_offset(&self) -> f32 {
        let half = (self.lane_width / 2.0) as f32;
        if self.single_lane {
            return 0.0;
        }
        match self.drive_lane {
            DriveLane::Right => -half,
            DriveLane::Left => half,
            DriveLane::Centre => 0.0,
        }
    }

    /// Number of centre-line segments.
    pub fn segment_count(&self) -> usize {
        self.segs.len()
    }

    /// The start pose of the centre line (s = 0).
    pub fn start_pose(&self) -> Pose2 {
        self.pose_at(0.0, 0.0)
    }

    // ------------------------------------------------------------------------------------
    // Queries

    /// The exact nearest centre-line point to (x, y).
    pub fn query(&self, x: f32, y: f32) -> TrackQuery {
        let (px, py) = (f64::from(x), f64::from(y));
        let mut best = f64::INFINITY;
        let mut hit = (0usize, 0.0, 0.0);
        for (i, seg) in self.segs.iter().enumerate() {
            if let Some((d, u, lat)) = seg.nearest(px, py, best) {
                best = d;
                hit = (i, u, lat);
            }
        }
        let (i, u, lateral) = hit;
        let Some(seg) = self.segs.get(i) else {
            return TrackQuery {
                s: 0.0,
                lateral: 0.0,
                tangent: 0.0,
            };
        };
        let (_, _, h) = seg.at(u);
        TrackQuery {
            s: self.wrap_s(seg.s0 + u) as f32,
            lateral: lateral as f32,
            tangent: wrap_f64(h) as f32,
        }
    }

    /// The pose at progress `s` (any value; wrapped to the lap) and lateral offset `lateral`
    /// from the centre line (+ left), heading along the road.
    pub fn pose_at(&self, s: f32, lateral: f32) -> Pose2 {
        let (x, y, h) = self.centre_at(f64::from(s));
        let lat = f64::from(lateral);
        Pose2::new(
            (x - lat * h.sin()) as f32,
            (y + lat * h.cos()) as f32,
            wrap_f64(h) as f32,
        )
    }

    /// The pose at progress `s` on the driving lane's centre.
    pub fn lane_pose_at(&self, s: f32) -> Pose2 {
        self.pose_at(s, self.lane_offset())
    }

    /// wrap(pose.heading - road heading at the nearest centre-line point).
    pub fn heading_error(&self, pose: &Pose2) -> f32 {
        wrap_angle(pose.heading - self.query(pose.x, pose.y).tangent)
    }

    /// Whether (x, y) is on the road (|lateral| <= road half width).
    pub fn on_road(&self, x: f32, y: f32) -> bool {
        self.query(x, y).lateral.abs() <= self.road_half_width()
    }

    /// Distance from (x, y) to the nearest boundary of the driving lane (its yellow edge or
    /// the dashed centre line, measured to the lines' middles), positive inside the lane,
    /// negative outside. At the lane centre it is lane_width/2 (0.10 m): the paper's ideal D.
    /// Driving the centre line, the lane is the whole road: the distance to the nearer edge.
    pub fn lane_edge_distance(&self, x: f32, y: f32) -> f32 {
        let lat = self.query(x, y).lateral;
        self.lane_half_width() - (lat - self.lane_offset()).abs()
    }

    /// Half the driving lane's width: half a lane, or the whole road's half width when the
    /// robot drives the centre line of a two-lane road.
    fn lane_half_width(&self) -> f32 {
        if self.drive_lane == DriveLane::Centre && !self.single_lane {
            self.road_half_width()
        } else {
            self.lane_width() / 2.0
        }
    }

    /// Signed progress from `s_prev` to `s_now`, taking the shorter way round the lap (so a
    /// crossing of the start line forward is a small positive number); on an open road,
    /// the plain difference.
    pub fn progress_delta(&self, s_prev: f32, s_now: f32) -> f32 {
        let len = self.length;
        if len <= 0.0 {
            return 0.0;
        }
        if !self.closed {
            return s_now - s_prev;
        }
        let d = (f64::from(s_now) - f64::from(s_prev)).rem_euclid(len);
        (if d > len / 2.0 { d - len } else { d }) as f32
    }

    /// Signed curvature of the centre line at `s` (1/m, positive turning left).
    pub fn curvature_at(&self, s: f32) -> f32 {
        self.seg_at(f64::from(s))
            .map(|(seg, _)| seg.curvature() as f32)
            .unwrap_or(0.0)
    }

    fn wrap_s(&self, s: f64) -> f64 {
        if self.length <= 0.0 {
            return 0.0;
        }
        if !self.closed {
            return s.clamp(0.0, self.length);
        }
        let w = s.rem_euclid(self.length);
        if w >= self.length { 0.0 } else { w }
    }

    /// The segment holding progress `s` (wrapped) and the distance into it.
    fn seg_at(&self, s: f64) -> Option<(&Seg, f64)> {
        let s = self.wrap_s(s);
        let i = self.segs.partition_point(|g| g.s0 <= s).saturating_sub(1);
        self.segs
            .get(i)
            .map(|seg| (seg, (s - seg.s0).clamp(0.0, seg.len)))
    }

    fn centre_at(&self, s: f64) -> (f64, f64, f64) {
        self.seg_at(s)
            .map(|(seg, u)| seg.at(u))
            .unwrap_or((0.0, 0.0, 0.0))
    }

    // ------------------------------------------------------------------------------------
    // Paint

    /// Strokes for the renderer in the simulator's own paint ([`RoadPaint::SIM`]): the road
    /// surface, the two yellow edges, the white dashed centre line.
    pub fn paint(&self) -> Vec<PaintStroke> {
        self.paint_with(&RoadPaint::SIM)
    }

    /// Strokes for the renderer in drawing order: the road surface, the two edge lines
    /// (centred on the road's edges), the centre line; each only where `style` has a
    /// colour for it. All are closed polylines; arcs are sampled to within 1 mm of chord
    /// error. The geometry (road width, lanes) stays the track's whatever the paint.
    pub fn paint_with(&self, style: &RoadPaint) -> Vec<PaintStroke> {
        let half = f64::from(self.road_half_width());
        let edge_w = style.edge_width_m.clamp(0.0, 0.1);
        let stations = self.paint_stations(half + f64::from(edge_w.max(EDGE_LINE_WIDTH_M)));
        let line = |lat: f64| -> Vec<(f32, f32)> {
            stations
                .iter()
                .map(|&s| {
                    let (x, y, h) = self.centre_at(s);
                    ((x - lat * h.sin()) as f32, (y + lat * h.cos()) as f32)
                })
                .collect()
        };
        let stroke = |lat: f64, width_m: f32, rgb: [u8; 3], dash: Option<(f32, f32)>| PaintStroke {
            points: line(lat),
            width_m,
            rgb,
            dash,
            closed: self.closed,
        };
        let mut out = Vec::with_capacity(4);
        if let Some(rgb) = style.road_rgb {
            out.push(stroke(0.0, (2.0 * half) as f32, rgb, None));
        }
        if let Some(rgb) = style.edge_rgb {
            for (lat, edge) in [half, -half].into_iter().zip(style.edges) {
                match edge {
                    EdgeLine::Whole => out.push(stroke(lat, edge_w, rgb, None)),
                    EdgeLine::Missing => {}
                    EdgeLine::Broken { piece_m, gap_m } => {
                        out.push(stroke(lat, edge_w, rgb, Some((piece_m, gap_m))))
                    }
                }
            }
        }
        if let Some(rgb) = style.centre_rgb
            && !self.single_lane
        {
            out.push(stroke(0.0, style.centre_width_m, rgb, style.centre_dash_m));
        }
        out
    }

    /// Progress values where the painted polylines get a vertex: each segment's start, and
    /// on arcs enough points that a curve offset by up to `reach` stays within
    /// `PAINT_SAGITTA_M` of its chords.
    fn paint_stations(&self, reach: f64) -> Vec<f64> {
        let mut out = Vec::new();
        for seg in &self.segs {
            let n = match seg.geom {
                Geom::Line { .. } => 1,
                Geom::Arc { radius, sweep, .. } => {
                    let r = radius + reach;
                    let step = 2.0 * (1.0 - PAINT_SAGITTA_M / r).clamp(-1.0, 1.0).acos();
                    (sweep / step).ceil().max(1.0) as usize
                }
            };
            for k in 0..n {
                out.push(seg.s0 + seg.len * k as f64 / n as f64);
            }
        }
        if !self.closed {
            out.push(self.length);
        }
        out
    }
}

/// A track file's values after the per-key checks.
struct Checked {
    name: String,
    mat: (f64, f64),
    lane_width: f64,
    drive_lane: DriveLane,
    start: [f64; 3],
    pieces: Vec<Piece>,
}

/// Per-key checks: ranges, and the keys each segment kind needs.
fn check_file(f: &TrackFile, text: &str) -> std::result::Result<Checked, String> {
    let finite_pos = |key: &str, v: f64, allowed: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(format!("key `{key}` = {v}: {allowed}"))
        }
    };
    finite_pos("mat[0]", f.mat[0], "must be a positive width in metres")?;
    finite_pos("mat[1]", f.mat[1], "must be a positive length in metres")?;
    finite_pos(
        "lane_width",
        f.lane_width,
        "must be a positive width in metres",
    )?;
    if f.lane_width > 1.0 {
        return Err(format!(
            "key `lane_width` = {}: allowed 0 < lane_width <= 1 m",
            f.lane_width
        ));
    }
    for (i, v) in f.start.iter().enumerate() {
        if !v.is_finite() {
            return Err(format!("key `start[{i}]` = {v}: must be a finite number"));
        }
    }
    if f.segment.is_empty() {
        return Err("no segments: add [[segment]] tables (kind = \"line\" or \"arc\")".into());
    }
    let half = f.lane_width;
    let mut pieces = Vec::with_capacity(f.segment.len());
    for (i, sp) in f.segment.iter().enumerate() {
        let seg = sp.get_ref();
        let at = |key: &str| {
            format!(
                "line {}: segment {} key `segment[{i}].{key}`",
                key_line(text, sp.span(), key),
                i + 1
            )
        };
        let unused = |key: &str, v: Option<f64>, kind: &str| match v {
            Some(_) => Err(format!("{}: not used by a {kind} segment", at(key))),
            None => Ok(()),
        };
        let need = |key: &str, v: Option<f64>, kind: &str| {
            v.ok_or_else(|| format!("{}: missing; a {kind} segment needs it", at(key)))
        };
        match seg.kind {
            SegmentKind::Line => {
                unused("radius", seg.radius, "line")?;
                unused("angle", seg.angle, "line")?;
                let length = need("length", seg.length, "line")?;
                if !(length.is_finite() && length > 0.0) {
                    return Err(format!(
                        "{} = {length}: must be a positive length in metres",
                        at("length")
                    ));
                }
                pieces.push(Piece::Line { length });
            }
            SegmentKind::Arc => {
                unused("length", seg.length, "arc")?;
                let radius = need("radius", seg.radius, "arc")?;
                let angle = need("angle", seg.angle, "arc")?;
                if !(radius.is_finite() && radius > 0.0) {
                    return Err(format!(
                        "{} = {radius}: must be a positive radius in metres (turn right with a \
                         negative angle)",
                        at("radius")
                    ));
                }
                if radius <= half {
                    return Err(format!(
                        "{} = {radius}: must be larger than the road's half width {half} m",
                        at("radius")
                    ));
                }
                if !(angle.is_finite() && angle != 0.0 && angle.abs() <= 360.0) {
                    return Err(format!(
                        "{} = {angle}: allowed -360 ..= 360 degrees, not 0",
                        at("angle")
                    ));
                }
                pieces.push(Piece::Arc {
                    radius,
                    angle: angle.to_radians(),
                });
            }
        }
    }
    Ok(Checked {
        name: f.name.clone(),
        mat: (f.mat[0], f.mat[1]),
        lane_width: f.lane_width,
        drive_lane: f.drive_lane,
        start: f.start,
        pieces,
    })
}

fn wrap_f64(a: f64) -> f64 {
    let r = a.rem_euclid(TAU);
    if r > PI { r - TAU } else { r }
}

fn line_prefix(line: Option<usize>) -> String {
    line.map(|l| format!("line {l}: ")).unwrap_or_default()
}

/// A serde path without the span wrapper's private keys.
fn clean_path(path: &serde_path_to_error::Path) -> String {
    use serde_path_to_error::Segment;
    let mut out = String::new();
    for seg in path.iter() {
        match seg {
            Segment::Seq { index } => out.push_str(&format!("[{index}]")),
            Segment::Map { key } => {
                if key.starts_with("$__") {
                    continue;
                }
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(key);
            }
            Segment::Enum { variant } => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(variant);
            }
            Segment::Unknown => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push('?');
            }
        }
    }
    if out.is_empty() { ".".into() } else { out }
}

/// The line of `key = ...` in the table whose span starts at `span.start` (a toml span of
/// an array-of-tables element covers only its header), else the table's first line.
fn key_line(text: &str, span: std::ops::Range<usize>, key: &str) -> usize {
    let body = text.get(span.start..).unwrap_or("");
    let mut offset = span.start;
    for (n, line) in body.split_inclusive('\n').enumerate() {
        let t = line.trim_start();
        if n > 0 && t.starts_with('[') {
            break;
        }
        if t.strip_prefix(key)
            .is_some_and(|rest| rest.trim_start().starts_with('='))
        {
            return line_of(text, offset);
        }
        offset += line.len();
    }
    line_of(text, span.start)
}

/// 1-based line number of a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text.get(..offset.min(text.len()))
        .map(|s| s.matches('\n').count() + 1)
        .unwrap_or(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn mat() -> Track {
        Track::from_toml(BUILTIN_TEXT, "jetbot_mat.toml").unwrap()
    }

    /// A tiny valid track text (a 1.0 x 1.6 m rounded rectangle) with `extra` appended to
    /// the header and the segments replaced by `segments` when given.
    fn oval(header_extra: &str, segments: Option<&str>) -> String {
        let default_segments = "\
[[segment]]
kind = \"line\"
length = 1.0
[[segment]]
kind = \"arc\"
radius = 0.3
angle = 180.0
[[segment]]
kind = \"line\"
length = 1.0
[[segment]]
kind = \"arc\"
radius = 0.3
angle = 180.0
";
        format!(
            "name = \"oval\"\nmat = [1.83, 2.74]\nstart = [1.2, 0.8, 90.0]\n{header_extra}\n{}",
            segments.unwrap_or(default_segments)
        )
    }

    #[test]
    fn shipped_track_loads_and_closes() {
        let t = mat();
        assert_eq!(t.name(), "jetbot_mat");
        assert_eq!(t.mat_size(), (1.83, 2.74));
        assert_eq!(t.lane_width(), 0.20);
        assert_eq!(t.road_half_width(), 0.20);
        assert_eq!(t.lane_offset(), -0.10);
        let last = t.segs.last().unwrap();
        let first = t.segs.first().unwrap();
        let (ex, ey, eh) = last.end();
        assert!((ex - first.x0).hypot(ey - first.y0) < 1e-3);
        assert!(wrap_f64(eh - first.h0).to_degrees().abs() < 0.1);
        // The loaded file and the compiled-in fallback describe the same road.
        let fb = Track::fallback();
        assert_eq!(fb.segs.len(), t.segs.len());
        for (a, b) in fb.segs.iter().zip(&t.segs) {
            assert!((a.len - b.len).abs() < 1e-12 && (a.x0 - b.x0).abs() < 1e-12);
            assert!((a.y0 - b.y0).abs() < 1e-12 && (a.h0 - b.h0).abs() < 1e-12);
        }
        assert_eq!(Track::jetbot_mat(), t);
    }

    #[test]
    fn shipped_track_has_sharp_and_gentle_corners() {
        let t = mat();
        let mut sharp = 0;
        let mut gentle = 0;
        for seg in &t.segs {
            if let Geom::Arc { radius, sweep, .. } = seg.geom {
                if radius <= 0.3 && (sweep.to_degrees() - 90.0).abs() < 1e-9 {
                    sharp += 1;
                }
                if radius >= 0.5 {
                    gentle += 1;
                }
            }
        }
        assert!(sharp >= 2, "{sharp}");
        assert!(gentle >= 2, "{gentle}");
    }

    #[test]
    fn shipped_file_on_disk_loads() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/tracks/jetbot_mat.toml");
        assert_eq!(Track::load(&p).unwrap(), mat());
    }

    #[test]
    fn length_is_the_sum_of_segments() {
        let t = mat();
        let lines = 0.97 + 0.69 + 0.03221 * 2.0 + 0.19 + 0.38;
        let arcs = 0.25 * PI / 2.0 * 2.0 + 0.5 * (160.0f64).to_radians() + 0.5 * PI / 2.0 * 2.0;
        assert!(
            (f64::from(t.length()) - (lines + arcs)).abs() < 1e-5,
            "{}",
            t.length()
        );
        let sum: f64 = t.segs.iter().map(|s| s.len).sum();
        assert!((t.length - sum).abs() < 1e-12);
    }

    #[test]
    fn reversed_is_the_same_road_the_other_way_round() {
        let t = mat();
        let r = t.reversed();
        assert!(r.check_closed().is_ok());
        assert!((r.length - t.length).abs() < 1e-9);
        assert_eq!(r.segment_count(), t.segment_count());
        let start = r.start_pose();
        assert!((start.x - 1.51).abs() < 1e-6 && (start.y - 1.20).abs() < 1e-6);
        assert!((start.heading + PI as f32 / 2.0).abs() < 1e-6, "{start:?}");
        // A point s along the reversed road is length - s along the original: same place,
        // opposite heading and curvature, mirrored lateral offset.
        for k in 1..60 {
            let s = k as f32 * 0.1;
            let p = r.pose_at(s, 0.07);
            let q = t.pose_at(t.length() - s, -0.07);
            assert!(
                (p.x - q.x).abs() < 1e-4 && (p.y - q.y).abs() < 1e-4,
                "s {s}"
            );
            assert!(wrap_angle(p.heading - q.heading - PI as f32).abs() < 1e-4);
            // Away from the joints, where the curvature steps.
            let (c, d) = (r.curvature_at(s), t.curvature_at(t.length() - s));
            if (r.curvature_at(s - 0.01) - r.curvature_at(s + 0.01)).abs() < 1e-6 {
                assert!((c + d).abs() < 1e-5, "s {s}: {c} vs {d}");
            }
        }
        // The clockwise mat turns right overall; twice reversed is the original road.
        let turned: f64 = r.segs.iter().map(|g| g.curvature() * g.len).sum();
        assert!((turned + TAU).abs() < 1e-9, "{turned}");
        let rr = r.reversed();
        for k in 0..60 {
            let s = k as f32 * 0.1;
            let (a, b) = (rr.pose_at(s, 0.0), t.pose_at(s, 0.0));
            assert!(
                (a.x - b.x).abs() < 1e-4 && (a.y - b.y).abs() < 1e-4,
                "s {s}"
            );
        }
    }

    #[test]
    fn query_inverts_pose_at() {
        let t = mat();
        let len = t.length();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut worst = (0.0f32, 0.0f32);
        let mut skipped = 0;
        for _ in 0..20_000 {
            let s = rng.random_range(0.0..len);
            let lat = rng.random_range(-0.3..0.3f32);
            let p = t.pose_at(s, lat);
            let q = t.query(p.x, p.y);
            // Inside a sharp corner (radius 0.25 m) a point more than the radius inward is
            // nearer the corner's other leg: it cannot map back. Skip those (< 6 cm of road).
            if inside_tight_corner(&t, s, lat) {
                skipped += 1;
                continue;
            }
            let ds = t.progress_delta(s, q.s).abs();
            let dl = (q.lateral - lat).abs();
            worst = (worst.0.max(ds), worst.1.max(dl));
            assert!(ds < 1e-4 && dl < 1e-4, "s {s} lat {lat} -> {q:?}");
            assert!((0.0..len).contains(&q.s));
            assert!(wrap_angle(q.tangent - p.heading).abs() < 1e-4);
        }
        eprintln!(
            "worst |ds| {} |dlat| {}, skipped {skipped}",
            worst.0, worst.1
        );
        assert!(skipped < 1000, "{skipped}");
    }

    /// Whether (s, lat) lies inward of a corner by at least (nearly) its radius, within
    /// 0.3 m of progress of it.
    fn inside_tight_corner(t: &Track, s: f32, lat: f32) -> bool {
        (-30..=30).any(|k| {
            let c = t.curvature_at(s + k as f32 * 0.01);
            c * lat > 0.0 && lat.abs() >= 1.0 / c.abs() - 0.01
        })
    }

    #[test]
    fn query_at_the_joints_and_the_start() {
        let t = mat();
        for seg in &t.segs {
            for lat in [-0.25f32, -0.1, 0.0, 0.1, 0.2] {
                let p = t.pose_at(seg.s0 as f32, lat);
                let q = t.query(p.x, p.y);
                assert!(t.progress_delta(seg.s0 as f32, q.s).abs() < 1e-4, "{q:?}");
                assert!((q.lateral - lat).abs() < 1e-4, "{q:?}");
            }
        }
        let start = t.start_pose();
        assert!((start.x - 1.51).abs() < 1e-6 && (start.y - 1.20).abs() < 1e-6);
        assert!((start.heading - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        let q = t.query(1.51, 1.20);
        assert!(q.s < 1e-4 || t.length() - q.s < 1e-4, "{q:?}");
    }

    #[test]
    fn pose_at_wraps_and_offsets_to_the_left() {
        let t = mat();
        let a = t.pose_at(0.3, 0.0);
        let b = t.pose_at(0.3 + t.length(), 0.0);
        assert!((a.x - b.x).abs() < 1e-5 && (a.y - b.y).abs() < 1e-5);
        let c = t.pose_at(-0.1, 0.0);
        let d = t.pose_at(t.length() - 0.1, 0.0);
        assert!((c.x - d.x).abs() < 1e-5 && (c.y - d.y).abs() < 1e-5);
        // Going up the right side (+y), left is -x.
        let l = t.pose_at(0.3, 0.1);
        assert!((l.x - (1.51 - 0.1)).abs() < 1e-6 && (l.y - 1.5).abs() < 1e-6);
        let lane = t.lane_pose_at(0.3);
        assert!((lane.x - 1.61).abs() < 1e-6);
    }

    #[test]
    fn lane_edge_distance_and_on_road() {
        let t = mat();
        for s in [0.0f32, 1.1, 2.0, 3.3, 4.4, 5.5] {
            let c = t.lane_pose_at(s);
            assert!((t.lane_edge_distance(c.x, c.y) - 0.10).abs() < 1e-5);
            // On the dashed centre line and on the right edge: 0; beyond: negative.
            let m = t.pose_at(s, 0.0);
            assert!(t.lane_edge_distance(m.x, m.y).abs() < 1e-5);
            let e = t.pose_at(s, -0.2);
            assert!(t.lane_edge_distance(e.x, e.y).abs() < 1e-5);
            let e = t.pose_at(s, -0.199);
            let o = t.pose_at(s, -0.25);
            assert!((t.lane_edge_distance(o.x, o.y) + 0.05).abs() < 1e-5);
            let l = t.pose_at(s, 0.1);
            assert!((t.lane_edge_distance(l.x, l.y) + 0.10).abs() < 1e-5);
            assert!(t.on_road(c.x, c.y) && t.on_road(l.x, l.y));
            assert!(t.on_road(e.x, e.y));
            let off = t.pose_at(s, -0.21);
            assert!(!t.on_road(off.x, off.y));
        }
        // The mat's corners and its middle are off the road.
        assert!(!t.on_road(0.02, 0.02));
        assert!(!t.on_road(0.915, 1.37));
        // A left-lane track measures from the other lane.
        let left = Track::from_toml(&oval("drive_lane = \"left\"", None), "o.toml").unwrap();
        assert_eq!(left.lane_offset(), 0.10);
        let c = left.lane_pose_at(0.5);
        assert!((left.lane_edge_distance(c.x, c.y) - 0.10).abs() < 1e-5);
        // A centre-line track drives the centre line, 0.20 m from either edge of the
        // 0.40 m road; 0.05 m to the right of it is 0.15 m from the right edge.
        let centre = Track::from_toml(&oval("drive_lane = \"centre\"", None), "o.toml").unwrap();
        assert_eq!(centre.lane_offset(), 0.0);
        let c = centre.lane_pose_at(0.5);
        let m = centre.pose_at(0.5, 0.0);
        assert!((c.x - m.x).abs() < 1e-6 && (c.y - m.y).abs() < 1e-6);
        assert!((centre.lane_edge_distance(c.x, c.y) - 0.20).abs() < 1e-5);
        let r = centre.pose_at(0.5, -0.05);
        assert!((centre.lane_edge_distance(r.x, r.y) - 0.15).abs() < 1e-5);
        let o = centre.pose_at(0.5, 0.25);
        assert!((centre.lane_edge_distance(o.x, o.y) + 0.05).abs() < 1e-5);
    }

    #[test]
    fn heading_error_and_curvature() {
        let t = mat();
        let mut p = t.pose_at(0.3, -0.05);
        assert!(t.heading_error(&p).abs() < 1e-6);
        p.heading += 0.2;
        assert!((t.heading_error(&p) - 0.2).abs() < 1e-5);
        p.heading = wrap_angle(p.heading + std::f32::consts::PI);
        assert!((t.heading_error(&p) - wrap_angle(0.2 + std::f32::consts::PI)).abs() < 1e-5);
        assert_eq!(t.curvature_at(0.3), 0.0);
        assert!((t.curvature_at(0.97 + 0.1) - 4.0).abs() < 1e-6);
        // The middle arc of the S-bulge turns right.
        let s_mid = 0.97 + 0.25 * PI as f32 / 2.0 * 2.0 + 0.69 + 0.03221 + 0.5 * 0.7 + 0.1;
        assert!((t.curvature_at(s_mid) + 2.0).abs() < 1e-6);
    }

    #[test]
    fn progress_delta_handles_the_wrap() {
        let t = mat();
        let len = t.length();
        assert!((t.progress_delta(1.0, 1.2) - 0.2).abs() < 1e-6);
        assert!((t.progress_delta(1.2, 1.0) + 0.2).abs() < 1e-6);
        assert!((t.progress_delta(len - 0.05, 0.03) - 0.08).abs() < 1e-5);
        assert!((t.progress_delta(0.03, len - 0.05) + 0.08).abs() < 1e-5);
        // Driving a lap in small steps adds up to the length.
        let mut total = 0.0;
        let mut prev = 0.0;
        for k in 1..=700 {
            let p = t.lane_pose_at(len * k as f32 / 700.0);
            let s = t.query(p.x, p.y).s;
            total += t.progress_delta(prev, s);
            prev = s;
        }
        assert!((total - len).abs() < 1e-3, "{total} vs {len}");
    }

    #[test]
    fn paint_strokes_lie_inside_the_mat() {
        let t = mat();
        let strokes = t.paint();
        assert_eq!(strokes.len(), 4);
        assert_eq!(strokes[0].width_m, 0.40);
        assert_eq!(strokes[0].rgb, ROAD_RGB);
        assert_eq!(strokes[1].rgb, EDGE_RGB);
        assert_eq!(strokes[2].width_m, 0.02);
        assert_eq!(strokes[3].dash, Some((0.05, 0.05)));
        assert_eq!(strokes[3].width_m, 0.012);
        let (w, h) = t.mat_size();
        for st in &strokes {
            assert!(st.closed && st.points.len() > 50);
            let r = st.width_m / 2.0;
            for &(x, y) in &st.points {
                assert!(x - r >= 0.05 - 1e-6 && x + r <= w - 0.05 + 1e-6, "{x}");
                assert!(y - r >= 0.05 - 1e-6 && y + r <= h - 0.05 + 1e-6, "{y}");
            }
        }
        // Edge strokes sit at +-0.2 m and the chords stay within 1 cm of the curve.
        for (st, lat) in [(&strokes[1], 0.2f32), (&strokes[2], -0.2)] {
            let pts = &st.points;
            for i in 0..pts.len() {
                let a = pts[i];
                let b = pts[(i + 1) % pts.len()];
                assert!((t.query(a.0, a.1).lateral - lat).abs() < 1e-4);
                let mid = ((a.0 + b.0) / 2.0, (a.1 + b.1) / 2.0);
                assert!((t.query(mid.0, mid.1).lateral - lat).abs() < 0.01);
            }
        }
    }

    fn err_of(text: &str) -> String {
        Track::from_toml(text, "bad.toml").unwrap_err().to_string()
    }

    #[test]
    fn a_track_that_does_not_close_is_an_error_naming_the_gap() {
        let text = oval(
            "",
            Some(
                "[[segment]]\nkind = \"line\"\nlength = 1.0\n[[segment]]\nkind = \"arc\"\n\
                 radius = 0.3\nangle = 180.0\n[[segment]]\nkind = \"line\"\nlength = 0.98\n\
                 [[segment]]\nkind = \"arc\"\nradius = 0.3\nangle = 180.0\n",
            ),
        );
        let err = err_of(&text);
        assert!(err.starts_with("track bad.toml:"), "{err}");
        assert!(err.contains("does not close"), "{err}");
        assert!(err.contains("20.0 mm"), "{err}");
        let err = err_of(&oval(
            "",
            Some("[[segment]]\nkind = \"arc\"\nradius = 0.3\nangle = 170.0\n"),
        ));
        assert!(
            err.contains("does not close") && err.contains("deg"),
            "{err}"
        );
        assert!(Track::from_toml(&oval("", None), "ok.toml").is_ok());
    }

    #[test]
    fn a_track_that_leaves_the_mat_names_the_segment() {
        // The same oval started further right: its right side leaves the mat.
        let text = oval("", None).replace("start = [1.2, 0.8, 90.0]", "start = [1.6, 0.8, 90.0]");
        let err = err_of(&text);
        assert!(err.contains("leaves the mat"), "{err}");
        assert!(err.contains("segment 1 (line, key `segment[0]`)"), "{err}");
        assert!(err.contains("line 5"), "{err}");
        // Upward: only the first arc (the top) leaves.
        let text = oval("", None).replace("start = [1.2, 0.8, 90.0]", "start = [1.2, 1.3, 90.0]");
        let err = err_of(&text);
        assert!(err.contains("segment 2 (arc"), "{err}");
        assert!(err.contains("y = "), "{err}");
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let err = err_of(&oval("colour = \"red\"", None));
        assert!(err.contains("line 4") && err.contains("colour"), "{err}");
        let err = err_of(&oval("", None).replace(
            "length = 1.0\n[[segment]]\nkind = \"arc\"",
            "lenght = 1.0\n[[segment]]\nkind = \"arc\"",
        ));
        assert!(err.contains("segment[0].lenght"), "{err}");
        assert!(err.contains("line 7"), "{err}");
        let err = err_of(&oval("", None).replacen("radius = 0.3", "radius = -0.3", 1));
        assert!(err.contains("segment[1].radius` = -0.3"), "{err}");
        assert!(err.contains("positive radius"), "{err}");
        assert!(err.contains("line 10"), "{err}");
        let err = err_of(&oval("", None).replacen("radius = 0.3", "radius = 0.15", 1));
        assert!(err.contains("half width 0.2"), "{err}");
        let err = err_of(&oval("", None).replacen("kind = \"arc\"", "kind = \"spiral\"", 1));
        assert!(err.contains("segment[1].kind"), "{err}");
        assert!(err.contains("line") && err.contains("arc"), "{err}");
        let err = err_of(&oval("", None).replacen("radius = 0.3\n", "", 1));
        assert!(
            err.contains("segment[1].radius") && err.contains("missing"),
            "{err}"
        );
        let err = err_of(&oval("", None).replacen("length = 1.0", "length = 1.0\nangle = 5.0", 1));
        assert!(
            err.contains("segment[0].angle") && err.contains("not used"),
            "{err}"
        );
        let err = err_of(&oval("lane_width = -0.2", None));
        assert!(err.contains("lane_width"), "{err}");
        let err = err_of(&oval("drive_lane = \"middle\"", None));
        assert!(err.contains("drive_lane") && err.contains("right"), "{err}");
        let err = err_of("name = \"x\"\nstart = [0.5, 0.5, 0.0]\n");
        assert!(err.contains("no segments"), "{err}");
        let err = err_of("name = \"x\"\nstart = [0.5, 0.5\n");
        assert!(err.contains("line 2") || err.contains("line 3"), "{err}");
    }

    #[test]
    fn missing_file_is_named() {
        let err = Track::load(Path::new("/nonexistent/t.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/t.toml"), "{err}");
    }

    #[test]
    fn query_is_fast() {
        let t = mat();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let pts: Vec<(f32, f32)> = (0..20_000)
            .map(|_| {
                (
                    rng.random_range(0.0..1.83f32),
                    rng.random_range(0.0..2.74f32),
                )
            })
            .collect();
        let t0 = std::time::Instant::now();
        let mut acc = 0.0;
        for &(x, y) in &pts {
            acc += t.query(x, y).lateral;
        }
        let per = t0.elapsed().as_secs_f64() / pts.len() as f64;
        eprintln!("query: {:.3} us per call ({acc})", per * 1e6);
        // Generous for unoptimised test builds on a busy machine.
        assert!(per < 50e-6, "{per}");
    }
}
