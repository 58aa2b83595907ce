//! Initializers stored outside the model file (ONNX "external data"): the weights go to
//! `<model>.data` beside it, each at a page-aligned offset, and the model keeps only their
//! location, offset and length. ONNX Runtime then maps the data file into memory instead
//! of reading the weights into its own buffers, so a daemon holds one copy of them fewer.

use std::path::{Path, PathBuf};

use prost::bytes::Bytes;

use super::proto::{DATA_LOCATION_EXTERNAL, ModelProto, StringStringEntryProto};
use super::{OnnxError, write_atomic, write_model};

/// Offsets in the data file are multiples of this (the page size ONNX Runtime maps in).
pub const ALIGN: usize = 4096;
/// Initializers smaller than this stay inside the model file.
pub const MIN_BYTES: usize = 1024;

/// The data file's name for a model at `path`: `model.onnx` -> `model.onnx.data`.
pub fn data_path(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".data");
    path.with_file_name(name)
}

/// Moves every initializer of at least [`MIN_BYTES`] of `raw_data` into one buffer; the
/// model's tensors point at `location` (a file name relative to the model's folder).
pub fn split(model: &ModelProto, location: &str) -> (ModelProto, Vec<u8>) {
    let mut out = model.clone();
    let mut data = Vec::new();
    if let Some(g) = out.graph.as_mut() {
        for t in &mut g.initializer {
            if t.raw_data.len() < MIN_BYTES {
                continue;
            }
            let offset = data.len().div_ceil(ALIGN) * ALIGN;
            data.resize(offset, 0);
            data.extend_from_slice(&t.raw_data);
            let entry = |k: &str, v: String| StringStringEntryProto {
                key: k.into(),
                value: v,
            };
            t.external_data = vec![
                entry("location", location.to_string()),
                entry("offset", offset.to_string()),
                entry("length", t.raw_data.len().to_string()),
            ];
            t.data_location = DATA_LOCATION_EXTERNAL;
            t.raw_data = Bytes::new();
        }
    }
    (out, data)
}

/// Writes `model` to `path` with its large initializers in [`data_path`]`(path)`, both
/// atomically, the data first (a crash between the two leaves the old model whole or
/// a new data file beside an old model that does not read it). Returns the data file.
pub fn write_model_external(path: &Path, model: &ModelProto) -> Result<PathBuf, OnnxError> {
    let data_file = data_path(path);
    let location = data_file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (small, data) = split(model, &location);
    write_atomic(&data_file, &data)?;
    write_model(path, &small)?;
    Ok(data_file)
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

    #[test]
    fn large_tensors_go_out_page_aligned_small_ones_stay() {
        let mut g = GraphBuilder::new("t");
        g.initializer_f32("big", &[300], &[1.5; 300]).unwrap(); // 1200 bytes
        g.initializer_f32("small", &[2], &[1.0, 2.0]).unwrap();
        g.initializer_f32("big2", &[400], &[-2.0; 400]).unwrap();
        g.input_f32("x", &[300.into()]);
        g.node("Add", &["x", "big"], &["y"], vec![]);
        g.output_f32("y", &[300.into()]);
        let m = g.finish("t", "0", &[]).unwrap();
        let (out, data) = split(&m, "m.onnx.data");
        let inits = &out.graph.as_ref().unwrap().initializer;
        let meta = |i: usize| -> Vec<(String, String)> {
            inits[i]
                .external_data
                .iter()
                .map(|e| (e.key.clone(), e.value.clone()))
                .collect()
        };
        assert_eq!(
            meta(0),
            vec![
                ("location".into(), "m.onnx.data".into()),
                ("offset".into(), "0".into()),
                ("length".into(), "1200".into())
            ]
        );
        assert_eq!(meta(2)[1], ("offset".into(), "4096".into()));
        assert!(inits[1].external_data.is_empty() && inits[1].raw_data.len() == 8);
        assert_eq!(data.len(), 4096 + 1600);
        assert_eq!(&data[..4], &1.5f32.to_le_bytes());
        assert_eq!(&data[4096..4100], &(-2.0f32).to_le_bytes());
        assert_eq!(
            data_path(Path::new("/a/m.onnx")),
            PathBuf::from("/a/m.onnx.data")
        );
    }

    #[test]
    fn written_external_reads_back_the_same_and_a_short_data_file_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut g = GraphBuilder::new("t");
        g.initializer_f32("big", &[300], &[1.5; 300]).unwrap();
        g.input_f32("x", &[300.into()]);
        g.node("Add", &["x", "big"], &["y"], vec![]);
        g.output_f32("y", &[300.into()]);
        let m = g.finish("t", "0", &[]).unwrap();
        let path = dir.path().join("m.onnx");
        let data = write_model_external(&path, &m).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let mut back = <ModelProto as prost::Message>::decode(&bytes[..]).unwrap();
        inline(&mut back, dir.path()).unwrap();
        assert_eq!(back, m);
        std::fs::write(&data, [0u8; 100]).unwrap();
        let mut again = <ModelProto as prost::Message>::decode(&bytes[..]).unwrap();
        let err = inline(&mut again, dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("`big`") && err.contains("m.onnx.data (100 bytes)"),
            "{err}"
        );
    }
}
