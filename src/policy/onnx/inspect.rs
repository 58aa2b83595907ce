//! Reads an ONNX file into a [`ModelSummary`] without ONNX Runtime: what `jetpilot inspect`
//! prints and what the loader checks before handing a model to the runtime.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::Path;

use prost::Message;
use prost::bytes::Bytes;

use super::OnnxError;
use super::graph::{Dim, dims_to_string, element_count};
use super::proto::{ModelProto, ValueInfoProto, data_type, tensor_shape_proto, type_proto};
use crate::policy::contract::{ContractError, ModelContract};

/// Name, element type and shape of a graph input or output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TensorInfo {
    pub name: String,
    /// `"float32"`, `"int64"`, ...; `"non-tensor"` for sequences, maps etc.,
    /// `"unknown"` when the type is missing.
    pub elem_type: String,
    /// Empty when the file records no shape.
    pub dims: Vec<Dim>,
}

impl TensorInfo {
    /// The shape as text: `[1,3,224,224]`, `[batch,2]`.
    pub fn shape_string(&self) -> String {
        dims_to_string(&self.dims)
    }
}

impl fmt::Display for TensorInfo {
    /// `input float32 [1,3,224,224]`
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {} {}",
            self.name,
            self.elem_type,
            self.shape_string()
        )
    }
}

/// What an ONNX file contains, at a glance.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSummary {
    pub ir_version: i64,
    /// `(domain, version)`; the default domain is shown as `ai.onnx`.
    pub opsets: Vec<(String, i64)>,
    /// Producer name and version, e.g. `jetpilot 0.1.0` or `pytorch 2.3.0`.
    pub producer: String,
    /// `metadata_props` (the contract lives here, see [`ModelSummary::contract`]).
    pub metadata: BTreeMap<String, String>,
    /// Graph inputs that are not initializers (old PyTorch exports list weights as inputs).
    pub inputs: Vec<TensorInfo>,
    pub outputs: Vec<TensorInfo>,
    /// Nodes of the main graph (subgraphs are not counted).
    pub nodes: usize,
    pub initializers: usize,
    /// Initializers whose values live in a separate data file ("external data").
    pub external_initializers: usize,
    /// Sum of the element counts of all initializers.
    pub parameters: u64,
    /// Node count per `op_type` in the main graph.
    pub op_counts: BTreeMap<String, usize>,
}

impl ModelSummary {
    /// The jetpilot contract recorded in the metadata; `Ok(None)` when there is none.
    pub fn contract(&self) -> Result<Option<ModelContract>, ContractError> {
        ModelContract::from_metadata(&self.metadata)
    }
}

/// Reads and summarises the ONNX file at `path`.
pub fn inspect_file(path: &Path) -> Result<ModelSummary, OnnxError> {
    let shown = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| OnnxError::Read {
        path: shown.clone(),
        source,
    })?;
    inspect_bytes(Bytes::from(bytes), &shown)
}

/// Decodes a model from `bytes` (initializer data is not copied), refused where it is empty,
/// not protobuf, or has no IR version, no graph, or no inputs or outputs.
/// `path_for_errors` names the source in error messages.
pub fn decode_model(bytes: Bytes, path_for_errors: &str) -> Result<ModelProto, OnnxError> {
    let not_model = |reason: &str| OnnxError::NotAModel {
        path: path_for_errors.to_string(),
        reason: reason.to_string(),
    };
    if bytes.is_empty() {
        return Err(not_model("the file is empty"));
    }
    let model = ModelProto::decode(bytes).map_err(|source| OnnxError::Decode {
        path: path_for_errors.to_string(),
        source,
    })?;
    if model.ir_version <= 0 {
        return Err(not_model("no IR version"));
    }
    match &model.graph {
        None => Err(not_model("no graph")),
        Some(g) if g.input.is_empty() || g.output.is_empty() => {
            Err(not_model("the graph has no inputs or no outputs"))
        }
        Some(_) => Ok(model),
    }
}

/// Decodes a model from `bytes` (initializer data is not copied) and summarises it.
/// `path_for_errors` names the source in error messages.
pub fn inspect_bytes(bytes: Bytes, path_for_errors: &str) -> Result<ModelSummary, OnnxError> {
    let model = decode_model(bytes, path_for_errors)?;
    // `decode_model` refuses a model without a graph.
    let graph = model.graph.unwrap_or_default();

    let init_names: BTreeSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let inputs = graph
        .input
        .iter()
        .filter(|v| !init_names.contains(v.name.as_str()))
        .map(tensor_info)
        .collect();
    let outputs = graph.output.iter().map(tensor_info).collect();
    let mut op_counts = BTreeMap::new();
    for n in &graph.node {
        *op_counts.entry(n.op_type.clone()).or_insert(0) += 1;
    }
    let opsets = model
        .opset_import
        .iter()
        .map(|o| {
            let domain = if o.domain.is_empty() {
                "ai.onnx"
            } else {
                &o.domain
            };
            (domain.to_string(), o.version)
        })
        .collect();
    let producer = format!("{} {}", model.producer_name, model.producer_version)
        .trim()
        .to_string();

    Ok(ModelSummary {
        ir_version: model.ir_version,
        opsets,
        producer,
        metadata: model
            .metadata_props
            .into_iter()
            .map(|e| (e.key, e.value))
            .collect(),
        inputs,
        outputs,
        nodes: graph.node.len(),
        initializers: graph.initializer.len(),
        external_initializers: graph
            .initializer
            .iter()
            .filter(|t| {
                t.data_location == super::proto::DATA_LOCATION_EXTERNAL
                    || !t.external_data.is_empty()
            })
            .count(),
        parameters: graph
            .initializer
            .iter()
            .map(|t| element_count(&t.dims))
            .fold(0u64, u64::saturating_add),
        op_counts,
    })
}

fn tensor_info(v: &ValueInfoProto) -> TensorInfo {
    use tensor_shape_proto::dimension::Value;
    let (elem_type, dims) = match v.r#type.as_ref().map(|t| &t.value) {
        Some(Some(type_proto::Value::TensorType(t))) => {
            let dims = t
                .shape
                .iter()
                .flat_map(|s| &s.dim)
                .map(|d| match &d.value {
                    Some(Value::DimValue(n)) => Dim::Fixed(*n),
                    Some(Value::DimParam(p)) if !p.is_empty() => Dim::Symbolic(p.clone()),
                    _ => Dim::Unknown,
                })
                .collect();
            (data_type::name(t.elem_type), dims)
        }
        Some(None) => ("non-tensor".to_string(), Vec::new()),
        None => ("unknown".to_string(), Vec::new()),
    };
    TensorInfo {
        name: v.name.clone(),
        elem_type,
        dims,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::graph::GraphBuilder;
    use crate::policy::onnx::proto::data_type;
    use crate::policy::onnx::{encode_model, write_model};

    fn small_model() -> ModelProto {
        let mut g = GraphBuilder::new("g");
        g.input_f32("x", &["batch".into(), 4.into()]);
        g.initializer_f32("w", &[4, 2], &[0.5; 8]).unwrap();
        g.node("MatMul", &["x", "w"], &["y"], vec![]);
        g.output_f32("y", &["batch".into(), 2.into()]);
        g.finish("unit", "1", &[]).unwrap()
    }

    #[test]
    fn summarises_symbolic_dims_and_no_contract() {
        let s = inspect_bytes(encode_model(&small_model()).into(), "m.onnx").unwrap();
        assert_eq!(s.inputs[0].to_string(), "x float32 [batch,4]");
        assert_eq!(s.outputs[0].shape_string(), "[batch,2]");
        assert_eq!(s.parameters, 8);
        assert_eq!(s.producer, "unit 1");
        assert_eq!(s.contract().unwrap(), None);
    }

    #[test]
    fn initializer_inputs_are_not_listed() {
        // Old PyTorch exports also declare every weight as a graph input.
        let mut m = small_model();
        let graph = m.graph.as_mut().unwrap();
        let mut w = graph.input[0].clone();
        w.name = "w".into();
        if let Some(type_proto::Value::TensorType(t)) =
            w.r#type.as_mut().and_then(|t| t.value.as_mut())
        {
            t.elem_type = data_type::INT64;
        }
        graph.input.push(w);
        let s = inspect_bytes(encode_model(&m).into(), "m.onnx").unwrap();
        assert_eq!(s.inputs.len(), 1);
        assert_eq!(s.inputs[0].name, "x");
    }

    fn not_model(bytes: Vec<u8>) -> String {
        let err = inspect_bytes(bytes.into(), "some/file.onnx").unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.starts_with("not an ONNX model: some/file.onnx"),
            "{msg}"
        );
        msg
    }

    #[test]
    fn garbage_is_rejected_without_panic() {
        not_model(Vec::new());
        not_model(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x10\0\0\0\x10\x08\x02\0\0\0".to_vec());
        not_model(b"hello, this is a text file\n".to_vec());
        not_model(vec![0xff; 64]);
        // Valid protobuf, but no graph.
        not_model(encode_model(&ModelProto {
            ir_version: 8,
            ..Default::default()
        }));
        // Pseudo-random bytes of many lengths.
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        for len in 0..300 {
            let bytes: Vec<u8> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x as u8
                })
                .collect();
            not_model(bytes);
        }
    }

    #[test]
    fn truncated_model_is_rejected() {
        let bytes = encode_model(&small_model());
        for cut in [1, 2, bytes.len() / 2, bytes.len() - 1] {
            not_model(bytes[..cut].to_vec());
        }
    }

    #[test]
    fn inspect_file_names_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.onnx");
        let err = inspect_file(&path).unwrap_err();
        assert!(matches!(err, OnnxError::Read { .. }));
        assert!(err.to_string().contains("model.onnx"), "{err}");

        std::fs::write(&path, b"").unwrap();
        let err = inspect_file(&path).unwrap_err().to_string();
        assert!(
            err.starts_with("not an ONNX model: ") && err.contains("model.onnx"),
            "{err}"
        );

        write_model(&path, &small_model()).unwrap();
        assert_eq!(inspect_file(&path).unwrap().nodes, 1);
    }
}
