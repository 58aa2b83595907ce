//! Lens projections: a camera-frame ray <-> a pixel, for the pinhole model and OpenCV's
//! fisheye model (Kannala-Brandt: equidistant projection with a k1..k4 polynomial), the
//! model of JetBot's ~160 degree IMX219 lens.
//!
//! Camera frame as in [`super::camera`]: x right, y down, z along the optical axis.
//! Pixels: continuous `(u, v)`, principal point `(cu, cv)`, focal lengths in pixels. A
//! fisheye may have different focal lengths along `u` and `v` (`fx`, `fy`), as OpenCV's
//! camera matrix allows: JetBot's camera captures 816x616 (4:3) and scales it to 224x224,
//! so a degree spans fewer pixels across than down.
//!
//! ```text
//! pinhole:  r = f * tan(theta)
//! fisheye:  theta_d = theta * (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
//!           r = f * theta_d
//! ```
//!
//! where `theta` is the angle between the ray and the optical axis and `r` the pixel
//! distance from the principal point. The fisheye model also images rays at 90 degrees and
//! beyond, which a pinhole cannot.
//!
//! `CameraModel` (`[sim.camera] lens`) projects through it, and so the renderer's per-pixel
//! tables and replayed-frame synthesis do (`synth` has a float32 copy of `project` for its
//! per-pixel loop).

use nalgebra::Vector3;

/// A lens projection with its intrinsics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lens {
    Pinhole {
        f: f64,
        cu: f64,
        cv: f64,
    },
    /// OpenCV's `cv::fisheye` model.
    Fisheye {
        fx: f64,
        fy: f64,
        cu: f64,
        cv: f64,
        k: [f64; 4],
    },
}

/// Newton iterations in [`Lens::unproject`]: quadratic convergence reaches float64
/// precision from `theta_d` in a handful.
const NEWTON_STEPS: usize = 20;

impl Lens {
    /// An equidistant fisheye (`k = 0`) whose `fov_deg` spans `span_px` pixels across the
    /// principal point: e.g. JetBot's 160 degree diagonal over a 224x224 frame's diagonal.
    pub fn equidistant(fov_deg: f64, span_px: f64, cu: f64, cv: f64) -> Self {
        Self::fisheye(fov_deg, span_px, cu, cv, [0.0; 4])
    }

    /// A fisheye with distortion `k` whose equidistant part (`k = 0`) spans `fov_deg` over
    /// `span_px` pixels.
    pub fn fisheye(fov_deg: f64, span_px: f64, cu: f64, cv: f64, k: [f64; 4]) -> Self {
        let f = (span_px / 2.0) / (fov_deg / 2.0).to_radians();
        Self::Fisheye {
            fx: f,
            fy: f,
            cu,
            cv,
            k,
        }
    }

    /// This fisheye with its `v` axis scaled by `sy` against `u` (`fy = sy * fx`): a frame
    /// scaled to a different aspect ratio after capture. A pinhole is returned unchanged.
    pub fn with_v_scale(self, sy: f64) -> Self {
        match self {
            Self::Fisheye { fx, cu, cv, k, .. } => Self::Fisheye {
                fx,
                fy: fx * sy,
                cu,
                cv,
                k,
            },
            pinhole => pinhole,
        }
    }

    /// A pinhole whose horizontal field of view `hfov_deg` spans `width` pixels.
    pub fn pinhole(hfov_deg: f64, width: f64, height: f64) -> Self {
        Self::Pinhole {
            f: (width / 2.0) / (hfov_deg / 2.0).to_radians().tan(),
            cu: width / 2.0,
            cv: height / 2.0,
        }
    }

    /// `(fx, fy, cu, cv)`.
    fn intrinsics(&self) -> (f64, f64, f64, f64) {
        match *self {
            Self::Pinhole { f, cu, cv } => (f, f, cu, cv),
            Self::Fisheye { fx, fy, cu, cv, .. } => (fx, fy, cu, cv),
        }
    }

    /// `theta` -> distorted angle `theta_d` (fisheye) or `tan(theta)` (pinhole).
    fn radial(&self, theta: f64) -> f64 {
        match self {
            Self::Pinhole { .. } => theta.tan(),
            Self::Fisheye { k, .. } => {
                let t2 = theta * theta;
                theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
            }
        }
    }

    fn radial_derivative(&self, theta: f64) -> f64 {
        match self {
            Self::Pinhole { .. } => 1.0 / theta.cos().powi(2),
            Self::Fisheye { k, .. } => {
                let t2 = theta * theta;
                1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))
            }
        }
    }

    /// The pixel a camera-frame ray (any length) lands on; `None` behind a pinhole, or
    /// beyond where the fisheye polynomial stops increasing.
    pub fn project(&self, ray: Vector3<f64>) -> Option<(f64, f64)> {
        let (fx, fy, cu, cv) = self.intrinsics();
        let rxy = ray.x.hypot(ray.y);
        let theta = rxy.atan2(ray.z);
        if let Self::Pinhole { .. } = self
            && ray.z <= 0.0
        {
            return None;
        }
        if self.radial_derivative(theta) <= 0.0 {
            return None;
        }
        if rxy == 0.0 {
            return Some((cu, cv));
        }
        let r = self.radial(theta) / rxy;
        Some((cu + fx * r * ray.x, cv + fy * r * ray.y))
    }

    /// The unit camera-frame ray through pixel `(u, v)`; `None` where no ray maps there.
    pub fn unproject(&self, u: f64, v: f64) -> Option<Vector3<f64>> {
        let (fx, fy, cu, cv) = self.intrinsics();
        let (x, y) = ((u - cu) / fx, (v - cv) / fy);
        let rd = x.hypot(y);
        if rd == 0.0 {
            return Some(Vector3::new(0.0, 0.0, 1.0));
        }
        let theta = match self {
            Self::Pinhole { .. } => rd.atan(),
            Self::Fisheye { .. } => {
                // Solve radial(theta) = rd by Newton from the equidistant guess.
                let mut t = rd;
                for _ in 0..NEWTON_STEPS {
                    let d = self.radial_derivative(t);
                    if d <= 0.0 {
                        return None;
                    }
                    let step = (self.radial(t) - rd) / d;
                    t -= step;
                    if step.abs() < 1e-15 {
                        break;
                    }
                }
                if !(t.is_finite() && t >= 0.0 && (self.radial(t) - rd).abs() < 1e-9) {
                    return None;
                }
                t
            }
        };
        let (s, c) = theta.sin_cos();
        Some(Vector3::new(s * x / rd, s * y / rd, c))
    }

    /// The angle from the optical axis of the ray through `(u, v)`, degrees.
    pub fn off_axis_deg(&self, u: f64, v: f64) -> Option<f64> {
        self.unproject(u, v)
            .map(|r| r.z.clamp(-1.0, 1.0).acos().to_degrees())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fisheye coefficients of the magnitude OpenCV calibrations give wide lenses.
    fn calibrated() -> Lens {
        Lens::Fisheye {
            fx: 110.0,
            fy: 110.0,
            cu: 112.0,
            cv: 112.0,
            k: [-0.03, 0.01, -0.004, 0.0005],
        }
    }

    #[test]
    fn pixels_round_trip_through_rays_within_a_hundredth_of_a_pixel() {
        for lens in [
            Lens::pinhole(120.0, 224.0, 224.0),
            Lens::equidistant(160.0, 224.0 * 2f64.sqrt(), 112.0, 112.0),
            calibrated(),
            calibrated().with_v_scale(816.0 / 616.0),
        ] {
            let mut worst = 0.0f64;
            for j in 0..=28 {
                for i in 0..=28 {
                    let (u, v) = (i as f64 * 8.0, j as f64 * 8.0);
                    let ray = lens
                        .unproject(u, v)
                        .expect("every pixel of the frame has a ray");
                    let (u2, v2) = lens.project(ray * 3.7).unwrap();
                    worst = worst.max((u2 - u).hypot(v2 - v));
                }
            }
            assert!(worst < 0.01, "{lens:?}: {worst} px");
        }
    }

    #[test]
    fn the_jetbot_lens_sees_80_degrees_off_axis_at_the_frame_corners() {
        // 160 degrees across the 224x224 frame's diagonal: f = 158.39 px / 1.3963 rad =
        // 113.44 px; the corner is 80 degrees off axis, the edge midpoint
        // 112 / 113.44 rad = 56.57 degrees, a pixel 10 px from the centre 5.05 degrees.
        let lens = Lens::equidistant(160.0, 224.0 * 2f64.sqrt(), 112.0, 112.0);
        let at = |u: f64, v: f64| lens.off_axis_deg(u, v).unwrap();
        assert!((at(0.0, 0.0) - 80.0).abs() < 1e-9);
        assert!(
            (at(224.0, 112.0) - 56.569).abs() < 1e-3,
            "{}",
            at(224.0, 112.0)
        );
        assert!(
            (at(122.0, 112.0) - 5.0508).abs() < 1e-3,
            "{}",
            at(122.0, 112.0)
        );
        // A ray 90 degrees off axis (sideways) still lands in the image plane's extension,
        // where a pinhole has no pixel.
        let side = Vector3::new(1.0, 0.0, 0.0);
        let (u, _) = lens.project(side).unwrap();
        assert!(
            (u - (112.0 + 113.44 * std::f64::consts::FRAC_PI_2)).abs() < 0.01,
            "{u}"
        );
        assert_eq!(Lens::pinhole(120.0, 224.0, 224.0).project(side), None);
    }

    #[test]
    fn a_pinhole_maps_its_field_of_view_to_the_frame_edges() {
        let lens = Lens::pinhole(120.0, 224.0, 224.0);
        assert!((lens.off_axis_deg(0.0, 112.0).unwrap() - 60.0).abs() < 1e-9);
        // Straight lines stay straight: three collinear ground points project collinear.
        let p = |x: f64| lens.project(Vector3::new(x, 0.5, 2.0 + x)).unwrap();
        let (a, b, c) = (p(-1.0), p(0.0), p(1.5));
        let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        assert!(cross.abs() < 1e-9, "{cross}");
        // The fisheye bends the same line (barrel distortion).
        let fish = Lens::equidistant(160.0, 224.0 * 2f64.sqrt(), 112.0, 112.0);
        let q = |x: f64| fish.project(Vector3::new(x, 0.5, 2.0 + x)).unwrap();
        let (a, b, c) = (q(-1.0), q(0.0), q(1.5));
        let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        assert!(cross.abs() > 1.0, "{cross}");
    }
}
