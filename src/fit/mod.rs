//! Closed-form fitting: a pretrained backbone kept as it is and its output layer solved by
//! ridge regression on labelled frames (`jetpilot train probe`). It needs ONNX Runtime and
//! linear algebra only, no deep-learning framework, so it is in every build: the robot's
//! own `jetpilot` fits a policy from the frames it has just collected, in about a minute.
//!
//! - [`ridge`]: the maths (standardised dual ridge, cross-validation over time blocks).
//! - [`probe`]: the backbone's final maps on ONNX Runtime, pooling into cells, mirroring,
//!   the choice among them, and the head folded back into the whole network.

pub mod probe;
pub mod ridge;

/// Errors of a fit.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// A frame folder or file that cannot be used.
    #[error("{path}: {reason}")]
    Data { path: String, reason: String },
    /// A pooling grid the backbone's final map cannot give.
    #[error("--grid: {grid} cells a side, but the final map is {side}x{side}")]
    Grid { grid: usize, side: usize },
    #[error("ONNX Runtime: {0}")]
    Runtime(#[from] ort::Error),
    #[error("preprocessing: {0}")]
    Preprocess(#[from] crate::policy::preprocess::PreprocessError),
    /// The backbone's output is not the final map its architecture promises.
    #[error("the backbone gave {found} values, expected a {channels}x{side}x{side} map")]
    MapSize {
        found: usize,
        channels: usize,
        side: usize,
    },
    #[error(transparent)]
    Ridge(#[from] ridge::RidgeError),
    #[error(transparent)]
    Onnx(#[from] crate::policy::onnx::OnnxError),
    /// ONNX Runtime could not be loaded.
    #[error(transparent)]
    Policy(#[from] crate::policy::PolicyError),
}
