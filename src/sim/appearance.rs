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
//! Light on top of that: a linear brightness gradient across the frame (`light_gradient`,
//! in a random direction) and, with `glare_probability`, a bright Gaussian patch.
//!
//! With `scene = true` a [`Scene`] is drawn with each look as well (road paint, mat and
//! floor colours, the room beyond the mat: `sim::scene`); the world repaints its mat when
//! [`Appearance::generation`] changes.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::SimError;
use super::scene::Scene;

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
    /// A new look at every reset (an episode's start, the car put back after an
    /// intervention). Off with `redraw_every_frames = 0`: one look for the whole run, as
    /// one camera in one room (an `eval` in the world a recording was made in).
    pub redraw_at_reset: bool,
    /// Strength of a linear brightness gradient across the frame (0.5: from 0.5x to 1.5x
    /// between opposite edges), in a random direction.
    pub light_gradient: [f32; 2],
    /// Probability of a glare patch.
    pub glare_probability: f32,
    /// Repaint the scene too (`sim::scene`): road style, colours, line widths, backdrop.
    pub scene: bool,
    /// Probability of JetBot's printed mat (black road, white lines, white mat).
    pub print_probability: f32,
    /// Probability of tape lines on a floor (else the simulator's own mat, jittered).
    pub tape_probability: f32,
    /// Line widths times a factor drawn from this range.
    pub line_width_scale: [f32; 2],
    /// Each paint colour's channels within `1 +- colour_jitter`.
    pub colour_jitter: f32,
    /// Probability of a road of paint or cardboard on the floor (with or without edges).
    pub painted_probability: f32,
    /// Probability that an edge line is worn: one missing, or broken as tape peels.
    pub edge_wear_probability: f32,
    /// Probability of a textured floor (carpet, concrete, wood, foam tiles, tiles:
    /// `sim::floor`) rather than a flat colour.
    pub floor_texture_probability: f32,
    /// Number of cables lying on the floor, `[least, most]`.
    pub cables: [u32; 2],
    /// Number of things standing on the floor in view (feet and legs, chair legs, boxes),
    /// `[least, most]`.
    pub floor_objects: [u32; 2],
    /// Probability of the robot's own shadow at the bottom of the frame, and again of
    /// another shadow on the floor.
    pub shadow_probability: f32,
    /// Probability of a bright window on the wall.
    pub window_probability: f32,
    /// Number of blocks (furniture, people) beyond the mat, `[least, most]`.
    pub clutter: [u32; 2],
    /// The camera's tilt below the horizontal, degrees, drawn with each look (rendered
    /// frames only; unset: `[sim.camera] tilt_deg` throughout). JetBot's camera mount is
    /// bent by hand: the real frames show it from about 15 to 37 degrees.
    pub camera_tilt_deg: Option<[f32; 2]>,
    /// The camera's height above the floor, metres, drawn with each look (rendered frames
    /// only; unset: `[sim.camera] height_m`). JetBot kits mount it from about 0.08 to
    /// 0.15 m.
    pub camera_height_m: Option<[f32; 2]>,
    /// The lens's field of view times a factor drawn from this range with each look
    /// (rendered frames only; unset: the configured lens). Spreads one lens model over
    /// the 160-200 degree lenses JetBot kits ship.
    pub lens_fov_scale: Option<[f32; 2]>,
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
            redraw_at_reset: true,
            light_gradient: [0.0, 0.5],
            glare_probability: 0.3,
            scene: true,
            print_probability: 0.3,
            tape_probability: 0.35,
            painted_probability: 0.15,
            edge_wear_probability: 0.25,
            floor_texture_probability: 0.8,
            cables: [0, 2],
            floor_objects: [0, 2],
            shadow_probability: 0.4,
            window_probability: 0.3,
            line_width_scale: [0.6, 1.6],
            colour_jitter: 0.15,
            clutter: [0, 6],
            camera_tilt_deg: None,
            camera_height_m: None,
            lens_fov_scale: None,
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
            ("light_gradient", self.light_gradient, 0.0, 1.0),
            ("line_width_scale", self.line_width_scale, 0.1, 5.0),
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
            ("glare_probability", self.glare_probability),
            ("print_probability", self.print_probability),
            ("tape_probability", self.tape_probability),
            ("painted_probability", self.painted_probability),
            ("edge_wear_probability", self.edge_wear_probability),
            ("floor_texture_probability", self.floor_texture_probability),
            ("shadow_probability", self.shadow_probability),
            ("window_probability", self.window_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return bad(format!("{name} = {p} must be in 0..=1"));
            }
        }
        if !(0.0..=0.9).contains(&self.tint) {
            return bad(format!("tint = {} must be in 0..=0.9", self.tint));
        }
        let roads = self.print_probability + self.tape_probability + self.painted_probability;
        if roads > 1.0 + 1e-6 {
            return bad(format!(
                "print_probability + tape_probability + painted_probability = {roads} must be \
                 at most 1 (the rest is the simulator's own mat)"
            ));
        }
        if !(0.0..=0.5).contains(&self.colour_jitter) {
            return bad(format!(
                "colour_jitter = {} must be in 0..=0.5",
                self.colour_jitter
            ));
        }
        for (name, [lo, hi], most) in [
            ("clutter", self.clutter, 64),
            ("cables", self.cables, 16),
            ("floor_objects", self.floor_objects, 16),
        ] {
            if lo > hi || hi > most {
                return bad(format!(
                    "{name} = [{lo}, {hi}] must satisfy low <= high <= {most}"
                ));
            }
        }
        for (name, range, min, max) in [
            ("camera_height_m", self.camera_height_m, 0.02, 2.0),
            ("lens_fov_scale", self.lens_fov_scale, 0.5, 1.5),
        ] {
            if let Some([lo, hi]) = range
                && !(lo.is_finite() && hi.is_finite() && min <= lo && lo <= hi && hi <= max)
            {
                return bad(format!(
                    "{name} = [{lo}, {hi}] must satisfy {min} <= low <= high <= {max}"
                ));
            }
        }
        if let Some([lo, hi]) = self.camera_tilt_deg
            && !(lo.is_finite() && hi.is_finite() && -80.0 <= lo && lo <= hi && hi <= 80.0)
        {
            return bad(format!(
                "camera_tilt_deg = [{lo}, {hi}] must satisfy -80 <= low <= high <= 80"
            ));
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
    /// Brightness gradient: `shade *= 1 + gx * dx / cx + gy * dy / cy` (offsets from the
    /// centre over the half sizes).
    pub gradient: [f32; 2],
    /// A glare patch: centre `(u, v)` in pixels, radius (the Gaussian's sigma) in pixels,
    /// and its peak, added to 0..1 values.
    pub glare: Option<Glare>,
    /// The camera's tilt below the horizontal, degrees (`None`: the configured camera's).
    pub tilt_deg: Option<f32>,
    /// The camera's height, metres (`None`: the configured camera's).
    pub height_m: Option<f32>,
    /// The lens's field of view times this (`None`: the configured lens).
    pub fov_scale: Option<f32>,
}

/// A value drawn uniformly from `[lo, hi)`, or `lo` where the range is empty.
pub(super) fn draw_in<R: Rng + ?Sized>(rng: &mut R, [lo, hi]: [f32; 2]) -> f32 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

/// A bright Gaussian patch (a lamp's reflection on a glossy mat).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Glare {
    /// Centre as fractions of the frame's width and height.
    pub centre: [f32; 2],
    /// Sigma as a fraction of the frame's width.
    pub radius: f32,
    pub peak: f32,
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
        gradient: [0.0, 0.0],
        glare: None,
        tilt_deg: None,
        height_m: None,
        fov_scale: None,
    };

    /// Draws a look from `cfg`'s ranges.
    pub fn draw<R: Rng + ?Sized>(cfg: &AppearanceConfig, rng: &mut R) -> Self {
        let mut range = |r: [f32; 2]| draw_in(rng, r);
        let exposure = range(cfg.exposure);
        let gamma = range(cfg.gamma);
        let vignette = range(cfg.vignette);
        let noise_std = range(cfg.noise_std);
        let strength = range(cfg.light_gradient);
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
        let angle = rng.random_range(0.0..std::f32::consts::TAU);
        let gradient = [strength * angle.cos(), strength * angle.sin()];
        let glare = (rng.random::<f32>() < cfg.glare_probability).then(|| Glare {
            centre: [rng.random_range(0.0..1.0), rng.random_range(0.0..1.0)],
            radius: rng.random_range(0.04..0.2),
            peak: rng.random_range(0.2..0.8),
        });
        // Drawn last, and only when asked for, so every other draw stays as it was.
        let mut within = |r: Option<[f32; 2]>| r.map(|r| draw_in(rng, r));
        let tilt_deg = within(cfg.camera_tilt_deg);
        let height_m = within(cfg.camera_height_m);
        let fov_scale = within(cfg.lens_fov_scale);
        Self {
            gains,
            exposure,
            gamma,
            vignette,
            noise_std,
            blur,
            gradient,
            glare,
            tilt_deg,
            height_m,
            fov_scale,
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
        let [gx, gy] = self.gradient;
        // Glare in pixels: centre, and -1 / (2 sigma^2).
        let glare = self.glare.map(|g| {
            let sigma = (g.radius * w as f32).max(0.5);
            (
                g.centre[0] * w as f32,
                g.centre[1] * h as f32,
                -0.5 / (sigma * sigma),
                g.peak,
            )
        });
        for (j, row) in rgb.chunks_exact_mut(w * 3).enumerate() {
            let dy = j as f32 + 0.5 - cy;
            for (i, px) in row.chunks_exact_mut(3).enumerate() {
                let dx = i as f32 + 0.5 - cx;
                let light = (1.0 + gx * dx / cx + gy * dy / cy).max(0.0);
                let shade = (1.0 - self.vignette * (dx * dx + dy * dy) / r2_max) * light;
                let flare = glare.map_or(0.0, |(gu, gv, k, peak)| {
                    let (du, dv) = (i as f32 + 0.5 - gu, j as f32 + 0.5 - gv);
                    peak * (k * (du * du + dv * dv)).exp()
                });
                for c in 0..3 {
                    let mut v = (lut[c][px[c] as usize] * shade + flare).min(1.0) * 255.0;
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
    /// The scene drawn with the look (`cfg.scene`).
    scene: Option<Scene>,
    /// Counts draws, so the world can tell when to repaint.
    generation: u64,
    frames: u32,
}

impl Appearance {
    /// A randomiser for `cfg` seeded with `seed`, with a first look drawn.
    pub fn new(cfg: AppearanceConfig, seed: u64) -> Self {
        // A stream of its own: the sim's seed, offset so it never equals the physics'.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6170_7065_6172_616e);
        let look = Look::draw(&cfg, &mut rng);
        let scene = cfg.scene.then(|| Scene::draw(&cfg, &mut rng));
        Self {
            cfg,
            rng,
            look,
            scene,
            generation: 0,
            frames: 0,
        }
    }

    /// The scene drawn with the current look (`None` unless `scene = true`).
    pub fn scene(&self) -> Option<&Scene> {
        self.scene.as_ref()
    }

    /// Changes whenever a new look (and scene) is drawn.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Counts a frame, drawing a new look (and scene) first when one is due.
    pub fn next_frame(&mut self) {
        if self.cfg.redraw_every_frames > 0 && self.frames >= self.cfg.redraw_every_frames {
            self.redraw();
        }
        self.frames += 1;
    }

    /// Applies the current look to a frame (no counting, no redraw).
    pub fn apply_look(&mut self, width: u32, height: u32, rgb: &mut [u8]) {
        let look = self.look;
        look.apply(width, height, &mut self.rng, rgb);
    }

    /// The look frames get now.
    pub fn look(&self) -> &Look {
        &self.look
    }

    /// The car was reset (a new episode, or put back after an intervention): a new look,
    /// unless `redraw_at_reset` is off.
    pub fn reset(&mut self) {
        if self.cfg.redraw_at_reset {
            self.redraw();
        }
    }

    /// A new episode: a new look.
    pub fn redraw(&mut self) {
        self.look = Look::draw(&self.cfg, &mut self.rng);
        if self.cfg.scene {
            self.scene = Some(Scene::draw(&self.cfg, &mut self.rng));
        }
        self.generation += 1;
        self.frames = 0;
    }

    /// [`Self::next_frame`] then [`Self::apply_look`].
    pub fn apply(&mut self, width: u32, height: u32, rgb: &mut [u8]) {
        self.next_frame();
        self.apply_look(width, height, rgb);
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
        // A reset draws a new look, unless redraw_at_reset is off (one look all run).
        let second = *a.look();
        a.reset();
        assert_ne!(*a.look(), second);
        let mut kept = Appearance::new(
            AppearanceConfig {
                redraw_every_frames: 0,
                redraw_at_reset: false,
                ..AppearanceConfig::default()
            },
            1,
        );
        let (look, generation) = (*kept.look(), kept.generation());
        for _ in 0..400 {
            kept.apply(2, 2, &mut rgb);
        }
        kept.reset();
        assert_eq!((*kept.look(), kept.generation()), (look, generation));
    }

    #[test]
    fn a_camera_tilt_range_is_drawn_last_and_leaves_every_other_draw_alone() {
        let plain = AppearanceConfig::default();
        let tilted = AppearanceConfig {
            camera_tilt_deg: Some([15.0, 40.0]),
            ..plain
        };
        let (mut a, mut b) = (ChaCha8Rng::seed_from_u64(5), ChaCha8Rng::seed_from_u64(5));
        let mut tilts = Vec::new();
        for _ in 0..100 {
            let (p, t) = (Look::draw(&plain, &mut a), Look::draw(&tilted, &mut b));
            assert_eq!(p.tilt_deg, None);
            let tilt = t.tilt_deg.unwrap();
            assert!((15.0..40.0).contains(&tilt), "{tilt}");
            assert_eq!(
                Look {
                    tilt_deg: None,
                    ..t
                },
                p
            );
            tilts.push(tilt);
            // Keep the two streams level: the tilted draw took one number more.
            let _: f32 = a.random();
        }
        let spread = tilts.iter().cloned().fold(f32::MIN, f32::max)
            - tilts.iter().cloned().fold(f32::MAX, f32::min);
        assert!(spread > 20.0, "{spread}");
        // A fixed tilt is a one-point range.
        let fixed = AppearanceConfig {
            camera_tilt_deg: Some([20.0, 20.0]),
            ..plain
        };
        assert_eq!(Look::draw(&fixed, &mut a).tilt_deg, Some(20.0));
        let bad = AppearanceConfig {
            camera_tilt_deg: Some([30.0, 10.0]),
            ..plain
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("camera_tilt_deg"), "{e}");
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
