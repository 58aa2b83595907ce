//! ResNet-18 in torchvision's exact layout and parameter names, as an ONNX model.
//!
//! Graph (NCHW, f32; `H = W = input_size`):
//!
//! ```text
//! input [1,3,H,W]
//!  -> conv1 7x7/2 pad 3 (64) -> bn1 -> Relu -> MaxPool 3x3/2 pad 1       [1,64,H/4,W/4]
//!  -> layer1 (64, stride 1) -> layer2 (128, /2) -> layer3 (256, /2) -> layer4 (512, /2)
//!  -> GlobalAveragePool [1,512,1,1] -> Flatten(axis=1) [1,512]
//!  -> Gemm(transB=1) with fc.weight [N,512], fc.bias [N]                  output [1,N]
//! ```
//!
//! Each `layerK` holds two BasicBlocks `layerK.0`, `layerK.1`:
//! conv3x3/s pad 1 -> BN -> Relu -> conv3x3 pad 1 -> BN -> Add(identity) -> Relu, where the
//! identity of `layer{2,3,4}.0` is `downsample.0` (conv1x1/2) -> `downsample.1` (BN).
//! Convolutions have no bias; BatchNormalization is in inference form (epsilon 1e-5).

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Uniform};

use super::OnnxError;
use super::graph::{
    Dim, GraphBuilder, attr_float, attr_int, attr_ints, element_count, shape_to_string,
};
use super::proto::ModelProto;
use crate::policy::contract::ModelContract;

/// Metadata key naming the architecture.
pub const META_ARCH: &str = "jetpilot.arch";
/// Channels of the four stages.
const STAGES: [i64; 4] = [64, 128, 256, 512];
/// Features entering the fully connected layer.
const FC_IN: i64 = 512;
const BN_EPSILON: f32 = 1e-5;

/// ResNet-18 parameters and BatchNorm running statistics by torchvision name
/// (`conv1.weight`, `layer2.0.downsample.1.running_var`, `fc.bias`, ...): shape and values.
/// `num_batches_tracked` buffers are not used for inference and not needed.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Resnet18Weights {
    pub tensors: TensorMap,
}

impl Resnet18Weights {
    /// Every tensor the graph uses, in torchvision `state_dict` order, with its shape.
    pub fn param_shapes(num_outputs: usize) -> Vec<(String, Vec<i64>)> {
        type Shapes = Vec<(String, Vec<i64>)>;
        fn conv(out: &mut Shapes, name: &str, o: i64, i: i64, k: i64) {
            out.push((format!("{name}.weight"), vec![o, i, k, k]));
        }
        fn bn(out: &mut Shapes, name: &str, c: i64) {
            for p in ["weight", "bias", "running_mean", "running_var"] {
                out.push((format!("{name}.{p}"), vec![c]));
            }
        }
        let mut out = Shapes::new();
        conv(&mut out, "conv1", 64, 3, 7);
        bn(&mut out, "bn1", 64);
        let mut in_ch = 64;
        for (s, &ch) in STAGES.iter().enumerate() {
            for b in 0..2 {
                let p = format!("layer{}.{b}", s + 1);
                let block_in = if b == 0 { in_ch } else { ch };
                conv(&mut out, &format!("{p}.conv1"), ch, block_in, 3);
                bn(&mut out, &format!("{p}.bn1"), ch);
                conv(&mut out, &format!("{p}.conv2"), ch, ch, 3);
                bn(&mut out, &format!("{p}.bn2"), ch);
                if b == 0 && s > 0 {
                    conv(&mut out, &format!("{p}.downsample.0"), ch, block_in, 1);
                    bn(&mut out, &format!("{p}.downsample.1"), ch);
                }
            }
            in_ch = ch;
        }
        let n = num_outputs as i64;
        out.push(("fc.weight".into(), vec![n, FC_IN]));
        out.push(("fc.bias".into(), vec![n]));
        out
    }

    /// torchvision's initialisation, reproducible from `seed` (ChaCha8):
    /// conv weights Kaiming normal (fan_out, ReLU: `std = sqrt(2 / (out_ch * kh * kw))`),
    /// BN weight 1, bias 0, running mean 0, running var 1, and `fc.weight` / `fc.bias`
    /// uniform in `±1/sqrt(512)` (PyTorch's `nn.Linear` default).
    pub fn random(num_outputs: usize, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let bound = linear_bound();
        let tensors = Self::param_shapes(num_outputs)
            .into_iter()
            .map(|(name, dims)| {
                let len = element_count(&dims) as usize;
                let values = if name.starts_with("fc.") {
                    uniform(&mut rng, bound, len)
                } else if dims.len() == 4 {
                    let fan_out = (dims[0] * dims[2] * dims[3]) as f32;
                    kaiming_normal(&mut rng, (2.0 / fan_out).sqrt(), len)
                } else if name.ends_with(".weight") || name.ends_with(".running_var") {
                    vec![1.0; len]
                } else {
                    vec![0.0; len] // BN bias, running_mean
                };
                (name, (dims, values))
            })
            .collect();
        Self { tensors }
    }

    /// The same backbone with a new `fc` of `num_outputs`: how JetBot's notebook turns an
    /// ImageNet ResNet-18 (1000 outputs) into a target-point or steering network
    /// (`model.fc = nn.Linear(512, 2)`). The new `fc.weight`, then `fc.bias`, are drawn
    /// uniform in `±1/sqrt(512)` (PyTorch's `nn.Linear` default) from ChaCha8 seeded with
    /// `seed`; every other tensor is kept as it is.
    pub fn with_fresh_head(&self, num_outputs: usize, seed: u64) -> Self {
        let mut tensors = self.tensors.clone();
        fresh_linear(&mut tensors, "fc", FC_IN as usize, num_outputs, seed);
        Self { tensors }
    }

    /// `num_outputs` from the shape of `fc.weight` (`[N,512]`).
    pub fn num_outputs(&self) -> Result<usize, OnnxError> {
        linear_outputs(&self.tensors, "fc.weight", FC_IN as usize)
    }
}

/// Named tensors: shape and values.
pub type TensorMap = BTreeMap<String, (Vec<i64>, Vec<f32>)>;

/// `N` from the shape `[N,W]` of the linear layer's weight `name`, where `W` is `features`
/// (on pooled features) or a multiple of it (on the whole final map, see [`head_nodes`]).
pub(crate) fn linear_outputs(
    tensors: &TensorMap,
    name: &str,
    features: usize,
) -> Result<usize, OnnxError> {
    let expected = format!("[N,{features}]");
    let (dims, _) = tensors.get(name).ok_or_else(|| OnnxError::MissingWeight {
        name: name.into(),
        expected: expected.clone(),
    })?;
    match dims.as_slice() {
        [n, f] if *n >= 1 && *f >= 1 && *f % features as i64 == 0 => Ok(*n as usize),
        _ => Err(OnnxError::WeightShape {
            name: name.into(),
            expected,
            found: shape_to_string(dims),
        }),
    }
}

/// The output layer `head` (`Gemm` with `{head}.weight` `[N,W]` and `{head}.bias`) on the
/// final feature map `map`, `[1,features,s,s]`, to the graph's `output`: with
/// `W = features` the map is average-pooled first (the networks' own head); with
/// `W = features * s * s` the head reads the whole map, flattened channel by channel (a head
/// fitted on pooled cells, `train probe --grid`, folds into this exactly). Any other `W` is
/// an error naming both shapes it could have.
pub(crate) fn head_nodes(
    g: &mut GraphBuilder,
    map: &str,
    head: &str,
    features: usize,
    s: usize,
    tensors: &TensorMap,
) -> Result<usize, OnnxError> {
    let name = format!("{head}.weight");
    let n = linear_outputs(tensors, &name, features)?;
    let width = tensors.get(&name).map_or(0, |(d, _)| d[1] as usize);
    let flat = if width == features {
        g.node("GlobalAveragePool", &[map], &["avgpool"], vec![]);
        "avgpool"
    } else if width == features * s * s {
        map
    } else {
        return Err(OnnxError::WeightShape {
            name,
            expected: format!(
                "[{n},{features}] (pooled) or [{n},{}] (the whole {s}x{s} final map of this input size)",
                features * s * s
            ),
            found: format!("[{n},{width}]"),
        });
    };
    g.node("Flatten", &[flat], &["flatten"], vec![attr_int("axis", 1)]);
    g.node_named(
        head,
        "Gemm",
        &[
            "flatten",
            &format!("{head}.weight"),
            &format!("{head}.bias"),
        ],
        &["output"],
        vec![attr_int("transB", 1)],
    );
    g.output_f32("output", &[Dim::Fixed(1), Dim::Fixed(n as i64)]);
    Ok(n)
}

/// `shapes` with the output layer's weight `{head}.weight` as `tensors` has it (a whole-map
/// head is wider than `param_shapes` says; [`head_nodes`] checks its width).
pub(crate) fn with_head_width(
    mut shapes: Vec<(String, Vec<i64>)>,
    head: &str,
    tensors: &TensorMap,
) -> Vec<(String, Vec<i64>)> {
    let name = format!("{head}.weight");
    if let (Some(entry), Some((dims, _))) = (
        shapes.iter_mut().find(|(n, _)| *n == name),
        tensors.get(&name),
    ) && dims.len() == 2
        && entry.1.len() == 2
        && dims[0] == entry.1[0]
    {
        entry.1[1] = dims[1];
    }
    shapes
}

/// The side of ResNet-18's final feature map for an input of `input`: conv1 (7x7, stride 2,
/// pad 3), the max pool (3x3, stride 2, pad 1), then three stride-2 stages (3x3, pad 1).
pub fn final_map(input: usize) -> usize {
    let down = |x: usize, k: usize, pad: usize| (x + 2 * pad).saturating_sub(k) / 2 + 1;
    let mut x = down(input, 7, 3);
    x = down(x, 3, 1);
    for _ in 0..3 {
        x = down(x, 3, 1);
    }
    x
}

/// Replaces the linear layer `{name}.weight` `[outputs,features]` and `{name}.bias`
/// `[outputs]` with PyTorch's `nn.Linear` initialisation, uniform in `±1/sqrt(features)`,
/// the weight then the bias drawn from ChaCha8 seeded with `seed`.
pub(crate) fn fresh_linear(
    tensors: &mut TensorMap,
    name: &str,
    features: usize,
    outputs: usize,
    seed: u64,
) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let bound = 1.0 / (features as f32).sqrt();
    let weight = uniform(&mut rng, bound, outputs * features);
    let bias = uniform(&mut rng, bound, outputs);
    let n = outputs as i64;
    tensors.insert(format!("{name}.weight"), (vec![n, features as i64], weight));
    tensors.insert(format!("{name}.bias"), (vec![n], bias));
}

/// Adds every tensor of `shapes` from `tensors` as an initializer, in `shapes`' order; the
/// error names the first one missing or of another shape.
pub(crate) fn add_checked_initializers(
    g: &mut GraphBuilder,
    shapes: Vec<(String, Vec<i64>)>,
    tensors: &TensorMap,
) -> Result<(), OnnxError> {
    for (name, dims) in shapes {
        let (found, values) = tensors.get(&name).ok_or_else(|| OnnxError::MissingWeight {
            name: name.clone(),
            expected: shape_to_string(&dims),
        })?;
        if *found != dims {
            return Err(OnnxError::WeightShape {
                name,
                expected: shape_to_string(&dims),
                found: shape_to_string(found),
            });
        }
        g.initializer_f32(&name, &dims, values)?;
    }
    Ok(())
}

/// PyTorch's `nn.Linear` default initialisation bound for `fc`: `1/sqrt(512)`.
fn linear_bound() -> f32 {
    1.0 / (FC_IN as f32).sqrt()
}

pub(crate) fn uniform(rng: &mut impl Rng, bound: f32, len: usize) -> Vec<f32> {
    match Uniform::new(-bound, bound) {
        Ok(d) => d.sample_iter(rng).take(len).collect(),
        Err(_) => vec![0.0; len],
    }
}

pub(crate) fn kaiming_normal(rng: &mut impl Rng, std: f32, len: usize) -> Vec<f32> {
    match Normal::new(0.0, std) {
        Ok(d) => d.sample_iter(rng).take(len).collect(),
        Err(_) => vec![0.0; len],
    }
}

/// Total number of values in `weights` (trainable parameters and BN running statistics).
pub fn parameter_count(weights: &Resnet18Weights) -> u64 {
    weights
        .tensors
        .values()
        .map(|(dims, _)| element_count(dims))
        .sum()
}

/// The input size a model builder is asked for: at least 32x32 (five stride-2 stages leave
/// one cell) and the contract's own, so that the file and its metadata agree.
pub(crate) fn check_input_size(
    net: &str,
    input_size: u32,
    contract: &ModelContract,
) -> Result<(), OnnxError> {
    if input_size < 32 {
        return Err(OnnxError::Graph(format!(
            "{net} needs an input of at least 32x32, got {input_size}"
        )));
    }
    if contract.input_size != input_size {
        return Err(OnnxError::Graph(format!(
            "input size {input_size} differs from the contract's {}",
            contract.input_size
        )));
    }
    Ok(())
}

/// Builds the ResNet-18 ONNX model: input `input [1,3,S,S]`, output `output [1,N]` where
/// `S = input_size` and `N` comes from `fc.weight`. Every tensor of
/// [`Resnet18Weights::param_shapes`] must be present with its shape (extra tensors, such as
/// `num_batches_tracked`, are ignored). The contract and `jetpilot.arch = resnet18` are
/// recorded in `metadata_props`; `contract.input_size` must equal `input_size`.
pub fn resnet18_model(
    input_size: u32,
    weights: &Resnet18Weights,
    contract: &ModelContract,
    producer_version: &str,
) -> Result<ModelProto, OnnxError> {
    check_input_size("ResNet-18", input_size, contract)?;
    let num_outputs = weights.num_outputs()?;
    let mut g = GraphBuilder::new("resnet18");
    add_checked_initializers(
        &mut g,
        with_head_width(
            Resnet18Weights::param_shapes(num_outputs),
            "fc",
            &weights.tensors,
        ),
        &weights.tensors,
    )?;

    let s = i64::from(input_size);
    g.input_f32("input", &[1.into(), 3.into(), s.into(), s.into()]);
    conv(&mut g, "conv1", "input", 7, 2, 3);
    bn(&mut g, "bn1", "conv1");
    g.node("Relu", &["bn1"], &["relu"], vec![]);
    let pool = vec![
        attr_ints("kernel_shape", &[3, 3]),
        attr_ints("strides", &[2, 2]),
        attr_ints("pads", &[1, 1, 1, 1]),
    ];
    g.node("MaxPool", &["relu"], &["maxpool"], pool);

    let mut x = "maxpool".to_string();
    for stage in 1..=4 {
        for block in 0..2 {
            let stride = if stage > 1 && block == 0 { 2 } else { 1 };
            x = basic_block(&mut g, &format!("layer{stage}.{block}"), &x, stride);
        }
    }

    head_nodes(
        &mut g,
        &x,
        "fc",
        FC_IN as usize,
        final_map(input_size as usize),
        &weights.tensors,
    )?;

    let mut metadata = contract.to_metadata();
    metadata.push((META_ARCH.to_string(), "resnet18".to_string()));
    g.finish("jetpilot", producer_version, &metadata)
}

/// `name = Conv(input, name.weight)`: square kernel `k`, stride, symmetric padding, no bias.
fn conv(g: &mut GraphBuilder, name: &str, input: &str, k: i64, stride: i64, pad: i64) {
    conv_node(g, name, input, k, stride, [pad, pad, pad, pad], 1);
}

/// `name = Conv(input, name.weight)` without bias: square kernel `k`, `stride`, `pads` in
/// ONNX's order (top, left, bottom, right), `group` groups.
pub(crate) fn conv_node(
    g: &mut GraphBuilder,
    name: &str,
    input: &str,
    k: i64,
    stride: i64,
    pads: [i64; 4],
    group: i64,
) {
    let weight = format!("{name}.weight");
    let attrs = vec![
        attr_ints("kernel_shape", &[k, k]),
        attr_ints("strides", &[stride, stride]),
        attr_ints("pads", &pads),
        attr_ints("dilations", &[1, 1]),
        attr_int("group", group),
    ];
    g.node("Conv", &[input, &weight], &[name], attrs);
}

/// `name = BatchNormalization(input, name.{weight,bias,running_mean,running_var})`.
fn bn(g: &mut GraphBuilder, name: &str, input: &str) {
    bn_node(g, name, input, BN_EPSILON);
}

/// `name = BatchNormalization(input, name.{weight,bias,running_mean,running_var})` in
/// inference form with `epsilon`.
pub(crate) fn bn_node(g: &mut GraphBuilder, name: &str, input: &str, epsilon: f32) {
    let p: Vec<String> = ["weight", "bias", "running_mean", "running_var"]
        .iter()
        .map(|s| format!("{name}.{s}"))
        .collect();
    g.node(
        "BatchNormalization",
        &[input, &p[0], &p[1], &p[2], &p[3]],
        &[name],
        vec![attr_float("epsilon", epsilon), attr_float("momentum", 0.9)],
    );
}

/// One BasicBlock named `p` (`layer2.0`); returns the name of its output value.
fn basic_block(g: &mut GraphBuilder, p: &str, input: &str, stride: i64) -> String {
    let n = |s: &str| format!("{p}.{s}");
    conv(g, &n("conv1"), input, 3, stride, 1);
    bn(g, &n("bn1"), &n("conv1"));
    g.node("Relu", &[&n("bn1")], &[&n("relu")], vec![]);
    conv(g, &n("conv2"), &n("relu"), 3, 1, 1);
    bn(g, &n("bn2"), &n("conv2"));
    let identity = if stride != 1 {
        conv(g, &n("downsample.0"), input, 1, stride, 0);
        bn(g, &n("downsample.1"), &n("downsample.0"));
        n("downsample.1")
    } else {
        input.to_string()
    };
    g.node("Add", &[&n("bn2"), &identity], &[&n("add")], vec![]);
    g.node("Relu", &[&n("add")], &[&n("out")], vec![]);
    n("out")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::{encode_model, inspect_bytes};

    /// `Resnet18Weights::random(2, 7)`, generated once (11M samples are slow in debug builds).
    fn seed7() -> &'static Resnet18Weights {
        static W: std::sync::OnceLock<Resnet18Weights> = std::sync::OnceLock::new();
        W.get_or_init(|| Resnet18Weights::random(2, 7))
    }

    fn contract(size: u32) -> ModelContract {
        ModelContract {
            input_size: size,
            ..Default::default()
        }
    }

    #[test]
    fn an_input_below_32_or_off_the_contract_is_refused_by_name() {
        assert!(check_input_size("ResNet-18", 32, &contract(32)).is_ok());
        let small = check_input_size("ResNet-18", 16, &contract(16)).unwrap_err();
        assert_eq!(
            small.to_string(),
            OnnxError::Graph("ResNet-18 needs an input of at least 32x32, got 16".into())
                .to_string()
        );
        let off = check_input_size("EfficientNet-Lite0", 96, &contract(128)).unwrap_err();
        assert!(
            off.to_string()
                .contains("input size 96 differs from the contract's 128"),
            "{off}"
        );
        // The builders call it before any tensor is read.
        let e = resnet18_model(96, seed7(), &contract(128), "t").unwrap_err();
        assert!(
            e.to_string().contains("differs from the contract's 128"),
            "{e}"
        );
    }

    #[test]
    fn a_fresh_head_replaces_fc_only_and_is_seeded() {
        let mut classifier = seed7().clone();
        classifier
            .tensors
            .insert("fc.weight".into(), (vec![1000, 512], vec![0.5; 512_000]));
        classifier
            .tensors
            .insert("fc.bias".into(), (vec![1000], vec![0.5; 1000]));
        let xy = classifier.with_fresh_head(2, 3);
        assert_eq!(xy.num_outputs().unwrap(), 2);
        let (dims, w) = &xy.tensors["fc.weight"];
        assert_eq!((dims.as_slice(), w.len()), (&[2i64, 512][..], 1024));
        let bound = 1.0 / 512f32.sqrt(); // 0.0442
        assert!(w.iter().all(|v| v.abs() <= bound) && w.iter().any(|v| *v != 0.0));
        assert_eq!(xy.tensors["fc.bias"].0, vec![2]);
        for (name, t) in &seed7().tensors {
            if !name.starts_with("fc.") {
                assert_eq!(&xy.tensors[name], t, "{name} kept");
            }
        }
        assert_eq!(xy, classifier.with_fresh_head(2, 3), "seeded");
        assert_ne!(
            xy.tensors["fc.weight"],
            classifier.with_fresh_head(2, 4).tensors["fc.weight"]
        );
    }

    #[test]
    fn parameter_count_matches_torchvision() {
        // torchvision resnet18 has 11,689,512 parameters with its 1000-class fc
        // (512*1000 + 1000 = 513,000), so 11,176,512 without fc; fc 512->2 adds 1,026:
        // 11,177,538 trainable parameters.
        // BN channels: bn1 64 + layer1 4*64 + layer2 (4+1)*128 + layer3 5*256 + layer4 5*512
        // = 64 + 256 + 640 + 1280 + 2560 = 4,800; running_mean + running_var add 9,600.
        let w = seed7();
        let trainable: u64 = w
            .tensors
            .iter()
            .filter(|(k, _)| !k.ends_with("running_mean") && !k.ends_with("running_var"))
            .map(|(_, (d, _))| element_count(d))
            .sum();
        assert_eq!(trainable, 11_177_538);
        assert_eq!(parameter_count(w), 11_177_538 + 9_600);
        assert_eq!(Resnet18Weights::param_shapes(2).len(), 102);
    }

    #[test]
    fn same_seed_same_bytes_different_seed_different_bytes() {
        let c = contract(64);
        let enc = |w: &Resnet18Weights| encode_model(&resnet18_model(64, w, &c, "t").unwrap());
        let a = enc(seed7());
        assert_eq!(a, enc(&Resnet18Weights::random(2, 7)));
        assert_ne!(a, enc(&Resnet18Weights::random(2, 8)));
    }

    #[test]
    fn kaiming_std_of_conv1() {
        let w = seed7();
        let (dims, v) = &w.tensors["conv1.weight"];
        assert_eq!(dims, &vec![64, 3, 7, 7]);
        let n = v.len() as f64;
        let mean = v.iter().map(|&x| f64::from(x)).sum::<f64>() / n;
        let var = v
            .iter()
            .map(|&x| (f64::from(x) - mean).powi(2))
            .sum::<f64>()
            / n;
        let want = (2.0f64 / (64.0 * 49.0)).sqrt();
        assert!(
            (var.sqrt() / want - 1.0).abs() < 0.05,
            "std {} want {want}",
            var.sqrt()
        );
        assert!(mean.abs() < 0.1 * want, "mean {mean}");
        let bound = 1.0 / 512f32.sqrt();
        let (_, fc) = &w.tensors["fc.weight"];
        assert!(fc.iter().all(|x| x.abs() <= bound));
        assert_eq!(
            w.tensors["layer3.0.downsample.1.running_var"].1,
            vec![1.0; 256]
        );
        assert_eq!(w.tensors["layer3.0.downsample.1.bias"].1, vec![0.0; 256]);
    }

    #[test]
    fn round_trip_through_inspect() {
        let c = contract(64);
        let m = resnet18_model(64, seed7(), &c, "0.1.0").unwrap();
        let s = inspect_bytes(encode_model(&m).into(), "mem.onnx").unwrap();
        assert_eq!(s.ir_version, 8);
        assert_eq!(s.opsets, vec![("ai.onnx".to_string(), 17)]);
        assert_eq!(s.producer, "jetpilot 0.1.0");
        assert_eq!(s.inputs.len(), 1);
        assert_eq!(s.inputs[0].to_string(), "input float32 [1,3,64,64]");
        assert_eq!(s.outputs.len(), 1);
        assert_eq!(s.outputs[0].to_string(), "output float32 [1,2]");
        assert_eq!(s.contract().unwrap(), Some(c));
        assert_eq!(s.metadata[META_ARCH], "resnet18");
        let ops: Vec<(&str, usize)> = s.op_counts.iter().map(|(k, v)| (k.as_str(), *v)).collect();
        assert_eq!(
            ops,
            vec![
                ("Add", 8),
                ("BatchNormalization", 20),
                ("Conv", 20),
                ("Flatten", 1),
                ("Gemm", 1),
                ("GlobalAveragePool", 1),
                ("MaxPool", 1),
                ("Relu", 17),
            ]
        );
        assert_eq!(s.nodes, 69);
        assert_eq!(s.initializers, 102);
        assert_eq!(s.parameters, 11_177_538 + 9_600);
    }

    #[test]
    fn missing_or_misshapen_weight_is_named() {
        let c = contract(64);
        let mut w = seed7().clone();
        w.tensors.remove("layer3.1.bn2.running_var");
        let err = resnet18_model(64, &w, &c, "t").unwrap_err().to_string();
        assert!(
            err.contains("`layer3.1.bn2.running_var`") && err.contains("[256]"),
            "{err}"
        );

        let mut w = seed7().clone();
        w.tensors.insert(
            "layer2.0.conv1.weight".into(),
            (vec![128, 64, 1, 1], vec![0.0; 128 * 64]),
        );
        let err = resnet18_model(64, &w, &c, "t").unwrap_err().to_string();
        assert_eq!(
            err,
            "weight `layer2.0.conv1.weight` has shape [128,64,1,1], expected [128,64,3,3]"
        );

        let mut w = seed7().clone();
        w.tensors.get_mut("fc.bias").unwrap().1.pop();
        let err = resnet18_model(64, &w, &c, "t").unwrap_err().to_string();
        assert!(err.contains("`fc.bias`"), "{err}");

        let mut w = seed7().clone();
        w.tensors.remove("fc.weight");
        let err = resnet18_model(64, &w, &c, "t").unwrap_err().to_string();
        assert!(err.contains("`fc.weight`"), "{err}");
    }

    #[test]
    fn input_size_must_match_contract() {
        let w = seed7();
        assert!(resnet18_model(112, w, &contract(64), "t").is_err());
        assert!(resnet18_model(16, w, &contract(16), "t").is_err());
    }

    /// Writes models for checking with Python's onnx / onnxruntime:
    /// `JETPILOT_ONNX_DUMP=/tmp/dir cargo test --lib policy::onnx -- --ignored dump`.
    #[test]
    #[ignore]
    fn dump_models_for_external_check() {
        let Ok(dir) = std::env::var("JETPILOT_ONNX_DUMP") else {
            return;
        };
        for size in [64u32, 112, 224] {
            let m = resnet18_model(
                size,
                &Resnet18Weights::random(2, 1),
                &contract(size),
                "test",
            )
            .unwrap();
            let path = std::path::Path::new(&dir).join(format!("resnet18_seed1_{size}.onnx"));
            crate::policy::onnx::write_model(&path, &m).unwrap();
        }
    }
}
