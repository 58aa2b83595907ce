//! The lockstep closed loop: frame -> pilot -> motor driver -> physics -> score, on a
//! simulated clock, so a run is deterministic for a seed and runs as fast as the machine
//! allows. The pilot is either the daemon's own per-frame work ([`FrameProcessor`] with a
//! policy) or the scripted expert; both write the motors through the same
//! [`MotorOutput`] (the real PCA9685 driver on the virtual HAT) under the same watchdog.

use std::sync::Arc;
use std::time::{Duration, Instant};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::Pose2;
use super::camera::CameraModel;
use super::expert::{ExpertAction, ExpertParams, Swerves, pursue};
use super::world::{StepScore, World};
use crate::camera::Frame;
use crate::clock::{Clock, SimClock};
use crate::control::WheelCommand;
use crate::drive::DriveError;
use crate::drive::stages::FrameProcessor;
use crate::drive::watchdog::Watchdog;
use crate::hw::MotorOutput;
use crate::policy::Policy;

/// Who drives.
pub enum Pilot<'a> {
    /// A policy network through the daemon's per-frame work.
    Model {
        policy: &'a mut dyn Policy,
        processor: Box<FrameProcessor>,
    },
    /// The scripted pure-pursuit expert (it sees the track, not the frames).
    Expert {
        params: ExpertParams,
        rng: Box<ChaCha8Rng>,
        swerves: Swerves,
    },
}

impl<'a> Pilot<'a> {
    pub fn expert(params: ExpertParams, seed: u64) -> Self {
        Pilot::Expert {
            params,
            rng: Box::new(ChaCha8Rng::seed_from_u64(seed)),
            swerves: Swerves::default(),
        }
    }
}

/// Loop timing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopSettings {
    /// Simulated seconds to run.
    pub seconds: f64,
    pub control_hz: f32,
    pub physics_hz: f32,
    pub watchdog: Duration,
}

/// Everything about one control step, for recorders and pictures.
pub struct StepRecord<'a> {
    pub seq: u64,
    pub time: Duration,
    /// The robot's pose when the frame was taken.
    pub pose: Pose2,
    pub frame: &'a Frame,
    /// The camera the frame was taken through (a randomised look may tilt it).
    pub camera: CameraModel,
    pub wheels: WheelCommand,
    /// The model's raw outputs (model pilot).
    pub outputs: Option<[f32; 2]>,
    /// The expert's action (expert pilot).
    pub expert: Option<ExpertAction>,
    pub score: StepScore,
}

/// Where the wall time went, in seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopTimes {
    pub frames: f64,
    pub pilot: f64,
    pub motors: f64,
    pub physics: f64,
    pub total: f64,
}

/// Runs the loop for `settings.seconds` of simulated time.
pub fn run(
    world: &mut World,
    motors: &mut dyn MotorOutput,
    pilot: &mut Pilot<'_>,
    settings: &LoopSettings,
    frame_size: (u32, u32),
    mut on_step: impl FnMut(&StepRecord<'_>),
) -> Result<LoopTimes, DriveError> {
    let clock = SimClock::new();
    let control_dt = Duration::from_secs_f64(1.0 / settings.control_hz as f64);
    let substeps = ((settings.physics_hz / settings.control_hz).round() as u32).max(1);
    let physics_dt = control_dt.as_secs_f32() / substeps as f32;
    let steps = (settings.seconds * settings.control_hz as f64).round() as u64;
    let (w, h) = frame_size;
    let mut pixels = Arc::new(vec![0u8; (w * h * 3) as usize]);
    let mut watchdog = Watchdog::new(settings.watchdog);
    let mut times = LoopTimes::default();
    let started = Instant::now();
    let result = (|| -> Result<(), DriveError> {
        for seq in 0..steps {
            let t0 = Instant::now();
            let pose = world.pose();
            match Arc::get_mut(&mut pixels) {
                Some(buf) => world.observe(buf),
                None => {
                    // Someone kept the last frame: render into a fresh buffer.
                    let mut buf = vec![0u8; (w * h * 3) as usize];
                    world.observe(&mut buf);
                    pixels = Arc::new(buf);
                }
            }
            let camera = *world.camera();
            let frame = Frame {
                seq,
                captured_at: clock.now(),
                width: w,
                height: h,
                rgb: pixels.clone(),
            };
            let t1 = Instant::now();
            let (wheels, outputs, expert) = match pilot {
                Pilot::Model { policy, processor } => {
                    let cmd = processor.process(&mut **policy, &frame, &clock)?;
                    (cmd.wheels, Some(cmd.outputs), None)
                }
                Pilot::Expert {
                    params,
                    rng,
                    swerves,
                } => {
                    let swerve = swerves.step(params, control_dt.as_secs_f32(), &mut **rng);
                    let a = pursue(
                        &world.track,
                        &pose,
                        world.robot.params(),
                        world.robot.car_params(),
                        params,
                        swerve,
                        &mut **rng,
                    );
                    (a.wheels, None, Some(a))
                }
            };
            let t2 = Instant::now();
            motors.drive(wheels)?;
            watchdog.feed(clock.now());
            let t3 = Instant::now();
            for _ in 0..substeps {
                world.advance(physics_dt);
            }
            clock.advance(control_dt);
            if watchdog.expired(clock.now()) {
                motors.stop()?;
            }
            let score = world.score();
            if score.intervention {
                // The human lifts the robot: the motors are released while it is re-centred.
                motors.stop()?;
            }
            let t4 = Instant::now();
            on_step(&StepRecord {
                seq,
                time: frame.captured_at,
                pose,
                frame: &frame,
                camera,
                wheels,
                outputs,
                expert,
                score,
            });
            drop(frame);
            times.frames += (t1 - t0).as_secs_f64();
            times.pilot += (t2 - t1).as_secs_f64();
            times.motors += (t3 - t2).as_secs_f64();
            times.physics += (t4 - t3).as_secs_f64();
        }
        Ok(())
    })();
    // Every way out ends with the motors stopped.
    let stopped = motors.stop();
    times.total = started.elapsed().as_secs_f64();
    result?;
    stopped?;
    Ok(times)
}
