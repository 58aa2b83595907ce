//! Demonstrations as replay transitions (DDPGfD): each tub's human steps in order, with the
//! action the steering law inverted on the recorded wheels, the recorded reward, and the
//! next frame of the same session as the successor. Features come from the frozen backbone,
//! once per frame.

use std::path::PathBuf;

use super::features::{Backbone, FEATURES};
use super::replay::{NStep, Step, Transition};
use crate::dataset::tub::{DriveMode, TubReader};
use crate::policy::{ModelContract, Preprocessor};
use crate::train::TrainError;
use crate::train::data::LabelMap;

/// Reads every tub in `dirs` into n-step transitions marked as demonstrations.
pub fn load(
    dirs: &[PathBuf],
    backbone: &mut Backbone,
    contract: &ModelContract,
    labels: &LabelMap,
    n_step: usize,
    gamma: f32,
) -> Result<Vec<Transition>, TrainError> {
    let mut pre = Preprocessor::new(contract);
    let mut out = Vec::new();
    for dir in dirs {
        let data_err = |reason: String| TrainError::Data {
            path: dir.display().to_string(),
            reason,
        };
        let tub = TubReader::open(dir).map_err(|e| data_err(e.to_string()))?;
        let mut nstep = NStep::new(n_step, gamma);
        let mut pending: Option<(Step, String, u64)> = None;
        let mut without_reward = 0usize;
        for rec in tub.records() {
            if rec.mode != DriveMode::User {
                continue;
            }
            let Some(reward) = rec.reward else {
                without_reward += 1;
                continue;
            };
            let Some(action) = labels.for_record(rec) else {
                continue;
            };
            let (w, h, rgb) = tub.load_rgb(rec).map_err(|e| data_err(e.to_string()))?;
            let input = pre.run(w, h, &rgb).map_err(|e| data_err(e.to_string()))?;
            let mut features = vec![0.0; FEATURES];
            backbone.features(input, &mut features)?;
            if let Some((step, session, index)) = pending.take() {
                if session == rec.session_id && index + 1 == rec.index {
                    out.extend(nstep.push(step, &features, true));
                } else {
                    // A gap: the previous step has no successor; end its episode there.
                    out.extend(nstep.finish(&step.features.clone(), false, true));
                }
            }
            pending = Some((
                Step {
                    features,
                    action,
                    reward,
                },
                rec.session_id.clone(),
                rec.index,
            ));
        }
        // The last step has no successor frame; drop it and cut the episode.
        if let Some((step, _, _)) = pending {
            out.extend(nstep.finish(&step.features, false, true));
        }
        if without_reward > 0 {
            tracing::warn!(
                tub = %dir.display(),
                records = without_reward,
                "demonstration records without a reward left out"
            );
        }
    }
    if out.is_empty() {
        return Err(crate::train::data::nothing_in(
            dirs,
            "no demonstration transitions (human steps with a reward)",
        ));
    }
    Ok(out)
}
