//! `jetpilot bench`'s CPU measurement: the frame -> command loop paced like a camera (one
//! frame per tick, sleeping until the next tick), at each requested rate, with ONNX
//! Runtime's spinning off (the daemon's default) and on. For each it reports the whole
//! process's CPU time per frame and CPU % of one core, from `/proc/self/stat`
//! ([`jetpilot::drive::usage`]), so the table shows what spinning costs between frames.
//!
//! Each frame's own time (frame -> command) is kept too: spinning trades CPU between frames
//! for the time a sleeping thread takes to wake up for the next one.
//!
//! The runs are interleaved: every combination runs once per round, the order rotating,
//! so a busy phase of the machine falls on all of them alike.

use std::time::{Duration, Instant};

use jetpilot::drive::stats::summarise;
use jetpilot::drive::usage;

/// Rounds the paced time of each combination is split into.
pub const ROUNDS: usize = 4;
/// Pause before each run, outside its window: the other session's threads stop spinning.
const SWITCH_PAUSE: Duration = Duration::from_millis(100);

/// One paced combination, summed over its rounds.
#[derive(Debug, Clone)]
pub struct Paced {
    pub fps: u32,
    pub spinning: bool,
    pub frames: usize,
    /// Frames that ended after the next tick was due (that tick then waits for the next).
    pub late: usize,
    pub wall: Duration,
    pub cpu: Duration,
    /// Each frame's frame -> command time, ms.
    pub frame_ms: Vec<f32>,
}

impl Paced {
    /// Median and p90 of the frame -> command time, ms.
    pub fn frame_p50_p90(&self) -> (f32, f32) {
        let s = summarise(&mut self.frame_ms.clone());
        (s.p50, s.p90)
    }

    pub fn cpu_ms_per_frame(&self) -> f64 {
        self.cpu.as_secs_f64() * 1e3 / self.frames.max(1) as f64
    }

    /// CPU time over wall time: 100 is one core busy all the time.
    pub fn cpu_percent(&self) -> f64 {
        100.0 * self.cpu.as_secs_f64() / self.wall.as_secs_f64().max(1e-9)
    }
}

/// Runs `step(spinning)` paced at each rate in `fps`, spinning off and on, `seconds` in all
/// per combination. Each window runs from the first tick to the end of the last frame's
/// period, so the idle time after the last frame counts.
pub fn measure(
    fps: &[u32],
    seconds: f64,
    step: &mut dyn FnMut(bool) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<Paced>> {
    let mut runs: Vec<Paced> = fps
        .iter()
        .flat_map(|&fps| {
            [false, true].map(|spinning| Paced {
                fps,
                spinning,
                frames: 0,
                late: 0,
                wall: Duration::ZERO,
                cpu: Duration::ZERO,
                frame_ms: Vec::new(),
            })
        })
        .collect();
    let n = runs.len();
    for round in 0..ROUNDS {
        for j in 0..n {
            let run = &mut runs[(round + j) % n];
            let frames = (seconds / ROUNDS as f64 * f64::from(run.fps))
                .round()
                .max(1.0) as usize;
            std::thread::sleep(SWITCH_PAUSE);
            let spinning = run.spinning;
            let (late, wall, cpu) =
                paced_window(run.fps, frames, &mut run.frame_ms, &mut || step(spinning))?;
            run.frames += frames;
            run.late += late;
            run.wall += wall;
            run.cpu += cpu;
        }
    }
    Ok(runs)
}

/// `frames` calls of `step`, one per tick of `fps`, each one's time pushed to `frame_ms`;
/// returns the late frames, the wall time and the process CPU time of the window.
fn paced_window(
    fps: u32,
    frames: usize,
    frame_ms: &mut Vec<f32>,
    step: &mut dyn FnMut() -> anyhow::Result<()>,
) -> anyhow::Result<(usize, Duration, Duration)> {
    let period = Duration::from_secs_f64(1.0 / f64::from(fps.max(1)));
    let cpu0 = usage::cpu_time()?;
    let t0 = Instant::now();
    let mut late = 0;
    let mut tick = 0u32;
    for _ in 0..frames {
        sleep_until(t0 + period * tick);
        let start = Instant::now();
        step()?;
        let now = Instant::now();
        frame_ms.push(((now - start).as_secs_f64() * 1e3) as f32);
        tick += 1;
        if now > t0 + period * tick {
            late += 1;
            // Like a camera: the frames that came meanwhile are gone; wait for the next.
            while t0 + period * tick < now {
                tick += 1;
            }
        }
    }
    sleep_until(t0 + period * tick);
    let wall = t0.elapsed();
    let cpu = usage::cpu_time()?.saturating_sub(cpu0);
    Ok((late, wall, cpu))
}

fn sleep_until(deadline: Instant) {
    let now = Instant::now();
    if deadline > now {
        std::thread::sleep(deadline - now);
    }
}

/// The paced table of one size.
pub fn print(runs: &[Paced]) {
    if runs.is_empty() {
        return;
    }
    println!(
        "  {:<44} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "paced frame -> command loop, whole process",
        "frames",
        "late",
        "fr p50",
        "fr p90",
        "CPU ms/fr",
        "CPU %"
    );
    for r in runs {
        let (p50, p90) = r.frame_p50_p90();
        println!(
            "  {:<44} {:>9} {:>9} {:>9.3} {:>9.3} {:>9.2} {:>9.1}",
            format!(
                "{} fps, spinning {}",
                r.fps,
                if r.spinning { "on" } else { "off (default)" }
            ),
            r.frames,
            r.late,
            p50,
            p90,
            r.cpu_ms_per_frame(),
            r.cpu_percent()
        );
    }
    println!(
        "  (fr: each frame's frame -> command time, ms; CPU: user + system time of all threads, \
         % of one core over the wall time)"
    );
}

/// One JSON record per paced run.
pub fn json_records(size: u32, runs: &[Paced]) -> Vec<String> {
    runs.iter()
        .map(|r| {
            let (p50, p90) = r.frame_p50_p90();
            format!(
                "    {{\"size\": {size}, \"measurement\": \"paced\", \"fps\": {}, \"spinning\": {}, \"frames\": {}, \"late_frames\": {}, \"frame_median_ms\": {p50:.4}, \"frame_p90_ms\": {p90:.4}, \"wall_s\": {:.4}, \"cpu_s\": {:.4}, \"cpu_ms_per_frame\": {:.4}, \"cpu_percent_of_one_core\": {:.2}}}",
                r.fps,
                r.spinning,
                r.frames,
                r.late,
                r.wall.as_secs_f64(),
                r.cpu.as_secs_f64(),
                r.cpu_ms_per_frame(),
                r.cpu_percent()
            )
        })
        .collect()
}
