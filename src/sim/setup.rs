//! The `[sim]` config section and building a simulated world from a [`Config`]: the
//! track, the virtual PCA9685 with the daemon's own motor driver on it, the robot, and the
//! frame maker (renderer, or replayed-frame synthesis from a recording).

use std::path::PathBuf;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::appearance::Appearance;
use super::camera::CameraModel;
use super::closed_loop::{self, LoopSettings, Pilot};
use super::expert::ExpertParams;
use super::path_road::{PathRoadConfig, road_from_path};
use super::render::{MatTexture, Renderer};
use super::reward::RewardParams;
use super::robot::RobotParams;
use super::synth::{RecordedFrame, Recording, Synthesizer};
use super::track::Track;
use super::virtual_bridge::VirtualBridge;
use super::virtual_hat::VirtualPca9685;
use super::virtual_motors::{SimMotors, VirtualMotors};
use super::world::{FrameMaker, World};
use super::{Pose2, SimError};
use crate::config::{Config, MotorBackend};
use crate::hw::MotorHat;
use crate::hw::motor_hat::HatSettings;

/// How the simulated camera makes frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameMode {
    /// Draw the mat at the exact pose.
    Render,
    /// Re-project the nearest frame of a recording (the replayed-frame simulator).
    Replay,
}

/// What drives on the road.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SimVehicle {
    /// A differential-drive JetBot (`[sim.robot]`).
    #[default]
    Wheels,
    /// A car-like vehicle (`[sim.car]`, a DonkeyCar): the motor channels carry its throttle
    /// and angle, so `control.mixing = "car"` goes with it.
    Car,
}

/// What the road is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RoadSource {
    /// The track file (`sim.track`) or the built-in mat.
    #[default]
    Track,
    /// The recording's own path plus or minus half a lane (`[sim.path]`): a real recording
    /// with estimated poses and no track file (`sim.frames = "replay"`, `sim.recording`).
    Path,
}

/// Where a replayed view's ground comes from when the nearest recorded frame did not see
/// it (a view moved sideways or turned: the floor just in front and to the side).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ReplayFill {
    /// From the frames recorded 6-28 cm further back along the recording, which saw it.
    #[default]
    Earlier,
    /// The nearest frame's edge pixel, smeared (the single-frame synthesis).
    Edge,
}

/// `[sim]`: the simulator. Every key has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Track file; unset: the built-in JetBot mat (config/tracks/jetbot_mat.toml).
    pub track: Option<PathBuf>,
    /// `track` (default) or `path`: the road is the recording's path (replay only).
    pub road: RoadSource,
    /// `road = "path"`: the lane around the recorded path.
    pub path: PathRoadConfig,
    /// Drive the track the other way round (the built-in mat: clockwise), still in the
    /// right-hand lane.
    pub reverse: bool,
    pub frames: FrameMode,
    /// `replay`: a tub (DonkeyCar v2) whose records carry `pose/x`, `pose/y`,
    /// `pose/heading` (real data with poses from a tracker, or `jetpilot sim --record`);
    /// unset: the expert drives one lap in the rendered world and that is the recording.
    pub recording: Option<PathBuf>,
    /// The part of `recording` the replay uses, as the fractions (from, to) of its frames
    /// in recorded order (time): 0.7 to 1.0 is its latest 30 %, the frames `train probe
    /// --leave-latest 0.3` left out. Both the views and (`road = "path"`) the road come
    /// from that part only. Default 0 to 1: all of it.
    pub recording_span: [f32; 2],
    /// `replay` without `recording`: spacing of the frames the expert records, metres.
    pub record_spacing_m: f32,
    /// Replay: a view turned further than this from its recorded frame ends the episode
    /// (an intervention), degrees; VISTA's 18 by default.
    pub replay_max_heading_deg: f32,
    /// Replay: where ground the nearest frame did not see comes from.
    pub replay_fill: ReplayFill,
    /// Replay: fit what the recording's camera adds at fixed pixels (vignetting, a light
    /// gradient, glare that moves with the robot) and keep it in place in replayed views
    /// ([`crate::sim::flat_field`]); used only where it explains the recording.
    pub replay_flat_field: bool,
    /// Frames, inferences and motor commands per simulated second.
    pub control_hz: f32,
    /// Physics steps per simulated second; each control period takes
    /// `round(physics_hz / control_hz)` of them (at least one).
    pub physics_hz: f32,
    /// The seed of everything random in the simulator (layouts, appearance, noise): one
    /// seed, one run, byte for byte.
    pub seed: u64,
    /// Length of `jetpilot eval`'s test, simulated seconds (the paper: 600).
    pub eval_seconds: f32,
    /// Texels per metre of the mat texture.
    pub mat_px_per_m: f32,
    pub camera: CameraModel,
    pub robot: RobotParams,
    /// `"wheels"` (JetBot, the default) or `"car"`: the `[sim.car]` vehicle (the replay of
    /// a DonkeyCar tub, which `jetpilot poses` writes).
    pub vehicle: SimVehicle,
    /// A car-like vehicle's command response (`jetpilot poses` on a DonkeyCar tub, and the
    /// simulated car).
    pub car: super::odometry::ackermann::CarParams,
    /// The chassis mask `jetpilot poses` leaves out of registration.
    pub chassis: super::odometry::mask::ChassisConfig,
    pub reward: RewardParams,
    pub expert: ExpertParams,
    /// No progress along the track for this long is an intervention too.
    pub stall: super::world::StallRule,
    /// Camera-side appearance randomisation (off by default).
    pub appearance: super::appearance::AppearanceConfig,
    /// Random track layouts (off by default; rendered frames only).
    pub layouts: super::layout::LayoutConfig,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            track: None,
            road: RoadSource::Track,
            path: PathRoadConfig::default(),
            reverse: false,
            frames: FrameMode::Render,
            recording: None,
            recording_span: [0.0, 1.0],
            record_spacing_m: 0.02,
            replay_max_heading_deg: 18.0,
            replay_fill: ReplayFill::Earlier,
            replay_flat_field: true,
            control_hz: 30.0,
            physics_hz: 240.0,
            seed: 0,
            eval_seconds: 600.0,
            mat_px_per_m: 400.0,
            camera: CameraModel::default(),
            robot: RobotParams::default(),
            vehicle: SimVehicle::Wheels,
            car: super::odometry::ackermann::CarParams::default(),
            chassis: super::odometry::mask::ChassisConfig::default(),
            reward: RewardParams::default(),
            expert: ExpertParams::default(),
            stall: super::world::StallRule::default(),
            appearance: super::appearance::AppearanceConfig::default(),
            layouts: super::layout::LayoutConfig::default(),
        }
    }
}

impl SimConfig {
    pub fn loop_settings(&self, seconds: f64, cfg: &Config) -> LoopSettings {
        LoopSettings {
            seconds,
            control_hz: self.control_hz,
            physics_hz: self.physics_hz,
            watchdog: std::time::Duration::from_millis(cfg.safety.watchdog_ms),
        }
    }
}

/// A world and the motor driver that moves it.
pub struct SimRig {
    pub world: World,
    /// The daemon's motor driver on the virtual hardware `[motors]` names.
    pub motors: SimMotors,
    /// The virtual PCA9685 (for tests: its bus counters and fault injection). With
    /// `motors.backend = "gpio"` nothing drives it: the H-bridge moves the robot.
    pub hat: VirtualPca9685,
    pub camera: CameraModel,
    /// `sim.road = "path"`: how far the recording's poses were moved to put the path
    /// 0.5 m inside the positive quadrant (world pose = recorded pose + this), metres.
    pub path_shift_m: (f32, f32),
}

fn renderer(cfg: &SimConfig, track: &Track) -> Result<Renderer, SimError> {
    let texture = MatTexture::new(
        &track.paint(),
        track.mat_size(),
        cfg.mat_px_per_m,
        super::scene::SIM_MAT_RGB,
        super::scene::SIM_FLOOR_RGB,
    )?;
    Renderer::new(texture, cfg.camera)
}

/// Loads the track named by the config (or the built-in mat), the other way round with
/// `reverse`.
pub fn load_track(cfg: &SimConfig) -> Result<Track, SimError> {
    let track = match &cfg.track {
        Some(p) => Track::load(p)?,
        None => Track::jetbot_mat(),
    };
    Ok(if cfg.reverse { track.reversed() } else { track })
}

/// `sim.road = "path"`: the recording, and the road made from its path.
pub fn path_road(sim: &SimConfig) -> Result<(Track, Recording, (f32, f32)), SimError> {
    let needs = |what: &str| {
        SimError::Invalid(format!(
            "sim.road = \"path\" needs {what}: the road is the path of a recording with poses \
             (docs/guides/training.md, \"Replay a real recording\")"
        ))
    };
    if sim.frames != FrameMode::Replay {
        return Err(needs("sim.frames = \"replay\""));
    }
    if sim.track.is_some() {
        return Err(needs(
            "no sim.track (a track file and a path road are two roads)",
        ));
    }
    if sim.layouts.enabled {
        return Err(needs("[sim.layouts] off (or no --random-layouts)"));
    }
    if sim.reverse {
        return Err(needs(
            "reverse = false (or no --reverse): the recorded frames look the way the recording drove",
        ));
    }
    let Some(dir) = &sim.recording else {
        return Err(needs("sim.recording"));
    };
    let mut recording = tub_recording(dir, &sim.camera)?;
    recording.frames = span_of(recording.frames, sim.recording_span, dir)?;
    // Moved so the path lies 0.5 m inside the positive quadrant (estimated poses start at
    // the origin; the top-down trace draws from it): frames and road move together, so
    // nothing changes but the coordinates.
    let (min_x, min_y) = recording
        .frames
        .iter()
        .fold((f32::MAX, f32::MAX), |(a, b), f| {
            (a.min(f.pose.x), b.min(f.pose.y))
        });
    for f in &mut recording.frames {
        f.pose.x += 0.5 - min_x;
        f.pose.y += 0.5 - min_y;
    }
    let poses: Vec<Pose2> = recording.frames.iter().map(|f| f.pose).collect();
    let road = road_from_path(&poses, &sim.path, &dir.display().to_string())?;
    tracing::info!(
        recording = %dir.display(),
        frames = recording.frames.len(),
        path_m = format!("{:.2}", road.path_length_m),
        road_m = format!("{:.2}", road.track.length()),
        closed = road.closed,
        closing_gap_m = format!("{:.3}", road.closing_gap_m),
        "replay: the road is the recorded path"
    );
    Ok((road.track, recording, (0.5 - min_x, 0.5 - min_y)))
}

/// The frames of `span` (`sim.recording_span`: fractions of the recording in recorded
/// order, `round(from * n) .. round(to * n)`), at least two.
pub fn span_of<T>(
    mut frames: Vec<T>,
    span: [f32; 2],
    dir: &std::path::Path,
) -> Result<Vec<T>, SimError> {
    let [from, to] = span;
    if !((0.0..1.0).contains(&from) && to > from && to <= 1.0) {
        return Err(SimError::Invalid(format!(
            "sim.recording_span = [{from}, {to}]: allowed 0 <= from < to <= 1 (fractions of \
             the recording in time)"
        )));
    }
    let n = frames.len();
    let (a, b) = (
        (from as f64 * n as f64).round() as usize,
        ((to as f64 * n as f64).round() as usize).min(n),
    );
    if b < a + 2 {
        return Err(SimError::File {
            path: dir.display().to_string(),
            reason: format!(
                "sim.recording_span = [{from}, {to}] leaves {} of its {n} frames with poses; the replay needs at least 2",
                b.saturating_sub(a)
            ),
        });
    }
    frames.truncate(b);
    frames.drain(..a);
    Ok(frames)
}

/// Builds the world for `cfg`: the motor driver initialises the virtual HAT exactly as it
/// would the real one (layout, address, trims from `[motors]`).
pub fn build(cfg: &Config) -> Result<SimRig, SimError> {
    let sim = &cfg.sim;
    if sim.road == RoadSource::Path {
        let (track, recording, shift) = path_road(sim)?;
        let frames = FrameMaker::Replay(replay_synthesizer(sim, recording, &track)?);
        let mut rig = rig(cfg, track, frames)?;
        rig.path_shift_m = shift;
        return Ok(rig);
    }
    let track = load_track(sim)?;
    let frames = match sim.frames {
        FrameMode::Render => FrameMaker::Render(renderer(sim, &track)?),
        FrameMode::Replay => {
            let recording = match &sim.recording {
                Some(dir) => {
                    let mut r = tub_recording(dir, &sim.camera)?;
                    r.frames = span_of(r.frames, sim.recording_span, dir)?;
                    r
                }
                None => expert_lap_recording(cfg, &track)?,
            };
            tracing::info!(
                frames = recording.frames.len(),
                source = %sim.recording.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "one expert lap".into()),
                "replay: frames to re-project"
            );
            FrameMaker::Replay(replay_synthesizer(sim, recording, &track)?)
        }
    };
    rig(cfg, track, frames)
}

/// The replay's synthesizer as `[sim]` sets it up: heading bound, fill, flat field.
fn replay_synthesizer(
    sim: &SimConfig,
    recording: Recording,
    track: &Track,
) -> Result<Synthesizer, SimError> {
    let synth = Synthesizer::new(recording, track.road_half_width())?
        .with_max_heading_deg(sim.replay_max_heading_deg)?
        .with_fill_from_earlier(sim.replay_fill == ReplayFill::Earlier);
    Ok(synth.with_flat_field(sim.replay_flat_field).0)
}

fn rig(cfg: &Config, track: Track, frames: FrameMaker) -> Result<SimRig, SimError> {
    let mut settings: HatSettings = cfg.motors.hat_settings();
    settings.bus_name = "virtual PCA9685".into();
    let hat = VirtualPca9685::new(settings.address);
    let invert = (settings.left.invert, settings.right.invert);
    let (motors, hardware) = match (&cfg.motors.backend, &cfg.motors.gpio) {
        (MotorBackend::Gpio, Some(gpio)) => {
            let bridge = VirtualBridge::new(gpio.clone());
            let trims = cfg.motors.trims();
            let driver = crate::hw::hbridge::assemble(
                gpio,
                trims,
                format!("virtual {}", gpio.summary()),
                |line, _| Ok(bridge.pin(line)),
                |ch, _| Ok(bridge.pwm(ch)),
            )
            .map_err(|e| SimError::Invalid(format!("virtual H-bridge: {e}")))?;
            (
                SimMotors::Bridge(Box::new(driver)),
                (
                    VirtualMotors::Bridge(bridge),
                    (trims.0.invert, trims.1.invert),
                ),
            )
        }
        _ => {
            let layout = settings.layout;
            let driver = MotorHat::init(hat.clone(), settings, &mut NoDelay)
                .map_err(|e| SimError::Invalid(format!("virtual motor HAT: {e}")))?;
            (
                SimMotors::Hat(driver),
                (
                    VirtualMotors::Hat {
                        hat: hat.clone(),
                        layout,
                    },
                    invert,
                ),
            )
        }
    };
    let mut world = World::new(
        track,
        cfg.sim.robot,
        hardware.0,
        hardware.1,
        frames,
        cfg.sim.reward,
        cfg.sim.seed,
    );
    if cfg.sim.vehicle == SimVehicle::Car {
        cfg.sim.car.validate()?;
        world.robot = super::robot::Robot::car(cfg.sim.robot, cfg.sim.car, world.robot.pose);
    }
    world.set_stall_rule(cfg.sim.stall);
    if cfg.sim.appearance.enabled {
        cfg.sim.appearance.validate()?;
        world.set_appearance(Some(Appearance::new(cfg.sim.appearance, cfg.sim.seed)));
    }
    if cfg.sim.layouts.enabled {
        if cfg.sim.frames != FrameMode::Render {
            return Err(SimError::Invalid(
                "[sim.layouts] enabled needs sim.frames = \"render\": replayed frames were \
                 recorded on one track"
                    .into(),
            ));
        }
        world.set_layouts(Some(cfg.sim.layouts), cfg.sim.seed)?;
    }
    Ok(SimRig {
        world,
        motors,
        hat,
        camera: cfg.sim.camera,
        path_shift_m: (0.0, 0.0),
    })
}

/// Simulated time needs no real waiting.
struct NoDelay;
impl embedded_hal::delay::DelayNs for NoDelay {
    fn delay_ns(&mut self, _ns: u32) {}
}

/// The recording for replay mode: the expert drives one lap in the rendered world, and a
/// frame is kept every `record_spacing_m` along with the pose it was taken at.
pub fn expert_lap_recording(cfg: &Config, track: &Track) -> Result<Recording, SimError> {
    let sim = &cfg.sim;
    let mut r = rig(
        cfg,
        track.clone(),
        FrameMaker::Render(renderer(sim, track)?),
    )?;
    let mut pilot = Pilot::expert(sim.expert, sim.seed);
    let lap_seconds = track.length() as f64 / sim.expert.speed_mps.max(0.05) as f64 * 1.6;
    let mut frames: Vec<RecordedFrame> = Vec::new();
    let mut last: Option<Pose2> = None;
    let mut travelled = 0.0f32;
    let (w, h) = (sim.camera.width, sim.camera.height);
    closed_loop::run(
        &mut r.world,
        &mut r.motors,
        &mut pilot,
        &sim.loop_settings(lap_seconds, cfg),
        (w, h),
        |step| {
            if let Some(p) = last {
                travelled += (step.pose.x - p.x).hypot(step.pose.y - p.y);
            }
            last = Some(step.pose);
            if frames.is_empty() || travelled >= sim.record_spacing_m {
                travelled = 0.0;
                frames.push(RecordedFrame {
                    pose: step.pose,
                    width: w,
                    height: h,
                    rgb: Arc::new(step.frame.rgb.as_ref().clone()),
                });
            }
        },
    )
    .map_err(|e| SimError::Invalid(format!("recording the expert lap: {e}")))?;
    Ok(Recording {
        camera: sim.camera,
        frames,
    })
}

/// A recording from a tub whose records carry poses; frames must have the camera's size.
pub fn tub_recording(dir: &std::path::Path, camera: &CameraModel) -> Result<Recording, SimError> {
    let file_err = |reason: String| SimError::File {
        path: dir.display().to_string(),
        reason,
    };
    let tub = crate::dataset::tub::TubReader::open(dir).map_err(|e| file_err(e.to_string()))?;
    let mut frames = Vec::new();
    for rec in tub.records() {
        let Some((x, y, heading)) = rec.pose else {
            continue;
        };
        let (w, h, rgb) = tub.load_rgb(rec).map_err(|e| file_err(e.to_string()))?;
        if (w, h) != (camera.width, camera.height) {
            return Err(file_err(format!(
                "record {}: frame is {w}x{h}, the [sim.camera] is {}x{}",
                rec.index, camera.width, camera.height
            )));
        }
        frames.push(RecordedFrame {
            pose: Pose2::new(x, y, heading),
            width: w,
            height: h,
            rgb: Arc::new(rgb),
        });
    }
    if frames.is_empty() {
        return Err(file_err(
            "no record carries a pose (pose/x, pose/y, pose/heading)".into(),
        ));
    }
    Ok(Recording {
        camera: *camera,
        frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_recording_span_keeps_the_frames_of_its_fractions() {
        let dir = std::path::Path::new("tub");
        let all: Vec<u32> = (0..10).collect();
        assert_eq!(span_of(all.clone(), [0.0, 1.0], dir).unwrap(), all);
        // The latest 30 %: frames 7, 8, 9 (round(0.7 * 10) = 7).
        assert_eq!(span_of(all.clone(), [0.7, 1.0], dir).unwrap(), [7, 8, 9]);
        assert_eq!(span_of(all.clone(), [0.25, 0.55], dir).unwrap(), [3, 4, 5]);
        // Too little left, or not a span: named.
        let err = span_of(all.clone(), [0.9, 1.0], dir)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("leaves 1 of its 10") && err.contains("tub"),
            "{err}"
        );
        for bad in [[0.5, 0.5], [-0.1, 1.0], [0.2, 1.5], [f32::NAN, 1.0]] {
            let err = span_of(all.clone(), bad, dir).unwrap_err().to_string();
            assert!(err.contains("sim.recording_span"), "{err}");
        }
    }
}
