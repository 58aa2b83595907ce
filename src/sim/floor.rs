//! Floors with texture (`[sim.appearance]`, `sim::scene`): what a JetBot road lies on in
//! people's homes and labs. A flat colour teaches a policy that anything with texture is
//! not floor; real roads lie on carpet, concrete, wood and tiles, with seams and stains
//! that are not roads.
//!
//! A [`Floor`] is a pure function of a world point: [`Floor::texel`] gives the colour at
//! `(x, y)` metres, so a drawn floor is reproducible from its seed and testable at any
//! point. The kinds, each from a base colour (and a second one where the kind has two):
//! - `Plain`: the base colour;
//! - `LowPile` and `Shag` carpet: fine fibre noise around the base, shag stronger and in
//!   clumps, with a slow mottle;
//! - `Concrete`: mottled grey with dark specks, sometimes a straight expansion joint;
//! - `Wood`: planks `cell_m` wide with their own tones, grain along them, dark gaps between
//!   them and staggered end joints;
//! - `Foam`: puzzle tiles `cell_m` square in two colours, each tile one of them, with
//!   toothed dark seams;
//! - `Tiles`: square tiles `cell_m` with grout lines `line_m` wide in the second colour.
//!
//! Over any kind, `stains`: soft round patches darker or lighter than the floor. The whole
//! pattern is turned by `angle` about the origin (floors are not laid along the track).

use rand::Rng;

/// The kinds of floor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FloorKind {
    Plain,
    LowPile,
    Shag,
    Concrete,
    Wood,
    Foam,
    Tiles,
}

impl FloorKind {
    /// Every kind, in the order [`Floor::draw`] picks from.
    pub const ALL: [FloorKind; 7] = [
        FloorKind::Plain,
        FloorKind::LowPile,
        FloorKind::Shag,
        FloorKind::Concrete,
        FloorKind::Wood,
        FloorKind::Foam,
        FloorKind::Tiles,
    ];
}

/// A soft round patch: `shade` times the floor's colour at the centre, fading to 1 at
/// `radius_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stain {
    pub centre: [f32; 2],
    pub radius_m: f32,
    pub shade: f32,
}

/// One drawn floor.
#[derive(Debug, Clone, PartialEq)]
pub struct Floor {
    pub kind: FloorKind,
    /// The floor's main colour (carpet, concrete, wood, the first foam colour, the tiles).
    pub base: [u8; 3],
    /// The second colour: foam's other tiles, the tiles' grout, wood's gaps.
    pub second: [u8; 3],
    /// Planks' width, foam and tile squares' side, metres.
    pub cell_m: f32,
    /// Grout, plank gap and seam width, metres.
    pub line_m: f32,
    /// How far the texture strays from the base colour (0: flat).
    pub contrast: f32,
    /// The pattern's turn about the origin, radians.
    pub angle: f32,
    /// Concrete's expansion joint: a straight line at this offset (metres, in the pattern's
    /// frame, across x), if any.
    pub joint_m: Option<f32>,
    pub stains: Vec<Stain>,
    /// Seed of the noise and of each plank's and tile's tone.
    pub seed: u64,
}

/// splitmix64 of a seed and a lattice point: the same inputs, the same value.
fn hash(seed: u64, i: i64, j: i64) -> u64 {
    let mut z = seed
        ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A value in `[0, 1)` from [`hash`].
fn unit(seed: u64, i: i64, j: i64) -> f32 {
    (hash(seed, i, j) >> 40) as f32 / (1u64 << 24) as f32
}

/// Smooth value noise in `[0, 1]` with one lattice cell per unit of `(x, y)`.
fn value_noise(seed: u64, x: f32, y: f32) -> f32 {
    let (fx, fy) = (x.floor(), y.floor());
    let (i, j) = (fx as i64, fy as i64);
    let (tx, ty) = (x - fx, y - fy);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let a = unit(seed, i, j) + sx * (unit(seed, i + 1, j) - unit(seed, i, j));
    let b = unit(seed, i, j + 1) + sx * (unit(seed, i + 1, j + 1) - unit(seed, i, j + 1));
    a + sy * (b - a)
}

fn scale(rgb: [u8; 3], k: f32) -> [u8; 3] {
    rgb.map(|c| (c as f32 * k).round().clamp(0.0, 255.0) as u8)
}

impl Floor {
    /// A flat floor of one colour (the simulator's own, and every floor before textures).
    pub fn plain(rgb: [u8; 3]) -> Floor {
        Floor {
            kind: FloorKind::Plain,
            base: rgb,
            second: rgb,
            cell_m: 1.0,
            line_m: 0.0,
            contrast: 0.0,
            angle: 0.0,
            joint_m: None,
            stains: Vec::new(),
            seed: 0,
        }
    }

    /// Draws a floor of `kind` around `base` (which `Scene::draw` picks), with its own
    /// sizes, second colour, turn, stains and seed. `extent` is the floor's size, metres
    /// (stains are placed within it).
    pub fn draw<R: Rng + ?Sized>(
        kind: FloorKind,
        base: [u8; 3],
        extent: (f32, f32),
        rng: &mut R,
    ) -> Floor {
        let mut f = Floor {
            kind,
            base,
            seed: rng.random(),
            angle: rng.random_range(0.0..std::f32::consts::PI),
            ..Floor::plain(base)
        };
        match kind {
            FloorKind::Plain => {}
            FloorKind::LowPile => f.contrast = rng.random_range(0.08..0.2),
            FloorKind::Shag => f.contrast = rng.random_range(0.2..0.4),
            FloorKind::Concrete => {
                f.contrast = rng.random_range(0.05..0.15);
                f.line_m = rng.random_range(0.004..0.01);
                f.joint_m = (rng.random::<f32>() < 0.5)
                    .then(|| rng.random_range(-extent.0 / 2.0..extent.0 / 2.0));
                f.second = scale(base, 0.55);
            }
            FloorKind::Wood => {
                f.contrast = rng.random_range(0.06..0.18);
                f.cell_m = rng.random_range(0.08..0.22);
                f.line_m = rng.random_range(0.001..0.004);
                f.second = scale(base, 0.45);
            }
            FloorKind::Foam => {
                f.contrast = rng.random_range(0.02..0.06);
                f.cell_m = rng.random_range(0.30..0.62);
                f.line_m = rng.random_range(0.002..0.005);
                // Puzzle mats come in sets: often two colours, sometimes all one.
                f.second = if rng.random::<f32>() < 0.6 {
                    [0, 1, 2].map(|_| rng.random_range(30..=230))
                } else {
                    base
                };
            }
            FloorKind::Tiles => {
                f.contrast = rng.random_range(0.02..0.08);
                f.cell_m = rng.random_range(0.10..0.60);
                f.line_m = rng.random_range(0.002..0.008);
                let g = rng.random_range(60..=230);
                f.second = [g, g, g];
            }
        }
        let n = rng.random_range(0..=3);
        f.stains = (0..n)
            .map(|_| Stain {
                centre: [
                    rng.random_range(0.0..extent.0.max(0.01)),
                    rng.random_range(0.0..extent.1.max(0.01)),
                ],
                radius_m: rng.random_range(0.03..0.25),
                shade: if rng.random::<f32>() < 0.7 {
                    rng.random_range(0.6..0.9)
                } else {
                    rng.random_range(1.1..1.3)
                },
            })
            .collect();
        f
    }

    /// The colour at world point `(x, y)` metres.
    pub fn texel(&self, x: f32, y: f32) -> [u8; 3] {
        let (s, c) = self.angle.sin_cos();
        // The pattern's frame: u along planks and tile rows, v across.
        let (u, v) = (c * x + s * y, -s * x + c * y);
        let seed = self.seed;
        let k = self.contrast;
        let (rgb, shade) = match self.kind {
            FloorKind::Plain => (self.base, 1.0),
            FloorKind::LowPile => {
                let fibre = unit(seed, (u * 600.0) as i64, (v * 600.0) as i64) - 0.5;
                let mottle = value_noise(seed ^ 1, u * 8.0, v * 8.0) - 0.5;
                (self.base, 1.0 + k * fibre + 0.5 * k * mottle)
            }
            FloorKind::Shag => {
                let clump = value_noise(seed, u * 120.0, v * 120.0) - 0.5;
                let fibre = unit(seed ^ 2, (u * 500.0) as i64, (v * 500.0) as i64) - 0.5;
                let mottle = value_noise(seed ^ 1, u * 5.0, v * 5.0) - 0.5;
                (
                    self.base,
                    1.0 + k * (1.2 * clump + 0.6 * fibre + 0.5 * mottle),
                )
            }
            FloorKind::Concrete => {
                if self
                    .joint_m
                    .is_some_and(|j| (u - j).abs() < self.line_m / 2.0)
                {
                    (self.second, 1.0)
                } else {
                    let coarse = value_noise(seed, u * 6.0, v * 6.0) - 0.5;
                    let fine = value_noise(seed ^ 3, u * 60.0, v * 60.0) - 0.5;
                    let speck = unit(seed ^ 4, (u * 300.0) as i64, (v * 300.0) as i64);
                    let dark = if speck > 0.985 { -0.35 } else { 0.0 };
                    (self.base, 1.0 + 2.0 * k * coarse + k * fine + dark)
                }
            }
            FloorKind::Wood => {
                let w = self.cell_m;
                let plank = (v / w).floor();
                let across = v - plank * w;
                // End joints: each plank's row is cut every 0.6-1.5 m, staggered.
                let length = 0.6 + 0.9 * unit(seed ^ 5, plank as i64, 0);
                let start = unit(seed ^ 6, plank as i64, 1) * length;
                let along = (u - start).rem_euclid(length);
                let piece = ((u - start) / length).floor() as i64;
                if across < self.line_m || along < self.line_m {
                    (self.second, 1.0)
                } else {
                    let tone = 1.0 + 1.5 * k * (unit(seed ^ 7, plank as i64, piece) - 0.5);
                    let wobble = value_noise(seed ^ 8, u * 3.0, plank) * 0.02;
                    let grain = ((across + wobble) * 700.0).sin() * 0.5
                        + (value_noise(seed ^ 9, u * 40.0, across * 400.0) - 0.5);
                    (self.base, tone * (1.0 + 0.5 * k * grain))
                }
            }
            FloorKind::Foam => {
                let w = self.cell_m;
                // Puzzle teeth: each seam wanders by a triangle wave of 1/6 the tile.
                let tooth = |t: f32| {
                    let p = (t / (w / 6.0)).rem_euclid(2.0);
                    (if p < 1.0 { p } else { 2.0 - p }) * 0.03 * w
                };
                let (cu, cv) = (u + tooth(v), v + tooth(u));
                let (i, j) = ((cu / w).floor(), (cv / w).floor());
                let (du, dv) = (cu - i * w, cv - j * w);
                let grain = value_noise(seed, u * 200.0, v * 200.0) - 0.5;
                if du < self.line_m || dv < self.line_m {
                    (scale(self.base, 0.5), 1.0)
                } else if unit(seed, i as i64, j as i64) < 0.5 {
                    (self.base, 1.0 + k * grain)
                } else {
                    (self.second, 1.0 + k * grain)
                }
            }
            FloorKind::Tiles => {
                let w = self.cell_m;
                let (i, j) = ((u / w).floor(), (v / w).floor());
                let (du, dv) = (u - i * w, v - j * w);
                if du < self.line_m || dv < self.line_m {
                    (self.second, 1.0)
                } else {
                    let tone = 1.0 + 2.0 * k * (unit(seed, i as i64, j as i64) - 0.5);
                    let fine = value_noise(seed ^ 10, u * 50.0, v * 50.0) - 0.5;
                    (self.base, tone + k * fine)
                }
            }
        };
        let mut shade = shade;
        for st in &self.stains {
            let d = (x - st.centre[0]).hypot(y - st.centre[1]) / st.radius_m;
            if d < 1.0 {
                let t = 1.0 - d * d;
                shade *= 1.0 + (st.shade - 1.0) * t * t;
            }
        }
        scale(rgb, shade)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn floor(kind: FloorKind) -> Floor {
        Floor {
            kind,
            base: [200, 150, 100],
            second: [40, 40, 40],
            cell_m: 0.5,
            line_m: 0.01,
            contrast: 0.1,
            angle: 0.0,
            joint_m: None,
            stains: Vec::new(),
            seed: 7,
        }
    }

    #[test]
    fn grout_lies_on_the_tile_lines_and_tiles_between_them() {
        let f = floor(FloorKind::Tiles);
        // Grout where u or v is within line_m past a multiple of 0.5 m.
        assert_eq!(f.texel(0.004, 0.25), [40, 40, 40]);
        assert_eq!(f.texel(0.25, 0.504), [40, 40, 40]);
        assert_eq!(f.texel(-0.496, 0.3), [40, 40, 40]);
        // Tile centres: the base colour within 1 +- 1.5 contrast (tone 1 +- k, noise k/2).
        for (x, y) in [(0.25, 0.25), (0.75, 0.25), (-0.25, 1.3)] {
            let px = f.texel(x, y);
            for (p, b) in px.iter().zip(f.base) {
                let r = *p as f32 / b as f32;
                assert!((0.84..=1.16).contains(&r), "tile at ({x}, {y}): {px:?}");
            }
        }
        // One tile has one tone: two points in it differ only by the fine noise.
        let (a, b) = (f.texel(0.2, 0.2), f.texel(0.21, 0.2));
        assert!((a[0] as i32 - b[0] as i32).abs() <= 6, "{a:?} {b:?}");
    }

    #[test]
    fn a_turned_floor_turns_its_grout() {
        let mut f = floor(FloorKind::Tiles);
        f.angle = std::f32::consts::FRAC_PI_2;
        // u = y, v = -x: grout where y is near a multiple of 0.5 m, or -x is.
        assert_eq!(f.texel(0.25, 0.004), [40, 40, 40]);
        assert_ne!(f.texel(0.004, 0.25), [40, 40, 40]);
        assert_eq!(f.texel(-0.004, 0.25), [40, 40, 40]);
    }

    #[test]
    fn planks_have_gaps_their_own_tones_and_grain() {
        let f = floor(FloorKind::Wood);
        // The gap between planks at v = 0.5 m (plank 1's first line_m).
        assert_eq!(f.texel(0.3, 0.505), [40, 40, 40]);
        // Along a plank, away from its joints, the grain makes the colour vary.
        let row: Vec<u8> = (0..50)
            .map(|k| f.texel(0.3, 0.52 + 0.009 * k as f32)[0])
            .collect();
        let (lo, hi) = (row.iter().min().unwrap(), row.iter().max().unwrap());
        assert!(hi - lo >= 5, "grain across a plank: {lo}..{hi}");
    }

    #[test]
    fn foam_seams_are_dark_and_tiles_take_one_of_two_colours() {
        let mut f = floor(FloorKind::Foam);
        f.second = [30, 90, 200];
        f.line_m = 0.004;
        // At v = 2 w / 6 the teeth are at 0: the seam is at u = 0, half the base colour.
        assert_eq!(f.texel(0.001, 0.5 / 3.0), [100, 75, 50]);
        // Half a tooth along (v = w / 6), the seam has moved by 0.03 w = 15 mm.
        assert_eq!(f.texel(-0.013, 0.5 / 6.0), [100, 75, 50]);
        assert_ne!(f.texel(0.001, 0.5 / 6.0), [100, 75, 50]);
        // Every tile centre is near one of the two colours.
        for i in 0..6 {
            let px = f.texel(0.25 + 0.5 * i as f32, 0.3);
            let near = |c: [u8; 3]| {
                px.iter()
                    .zip(c)
                    .all(|(p, c)| (*p as i32 - c as i32).abs() <= 12)
            };
            assert!(near(f.base) || near(f.second), "tile {i}: {px:?}");
        }
    }

    #[test]
    fn carpet_varies_around_its_base_and_shag_varies_more() {
        let spread = |kind| {
            let mut f = floor(kind);
            f.contrast = 0.3;
            let v: Vec<f32> = (0..400)
                .map(|k| f.texel(0.0123 * k as f32, 0.0071 * k as f32)[1] as f32)
                .collect();
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / v.len() as f32).sqrt();
            (mean, sd)
        };
        let (low_mean, low_sd) = spread(FloorKind::LowPile);
        let (shag_mean, shag_sd) = spread(FloorKind::Shag);
        assert!((low_mean - 150.0).abs() < 8.0, "low pile mean {low_mean}");
        assert!((shag_mean - 150.0).abs() < 12.0, "shag mean {shag_mean}");
        assert!(low_sd > 3.0, "low pile varies: sd {low_sd}");
        assert!(shag_sd > low_sd, "shag {shag_sd} > low pile {low_sd}");
        assert_eq!(spread(FloorKind::Plain), (150.0, 0.0));
    }

    #[test]
    fn a_stain_darkens_its_centre_and_nothing_past_its_radius() {
        let mut f = floor(FloorKind::Plain);
        f.stains = vec![Stain {
            centre: [1.0, 1.0],
            radius_m: 0.1,
            shade: 0.5,
        }];
        assert_eq!(f.texel(1.0, 1.0), [100, 75, 50]);
        assert_eq!(f.texel(1.1, 1.0), [200, 150, 100]);
        assert_eq!(f.texel(0.5, 0.5), [200, 150, 100]);
    }

    #[test]
    fn a_concrete_joint_is_a_straight_dark_line() {
        let mut f = floor(FloorKind::Concrete);
        f.joint_m = Some(0.3);
        for y in [-1.0, 0.0, 2.5] {
            assert_eq!(f.texel(0.302, y), [40, 40, 40]);
            assert_ne!(f.texel(0.32, y), [40, 40, 40]);
        }
    }

    #[test]
    fn a_draw_is_reproducible_from_its_seed() {
        for kind in FloorKind::ALL {
            let a = Floor::draw(
                kind,
                [120, 110, 100],
                (2.0, 3.0),
                &mut ChaCha8Rng::seed_from_u64(3),
            );
            let b = Floor::draw(
                kind,
                [120, 110, 100],
                (2.0, 3.0),
                &mut ChaCha8Rng::seed_from_u64(3),
            );
            assert_eq!(a, b);
            assert_eq!(a.texel(0.37, 1.21), b.texel(0.37, 1.21));
        }
    }
}
