//! The paper's test protocol during training: the same closed loop as `jetpilot eval`
//! (daemon per-frame code, steering law, PCA9685 driver on the virtual HAT, interventions put
//! the robot back on the lane), driven by the actor being trained, and which of its
//! evaluations is the best so far ([`improves_on`]).

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

/// Drives `policy` for `seconds` simulated seconds in `cfg`'s world as written: its track,
/// or its random layouts where `[sim.layouts]` is on (drawn from `sim.seed`, so every test
/// of a run drives the same roads). [`test_world`] makes the training world's test.
pub fn evaluate(
    cfg: &Config,
    policy: &mut dyn Policy,
    seconds: f64,
) -> Result<EvalOutcome, TrainError> {
    let sim_err = |e: String| TrainError::Backend(format!("simulator: {e}"));
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

/// Where a run's tests drive: the `--select-sim` world as written (random layouts too, when
/// its file turns them on), else the training world on its configured track: a run that
/// trains on random layouts is tested on the track.
pub fn test_world(train: &Config, select: Option<&Config>) -> Config {
    match select {
        Some(select) => select.clone(),
        None => {
            let mut cfg = train.clone();
            cfg.sim.layouts.enabled = false;
            cfg
        }
    }
}

/// What the best evaluation is chosen by: (autonomy in percent, rewards).
pub type Score = (f64, f64);

impl EvalOutcome {
    pub fn score(&self) -> Score {
        (f64::from(self.autonomy_percent), self.rewards as f64)
    }
}

/// Whether `candidate` replaces `best` as the run's best evaluation: a higher autonomy, then
/// more rewards, among the evaluations that still drive. An evaluation that earns fewer than
/// half the rewards of the `start` (the evaluation before any update) does not drive: a
/// policy that stops has few interventions (only the stall rule's, one every few seconds)
/// and so a higher autonomy than one that drives and leaves the road (a DonkeyCar replay's
/// run: 5 interventions and 0 rewards in 60 s against the start's 19 and 721). Without a
/// `start` (the candidate is the start) every evaluation counts. `train report` picks by
/// the same rule ([`crate::train::experiment::best_by`]).
pub fn improves_on(candidate: Score, best: Option<Score>, start: Option<Score>) -> bool {
    let drives = start.is_none_or(|s| 2.0 * candidate.1 >= s.1);
    drives && best.is_none_or(|b| candidate > b)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outcome(interventions: u32, rewards: u64) -> Score {
        EvalOutcome {
            seconds: 60.0,
            interventions,
            causes: InterventionCauses::default(),
            autonomy_percent: autonomy(interventions, 60.0),
            rewards,
            mean_reward: 0.0,
            laps: 0.0,
            wall_seconds: 1.0,
        }
        .score()
    }

    #[test]
    fn a_policy_that_stops_is_never_the_best() {
        // The run that found this: the start 19 interventions and 721 rewards in 60 s
        // (autonomy -90 %); a later actor that stands still, 5 stall interventions and 0
        // rewards (autonomy 50 %); a later one that drives, 8 and 697 (autonomy 20 %).
        let start = outcome(19, 721);
        assert!(
            improves_on(start, None, None),
            "the start is the first best"
        );
        let stopped = outcome(5, 0);
        assert!(!improves_on(stopped, Some(start), Some(start)));
        let driving = outcome(8, 697);
        assert!(improves_on(driving, Some(start), Some(start)));
        // Half the start's rewards still drives (721 / 2 = 360.5: 361 does, 360 does not).
        assert!(improves_on(outcome(8, 361), Some(start), Some(start)));
        assert!(!improves_on(outcome(8, 360), Some(start), Some(start)));
    }

    #[test]
    fn autonomy_first_then_rewards() {
        let start = outcome(19, 721);
        let best = outcome(8, 697);
        assert!(!improves_on(outcome(9, 900), Some(best), Some(start)));
        assert!(
            !improves_on(outcome(8, 697), Some(best), Some(start)),
            "a tie keeps the best"
        );
        assert!(improves_on(outcome(8, 698), Some(best), Some(start)));
        assert!(improves_on(outcome(7, 400), Some(best), Some(start)));
        // A start that earned nothing (DDPG from random weights) lets every evaluation count.
        let idle = outcome(10, 0);
        assert!(improves_on(outcome(9, 0), Some(idle), Some(idle)));
    }

    #[test]
    fn a_selection_world_keeps_its_layouts_and_the_training_world_tests_on_its_track() {
        let mut train: Config = toml::from_str("[sim]\nseed = 0").expect("config");
        train.sim.layouts.enabled = true; // --random-layouts
        let mut select: Config = toml::from_str("[sim]\nseed = 101").expect("config");
        select.sim.layouts.enabled = true;

        let on_track = test_world(&train, None);
        assert!(!on_track.sim.layouts.enabled, "no --select-sim: the track");
        assert_eq!(on_track.sim.seed, 0);
        let held_out = test_world(&train, Some(&select));
        assert!(
            held_out.sim.layouts.enabled,
            "--select-sim is taken as written"
        );
        assert_eq!(held_out.sim.seed, 101);
    }
}
