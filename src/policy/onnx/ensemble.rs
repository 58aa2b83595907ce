//! [`ensemble`]: several models of one contract become one ONNX file whose output is the
//! mean of theirs (the seeds of one recipe, say; `jetpilot model ensemble`).
//!
//! The models share the graph input. Every other name of model `k` (its nodes, weights,
//! values and output) is put under `m{k}/`, so nothing collides, and one ONNX `Mean` node
//! writes the first model's output name. The metadata (the contract, the architecture) is
//! the first model's, plus [`META_ENSEMBLE`]. The models must agree on the contract, the
//! input, the output and the opsets; an error names the file that differs and how.

use std::collections::{BTreeMap, BTreeSet};

use super::OnnxError;
use super::proto::{
    AttributeType, DATA_LOCATION_EXTERNAL, GraphProto, ModelProto, NodeProto,
    StringStringEntryProto,
};
use crate::policy::ModelContract;

/// Metadata key of an ensemble: how many models, and the files they came from.
pub const META_ENSEMBLE: &str = "jetpilot.ensemble";

/// One model to average and the name its errors use (its path).
pub struct Member {
    pub path: String,
    pub model: ModelProto,
}

/// The model whose output is the mean of `members`' outputs, for the same input.
pub fn ensemble(members: &[Member]) -> Result<ModelProto, OnnxError> {
    let Some(first) = members.first() else {
        return Err(OnnxError::Graph(
            "an ensemble needs at least one model".into(),
        ));
    };
    let shape = Shape::of(first)?;
    for m in &members[1..] {
        shape.same_as(&Shape::of(m)?, &first.path, &m.path)?;
    }

    let mut graph = GraphProto {
        name: format!("ensemble of {}", members.len()),
        input: vec![shape.input.clone()],
        output: vec![shape.output.clone()],
        ..Default::default()
    };
    let mut means = Vec::with_capacity(members.len());
    for (k, m) in members.iter().enumerate() {
        let g = graph_of(m)?;
        let prefix = format!("m{k}/");
        let rename = |name: &str| -> String {
            if name.is_empty() || name == shape.input.name {
                name.to_string()
            } else {
                format!("{prefix}{name}")
            }
        };
        for t in &g.initializer {
            if t.data_location == DATA_LOCATION_EXTERNAL {
                return Err(OnnxError::TensorData {
                    name: t.name.clone(),
                    reason: format!(
                        "{}: its data lives in a file beside the model (`model optimize` \
                         writes such files); ensemble the models before optimising",
                        m.path
                    ),
                });
            }
            let mut t = t.clone();
            t.name = rename(&t.name);
            graph.initializer.push(t);
        }
        for n in &g.node {
            if let Some(a) = n
                .attribute
                .iter()
                .find(|a| a.r#type == AttributeType::Graph as i32)
            {
                return Err(OnnxError::Graph(format!(
                    "{}: node `{}` ({}) has a subgraph (attribute `{}`), which an ensemble \
                     cannot rename",
                    m.path, n.name, n.op_type, a.name
                )));
            }
            graph.node.push(NodeProto {
                input: n.input.iter().map(|s| rename(s)).collect(),
                output: n.output.iter().map(|s| rename(s)).collect(),
                name: rename(&n.name),
                ..n.clone()
            });
        }
        for v in &g.value_info {
            let mut v = v.clone();
            v.name = rename(&v.name);
            graph.value_info.push(v);
        }
        means.push(rename(&shape.output.name));
    }
    graph.node.push(NodeProto {
        input: means,
        output: vec![shape.output.name.clone()],
        name: "ensemble_mean".into(),
        op_type: "Mean".into(),
        ..Default::default()
    });

    let mut metadata_props = first.model.metadata_props.clone();
    metadata_props.retain(|e| e.key != META_ENSEMBLE);
    let paths: Vec<&str> = members.iter().map(|m| m.path.as_str()).collect();
    metadata_props.push(StringStringEntryProto {
        key: META_ENSEMBLE.into(),
        value: format!("mean of {} models: {}", members.len(), paths.join(", ")),
    });
    Ok(ModelProto {
        graph: Some(graph),
        metadata_props,
        doc_string: format!("the mean output of {} models", members.len()),
        ..first.model.clone()
    })
}

fn graph_of(m: &Member) -> Result<&GraphProto, OnnxError> {
    m.model.graph.as_ref().ok_or_else(|| OnnxError::NotAModel {
        path: m.path.clone(),
        reason: "no graph".into(),
    })
}

/// What the members must share: the graph input (initializers listed as inputs left
/// out), the one output, the opsets and the contract.
struct Shape {
    input: super::proto::ValueInfoProto,
    output: super::proto::ValueInfoProto,
    opsets: BTreeSet<(String, i64)>,
    contract: Option<ModelContract>,
}

impl Shape {
    fn of(m: &Member) -> Result<Shape, OnnxError> {
        let g = graph_of(m)?;
        let not_model = |reason: String| OnnxError::NotAModel {
            path: m.path.clone(),
            reason,
        };
        let weights: BTreeSet<&str> = g.initializer.iter().map(|t| t.name.as_str()).collect();
        let inputs: Vec<_> = g
            .input
            .iter()
            .filter(|v| !weights.contains(v.name.as_str()))
            .collect();
        let [input] = inputs[..] else {
            return Err(not_model(format!(
                "an ensemble takes models of one input, this one has {}",
                inputs.len()
            )));
        };
        let [output] = &g.output[..] else {
            return Err(not_model(format!(
                "an ensemble takes models of one output, this one has {}",
                g.output.len()
            )));
        };
        let metadata: BTreeMap<String, String> = m
            .model
            .metadata_props
            .iter()
            .map(|e| (e.key.clone(), e.value.clone()))
            .collect();
        let contract =
            ModelContract::from_metadata(&metadata).map_err(|source| OnnxError::Contract {
                path: m.path.clone(),
                source,
            })?;
        Ok(Shape {
            input: input.clone(),
            output: output.clone(),
            opsets: m
                .model
                .opset_import
                .iter()
                .map(|o| (o.domain.clone(), o.version))
                .collect(),
            contract,
        })
    }

    /// Whether `other` (of the file `theirs`) can be averaged with `self` (of `ours`).
    fn same_as(&self, other: &Shape, ours: &str, theirs: &str) -> Result<(), OnnxError> {
        let differ = |what: &str, a: String, b: String| {
            Err(OnnxError::Graph(format!(
                "{theirs} cannot join an ensemble with {ours}: its {what} is {b}, not {a}"
            )))
        };
        let show_contract = |c: &Option<ModelContract>| {
            c.as_ref()
                .map_or_else(|| "none".to_string(), ToString::to_string)
        };
        if self.contract != other.contract {
            return differ(
                "contract",
                show_contract(&self.contract),
                show_contract(&other.contract),
            );
        }
        if self.input != other.input {
            return differ(
                "input",
                format!("{:?}", self.input),
                format!("{:?}", other.input),
            );
        }
        if self.output.name != other.output.name || self.output.r#type != other.output.r#type {
            return differ(
                "output",
                format!("{:?}", self.output),
                format!("{:?}", other.output),
            );
        }
        if self.opsets != other.opsets {
            return differ(
                "opset list",
                format!("{:?}", self.opsets),
                format!("{:?}", other.opsets),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::graph::{Dim, GraphBuilder};

    /// y = x * w, with the weight `w` and one node, as a member named `path`.
    fn scale(path: &str, w: f32, out: &str) -> Member {
        let mut b = GraphBuilder::new("scale");
        b.input_f32("x", &[Dim::Fixed(1), Dim::Fixed(2)]);
        b.initializer_f32("w", &[2], &[w, w]).unwrap();
        b.node("Mul", &["x", "w"], &[out], vec![]);
        b.output_f32(out, &[Dim::Fixed(1), Dim::Fixed(2)]);
        Member {
            path: path.into(),
            model: b.finish("test", "0", &[]).unwrap(),
        }
    }

    #[test]
    fn members_are_renamed_apart_and_averaged_by_one_mean_node() {
        let m = ensemble(&[scale("a.onnx", 2.0, "y"), scale("b.onnx", 4.0, "y")]).unwrap();
        let g = m.graph.as_ref().unwrap();
        let weights: Vec<&str> = g.initializer.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(weights, ["m0/w", "m1/w"]);
        let nodes: Vec<(&str, Vec<&str>, Vec<&str>)> = g
            .node
            .iter()
            .map(|n| {
                (
                    n.op_type.as_str(),
                    n.input.iter().map(String::as_str).collect(),
                    n.output.iter().map(String::as_str).collect(),
                )
            })
            .collect();
        assert_eq!(
            nodes,
            [
                ("Mul", vec!["x", "m0/w"], vec!["m0/y"]),
                ("Mul", vec!["x", "m1/w"], vec!["m1/y"]),
                ("Mean", vec!["m0/y", "m1/y"], vec!["y"]),
            ]
        );
        assert_eq!(g.input.len(), 1);
        assert_eq!(g.input[0].name, "x");
        assert_eq!(g.output.len(), 1);
        assert_eq!(g.output[0].name, "y");
        let meta: Vec<(&str, &str)> = m
            .metadata_props
            .iter()
            .map(|e| (e.key.as_str(), e.value.as_str()))
            .collect();
        assert!(
            meta.contains(&(META_ENSEMBLE, "mean of 2 models: a.onnx, b.onnx")),
            "{meta:?}"
        );
    }

    #[test]
    fn a_member_with_another_output_is_refused_with_both_files_named() {
        let err = ensemble(&[scale("a.onnx", 2.0, "y"), scale("b.onnx", 4.0, "z")]).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("b.onnx cannot join an ensemble with a.onnx: its output is"),
            "{msg}"
        );
    }

    #[test]
    fn a_member_with_weights_in_a_side_file_is_refused() {
        let mut b = scale("b.onnx", 4.0, "y");
        if let Some(g) = b.model.graph.as_mut() {
            g.initializer[0].data_location = DATA_LOCATION_EXTERNAL;
        }
        let err = ensemble(&[scale("a.onnx", 2.0, "y"), b]).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("tensor `w`: b.onnx: its data lives in a file beside the model"),
            "{msg}"
        );
    }
}
