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

use std::path::{Path, PathBuf};

use ort::ep::{self, ArbitrarilyConfigurableExecutionProvider, ExecutionProviderDispatch};
use serde::{Deserialize, Serialize};

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

/// The TensorRT provider's options under ONNX Runtime's own names
/// (`OrtTensorRTProviderOptionsV2`), the cache folder given when the cache is on.
pub fn tensorrt_entries(o: &TensorrtOptions, cache: Option<&Path>) -> Vec<(&'static str, String)> {
    let mut entries = vec![
        ("device_id", o.device_id.to_string()),
        (
            "trt_max_workspace_size",
            (u64::from(o.max_workspace_mib) * MIB).to_string(),
        ),
        ("trt_fp16_enable", flag(o.fp16)),
    ];
    if let Some(dir) = cache {
        let dir = dir.display().to_string();
        entries.extend([
            ("trt_engine_cache_enable", flag(true)),
            ("trt_engine_cache_path", dir.clone()),
            ("trt_timing_cache_enable", flag(true)),
            ("trt_timing_cache_path", dir),
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

/// The engine cache's folder, created; `None` (with a warning naming the folder) when the
/// cache is off, no folder can be named, or it cannot be created: the provider then builds
/// the engine at every start.
fn engine_cache(o: &TensorrtOptions) -> Option<PathBuf> {
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
    match std::fs::create_dir_all(&dir) {
        Ok(()) => Some(dir),
        Err(e) => {
            tracing::warn!(folder = %dir.display(), error = %e, "runtime.tensorrt.cache_dir cannot be created; TensorRT builds its engine at every start");
            None
        }
    }
}

/// Whether this ONNX Runtime library has provider `p`, and its registration (failing
/// loudly, so the caller can log it and try the next). The TensorRT cache folder is made
/// only when the library has that provider.
pub fn dispatch(p: Provider, gpu: &GpuOptions) -> (bool, ExecutionProviderDispatch) {
    match p {
        Provider::Tensorrt => {
            let available = matches!(
                <ep::TensorRT as ep::ExecutionProvider>::is_available(),
                Ok(true)
            );
            let cache = if available {
                engine_cache(&gpu.tensorrt)
            } else {
                None
            };
            let ep = tensorrt_entries(&gpu.tensorrt, cache.as_deref())
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
        let got = strings(tensorrt_entries(
            &o,
            Some(Path::new("/var/cache/jetpilot/tensorrt")),
        ));
        assert_eq!(
            got,
            pairs(&[
                ("device_id", "0"),
                ("trt_max_workspace_size", "1073741824"),
                ("trt_fp16_enable", "1"),
                ("trt_engine_cache_enable", "1"),
                ("trt_engine_cache_path", "/var/cache/jetpilot/tensorrt"),
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
    fn the_cpu_library_has_no_gpu_provider_and_makes_no_cache_folder() {
        // The CPU wheel's library (scripts/install-onnxruntime.sh) has neither GPU provider.
        super::super::runtime::environment(None)
            .expect("the ONNX Runtime library (scripts/install-onnxruntime.sh)");
        let dir = tempfile::tempdir().unwrap();
        let gpu = GpuOptions {
            tensorrt: TensorrtOptions {
                cache_dir: Some(dir.path().join("trt")),
                ..TensorrtOptions::default()
            },
            cuda: CudaOptions::default(),
        };
        assert!(!dispatch(Provider::Tensorrt, &gpu).0);
        assert!(!dispatch(Provider::Cuda, &gpu).0);
        assert!(dispatch(Provider::Cpu, &gpu).0);
        assert!(!dir.path().join("trt").exists());
    }
}
