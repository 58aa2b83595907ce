//! The paper's test protocol during training: the same closed loop as `jetpilot eval`
//! (daemon per-frame code, steering law, PCA9685 driver on the virtual HAT, interventions put
//! the robot back on the lane), driven by the actor being trained.

use crate::config::Config;
use crate::drive::DriveParams;
use crate::drive::stages::FrameProcessor;
use crate::policy::Policy;
use crate::sim::closed_loop::{self, Pilot};
use crate::sim::reward::autonomy;
use crate::sim::setup;
use crate::sim::world::InterventionCauses;
use crate::train::TrainError;

/// What one test gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalOutcome {
    pub seconds: f64,
    pub interventions: u32,
    /// What ended each intervention (off the road, the replay's bounds, the stall rule).
    pub causes: InterventionCauses,
    pub autonomy_percent: f32,
    pub rewards: u64,
    pub mean_reward: f64,
    pub laps: f64,
    pub wall_seconds: f64,
}

/// Drives `policy` for `seconds` simulated seconds on `cfg`'s track (never a random layout).
pub fn evaluate(
    cfg: &Config,
    policy: &mut dyn Policy,
    seconds: f64,
) -> Result<EvalOutcome, TrainError> {
    let sim_err = |e: String| TrainError::Backend(format!("simulator: {e}"));
    // Tests are on the configured track, even where training draws random layouts.
    let mut cfg = cfg.clone();
    cfg.sim.layouts.enabled = false;
    let cfg = &cfg;
    let mut rig = setup::build(cfg).map_err(|e| sim_err(e.to_string()))?;
    let params = DriveParams::from_config(cfg);
    let processor = FrameProcessor::new(
        &policy.contract().clone(),
        params.gains,
        params.max_abs_output,
    );
    let mut pilot = Pilot::Model {
        policy,
        processor: Box::new(processor),
    };
    let times = closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(seconds, cfg),
        (cfg.sim.camera.width, cfg.sim.camera.height),
        |_| {},
    )
    .map_err(|e| sim_err(e.to_string()))?;
    let s = &rig.world.stats;
    Ok(EvalOutcome {
        seconds: s.time_s,
        interventions: s.interventions,
        causes: s.causes,
        autonomy_percent: autonomy(s.interventions, s.time_s as f32),
        rewards: s.rewards,
        mean_reward: s.reward_sum / s.control_steps.max(1) as f64,
        laps: rig.world.laps(),
        wall_seconds: times.total,
    })
}
