//! The paper's reward and the autonomy score.
//!
//! Per step:
//! `R = 0 if R_distance < floor or R_speed < floor, else w_d * R_distance + w_s * R_speed`,
//! with `R_distance = min(1, D / D_ideal)` (D = distance to the nearest edge of the driving
//! lane) and `R_speed = min(1, V / V_ideal)`; negative (or NaN) D and V count as 0. The
//! paper's values are the defaults: D_ideal 10 cm, V_ideal 10 cm/s, weights 0.5, floor 0.1.
//! "One reward" is counted when R reaches `count_threshold` (R "close to 1").
//!
//! Autonomy over a test drive, as in the paper and NVIDIA's DAVE-2:
//! `autonomy = (1 - interventions * 6 s / test_seconds) * 100`.

use serde::{Deserialize, Serialize};

use super::{Result, SimError};

/// Seconds charged for each human intervention in the autonomy score.
pub const SECONDS_PER_INTERVENTION: f32 = 6.0;

/// The reward's parameters; can sit in a config section (every key optional).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RewardParams {
    /// Distance to the lane edge that earns the full distance term (m).
    pub d_ideal_m: f32,
    /// Speed that earns the full speed term (m/s).
    pub v_ideal_mps: f32,
    /// Weight of the distance term, w_d (the paper: 0.5).
    pub w_distance: f32,
    /// Weight of the speed term, w_s (the paper: 0.5).
    pub w_speed: f32,
    /// Below this, either term zeroes the whole reward.
    pub floor: f32,
    /// A step counts as "one reward" when R >= this.
    pub count_threshold: f32,
}

impl Default for RewardParams {
    fn default() -> Self {
        Self {
            d_ideal_m: 0.10,
            v_ideal_mps: 0.10,
            w_distance: 0.5,
            w_speed: 0.5,
            floor: 0.1,
            count_threshold: 0.95,
        }
    }
}

impl RewardParams {
    /// Checks every value against its allowed range, naming the key.
    pub fn validate(&self) -> Result<()> {
        let check = |key: &str, v: f32, lo: f32, hi: f32, open_lo: bool| {
            let ok = v.is_finite() && v <= hi && if open_lo { v > lo } else { v >= lo };
            if ok {
                Ok(())
            } else {
                let lo_op = if open_lo { "<" } else { "<=" };
                Err(SimError::Invalid(format!(
                    "reward key `{key}` = {v} is out of range: allowed {lo} {lo_op} value <= {hi}"
                )))
            }
        };
        check("d_ideal_m", self.d_ideal_m, 0.0, 10.0, true)?;
        check("v_ideal_mps", self.v_ideal_mps, 0.0, 10.0, true)?;
        check("w_distance", self.w_distance, 0.0, 10.0, false)?;
        check("w_speed", self.w_speed, 0.0, 10.0, false)?;
        check("floor", self.floor, 0.0, 1.0, false)?;
        check("count_threshold", self.count_threshold, 0.0, 10.0, false)?;
        Ok(())
    }
}

/// `min(1, value / ideal)`, with negative or NaN values as 0.
fn term(value: f32, ideal: f32) -> f32 {
    // f32::max returns the other operand for NaN.
    let v = value.max(0.0);
    if ideal > 0.0 {
        (v / ideal).min(1.0)
    } else if v > 0.0 {
        1.0
    } else {
        0.0
    }
}

/// The paper's per-step reward for a distance to the lane edge `distance_m` and a forward
/// speed `speed_mps`.
pub fn reward(distance_m: f32, speed_mps: f32, p: &RewardParams) -> f32 {
    let rd = term(distance_m, p.d_ideal_m);
    let rs = term(speed_mps, p.v_ideal_mps);
    if rd < p.floor || rs < p.floor {
        0.0
    } else {
        p.w_distance * rd + p.w_speed * rs
    }
}

/// Whether a step's reward counts as "one reward" (R >= `count_threshold`).
pub fn is_reward(r: f32, p: &RewardParams) -> bool {
    r >= p.count_threshold
}

/// Autonomy in percent: `(1 - interventions * 6 / test_seconds) * 100`.
///
/// Not clamped: more than `test_seconds / 6` interventions give a negative score, which is
/// what the formula says (the paper's pure-RL run, 95 in 600 s, scores 5 %). A
/// `test_seconds` of 0 or less (or NaN) has no meaningful score and gives NaN.
pub fn autonomy(interventions: u32, test_seconds: f32) -> f32 {
    if test_seconds.is_nan() || test_seconds <= 0.0 {
        return f32::NAN;
    }
    let charged = f64::from(interventions) * f64::from(SECONDS_PER_INTERVENTION);
    ((1.0 - charged / f64::from(test_seconds)) * 100.0) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(d: f32, v: f32) -> f32 {
        reward(d, v, &RewardParams::default())
    }

    #[test]
    fn worked_examples() {
        assert!((r(0.10, 0.10) - 1.0).abs() < 1e-6);
        // R_d = 0.5, R_s = min(1, 2) = 1.
        assert!((r(0.05, 0.2) - 0.75).abs() < 1e-6);
        // R_d = 0.09 < 0.1: the floor zeroes it whatever the speed.
        assert_eq!(r(0.009, 0.5), 0.0);
        // R_d = min(1, 2) = 1, R_s = 0.5.
        assert!((r(0.2, 0.05) - 0.75).abs() < 1e-6);
        assert_eq!(r(0.10, 0.0), 0.0);
        assert_eq!(r(0.10, 0.009), 0.0);
        // Just above the floor: 0.5 * 0.11 + 0.5 * 1.
        assert!((r(0.1, 0.011) - 0.555).abs() < 1e-6);
        assert!((r(0.03, 0.04) - 0.35).abs() < 1e-6);
    }

    #[test]
    fn negative_and_nan_inputs_count_as_zero() {
        assert_eq!(r(-0.05, 0.1), 0.0);
        assert_eq!(r(0.1, -0.3), 0.0);
        assert_eq!(r(f32::NAN, 0.1), 0.0);
        assert_eq!(r(0.1, f32::NAN), 0.0);
    }

    #[test]
    fn counting_one_reward() {
        let p = RewardParams::default();
        assert!(is_reward(r(0.10, 0.10), &p));
        assert!(is_reward(r(0.10, 0.09), &p)); // 0.95
        assert!(!is_reward(r(0.10, 0.08), &p)); // 0.9
        assert!(!is_reward(r(0.05, 0.2), &p));
    }

    #[test]
    fn autonomy_matches_the_paper() {
        assert!(
            (autonomy(95, 600.0) - 5.0).abs() < 1e-4,
            "{}",
            autonomy(95, 600.0)
        );
        assert_eq!(autonomy(0, 600.0), 100.0);
        assert!((autonomy(10, 600.0) - 90.0).abs() < 1e-4);
        // Not clamped.
        assert!((autonomy(200, 600.0) + 100.0).abs() < 1e-4);
        assert!(autonomy(0, 0.0).is_nan());
        assert_eq!(SECONDS_PER_INTERVENTION, 6.0);
    }

    #[test]
    fn params_parse_and_validate() {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Doc {
            reward: RewardParams,
        }
        let d: Doc = toml::from_str("[reward]\nfloor = 0.2\n").unwrap();
        assert_eq!(d.reward.floor, 0.2);
        assert_eq!(d.reward.d_ideal_m, 0.10);
        assert!(d.reward.validate().is_ok());
        assert!(toml::from_str::<Doc>("[reward]\nflor = 0.2\n").is_err());
        let bad = RewardParams {
            v_ideal_mps: 0.0,
            ..RewardParams::default()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("v_ideal_mps"), "{err}");
    }
}
