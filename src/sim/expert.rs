//! The scripted expert: pure pursuit on the driving lane's centre line, with tunable
//! noise. It stands in for the human with the gamepad: its wheel commands go through the
//! same motor path as the daemon's, and its labels are what a JetBot user would give: the
//! target point it is steering to, as a pixel in the camera image.
//!
//! Optional deliberate swerves ([`Swerves`]) make recovery demonstrations, the way JetBot
//! and DonkeyCar users are told to collect them: now and then the driver swerves off the
//! lane centre with recording paused, then steers back while recording. The swerve steps
//! are marked ([`ExpertAction::swerving`]) so the recorder leaves them out; the recorded
//! labels are the expert's own corrections.

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::Pose2;
use super::camera::CameraModel;
use super::odometry::ackermann::CarParams;
use super::robot::RobotParams;
use super::track::Track;
use crate::control::{Mixing, WheelCommand};

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
    /// Mean seconds between deliberate swerves (0: none). Each next swerve comes after
    /// 0.5x to 1.5x this, uniformly drawn.
    pub swerve_every_s: f32,
    /// How long one swerve lasts, seconds.
    pub swerve_s: f32,
    /// Curvature added during a swerve, 1/m, to the left or right at random.
    pub swerve_curvature: f32,
}

impl Default for ExpertParams {
    fn default() -> Self {
        Self {
            lookahead_m: 0.22,
            speed_mps: 0.20,
            max_lateral_accel: 0.25,
            curvature_noise: 0.0,
            swerve_every_s: 0.0,
            swerve_s: 0.5,
            swerve_curvature: 3.0,
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
    /// A deliberate swerve (not a demonstration of good driving: recorders skip it).
    pub swerving: bool,
}

/// When the expert swerves: a timer per drive, drawn from the pilot's RNG (nothing is
/// drawn while swerves are off, so other drives stay bit for bit the same).
#[derive(Debug, Clone, Default)]
pub struct Swerves {
    /// Seconds left in the current swerve (0: none).
    remaining_s: f32,
    curvature: f32,
    /// Seconds until the next swerve starts (`None`: not drawn yet).
    until_next_s: Option<f32>,
}

impl Swerves {
    /// Advances by `dt` seconds; the curvature to add at this step while swerving.
    pub fn step(&mut self, p: &ExpertParams, dt: f32, rng: &mut impl Rng) -> Option<f32> {
        if p.swerve_every_s <= 0.0 || p.swerve_s <= 0.0 {
            return None;
        }
        if self.remaining_s > 0.0 {
            self.remaining_s -= dt;
            return Some(self.curvature);
        }
        let next = self
            .until_next_s
            .get_or_insert_with(|| p.swerve_every_s * rng.random_range(0.5..1.5));
        *next -= dt;
        if *next > 0.0 {
            return None;
        }
        self.until_next_s = None;
        self.remaining_s = p.swerve_s - dt;
        self.curvature = if rng.random_bool(0.5) {
            p.swerve_curvature
        } else {
            -p.swerve_curvature
        };
        Some(self.curvature)
    }
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

/// The pure-pursuit command from `pose` on `track`; `swerve` adds that curvature (a
/// deliberate swerve, see [`Swerves`]). With `car` (the simulator's car, `sim.vehicle =
/// "car"`) the command is DonkeyCar's throttle and angle for that speed and curvature
/// ([`Mixing::Car`]; past full lock the car turns no tighter), else the wheels' duties.
pub fn pursue(
    track: &Track,
    pose: &Pose2,
    robot: &RobotParams,
    car: Option<&CarParams>,
    p: &ExpertParams,
    swerve: Option<f32>,
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
    kappa += swerve.unwrap_or(0.0);
    let v = p
        .speed_mps
        .min((p.max_lateral_accel / kappa.abs().max(1e-6)).sqrt())
        .max(0.05);
    let wheels = match car {
        Some(c) => {
            let throttle = v / c.speed_per_throttle_mps.max(1e-6);
            let angle = if c.curvature_per_unit.abs() > 1e-6 {
                (kappa - c.curvature_offset) / c.curvature_per_unit
            } else {
                0.0
            };
            Mixing::Car.mix(throttle, angle)
        }
        None => {
            let half = robot.wheel_base_m / 2.0;
            let (vl, vr) = (v * (1.0 - kappa * half), v * (1.0 + kappa * half));
            WheelCommand::new(duty_for_speed(vl, robot), duty_for_speed(vr, robot))
        }
    };
    ExpertAction {
        wheels,
        target: (goal.x, goal.y),
        curvature: kappa,
        speed: v,
        swerving: swerve.is_some(),
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngCore, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn swerves_last_their_time_and_come_at_the_drawn_intervals() {
        // dt 1/8 s and a 0.5 s swerve: exactly 4 steps each, one side each; the gaps between
        // swerves lie in 0.5x..1.5x of 2 s = 8..24 steps.
        let p = ExpertParams {
            swerve_every_s: 2.0,
            swerve_s: 0.5,
            swerve_curvature: 3.0,
            ..ExpertParams::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut sw = Swerves::default();
        let steps: Vec<Option<f32>> = (0..800).map(|_| sw.step(&p, 0.125, &mut rng)).collect();
        let mut runs: Vec<(usize, usize, f32)> = Vec::new(); // (start, length, curvature)
        for (i, s) in steps.iter().enumerate() {
            if let Some(k) = *s {
                assert!(k == 3.0 || k == -3.0);
                match runs.last_mut() {
                    Some((start, len, c)) if *start + *len == i => {
                        assert_eq!(*c, k, "a swerve changed side");
                        *len += 1;
                    }
                    _ => runs.push((i, 1, k)),
                }
            }
        }
        assert!(
            (30..=50).contains(&runs.len()),
            "{} swerves in 100 s",
            runs.len()
        );
        for r in &runs[..runs.len() - 1] {
            assert_eq!(r.1, 4, "{runs:?}");
        }
        for w in runs.windows(2) {
            let gap = w[1].0 - (w[0].0 + w[0].1);
            assert!((7..=24).contains(&gap), "gap {gap} in {runs:?}");
        }
        assert!(runs.iter().any(|r| r.2 > 0.0) && runs.iter().any(|r| r.2 < 0.0));
    }

    #[test]
    fn without_swerves_nothing_is_drawn() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut sw = Swerves::default();
        for _ in 0..100 {
            assert_eq!(sw.step(&ExpertParams::default(), 0.1, &mut rng), None);
        }
        assert_eq!(rng.next_u64(), ChaCha8Rng::seed_from_u64(9).next_u64());
    }
}
