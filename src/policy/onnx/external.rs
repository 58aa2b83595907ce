//! Initializers stored outside the model file (ONNX "external data": the model keeps
//! each tensor's file, offset and length), as `jetpilot model optimize` writes them and
//! other exporters do for large models: read back in so such a model can be rewritten.

use std::path::{Path, PathBuf};

use prost::bytes::Bytes;

use super::OnnxError;
use super::proto::{DATA_LOCATION_EXTERNAL, ModelProto};

/// The data file's name for a model at `path`: `model.onnx` -> `model.onnx.data`.
pub fn data_path(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".data");
    path.with_file_name(name)
}

/// Reads every external initializer of `model` back into `raw_data` (from files relative to
/// `base_dir`, the model's folder), so the model can be changed and written anew.
pub fn inline(model: &mut ModelProto, base_dir: &Path) -> Result<(), OnnxError> {
    let Some(g) = model.graph.as_mut() else {
        return Ok(());
    };
    let mut files: std::collections::BTreeMap<String, Vec<u8>> = Default::default();
    for t in &mut g.initializer {
        if t.data_location != DATA_LOCATION_EXTERNAL && t.external_data.is_empty() {
            continue;
        }
        let get = |k: &str| {
            t.external_data
                .iter()
                .find(|e| e.key == k)
                .map(|e| e.value.clone())
        };
        let bad = |reason: String| OnnxError::NotAModel {
            path: base_dir.display().to_string(),
            reason: format!("initializer `{}`: {reason}", t.name),
        };
        let location =
            get("location").ok_or_else(|| bad("external data without a location".into()))?;
        let offset: usize = get("offset")
            .map_or(Ok(0), |v| v.parse())
            .map_err(|_| bad("bad offset".into()))?;
        if !files.contains_key(&location) {
            let path = base_dir.join(&location);
            let bytes = std::fs::read(&path).map_err(|source| OnnxError::Read {
                path: path.display().to_string(),
                source,
            })?;
            files.insert(location.clone(), bytes);
        }
        let data = &files[&location];
        let length: usize = match get("length") {
            Some(v) => v.parse().map_err(|_| bad("bad length".into()))?,
            None => data.len().saturating_sub(offset),
        };
        let bytes = data
            .get(offset..offset.saturating_add(length))
            .ok_or_else(|| {
                bad(format!(
                    "bytes {offset}..{} lie beyond the end of {location} ({} bytes)",
                    offset + length,
                    data.len()
                ))
            })?;
        t.raw_data = Bytes::copy_from_slice(bytes);
        t.external_data.clear();
        t.data_location = 0;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::graph::GraphBuilder;
    use crate::policy::onnx::proto::StringStringEntryProto;

    #[test]
    fn external_tensors_are_read_back_and_a_short_data_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut g = GraphBuilder::new("t");
        g.initializer_f32("big", &[300], &[1.5; 300]).unwrap();
        g.input_f32("x", &[300.into()]);
        g.node("Add", &["x", "big"], &["y"], vec![]);
        g.output_f32("y", &[300.into()]);
        let m = g.finish("t", "0", &[]).unwrap();
        // The same model with `big` at offset 4096 of m.onnx.data.
        let mut ext = m.clone();
        let t = &mut ext.graph.as_mut().unwrap().initializer[0];
        let mut data = vec![0u8; 4096];
        data.extend_from_slice(&t.raw_data);
        let entry = |k: &str, v: &str| StringStringEntryProto {
            key: k.into(),
            value: v.into(),
        };
        t.external_data = vec![
            entry("location", "m.onnx.data"),
            entry("offset", "4096"),
            entry("length", "1200"),
        ];
        t.data_location = DATA_LOCATION_EXTERNAL;
        t.raw_data = Bytes::new();
        let path = dir.path().join("m.onnx");
        std::fs::write(data_path(&path), &data).unwrap();
        let mut back = ext.clone();
        inline(&mut back, dir.path()).unwrap();
        assert_eq!(back, m);
        std::fs::write(data_path(&path), [0u8; 100]).unwrap();
        let mut again = ext.clone();
        let err = inline(&mut again, dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("`big`") && err.contains("m.onnx.data (100 bytes)"),
            "{err}"
        );
        assert_eq!(
            data_path(Path::new("/a/m.onnx")),
            PathBuf::from("/a/m.onnx.data")
        );
    }
}
