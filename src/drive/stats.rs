//! Latency bookkeeping for the daemon: per-stage durations and frame age, summarised as
//! median / p90 / max, both per reporting interval and for the whole run.

use std::fmt;
use std::time::Duration;

/// Keeps at most this many samples per series for the whole-run summary.
const KEEP: usize = 100_000;

/// Samples of one quantity, in milliseconds.
#[derive(Debug, Default, Clone)]
pub struct Series {
    window: Vec<f32>,
    all: Vec<f32>,
}

/// Median, p90 and max of a set of samples, in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Summary {
    pub count: usize,
    pub p50: f32,
    pub p90: f32,
    pub max: f32,
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.count == 0 {
            return write!(f, "-");
        }
        write!(
            f,
            "p50 {:.2} p90 {:.2} max {:.2} ms",
            self.p50, self.p90, self.max
        )
    }
}

/// Nearest-rank percentiles of `samples` (sorted in place).
pub fn summarise(samples: &mut [f32]) -> Summary {
    if samples.is_empty() {
        return Summary::default();
    }
    samples.sort_by(f32::total_cmp);
    let rank = |q: f32| {
        let i = ((q * samples.len() as f32).ceil() as usize).clamp(1, samples.len());
        samples[i - 1]
    };
    Summary {
        count: samples.len(),
        p50: rank(0.5),
        p90: rank(0.9),
        max: samples[samples.len() - 1],
    }
}

impl Series {
    pub fn push(&mut self, d: Duration) {
        let ms = d.as_secs_f32() * 1000.0;
        self.window.push(ms);
        if self.all.len() < KEEP {
            self.all.push(ms);
        }
    }

    /// Summary since the last call, then starts a new window.
    pub fn take_window(&mut self) -> Summary {
        let s = summarise(&mut self.window);
        self.window.clear();
        s
    }

    pub fn overall(&self) -> Summary {
        summarise(&mut self.all.clone())
    }
}

/// The stages the daemon times, plus the age of the frame when its command is written.
#[derive(Debug, Default, Clone)]
pub struct StageStats {
    pub preprocess: Series,
    pub inference: Series,
    pub control: Series,
    pub actuate: Series,
    /// Capture to motor write.
    pub frame_age: Series,
}

/// One summary per stage.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageSummary {
    pub preprocess: Summary,
    pub inference: Summary,
    pub control: Summary,
    pub actuate: Summary,
    pub frame_age: Summary,
}

impl StageStats {
    pub fn take_window(&mut self) -> StageSummary {
        StageSummary {
            preprocess: self.preprocess.take_window(),
            inference: self.inference.take_window(),
            control: self.control.take_window(),
            actuate: self.actuate.take_window(),
            frame_age: self.frame_age.take_window(),
        }
    }

    pub fn overall(&self) -> StageSummary {
        StageSummary {
            preprocess: self.preprocess.overall(),
            inference: self.inference.overall(),
            control: self.control.overall(),
            actuate: self.actuate.overall(),
            frame_age: self.frame_age.overall(),
        }
    }
}

impl fmt::Display for StageSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "  preprocess  {}", self.preprocess)?;
        writeln!(f, "  inference   {}", self.inference)?;
        writeln!(f, "  control     {}", self.control)?;
        writeln!(f, "  actuate     {}", self.actuate)?;
        write!(f, "  frame age   {}", self.frame_age)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let mut v: Vec<f32> = (1..=10).map(|x| x as f32).collect();
        v.reverse();
        let s = summarise(&mut v);
        assert_eq!(
            s,
            Summary {
                count: 10,
                p50: 5.0,
                p90: 9.0,
                max: 10.0
            }
        );
        assert_eq!(summarise(&mut []).count, 0);
        assert_eq!(summarise(&mut [3.0]).p90, 3.0);
    }

    #[test]
    fn windows_reset_but_the_run_summary_keeps_everything() {
        let mut s = Series::default();
        s.push(Duration::from_millis(2));
        s.push(Duration::from_millis(4));
        assert_eq!(s.take_window().count, 2);
        s.push(Duration::from_millis(6));
        assert_eq!(s.take_window().p50, 6.0);
        assert_eq!(s.overall().count, 3);
        assert_eq!(s.overall().max, 6.0);
    }
}
