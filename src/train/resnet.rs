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

use std::path::Path;

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig, MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, Linear, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use super::TrainError;
use super::net::read_onnx;
use super::tensors::{Source, put_bn, put_conv, put_linear};
use crate::policy::ModelContract;
use crate::policy::onnx::{NetWeights, Resnet18Weights, TensorMap};

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
            tensors: &weights.tensors,
            shapes: Resnet18Weights::param_shapes(n).into_iter().collect(),
            device,
            title: "ResNet-18",
        };
        let conv = |name: &str, stride: usize, pad: usize| {
            src.conv(
                name,
                stride,
                PaddingConfig2d::Explicit(pad, pad, pad, pad),
                1,
            )
        };
        let bn = |name: &str| src.bn(name, BN_EPSILON, BN_MOMENTUM);
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
                            conv: conv(&format!("{p}.downsample.0"), 2, 0)?,
                            bn: bn(&format!("{p}.downsample.1"))?,
                        })
                    } else {
                        None
                    };
                    Ok(BasicBlock {
                        conv1: conv(&format!("{p}.conv1"), stride, 1)?,
                        bn1: bn(&format!("{p}.bn1"))?,
                        conv2: conv(&format!("{p}.conv2"), 1, 1)?,
                        bn2: bn(&format!("{p}.bn2"))?,
                        downsample,
                    })
                })
                .collect()
        };
        Ok(Self {
            conv1: conv("conv1", 2, 3)?,
            bn1: bn("bn1")?,
            maxpool,
            layer1: layer(1)?,
            layer2: layer(2)?,
            layer3: layer(3)?,
            layer4: layer(4)?,
            avgpool: AdaptiveAvgPool2dConfig::new([1, 1]).init(),
            fc: src.linear("fc")?,
        })
    }

    /// Every tensor of [`Resnet18Weights::param_shapes`] under its torchvision name, read
    /// back from the device (`from_weights(to_weights(m))` reproduces `m`). BatchNorm running
    /// statistics are read with `value_sync`, so the latest training step's update is
    /// included (burn's `RunningState::value` may lag one update behind).
    pub fn to_weights(&self) -> Result<Resnet18Weights, TrainError> {
        let mut out = TensorMap::new();
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
        put_linear(&mut out, "fc", &self.fc)?;
        Ok(Resnet18Weights { tensors: out })
    }

    /// Calls `f` on every BatchNorm, in `to_weights` order.
    pub fn for_each_batch_norm(&mut self, f: &mut impl FnMut(&mut BatchNorm)) {
        f(&mut self.bn1);
        for block in self
            .layer1
            .iter_mut()
            .chain(&mut self.layer2)
            .chain(&mut self.layer3)
            .chain(&mut self.layer4)
        {
            f(&mut block.bn1);
            f(&mut block.bn2);
            if let Some(d) = &mut block.downsample {
                f(&mut d.bn);
            }
        }
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

/// Reads a ResNet-18 from an ONNX file (see [`super::net::read_onnx`]); a file of another
/// architecture is refused with its name.
pub fn load_onnx(path: &Path, device: &Device) -> Result<(Resnet18, ModelContract), TrainError> {
    let (weights, contract) = read_onnx(path)?;
    match weights {
        NetWeights::Resnet18(w) => Ok((Resnet18::from_weights(&w, device)?, contract)),
        other => Err(TrainError::Data {
            path: path.display().to_string(),
            reason: format!(
                "a {} model; this needs a ResNet-18 (this burn network is ResNet-18; `read_onnx` reads both)",
                other.arch().title()
            ),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
