//! The replayed-frame simulator: a JetBot mat track, differential-drive robot physics, a
//! virtual PCA9685 that the daemon's own motor driver writes to, a camera (JetBot's fisheye
//! by default, or a pinhole) that renders the mat or re-projects recorded frames to new
//! poses, the paper's reward, and intervention accounting.
//!
//! ```text
//! track (geometry, queries) --paint--> render (mat texture, camera view at a pose)
//! recording (frames + poses) --------> synth (nearest frame re-projected by homography)
//! MotorHat --I2C--> virtual_hat --signed duties--> robot (motor model + kinematics) --pose--+
//!      ^                                                                                    |
//!      +---- daemon (preprocess -> policy -> steering law) <---- camera frame at the pose <-+
//! ```
//!
//! Conventions: world frame on the mat in metres, x to the right along the mat's short side,
//! y up along its long side, origin at the mat's lower-left corner; headings in radians,
//! 0 along +x, counter-clockwise positive. Lateral offsets are positive to the left of the
//! direction of travel.

pub mod appearance;
pub mod camera;
pub mod closed_loop;
pub mod demos;
pub mod env;
pub mod expert;
pub mod flat_field;
pub mod floor;
pub mod layout;
pub mod lens;
pub mod odometry;
pub mod path_road;
pub mod realtime;
pub mod render;
pub mod reward;
pub mod robot;
pub mod scatter;
pub mod scene;
pub mod setup;
pub mod synth;
pub mod track;
pub mod virtual_bridge;
pub mod virtual_hat;
pub mod virtual_motors;
pub mod world;

use serde::{Deserialize, Serialize};

/// A pose on the mat.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose2 {
    pub x: f32,
    pub y: f32,
    /// Radians, 0 along +x, counter-clockwise positive.
    pub heading: f32,
}

impl Pose2 {
    pub fn new(x: f32, y: f32, heading: f32) -> Self {
        Self { x, y, heading }
    }
}

/// Wraps an angle to -pi..=pi.
pub fn wrap_angle(a: f32) -> f32 {
    let tau = std::f32::consts::TAU;
    let mut r = a.rem_euclid(tau);
    if r > std::f32::consts::PI {
        r -= tau;
    }
    r
}

/// A painted line on the mat, for the renderer: a polyline in world metres.
#[derive(Debug, Clone, PartialEq)]
pub struct PaintStroke {
    pub points: Vec<(f32, f32)>,
    pub width_m: f32,
    pub rgb: [u8; 3],
    /// `Some((dash, gap))` in metres for a dashed line.
    pub dash: Option<(f32, f32)>,
    pub closed: bool,
}

/// Errors from the simulator's inputs (track files, recordings, settings).
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("{path}: {reason}")]
    File { path: String, reason: String },
    #[error("track {origin}: {reason}")]
    Track { origin: String, reason: String },
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T> = std::result::Result<T, SimError>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_angle_stays_in_range() {
        assert!((wrap_angle(3.0 * std::f32::consts::PI) - std::f32::consts::PI).abs() < 1e-5);
        assert!((wrap_angle(-0.5) + 0.5).abs() < 1e-6);
        assert!((wrap_angle(7.0) - (7.0 - std::f32::consts::TAU)).abs() < 1e-5);
    }
}
