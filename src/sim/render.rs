//! Rendering the mat: the painted texture, the robot camera's view of it at a pose, optional
//! photometric effects, and a top-down picture of a drive for people to look at.
//!
//! This module owns:
//! - [`MatTexture`]: the mat's paint (from `PaintStroke`s, drawn anti-aliased with
//!   tiny-skia) as an RGB mip pyramid in world-aligned texels, surrounded by the floor.
//! - [`Renderer`]: camera image at a pose. A per-pixel table built once in
//!   [`Renderer::new`] holds, for every pixel, where its viewing ray meets the ground in
//!   the robot frame (pose-independent for a flat floor and a fixed mount), plus its
//!   footprint: a mip level and up to [`MAX_PROBES`] probes along the footprint's long axis
//!   (cheap anisotropic filtering, so that the far, grazing ground does not alias). A frame
//!   is then one affine transform per probe and a trilinear texture lookup; nothing is
//!   allocated per frame. Above the horizon (and beyond the camera's ground range) a wall
//!   colour with a slight vertical gradient.
//! - [`RenderEffects`] / [`apply_effects`]: blur, brightness, Gaussian sensor noise.
//! - [`top_down`] and [`write_png`].
//!
//! Image buffers are RGB8, row-major, top row first, `width * height * 3` bytes.
//! Colour values inside the texture code are `f32` on the 0..=255 scale.

use std::path::Path;

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use tiny_skia::{
    Color, FillRule, IntSize, LineCap, LineJoin, Paint, PathBuilder, Pixmap, Rect, Stroke,
    StrokeDash, Transform,
};

use super::camera::CameraModel;
use super::floor::{Floor, FloorKind};
use super::{PaintStroke, Pose2, SimError};

/// Default texture resolution, texels per metre (2.5 mm texels).
pub const DEFAULT_PX_PER_M: f32 = 400.0;
/// Default colour of the bare mat (where no stroke is painted).
pub const DEFAULT_MAT_RGB: [u8; 3] = [168, 172, 166];
/// Default colour of the floor around the mat.
pub const DEFAULT_FLOOR_RGB: [u8; 3] = [142, 112, 84];
/// Default colour of the walls (seen above the horizon).
pub const DEFAULT_WALL_RGB: [u8; 3] = [214, 210, 200];
/// Most texture probes per pixel along the footprint's long axis.
pub const MAX_PROBES: u32 = 4;

/// Mip levels 0..NUM_LEVELS; level `L` has texels `2^L` times larger than level 0.
const NUM_LEVELS: usize = 6;
/// Floor texels kept around the mat at the coarsest level (so clamped lookups read floor).
const COARSE_BORDER: usize = 2;

/// Packed colour for fast filtering: R, G, B in 21-bit lanes of a `u64` (bits 0, 21, 42).
/// A bilinear result holds `value * 256` per lane (at most 65 280); sums of a few of them
/// still fit in a lane.
type Packed = u64;
const LANE_BITS: u32 = 21;
const LANE: u64 = (1 << LANE_BITS) - 1;
/// 16 low bits of every lane.
const LANES16: u64 = 0xFFFF | (0xFFFF << LANE_BITS) | (0xFFFF << (2 * LANE_BITS));
/// Trilinear weights are quantised to 1/32 (a lane of `value * 256 * 32` still fits).
const TRI_BITS: u32 = 5;
const TRI_ONE: u32 = 1 << TRI_BITS;

/// RGBA8 (as `[r, g, b, a]` read little-endian) -> packed lanes.
#[inline(always)]
fn expand(t: u32) -> Packed {
    let t = t as u64;
    (t & 0xFF) | ((t & 0xFF00) << (LANE_BITS - 8)) | ((t & 0xFF_0000) << (2 * LANE_BITS - 16))
}

#[inline(always)]
fn lane(p: Packed, k: u32) -> u32 {
    ((p >> (k * LANE_BITS)) & LANE) as u32
}

/// One mip level: `w x h` texels `[r, g, b, 255]` stored as little-endian `u32`, row 0
/// at the lowest world y.
#[derive(Debug, Clone)]
struct Level {
    w: usize,
    h: usize,
    /// Texels per metre at this level.
    scale: f32,
    /// Largest continuous texel coordinate that keeps a 2x2 neighbourhood inside.
    max_x: f32,
    max_y: f32,
    texels: Vec<u32>,
}

impl Level {
    /// Bilinear lookup at continuous texel coordinates (texel `(i, j)` has its centre at
    /// `(i, j)`), 8-bit weights; `value * 256` per lane. Coordinates are clamped, and the
    /// border is floor, so outside reads floor.
    #[inline(always)]
    fn bilinear(&self, tx: f32, ty: f32) -> Packed {
        let tx = tx.max(0.0).min(self.max_x);
        let ty = ty.max(0.0).min(self.max_y);
        let x0 = tx as usize;
        let y0 = ty as usize;
        let wx = ((tx - x0 as f32) * 256.0) as u64;
        let wy = ((ty - y0 as f32) * 256.0) as u64;
        let i = y0 * self.w + x0;
        let (Some(r0), Some(r1)) = (
            self.texels.get(i..i + 2),
            self.texels.get(i + self.w..i + self.w + 2),
        ) else {
            return 0;
        };
        let w11 = (wx * wy) >> 8;
        let w10 = (wx * (256 - wy)) >> 8;
        let w01 = ((256 - wx) * wy) >> 8;
        let w00 = 256 - w11 - w10 - w01;
        expand(r0[0]) * w00 + expand(r0[1]) * w10 + expand(r1[0]) * w01 + expand(r1[1]) * w11
    }

    fn texel_rgb(&self, i: usize, j: usize) -> [u8; 3] {
        let t = self.texels.get(j * self.w + i).copied().unwrap_or(0);
        [t as u8, (t >> 8) as u8, (t >> 16) as u8]
    }
}

/// The painted mat as a world-aligned RGB mip pyramid, with the floor around it.
#[derive(Debug, Clone)]
pub struct MatTexture {
    levels: Vec<Level>,
    /// World coordinates (metres) of the lower-left corner of texel (0, 0), all levels.
    origin: (f32, f32),
    px_per_m: f32,
    mat_size: (f32, f32),
    mat_rgb: [u8; 3],
    floor_rgb: [u8; 3],
}

fn color(rgb: [u8; 3]) -> Color {
    Color::from_rgba8(rgb[0], rgb[1], rgb[2], 255)
}

fn paint_of(rgb: [u8; 3]) -> Paint<'static> {
    let mut paint = Paint::default();
    paint.set_color(color(rgb));
    paint.anti_alias = true;
    paint
}

impl MatTexture {
    /// Paints the mat: the floor colour everywhere, the mat rectangle
    /// `[0, mat_size.0] x [0, mat_size.1]` (metres) in `mat_rgb`, then `strokes` in order
    /// (anti-aliased, round caps and joins, dashes in metres), at `px_per_m` texels per
    /// metre, and builds the mip pyramid.
    pub fn new(
        strokes: &[PaintStroke],
        mat_size: (f32, f32),
        px_per_m: f32,
        mat_rgb: [u8; 3],
        floor_rgb: [u8; 3],
    ) -> Result<Self, SimError> {
        Self::on_floor(
            strokes,
            mat_size,
            px_per_m,
            Some(mat_rgb),
            &Floor::plain(floor_rgb),
        )
    }

    /// [`Self::new`] on a textured `floor` (`sim::floor`), with the mat rectangle in
    /// `mat_rgb` or, with `None`, no mat: the floor runs under the strokes (tape on a floor).
    pub fn on_floor(
        strokes: &[PaintStroke],
        mat_size: (f32, f32),
        px_per_m: f32,
        mat_rgb: Option<[u8; 3]>,
        floor: &Floor,
    ) -> Result<Self, SimError> {
        let floor_rgb = floor.base;
        let (mw, mh) = mat_size;
        if !(mw.is_finite() && mh.is_finite() && mw > 0.0 && mh > 0.0 && mw <= 50.0 && mh <= 50.0) {
            return Err(SimError::Invalid(format!(
                "mat size {mw} x {mh} m must be positive and at most 50 m"
            )));
        }
        if !(px_per_m.is_finite() && (10.0..=4000.0).contains(&px_per_m)) {
            return Err(SimError::Invalid(format!(
                "texture resolution {px_per_m} px/m must be in 10..=4000"
            )));
        }
        let coarse = 1usize << (NUM_LEVELS - 1);
        let border0 = COARSE_BORDER * coarse; // level-0 texels of floor around the mat
        let round_up = |n: usize| n.div_ceil(coarse) * coarse;
        let w0 = round_up((mw * px_per_m).ceil() as usize + 2 * border0);
        let h0 = round_up((mh * px_per_m).ceil() as usize + 2 * border0);
        if w0 * h0 > 64 << 20 {
            return Err(SimError::Invalid(format!(
                "texture of {w0} x {h0} texels is too large; lower px_per_m"
            )));
        }
        let border_m = border0 as f32 / px_per_m;
        let origin = (-border_m, -border_m);

        let size = IntSize::from_wh(w0 as u32, h0 as u32)
            .ok_or_else(|| SimError::Invalid("empty texture".into()))?;
        let mut pixmap = Pixmap::new(size.width(), size.height())
            .ok_or_else(|| SimError::Invalid(format!("cannot allocate a {w0} x {h0} pixmap")))?;
        if floor.kind == FloorKind::Plain && floor.stains.is_empty() {
            pixmap.fill(color(floor_rgb));
        } else {
            // Texel (i, r) (r from the top row) has its centre at world
            // (ox + (i + 0.5) / ppm, oy + (h0 - r - 0.5) / ppm).
            for (r, row) in pixmap.data_mut().chunks_exact_mut(w0 * 4).enumerate() {
                let y = origin.1 + (h0 as f32 - r as f32 - 0.5) / px_per_m;
                for (i, px) in row.chunks_exact_mut(4).enumerate() {
                    let x = origin.0 + (i as f32 + 0.5) / px_per_m;
                    let [cr, cg, cb] = floor.texel(x, y);
                    px.copy_from_slice(&[cr, cg, cb, 255]);
                }
            }
        }
        // World (x, y) -> pixmap pixel (x right, y down from the top row).
        let to_px = |x: f32, y: f32| {
            (
                (x - origin.0) * px_per_m,
                h0 as f32 - (y - origin.1) * px_per_m,
            )
        };
        let (x0, y0) = to_px(0.0, mh);
        if let Some(mat_rgb) = mat_rgb
            && let Some(rect) = Rect::from_xywh(x0, y0, mw * px_per_m, mh * px_per_m)
        {
            pixmap.fill_rect(rect, &paint_of(mat_rgb), Transform::identity(), None);
        }
        for stroke in strokes {
            draw_stroke(&mut pixmap, stroke, px_per_m, &to_px)?;
        }

        // Pixmap (premultiplied, opaque) -> level 0 with row 0 at the lowest y.
        let data = pixmap.data();
        let mut texels = vec![0u32; w0 * h0];
        for (j, row) in texels.chunks_exact_mut(w0).enumerate() {
            let src_row = h0 - 1 - j;
            let src = &data[src_row * w0 * 4..(src_row + 1) * w0 * 4];
            for (t, s) in row.iter_mut().zip(src.chunks_exact(4)) {
                *t = u32::from_le_bytes([s[0], s[1], s[2], 255]);
            }
        }
        let mut levels = vec![make_level(w0, h0, px_per_m, texels)];
        for _ in 1..NUM_LEVELS {
            let Some(prev) = levels.last() else { break };
            let (w, h) = (prev.w / 2, prev.h / 2);
            let mut texels = vec![0u32; w * h];
            for j in 0..h {
                for i in 0..w {
                    let sum = expand(prev.texels[(2 * j) * prev.w + 2 * i])
                        + expand(prev.texels[(2 * j) * prev.w + 2 * i + 1])
                        + expand(prev.texels[(2 * j + 1) * prev.w + 2 * i])
                        + expand(prev.texels[(2 * j + 1) * prev.w + 2 * i + 1]);
                    let avg = |k| ((lane(sum, k) + 2) / 4) as u8;
                    texels[j * w + i] = u32::from_le_bytes([avg(0), avg(1), avg(2), 255]);
                }
            }
            let scale = prev.scale / 2.0;
            levels.push(make_level(w, h, scale, texels));
        }
        Ok(Self {
            levels,
            origin,
            px_per_m,
            mat_size,
            mat_rgb: mat_rgb.unwrap_or(floor_rgb),
            floor_rgb,
        })
    }

    /// [`Self::new`] with the default resolution and colours.
    pub fn with_defaults(strokes: &[PaintStroke], mat_size: (f32, f32)) -> Result<Self, SimError> {
        Self::new(
            strokes,
            mat_size,
            DEFAULT_PX_PER_M,
            DEFAULT_MAT_RGB,
            DEFAULT_FLOOR_RGB,
        )
    }

    /// Bilinear colour (0..=255 per channel) at world point `(x, y)` metres, from the
    /// full-resolution level. Outside the mat: the floor colour.
    pub fn sample(&self, x: f32, y: f32) -> [f32; 3] {
        let l = &self.levels[0];
        let p = l.bilinear(
            (x - self.origin.0) * l.scale - 0.5,
            (y - self.origin.1) * l.scale - 0.5,
        );
        [0, 1, 2].map(|k| lane(p, k) as f32 / 256.0)
    }

    /// Texels per metre of the full-resolution level.
    pub fn px_per_m(&self) -> f32 {
        self.px_per_m
    }

    /// Mat size in metres `(x extent, y extent)`.
    pub fn mat_size(&self) -> (f32, f32) {
        self.mat_size
    }

    /// Colour of the bare mat.
    pub fn mat_rgb(&self) -> [u8; 3] {
        self.mat_rgb
    }

    /// Colour of the floor around the mat.
    pub fn floor_rgb(&self) -> [u8; 3] {
        self.floor_rgb
    }
}

fn make_level(w: usize, h: usize, scale: f32, texels: Vec<u32>) -> Level {
    Level {
        w,
        h,
        scale,
        max_x: (w.saturating_sub(2)) as f32 + 0.999,
        max_y: (h.saturating_sub(2)) as f32 + 0.999,
        texels,
    }
}

fn draw_stroke(
    pixmap: &mut Pixmap,
    stroke: &PaintStroke,
    px_per_m: f32,
    to_px: &dyn Fn(f32, f32) -> (f32, f32),
) -> Result<(), SimError> {
    if stroke.points.is_empty() || !(stroke.width_m.is_finite() && stroke.width_m > 0.0) {
        return Err(SimError::Invalid(format!(
            "paint stroke needs points and a positive width (width {} m, {} points)",
            stroke.width_m,
            stroke.points.len()
        )));
    }
    let mut pb = PathBuilder::new();
    for (k, &(x, y)) in stroke.points.iter().enumerate() {
        if !(x.is_finite() && y.is_finite()) {
            return Err(SimError::Invalid(format!(
                "paint stroke point ({x}, {y}) is not finite"
            )));
        }
        let (px, py) = to_px(x, y);
        if k == 0 {
            pb.move_to(px, py);
        } else {
            pb.line_to(px, py);
        }
    }
    if stroke.points.len() == 1 {
        // A dot: a zero-length segment with round caps.
        let (px, py) = to_px(stroke.points[0].0, stroke.points[0].1);
        pb.line_to(px + 1e-3, py);
    }
    if stroke.closed {
        pb.close();
    }
    let Some(path) = pb.finish() else {
        return Ok(());
    };
    let width_px = stroke.width_m * px_per_m;
    let dash = match stroke.dash {
        Some((on, off)) => {
            if !(on.is_finite() && off.is_finite() && on > 0.0 && off > 0.0) {
                return Err(SimError::Invalid(format!(
                    "dash ({on}, {off}) m must be positive"
                )));
            }
            // Round caps lengthen each dash by the line width: shorten the dash and shift
            // the pattern so that each painted dash, caps included, spans its stated
            // length from the start of the pattern.
            let (on, off) = (on * px_per_m, off * px_per_m);
            let core = (on - width_px).max(0.05 * on);
            StrokeDash::new(vec![core, off + on - core], -(on - core) / 2.0)
        }
        None => None,
    };
    let sk = Stroke {
        width: width_px,
        line_cap: LineCap::Round,
        line_join: LineJoin::Round,
        dash,
        ..Stroke::default()
    };
    pixmap.stroke_path(
        &path,
        &paint_of(stroke.rgb),
        &sk,
        Transform::identity(),
        None,
    );
    Ok(())
}

/// Photometric effects applied to a rendered (or synthesised) frame, in this order:
/// blur (optics), brightness (exposure), noise (sensor).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderEffects {
    /// Multiplies every channel (1.0: unchanged).
    pub brightness: f32,
    /// Standard deviation of additive Gaussian noise, in 8-bit levels (0: none).
    pub noise_std: f32,
    /// A 3x3 binomial ([1 2 1] x [1 2 1] / 16) blur.
    pub blur: bool,
}

impl Default for RenderEffects {
    fn default() -> Self {
        Self {
            brightness: 1.0,
            noise_std: 0.0,
            blur: false,
        }
    }
}

impl RenderEffects {
    /// True when applying these effects leaves a frame unchanged.
    pub fn is_identity(&self) -> bool {
        self.brightness == 1.0 && self.noise_std <= 0.0 && !self.blur
    }
}

/// Applies `effects` in place to an RGB8 `width x height` frame, drawing noise from `rng`
/// (seed it for reproducible frames). Allocates nothing.
///
/// Panics if `rgb.len() != width * height * 3`.
pub fn apply_effects<R: Rng + ?Sized>(
    width: u32,
    height: u32,
    effects: &RenderEffects,
    rng: &mut R,
    rgb: &mut [u8],
) {
    let (w, h) = (width as usize, height as usize);
    assert_eq!(
        rgb.len(),
        w * h * 3,
        "frame buffer must be width * height * 3 bytes"
    );
    if effects.blur && w >= 2 && h >= 2 {
        blur_121(w, h, rgb);
    }
    let gain = if effects.brightness.is_finite() {
        effects.brightness.max(0.0)
    } else {
        1.0
    };
    let noise = if effects.noise_std.is_finite() && effects.noise_std > 0.0 {
        Normal::new(0.0f32, effects.noise_std).ok()
    } else {
        None
    };
    match noise {
        Some(normal) => {
            for p in rgb.iter_mut() {
                let val = *p as f32 * gain + normal.sample(rng);
                *p = val.round().clamp(0.0, 255.0) as u8;
            }
        }
        None if gain != 1.0 => {
            for p in rgb.iter_mut() {
                *p = (*p as f32 * gain).round().clamp(0.0, 255.0) as u8;
            }
        }
        None => {}
    }
}

/// Separable [1 2 1] / 4 blur in place (edges replicated), with scalar carries only.
pub(crate) fn blur_121(w: usize, h: usize, rgb: &mut [u8]) {
    // Horizontal.
    for row in rgb.chunks_exact_mut(w * 3) {
        for c in 0..3 {
            let mut prev = row[c] as u16;
            for i in 0..w {
                let cur = row[i * 3 + c] as u16;
                let next = if i + 1 < w {
                    row[(i + 1) * 3 + c] as u16
                } else {
                    cur
                };
                row[i * 3 + c] = ((prev + 2 * cur + next + 2) / 4) as u8;
                prev = cur;
            }
        }
    }
    // Vertical.
    let stride = w * 3;
    for col in 0..stride {
        let mut prev = rgb[col] as u16;
        for j in 0..h {
            let cur = rgb[j * stride + col] as u16;
            let next = if j + 1 < h {
                rgb[(j + 1) * stride + col] as u16
            } else {
                cur
            };
            rgb[j * stride + col] = ((prev + 2 * cur + next + 2) / 4) as u8;
            prev = cur;
        }
    }
}

/// Where one pixel looks, in the robot frame (pose-independent), built once.
#[derive(Debug, Clone, Copy, Default)]
struct PixelRay {
    /// First probe's ground point, metres ahead of / left of the axle centre.
    fwd: f32,
    left: f32,
    /// Robot-frame step between consecutive probes (metres).
    step_fwd: f32,
    step_left: f32,
    /// Weight of mip level `level + 1` (trilinear), in 1/32; 0: `level` only.
    tri: u8,
    level: u8,
    /// Number of probes; 0: no ground here (wall).
    probes: u8,
}

/// Renders the camera view of a [`MatTexture`] at any pose.
#[derive(Debug, Clone)]
pub struct Renderer {
    texture: MatTexture,
    camera: CameraModel,
    /// One entry per pixel, row-major.
    rays: Vec<PixelRay>,
    /// The wall's colour, and its shade per image row.
    wall_rgb: [u8; 3],
    wall_rows: Vec<[u8; 3]>,
    /// Per-pixel colours beyond the ground (RGB8, a whole frame), instead of `wall_rows`.
    backdrop: Option<Vec<u8>>,
    /// RGBA8 over the rendered frame (`sim::scene`'s things in view), if any.
    foreground: Option<Vec<u8>>,
}

/// The ground footprint of one pixel: the difference between the ground points of the
/// pixel's two opposite edges along `u` and along `v`, robot frame.
fn footprint(camera: &CameraModel, u: f32, v: f32, g: (f32, f32)) -> Option<[(f32, f32); 2]> {
    let diff = |a: Option<(f32, f32)>, b: Option<(f32, f32)>| match (a, b) {
        (Some(a), Some(b)) => Some((b.0 - a.0, b.1 - a.1)),
        (None, Some(b)) => Some((2.0 * (b.0 - g.0), 2.0 * (b.1 - g.1))),
        (Some(a), None) => Some((2.0 * (g.0 - a.0), 2.0 * (g.1 - a.1))),
        (None, None) => None,
    };
    let du = diff(
        camera.pixel_to_robot_ground(u - 0.5, v),
        camera.pixel_to_robot_ground(u + 0.5, v),
    )?;
    let dv = diff(
        camera.pixel_to_robot_ground(u, v - 0.5),
        camera.pixel_to_robot_ground(u, v + 0.5),
    )?;
    Some([du, dv])
}

/// For every pixel of `camera`, row-major: where its ray meets the ground (robot frame),
/// and how to filter the texture over its footprint.
fn ray_table(texture: &MatTexture, camera: &CameraModel) -> Vec<PixelRay> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let max_level = (NUM_LEVELS - 1) as f32;
    let ppm = texture.px_per_m;
    let mut rays = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let (u, v) = (i as f32 + 0.5, j as f32 + 0.5);
            let Some(g) = camera.pixel_to_robot_ground(u, v) else {
                rays.push(PixelRay::default());
                continue;
            };
            let Some([du, dv]) = footprint(camera, u, v, g) else {
                rays.push(PixelRay {
                    fwd: g.0,
                    left: g.1,
                    level: (NUM_LEVELS - 1) as u8,
                    probes: 1,
                    ..PixelRay::default()
                });
                continue;
            };
            let len_u = du.0.hypot(du.1);
            let len_v = dv.0.hypot(dv.1);
            let (major, major_len) = if len_v >= len_u {
                (dv, len_v)
            } else {
                (du, len_u)
            };
            let area = (du.0 * dv.1 - du.1 * dv.0).abs();
            let minor_len = (area / major_len.max(1e-12)).max(1e-9);
            // Filter size: the short axis, but no finer than a texel and no finer than
            // the long axis split among the most probes; probes cover the long axis.
            let texel = 1.0 / ppm;
            let size = minor_len.max(texel).max(major_len / MAX_PROBES as f32);
            let probes = ((major_len / size).round() as u32).clamp(1, MAX_PROBES);
            let lod = (size * ppm).log2().clamp(0.0, max_level);
            let level = (lod.floor() as usize).min(NUM_LEVELS - 1);
            let frac = if level + 1 < NUM_LEVELS {
                lod - level as f32
            } else {
                0.0
            };
            let n = probes as f32;
            let step = (major.0 / n, major.1 / n);
            let start = (n - 1.0) / 2.0;
            rays.push(PixelRay {
                fwd: g.0 - start * step.0,
                left: g.1 - start * step.1,
                step_fwd: step.0,
                step_left: step.1,
                tri: (frac * TRI_ONE as f32).round() as u8,
                level: level as u8,
                probes: probes as u8,
            });
        }
    }
    rays
}

impl Renderer {
    /// Builds the per-pixel ray table for `camera` (validated) over `texture`.
    pub fn new(texture: MatTexture, camera: CameraModel) -> Result<Self, SimError> {
        camera.validate()?;
        let rays = ray_table(&texture, &camera);
        let mut renderer = Self {
            texture,
            camera,
            rays,
            wall_rgb: DEFAULT_WALL_RGB,
            wall_rows: Vec::new(),
            backdrop: None,
            foreground: None,
        };
        renderer.set_wall_rgb(DEFAULT_WALL_RGB);
        Ok(renderer)
    }

    /// Moves the camera (another tilt, height or lens, same image size): the ray table and
    /// the wall's shading are built again (as in `new`; not timed). The backdrop,
    /// drawn for the old camera, is dropped; the caller sets one for the new camera.
    pub fn set_camera(&mut self, camera: CameraModel) -> Result<(), SimError> {
        camera.validate()?;
        if (camera.width, camera.height) != (self.camera.width, self.camera.height) {
            return Err(SimError::Invalid(format!(
                "a {}x{} camera for a renderer of {}x{} frames",
                camera.width, camera.height, self.camera.width, self.camera.height
            )));
        }
        self.rays = ray_table(&self.texture, &camera);
        self.camera = camera;
        self.backdrop = None;
        self.foreground = None;
        self.set_wall_rgb(self.wall_rgb);
        Ok(())
    }

    /// Sets the wall colour (seen above the horizon): `rgb` scaled by 0.95 at the horizon,
    /// brightening linearly to 1.10 at the top of the image.
    pub fn set_wall_rgb(&mut self, rgb: [u8; 3]) {
        self.wall_rgb = rgb;
        let h = self.camera.height as usize;
        let horizon = self.camera.horizon_v().max(1.0);
        self.wall_rows = (0..h)
            .map(|j| {
                let v = j as f32 + 0.5;
                let up = (1.0 - v / horizon).clamp(0.0, 1.0);
                let gain = 0.95 + 0.15 * up;
                rgb.map(|c| (c as f32 * gain).round().clamp(0.0, 255.0) as u8)
            })
            .collect();
    }

    /// Paints the mat anew (same size and resolution, so the ray table stays): `strokes`
    /// on `mat_rgb`, surrounded by `floor_rgb`. Scene randomisation calls it per scene.
    pub fn repaint(
        &mut self,
        strokes: &[PaintStroke],
        mat_rgb: [u8; 3],
        floor_rgb: [u8; 3],
    ) -> Result<(), SimError> {
        self.repaint_on_floor(strokes, Some(mat_rgb), &Floor::plain(floor_rgb))
    }

    /// [`Self::repaint`] on a textured floor, with or without a mat
    /// ([`MatTexture::on_floor`]).
    pub fn repaint_on_floor(
        &mut self,
        strokes: &[PaintStroke],
        mat_rgb: Option<[u8; 3]>,
        floor: &Floor,
    ) -> Result<(), SimError> {
        let t = &self.texture;
        self.texture = MatTexture::on_floor(strokes, t.mat_size, t.px_per_m, mat_rgb, floor)?;
        Ok(())
    }

    /// What the camera sees where its rays miss the ground: a whole RGB8 frame whose pixels
    /// are used there (walls, furniture, people), or `None` for the plain wall gradient.
    pub fn set_backdrop(&mut self, image: Option<Vec<u8>>) -> Result<(), SimError> {
        if let Some(img) = &image
            && img.len() != self.frame_len()
        {
            return Err(SimError::Invalid(format!(
                "backdrop of {} bytes for a {}x{} camera (needs {})",
                img.len(),
                self.camera.width,
                self.camera.height,
                self.frame_len()
            )));
        }
        self.backdrop = image;
        Ok(())
    }

    /// What stands in front of the camera: RGBA8, `width * height * 4` bytes, blended over
    /// every rendered frame (`out = out * (1 - a) + rgb * a`), or `None` for nothing.
    pub fn set_foreground(&mut self, image: Option<Vec<u8>>) -> Result<(), SimError> {
        let need = self.camera.width as usize * self.camera.height as usize * 4;
        if let Some(img) = &image
            && img.len() != need
        {
            return Err(SimError::Invalid(format!(
                "foreground of {} bytes for a {}x{} camera (needs {need})",
                img.len(),
                self.camera.width,
                self.camera.height,
            )));
        }
        self.foreground = image;
        Ok(())
    }

    /// The texture this renderer draws.
    pub fn texture(&self) -> &MatTexture {
        &self.texture
    }

    /// The camera this renderer draws for.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// Bytes in one frame: `width * height * 3`.
    pub fn frame_len(&self) -> usize {
        self.camera.width as usize * self.camera.height as usize * 3
    }

    /// Renders the camera view from a robot at `pose` into `out` (RGB8, row-major, top row
    /// first). Allocates nothing.
    ///
    /// Panics if `out.len() != width * height * 3`.
    pub fn render(&self, pose: &Pose2, out: &mut [u8]) {
        assert_eq!(
            out.len(),
            self.frame_len(),
            "frame buffer must be width * height * 3 bytes"
        );
        let w = self.camera.width as usize;
        let tex = &self.texture;
        let (s, c) = pose.heading.sin_cos();
        // Robot frame (fwd, left) -> level-0 texel-edge coordinates
        // (X, Y) = ((x - ox) * ppm, (y - oy) * ppm).
        let k0 = tex.px_per_m;
        let (axf, axl, ax0) = (c * k0, -s * k0, (pose.x - tex.origin.0) * k0);
        let (ayf, ayl, ay0) = (s * k0, c * k0, (pose.y - tex.origin.1) * k0);
        let levels = &tex.levels;
        let inv_scale: [f32; NUM_LEVELS] = std::array::from_fn(|l| 1.0 / (1u32 << l) as f32);

        for (j, ((rays, row), wall)) in self
            .rays
            .chunks_exact(w)
            .zip(out.chunks_exact_mut(w * 3))
            .zip(self.wall_rows.iter())
            .enumerate()
        {
            let backdrop = self
                .backdrop
                .as_deref()
                .and_then(|b| b.get(j * w * 3..(j + 1) * w * 3));
            for (i, (ray, px)) in rays.iter().zip(row.chunks_exact_mut(3)).enumerate() {
                if ray.probes == 0 {
                    match backdrop {
                        Some(b) => px.copy_from_slice(&b[i * 3..i * 3 + 3]),
                        None => px.copy_from_slice(wall),
                    }
                    continue;
                }
                let l0 = ray.level as usize;
                let tri = ray.tri as u64;
                let (Some(lev0), Some(lev1)) =
                    (levels.get(l0), levels.get((l0 + 1).min(NUM_LEVELS - 1)))
                else {
                    px.copy_from_slice(wall);
                    continue;
                };
                let (i0, i1) = (inv_scale[l0], inv_scale[(l0 + 1).min(NUM_LEVELS - 1)]);
                let mut acc: Packed = 0;
                let (mut f, mut l) = (ray.fwd, ray.left);
                for _ in 0..ray.probes {
                    let x = axf * f + axl * l + ax0;
                    let y = ayf * f + ayl * l + ay0;
                    acc += if tri == 0 {
                        lev0.bilinear(x * i0 - 0.5, y * i0 - 0.5)
                    } else if tri == TRI_ONE as u64 {
                        lev1.bilinear(x * i1 - 0.5, y * i1 - 0.5)
                    } else {
                        let a = lev0.bilinear(x * i0 - 0.5, y * i0 - 0.5);
                        let b = lev1.bilinear(x * i1 - 0.5, y * i1 - 0.5);
                        ((a * (TRI_ONE as u64 - tri) + b * tri) >> TRI_BITS) & LANES16
                    };
                    f += ray.step_fwd;
                    l += ray.step_left;
                }
                let norm = 1.0 / (256.0 * ray.probes as f32);
                for k in 0..3 {
                    px[k as usize] = (lane(acc, k) as f32 * norm + 0.5) as u8;
                }
            }
        }
        if let Some(fg) = &self.foreground {
            blend_over(out, fg);
        }
    }

    /// [`Self::render`] followed by [`apply_effects`].
    pub fn render_with_effects<R: Rng + ?Sized>(
        &self,
        pose: &Pose2,
        effects: &RenderEffects,
        rng: &mut R,
        out: &mut [u8],
    ) {
        self.render(pose, out);
        apply_effects(self.camera.width, self.camera.height, effects, rng, out);
    }
}

/// Blends RGBA8 `over` onto RGB8 `rgb` of the same pixel count:
/// `rgb = rgb * (1 - a) + over * a`, rounded; alpha 0 leaves the pixel as it is.
pub fn blend_over(rgb: &mut [u8], over: &[u8]) {
    for (px, o) in rgb.chunks_exact_mut(3).zip(over.chunks_exact(4)) {
        match o[3] {
            0 => {}
            255 => px.copy_from_slice(&o[..3]),
            a => {
                let a = a as u32;
                for k in 0..3 {
                    px[k] = ((px[k] as u32 * (255 - a) + o[k] as u32 * a + 127) / 255) as u8;
                }
            }
        }
    }
}

/// Colour of the driven trace in [`top_down`].
pub const TRACE_RGB: [u8; 3] = [30, 90, 230];
/// Extra floor shown around the mat in [`top_down`], metres.
const TOP_DOWN_MARGIN_M: f32 = 0.05;

/// The mat seen from above (about 200 px/m, north up: world +y at the top), with `trace`
/// (the driven path) as a blue polyline, a green dot at its start, and `marks` (e.g.
/// interventions, in red) as dots with a heading tick. Returns `(width, height, rgb)`,
/// RGB8 row-major, top row first, for [`write_png`].
pub fn top_down(
    texture: &MatTexture,
    trace: &[Pose2],
    marks: &[(Pose2, [u8; 3])],
) -> (u32, u32, Vec<u8>) {
    // The level closest to 200 px/m.
    let level_index = (0..texture.levels.len())
        .min_by(|&a, &b| {
            let da = (texture.levels[a].scale / 200.0).log2().abs();
            let db = (texture.levels[b].scale / 200.0).log2().abs();
            da.total_cmp(&db)
        })
        .unwrap_or(0);
    let lev = &texture.levels[level_index];
    let k = lev.scale;
    let (mw, mh) = texture.mat_size;
    // Texel window: the mat plus a margin, clamped to the level.
    let i0 = (((-TOP_DOWN_MARGIN_M - texture.origin.0) * k)
        .floor()
        .max(0.0)) as usize;
    let j0 = (((-TOP_DOWN_MARGIN_M - texture.origin.1) * k)
        .floor()
        .max(0.0)) as usize;
    let i1 = ((((mw + TOP_DOWN_MARGIN_M - texture.origin.0) * k).ceil()) as usize).min(lev.w);
    let j1 = ((((mh + TOP_DOWN_MARGIN_M - texture.origin.1) * k).ceil()) as usize).min(lev.h);
    let (w, h) = (i1.saturating_sub(i0).max(1), j1.saturating_sub(j0).max(1));
    let mut rgba = Vec::with_capacity(w * h * 4);
    for r in 0..h {
        let j = j1.saturating_sub(1 + r); // top image row = highest y
        for i in i0..i0 + w {
            let [r, g, b] = lev.texel_rgb(i, j);
            rgba.extend_from_slice(&[r, g, b, 255]);
        }
    }
    // World -> image pixel.
    let wx0 = texture.origin.0 + i0 as f32 / k;
    let wy1 = texture.origin.1 + j1 as f32 / k;
    let to_px = |x: f32, y: f32| ((x - wx0) * k, (wy1 - y) * k);

    let Some(mut pixmap) = IntSize::from_wh(w as u32, h as u32).and_then(|size| {
        // Opaque, so premultiplied == straight RGBA.
        Pixmap::from_vec(rgba, size)
    }) else {
        return (w as u32, h as u32, vec![0; w * h * 3]);
    };
    let line = Stroke {
        width: 2.5,
        line_cap: LineCap::Round,
        line_join: LineJoin::Round,
        ..Stroke::default()
    };
    let finite: Vec<&Pose2> = trace
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .collect();
    if finite.len() >= 2 {
        let mut pb = PathBuilder::new();
        for (n, p) in finite.iter().enumerate() {
            let (x, y) = to_px(p.x, p.y);
            if n == 0 {
                pb.move_to(x, y);
            } else {
                pb.line_to(x, y);
            }
        }
        if let Some(path) = pb.finish() {
            pixmap.stroke_path(
                &path,
                &paint_of(TRACE_RGB),
                &line,
                Transform::identity(),
                None,
            );
        }
    }
    if let Some(p) = finite.first() {
        let (x, y) = to_px(p.x, p.y);
        if let Some(dot) = PathBuilder::from_circle(x, y, 5.0) {
            pixmap.fill_path(
                &dot,
                &paint_of([40, 190, 60]),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
        }
    }
    let outline = Stroke {
        width: 1.5,
        ..Stroke::default()
    };
    let tick = Stroke {
        width: 2.0,
        line_cap: LineCap::Round,
        ..Stroke::default()
    };
    for (pose, rgb) in marks {
        if !(pose.x.is_finite() && pose.y.is_finite() && pose.heading.is_finite()) {
            continue;
        }
        let (x, y) = to_px(pose.x, pose.y);
        if let Some(dot) = PathBuilder::from_circle(x, y, 6.0) {
            pixmap.fill_path(
                &dot,
                &paint_of(*rgb),
                FillRule::Winding,
                Transform::identity(),
                None,
            );
            pixmap.stroke_path(
                &dot,
                &paint_of([20, 20, 20]),
                &outline,
                Transform::identity(),
                None,
            );
        }
        let (s, c) = pose.heading.sin_cos();
        let mut pb = PathBuilder::new();
        pb.move_to(x, y);
        pb.line_to(x + 14.0 * c, y - 14.0 * s);
        if let Some(path) = pb.finish() {
            pixmap.stroke_path(&path, &paint_of(*rgb), &tick, Transform::identity(), None);
        }
    }
    (w as u32, h as u32, rgba_to_rgb(pixmap.data()))
}

fn rgba_to_rgb(rgba: &[u8]) -> Vec<u8> {
    rgba.chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

/// Writes an RGB8 image (`w * h * 3` bytes, top row first) as a PNG file.
pub fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<(), SimError> {
    let file_err = |reason: String| SimError::File {
        path: path.display().to_string(),
        reason,
    };
    if rgb.len() != w as usize * h as usize * 3 {
        return Err(file_err(format!(
            "image buffer has {} bytes, expected {} for {w} x {h} RGB",
            rgb.len(),
            w as usize * h as usize * 3
        )));
    }
    image::save_buffer_with_format(
        path,
        rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| file_err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use std::f32::consts::FRAC_PI_2;

    const MAT: (f32, f32) = (1.83, 2.74);
    const ROAD: [u8; 3] = [60, 60, 64];
    const EDGE: [u8; 3] = [235, 200, 40];
    const WHITE: [u8; 3] = [245, 245, 245];

    /// A straight road up the mat at x = 0.9: surface, two edges, dashed centre line.
    fn straight_road() -> Vec<PaintStroke> {
        let line = |x: f32, width_m: f32, rgb, dash| PaintStroke {
            points: vec![(x, 0.1), (x, 2.6)],
            width_m,
            rgb,
            dash,
            closed: false,
        };
        vec![
            line(0.9, 0.30, ROAD, None),
            line(0.76, 0.02, EDGE, None),
            line(1.04, 0.02, EDGE, None),
            line(0.9, 0.012, WHITE, Some((0.05, 0.05))),
        ]
    }

    fn close(a: [f32; 3], b: [u8; 3], tol: f32) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y as f32).abs() <= tol)
    }

    #[test]
    fn texture_has_mat_floor_and_strokes() {
        let tex = MatTexture::with_defaults(&straight_road(), MAT).unwrap();
        assert!(close(tex.sample(0.3, 1.0), DEFAULT_MAT_RGB, 1.0));
        assert!(close(tex.sample(-0.05, 1.0), DEFAULT_FLOOR_RGB, 1.0));
        assert!(close(tex.sample(1.0, 2.9), DEFAULT_FLOOR_RGB, 1.0));
        assert!(close(tex.sample(-3.0, 9.0), DEFAULT_FLOOR_RGB, 1.0));
        assert!(close(tex.sample(0.85, 1.0), ROAD, 1.0));
        assert!(close(tex.sample(0.76, 1.0), EDGE, 1.0));
        assert!(close(tex.sample(1.04, 1.5), EDGE, 1.0));
        // Dashes of 5 cm every 10 cm from the start at y = 0.1.
        assert!(close(tex.sample(0.9, 0.125), WHITE, 1.0));
        assert!(close(tex.sample(0.9, 0.525), WHITE, 1.0));
        assert!(close(tex.sample(0.9, 0.175), ROAD, 1.0));
        assert!(close(tex.sample(0.9, 0.575), ROAD, 1.0));
        // Coarser levels average the same scene.
        let coarse = tex.levels.last().unwrap();
        assert_eq!(tex.levels.len(), NUM_LEVELS);
        assert_eq!(coarse.w * (1 << (NUM_LEVELS - 1)), tex.levels[0].w);
        assert!(MatTexture::with_defaults(&straight_road(), (0.0, 1.0)).is_err());
        let bad = PaintStroke {
            points: vec![(0.0, 0.0), (1.0, 1.0)],
            width_m: -1.0,
            rgb: WHITE,
            dash: None,
            closed: false,
        };
        assert!(MatTexture::with_defaults(&[bad], MAT).is_err());
    }

    fn px(frame: &[u8], w: u32, u: u32, v: u32) -> [u8; 3] {
        let i = ((v * w + u) * 3) as usize;
        [frame[i], frame[i + 1], frame[i + 2]]
    }

    #[test]
    fn a_fisheye_view_bends_the_straight_road_edges() {
        use crate::sim::camera::LensKind;
        let tex = MatTexture::with_defaults(&straight_road(), MAT).unwrap();
        let camera = CameraModel {
            lens: LensKind::Fisheye,
            ..CameraModel::pinhole(224, 224)
        };
        let r = Renderer::new(tex, camera).unwrap();
        let (w, h) = (camera.width, camera.height);
        let mut frame = vec![0u8; r.frame_len()];
        let pose = Pose2::new(0.9, 0.5, FRAC_PI_2);
        r.render(&pose, &mut frame);
        // Wall in the top corners, road at the bottom centre.
        assert!(
            px(&frame, w, 0, 0)
                .iter()
                .zip(DEFAULT_WALL_RGB)
                .all(|(a, b)| a.abs_diff(b) < 25)
        );
        assert!(
            px(&frame, w, w / 2 - 20, h - 1)
                .iter()
                .zip(ROAD)
                .all(|(a, b)| a.abs_diff(b) < 3)
        );
        // The right edge line's inner side (x = 1.03) is drawn where the fisheye projects
        // it, 0.2, 0.5 and 1.2 m ahead, where a pinhole would put it elsewhere.
        let yellow = |p: [u8; 3]| p[0] > 150 && p[1] > 130 && p[2] < 120;
        let pinhole = CameraModel::pinhole(224, 224);
        for d in [0.2f32, 0.5, 1.2] {
            let (u, v) = camera.ground_to_pixel(&pose, 1.03, pose.y + d).unwrap();
            let found = (w / 2..w)
                .find(|&x| yellow(px(&frame, w, x, v as u32)))
                .unwrap_or_else(|| panic!("{d} m ahead: no edge in row {v}"));
            assert!(
                (found as f32 - u).abs() <= 2.0,
                "{d} m ahead: edge at {found}, projected {u}"
            );
            let (up, vp) = pinhole.ground_to_pixel(&pose, 1.03, pose.y + d).unwrap();
            assert!(
                (up - u).hypot(vp - v) > 3.0,
                "{d} m ahead: pinhole ({up}, {vp}) vs ({u}, {v})"
            );
        }
    }

    #[test]
    fn a_moved_camera_renders_as_a_renderer_built_for_it() {
        let tex = MatTexture::with_defaults(&straight_road(), MAT).unwrap();
        let (low, high) = (
            CameraModel::jetbot(224, 224),
            CameraModel {
                tilt_deg: 18.0,
                ..CameraModel::jetbot(224, 224)
            },
        );
        let mut moved = Renderer::new(tex.clone(), low).unwrap();
        moved.set_wall_rgb([90, 120, 150]);
        moved.set_camera(high).unwrap();
        let mut built = Renderer::new(tex, high).unwrap();
        built.set_wall_rgb([90, 120, 150]);
        let pose = Pose2::new(0.9, 0.5, FRAC_PI_2);
        let (mut a, mut b) = (vec![0u8; moved.frame_len()], vec![0u8; built.frame_len()]);
        moved.render(&pose, &mut a);
        built.render(&pose, &mut b);
        assert_eq!(a, b);
        assert_eq!(moved.camera().tilt_deg, 18.0);
        // Tilted up, more of the frame is wall: the horizon is lower.
        assert!(high.horizon_v() > low.horizon_v() + 30.0);
        // Another frame size is refused, naming both.
        let small = CameraModel {
            width: 96,
            height: 96,
            ..high
        };
        let e = moved.set_camera(small).unwrap_err().to_string();
        assert!(e.contains("96x96") && e.contains("224x224"), "{e}");
    }

    #[test]
    fn camera_view_of_a_straight_road() {
        let tex = MatTexture::with_defaults(&straight_road(), MAT).unwrap();
        let camera = CameraModel::pinhole(224, 224);
        let r = Renderer::new(tex, camera).unwrap();
        let (w, h) = (camera.width, camera.height);
        let mut frame = vec![0u8; r.frame_len()];
        // On the road's centre line, between dashes... the centre column at the bottom
        // sees the ground 1 cm ahead of the camera.
        let pose = Pose2::new(0.9, 0.5, FRAC_PI_2);
        r.render(&pose, &mut frame);
        // Top row: wall; the wall is brighter at the top than at the horizon.
        let top = px(&frame, w, 5, 0);
        let near_horizon = px(&frame, w, 5, camera.horizon_v() as u32 - 1);
        assert!(top[0] > near_horizon[0]);
        assert!(
            top.iter()
                .zip(DEFAULT_WALL_RGB)
                .all(|(a, b)| a.abs_diff(b) < 25)
        );
        // Bottom corners: road (it is 30 cm wide; the bottom row sees a few cm).
        assert!(
            px(&frame, w, 0, h - 1)
                .iter()
                .zip(ROAD)
                .all(|(a, b)| a.abs_diff(b) < 3)
        );
        // The view is left-right symmetric apart from the dashes.
        let mut asym = 0u64;
        for v in (camera.horizon_v().ceil() as u32 + 2)..h {
            for u in 0..w / 2 - 8 {
                let (a, b) = (px(&frame, w, u, v), px(&frame, w, w - 1 - u, v));
                asym += a
                    .iter()
                    .zip(b)
                    .map(|(x, y)| x.abs_diff(y) as u64)
                    .sum::<u64>();
            }
        }
        let mean = asym as f64 / ((h as f64 - camera.horizon_v() as f64) * w as f64 * 1.5);
        assert!(mean < 1.0, "mean asymmetry {mean}");
        // Both yellow edges are visible at the row 0.3 m ahead, left and right of the centre.
        let (_, v) = camera.ground_to_pixel(&pose, 0.9, 0.8).unwrap();
        let row: Vec<[u8; 3]> = (0..w).map(|u| px(&frame, w, u, v as u32)).collect();
        let yellow = |p: &[u8; 3]| p[0] > 150 && p[1] > 130 && p[2] < 120;
        assert!(row[..w as usize / 2].iter().any(yellow));
        assert!(row[w as usize / 2..].iter().any(yellow));
        // Turned to face +x the road runs across the view: no yellow in the centre column
        // far ahead, only mat.
        r.render(&Pose2::new(0.3, 1.0, 0.0), &mut frame);
        let p = px(&frame, w, w / 2, h - 10);
        assert!(
            p.iter()
                .zip(DEFAULT_MAT_RGB)
                .all(|(a, b)| a.abs_diff(b) < 3),
            "{p:?}"
        );
    }

    #[test]
    fn effects_are_seeded_and_do_what_they_say() {
        let (w, h) = (8u32, 6u32);
        let base: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 200) as u8 + 20).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut same = base.clone();
        apply_effects(w, h, &RenderEffects::default(), &mut rng, &mut same);
        assert_eq!(same, base);
        assert!(RenderEffects::default().is_identity());
        let bright = RenderEffects {
            brightness: 1.1,
            ..RenderEffects::default()
        };
        let mut b = base.clone();
        apply_effects(w, h, &bright, &mut rng, &mut b);
        assert!(
            b.iter()
                .zip(&base)
                .all(|(x, y)| *x as f32 >= *y as f32 * 1.1 - 0.51)
        );
        let noisy = RenderEffects {
            noise_std: 4.0,
            ..RenderEffects::default()
        };
        let (mut n1, mut n2) = (base.clone(), base.clone());
        apply_effects(w, h, &noisy, &mut ChaCha8Rng::seed_from_u64(7), &mut n1);
        apply_effects(w, h, &noisy, &mut ChaCha8Rng::seed_from_u64(7), &mut n2);
        assert_eq!(n1, n2);
        assert_ne!(n1, base);
        // Blur keeps a flat image flat and softens an edge.
        let blur = RenderEffects {
            blur: true,
            ..RenderEffects::default()
        };
        let mut flat = vec![100u8; (w * h * 3) as usize];
        apply_effects(w, h, &blur, &mut rng, &mut flat);
        assert!(flat.iter().all(|&x| x == 100));
        let mut edge: Vec<u8> = (0..w * h)
            .flat_map(|i| if i % w < w / 2 { [0u8; 3] } else { [200u8; 3] })
            .collect();
        apply_effects(w, h, &blur, &mut rng, &mut edge);
        assert_eq!(px(&edge, w, 2, 2), [0; 3]);
        assert_eq!(px(&edge, w, 3, 2), [50; 3]);
        assert_eq!(px(&edge, w, 4, 2), [150; 3]);
        assert_eq!(px(&edge, w, 7, 2), [200; 3]);
        let e: RenderEffects = serde_json::from_str(r#"{"blur": true}"#).unwrap();
        assert_eq!(e.brightness, 1.0);
    }

    #[test]
    fn top_down_shows_the_mat_and_marks() {
        let tex = MatTexture::with_defaults(&straight_road(), MAT).unwrap();
        let trace = vec![
            Pose2::new(0.9, 0.3, FRAC_PI_2),
            Pose2::new(0.9, 1.5, FRAC_PI_2),
        ];
        let red = [220, 20, 20];
        let (w, h, rgb) = top_down(&tex, &trace, &[(Pose2::new(0.4, 2.0, 0.0), red)]);
        assert_eq!(rgb.len(), (w * h * 3) as usize);
        // About 200 px/m over the mat plus 5 cm each side.
        assert!((w as f32 - 1.93 * 200.0).abs() <= 3.0, "{w}");
        assert!((h as f32 - 2.84 * 200.0).abs() <= 3.0, "{h}");
        // The mark's centre: x = (0.4 + 0.05) * 200, y from the top = (2.74 + 0.05 - 2.0) * 200.
        let (mu, mv) = (90, 158);
        let p = px(&rgb, w, mu, mv);
        assert!(p.iter().zip(red).all(|(a, b)| a.abs_diff(b) < 10), "{p:?}");
        // The trace (blue) at y = 1.0, x = 0.9.
        let p = px(&rgb, w, 190, 358);
        assert!(p[2] > 150 && p[0] < 100, "{p:?}");
        // A corner: floor.
        let p = px(&rgb, w, 2, 2);
        assert!(
            p.iter()
                .zip(DEFAULT_FLOOR_RGB)
                .all(|(a, b)| a.abs_diff(b) < 3)
        );
    }

    #[test]
    fn png_round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let rgb: Vec<u8> = (0..4 * 3 * 3).map(|i| i as u8 * 5).collect();
        write_png(&path, 4, 3, &rgb).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (4, 3));
        assert_eq!(img.into_raw(), rgb);
        assert!(write_png(&path, 5, 3, &rgb).is_err());
        assert!(write_png(&dir.path().join("no/such/dir/x.png"), 4, 3, &rgb).is_err());
    }

    #[test]
    fn blend_over_worked_numbers() {
        let mut rgb = vec![100, 200, 50, 10, 20, 30, 0, 0, 0];
        let over = [0, 0, 0, 0, 255, 255, 255, 255, 0, 0, 0, 102];
        blend_over(&mut rgb, &over);
        // Alpha 0: unchanged; 255: replaced; 102 of black over 0 stays 0.
        assert_eq!(rgb, [100, 200, 50, 255, 255, 255, 0, 0, 0]);
        let mut grey = vec![200, 200, 200];
        // 200 * (255 - 102) / 255 = 120.0 plus 10 * 102 / 255 = 4.0: 124.
        blend_over(&mut grey, &[10, 10, 10, 102]);
        assert_eq!(grey, [124, 124, 124]);
    }
}
