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

/// Upper bounds, in milliseconds, of the latency histograms' buckets (`+Inf` is implied).
pub const BUCKETS_MS: [f64; 12] = [
    1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 50.0, 75.0, 100.0, 200.0, 500.0, 1000.0,
];

/// A cumulative latency histogram for the whole run (Prometheus style: each bucket counts
/// the samples at or below its bound).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Histogram {
    /// Samples at or below `BUCKETS_MS[i]`.
    pub le: [u64; BUCKETS_MS.len()],
    pub count: u64,
    pub sum_ms: f64,
}

impl Histogram {
    pub fn observe(&mut self, d: Duration) {
        let ms = d.as_secs_f64() * 1000.0;
        for (n, bound) in self.le.iter_mut().zip(BUCKETS_MS) {
            if ms <= bound {
                *n += 1;
            }
        }
        self.count += 1;
        self.sum_ms += ms;
    }

    /// The mean of the samples added since `earlier` (a previous copy), in ms.
    pub fn mean_since(&self, earlier: &Histogram) -> Option<f64> {
        let n = self.count.checked_sub(earlier.count)?;
        (n > 0).then(|| (self.sum_ms - earlier.sum_ms) / n as f64)
    }
}

/// One histogram per stage.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageHistograms {
    pub preprocess: Histogram,
    pub inference: Histogram,
    pub control: Histogram,
    pub actuate: Histogram,
    pub frame_age: Histogram,
}

impl StageHistograms {
    /// `(stage name, histogram)` in pipeline order.
    pub fn named(&self) -> [(&'static str, &Histogram); 5] {
        [
            ("preprocess", &self.preprocess),
            ("inference", &self.inference),
            ("control", &self.control),
            ("actuate", &self.actuate),
            ("frame_age", &self.frame_age),
        ]
    }
}

#[cfg(test)]
mod histogram_tests {
    use super::*;

    #[test]
    fn buckets_are_cumulative_and_the_mean_is_over_new_samples() {
        let mut h = Histogram::default();
        h.observe(Duration::from_micros(1500)); // 1.5 ms: le 2 and up
        h.observe(Duration::from_millis(40)); // le 50 and up
        assert_eq!(h.le[0], 0);
        assert_eq!(h.le[1], 1);
        assert_eq!(h.le[5], 1); // le 30
        assert_eq!(h.le[6], 2); // le 50
        assert_eq!(h.le[11], 2);
        assert_eq!(h.count, 2);
        assert!((h.sum_ms - 41.5).abs() < 1e-9);
        let before = h;
        assert_eq!(h.mean_since(&before), None);
        h.observe(Duration::from_millis(10));
        h.observe(Duration::from_millis(20));
        assert!((h.mean_since(&before).unwrap() - 15.0).abs() < 1e-9);
        // Past the last bound: only in count (+Inf).
        let mut big = Histogram::default();
        big.observe(Duration::from_secs(2));
        assert_eq!(big.le, [0; 12]);
        assert_eq!(big.count, 1);
    }
}
