//! The GPU execution providers' settings (`[runtime.tensorrt]`, `[runtime.cuda]`) and the
//! exact options ONNX Runtime is handed for each.
//!
//! They matter on a Jetson Orin (JetPack 6) or a desktop GPU with ONNX Runtime's GPU build;
//! the CPU library jetpilot installs has neither provider, and on the original Nano
//! (CUDA 10.2) no current GPU build runs. TensorRT compiles the model into an engine the
//! first time a session is made, which takes minutes on a Jetson: the engine cache keeps
//! the engine (and TensorRT's timing cache) on disk, so later starts take seconds. The
//! cache folder is, unless set: `$CACHE_DIRECTORY/tensorrt` (systemd's `CacheDirectory=`,
//! see `systemd/orin-gpu.conf`), else `${XDG_CACHE_HOME:-~/.cache}/jetpilot/tensorrt`.
//!
//! ONNX Runtime names a cached engine after the model's file name, its tensor names and the
//! library versions, not its weights: a model retrained to the same `best.onnx` would run
//! on the old engine. So each model's engines go in a subfolder named after the SHA-256
//! of its bytes (and of its external weights, if any); the timing cache is shared.

use std::path::{Path, PathBuf};

use ort::ep::{self, ArbitrarilyConfigurableExecutionProvider, ExecutionProviderDispatch};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::runtime::Provider;

/// `[runtime.tensorrt]`: ONNX Runtime's TensorRT provider.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TensorrtOptions {
    /// Half-precision kernels where the GPU has them (every Jetson Orin does).
    pub fp16: bool,
    /// Keep built engines and TensorRT's timing cache on disk.
    pub engine_cache: bool,
    /// The cache's folder; unset: see the module documentation.
    pub cache_dir: Option<PathBuf>,
    /// TensorRT's builder workspace in MiB.
    pub max_workspace_mib: u32,
    /// CUDA device number.
    pub device_id: u32,
}

impl Default for TensorrtOptions {
    fn default() -> Self {
        Self {
            fp16: true,
            engine_cache: true,
            cache_dir: None,
            max_workspace_mib: 1024,
            device_id: 0,
        }
    }
}

/// `[runtime.cuda]`: ONNX Runtime's CUDA provider.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CudaOptions {
    /// CUDA device number.
    pub device_id: u32,
    /// Cap on the provider's memory arena in MiB (0: none). On a Jetson the GPU shares
    /// the board's memory with everything else.
    pub memory_limit_mib: u32,
}

/// Both GPU providers' settings, as a session is built with them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GpuOptions {
    pub tensorrt: TensorrtOptions,
    pub cuda: CudaOptions,
}

const MIB: u64 = 1024 * 1024;

fn flag(on: bool) -> String {
    if on { "1" } else { "0" }.to_string()
}

/// Where TensorRT keeps one model's engines and the shared timing cache.
#[derive(Debug, Clone, PartialEq)]
pub struct TensorrtCache {
    pub engines: PathBuf,
    pub timing: PathBuf,
}

/// The TensorRT provider's options under ONNX Runtime's own names
/// (`OrtTensorRTProviderOptionsV2`), the cache's folders given when the cache is on.
pub fn tensorrt_entries(
    o: &TensorrtOptions,
    cache: Option<&TensorrtCache>,
) -> Vec<(&'static str, String)> {
    let mut entries = vec![
        ("device_id", o.device_id.to_string()),
        (
            "trt_max_workspace_size",
            (u64::from(o.max_workspace_mib) * MIB).to_string(),
        ),
        ("trt_fp16_enable", flag(o.fp16)),
    ];
    if let Some(c) = cache {
        entries.extend([
            ("trt_engine_cache_enable", flag(true)),
            ("trt_engine_cache_path", c.engines.display().to_string()),
            ("trt_timing_cache_enable", flag(true)),
            ("trt_timing_cache_path", c.timing.display().to_string()),
        ]);
    }
    entries
}

/// The CUDA provider's options under ONNX Runtime's own names (`OrtCUDAProviderOptionsV2`).
pub fn cuda_entries(o: &CudaOptions) -> Vec<(&'static str, String)> {
    let mut entries = vec![("device_id", o.device_id.to_string())];
    if o.memory_limit_mib > 0 {
        entries.push((
            "gpu_mem_limit",
            (u64::from(o.memory_limit_mib) * MIB).to_string(),
        ));
    }
    entries
}

/// Where TensorRT's engines are kept when `cache_dir` is unset, from these environment
/// values (`CACHE_DIRECTORY`, `XDG_CACHE_HOME`, `HOME`); `None` when none is set.
pub fn default_cache_dir(
    cache_directory: Option<&str>,
    xdg_cache_home: Option<&str>,
    home: Option<&str>,
) -> Option<PathBuf> {
    let set = |v: Option<&str>| v.filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(d) = set(cache_directory) {
        // systemd may list several folders, separated by ':'; the first is ours.
        let first = d.to_string_lossy().split(':').next().map(PathBuf::from)?;
        return Some(first.join("tensorrt"));
    }
    set(xdg_cache_home)
        .or_else(|| set(home).map(|h| h.join(".cache")))
        .map(|d| d.join("jetpilot/tensorrt"))
}

/// The SHA-256 of a model's bytes, and of its external weights file (`FILE.data`) if there
/// is one, in hex: the name of its engines' folder.
pub fn model_key(model: &Path) -> std::io::Result<String> {
    let mut hash = Sha256::new();
    let mut data = model.as_os_str().to_owned();
    data.push(".data");
    for (i, file) in [model, Path::new(&data)].into_iter().enumerate() {
        let mut f = match std::fs::File::open(file) {
            Err(e) if i > 0 && e.kind() == std::io::ErrorKind::NotFound => continue,
            other => other?,
        };
        std::io::copy(&mut f, &mut hash)?;
    }
    Ok(hash.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// The engine cache's folders for `model`, created; `None` (with a warning naming the
/// folder) when the cache is off, no folder can be named, or it cannot be created or the
/// model read: the provider then builds the engine at every start.
fn engine_cache(o: &TensorrtOptions, model: &Path) -> Option<TensorrtCache> {
    if !o.engine_cache {
        return None;
    }
    let env = |k: &str| std::env::var(k).ok();
    let dir = o.cache_dir.clone().or_else(|| {
        default_cache_dir(
            env("CACHE_DIRECTORY").as_deref(),
            env("XDG_CACHE_HOME").as_deref(),
            env("HOME").as_deref(),
        )
    });
    let Some(dir) = dir else {
        tracing::warn!(
            "runtime.tensorrt.engine_cache: no folder (set runtime.tensorrt.cache_dir); TensorRT builds its engine at every start"
        );
        return None;
    };
    let key = match model_key(model) {
        Ok(k) => k,
        Err(e) => {
            tracing::warn!(model = %model.display(), error = %e, "cannot read the model to name its engine cache; TensorRT builds its engine at every start");
            return None;
        }
    };
    let engines = dir.join(key);
    match std::fs::create_dir_all(&engines) {
        Ok(()) => Some(TensorrtCache {
            engines,
            timing: dir,
        }),
        Err(e) => {
            tracing::warn!(folder = %engines.display(), error = %e, "runtime.tensorrt.cache_dir cannot be created; TensorRT builds its engine at every start");
            None
        }
    }
}

/// Whether this ONNX Runtime library has provider `p`, and its registration for `model`
/// (failing loudly, so the caller can log it and try the next). The TensorRT cache folder
/// is made only when the library has that provider.
pub fn dispatch(p: Provider, gpu: &GpuOptions, model: &Path) -> (bool, ExecutionProviderDispatch) {
    match p {
        Provider::Tensorrt => {
            let available = matches!(
                <ep::TensorRT as ep::ExecutionProvider>::is_available(),
                Ok(true)
            );
            let cache = if available {
                engine_cache(&gpu.tensorrt, model)
            } else {
                None
            };
            let ep = tensorrt_entries(&gpu.tensorrt, cache.as_ref())
                .into_iter()
                .fold(ep::TensorRT::default(), |ep, (k, v)| {
                    ep.with_arbitrary_config(k, v)
                });
            (available, ep.build().error_on_failure())
        }
        Provider::Cuda => {
            let available = matches!(
                <ep::CUDA as ep::ExecutionProvider>::is_available(),
                Ok(true)
            );
            let ep = cuda_entries(&gpu.cuda)
                .into_iter()
                .fold(ep::CUDA::default(), |ep, (k, v)| {
                    ep.with_arbitrary_config(k, v)
                });
            (available, ep.build().error_on_failure())
        }
        Provider::Cpu => (true, ep::CPU::default().build().error_on_failure()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strings(v: Vec<(&'static str, String)>) -> Vec<(String, String)> {
        v.into_iter().map(|(k, v)| (k.to_string(), v)).collect()
    }

    fn pairs(v: &[(&str, &str)]) -> Vec<(String, String)> {
        v.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn tensorrt_defaults_are_fp16_with_a_1_gib_workspace_and_the_cache_in_the_folder() {
        let o = TensorrtOptions::default();
        let cache = TensorrtCache {
            engines: PathBuf::from("/var/cache/jetpilot/tensorrt/0a1b"),
            timing: PathBuf::from("/var/cache/jetpilot/tensorrt"),
        };
        let got = strings(tensorrt_entries(&o, Some(&cache)));
        assert_eq!(
            got,
            pairs(&[
                ("device_id", "0"),
                ("trt_max_workspace_size", "1073741824"),
                ("trt_fp16_enable", "1"),
                ("trt_engine_cache_enable", "1"),
                ("trt_engine_cache_path", "/var/cache/jetpilot/tensorrt/0a1b"),
                ("trt_timing_cache_enable", "1"),
                ("trt_timing_cache_path", "/var/cache/jetpilot/tensorrt"),
            ])
        );
    }

    #[test]
    fn tensorrt_without_cache_fp32_on_device_1() {
        let o = TensorrtOptions {
            fp16: false,
            engine_cache: false,
            cache_dir: None,
            max_workspace_mib: 256,
            device_id: 1,
        };
        assert_eq!(
            strings(tensorrt_entries(&o, None)),
            pairs(&[
                ("device_id", "1"),
                ("trt_max_workspace_size", "268435456"),
                ("trt_fp16_enable", "0"),
            ])
        );
    }

    #[test]
    fn cuda_memory_limit_only_when_set() {
        assert_eq!(
            strings(cuda_entries(&CudaOptions::default())),
            pairs(&[("device_id", "0")])
        );
        let o = CudaOptions {
            device_id: 0,
            memory_limit_mib: 2048,
        };
        assert_eq!(
            strings(cuda_entries(&o)),
            pairs(&[("device_id", "0"), ("gpu_mem_limit", "2147483648")])
        );
    }

    #[test]
    fn cache_folder_from_systemd_then_xdg_then_home() {
        assert_eq!(
            default_cache_dir(
                Some("/var/cache/jetpilot:/var/cache/other"),
                Some("/x"),
                Some("/home/j")
            ),
            Some(PathBuf::from("/var/cache/jetpilot/tensorrt"))
        );
        assert_eq!(
            default_cache_dir(Some(""), Some("/x"), Some("/home/j")),
            Some(PathBuf::from("/x/jetpilot/tensorrt"))
        );
        assert_eq!(
            default_cache_dir(None, None, Some("/home/j")),
            Some(PathBuf::from("/home/j/.cache/jetpilot/tensorrt"))
        );
        assert_eq!(default_cache_dir(None, None, None), None);
    }

    #[test]
    fn engines_are_keyed_by_the_model_bytes_and_its_external_weights() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("best.onnx");
        std::fs::write(&model, b"abc").unwrap();
        // SHA-256("abc"), the FIPS 180-2 example.
        assert_eq!(
            model_key(&model).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        // The same name with other weights (a retrained best.onnx) gets another folder.
        std::fs::write(&model, b"abd").unwrap();
        assert_ne!(
            model_key(&model).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        // External weights count: "ab" + "c" hashes as "abc".
        std::fs::write(&model, b"ab").unwrap();
        std::fs::write(dir.path().join("best.onnx.data"), b"c").unwrap();
        assert_eq!(
            model_key(&model).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let err = model_key(&dir.path().join("gone.onnx")).unwrap_err();
        assert_eq!(err.kind(), std::io::ErrorKind::NotFound);
    }
}
