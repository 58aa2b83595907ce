//! [`OrtPolicy`]: a model file run by ONNX Runtime, with its contract and shapes checked
//! at load and the execution provider actually in use logged.
//!
//! Spinning is off unless asked for ([`OrtOptions::allow_spinning`], `runtime.allow_spinning`):
//! by default ONNX Runtime's intra- and inter-op worker threads busy-wait for more work after
//! every run. The daemon runs one frame every 33-67 ms, so the threads would spin through
//! most of that gap, burning a core of a battery robot and taking cores from anything else
//! running (the camera decode, a second session).

use std::collections::BTreeMap;
use std::path::Path;

use ort::session::Session;
use ort::session::builder::{GraphOptimizationLevel, SessionBuilder};
use ort::value::TensorRef;

use super::optimize;
use super::providers::{self, GpuOptions};
use super::runtime::{self, Provider};
use super::{ModelContract, Policy, PolicyError, Result};

/// How to build the session.
#[derive(Debug, Clone)]
pub struct OrtOptions<'a> {
    /// `runtime.library` from the config.
    pub library: Option<&'a Path>,
    /// Execution providers in order of preference.
    pub providers: &'a [Provider],
    /// The GPU providers' settings (`[runtime.tensorrt]`, `[runtime.cuda]`).
    pub gpu: GpuOptions,
    /// Threads inside one operator (0: ONNX Runtime decides).
    pub intra_threads: usize,
    /// Let the worker threads spin-wait between runs (ONNX Runtime's own default); off,
    /// they block as soon as a run ends. See [`spinning_entries`].
    pub allow_spinning: bool,
    /// The contract for a model that carries none in its metadata.
    pub fallback_contract: &'a ModelContract,
}

impl<'a> OrtOptions<'a> {
    /// The CPU provider only, the library found as usual: how the tools that are not the
    /// daemon (`score`, `bench`, `model optimize`, tests) load a model.
    pub fn cpu(
        intra_threads: usize,
        allow_spinning: bool,
        fallback_contract: &'a ModelContract,
    ) -> Self {
        Self {
            library: None,
            providers: &[Provider::Cpu],
            gpu: GpuOptions::default(),
            intra_threads,
            allow_spinning,
            fallback_contract,
        }
    }
}

/// Where a model's contract came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ContractSource {
    ModelMetadata,
    Config,
}

pub struct OrtPolicy {
    session: Session,
    contract: ModelContract,
    contract_source: ContractSource,
    path: String,
    provider: Provider,
    shape: [usize; 4],
}

impl OrtPolicy {
    /// Loads `path` into an ONNX Runtime session.
    pub fn load(path: &Path, opts: &OrtOptions<'_>) -> Result<Self> {
        let shown = path.display().to_string();
        let model_err = |reason: String| PolicyError::Model {
            path: shown.clone(),
            reason,
        };
        // ONNX Runtime reads the file itself: no copy of the weights in this process's
        // memory beside its own (the whole process's peak is what a Nano has to hold).
        let len = std::fs::metadata(path)
            .map_err(|e| model_err(format!("cannot read: {e}")))?
            .len();
        if len == 0 {
            return Err(model_err("the file is empty".into()));
        }
        let (library, env) = runtime::environment(opts.library)?;
        // A model pre-optimised by `jetpilot model optimize` is loaded as it is, and only on
        // the machine it was made for (its graph may be laid out for that CPU).
        let level = match optimize::optimized_for(path) {
            Some(made_for) => {
                let here = optimize::machine(&runtime::ort_version(library));
                if made_for != here {
                    return Err(model_err(format!(
                        "it was pre-optimised for `{made_for}`, this machine is `{here}`: run `jetpilot model optimize` on the original model here, or use the original"
                    )));
                }
                tracing::info!(model = %shown, "pre-optimised for this machine: loading it with ONNX Runtime's optimisations off");
                GraphOptimizationLevel::Disable
            }
            None => GraphOptimizationLevel::Level3,
        };
        let make = |list: &[Provider]| {
            let builder =
                runtime::session_builder(env, level, opts.intra_threads, opts.allow_spinning)
                    .map_err(|e| PolicyError::Inference(e.to_string()))?;
            Ok::<_, PolicyError>(register(builder, list, &opts.gpu, path))
        };
        let (mut builder, registered) = make(opts.providers)?;
        // ONNX Runtime always has its CPU provider underneath.
        let mut provider = registered.first().copied().unwrap_or(Provider::Cpu);
        let session = match builder.commit_from_file(path) {
            Ok(s) => s,
            // A GPU provider that registered can still fail when the session is made (no
            // device, a sandbox without the GPU's devices, out of memory): drive on the
            // CPU rather than not at all.
            Err(e) if provider != Provider::Cpu => {
                tracing::warn!(provider = provider.as_str(), error = %e, "the session could not be made with the GPU providers; loading the model on the CPU");
                provider = Provider::Cpu;
                make(&[Provider::Cpu])?
                    .0
                    .commit_from_file(path)
                    .map_err(|e| model_err(format!("ONNX Runtime cannot load it: {e}")))?
            }
            Err(e) => return Err(model_err(format!("ONNX Runtime cannot load it: {e}"))),
        };

        let meta = read_metadata(&session);
        let (contract, contract_source) = match ModelContract::from_metadata(&meta) {
            Ok(Some(c)) => (c, ContractSource::ModelMetadata),
            Ok(None) => {
                let dims = session
                    .inputs()
                    .first()
                    .and_then(|i| i.dtype().tensor_shape().map(|d| d.to_vec()))
                    .unwrap_or_default();
                let c = opts.fallback_contract.for_unlabelled_input(&dims);
                if c.input_size != opts.fallback_contract.input_size {
                    tracing::info!(model = %shown, input_size = c.input_size, config_input_size = opts.fallback_contract.input_size, "no jetpilot metadata: the input size is the model's fixed input, not the config's model.input_size");
                }
                (c, ContractSource::Config)
            }
            Err(source) => {
                return Err(PolicyError::Contract {
                    path: shown,
                    source,
                });
            }
        };
        let shape = check_shapes(&session, &contract, &shown)?;
        tracing::info!(
            model = %shown,
            provider = provider.as_str(),
            contract = %contract,
            contract_from = ?contract_source,
            "model loaded"
        );
        Ok(Self {
            session,
            contract,
            contract_source,
            path: shown,
            provider,
            shape,
        })
    }

    pub fn provider(&self) -> Provider {
        self.provider
    }

    pub fn contract_source(&self) -> ContractSource {
        self.contract_source
    }
}

/// The session config entries that allow or forbid spinning: ONNX Runtime's keys for
/// `SessionOptions.add_session_config_entry` (the same as `ort`'s `with_intra_op_spinning`
/// and `with_inter_op_spinning`). Both are "1" in ONNX Runtime when unset.
pub fn spinning_entries(allow: bool) -> [(&'static str, &'static str); 2] {
    let value = if allow { "1" } else { "0" };
    [
        ("session.intra_op.allow_spinning", value),
        ("session.inter_op.allow_spinning", value),
    ]
}

/// Registers each of `list` that this ONNX Runtime library has, in order: ONNX Runtime
/// gives every node to the first provider that can run it (TensorRT, then CUDA for what
/// TensorRT leaves, then the CPU). Returns the builder and the providers registered.
fn register(
    mut builder: SessionBuilder,
    list: &[Provider],
    gpu: &GpuOptions,
    model: &Path,
) -> (SessionBuilder, Vec<Provider>) {
    let mut registered = Vec::new();
    for &p in list {
        let (available, dispatch) = providers::dispatch(p, gpu, model);
        if !available {
            tracing::warn!(
                provider = p.as_str(),
                "execution provider not in this ONNX Runtime build; trying the next"
            );
            continue;
        }
        match builder.with_execution_providers([dispatch]) {
            Ok(b) => {
                builder = b;
                registered.push(p);
            }
            Err(e) => {
                tracing::warn!(provider = p.as_str(), error = %e, "execution provider failed to register; trying the next");
                builder = e.recover();
            }
        }
    }
    (builder, registered)
}

fn read_metadata(session: &Session) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    if let Ok(meta) = session.metadata()
        && let Ok(keys) = meta.custom_keys()
    {
        for k in keys {
            if let Some(v) = meta.custom(&k) {
                out.insert(k, v);
            }
        }
    }
    out
}

fn fmt_dims(d: &[i64]) -> String {
    let parts: Vec<String> = d
        .iter()
        .map(|x| if *x < 0 { "?".into() } else { x.to_string() })
        .collect();
    format!("[{}]", parts.join(","))
}

/// Input `[1|?, 3, S|?, S|?]` f32 and a first output `[1|?, 2|?]`; returns the concrete
/// input shape.
fn check_shapes(session: &Session, c: &ModelContract, path: &str) -> Result<[usize; 4]> {
    let s = c.input_size as i64;
    let shape_err = |what: String, expected: String, found: String| PolicyError::Shape {
        path: path.to_string(),
        what,
        expected,
        found,
    };
    let inputs = session.inputs();
    if inputs.len() != 1 {
        return Err(shape_err(
            "the graph".into(),
            "exactly 1 input".into(),
            format!("{} inputs", inputs.len()),
        ));
    }
    let input = &inputs[0];
    let expected_in = format!("[1,3,{s},{s}] float32 (input_size {s} from the contract)");
    let dims = input.dtype().tensor_shape().map(|d| d.to_vec());
    let ok = matches!(
        input.dtype().tensor_type(),
        Some(ort::value::TensorElementType::Float32)
    ) && dims.as_ref().is_some_and(|d| {
        d.len() == 4
            && (d[0] == 1 || d[0] < 0)
            && d[1] == 3
            && (d[2] == s || d[2] < 0)
            && (d[3] == s || d[3] < 0)
    });
    if !ok {
        return Err(shape_err(
            format!("input `{}`", input.name()),
            expected_in,
            format!(
                "{} {:?}",
                dims.as_deref()
                    .map(fmt_dims)
                    .unwrap_or_else(|| "(not a tensor)".into()),
                input.dtype().tensor_type()
            ),
        ));
    }
    let Some(output) = session.outputs().first() else {
        return Err(shape_err(
            "the graph".into(),
            "at least 1 output".into(),
            "none".into(),
        ));
    };
    let odims = output.dtype().tensor_shape().map(|d| d.to_vec());
    let ok = matches!(
        output.dtype().tensor_type(),
        Some(ort::value::TensorElementType::Float32)
    ) && odims
        .as_ref()
        .is_some_and(|d| d.len() == 2 && (d[0] == 1 || d[0] < 0) && (d[1] == 2 || d[1] < 0));
    if !ok {
        return Err(shape_err(
            format!("output `{}`", output.name()),
            "[1,2] float32".into(),
            format!(
                "{} {:?}",
                odims
                    .as_deref()
                    .map(fmt_dims)
                    .unwrap_or_else(|| "(not a tensor)".into()),
                output.dtype().tensor_type()
            ),
        ));
    }
    Ok([1, 3, s as usize, s as usize])
}

impl Policy for OrtPolicy {
    fn contract(&self) -> &ModelContract {
        &self.contract
    }

    fn infer(&mut self, input: &[f32]) -> Result<[f32; 2]> {
        let expected: usize = self.shape.iter().product();
        if input.len() != expected {
            return Err(PolicyError::InputSize {
                expected,
                found: input.len(),
            });
        }
        let tensor = TensorRef::from_array_view((self.shape, input))
            .map_err(|e| PolicyError::Inference(e.to_string()))?;
        let outputs = self
            .session
            .run(ort::inputs![tensor])
            .map_err(|e| PolicyError::Inference(e.to_string()))?;
        let (_, data) = outputs[0]
            .try_extract_tensor::<f32>()
            .map_err(|e| PolicyError::Inference(e.to_string()))?;
        match data {
            [a, b, ..] => Ok([*a, *b]),
            _ => Err(PolicyError::Inference(format!(
                "output has {} values, expected 2",
                data.len()
            ))),
        }
    }

    fn describe(&self) -> String {
        format!("{} on ONNX Runtime ({})", self.path, self.provider.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spinning_entries_use_onnx_runtime_keys() {
        assert_eq!(
            spinning_entries(false),
            [
                ("session.intra_op.allow_spinning", "0"),
                ("session.inter_op.allow_spinning", "0")
            ]
        );
        assert!(spinning_entries(true).iter().all(|(_, v)| *v == "1"));
    }
}
