//! The numbers of int8 quantization, pure: activation ranges from calibration statistics
//! (min-max or a percentile of a histogram), scales and zero points, per-channel symmetric
//! weights and int32 biases.
//!
//! An activation `x` in `[lo, hi]` (widened to hold 0, so zero is exact) is stored as
//! `q = clamp(round(x / scale) + zero_point)` with `scale = (hi - lo) / 255`; a weight row
//! `W_c` as `round(W_c / s_c)` with `s_c = max|W_c| / 127` and zero point 0; a bias as
//! `round(b_c / (s_x * s_c))` in int32, the scale the integer convolution accumulates in.

/// The integer type activations are stored in. Weights are always int8.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ActivationType {
    /// uint8, zero point in 0..=255 (ONNX Runtime's U8S8 kernels).
    U8,
    /// int8, zero point in -128..=127 (S8S8 kernels, preferred on some ARM cores).
    S8,
}

impl ActivationType {
    pub fn as_str(self) -> &'static str {
        match self {
            ActivationType::U8 => "uint8",
            ActivationType::S8 => "int8",
        }
    }
    fn q_min(self) -> i32 {
        match self {
            ActivationType::U8 => 0,
            ActivationType::S8 => -128,
        }
    }
}

/// Scale and zero point of one tensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QParams {
    pub scale: f32,
    pub zero_point: i32,
}

/// Asymmetric parameters for values in `[lo, hi]`, widened to hold 0.
pub fn activation_params(lo: f32, hi: f32, t: ActivationType) -> QParams {
    let lo = lo.min(0.0);
    let mut hi = hi.max(0.0);
    if !(hi - lo).is_finite() || hi - lo < 1e-8 {
        hi = lo + 1e-8;
    }
    let scale = (hi - lo) / 255.0;
    let q_min = t.q_min();
    let zero_point = (q_min as f32 - lo / scale).round() as i32;
    QParams {
        scale,
        zero_point: zero_point.clamp(q_min, q_min + 255),
    }
}

/// Per-output-channel symmetric int8 weights.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelWeights {
    pub values: Vec<i8>,
    pub scales: Vec<f32>,
}

/// Quantizes `w` (`channels` rows of equal length) to `[-q_max, q_max]` per row: 127, or 63
/// for "reduce range" (7-bit weights, for x86 kernels whose int16 sums can saturate).
pub fn quantize_weights(w: &[f32], channels: usize, q_max: i8) -> ChannelWeights {
    let per = w.len() / channels.max(1);
    let q = f32::from(q_max);
    let mut values = Vec::with_capacity(w.len());
    let mut scales = Vec::with_capacity(channels);
    for row in w.chunks(per.max(1)).take(channels) {
        let max = row.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let scale = if max > 0.0 && max.is_finite() {
            max / q
        } else {
            1.0
        };
        scales.push(scale);
        values.extend(row.iter().map(|v| (v / scale).round().clamp(-q, q) as i8));
    }
    ChannelWeights { values, scales }
}

/// int32 biases for an input scale and the weights' per-channel scales; returns the values
/// and their scales (`s_x * s_c`).
pub fn quantize_bias(b: &[f32], input_scale: f32, weight_scales: &[f32]) -> (Vec<i32>, Vec<f32>) {
    let scales: Vec<f32> = weight_scales.iter().map(|s| s * input_scale).collect();
    let values = b
        .iter()
        .zip(&scales)
        .map(|(v, s)| {
            (f64::from(*v) / f64::from(*s))
                .round()
                .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
        })
        .collect();
    (values, scales)
}

/// How an activation's range is chosen from what calibration saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RangeMethod {
    /// The smallest and largest value seen.
    MinMax,
    /// The `p` and `1 - p` quantiles of every value seen (`p` such as 0.9999): a few
    /// outliers no longer stretch the scale that every other value is rounded to.
    Percentile(f64),
}

/// Histogram of one tensor's values over a fixed `[lo, hi]` (from a min-max pass).
#[derive(Debug, Clone)]
pub struct Histogram {
    lo: f32,
    hi: f32,
    counts: Vec<u64>,
}

impl Histogram {
    pub fn new(lo: f32, hi: f32, bins: usize) -> Self {
        Self {
            lo,
            hi: if hi > lo { hi } else { lo + 1e-8 },
            counts: vec![0; bins.max(1)],
        }
    }

    pub fn add(&mut self, values: &[f32]) {
        let n = self.counts.len();
        let k = n as f32 / (self.hi - self.lo);
        for v in values {
            let i = ((v - self.lo) * k) as isize;
            self.counts[i.clamp(0, n as isize - 1) as usize] += 1;
        }
    }

    /// The value below which a share `q` of the values lie (bin upper edge for q >= 0.5,
    /// lower edge below, so both tails are cut conservatively).
    pub fn quantile(&self, q: f64) -> f32 {
        let total: u64 = self.counts.iter().sum();
        if total == 0 {
            return 0.0;
        }
        let width = (self.hi - self.lo) / self.counts.len() as f32;
        let target = (q.clamp(0.0, 1.0) * total as f64).ceil() as u64;
        let mut seen = 0u64;
        for (i, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= target.max(1) {
                let edge = if q >= 0.5 { i + 1 } else { i };
                return self.lo + width * edge as f32;
            }
        }
        self.hi
    }
}

/// Running minimum and maximum of one tensor.
#[derive(Debug, Clone, Copy)]
pub struct MinMax {
    pub min: f32,
    pub max: f32,
}

impl Default for MinMax {
    fn default() -> Self {
        Self {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
        }
    }
}

impl MinMax {
    pub fn add(&mut self, values: &[f32]) {
        for &v in values {
            if v.is_finite() {
                self.min = self.min.min(v);
                self.max = self.max.max(v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn activation_params_worked_numbers() {
        // ReLU output in [0, 5.1]: scale 0.02, zero point 0 (uint8) or -128 (int8).
        let p = activation_params(0.0, 5.1, ActivationType::U8);
        assert!((p.scale - 0.02).abs() < 1e-7 && p.zero_point == 0, "{p:?}");
        assert_eq!(
            activation_params(0.0, 5.1, ActivationType::S8).zero_point,
            -128
        );
        // [-1, 1.55]: scale 0.01, zero point round(1 / 0.01) = 100; 0 maps to 100 exactly.
        let p = activation_params(-1.0, 1.55, ActivationType::U8);
        assert!(
            (p.scale - 0.01).abs() < 1e-7 && p.zero_point == 100,
            "{p:?}"
        );
        // A range that does not hold 0 is widened to hold it.
        let p = activation_params(2.0, 2.55, ActivationType::U8);
        assert!((p.scale - 0.01).abs() < 1e-7 && p.zero_point == 0, "{p:?}");
        // A constant tensor gets a tiny positive scale, never 0 or NaN.
        assert!(activation_params(0.0, 0.0, ActivationType::U8).scale > 0.0);
    }

    #[test]
    fn weights_per_channel_and_bias_worked_numbers() {
        let w = [0.5, -1.27, 0.0, 0.02, 0.005, -0.0075];
        let q = quantize_weights(&w, 2, 127);
        // Row 0: max 1.27 -> scale 0.01; row 1: max 0.02 -> scale 0.02/127.
        assert!((q.scales[0] - 0.01).abs() < 1e-7);
        assert_eq!(&q.values[..3], &[50, -127, 0]);
        assert_eq!(&q.values[3..], &[127, 32, -48]); // 0.005 / (0.02 / 127) = 31.75; -47.625
        let reduced = quantize_weights(&w, 2, 63);
        assert_eq!(&reduced.values[..3], &[25, -63, 0]);
        // All-zero row: scale 1, values 0.
        assert_eq!(quantize_weights(&[0.0, 0.0], 1, 127).scales, vec![1.0]);
        // Bias 0.3 with input scale 0.02 and weight scale 0.01: 0.3 / 0.0002 = 1500.
        let (b, s) = quantize_bias(&[0.3, -0.1], 0.02, &[0.01, 0.05]);
        assert_eq!(b, vec![1500, -100]);
        assert!((s[0] - 2e-4).abs() < 1e-9 && (s[1] - 1e-3).abs() < 1e-9);
    }

    #[test]
    fn histogram_quantiles_cut_outliers() {
        // 10000 values spread over [0, 1) and one outlier at 100.
        let mut values: Vec<f32> = (0..10_000).map(|i| i as f32 / 10_000.0).collect();
        values.push(100.0);
        let mut mm = MinMax::default();
        mm.add(&values);
        assert_eq!((mm.min, mm.max), (0.0, 100.0));
        let mut h = Histogram::new(mm.min, mm.max, 10_000);
        h.add(&values);
        let hi = h.quantile(0.9999);
        assert!((0.99..=1.02).contains(&hi), "{hi}");
        assert_eq!(h.quantile(1.0), 100.0);
        assert_eq!(h.quantile(0.0), 0.0);
    }
}
