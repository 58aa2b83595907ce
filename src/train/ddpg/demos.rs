//! Demonstrations as replay transitions (DDPGfD): each tub's human steps in order, with the
//! action the steering law inverted on the recorded wheels, the recorded reward, and the
//! next frame of the same session as the successor. States are the frozen backbone's
//! features, computed once per frame, or the preprocessed frames themselves when the
//! backbone trains ([`super::State`]).
//!
//! A step's successor is the next record of the same session if it follows within 1.5x the
//! tub's usual interval (the median): a longer gap (a pause, dropped frames, the skipped
//! swerve of a recovery demonstration) ends the chain there. A tub recorded at a lower rate
//! than the simulator's control rate (`sim --record-every`) gives transitions that span
//! that many control steps, used as they are.

use std::path::PathBuf;

use super::State;
use super::features::Backbone;
use super::replay::{NStep, Step, Transition};
use crate::dataset::tub::{DriveMode, TubReader, TubRecord};
use crate::policy::{ModelContract, Preprocessor};
use crate::train::TrainError;
use crate::train::data::LabelMap;

/// Reads every tub in `dirs` into n-step transitions marked as demonstrations.
pub fn load(
    dirs: &[PathBuf],
    backbone: &mut Backbone,
    state: State,
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
        let max_gap_ms = usual_interval_ms(tub.records()).map_or(u64::MAX, |m| m + m / 2);
        let mut nstep = NStep::new(n_step, gamma);
        let mut pending: Option<(Step, String, u64, u64)> = None;
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
            let features = match state {
                State::Features => {
                    let mut f = vec![0.0; backbone.width()];
                    backbone.features(input, &mut f)?;
                    f
                }
                State::Frames => input.to_vec(),
            };
            if let Some((step, session, index, ms)) = pending.take() {
                if session == rec.session_id
                    && index + 1 == rec.index
                    && rec.timestamp_ms.saturating_sub(ms) <= max_gap_ms
                {
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
                rec.timestamp_ms,
            ));
        }
        // The last step has no successor frame; drop it and cut the episode.
        if let Some((step, _, _, _)) = pending {
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

/// The median interval between consecutive human records of one session, ms.
fn usual_interval_ms<'a>(records: impl Iterator<Item = &'a TubRecord>) -> Option<u64> {
    let mut last: Option<(&str, u64, u64)> = None;
    let mut gaps = Vec::new();
    for rec in records.filter(|r| r.mode == DriveMode::User) {
        if let Some((session, index, ms)) = last
            && session == rec.session_id
            && index + 1 == rec.index
            && rec.timestamp_ms > ms
        {
            gaps.push(rec.timestamp_ms - ms);
        }
        last = Some((&rec.session_id, rec.index, rec.timestamp_ms));
    }
    gaps.sort_unstable();
    gaps.get(gaps.len() / 2).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(index: u64, ms: u64) -> TubRecord {
        let mut r = TubRecord::new(ms, 0.0, 0.5, DriveMode::User);
        r.index = index;
        r.session_id = "26-11-22_0".into();
        r
    }

    #[test]
    fn the_usual_interval_is_the_median_gap() {
        // Gaps 100, 100, 300 (a skipped swerve), 100, then a new session: median 100.
        let mut recs: Vec<TubRecord> = [0, 100, 200, 500, 600]
            .iter()
            .enumerate()
            .map(|(i, ms)| rec(i as u64, *ms))
            .collect();
        let mut other = rec(5, 10_000);
        other.session_id = "26-11-22_1".into();
        recs.push(other);
        assert_eq!(usual_interval_ms(recs.iter()), Some(100));
        assert_eq!(usual_interval_ms(recs[..1].iter()), None);
    }
}
