//! Random track layouts (`[sim.layouts]`): closed roads of lines and arcs on the mat, the
//! way JetBot owners tape their own, drawn from a seed.
//!
//! This module owns the generator and its settings. A layout is a rounded polygon: 5 to 8
//! corners at jittered angles around the mat's centre, each at a random fraction of the
//! largest ellipse that fits, so some corners turn the other way (S-bends); every corner is
//! replaced by an arc tangent to both sides with a radius drawn from `corner_radius_m`, as
//! tight as the JetBot mat's sharpest (0.25 m on the centre line) by default. The result is
//! written as a track file and read back through [`Track::from_toml`], so every layout has
//! passed the checks a hand-written one does (closure, radii, 5 cm from the mat's sides);
//! on top, the road may not come near itself. Draws that fail are drawn again.

use std::f64::consts::{PI, TAU};
use std::fmt::Write as _;

use rand::Rng;
use serde::{Deserialize, Serialize};

use super::track::{DriveLane, EDGE_LINE_WIDTH_M, Track};
use super::{Result, SimError};

/// Settings of the layout generator, `[sim.layouts]`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LayoutConfig {
    /// Draw random layouts (rendered frames only). Off by default, so `eval` drives the
    /// configured track; `--random-layouts` turns it on.
    pub enabled: bool,
    /// A new layout every so many simulated seconds of a `sim` run (0: only at the start),
    /// and at every episode of `train ddpg`.
    pub every_s: f32,
    /// Each lane's width, metres, least and most (the JetBot mat's: 0.20; the printed
    /// mat's road looks about 0.09 m a lane).
    pub lane_width_m: [f32; 2],
    /// Corner radii on the centre line, metres, least and most.
    pub corner_radius_m: [f32; 2],
    /// Each corner's radius is at least this many lane widths, whatever
    /// `corner_radius_m` draws: a wide road has wide corners. Above 1, the inside edge line
    /// never folds, so `corner_radius_m` may start below the widest lane.
    pub corner_lanes: f32,
    /// Number of corners, least and most (3..=12).
    pub corners: [u32; 2],
    /// Chance that a layout is driven clockwise.
    pub clockwise_probability: f32,
    /// The lane the robot drives: "right" (the track files' default), "left", or "centre"
    /// (the centre line, as people click it in JetBot's road-following notebook).
    pub drive_lane: DriveLane,
}

impl Default for LayoutConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            every_s: 20.0,
            lane_width_m: [0.09, 0.20],
            corner_radius_m: [0.25, 0.50],
            corner_lanes: 1.25,
            corners: [5, 8],
            clockwise_probability: 0.5,
            drive_lane: DriveLane::Right,
        }
    }
}

/// The JetBot mat's size, metres: what the tests draw layouts on.
pub const JETBOT_MAT_M: (f64, f64) = (1.83, 2.74);
/// Draws tried before giving up.
const MAX_DRAWS: usize = 500;
/// The largest turn at one corner, degrees: sharper would fold the road onto itself.
const MAX_TURN_DEG: f64 = 135.0;
/// The largest turn to the outside (a concave corner), degrees.
const MAX_OUTSIDE_TURN_DEG: f64 = 90.0;
/// The least straight between two corners, metres.
const MIN_LINE_M: f64 = 0.02;
/// The least gap between the road's edge lines where the road passes itself, metres.
const MIN_GAP_M: f64 = 0.05;

impl LayoutConfig {
    pub fn validate(&self) -> Result<()> {
        let bad = |what: String| Err(SimError::Invalid(format!("[sim.layouts] {what}")));
        let range = |name: &str, r: [f32; 2], lo: f32, hi: f32| {
            if r[0].is_finite() && r[1].is_finite() && lo <= r[0] && r[0] <= r[1] && r[1] <= hi {
                Ok(())
            } else {
                Err(SimError::Invalid(format!(
                    "[sim.layouts] {name} = [{}, {}]: need {lo} <= least <= most <= {hi}",
                    r[0], r[1]
                )))
            }
        };
        range("lane_width_m", self.lane_width_m, 0.03, 0.30)?;
        range("corner_radius_m", self.corner_radius_m, 0.10, 0.80)?;
        if !(self.corner_lanes.is_finite() && (0.0..=4.0).contains(&self.corner_lanes)) {
            return bad(format!(
                "corner_lanes = {}: must be in 0..=4",
                self.corner_lanes
            ));
        }
        if self.corner_lanes <= 1.0 && self.corner_radius_m[0] <= self.lane_width_m[1] {
            return bad(format!(
                "corner_radius_m's least {} must exceed lane_width_m's most {} (the road's \
                 half width), or corner_lanes must be above 1",
                self.corner_radius_m[0], self.lane_width_m[1]
            ));
        }
        let [least, most] = self.corners;
        if !(3 <= least && least <= most && most <= 12) {
            return bad(format!(
                "corners = [{least}, {most}]: need 3 <= least <= most <= 12"
            ));
        }
        if !(self.every_s.is_finite() && self.every_s >= 0.0) {
            return bad(format!("every_s = {}: must be >= 0", self.every_s));
        }
        if !(0.0..=1.0).contains(&self.clockwise_probability) {
            return bad(format!(
                "clockwise_probability = {}: must be in 0..=1",
                self.clockwise_probability
            ));
        }
        Ok(())
    }
}

/// A random layout on a `mat` (width, length in metres), ready to drive: drawn until one
/// passes every check, then reversed (clockwise) with `clockwise_probability`.
pub fn random_track<R: Rng + ?Sized>(
    cfg: &LayoutConfig,
    mat: (f64, f64),
    rng: &mut R,
) -> Result<Track> {
    cfg.validate()?;
    // The lane is drawn once, so wide roads, which fit a mat less often, come as often as
    // narrow ones. Rounded as the track file writes it, so the corners' least radius is
    // the file's.
    let lane = (uniform(rng, cfg.lane_width_m) as f64 * 1e4).round() / 1e4;
    for _ in 0..MAX_DRAWS {
        let Some(text) = draw_toml(cfg, lane, mat, rng) else {
            continue;
        };
        let Ok(track) = Track::from_toml(&text, "random layout") else {
            continue;
        };
        if !clears_itself(&track) {
            continue;
        }
        let clockwise = rng.random::<f32>() < cfg.clockwise_probability;
        return Ok(if clockwise { track.reversed() } else { track });
    }
    Err(SimError::Invalid(format!(
        "[sim.layouts]: no layout with {lane:.3} m lanes fits the {:.2} x {:.2} m mat in \
         {MAX_DRAWS} draws; allow narrower lanes, smaller corners or fewer of them",
        mat.0, mat.1
    )))
}

/// One draw with `lane`-wide lanes as a track file (counter-clockwise), or `None` where the
/// corners do not fit their sides.
pub fn draw_toml<R: Rng + ?Sized>(
    cfg: &LayoutConfig,
    lane: f64,
    mat: (f64, f64),
    rng: &mut R,
) -> Option<String> {
    let n = rng.random_range(cfg.corners[0]..=cfg.corners[1]) as usize;
    let (mw, mh) = mat;
    // The road (two lanes and the edge line) keeps 5 cm and a little from the sides; a
    // corner's arc stays inside its polygon corner, so the polygon may reach that far.
    let keep = lane + EDGE_LINE_WIDTH_M as f64 / 2.0 + 0.06;
    let (ax, ay) = (mw / 2.0 - keep, mh / 2.0 - keep);
    let (cx, cy) = (mw / 2.0, mh / 2.0);
    let phase = rng.random_range(0.0..TAU);
    let corners: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let a = phase + TAU * (i as f64 + rng.random_range(-0.3..0.3)) / n as f64;
            // Most corners far out, some pulled in: those turn to the outside.
            // (A convex corner's arc cuts inside it, so corners may lie a little beyond
            // the road's limits; the mat check refuses those that reach too far.)
            let r = if rng.random::<f64>() < 0.4 {
                rng.random_range(0.55..0.8)
            } else {
                rng.random_range(0.85..1.2)
            };
            // The ellipse point, pushed out towards the rectangle's corners.
            let (c, s) = (a.cos(), a.sin());
            let k = 1.0 / c.abs().max(s.abs()).max(1e-9);
            let square = (k * c, k * s);
            let blend = 0.6;
            let px = c * (1.0 - blend) + square.0 * blend;
            let py = s * (1.0 - blend) + square.1 * blend;
            (cx + ax * r * px, cy + ay * r * py)
        })
        .collect();
    fillet(&corners, lane, mat, cfg, rng)
}

/// The rounded polygon through `corners` (counter-clockwise) as a track file.
fn fillet<R: Rng + ?Sized>(
    corners: &[(f64, f64)],
    lane: f64,
    mat: (f64, f64),
    cfg: &LayoutConfig,
    rng: &mut R,
) -> Option<String> {
    let n = corners.len();
    let side = |i: usize| {
        let (a, b) = (corners[i], corners[(i + 1) % n]);
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len = dx.hypot(dy);
        (dx / len, dy / len, len)
    };
    // Turn at corner i: from side i-1 into side i, positive left.
    let mut turns = Vec::with_capacity(n);
    for i in 0..n {
        let (ix, iy, _) = side((i + n - 1) % n);
        let (ox, oy, _) = side(i);
        let turn = (ix * oy - iy * ox).atan2(ix * ox + iy * oy);
        let deg = turn.to_degrees();
        // (Two corners in one place give no direction: NaN.)
        if !deg.is_finite()
            || deg.abs() > MAX_TURN_DEG
            || deg < -MAX_OUTSIDE_TURN_DEG
            || deg.abs() < 5.0
        {
            return None;
        }
        turns.push(turn);
    }
    // Counter-clockwise overall.
    if (turns.iter().sum::<f64>() - TAU).abs() > 1e-6 {
        return None;
    }
    let mut radii: Vec<f64> = (0..n)
        .map(|_| (uniform(rng, cfg.corner_radius_m) as f64).max(cfg.corner_lanes as f64 * lane))
        .collect();
    // Where two corners' arcs do not fit their side, both get tighter, down to the least
    // radius.
    let least = (cfg.corner_radius_m[0] as f64).max(cfg.corner_lanes as f64 * lane);
    for i in 0..n {
        let j = (i + 1) % n;
        let (ti, tj) = ((turns[i].abs() / 2.0).tan(), (turns[j].abs() / 2.0).tan());
        let room = side(i).2 - MIN_LINE_M;
        let used = radii[i] * ti + radii[j] * tj;
        if used > room {
            let k = room / used;
            radii[i] = (radii[i] * k).max(least);
            radii[j] = (radii[j] * k).max(least);
        }
    }
    let tangent = |i: usize| radii[i] * (turns[i].abs() / 2.0).tan();
    let mut lines = Vec::with_capacity(n);
    for i in 0..n {
        let line = side(i).2 - tangent(i) - tangent((i + 1) % n);
        if line < MIN_LINE_M {
            return None;
        }
        lines.push(line);
    }
    // Start where side 0 leaves corner 0's arc, heading along it.
    let (dx, dy, _) = side(0);
    let t0 = tangent(0);
    let start = (corners[0].0 + dx * t0, corners[0].1 + dy * t0);
    let mut text = String::new();
    let _ = writeln!(text, "name = \"random\"");
    let _ = writeln!(text, "mat = [{}, {}]", mat.0, mat.1);
    let _ = writeln!(text, "lane_width = {lane:.4}");
    let _ = writeln!(text, "drive_lane = \"{}\"", cfg.drive_lane.name());
    let _ = writeln!(
        text,
        "start = [{:.6}, {:.6}, {:.6}]",
        start.0,
        start.1,
        dy.atan2(dx).to_degrees()
    );
    for (i, line) in lines.iter().enumerate() {
        let j = (i + 1) % n;
        let _ = writeln!(text, "\n[[segment]]\nkind = \"line\"\nlength = {line:.6}");
        let _ = writeln!(
            text,
            "\n[[segment]]\nkind = \"arc\"\nradius = {:.6}\nangle = {:.6}",
            radii[j],
            turns[j].to_degrees()
        );
    }
    Some(text)
}

fn uniform<R: Rng + ?Sized>(rng: &mut R, r: [f32; 2]) -> f32 {
    if r[1] > r[0] {
        rng.random_range(r[0]..=r[1])
    } else {
        r[0]
    }
}

/// Whether the road keeps `MIN_GAP_M` between its edge lines wherever it passes itself:
/// centre-line points more than a U-turn apart along the road must be at least a road
/// width, two edge lines and the gap apart.
pub fn clears_itself(track: &Track) -> bool {
    let half = track.road_half_width() as f64 + EDGE_LINE_WIDTH_M as f64 / 2.0;
    let need = 2.0 * half + MIN_GAP_M;
    let len = track.length() as f64;
    let step = 0.02;
    let n = (len / step).ceil() as usize;
    let pts: Vec<(f64, f64)> = (0..n)
        .map(|i| {
            let p = track.pose_at((i as f64 * len / n as f64) as f32, 0.0);
            (p.x as f64, p.y as f64)
        })
        .collect();
    // Along the road, a U-turn on the tightest allowed corner covers pi * need / 2.
    let apart = PI * need / 2.0 + 0.05;
    for i in 0..n {
        for j in i + 1..n {
            let along = (j - i) as f64 * len / n as f64;
            if along.min(len - along) < apart {
                continue;
            }
            let (a, b) = (pts[i], pts[j]);
            if (a.0 - b.0).hypot(a.1 - b.1) < need {
                return false;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn draw(seed: u64) -> Track {
        random_track(
            &LayoutConfig::default(),
            JETBOT_MAT_M,
            &mut ChaCha8Rng::seed_from_u64(seed),
        )
        .unwrap()
    }

    #[test]
    fn layouts_close_fit_the_mat_and_keep_clear_of_themselves() {
        let cfg = LayoutConfig::default();
        let (mut clockwise, mut tight, mut outside) = (0, 0, 0);
        for seed in 0..40 {
            let t = draw(seed);
            // from_toml checked closure and the 5 cm margin; check them again here by
            // walking the road's edges.
            assert!(clears_itself(&t), "seed {seed}");
            let half = t.road_half_width();
            let lw = t.lane_width();
            assert!((cfg.lane_width_m[0]..=cfg.lane_width_m[1]).contains(&lw));
            let steps = (t.length() / 0.01) as usize;
            let mut turned = 0.0f32;
            let mut prev = t.pose_at(0.0, 0.0).heading;
            let mut max_curv = 0.0f32;
            for k in 0..=steps {
                let s = t.length() * k as f32 / steps as f32;
                for side in [-1.0, 1.0] {
                    let p = t.pose_at(s, side * half);
                    assert!(
                        p.x > 0.05 && p.x < 1.78 && p.y > 0.05 && p.y < 2.69,
                        "seed {seed}: edge at ({}, {})",
                        p.x,
                        p.y
                    );
                }
                let h = t.pose_at(s, 0.0).heading;
                turned += crate::sim::wrap_angle(h - prev);
                prev = h;
                max_curv = max_curv.max(t.curvature_at(s).abs());
            }
            // One full turn, either way round.
            assert!(
                (turned.abs() - std::f32::consts::TAU).abs() < 0.05,
                "seed {seed}: turned {turned}"
            );
            if turned < 0.0 {
                clockwise += 1;
            }
            // Corners within the configured radii.
            assert!(
                max_curv <= 1.0 / cfg.corner_radius_m[0] + 1e-3,
                "seed {seed}: {max_curv}"
            );
            if max_curv >= 1.0 / 0.30 {
                tight += 1;
            }
            // A corner turning against the loop's sense: an S-bend.
            let sense = turned.signum();
            if (0..steps)
                .any(|k| t.curvature_at(t.length() * k as f32 / steps as f32) * sense < -0.5)
            {
                outside += 1;
            }
        }
        assert!((8..=32).contains(&clockwise), "{clockwise} of 40 clockwise");
        assert!(
            tight >= 10,
            "only {tight} of 40 have a corner of 0.30 m or tighter"
        );
        // 20, 32 and 8 of 40 when written.
        assert!(outside >= 6, "only {outside} of 40 have an S-bend");
    }

    #[test]
    fn wide_roads_have_wide_corners() {
        // Roads of 0.10 to 0.50 m (two lanes of 0.05 to 0.25), each corner at least 1.5
        // lanes round on the centre line, whatever corner_radius_m draws.
        let cfg = LayoutConfig {
            lane_width_m: [0.05, 0.25],
            corner_radius_m: [0.15, 0.50],
            corner_lanes: 1.5,
            corners: [3, 6],
            ..LayoutConfig::default()
        };
        cfg.validate().unwrap();
        let (mut narrow, mut wide) = (0, 0);
        for seed in 0..30 {
            let t = random_track(&cfg, JETBOT_MAT_M, &mut ChaCha8Rng::seed_from_u64(seed))
                .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            let road = 2.0 * t.road_half_width();
            assert!((0.10..=0.50 + 1e-4).contains(&road), "seed {seed}: {road}");
            let least = (1.5 * t.lane_width()).max(0.15);
            let steps = (t.length() / 0.01) as usize;
            let max_curv = (0..steps)
                .map(|k| t.curvature_at(t.length() * k as f32 / steps as f32).abs())
                .fold(0.0f32, f32::max);
            assert!(
                max_curv <= 1.0 / least + 1e-3,
                "seed {seed}: a {road:.2} m road turns at radius {:.3}",
                1.0 / max_curv
            );
            assert!(clears_itself(&t), "seed {seed}");
            narrow += usize::from(road < 0.2);
            wide += usize::from(road > 0.4);
        }
        assert!(
            narrow >= 3 && wide >= 3,
            "{narrow} narrow, {wide} wide of 30"
        );
        // Without the lane rule, corners narrower than the widest lane would fold.
        let folded = LayoutConfig {
            corner_lanes: 1.0,
            ..cfg
        };
        let e = folded.validate().unwrap_err().to_string();
        assert!(e.contains("corner_lanes must be above 1"), "{e}");
    }

    #[test]
    fn layouts_drive_the_configured_lane() {
        let centre = LayoutConfig {
            drive_lane: DriveLane::Centre,
            ..LayoutConfig::default()
        };
        let t = random_track(&centre, JETBOT_MAT_M, &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
        assert_eq!(t.drive_lane(), DriveLane::Centre);
        assert_eq!(t.lane_offset(), 0.0);
        // The same draw otherwise: only the lane differs from the default's.
        let right = draw(3);
        assert_eq!(right.drive_lane(), DriveLane::Right);
        assert_eq!(right.lane_offset(), -right.lane_width() / 2.0);
        assert_eq!(t.length(), right.length());
    }

    #[test]
    fn layouts_repeat_for_a_seed_and_change_with_it() {
        assert_eq!(draw(7), draw(7));
        assert_ne!(draw(7), draw(8));
    }

    #[test]
    fn a_rounded_square_has_the_worked_numbers() {
        // Corners of a 1.0 m square, radius 0.25 everywhere: each side keeps
        // 1.0 - 2 * 0.25 * tan(45) = 0.5 m of straight, and the track is
        // 4 * 0.5 + 2 * pi * 0.25 = 3.5708 m long.
        let cfg = LayoutConfig {
            corner_radius_m: [0.25, 0.25],
            lane_width_m: [0.2, 0.2],
            ..LayoutConfig::default()
        };
        let sq = [(0.4, 0.8), (1.4, 0.8), (1.4, 1.8), (0.4, 1.8)];
        let text = fillet(
            &sq,
            0.2,
            JETBOT_MAT_M,
            &cfg,
            &mut ChaCha8Rng::seed_from_u64(0),
        )
        .unwrap();
        let t = Track::from_toml(&text, "square").unwrap();
        assert!((t.length() - 3.570_796).abs() < 1e-4, "{}", t.length());
        assert!(text.contains("length = 0.500000"), "{text}");
        assert!(text.contains("angle = 90.000000"), "{text}");
        assert!(clears_itself(&t));
        // Clockwise corners are refused (a layout is drawn counter-clockwise).
        let cw: Vec<_> = sq.iter().rev().copied().collect();
        assert!(
            fillet(
                &cw,
                0.2,
                JETBOT_MAT_M,
                &cfg,
                &mut ChaCha8Rng::seed_from_u64(0)
            )
            .is_none()
        );
    }

    #[test]
    fn a_road_that_passes_itself_is_refused() {
        // 0.08 m lanes: edge lines at +-0.09 m, so the centre lines must be
        // 2 * 0.09 + 0.05 = 0.23 m apart. Two long sides 0.22 m apart are refused.
        let cfg = LayoutConfig {
            corner_radius_m: [0.09, 0.09],
            corner_lanes: 0.0,
            lane_width_m: [0.08, 0.08],
            ..LayoutConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let thin = [(0.4, 0.8), (1.4, 0.8), (1.4, 1.02), (0.4, 1.02)];
        let text = fillet(&thin, 0.08, JETBOT_MAT_M, &cfg, &mut rng).unwrap();
        assert!(!clears_itself(&Track::from_toml(&text, "thin").unwrap()));
        let wide = [(0.4, 0.8), (1.4, 0.8), (1.4, 1.04), (0.4, 1.04)];
        let text = fillet(&wide, 0.08, JETBOT_MAT_M, &cfg, &mut rng).unwrap();
        assert!(clears_itself(&Track::from_toml(&text, "wide").unwrap()));
    }

    #[test]
    fn settings_are_checked() {
        assert!(LayoutConfig::default().validate().is_ok());
        let bad = LayoutConfig {
            corner_radius_m: [0.15, 0.5],
            corner_lanes: 1.0,
            ..LayoutConfig::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(
            e.contains("corner_radius_m") && e.contains("half width"),
            "{e}"
        );
        let bad = LayoutConfig {
            corners: [2, 5],
            ..LayoutConfig::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("corners"));
    }
}
