//! The frozen backbone: owns computing the pooled features once per frame (ResNet-18's
//! 512 or EfficientNet-Lite0's 1280), and the actor that drives with them.
//!
//! The backbone runs on ONNX Runtime, not burn: a batch-1 ResNet-18 forward pass at 96x96
//! takes about 21 ms on burn's Flex backend on this 2-core machine, while ONNX Runtime runs
//! the whole 112x112 network in 3.7 ms (`jetpilot bench`), and DDPG needs one per
//! environment step. The session's model is the actor's own network with its output layer
//! (`fc`, Lite0's `_fc`) replaced by the FxF identity, so its output *is* the pooled
//! feature vector, bit for bit what the exported actor computes before that layer.
//!
//! [`FeatureActor`] = backbone + a linear head `a = W f + b` (the actor's `fc`), as a
//! [`Policy`], so training-time evaluation drives through the daemon's own per-frame code.

use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::TensorRef;

use super::super::TrainError;
use crate::policy::onnx::{NetWeights, encode_model};
use crate::policy::{ModelContract, Policy, PolicyError, runtime};

/// A network's pooled features on ONNX Runtime.
pub struct Backbone {
    session: Session,
    shape: [usize; 4],
    width: usize,
}

fn ort_err(e: impl std::fmt::Display) -> TrainError {
    TrainError::Backend(format!("ONNX Runtime: {e}"))
}

impl Backbone {
    /// A session for `weights`' convolutional part (the output layer is ignored), `threads`
    /// intra-op threads that sleep rather than spin when idle (the trainer shares the cores).
    pub fn new(
        weights: &NetWeights,
        contract: &ModelContract,
        threads: usize,
    ) -> Result<Self, TrainError> {
        let width = weights.arch().features();
        let mut eye = vec![0.0f32; width * width];
        for i in 0..width {
            eye[i * width + i] = 1.0;
        }
        let proto = weights.with_head(width, eye, vec![0.0; width]).model(
            contract.input_size,
            contract,
            env!("CARGO_PKG_VERSION"),
        )?;
        let bytes = encode_model(&proto);
        let (_, env) = runtime::environment(None).map_err(ort_err)?;
        let session = Session::builder(env)
            .map_err(ort_err)?
            .with_optimization_level(GraphOptimizationLevel::Level3)
            .map_err(ort_err)?
            .with_intra_threads(threads.max(1))
            .map_err(ort_err)?
            .with_intra_op_spinning(false)
            .map_err(ort_err)?
            .commit_from_memory(&bytes)
            .map_err(ort_err)?;
        let s = contract.input_size as usize;
        Ok(Self {
            session,
            shape: [1, 3, s, s],
            width,
        })
    }

    /// How many features: 512 for ResNet-18, 1280 for EfficientNet-Lite0.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Features of one preprocessed input (`[1,3,S,S]`, NCHW) into `out` ([`Self::width`]
    /// values).
    pub fn features(&mut self, input: &[f32], out: &mut [f32]) -> Result<(), TrainError> {
        let tensor = TensorRef::from_array_view((self.shape, input)).map_err(ort_err)?;
        let outputs = self.session.run(ort::inputs![tensor]).map_err(ort_err)?;
        let (_, data) = outputs[0].try_extract_tensor::<f32>().map_err(ort_err)?;
        if data.len() != out.len() {
            return Err(ort_err(format!(
                "backbone gave {} values, expected {}",
                data.len(),
                out.len()
            )));
        }
        out.copy_from_slice(data);
        Ok(())
    }
}

/// A linear head on the features: `a = W f + b`, `W` stored `[2][F]` (torchvision's layout).
#[derive(Debug, Clone, PartialEq)]
pub struct Head {
    pub weight: Vec<f32>,
    pub bias: [f32; 2],
}

impl Head {
    /// The output layer of `weights` (`fc` for ResNet-18, `_fc` for Lite0: `[2,F]`, `[2]`).
    pub fn from_weights(weights: &NetWeights) -> Result<Self, TrainError> {
        let prefix = weights.arch().head();
        let features = weights.arch().features();
        let get = |name: String, len: usize| -> Result<Vec<f32>, TrainError> {
            let (dims, v) =
                weights
                    .tensors()
                    .get(&name)
                    .ok_or_else(|| TrainError::MissingTensor {
                        name: name.clone(),
                        expected: format!("{len} values"),
                    })?;
            if v.len() != len {
                // `[2, F*s*s]`: a head on the whole final map (`train probe --grid 2|3`).
                let whole_map = matches!(dims.as_slice(),
                    [2, w] if *w as usize > features && *w as usize % features == 0);
                let hint = if whole_map {
                    ": a head on the whole final map; DDPG's actor reads the pooled \
                     features (a pooled head, e.g. `train probe --grid 1`)"
                } else {
                    ""
                };
                return Err(TrainError::TensorShape {
                    name,
                    expected: format!("{len} values"),
                    found: format!("{} values{hint}", v.len()),
                });
            }
            Ok(v.clone())
        };
        let weight = get(format!("{prefix}.weight"), 2 * features)?;
        let b = get(format!("{prefix}.bias"), 2)?;
        Ok(Self {
            weight,
            bias: [b[0], b[1]],
        })
    }

    /// How many features it reads.
    pub fn width(&self) -> usize {
        self.weight.len() / 2
    }

    pub fn apply(&self, f: &[f32]) -> [f32; 2] {
        let dot = |row: &[f32]| row.iter().zip(f).map(|(w, x)| w * x).sum::<f32>();
        let (w0, w1) = self.weight.split_at(self.width());
        [dot(w0) + self.bias[0], dot(w1) + self.bias[1]]
    }

    /// `weights` with this head as their output layer.
    pub fn into_weights(&self, weights: &NetWeights) -> NetWeights {
        weights.with_head(2, self.weight.clone(), self.bias.to_vec())
    }
}

/// Backbone + head as a [`Policy`]: what the exported actor computes.
pub struct FeatureActor<'a> {
    pub backbone: &'a mut Backbone,
    pub head: &'a Head,
    pub contract: &'a ModelContract,
    features: Vec<f32>,
}

impl<'a> FeatureActor<'a> {
    pub fn new(backbone: &'a mut Backbone, head: &'a Head, contract: &'a ModelContract) -> Self {
        Self {
            backbone,
            head,
            contract,
            features: vec![0.0; head.width()],
        }
    }
}

impl Policy for FeatureActor<'_> {
    fn contract(&self) -> &ModelContract {
        self.contract
    }
    fn infer(&mut self, input: &[f32]) -> crate::policy::Result<[f32; 2]> {
        self.backbone
            .features(input, &mut self.features)
            .map_err(|e| PolicyError::Inference(e.to_string()))?;
        Ok(self.head.apply(&self.features))
    }
    fn describe(&self) -> String {
        "DDPG actor (ONNX Runtime backbone + linear head)".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::Arch;

    #[test]
    fn a_head_on_the_whole_map_is_refused_with_the_probe_flag_that_makes_a_pooled_one() {
        let pooled = NetWeights::random(Arch::EfficientNetLite0, 2, 3);
        let head = Head::from_weights(&pooled).unwrap();
        assert_eq!(head.width(), 1280);
        // A 2x2 map's head, as `train probe --grid 2` writes it at 64x64.
        let wide = pooled.with_head(2, vec![0.0; 2 * 1280 * 4], vec![0.0; 2]);
        let err = Head::from_weights(&wide).unwrap_err().to_string();
        assert!(
            err.contains("_fc.weight") && err.contains("10240 values") && err.contains("--grid 1"),
            "{err}"
        );
    }
}
