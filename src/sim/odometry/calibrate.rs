//! Calibrating the wheel model from the frames themselves: a real robot's motor model
//! (top speed, wheel base, a weaker motor) is only roughly known, and a prior that is off
//! by 10 % drifts 15 % of the distance. Vision measures the motion well in some frames
//! and directions (forward where the floor has marks across the path, the turn where it
//! has marks to the side) and not in others; over the frames where a direction is well
//! measured, the ratio of vision's motion to the wheels' gives that direction's scale.
//! Pure.

use super::register::{Motion, Registration};

/// A frame's wheel prediction and its registration without the prior's pull.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    pub prior: Motion,
    pub vision: Registration,
}

/// What the calibration found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scales {
    /// Multiply the wheels' speed by this...
    pub speed: f32,
    /// ...and their turn rate by this.
    pub turn: f32,
    /// The car model only ([`fit_car`]): radians of yaw per metre the uncorrected model
    /// travels, added (a steering trim that is off); 0 for the wheels.
    pub offset: f32,
    /// Frames that measured each (fewer than [`MIN_FRAMES`]: the scale stays 1).
    pub speed_frames: usize,
    pub turn_frames: usize,
}

/// A scale needs this many well-measured frames.
pub const MIN_FRAMES: usize = 20;
/// Scales are kept within this range (a model off by more is a configuration error).
pub const RANGE: (f32, f32) = (0.6, 1.6);

/// The marginal standard deviation of component `i` of a registration (from its
/// information matrix), or infinity when it is not measured.
fn marginal_sd(r: &Registration, i: usize) -> f64 {
    match r.information.try_inverse() {
        Some(cov) if cov[(i, i)] > 0.0 => cov[(i, i)].sqrt(),
        _ => f64::INFINITY,
    }
}

/// The weighted least-squares scale taking the wheels' `p` to vision's `v` over
/// `(p, v, weight)` triples, `Σ w v p / Σ w p²` (`None` when no triple carries weight),
/// and how many triples there were.
fn weighted_scale(triples: impl Iterator<Item = (f64, f64, f64)>) -> (Option<f64>, usize) {
    let (mut num, mut den, mut n) = (0.0f64, 0.0f64, 0usize);
    for (p, v, w) in triples {
        num += w * v * p;
        den += w * p * p;
        n += 1;
    }
    ((den > 0.0).then(|| num / den), n)
}

/// Least-squares scales over the frames that measure each direction well: forward to
/// 0.5 mm while the wheels predict at least 3 mm, the turn to 0.003 rad while they predict
/// at least 0.008 rad. Vision's claimed variances are first multiplied by
/// `overconfidence` (at least 1; [`overconfidence`]): where vision is known to claim more
/// than it measures, fewer frames count as well measured, and with fewer than
/// [`MIN_FRAMES`] the wheel model is left as configured.
pub fn fit(samples: &[Sample], overconfidence: f64) -> Scales {
    fit_with(samples, overconfidence, &JETBOT)
}

/// What counts as a well-measured frame, and how far a scale may go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    /// Forward: vision's standard deviation at most this (m) while the prior moves at
    /// least `min_forward_m`.
    pub forward_sd_m: f64,
    pub min_forward_m: f32,
    /// The turn: at most this (rad) while the prior turns at least `min_yaw_rad`.
    pub yaw_sd_rad: f64,
    pub min_yaw_rad: f32,
    /// The scales are kept within this range.
    pub range: (f32, f32),
}

/// A JetBot at 224x224, 4 mm cells, 0.2 m/s at 10-30 Hz: 3-20 mm a frame.
pub const JETBOT: Thresholds = Thresholds {
    forward_sd_m: 5e-4,
    min_forward_m: 0.003,
    yaw_sd_rad: 3e-3,
    min_yaw_rad: 0.008,
    range: RANGE,
};

/// A DonkeyCar at 160x120, 8 mm cells, about 1 m/s at 20 Hz: 5 cm a frame, and up to
/// 0.1 rad in a turn. The scales may go further ([`CAR_RANGE`]).
pub const CAR: Thresholds = Thresholds {
    forward_sd_m: 2e-3,
    min_forward_m: 0.01,
    yaw_sd_rad: 5e-3,
    min_yaw_rad: 0.02,
    range: CAR_RANGE,
};

/// [`fit`] with `t`'s thresholds.
fn fit_with(samples: &[Sample], overconfidence: f64, t: &Thresholds) -> Scales {
    let range = t.range;
    let inflate = if overconfidence.is_finite() {
        overconfidence.max(1.0).sqrt()
    } else {
        1.0
    };
    let fit_one = |pick: &dyn Fn(&Motion) -> f32, i: usize, sd_max: f64, min_prior: f32| {
        let well_measured = samples
            .iter()
            .filter(|s| s.vision.converged)
            .filter_map(|s| {
                let p = pick(&s.prior);
                let sd = marginal_sd(&s.vision, i) * inflate;
                if p.abs() < min_prior || sd.is_nan() || sd > sd_max {
                    return None;
                }
                Some((
                    f64::from(p),
                    f64::from(pick(&s.vision.motion)),
                    1.0 / (sd * sd),
                ))
            });
        match weighted_scale(well_measured) {
            (Some(scale), n) if n >= MIN_FRAMES => (scale as f32, n),
            (_, n) => (1.0, n),
        }
    };
    let (speed, speed_frames) = fit_one(&|m| m.forward, 0, t.forward_sd_m, t.min_forward_m);
    let (turn, turn_frames) = fit_one(&|m| m.yaw, 2, t.yaw_sd_rad, t.min_yaw_rad);
    let clamp = |v: f32| {
        if v.is_finite() {
            v.clamp(range.0, range.1)
        } else {
            1.0
        }
    };
    Scales {
        speed: clamp(speed),
        turn: clamp(turn),
        offset: 0.0,
        speed_frames,
        turn_frames,
    }
}

/// The steering offset is kept within this, rad per metre (a 2 m radius at angle 0).
pub const OFFSET_RANGE: f32 = 0.5;
/// The car's scales are kept within this: its defaults are a guess at a DonkeyCar, not a
/// measured motor model like the JetBot's, and may be off by more than [`RANGE`] allows.
pub const CAR_RANGE: (f32, f32) = (0.25, 4.0);

/// The car model's corrections ([`super::ackermann`]): the speed as [`fit`] with the
/// [`CAR`] thresholds; the turn scale and the steering offset together, by least squares
/// of vision's yaw on the prior's yaw and distance, `yaw_v = turn * yaw_p + offset *
/// forward_p`, weighted by vision's yaw information, over the frames whose yaw vision
/// measures to [`CAR`]'s 5 mrad while the prior moves at least 1 cm. Straight frames fix
/// the offset, turning ones the scale. With fewer than [`MIN_FRAMES`] turning frames
/// (prior yaw at least 0.02 rad) the curvature per unit angle stays as configured (the
/// turn scale is the speed scale: the yaw follows the corrected distance) and the offset
/// alone is fitted; with fewer than [`MIN_FRAMES`] frames in all, neither.
pub fn fit_car(samples: &[Sample], overconfidence: f64) -> Scales {
    let t = &CAR;
    let base = fit_with(samples, overconfidence, t);
    let inflate = if overconfidence.is_finite() {
        overconfidence.max(1.0).sqrt()
    } else {
        1.0
    };
    let rows: Vec<(f64, f64, f64, f64)> = samples
        .iter()
        .filter(|s| s.vision.converged && s.prior.forward >= t.min_forward_m)
        .filter_map(|s| {
            let sd = marginal_sd(&s.vision, 2) * inflate;
            (sd.is_finite() && sd <= t.yaw_sd_rad).then(|| {
                (
                    f64::from(s.prior.yaw),
                    f64::from(s.prior.forward),
                    f64::from(s.vision.motion.yaw),
                    1.0 / (sd * sd),
                )
            })
        })
        .collect();
    let turning = rows
        .iter()
        .filter(|r| r.0.abs() >= f64::from(t.min_yaw_rad))
        .count();
    // The curvature kept: the yaw scales with the corrected distance.
    let kept = f64::from(base.speed);
    let (turn, offset) = if rows.len() < MIN_FRAMES {
        (kept, 0.0)
    } else if turning < MIN_FRAMES {
        // The offset alone: yaw_v - kept * yaw_p = offset * forward_p.
        let (o, _) = weighted_scale(rows.iter().map(|&(a, b, y, w)| (b, y - kept * a, w)));
        (kept, o.unwrap_or(0.0))
    } else {
        let (mut saa, mut sab, mut sbb, mut say, mut sby) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(a, b, y, w) in &rows {
            saa += w * a * a;
            sab += w * a * b;
            sbb += w * b * b;
            say += w * a * y;
            sby += w * b * y;
        }
        let det = saa * sbb - sab * sab;
        if det.abs() > 1e-12 * (saa * sbb).abs().max(1e-300) {
            ((say * sbb - sby * sab) / det, (saa * sby - sab * say) / det)
        } else {
            (kept, 0.0)
        }
    };
    let (turn, offset) = (turn as f32, offset as f32);
    Scales {
        turn: if turn.is_finite() {
            turn.clamp(t.range.0, t.range.1)
        } else {
            1.0
        },
        offset: if offset.is_finite() {
            offset.clamp(-OFFSET_RANGE, OFFSET_RANGE)
        } else {
            0.0
        },
        turn_frames: if rows.len() < MIN_FRAMES {
            0
        } else {
            rows.len()
        },
        ..base
    }
}

/// How much more vision claims than it measures, as the fit and the fused pass use it:
/// `scatter / reference` where vision's scatter ([`scatter`]) is above `reference`, else 1
/// (`reference` 0: always 1). The same rule raises the wheels' weight in the fused pass
/// ([`super::held_harder`]).
pub fn overconfidence(scatter: Option<f64>, reference: f64) -> f64 {
    match scatter {
        Some(s) if reference > 0.0 && s > reference => s / reference,
        _ => 1.0,
    }
}

/// The median of a chi-square with 3 degrees of freedom.
const CHI2_3_MEDIAN: f64 = 2.366;

/// A frame counts in [`turn_agreement`] where the prior turns at least this much
/// (radians, about 1 degree).
pub const MIN_TURN_RAD: f32 = 0.0175;

/// How vision's turn follows the prior's over a calibration pass: the least-squares slope
/// of vision's yaw on the prior's (through the origin), over converged registrations whose
/// prior turns at least [`MIN_TURN_RAD`], and how many counted (`None` under
/// [`MIN_FRAMES`]). Near 1 they agree; below 0 the frames turn the other way from the
/// commands: the steering's sign is reversed (the car's `curvature_per_unit`), or the
/// camera's picture is mirrored.
pub fn turn_agreement(samples: &[Sample]) -> Option<(f64, usize)> {
    let turning: Vec<(f64, f64)> = samples
        .iter()
        .filter(|s| s.vision.converged && s.prior.yaw.abs() >= MIN_TURN_RAD)
        .map(|s| (f64::from(s.prior.yaw), f64::from(s.vision.motion.yaw)))
        .collect();
    if turning.len() < MIN_FRAMES {
        return None;
    }
    let pp: f64 = turning.iter().map(|(p, _)| p * p).sum();
    let pv: f64 = turning.iter().map(|(p, v)| p * v).sum();
    Some((pv / pp, turning.len()))
}

/// How far vision's own motions (the calibration pass: no pull towards the wheels) lie
/// from the wheels', in units of the uncertainty vision claims: the median over the
/// registered frames of `dᵀ I d / 2.366` (2.366 is the median of a chi-square with 3
/// degrees of freedom), `d` the difference of the two motions and `I` vision's
/// information. The wheels are first scaled to vision's motion over all registered frames
/// (speed and turn, least squares weighted by vision's information), so a wheel model that
/// is only off in scale (too few well-measured frames for [`fit`]) does not count as
/// vision's scatter. About 1 when vision's errors are as small as it claims; larger when
/// vision is overconfident or biased from frame to frame (a low-contrast floor, glare) or
/// the wheels slip. `None` with fewer than [`MIN_FRAMES`] registered frames.
pub fn scatter(samples: &[Sample]) -> Option<f64> {
    let registered: Vec<&Sample> = samples.iter().filter(|s| s.vision.converged).collect();
    if registered.len() < MIN_FRAMES {
        return None;
    }
    let scale = |pick: &dyn Fn(&Motion) -> f32, i: usize| {
        let triples = registered.iter().filter_map(|s| {
            let w = s.vision.information[(i, i)];
            w.is_finite().then(|| {
                (
                    f64::from(pick(&s.prior)),
                    f64::from(pick(&s.vision.motion)),
                    w,
                )
            })
        });
        weighted_scale(triples).0.unwrap_or(1.0)
    };
    let speed = scale(&|m| m.forward, 0);
    let turn = scale(&|m| m.yaw, 2);
    let mut r: Vec<f64> = registered
        .iter()
        .map(|s| {
            let d = nalgebra::Vector3::new(
                f64::from(s.vision.motion.forward) - f64::from(s.prior.forward) * speed,
                f64::from(s.vision.motion.left) - f64::from(s.prior.left) * speed,
                f64::from(s.vision.motion.yaw) - f64::from(s.prior.yaw) * turn,
            );
            (d.transpose() * s.vision.information * d)[(0, 0)] / CHI2_3_MEDIAN
        })
        .filter(|v| v.is_finite())
        .collect();
    if r.len() < MIN_FRAMES {
        return None;
    }
    r.sort_by(f64::total_cmp);
    Some(r[r.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    fn sample(prior: Motion, vision: Motion, info: [f64; 3]) -> Sample {
        Sample {
            prior,
            vision: Registration {
                motion: vision,
                information: Matrix3::from_diagonal(&Vector3::new(info[0], info[1], info[2])),
                ncc: 0.99,
                cells: 3000,
                converged: true,
            },
        }
    }

    #[test]
    fn turn_agreement_is_the_slope_of_visions_turn_on_the_priors() {
        // 30 turning frames where vision turns half as much the other way, and 10 frames
        // whose prior turns under a degree (left out, whatever vision says).
        let mut samples: Vec<Sample> = (0..30)
            .map(|i| {
                let yaw = 0.02 + 0.002 * i as f32;
                let prior = Motion::new(0.05, 0.0, if i % 2 == 0 { yaw } else { -yaw });
                let vision = Motion::new(0.05, 0.0, -0.5 * prior.yaw);
                sample(prior, vision, [1e4; 3])
            })
            .collect();
        samples.extend((0..10).map(|_| {
            sample(
                Motion::new(0.05, 0.0, 0.01),
                Motion::new(0.05, 0.0, 0.5),
                [1e4; 3],
            )
        }));
        // A registration that did not converge takes no part either.
        let mut lost = sample(
            Motion::new(0.05, 0.0, 0.1),
            Motion::new(0.05, 0.0, 0.1),
            [1e4; 3],
        );
        lost.vision.converged = false;
        samples.push(lost);
        let (slope, n) = turn_agreement(&samples).expect("enough frames");
        assert!((slope + 0.5).abs() < 1e-6 && n == 30, "{slope} {n}");
        assert_eq!(turn_agreement(&samples[..19]), None, "under MIN_FRAMES");
    }

    #[test]
    fn scales_come_from_the_well_measured_frames_only() {
        let mut s = Vec::new();
        // 30 straight frames: wheels say 6 mm, vision (sure of forward) 5.4 mm: speed 0.9.
        for _ in 0..30 {
            s.push(sample(
                Motion::new(0.006, 0.0, 0.0),
                Motion::new(0.0054, 0.0, 0.0),
                [1e8, 1e8, 1.0],
            ));
        }
        // 25 turning frames: wheels say 0.02 rad, vision (sure of the turn) 0.023: turn 1.15.
        for _ in 0..25 {
            s.push(sample(
                Motion::new(0.006, 0.0, 0.02),
                Motion::new(0.0, 0.0, 0.023),
                [1.0, 1e8, 1e7],
            ));
        }
        // Frames that measure nothing well are ignored, however wrong.
        for _ in 0..50 {
            s.push(sample(
                Motion::new(0.006, 0.0, 0.02),
                Motion::new(-0.02, 0.0, -0.05),
                [10.0, 10.0, 10.0],
            ));
        }
        let f = fit(&s, 1.0);
        assert!((f.speed - 0.9).abs() < 1e-4, "{f:?}");
        assert!((f.turn - 1.15).abs() < 1e-4, "{f:?}");
        assert_eq!((f.speed_frames, f.turn_frames), (30, 25));
        // Too few frames: no correction.
        let f = fit(&s[..10], 1.0);
        assert_eq!((f.speed, f.turn), (1.0, 1.0));
        // Vision 4 times overconfident: every claimed sd doubles. The turning frames' 0.32
        // mrad (information 1e7) becomes 0.63, still under 3 mrad: the same fit.
        let f = fit(&s, 4.0);
        assert_eq!((f.speed_frames, f.turn_frames), (30, 25));
        assert!((f.turn - 1.15).abs() < 1e-4, "{f:?}");
        // 100 times: forward's 0.1 mm becomes 1 mm (over 0.5), the turn's 3.2 mrad (over
        // 3): nothing counts as well measured, and the model stays as configured.
        let f = fit(&s, 100.0);
        assert_eq!((f.speed, f.turn), (1.0, 1.0), "{f:?}");
        assert_eq!((f.speed_frames, f.turn_frames), (0, 0));
        // Below 1 or not a number: as 1.
        assert_eq!(fit(&s, 0.5), fit(&s, 1.0));
        assert_eq!(fit(&s, f64::NAN), fit(&s, 1.0));
    }

    #[test]
    fn the_cars_turn_scale_and_steering_offset_from_straight_and_turning_frames() {
        let mut s = Vec::new();
        // 30 straight frames, 5 cm each: vision sees 0.005 rad of yaw every time, a trim
        // that is off by 0.1 rad per metre.
        for _ in 0..30 {
            s.push(sample(
                Motion::new(0.05, 0.0, 0.0),
                Motion::new(0.05, 0.0, 0.005),
                [1e8, 1e8, 1e7],
            ));
        }
        // 30 turning frames: the model says 0.1 rad over 5 cm, vision 0.125 = 1.2 x 0.1 +
        // 0.1 x 0.05.
        for _ in 0..30 {
            s.push(sample(
                Motion::new(0.05, 0.0, 0.1),
                Motion::new(0.05, 0.0, 0.125),
                [1e8, 1e8, 1e7],
            ));
        }
        // Frames whose yaw vision does not measure are ignored.
        for _ in 0..30 {
            s.push(sample(
                Motion::new(0.05, 0.0, 0.1),
                Motion::new(0.05, 0.0, -0.3),
                [1e8, 1e8, 10.0],
            ));
        }
        let f = fit_car(&s, 1.0);
        assert!((f.turn - 1.2).abs() < 1e-4, "{f:?}");
        assert!((f.offset - 0.1).abs() < 1e-4, "{f:?}");
        assert_eq!(f.turn_frames, 60);
        assert!((f.speed - 1.0).abs() < 1e-4, "{f:?}");
        // Straight frames only: the offset alone, 0.005 / 0.05.
        let f = fit_car(&s[..30], 1.0);
        assert_eq!(f.turn, 1.0);
        assert!((f.offset - 0.1).abs() < 1e-4, "{f:?}");
        // Too few: nothing.
        let f = fit_car(&s[..10], 1.0);
        assert_eq!((f.turn, f.offset, f.turn_frames), (1.0, 0.0, 0));
        // Vision sees 0.8 of the distance on every frame (speed x0.8) and no turn well:
        // the curvature per unit angle is kept, the yaw scaled with the distance (turn
        // x0.8), and the straight frames' 0.004 rad of yaw over the model's 5 cm give the
        // offset, 0.08 rad per metre.
        let s: Vec<Sample> = (0..30)
            .map(|_| {
                sample(
                    Motion::new(0.05, 0.0, 0.0),
                    Motion::new(0.04, 0.0, 0.004),
                    [1e8, 1e8, 1e7],
                )
            })
            .chain((0..30).map(|_| {
                sample(
                    Motion::new(0.05, 0.0, 0.1),
                    Motion::new(0.04, 0.0, 0.3),
                    [1e8, 1e8, 10.0],
                )
            }))
            .collect();
        let f = fit_car(&s, 1.0);
        assert!((f.speed - 0.8).abs() < 1e-4, "{f:?}");
        assert!((f.turn - 0.8).abs() < 1e-4, "{f:?}");
        assert!((f.offset - 0.08).abs() < 1e-4, "{f:?}");
    }

    #[test]
    fn overconfidence_is_the_scatter_above_its_reference() {
        assert!((overconfidence(Some(11.19), 4.0) - 2.7975).abs() < 1e-9);
        assert_eq!(overconfidence(Some(3.9), 4.0), 1.0);
        assert_eq!(overconfidence(None, 4.0), 1.0);
        assert_eq!(overconfidence(Some(11.19), 0.0), 1.0, "0: off");
    }

    #[test]
    fn scatter_in_units_of_visions_claimed_uncertainty() {
        // Vision's forward motion alternates 9.2 and 10.8 mm about the wheels' 10 mm (the
        // best scale is 1), sure to 0.1 mm (information 1e8 /m²): d = 0.8 mm, dᵀ I d = 64,
        // / 2.366 = 27.05.
        let s: Vec<Sample> = (0..26)
            .map(|i| {
                let v = if i % 2 == 0 { 0.0092 } else { 0.0108 };
                sample(
                    Motion::new(0.010, 0.0, 0.0),
                    Motion::new(v, 0.0, 0.0),
                    [1e8, 1e8, 1e6],
                )
            })
            .collect();
        let k = scatter(&s).unwrap();
        assert!((k - 64.0 / 2.366).abs() < 0.05, "{k}");
        // Wheels off in scale only (vision 9 mm every frame): not vision's scatter.
        let s: Vec<Sample> = (0..25)
            .map(|_| {
                sample(
                    Motion::new(0.010, 0.0, 0.02),
                    Motion::new(0.009, 0.0, 0.024),
                    [1e8, 1e8, 1e6],
                )
            })
            .collect();
        assert!(scatter(&s).unwrap() < 1e-6);
        // A direction vision cannot measure (information 1e-6) adds nothing however far off.
        let s: Vec<Sample> = (0..25)
            .map(|_| {
                sample(
                    Motion::new(0.010, 0.0, 0.0),
                    Motion::new(0.010, 0.05, 0.0),
                    [1e8, 1e-6, 1e6],
                )
            })
            .collect();
        assert!(scatter(&s).unwrap() < 1e-3);
        assert_eq!(scatter(&s[..10]), None);
    }
}
