//! int8 quantization of a float32 model into QDQ form (QuantizeLinear/DequantizeLinear
//! around float operators), written through our own ONNX writer; `jetpilot model quantize`.
//!
//! The steps, each its own module:
//! - [`fold`]: batch normalisation folded into the convolutions (exact, pure);
//! - [`plan`]: which activations are quantized, read off the graph (pure);
//! - [`calibrate`]: the folded model run by ONNX Runtime on real frames, with every planned
//!   activation as an extra output, for its range (min-max or percentile, [`params`]);
//! - [`qdq`]: the rewrite: per-channel symmetric int8 weights, int32 biases, uint8 (or
//!   int8) activations (pure);
//! - [`calibrate::compare`]: the quantized model against the original on frames, the
//!   number the tolerance check refuses a model on.
//!
//! The model's metadata (the contract) is kept, with `jetpilot.quantization` added.

pub mod calibrate;
pub mod fold;
pub mod params;
pub mod plan;
pub mod qdq;
pub mod tensor;

use std::collections::{BTreeMap, BTreeSet};

use crate::policy::onnx::OnnxError;
use crate::policy::onnx::proto::{ModelProto, StringStringEntryProto, ValueInfoProto};

pub use params::{ActivationType, RangeMethod};
pub use plan::FloatConvs;
pub use qdq::QdqOptions;

/// Metadata key describing how a model was quantized.
pub const META_QUANTIZATION: &str = "jetpilot.quantization";

/// Errors from quantizing a model.
#[derive(Debug, thiserror::Error)]
pub enum QuantizeError {
    /// The model holds something the quantizer does not handle.
    #[error("cannot quantize: {0}")]
    Unsupported(String),
    #[error(transparent)]
    Onnx(#[from] OnnxError),
    /// ONNX Runtime failed to load or run a model.
    #[error("ONNX Runtime, {what}: {reason}")]
    Runtime { what: String, reason: String },
    #[error(transparent)]
    Policy(#[from] crate::policy::PolicyError),
}

/// A float model made ready for calibration: batch norms folded, activations planned.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub folded: ModelProto,
    pub plan: Vec<plan::Activation>,
    pub folded_batch_norms: usize,
    /// The first outputs of the convolutions that stay float32.
    pub float_convs: BTreeSet<String>,
}

impl Prepared {
    /// Folds and plans `model`, the convolutions `float` names left in float32; an opset
    /// below 13 (no per-channel QDQ) or a model with nothing to quantize is an error.
    pub fn new(model: &ModelProto, float: plan::FloatConvs) -> Result<Self, QuantizeError> {
        let opset = model
            .opset_import
            .iter()
            .find(|o| o.domain.is_empty() || o.domain == "ai.onnx")
            .map(|o| o.version)
            .unwrap_or(0);
        if opset < 13 {
            return Err(QuantizeError::Unsupported(format!(
                "the model uses opset {opset}; per-channel QuantizeLinear/DequantizeLinear needs 13 or later"
            )));
        }
        let mut folded = model.clone();
        let graph = folded
            .graph
            .as_mut()
            .ok_or_else(|| QuantizeError::Unsupported("the model has no graph".into()))?;
        let folded_batch_norms = fold::fold_batch_norms(graph)?;
        let float_convs = plan::float_convs(graph, float).map_err(QuantizeError::Unsupported)?;
        let plan = plan::activations(graph, &float_convs);
        if plan.is_empty() {
            return Err(QuantizeError::Unsupported(
                "no Conv or Add with constant weights to quantize".into(),
            ));
        }
        Ok(Self {
            folded,
            plan,
            folded_batch_norms,
            float_convs,
        })
    }

    /// The activations whose ranges calibration must measure (the others copy one).
    pub fn measured(&self) -> Vec<String> {
        self.plan
            .iter()
            .filter(|a| a.same_as.is_none())
            .map(|a| a.name.clone())
            .collect()
    }

    /// The folded model with every measured activation as an extra float output.
    pub fn instrumented(&self) -> ModelProto {
        let mut m = self.folded.clone();
        if let Some(g) = m.graph.as_mut() {
            for name in self.measured() {
                if !g.output.iter().any(|o| o.name == name) {
                    g.output.push(ValueInfoProto {
                        name,
                        ..Default::default()
                    });
                }
            }
        }
        m
    }

    /// The QDQ model for calibrated `ranges`, `note` recorded in its metadata.
    pub fn quantize(
        &self,
        ranges: &BTreeMap<String, (f32, f32)>,
        opts: QdqOptions,
        note: &str,
    ) -> Result<ModelProto, QuantizeError> {
        let table = qdq::activation_table(&self.plan, ranges, opts.activations)?;
        let mut m = self.folded.clone();
        let graph = m
            .graph
            .as_ref()
            .ok_or_else(|| QuantizeError::Unsupported("the model has no graph".into()))?;
        m.graph = Some(qdq::rewrite(graph, &table, &self.float_convs, opts)?);
        m.metadata_props.retain(|p| p.key != META_QUANTIZATION);
        m.metadata_props.push(StringStringEntryProto {
            key: META_QUANTIZATION.into(),
            value: note.into(),
        });
        Ok(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::ModelContract;
    use crate::policy::onnx::{Resnet18Weights, resnet18_model};

    /// A random ResNet-18 at 32x32, built once (11M random weights are slow in debug builds).
    fn model() -> &'static ModelProto {
        static M: std::sync::OnceLock<ModelProto> = std::sync::OnceLock::new();
        M.get_or_init(|| {
            let c = ModelContract {
                input_size: 32,
                ..Default::default()
            };
            resnet18_model(32, &Resnet18Weights::random(2, 3), &c, "t").unwrap()
        })
    }

    /// `p` quantized with every measured range `[-1, 1]`, uint8 activations, 8-bit weights.
    fn quantized(p: &Prepared) -> ModelProto {
        let ranges = p.measured().into_iter().map(|n| (n, (-1.0, 1.0))).collect();
        let opts = QdqOptions {
            activations: ActivationType::U8,
            weight_max: 127,
        };
        p.quantize(&ranges, opts, "test").unwrap()
    }

    #[test]
    fn resnet18_folds_every_batch_norm_and_rewrites_every_conv() {
        let p = Prepared::new(model(), FloatConvs::default()).unwrap();
        assert_eq!(p.folded_batch_norms, 20);
        // input, conv1's ReLU, the max pool (same as the ReLU), and per block: conv1's
        // ReLU, conv2's output, the block's ReLU; plus the three downsample convs.
        assert_eq!(p.plan.len(), 3 + 8 * 3 + 3);
        assert_eq!(p.measured().len(), p.plan.len() - 1);
        let q = quantized(&p);
        let g = q.graph.as_ref().unwrap();
        let count = |op: &str| g.node.iter().filter(|n| n.op_type == op).count();
        assert_eq!(count("Conv"), 20);
        assert_eq!(count("BatchNormalization"), 0);
        assert_eq!(count("QuantizeLinear"), p.plan.len());
        // one per activation, one per conv weight and one per conv bias
        assert_eq!(count("DequantizeLinear"), p.plan.len() + 40);
        // no float conv weight is left; the head's fc stays float
        assert!(
            g.initializer
                .iter()
                .all(|t| !t.name.ends_with("conv1.weight"))
        );
        assert!(g.initializer.iter().any(|t| t.name == "fc.weight"));
        let meta: Vec<(&str, &str)> = q
            .metadata_props
            .iter()
            .map(|p| (p.key.as_str(), p.value.as_str()))
            .collect();
        assert!(meta.contains(&(META_QUANTIZATION, "test")));
        assert!(
            meta.iter()
                .any(|(k, _)| k.starts_with("jetpilot.") && *k != META_QUANTIZATION),
            "the contract is kept"
        );
        // Every node input is defined before use.
        let mut defined: std::collections::BTreeSet<&str> =
            g.initializer.iter().map(|t| t.name.as_str()).collect();
        defined.extend(g.input.iter().map(|i| i.name.as_str()));
        for n in &g.node {
            for i in &n.input {
                assert!(
                    defined.contains(i.as_str()),
                    "`{i}` read by {} before it is defined",
                    n.name
                );
            }
            defined.extend(n.output.iter().map(String::as_str));
        }
    }

    #[test]
    fn the_last_conv_left_float_keeps_its_float_weights() {
        let all = Prepared::new(model(), FloatConvs::default()).unwrap();
        let p = Prepared::new(model(), FloatConvs { first: 0, last: 1 }).unwrap();
        assert_eq!(p.float_convs.len(), 1);
        // The last conv (layer4.1.conv2) reads conv1's ReLU (still marked by conv1); its
        // output, which the block's Add reads, is no longer quantized.
        assert_eq!(p.plan.len(), all.plan.len() - 1);
        let q = quantized(&p);
        let g = q.graph.as_ref().unwrap();
        let count = |op: &str| g.node.iter().filter(|n| n.op_type == op).count();
        assert_eq!(count("DequantizeLinear"), p.plan.len() + 38);
        let last = g
            .node
            .iter()
            .find(|n| n.op_type == "Conv" && p.float_convs.contains(&n.output[0]))
            .unwrap();
        assert!(
            last.input[0].ends_with("_dequantized"),
            "it reads int8 values"
        );
        for w in &last.input[1..] {
            assert!(!w.ends_with("_dequantized"), "{w}");
            let t = g.initializer.iter().find(|t| &t.name == w).unwrap();
            assert_eq!(t.data_type, 1, "{w} stays float32");
        }
        let err = Prepared::new(model(), FloatConvs { first: 0, last: 20 })
            .unwrap_err()
            .to_string();
        assert!(err.contains("has 20 convolutions"), "{err}");
    }

    #[test]
    fn an_old_opset_is_refused_with_its_number() {
        let mut model = model().clone();
        model.opset_import[0].version = 11;
        let err = Prepared::new(&model, FloatConvs::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("opset 11"), "{err}");
    }
}
