//! Which activations a QDQ model quantizes, read off the graph (after batch-norm folding).
//!
//! ONNX Runtime turns `DequantizeLinear -> op -> QuantizeLinear` groups into integer
//! kernels (QLinearConv, QLinearAdd) and drops a ReLU whose output feeds a
//! QuantizeLinear with the type's lowest zero point. So a tensor is quantized where an
//! integer kernel reads or writes it:
//! - the data input of every Conv with constant weights;
//! - both inputs of every Add;
//! - the output of such a Conv or Add, or of the ReLU (or ReLU6, `Clip`: EfficientNet-Lite0)
//!   right after it when that is its only reader (it then folds into the quantization: a
//!   range calibrated after it starts at 0 and, for ReLU6, ends at 6 at most);
//! - the output of a MaxPool whose input is quantized, with the input's own scale, so ONNX
//!   Runtime runs the pooling on the integers.
//!
//! Everything else (global pooling, the fully connected head) stays float32 and reads
//! dequantized values, and so do the convolutions named to stay float ([`float_convs`]):
//! they read dequantized values (or the float graph input), and their outputs are
//! quantized only where an integer convolution reads them, not for an `Add` (which then
//! runs in float). A quantized output after a quantized input would let ONNX Runtime's
//! `WeightBiasQuantization` quantize the float weights itself.

use std::collections::{BTreeMap, BTreeSet};

use crate::policy::onnx::proto::{GraphProto, NodeProto};

/// One activation to quantize.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Activation {
    pub name: String,
    /// Takes this tensor's scale and zero point instead of its own calibrated range.
    pub same_as: Option<String>,
}

/// Whether `n` is a Conv whose weight is a constant (one the quantizer can make integer).
fn weighted_conv(n: &NodeProto, inits: &BTreeSet<&str>) -> bool {
    n.op_type == "Conv" && n.input.len() >= 2 && inits.contains(n.input[1].as_str())
}

/// Which convolutions stay float32, counted in graph order from each end.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FloatConvs {
    /// The first N (for EfficientNet-Lite0 and ResNet-18, 1 is the stem, `_conv_stem` or
    /// `conv1`: the graph input is then not quantized either).
    pub first: usize,
    /// The last N (for EfficientNet-Lite0, 1 is `_conv_head`; for ResNet-18,
    /// `layer4.1.conv2`).
    pub last: usize,
}

/// The first outputs of the convolutions `f` names, or an error when that is all of them
/// (nothing would be left to quantize).
pub fn float_convs(graph: &GraphProto, f: FloatConvs) -> Result<BTreeSet<String>, String> {
    let inits: BTreeSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let convs: Vec<&NodeProto> = graph
        .node
        .iter()
        .filter(|c| weighted_conv(c, &inits))
        .collect();
    let n = f.first + f.last;
    if n >= convs.len() && n > 0 {
        return Err(format!(
            "the model has {} convolutions; leaving the first {} and the last {} in float would quantize none",
            convs.len(),
            f.first,
            f.last
        ));
    }
    Ok(convs[..f.first]
        .iter()
        .chain(&convs[convs.len() - f.last..])
        .filter_map(|c| c.output.first().cloned())
        .collect())
}

/// The activations in the order their producers run (graph inputs first). The Convs whose
/// first output is in `float` stay float32: they mark nothing, and their outputs (or the
/// ReLU right after) are quantized only where an integer Conv reads them, not for an `Add`.
pub fn activations(graph: &GraphProto, float: &BTreeSet<String>) -> Vec<Activation> {
    let inits: BTreeSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let graph_outputs: BTreeSet<&str> = graph.output.iter().map(|o| o.name.as_str()).collect();
    let mut readers: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, n) in graph.node.iter().enumerate() {
        for input in &n.input {
            readers.entry(input.as_str()).or_default().push(i);
        }
    }
    // `v`, or the ReLU output that is `v`'s only reader.
    let after_relu = |v: &str| -> String {
        match readers.get(v).map(Vec::as_slice) {
            Some([r])
                if matches!(graph.node[*r].op_type.as_str(), "Relu" | "Clip")
                    && !graph_outputs.contains(v) =>
            {
                graph.node[*r].output[0].clone()
            }
            _ => v.to_string(),
        }
    };
    // What the float convolutions write (or the ReLU right after): only an integer
    // convolution that reads it as its input may quantize it.
    let float_outputs: BTreeSet<String> = graph
        .node
        .iter()
        .filter(|n| weighted_conv(n, &inits))
        .filter_map(|n| n.output.first().filter(|o| float.contains(*o)))
        .flat_map(|o| [o.clone(), after_relu(o)])
        .collect();
    let mut marked: BTreeSet<String> = BTreeSet::new();
    for n in &graph.node {
        match n.op_type.as_str() {
            "Conv"
                if weighted_conv(n, &inits)
                    && !n.output.first().is_some_and(|o| float.contains(o)) =>
            {
                marked.insert(n.input[0].clone());
                marked.insert(after_relu(&n.output[0]));
            }
            "Add" if n.input.len() == 2 && n.input.iter().all(|i| !inits.contains(i.as_str())) => {
                marked.extend(
                    n.input
                        .iter()
                        .filter(|i| !float_outputs.contains(*i))
                        .cloned(),
                );
                marked.insert(after_relu(&n.output[0]));
            }
            _ => {}
        }
    }
    let mut same_as = BTreeMap::new();
    for n in &graph.node {
        if n.op_type == "MaxPool" && n.output.len() == 1 && marked.contains(&n.output[0]) {
            marked.insert(n.input[0].clone());
            same_as.insert(n.output[0].clone(), n.input[0].clone());
        }
    }
    let order = graph
        .input
        .iter()
        .map(|i| &i.name)
        .chain(graph.node.iter().flat_map(|n| n.output.iter()));
    order
        .filter(|v| marked.contains(*v))
        .map(|v| Activation {
            name: v.clone(),
            same_as: same_as.get(v).cloned(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::graph::{Dim, GraphBuilder};

    fn last(n: usize) -> FloatConvs {
        FloatConvs { first: 0, last: n }
    }

    /// Input `x` [1,1,4,4], 1x1 weights `wa` and `wb`, then `nodes` (op, inputs, output),
    /// then `o -> GlobalAveragePool -> y`.
    fn two_convs(nodes: &[(&str, &[&str], &str)]) -> GraphProto {
        let mut g = GraphBuilder::new("t");
        for w in ["wa", "wb"] {
            g.initializer_f32(w, &[1, 1, 1, 1], &[1.0]).unwrap();
        }
        g.input_f32("x", &[1.into(), 1.into(), 4.into(), 4.into()]);
        for (op, inputs, output) in nodes {
            g.node(op, inputs, &[output], vec![]);
        }
        g.node("GlobalAveragePool", &["o"], &["y"], vec![]);
        g.output_f32("y", &[Dim::Fixed(1), 1.into(), 1.into(), 1.into()]);
        g.finish("t", "0", &[]).unwrap().graph.unwrap()
    }

    #[test]
    fn a_residual_block_quantizes_where_integer_kernels_read_and_write() {
        // x -> conv a -> relu r -> maxpool m -> conv b -> add(b, m) -> relu o -> gap -> y
        let graph = two_convs(&[
            ("Conv", &["x", "wa"], "a"),
            ("Relu", &["a"], "r"),
            ("MaxPool", &["r"], "m"),
            ("Conv", &["m", "wb"], "b"),
            ("Add", &["b", "m"], "s"),
            ("Relu", &["s"], "o"),
        ]);
        let got: Vec<(String, Option<String>)> = activations(&graph, &BTreeSet::new())
            .into_iter()
            .map(|a| (a.name, a.same_as))
            .collect();
        let want = vec![
            ("x".to_string(), None),
            ("r".to_string(), None),
            ("m".to_string(), Some("r".to_string())),
            ("b".to_string(), None),
            ("o".to_string(), None),
        ];
        assert_eq!(
            got, want,
            "a, s (ReLU follows) and y (float head) stay float"
        );
        // b left float: its output is not quantized, though the Add reads it.
        let names: Vec<String> = activations(&graph, &float_convs(&graph, last(1)).unwrap())
            .into_iter()
            .map(|a| a.name)
            .collect();
        assert_eq!(names, ["x", "r", "m", "o"]);
    }

    #[test]
    fn a_conv_left_float_marks_nothing_and_its_producer_still_quantizes() {
        // x -> conv a -> relu r -> conv b -> relu o -> gap -> y; b stays float
        let graph = two_convs(&[
            ("Conv", &["x", "wa"], "a"),
            ("Relu", &["a"], "r"),
            ("Conv", &["r", "wb"], "b"),
            ("Relu", &["b"], "o"),
        ]);
        let float = float_convs(&graph, last(1)).unwrap();
        assert_eq!(float, BTreeSet::from(["b".to_string()]));
        let names: Vec<String> = activations(&graph, &float)
            .into_iter()
            .map(|a| a.name)
            .collect();
        assert_eq!(names, ["x", "r"], "o is b's, which stays float");
        let all: Vec<String> =
            activations(&graph, &float_convs(&graph, FloatConvs::default()).unwrap())
                .into_iter()
                .map(|a| a.name)
                .collect();
        assert_eq!(all, ["x", "r", "o"]);
        let err = float_convs(&graph, last(2)).unwrap_err();
        assert!(err.contains("has 2 convolutions"), "{err}");
        // a left float: the graph input is no longer quantized, r still is (b reads it)
        let first = FloatConvs { first: 1, last: 0 };
        assert_eq!(
            float_convs(&graph, first).unwrap(),
            BTreeSet::from(["a".to_string()])
        );
        let names: Vec<String> = activations(&graph, &float_convs(&graph, first).unwrap())
            .into_iter()
            .map(|a| a.name)
            .collect();
        assert_eq!(names, ["r", "o"]);
    }
}
