//! `jetpilot poses`' corrections of the motion model from the drive itself: the turn's
//! sign where vision turns against the commands, and the turn's scale from the drive's loops
//! (`--turn-from-loops`, fitted on the drive's first half and reported on its second).

use jetpilot::dataset::tub::TubReader;
use jetpilot::sim::Pose2;
use jetpilot::sim::camera::CameraModel;
use jetpilot::sim::odometry::{self, OdometryParams, ReadOptions, Vehicle};

use jetpilot::sim::odometry::views::Frame;

use super::check_views;

/// Below this [`odometry::calibrate::turn_agreement`] slope, the frames turn the other way.
pub const REVERSED_BELOW: f64 = -0.2;

/// Where vision turns the other way from the commands (the `turn agreement` slope below
/// [`REVERSED_BELOW`]) and `--keep-turn-sign` is not given: the estimate again with the
/// commands' turn reversed, and a line that says so.
#[allow(clippy::too_many_arguments)]
pub fn fix_turn_sign(
    keep_turn_sign: bool,
    tub: &TubReader,
    camera: &CameraModel,
    vehicle: Vehicle,
    params: OdometryParams,
    est: odometry::Estimate,
    start: Pose2,
    opts: ReadOptions,
) -> anyhow::Result<(odometry::Estimate, OdometryParams)> {
    match est.turn_agreement {
        Some((slope, n)) if slope < REVERSED_BELOW && !keep_turn_sign => {
            println!(
                "turn sign:       vision turns x{slope:.2} of the prior over {n} turning frames: the commands turn the other way here (a reversed steering sign, swapped wheels, or a mirrored camera); estimating again with their turn reversed (fix it in the config's [sim.car] curvature_per_unit or wiring, or pass --keep-turn-sign)"
            );
            let params = OdometryParams {
                reverse_turn: !params.reverse_turn,
                ..params
            };
            let again = odometry::estimate(tub, camera, vehicle, params, start, opts)?;
            Ok((again, params))
        }
        _ => Ok((est, params)),
    }
}

/// `--turn-from-loops` on `frames` ([`check_views::load_frames`] of `est`): the turn
/// scale fitted on the loops within the drive's first half,
/// the estimate again with it, and the closure of the loops within the second half before
/// and after. The re-estimate's own calibration may still refit the turn where vision
/// measures it well (the `car model` / `wheel model` line prints what was used).
pub fn turn_from_loops(
    tub: &TubReader,
    camera: &CameraModel,
    vehicle: Vehicle,
    params: OdometryParams,
    est: odometry::Estimate,
    frames: &[Frame],
) -> anyhow::Result<(odometry::Estimate, Vehicle)> {
    let matches = check_views::loop_matches(frames, camera, &est);
    let half = est.poses.len() / 2;
    // Loops within the first half fit the scale, loops within the second check it, and
    // loops across the middle take no part (they would tie the two together).
    let fit: Vec<_> = matches.iter().copied().filter(|m| m.b < half).collect();
    let held: Vec<_> = matches.iter().copied().filter(|m| m.a >= half).collect();
    let poses = |e: &odometry::Estimate| -> Vec<Pose2> { e.poses.iter().map(|p| p.pose).collect() };
    let Some((scale, n)) = odometry::loops::turn_scale(&fit, &poses(&est)) else {
        println!(
            "turn from loops: no view of the first half is seen again a turn later within it; the prior's turn is kept"
        );
        return Ok((est, vehicle));
    };
    let turned = vehicle.with_turn(scale);
    let again = odometry::estimate(
        tub,
        camera,
        turned,
        params,
        Pose2::default(),
        ReadOptions::default(),
    )?;
    println!(
        "turn from loops: x{scale:.3} from {n} loops within the first half; the estimate again with it"
    );
    if held.is_empty() {
        println!(
            "  no loop lies within the second half: the scale is not checked on frames it was not fitted on"
        );
    } else {
        println!(
            "  second half, before: {}",
            odometry::loops::closure(&held, &poses(&est))
        );
        println!(
            "  second half, after:  {}",
            odometry::loops::closure(&held, &poses(&again))
        );
    }
    Ok((again, turned))
}
