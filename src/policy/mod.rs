//! The policy stage: model contract, preprocessing, and the network itself.
//!
//! - [`contract`]: input size, channel order, normalisation and output meaning of a model.
//! - [`preprocess`]: RGB8 frame of any size -> NCHW f32 tensor, with no allocation per frame.
//! - [`onnx`]: our own ONNX writer (ResNet-18 in torchvision's layout) and reader.
//! - [`optimize`]: models pre-optimised by ONNX Runtime for this machine, loaded without a
//!   second copy of the weights.
//! - [`quantize`]: int8 QDQ models from float ones, calibrated on frames.
//! - [`runtime`] and [`ort_policy`]: ONNX Runtime, loaded from a shared library at run time.

pub mod contract;
pub mod null;
pub mod onnx;
pub mod optimize;
pub mod ort_policy;
pub mod preprocess;
pub mod providers;
pub mod pytorch;
pub mod quantize;
pub mod runtime;

pub use contract::{ChannelOrder, ModelContract, OutputKind};
pub use ort_policy::OrtPolicy;
pub use preprocess::Preprocessor;

/// Errors from loading or running a policy.
#[derive(Debug, thiserror::Error)]
pub enum PolicyError {
    #[error(
        "ONNX Runtime library not found (looked in: {searched}).\n  Install it with `scripts/install-onnxruntime.sh` (it unpacks libonnxruntime.so.1.23.2 from the pinned PyPI wheel onnxruntime==1.23.2),\n  or point `runtime.library` in the config or the ORT_DYLIB_PATH environment variable at libonnxruntime.so"
    )]
    RuntimeNotFound { searched: String },
    #[error("cannot load ONNX Runtime from {path}: {reason}")]
    RuntimeLoad { path: String, reason: String },
    #[error("model {path}: {reason}")]
    Model { path: String, reason: String },
    #[error("model {path}: {what} has shape {found}, expected {expected}")]
    Shape {
        path: String,
        what: String,
        expected: String,
        found: String,
    },
    #[error("model {path}: {source}")]
    Contract {
        path: String,
        #[source]
        source: contract::ContractError,
    },
    #[error("execution provider `{0}` is not known: use tensorrt, cuda or cpu")]
    UnknownProvider(String),
    #[error("inference failed: {0}")]
    Inference(String),
    #[error("input tensor has {found} values, the model expects {expected}")]
    InputSize { expected: usize, found: usize },
}

pub type Result<T> = std::result::Result<T, PolicyError>;

/// A network that maps a preprocessed frame to two numbers (see [`OutputKind`]).
///
/// Implemented by [`OrtPolicy`] on the robot and by scripted doubles in tests. `infer` runs
/// on a blocking thread, never on the async runtime.
pub trait Policy: Send {
    fn contract(&self) -> &ModelContract;
    /// `input` is NCHW f32, `3 * input_size * input_size` values.
    fn infer(&mut self, input: &[f32]) -> Result<[f32; 2]>;
    /// For logs: model path, execution provider in use.
    fn describe(&self) -> String;
}
