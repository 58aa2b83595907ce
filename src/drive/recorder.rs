//! Recording demonstrations while driving, off the control path: the actuator hands each
//! step to [`Recorder::offer`], which never blocks (a bounded queue; a full queue drops the
//! step and counts it), and a writer thread JPEG-encodes the frame and appends it to an
//! [`EpisodeSink`] (a DonkeyCar tub), and optionally to JetBot's road-following folder.
//! Disk use is bounded by `max_records`; a write error (a full disk) stops recording
//! cleanly: everything already written stays readable.
//!
//! # From a gamepad command to JetBot's target point
//! JetBot's xy folder labels each frame with the point the robot should head for. A human
//! driving with sticks gives wheel commands instead, so the label is the target point that
//! makes JetBot's own law reproduce the command's steering, at a fixed look-ahead on the
//! middle row of the image:
//!
//! ```text
//! steering = (left - right) / 2            (what the law's clamp(speed +- steering) undoes)
//! angle    = steering / steering_gain      (the law: steering = angle * steering_gain, kd = 0)
//! y = 0    -> (0.5 - y) / 2 = 0.25         (look-ahead row: the middle of the image)
//! x = clamp(tan(angle) * 0.25, -1, 1)      (so that atan2(x, 0.25) = angle)
//! px = 112 + 112 x,  py = 112              (for a 224x224 frame)
//! ```

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use crate::control::WheelCommand;
use crate::dataset::DatasetError;
use crate::dataset::tub::{DriveMode, TubRecord, TubWriter};

/// One step to record.
#[derive(Debug, Clone)]
pub struct RecordStep {
    pub time_ms: u64,
    pub width: u32,
    pub height: u32,
    pub rgb: Arc<Vec<u8>>,
    /// The command that went to the motors.
    pub wheels: WheelCommand,
    pub mode: DriveMode,
    /// The autopilot's command for this frame, when it ran.
    pub pilot: Option<WheelCommand>,
    /// The steering gain in force, to turn `wheels` into a JetBot target point.
    pub steering_gain: f32,
}

/// JetBot's `(x, y)` label (each -1..1) for a wheel command; see the module doc.
pub fn target_for_wheels(w: WheelCommand, steering_gain: f32) -> (f32, f32) {
    let steering = (w.left - w.right) / 2.0;
    let angle = if steering_gain > 1e-6 {
        (steering / steering_gain).clamp(-1.5, 1.5)
    } else {
        0.0
    };
    ((angle.tan() * 0.25).clamp(-1.0, 1.0), 0.0)
}

/// Where recorded steps go (a tub; tests inject failures).
pub trait EpisodeSink: Send {
    fn append(&mut self, record: &TubRecord, jpeg: &[u8]) -> Result<u64, DatasetError>;
    fn sync(&mut self) -> Result<(), DatasetError>;
    /// Soft-deletes the last `n` records (DonkeyCar's "erase last 100" button).
    fn delete_last(&mut self, n: usize) -> Result<usize, DatasetError>;
}

impl EpisodeSink for TubWriter {
    fn append(&mut self, record: &TubRecord, jpeg: &[u8]) -> Result<u64, DatasetError> {
        TubWriter::append(self, record, jpeg)
    }
    fn sync(&mut self) -> Result<(), DatasetError> {
        self.flush_and_sync()
    }
    fn delete_last(&mut self, n: usize) -> Result<usize, DatasetError> {
        TubWriter::delete_last(self, n)
    }
}

/// What the writer thread is asked to do.
enum Msg {
    Step(RecordStep),
    EraseLast(usize),
}

/// Counters shared with the writer thread.
#[derive(Debug, Default)]
pub struct RecorderCounts {
    pub written: AtomicU64,
    pub dropped: AtomicU64,
    /// Set when recording stopped by itself (limit reached or write error).
    pub stopped: AtomicBool,
    /// Why recording stopped by itself, for the log and the web page.
    reason: std::sync::Mutex<Option<String>>,
}

impl RecorderCounts {
    /// Why recording stopped by itself (`None` while it goes on, or after a normal end).
    pub fn stop_reason(&self) -> Option<String> {
        self.reason.lock().ok().and_then(|r| r.clone())
    }

    /// Stops recording for `reason`; the first reason is kept.
    fn stop(&self, reason: String) {
        if let Ok(mut r) = self.reason.lock()
            && r.is_none()
        {
            *r = Some(reason);
        }
        self.stopped.store(true, Ordering::Relaxed);
    }
}

pub struct Recorder {
    tx: Option<SyncSender<Msg>>,
    counts: Arc<RecorderCounts>,
    thread: Option<JoinHandle<()>>,
}

/// `(angle, throttle)` from wheel commands, as DonkeyCar stores them:
/// `angle = (left - right) / 2` (positive turns right), `throttle = (left + right) / 2`.
pub fn angle_throttle(w: WheelCommand) -> (f32, f32) {
    ((w.left - w.right) / 2.0, (w.left + w.right) / 2.0)
}

impl Recorder {
    /// Starts the writer thread; at most `max_records` steps are written.
    /// `xy_dir`: also write JetBot's road-following folder (`xy_XXX_YYY_<uuid>.jpg`).
    pub fn start(
        sink: Box<dyn EpisodeSink>,
        max_records: u64,
        xy_dir: Option<std::path::PathBuf>,
    ) -> std::io::Result<Self> {
        if let Some(d) = &xy_dir {
            std::fs::create_dir_all(d)?;
        }
        let (tx, rx) = sync_channel::<Msg>(32);
        let counts = Arc::new(RecorderCounts::default());
        let c = counts.clone();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || write_loop(sink, rx, c, max_records, xy_dir))?;
        Ok(Self {
            tx: Some(tx),
            counts,
            thread: Some(thread),
        })
    }

    /// Queues a step without blocking; false when it was dropped or recording has stopped.
    pub fn offer(&self, step: RecordStep) -> bool {
        if self.counts.stopped.load(Ordering::Relaxed) {
            return false;
        }
        match self.tx.as_ref().map(|tx| tx.try_send(Msg::Step(step))) {
            Some(Ok(())) => true,
            Some(Err(TrySendError::Full(_))) | Some(Err(TrySendError::Disconnected(_))) | None => {
                self.counts.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Asks the writer to soft-delete the last `n` records (after what is queued).
    /// False when the queue is full; the button can be pressed again.
    pub fn erase_last(&self, n: usize) -> bool {
        self.tx
            .as_ref()
            .is_some_and(|tx| tx.try_send(Msg::EraseLast(n)).is_ok())
    }

    pub fn counts(&self) -> &RecorderCounts {
        &self.counts
    }

    /// Writes what is queued, syncs, and ends the thread. Returns the steps written.
    pub fn finish(mut self) -> u64 {
        self.close();
        self.counts.written.load(Ordering::Relaxed)
    }

    fn close(&mut self) {
        self.tx.take();
        if let Some(t) = self.thread.take()
            && t.join().is_err()
        {
            tracing::error!("the recorder thread panicked; records before it are kept");
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.close();
    }
}

fn write_loop(
    mut sink: Box<dyn EpisodeSink>,
    rx: Receiver<Msg>,
    counts: Arc<RecorderCounts>,
    max_records: u64,
    xy_dir: Option<std::path::PathBuf>,
) {
    // JetBot's names: uuid1, the capture time (the wall clock at the first step, moved on
    // by the steps' own clock) with a node drawn for this recording, so `score
    // --split-by-time` can order the frames and a second recording into the same folder
    // never meets the first one's names.
    // The node comes from the clock and the process, not the OS's random source (which
    // could fail): two recordings draw different nodes without any call that can panic.
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
        ^ (u64::from(std::process::id()) << 32);
    let mut names = crate::dataset::jetbot_xy::Uuid1Clock::new(
        &mut <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed),
    );
    let mut wall_at_zero: Option<std::time::Duration> = None;
    let mut jpeg = Vec::new();
    for msg in rx.iter() {
        let step = match msg {
            Msg::Step(step) => step,
            Msg::EraseLast(n) => {
                match sink.delete_last(n) {
                    Ok(k) => tracing::info!(erased = k, "erased the last records"),
                    Err(e) => tracing::error!(error = %e, "cannot erase records"),
                }
                continue;
            }
        };
        if counts.stopped.load(Ordering::Relaxed) {
            continue; // drain
        }
        if counts.written.load(Ordering::Relaxed) >= max_records {
            tracing::warn!(max_records, "recording limit reached: recording stopped");
            counts.stop(format!(
                "the limit of {max_records} records (record.max_records) is reached"
            ));
            continue;
        }
        if let Err(e) = crate::dataset::encode_jpeg(&step.rgb, step.width, step.height, &mut jpeg) {
            tracing::warn!(error = %e, "cannot encode a frame; step skipped");
            continue;
        }
        let (angle, throttle) = angle_throttle(step.wheels);
        let mut rec = TubRecord::new(step.time_ms, angle, throttle, step.mode);
        rec.wheels = Some((step.wheels.left, step.wheels.right));
        if let Some(p) = step.pilot {
            let (a, t) = angle_throttle(p);
            rec.pilot_angle = Some(a);
            rec.pilot_throttle = Some(t);
        }
        let (tx, ty) = target_for_wheels(step.wheels, step.steering_gain);
        rec.target = Some((tx, ty));
        if let Some(dir) = &xy_dir {
            let (px, py) =
                crate::dataset::jetbot_xy::pixel_for_label(tx, ty, step.width, step.height);
            let step_time = std::time::Duration::from_millis(step.time_ms);
            let zero = *wall_at_zero.get_or_insert_with(|| {
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .unwrap_or_default()
                    .saturating_sub(step_time)
            });
            let uuid = names.next(zero + step_time);
            if let Err(e) = crate::dataset::jetbot_xy::write_sample(dir, px, py, &jpeg, &uuid) {
                tracing::error!(error = %e, "recording stopped (disk full?); what was written is kept");
                counts.stop(format!("{e}; what was written is kept"));
                continue;
            }
        }
        match sink.append(&rec, &jpeg) {
            Ok(_) => {
                let n = counts.written.fetch_add(1, Ordering::Relaxed) + 1;
                if n % 100 == 0
                    && let Err(e) = sink.sync()
                {
                    tracing::warn!(error = %e, "sync failed");
                }
            }
            Err(e) => {
                tracing::error!(error = %e, "recording stopped (disk full?); what was written is kept");
                counts.stop(format!("{e}; what was written is kept"));
            }
        }
    }
    if let Err(e) = sink.sync() {
        tracing::warn!(error = %e, "final sync of the recording failed");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::tub::{TubInputs, TubReader};

    fn step(i: u64) -> RecordStep {
        RecordStep {
            time_ms: i * 33,
            width: 8,
            height: 8,
            rgb: Arc::new(vec![(i * 10) as u8; 8 * 8 * 3]),
            wheels: WheelCommand::new(0.4, 0.2),
            mode: DriveMode::User,
            pilot: None,
            steering_gain: 0.2,
        }
    }

    #[test]
    fn a_wheel_command_maps_to_the_target_point_that_reproduces_it() {
        // Straight: the middle of the image.
        assert_eq!(
            target_for_wheels(WheelCommand::new(0.3, 0.3), 0.2),
            (0.0, 0.0)
        );
        // left 0.4, right 0.2: steering 0.1, angle 0.1 / 0.2 = 0.5 rad, x = tan(0.5) / 4.
        let (x, y) = target_for_wheels(WheelCommand::new(0.4, 0.2), 0.2);
        assert!((x - 0.5f32.tan() * 0.25).abs() < 1e-6 && y == 0.0);
        // JetBot's law on that label gives the steering back.
        let angle = x.atan2((0.5 - y) / 2.0);
        assert!((angle * 0.2 - 0.1).abs() < 1e-6);
    }

    /// Five steps recorded into a new tub at `tub` and the xy folder `xy`.
    fn record_five_steps(tub: &std::path::Path, xy: &std::path::Path) {
        let tub = TubWriter::create(tub, &TubInputs::ALL, 1.0e9).unwrap();
        let rec = Recorder::start(Box::new(tub), 100, Some(xy.to_path_buf())).unwrap();
        for i in 0..5 {
            while !rec.offer(step(i)) {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        }
        assert_eq!(rec.finish(), 5);
    }

    #[test]
    fn the_jetbot_folder_is_written_too() {
        let dir = tempfile::tempdir().unwrap();
        let xy = dir.path().join("xy");
        record_five_steps(&dir.path().join("tub"), &xy);
        let folder = crate::dataset::jetbot_xy::XyFolder::open(&xy).unwrap();
        assert_eq!(folder.samples().len(), 5);
        // left 0.4, right 0.2 at steering_gain 0.2 on an 8x8 frame: px = round(4 + 4 x).
        let s = &folder.samples()[0];
        assert_eq!((s.px, s.py), (5, 4));

        // Named with uuid1 at the capture time: 33 ms apart, in order, near now.
        let mut sorted: Vec<f64> = folder
            .samples()
            .iter()
            .map(|s| {
                let name = s.path.file_name().unwrap().to_string_lossy();
                crate::dataset::jetbot_xy::capture_time_s(&name).unwrap()
            })
            .collect();
        sorted.sort_by(f64::total_cmp);
        let steps: Vec<f64> = sorted.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|d| (d - 0.033).abs() < 1e-5), "{steps:?}");
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs_f64();
        assert!(
            (now - sorted[0]).abs() < 60.0,
            "{} against now {now}",
            sorted[0]
        );

        // A second recording of the same commands into the same folder keeps both.
        record_five_steps(&dir.path().join("tub2"), &xy);
        let folder = crate::dataset::jetbot_xy::XyFolder::open(&xy).unwrap();
        assert_eq!(folder.samples().len(), 10);
    }

    #[test]
    fn records_reach_the_tub_with_angle_and_throttle() {
        let dir = tempfile::tempdir().unwrap();
        let tub = TubWriter::create(dir.path(), &TubInputs::ALL, 1.0e9).unwrap();
        let rec = Recorder::start(Box::new(tub), 1000, None).unwrap();
        for i in 0..20 {
            while !rec.offer(step(i)) {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        }
        assert_eq!(rec.finish(), 20);
        let r = TubReader::open(dir.path()).unwrap();
        let all: Vec<_> = r.records().collect();
        assert_eq!(all.len(), 20);
        // (0.4 - 0.2) / 2 = 0.1 right, (0.4 + 0.2) / 2 = 0.3 forward
        assert!((all[0].user_angle - 0.1).abs() < 1e-6);
        assert!((all[0].user_throttle - 0.3).abs() < 1e-6);
        assert_eq!(all[0].wheels, Some((0.4, 0.2)));
    }

    /// A sink that fails like a full disk after `ok` records.
    struct FullDisk {
        inner: TubWriter,
        ok: u64,
    }
    impl EpisodeSink for FullDisk {
        fn append(&mut self, r: &TubRecord, jpeg: &[u8]) -> Result<u64, DatasetError> {
            if self.inner.len() as u64 >= self.ok {
                return Err(DatasetError::Io {
                    path: "images/".into(),
                    source: std::io::Error::from_raw_os_error(28), // ENOSPC
                });
            }
            self.inner.append(r, jpeg)
        }
        fn sync(&mut self) -> Result<(), DatasetError> {
            self.inner.flush_and_sync()
        }
        fn delete_last(&mut self, n: usize) -> Result<usize, DatasetError> {
            self.inner.delete_last(n)
        }
    }

    #[test]
    fn the_erase_button_soft_deletes_the_last_records() {
        let dir = tempfile::tempdir().unwrap();
        let tub = TubWriter::create(dir.path(), &TubInputs::ALL, 1.0e9).unwrap();
        let rec = Recorder::start(Box::new(tub), 1000, None).unwrap();
        for i in 0..12 {
            while !rec.offer(step(i)) {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        }
        assert!(rec.erase_last(5));
        assert_eq!(rec.finish(), 12);
        let r = TubReader::open(dir.path()).unwrap();
        assert_eq!(
            r.records().count(),
            7,
            "deletes are soft: 12 written, 5 hidden"
        );
    }

    #[test]
    fn a_full_disk_stops_recording_and_keeps_what_was_written() {
        let dir = tempfile::tempdir().unwrap();
        let inner = TubWriter::create(dir.path(), &TubInputs::ALL, 1.0e9).unwrap();
        let rec = Recorder::start(Box::new(FullDisk { inner, ok: 7 }), 1000, None).unwrap();
        let mut offered = 0;
        for i in 0..50 {
            if rec.offer(step(i)) {
                offered += 1;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert!(offered >= 7);
        assert!(rec.counts().stopped.load(Ordering::Relaxed));
        let why = rec.counts().stop_reason().expect("a reason");
        assert!(why.contains("images/"), "{why}");
        assert!(why.contains("No space left on device"), "{why}");
        assert_eq!(rec.finish(), 7);
        assert_eq!(TubReader::open(dir.path()).unwrap().records().count(), 7);
    }

    #[test]
    fn the_record_limit_bounds_disk_use() {
        let dir = tempfile::tempdir().unwrap();
        let tub = TubWriter::create(dir.path(), &TubInputs::ALL, 1.0e9).unwrap();
        let rec = Recorder::start(Box::new(tub), 5, None).unwrap();
        for i in 0..30 {
            rec.offer(step(i));
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        // The writer sees the 6th step after the loop on a slow machine: wait for it.
        let t0 = std::time::Instant::now();
        while !rec.counts().stopped.load(Ordering::Relaxed) && t0.elapsed().as_secs() < 10 {
            rec.offer(step(99));
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert_eq!(
            rec.counts().stop_reason().as_deref(),
            Some("the limit of 5 records (record.max_records) is reached")
        );
        assert_eq!(rec.finish(), 5);
    }
}
