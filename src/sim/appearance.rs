//! Appearance randomisation, camera side (`[sim.appearance]`): what differs from one JetBot
//! camera and room to the next in the pixels, drawn from a seeded generator so a run is
//! reproducible and a policy trained on it learns to ignore it.
//!
//! A [`Look`] is drawn per episode (at every reset) and again every `redraw_every_frames`
//! frames; sensor noise is drawn per frame. Applied to a rendered or synthesised RGB8 frame
//! in this order, per pixel and channel `c` (values in 0..1):
//!
//! ```text
//! x' = clamp(exposure * gain[c] * x^gamma * (1 - vignette * r^2)) + noise
//! ```
//!
//! where `r` is the distance from the frame centre over the half diagonal. The white
//! balance `gain` is JetBot's pink cast (red and blue up, green down: its IMX219 has no
//! IR-cut filter) with probability `pink_probability`, otherwise a plain tint of up to
//! `tint` per channel. Then an optional 3x3 blur (`blur_probability`, a little defocus or
//! motion). Off by default: evaluation stays deterministic and unchanged.
//!
//! Not here yet (the sim-to-real issue's other half): floors, road paints and widths,
//! light gradients and glare, and what stands beyond the mat.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::SimError;

/// `[sim.appearance]`. Ranges are `[low, high]`, drawn uniformly.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct AppearanceConfig {
    /// Randomise at all (`sim --randomise` and `train ddpg --randomise` turn it on).
    pub enabled: bool,
    /// Probability of JetBot's pink cast rather than a plain tint.
    pub pink_probability: f32,
    /// Plain tint: each channel's gain within `1 +- tint`.
    pub tint: f32,
    /// Exposure (a gain on every channel).
    pub exposure: [f32; 2],
    /// Gamma applied to 0..1 values (above 1: darker mid-tones).
    pub gamma: [f32; 2],
    /// Darkening at the frame's corners, `1 - vignette` of the centre's brightness there.
    pub vignette: [f32; 2],
    /// Standard deviation of per-pixel sensor noise, 8-bit levels.
    pub noise_std: [f32; 2],
    /// Probability of a 3x3 blur.
    pub blur_probability: f32,
    /// A new look every this many frames as well as at every reset (0: at resets only).
    pub redraw_every_frames: u32,
}

impl Default for AppearanceConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            pink_probability: 0.5,
            tint: 0.15,
            exposure: [0.6, 1.4],
            gamma: [0.8, 1.25],
            vignette: [0.0, 0.6],
            noise_std: [0.0, 6.0],
            blur_probability: 0.3,
            redraw_every_frames: 150,
        }
    }
}

impl AppearanceConfig {
    /// Checks every range: finite, `low <= high`, and in a sensible domain.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |what: String| Err(SimError::Invalid(format!("sim.appearance: {what}")));
        let ranges = [
            ("exposure", self.exposure, 0.0, 4.0),
            ("gamma", self.gamma, 0.1, 5.0),
            ("vignette", self.vignette, 0.0, 1.0),
            ("noise_std", self.noise_std, 0.0, 64.0),
        ];
        for (name, [lo, hi], min, max) in ranges {
            if !(lo.is_finite() && hi.is_finite() && min <= lo && lo <= hi && hi <= max) {
                return bad(format!(
                    "{name} = [{lo}, {hi}] must satisfy {min} <= low <= high <= {max}"
                ));
            }
        }
        for (name, p) in [
            ("pink_probability", self.pink_probability),
            ("blur_probability", self.blur_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return bad(format!("{name} = {p} must be in 0..=1"));
            }
        }
        if !(0.0..=0.9).contains(&self.tint) {
            return bad(format!("tint = {} must be in 0..=0.9", self.tint));
        }
        Ok(())
    }
}

/// One drawn camera look.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// White balance, per channel (R, G, B).
    pub gains: [f32; 3],
    pub exposure: f32,
    pub gamma: f32,
    pub vignette: f32,
    pub noise_std: f32,
    pub blur: bool,
}

impl Look {
    /// The identity: applying it leaves a frame unchanged.
    pub const PLAIN: Look = Look {
        gains: [1.0; 3],
        exposure: 1.0,
        gamma: 1.0,
        vignette: 0.0,
        noise_std: 0.0,
        blur: false,
    };

    /// Draws a look from `cfg`'s ranges.
    pub fn draw<R: Rng + ?Sized>(cfg: &AppearanceConfig, rng: &mut R) -> Self {
        let mut range = |[lo, hi]: [f32; 2]| {
            if hi > lo {
                rng.random_range(lo..hi)
            } else {
                lo
            }
        };
        let exposure = range(cfg.exposure);
        let gamma = range(cfg.gamma);
        let vignette = range(cfg.vignette);
        let noise_std = range(cfg.noise_std);
        let gains = if rng.random::<f32>() < cfg.pink_probability {
            // No IR-cut filter: infrared lifts red and blue over green.
            [
                rng.random_range(1.10..1.35),
                rng.random_range(0.75..0.92),
                rng.random_range(1.00..1.25),
            ]
        } else {
            let t = cfg.tint;
            let mut g = || {
                if t > 0.0 {
                    rng.random_range(1.0 - t..1.0 + t)
                } else {
                    1.0
                }
            };
            [g(), g(), g()]
        };
        let blur = rng.random::<f32>() < cfg.blur_probability;
        Self {
            gains,
            exposure,
            gamma,
            vignette,
            noise_std,
            blur,
        }
    }

    /// Applies the look in place to an RGB8 `width x height` frame, drawing the sensor
    /// noise from `rng`.
    ///
    /// Panics if `rgb.len() != width * height * 3`.
    pub fn apply<R: Rng + ?Sized>(&self, width: u32, height: u32, rng: &mut R, rgb: &mut [u8]) {
        let (w, h) = (width as usize, height as usize);
        assert_eq!(
            rgb.len(),
            w * h * 3,
            "frame buffer must be width * height * 3 bytes"
        );
        // Per channel: 8-bit value -> exposure * gain * x^gamma, in 0..1 (before vignette).
        let mut lut = [[0.0f32; 256]; 3];
        for (c, table) in lut.iter_mut().enumerate() {
            let k = self.exposure * self.gains[c];
            for (v, out) in table.iter_mut().enumerate() {
                *out = k * (v as f32 / 255.0).powf(self.gamma);
            }
        }
        let noise = (self.noise_std > 0.0)
            .then(|| Normal::new(0.0f32, self.noise_std).ok())
            .flatten();
        let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
        let r2_max = cx * cx + cy * cy;
        for (j, row) in rgb.chunks_exact_mut(w * 3).enumerate() {
            let dy = j as f32 + 0.5 - cy;
            for (i, px) in row.chunks_exact_mut(3).enumerate() {
                let dx = i as f32 + 0.5 - cx;
                let shade = 1.0 - self.vignette * (dx * dx + dy * dy) / r2_max;
                for c in 0..3 {
                    let mut v = (lut[c][px[c] as usize] * shade).min(1.0) * 255.0;
                    if let Some(n) = &noise {
                        v += n.sample(rng);
                    }
                    px[c] = v.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        if self.blur && w >= 2 && h >= 2 {
            super::render::blur_121(w, h, rgb);
        }
    }
}

/// The world's randomiser: its own generator (so turning it on leaves the physics' random
/// draws alone), the current look, and the frame count since it was drawn.
#[derive(Debug, Clone)]
pub struct Appearance {
    cfg: AppearanceConfig,
    rng: ChaCha8Rng,
    look: Look,
    frames: u32,
}

impl Appearance {
    /// A randomiser for `cfg` seeded with `seed`, with a first look drawn.
    pub fn new(cfg: AppearanceConfig, seed: u64) -> Self {
        // A stream of its own: the sim's seed, offset so it never equals the physics'.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6170_7065_6172_616e);
        let look = Look::draw(&cfg, &mut rng);
        Self {
            cfg,
            rng,
            look,
            frames: 0,
        }
    }

    /// The look frames get now.
    pub fn look(&self) -> &Look {
        &self.look
    }

    /// A new episode: a new look.
    pub fn redraw(&mut self) {
        self.look = Look::draw(&self.cfg, &mut self.rng);
        self.frames = 0;
    }

    /// Applies the current look to a frame, redrawing it first when it is due.
    pub fn apply(&mut self, width: u32, height: u32, rgb: &mut [u8]) {
        if self.cfg.redraw_every_frames > 0 && self.frames >= self.cfg.redraw_every_frames {
            self.redraw();
        }
        self.frames += 1;
        let look = self.look;
        look.apply(width, height, &mut self.rng, rgb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(w: u32, h: u32, v: u8) -> Vec<u8> {
        vec![v; (w * h * 3) as usize]
    }

    #[test]
    fn plain_look_leaves_a_frame_alone() {
        let mut rgb: Vec<u8> = (0..8 * 8 * 3).map(|i| (i * 7 % 256) as u8).collect();
        let before = rgb.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        Look::PLAIN.apply(8, 8, &mut rng, &mut rgb);
        assert_eq!(rgb, before);
    }

    #[test]
    fn gains_gamma_and_vignette_worked_numbers() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        // White balance: 100 * (1.2, 0.8, 1.0).
        let look = Look {
            gains: [1.2, 0.8, 1.0],
            ..Look::PLAIN
        };
        let mut rgb = grey(4, 4, 100);
        look.apply(4, 4, &mut rng, &mut rgb);
        assert_eq!(&rgb[..3], &[120, 80, 100]);
        // Gamma 2: 255 * (128 / 255)^2 = 64.25 -> 64; exposure 1.5 on top: 96.4 -> 96.
        let look = Look {
            gamma: 2.0,
            exposure: 1.5,
            ..Look::PLAIN
        };
        let mut rgb = grey(4, 4, 128);
        look.apply(4, 4, &mut rng, &mut rgb);
        assert_eq!(rgb[0], 96);
        // Vignette 0.5 on a 4x4 frame: the corner pixel's centre (0.5, 0.5) is at
        // r^2 = (1.5^2 + 1.5^2) / 8 = 0.5625 of the half diagonal's square:
        // 200 * (1 - 0.5 * 0.5625) = 143.75 -> 144; an inner pixel (1.5, 1.5): r^2 = 0.0625,
        // 200 * 0.96875 = 193.75 -> 194.
        let look = Look {
            vignette: 0.5,
            ..Look::PLAIN
        };
        let mut rgb = grey(4, 4, 200);
        look.apply(4, 4, &mut rng, &mut rgb);
        assert_eq!(rgb[0], 144);
        assert_eq!(rgb[(4 + 1) * 3], 194);
        // Over-exposure clips at 255.
        let look = Look {
            exposure: 3.0,
            ..Look::PLAIN
        };
        let mut rgb = grey(2, 2, 200);
        look.apply(2, 2, &mut rng, &mut rgb);
        assert!(rgb.iter().all(|&v| v == 255));
    }

    #[test]
    fn looks_are_deterministic_for_a_seed_and_change_with_it() {
        let cfg = AppearanceConfig {
            enabled: true,
            ..AppearanceConfig::default()
        };
        let frames = |seed: u64| {
            let mut a = Appearance::new(cfg, seed);
            let mut out = Vec::new();
            for k in 0..3 {
                let mut rgb = grey(16, 16, 90 + k);
                a.apply(16, 16, &mut rgb);
                out.push(rgb);
                a.redraw();
            }
            out
        };
        assert_eq!(frames(7), frames(7));
        assert_ne!(frames(7), frames(8));
        // Within one seed, episodes differ.
        let f = frames(7);
        assert_ne!(f[0], f[1]);
    }

    #[test]
    fn draws_stay_in_their_ranges_and_pink_means_red_and_blue_over_green() {
        let cfg = AppearanceConfig {
            pink_probability: 1.0,
            ..AppearanceConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let l = Look::draw(&cfg, &mut rng);
            assert!(l.gains[0] > l.gains[1] && l.gains[2] > l.gains[1], "{l:?}");
            assert!((0.6..1.4).contains(&l.exposure) && (0.8..1.25).contains(&l.gamma));
            assert!((0.0..0.6).contains(&l.vignette) && (0.0..6.0).contains(&l.noise_std));
        }
        // The redraw period: a new look after 150 frames.
        let mut a = Appearance::new(AppearanceConfig::default(), 1);
        let first = *a.look();
        let mut rgb = grey(2, 2, 50);
        for _ in 0..150 {
            a.apply(2, 2, &mut rgb);
        }
        assert_eq!(*a.look(), first);
        a.apply(2, 2, &mut rgb);
        assert_ne!(*a.look(), first);
    }

    #[test]
    fn validate_names_the_bad_key() {
        let cfg = AppearanceConfig {
            gamma: [1.3, 0.9],
            ..AppearanceConfig::default()
        };
        let e = cfg.validate().unwrap_err().to_string();
        assert!(e.contains("sim.appearance: gamma"), "{e}");
        assert!(AppearanceConfig::default().validate().is_ok());
    }
}
