//! The scripted expert: pure pursuit on the driving lane's centre line, with tunable
//! noise. It stands in for the human with the gamepad: its wheel commands go through the
//! same motor path as the daemon's, and its labels are what a JetBot user would give: the
//! target point it is steering to, as a pixel in the camera image.

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::Pose2;
use super::camera::CameraModel;
use super::robot::RobotParams;
use super::track::Track;
use crate::control::WheelCommand;

/// Pure-pursuit settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExpertParams {
    /// Distance along the lane to the pursued point, metres.
    pub lookahead_m: f32,
    /// Cruise speed on straights, m/s.
    pub speed_mps: f32,
    /// Lateral acceleration limit that slows it down in corners, m/s^2.
    pub max_lateral_accel: f32,
    /// Standard deviation of noise added to the path curvature, 1/m (0: a perfect driver).
    pub curvature_noise: f32,
}

impl Default for ExpertParams {
    fn default() -> Self {
        Self {
            lookahead_m: 0.22,
            speed_mps: 0.20,
            max_lateral_accel: 0.25,
            curvature_noise: 0.0,
        }
    }
}

/// What the expert does at one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExpertAction {
    pub wheels: WheelCommand,
    /// The pursued point on the mat.
    pub target: (f32, f32),
    /// Curvature of the commanded arc, 1/m (positive turns left).
    pub curvature: f32,
    /// Commanded forward speed, m/s.
    pub speed: f32,
}

/// Wheel duty for a wheel speed, inverting the motor model (dead band included).
pub fn duty_for_speed(v: f32, robot: &RobotParams) -> f32 {
    let m = &robot.motor;
    if v.abs() < 1e-6 {
        return 0.0;
    }
    let d = m.dead_band + (1.0 - m.dead_band) * (v.abs() / m.top_speed_mps);
    (d.min(1.0)).copysign(v)
}

/// The pure-pursuit command from `pose` on `track`.
pub fn pursue(
    track: &Track,
    pose: &Pose2,
    robot: &RobotParams,
    p: &ExpertParams,
    rng: &mut impl Rng,
) -> ExpertAction {
    let q = track.query(pose.x, pose.y);
    let goal = track.lane_pose_at(q.s + p.lookahead_m);
    // The goal in the robot frame.
    let (dx, dy) = (goal.x - pose.x, goal.y - pose.y);
    let (s, c) = pose.heading.sin_cos();
    let fwd = c * dx + s * dy;
    let left = -s * dx + c * dy;
    let dist2 = (fwd * fwd + left * left).max(1e-6);
    // Pure pursuit: the arc through the goal has curvature 2 * lateral / distance^2.
    let mut kappa = 2.0 * left / dist2;
    if p.curvature_noise > 0.0
        && let Ok(n) = Normal::new(0.0, p.curvature_noise)
    {
        kappa += n.sample(rng);
    }
    let v = p
        .speed_mps
        .min((p.max_lateral_accel / kappa.abs().max(1e-6)).sqrt())
        .max(0.05);
    let half = robot.wheel_base_m / 2.0;
    let (vl, vr) = (v * (1.0 - kappa * half), v * (1.0 + kappa * half));
    ExpertAction {
        wheels: WheelCommand::new(duty_for_speed(vl, robot), duty_for_speed(vr, robot)),
        target: (goal.x, goal.y),
        curvature: kappa,
        speed: v,
    }
}

/// JetBot's label for a frame: the target point as a pixel, then
/// `x = (px - W/2) / (W/2)`, `y = (py - H/2) / (H/2)`. `None` when the point is not in view.
pub fn target_label(camera: &CameraModel, pose: &Pose2, target: (f32, f32)) -> Option<(f32, f32)> {
    let (u, v) = camera.ground_to_pixel(pose, target.0, target.1)?;
    let (hw, hh) = (camera.width as f32 / 2.0, camera.height as f32 / 2.0);
    let (x, y) = ((u - hw) / hw, (v - hh) / hh);
    (x.abs() <= 1.0 && y.abs() <= 1.0).then_some((x, y))
}
