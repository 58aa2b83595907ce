//! Replayed-frame synthesis, the heart of the simulator: a new camera view at a simulated
//! pose made from a recorded frame, as VISTA and DAVE-2 do.
//!
//! A [`Recording`] is frames plus the pose each was taken at (from the renderer, or real
//! data with poses). For a simulated pose the [`Synthesizer`] picks the nearest recorded
//! frame along the path (position plus a heading term) and re-projects it through the
//! ground plane:
//!
//! ```text
//! output pixel --(per-pixel table, built once)--> ground point in the robot frame (m)
//!   --(new pose)--> world ground point --(recorded pose's homography)--> recorded pixel
//!   --> bilinear sample of the recorded frame
//! ```
//!
//! A fisheye's pixels are not a homography of the ground, so for a fisheye camera the
//! recorded pose's matrix maps the ground point to the camera-frame ray instead, and the
//! lens (OpenCV's fisheye polynomial, in float32) projects that ray to the recorded pixel.
//! The output side needs nothing new: its per-pixel table already holds, for any lens, the
//! ground point each output pixel sees.
//!
//! Output pixels with no ground (above the horizon, or beyond the camera's ground range)
//! copy the recorded pixel at the same `(u, v)`: walls far away barely move. Ground points
//! that fall outside the recorded frame (the floor just in front and to the side of a view
//! moved sideways or turned) are looked up in the frames recorded 6, 14 and 28 cm further
//! back, which drove towards that floor; where none saw it (or with
//! [`Synthesizer::with_fill_from_earlier`] off) they are clamped to the frame's nearest
//! edge pixel and count against [`SynthInfo::coverage`]. What the camera adds to every
//! frame in the same place (glare, vignetting) would move with the floor; with
//! [`Synthesizer::with_flat_field`] it is fitted from the recording, the frames are kept
//! flattened and each view is put back through it, so it stays in place
//! ([`super::flat_field`]). Synthesis is faithful only near the recording, so [`SynthInfo::valid`] turns false
//! beyond half a road width or 18 degrees of heading error (VISTA's episode-end rule;
//! [`Synthesizer::with_max_heading_deg`] sets a wider heading bound for a wide lens).
//!
//! Frames are RGB8, row-major, top row first, `width * height * 3` bytes; pixel
//! conventions are those of [`crate::sim::camera`].

use std::sync::Arc;

use nalgebra::Matrix3;

use super::camera::CameraModel;
use super::flat_field::{FlatField, PixelPair};
use super::lens::Lens;
use super::{Pose2, SimError, wrap_angle};

/// Largest heading error (radians) at which a synthesised view counts as valid by default:
/// VISTA's 18 degrees (`sim.replay_max_heading_deg` sets another).
pub const MAX_HEADING_ERROR_RAD: f32 = 18.0 * std::f32::consts::PI / 180.0;

/// Weight of the heading difference in [`Synthesizer::nearest`], metres: a frame facing
/// the other way costs as much as one `2 * HEADING_WEIGHT_M` farther away, a frame
/// 18 degrees off about as much as one 6 cm farther away.
pub const HEADING_WEIGHT_M: f32 = 0.2;

/// One recorded camera frame and the robot pose it was taken at.
#[derive(Debug, Clone)]
pub struct RecordedFrame {
    pub pose: Pose2,
    pub width: u32,
    pub height: u32,
    /// RGB8, row-major, top row first, `width * height * 3` bytes.
    pub rgb: Arc<Vec<u8>>,
}

/// Frames recorded by one camera along a path.
#[derive(Debug, Clone)]
pub struct Recording {
    pub camera: CameraModel,
    pub frames: Vec<RecordedFrame>,
}

/// What [`Synthesizer::synthesize`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SynthInfo {
    /// Index of the recorded frame used.
    pub index: usize,
    /// Offset of the new pose from the recorded pose, perpendicular to the recorded
    /// heading, metres, positive to the left.
    pub lateral_m: f32,
    /// `wrap(pose.heading - recorded.heading)`, radians.
    pub heading_error: f32,
    /// `|lateral_m| <= half road width` and `|heading_error| <=` the heading bound (18
    /// degrees unless set).
    pub valid: bool,
    /// Fraction of the output's ground pixels whose source lies inside the recorded frame
    /// or an earlier one that fills it (1.0 when the output shows no ground).
    pub coverage: f32,
}

/// Re-projects recorded frames to new poses.
#[derive(Debug, Clone)]
pub struct Synthesizer {
    recording: Recording,
    half_road_width_m: f32,
    /// The heading bound of [`SynthInfo::valid`], radians.
    max_heading_error_rad: f32,
    /// Per output pixel, row-major: the ground point `[forward, left]` (metres, robot
    /// frame) it sees, or `None` for no ground (above the horizon or too far).
    /// Built through the camera's lens, so it serves pinhole and fisheye alike.
    ground: Vec<Option<[f32; 2]>>,
    /// Number of `Some` entries in `ground`.
    ground_pixels: usize,
    /// Per recorded frame: world ground `(x, y, 1)` -> the recorded camera's pixel
    /// `(u w, v w, w)` (pinhole: its ground homography) or camera-frame ray (fisheye).
    to_recorded: Vec<Matrix3<f32>>,
    /// How a recorded camera's `to_recorded` output becomes a pixel.
    projection: Projection,
    /// Per recorded frame: earlier frames about [`EARLIER_M`] back along the recording
    /// (`u32::MAX`: none), which saw the ground now just in front of it.
    earlier: Vec<[u32; EARLIER_M.len()]>,
    /// Fill ground that the frame did not see from [`Self::earlier`] frames.
    fill_from_earlier: bool,
    /// Project one pixel in four and interpolate the rest ([`Synthesizer::remap`]): the
    /// fisheye at [`INTERPOLATE_FROM_WIDTH`] and wider.
    interpolate_map: bool,
    /// The camera's image-fixed effects, fitted from the recording: the frames are kept
    /// flattened and each view is restored through it ([`Synthesizer::with_flat_field`]).
    flat: Option<FlatField>,
}

/// How far back along the recording (metres of path) the frames lie that fill ground the
/// nearest frame did not see: a JetBot's fisheye sees the floor from about 8 cm ahead, so
/// a view moved sideways or turned needs the floor that frames 5-30 cm back saw.
const EARLIER_M: [f32; 3] = [0.06, 0.14, 0.28];

/// What [`Synthesizer::with_flat_field`] fitted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatFieldFit {
    /// Pixel pairs that saw the same floor.
    pub pairs: usize,
    /// Their root mean square disagreement, levels: as recorded, and as light.
    pub mismatch: (f32, f32),
    /// [`FlatField::largest_correction`], levels.
    pub largest_correction: f32,
}

impl FlatFieldFit {
    /// The field takes away at least a level and a quarter of the pairs' disagreement: the
    /// camera adds something at fixed pixels. Otherwise what is left is resampling and
    /// pose error, which a field cannot explain, and it is not used.
    pub fn explains_the_pairs(&self) -> bool {
        let (before, after) = self.mismatch;
        before - after >= 1.0f32.max(0.25 * before)
    }
}

/// Fisheye frames at least this wide project one pixel in four (every other pixel of every
/// other row) and interpolate the rest ([`Synthesizer::remap`]): at 96 and 224 px within
/// 2 levels of projecting every pixel (tested).
const INTERPOLATE_FROM_WIDTH: usize = 64;
/// Frames at least this wide fit the flat field on a finer grid from sparser pixel pairs.
const FINE_FIELD_FROM_WIDTH: usize = 128;
/// The widest frame whose projected rows fit the remap's stack buffers (1280 px); wider
/// frames project every pixel.
const QUARTER_MAX_EVENS: usize = 640;

/// The recorded camera's lens, in float32 for the per-pixel loop.
#[derive(Debug, Clone, Copy)]
enum Projection {
    /// `to_recorded` is the ground homography: divide by `w`.
    Pinhole,
    /// `to_recorded` gives the ray; project it with OpenCV's fisheye model.
    Fisheye {
        fx: f32,
        fy: f32,
        cu: f32,
        cv: f32,
        k: [f32; 4],
    },
}

/// Pinhole: the homogeneous pixel `(pu, pv, pw)` -> `(u, v)`; `None` behind the camera.
#[inline(always)]
fn pinhole_pixel(pu: f32, pv: f32, pw: f32) -> Option<(f32, f32)> {
    if pw > 1e-6 {
        let inv = 1.0 / pw;
        Some((pu * inv, pv * inv))
    } else {
        None
    }
}

/// `atan(t)` for `t >= 0`, to within 1e-5 radians (a thousandth of a pixel at JetBot's
/// focal length), about ten times faster than the library's `atan2`, which would take most
/// of a fisheye synthesis: a degree-11 odd polynomial on `[0, 1]` (Abramowitz and Stegun's
/// coefficients) and `atan(t) = pi / 2 - atan(1 / t)` above it.
#[inline(always)]
fn atan_nonnegative(t: f32) -> f32 {
    let (x, flip) = if t > 1.0 { (1.0 / t, true) } else { (t, false) };
    let x2 = x * x;
    let p = x
        * (0.999_977_26
            + x2 * (-0.332_623_47
                + x2 * (0.193_543_46
                    + x2 * (-0.116_432_87 + x2 * (0.052_653_32 - x2 * 0.011_721_2)))));
    if flip {
        std::f32::consts::FRAC_PI_2 - p
    } else {
        p
    }
}

/// Fisheye: the camera-frame ray `(x, y, z)` -> `(u, v)`, as [`super::lens::Lens::project`]
/// in float32; `None` behind the camera (the 160 degree lens sees at most 80 degrees
/// off axis in the frame, so nothing behind it lands inside).
#[inline(always)]
fn fisheye_pixel(
    x: f32,
    y: f32,
    z: f32,
    (fx, fy): (f32, f32),
    cu: f32,
    cv: f32,
    k: &[f32; 4],
) -> Option<(f32, f32)> {
    if z <= 1e-6 {
        return None;
    }
    let rxy = (x * x + y * y).sqrt();
    if rxy <= 1e-12 {
        return Some((cu, cv));
    }
    let theta = atan_nonnegative(rxy / z);
    let t2 = theta * theta;
    let theta_d = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))));
    let scale = theta_d / rxy;
    Some((cu + fx * scale * x, cv + fy * scale * y))
}

impl Synthesizer {
    /// Checks the recording (not empty, every frame the camera's size with a buffer of
    /// `width * height * 3` bytes, finite poses) and builds the per-pixel ground table.
    pub fn new(recording: Recording, half_road_width_m: f32) -> Result<Self, SimError> {
        let camera = recording.camera;
        camera.validate()?;
        if !(half_road_width_m.is_finite() && half_road_width_m > 0.0) {
            return Err(SimError::Invalid(format!(
                "half road width {half_road_width_m} m must be positive"
            )));
        }
        if recording.frames.is_empty() {
            return Err(SimError::Invalid("recording has no frames".into()));
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        for (i, f) in recording.frames.iter().enumerate() {
            if f.width != camera.width || f.height != camera.height {
                return Err(SimError::Invalid(format!(
                    "recorded frame {i} is {}x{}, the camera is {}x{}",
                    f.width, f.height, camera.width, camera.height
                )));
            }
            if f.rgb.len() != w * h * 3 {
                return Err(SimError::Invalid(format!(
                    "recorded frame {i} has {} bytes, expected {} (RGB8)",
                    f.rgb.len(),
                    w * h * 3
                )));
            }
            let p = f.pose;
            if !(p.x.is_finite() && p.y.is_finite() && p.heading.is_finite()) {
                return Err(SimError::Invalid(format!(
                    "recorded frame {i} has a non-finite pose {p:?}"
                )));
            }
        }
        let mut ground = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let g = camera.pixel_to_robot_ground(i as f32 + 0.5, j as f32 + 0.5);
                ground.push(g.map(|(f, l)| [f, l]));
            }
        }
        let ground_pixels = ground.iter().filter(|g| g.is_some()).count();
        let projection = match camera.lens() {
            Lens::Pinhole { .. } => Projection::Pinhole,
            Lens::Fisheye { fx, fy, cu, cv, k } => Projection::Fisheye {
                fx: fx as f32,
                fy: fy as f32,
                cu: cu as f32,
                cv: cv as f32,
                k: k.map(|x| x as f32),
            },
        };
        let to_recorded = recording
            .frames
            .iter()
            .map(|f| match projection {
                Projection::Pinhole => camera.ground_homography(&f.pose),
                Projection::Fisheye { .. } => camera.ground_to_ray(&f.pose),
            })
            .collect();
        let earlier = earlier_frames(&recording.frames);
        Ok(Self {
            recording,
            half_road_width_m,
            max_heading_error_rad: MAX_HEADING_ERROR_RAD,
            ground,
            ground_pixels,
            to_recorded,
            projection,
            earlier,
            fill_from_earlier: true,
            interpolate_map: matches!(projection, Projection::Fisheye { .. })
                && camera.width as usize >= INTERPOLATE_FROM_WIDTH,
            flat: None,
        })
    }

    /// With `on`, fits the camera's image-fixed effects (vignetting, a light gradient,
    /// glare that moves with the camera: [`FlatField`]) from pixel pairs that saw the same
    /// floor in two frames, and keeps them in place: the recorded frames are flattened
    /// once and every view is restored through the field at its own pixels. The field is
    /// used only where it explains the pairs' disagreement
    /// ([`FlatFieldFit::explains_the_pairs`]); a fit that fails leaves the synthesis as it
    /// was, with a warning. Returns what was fitted (`None`: off, or the fit failed).
    pub fn with_flat_field(mut self, on: bool) -> (Self, Option<FlatFieldFit>) {
        self.unflatten();
        if !on {
            return (self, None);
        }
        let Some((field, fit)) = self.fit_flat_field() else {
            return (self, None);
        };
        if fit.explains_the_pairs() {
            for f in &mut self.recording.frames {
                f.rgb = Arc::new(field.flatten(&f.rgb));
            }
            self.flat = Some(field);
        }
        (self, Some(fit))
    }

    /// Fits a [`FlatField`] to the frames as this synthesizer holds them (as recorded
    /// unless a field is in use) without using it, and logs the fit; `None` (with a
    /// warning) where the fit fails. [`Self::with_flat_field`] uses it, and so does the
    /// odometry, which needs the field and not the views.
    pub(crate) fn fit_flat_field(&self) -> Option<(FlatField, FlatFieldFit)> {
        let c = self.recording.camera;
        let (w, h) = (c.width as usize, c.height as usize);
        let pairs = self.floor_pairs();
        let nodes = if w >= FINE_FIELD_FROM_WIDTH { 16 } else { 10 };
        let field = match FlatField::fit(w, h, &pairs, nodes) {
            Ok(f) => f,
            Err(e) => {
                tracing::warn!(
                    pairs = pairs.len(),
                    "no flat field for the camera's effects ({e})"
                );
                return None;
            }
        };
        let fit = FlatFieldFit {
            pairs: pairs.len(),
            mismatch: field.mismatch(),
            largest_correction: field.largest_correction(),
        };
        tracing::info!(
            pairs = fit.pairs,
            mismatch_levels = format!("{:.1} -> {:.1}", fit.mismatch.0, fit.mismatch.1),
            largest_correction = format!("{:.1}", fit.largest_correction),
            used = fit.explains_the_pairs(),
            "the camera's image-fixed effects (flat field)"
        );
        Some((field, fit))
    }

    /// Whether views are restored through a fitted [`FlatField`].
    pub fn has_flat_field(&self) -> bool {
        self.flat.is_some()
    }

    /// The fitted [`FlatField`] views are restored through, if one is used.
    pub fn flat_field(&self) -> Option<&FlatField> {
        self.flat.as_ref()
    }

    /// Undoes [`Self::with_flat_field`]'s flattening of the recorded frames (to within
    /// rounding), so a second call fits on what the camera recorded.
    fn unflatten(&mut self) {
        if let Some(field) = self.flat.take() {
            for f in &mut self.recording.frames {
                let mut rgb = f.rgb.to_vec();
                field.restore(&mut rgb);
                f.rgb = Arc::new(rgb);
            }
        }
    }

    /// Pixel pairs that saw the same floor point, for [`FlatField::fit`]: up to 120
    /// frames spread over the recording, each against the frames 6 and 14 cm before it
    /// (whose views of the floor ahead lie higher up in the frame, and to the side in a
    /// bend), on every fourth pixel (every second below 128 px). Left out: values within
    /// 3 levels of black or white in either frame (clipped) and pixels on edges (a
    /// summed central difference over 30 levels in either frame), where a pose error of a
    /// pixel would change the value.
    fn floor_pairs(&self) -> Vec<PixelPair> {
        const EDGE_LEVELS: f32 = 30.0;
        let frames = &self.recording.frames;
        let c = self.recording.camera;
        let (w, h) = (c.width as usize, c.height as usize);
        let stride = if w >= FINE_FIELD_FROM_WIDTH { 4 } else { 2 };
        let every = frames.len().div_ceil(120).max(1);
        let luma = |rgb: &[u8], i: usize, j: usize| -> f32 {
            let k = (j * w + i) * 3;
            (rgb[k] as f32 + rgb[k + 1] as f32 + rgb[k + 2] as f32) / 3.0
        };
        // Summed central differences of luma at the pixel nearest (u, v), not at the border.
        let edge = |rgb: &[u8], u: f32, v: f32| -> f32 {
            let (i, j) = (u as usize, v as usize);
            if i == 0 || j == 0 || i + 1 >= w || j + 1 >= h {
                return f32::INFINITY;
            }
            (luma(rgb, i + 1, j) - luma(rgb, i - 1, j)).abs()
                + (luma(rgb, i, j + 1) - luma(rgb, i, j - 1)).abs()
        };
        let bilinear = |rgb: &[u8], u: f32, v: f32| -> [f32; 3] {
            let (tx, ty) = (u - 0.5, v - 0.5);
            let (x0, y0) = (tx as usize, ty as usize);
            let (fx, fy) = (tx - x0 as f32, ty - y0 as f32);
            let at = |i: usize, j: usize, ch: usize| rgb[(j * w + i) * 3 + ch] as f32;
            [0, 1, 2].map(|ch| {
                let top = at(x0, y0, ch) * (1.0 - fx) + at(x0 + 1, y0, ch) * fx;
                let bot = at(x0, y0 + 1, ch) * (1.0 - fx) + at(x0 + 1, y0 + 1, ch) * fx;
                top * (1.0 - fy) + bot * fy
            })
        };
        let clipped = |rgb: &[f32; 3]| rgb.iter().any(|&x| !(3.0..=252.0).contains(&x));
        let mut pairs = Vec::new();
        for (i, fa) in frames.iter().enumerate().step_by(every) {
            let (s, co) = fa.pose.heading.sin_cos();
            let to_world = Matrix3::new(co, -s, fa.pose.x, s, co, fa.pose.y, 0.0, 0.0, 1.0);
            for &e in &self.earlier[i][..2] {
                let Some(fb) = frames.get(e as usize) else {
                    continue;
                };
                let m = self.to_recorded[e as usize] * to_world;
                for j in (stride / 2..h).step_by(stride) {
                    for k in (stride / 2..w).step_by(stride) {
                        let Some([f, l]) = self.ground[j * w + k] else {
                            continue;
                        };
                        let Some((u, v)) = self.project(&m, f, l) else {
                            continue;
                        };
                        if !(u >= 1.5 && v >= 1.5 && u <= w as f32 - 1.5 && v <= h as f32 - 1.5) {
                            continue;
                        }
                        let (ua, va) = (k as f32 + 0.5, j as f32 + 0.5);
                        if edge(&fa.rgb, ua, va) > EDGE_LEVELS || edge(&fb.rgb, u, v) > EDGE_LEVELS
                        {
                            continue;
                        }
                        let a_rgb = bilinear(&fa.rgb, ua, va);
                        let b_rgb = bilinear(&fb.rgb, u, v);
                        if clipped(&a_rgb) || clipped(&b_rgb) {
                            continue;
                        }
                        pairs.push(PixelPair {
                            a: (ua, va),
                            a_rgb,
                            b: (u, v),
                            b_rgb,
                        });
                    }
                }
            }
        }
        pairs
    }

    /// Per pixel of the view from `pose`, row-major: where its ground point lies in
    /// recorded frame `index` (clamped to the recording), or `None` where the pixel sees no
    /// ground or the point lies outside that frame. The pixels [`Self::synthesize_from`]
    /// samples from the frame itself rather than filling or clamping.
    pub fn sources(&self, index: usize, pose: &Pose2) -> Vec<Option<(f32, f32)>> {
        let index = index.min(self.recording.frames.len() - 1);
        let c = &self.recording.camera;
        let (wf, hf) = (c.width as f32, c.height as f32);
        let (s, co) = pose.heading.sin_cos();
        let to_world = Matrix3::new(co, -s, pose.x, s, co, pose.y, 0.0, 0.0, 1.0);
        let m = self.to_recorded[index] * to_world;
        self.ground
            .iter()
            .map(|g| {
                let [f, l] = (*g)?;
                self.project(&m, f, l)
                    .filter(|&(u, v)| u >= 0.0 && u <= wf && v >= 0.0 && v <= hf)
            })
            .collect()
    }

    /// A ground point `(forward, left)` through `m` (robot ground -> recorded camera) to
    /// the recorded pixel; `None` behind the camera.
    fn project(&self, m: &Matrix3<f32>, f: f32, l: f32) -> Option<(f32, f32)> {
        let pu = m[(0, 0)] * f + m[(0, 1)] * l + m[(0, 2)];
        let pv = m[(1, 0)] * f + m[(1, 1)] * l + m[(1, 2)];
        let pw = m[(2, 0)] * f + m[(2, 1)] * l + m[(2, 2)];
        match self.projection {
            Projection::Pinhole => pinhole_pixel(pu, pv, pw),
            Projection::Fisheye { fx, fy, cu, cv, k } => {
                fisheye_pixel(pu, pv, pw, (fx, fy), cu, cv, &k)
            }
        }
    }

    /// Whether ground the chosen frame did not see comes from earlier frames (true, the
    /// default) or is clamped to the chosen frame's nearest edge pixel (false: the
    /// single-frame synthesis, `sim.replay_fill = "edge"`).
    pub fn with_fill_from_earlier(mut self, on: bool) -> Self {
        self.fill_from_earlier = on;
        self
    }

    /// With `false`, every ground pixel is projected through the lens, where by default a
    /// fisheye of [`INTERPOLATE_FROM_WIDTH`] px and wider projects one in four and interpolates
    /// the rest: the exact reference the interpolation is checked and timed against.
    pub fn with_interpolated_map(mut self, on: bool) -> Self {
        self.interpolate_map = on && matches!(self.projection, Projection::Fisheye { .. });
        self
    }

    /// The recording frames are synthesised from.
    pub fn recording(&self) -> &Recording {
        &self.recording
    }

    /// The camera of the recording (and of the synthesised frames).
    pub fn camera(&self) -> &CameraModel {
        &self.recording.camera
    }

    /// Half the road width used for [`SynthInfo::valid`], metres.
    pub fn half_road_width_m(&self) -> f32 {
        self.half_road_width_m
    }

    /// The heading bound of [`SynthInfo::valid`]: `degrees` (above 0, at most 90) instead
    /// of VISTA's 18.
    pub fn with_max_heading_deg(mut self, degrees: f32) -> Result<Self, SimError> {
        if !(degrees.is_finite() && degrees > 0.0 && degrees <= 90.0) {
            return Err(SimError::Invalid(format!(
                "sim.replay_max_heading_deg = {degrees}: allowed above 0, at most 90"
            )));
        }
        self.max_heading_error_rad = degrees.to_radians();
        Ok(self)
    }

    /// The heading bound of [`SynthInfo::valid`], radians.
    pub fn max_heading_error_rad(&self) -> f32 {
        self.max_heading_error_rad
    }

    /// Bytes in one frame: `width * height * 3`.
    pub fn frame_len(&self) -> usize {
        let c = &self.recording.camera;
        c.width as usize * c.height as usize * 3
    }

    /// Index of the recorded frame nearest to `pose`: smallest
    /// `distance^2 + (HEADING_WEIGHT_M * 2 sin(dheading / 2))^2`, so among frames at about
    /// the same place the one facing the same way wins. Linear scan.
    pub fn nearest(&self, pose: &Pose2) -> usize {
        let mut best = (f32::INFINITY, 0usize);
        for (i, f) in self.recording.frames.iter().enumerate() {
            let (dx, dy) = (pose.x - f.pose.x, pose.y - f.pose.y);
            let chord = 2.0 * (0.5 * (pose.heading - f.pose.heading)).sin();
            let hw = HEADING_WEIGHT_M * chord;
            let cost = dx * dx + dy * dy + hw * hw;
            if cost < best.0 {
                best = (cost, i);
            }
        }
        best.1
    }

    /// Offsets of `pose` from recorded frame `index`: `(lateral_m, heading_error, valid)`.
    fn offsets(&self, index: usize, pose: &Pose2) -> (f32, f32, bool) {
        let rec = self.recording.frames[index].pose;
        let (s, c) = rec.heading.sin_cos();
        let lateral = -s * (pose.x - rec.x) + c * (pose.y - rec.y);
        let heading_error = wrap_angle(pose.heading - rec.heading);
        let valid = lateral.abs() <= self.half_road_width_m
            && heading_error.abs() <= self.max_heading_error_rad;
        (lateral, heading_error, valid)
    }

    /// Synthesises the view from `pose` out of the nearest recorded frame into `out`
    /// (RGB8). Allocates nothing.
    ///
    /// Panics if `out.len() != width * height * 3`.
    pub fn synthesize(&self, pose: &Pose2, out: &mut [u8]) -> SynthInfo {
        let index = self.nearest(pose);
        self.synthesize_from(index, pose, out)
    }

    /// Synthesises the view from `pose` out of recorded frame `index` (clamped to the
    /// recording) into `out` (RGB8). Allocates nothing.
    ///
    /// Panics if `out.len() != width * height * 3`.
    pub fn synthesize_from(&self, index: usize, pose: &Pose2, out: &mut [u8]) -> SynthInfo {
        assert_eq!(
            out.len(),
            self.frame_len(),
            "frame buffer must be width * height * 3 bytes"
        );
        let index = index.min(self.recording.frames.len() - 1);
        let frame = &self.recording.frames[index];
        let src: &[u8] = &frame.rgb;
        let (w, h) = (frame.width as usize, frame.height as usize);

        // Robot frame of the new pose (forward, left, 1) -> world (x, y, 1) -> recorded
        // pixel (u w, v w, w), or recorded camera ray for a fisheye.
        let (s, c) = pose.heading.sin_cos();
        let to_world = Matrix3::new(c, -s, pose.x, s, c, pose.y, 0.0, 0.0, 1.0);
        let m = self.to_recorded[index] * to_world;
        // Earlier frames for the ground this one did not see (at most EARLIER_M.len()).
        let mut fill: [Option<(Matrix3<f32>, &[u8])>; EARLIER_M.len()] = [None; EARLIER_M.len()];
        if self.fill_from_earlier {
            for (slot, &e) in fill.iter_mut().zip(self.earlier[index].iter()) {
                if let Some(f) = self.recording.frames.get(e as usize) {
                    *slot = Some((self.to_recorded[e as usize] * to_world, &f.rgb[..]));
                }
            }
        }
        let inside = match self.projection {
            Projection::Pinhole => self.remap(&m, src, w, h, &fill, out, false, pinhole_pixel),
            Projection::Fisheye { fx, fy, cu, cv, k } => self.remap(
                &m,
                src,
                w,
                h,
                &fill,
                out,
                self.interpolate_map,
                |x, y, z| fisheye_pixel(x, y, z, (fx, fy), cu, cv, &k),
            ),
        };
        if let Some(field) = &self.flat {
            field.restore(out);
        }
        let coverage = if self.ground_pixels == 0 {
            1.0
        } else {
            inside as f32 / self.ground_pixels as f32
        };
        let (lateral_m, heading_error, valid) = self.offsets(index, pose);
        SynthInfo {
            index,
            lateral_m,
            heading_error,
            valid,
            coverage,
        }
    }

    /// Fills `out` from the recorded frame `src` (`w x h`): each output ground pixel's
    /// point goes through `m` (robot ground -> recorded camera) and `project`, and is
    /// sampled bilinearly; pixels with no ground copy `src` at the same place. A ground
    /// point outside `src` is looked up in the `fill` frames in turn (their own `m` and
    /// pixels), and clamped to `src`'s nearest edge pixel where none saw it. Returns how
    /// many ground pixels came from inside a recorded frame.
    ///
    /// With `interpolate`, only every other pixel of every other row is projected: a pixel
    /// between two projected ground pixels (along its row, or between the rows above and
    /// below) takes the mean of their recorded coordinates (the map is smooth; its error is
    /// a quarter of the second difference, hundredths of a pixel below the horizon), and
    /// one whose neighbours are not both seen ground is projected itself. The fisheye
    /// takes it (at 64 px and wider), where the projection is most of the cost.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn remap<P: Fn(f32, f32, f32) -> Option<(f32, f32)>>(
        &self,
        m: &Matrix3<f32>,
        src: &[u8],
        w: usize,
        h: usize,
        fill: &[Option<(Matrix3<f32>, &[u8])>],
        out: &mut [u8],
        interpolate: bool,
        project: P,
    ) -> usize {
        let (wf, hf) = (w as f32, h as f32);
        let (m00, m01, m02) = (m[(0, 0)], m[(0, 1)], m[(0, 2)]);
        let (m10, m11, m12) = (m[(1, 0)], m[(1, 1)], m[(1, 2)]);
        let (m20, m21, m22) = (m[(2, 0)], m[(2, 1)], m[(2, 2)]);
        let max_x = (w.saturating_sub(2)) as f32 + 0.999;
        let max_y = (h.saturating_sub(2)) as f32 + 0.999;

        // Where output pixel `k` comes from in the recorded frame: `None` with no ground;
        // `(u, v, seen)` with `seen` false behind the recorded camera (it passed over this
        // ground already; the nearest it saw is the bottom edge, on the same side).
        let locate = |k: usize| -> Option<(f32, f32, bool)> {
            let [f, l] = self.ground.get(k).copied().flatten()?;
            let pu = m00 * f + m01 * l + m02;
            let pv = m10 * f + m11 * l + m12;
            let pw = m20 * f + m21 * l + m22;
            Some(match project(pu, pv, pw) {
                Some((u, v)) => (u, v, true),
                None => (if pu >= 0.0 { wf } else { 0.0 }, hf, false),
            })
        };
        let in_frame = |u: f32, v: f32| u >= 0.0 && u <= wf && v >= 0.0 && v <= hf;
        // Bilinear, pixel centres at integer + 0.5; clamped to the frame.
        let sample = |from: &[u8], u: f32, v: f32, px: &mut [u8]| {
            let tx = (u - 0.5).max(0.0).min(max_x);
            let ty = (v - 0.5).max(0.0).min(max_y);
            let (x0, y0) = (tx as usize, ty as usize);
            let (fx, fy) = (tx - x0 as f32, ty - y0 as f32);
            let i00 = (y0 * w + x0) * 3;
            let i10 = i00 + w * 3;
            let (Some(r0), Some(r1)) = (from.get(i00..i00 + 6), from.get(i10..i10 + 6)) else {
                px.fill(0);
                return;
            };
            for ch in 0..3 {
                let a = r0[ch] as f32;
                let b = r0[3 + ch] as f32;
                let d = r1[ch] as f32;
                let e = r1[3 + ch] as f32;
                let top = a + (b - a) * fx;
                let bot = d + (e - d) * fx;
                px[ch] = (top + (bot - top) * fy + 0.5) as u8;
            }
        };
        // Output pixel `k`'s ground point in an earlier frame, if that frame saw it.
        let earlier = |k: usize| -> Option<(&[u8], f32, f32)> {
            let [f, l] = self.ground.get(k).copied().flatten()?;
            fill.iter().flatten().find_map(|(mf, from)| {
                let pu = mf[(0, 0)] * f + mf[(0, 1)] * l + mf[(0, 2)];
                let pv = mf[(1, 0)] * f + mf[(1, 1)] * l + mf[(1, 2)];
                let pw = mf[(2, 0)] * f + mf[(2, 1)] * l + mf[(2, 2)];
                let (u, v) = project(pu, pv, pw)?;
                in_frame(u, v).then_some((*from, u, v))
            })
        };
        let mut inside = 0usize;
        let mut put = |k: usize, at: Option<(f32, f32, bool)>, px: &mut [u8]| {
            let Some((u, v, seen)) = at else {
                px.copy_from_slice(&src[k * 3..k * 3 + 3]);
                return;
            };
            if seen && in_frame(u, v) {
                inside += 1;
                sample(src, u, v, px);
            } else if let Some((from, ue, ve)) = earlier(k) {
                inside += 1;
                sample(from, ue, ve, px);
            } else {
                sample(src, u, v, px);
            }
        };

        if !interpolate || w.div_ceil(2) > QUARTER_MAX_EVENS {
            for (k, px) in out.chunks_exact_mut(3).enumerate() {
                put(k, locate(k), px);
            }
            return inside;
        }
        // Projected pixels of a row's even columns go in `above` (row j) and `below` (row
        // j + 2); row j + 1's even columns are their mean, and every odd column the mean of
        // its two even neighbours, where both are seen ground; anything else is projected.
        let mean = |a: Option<(f32, f32, bool)>, b: Option<(f32, f32, bool)>| match (a, b) {
            (Some((u0, v0, true)), Some((u1, v1, true))) => {
                Some((0.5 * (u0 + u1), 0.5 * (v0 + v1), true))
            }
            _ => None,
        };
        let evens = w.div_ceil(2);
        let mut above = [None; QUARTER_MAX_EVENS];
        let mut below = [None; QUARTER_MAX_EVENS];
        let mut between = [None; QUARTER_MAX_EVENS];
        let project_row = |j: usize, into: &mut [Option<(f32, f32, bool)>]| {
            for (c, slot) in into.iter_mut().enumerate().take(evens) {
                *slot = locate(j * w + 2 * c);
            }
        };
        let mut emit_row = |j: usize, even: &[Option<(f32, f32, bool)>], out: &mut [u8]| {
            let base = j * w;
            let row = &mut out[base * 3..(base + w) * 3];
            for c in 0..evens {
                let i = 2 * c;
                put(base + i, even[c], &mut row[i * 3..i * 3 + 3]);
                if i + 1 < w {
                    let next = if c + 1 < evens { even[c + 1] } else { None };
                    let mid = mean(even[c], next).or_else(|| locate(base + i + 1));
                    put(base + i + 1, mid, &mut row[(i + 1) * 3..(i + 2) * 3]);
                }
            }
        };
        project_row(0, &mut above);
        let mut j = 0;
        while j < h {
            emit_row(j, &above, out);
            if j + 1 >= h {
                break;
            }
            if j + 2 < h {
                project_row(j + 2, &mut below);
                for c in 0..evens {
                    between[c] = mean(above[c], below[c]).or_else(|| locate((j + 1) * w + 2 * c));
                }
            } else {
                project_row(j + 1, &mut between);
            }
            emit_row(j + 1, &between, out);
            std::mem::swap(&mut above, &mut below);
            j += 2;
        }
        inside
    }
}

/// For each frame, the frames about [`EARLIER_M`] back along the recording's path (the
/// first frame at least that far back, by the summed distance between consecutive
/// frames; `u32::MAX` where the recording starts too late). A jump of more than 0.2 m
/// between consecutive frames (a recording of separate runs) starts the path afresh.
fn earlier_frames(frames: &[RecordedFrame]) -> Vec<[u32; EARLIER_M.len()]> {
    const JUMP_M: f32 = 0.2;
    let mut along = Vec::with_capacity(frames.len());
    let mut run_start = Vec::with_capacity(frames.len());
    let (mut s, mut start) = (0.0f32, 0usize);
    for (i, f) in frames.iter().enumerate() {
        if i > 0 {
            let p = frames[i - 1].pose;
            let d = (f.pose.x - p.x).hypot(f.pose.y - p.y);
            if d > JUMP_M {
                start = i;
            } else {
                s += d;
            }
        }
        along.push(s);
        run_start.push(start);
    }
    (0..frames.len())
        .map(|i| {
            EARLIER_M.map(|back| {
                let target = along[i] - back;
                (run_start[i]..i)
                    .rev()
                    .find(|&j| along[j] <= target)
                    .map_or(u32::MAX, |j| j as u32)
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::PaintStroke;
    use crate::sim::render::{MatTexture, Renderer, top_down, write_png};
    use std::f32::consts::{FRAC_PI_2, PI};

    const MAT: (f32, f32) = (1.83, 2.74);

    /// A test road: straight up the mat at x = 0.9 from y = 0.2 to 1.4, then a left
    /// quarter turn of radius 0.5 m: grey surface, yellow edges, dashed white centre.
    fn road_strokes() -> Vec<PaintStroke> {
        let mut centre = Vec::new();
        for k in 0..=24 {
            centre.push((0.9, 0.2 + 1.2 * k as f32 / 24.0));
        }
        for k in 1..=30 {
            let a = FRAC_PI_2 * k as f32 / 30.0;
            // Circle centred at (0.4, 1.4), from angle 0 (the point (0.9, 1.4)) CCW.
            centre.push((0.4 + 0.5 * a.cos(), 1.4 + 0.5 * a.sin()));
        }
        let offset = |d: f32| -> Vec<(f32, f32)> {
            // Offset to the left of the direction of travel by d.
            let n = centre.len();
            (0..n)
                .map(|i| {
                    let (a, b) = (centre[i.saturating_sub(1)], centre[(i + 1).min(n - 1)]);
                    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
                    let len = dx.hypot(dy);
                    (centre[i].0 - d * dy / len, centre[i].1 + d * dx / len)
                })
                .collect()
        };
        vec![
            PaintStroke {
                points: centre.clone(),
                width_m: 0.30,
                rgb: [60, 60, 64],
                dash: None,
                closed: false,
            },
            PaintStroke {
                points: offset(0.14),
                width_m: 0.02,
                rgb: [235, 200, 40],
                dash: None,
                closed: false,
            },
            PaintStroke {
                points: offset(-0.14),
                width_m: 0.02,
                rgb: [235, 200, 40],
                dash: None,
                closed: false,
            },
            PaintStroke {
                points: centre,
                width_m: 0.012,
                rgb: [245, 245, 245],
                dash: Some((0.05, 0.05)),
                closed: false,
            },
        ]
    }

    fn renderer(camera: CameraModel) -> Renderer {
        let tex = MatTexture::with_defaults(&road_strokes(), MAT).unwrap();
        Renderer::new(tex, camera).unwrap()
    }

    fn frame(r: &Renderer, pose: Pose2) -> RecordedFrame {
        let mut rgb = vec![0u8; r.frame_len()];
        r.render(&pose, &mut rgb);
        RecordedFrame {
            pose,
            width: r.camera().width,
            height: r.camera().height,
            rgb: Arc::new(rgb),
        }
    }

    fn psnr(a: &[u8], b: &[u8], mask: &[bool]) -> f64 {
        let (mut se, mut n) = (0.0f64, 0usize);
        for ((pa, pb), &m) in a.chunks_exact(3).zip(b.chunks_exact(3)).zip(mask) {
            if m {
                for k in 0..3 {
                    let d = pa[k] as f64 - pb[k] as f64;
                    se += d * d;
                }
                n += 3;
            }
        }
        assert!(n > 0);
        let mse = se / n as f64;
        if mse == 0.0 {
            return f64::INFINITY;
        }
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }

    /// Pixels of the view from `b` whose ground point is seen, inside the frame and
    /// below the horizon, by the camera at `a` (independent of the synthesiser's code).
    fn inside_mask(cam: &CameraModel, a: &Pose2, b: &Pose2) -> Vec<bool> {
        let (w, h) = (cam.width, cam.height);
        let mut mask = Vec::with_capacity((w * h) as usize);
        for j in 0..h {
            for i in 0..w {
                let (u, v) = (i as f32 + 0.5, j as f32 + 0.5);
                let ok = cam
                    .pixel_to_ground(b, u, v)
                    .and_then(|(x, y)| cam.ground_to_pixel(a, x, y))
                    .filter(|&(ua, va)| {
                        ua >= 0.5
                            && ua <= w as f32 - 0.5
                            && va <= h as f32 - 0.5
                            && cam.pixel_to_ground(a, ua, va).is_some()
                    })
                    .is_some();
                mask.push(ok);
            }
        }
        mask
    }

    fn side_step(a: Pose2, lateral: f32, turn_deg: f32) -> Pose2 {
        let (s, c) = a.heading.sin_cos();
        Pose2::new(
            a.x - s * lateral,
            a.y + c * lateral,
            a.heading + turn_deg.to_radians(),
        )
    }

    fn check_reprojection(
        camera: CameraModel,
        a: Pose2,
        lateral: f32,
        turn_deg: f32,
    ) -> (f64, f32) {
        let r = renderer(camera);
        let rec = Recording {
            camera,
            frames: vec![frame(&r, a)],
        };
        let synth = Synthesizer::new(rec, 0.14).unwrap();
        let b = side_step(a, lateral, turn_deg);
        let mut synthesized = vec![0u8; r.frame_len()];
        let info = synth.synthesize(&b, &mut synthesized);
        let mut direct = vec![0u8; r.frame_len()];
        r.render(&b, &mut direct);
        let mask = inside_mask(&camera, &a, &b);
        (psnr(&synthesized, &direct, &mask), info.coverage)
    }

    #[test]
    fn synthesis_matches_direct_render_after_a_side_step_and_turn() {
        let a = Pose2::new(0.9, 0.5, FRAC_PI_2);
        let (p224, cov224) = check_reprojection(CameraModel::pinhole(224, 224), a, 0.03, 5.0);
        let cam96 = CameraModel {
            width: 96,
            height: 96,
            ..CameraModel::pinhole(224, 224)
        };
        let (p96, cov96) = check_reprojection(cam96, a, 0.03, 5.0);
        // In the curve, the other way.
        let c = Pose2::new(
            0.4 + 0.5 * 0.6f32.cos(),
            1.4 + 0.5 * 0.6f32.sin(),
            0.6 + FRAC_PI_2,
        );
        let (pcurve, covcurve) = check_reprojection(CameraModel::pinhole(224, 224), c, -0.03, -5.0);
        println!(
            "reprojection PSNR: 224x224 {p224:.2} dB (coverage {cov224:.3}), 96x96 {p96:.2} dB \
             (coverage {cov96:.3}), curve 224x224 {pcurve:.2} dB (coverage {covcurve:.3})"
        );
        assert!(p224 >= PSNR_BOUND_224, "224x224 PSNR {p224}");
        assert!(p96 >= PSNR_BOUND_96, "96x96 PSNR {p96}");
        assert!(pcurve >= PSNR_BOUND_224, "curve PSNR {pcurve}");
        assert!(cov224 > 0.5 && cov96 > 0.5 && covcurve > 0.5);
    }

    /// Reached: 38.5 dB at 224x224 (39 dB in the curve), 36.7 dB at 96x96.
    const PSNR_BOUND_224: f64 = 35.0;
    const PSNR_BOUND_96: f64 = 33.0;

    #[test]
    fn the_fast_arctangent_is_within_1e_5_radians() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            // 0 to 1 finely, then out to 1000.
            let t = if i <= 100_000 {
                i as f64 / 100_000.0
            } else {
                (((i - 100_000) as f64 / 100_000.0) * 1000f64.ln()).exp()
            };
            let err = (f64::from(atan_nonnegative(t as f32)) - t.atan()).abs();
            worst = worst.max(err);
        }
        assert!(worst < 1e-5, "worst error {worst}");
    }

    fn jetbot_fisheye(size: u32) -> CameraModel {
        CameraModel {
            width: size,
            height: size,
            lens: crate::sim::camera::LensKind::Fisheye,
            ..CameraModel::pinhole(224, 224)
        }
    }

    #[test]
    fn ground_the_frame_did_not_see_comes_from_an_earlier_frame() {
        // Two frames up the straight (x = 0.9, heading +y), 14 cm apart; the view from the
        // second, turned 25 degrees right and 3 cm left, misses floor near its bottom-right
        // corner that the first frame saw.
        let cam = jetbot_fisheye(224);
        let r = renderer(cam);
        let a = Pose2::new(0.9, 0.5, FRAC_PI_2);
        let b = Pose2::new(0.9, 0.64, FRAC_PI_2);
        let rec = Recording {
            camera: cam,
            frames: vec![frame(&r, a), frame(&r, b)],
        };
        let view = side_step(b, 0.03, -25.0);
        let mut direct = vec![0u8; r.frame_len()];
        r.render(&view, &mut direct);
        let ground: Vec<bool> = (0..cam.height)
            .flat_map(|j| (0..cam.width).map(move |i| (i, j)))
            .map(|(i, j)| {
                cam.pixel_to_robot_ground(i as f32 + 0.5, j as f32 + 0.5)
                    .is_some()
            })
            .collect();
        // The pixels the second frame did not see.
        let missed: Vec<bool> = inside_mask(&cam, &b, &view)
            .iter()
            .zip(&ground)
            .map(|(&inside, &g)| g && !inside)
            .collect();
        let n_missed = missed.iter().filter(|&&m| m).count();
        assert!(n_missed > 1000, "{n_missed} pixels missed");

        let mut out = vec![0u8; r.frame_len()];
        let synth = Synthesizer::new(rec, 0.14).unwrap();
        let edge = synth.clone().with_fill_from_earlier(false);
        let info_edge = edge.synthesize_from(1, &view, &mut out);
        let p_edge = psnr(&out, &direct, &missed);
        let info = synth.synthesize_from(1, &view, &mut out);
        let p_fill = psnr(&out, &direct, &missed);
        println!(
            "missed {n_missed} px: edge {p_edge:.2} dB (coverage {:.3}), earlier frame \
             {p_fill:.2} dB (coverage {:.3})",
            info_edge.coverage, info.coverage
        );
        assert!(info_edge.coverage < 0.97, "{info_edge:?}");
        assert!(info.coverage > 0.95, "{info:?}");
        assert!(
            p_fill > 24.0 && p_fill > p_edge + 6.0,
            "{p_fill} vs {p_edge}"
        );
        // Seen pixels are the same either way.
        let seen: Vec<bool> = inside_mask(&cam, &b, &view);
        let mut out_edge = vec![0u8; r.frame_len()];
        edge.synthesize_from(1, &view, &mut out_edge);
        assert_eq!(psnr(&out, &out_edge, &seen), f64::INFINITY);
        // The first frame has nothing earlier: as the single-frame synthesis.
        let v0 = side_step(a, 0.03, -25.0);
        synth.synthesize_from(0, &v0, &mut out);
        edge.synthesize_from(0, &v0, &mut out_edge);
        assert_eq!(out, out_edge);
    }

    #[test]
    fn the_cameras_image_fixed_effects_stay_in_place() {
        // A weaving drive up the straight (frames every 2 cm, 4 cm either side of the
        // centre), recorded through a camera with vignetting, a light gradient and a
        // glare patch: what it adds at fixed pixels must stay there in a turned view.
        use crate::sim::appearance::{Glare, Look};
        let cam = jetbot_fisheye(96);
        let r = renderer(cam);
        let look = Look {
            vignette: 0.5,
            gradient: [0.3, -0.2],
            glare: Some(Glare {
                centre: [0.7, 0.6],
                radius: 0.1,
                peak: 0.5,
            }),
            ..Look::PLAIN
        };
        let mut rng = rand::rng();
        let shot = |pose: Pose2, rng: &mut rand::rngs::ThreadRng| {
            let mut f = frame(&r, pose);
            let mut rgb = f.rgb.to_vec();
            look.apply(cam.width, cam.height, rng, &mut rgb);
            f.rgb = Arc::new(rgb);
            f
        };
        let frames: Vec<RecordedFrame> = (0..56)
            .map(|k| {
                let y = 0.2 + 0.02 * k as f32;
                let x = 0.9 + 0.04 * (8.0 * y).sin();
                let slope = 0.32 * (8.0 * y).cos();
                shot(Pose2::new(x, y, FRAC_PI_2 - slope.atan()), &mut rng)
            })
            .collect();
        let rec = Recording {
            camera: cam,
            frames,
        };
        let plain = Synthesizer::new(rec, 0.14).unwrap();
        let (flat, fit) = plain.clone().with_flat_field(true);
        let Some(FlatFieldFit { mismatch, .. }) = fit else {
            panic!("no field fitted")
        };
        assert!(flat.flat.is_some(), "{fit:?}");
        // The recorded values disagree by tens of levels; their light by a few.
        assert!(
            mismatch.0 > 20.0 && mismatch.1 < 0.15 * mismatch.0,
            "{fit:?}"
        );
        let mut out = vec![0u8; plain.frame_len()];
        let (mut p_plain, mut p_flat) = (0.0, 0.0);
        let views = [(30, 0.03, -20.0), (40, -0.03, 15.0), (45, 0.0, 25.0)];
        for (k, lateral, turn) in views {
            let at = plain.recording().frames[k].pose;
            let view = side_step(at, lateral, turn);
            let truth = shot(view, &mut rng);
            let mask = inside_mask(&cam, &at, &view);
            plain.synthesize_from(k, &view, &mut out);
            let a = psnr(&out, &truth.rgb, &mask);
            flat.synthesize_from(k, &view, &mut out);
            let b = psnr(&out, &truth.rgb, &mask);
            println!(
                "frame {k}, {lateral} m, {turn} deg: {a:.2} dB -> {b:.2} dB with the flat field"
            );
            p_plain += a / views.len() as f64;
            p_flat += b / views.len() as f64;
        }
        assert!(p_flat > p_plain + 3.0, "{p_plain:.2} -> {p_flat:.2} dB");
        // A camera that adds nothing fits no field, and a second call refits from the
        // frames as recorded.
        let clean = Recording {
            camera: cam,
            frames: (0..56)
                .map(|k| frame(&r, Pose2::new(0.9, 0.2 + 0.02 * k as f32, FRAC_PI_2)))
                .collect(),
        };
        let (none, fit) = Synthesizer::new(clean, 0.14).unwrap().with_flat_field(true);
        assert!(none.flat.is_none(), "{fit:?}");
        let (again, fit_again) = flat.with_flat_field(true);
        let again_mismatch = fit_again.map(|f| f.mismatch).unwrap_or_default();
        assert!((again_mismatch.0 - mismatch.0).abs() < 0.05 * mismatch.0 && again.flat.is_some());
        let (off, _) = again.with_flat_field(false);
        assert!(off.flat.is_none());
        let back = &off.recording().frames[30].rgb;
        let worst = back
            .iter()
            .zip(plain.recording().frames[30].rgb.iter())
            .map(|(&a, &b)| (a as i32 - b as i32).abs())
            .max()
            .unwrap();
        assert!(worst <= 2, "frames back within {worst} levels");
    }

    #[test]
    fn earlier_frames_are_found_by_distance_along_the_recording() {
        let f = |x: f32| RecordedFrame {
            pose: Pose2::new(x, 0.0, 0.0),
            width: 1,
            height: 1,
            rgb: Arc::new(vec![0; 3]),
        };
        // Every 2.5 cm up to 0.40 m, then a jump of 1 m (another run) and two more frames.
        let mut frames: Vec<RecordedFrame> = (0..=16).map(|i| f(i as f32 * 0.025)).collect();
        frames.push(f(1.40));
        frames.push(f(1.425));
        let e = earlier_frames(&frames);
        let none = u32::MAX;
        assert_eq!(e[0], [none, none, none]);
        // Frame 4 (0.10 m): 6 cm back is 0.04 -> frame 1 (0.025); 14 and 28 cm: none.
        assert_eq!(e[4], [1, none, none]);
        // Frame 12 (0.30 m): 0.24 -> 9 (0.225), 0.16 -> 6 (0.15), 0.02 -> 0.
        assert_eq!(e[12], [9, 6, 0]);
        // Frame 16 (0.40 m): 0.34 -> 13, 0.26 -> 10, 0.12 -> 4.
        assert_eq!(e[16], [13, 10, 4]);
        // After the jump the path starts afresh: nothing 6 cm back.
        assert_eq!(e[17], [none, none, none]);
        assert_eq!(e[18], [none, none, none]);
    }

    #[test]
    fn fisheye_synthesis_matches_direct_render_after_a_side_step_and_turn() {
        let a = Pose2::new(0.9, 0.5, FRAC_PI_2);
        let (p224, cov224) = check_reprojection(jetbot_fisheye(224), a, 0.03, 5.0);
        let (p96, cov96) = check_reprojection(jetbot_fisheye(96), a, 0.03, 5.0);
        let c = Pose2::new(
            0.4 + 0.5 * 0.6f32.cos(),
            1.4 + 0.5 * 0.6f32.sin(),
            0.6 + FRAC_PI_2,
        );
        let (pcurve, covcurve) = check_reprojection(jetbot_fisheye(224), c, -0.03, -5.0);
        println!(
            "fisheye reprojection PSNR: 224x224 {p224:.2} dB (coverage {cov224:.3}), 96x96 \
             {p96:.2} dB (coverage {cov96:.3}), curve 224x224 {pcurve:.2} dB (coverage \
             {covcurve:.3})"
        );
        assert!(p224 >= PSNR_BOUND_224, "224x224 PSNR {p224}");
        assert!(p96 >= PSNR_BOUND_96, "96x96 PSNR {p96}");
        assert!(pcurve >= PSNR_BOUND_224, "curve PSNR {pcurve}");
        assert!(cov224 > 0.5 && cov96 > 0.5 && covcurve > 0.5);
    }

    #[test]
    fn the_interpolated_map_matches_projecting_every_pixel() {
        // One pixel in four projected (fisheye), against all of them: views moved 3 cm
        // aside and turned 5-25 degrees, with earlier frames filling unseen floor.
        for size in [224, 96] {
            let camera = jetbot_fisheye(size);
            let r = renderer(camera);
            let frames: Vec<_> = (0..8)
                .map(|i| frame(&r, Pose2::new(0.9, 0.3 + 0.04 * i as f32, FRAC_PI_2)))
                .collect();
            let fast = Synthesizer::new(Recording { camera, frames }, 0.14).unwrap();
            assert!(fast.interpolate_map);
            let exact = fast.clone().with_interpolated_map(false);
            let (mut a, mut b) = (vec![0u8; r.frame_len()], vec![0u8; r.frame_len()]);
            for turn in [5.0, -15.0, 25.0] {
                let pose = side_step(Pose2::new(0.9, 0.58, FRAC_PI_2), 0.03, turn);
                let fa = fast.synthesize_from(7, &pose, &mut a);
                let fb = exact.synthesize_from(7, &pose, &mut b);
                let diffs: Vec<u8> = a.iter().zip(&b).map(|(x, y)| x.abs_diff(*y)).collect();
                let over_2 = diffs.iter().filter(|&&d| d > 2).count() as f64 / diffs.len() as f64;
                let largest = diffs.iter().copied().max().unwrap_or(0);
                let p = psnr(&a, &b, &vec![true; a.len() / 3]);
                println!(
                    "{size} px, turned {turn} deg: {p:.1} dB, {:.3} % of values more than 2 \
                 levels apart, largest {largest}; coverage {:.4} / {:.4}",
                    100.0 * over_2,
                    fa.coverage,
                    fb.coverage
                );
                assert!(
                    p >= 45.0,
                    "turned {turn}: interpolated map {p} dB from exact"
                );
                assert!(
                    over_2 < 0.002,
                    "turned {turn}: {over_2} of values over 2 levels"
                );
                assert!((fa.coverage - fb.coverage).abs() < 0.002);
            }
        }
    }

    /// A frame rendered at a pose, synthesised again at that same pose: its PSNR against the
    /// frame and what `synthesize` says of the match.
    fn identity_synthesis(camera: CameraModel) -> (f64, SynthInfo) {
        let r = renderer(camera);
        let a = Pose2::new(0.9, 0.6, FRAC_PI_2 + 0.05);
        let f = frame(&r, a);
        let original = f.rgb.clone();
        let recording = Recording {
            camera,
            frames: vec![f],
        };
        let synth = Synthesizer::new(recording, 0.14).unwrap();
        let mut out = vec![0u8; r.frame_len()];
        let info = synth.synthesize(&a, &mut out);
        let all = vec![true; (camera.width * camera.height) as usize];
        (psnr(&out, &original, &all), info)
    }

    #[test]
    fn fisheye_synthesis_at_the_recorded_pose_reproduces_the_frame() {
        let (p, info) = identity_synthesis(jetbot_fisheye(224));
        println!(
            "fisheye identity PSNR {p:.2} dB, coverage {}",
            info.coverage
        );
        assert!(p >= 40.0, "identity PSNR {p}");
        assert!(info.coverage > 0.999, "coverage {}", info.coverage);
    }

    #[test]
    fn synthesis_at_the_recorded_pose_reproduces_the_frame() {
        let (p, info) = identity_synthesis(CameraModel::pinhole(224, 224));
        println!("identity PSNR {p:.2} dB, coverage {}", info.coverage);
        assert!(p >= 40.0, "identity PSNR {p}");
        assert_eq!(info.index, 0);
        assert!(info.valid);
        assert!(info.lateral_m.abs() < 1e-6 && info.heading_error.abs() < 1e-6);
        assert!(info.coverage > 0.999, "coverage {}", info.coverage);
    }

    #[test]
    fn valid_turns_false_beyond_half_road_or_the_heading_bound() {
        let camera = CameraModel {
            width: 32,
            height: 32,
            ..CameraModel::pinhole(224, 224)
        };
        let r = renderer(camera);
        let a = Pose2::new(0.9, 0.6, FRAC_PI_2);
        let synth = Synthesizer::new(
            Recording {
                camera,
                frames: vec![frame(&r, a)],
            },
            0.14,
        )
        .unwrap();
        let mut out = vec![0u8; r.frame_len()];
        let mut check = |lateral: f32, turn: f32| {
            let info = synth.synthesize_from(0, &side_step(a, lateral, turn), &mut out);
            assert!((info.lateral_m - lateral).abs() < 1e-4, "{info:?}");
            assert!(
                (info.heading_error - turn.to_radians()).abs() < 1e-4,
                "{info:?}"
            );
            info.valid
        };
        assert!(check(0.0, 0.0));
        assert!(check(0.13, 0.0));
        assert!(check(-0.13, 17.0));
        assert!(check(0.05, -17.9));
        assert!(!check(0.15, 0.0));
        assert!(!check(-0.15, 0.0));
        assert!(!check(0.0, 18.5));
        assert!(!check(0.0, -19.0));
        assert!(!check(0.2, 30.0));
        // Heading error wraps.
        let info = synth.synthesize_from(
            0,
            &Pose2::new(0.9, 0.6, FRAC_PI_2 + 2.0 * PI + 0.1),
            &mut out,
        );
        assert!((info.heading_error - 0.1).abs() < 1e-4 && info.valid);
        // A wider heading bound for a wide lens: 30 degrees.
        let wide = synth.clone().with_max_heading_deg(30.0).unwrap();
        assert!((wide.max_heading_error_rad() - 30f32.to_radians()).abs() < 1e-6);
        assert!(
            wide.synthesize_from(0, &side_step(a, 0.0, 25.0), &mut out)
                .valid
        );
        assert!(
            wide.synthesize_from(0, &side_step(a, 0.0, -29.5), &mut out)
                .valid
        );
        assert!(
            !wide
                .synthesize_from(0, &side_step(a, 0.0, 31.0), &mut out)
                .valid
        );
        assert!(
            !wide
                .synthesize_from(0, &side_step(a, 0.15, 0.0), &mut out)
                .valid
        );
        for bad in [0.0, -5.0, 91.0, f32::NAN] {
            let e = synth.clone().with_max_heading_deg(bad).unwrap_err();
            assert!(e.to_string().contains("sim.replay_max_heading_deg"), "{e}");
        }
    }

    #[test]
    fn nearest_picks_the_right_frame() {
        let camera = CameraModel {
            width: 16,
            height: 16,
            ..CameraModel::pinhole(224, 224)
        };
        let blank = |pose| RecordedFrame {
            pose,
            width: 16,
            height: 16,
            rgb: Arc::new(vec![0; 16 * 16 * 3]),
        };
        let frames = vec![
            blank(Pose2::new(0.9, 0.2, FRAC_PI_2)),
            blank(Pose2::new(0.9, 0.3, FRAC_PI_2)),
            blank(Pose2::new(0.9, 0.4, FRAC_PI_2)),
            // The same place driven the other way (e.g. the return lane of a loop).
            blank(Pose2::new(0.91, 0.31, -FRAC_PI_2)),
            blank(Pose2::new(1.5, 2.0, 0.0)),
        ];
        let synth = Synthesizer::new(Recording { camera, frames }, 0.14).unwrap();
        assert_eq!(synth.nearest(&Pose2::new(0.9, 0.21, FRAC_PI_2)), 0);
        assert_eq!(synth.nearest(&Pose2::new(0.92, 0.33, FRAC_PI_2 + 0.2)), 1);
        assert_eq!(synth.nearest(&Pose2::new(0.91, 0.31, -FRAC_PI_2 + 0.1)), 3);
        assert_eq!(synth.nearest(&Pose2::new(0.89, 0.37, FRAC_PI_2)), 2);
        assert_eq!(synth.nearest(&Pose2::new(1.4, 1.9, 0.3)), 4);
        // Heading wraps: -pi and pi face the same way.
        assert_eq!(synth.nearest(&Pose2::new(0.91, 0.31, 3.0 * FRAC_PI_2)), 3);
        let mut out = vec![0u8; 16 * 16 * 3];
        assert_eq!(
            synth
                .synthesize(&Pose2::new(0.9, 0.39, FRAC_PI_2), &mut out)
                .index,
            2
        );
    }

    #[test]
    fn new_rejects_bad_recordings() {
        let camera = CameraModel {
            width: 8,
            height: 8,
            ..CameraModel::pinhole(224, 224)
        };
        assert!(
            Synthesizer::new(
                Recording {
                    camera,
                    frames: vec![]
                },
                0.14
            )
            .is_err()
        );
        let wrong = RecordedFrame {
            pose: Pose2::default(),
            width: 16,
            height: 8,
            rgb: Arc::new(vec![0; 16 * 8 * 3]),
        };
        assert!(
            Synthesizer::new(
                Recording {
                    camera,
                    frames: vec![wrong]
                },
                0.14
            )
            .is_err()
        );
        let short = RecordedFrame {
            pose: Pose2::default(),
            width: 8,
            height: 8,
            rgb: Arc::new(vec![0; 10]),
        };
        assert!(
            Synthesizer::new(
                Recording {
                    camera,
                    frames: vec![short]
                },
                0.14
            )
            .is_err()
        );
        let ok = RecordedFrame {
            pose: Pose2::default(),
            width: 8,
            height: 8,
            rgb: Arc::new(vec![0; 8 * 8 * 3]),
        };
        assert!(
            Synthesizer::new(
                Recording {
                    camera,
                    frames: vec![ok.clone()]
                },
                0.0
            )
            .is_err()
        );
        assert!(
            Synthesizer::new(
                Recording {
                    camera,
                    frames: vec![ok]
                },
                0.14
            )
            .is_ok()
        );
    }

    /// Timings (one core) and example pictures in the temp dir; prints only. Run with
    /// `cargo test --release --lib sim::synth::tests::timing_and_pictures -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing_and_pictures() {
        use crate::sim::camera::LensKind;
        use std::time::Instant;
        let cases = [
            (LensKind::Pinhole, 224u32),
            (LensKind::Pinhole, 96),
            (LensKind::Fisheye, 224),
            (LensKind::Fisheye, 96),
        ];
        for (lens, size) in cases {
            let camera = CameraModel {
                width: size,
                height: size,
                lens,
                ..CameraModel::pinhole(224, 224)
            };
            let r = renderer(camera);
            let a = Pose2::new(0.9, 0.5, FRAC_PI_2);
            let synth = Synthesizer::new(
                Recording {
                    camera,
                    frames: vec![frame(&r, a)],
                },
                0.14,
            )
            .unwrap();
            let mut out = vec![0u8; r.frame_len()];
            let iters = if cfg!(debug_assertions) { 3 } else { 300 };
            let t = Instant::now();
            for k in 0..iters {
                let p = Pose2::new(0.9 + 0.0001 * k as f32, 0.5 + 0.001 * k as f32, FRAC_PI_2);
                r.render(&p, &mut out);
            }
            let render_ms = t.elapsed().as_secs_f64() * 1e3 / iters as f64;
            let t = Instant::now();
            for k in 0..iters {
                let p = side_step(a, 0.0001 * k as f32, 0.01 * k as f32);
                synth.synthesize(&p, &mut out);
            }
            let synth_ms = t.elapsed().as_secs_f64() * 1e3 / iters as f64;
            let effects = crate::sim::render::RenderEffects {
                brightness: 0.9,
                noise_std: 3.0,
                blur: true,
            };
            let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
            let t = Instant::now();
            for _ in 0..iters {
                crate::sim::render::apply_effects(size, size, &effects, &mut rng, &mut out);
            }
            let fx_ms = t.elapsed().as_secs_f64() * 1e3 / iters as f64;
            println!(
                "{lens:?} {size}x{size}: render {render_ms:.3} ms/frame, synthesize \
                 {synth_ms:.3} ms/frame, effects (blur + brightness + noise) {fx_ms:.3} ms/frame"
            );
            if lens == LensKind::Fisheye {
                if size == 224 {
                    let dir = std::env::temp_dir();
                    let b = side_step(a, 0.03, 5.0);
                    synth.synthesize(&b, &mut out);
                    write_png(
                        &dir.join("jetpilot_fisheye_synth_view.png"),
                        size,
                        size,
                        &out,
                    )
                    .unwrap();
                    r.render(&b, &mut out);
                    write_png(
                        &dir.join("jetpilot_fisheye_direct_view.png"),
                        size,
                        size,
                        &out,
                    )
                    .unwrap();
                }
                continue;
            }
            if size == 96 {
                r.render(&Pose2::new(0.9, 0.9, FRAC_PI_2), &mut out);
                let path = std::env::temp_dir().join("jetpilot_camera_view_96.png");
                write_png(&path, size, size, &out).unwrap();
            }
            if size == 224 {
                let dir = std::env::temp_dir();
                r.render(&Pose2::new(0.9, 0.9, FRAC_PI_2), &mut out);
                write_png(&dir.join("jetpilot_camera_view.png"), size, size, &out).unwrap();
                let b = side_step(a, 0.03, 5.0);
                synth.synthesize(&b, &mut out);
                write_png(&dir.join("jetpilot_synth_view.png"), size, size, &out).unwrap();
                r.render(&b, &mut out);
                write_png(&dir.join("jetpilot_direct_view.png"), size, size, &out).unwrap();
                let trace: Vec<Pose2> = (0..60)
                    .map(|k| {
                        let t = k as f32 / 59.0;
                        Pose2::new(0.9 + 0.02 * (6.0 * t).sin(), 0.25 + 1.1 * t, FRAC_PI_2)
                    })
                    .collect();
                let marks = [(trace[30], [220, 30, 30])];
                let (w, h, rgb) = top_down(r.texture(), &trace, &marks);
                write_png(&dir.join("jetpilot_top_down.png"), w, h, &rgb).unwrap();
            }
        }
    }
}
