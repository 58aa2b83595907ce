//! Odometry against the truth: on a tub whose poses are known (the simulator's), how far
//! the estimate drifts over the distance travelled. Pure.

use super::super::{Pose2, wrap_angle};
use super::FramePose;

/// Drift of an estimate over a recording.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Drift {
    pub frames: usize,
    /// Length of the true path over the compared frames (m).
    pub distance_m: f32,
    /// Position error at the last frame (m) and as a percentage of `distance_m`.
    pub final_error_m: f32,
    pub final_error_pct: f32,
    /// Largest position error over the recording (m).
    pub max_error_m: f32,
    /// Heading error at the last frame (degrees) and per metre travelled.
    pub heading_error_deg: f32,
    pub heading_deg_per_m: f32,
}

impl std::fmt::Display for Drift {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} frames, {:.2} m: position drift {:.3} m ({:.2} % of the distance), worst {:.3} m; heading drift {:.2} deg ({:.2} deg/m)",
            self.frames,
            self.distance_m,
            self.final_error_m,
            self.final_error_pct,
            self.max_error_m,
            self.heading_error_deg,
            self.heading_deg_per_m
        )
    }
}

/// Compares `estimate` with `truth` (record index -> pose), frame by frame.
pub fn drift(estimate: &[FramePose], truth: &std::collections::HashMap<u64, Pose2>) -> Drift {
    let pairs: Vec<(Pose2, Pose2)> = estimate
        .iter()
        .filter_map(|e| truth.get(&e.index).map(|t| (e.pose, *t)))
        .collect();
    let Some(&(last_e, last_t)) = pairs.last() else {
        return Drift::default();
    };
    let distance_m: f32 = pairs
        .windows(2)
        .map(|w| (w[1].1.x - w[0].1.x).hypot(w[1].1.y - w[0].1.y))
        .sum();
    let err = |e: &Pose2, t: &Pose2| (e.x - t.x).hypot(e.y - t.y);
    let final_error_m = err(&last_e, &last_t);
    let max_error_m = pairs.iter().map(|(e, t)| err(e, t)).fold(0.0, f32::max);
    let heading_error_deg = wrap_angle(last_e.heading - last_t.heading)
        .abs()
        .to_degrees();
    let per = |v: f32| {
        if distance_m > 0.0 {
            v / distance_m
        } else {
            0.0
        }
    };
    Drift {
        frames: pairs.len(),
        distance_m,
        final_error_m,
        final_error_pct: per(final_error_m) * 100.0,
        max_error_m,
        heading_error_deg,
        heading_deg_per_m: per(heading_error_deg),
    }
}

#[cfg(test)]
mod tests {
    use super::super::fuse::Source;
    use super::*;

    #[test]
    fn drift_over_a_straight_line() {
        // 11 frames 0.1 m apart along x; the estimate runs 2 % long and turns 1 degree.
        let truth: std::collections::HashMap<u64, Pose2> = (0..11)
            .map(|i| (i, Pose2::new(0.1 * i as f32, 0.0, 0.0)))
            .collect();
        let est: Vec<FramePose> = (0..11)
            .map(|i| FramePose {
                index: i,
                time_s: i as f64,
                pose: Pose2::new(0.102 * i as f32, 0.0, (0.1 * i as f32).to_radians()),
                confidence: 1.0,
                source: Source::Fused,
            })
            .collect();
        let d = drift(&est, &truth);
        assert_eq!(d.frames, 11);
        assert!((d.distance_m - 1.0).abs() < 1e-5);
        assert!((d.final_error_m - 0.02).abs() < 1e-5 && (d.final_error_pct - 2.0).abs() < 1e-3);
        assert!((d.max_error_m - 0.02).abs() < 1e-5);
        assert!(
            (d.heading_error_deg - 1.0).abs() < 1e-3 && (d.heading_deg_per_m - 1.0).abs() < 1e-3
        );
        assert!(d.to_string().contains("2.00 % of the distance"), "{d}");
        assert_eq!(drift(&[], &truth), Drift::default());
    }
}
