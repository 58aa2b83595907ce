//! Loop closure without ground truth: where a drive passes the same place again, the
//! camera sees the same view, and right poses put the two frames in the same place facing
//! the same way. Views are matched by their thumbnails (16 x 12 grey levels, each
//! normalised to zero mean and unit variance, so exposure changes do not count). Among the
//! frames at least `min_gap_s` later, those that stand out from the rest (at most
//! `DISTINCT` of the median distance) are revisits; a frame's match is the most similar
//! frame of its first run of them (the next lap, not a later one). The gap between the
//! poses of matched frames is how far the path fails to close. Pure.

use super::super::{Pose2, wrap_angle};

/// Thumbnail size.
const THUMB_W: usize = 16;
const THUMB_H: usize = 12;
/// A match must be at most this share of the median distance to the frames it was
/// chosen among.
const DISTINCT: f32 = 0.35;

/// A frame and the later frame that sees the same view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopMatch {
    pub a: usize,
    pub b: usize,
    /// Mean squared difference of the normalised thumbnails.
    pub distance: f32,
}

/// How well a path closes over the matched frames.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Closure {
    pub pairs: usize,
    /// Median frames between matched frames (a lap, where the drive repeats a loop).
    pub period_frames: f32,
    /// Median and 90th percentile distance between matched frames' positions (m).
    pub gap_m: f32,
    pub gap_m_p90: f32,
    /// Median heading difference (degrees).
    pub gap_deg: f32,
    /// Median distance travelled between matched frames (m): the gap's scale.
    pub travelled_m: f32,
}

impl std::fmt::Display for Closure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.pairs == 0 {
            return write!(f, "no view seen again");
        }
        write!(
            f,
            "{} frames see a view again {:.0} frames later (median); there the path is {:.3} m apart (90 %: {:.3} m) after {:.2} m travelled, and {:.1} deg off",
            self.pairs,
            self.period_frames,
            self.gap_m,
            self.gap_m_p90,
            self.travelled_m,
            self.gap_deg
        )
    }
}

/// The normalised thumbnail of an RGB8 frame (`None`: a flat frame, or the wrong size).
pub fn thumbnail(rgb: &[u8], width: usize, height: usize) -> Option<Vec<f32>> {
    if width < THUMB_W || height < THUMB_H || rgb.len() != width * height * 3 {
        return None;
    }
    let mut sum = vec![0.0f32; THUMB_W * THUMB_H];
    let mut count = vec![0u32; THUMB_W * THUMB_H];
    for y in 0..height {
        let ty = y * THUMB_H / height;
        for x in 0..width {
            let tx = x * THUMB_W / width;
            let i = (y * width + x) * 3;
            let g = (f32::from(rgb[i]) + f32::from(rgb[i + 1]) + f32::from(rgb[i + 2])) / 3.0;
            sum[ty * THUMB_W + tx] += g;
            count[ty * THUMB_W + tx] += 1;
        }
    }
    let cells: Vec<f32> = sum
        .iter()
        .zip(&count)
        .map(|(s, &n)| s / n.max(1) as f32)
        .collect();
    let mean = cells.iter().sum::<f32>() / cells.len() as f32;
    let sd =
        (cells.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / cells.len() as f32).sqrt();
    (sd > 1e-3).then(|| cells.iter().map(|v| (v - mean) / sd).collect())
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>() / a.len() as f32
}

/// For each frame, its distinct match among the frames at least `min_gap_s` later
/// (`times_s` per frame; frames past its end take no part, nor do frames with no
/// thumbnail). A view that stays close from `min_gap_s` on (a car standing still) is not
/// a revisit until it was left and came back.
pub fn find_loops(thumbs: &[Option<Vec<f32>>], times_s: &[f64], min_gap_s: f64) -> Vec<LoopMatch> {
    let mut out = Vec::new();
    for (a, ta) in thumbs.iter().enumerate() {
        let Some(ta) = ta else { continue };
        let Some(&t_a) = times_s.get(a) else { break };
        let later: Vec<(usize, f32)> = thumbs
            .iter()
            .enumerate()
            .skip(a + 1)
            .filter(|(b, _)| times_s.get(*b).is_some_and(|t| t - t_a >= min_gap_s))
            .filter_map(|(b, tb)| tb.as_ref().map(|tb| (b, distance(ta, tb))))
            .collect();
        if later.len() < 8 {
            continue;
        }
        let mut ds: Vec<f32> = later.iter().map(|(_, d)| *d).collect();
        ds.sort_by(f32::total_cmp);
        let median = ds[ds.len() / 2];
        // The first revisit: the most similar frame of the first run of frames close
        // enough, in time order, after the view was left (a car standing still sees the
        // same view 2 s later without having gone anywhere: that first run is skipped).
        let close = DISTINCT * median;
        let first = later
            .iter()
            .skip_while(|(_, d)| *d <= close)
            .skip_while(|(_, d)| *d > close)
            .take_while(|(_, d)| *d <= close)
            .min_by(|x, y| x.1.total_cmp(&y.1));
        if let Some(&(b, distance)) = first {
            out.push(LoopMatch { a, b, distance });
        }
    }
    out
}

fn median(mut v: Vec<f32>) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    v[v.len() / 2]
}

/// How far `poses` (one per frame) are from closing at the matched frames.
pub fn closure(matches: &[LoopMatch], poses: &[Pose2]) -> Closure {
    let matches: Vec<&LoopMatch> = matches
        .iter()
        .filter(|m| m.a < poses.len() && m.b < poses.len())
        .collect();
    if matches.is_empty() {
        return Closure::default();
    }
    let travelled: Vec<f32> = std::iter::once(0.0)
        .chain(poses.windows(2).scan(0.0, |acc, w| {
            *acc += (w[1].x - w[0].x).hypot(w[1].y - w[0].y);
            Some(*acc)
        }))
        .collect();
    let gaps: Vec<f32> = matches
        .iter()
        .map(|m| (poses[m.b].x - poses[m.a].x).hypot(poses[m.b].y - poses[m.a].y))
        .collect();
    let mut sorted = gaps.clone();
    sorted.sort_by(f32::total_cmp);
    Closure {
        pairs: matches.len(),
        period_frames: median(matches.iter().map(|m| (m.b - m.a) as f32).collect()),
        gap_m: median(gaps),
        gap_m_p90: sorted[(sorted.len() * 9 / 10).min(sorted.len() - 1)],
        gap_deg: median(
            matches
                .iter()
                .map(|m| {
                    wrap_angle(poses[m.b].heading - poses[m.a].heading)
                        .abs()
                        .to_degrees()
                })
                .collect(),
        ),
        travelled_m: median(
            matches
                .iter()
                .map(|m| travelled[m.b] - travelled[m.a])
                .collect(),
        ),
    }
}

/// The heading turned from frame to frame, summed (radians, unwrapped), per frame.
fn turned(poses: &[Pose2]) -> Vec<f32> {
    std::iter::once(0.0)
        .chain(poses.windows(2).scan(0.0, |acc, w| {
            *acc += wrap_angle(w[1].heading - w[0].heading);
            Some(*acc)
        }))
        .collect()
}

/// How many times as much `poses` should turn for the matched frames to face the same way:
/// each match spans whole turns (the nearest number to what the poses turned, at least
/// one, so poses more than half a turn off per loop are misread), and the median of
/// `whole turns / turned` over the matches is the scale. `None`
/// where no match spans at least half a turn. Also returns how many matches counted.
pub fn turn_scale(matches: &[LoopMatch], poses: &[Pose2]) -> Option<(f32, usize)> {
    let cum = turned(poses);
    let full = std::f32::consts::TAU;
    let scales: Vec<f32> = matches
        .iter()
        .filter(|m| m.a < poses.len() && m.b < poses.len())
        .filter_map(|m| {
            let t = cum[m.b] - cum[m.a];
            let turns = (t / full).round();
            (turns != 0.0).then(|| turns * full / t)
        })
        .collect();
    (!scales.is_empty()).then(|| (median(scales.clone()), scales.len()))
}

#[cfg(test)]
mod tests {
    use super::super::super::camera::CameraModel;
    use super::super::car_drive_test::{render, test_car};
    use super::super::compose;
    use super::*;

    #[test]
    fn thumbnails_are_normalised_and_ignore_exposure() {
        let (w, h) = (32, 24);
        let rgb: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let g = ((i % w) * 3) as u8;
                [g, g, g]
            })
            .collect();
        let t = thumbnail(&rgb, w, h).expect("a thumbnail");
        assert_eq!(t.len(), 16 * 12);
        let mean = t.iter().sum::<f32>() / t.len() as f32;
        let var = t.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / t.len() as f32;
        assert!(
            mean.abs() < 1e-5 && (var - 1.0).abs() < 1e-4,
            "{mean} {var}"
        );
        // Twice as bright, plus 10: the same thumbnail.
        let bright: Vec<u8> = rgb.iter().map(|v| v * 2 + 10).collect();
        let tb = thumbnail(&bright, w, h).expect("a thumbnail");
        assert!(distance(&t, &tb) < 1e-4);
        assert_eq!(thumbnail(&vec![7u8; w * h * 3], w, h), None, "flat");
        assert_eq!(thumbnail(&rgb, w, h - 1), None, "wrong size");
    }

    #[test]
    fn a_circle_driven_twice_closes_with_the_true_poses_and_not_with_a_short_turn() {
        // Full lock at 0.7 m/s: a 0.8 m circle, 5.03 m round, 7.18 s, 143.6 frames at 20 Hz.
        let camera = CameraModel::donkeycar(160, 120);
        let mut car = test_car(0.0);
        let mut pose = Pose2::default();
        let (mut thumbs, mut truth, mut times) = (Vec::new(), Vec::new(), Vec::new());
        // 3 s standing still first: the same view 2 s later is not a loop.
        for k in 0..60 {
            thumbs.push(thumbnail(&render(&camera, &pose), 160, 120));
            truth.push(pose);
            times.push(k as f64 * 0.05);
        }
        for k in 60..280 {
            if k > 60 {
                pose = compose(&pose, &car.advance(-1.0, 0.25, 0.05));
            }
            let rgb = render(&camera, &pose);
            thumbs.push(thumbnail(&rgb, 160, 120));
            truth.push(pose);
            times.push(k as f64 * 0.05);
        }
        let matches = find_loops(&thumbs, &times[..times.len() - 1], 2.0);
        assert!(
            matches.iter().all(|m| m.b < times.len() - 1),
            "past the times"
        );
        // Frames 0..76 of the drive (and the still frames, whose view the drive comes
        // back to) are seen again one lap after the car set off, give or take a frame.
        assert!(matches.len() >= 60, "{} matches", matches.len());
        assert!(
            matches
                .iter()
                .all(|m| (m.b - m.a.max(60)).abs_diff(144) <= 1),
            "{:?}",
            matches.iter().map(|m| (m.a, m.b)).collect::<Vec<_>>()
        );
        assert!(
            matches.iter().any(|m| m.a < 60),
            "the still frames' view comes back"
        );
        // Measured: 77 matches 144 frames apart; 0.013 m and 1.0 degrees with the truth.
        let c = closure(&matches, &truth);
        assert!(c.gap_m < 0.03 && c.gap_deg < 3.0, "{c}");
        assert!((c.travelled_m - 5.03).abs() < 0.05, "{c}");
        // A model that turns 10 % less leaves a lap 36 degrees short and far from closed
        // (measured: 0.537 m, 35.1 degrees).
        let short: Vec<Pose2> = std::iter::once(Pose2::default())
            .chain(truth.windows(2).scan(Pose2::default(), |p, w| {
                let (s, co) = (-w[0].heading).sin_cos();
                let (dx, dy) = (w[1].x - w[0].x, w[1].y - w[0].y);
                let (f, l) = (co * dx - s * dy, s * dx + co * dy);
                let yaw = wrap_angle(w[1].heading - w[0].heading);
                *p = compose(p, &super::super::register::Motion::new(f, l, 0.9 * yaw));
                Some(*p)
            }))
            .collect();
        let s = closure(&matches, &short);
        assert!(s.gap_deg > 30.0 && s.gap_m > 0.5, "{s}");
        // The loops say how much more it should turn: 1 / 0.9.
        let (scale, n) = turn_scale(&matches, &short).expect("a scale");
        assert!(
            (scale - 1.0 / 0.9).abs() < 0.01 && n == matches.len(),
            "{scale} {n}"
        );
        let (scale, _) = turn_scale(&matches, &truth).expect("a scale");
        assert!((scale - 1.0).abs() < 0.01, "{scale}");
        assert_eq!(turn_scale(&[], &truth), None);
        assert!(c.to_string().contains("frames see a view again"), "{c}");
        assert_eq!(closure(&[], &truth).to_string(), "no view seen again");
    }
}
