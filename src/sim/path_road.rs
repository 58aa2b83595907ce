//! The recorded path as the road (VISTA's premise: where the person drove is the road).
//!
//! A recording with poses (true ones from the simulator, or estimated by `jetpilot poses`)
//! becomes a [`Track`]: the path resampled every `spacing_m` along its length is the lane
//! centre. With `lanes = 1` (a lane between two tape lines) the road is that line plus or
//! minus half a lane width. With `lanes = 2` (the JetBot mat: the recording drove the right
//! lane of a two-lane road) the road reaches one more lane to the path's left, so leaving
//! the lane to the left costs reward but is not an intervention until the road's far edge
//! (or the replay's validity bound, half the road's width from the nearest recorded
//! frame). A path that comes back to where it started (within half a lane width, heading
//! within 45 degrees, after going at least a metre away) is closed into a loop at its first
//! return, and progress wraps there; otherwise the road is open and ends where the
//! recording does.
//!
//! No smoothing: a moving average would pull curves inwards, and the poses are already a
//! fused estimate. Recorded points closer than [`MIN_STEP_M`] to the last kept one (a car
//! standing still, its poses jittering) are dropped. The gap left where a loop closes is
//! spread along the whole loop, so the road has no sideways step there. An open road must
//! be at least [`MIN_OPEN_ROAD_M`] long.

use serde::{Deserialize, Serialize};

use super::track::Track;
use super::{Pose2, Result, SimError};

/// `[sim.path]`: the road made from the recording's path (`sim.road = "path"`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PathRoadConfig {
    /// Width of the one lane centred on the path, metres (the JetBot mat's lanes: 0.20).
    pub lane_width_m: f32,
    /// Spacing of the road's centre-line points along the path, metres.
    pub spacing_m: f32,
    /// Lanes of the road: 1, the path's own lane; 2, the path is the right lane of a
    /// two-lane road (the JetBot mat), the other lane to its left.
    pub lanes: u8,
}

impl Default for PathRoadConfig {
    fn default() -> Self {
        Self {
            lane_width_m: 0.20,
            spacing_m: 0.02,
            lanes: 1,
        }
    }
}

/// Recorded points closer than this to the last kept one are dropped.
pub const MIN_STEP_M: f64 = 0.003;
/// The shortest open road.
pub const MIN_OPEN_ROAD_M: f64 = 0.5;
/// How far a path must go from its start before a return counts as closing the loop.
pub const MIN_LOOP_AWAY_M: f64 = 1.0;
/// The largest heading difference between the start and a return that closes the loop.
pub const MAX_LOOP_HEADING_DEG: f64 = 45.0;

/// The road built from a path, with what was found.
#[derive(Debug, Clone)]
pub struct PathRoad {
    pub track: Track,
    /// The path closes into a loop.
    pub closed: bool,
    /// Length of the recorded path, metres (more than the road's length when the
    /// recording drove past the loop's start again).
    pub path_length_m: f64,
    /// The gap bridged to close the loop, metres (0 when open).
    pub closing_gap_m: f64,
}

impl PathRoadConfig {
    pub fn validate(&self) -> Result<()> {
        if !(self.lane_width_m.is_finite() && self.lane_width_m > 0.0 && self.lane_width_m <= 1.0) {
            return Err(SimError::Invalid(format!(
                "sim.path.lane_width_m = {}: allowed 0 < lane_width_m <= 1",
                self.lane_width_m
            )));
        }
        if !(self.spacing_m.is_finite() && self.spacing_m >= 0.005 && self.spacing_m <= 0.2) {
            return Err(SimError::Invalid(format!(
                "sim.path.spacing_m = {}: allowed 0.005 to 0.2 m",
                self.spacing_m
            )));
        }
        if !(1..=2).contains(&self.lanes) {
            return Err(SimError::Invalid(format!(
                "sim.path.lanes = {}: allowed 1 (the path's lane) or 2 (the path is the right lane of two)",
                self.lanes
            )));
        }
        Ok(())
    }
}

/// The road around the path through `poses` (in recording order; only x and y are used).
/// `origin` names the recording in errors.
pub fn road_from_path(poses: &[Pose2], cfg: &PathRoadConfig, origin: &str) -> Result<PathRoad> {
    cfg.validate()?;
    let mut raw: Vec<(f64, f64)> = Vec::with_capacity(poses.len());
    for p in poses {
        let q = (f64::from(p.x), f64::from(p.y));
        if !(q.0.is_finite() && q.1.is_finite()) {
            return Err(SimError::Track {
                origin: origin.to_string(),
                reason: format!("a recorded pose is not finite: ({}, {})", p.x, p.y),
            });
        }
        if raw.last().is_none_or(|&l| dist(l, q) >= MIN_STEP_M) {
            raw.push(q);
        }
    }
    let spacing = f64::from(cfg.spacing_m);
    let points = resample(&raw, spacing);
    let path_length_m = polyline_length(&raw);
    if points.len() < 3 {
        return Err(SimError::Track {
            origin: origin.to_string(),
            reason: format!(
                "the recorded path is {path_length_m:.3} m long: too short for a road (it needs a few {spacing} m steps)"
            ),
        });
    }
    let half = f64::from(cfg.lane_width_m) / 2.0;
    let (used, closed, closing_gap_m) = match loop_end(&points, half) {
        Some(k) => {
            // points[k] is where the path came back. The gap's sideways part (across the
            // start's direction) is spread along the loop, each point moved by its share
            // of the way round, so the road has no sideways step at the seam; the part
            // along the road only makes the closing piece a little longer or shorter.
            let raw_gap = (points[0].0 - points[k].0, points[0].1 - points[k].1);
            let t = {
                let (dx, dy) = (points[1].0 - points[0].0, points[1].1 - points[0].1);
                let n = dx.hypot(dy).max(1e-12);
                (dx / n, dy / n)
            };
            let along = raw_gap.0 * t.0 + raw_gap.1 * t.1;
            let gap = (raw_gap.0 - along * t.0, raw_gap.1 - along * t.1);
            let total = spacing * k as f64;
            let spread: Vec<(f64, f64)> = points[..k]
                .iter()
                .enumerate()
                .map(|(i, &(x, y))| {
                    let share = spacing * i as f64 / total;
                    (x + share * gap.0, y + share * gap.1)
                })
                .collect();
            (spread, true, raw_gap.0.hypot(raw_gap.1))
        }
        None => {
            let length = spacing * (points.len() - 1) as f64;
            if length < MIN_OPEN_ROAD_M {
                return Err(SimError::Track {
                    origin: origin.to_string(),
                    reason: format!(
                        "the recorded path is {length:.2} m long and does not come back to its start: an open road must be at least {MIN_OPEN_ROAD_M} m"
                    ),
                });
            }
            (points, false, 0.0)
        }
    };
    let used = &used[..];
    let (min_x, min_y, max_x, max_y) = used.iter().fold(
        (f64::MAX, f64::MAX, f64::MIN, f64::MIN),
        |(a, b, c, d), &(x, y)| (a.min(x), b.min(y), c.max(x), d.max(y)),
    );
    // The area the road lies in, from the origin (for a texture; the replay does not draw).
    let mat = (
        (max_x.max(0.0) - min_x.min(0.0)) + 0.5,
        (max_y.max(0.0) - min_y.min(0.0)) + 0.5,
    );
    let name = format!("path of {origin}");
    let lane_width = f64::from(cfg.lane_width_m);
    let track = if cfg.lanes == 2 {
        let centre = resample_closed(
            &offset_left(used, closed, lane_width / 2.0),
            closed,
            spacing,
        );
        Track::two_lanes_from_polyline(&name, &centre, closed, lane_width, mat)?
    } else {
        Track::from_polyline(&name, used, closed, lane_width, mat)?
    };
    Ok(PathRoad {
        track,
        closed,
        path_length_m,
        closing_gap_m,
    })
}

/// `points` moved `by` metres to their left (across the direction from the previous point to
/// the next; a loop wraps round, an open path's ends use their one neighbour).
pub fn offset_left(points: &[(f64, f64)], closed: bool, by: f64) -> Vec<(f64, f64)> {
    let n = points.len();
    (0..n)
        .map(|i| {
            let (a, b) = if closed {
                (points[(i + n - 1) % n], points[(i + 1) % n])
            } else {
                (points[i.saturating_sub(1)], points[(i + 1).min(n - 1)])
            };
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let len = dx.hypot(dy).max(1e-12);
            (points[i].0 - by * dy / len, points[i].1 + by * dx / len)
        })
        .collect()
}

/// [`resample`], and for a loop the piece from the last point back to the first too
/// (without repeating the first point at the end).
fn resample_closed(points: &[(f64, f64)], closed: bool, spacing: f64) -> Vec<(f64, f64)> {
    if !closed {
        return resample(points, spacing);
    }
    let mut round: Vec<(f64, f64)> = points.to_vec();
    if let Some(&first) = points.first() {
        round.push(first);
    }
    let mut out = resample(&round, spacing);
    // Drop a last point that (nearly) repeats the first.
    if out.len() > 3
        && let (Some(&last), Some(&first)) = (out.last(), out.first())
        && dist(last, first) < 0.5 * spacing
    {
        out.pop();
    }
    out
}

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

fn polyline_length(points: &[(f64, f64)]) -> f64 {
    points.windows(2).map(|w| dist(w[0], w[1])).sum()
}

/// Points every `spacing` metres along the polyline through `raw` (by arc length, linear
/// between recorded points), starting at the first; repeated points are skipped.
pub fn resample(raw: &[(f64, f64)], spacing: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let Some(&first) = raw.first() else {
        return out;
    };
    out.push(first);
    // Distance still to go to the next output point.
    let mut to_next = spacing;
    let mut prev = first;
    for &p in &raw[1..] {
        let mut seg = dist(prev, p);
        if !(seg.is_finite()) || seg < 1e-9 {
            continue;
        }
        let mut start = prev;
        while seg >= to_next {
            let t = to_next / seg;
            let q = (start.0 + t * (p.0 - start.0), start.1 + t * (p.1 - start.1));
            out.push(q);
            seg -= to_next;
            start = q;
            to_next = spacing;
        }
        to_next -= seg;
        prev = p;
    }
    out
}

/// The index at which the evenly spaced `points` first come back to their start: within
/// `tolerance` of it, heading within [`MAX_LOOP_HEADING_DEG`] of the start's, after having
/// been at least [`MIN_LOOP_AWAY_M`] (and more than twice `tolerance`) away; the point of
/// that return nearest the start. `None`: the path does not close.
pub fn loop_end(points: &[(f64, f64)], tolerance: f64) -> Option<usize> {
    if points.len() < 4 {
        return None;
    }
    let start = points[0];
    let heading = |i: usize| {
        let (a, b) = (points[i], points[i + 1]);
        (b.1 - a.1).atan2(b.0 - a.0)
    };
    let h0 = heading(0);
    let away_needed = MIN_LOOP_AWAY_M.max(2.0 * tolerance);
    let mut been_away = false;
    let mut i = 1;
    while i + 1 < points.len() {
        let d = dist(points[i], start);
        if d >= away_needed {
            been_away = true;
        }
        let turned = super::wrap_angle((heading(i) - h0) as f32).abs() as f64;
        if been_away && d <= tolerance && turned <= MAX_LOOP_HEADING_DEG.to_radians() {
            // The nearest point of this return.
            let mut best = i;
            while best + 2 < points.len()
                && dist(points[best + 1], start) < dist(points[best], start)
            {
                best += 1;
            }
            // At least three points stay, and the loop's last point is not the start itself.
            return (best >= 3).then_some(best);
        }
        i += 1;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::reward::{RewardParams, reward};

    #[test]
    fn resampling_spaces_points_evenly_along_the_path() {
        // An L: 0.05 m along x, then 0.05 m along y, sampled every 0.02 m.
        let raw = [(0.0, 0.0), (0.05, 0.0), (0.05, 0.0), (0.05, 0.05)];
        let p = resample(&raw, 0.02);
        let expected = [
            (0.0, 0.0),
            (0.02, 0.0),
            (0.04, 0.0),
            (0.05, 0.01),
            (0.05, 0.03),
            (0.05, 0.05),
        ];
        assert_eq!(p.len(), expected.len(), "{p:?}");
        for (a, b) in p.iter().zip(expected) {
            assert!(
                (a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12,
                "{p:?}"
            );
        }
    }

    /// A circle of radius `r` about (1, 1), counter-clockwise from angle 0, `turns` times round,
    /// `n` poses per turn.
    fn circle(r: f32, turns: f32, n: usize) -> Vec<Pose2> {
        let total = (turns * n as f32) as usize;
        (0..=total)
            .map(|i| {
                let a = i as f32 / n as f32 * std::f32::consts::TAU;
                Pose2::new(
                    1.0 + r * a.cos(),
                    1.0 + r * a.sin(),
                    a + std::f32::consts::FRAC_PI_2,
                )
            })
            .collect()
    }

    #[test]
    fn a_path_that_comes_back_closes_at_its_first_return() {
        // 1.2 turns of a 0.6 m circle (3.77 m a turn): closed after one turn.
        let road = road_from_path(&circle(0.6, 1.2, 400), &PathRoadConfig::default(), "t").unwrap();
        assert!(road.closed);
        assert!(road.track.is_closed());
        let lap = std::f64::consts::TAU * 0.6;
        assert!(
            (road.path_length_m - 1.2 * lap).abs() < 0.01,
            "{}",
            road.path_length_m
        );
        // The loop's centre line is one turn (chords of 2 cm: 0.3 mm short per metre).
        assert!(
            (road.track.length() as f64 - lap).abs() < 0.02,
            "{}",
            road.track.length()
        );
        assert!(road.closing_gap_m < 0.02, "{}", road.closing_gap_m);
        // Progress wraps: crossing the start forwards is a small step forwards.
        let len = road.track.length();
        assert!((road.track.progress_delta(len - 0.01, 0.01) - 0.02).abs() < 1e-4);
    }

    #[test]
    fn the_gap_where_a_loop_closes_is_spread_along_it() {
        // A spiral: the radius grows 6 cm over a turn, so the path comes back 6 cm outside
        // its start (drifting poses do that).
        let n = 400;
        let spiral: Vec<Pose2> = (0..=(1.2 * n as f32) as usize)
            .map(|i| {
                let a = i as f32 / n as f32 * std::f32::consts::TAU;
                let r = 0.6 + 0.06 * a / std::f32::consts::TAU;
                Pose2::new(1.0 + r * a.cos(), 1.0 + r * a.sin(), 0.0)
            })
            .collect();
        let road = road_from_path(&spiral, &PathRoadConfig::default(), "t").unwrap();
        assert!(road.closed);
        assert!(
            (road.closing_gap_m - 0.06).abs() < 0.01,
            "{}",
            road.closing_gap_m
        );
        // No sideways step at the seam: the heading just before and just after it differ
        // by about the 2 cm of turning between them (1.9 degrees), not the 72 degrees of a
        // 6 cm step over 2 cm.
        let t = &road.track;
        let before = t.pose_at(t.length() - 0.01, 0.0).heading;
        let after = t.pose_at(0.01, 0.0).heading;
        let turn = crate::sim::wrap_angle(after - before).abs().to_degrees();
        assert!(turn < 6.0, "{turn} degrees across the seam");
        // The start stays where it was recorded.
        let q = t.query(1.6, 1.0);
        assert!(q.lateral.abs() < 0.002, "{q:?}");
    }

    #[test]
    fn a_path_that_does_not_come_back_stays_open() {
        // Half a turn of a 0.6 m circle: it ends 1.2 m from where it started.
        let road = road_from_path(&circle(0.6, 0.5, 200), &PathRoadConfig::default(), "t").unwrap();
        assert!(!road.closed);
        assert!(!road.track.is_closed());
        assert_eq!(road.closing_gap_m, 0.0);
        // No wrap: progress is the plain difference, and s stays within the road.
        let len = road.track.length();
        assert!((road.track.progress_delta(len - 0.01, 0.01) + (len - 0.02)).abs() < 1e-4);
        let end = road.track.pose_at(len + 5.0, 0.0);
        let last = circle(0.6, 0.5, 200)[100];
        assert!(
            (end.x - last.x).abs() < 0.02 && (end.y - last.y).abs() < 0.02,
            "{end:?}"
        );
        // A return against the start's heading is no loop: out and back along a line.
        let mut there_and_back: Vec<Pose2> = (0..=150)
            .map(|i| Pose2::new(i as f32 * 0.01, 0.0, 0.0))
            .collect();
        there_and_back.extend(
            (0..=150)
                .rev()
                .map(|i| Pose2::new(i as f32 * 0.01, 0.001, 3.1)),
        );
        let road = road_from_path(&there_and_back, &PathRoadConfig::default(), "t").unwrap();
        assert!(!road.closed);
    }

    #[test]
    fn a_one_lane_road_around_the_path() {
        let road = road_from_path(&circle(0.4, 1.0, 400), &PathRoadConfig::default(), "t").unwrap();
        let t = &road.track;
        assert!(
            !road.closed,
            "a 0.4 m circle never goes a metre away from its start"
        );
        assert!(t.is_single_lane());
        assert_eq!(t.road_half_width(), 0.10);
        assert_eq!(t.lane_offset(), 0.0);
        // On the path the lane edge is 10 cm away: the paper's ideal distance.
        assert!((t.lane_edge_distance(1.4, 1.0) - 0.10).abs() < 1e-3);
        // 9 cm beside the path is on the road, 11 cm is not, on either side.
        assert!(t.on_road(1.49, 1.0));
        assert!(!t.on_road(1.51, 1.0));
        assert!(t.on_road(1.31, 1.0));
        assert!(!t.on_road(1.29, 1.0));
        // The robot drives the path: the lane pose at s = 0 is its start, facing along it.
        let p = t.lane_pose_at(0.0);
        assert!(
            (p.x - 1.4).abs() < 1e-3 && (p.y - 1.0).abs() < 1e-3,
            "{p:?}"
        );
        assert!(
            (p.heading - std::f32::consts::FRAC_PI_2).abs() < 0.05,
            "{p:?}"
        );
    }

    #[test]
    fn path_reward_equals_track_reward_when_the_path_is_the_lane_centre() {
        // The built-in mat's right-lane centre, one pose every 2 cm, as a recording's path.
        let mat = Track::jetbot_mat();
        let n = (mat.length() / 0.02) as usize;
        let lane: Vec<Pose2> = (0..=n + 25)
            .map(|i| mat.lane_pose_at(i as f32 * mat.length() / n as f32))
            .collect();
        let road = road_from_path(&lane, &PathRoadConfig::default(), "mat lane").unwrap();
        assert!(road.closed, "the lane is a loop");
        let path = &road.track;
        // The right lane is the outside of the mat's counter-clockwise loop: a full turn at
        // 10 cm more radius makes it 2 pi 0.1 = 0.63 m longer than the road's centre line.
        let longer = path.length() - mat.length();
        assert!(
            (longer - 0.1 * std::f32::consts::TAU).abs() < 0.03,
            "{longer}"
        );
        let params = RewardParams::default();
        let mut worst = 0.0f32;
        // Poses across the lane, every 7 cm of the lap, 0.1..0.5 m/s.
        for k in 0..(mat.length() / 0.07) as usize {
            let s = k as f32 * 0.07;
            for off in [-0.08, -0.04, 0.0, 0.03, 0.07] {
                let p = mat.pose_at(s, mat.lane_offset() + off);
                let speed = 0.1 + 0.4 * (k % 5) as f32 / 4.0;
                let on_mat = reward(mat.lane_edge_distance(p.x, p.y), speed, &params);
                let on_path = reward(path.lane_edge_distance(p.x, p.y), speed, &params);
                worst = worst.max((on_mat - on_path).abs());
                let d = mat.lane_edge_distance(p.x, p.y) - path.lane_edge_distance(p.x, p.y);
                assert!(
                    d.abs() < 0.002,
                    "s {s} offset {off}: lane edge distance {d} m apart"
                );
            }
        }
        assert!(worst < 0.01, "largest reward difference {worst}");
    }

    #[test]
    fn a_two_lane_path_road_is_the_mat_when_the_path_is_its_right_lane() {
        // The mat's right-lane centre as the path; lanes = 2: the road reaches one lane to
        // its left, so it is the mat's road again (its centre line and both edges).
        let mat = Track::jetbot_mat();
        let n = (mat.length() / 0.02) as usize;
        let lane: Vec<Pose2> = (0..=n + 25)
            .map(|i| mat.lane_pose_at(i as f32 * mat.length() / n as f32))
            .collect();
        let cfg = PathRoadConfig {
            lanes: 2,
            ..PathRoadConfig::default()
        };
        let road = road_from_path(&lane, &cfg, "mat lane").unwrap();
        assert!(road.closed);
        let path = &road.track;
        assert!(!path.is_single_lane());
        assert_eq!(path.road_half_width(), 0.20);
        assert_eq!(path.lane_offset(), -0.10);
        // Its centre line is the mat's: the same length within the chords' shortfall.
        assert!(
            (path.length() - mat.length()).abs() < 0.03,
            "{} against {}",
            path.length(),
            mat.length()
        );
        let params = RewardParams::default();
        let mut worst = 0.0f32;
        for k in 0..(mat.length() / 0.07) as usize {
            let s = k as f32 * 0.07;
            // Across the whole road: the right lane, the centre line, the left lane.
            for off in [-0.08, -0.04, 0.0, 0.07, 0.12, 0.2, 0.28] {
                let p = mat.pose_at(s, mat.lane_offset() + off);
                let on_mat = reward(mat.lane_edge_distance(p.x, p.y), 0.2, &params);
                let on_path = reward(path.lane_edge_distance(p.x, p.y), 0.2, &params);
                worst = worst.max((on_mat - on_path).abs());
                assert!(path.on_road(p.x, p.y), "s {s} offset {off}: off the road");
            }
            // Beyond either edge: off the road on both.
            for off in [-0.115, 0.315] {
                let p = mat.pose_at(s, mat.lane_offset() + off);
                assert!(!mat.on_road(p.x, p.y));
                assert!(!path.on_road(p.x, p.y), "s {s} offset {off}: on the road");
            }
        }
        assert!(worst < 0.01, "largest reward difference {worst}");
        // An open path: the offset centre line keeps its ends.
        let half_lap: Vec<Pose2> = lane[..n / 2].to_vec();
        let open = road_from_path(&half_lap, &cfg, "t").unwrap();
        assert!(!open.closed);
        let q = open.track.query(lane[3].x, lane[3].y);
        assert!((q.lateral + 0.10).abs() < 0.002, "{q:?}");
    }

    #[test]
    fn bad_paths_and_settings_are_named() {
        let still = vec![Pose2::new(0.3, 0.3, 0.0); 50];
        let e = road_from_path(&still, &PathRoadConfig::default(), "data/tub").unwrap_err();
        assert!(
            e.to_string().contains("data/tub") && e.to_string().contains("too short"),
            "{e}"
        );
        let cfg = PathRoadConfig {
            lane_width_m: 0.0,
            ..PathRoadConfig::default()
        };
        let e = road_from_path(&circle(0.5, 1.0, 100), &cfg, "t").unwrap_err();
        assert!(e.to_string().contains("sim.path.lane_width_m"), "{e}");
        let cfg = PathRoadConfig {
            lanes: 3,
            ..PathRoadConfig::default()
        };
        let e = road_from_path(&circle(0.5, 1.0, 100), &cfg, "t").unwrap_err();
        assert!(e.to_string().contains("sim.path.lanes = 3"), "{e}");
    }
}
