//! The simulated world: the robot on the track, moved by whatever the daemon's motor driver
//! wrote into the virtual motor hardware (PCA9685 HAT or GPIO H-bridge), seen through the
//! camera (rendered, or re-projected from a recording), scored with the paper's reward,
//! with interventions when it leaves the road.
//!
//! One control period is: [`World::observe`] (camera frame at the current pose), the pilot
//! writes the motors, [`World::advance`] (physics substeps reading the virtual hardware),
//! then [`World::score`] (reward, intervention, laps).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::appearance::Appearance;
use super::layout::{LayoutConfig, random_track};
use super::reward::{RewardParams, is_reward, reward};
use super::robot::{Robot, RobotParams};
use super::synth::Synthesizer;
use super::track::Track;
use super::virtual_motors::VirtualMotors;
use super::{Pose2, render::Renderer};

/// On a road that does not close (a recorded path, `sim.road = "path"`), this close to its
/// end the robot is put back at the start.
pub const OPEN_ROAD_END_M: f32 = 0.05;
/// On an open road, a change of progress larger than this in one control period is a jump
/// of the nearest road point (the road passing near itself), not driving.
pub const OPEN_ROAD_MAX_STEP_M: f32 = 0.3;

/// How camera frames are made.
pub enum FrameMaker {
    /// Drawn from the mat texture at the exact pose.
    Render(Renderer),
    /// Re-projected from the nearest recorded frame; only faithful near the recording.
    Replay(Synthesizer),
}

/// What the simulation has counted so far.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WorldStats {
    /// Simulated seconds.
    pub time_s: f64,
    pub control_steps: u64,
    pub interventions: u32,
    /// Steps whose reward reached the count threshold ("one reward" in the paper).
    pub rewards: u64,
    pub reward_sum: f64,
    /// Distance driven, metres.
    pub distance_m: f64,
    /// Signed progress along the track, metres (laps = progress / length).
    pub progress_m: f64,
    /// Where each intervention happened.
    pub intervention_poses: Vec<Pose2>,
    /// Why the interventions happened.
    pub causes: InterventionCauses,
}

/// The interventions counted by what ended each one (the first that applies, in this order).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct InterventionCauses {
    /// The robot left the road.
    pub off_road: u32,
    /// A replayed view farther sideways from its recorded frame than half the road's width.
    pub replay_offset: u32,
    /// A replayed view turned from its recorded frame by more than the heading bound
    /// (`sim.replay_max_heading_deg`, VISTA's 18 degrees by default).
    pub replay_heading: u32,
    /// Too little progress within the stall rule's window.
    pub stalled: u32,
}

impl InterventionCauses {
    /// Those of the replay's validity bounds.
    pub fn replay(&self) -> u32 {
        self.replay_offset + self.replay_heading
    }
}

/// Why the last replayed view was out of its validity bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ViewBound {
    Offset,
    Heading,
}

/// The outcome of one control period.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepScore {
    pub reward: f32,
    /// The robot left the road (or the replayed view went out of its validity bounds) and
    /// was put back on the lane: one intervention.
    pub intervention: bool,
    /// Lane-edge distance and speed that went into the reward.
    pub edge_distance_m: f32,
    pub speed_mps: f32,
    /// The robot reached the end of an open road and was carried back to its start (not
    /// an intervention; a training episode is cut here).
    pub carried_back: bool,
}

pub struct World {
    pub track: Track,
    pub robot: Robot,
    motors: VirtualMotors,
    invert: (bool, bool),
    frames: FrameMaker,
    reward: RewardParams,
    rng: ChaCha8Rng,
    pub stats: WorldStats,
    last_s: f32,
    /// The last replayed view's broken validity bound (`None`: valid, or rendered).
    view_out: Option<ViewBound>,
    stall: StallRule,
    /// Simulated time and progress at the start of the current stall window.
    stall_window: (f64, f64),
    /// Randomised camera looks, when on (`[sim.appearance]`).
    appearance: Option<Appearance>,
    /// The appearance generation whose scene the renderer shows.
    painted: Option<u64>,
    /// Random track layouts, when on (`[sim.layouts]`).
    layouts: Option<Layouts>,
    /// The track changed since the renderer's mat was painted.
    track_changed: bool,
    /// The configured camera, for looks that do not draw a tilt, height or lens.
    base_camera: super::camera::CameraModel,
}

/// The layout generator's settings, its own random stream (so turning layouts on leaves
/// the robot's noise as it was), and when the current layout was drawn.
struct Layouts {
    cfg: LayoutConfig,
    rng: ChaCha8Rng,
    drawn_at_s: f64,
}

/// A robot that makes no progress along the track (circling, stuck, or driving the wrong
/// way) is also taken by the hand and put back: `min_progress_m` of forward progress is
/// required in every `seconds` window. Without it, the paper's autonomy value rates a car
/// that spins on the road at 100 %.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StallRule {
    /// Window length, simulated seconds (0: no stall rule).
    pub seconds: f32,
    /// Forward progress along the track required in each window, metres.
    pub min_progress_m: f32,
}

impl Default for StallRule {
    fn default() -> Self {
        Self {
            seconds: 10.0,
            min_progress_m: 0.3,
        }
    }
}

impl World {
    /// `motors` is a handle on the virtual hardware the daemon's driver writes to (HAT or
    /// H-bridge); `invert` says which motors are wired the other way round (as on the real
    /// robot).
    pub fn new(
        track: Track,
        robot: RobotParams,
        motors: VirtualMotors,
        invert: (bool, bool),
        frames: FrameMaker,
        reward: RewardParams,
        seed: u64,
    ) -> Self {
        let start = track.lane_pose_at(0.0);
        let base_camera = match &frames {
            FrameMaker::Render(r) => *r.camera(),
            FrameMaker::Replay(s) => *s.camera(),
        };
        let mut w = Self {
            robot: Robot::new(robot, start),
            track,
            motors,
            invert,
            frames,
            reward,
            rng: ChaCha8Rng::seed_from_u64(seed),
            stats: WorldStats::default(),
            last_s: 0.0,
            view_out: None,
            stall: StallRule::default(),
            stall_window: (0.0, 0.0),
            appearance: None,
            painted: None,
            layouts: None,
            track_changed: false,
            base_camera,
        };
        w.reset_at(0.0);
        w
    }

    /// Puts the robot at rest on the driving lane's centre at progress `s`.
    pub fn reset_at(&mut self, s: f32) {
        let pose = self.track.lane_pose_at(s);
        self.robot.reset(pose);
        self.last_s = self.track.query(pose.x, pose.y).s;
        self.view_out = None;
        if let Some(a) = self.appearance.as_mut() {
            a.reset();
        }
    }

    /// Puts the robot down at rest at `pose`, anywhere (on the road or not), with a new look
    /// and scene when the appearance is randomised: one scattered sample
    /// ([`super::scatter`]). Progress and counters are left as they are.
    pub fn place(&mut self, pose: Pose2) {
        self.robot.reset(pose);
        self.last_s = self.track.query(pose.x, pose.y).s;
        self.view_out = None;
        if let Some(a) = self.appearance.as_mut() {
            a.redraw();
        }
    }

    /// The replay's synthesizer (`None`: rendered frames).
    pub fn synthesizer(&self) -> Option<&Synthesizer> {
        match &self.frames {
            FrameMaker::Replay(s) => Some(s),
            FrameMaker::Render(_) => None,
        }
    }

    /// Randomises the camera's look from now on (`None`: plain frames).
    pub fn set_appearance(&mut self, appearance: Option<Appearance>) {
        self.appearance = appearance;
        if let Err(e) = self.aim_camera() {
            tracing::warn!("camera from the look: {e}; keeping the camera there is");
        }
    }

    /// Draws random track layouts from now on (`None`: keep the track), starting with one
    /// now; the robot is put on its lane at the start.
    pub fn set_layouts(
        &mut self,
        cfg: Option<LayoutConfig>,
        seed: u64,
    ) -> Result<(), super::SimError> {
        self.layouts = match cfg {
            Some(cfg) => {
                cfg.validate()?;
                Some(Layouts {
                    cfg,
                    // A stream of its own: "LAYOUT" in ASCII.
                    rng: ChaCha8Rng::seed_from_u64(seed ^ 0x4c41_594f_5554),
                    drawn_at_s: self.stats.time_s,
                })
            }
            None => None,
        };
        if self.new_layout() {
            self.reset_at(0.0);
        }
        Ok(())
    }

    /// A new random layout in place of the track, when layouts are on (the caller puts the
    /// robot back on the lane); `false` when they are off.
    pub fn new_layout(&mut self) -> bool {
        let Some(l) = self.layouts.as_mut() else {
            return false;
        };
        let (w, h) = self.track.mat_size();
        l.drawn_at_s = self.stats.time_s;
        match random_track(&l.cfg, (w as f64, h as f64), &mut l.rng) {
            Ok(track) => {
                self.track = track;
                self.track_changed = true;
                true
            }
            Err(e) => {
                // Settings were validated; drive on the layout there is.
                tracing::warn!("random layouts: {e}; keeping the current layout");
                false
            }
        }
    }

    /// With `[sim.layouts]` on: when (simulated seconds) the road now under the robot was
    /// drawn.
    pub fn layout_drawn_at_s(&self) -> Option<f64> {
        self.layouts.as_ref().map(|l| l.drawn_at_s)
    }

    /// The appearance randomiser, when on.
    pub fn appearance(&self) -> Option<&Appearance> {
        self.appearance.as_ref()
    }

    pub fn set_stall_rule(&mut self, rule: StallRule) {
        self.stall = rule;
    }

    pub fn pose(&self) -> Pose2 {
        self.robot.pose
    }

    /// The camera the last [`Self::observe`] saw through (a look may tilt it: JetBot
    /// target labels must be projected through this one).
    pub fn camera(&self) -> &super::camera::CameraModel {
        match &self.frames {
            FrameMaker::Render(r) => r.camera(),
            FrameMaker::Replay(s) => s.camera(),
        }
    }

    /// The camera frame at the current pose into `out` (`width * height * 3` RGB8).
    pub fn observe(&mut self, out: &mut [u8]) {
        if let Some(a) = self.appearance.as_mut() {
            a.next_frame();
        }
        self.show_scene();
        let pose = self.robot.pose;
        match &self.frames {
            FrameMaker::Render(r) => {
                r.render(&pose, out);
                self.view_out = None;
            }
            FrameMaker::Replay(s) => {
                let info = s.synthesize(&pose, out);
                self.view_out = if info.valid {
                    None
                } else if info.heading_error.abs() > s.max_heading_error_rad() {
                    Some(ViewBound::Heading)
                } else {
                    Some(ViewBound::Offset)
                };
            }
        }
        if let Some(a) = self.appearance.as_mut() {
            let c = match &self.frames {
                FrameMaker::Render(r) => r.camera(),
                FrameMaker::Replay(s) => s.camera(),
            };
            a.apply_look(c.width, c.height, out);
        }
    }

    /// Aims the rendered camera as the current look says: its tilt, height and lens
    /// spread (back to the configured camera's where the look draws none, or randomisation
    /// is off).
    fn aim_camera(&mut self) -> Result<(), super::SimError> {
        let FrameMaker::Render(r) = &mut self.frames else {
            return Ok(());
        };
        let base = self.base_camera;
        let look = self.appearance.as_ref().map(|a| *a.look());
        let fov = look.and_then(|l| l.fov_scale).unwrap_or(1.0);
        let camera = super::camera::CameraModel {
            tilt_deg: look.and_then(|l| l.tilt_deg).unwrap_or(base.tilt_deg),
            height_m: look.and_then(|l| l.height_m).unwrap_or(base.height_m),
            hfov_deg: base.hfov_deg * fov,
            fisheye_fov_deg: base.fisheye_fov_deg * fov,
            ..*r.camera()
        };
        if *r.camera() != camera {
            // The backdrop is dropped with the old camera; a new look brings a new scene,
            // whose backdrop show_scene draws for this camera.
            r.set_camera(camera)?;
        }
        Ok(())
    }

    /// Repaints the rendered mat and backdrop when the appearance has drawn a new scene.
    /// Replayed frames keep the scene they recorded.
    fn show_scene(&mut self) {
        if !matches!(self.frames, FrameMaker::Render(_)) {
            return;
        }
        let generation = self.appearance.as_ref().map(|a| a.generation());
        let new_look = generation.is_some() && self.painted != generation;
        if new_look && let Err(e) = self.aim_camera() {
            // The range was validated; keep the camera there is.
            tracing::warn!("camera from the look: {e}; keeping the camera there is");
        }
        if !new_look && !self.track_changed {
            return;
        }
        let FrameMaker::Render(r) = &mut self.frames else {
            return;
        };
        self.painted = generation;
        let scene = self.appearance.as_ref().and_then(|a| a.scene());
        if scene.is_none() && !self.track_changed {
            return;
        }
        self.track_changed = false;
        let done = match scene {
            Some(scene) => scene.show(r, &self.track),
            None => r.repaint(
                &self.track.paint(),
                super::scene::SIM_MAT_RGB,
                super::scene::SIM_FLOOR_RGB,
            ),
        };
        if let Err(e) = done {
            // Settings were validated; keep the previous scene rather than stop the run.
            tracing::warn!("scene randomisation: {e}; keeping the previous scene");
        }
    }

    /// Physics for `dt` seconds with the wheel duties the virtual motor hardware says now.
    pub fn advance(&mut self, dt: f32) {
        let (l, r) = self.motors.wheel_duties(self.invert);
        let before = self.robot.pose;
        self.robot.step(l, r, dt, &mut self.rng);
        let after = self.robot.pose;
        self.stats.distance_m += ((after.x - before.x).hypot(after.y - before.y)) as f64;
        self.stats.time_s += dt as f64;
        let due = self.layouts.as_ref().is_some_and(|l| {
            l.cfg.every_s > 0.0 && self.stats.time_s - l.drawn_at_s >= l.cfg.every_s as f64
        });
        if due && self.new_layout() {
            // Somewhere on the new road, not an intervention: the hand moved the mat.
            let s = rand::Rng::random_range(&mut self.rng, 0.0..self.track.length());
            self.reset_at(s);
            self.stall_window = (self.stats.time_s, self.stats.progress_m);
        }
    }

    /// Reward, interventions and progress at the end of a control period.
    pub fn score(&mut self) -> StepScore {
        let p = self.robot.pose;
        let q = self.track.query(p.x, p.y);
        let s_before = self.last_s;
        let delta = self.track.progress_delta(self.last_s, q.s);
        // An open road that passes near another part of itself can make the nearest point
        // jump along it; no robot covers that in one control period, so it is not progress.
        if self.track.is_closed() || delta.abs() <= OPEN_ROAD_MAX_STEP_M {
            self.stats.progress_m += delta as f64;
        }
        self.last_s = q.s;
        self.stats.control_steps += 1;
        let edge = self.track.lane_edge_distance(p.x, p.y);
        let speed = self.robot.speed();
        let stalled = self.stall.seconds > 0.0
            && self.stats.time_s - self.stall_window.0 >= self.stall.seconds as f64
            && {
                let progress = self.stats.progress_m - self.stall_window.1;
                self.stall_window = (self.stats.time_s, self.stats.progress_m);
                progress < self.stall.min_progress_m as f64
            };
        let off_road = !self.track.on_road(p.x, p.y);
        if stalled || off_road || self.view_out.is_some() {
            let c = &mut self.stats.causes;
            match (off_road, self.view_out) {
                (true, _) => c.off_road += 1,
                (false, Some(ViewBound::Offset)) => c.replay_offset += 1,
                (false, Some(ViewBound::Heading)) => c.replay_heading += 1,
                (false, None) => c.stalled += 1,
            }
            self.stall_window = (self.stats.time_s, self.stats.progress_m);
            self.stats.interventions += 1;
            self.stats.intervention_poses.push(p);
            self.reset_at(q.s);
            return StepScore {
                reward: 0.0,
                intervention: true,
                edge_distance_m: edge,
                speed_mps: speed,
                carried_back: false,
            };
        }
        let r = reward(edge, speed, &self.reward);
        self.stats.reward_sum += r as f64;
        if is_reward(r, &self.reward) {
            self.stats.rewards += 1;
        }
        let carried_back = !self.track.is_closed()
            && q.s >= self.track.length() - OPEN_ROAD_END_M
            && s_before >= self.track.length() - OPEN_ROAD_MAX_STEP_M;
        if carried_back {
            // The end of a recording that is not a loop: carried back to its start, which
            // is not an intervention (the car did nothing wrong).
            self.reset_at(0.0);
            self.stall_window = (self.stats.time_s, self.stats.progress_m);
        }
        StepScore {
            reward: r,
            intervention: false,
            edge_distance_m: edge,
            speed_mps: speed,
            carried_back,
        }
    }

    pub fn laps(&self) -> f64 {
        self.stats.progress_m / self.track.length() as f64
    }

    pub fn reward_params(&self) -> &RewardParams {
        &self.reward
    }
}
