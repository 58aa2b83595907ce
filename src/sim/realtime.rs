//! The simulator in real time, under the real daemon: [`SimSource`] is a [`FrameSource`]
//! that shows the camera view at the robot's current pose, paced by the wall clock, and a
//! physics thread moves the robot with whatever the daemon's motor driver wrote into the
//! virtual PCA9685. So `drive::run` — its capture thread, latest-frame slot, inference
//! thread, actuator, watchdog and fault handling — drives the simulated car unchanged.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use super::Pose2;
use super::world::World;
use crate::camera::{Frame, FrameSource, Result as CameraResult};
use crate::clock::Clock;

/// A shared world, locked briefly by the frame source and the physics thread.
pub type SharedWorld = Arc<Mutex<World>>;

fn lock(world: &SharedWorld) -> MutexGuard<'_, World> {
    world.lock().unwrap_or_else(|p| p.into_inner())
}

/// Camera frames from the simulated world at `fps`, in real time.
pub struct SimSource {
    world: SharedWorld,
    clock: Arc<dyn Clock>,
    size: (u32, u32),
    period: Duration,
    next_due: Option<Instant>,
    seq: u64,
}

impl SimSource {
    pub fn new(world: SharedWorld, clock: Arc<dyn Clock>, size: (u32, u32), fps: f32) -> Self {
        Self {
            world,
            clock,
            size,
            period: Duration::from_secs_f64(1.0 / fps.max(0.1) as f64),
            next_due: None,
            seq: 0,
        }
    }
}

impl FrameSource for SimSource {
    fn next_frame(&mut self) -> CameraResult<Option<Frame>> {
        let due = self.next_due.unwrap_or_else(Instant::now);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        self.next_due = Some(due + self.period);
        let (w, h) = self.size;
        let mut rgb = vec![0u8; (w * h * 3) as usize];
        lock(&self.world).observe(&mut rgb);
        let frame = Frame {
            seq: self.seq,
            captured_at: self.clock.now(),
            width: w,
            height: h,
            rgb: Arc::new(rgb),
        };
        self.seq += 1;
        Ok(Some(frame))
    }

    fn describe(&self) -> String {
        format!(
            "simulated camera {}x{} at {:.0} fps (real time)",
            self.size.0,
            self.size.1,
            1.0 / self.period.as_secs_f64()
        )
    }
}

/// What the physics thread saw of a drive: for the top-down trace of `sim --realtime --png`.
#[derive(Debug, Clone, Default)]
pub struct DriveTrace {
    /// (simulated seconds, pose), ten a second.
    pub poses: Vec<(f64, Pose2)>,
    /// When each intervention happened, in the order of the world's `intervention_poses`.
    pub intervention_times: Vec<f64>,
}

/// Steps the physics at `physics_hz` in real time and scores every control period, until
/// `stop` is set; the thread's result is the drive's [`DriveTrace`].
pub fn spawn_physics(
    world: SharedWorld,
    physics_hz: f32,
    control_hz: f32,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<DriveTrace>> {
    let dt = Duration::from_secs_f64(1.0 / physics_hz as f64);
    let per_score = ((physics_hz / control_hz).round() as u32).max(1);
    let per_pose = ((physics_hz / 10.0).round() as u32).max(1);
    std::thread::Builder::new()
        .name("sim-physics".into())
        .spawn(move || {
            let mut trace = DriveTrace::default();
            let mut due = Instant::now();
            let mut n = 0u32;
            while !stop.load(Ordering::Relaxed) {
                {
                    let mut w = lock(&world);
                    w.advance(dt.as_secs_f32());
                    n += 1;
                    if n % per_score == 0 && w.score().intervention {
                        trace.intervention_times.push(w.stats.time_s);
                    }
                    if n % per_pose == 0 {
                        trace.poses.push((w.stats.time_s, w.pose()));
                    }
                }
                due += dt;
                let now = Instant::now();
                if due > now {
                    std::thread::sleep(due - now);
                } else if now - due > Duration::from_millis(100) {
                    due = now; // fell behind: do not try to catch up in a burst
                }
            }
            trace
        })
}
