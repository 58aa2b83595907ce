//! Pre-optimised models (`jetpilot model optimize`): ONNX Runtime's graph optimisations
//! (fusions, and on x86 the NCHWc layout) run once, on the machine that will run the
//! model, and saved with the weights in a data file beside it. [`super::OrtPolicy`] loads
//! such a file with optimisations off, so the weights are never held twice or three times
//! while they are rewritten at start-up: a lower peak RSS on the robot (docs/results/memory.md).
//!
//! The saved graph may hold operators laid out for this CPU, so the file records the
//! machine it was made for ([`META_OPTIMIZED_FOR`]) and is refused anywhere else.

use std::io::Read;
use std::path::{Path, PathBuf};

use ort::session::builder::GraphOptimizationLevel;
use prost::Message;

use super::onnx::external::data_path;
use super::onnx::proto::StringStringEntryProto;
use super::{PolicyError, Result, runtime};

/// Metadata key: the machine a pre-optimised model was made for ([`machine`]).
pub const META_OPTIMIZED_FOR: &str = "jetpilot.optimized_for";

/// `onnxruntime 1.23.2, x86_64, AMD EPYC 7B13`: what a pre-optimised model depends on.
pub fn machine(ort_version: &str) -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |key: &str| {
        info.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            (k.trim() == key).then(|| v.trim().to_string())
        })
    };
    // x86 names the model; ARM kernels give the implementer and part numbers.
    let cpu = field("model name").unwrap_or_else(|| {
        let part = |k: &str| field(k).unwrap_or_else(|| "?".into());
        format!(
            "CPU implementer {} part {}",
            part("CPU implementer"),
            part("CPU part")
        )
    });
    format!(
        "onnxruntime {ort_version}, {}, {cpu}",
        std::env::consts::ARCH
    )
}

/// Reads a `.onnx` file's top-level metadata (`metadata_props`) without reading its graph:
/// the file is walked field by field and the graph's bytes are skipped.
pub fn read_metadata(path: &Path) -> std::io::Result<Vec<(String, String)>> {
    let mut f = std::io::BufReader::new(std::fs::File::open(path)?);
    let bad = |what: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, what.to_string());
    let mut out = Vec::new();
    loop {
        let key = match varint(&mut f) {
            Ok(k) => k,
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(out),
            Err(e) => return Err(e),
        };
        match (key >> 3, key & 7) {
            (14, 2) => {
                let len = usize::try_from(varint(&mut f)?).map_err(|_| bad("length"))?;
                let mut buf = vec![0; len];
                f.read_exact(&mut buf)?;
                let e = StringStringEntryProto::decode(&buf[..]).map_err(|_| bad("metadata"))?;
                out.push((e.key, e.value));
            }
            (_, 0) => {
                varint(&mut f)?;
            }
            (_, 1) => f.seek_relative(8)?,
            (_, 2) => {
                let len = i64::try_from(varint(&mut f)?).map_err(|_| bad("length"))?;
                f.seek_relative(len)?;
            }
            (_, 5) => f.seek_relative(4)?,
            _ => return Err(bad("not a protobuf message")),
        }
    }
}

fn varint(r: &mut impl Read) -> std::io::Result<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let mut b = [0u8];
        r.read_exact(&mut b)?;
        v |= u64::from(b[0] & 0x7f) << shift;
        if b[0] & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        "varint too long",
    ))
}

/// Appends one `metadata_props` entry to an encoded model. Protobuf merges a repeated
/// field's elements across the message, so nothing else in the bytes is decoded or
/// rewritten (the saved graph may hold fields our own messages do not declare).
pub fn append_metadata(model: &mut Vec<u8>, key: &str, value: &str) {
    let entry = StringStringEntryProto {
        key: key.into(),
        value: value.into(),
    };
    prost::encoding::message::encode(14, &entry, model);
}

/// The machine `path` was pre-optimised for, if it was (unreadable files: `None`, and
/// ONNX Runtime reports them when it loads them).
pub fn optimized_for(path: &Path) -> Option<String> {
    read_metadata(path)
        .ok()?
        .into_iter()
        .find_map(|(k, v)| (k == META_OPTIMIZED_FOR).then_some(v))
}

/// Runs ONNX Runtime's optimisations on `input` and writes the result to `output`, with
/// its weights in `output.data`; returns the data file. Both are written into a
/// temporary folder beside `output` and renamed into place, the data first.
pub fn optimize(input: &Path, output: &Path) -> Result<PathBuf> {
    let shown = input.display().to_string();
    let err = |reason: String| PolicyError::Model {
        path: shown.clone(),
        reason,
    };
    let (library, env) = runtime::environment(None)?;
    let dir = match output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let name = output
        .file_name()
        .ok_or_else(|| err(format!("{}: no file name", output.display())))?;
    let data = data_path(output);
    let data_name = data
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = tempfile::Builder::new()
        .prefix(".optimize")
        .tempdir_in(dir)
        .map_err(|e| {
            err(format!(
                "cannot make a temporary folder in {}: {e}",
                dir.display()
            ))
        })?;
    let tmp_model = tmp.path().join(name);
    let builder = runtime::session_builder(env, GraphOptimizationLevel::Level3, 0, false)
        .and_then(|b| b.with_optimized_model_path(&tmp_model).map_err(Into::into))
        .and_then(|b| {
            b.with_config_entry(
                "session.optimized_model_external_initializers_file_name",
                &data_name,
            )
            .map_err(Into::into)
        })
        .and_then(|b| {
            b.with_config_entry(
                "session.optimized_model_external_initializers_min_size_in_bytes",
                "1024",
            )
            .map_err(Into::into)
        });
    let mut builder = builder.map_err(|e: ort::Error| err(e.to_string()))?;
    drop(
        builder
            .commit_from_file(input)
            .map_err(|e| err(format!("ONNX Runtime cannot load it: {e}")))?,
    );
    let mut bytes =
        std::fs::read(&tmp_model).map_err(|e| err(format!("ONNX Runtime saved no model: {e}")))?;
    append_metadata(
        &mut bytes,
        META_OPTIMIZED_FOR,
        &machine(&runtime::ort_version(library)),
    );
    let write_err =
        |path: &Path, e: std::io::Error| err(format!("cannot write {}: {e}", path.display()));
    std::fs::rename(tmp.path().join(&data_name), &data).map_err(|e| write_err(&data, e))?;
    super::onnx::write_atomic(output, &bytes).map_err(|e| err(e.to_string()))?;
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::{ModelProto, encode_model};

    #[test]
    fn metadata_is_read_past_the_graph_and_appended_without_decoding() {
        let m = ModelProto {
            ir_version: 8,
            producer_name: "p".into(),
            graph: Some(Default::default()),
            metadata_props: vec![StringStringEntryProto {
                key: "a".into(),
                value: "1".into(),
            }],
            ..Default::default()
        };
        let mut bytes = encode_model(&m);
        append_metadata(&mut bytes, META_OPTIMIZED_FOR, "here");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.onnx");
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(
            read_metadata(&path).unwrap(),
            vec![
                ("a".into(), "1".into()),
                (META_OPTIMIZED_FOR.into(), "here".into())
            ]
        );
        assert_eq!(optimized_for(&path).as_deref(), Some("here"));
        let back = ModelProto::decode(&bytes[..]).unwrap();
        assert_eq!(back.metadata_props.len(), 2);
        assert_eq!(back.graph, m.graph);
        std::fs::write(&path, [0xffu8, 0xff, 0xff]).unwrap();
        assert!(optimized_for(&path).is_none());
        assert!(
            machine("1.23.2")
                .starts_with(&format!("onnxruntime 1.23.2, {}, ", std::env::consts::ARCH))
        );
    }
}
