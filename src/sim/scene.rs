//! Scene randomisation, world side (`[sim.appearance]` with `scene = true`): what the road,
//! the floor it lies on, what stands and lies on that floor, and the room beyond look like.
//! JetBot owners drive on JetBot's printed mat, on tape stuck to carpet, concrete, wood or
//! foam tiles, or on roads of painted card, in rooms full of desks, chairs and people; a
//! policy that has only seen one paint learns the paint.
//!
//! A [`Scene`] is drawn with each camera look (per episode, and every
//! `redraw_every_frames`). It is one of four road styles:
//! - `Sim`: the simulator's own mat (dark road, yellow edges, white dashes on green);
//! - `Print`: JetBot's printed mat as it shows in real frames: a near-black road with a
//!   white dashed centre line, sometimes thin light edges, on a white mat;
//! - `Tape`: no road surface, two tape lines of any colour, 1-5 cm wide, on the floor,
//!   sometimes a solid or dashed centre line;
//! - `Painted`: a road of paint or cardboard on the floor, with or without edge lines.
//!
//! Edge lines are sometimes worn (`edge_wear_probability`): one missing, or broken into
//! pieces as tape peels. The floor (`sim::floor`) is a texture (carpet, concrete, wood,
//! foam tiles, tiles with grout, stains) with `floor_texture_probability`, else a flat
//! colour; `cables` lie on it across the road. In front of the camera, in image space
//! ([`Thing`]): feet and legs, chair legs, boxes standing on the floor, and shadows (the
//! robot's own at the bottom of the frame, and others). Beyond the floor, a backdrop: a wall
//! with a vertical gradient, sometimes a bright window, and up to `clutter` upright blocks
//! (furniture-sized boxes and person-height shapes) behind the horizon. Image-space parts
//! move with the camera: good enough to teach a policy to ignore what is not the road, not
//! a room model. Labels come from the road's geometry, never from these.
//!
//! Positions drawn here that depend on the mat (stains, cables) are fractions of the mat's
//! size until [`Scene::show`] places them on a track's mat.
//!
//! Only rendered frames are repainted; replayed frames keep the real scene they recorded.

use rand::Rng;

use super::PaintStroke;
use super::SimError;
use super::appearance::{AppearanceConfig, draw_in};
use super::camera::CameraModel;
use super::floor::{Floor, FloorKind};
use super::render::Renderer;
use super::track::{CENTRE_DASH_M, CENTRE_LINE_WIDTH_M, EdgeLine, RoadPaint, Track};

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
    Painted,
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

/// A window on the wall: a bright pane with a frame, in image space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Left and right edges, fractions of the image width.
    pub u: [f32; 2],
    /// Top and bottom edges as fractions of the horizon's row.
    pub v: [f32; 2],
    pub rgb: [u8; 3],
}

/// Something in front of the camera, on the floor, in image space. `u` is a fraction of
/// the width, `v` of the height (0 at the top); `foot_v` is where it meets the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Thing {
    /// A person's two legs from the top of the frame down to their shoes.
    Legs {
        u: f32,
        foot_v: f32,
        width: f32,
        rgb: [u8; 3],
        shoe_rgb: [u8; 3],
    },
    /// Four thin chair legs, the front two lower (nearer) than the back two.
    ChairLegs {
        u: [f32; 2],
        foot_v: [f32; 2],
        width: f32,
        rgb: [u8; 3],
    },
    /// A box standing on the floor: its front face, and a darker top.
    Box {
        u: [f32; 2],
        v: [f32; 2],
        rgb: [u8; 3],
    },
    /// A soft shadow: the frame times `shade` at the centre, fading out at the radii.
    Shadow {
        centre: [f32; 2],
        radius: [f32; 2],
        shade: f32,
    },
}

/// One drawn scene: the road paint, the mat and floor, what is in view, and the backdrop.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub style: RoadStyle,
    pub paint: RoadPaint,
    /// The mat's colour; `None`: no mat, the floor runs under the road (tape, painted).
    pub mat_rgb: Option<[u8; 3]>,
    /// The floor; stain centres are fractions of the mat's size.
    pub floor: Floor,
    /// Cables on the floor: points as fractions of the mat's size.
    pub cables: Vec<PaintStroke>,
    pub wall_rgb: [u8; 3],
    pub windows: Vec<Window>,
    pub blocks: Vec<Block>,
    pub things: Vec<Thing>,
}

fn count<R: Rng + ?Sized>(rng: &mut R, [lo, hi]: [u32; 2]) -> u32 {
    if hi > lo {
        rng.random_range(lo..=hi)
    } else {
        lo
    }
}

fn grey<R: Rng + ?Sized>(rng: &mut R, lo: u8, hi: u8) -> [u8; 3] {
    let v = rng.random_range(lo..=hi);
    [v, v, v]
}

fn any_rgb<R: Rng + ?Sized>(rng: &mut R, lo: u8, hi: u8) -> [u8; 3] {
    [0, 1, 2].map(|_| rng.random_range(lo..=hi))
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

/// Floor colours people put mats and tape on, with the kinds of floor they come as:
/// light tiles, wood, concrete grey, dark carpet, beige carpet, blue and grey foam.
fn floor_colour<R: Rng + ?Sized>(rng: &mut R) -> ([u8; 3], &'static [FloorKind]) {
    use FloorKind::*;
    const FLOORS: [([u8; 3], &[FloorKind]); 7] = [
        ([215, 212, 205], &[Tiles, Plain, Foam]),
        ([165, 120, 80], &[Wood, Plain]),
        ([140, 138, 132], &[Concrete, LowPile, Plain]),
        ([70, 68, 72], &[LowPile, Shag, Foam]),
        ([190, 170, 140], &[LowPile, Shag, Wood, Tiles]),
        ([60, 90, 150], &[Foam, LowPile]),
        ([120, 120, 125], &[Foam, Concrete, Tiles]),
    ];
    FLOORS[rng.random_range(0..FLOORS.len())]
}

/// Tape colours on sale: white, yellow, blue, black, red, green, and now and then any.
fn tape_colour<R: Rng + ?Sized>(rng: &mut R, j: f32) -> [u8; 3] {
    const TAPES: [[u8; 3]; 6] = [
        [240, 240, 235],
        [235, 200, 40],
        [40, 90, 200],
        [25, 25, 28],
        [200, 40, 40],
        [40, 160, 70],
    ];
    if rng.random::<f32>() < 0.25 {
        any_rgb(rng, 10, 250)
    } else {
        let t = TAPES[rng.random_range(0..TAPES.len())];
        jitter(rng, t, j)
    }
}

/// The two edges: both whole, or (with `wear`) one missing or one or both broken.
fn edges<R: Rng + ?Sized>(rng: &mut R, wear: f32) -> [EdgeLine; 2] {
    let mut out = [EdgeLine::Whole; 2];
    if rng.random::<f32>() < wear {
        let broken = |rng: &mut R| EdgeLine::Broken {
            piece_m: rng.random_range(0.15..1.0),
            gap_m: rng.random_range(0.03..0.25),
        };
        let side = rng.random_range(0..2);
        match rng.random_range(0..3) {
            0 => out[side] = EdgeLine::Missing,
            1 => out[side] = broken(rng),
            _ => out = [broken(rng), broken(rng)],
        }
    }
    out
}

/// A cable: a smooth random curve, 1 to 3 m long, points as fractions of a 1 x 1 mat.
fn cable<R: Rng + ?Sized>(rng: &mut R) -> PaintStroke {
    let (mut x, mut y) = (rng.random_range(0.0..1.0f32), rng.random_range(0.0..1.0f32));
    let mut heading = rng.random_range(0.0..std::f32::consts::TAU);
    let n = rng.random_range(20..60);
    let mut points = Vec::with_capacity(n);
    for _ in 0..n {
        points.push((x, y));
        heading += rng.random_range(-0.3..0.3);
        x += 0.025 * heading.cos();
        y += 0.025 * heading.sin();
    }
    const CABLES: [[u8; 3]; 4] = [[20, 20, 22], [235, 235, 230], [90, 90, 95], [30, 60, 160]];
    PaintStroke {
        points,
        width_m: rng.random_range(0.004..0.012),
        rgb: CABLES[rng.random_range(0..CABLES.len())],
        dash: None,
        closed: false,
    }
}

/// Something standing on the floor in view, its feet below the horizon's row `h0`
/// (fraction of the height); nearer (lower) things are drawn wider.
fn thing<R: Rng + ?Sized>(rng: &mut R, h0: f32) -> Thing {
    let foot = |rng: &mut R| rng.random_range((h0 + 0.05).min(0.95)..0.95f32.max(h0 + 0.06));
    let near = |v: f32| ((v - h0) / (1.0 - h0).max(0.05)).clamp(0.0, 1.0);
    match rng.random_range(0..3) {
        0 => {
            let foot_v = foot(rng);
            const TROUSERS: [[u8; 3]; 4] =
                [[30, 35, 60], [25, 25, 28], [110, 100, 90], [60, 80, 120]];
            Thing::Legs {
                u: rng.random_range(0.0..1.0),
                foot_v,
                width: 0.03 + 0.12 * near(foot_v),
                rgb: {
                    let t = TROUSERS[rng.random_range(0..TROUSERS.len())];
                    jitter(rng, t, 0.2)
                },
                shoe_rgb: any_rgb(rng, 15, 240),
            }
        }
        1 => {
            let back = foot(rng);
            let front = (back + rng.random_range(0.03..0.15)).min(0.99);
            let left = rng.random_range(-0.1..0.9f32);
            Thing::ChairLegs {
                u: [left, left + rng.random_range(0.1..0.4)],
                foot_v: [back, front],
                width: 0.008 + 0.03 * near(front),
                rgb: if rng.random::<bool>() {
                    grey(rng, 150, 220)
                } else {
                    jitter(rng, [110, 70, 40], 0.2)
                },
            }
        }
        _ => {
            let bottom = foot(rng);
            let size = 0.05 + 0.3 * near(bottom);
            let left = rng.random_range(-0.1..0.95f32);
            Thing::Box {
                u: [left, left + size * rng.random_range(0.6..1.6)],
                v: [bottom - size, bottom],
                rgb: any_rgb(rng, 40, 230),
            }
        }
    }
}

impl Scene {
    /// The simulator's own scene, unjittered (what rendering shows without randomisation).
    pub fn sim() -> Scene {
        Scene {
            style: RoadStyle::Sim,
            paint: RoadPaint::SIM,
            mat_rgb: Some(SIM_MAT_RGB),
            floor: Floor::plain(SIM_FLOOR_RGB),
            cables: Vec::new(),
            wall_rgb: super::render::DEFAULT_WALL_RGB,
            windows: Vec::new(),
            blocks: Vec::new(),
            things: Vec::new(),
        }
    }

    /// Draws a scene from `cfg`'s probabilities and ranges.
    pub fn draw<R: Rng + ?Sized>(cfg: &AppearanceConfig, rng: &mut R) -> Scene {
        let k = draw_in(rng, cfg.line_width_scale);
        let j = cfg.colour_jitter;
        let pick: f32 = rng.random();
        let (p, t, q) = (
            cfg.print_probability,
            cfg.tape_probability,
            cfg.painted_probability,
        );
        let style = if pick < p {
            RoadStyle::Print
        } else if pick < p + t {
            RoadStyle::Tape
        } else if pick < p + t + q {
            RoadStyle::Painted
        } else {
            RoadStyle::Sim
        };
        let dash = |rng: &mut R| {
            Some((
                rng.random_range(0.03..0.08f32),
                rng.random_range(0.03..0.08f32),
            ))
        };
        let (floor_base, kinds) = floor_colour(rng);
        let floor_base = jitter(rng, floor_base, j);
        let edges = edges(rng, cfg.edge_wear_probability);
        let (paint, mat_rgb, floor_base) = match style {
            RoadStyle::Sim => {
                let s = RoadPaint::SIM;
                let paint = RoadPaint {
                    road_rgb: s.road_rgb.map(|c| jitter(rng, c, j)),
                    edge_rgb: s.edge_rgb.map(|c| jitter(rng, c, j)),
                    edge_width_m: s.edge_width_m * k,
                    centre_rgb: s.centre_rgb.map(|c| jitter(rng, c, j)),
                    centre_width_m: s.centre_width_m * k,
                    centre_dash_m: s.centre_dash_m,
                    edges,
                };
                let mat = jitter(rng, SIM_MAT_RGB, j);
                (paint, Some(mat), jitter(rng, SIM_FLOOR_RGB, j))
            }
            RoadStyle::Print => {
                let g = grey(rng, 215, 250);
                let white = jitter(rng, g, j / 3.0);
                let with_edges = rng.random::<f32>() < 0.5;
                let g = grey(rng, 12, 55);
                let road = jitter(rng, g, j);
                let paint = RoadPaint {
                    road_rgb: Some(road),
                    edge_rgb: with_edges.then_some(white),
                    edge_width_m: 0.008 * k,
                    centre_rgb: Some(white),
                    centre_width_m: CENTRE_LINE_WIDTH_M * k,
                    centre_dash_m: dash(rng),
                    edges: [EdgeLine::Whole; 2],
                };
                let g = grey(rng, 205, 250);
                let mat = jitter(rng, g, j / 3.0);
                (paint, Some(mat), floor_base)
            }
            RoadStyle::Tape => {
                let tape = tape_colour(rng, j);
                let centre = rng.random::<f32>() < 0.4;
                let centre_rgb = if rng.random::<f32>() < 0.5 {
                    tape
                } else {
                    tape_colour(rng, j)
                };
                let paint = RoadPaint {
                    road_rgb: None,
                    edge_rgb: Some(tape),
                    edge_width_m: rng.random_range(0.01..0.05),
                    centre_rgb: centre.then_some(centre_rgb),
                    centre_width_m: rng.random_range(0.01..0.05),
                    centre_dash_m: if rng.random::<bool>() {
                        Some(CENTRE_DASH_M)
                    } else {
                        None
                    },
                    edges,
                };
                (paint, None, floor_base)
            }
            RoadStyle::Painted => {
                // Cardboard brown, or a paint of any colour.
                let road = if rng.random::<bool>() {
                    jitter(rng, [175, 135, 90], j)
                } else {
                    any_rgb(rng, 20, 235)
                };
                let with_edges = rng.random::<f32>() < 0.5;
                let line = tape_colour(rng, j);
                let centre = rng.random::<f32>() < 0.5;
                let paint = RoadPaint {
                    road_rgb: Some(road),
                    edge_rgb: with_edges.then_some(line),
                    edge_width_m: rng.random_range(0.01..0.05),
                    centre_rgb: centre.then_some(line),
                    centre_width_m: CENTRE_LINE_WIDTH_M * k,
                    centre_dash_m: dash(rng),
                    edges,
                };
                (paint, None, floor_base)
            }
        };
        let floor = if rng.random::<f32>() < cfg.floor_texture_probability {
            let kind = kinds[rng.random_range(0..kinds.len())];
            Floor::draw(kind, floor_base, (1.0, 1.0), rng)
        } else {
            Floor::plain(floor_base)
        };
        let cables = (0..count(rng, cfg.cables)).map(|_| cable(rng)).collect();
        let g = grey(rng, 120, 235);
        let wall_rgb = jitter(rng, g, j);
        let windows = (0..u32::from(rng.random::<f32>() < cfg.window_probability))
            .map(|_| {
                let left = rng.random_range(-0.1..0.9f32);
                let top = rng.random_range(0.0..0.5f32);
                Window {
                    u: [left, left + rng.random_range(0.1..0.5)],
                    v: [top, top + rng.random_range(0.2..0.6)],
                    rgb: jitter(rng, [235, 240, 250], 0.05),
                }
            })
            .collect();
        let n = count(rng, cfg.clutter);
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
                Block {
                    u: [left, left + width],
                    top,
                    rgb: any_rgb(rng, 20, 240),
                }
            })
            .collect();
        // The horizon's row is the camera's; things are placed for a JetBot-like one, with
        // the horizon a third of the way down.
        let h0 = 0.33;
        let mut things: Vec<Thing> = (0..count(rng, cfg.floor_objects))
            .map(|_| thing(rng, h0))
            .collect();
        if rng.random::<f32>() < cfg.shadow_probability {
            // The robot's own shadow, at the bottom of the frame.
            things.push(Thing::Shadow {
                centre: [rng.random_range(0.3..0.7), rng.random_range(0.95..1.15)],
                radius: [rng.random_range(0.2..0.45), rng.random_range(0.1..0.3)],
                shade: rng.random_range(0.5..0.85),
            });
        }
        if rng.random::<f32>() < cfg.shadow_probability {
            things.push(Thing::Shadow {
                centre: [rng.random_range(0.0..1.0), rng.random_range(h0..1.0)],
                radius: [rng.random_range(0.1..0.6), rng.random_range(0.05..0.3)],
                shade: rng.random_range(0.55..0.9),
            });
        }
        Scene {
            style,
            paint,
            mat_rgb,
            floor,
            cables,
            wall_rgb,
            windows,
            blocks,
            things,
        }
    }

    /// The floor with its stains placed on a `mat` (metres).
    pub fn floor_on(&self, mat: (f32, f32)) -> Floor {
        let mut f = self.floor.clone();
        for s in &mut f.stains {
            s.centre = [s.centre[0] * mat.0, s.centre[1] * mat.1];
        }
        f
    }

    /// Paints `track` in this scene's style on its floor and shows the scene on `renderer`:
    /// the texture (floor, mat, road, cables), the backdrop and the foreground.
    pub fn show(&self, renderer: &mut Renderer, track: &Track) -> Result<(), SimError> {
        let (mw, mh) = renderer.texture().mat_size();
        let mut strokes = track.paint_with(&self.paint);
        strokes.extend(self.cables.iter().map(|c| PaintStroke {
            points: c.points.iter().map(|&(x, y)| (x * mw, y * mh)).collect(),
            ..c.clone()
        }));
        renderer.repaint_on_floor(&strokes, self.mat_rgb, &self.floor_on((mw, mh)))?;
        let camera = *renderer.camera();
        renderer.set_backdrop(Some(self.backdrop(&camera)))?;
        renderer.set_foreground(self.foreground(&camera))
    }

    /// The backdrop for `camera`: the wall (`wall_rgb` scaled by 0.95 at the horizon,
    /// brightening to 1.10 at the top), windows on it, and the blocks painted over both
    /// from their tops to the image's bottom (the ground, drawn by the renderer, covers
    /// what is below the horizon). RGB8, `width * height * 3` bytes.
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
                let window = || {
                    self.windows.iter().find_map(|win| {
                        let inside = win.u[0] <= u
                            && u < win.u[1]
                            && win.v[0] * horizon <= v
                            && v < win.v[1] * horizon;
                        // A frame bar down the middle and across.
                        let mid_u = (u - (win.u[0] + win.u[1]) / 2.0).abs() * (w as f32) < 1.0;
                        let mid_v = (v - (win.v[0] + win.v[1]) / 2.0 * horizon).abs() < 1.0;
                        let rgb = if mid_u || mid_v {
                            self.wall_rgb
                        } else {
                            win.rgb
                        };
                        inside.then_some(rgb)
                    })
                };
                let rgb = match block {
                    Some(b) => b.rgb,
                    None => window().unwrap_or(wall),
                };
                out.extend_from_slice(&rgb);
            }
        }
        out
    }

    /// What stands in front of the camera, as RGBA8 over the rendered frame (alpha 0:
    /// nothing; 255: the thing's colour replaces the frame's; between: shadows, which are
    /// black at `1 - shade`), or `None` when there is nothing.
    pub fn foreground(&self, camera: &CameraModel) -> Option<Vec<u8>> {
        if self.things.is_empty() {
            return None;
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut out = vec![0u8; w * h * 4];
        for thing in &self.things {
            for j in 0..h {
                let v = (j as f32 + 0.5) / h as f32;
                for i in 0..w {
                    let u = (i as f32 + 0.5) / w as f32;
                    let px = &mut out[(j * w + i) * 4..][..4];
                    if let Some((rgb, a)) = thing.cover(u, v) {
                        if a >= 1.0 {
                            px.copy_from_slice(&[rgb[0], rgb[1], rgb[2], 255]);
                        } else if px[3] < 255 {
                            // Shadows over shadows: the darker wins.
                            let a8 = (a * 255.0).round() as u8;
                            if a8 > px[3] {
                                px.copy_from_slice(&[rgb[0], rgb[1], rgb[2], a8]);
                            }
                        }
                    }
                }
            }
        }
        Some(out)
    }
}

impl Thing {
    /// The colour and coverage (1: opaque) of this thing at image point `(u, v)`
    /// (fractions), or `None` where it is not.
    pub fn cover(&self, u: f32, v: f32) -> Option<([u8; 3], f32)> {
        match *self {
            Thing::Legs {
                u: x,
                foot_v,
                width,
                rgb,
                shoe_rgb,
            } => {
                // Two legs, `width` apart, each 0.4 width wide; shoes the last 0.15 width
                // of height, reaching 0.3 width forward (down the frame's centre line).
                let shoe = 0.15 * width;
                for side in [-0.5f32, 0.5] {
                    let cx = x + side * width;
                    if (u - cx).abs() < 0.2 * width {
                        if v <= foot_v - shoe {
                            return Some((rgb, 1.0));
                        }
                        if v <= foot_v {
                            return Some((shoe_rgb, 1.0));
                        }
                    }
                }
                None
            }
            Thing::ChairLegs {
                u: [l, r],
                foot_v: [back, front],
                width,
                rgb,
            } => {
                let inset = 0.15 * (r - l);
                let legs = [(l + inset, back), (r - inset, back), (l, front), (r, front)];
                // Each leg rises from its foot to the seat, 0.3 of the height above the
                // front feet.
                let seat = front - 0.3;
                legs.iter()
                    .any(|&(x, foot)| (u - x).abs() < width / 2.0 && seat <= v && v <= foot)
                    .then_some((rgb, 1.0))
            }
            Thing::Box {
                u: [l, r],
                v: [t, b],
                rgb,
            } => {
                if !(l <= u && u < r && v <= b) {
                    return None;
                }
                // The top face: a darker band above the front face.
                let top = 0.25 * (b - t);
                if v >= t {
                    Some((rgb, 1.0))
                } else if v >= t - top {
                    Some((rgb.map(|c| (c as f32 * 0.75) as u8), 1.0))
                } else {
                    None
                }
            }
            Thing::Shadow {
                centre,
                radius,
                shade,
            } => {
                let dx = (u - centre[0]) / radius[0].max(1e-3);
                let dy = (v - centre[1]) / radius[1].max(1e-3);
                let d2 = dx * dx + dy * dy;
                (d2 < 1.0).then(|| {
                    let t = 1.0 - d2;
                    ([0, 0, 0], (1.0 - shade) * t * t.sqrt())
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::Pose2;
    use crate::sim::render::MatTexture;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn styles_come_at_their_probabilities_and_paint_what_they_say() {
        let cfg = AppearanceConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut counts = [0usize; 4];
        let mut broken_or_missing = 0;
        for _ in 0..1000 {
            let s = Scene::draw(&cfg, &mut rng);
            match s.style {
                RoadStyle::Sim => {
                    counts[0] += 1;
                    assert!(s.paint.road_rgb.is_some() && s.paint.edge_rgb.is_some());
                    assert!(s.mat_rgb.is_some());
                }
                RoadStyle::Print => {
                    counts[1] += 1;
                    let road = s.paint.road_rgb.map_or(255, |c| c[0]);
                    assert!(road <= 70, "print road {road}");
                    let mat = s.mat_rgb.expect("a printed mat");
                    assert!(mat.iter().all(|&c| c >= 170), "{mat:?}");
                    assert!(s.paint.centre_dash_m.is_some());
                }
                RoadStyle::Tape => {
                    counts[2] += 1;
                    assert_eq!(s.paint.road_rgb, None);
                    assert_eq!(s.mat_rgb, None, "tape: no mat, only floor");
                    assert!((0.01..0.05).contains(&s.paint.edge_width_m));
                    assert!(s.paint.edge_rgb.is_some());
                }
                RoadStyle::Painted => {
                    counts[3] += 1;
                    assert!(s.paint.road_rgb.is_some());
                    assert_eq!(s.mat_rgb, None, "painted: on the floor");
                }
            }
            if s.paint.edges != [EdgeLine::Whole; 2] {
                broken_or_missing += 1;
            }
            let n = s.blocks.len() as u32;
            assert!((cfg.clutter[0]..=cfg.clutter[1]).contains(&n));
            let n = s.cables.len() as u32;
            assert!((cfg.cables[0]..=cfg.cables[1]).contains(&n));
        }
        // Defaults 0.2 sim, 0.3 print, 0.35 tape, 0.15 painted: 1000 draws within 5
        // standard deviations.
        let expect = [200.0, 300.0, 350.0, 150.0];
        for (c, e) in counts.iter().zip(expect) {
            assert!(
                (*c as f64 - e).abs() < 5.0 * (e * (1.0 - e / 1000.0)).sqrt(),
                "{counts:?}"
            );
        }
        // Print keeps whole edges; the other 70 % wear at 0.25: about 175.
        assert!(
            (100..260).contains(&broken_or_missing),
            "{broken_or_missing}"
        );
    }

    #[test]
    fn the_draw_is_reproducible_from_its_seed() {
        let cfg = AppearanceConfig::default();
        let draw = |seed| Scene::draw(&cfg, &mut ChaCha8Rng::seed_from_u64(seed));
        assert_eq!(draw(5), draw(5));
        assert_ne!(draw(5), draw(6));
        let camera = CameraModel::jetbot(64, 64);
        let scene = (0..50)
            .map(draw)
            .find(|s| !s.things.is_empty())
            .expect("things in view in 50 draws");
        assert_eq!(scene.foreground(&camera), scene.foreground(&camera));
        assert_eq!(scene.backdrop(&camera), scene.backdrop(&camera));
    }

    #[test]
    fn backdrop_worked_numbers_wall_gradient_and_a_block() {
        // Read the 224 pinhole's horizon instead of assuming one.
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
    fn a_window_is_its_pane_with_a_frame_bar_in_the_wall_colour() {
        let camera = CameraModel::pinhole(100, 100);
        let w = 100usize;
        let horizon = camera.horizon_v();
        let scene = Scene {
            wall_rgb: [100, 100, 100],
            windows: vec![Window {
                u: [0.1, 0.5],
                v: [0.2, 0.8],
                rgb: [250, 251, 252],
            }],
            ..Scene::sim()
        };
        let img = scene.backdrop(&camera);
        let at = |i: usize, j: usize| &img[(j * w + i) * 3..][..3];
        // Inside the pane, off its bars (u = 0.2, v = 0.4 of the horizon's row).
        let j = (0.4 * horizon) as usize;
        assert_eq!(at(20, j), &[250, 251, 252]);
        // The vertical bar: the column whose centre is within a pixel of u = 0.3.
        assert_eq!(at(30, j), &[100, 100, 100]);
        // Left of the window: the wall with its gradient, not the pane.
        assert_ne!(at(5, j), &[250, 251, 252]);
    }

    #[test]
    fn worn_edges_paint_one_line_or_dashes() {
        let track = crate::sim::track::Track::jetbot_mat();
        let tape = |edges| RoadPaint {
            road_rgb: None,
            edge_rgb: Some([1, 2, 3]),
            edge_width_m: 0.03,
            centre_rgb: None,
            centre_width_m: 0.01,
            centre_dash_m: None,
            edges,
        };
        let whole = track.paint_with(&tape([EdgeLine::Whole; 2]));
        assert_eq!(whole.len(), 2, "two edge lines, nothing else");
        assert!(
            whole
                .iter()
                .all(|s| s.rgb == [1, 2, 3] && s.width_m == 0.03 && s.dash.is_none())
        );
        let missing = track.paint_with(&tape([EdgeLine::Whole, EdgeLine::Missing]));
        assert_eq!(missing, whole[..1], "the left edge alone");
        let broken = EdgeLine::Broken {
            piece_m: 0.4,
            gap_m: 0.1,
        };
        let peeled = track.paint_with(&tape([EdgeLine::Whole, broken]));
        assert_eq!(peeled.len(), 2);
        assert_eq!(peeled[0], whole[0]);
        assert_eq!(peeled[1].dash, Some((0.4, 0.1)));
        assert_eq!(peeled[1].points, whole[1].points);

        let sim = track.paint_with(&RoadPaint::SIM);
        assert_eq!(
            sim,
            track.paint(),
            "the default paint is the simulator's own"
        );
        assert_eq!(sim.len(), 4);
        assert_eq!(sim[0].width_m, 2.0 * track.road_half_width());
    }

    /// A tape scene on a plain floor, rendered by a pinhole camera standing in the lane.
    fn tape_frame(scene: &Scene) -> (Renderer, Pose2, Vec<u8>) {
        let track = crate::sim::track::Track::jetbot_mat();
        let strokes = track.paint();
        let texture =
            MatTexture::with_defaults(&strokes, track.mat_size()).expect("the mat's texture");
        let mut r = Renderer::new(texture, CameraModel::pinhole(96, 96)).expect("a renderer");
        scene.show(&mut r, &track).expect("the scene shows");
        let pose = track.lane_pose_at(0.0);
        let mut out = vec![0; r.frame_len()];
        r.render(&pose, &mut out);
        (r, pose, out)
    }

    #[test]
    fn a_rendered_tape_line_is_where_the_track_says_in_its_colour() {
        let track = crate::sim::track::Track::jetbot_mat();
        let scene = Scene {
            style: RoadStyle::Tape,
            paint: RoadPaint {
                road_rgb: None,
                edge_rgb: Some([20, 60, 220]),
                edge_width_m: 0.05,
                centre_rgb: None,
                centre_width_m: 0.01,
                centre_dash_m: None,
                edges: [EdgeLine::Whole; 2],
            },
            mat_rgb: None,
            floor: Floor::plain([140, 138, 132]),
            ..Scene::sim()
        };
        let (r, pose, frame) = tape_frame(&scene);
        let cam = r.camera();
        let s = 0.25;
        let half = track.road_half_width();
        let pixel = |lat: f32| {
            let p = track.pose_at(s, lat);
            let (u, v) = cam.ground_to_pixel(&pose, p.x, p.y).expect("in view");
            let (i, j) = (u as usize, v as usize);
            frame[(j * 96 + i) * 3..][..3].to_vec()
        };
        let near = |a: &[u8], b: [u8; 3]| a.iter().zip(b).all(|(&x, y)| x.abs_diff(y) <= 6);
        // On each edge line: the tape's blue; halfway between them: the floor (no mat,
        // no road paint).
        assert!(near(&pixel(half), [20, 60, 220]), "{:?}", pixel(half));
        assert!(near(&pixel(-half), [20, 60, 220]), "{:?}", pixel(-half));
        assert!(near(&pixel(0.0), [140, 138, 132]), "{:?}", pixel(0.0));
    }

    #[test]
    fn things_cover_the_frame_worked_numbers() {
        // Legs at u 0.5, 0.2 wide: legs at 0.4 and 0.6, each 0.04 wide, shoes below
        // v = 0.9 - 0.03.
        let legs = Thing::Legs {
            u: 0.5,
            foot_v: 0.9,
            width: 0.2,
            rgb: [1, 1, 1],
            shoe_rgb: [2, 2, 2],
        };
        assert_eq!(legs.cover(0.41, 0.5), Some(([1, 1, 1], 1.0)));
        assert_eq!(legs.cover(0.61, 0.88), Some(([2, 2, 2], 1.0)));
        assert_eq!(legs.cover(0.5, 0.5), None, "between the legs");
        assert_eq!(legs.cover(0.4, 0.95), None, "below the feet");
        // A box [0.2, 0.4] x [0.5, 0.7]: front face, and a top band 0.05 high, darker.
        let b = Thing::Box {
            u: [0.2, 0.4],
            v: [0.5, 0.7],
            rgb: [100, 200, 40],
        };
        assert_eq!(b.cover(0.3, 0.6), Some(([100, 200, 40], 1.0)));
        assert_eq!(b.cover(0.3, 0.47), Some(([75, 150, 30], 1.0)));
        assert_eq!(b.cover(0.3, 0.44), None);
        // A shadow of shade 0.6: alpha (1 - 0.6) t^1.5 with t = 1 - d^2; at the centre 0.4,
        // halfway out (d^2 = 0.25) 0.4 * 0.75^1.5 = 0.2598.
        let sh = Thing::Shadow {
            centre: [0.5, 1.0],
            radius: [0.4, 0.2],
            shade: 0.6,
        };
        let (rgb, a) = sh.cover(0.5, 1.0).expect("the centre");
        assert_eq!(rgb, [0, 0, 0]);
        assert!((a - 0.4).abs() < 1e-6, "{a}");
        let (_, a) = sh.cover(0.7, 1.0).expect("halfway");
        assert!((a - 0.2598).abs() < 1e-4, "{a}");
        assert_eq!(sh.cover(0.95, 1.0), None);
    }

    #[test]
    fn the_foreground_is_blended_over_the_rendered_frame() {
        let mut scene = Scene {
            things: vec![Thing::Box {
                u: [0.0, 0.5],
                v: [0.6, 1.0],
                rgb: [9, 99, 199],
            }],
            ..Scene::sim()
        };
        let (_, _, frame) = tape_frame(&scene);
        // Bottom-left is the box's face; bottom-right is the ground as it was.
        assert_eq!(&frame[(90 * 96 + 10) * 3..][..3], &[9, 99, 199]);
        scene.things.clear();
        let (_, _, bare) = tape_frame(&scene);
        assert_eq!(
            &frame[(90 * 96 + 80) * 3..][..3],
            &bare[(90 * 96 + 80) * 3..][..3]
        );
        assert_ne!(&bare[(90 * 96 + 10) * 3..][..3], &[9, 99, 199]);
    }
}
