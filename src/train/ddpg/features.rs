//! The frozen backbone: owns computing ResNet-18 features once per frame, and the actor
//! that drives with them.
//!
//! The backbone runs on ONNX Runtime, not burn: a batch-1 ResNet-18 forward pass at 96x96
//! takes about 21 ms on burn's Flex backend on this 2-core machine, while ONNX Runtime runs
//! the whole 112x112 network in 3.7 ms (`jetpilot bench`), and DDPG needs one per
//! environment step. The session's model is the actor's own ResNet-18 with `fc` replaced by the 512x512 identity, so its output *is* the pooled
//! feature vector, bit for bit what the exported actor computes before its `fc`.
//!
//! [`FeatureActor`] = backbone + a linear head `a = W f + b` (the actor's `fc`), as a
//! [`Policy`], so training-time evaluation drives through the daemon's own per-frame code.

use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::TensorRef;

use super::super::TrainError;
use crate::policy::onnx::{Resnet18Weights, encode_model, resnet18_model};
use crate::policy::{ModelContract, Policy, PolicyError, runtime};

/// Width of the feature vector.
pub const FEATURES: usize = crate::train::resnet::FEATURES;

/// ResNet-18 features on ONNX Runtime.
pub struct Backbone {
    session: Session,
    shape: [usize; 4],
}

fn ort_err(e: impl std::fmt::Display) -> TrainError {
    TrainError::Backend(format!("ONNX Runtime: {e}"))
}

impl Backbone {
    /// A session for `weights`' convolutional part (`fc` is ignored), `threads` intra-op
    /// threads that sleep rather than spin when idle (the trainer shares the cores).
    pub fn new(
        weights: &Resnet18Weights,
        contract: &ModelContract,
        threads: usize,
    ) -> Result<Self, TrainError> {
        let mut w = weights.clone();
        let mut eye = vec![0.0f32; FEATURES * FEATURES];
        for i in 0..FEATURES {
            eye[i * FEATURES + i] = 1.0;
        }
        w.tensors.insert(
            "fc.weight".into(),
            (vec![FEATURES as i64, FEATURES as i64], eye),
        );
        w.tensors.insert(
            "fc.bias".into(),
            (vec![FEATURES as i64], vec![0.0; FEATURES]),
        );
        let proto = resnet18_model(contract.input_size, &w, contract, env!("CARGO_PKG_VERSION"))?;
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
        })
    }

    /// Features of one preprocessed input (`[1,3,S,S]`, NCHW) into `out` (512 values).
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

/// A linear head on the features: `a = W f + b`, `W` stored `[2][512]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Head {
    pub weight: Vec<f32>,
    pub bias: [f32; 2],
}

impl Head {
    /// The head of `weights` (`fc.weight [2,512]`, `fc.bias [2]`, torchvision's layout).
    pub fn from_weights(weights: &Resnet18Weights) -> Result<Self, TrainError> {
        let get = |name: &str, len: usize| -> Result<Vec<f32>, TrainError> {
            let (_, v) = weights
                .tensors
                .get(name)
                .ok_or_else(|| TrainError::MissingTensor {
                    name: name.into(),
                    expected: format!("{len} values"),
                })?;
            if v.len() != len {
                return Err(TrainError::TensorShape {
                    name: name.into(),
                    expected: format!("{len} values"),
                    found: format!("{} values", v.len()),
                });
            }
            Ok(v.clone())
        };
        let weight = get("fc.weight", 2 * FEATURES)?;
        let b = get("fc.bias", 2)?;
        Ok(Self {
            weight,
            bias: [b[0], b[1]],
        })
    }

    pub fn apply(&self, f: &[f32]) -> [f32; 2] {
        let dot = |row: &[f32]| row.iter().zip(f).map(|(w, x)| w * x).sum::<f32>();
        [
            dot(&self.weight[..FEATURES]) + self.bias[0],
            dot(&self.weight[FEATURES..]) + self.bias[1],
        ]
    }

    /// `weights` with this head as `fc`.
    pub fn into_weights(&self, weights: &Resnet18Weights) -> Resnet18Weights {
        let mut w = weights.clone();
        w.tensors.insert(
            "fc.weight".into(),
            (vec![2, FEATURES as i64], self.weight.clone()),
        );
        w.tensors
            .insert("fc.bias".into(), (vec![2], self.bias.to_vec()));
        w
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
            features: vec![0.0; FEATURES],
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
