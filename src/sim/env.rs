//! The simulator in the usual RL shape for the trainer: [`Env::reset`] and
//! [`Env::step`]`(action) -> (reward, done, truncated)` with the camera frame as the
//! observation. An action is the paper's `(speed, steering)`; it goes through the daemon's
//! steering law (`speed_steering` mode) and the real PCA9685 driver on the virtual HAT, so
//! what the agent learns drives the robot the same way.
//!
//! An episode ends (`done`) when the robot leaves the road, or the replayed view leaves its
//! validity bounds, or it stalls; it is cut (`truncated`) after `max_steps`.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::setup::{self, SimRig};
use super::{Pose2, SimError};
use crate::config::Config;
use crate::control::{SteeringLaw, WheelCommand};
use crate::hw::MotorOutput;
use crate::policy::OutputKind;

/// One transition's outcome.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
    /// The paper's reward for this control period.
    pub reward: f32,
    /// The robot left the road (an intervention in evaluation terms).
    pub done: bool,
    /// The episode hit `max_steps`.
    pub truncated: bool,
    /// Where the robot is now.
    pub pose: Pose2,
}

pub struct Env {
    rig: SimRig,
    law: SteeringLaw,
    control_dt: f32,
    substeps: u32,
    max_steps: u64,
    steps: u64,
    rng: ChaCha8Rng,
    frame: Vec<u8>,
}

impl Env {
    /// A world built from `cfg` (track, camera, robot, reward, `[motors]` layout, gains).
    pub fn new(cfg: &Config, max_steps: u64) -> Result<Self, SimError> {
        let rig = setup::build(cfg)?;
        let (w, h) = (cfg.sim.camera.width, cfg.sim.camera.height);
        let substeps = ((cfg.sim.physics_hz / cfg.sim.control_hz).round() as u32).max(1);
        Ok(Self {
            rig,
            law: SteeringLaw::new(cfg.control.gains(), OutputKind::SpeedSteering),
            control_dt: 1.0 / cfg.sim.control_hz,
            substeps,
            max_steps,
            steps: 0,
            rng: ChaCha8Rng::seed_from_u64(cfg.sim.seed),
            frame: vec![0u8; (w * h * 3) as usize],
        })
    }

    /// Starts an episode at a random place on the lane (or `at`, metres along the track),
    /// motors stopped, on a new random layout when `[sim.layouts]` is on; returns the first
    /// observation.
    pub fn reset(&mut self, at: Option<f32>) -> Result<&[u8], SimError> {
        // With `[sim.layouts]` on, every episode is on a new road.
        self.rig.world.new_layout();
        let s = at.unwrap_or_else(|| self.rng.random_range(0.0..self.rig.world.track.length()));
        self.rig
            .motors
            .stop()
            .map_err(|e| SimError::Invalid(format!("virtual motors: {e}")))?;
        self.rig.world.reset_at(s);
        self.law.reset();
        self.steps = 0;
        self.rig.world.observe(&mut self.frame);
        Ok(&self.frame)
    }

    /// The current observation: the camera frame, RGB8, `width * height * 3`.
    pub fn observation(&self) -> &[u8] {
        &self.frame
    }

    /// Applies `(speed, steering)` for one control period, then observes.
    pub fn step(&mut self, action: [f32; 2]) -> Result<StepOutcome, SimError> {
        let wheels: WheelCommand = self.law.step(action, self.control_dt).wheels;
        self.rig
            .motors
            .drive(wheels)
            .map_err(|e| SimError::Invalid(format!("virtual motors: {e}")))?;
        for _ in 0..self.substeps {
            self.rig
                .world
                .advance(self.control_dt / self.substeps as f32);
        }
        let score = self.rig.world.score();
        self.steps += 1;
        self.rig.world.observe(&mut self.frame);
        Ok(StepOutcome {
            reward: score.reward,
            done: score.intervention,
            // The end of an open road: carried back to its start, the episode is cut there.
            truncated: self.steps >= self.max_steps || score.carried_back,
            pose: self.rig.world.pose(),
        })
    }

    pub fn world(&self) -> &super::world::World {
        &self.rig.world
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> Config {
        Config::parse(
            "[control]\nspeed_gain = 0.3\nsteering_gain = 0.5\n[sim.camera]\nwidth = 32\nheight = 32\n",
            "t.toml",
        )
        .unwrap()
    }

    #[test]
    fn driving_straight_earns_rewards_until_the_road_bends_away() {
        let mut env = Env::new(&cfg(), 2000).unwrap();
        let obs = env.reset(Some(0.0)).unwrap().to_vec();
        assert_eq!(obs.len(), 32 * 32 * 3);
        let mut total = 0.0;
        let mut done_at = None;
        for i in 0..2000 {
            let o = env.step([1.0, 0.0]).unwrap();
            total += o.reward;
            if o.done {
                done_at = Some(i);
                break;
            }
        }
        // The start is on a 0.97 m straight: it scores, then leaves at the corner.
        assert!(total > 10.0, "{total}");
        let i = done_at.expect("leaves the road at the first corner");
        assert!((60..400).contains(&i), "{i}");
    }

    #[test]
    fn episodes_are_truncated_and_reset_is_seeded() {
        let mut env = Env::new(&cfg(), 5).unwrap();
        env.reset(None).unwrap();
        let p1 = env.world().pose();
        let mut last = None;
        for _ in 0..5 {
            last = Some(env.step([0.0, 0.0]).unwrap());
        }
        assert!(last.unwrap().truncated);
        let mut env2 = Env::new(&cfg(), 5).unwrap();
        env2.reset(None).unwrap();
        assert_eq!(env2.world().pose(), p1, "same seed, same start");
    }
}
