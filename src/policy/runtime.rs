//! Finding and loading the ONNX Runtime shared library, once per process.
//!
//! jetpilot links nothing at build time (`ort`'s `load-dynamic`): the library is the one in
//! the pinned PyPI wheel `onnxruntime==1.23.2`, the newest whose x86_64 and aarch64 wheels
//! are built for glibc 2.27, so the same version runs here and on JetPack 4.6. It is looked
//! for, in order: the config key `runtime.library`, `ORT_DYLIB_PATH`, then the standard
//! places listed by [`standard_dirs`]. It is loaded with `ort::init_from`, which returns an
//! error for a missing library (never `ort::init()`, which panics).
//!
//! # Troubleshooting
//! - "not found": run `scripts/install-onnxruntime.sh`, which unpacks the library from the
//!   wheel into `~/.local/share/jetpilot/onnxruntime/`.
//! - "is not compatible": the library is older than 1.17 (the API level `ort` needs).
//! - GPU providers silently unused: the CPU wheel has none; jetpilot logs the provider in
//!   use, and on a Jetson Nano (JetPack 4.6, CUDA 10.2) only the CPU provider of a current
//!   ONNX Runtime works.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use super::{PolicyError, Result};

/// The version the install script fetches and the standard places look for first.
pub const PINNED_VERSION: &str = "1.23.2";
/// Environment variable naming the library file (as `ort` itself uses it).
pub const ENV_VAR: &str = "ORT_DYLIB_PATH";

/// ONNX Runtime execution providers, tried in the configured order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Provider {
    Tensorrt,
    Cuda,
    Cpu,
}

impl Provider {
    pub fn as_str(self) -> &'static str {
        match self {
            Provider::Tensorrt => "tensorrt",
            Provider::Cuda => "cuda",
            Provider::Cpu => "cpu",
        }
    }
}

static ENVIRONMENT: OnceLock<(PathBuf, ort::environment::Environment)> = OnceLock::new();

/// Folders searched for `libonnxruntime.so*` when neither the config nor the environment
/// names the file.
pub fn standard_dirs() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Ok(exe) = std::env::current_exe()
        && let Some(dir) = exe.parent()
    {
        dirs.push(dir.to_path_buf());
        dirs.push(dir.join("../lib/jetpilot"));
    }
    let data_home = std::env::var_os("XDG_DATA_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")));
    if let Some(d) = data_home {
        dirs.push(d.join("jetpilot/onnxruntime"));
    }
    for d in [
        "/usr/lib/jetpilot",
        "/usr/local/lib",
        "/usr/lib",
        "/usr/lib/aarch64-linux-gnu",
        "/usr/lib/x86_64-linux-gnu",
    ] {
        dirs.push(PathBuf::from(d));
    }
    dirs
}

/// The best `libonnxruntime.so*` in a folder: the pinned version, then the plain name,
/// then the highest other version.
fn library_in(dir: &Path) -> Option<PathBuf> {
    let pinned = dir.join(format!("libonnxruntime.so.{PINNED_VERSION}"));
    if pinned.is_file() {
        return Some(pinned);
    }
    let plain = dir.join("libonnxruntime.so");
    if plain.is_file() {
        return Some(plain);
    }
    let mut versioned: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("libonnxruntime.so."))
        })
        .collect();
    // Highest version by number (1.20 above 1.9).
    versioned.sort_by_key(|p| {
        p.file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.strip_prefix("libonnxruntime.so."))
            .map(|v| {
                v.split('.')
                    .map(|x| x.parse::<u32>().unwrap_or(0))
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default()
    });
    versioned.pop()
}

/// Resolves which library file to load, without loading it.
pub fn find_library(configured: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = configured {
        return if p.is_file() {
            Ok(p.to_path_buf())
        } else {
            Err(PolicyError::RuntimeNotFound {
                searched: format!("runtime.library = {} (no such file)", p.display()),
            })
        };
    }
    if let Some(p) = std::env::var_os(ENV_VAR).filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(PolicyError::RuntimeNotFound {
                searched: format!("{ENV_VAR}={} (no such file)", p.display()),
            })
        };
    }
    let dirs = standard_dirs();
    dirs.iter()
        .find_map(|d| library_in(d))
        .ok_or_else(|| PolicyError::RuntimeNotFound {
            searched: dirs
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// The process-wide ONNX Runtime environment, loading the library on first use.
/// Returns the environment and the path it was loaded from.
pub fn environment(
    configured: Option<&Path>,
) -> Result<(&'static Path, &'static ort::environment::Environment)> {
    if let Some((path, env)) = ENVIRONMENT.get() {
        return Ok((path.as_path(), env));
    }
    let path = find_library(configured)?;
    let load_err = |reason: String| PolicyError::RuntimeLoad {
        path: path.display().to_string(),
        reason,
    };
    let env = ort::init_from(&path)
        .map_err(|e| load_err(e.to_string()))?
        .with_name("jetpilot")
        .build()
        .map_err(|e| load_err(e.to_string()))?;
    let (p, e) = ENVIRONMENT.get_or_init(|| (path, env));
    tracing::debug!(library = %p.display(), "ONNX Runtime loaded");
    Ok((p.as_path(), e))
}

/// A session builder as jetpilot makes every session: this optimisation level, this many
/// intra-op threads (0: ONNX Runtime decides), spinning as asked
/// ([`super::ort_policy::spinning_entries`]). Execution providers are the caller's.
pub fn session_builder(
    env: &ort::environment::Environment,
    level: ort::session::builder::GraphOptimizationLevel,
    intra_threads: usize,
    allow_spinning: bool,
) -> ort::Result<ort::session::builder::SessionBuilder> {
    let mut builder = ort::session::Session::builder(env)?.with_optimization_level(level)?;
    if intra_threads > 0 {
        builder = builder.with_intra_threads(intra_threads)?;
    }
    for (key, value) in super::ort_policy::spinning_entries(allow_spinning) {
        builder = builder.with_config_entry(key, value)?;
    }
    Ok(builder)
}

/// The loaded library's version from its build info (`git-branch=rel-1.23.2`), else from
/// its file name (`libonnxruntime.so.1.23.2`).
pub fn ort_version(library: &Path) -> String {
    let info = ort::info();
    let from_info = info
        .split(',')
        .find_map(|p| p.trim().strip_prefix("git-branch=rel-"));
    let from_name = library
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.strip_prefix("libonnxruntime.so."));
    from_info
        .or(from_name)
        .map_or_else(|| "version unknown".into(), str::to_string)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configured_path_that_does_not_exist_is_named() {
        let err = find_library(Some(Path::new("/nope/libonnxruntime.so")))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nope/libonnxruntime.so"), "{err}");
        assert!(err.contains("install-onnxruntime.sh"), "{err}");
    }

    #[test]
    fn prefers_the_pinned_version_in_a_folder() {
        let dir = tempfile::tempdir().unwrap();
        for name in [
            "libonnxruntime.so.1.20.0",
            "libonnxruntime.so.1.23.2",
            "libonnxruntime.so.1.9.0",
        ] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        assert_eq!(
            library_in(dir.path()).unwrap(),
            dir.path().join("libonnxruntime.so.1.23.2")
        );
        std::fs::remove_file(dir.path().join("libonnxruntime.so.1.23.2")).unwrap();
        assert_eq!(
            library_in(dir.path()).unwrap(),
            dir.path().join("libonnxruntime.so.1.20.0")
        );
    }
}
