//! Batch normalisation folded into the convolution before it, the first step of
//! quantizing: a QDQ convolution's weights must be the ones it multiplies with.
//!
//! For a `Conv` whose only consumer is a `BatchNormalization` (inference form) with
//! per-channel `gamma, beta, mean, var` and `epsilon`:
//! `s_c = gamma_c / sqrt(var_c + epsilon)`, `W'_c = W_c * s_c`, `b'_c = (b_c - mean_c) * s_c + beta_c`.
//! The fold is exact up to float32 rounding, so the folded model gives the same outputs.

use std::collections::{BTreeMap, BTreeSet};

use super::QuantizeError;
use super::tensor::{f32_tensor, read_f32};
use crate::policy::onnx::proto::GraphProto;

/// Folds every foldable BatchNormalization into its Conv and drops the initializers
/// nothing uses any more; returns how many were folded. A BatchNormalization that cannot
/// be folded (its input is not a Conv's own output, weights shared, ...) is left in place.
pub fn fold_batch_norms(graph: &mut GraphProto) -> Result<usize, QuantizeError> {
    let uses = use_counts(graph);
    let init_index: BTreeMap<String, usize> = graph
        .initializer
        .iter()
        .enumerate()
        .map(|(i, t)| (t.name.clone(), i))
        .collect();
    let producer: BTreeMap<String, usize> = graph
        .node
        .iter()
        .enumerate()
        .flat_map(|(i, n)| n.output.iter().map(move |o| (o.clone(), i)))
        .collect();
    let mut drop_nodes = BTreeSet::new();
    let mut new_bias_names = BTreeSet::new();
    let mut folded = 0;
    for b in 0..graph.node.len() {
        let bn = &graph.node[b];
        if bn.op_type != "BatchNormalization" || bn.input.len() != 5 || bn.output.len() != 1 {
            continue;
        }
        let training = bn
            .attribute
            .iter()
            .any(|a| a.name == "training_mode" && a.i == Some(1));
        let Some(&c) = producer.get(&bn.input[0]) else {
            continue;
        };
        let conv = &graph.node[c];
        let params: Option<Vec<usize>> = bn.input[1..]
            .iter()
            .map(|n| init_index.get(n).copied())
            .collect();
        let weight = conv.input.get(1).and_then(|w| init_index.get(w).copied());
        let bias_name = conv.input.get(2).filter(|s| !s.is_empty()).cloned();
        let bias = bias_name.as_ref().and_then(|n| init_index.get(n).copied());
        let foldable = !training
            && conv.op_type == "Conv"
            && conv.output.len() == 1
            && uses.get(&bn.input[0]) == Some(&1)
            && weight.is_some_and(|w| uses.get(&graph.initializer[w].name) == Some(&1))
            && (bias_name.is_none()
                || bias.is_some_and(|i| uses.get(&graph.initializer[i].name) == Some(&1)));
        let (Some(params), Some(w), true) = (params, weight, foldable) else {
            continue;
        };
        let eps = bn
            .attribute
            .iter()
            .find(|a| a.name == "epsilon")
            .and_then(|a| a.f)
            .unwrap_or(1e-5);
        let [gamma, beta, mean, var] =
            [0, 1, 2, 3].map(|k| read_f32(&graph.initializer[params[k]]));
        let (gamma, beta, mean, var) = (gamma?, beta?, mean?, var?);
        let wt = &graph.initializer[w];
        let channels = wt.dims.first().copied().unwrap_or(0) as usize;
        if [gamma.len(), beta.len(), mean.len(), var.len()] != [channels; 4] || channels == 0 {
            return Err(QuantizeError::Unsupported(format!(
                "BatchNormalization `{}` has {} channels, the Conv weight `{}` before it {channels}",
                bn.output[0],
                gamma.len(),
                wt.name
            )));
        }
        let mut weights = read_f32(wt)?;
        let per_channel = weights.len() / channels;
        let old_bias = match bias {
            Some(i) => read_f32(&graph.initializer[i])?,
            None => vec![0.0; channels],
        };
        let mut new_bias = vec![0.0f32; channels];
        for ch in 0..channels {
            let s = gamma[ch] / (var[ch] + eps).sqrt();
            for v in &mut weights[ch * per_channel..(ch + 1) * per_channel] {
                *v *= s;
            }
            new_bias[ch] = (old_bias.get(ch).copied().unwrap_or(0.0) - mean[ch]) * s + beta[ch];
        }
        let (w_name, w_dims) = (wt.name.clone(), wt.dims.clone());
        let bn_out = bn.output[0].clone();
        graph.initializer[w] = f32_tensor(&w_name, &w_dims, &weights);
        let bias_target = match bias {
            Some(i) => {
                let name = graph.initializer[i].name.clone();
                graph.initializer[i] = f32_tensor(&name, &[channels as i64], &new_bias);
                name
            }
            None => {
                let mut name = format!("{w_name}.folded_bias");
                while init_index.contains_key(&name) || new_bias_names.contains(&name) {
                    name.push('_');
                }
                graph
                    .initializer
                    .push(f32_tensor(&name, &[channels as i64], &new_bias));
                new_bias_names.insert(name.clone());
                name
            }
        };
        let conv = &mut graph.node[c];
        conv.input.truncate(2);
        conv.input.push(bias_target);
        conv.output[0] = bn_out;
        drop_nodes.insert(b);
        folded += 1;
    }
    let mut i = 0;
    graph.node.retain(|_| {
        let keep = !drop_nodes.contains(&i);
        i += 1;
        keep
    });
    prune_initializers(graph);
    Ok(folded)
}

/// How often each value is read: node inputs and graph outputs.
pub fn use_counts(graph: &GraphProto) -> BTreeMap<String, usize> {
    let mut uses = BTreeMap::new();
    let names = graph
        .node
        .iter()
        .flat_map(|n| n.input.iter())
        .chain(graph.output.iter().map(|o| &o.name));
    for name in names.filter(|n| !n.is_empty()) {
        *uses.entry(name.clone()).or_insert(0) += 1;
    }
    uses
}

/// Drops initializers no node or graph output reads.
pub fn prune_initializers(graph: &mut GraphProto) {
    let uses = use_counts(graph);
    graph.initializer.retain(|t| uses.contains_key(&t.name));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::graph::{Dim, GraphBuilder, attr_float, attr_ints};

    /// Conv 1x1 (2 -> 2 channels, no bias) then BatchNormalization.
    fn conv_bn(with_bias: bool) -> GraphProto {
        let mut g = GraphBuilder::new("t");
        g.initializer_f32("w", &[2, 2, 1, 1], &[1.0, 2.0, -1.0, 0.5])
            .unwrap();
        if with_bias {
            g.initializer_f32("b", &[2], &[0.5, -0.5]).unwrap();
        }
        g.initializer_f32("gamma", &[2], &[2.0, 0.5]).unwrap();
        g.initializer_f32("beta", &[2], &[0.1, -0.2]).unwrap();
        g.initializer_f32("mean", &[2], &[1.0, -1.0]).unwrap();
        g.initializer_f32("var", &[2], &[3.0, 0.0]).unwrap();
        g.input_f32("x", &[1.into(), 2.into(), 1.into(), 1.into()]);
        let inputs: &[&str] = if with_bias {
            &["x", "w", "b"]
        } else {
            &["x", "w"]
        };
        g.node(
            "Conv",
            inputs,
            &["c"],
            vec![attr_ints("kernel_shape", &[1, 1])],
        );
        g.node(
            "BatchNormalization",
            &["c", "gamma", "beta", "mean", "var"],
            &["y"],
            vec![attr_float("epsilon", 1.0)],
        );
        g.output_f32("y", &[Dim::Fixed(1), 2.into(), 1.into(), 1.into()]);
        g.finish("t", "0", &[]).unwrap().graph.unwrap()
    }

    fn init(g: &GraphProto, name: &str) -> Vec<f32> {
        read_f32(g.initializer.iter().find(|t| t.name == name).unwrap()).unwrap()
    }

    #[test]
    fn folds_with_the_worked_numbers() {
        // s = gamma / sqrt(var + 1) = [2/2, 0.5/1] = [1, 0.5]
        // W' = [1*1, 2*1, -1*0.5, 0.5*0.5] = [1, 2, -0.5, 0.25]
        // b' = (0 - mean) * s + beta = [-1 + 0.1, 0.5 - 0.2] = [-0.9, 0.3]
        let mut g = conv_bn(false);
        assert_eq!(fold_batch_norms(&mut g).unwrap(), 1);
        assert_eq!(g.node.len(), 1);
        assert_eq!(g.node[0].op_type, "Conv");
        assert_eq!(g.node[0].input, vec!["x", "w", "w.folded_bias"]);
        assert_eq!(g.node[0].output, vec!["y"]);
        assert_eq!(init(&g, "w"), vec![1.0, 2.0, -0.5, 0.25]);
        let b = init(&g, "w.folded_bias");
        assert!(
            (b[0] + 0.9).abs() < 1e-6 && (b[1] - 0.3).abs() < 1e-6,
            "{b:?}"
        );
        let names: Vec<&str> = g.initializer.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(
            names,
            vec!["w", "w.folded_bias"],
            "the BN's tensors are dropped"
        );
    }

    #[test]
    fn an_existing_bias_is_folded_too() {
        // b' = (b - mean) * s + beta = [(0.5 - 1) * 1 + 0.1, (-0.5 + 1) * 0.5 - 0.2] = [-0.4, 0.05]
        let mut g = conv_bn(true);
        fold_batch_norms(&mut g).unwrap();
        assert_eq!(g.node[0].input, vec!["x", "w", "b"]);
        let b = init(&g, "b");
        assert!(
            (b[0] + 0.4).abs() < 1e-6 && (b[1] - 0.05).abs() < 1e-6,
            "{b:?}"
        );
    }

    #[test]
    fn a_conv_output_read_twice_is_not_folded() {
        let mut g = conv_bn(false);
        g.output.push(g.output[0].clone());
        g.output[1].name = "c".into();
        assert_eq!(fold_batch_norms(&mut g).unwrap(), 0);
        assert_eq!(g.node.len(), 2);
    }
}
