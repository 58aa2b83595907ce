//! Writing simulated drives as demonstrations, in the same formats as real ones, so the
//! trainer reads sim and robot data the same way: a DonkeyCar tub v2 with everything
//! (frame, sim time, mode, the wheels sent, angle/throttle, pose, reward, JetBot target
//! label), and optionally JetBot's road-following xy folder.
//!
//! Angle and throttle from the wheel commands as the daemon's recorder stores them
//! (`crate::drive::recorder::angle_throttle`: `(left - right) / 2`, `(left + right) / 2`),
//! or, for the simulated car, the throttle and angle its channels carry
//! ([`Mixing::unmix`]). A car's tub has no `wheels/*`, as a DonkeyCar's has none: `poses`
//! and the trainer then read it as a car's without being told.

use std::path::Path;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::closed_loop::StepRecord;
use super::expert::target_label;
use crate::control::Mixing;
use crate::dataset::tub::{DriveMode, TubInputs, TubRecord, TubWriter};
use crate::dataset::{DatasetError, jetbot_xy};

/// Records simulated steps.
pub struct DemoRecorder {
    tub: TubWriter,
    xy_dir: Option<std::path::PathBuf>,
    rng: ChaCha8Rng,
    jpeg: Vec<u8>,
    written: u64,
    record_swerves: bool,
    mixing: Mixing,
}

impl DemoRecorder {
    /// `created_at` (Unix seconds) stamps the tub's session; `xy_dir` also writes JetBot's
    /// format (one file per step whose target point is in view, through the camera the step
    /// saw through). `mixing` is how the steps' wheel commands were mixed
    /// (`control.mixing`): `user/angle` and `user/throttle` are read back through it, and
    /// with [`Mixing::Car`] (the simulated car's channels carry throttle and angle, not
    /// wheels) no `wheels/*` are recorded.
    pub fn create(
        tub_dir: &Path,
        xy_dir: Option<&Path>,
        created_at: f64,
        seed: u64,
        mixing: Mixing,
    ) -> Result<Self, DatasetError> {
        if let Some(d) = xy_dir {
            std::fs::create_dir_all(d).map_err(|source| DatasetError::Io {
                path: d.display().to_string(),
                source,
            })?;
        }
        Ok(Self {
            tub: TubWriter::create(tub_dir, &Self::inputs(mixing), created_at)?,
            xy_dir: xy_dir.map(Path::to_path_buf),
            rng: ChaCha8Rng::seed_from_u64(seed),
            jpeg: Vec::new(),
            written: 0,
            record_swerves: false,
            mixing,
        })
    }

    /// The keys a drive mixed this way records: everything, less the wheels for a car.
    fn inputs(mixing: Mixing) -> TubInputs {
        TubInputs {
            wheels: mixing == Mixing::Differential,
            ..TubInputs::ALL
        }
    }

    /// Also records the expert's deliberate swerves, as a person who leaves the recorder
    /// running through the whole drive would (a continuous recording, e.g. to replay its
    /// path with `sim.road = "path"`; not demonstrations to imitate).
    pub fn record_swerves(mut self, on: bool) -> Self {
        self.record_swerves = on;
        self
    }

    /// Appends one step. The expert's steps are "user" (the human stand-in), a model's "local".
    /// The expert's deliberate swerves are left out (recording paused, as a person collecting
    /// recovery data would): only the way back is a demonstration. Unless
    /// [`Self::record_swerves`].
    pub fn append(&mut self, step: &StepRecord<'_>) -> Result<(), DatasetError> {
        if !self.record_swerves && step.expert.is_some_and(|e| e.swerving) {
            return Ok(());
        }
        let f = step.frame;
        crate::dataset::encode_jpeg(&f.rgb, f.width, f.height, &mut self.jpeg).map_err(
            |source| DatasetError::Image {
                path: "(simulated frame)".into(),
                source,
            },
        )?;
        let (throttle, angle) = self.mixing.unmix(step.wheels);
        let mode = if step.expert.is_some() {
            DriveMode::User
        } else {
            DriveMode::Local
        };
        let mut rec = TubRecord::new(step.time.as_millis() as u64, angle, throttle, mode);
        if Self::inputs(self.mixing).wheels {
            rec.wheels = Some((step.wheels.left, step.wheels.right));
        }
        rec.pose = Some((step.pose.x, step.pose.y, step.pose.heading));
        rec.reward = Some(step.score.reward);
        if step.expert.is_none() {
            rec.pilot_angle = Some(angle);
            rec.pilot_throttle = Some(throttle);
        }
        let label = step
            .expert
            .and_then(|a| target_label(&step.camera, &step.pose, a.target));
        rec.target = label;
        self.tub.append(&rec, &self.jpeg)?;
        if let (Some(dir), Some((x, y))) = (&self.xy_dir, label) {
            let (px, py) = jetbot_xy::pixel_for_label(x, y, f.width, f.height);
            let uuid = jetbot_xy::uuid_from_rng(&mut self.rng);
            jetbot_xy::write_sample(dir, px, py, &self.jpeg, &uuid)?;
        }
        self.written += 1;
        if self.written % 300 == 0 {
            self.tub.flush_and_sync()?;
        }
        Ok(())
    }

    /// Steps written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Flushes and syncs everything written.
    pub fn finish(mut self) -> Result<u64, DatasetError> {
        self.tub.flush_and_sync()?;
        Ok(self.written)
    }
}
