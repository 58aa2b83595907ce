//! ResNet-18 as a burn [`Module`], in torchvision's layout, with import from and export to
//! the ONNX writer's [`Resnet18Weights`] (torchvision `state_dict` names and shapes).
//!
//! ```text
//! x [B,3,H,W]
//!  -> conv1 7x7/2 pad 3 (64, no bias) -> bn1 -> relu -> maxpool 3x3/2 pad 1  [B,64,H/4,W/4]
//!  -> layer1 (64) -> layer2 (128, /2) -> layer3 (256, /2) -> layer4 (512, /2) [B,512,H/32,W/32]
//!  -> adaptive average pool to 1x1 -> flatten                                 [B,512] features
//!  -> fc 512 -> N                                                             [B,N]
//! ```
//!
//! Each layer holds two BasicBlocks (conv3x3 -> BN -> relu -> conv3x3 -> BN, plus the
//! identity, then relu); the first block of layers 2-4 has stride 2 and a `downsample`
//! (conv1x1/2 -> BN) on its identity path.
//!
//! BatchNorm: epsilon 1e-5, momentum 0.1. burn's convention is PyTorch's:
//! `running = (1 - momentum) * running + momentum * batch`, so torchvision's 0.1 is burn's
//! 0.1 (ONNX's `momentum` attribute is the other way round, 0.9 in our exports; it does not
//! matter for inference). A BatchNorm uses batch statistics and updates its running
//! statistics only when the input lives on an autodiff device (`device.autodiff()`) *and*
//! the module is in training mode; on a plain device, or after [`Module::valid`], it uses
//! the running statistics, as ONNX Runtime does.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use burn::module::{Module, Param, RunningState};
use burn::nn::conv::Conv2d;
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig, MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, Linear, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use prost::Message;
use prost::bytes::Bytes;

use super::TrainError;
use crate::policy::ModelContract;
use crate::policy::onnx::proto::{ModelProto, TensorProto};
use crate::policy::onnx::{Dim, Resnet18Weights, inspect_bytes};

/// BatchNorm epsilon (torchvision and our ONNX exports).
pub const BN_EPSILON: f64 = 1e-5;
/// BatchNorm momentum in burn's (= PyTorch's) convention: the weight of the batch statistic.
pub const BN_MOMENTUM: f64 = 0.1;
/// Width of the pooled features that enter `fc`.
pub const FEATURES: usize = 512;

/// `downsample.0` (conv1x1/2, no bias) and `downsample.1` (BN) of a block's identity path.
#[derive(Module, Debug)]
pub struct Downsample {
    pub conv: Conv2d,
    pub bn: BatchNorm,
}

/// torchvision's `BasicBlock` (expansion 1).
#[derive(Module, Debug)]
pub struct BasicBlock {
    pub conv1: Conv2d,
    pub bn1: BatchNorm,
    pub conv2: Conv2d,
    pub bn2: BatchNorm,
    pub downsample: Option<Downsample>,
}

impl BasicBlock {
    /// `[B,C_in,H,W] -> [B,C,H/s,W/s]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let identity = match &self.downsample {
            Some(d) => d.bn.forward(d.conv.forward(x.clone())), // [B,C,H/2,W/2]
            None => x.clone(),                                  // [B,C,H,W]
        };
        let out = relu(self.bn1.forward(self.conv1.forward(x))); // [B,C,H/s,W/s]
        let out = self.bn2.forward(self.conv2.forward(out)); // [B,C,H/s,W/s]
        relu(out.add(identity))
    }
}

/// ResNet-18 in torchvision's layout; `layerK[b]` is torchvision's `layerK.b`.
#[derive(Module, Debug)]
pub struct Resnet18 {
    pub conv1: Conv2d,
    pub bn1: BatchNorm,
    pub maxpool: MaxPool2d,
    pub layer1: Vec<BasicBlock>,
    pub layer2: Vec<BasicBlock>,
    pub layer3: Vec<BasicBlock>,
    pub layer4: Vec<BasicBlock>,
    pub avgpool: AdaptiveAvgPool2d,
    /// Weight stored `[512,N]` (burn's row layout), torchvision's `fc.weight` transposed.
    pub fc: Linear,
}

impl Resnet18 {
    /// Builds the network from torchvision-named tensors on `device`. Every tensor of
    /// [`Resnet18Weights::param_shapes`] must be present with its shape and value count;
    /// the error names the first one that is not. Extra tensors are ignored.
    pub fn from_weights(weights: &Resnet18Weights, device: &Device) -> Result<Self, TrainError> {
        let n = weights.num_outputs()?;
        let src = Source {
            weights,
            shapes: Resnet18Weights::param_shapes(n).into_iter().collect(),
            device,
        };
        let maxpool = MaxPool2dConfig::new([3, 3])
            .with_strides([2, 2])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init();
        let layer = |stage: usize| -> Result<Vec<BasicBlock>, TrainError> {
            (0..2)
                .map(|b| {
                    let p = format!("layer{stage}.{b}");
                    let stride = if stage > 1 && b == 0 { 2 } else { 1 };
                    let downsample = if stride == 2 {
                        Some(Downsample {
                            conv: src.conv(&format!("{p}.downsample.0"), 2, 0)?,
                            bn: src.bn(&format!("{p}.downsample.1"))?,
                        })
                    } else {
                        None
                    };
                    Ok(BasicBlock {
                        conv1: src.conv(&format!("{p}.conv1"), stride, 1)?,
                        bn1: src.bn(&format!("{p}.bn1"))?,
                        conv2: src.conv(&format!("{p}.conv2"), 1, 1)?,
                        bn2: src.bn(&format!("{p}.bn2"))?,
                        downsample,
                    })
                })
                .collect()
        };
        let fc_weight: Tensor<2> = src.tensor("fc.weight")?; // [N,512]
        Ok(Self {
            conv1: src.conv("conv1", 2, 3)?,
            bn1: src.bn("bn1")?,
            maxpool,
            layer1: layer(1)?,
            layer2: layer(2)?,
            layer3: layer(3)?,
            layer4: layer(4)?,
            avgpool: AdaptiveAvgPool2dConfig::new([1, 1]).init(),
            fc: Linear {
                // [512,N], stored contiguously (as a trained layer's is: the arithmetic,
                // and so the rounding, then matches a model that never left memory).
                weight: Param::from_tensor(Tensor::from_data(
                    fc_weight.transpose().into_data(),
                    device,
                )),
                bias: Some(Param::from_tensor(src.tensor("fc.bias")?)), // [N]
            },
        })
    }

    /// Every tensor of [`Resnet18Weights::param_shapes`] under its torchvision name, read
    /// back from the device (`from_weights(to_weights(m))` reproduces `m`). BatchNorm running
    /// statistics are read with `value_sync`, so the latest training step's update is
    /// included (burn's `RunningState::value` may lag one update behind).
    pub fn to_weights(&self) -> Result<Resnet18Weights, TrainError> {
        let mut out = BTreeMap::new();
        put_conv(&mut out, "conv1", &self.conv1)?;
        put_bn(&mut out, "bn1", &self.bn1)?;
        for (s, layer) in [&self.layer1, &self.layer2, &self.layer3, &self.layer4]
            .into_iter()
            .enumerate()
        {
            for (b, block) in layer.iter().enumerate() {
                let p = format!("layer{}.{b}", s + 1);
                put_conv(&mut out, &format!("{p}.conv1"), &block.conv1)?;
                put_bn(&mut out, &format!("{p}.bn1"), &block.bn1)?;
                put_conv(&mut out, &format!("{p}.conv2"), &block.conv2)?;
                put_bn(&mut out, &format!("{p}.bn2"), &block.bn2)?;
                if let Some(d) = &block.downsample {
                    put_conv(&mut out, &format!("{p}.downsample.0"), &d.conv)?;
                    put_bn(&mut out, &format!("{p}.downsample.1"), &d.bn)?;
                }
            }
        }
        put(&mut out, "fc.weight", self.fc.weight.val().transpose())?; // [N,512]
        if let Some(bias) = &self.fc.bias {
            put(&mut out, "fc.bias", bias.val())?;
        }
        Ok(Resnet18Weights { tensors: out })
    }

    /// Number of outputs `N` of `fc`.
    pub fn num_outputs(&self) -> usize {
        let [_, n] = self.fc.weight.dims();
        n
    }

    /// The pooled features: `[B,3,H,W] -> [B,512]`.
    pub fn features(&self, x: Tensor<4>) -> Tensor<2> {
        let x = relu(self.bn1.forward(self.conv1.forward(x))); // [B,64,H/2,W/2]
        let mut x = self.maxpool.forward(x); // [B,64,H/4,W/4]
        for block in self
            .layer1
            .iter()
            .chain(&self.layer2)
            .chain(&self.layer3)
            .chain(&self.layer4)
        {
            x = block.forward(x);
        } // [B,512,H/32,W/32]
        let x = self.avgpool.forward(x); // [B,512,1,1]
        let [b, c, _, _] = x.dims();
        x.reshape([b, c]) // [B,512]
    }

    /// The actor's output: `[B,3,H,W] -> [B,N]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        self.fc.forward(self.features(x)) // [B,N]
    }
}

/// Looks up tensors by torchvision name and checks them against the expected shapes.
struct Source<'a> {
    weights: &'a Resnet18Weights,
    shapes: BTreeMap<String, Vec<i64>>,
    device: &'a Device,
}

impl Source<'_> {
    fn tensor<const D: usize>(&self, name: &str) -> Result<Tensor<D>, TrainError> {
        let expected = self
            .shapes
            .get(name)
            .ok_or_else(|| TrainError::TensorData {
                name: name.to_string(),
                reason: "not a ResNet-18 tensor".into(),
            })?;
        let (dims, values) =
            self.weights
                .tensors
                .get(name)
                .ok_or_else(|| TrainError::MissingTensor {
                    name: name.to_string(),
                    expected: shape_string(expected),
                })?;
        if dims != expected || dims.len() != D {
            return Err(TrainError::TensorShape {
                name: name.to_string(),
                expected: shape_string(expected),
                found: shape_string(dims),
            });
        }
        let shape: Vec<usize> = dims.iter().map(|&d| d as usize).collect();
        let count: usize = shape.iter().product();
        if values.len() != count {
            return Err(TrainError::TensorData {
                name: name.to_string(),
                reason: format!(
                    "{} values, its shape {} needs {count}",
                    values.len(),
                    shape_string(dims)
                ),
            });
        }
        Ok(Tensor::from_data(
            TensorData::new(values.clone(), shape),
            self.device,
        ))
    }

    fn conv(&self, name: &str, stride: usize, pad: usize) -> Result<Conv2d, TrainError> {
        let weight: Tensor<4> = self.tensor(&format!("{name}.weight"))?; // [O,I,k,k]
        let [_, _, kh, kw] = weight.dims();
        Ok(Conv2d {
            weight: Param::from_tensor(weight),
            bias: None,
            stride: [stride, stride],
            kernel_size: [kh, kw],
            dilation: [1, 1],
            groups: 1,
            padding: PaddingConfig2d::Explicit(pad, pad, pad, pad),
        })
    }

    fn bn(&self, name: &str) -> Result<BatchNorm, TrainError> {
        let t = |p: &str| self.tensor::<1>(&format!("{name}.{p}")); // [C]
        Ok(BatchNorm {
            gamma: Param::from_tensor(t("weight")?),
            beta: Param::from_tensor(t("bias")?),
            training: Param::from_bool(true),
            running_mean: RunningState::new(t("running_mean")?),
            running_var: RunningState::new(t("running_var")?),
            momentum: BN_MOMENTUM,
            epsilon: BN_EPSILON,
        })
    }
}

type TensorMap = BTreeMap<String, (Vec<i64>, Vec<f32>)>;

fn put<const D: usize>(out: &mut TensorMap, name: &str, t: Tensor<D>) -> Result<(), TrainError> {
    let dims: Vec<i64> = t.dims().iter().map(|&d| d as i64).collect();
    let values = t
        .try_into_data_as::<f32>()
        .map_err(|e| TrainError::Backend(format!("reading `{name}`: {e:?}")))?
        .try_into_vec::<f32>()
        .map_err(|e| TrainError::Backend(format!("reading `{name}`: {e:?}")))?;
    out.insert(name.to_string(), (dims, values));
    Ok(())
}

fn put_conv(out: &mut TensorMap, name: &str, conv: &Conv2d) -> Result<(), TrainError> {
    put(out, &format!("{name}.weight"), conv.weight.val())
}

fn put_bn(out: &mut TensorMap, name: &str, bn: &BatchNorm) -> Result<(), TrainError> {
    put(out, &format!("{name}.weight"), bn.gamma.val())?;
    put(out, &format!("{name}.bias"), bn.beta.val())?;
    put(
        out,
        &format!("{name}.running_mean"),
        bn.running_mean.value_sync(),
    )?;
    put(
        out,
        &format!("{name}.running_var"),
        bn.running_var.value_sync(),
    )
}

fn shape_string(dims: &[i64]) -> String {
    let parts: Vec<String> = dims.iter().map(i64::to_string).collect();
    format!("[{}]", parts.join(","))
}

/// Reads a ResNet-18 from an ONNX file: our exports (`model init`, the trainer's export) or
/// a torchvision-layout ResNet-18 exported from PyTorch. Initializers are matched by their
/// torchvision names; a common prefix in front of all of them (`model.`, `backbone.`, ...,
/// as `torch.onnx.export` writes for a wrapped module) is detected from where `conv1.weight`
/// and `fc.weight` sit and stripped. Values are float32, as `raw_data` (little-endian) or
/// `float_data`; other initializers (`num_batches_tracked`, ...) are ignored.
///
/// The contract comes from the model's metadata; a model without one gets the default
/// contract with `input_size` taken from a fixed square input (else the default's 224).
///
/// PyTorch's exporter in eval mode folds BatchNorm into the preceding convolution and renames
/// the results (`onnx::Conv_123`); such a file has no `bn1.*` tensors and is refused with
/// the name of the first missing one. Export with `training=torch.onnx.TrainingMode.PRESERVE`
/// (or `do_constant_folding=False`) from a model in eval mode to keep the names.
pub fn load_onnx(path: &Path, device: &Device) -> Result<(Resnet18, ModelContract), TrainError> {
    let shown = path.display().to_string();
    let bytes = Bytes::from(std::fs::read(path).map_err(|source| {
        crate::policy::onnx::OnnxError::Read {
            path: shown.clone(),
            source,
        }
    })?);
    let summary = inspect_bytes(bytes.clone(), &shown)?;
    let contract = match summary.contract() {
        Ok(Some(c)) => c,
        Ok(None) => {
            let dims: Vec<i64> = summary
                .inputs
                .first()
                .map(|input| {
                    input
                        .dims
                        .iter()
                        .map(|d| match d {
                            Dim::Fixed(n) => *n,
                            _ => -1,
                        })
                        .collect()
                })
                .unwrap_or_default();
            ModelContract::default().for_unlabelled_input(&dims)
        }
        Err(source) => {
            return Err(TrainError::Contract {
                path: shown,
                source,
            });
        }
    };
    let model =
        ModelProto::decode(bytes).map_err(|source| crate::policy::onnx::OnnxError::Decode {
            path: shown.clone(),
            source,
        })?;
    let initializers = model.graph.map(|g| g.initializer).unwrap_or_default();
    let weights = weights_from_initializers(&initializers)?;
    Ok((Resnet18::from_weights(&weights, device)?, contract))
}

/// The prefix in front of torchvision's names: `""` when `conv1.weight` is present as is,
/// else the `P` (ending in `.`) for which both `Pconv1.weight` and `Pfc.weight` exist.
fn common_prefix(names: &BTreeSet<&str>) -> String {
    if names.contains("conv1.weight") {
        return String::new();
    }
    names
        .iter()
        .filter_map(|n| n.strip_suffix("conv1.weight"))
        .filter(|p| p.ends_with('.') && names.contains(format!("{p}fc.weight").as_str()))
        .min_by_key(|p| p.len())
        .unwrap_or("")
        .to_string()
}

/// The ResNet-18 tensors among `initializers`, under their torchvision names.
pub fn weights_from_initializers(
    initializers: &[TensorProto],
) -> Result<Resnet18Weights, TrainError> {
    const FLOAT: i32 = 1;
    const EXTERNAL: i32 = 1;
    let wanted: BTreeSet<String> = Resnet18Weights::param_shapes(1)
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    let names: BTreeSet<&str> = initializers.iter().map(|t| t.name.as_str()).collect();
    let prefix = common_prefix(&names);
    let mut tensors = BTreeMap::new();
    for t in initializers {
        let Some(name) = t.name.strip_prefix(prefix.as_str()) else {
            continue;
        };
        if !wanted.contains(name) {
            continue;
        }
        let bad = |reason: &str| TrainError::TensorData {
            name: t.name.clone(),
            reason: reason.to_string(),
        };
        if t.data_type != FLOAT {
            return Err(bad(&format!(
                "element type {} is not float32 (1)",
                t.data_type
            )));
        }
        if t.data_location == EXTERNAL || !t.external_data.is_empty() {
            return Err(bad("external data files are not supported"));
        }
        let values: Vec<f32> = if t.raw_data.is_empty() {
            t.float_data.clone()
        } else {
            if t.raw_data.len() % 4 != 0 {
                return Err(bad("raw_data length is not a multiple of 4"));
            }
            t.raw_data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        tensors.insert(name.to_string(), (t.dims.clone(), values));
    }
    Ok(Resnet18Weights { tensors })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefix_is_found_and_stripped() {
        let names: BTreeSet<&str> = [
            "model.conv1.weight",
            "model.layer1.0.conv1.weight",
            "model.fc.weight",
        ]
        .into_iter()
        .collect();
        assert_eq!(common_prefix(&names), "model.");
        let names: BTreeSet<&str> = ["conv1.weight", "layer1.0.conv1.weight", "fc.weight"]
            .into_iter()
            .collect();
        assert_eq!(common_prefix(&names), "");
    }

    #[test]
    fn missing_and_misshapen_tensors_are_named() {
        let device = Device::flex();
        let mut w = Resnet18Weights::random(2, 3);
        w.tensors.remove("layer2.1.bn1.running_mean");
        let err = Resnet18::from_weights(&w, &device)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains("`layer2.1.bn1.running_mean`"), "{err}");

        let mut w = Resnet18Weights::random(2, 3);
        w.tensors.insert(
            "conv1.weight".into(),
            (vec![64, 3, 3, 3], vec![0.0; 64 * 27]),
        );
        let err = Resnet18::from_weights(&w, &device)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert_eq!(
            err,
            "tensor `conv1.weight` has shape [64,3,3,3], expected [64,3,7,7]"
        );
    }

    #[test]
    fn shapes_and_round_trip() {
        let device = Device::flex();
        let w = Resnet18Weights::random(3, 5);
        let m = Resnet18::from_weights(&w, &device).unwrap();
        assert_eq!(m.num_outputs(), 3);
        let x = Tensor::<4>::zeros([2, 3, 64, 64], &device);
        assert_eq!(m.features(x.clone()).dims(), [2, FEATURES]);
        assert_eq!(m.forward(x).dims(), [2, 3]);
        assert_eq!(m.to_weights().unwrap(), w);
    }

    #[test]
    fn load_onnx_strips_a_common_prefix_and_ignores_other_initializers() {
        use crate::policy::onnx::{resnet18_model, write_model};
        let w = Resnet18Weights::random(2, 4);
        let contract = ModelContract {
            input_size: 32,
            ..ModelContract::default()
        };
        let mut model = resnet18_model(32, &w, &contract, "t").unwrap();
        let graph = model.graph.as_mut().unwrap();
        for t in &mut graph.initializer {
            t.name = format!("model.{}", t.name);
        }
        graph.initializer.push(TensorProto {
            name: "model.bn1.num_batches_tracked".into(),
            data_type: 7, // int64
            raw_data: Bytes::from(vec![0u8; 8]),
            ..TensorProto::default()
        });
        model.metadata_props.clear();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("prefixed.onnx");
        write_model(&path, &model).unwrap();
        let (net, c) = load_onnx(&path, &Device::flex()).unwrap();
        assert_eq!(c.input_size, 32, "from the input shape without metadata");
        assert_eq!(net.to_weights().unwrap(), w);
    }
}
