//! EfficientNet-Lite0 as a burn [`Module`], in the PyTorch port's layout, with import from
//! and export to the ONNX writer's [`Lite0Weights`]. The graph and its names are documented
//! in [`crate::policy::onnx::lite0`]; this is the same network, layer for layer.
//!
//! ```text
//! x [B,3,S,S] -> stem 3x3/2 (32) -> 16 MBConv blocks -> head 1x1 (1280)   [B,1280,S/32,S/32]
//!  -> adaptive average pool -> flatten                                      [B,1280] features
//!  -> fc 1280 -> N                                                          [B,N]
//! ```
//!
//! Or, where `_fc.weight` is `[N, 1280*s*s]` for the input size's `s` x `s` final map (what
//! `train probe --grid 2|3` writes), the head reads the whole map flattened channel by
//! channel, as the ONNX graph's `Flatten` does: a probe on cells, then a fine-tune (LP-FT).
//!
//! Padding is TensorFlow's `SAME` for the input size the module is built for, so a module
//! belongs to one input size (the contract's). BatchNorm epsilon is 1e-3; the momentum is
//! a parameter of [`EfficientNetLite0::from_weights`] in burn's (= PyTorch's) convention.

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig};
use burn::nn::{BatchNorm, Linear, PaddingConfig2d};
use burn::tensor::activation::relu6;
use burn::tensor::{Device, Tensor};

use super::TrainError;
use super::tensors::{Source, head_reads_whole_map, put_bn, put_conv, put_linear};
use crate::policy::onnx::TensorMap;
use crate::policy::onnx::lite0::{
    BN_EPSILON, FEATURES, Lite0Weights, blocks, final_map, same_output, same_padding,
};
use crate::policy::onnx::resnet::with_head_width;

/// A convolution (no bias) and its BatchNorm.
#[derive(Module, Debug)]
pub struct ConvBn {
    pub conv: Conv2d,
    pub bn: BatchNorm,
}

impl ConvBn {
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.bn.forward(self.conv.forward(x))
    }
}

/// One MBConv block: expand 1x1 (absent in block 0) -> depthwise kxk/s -> project 1x1,
/// ReLU6 after the first two, plus the input when `skip`.
#[derive(Module, Debug)]
pub struct MbConv {
    pub expand: Option<ConvBn>,
    pub depthwise: ConvBn,
    pub project: ConvBn,
    pub skip: bool,
}

impl MbConv {
    /// `[B,C_in,H,W] -> [B,C_out,H/s,W/s]`.
    pub fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        let x = match &self.expand {
            Some(e) => relu6(e.forward(input.clone())), // [B,6 C_in,H,W]
            None => input.clone(),
        };
        let x = relu6(self.depthwise.forward(x)); // [B,mid,H/s,W/s]
        let x = self.project.forward(x); // [B,C_out,H/s,W/s]
        if self.skip { x.add(input) } else { x }
    }
}

/// EfficientNet-Lite0; `blocks[i]` is the port's `_blocks.i`.
#[derive(Module, Debug)]
pub struct EfficientNetLite0 {
    pub stem: ConvBn,
    pub blocks: Vec<MbConv>,
    pub head: ConvBn,
    pub avgpool: AdaptiveAvgPool2d,
    /// Weight stored `[1280,N]` (burn's row layout), the port's `_fc.weight` transposed;
    /// `[1280*s*s,N]` when [`Self::whole_map`].
    pub fc: Linear,
    /// The head reads the whole final map, not its average.
    pub whole_map: bool,
}

impl EfficientNetLite0 {
    /// Builds the network for `input_size` x `input_size` inputs from the port's tensors
    /// on `device`, its BatchNorms with `bn_momentum`. Every tensor of
    /// [`Lite0Weights::param_shapes`] must be present with its shape; the error names the
    /// first that is not. Extra tensors are ignored.
    pub fn from_weights(
        weights: &Lite0Weights,
        input_size: usize,
        bn_momentum: f64,
        device: &Device,
    ) -> Result<Self, TrainError> {
        let n = weights.num_outputs()?;
        let side = final_map(input_size);
        let whole_map = head_reads_whole_map(&weights.tensors, "_fc", FEATURES, side, input_size)?;
        let src = Source {
            tensors: &weights.tensors,
            shapes: with_head_width(Lite0Weights::param_shapes(n), "_fc", &weights.tensors)
                .into_iter()
                .collect(),
            device,
            title: "EfficientNet-Lite0",
        };
        // A conv + BN pair with SAME padding for an input of `size`.
        let conv_bn = |conv: &str, bn: &str, size: usize, stride: usize, groups: usize| {
            let k = src
                .tensors
                .get(&format!("{conv}.weight"))
                .and_then(|(d, _)| d.get(2).copied())
                .unwrap_or(1) as usize;
            let (before, after) = same_padding(size, k, stride);
            let padding = PaddingConfig2d::Explicit(before, before, after, after);
            Ok::<_, TrainError>(ConvBn {
                conv: src.conv(conv, stride, padding, groups)?,
                bn: src.bn(bn, f64::from(BN_EPSILON), bn_momentum)?,
            })
        };
        let mut size = input_size;
        let stem = conv_bn("_conv_stem", "_bn0", size, 2, 1)?;
        size = same_output(size, 2);
        let mut layers = Vec::new();
        for (i, b) in blocks().iter().enumerate() {
            let p = format!("_blocks.{i}");
            let expand = if b.expands() {
                Some(conv_bn(
                    &format!("{p}._expand_conv"),
                    &format!("{p}._bn0"),
                    size,
                    1,
                    1,
                )?)
            } else {
                None
            };
            let depthwise = conv_bn(
                &format!("{p}._depthwise_conv"),
                &format!("{p}._bn1"),
                size,
                b.stride,
                b.mid,
            )?;
            size = same_output(size, b.stride);
            let project = conv_bn(
                &format!("{p}._project_conv"),
                &format!("{p}._bn2"),
                size,
                1,
                1,
            )?;
            layers.push(MbConv {
                expand,
                depthwise,
                project,
                skip: b.skip(),
            });
        }
        Ok(Self {
            stem,
            blocks: layers,
            head: conv_bn("_conv_head", "_bn1", size, 1, 1)?,
            avgpool: AdaptiveAvgPool2dConfig::new([1, 1]).init(),
            fc: src.linear("_fc")?,
            whole_map,
        })
    }

    /// Every tensor of [`Lite0Weights::param_shapes`] under the port's name (`_fc.weight`
    /// as wide as the head reads), read back from the device (`from_weights(to_weights(m))`
    /// reproduces `m`).
    pub fn to_weights(&self) -> Result<Lite0Weights, TrainError> {
        let mut out = TensorMap::new();
        let pair = |out: &mut TensorMap, conv: &str, bn: &str, l: &ConvBn| {
            put_conv(out, conv, &l.conv)?;
            put_bn(out, bn, &l.bn)
        };
        pair(&mut out, "_conv_stem", "_bn0", &self.stem)?;
        for (i, b) in self.blocks.iter().enumerate() {
            let p = format!("_blocks.{i}");
            if let Some(e) = &b.expand {
                pair(
                    &mut out,
                    &format!("{p}._expand_conv"),
                    &format!("{p}._bn0"),
                    e,
                )?;
            }
            pair(
                &mut out,
                &format!("{p}._depthwise_conv"),
                &format!("{p}._bn1"),
                &b.depthwise,
            )?;
            pair(
                &mut out,
                &format!("{p}._project_conv"),
                &format!("{p}._bn2"),
                &b.project,
            )?;
        }
        pair(&mut out, "_conv_head", "_bn1", &self.head)?;
        put_linear(&mut out, "_fc", &self.fc)?;
        Ok(Lite0Weights { tensors: out })
    }

    /// Calls `f` on every BatchNorm, in `to_weights` order.
    pub fn for_each_batch_norm(&mut self, f: &mut impl FnMut(&mut BatchNorm)) {
        f(&mut self.stem.bn);
        for b in &mut self.blocks {
            if let Some(e) = &mut b.expand {
                f(&mut e.bn);
            }
            f(&mut b.depthwise.bn);
            f(&mut b.project.bn);
        }
        f(&mut self.head.bn);
    }

    /// Number of outputs `N` of `fc`.
    pub fn num_outputs(&self) -> usize {
        let [_, n] = self.fc.weight.dims();
        n
    }

    /// The final feature map: `[B,3,S,S] -> [B,1280,s,s]`.
    pub fn feature_map(&self, x: Tensor<4>) -> Tensor<4> {
        let mut x = relu6(self.stem.forward(x)); // [B,32,S/2,S/2]
        for block in &self.blocks {
            x = block.forward(x);
        } // [B,320,S/32,S/32]
        relu6(self.head.forward(x)) // [B,1280,S/32,S/32]
    }

    /// The pooled features: `[B,3,S,S] -> [B,1280]`.
    pub fn features(&self, x: Tensor<4>) -> Tensor<2> {
        let x = self.avgpool.forward(self.feature_map(x)); // [B,1280,1,1]
        let [b, c, _, _] = x.dims();
        debug_assert_eq!(c, FEATURES);
        x.reshape([b, c]) // [B,1280]
    }

    /// What `fc` reads: the pooled features `[B,1280]`, or with [`Self::whole_map`] the
    /// whole map flattened channel by channel, `[B,1280*s*s]`.
    pub fn head_input(&self, x: Tensor<4>) -> Tensor<2> {
        if self.whole_map {
            let m = self.feature_map(x);
            let [b, c, h, w] = m.dims();
            m.reshape([b, c * h * w])
        } else {
            self.features(x)
        }
    }

    /// `[B,3,S,S] -> [B,N]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        self.fc.forward(self.head_input(x)) // [B,N]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_and_round_trip() {
        let device = Device::flex();
        let w = Lite0Weights::random(2, 5);
        let m = EfficientNetLite0::from_weights(&w, 64, 0.1, &device).unwrap();
        assert_eq!(m.num_outputs(), 2);
        assert_eq!(m.blocks.len(), 16);
        let x = Tensor::<4>::zeros([2, 3, 64, 64], &device);
        assert_eq!(m.features(x.clone()).dims(), [2, FEATURES]);
        assert_eq!(m.forward(x).dims(), [2, 2]);
        assert_eq!(m.to_weights().unwrap(), w);
    }

    #[test]
    fn a_whole_map_head_reads_the_map_channel_by_channel() {
        // 64x64: a 2x2 final map. Output 0 weighs channel 1's top-right cell only, output 1
        // the mean of channel 0's four cells: flattening is channel, then row, then column.
        let device = Device::flex();
        let mut w = Lite0Weights::random(2, 5);
        let width = FEATURES * 4;
        let mut weight = vec![0.0f32; 2 * width];
        weight[4 + 1] = 1.0; // channel 1, row 0, column 1
        for cell in 0..4 {
            weight[width + cell] = 0.25; // channel 0
        }
        w.tensors
            .insert("_fc.weight".into(), (vec![2, width as i64], weight));
        w.tensors
            .insert("_fc.bias".into(), (vec![2], vec![0.5, 0.0]));
        let m = EfficientNetLite0::from_weights(&w, 64, 0.1, &device).unwrap();
        assert!(m.whole_map);
        let x = Tensor::<4>::ones([1, 3, 64, 64], &device);
        let map = m
            .feature_map(x.clone())
            .into_data()
            .try_into_vec::<f32>()
            .unwrap(); // [1,1280,2,2]
        let pooled = m
            .features(x.clone())
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let out = m.forward(x).into_data().try_into_vec::<f32>().unwrap();
        assert!((out[0] - (map[4 + 1] + 0.5)).abs() < 1e-5, "{out:?}");
        assert!((out[1] - pooled[0]).abs() < 1e-5, "{out:?} {}", pooled[0]);
        assert_eq!(m.to_weights().unwrap(), w);
        // The pooled default is not whole-map.
        let pooled_head =
            EfficientNetLite0::from_weights(&Lite0Weights::random(2, 5), 64, 0.1, &device);
        assert!(!pooled_head.unwrap().whole_map);
    }

    #[test]
    fn a_missing_tensor_is_named() {
        let mut w = Lite0Weights::random(2, 5);
        w.tensors.remove("_blocks.4._bn0.running_var");
        let err = EfficientNetLite0::from_weights(&w, 64, 0.1, &Device::flex())
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert_eq!(
            err,
            "tensor `_blocks.4._bn0.running_var` is missing (expected shape [240])"
        );
    }
}
