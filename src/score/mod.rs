//! Scoring a policy on labelled frames (`jetpilot score`): how far its outputs are from
//! what people labelled, beside what always answering the average label would score.
//!
//! This module owns the pure arithmetic; `cli/score.rs` reads the frames and runs the
//! model, [`sheet`] draws the picture, [`explain`] makes the occlusion maps of `--explain`.
//! [`contact`] draws `sim --png --real`'s sheet: sim views above real frames.
//!
//! - `xy` heads (JetBot's target point): the distance between the predicted and the
//!   labelled point in pixels of JetBot's 224x224 frame, `112 * |p - l|` for labels in
//!   -1..1, summarised by mean, median and 90th percentile.
//! - `speed_steering` heads: the mean squared error of each output.
//!
//! The mean-label baseline predicts one constant, the mean label of the frames it is given
//! (the training part of a split by time, so the baseline never sees the test labels).
//! [`agreement`] measures how far a folder's labels disagree on near-duplicate frames: the
//! error no model can be expected to beat there.

pub mod agreement;
pub mod contact;
pub mod explain;
pub mod sheet;

use std::fmt;

use crate::policy::OutputKind;

/// JetBot's frame: labels are pixels of a 224x224 image.
pub const JETBOT_FRAME_PX: f32 = 224.0;

/// The distance between two points given in -1..1 coordinates, in pixels of a square
/// frame of `frame_px`.
pub fn pixel_error(label: [f32; 2], prediction: [f32; 2], frame_px: f32) -> f64 {
    let half = frame_px as f64 / 2.0;
    let dx = (prediction[0] - label[0]) as f64 * half;
    let dy = (prediction[1] - label[1]) as f64 * half;
    dx.hypot(dy)
}

/// The mean of each label component; `[0, 0]` for no labels.
pub fn mean_label(labels: &[[f32; 2]]) -> [f32; 2] {
    if labels.is_empty() {
        return [0.0; 2];
    }
    let n = labels.len() as f64;
    let sum = labels
        .iter()
        .fold([0.0f64; 2], |a, l| [a[0] + l[0] as f64, a[1] + l[1] as f64]);
    [(sum[0] / n) as f32, (sum[1] / n) as f32]
}

/// Mean, median and 90th percentile (nearest rank) of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub mean: f64,
    pub median: f64,
    pub p90: f64,
}

impl Spread {
    /// `None` for an empty set.
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        };
        let rank = ((0.9 * n as f64).ceil() as usize).clamp(1, n);
        Some(Self {
            mean: v.iter().sum::<f64>() / n as f64,
            median,
            p90: v[rank - 1],
        })
    }
}

/// How close a set of predictions is to its labels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Accuracy {
    /// Pixel errors in the 224x224 frame (xy heads).
    Pixels(Spread),
    /// Mean squared error of speed and of steering (speed_steering heads).
    Mse([f64; 2]),
}

impl Accuracy {
    /// The number the comparison with the baseline uses: the mean pixel error, or the mean
    /// of the two MSEs.
    pub fn headline(&self) -> f64 {
        match self {
            Self::Pixels(s) => s.mean,
            Self::Mse(m) => (m[0] + m[1]) / 2.0,
        }
    }
}

impl fmt::Display for Accuracy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Pixels(s) => write!(
                f,
                "mean {:.1} px, median {:.1} px, p90 {:.1} px",
                s.mean, s.median, s.p90
            ),
            Self::Mse(m) => write!(f, "MSE speed {:.4}, steering {:.4}", m[0], m[1]),
        }
    }
}

/// Per-frame error: pixels for xy heads, the mean of the two squared errors otherwise.
pub fn frame_error(output: OutputKind, label: [f32; 2], prediction: [f32; 2]) -> f64 {
    match output {
        OutputKind::Xy => pixel_error(label, prediction, JETBOT_FRAME_PX),
        OutputKind::SpeedSteering => {
            let e0 = (prediction[0] - label[0]) as f64;
            let e1 = (prediction[1] - label[1]) as f64;
            (e0 * e0 + e1 * e1) / 2.0
        }
    }
}

/// The accuracy of `predictions` against `labels` (same length, at least one).
pub fn accuracy(output: OutputKind, labels: &[[f32; 2]], predictions: &[[f32; 2]]) -> Accuracy {
    debug_assert_eq!(labels.len(), predictions.len());
    match output {
        OutputKind::Xy => {
            let errors: Vec<f64> = labels
                .iter()
                .zip(predictions)
                .map(|(l, p)| pixel_error(*l, *p, JETBOT_FRAME_PX))
                .collect();
            Accuracy::Pixels(Spread::of(&errors).unwrap_or(Spread {
                mean: 0.0,
                median: 0.0,
                p90: 0.0,
            }))
        }
        OutputKind::SpeedSteering => {
            let n = labels.len().max(1) as f64;
            let mut sum = [0.0f64; 2];
            for (l, p) in labels.iter().zip(predictions) {
                for k in 0..2 {
                    sum[k] += ((p[k] - l[k]) as f64).powi(2);
                }
            }
            Accuracy::Mse([sum[0] / n, sum[1] / n])
        }
    }
}

/// A model's accuracy beside the mean-label baseline's on the same frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scorecard {
    pub frames: usize,
    pub model: Accuracy,
    /// The constant the baseline predicts.
    pub baseline_label: [f32; 2],
    pub baseline: Accuracy,
}

impl Scorecard {
    /// Scores `predictions`; the baseline predicts `baseline_label` for every frame.
    pub fn new(
        output: OutputKind,
        labels: &[[f32; 2]],
        predictions: &[[f32; 2]],
        baseline_label: [f32; 2],
    ) -> Self {
        let constant = vec![baseline_label; labels.len()];
        Self {
            frames: labels.len(),
            model: accuracy(output, labels, predictions),
            baseline_label,
            baseline: accuracy(output, labels, &constant),
        }
    }

    /// The model's headline error as a fraction of the baseline's (below 1: better than
    /// always answering the mean label).
    pub fn ratio(&self) -> f64 {
        self.model.headline() / self.baseline.headline().max(1e-12)
    }
}

/// Whether a model follows the labels at all, per output: the spread of the labels and of
/// the predictions (standard deviations) and their Pearson correlation. A model that has
/// learnt nothing that holds on these frames answers nearly the same everywhere: a small
/// prediction spread and a correlation near 0, whatever its mean error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tracking {
    pub label_sd: [f64; 2],
    pub prediction_sd: [f64; 2],
    /// `None` where either side does not vary.
    pub correlation: [Option<f64>; 2],
}

impl Tracking {
    /// Over paired `labels` and `predictions` (in the outputs' own units).
    pub fn of(labels: &[[f32; 2]], predictions: &[[f32; 2]]) -> Self {
        debug_assert_eq!(labels.len(), predictions.len());
        let n = labels.len().max(1) as f64;
        let mut out = Self {
            label_sd: [0.0; 2],
            prediction_sd: [0.0; 2],
            correlation: [None; 2],
        };
        for k in 0..2 {
            let mean = |v: &[[f32; 2]]| v.iter().map(|x| x[k] as f64).sum::<f64>() / n;
            let (ml, mp) = (mean(labels), mean(predictions));
            let (mut sll, mut spp, mut slp) = (0.0, 0.0, 0.0);
            for (l, p) in labels.iter().zip(predictions) {
                let (dl, dp) = (l[k] as f64 - ml, p[k] as f64 - mp);
                sll += dl * dl;
                spp += dp * dp;
                slp += dl * dp;
            }
            out.label_sd[k] = (sll / n).sqrt();
            out.prediction_sd[k] = (spp / n).sqrt();
            out.correlation[k] = (sll > 1e-12 && spp > 1e-12).then(|| slp / (sll * spp).sqrt());
        }
        out
    }

    /// Standard deviations scaled (`112`: xy labels in -1..1 to pixels of JetBot's frame).
    pub fn scaled(self, by: f64) -> Self {
        Self {
            label_sd: self.label_sd.map(|v| v * by),
            prediction_sd: self.prediction_sd.map(|v| v * by),
            ..self
        }
    }
}

impl fmt::Display for Tracking {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // The spreads to `{:.N}` decimals (3 unless given); correlations to 2.
        let d = f.precision().unwrap_or(3);
        let r = |c: Option<f64>| c.map_or("-".to_string(), |c| format!("{c:.2}"));
        write!(
            f,
            "labels sd ({:.d$}, {:.d$}), predictions sd ({:.d$}, {:.d$}), correlation ({}, {})",
            self.label_sd[0],
            self.label_sd[1],
            self.prediction_sd[0],
            self.prediction_sd[1],
            r(self.correlation[0]),
            r(self.correlation[1])
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracking_worked_numbers() {
        // x: labels -0.5, 0.5, 0, 0 (sd sqrt(0.125) = 0.354); predictions half of them,
        // so sd 0.177 and correlation 1. y: predictions constant, so no correlation.
        let labels = [[-0.5, 0.2], [0.5, -0.2], [0.0, 0.2], [0.0, -0.2]];
        let preds = [[-0.25, 0.1], [0.25, 0.1], [0.0, 0.1], [0.0, 0.1]];
        let t = Tracking::of(&labels, &preds);
        assert!((t.label_sd[0] - 0.125f64.sqrt()).abs() < 1e-6, "{t:?}");
        assert!((t.prediction_sd[0] - 0.125f64.sqrt() / 2.0).abs() < 1e-6);
        assert!((t.correlation[0].unwrap() - 1.0).abs() < 1e-6);
        assert!((t.label_sd[1] - 0.2).abs() < 1e-6 && t.prediction_sd[1] < 1e-7);
        assert_eq!(t.correlation[1], None);
        // Opposite predictions: -1. In pixels: 0.2 * 112 = 22.4.
        let flipped: Vec<[f32; 2]> = labels.iter().map(|l| [-l[0], -l[1]]).collect();
        let t = Tracking::of(&labels, &flipped).scaled(112.0);
        assert!((t.correlation[1].unwrap() + 1.0).abs() < 1e-6);
        assert!((t.label_sd[1] - 22.4).abs() < 1e-4);
        assert_eq!(
            format!("{t:.1}"),
            "labels sd (39.6, 22.4), predictions sd (39.6, 22.4), correlation (-1.00, -1.00)"
        );
    }

    #[test]
    fn pixel_errors_are_in_jetbots_224_frame() {
        // (0.5, 0) vs (0, 0): 0.5 * 112 = 56 px; a 3-4-5 triangle of 0.3/0.4: 0.5 * 112.
        assert!((pixel_error([0.0, 0.0], [0.5, 0.0], 224.0) - 56.0).abs() < 1e-9);
        assert!((pixel_error([0.1, 0.1], [0.4, 0.5], 224.0) - 56.0).abs() < 1e-4);
    }

    #[test]
    fn spread_worked_numbers() {
        let s = Spread::of(&[4.0, 1.0, 3.0, 2.0]).unwrap();
        assert_eq!((s.mean, s.median, s.p90), (2.5, 2.5, 4.0));
        let s = Spread::of(&(1..=10).map(f64::from).collect::<Vec<_>>()).unwrap();
        assert_eq!((s.median, s.p90), (5.5, 9.0));
        assert_eq!(Spread::of(&[]), None);
    }

    #[test]
    fn the_baseline_predicts_the_mean_label() {
        let labels = [[-0.5, 0.0], [0.5, 0.0]];
        assert_eq!(mean_label(&labels), [0.0, 0.0]);
        // A perfect model against the baseline, which is 0.5 * 112 = 56 px off on both.
        let card = Scorecard::new(OutputKind::Xy, &labels, &labels, mean_label(&labels));
        assert_eq!(
            card.model,
            Accuracy::Pixels(Spread {
                mean: 0.0,
                median: 0.0,
                p90: 0.0
            })
        );
        assert!((card.baseline.headline() - 56.0).abs() < 1e-9);
        assert_eq!(card.ratio(), 0.0);
        // speed_steering: MSE per output; speed off by 0.2 and 0.0, steering by 0.1 and 0.3.
        let preds = [[0.7, 0.1], [0.5, -0.3]];
        let labels = [[0.5, 0.0], [0.5, 0.0]];
        let Accuracy::Mse(m) = accuracy(OutputKind::SpeedSteering, &labels, &preds) else {
            panic!("mse")
        };
        assert!(
            (m[0] - 0.02).abs() < 1e-7 && (m[1] - 0.05).abs() < 1e-7,
            "{m:?}"
        );
    }
}
