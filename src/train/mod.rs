//! The trainer (cargo feature `train`; the robot's build does not carry it).
//!
//! This folder owns everything that needs a deep-learning framework: the actor network
//! as a [burn](https://burn.dev) module, its import from and export to the ONNX files the
//! runtime loads, and (next) the training loop itself. burn 0.22 chooses its backend at
//! run time through its `Device` (tensors carry only their rank in the type): the crate
//! enables burn's `flex` feature, the pure-Rust CPU backend (`Device::flex()`); adding
//! burn's `cuda` or `wgpu` feature makes `Device::cuda(0)` / `Device::wgpu(..)` available
//! to the same model code. Gradients are a device decorator: `device.autodiff()`.
//!
//! - [`resnet`]: ResNet-18 in torchvision's layout, [`Resnet18::from_weights`] /
//!   [`Resnet18::to_weights`] against the ONNX writer's [`Resnet18Weights`], and
//!   [`load_onnx`] for our exports and torchvision-layout files exported from PyTorch.
//! - [`lite0`]: EfficientNet-Lite0 the same way; [`net`]: [`Net`], either of the two as one
//!   module, and [`load_net`] / [`read_onnx`] for ONNX files and PyTorch state dicts.
//! - [`tensors`]: named tensors into and out of burn layers, for both.
//!
//! [`Resnet18Weights`]: crate::policy::onnx::Resnet18Weights

pub mod augment;
pub mod curve;
pub mod data;
pub mod ddpg;
pub mod device;
pub mod experiment;
pub mod export;
pub mod il;
pub mod lite0;
pub mod net;
pub mod resnet;
pub mod tensors;

pub use device::TrainDevice;
pub use net::{Net, load_net, read_onnx};
pub use resnet::{Resnet18, load_onnx};

/// Errors of the trainer.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The model's contract metadata is present but invalid.
    #[error("{path}: {source}")]
    Contract {
        path: String,
        #[source]
        source: crate::policy::contract::ContractError,
    },
    #[error("tensor `{name}` is missing (expected shape {expected})")]
    MissingTensor { name: String, expected: String },
    #[error("tensor `{name}` has shape {found}, expected {expected}")]
    TensorShape {
        name: String,
        expected: String,
        found: String,
    },
    /// A tensor whose values cannot be read (not float32, external data, wrong length).
    #[error("tensor `{name}`: {reason}")]
    TensorData { name: String, reason: String },
    /// The `--device` asked for is not built in or cannot be opened.
    #[error("device `{device}`: {reason}")]
    Device { device: String, reason: String },
    /// Reading a tensor back from the backend failed.
    #[error("backend: {0}")]
    Backend(String),
    #[error(transparent)]
    Onnx(#[from] crate::policy::onnx::OnnxError),
    /// A demonstration folder, file or training output that cannot be used.
    #[error("{path}: {reason}")]
    Data { path: String, reason: String },
    /// The loss became NaN or infinite (lower the learning rate).
    #[error("training diverged in epoch {epoch}: loss {loss}; lower --lr")]
    Diverged { epoch: usize, loss: f64 },
    #[error(transparent)]
    Curve(#[from] curve::CurveError),
}
