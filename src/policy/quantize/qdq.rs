//! The QDQ rewrite: QuantizeLinear/DequantizeLinear pairs after each planned activation,
//! int8 per-channel weights and int32 biases behind DequantizeLinear nodes in front of each
//! Conv. The float graph is otherwise unchanged, so any ONNX runtime can run the result;
//! ONNX Runtime fuses the groups into integer kernels.

use std::collections::{BTreeMap, BTreeSet};

use super::QuantizeError;
use super::fold::prune_initializers;
use super::params::{ActivationType, QParams, activation_params, quantize_bias, quantize_weights};
use super::plan::Activation;
use super::tensor::{f32_tensor, i8_tensor, i32_tensor, read_f32, u8_tensor};
use crate::policy::onnx::attr_int;
use crate::policy::onnx::proto::{GraphProto, NodeProto, TensorProto};

/// How to store what the plan quantizes.
#[derive(Debug, Clone, Copy)]
pub struct QdqOptions {
    pub activations: ActivationType,
    /// 127, or 63 for 7-bit weights.
    pub weight_max: i8,
}

/// Each planned activation's scale and zero point, from its calibrated `[lo, hi]`.
pub fn activation_table(
    plan: &[Activation],
    ranges: &BTreeMap<String, (f32, f32)>,
    t: ActivationType,
) -> Result<BTreeMap<String, QParams>, QuantizeError> {
    let mut table = BTreeMap::new();
    for a in plan {
        let p = match &a.same_as {
            Some(other) => table.get(other).copied(),
            None => ranges
                .get(&a.name)
                .map(|&(lo, hi)| activation_params(lo, hi, t)),
        };
        let p = p.ok_or_else(|| {
            QuantizeError::Unsupported(format!("no calibration range for activation `{}`", a.name))
        })?;
        table.insert(a.name.clone(), p);
    }
    Ok(table)
}

fn node(op: &str, name: String, inputs: [&str; 3], output: String, axis: Option<i64>) -> NodeProto {
    NodeProto {
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output],
        name,
        op_type: op.to_string(),
        attribute: axis.map(|a| vec![attr_int("axis", a)]).unwrap_or_default(),
        ..Default::default()
    }
}

fn dq_name(v: &str) -> String {
    format!("{v}_dequantized")
}

/// `v -> QuantizeLinear -> DequantizeLinear -> v_dequantized`.
fn push_qdq(
    v: &str,
    p: QParams,
    t: ActivationType,
    nodes: &mut Vec<NodeProto>,
    inits: &mut Vec<TensorProto>,
) {
    let (scale, zp, q) = (
        format!("{v}_scale"),
        format!("{v}_zero_point"),
        format!("{v}_quantized"),
    );
    inits.push(f32_tensor(&scale, &[], &[p.scale]));
    inits.push(match t {
        ActivationType::U8 => u8_tensor(&zp, &[], &[p.zero_point as u8]),
        ActivationType::S8 => i8_tensor(&zp, &[], &[p.zero_point as i8]),
    });
    nodes.push(node(
        "QuantizeLinear",
        format!("{v}_QuantizeLinear"),
        [v, &scale, &zp],
        q.clone(),
        None,
    ));
    nodes.push(node(
        "DequantizeLinear",
        format!("{v}_DequantizeLinear"),
        [&q, &scale, &zp],
        dq_name(v),
        None,
    ));
}

/// Rewrites `graph` (batch norms already folded) with `table`'s activations quantized. The
/// Convs whose first output is in `float` keep their float32 weights.
pub fn rewrite(
    graph: &GraphProto,
    table: &BTreeMap<String, QParams>,
    float: &BTreeSet<String>,
    opts: QdqOptions,
) -> Result<GraphProto, QuantizeError> {
    let by_name: BTreeMap<&str, &TensorProto> = graph
        .initializer
        .iter()
        .map(|t| (t.name.as_str(), t))
        .collect();
    let mut inits = graph.initializer.clone();
    let mut nodes = Vec::with_capacity(graph.node.len() * 3);
    for input in &graph.input {
        if let Some(&p) = table.get(&input.name) {
            push_qdq(&input.name, p, opts.activations, &mut nodes, &mut inits);
        }
    }
    for n in &graph.node {
        let mut out = n.clone();
        for i in &mut out.input {
            if table.contains_key(i.as_str()) {
                *i = dq_name(i);
            }
        }
        let weight = n
            .input
            .get(1)
            .and_then(|w| by_name.get(w.as_str()))
            .filter(|_| !n.output.first().is_some_and(|o| float.contains(o)));
        if let ("Conv", Some(w), Some(x)) = (n.op_type.as_str(), weight, table.get(&n.input[0])) {
            let values = read_f32(w)?;
            let channels = w.dims.first().copied().unwrap_or(0);
            if channels <= 0 || values.len() % channels as usize != 0 {
                return Err(QuantizeError::Unsupported(format!(
                    "Conv weight `{}` has shape {:?}",
                    w.name, w.dims
                )));
            }
            let q = quantize_weights(&values, channels as usize, opts.weight_max);
            let c = [channels];
            let (wq, ws, wz) = (
                format!("{}_quantized", w.name),
                format!("{}_scale", w.name),
                format!("{}_zero_point", w.name),
            );
            inits.push(i8_tensor(&wq, &w.dims, &q.values));
            inits.push(f32_tensor(&ws, &c, &q.scales));
            inits.push(i8_tensor(&wz, &c, &vec![0; channels as usize]));
            nodes.push(node(
                "DequantizeLinear",
                format!("{}_DequantizeLinear", w.name),
                [&wq, &ws, &wz],
                dq_name(&w.name),
                Some(0),
            ));
            out.input[1] = dq_name(&w.name);
            if let Some(b) = n.input.get(2).and_then(|b| by_name.get(b.as_str())) {
                let (bv, bs) = quantize_bias(&read_f32(b)?, x.scale, &q.scales);
                let (bq, bsn, bz) = (
                    format!("{}_quantized", b.name),
                    format!("{}_scale", b.name),
                    format!("{}_zero_point", b.name),
                );
                inits.push(i32_tensor(&bq, &c, &bv));
                inits.push(f32_tensor(&bsn, &c, &bs));
                inits.push(i32_tensor(&bz, &c, &vec![0; channels as usize]));
                nodes.push(node(
                    "DequantizeLinear",
                    format!("{}_DequantizeLinear", b.name),
                    [&bq, &bsn, &bz],
                    dq_name(&b.name),
                    Some(0),
                ));
                out.input[2] = dq_name(&b.name);
            }
        }
        let outputs = n.output.clone();
        nodes.push(out);
        for o in &outputs {
            if let Some(&p) = table.get(o) {
                push_qdq(o, p, opts.activations, &mut nodes, &mut inits);
            }
        }
    }
    let mut result = GraphProto {
        node: nodes,
        initializer: inits,
        ..graph.clone()
    };
    prune_initializers(&mut result);
    Ok(result)
}
