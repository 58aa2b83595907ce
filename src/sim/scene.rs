//! Scene randomisation, world side (`[sim.appearance]` with `scene = true`): what the mat,
//! its road, the floor around it and the room beyond look like. JetBot owners drive on
//! JetBot's printed mat, on tape stuck to a floor, or on mats of their own, in rooms full
//! of desks and people; a policy that has only seen one paint learns the paint.
//!
//! A [`Scene`] is drawn with each camera look (per episode, and every
//! `redraw_every_frames`). It is one of three road styles, with jittered colours and line
//! widths:
//! - `Sim`: the simulator's own mat (dark road, yellow edges, white dashes on green);
//! - `Print`: JetBot's printed mat as it shows in real frames: a near-black road with a
//!   white dashed centre line, sometimes thin light edges, on a white mat;
//! - `Tape`: no road surface, two tape lines (white, yellow, blue, black, red or green) on
//!   a grey, wooden or tiled floor, sometimes a centre line.
//!
//! Beyond the ground, a backdrop: a wall with a vertical gradient and up to `clutter`
//! upright blocks (furniture-sized boxes and person-height shapes) standing behind the
//! horizon. The backdrop is drawn in image space, so it moves with the camera: good enough
//! to teach a policy to ignore what is above the road, not a room model.
//!
//! Only rendered frames are repainted; replayed frames keep the real scene they recorded.

use rand::Rng;

use super::appearance::AppearanceConfig;
use super::camera::CameraModel;
use super::track::{CENTRE_DASH_M, CENTRE_LINE_WIDTH_M, EDGE_LINE_WIDTH_M, RoadPaint};

/// The mat colour the simulator's own scene uses (`sim::setup`).
pub const SIM_MAT_RGB: [u8; 3] = [96, 120, 92];
/// The floor colour the simulator's own scene uses.
pub const SIM_FLOOR_RGB: [u8; 3] = [150, 130, 110];

/// Which kind of road a scene has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RoadStyle {
    Sim,
    Print,
    Tape,
}

/// An upright shape beyond the mat, in image space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Block {
    /// Left and right edges, fractions of the image width.
    pub u: [f32; 2],
    /// Top edge as a fraction of the horizon's row (0: the image's top, 1: the horizon).
    pub top: f32,
    pub rgb: [u8; 3],
}

/// One drawn scene: the road paint, the mat and floor colours, and the backdrop.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub style: RoadStyle,
    pub paint: RoadPaint,
    pub mat_rgb: [u8; 3],
    pub floor_rgb: [u8; 3],
    pub wall_rgb: [u8; 3],
    pub blocks: Vec<Block>,
}

fn range<R: Rng + ?Sized>(rng: &mut R, [lo, hi]: [f32; 2]) -> f32 {
    if hi > lo {
        rng.random_range(lo..hi)
    } else {
        lo
    }
}

fn grey<R: Rng + ?Sized>(rng: &mut R, lo: u8, hi: u8) -> [u8; 3] {
    let v = rng.random_range(lo..=hi);
    [v, v, v]
}

/// Each channel scaled by its own factor within `1 +- amount`.
fn jitter<R: Rng + ?Sized>(rng: &mut R, rgb: [u8; 3], amount: f32) -> [u8; 3] {
    rgb.map(|c| {
        let k = if amount > 0.0 {
            rng.random_range(1.0 - amount..1.0 + amount)
        } else {
            1.0
        };
        (c as f32 * k).round().clamp(0.0, 255.0) as u8
    })
}

/// Floors people put mats and tape on: light tiles, wood, concrete grey, dark carpet.
fn floor<R: Rng + ?Sized>(rng: &mut R) -> [u8; 3] {
    const FLOORS: [[u8; 3]; 5] = [
        [215, 212, 205],
        [165, 120, 80],
        [140, 138, 132],
        [70, 68, 72],
        [190, 170, 140],
    ];
    FLOORS[rng.random_range(0..FLOORS.len())]
}

impl Scene {
    /// The simulator's own scene, unjittered (what rendering shows without randomisation).
    pub fn sim() -> Scene {
        Scene {
            style: RoadStyle::Sim,
            paint: RoadPaint::SIM,
            mat_rgb: SIM_MAT_RGB,
            floor_rgb: SIM_FLOOR_RGB,
            wall_rgb: super::render::DEFAULT_WALL_RGB,
            blocks: Vec::new(),
        }
    }

    /// Draws a scene from `cfg`'s probabilities and ranges.
    pub fn draw<R: Rng + ?Sized>(cfg: &AppearanceConfig, rng: &mut R) -> Scene {
        let k = range(rng, cfg.line_width_scale);
        let j = cfg.colour_jitter;
        let pick: f32 = rng.random();
        let style = if pick < cfg.print_probability {
            RoadStyle::Print
        } else if pick < cfg.print_probability + cfg.tape_probability {
            RoadStyle::Tape
        } else {
            RoadStyle::Sim
        };
        let dash = |rng: &mut R| {
            Some((
                rng.random_range(0.03..0.08f32),
                rng.random_range(0.03..0.08f32),
            ))
        };
        let (paint, mat_rgb, floor_rgb) = match style {
            RoadStyle::Sim => {
                let s = RoadPaint::SIM;
                let paint = RoadPaint {
                    road_rgb: s.road_rgb.map(|c| jitter(rng, c, j)),
                    edge_rgb: s.edge_rgb.map(|c| jitter(rng, c, j)),
                    edge_width_m: s.edge_width_m * k,
                    centre_rgb: s.centre_rgb.map(|c| jitter(rng, c, j)),
                    centre_width_m: s.centre_width_m * k,
                    centre_dash_m: s.centre_dash_m,
                };
                let mat = jitter(rng, SIM_MAT_RGB, j);
                (paint, mat, jitter(rng, SIM_FLOOR_RGB, j))
            }
            RoadStyle::Print => {
                let g = grey(rng, 215, 250);
                let white = jitter(rng, g, j / 3.0);
                let edges = rng.random::<f32>() < 0.5;
                let g = grey(rng, 12, 55);
                let road = jitter(rng, g, j);
                let paint = RoadPaint {
                    road_rgb: Some(road),
                    edge_rgb: edges.then_some(white),
                    edge_width_m: 0.008 * k,
                    centre_rgb: Some(white),
                    centre_width_m: CENTRE_LINE_WIDTH_M * k,
                    centre_dash_m: dash(rng),
                };
                let g = grey(rng, 205, 250);
                let mat = jitter(rng, g, j / 3.0);
                let f = floor(rng);
                (paint, mat, jitter(rng, f, j))
            }
            RoadStyle::Tape => {
                const TAPES: [[u8; 3]; 6] = [
                    [240, 240, 235],
                    [235, 200, 40],
                    [40, 90, 200],
                    [25, 25, 28],
                    [200, 40, 40],
                    [40, 160, 70],
                ];
                let t = TAPES[rng.random_range(0..TAPES.len())];
                let tape = jitter(rng, t, j);
                let centre = rng.random::<f32>() < 0.4;
                let paint = RoadPaint {
                    road_rgb: None,
                    edge_rgb: Some(tape),
                    edge_width_m: rng.random_range(0.6..2.5) * EDGE_LINE_WIDTH_M * k,
                    centre_rgb: centre.then_some(tape),
                    centre_width_m: CENTRE_LINE_WIDTH_M * k,
                    centre_dash_m: if rng.random::<bool>() {
                        Some(CENTRE_DASH_M)
                    } else {
                        None
                    },
                };
                let f = floor(rng);
                let f = jitter(rng, f, j);
                (paint, f, f)
            }
        };
        let g = grey(rng, 120, 235);
        let wall_rgb = jitter(rng, g, j);
        let n = if cfg.clutter[1] > cfg.clutter[0] {
            rng.random_range(cfg.clutter[0]..=cfg.clutter[1])
        } else {
            cfg.clutter[0]
        };
        let blocks = (0..n)
            .map(|_| {
                let person = rng.random::<f32>() < 0.3;
                let width = if person {
                    rng.random_range(0.03..0.10)
                } else {
                    rng.random_range(0.08..0.45)
                };
                let left = rng.random_range(-0.1..1.0f32);
                let top = if person {
                    rng.random_range(0.0..0.4)
                } else {
                    rng.random_range(0.2..0.9)
                };
                let rgb = [
                    rng.random_range(20..=240),
                    rng.random_range(20..=240),
                    rng.random_range(20..=240),
                ];
                Block {
                    u: [left, left + width],
                    top,
                    rgb,
                }
            })
            .collect();
        Scene {
            style,
            paint,
            mat_rgb,
            floor_rgb,
            wall_rgb,
            blocks,
        }
    }

    /// The backdrop for `camera`: the wall (`wall_rgb` scaled by 0.95 at the horizon,
    /// brightening to 1.10 at the top), with the blocks painted over it from their tops to
    /// the image's bottom (the ground, drawn by the renderer, covers what is below the
    /// horizon). RGB8, `width * height * 3` bytes.
    pub fn backdrop(&self, camera: &CameraModel) -> Vec<u8> {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let horizon = camera.horizon_v().max(1.0);
        let mut out = Vec::with_capacity(w * h * 3);
        for j in 0..h {
            let v = j as f32 + 0.5;
            let up = (1.0 - v / horizon).clamp(0.0, 1.0);
            let gain = 0.95 + 0.15 * up;
            let wall = self
                .wall_rgb
                .map(|c| (c as f32 * gain).round().clamp(0.0, 255.0) as u8);
            for i in 0..w {
                let u = (i as f32 + 0.5) / w as f32;
                let block = self
                    .blocks
                    .iter()
                    .rev()
                    .find(|b| b.u[0] <= u && u < b.u[1] && v >= b.top * horizon);
                out.extend_from_slice(&block.map_or(wall, |b| b.rgb));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn styles_come_at_their_probabilities_and_paint_what_they_say() {
        let cfg = AppearanceConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut counts = [0usize; 3];
        for _ in 0..1000 {
            let s = Scene::draw(&cfg, &mut rng);
            match s.style {
                RoadStyle::Sim => {
                    counts[0] += 1;
                    assert!(s.paint.road_rgb.is_some() && s.paint.edge_rgb.is_some());
                }
                RoadStyle::Print => {
                    counts[1] += 1;
                    let road = s.paint.road_rgb.map_or(255, |c| c[0]);
                    assert!(road <= 70, "print road {road}");
                    assert!(s.mat_rgb.iter().all(|&c| c >= 170), "{:?}", s.mat_rgb);
                    assert!(s.paint.centre_dash_m.is_some());
                }
                RoadStyle::Tape => {
                    counts[2] += 1;
                    assert_eq!(s.paint.road_rgb, None);
                    assert_eq!(s.mat_rgb, s.floor_rgb, "tape: no mat, only floor");
                }
            }
            let n = s.blocks.len() as u32;
            assert!((cfg.clutter[0]..=cfg.clutter[1]).contains(&n));
        }
        // Defaults 0.4 print, 0.3 tape, 0.3 sim: 1000 draws within 5 standard deviations.
        let expect = [300.0, 400.0, 300.0];
        for (c, e) in counts.iter().zip(expect) {
            assert!(
                (*c as f64 - e).abs() < 5.0 * (e * (1.0 - e / 1000.0)).sqrt(),
                "{counts:?}"
            );
        }
    }

    #[test]
    fn backdrop_worked_numbers_wall_gradient_and_a_block() {
        // Pinhole 8x8 with the horizon at row 4 needs a camera; use the 224 pinhole and
        // read its horizon instead of assuming one.
        let camera = CameraModel::pinhole(224, 224);
        let (w, h) = (camera.width as usize, camera.height as usize);
        let horizon = camera.horizon_v();
        assert!(horizon > 2.0, "the pinhole sees a wall above row {horizon}");
        let scene = Scene {
            wall_rgb: [200, 100, 0],
            blocks: vec![Block {
                u: [0.5, 0.75],
                top: 0.5,
                rgb: [1, 2, 3],
            }],
            ..Scene::sim()
        };
        let img = scene.backdrop(&camera);
        assert_eq!(img.len(), w * h * 3);
        // Top-left pixel: v = 0.5, up = 1 - 0.5 / horizon, gain 0.95 + 0.15 up.
        let gain = 0.95 + 0.15 * (1.0 - 0.5 / horizon);
        assert_eq!(img[0], (200.0 * gain).round() as u8);
        assert_eq!(img[1], (100.0 * gain).round() as u8);
        assert_eq!(img[2], 0);
        // In the block's columns: wall above half the horizon's row, the block below it.
        let col = (0.6 * w as f32) as usize;
        let above = ((0.5 * horizon) as usize).saturating_sub(1);
        let below = (0.5 * horizon).ceil() as usize;
        assert_ne!(&img[(above * w + col) * 3..][..3], &[1, 2, 3]);
        assert_eq!(&img[(below * w + col) * 3..][..3], &[1, 2, 3]);
        assert_eq!(&img[((h - 1) * w + col) * 3..][..3], &[1, 2, 3]);
        // Outside its columns, the wall.
        assert_ne!(&img[(below * w + w / 4) * 3..][..3], &[1, 2, 3]);
    }

    #[test]
    fn tape_paints_only_its_lines_and_print_paints_a_road() {
        let track = crate::sim::track::Track::jetbot_mat();
        let tape = RoadPaint {
            road_rgb: None,
            edge_rgb: Some([1, 2, 3]),
            edge_width_m: 0.03,
            centre_rgb: None,
            centre_width_m: 0.01,
            centre_dash_m: None,
        };
        let strokes = track.paint_with(&tape);
        assert_eq!(strokes.len(), 2, "two edge lines, nothing else");
        assert!(
            strokes
                .iter()
                .all(|s| s.rgb == [1, 2, 3] && s.width_m == 0.03)
        );
        let sim = track.paint_with(&RoadPaint::SIM);
        assert_eq!(
            sim,
            track.paint(),
            "the default paint is the simulator's own"
        );
        assert_eq!(sim.len(), 4);
        assert_eq!(sim[0].width_m, 2.0 * track.road_half_width());
    }
}
