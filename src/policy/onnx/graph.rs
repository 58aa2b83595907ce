//! [`GraphBuilder`]: assembles initializers, nodes, inputs and outputs into a [`ModelProto`].
//!
//! Used by the ResNet-18 writer and by the trainer's exporter. Values are named by the
//! caller; node names are derived from them and kept unique. [`GraphBuilder::finish`] checks
//! that every node input is defined before use and every value is produced only once.

use std::collections::BTreeSet;
use std::fmt;

use prost::bytes::Bytes;

use super::OnnxError;
use super::proto::{
    AttributeProto, AttributeType, GraphProto, ModelProto, NodeProto, OperatorSetIdProto,
    StringStringEntryProto, TensorProto, TensorShapeProto, TypeProto, ValueInfoProto, data_type,
    tensor_shape_proto, type_proto,
};

/// ONNX IR version written (ONNX 1.12; ONNX Runtime 1.17+ loads it).
pub const IR_VERSION: i64 = 8;
/// Default-domain (`ai.onnx`) opset written.
pub const OPSET: i64 = 17;

/// One dimension of a tensor shape.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Dim {
    /// A fixed size.
    Fixed(i64),
    /// A named size that varies at run time, such as `batch`.
    Symbolic(String),
    /// A dimension with neither a size nor a name.
    Unknown,
}

impl fmt::Display for Dim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Dim::Fixed(n) => write!(f, "{n}"),
            Dim::Symbolic(s) => f.write_str(s),
            Dim::Unknown => f.write_str("?"),
        }
    }
}

impl From<i64> for Dim {
    fn from(n: i64) -> Self {
        Dim::Fixed(n)
    }
}

impl From<&str> for Dim {
    fn from(s: &str) -> Self {
        Dim::Symbolic(s.to_string())
    }
}

/// A shape as text: `[1,3,224,224]`, `[batch,2]`.
pub fn dims_to_string(dims: &[Dim]) -> String {
    let parts: Vec<String> = dims.iter().map(Dim::to_string).collect();
    format!("[{}]", parts.join(","))
}

/// `[64,3,7,7]` for fixed dims.
pub fn shape_to_string(dims: &[i64]) -> String {
    let parts: Vec<String> = dims.iter().map(i64::to_string).collect();
    format!("[{}]", parts.join(","))
}

/// Number of elements of a shape (1 for a scalar); negative dims count as 0.
pub(crate) fn element_count(dims: &[i64]) -> u64 {
    dims.iter().fold(1u64, |n, &d| {
        n.saturating_mul(u64::try_from(d).unwrap_or(0))
    })
}

/// An `INT` attribute.
pub fn attr_int(name: &str, value: i64) -> AttributeProto {
    AttributeProto {
        name: name.to_string(),
        i: Some(value),
        r#type: AttributeType::Int as i32,
        ..Default::default()
    }
}

/// An `INTS` attribute, such as `kernel_shape` or `pads`.
pub fn attr_ints(name: &str, values: &[i64]) -> AttributeProto {
    AttributeProto {
        name: name.to_string(),
        ints: values.to_vec(),
        r#type: AttributeType::Ints as i32,
        ..Default::default()
    }
}

/// A `FLOAT` attribute, such as BatchNormalization's `epsilon`.
pub fn attr_float(name: &str, value: f32) -> AttributeProto {
    AttributeProto {
        name: name.to_string(),
        f: Some(value),
        r#type: AttributeType::Float as i32,
        ..Default::default()
    }
}

/// Builds one ONNX graph; see the module docs.
#[derive(Debug, Default)]
pub struct GraphBuilder {
    name: String,
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
    inputs: Vec<ValueInfoProto>,
    outputs: Vec<ValueInfoProto>,
    node_names: BTreeSet<String>,
}

impl GraphBuilder {
    /// An empty graph called `name`.
    pub fn new(name: &str) -> Self {
        Self {
            name: name.to_string(),
            ..Default::default()
        }
    }

    /// A float32 constant tensor of shape `dims`, stored as little-endian `raw_data`.
    pub fn initializer_f32(
        &mut self,
        name: &str,
        dims: &[i64],
        values: &[f32],
    ) -> Result<(), OnnxError> {
        check_len(name, dims, values.len())?;
        let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.push_initializer(name, dims, data_type::FLOAT, raw);
        Ok(())
    }

    /// An int64 constant tensor of shape `dims` (e.g. a Reshape target), little-endian.
    pub fn initializer_i64(
        &mut self,
        name: &str,
        dims: &[i64],
        values: &[i64],
    ) -> Result<(), OnnxError> {
        check_len(name, dims, values.len())?;
        let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.push_initializer(name, dims, data_type::INT64, raw);
        Ok(())
    }

    fn push_initializer(&mut self, name: &str, dims: &[i64], data_type: i32, raw: Vec<u8>) {
        self.initializers.push(TensorProto {
            dims: dims.to_vec(),
            data_type,
            name: name.to_string(),
            raw_data: Bytes::from(raw),
            ..Default::default()
        });
    }

    /// Adds a default-domain node; its name is its first output's name (made unique).
    /// Returns the node name.
    pub fn node(
        &mut self,
        op_type: &str,
        inputs: &[&str],
        outputs: &[&str],
        attributes: Vec<AttributeProto>,
    ) -> String {
        let base = outputs.first().copied().unwrap_or(op_type);
        self.node_named(base, op_type, inputs, outputs, attributes)
    }

    /// Adds a node called `name` (suffixed `_2`, `_3`, ... if taken). Returns the name used.
    pub fn node_named(
        &mut self,
        name: &str,
        op_type: &str,
        inputs: &[&str],
        outputs: &[&str],
        attributes: Vec<AttributeProto>,
    ) -> String {
        let mut unique = name.to_string();
        let mut k = 2;
        while self.node_names.contains(&unique) {
            unique = format!("{name}_{k}");
            k += 1;
        }
        self.node_names.insert(unique.clone());
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: outputs.iter().map(|s| s.to_string()).collect(),
            name: unique.clone(),
            op_type: op_type.to_string(),
            attribute: attributes,
            ..Default::default()
        });
        unique
    }

    /// Declares a float32 graph input, e.g. `input [1,3,224,224]` or `[batch,3,224,224]`.
    pub fn input_f32(&mut self, name: &str, dims: &[Dim]) {
        self.inputs.push(value_info(name, data_type::FLOAT, dims));
    }

    /// Declares a float32 graph output, e.g. `output [1,2]`.
    pub fn output_f32(&mut self, name: &str, dims: &[Dim]) {
        self.outputs.push(value_info(name, data_type::FLOAT, dims));
    }

    /// Checks the graph and wraps it in a model: IR version [`IR_VERSION`], opset [`OPSET`],
    /// and `metadata` as `metadata_props`.
    pub fn finish(
        self,
        producer_name: &str,
        producer_version: &str,
        metadata: &[(String, String)],
    ) -> Result<ModelProto, OnnxError> {
        self.check()?;
        Ok(ModelProto {
            ir_version: IR_VERSION,
            opset_import: vec![OperatorSetIdProto {
                domain: String::new(),
                version: OPSET,
            }],
            producer_name: producer_name.to_string(),
            producer_version: producer_version.to_string(),
            graph: Some(GraphProto {
                node: self.nodes,
                name: self.name,
                initializer: self.initializers,
                input: self.inputs,
                output: self.outputs,
                ..Default::default()
            }),
            metadata_props: metadata
                .iter()
                .map(|(k, v)| StringStringEntryProto {
                    key: k.clone(),
                    value: v.clone(),
                })
                .collect(),
            ..Default::default()
        })
    }

    /// SSA and ordering rules: each value defined once (input, initializer or node
    /// output), node inputs defined before the node, graph outputs defined somewhere.
    fn check(&self) -> Result<(), OnnxError> {
        let mut defined = BTreeSet::new();
        let define = |defined: &mut BTreeSet<String>, name: &str, by: &str| {
            if name.is_empty() || !defined.insert(name.to_string()) {
                return Err(OnnxError::Graph(format!(
                    "value `{name}` ({by}) is empty or defined twice"
                )));
            }
            Ok(())
        };
        for v in &self.inputs {
            define(&mut defined, &v.name, "graph input")?;
        }
        for t in &self.initializers {
            define(&mut defined, &t.name, "initializer")?;
        }
        for n in &self.nodes {
            // Empty input names mark omitted optional inputs.
            if let Some(missing) = n
                .input
                .iter()
                .find(|i| !i.is_empty() && !defined.contains(i.as_str()))
            {
                return Err(OnnxError::Graph(format!(
                    "node `{}` ({}) uses `{missing}` before it is defined",
                    n.name, n.op_type
                )));
            }
            for o in &n.output {
                define(&mut defined, o, &format!("output of node `{}`", n.name))?;
            }
        }
        if self.outputs.is_empty() {
            return Err(OnnxError::Graph("the graph has no outputs".into()));
        }
        if let Some(o) = self.outputs.iter().find(|o| !defined.contains(&o.name)) {
            return Err(OnnxError::Graph(format!(
                "graph output `{}` is not produced by any node",
                o.name
            )));
        }
        Ok(())
    }
}

fn check_len(name: &str, dims: &[i64], found: usize) -> Result<(), OnnxError> {
    let expected = element_count(dims);
    if dims.iter().any(|&d| d < 0) || expected != found as u64 {
        return Err(OnnxError::DataLength {
            name: name.to_string(),
            dims: shape_to_string(dims),
            expected,
            found,
        });
    }
    Ok(())
}

pub(crate) fn value_info(name: &str, elem_type: i32, dims: &[Dim]) -> ValueInfoProto {
    use tensor_shape_proto::{Dimension, dimension::Value};
    let dim = dims
        .iter()
        .map(|d| Dimension {
            value: match d {
                Dim::Fixed(n) => Some(Value::DimValue(*n)),
                Dim::Symbolic(s) => Some(Value::DimParam(s.clone())),
                Dim::Unknown => None,
            },
            ..Default::default()
        })
        .collect();
    ValueInfoProto {
        name: name.to_string(),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type,
                shape: Some(TensorShapeProto { dim }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> GraphBuilder {
        let mut g = GraphBuilder::new("tiny");
        g.input_f32("x", &["batch".into(), 2.into()]);
        g.initializer_f32("w", &[2, 2], &[1.0, 0.0, 0.0, 1.0])
            .unwrap();
        g.output_f32("y", &["batch".into(), 2.into()]);
        g
    }

    #[test]
    fn builds_a_small_model() {
        let mut g = tiny();
        g.node("MatMul", &["x", "w"], &["h"], vec![]);
        let n = g.node("Relu", &["h"], &["y"], vec![]);
        assert_eq!(n, "y");
        let m = g.finish("test", "0", &[("k".into(), "v".into())]).unwrap();
        assert_eq!(m.ir_version, 8);
        assert_eq!(m.opset_import[0].version, 17);
        let graph = m.graph.unwrap();
        assert_eq!(graph.node.len(), 2);
        assert_eq!(graph.initializer[0].raw_data.len(), 16);
        assert_eq!(&graph.initializer[0].raw_data[..4], &1.0f32.to_le_bytes());
        assert_eq!(m.metadata_props[0].key, "k");
    }

    #[test]
    fn node_names_are_unique() {
        let mut g = tiny();
        assert_eq!(g.node_named("n", "Relu", &["x"], &["a"], vec![]), "n");
        assert_eq!(g.node_named("n", "Relu", &["a"], &["b"], vec![]), "n_2");
        assert_eq!(g.node_named("n", "Relu", &["b"], &["y"], vec![]), "n_3");
        g.finish("t", "0", &[]).unwrap();
    }

    #[test]
    fn finish_rejects_undefined_and_duplicate_values() {
        let mut g = tiny();
        g.node("Relu", &["nope"], &["y"], vec![]);
        let err = g.finish("t", "0", &[]).unwrap_err().to_string();
        assert!(err.contains("`nope`"), "{err}");

        let mut g = tiny();
        g.node("Relu", &["x"], &["w"], vec![]);
        let err = g.finish("t", "0", &[]).unwrap_err().to_string();
        assert!(err.contains("`w`"), "{err}");

        let err = tiny().finish("t", "0", &[]).unwrap_err().to_string();
        assert!(err.contains("`y`"), "{err}");
    }

    #[test]
    fn initializer_length_must_match_shape() {
        let mut g = GraphBuilder::new("g");
        let err = g.initializer_f32("w", &[2, 3], &[0.0; 5]).unwrap_err();
        assert_eq!(
            err.to_string(),
            "tensor `w` has 5 values, its shape [2,3] needs 6"
        );
        g.initializer_i64("shape", &[2], &[1, -1]).unwrap();
        g.initializer_i64("scalar", &[], &[7]).unwrap();
    }

    #[test]
    fn int_attribute_zero_is_still_encoded() {
        use prost::Message;
        let a = attr_int("axis", 0);
        let back = AttributeProto::decode(a.encode_to_vec().as_slice()).unwrap();
        assert_eq!(back.i, Some(0));
        assert_eq!(back.r#type, AttributeType::Int as i32);
    }

    #[test]
    fn dims_display() {
        assert_eq!(
            dims_to_string(&[1.into(), 3.into(), 224.into(), 224.into()]),
            "[1,3,224,224]"
        );
        assert_eq!(
            dims_to_string(&["batch".into(), 2.into(), Dim::Unknown]),
            "[batch,2,?]"
        );
    }
}
