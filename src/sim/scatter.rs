//! Demonstrations the way JetBot's road-following notebook collects them: the robot is put
//! down at a random place on or beside the road, at a random angle, one frame is taken and
//! the target point (where a person would click) is recorded. Driving demonstrations only
//! show the views an expert on the lane sees; real JetBot datasets are mostly these
//! scattered views, so a policy that has to find the road from anywhere learns from them.
//!
//! [`sample_pose`] and [`target`] are the pure part; [`write_scattered`] renders the frames
//! through a [`World`] (appearance randomisation included) into JetBot's xy folder format.

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::camera::CameraModel;
use super::expert::target_label;
use super::track::Track;
use super::world::World;
use super::{Pose2, wrap_angle};
use crate::dataset::{DatasetError, jetbot_xy};

/// Where the robot is put down.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScatterParams {
    /// How far beyond the road's edges the robot may stand, metres (0: on the road only).
    pub off_road_m: f32,
    /// Largest angle between the robot and the road, radians, either way.
    pub max_heading_rad: f32,
    /// How far along the lane, from the nearest point on the road, the target lies, metres
    /// (the expert's `lookahead_m`).
    pub lookahead_m: f32,
    /// With random layouts on: a new layout after every so many samples (0: one for all).
    pub per_layout: u64,
}

impl Default for ScatterParams {
    fn default() -> Self {
        Self {
            off_road_m: 0.05,
            max_heading_rad: 40f32.to_radians(),
            lookahead_m: 0.22,
            per_layout: 10,
        }
    }
}

/// A random pose: progress uniform along the lap, offset uniform across the road and
/// `off_road_m` beyond either edge, heading within `max_heading_rad` of the road's.
pub fn sample_pose(track: &Track, p: &ScatterParams, rng: &mut impl Rng) -> Pose2 {
    let s = rng.random_range(0.0..track.length().max(1e-3));
    let reach = track.road_half_width() + p.off_road_m.max(0.0);
    let lateral = rng.random_range(-reach..=reach);
    let turn = p.max_heading_rad.abs();
    let dh = if turn > 0.0 {
        rng.random_range(-turn..=turn)
    } else {
        0.0
    };
    let base = track.pose_at(s, lateral);
    Pose2::new(base.x, base.y, wrap_angle(base.heading + dh))
}

/// The target a person would click for a robot at `pose`: the driving lane's centre
/// `lookahead_m` further along than the nearest point on the road (world metres).
pub fn target(track: &Track, pose: &Pose2, lookahead_m: f32) -> (f32, f32) {
    let q = track.query(pose.x, pose.y);
    let goal = track.lane_pose_at(q.s + lookahead_m);
    (goal.x, goal.y)
}

/// What [`write_scattered`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ScatterSummary {
    /// Samples written.
    pub written: u64,
    /// Poses drawn and dropped because the target was out of view (behind the robot or off
    /// the frame), as a person would not click there either.
    pub out_of_view: u64,
}

/// Renders `n` scattered samples through `world` (a new look and scene per sample when its
/// appearance is randomised; a new road every `per_layout` samples when its random layouts
/// are on) and writes them to `dir` as `xy_XXX_YYY_<uuid>.jpg`. Poses whose
/// target is out of view are drawn again, up to 20 tries per sample; `keep` sees each
/// written frame (RGB) and its pixel label. `camera` gives the frame size; labels go
/// through the camera each frame was taken with ([`World::camera`]: a look may tilt it).
pub fn write_scattered(
    world: &mut World,
    camera: &CameraModel,
    p: &ScatterParams,
    n: u64,
    seed: u64,
    dir: &Path,
    mut keep: impl FnMut(&[u8], (u32, u32)),
) -> Result<ScatterSummary, DatasetError> {
    std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io {
        path: dir.display().to_string(),
        source,
    })?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut frame = vec![0u8; (camera.width * camera.height * 3) as usize];
    let mut jpeg = Vec::new();
    let mut summary = ScatterSummary::default();
    let tries = n.saturating_mul(20);
    while summary.written < n && summary.written + summary.out_of_view < tries {
        let pose = sample_pose(&world.track, p, &mut rng);
        let goal = target(&world.track, &pose, p.lookahead_m);
        world.place(pose);
        world.observe(&mut frame);
        // Through the camera the frame was taken with (a look may tilt it).
        let Some((x, y)) = target_label(world.camera(), &pose, goal) else {
            summary.out_of_view += 1;
            continue;
        };
        crate::dataset::encode_jpeg(&frame, camera.width, camera.height, &mut jpeg).map_err(
            |source| DatasetError::Image {
                path: "(simulated frame)".into(),
                source,
            },
        )?;
        let (px, py) = jetbot_xy::pixel_for_label(x, y, camera.width, camera.height);
        let uuid = jetbot_xy::uuid_from_rng(&mut rng);
        jetbot_xy::write_sample(dir, px, py, &jpeg, &uuid)?;
        keep(&frame, (px, py));
        summary.written += 1;
        // A new road after every `per_layout` samples when random layouts are on (a no-op
        // when they are off), before the next pose is drawn on it.
        if p.per_layout > 0 && summary.written % p.per_layout == 0 && summary.written < n {
            world.new_layout();
        }
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_stay_within_the_reach_and_the_angle() {
        let track = Track::jetbot_mat();
        let p = ScatterParams::default();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let reach = track.road_half_width() + p.off_road_m;
        let (mut off_road, mut max_turn) = (0, 0f32);
        for _ in 0..2000 {
            let pose = sample_pose(&track, &p, &mut rng);
            let q = track.query(pose.x, pose.y);
            assert!(q.lateral.abs() <= reach + 1e-3, "{q:?}");
            let turn = wrap_angle(pose.heading - q.tangent).abs();
            assert!(turn <= p.max_heading_rad + 1e-3, "{turn}");
            max_turn = max_turn.max(turn);
            off_road += usize::from(!track.on_road(pose.x, pose.y));
        }
        // Beside the road: 2 * 0.05 of 2 * (half width + 0.05) of the draws.
        let expected = 2000.0 * p.off_road_m / reach;
        assert!(
            (off_road as f32 - expected).abs() < 0.25 * expected,
            "{off_road} off the road, expected about {expected}"
        );
        assert!(max_turn > 0.9 * p.max_heading_rad);
    }

    #[test]
    fn the_target_is_the_lane_point_ahead_of_the_nearest_road_point() {
        let track = Track::jetbot_mat();
        // On the lane, facing along it: exactly the expert's goal.
        let on_lane = track.lane_pose_at(1.0);
        let t = target(&track, &on_lane, 0.22);
        let goal = track.lane_pose_at(1.22);
        assert!((t.0 - goal.x).abs() < 1e-4 && (t.1 - goal.y).abs() < 1e-4);
        // Beside the road and turned away: still the lane point 0.22 m past the nearest
        // road point, whatever the heading.
        let beside = track.pose_at(1.0, track.road_half_width() + 0.04);
        let turned = Pose2::new(beside.x, beside.y, beside.heading + 0.6);
        assert_eq!(target(&track, &beside, 0.22), target(&track, &turned, 0.22));
        assert!((target(&track, &beside, 0.22).0 - goal.x).abs() < 1e-3);
    }
}
