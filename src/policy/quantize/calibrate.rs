//! ONNX Runtime's side of quantizing: the folded model run on calibration frames with its
//! planned activations as outputs (their ranges), and two models compared on frames.

use std::collections::BTreeMap;

use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::TensorRef;

use super::params::{Histogram, MinMax, RangeMethod};
use super::{Prepared, QuantizeError};
use crate::policy::onnx::{ModelProto, encode_model};
use crate::policy::runtime;

/// Histogram bins per activation for percentile ranges.
const BINS: usize = 4096;

/// One model in an ONNX Runtime session on the CPU, fed `[1, 3, size, size]` frames.
pub struct Runner {
    session: Session,
    shape: [usize; 4],
    what: String,
}

impl Runner {
    /// `what` names the model in errors ("the quantized model").
    pub fn new(
        model: &ModelProto,
        input_size: u32,
        threads: usize,
        what: &str,
    ) -> Result<Self, QuantizeError> {
        let err = |e: &dyn std::fmt::Display| QuantizeError::Runtime {
            what: what.to_string(),
            reason: e.to_string(),
        };
        let (_, env) = runtime::environment(None)?;
        let mut builder =
            runtime::session_builder(env, GraphOptimizationLevel::Level3, threads, false)
                .map_err(|e| err(&e))?;
        let session = builder
            .commit_from_memory(&encode_model(model))
            .map_err(|e| err(&e))?;
        let s = input_size as usize;
        Ok(Self {
            session,
            shape: [1, 3, s, s],
            what: what.to_string(),
        })
    }

    /// Runs one frame and hands each named output's values to `each`.
    pub fn run(
        &mut self,
        input: &[f32],
        names: &[String],
        mut each: impl FnMut(usize, &[f32]),
    ) -> Result<(), QuantizeError> {
        let err = |reason: String| QuantizeError::Runtime {
            what: self.what.clone(),
            reason,
        };
        let tensor =
            TensorRef::from_array_view((self.shape, input)).map_err(|e| err(e.to_string()))?;
        let outputs = self
            .session
            .run(ort::inputs![tensor])
            .map_err(|e| err(e.to_string()))?;
        for (i, name) in names.iter().enumerate() {
            let value = outputs
                .get(name)
                .ok_or_else(|| err(format!("no output `{name}`")))?;
            let (_, data) = value
                .try_extract_tensor::<f32>()
                .map_err(|e| err(e.to_string()))?;
            each(i, data);
        }
        Ok(())
    }

    /// The first output's values for one frame.
    pub fn first_output(&mut self, input: &[f32]) -> Result<Vec<f32>, QuantizeError> {
        let name = self
            .session
            .outputs()
            .first()
            .map(|o| o.name().to_string())
            .ok_or_else(|| QuantizeError::Runtime {
                what: self.what.clone(),
                reason: "the model has no output".into(),
            })?;
        let mut out = Vec::new();
        self.run(input, &[name], |_, v| out = v.to_vec())?;
        Ok(out)
    }
}

/// Each measured activation's `[lo, hi]` over `frames`: min-max in one pass, or the
/// percentile's quantiles of a histogram over the min-max range in a second.
pub fn ranges(
    prepared: &Prepared,
    input_size: u32,
    frames: &[Vec<f32>],
    method: RangeMethod,
    threads: usize,
) -> Result<BTreeMap<String, (f32, f32)>, QuantizeError> {
    let names = prepared.measured();
    let mut runner = Runner::new(
        &prepared.instrumented(),
        input_size,
        threads,
        "the model prepared for calibration",
    )?;
    let mut minmax = vec![MinMax::default(); names.len()];
    for f in frames {
        runner.run(f, &names, |i, v| minmax[i].add(v))?;
    }
    let mut out = BTreeMap::new();
    match method {
        RangeMethod::MinMax => {
            for (name, mm) in names.iter().zip(&minmax) {
                out.insert(name.clone(), finite(mm));
            }
        }
        RangeMethod::Percentile(p) => {
            let mut hists: Vec<Histogram> = minmax
                .iter()
                .map(|mm| {
                    let (lo, hi) = finite(mm);
                    Histogram::new(lo, hi, BINS)
                })
                .collect();
            for f in frames {
                runner.run(f, &names, |i, v| hists[i].add(v))?;
            }
            for (name, h) in names.iter().zip(&hists) {
                out.insert(name.clone(), (h.quantile(1.0 - p), h.quantile(p)));
            }
        }
    }
    Ok(out)
}

fn finite(mm: &MinMax) -> (f32, f32) {
    if mm.min <= mm.max {
        (mm.min, mm.max)
    } else {
        (0.0, 0.0)
    }
}

/// How far two models' first outputs lie apart over some frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Difference {
    /// The largest absolute difference of any output on any frame.
    pub max: f32,
    /// The mean absolute difference over every output of every frame.
    pub mean: f32,
    pub frames: usize,
}

/// Runs both models on every frame and measures their outputs' difference.
pub fn compare(
    a: &mut Runner,
    b: &mut Runner,
    frames: &[Vec<f32>],
) -> Result<Difference, QuantizeError> {
    let (mut max, mut sum, mut n) = (0.0f32, 0.0f64, 0usize);
    for f in frames {
        let (x, y) = (a.first_output(f)?, b.first_output(f)?);
        for (u, v) in x.iter().zip(&y) {
            let d = (u - v).abs();
            max = if d.is_nan() {
                f32::INFINITY
            } else {
                max.max(d)
            };
            sum += f64::from(d);
            n += 1;
        }
    }
    Ok(Difference {
        max,
        mean: if n > 0 { (sum / n as f64) as f32 } else { 0.0 },
        frames: frames.len(),
    })
}

/// The operators ONNX Runtime actually runs for `model` on the CPU after its graph
/// level-2 optimisations, the ones that fuse QDQ groups (QLinearConv where a QDQ convolution was fused, Conv where it was not).
pub fn optimized_op_counts(model: &ModelProto) -> Result<BTreeMap<String, usize>, QuantizeError> {
    let dir = tempfile::tempdir().map_err(|e| QuantizeError::Runtime {
        what: "the optimised model".into(),
        reason: format!("no temporary folder: {e}"),
    })?;
    let path = dir.path().join("optimized.onnx");
    let err = |e: &dyn std::fmt::Display| QuantizeError::Runtime {
        what: "the optimised model".into(),
        reason: e.to_string(),
    };
    let (_, env) = runtime::environment(None)?;
    // Level 2 holds the QDQ fusions; level 3 adds layout changes specific to this CPU
    // (and a warning when saved).
    let mut builder = runtime::session_builder(env, GraphOptimizationLevel::Level2, 0, false)
        .and_then(|b| b.with_optimized_model_path(&path).map_err(Into::into))
        .map_err(|e| err(&e))?;
    let session = builder
        .commit_from_memory(&encode_model(model))
        .map_err(|e| err(&e))?;
    drop(session);
    let summary = crate::policy::onnx::inspect_file(&path)?;
    Ok(summary.op_counts)
}
