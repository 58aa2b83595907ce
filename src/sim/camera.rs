//! The simulated JetBot camera: a pinhole or fisheye model of the wide CSI lens, mounted on
//! the robot, and the geometry that links its pixels with points on the flat mat.
//!
//! This module owns the camera's placement on the robot (height, forward offset, downward
//! tilt), its intrinsics (principal point at the image centre; a pinhole's focal length
//! from the horizontal field of view, a fisheye's from the diagonal one of the frame it
//! captured, which may have been scaled to another aspect ratio since), pixel <-> ground conversions, and the ground-plane
//! homography that `render` and `synth` build on.
//!
//! Conventions:
//! - World: metres on the mat, x right, y up, z out of the mat (the ground is z = 0).
//! - Robot frame: origin at the axle centre on the ground, `forward` along the heading,
//!   `left` 90 degrees counter-clockwise from it.
//! - Camera frame (computer-vision convention): x right, y down, z along the optical axis.
//! - Pixels: continuous coordinates `(u, v)` in pixels, `u` to the right, `v` down, with
//!   the top-left corner of the image at (0, 0); pixel `(i, j)` covers
//!   `[i, i + 1) x [j, j + 1)` and has its centre at `(i + 0.5, j + 0.5)`. The principal
//!   point is `(width / 2, height / 2)`.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::lens::Lens;
use super::{Pose2, SimError};

/// Ground points farther than this (horizontally, from the point under the camera) are
/// treated as "not on the ground": the renderer draws a wall there.
pub const MAX_GROUND_RANGE_M: f32 = 5.0;

/// The lens projection of a [`CameraModel`] (see [`super::lens`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LensKind {
    /// Straight lines stay straight; `hfov_deg` spans the image width.
    Pinhole,
    /// OpenCV's fisheye model (Kannala-Brandt): `r = f * theta_d`,
    /// `theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`, with
    /// `f` such that `fisheye_fov_deg` spans the image diagonal when `k = 0`. JetBot's
    /// IMX219 lens is sold as 160 degrees (diagonal).
    Fisheye,
}

/// A camera mounted on the robot, looking forward and pitched down.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraModel {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// `pinhole` or `fisheye`.
    pub lens: LensKind,
    /// Pinhole: horizontal field of view in degrees.
    pub hfov_deg: f32,
    /// Fisheye: field of view across the image diagonal, degrees (of the equidistant
    /// part: with `fisheye_k` all zero it is exact).
    pub fisheye_fov_deg: f32,
    /// Fisheye: OpenCV's k1..k4.
    pub fisheye_k: [f32; 4],
    /// Fisheye: width / height of the frame the camera captured before it was scaled to
    /// `width x height`; `fisheye_fov_deg` spans that frame's diagonal, and a degree spans
    /// different pixel counts across and down. JetBot captures 816x616 and scales it to
    /// 224x224: 1.3247. Unset: the frame was not rescaled (`width / height`).
    pub capture_aspect: Option<f32>,
    /// Height of the optical centre above the ground, metres.
    pub height_m: f32,
    /// Downward pitch of the optical axis below the horizontal, degrees.
    pub tilt_deg: f32,
    /// Distance of the optical centre ahead of the axle centre, metres.
    pub forward_m: f32,
}

impl Default for CameraModel {
    /// JetBot's camera at 224x224: [`CameraModel::jetbot`].
    fn default() -> Self {
        Self::jetbot(224, 224)
    }
}

/// The camera's placement in the world (f64 internally for accurate round trips).
#[derive(Debug, Clone, Copy)]
struct Extrinsics {
    /// Optical centre in world metres.
    centre: Vector3<f64>,
    /// Camera-to-world rotation; columns are the camera's right, down and forward axes.
    rot: Matrix3<f64>,
}

/// JetBot's capture aspect ratio: its camera class captures 816x616 (the IMX219's full
/// 4:3 field, binned) and scales it to 224x224.
pub const JETBOT_CAPTURE_ASPECT: f32 = 816.0 / 616.0;

/// Downward tilt of JetBot's camera, degrees, fitted to the real frames of
/// `../shared/realdata/jetbot_xy_mat/low_tilt` (docs/guides/simulator.md, "JetBot's camera,
/// fitted so far"):
/// the far wall's foot, a few metres away, lies 25-35 px below the top of the 224x224
/// frame, so the horizon is about 27 px down, `112 - 27 = 85` px above the centre. 160
/// degrees over the 816x616 capture's diagonal, scaled to 224 px down from 616, give
/// `fy = 2.324 px/degree`, and `85 / fy` is 36.6 degrees. (With square pixels, 1.98
/// px/degree, it was 43 degrees, and the bottom rows looked back under the camera.)
pub const JETBOT_TILT_DEG: f32 = 36.6;

impl CameraModel {
    /// JetBot's camera: the IMX219 with its 160 degree (diagonal) fisheye, equidistant
    /// (`k = 0`), its 4:3 capture scaled to `width x height` ([`JETBOT_CAPTURE_ASPECT`]),
    /// 10 cm up and 5 cm ahead of the axle, tilted down [`JETBOT_TILT_DEG`].
    pub fn jetbot(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            lens: LensKind::Fisheye,
            hfov_deg: 120.0,
            fisheye_fov_deg: 160.0,
            fisheye_k: [0.0; 4],
            capture_aspect: Some(JETBOT_CAPTURE_ASPECT),
            height_m: 0.10,
            tilt_deg: JETBOT_TILT_DEG,
            forward_m: 0.05,
        }
    }

    /// The simulator's first camera, before it was fitted to JetBot's: a 120 degree
    /// (horizontal) pinhole, 10 cm up, 5 cm ahead of the axle, tilted down 25 degrees.
    /// Straight lines stay straight and the ground maps to the image by a homography;
    /// the pinhole results in docs/results/ (the paper's experiment, `train-e2e.sh`) use it
    /// (`--camera pinhole`).
    pub fn pinhole(width: u32, height: u32) -> Self {
        Self {
            lens: LensKind::Pinhole,
            capture_aspect: None,
            tilt_deg: 25.0,
            ..Self::jetbot(width, height)
        }
    }

    /// A DonkeyCar's wide-angle camera (the Raspberry Pi camera with a 160 degree
    /// diagonal fisheye, equidistant, its 4:3 capture), 15 cm up and 8 cm ahead
    /// of the rear axle, tilted down 20 degrees. Set by eye on `donkey_tub_tarp`'s 160x120
    /// frames, not fitted: the horizon lies about 25 px above the centre, and 160 degrees
    /// over the 200 px diagonal is 1.25 px/degree, so the tilt is about 20 degrees; the
    /// height is a DonkeyCar's usual mount. A wrong height scales every distance (the speed
    /// calibration then absorbs it), a wrong tilt bends the floor.
    pub fn donkeycar(width: u32, height: u32) -> Self {
        Self {
            // The sensor's 4:3 (the frame is not rescaled at 160x120); set rather than left
            // unset so a config file can spell it out.
            capture_aspect: Some(4.0 / 3.0),
            height_m: 0.15,
            tilt_deg: 20.0,
            forward_m: 0.08,
            // JetBot's lens otherwise: a 160 degree equidistant fisheye.
            ..Self::jetbot(width, height)
        }
    }

    /// Checks that the model describes a usable camera.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |what: String| Err(SimError::Invalid(format!("camera: {what}")));
        if !(2..=8192).contains(&self.width) || !(2..=8192).contains(&self.height) {
            return bad(format!(
                "image size {}x{} must be 2..=8192 on each side",
                self.width, self.height
            ));
        }
        if !(self.hfov_deg.is_finite() && self.hfov_deg > 1.0 && self.hfov_deg < 170.0) {
            return bad(format!("hfov_deg {} must be in (1, 170)", self.hfov_deg));
        }
        if self.lens == LensKind::Fisheye {
            let fov = self.fisheye_fov_deg;
            if !(fov.is_finite() && fov > 1.0 && fov < 300.0) {
                return bad(format!("fisheye_fov_deg {fov} must be in (1, 300)"));
            }
            if let Some(a) = self.capture_aspect
                && !(a.is_finite() && (0.1..=10.0).contains(&a))
            {
                return bad(format!("capture_aspect {a} must be in [0.1, 10]"));
            }
            if self.fisheye_k.iter().any(|k| !k.is_finite()) {
                return bad(format!("fisheye_k {:?} must be finite", self.fisheye_k));
            }
            // Every pixel of the frame must have a ray: the polynomial must still rise at
            // the corners.
            let (w, h) = (self.width as f64, self.height as f64);
            if self.lens().unproject(0.0, 0.0).is_none() || self.lens().unproject(w, h).is_none() {
                return bad(format!(
                    "fisheye_k {:?}: the distortion polynomial turns back inside the image",
                    self.fisheye_k
                ));
            }
        }
        if !(self.height_m.is_finite() && self.height_m > 0.0) {
            return bad(format!("height_m {} must be > 0", self.height_m));
        }
        if !(self.tilt_deg.is_finite() && self.tilt_deg > -89.0 && self.tilt_deg < 89.0) {
            return bad(format!("tilt_deg {} must be in (-89, 89)", self.tilt_deg));
        }
        if !self.forward_m.is_finite() {
            return bad(format!("forward_m {} must be finite", self.forward_m));
        }
        Ok(())
    }

    /// The lens projection with this camera's intrinsics.
    pub fn lens(&self) -> Lens {
        let (w, h) = (self.width as f64, self.height as f64);
        match self.lens {
            LensKind::Pinhole => Lens::pinhole(self.hfov_deg as f64, w, h),
            LensKind::Fisheye => {
                // The captured frame, in units of this frame's width.
                let aspect = self.capture_aspect.map_or(w / h, f64::from);
                let captured_h = w / aspect;
                Lens::fisheye(
                    self.fisheye_fov_deg as f64,
                    w.hypot(captured_h),
                    w / 2.0,
                    h / 2.0,
                    self.fisheye_k.map(f64::from),
                )
                .with_v_scale(h / captured_h)
            }
        }
    }

    fn focal64(&self) -> f64 {
        match self.lens() {
            Lens::Pinhole { f, .. } | Lens::Fisheye { fx: f, .. } => f,
        }
    }

    /// Focal length in pixels (the same along u and v: square pixels).
    pub fn focal_px(&self) -> f32 {
        self.focal64() as f32
    }

    /// Principal point `(cu, cv)` in pixels: the image centre.
    pub fn principal_point(&self) -> (f32, f32) {
        (self.width as f32 / 2.0, self.height as f32 / 2.0)
    }

    /// Intrinsic matrix K: camera-frame point (x right, y down, z forward) -> pixel
    /// `(u w, v w, w)` with `w = z`.
    pub fn intrinsics(&self) -> Matrix3<f32> {
        self.intrinsics64().cast()
    }

    fn intrinsics64(&self) -> Matrix3<f64> {
        let f = self.focal64();
        let (cu, cv) = (self.width as f64 / 2.0, self.height as f64 / 2.0);
        Matrix3::new(f, 0.0, cu, 0.0, f, cv, 0.0, 0.0, 1.0)
    }

    /// Row `v` (pixels, may be fractional or negative) of the horizon in the centre
    /// column: the ground is seen only below it (`v > horizon_v`). The camera has no roll,
    /// so for a pinhole the horizon is this row; a fisheye bends it down towards the sides.
    pub fn horizon_v(&self) -> f32 {
        let (s, c) = (self.tilt_deg as f64).to_radians().sin_cos();
        // The level ray straight ahead, in the camera frame (y down, z along the axis).
        let level = Vector3::new(0.0, -s, c);
        match self.lens().project(level) {
            Some((_, v)) => v as f32,
            None => f32::NEG_INFINITY,
        }
    }

    /// Whether the ground-plane homographies describe this camera (a pinhole).
    pub fn has_homography(&self) -> bool {
        self.lens == LensKind::Pinhole
    }

    fn extrinsics(&self, pose: &Pose2) -> Extrinsics {
        let (s, c) = (pose.heading as f64).sin_cos();
        let fwd = Vector3::new(c, s, 0.0);
        let up = Vector3::new(0.0, 0.0, 1.0);
        let right = Vector3::new(s, -c, 0.0);
        let (st, ct) = (self.tilt_deg as f64).to_radians().sin_cos();
        // Optical axis pitched down by the tilt; "down" in the image completes the frame.
        let z_axis = fwd * ct - up * st;
        let y_axis = -fwd * st - up * ct;
        let centre = Vector3::new(
            pose.x as f64 + self.forward_m as f64 * c,
            pose.y as f64 + self.forward_m as f64 * s,
            self.height_m as f64,
        );
        Extrinsics {
            centre,
            rot: Matrix3::from_columns(&[right, y_axis, z_axis]),
        }
    }

    /// World position of the optical centre (metres) for a robot at `pose`.
    pub fn position(&self, pose: &Pose2) -> Vector3<f32> {
        self.extrinsics(pose).centre.cast()
    }

    /// Camera-to-world rotation for a robot at `pose`: its columns are the camera's right
    /// (image +u), down (image +v) and optical axis, in world coordinates. World to camera
    /// is `R^T (p - position)`.
    pub fn rotation(&self, pose: &Pose2) -> Matrix3<f32> {
        self.extrinsics(pose).rot.cast()
    }

    fn pixel_to_ground64(&self, pose: &Pose2, u: f32, v: f32) -> Option<(f64, f64)> {
        let e = self.extrinsics(pose);
        let d_cam = self.lens().unproject(u as f64, v as f64)?;
        let d = e.rot * d_cam;
        // At or above the horizon, or NaN input.
        if d.z.is_nan() || d.z >= -1e-12 {
            return None;
        }
        let s = -e.centre.z / d.z;
        let (dx, dy) = (s * d.x, s * d.y);
        if dx * dx + dy * dy > (MAX_GROUND_RANGE_M as f64).powi(2) {
            return None;
        }
        Some((e.centre.x + dx, e.centre.y + dy))
    }

    /// The ground point (world metres) seen at pixel `(u, v)` from a robot at `pose`.
    /// `None` at or above the horizon, or farther than [`MAX_GROUND_RANGE_M`] from the
    /// point under the camera.
    pub fn pixel_to_ground(&self, pose: &Pose2, u: f32, v: f32) -> Option<(f32, f32)> {
        self.pixel_to_ground64(pose, u, v)
            .map(|(x, y)| (x as f32, y as f32))
    }

    /// The pixel `(u, v)` where the ground point `(x, y)` (world metres) appears from a
    /// robot at `pose`. `None` when the point is behind the camera (or on its image
    /// plane). The pixel may lie outside the image.
    pub fn ground_to_pixel(&self, pose: &Pose2, x: f32, y: f32) -> Option<(f32, f32)> {
        let e = self.extrinsics(pose);
        let p = e.rot.transpose() * (Vector3::new(x as f64, y as f64, 0.0) - e.centre);
        if p.z.is_nan() || p.z <= 1e-9 {
            return None;
        }
        let (u, v) = self.lens().project(p)?;
        Some((u as f32, v as f32))
    }

    /// The ground point in the robot frame, `(forward, left)` metres from the axle
    /// centre, seen at pixel `(u, v)`. It does not depend on the pose (flat ground, fixed
    /// mount), so per-pixel tables can be built once. Same `None` cases as
    /// [`Self::pixel_to_ground`].
    pub fn pixel_to_robot_ground(&self, u: f32, v: f32) -> Option<(f32, f32)> {
        self.pixel_to_ground(&Pose2::default(), u, v)
    }

    fn ground_to_ray64(&self, pose: &Pose2) -> Matrix3<f64> {
        let e = self.extrinsics(pose);
        let c = e.centre;
        // [e1 | e2 | -C]: ground (x, y, 1) -> world point minus the optical centre.
        let lift = Matrix3::new(1.0, 0.0, -c.x, 0.0, 1.0, -c.y, 0.0, 0.0, -c.z);
        e.rot.transpose() * lift
    }

    fn homography64(&self, pose: &Pose2) -> Matrix3<f64> {
        self.intrinsics64() * self.ground_to_ray64(pose)
    }

    /// `R^T [e1 | e2 | -C]` for a robot at `pose`: maps the homogeneous ground point
    /// `(x, y, 1)` (world metres) to the camera-frame vector from the optical centre to that
    /// point (metres, exact, not up to scale). Any lens projects it to the pixel, so this
    /// is what fisheye synthesis re-projects through; for a pinhole,
    /// [`Self::ground_homography`] is `K` times it.
    pub fn ground_to_ray(&self, pose: &Pose2) -> Matrix3<f32> {
        self.ground_to_ray64(pose).cast()
    }

    /// Ground-plane homography `H = K R^T [e1 | e2 | -C]` for a robot at `pose` (a pinhole's
    /// only: see [`Self::has_homography`]; a fisheye's pixels are not a homography of the
    /// ground). Maps the
    /// homogeneous ground point `(x, y, 1)` (world metres) to the pixel `(u w, v w, w)`,
    /// where `w` is the depth along the optical axis (metres; `w <= 0`: behind the camera).
    pub fn ground_homography(&self, pose: &Pose2) -> Matrix3<f32> {
        self.homography64(pose).cast()
    }

    /// Inverse of [`Self::ground_homography`]: maps the homogeneous pixel `(u, v, 1)` to
    /// `(x s, y s, s)` on the ground plane. Only pixels below the horizon give `s > 0`
    /// (a point in front of the camera). Always exists for a camera above the ground.
    pub fn ground_homography_inverse(&self, pose: &Pose2) -> Matrix3<f32> {
        let e = self.extrinsics(pose);
        let c = e.centre;
        // [e1 | e2 | -C]^-1 in closed form (c.z > 0 is checked by `validate`).
        let lift_inv = Matrix3::new(
            1.0,
            0.0,
            -c.x / c.z,
            0.0,
            1.0,
            -c.y / c.z,
            0.0,
            0.0,
            -1.0 / c.z,
        );
        let f = self.focal64();
        let (cu, cv) = (self.width as f64 / 2.0, self.height as f64 / 2.0);
        let k_inv = Matrix3::new(1.0 / f, 0.0, -cu / f, 0.0, 1.0 / f, -cv / f, 0.0, 0.0, 1.0);
        (lift_inv * e.rot * k_inv).cast()
    }

    /// Homography from the robot-frame ground point `(forward, left, 1)` to the pixel
    /// `(u w, v w, w)`; pose-independent.
    pub fn robot_ground_homography(&self) -> Matrix3<f32> {
        self.ground_homography(&Pose2::default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(h: &Matrix3<f32>, x: f32, y: f32) -> (f32, f32, f32) {
        let p = h * Vector3::new(x, y, 1.0);
        (p.x, p.y, p.z)
    }

    #[test]
    fn round_trip_pixel_ground_pixel() {
        let cam = CameraModel::pinhole(224, 224);
        cam.validate().unwrap();
        let hv = cam.horizon_v();
        let poses = [
            Pose2::new(0.0, 0.0, 0.0),
            Pose2::new(0.9, 1.3, 1.1),
            Pose2::new(1.5, 2.2, -2.7),
        ];
        let mut checked = 0;
        for pose in &poses {
            let mut v = hv.ceil() + 0.5;
            while v < cam.height as f32 {
                let mut u = 0.5;
                while u < cam.width as f32 {
                    if let Some((x, y)) = cam.pixel_to_ground(pose, u, v) {
                        let (u2, v2) = cam.ground_to_pixel(pose, x, y).unwrap();
                        assert!(
                            (u2 - u).abs() < 1e-3 && (v2 - v).abs() < 1e-3,
                            "({u}, {v}) -> ({x}, {y}) -> ({u2}, {v2})"
                        );
                        // The homography agrees with the direct projection.
                        let (a, b, w) = apply(&cam.ground_homography(pose), x, y);
                        assert!(w > 0.0);
                        assert!((a / w - u).abs() < 2e-3 && (b / w - v).abs() < 2e-3);
                        checked += 1;
                    }
                    u += 7.0;
                }
                v += 3.0;
            }
        }
        assert!(checked > 1000, "only {checked} pixels checked");
    }

    #[test]
    fn homography_inverse_is_inverse() {
        let cam = CameraModel::pinhole(224, 224);
        let pose = Pose2::new(0.4, 1.7, 2.0);
        let h = cam.ground_homography(&pose);
        let hi = cam.ground_homography_inverse(&pose);
        for (x, y) in [(0.4, 2.0), (0.1, 1.9), (0.6, 2.5), (-0.5, 3.0)] {
            let (a, b, w) = apply(&h, x, y);
            let (x2, y2, s) = apply(&hi, a / w, b / w);
            assert!((x2 / s - x).abs() < 1e-4 && (y2 / s - y).abs() < 1e-4);
        }
        // Pixel -> ground through the inverse homography matches the ray intersection.
        let (u, v) = (150.5, 180.5);
        let (gx, gy, s) = apply(&hi, u, v);
        assert!(s > 0.0);
        let (x, y) = cam.pixel_to_ground(&pose, u, v).unwrap();
        assert!((gx / s - x).abs() < 1e-4 && (gy / s - y).abs() < 1e-4);
    }

    #[test]
    fn centre_column_looks_straight_ahead() {
        let cam = CameraModel::pinhole(224, 224);
        let (cu, _) = cam.principal_point();
        let pose = Pose2::new(1.0, 1.0, 0.7);
        let (s, c) = pose.heading.sin_cos();
        for v in [100.5f32, 130.0, 170.0, 223.5] {
            let (x, y) = cam.pixel_to_ground(&pose, cu, v).unwrap();
            let (dx, dy) = (x - pose.x, y - pose.y);
            let lateral = -s * dx + c * dy;
            let forward = c * dx + s * dy;
            assert!(lateral.abs() < 1e-5, "v {v}: lateral {lateral}");
            assert!(forward > cam.forward_m, "v {v}: forward {forward}");
        }
        // Left of the centre column sees ground to the left.
        let (f, l) = cam.pixel_to_robot_ground(cu - 40.0, 150.0).unwrap();
        assert!(f > 0.0 && l > 0.0);
    }

    #[test]
    fn ground_ahead_projects_below_the_centre_and_horizon() {
        let cam = CameraModel::pinhole(224, 224);
        let pose = Pose2::new(0.5, 0.5, std::f32::consts::FRAC_PI_2);
        let (cu, cv) = cam.principal_point();
        let hv = cam.horizon_v();
        // The optical axis meets the ground height / tan(tilt) ahead of the camera
        // (0.214 m with the defaults): that point is the image centre, nearer ground lies
        // below it, farther ground above it but still below the horizon.
        let axis = cam.height_m / cam.tilt_deg.to_radians().tan();
        let y_axis = 0.5 + cam.forward_m + axis;
        let (u, v) = cam.ground_to_pixel(&pose, 0.5, y_axis).unwrap();
        assert!((u - cu).abs() < 1e-3 && (v - cv).abs() < 1e-3, "({u}, {v})");
        let (u, v) = cam.ground_to_pixel(&pose, 0.5, 0.65).unwrap();
        assert!((u - cu).abs() < 1e-3, "u {u}");
        assert!(
            v > cv,
            "0.15 m ahead: v {v} should be below the centre row {cv}"
        );
        let (_, v) = cam.ground_to_pixel(&pose, 0.5, 0.8).unwrap();
        assert!(
            v < cv && v > hv,
            "0.3 m ahead: v {v} between horizon {hv} and centre"
        );
        // Without tilt, any ground point ahead is below the centre, which is the horizon.
        let level = CameraModel {
            tilt_deg: 0.0,
            ..cam
        };
        let (_, v) = level.ground_to_pixel(&pose, 0.5, 0.8).unwrap();
        assert!(v > cv, "untilted, 0.3 m ahead: v {v}");
        assert!((level.horizon_v() - cv).abs() < 1e-4);
        // Tilting down moves the horizon up; nothing is seen above it.
        assert!(hv < cv);
        assert!(cam.pixel_to_ground(&pose, cu, hv - 1.0).is_none());
        // Behind the camera.
        assert!(cam.ground_to_pixel(&pose, 0.5, 0.2).is_none());
        // Too far.
        assert!(cam.pixel_to_ground(&pose, cu, hv + 0.01).is_none());
    }

    #[test]
    fn the_jetbot_camera_puts_the_horizon_27_px_down_and_sees_80_degrees_at_the_corners() {
        let cam = CameraModel::jetbot(224, 224);
        cam.validate().unwrap();
        // The 816x616 capture in units of the 224 px width: 224 x 169.10, diagonal 280.66
        // px over 160 degrees: fx = 140.33 px / 1.39626 rad = 100.50 px/rad (1.7541
        // px/degree); scaled 616 -> 224 down: fy = 1.32468 fx = 133.14 px/rad (2.3237
        // px/degree). The horizon: 112 - 36.6 * 2.3237 = 26.95.
        assert!(
            (cam.horizon_v() - 26.95).abs() < 0.02,
            "{}",
            cam.horizon_v()
        );
        // The corner is the capture's corner: 80 degrees off axis.
        let corner = cam.lens().off_axis_deg(0.0, 0.0).unwrap();
        assert!((corner - 80.0).abs() < 1e-6, "{corner}");
        // Half way out along the centre row, 56 px: 56 / 1.7541 = 31.92 degrees; half way
        // down the centre column: 56 / 2.3237 = 24.10 degrees.
        let across = cam.lens().off_axis_deg(168.0, 112.0).unwrap();
        assert!((across - 31.925).abs() < 1e-2, "{across}");
        let down = cam.lens().off_axis_deg(112.0, 168.0).unwrap();
        assert!((down - 24.100).abs() < 1e-2, "{down}");
        // The bottom centre sees the ground 36.6 + 48.20 = 84.80 degrees below the
        // horizontal: 0.10 m / tan(84.80) = 9.1 mm ahead of the lens, 5 cm ahead of the axle.
        let (f, l) = cam.pixel_to_robot_ground(112.0, 224.0).unwrap();
        let expect = 0.05 + 0.10 / 84.80f32.to_radians().tan();
        assert!(
            (f - expect).abs() < 2e-4 && l.abs() < 1e-4,
            "{f} {l} vs {expect}"
        );
        // Unset, the frame keeps its aspect: square pixels, as before.
        let square = CameraModel {
            capture_aspect: None,
            ..cam
        };
        let mid = square.lens().off_axis_deg(168.0, 112.0).unwrap();
        assert!((mid - 56.0 / 1.979_899).abs() < 1e-3, "{mid}");
        let bad = CameraModel {
            capture_aspect: Some(0.0),
            ..cam
        };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn validate_rejects_nonsense() {
        let cam = CameraModel {
            height_m: 0.0,
            ..CameraModel::pinhole(224, 224)
        };
        assert!(cam.validate().is_err());
        let cam = CameraModel {
            hfov_deg: 180.0,
            ..CameraModel::pinhole(224, 224)
        };
        assert!(cam.validate().is_err());
        // Keys left out are JetBot's camera.
        let cam: CameraModel = serde_json::from_str(r#"{"width": 96, "height": 96}"#).unwrap();
        assert_eq!(cam, CameraModel::jetbot(96, 96));
        assert_eq!(cam.lens, LensKind::Fisheye);
        assert_eq!(cam.tilt_deg, JETBOT_TILT_DEG);
        assert!(serde_json::from_str::<CameraModel>(r#"{"fov": 3}"#).is_err());
    }

    fn jetbot_fisheye() -> CameraModel {
        CameraModel {
            lens: LensKind::Fisheye,
            ..CameraModel::pinhole(224, 224)
        }
    }

    #[test]
    fn fisheye_pixels_round_trip_through_the_ground() {
        let cam = jetbot_fisheye();
        cam.validate().unwrap();
        let pose = Pose2::new(0.9, 1.3, 1.1);
        let mut checked = 0;
        for j in 0..cam.height {
            for i in (0..cam.width).step_by(5) {
                let (u, v) = (i as f32 + 0.5, j as f32 + 0.5);
                if let Some((x, y)) = cam.pixel_to_ground(&pose, u, v) {
                    let (u2, v2) = cam.ground_to_pixel(&pose, x, y).unwrap();
                    assert!(
                        (u2 - u).abs() < 1e-2 && (v2 - v).abs() < 1e-2,
                        "({u}, {v}) -> ({x}, {y}) -> ({u2}, {v2})"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 3000, "only {checked} pixels checked");
        assert!(!cam.has_homography() && CameraModel::pinhole(224, 224).has_homography());
    }

    #[test]
    fn the_fisheye_sees_more_ground_and_bends_its_horizon() {
        let (pin, fish) = (CameraModel::pinhole(224, 224), jetbot_fisheye());
        // 160 degrees over the 316.8 px diagonal: f = 113.44 px; the level ray is 25
        // degrees (0.4363 rad) above the axis: 112 - 113.44 * 0.4363 = 62.50.
        assert!(
            (fish.horizon_v() - 62.50).abs() < 0.01,
            "{}",
            fish.horizon_v()
        );
        // The horizon curves down towards the sides: the top-left corner looks at the sky,
        // but the left edge at the centre-column horizon row sees no ground either.
        let pose = Pose2::default();
        assert!(fish.pixel_to_ground(&pose, 0.5, 0.5).is_none());
        assert!(
            fish.pixel_to_ground(&pose, 0.5, fish.horizon_v() + 1.0)
                .is_none()
        );
        // Near the bottom corners the fisheye sees ground far to the side, wider than the
        // pinhole.
        let (_, l_pin) = pin.pixel_to_robot_ground(0.5, 223.5).unwrap();
        let (_, l_fish) = fish.pixel_to_robot_ground(0.5, 223.5).unwrap();
        assert!(
            l_fish > l_pin,
            "fisheye {l_fish} m vs pinhole {l_pin} m to the left"
        );
        // A fisheye whose polynomial turns back inside the image is refused.
        let bad = CameraModel {
            fisheye_k: [-0.5, 0.0, 0.0, 0.0],
            ..jetbot_fisheye()
        };
        assert!(bad.validate().is_err());
        let cam: CameraModel =
            serde_json::from_str(r#"{"lens": "fisheye", "fisheye_k": [0.01, 0, 0, 0]}"#).unwrap();
        assert_eq!((cam.lens, cam.fisheye_k[0]), (LensKind::Fisheye, 0.01));
    }
}
