//! Exploration noise on the actor's `(speed, steering)`: Gaussian, or Ornstein-Uhlenbeck
//! (temporally correlated, DDPG's original choice):
//!
//! ```text
//! gaussian: n_t = sigma * N(0, 1)
//! ou:       n_t = n_{t-1} + theta * (0 - n_{t-1}) * dt + sigma * sqrt(dt) * N(0, 1)
//! ```

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoiseKind {
    Gaussian,
    Ou,
}

#[derive(Debug, Clone)]
pub struct Noise {
    kind: NoiseKind,
    /// Per action component.
    sigma: [f32; 2],
    theta: f32,
    dt: f32,
    state: [f32; 2],
}

impl Noise {
    pub fn new(kind: NoiseKind, sigma: [f32; 2], theta: f32, dt: f32) -> Self {
        Self {
            kind,
            sigma,
            theta,
            dt,
            state: [0.0; 2],
        }
    }

    /// Back to zero (OU) at the start of an episode.
    pub fn reset(&mut self) {
        self.state = [0.0; 2];
    }

    pub fn sample(&mut self, rng: &mut impl Rng) -> [f32; 2] {
        let mut out = [0.0; 2];
        for (i, o) in out.iter_mut().enumerate() {
            let z: f32 = StandardNormal.sample(rng);
            *o = match self.kind {
                NoiseKind::Gaussian => self.sigma[i] * z,
                NoiseKind::Ou => {
                    let s = &mut self.state[i];
                    *s += -self.theta * *s * self.dt + self.sigma[i] * self.dt.sqrt() * z;
                    *s
                }
            };
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn stats(kind: NoiseKind) -> (f32, f32, f32) {
        let mut n = Noise::new(kind, [0.2, 0.1], 0.15 * 30.0, 1.0 / 30.0);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let xs: Vec<[f32; 2]> = (0..20000).map(|_| n.sample(&mut rng)).collect();
        let mean = xs.iter().map(|x| x[0]).sum::<f32>() / xs.len() as f32;
        let var = xs.iter().map(|x| (x[0] - mean).powi(2)).sum::<f32>() / xs.len() as f32;
        let lag1 = xs
            .windows(2)
            .map(|w| (w[0][0] - mean) * (w[1][0] - mean))
            .sum::<f32>()
            / (xs.len() as f32 * var);
        (mean, var.sqrt(), lag1)
    }

    #[test]
    fn gaussian_is_white_with_the_given_sigma() {
        let (mean, sd, lag1) = stats(NoiseKind::Gaussian);
        assert!(
            mean.abs() < 0.01 && (sd - 0.2).abs() < 0.01 && lag1.abs() < 0.03,
            "{mean} {sd} {lag1}"
        );
    }

    #[test]
    fn ou_is_correlated_and_mean_reverting() {
        // theta*dt = 0.15: lag-1 correlation 0.85; stationary sd = sigma*sqrt(dt/(1-0.85^2)).
        let (mean, sd, lag1) = stats(NoiseKind::Ou);
        let want_sd = 0.2 * (1.0f32 / 30.0 / (1.0 - 0.85f32 * 0.85)).sqrt();
        assert!((lag1 - 0.85).abs() < 0.03, "{lag1}");
        assert!((sd - want_sd).abs() < 0.15 * want_sd, "{sd} vs {want_sd}");
        assert!(mean.abs() < 0.03, "{mean}");
    }
}
