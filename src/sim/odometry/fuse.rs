//! Fusing the registration with the wheel prior, per frame. Pure.
//!
//! Each is a Gaussian on the motion: the registration's information matrix (strong along
//! texture, zero along a direction the floor does not constrain, such as along a stripe)
//! and the prior's ([`prior_information`]: its standard deviation a fraction of the
//! predicted motion plus a floor). The registration is solved with the prior's term in it
//! (see `register`), so its motion is already the fused one: a direction the floor cannot
//! fix comes from the wheels. Here a frame falls back to the prior alone, and is flagged,
//! when its view is textureless, the registration did not settle, matched poorly, or
//! disagrees with the wheels beyond the gate; and the confidence is computed.

use nalgebra::{Matrix3, Vector3};

use super::register::{Motion, Registration};

/// Where a frame's motion came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// The registration and the prior, fused.
    Fused,
    /// The prior alone; the frame is flagged.
    Prior(Fallback),
}

/// Why a frame fell back to the prior.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fallback {
    /// The floor in view has too little texture (the first frame too: nothing to match).
    Textureless,
    /// The registration did not settle on enough cells.
    NoMatch,
    /// The match's correlation is below `min_ncc`.
    PoorMatch,
    /// The registration and the wheels disagree beyond the gate.
    Disagrees,
}

impl Source {
    pub fn as_str(&self) -> &'static str {
        match self {
            Source::Fused => "fused",
            Source::Prior(Fallback::Textureless) => "prior:textureless",
            Source::Prior(Fallback::NoMatch) => "prior:no_match",
            Source::Prior(Fallback::PoorMatch) => "prior:poor_match",
            Source::Prior(Fallback::Disagrees) => "prior:disagrees",
        }
    }
}

/// Thresholds of the fusion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionParams {
    /// A view whose grey values vary less than this (standard deviation, 0..255) is
    /// textureless.
    pub min_texture: f32,
    pub min_ncc: f32,
    /// The prior's standard deviation: this fraction of its motion...
    pub prior_fraction: f32,
    /// ...plus these floors (m, rad).
    pub prior_floor_m: f32,
    pub prior_floor_rad: f32,
    /// The gate: vision and wheels may differ by this many prior standard deviations
    /// (plus 1 cm and 3 degrees: real wheels slip).
    pub gate_sigmas: f32,
    /// How hard the (calibrated) wheel prior holds the registration: its information is
    /// multiplied by this. Vision's information counts every floor cell as a measurement,
    /// but its errors are not independent (interpolation, a curve's near-symmetry), so
    /// taken at face value it outweighs the wheels where it should not. Chosen on one
    /// simulated lap (1, 4, 16, 64 tried; 16 kept; the study: docs/results/odometry.md), not
    /// on real data.
    pub prior_weight: f32,
}

impl Default for FusionParams {
    fn default() -> Self {
        Self {
            min_texture: 3.0,
            min_ncc: 0.5,
            prior_fraction: 0.3,
            prior_floor_m: 0.002,
            prior_floor_rad: 0.01,
            gate_sigmas: 4.0,
            prior_weight: 16.0,
        }
    }
}

/// One frame's fused motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fused {
    pub motion: Motion,
    pub source: Source,
    /// 0..1: the match's correlation times the share of the fused information that came
    /// from vision (0 for a fallback).
    pub confidence: f32,
}

/// Yaw is weighed as a displacement at this lever arm when shares are compared.
const LEVER_M: f64 = 0.2;

/// The prior's standard deviations `(translation m, yaw rad)`.
fn prior_sigmas(prior: &Motion, p: &FusionParams) -> (f64, f64) {
    let dist = prior.forward.hypot(prior.left);
    (
        f64::from(p.prior_fraction * dist + p.prior_floor_m),
        f64::from(p.prior_fraction * prior.yaw.abs() + p.prior_floor_rad),
    )
}

/// The prior's information matrix (inverse covariance, (m, m, rad) units).
pub fn prior_information(prior: &Motion, p: &FusionParams) -> Matrix3<f64> {
    let (st, sr) = prior_sigmas(prior, p);
    Matrix3::from_diagonal(&Vector3::new(
        1.0 / (st * st),
        1.0 / (st * st),
        1.0 / (sr * sr),
    ))
}

/// Decides on `reg` (solved with the prior's term, if the frame was registered) against
/// the wheel `prior`; `texture` is the later view's grey-level standard deviation.
pub fn fuse(prior: Motion, reg: Option<&Registration>, texture: f32, p: &FusionParams) -> Fused {
    let fallback = |why| Fused {
        motion: prior,
        source: Source::Prior(why),
        confidence: 0.0,
    };
    if texture.is_nan() || texture < p.min_texture {
        return fallback(Fallback::Textureless);
    }
    let Some(reg) = reg.filter(|r| r.converged) else {
        return fallback(Fallback::NoMatch);
    };
    if reg.ncc.is_nan() || reg.ncc < p.min_ncc {
        return fallback(Fallback::PoorMatch);
    }
    let (sigma_t, sigma_r) = prior_sigmas(&prior, p);
    let m = reg.motion;
    let gate_t = f64::from(p.gate_sigmas) * sigma_t + 0.01;
    let gate_r = f64::from(p.gate_sigmas) * sigma_r + 3f64.to_radians();
    let off_t = f64::from((m.forward - prior.forward).hypot(m.left - prior.left));
    let off_r = f64::from((m.yaw - prior.yaw).abs());
    if off_t > gate_t || off_r > gate_r {
        return fallback(Fallback::Disagrees);
    }
    let ip = prior_information(&prior, p);
    let iv = reg.information;
    let scale = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, LEVER_M));
    let tv = (scale * iv * scale).trace();
    let tp = (scale * ip * scale).trace();
    let share = if tv + tp > 0.0 { tv / (tv + tp) } else { 0.0 };
    Fused {
        motion: m,
        source: Source::Fused,
        confidence: (f64::from(reg.ncc.clamp(0.0, 1.0)) * share) as f32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reg(m: Motion, info: [f64; 3]) -> Registration {
        Registration {
            motion: m,
            information: Matrix3::from_diagonal(&Vector3::new(info[0], info[1], info[2])),
            ncc: 0.95,
            cells: 3000,
            converged: true,
        }
    }

    #[test]
    fn a_textureless_frame_falls_back_to_the_prior() {
        let prior = Motion::new(0.01, 0.0, 0.02);
        let good = reg(Motion::new(0.012, 0.0, 0.02), [1e8, 1e8, 1e8]);
        let p = FusionParams::default();
        let f = fuse(prior, Some(&good), 1.0, &p);
        assert_eq!(f.source, Source::Prior(Fallback::Textureless));
        assert_eq!((f.motion, f.confidence), (prior, 0.0));
        assert_eq!(
            fuse(prior, None, 1.0, &p).source,
            Source::Prior(Fallback::Textureless)
        );
        assert_eq!(
            fuse(prior, None, 20.0, &p).source,
            Source::Prior(Fallback::NoMatch)
        );
        let poor = Registration { ncc: 0.2, ..good };
        assert_eq!(
            fuse(prior, Some(&poor), 20.0, &p).source,
            Source::Prior(Fallback::PoorMatch)
        );
        let far = reg(Motion::new(0.09, 0.0, 0.02), [1e8, 1e8, 1e8]);
        assert_eq!(
            fuse(prior, Some(&far), 20.0, &p).source,
            Source::Prior(Fallback::Disagrees)
        );
        assert_eq!(
            Source::Prior(Fallback::Textureless).as_str(),
            "prior:textureless"
        );
    }

    #[test]
    fn the_confidence_is_the_match_times_visions_share() {
        let prior = Motion::new(0.010, 0.0, 0.0);
        let p = FusionParams::default();
        let v = reg(Motion::new(0.012, 0.001, 0.01), [1e12, 1e12, 1e12]);
        let f = fuse(prior, Some(&v), 20.0, &p);
        assert_eq!(f.source, Source::Fused);
        assert_eq!(f.motion, v.motion, "the registration's (fused) motion");
        assert!(f.confidence > 0.94, "{}", f.confidence);
        // Equal information: half the share. Prior sigma 0.3 * 0.01 + 0.002 = 0.005 m,
        // 0.01 rad.
        let ip = prior_information(&prior, &p);
        assert!((ip[(0, 0)] * 25e-6 - 1.0).abs() < 1e-5 && (ip[(2, 2)] * 1e-4 - 1.0).abs() < 1e-5);
        let v = reg(
            Motion::new(0.012, 0.0, 0.0),
            [ip[(0, 0)], ip[(1, 1)], ip[(2, 2)]],
        );
        let f = fuse(prior, Some(&v), 20.0, &p);
        assert!((f.confidence - 0.95 * 0.5).abs() < 1e-3, "{}", f.confidence);
    }
}
