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
//! dequantized values.

use std::collections::{BTreeMap, BTreeSet};

use crate::policy::onnx::proto::GraphProto;

/// One activation to quantize.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Activation {
    pub name: String,
    /// Takes this tensor's scale and zero point instead of its own calibrated range.
    pub same_as: Option<String>,
}

/// The activations in the order their producers run (graph inputs first).
pub fn activations(graph: &GraphProto) -> Vec<Activation> {
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
    let mut marked: BTreeSet<String> = BTreeSet::new();
    for n in &graph.node {
        match n.op_type.as_str() {
            "Conv" if n.input.len() >= 2 && inits.contains(n.input[1].as_str()) => {
                marked.insert(n.input[0].clone());
                marked.insert(after_relu(&n.output[0]));
            }
            "Add" if n.input.len() == 2 && n.input.iter().all(|i| !inits.contains(i.as_str())) => {
                marked.extend(n.input.iter().cloned());
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

    #[test]
    fn a_residual_block_quantizes_where_integer_kernels_read_and_write() {
        // x -> conv a -> relu r -> maxpool m -> conv b -> add(b, m) -> relu o -> gap -> y
        let mut g = GraphBuilder::new("t");
        for w in ["wa", "wb"] {
            g.initializer_f32(w, &[1, 1, 1, 1], &[1.0]).unwrap();
        }
        g.input_f32("x", &[1.into(), 1.into(), 4.into(), 4.into()]);
        g.node("Conv", &["x", "wa"], &["a"], vec![]);
        g.node("Relu", &["a"], &["r"], vec![]);
        g.node("MaxPool", &["r"], &["m"], vec![]);
        g.node("Conv", &["m", "wb"], &["b"], vec![]);
        g.node("Add", &["b", "m"], &["s"], vec![]);
        g.node("Relu", &["s"], &["o"], vec![]);
        g.node("GlobalAveragePool", &["o"], &["y"], vec![]);
        g.output_f32("y", &[Dim::Fixed(1), 1.into(), 1.into(), 1.into()]);
        let graph = g.finish("t", "0", &[]).unwrap().graph.unwrap();
        let got: Vec<(String, Option<String>)> = activations(&graph)
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
    }
}
