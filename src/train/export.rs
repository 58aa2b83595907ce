//! Writing a trained actor as the ONNX file `jetpilot run` and `jetpilot eval` load: the
//! burn module's weights (BatchNorm running statistics included) through the foundation's
//! ONNX writer, with the model contract in the metadata. Files are replaced atomically, so a
//! run killed mid-write leaves the previous checkpoint intact.

use std::path::Path;

use burn::module::Module;

use super::{Net, TrainError};
use crate::policy::ModelContract;
use crate::policy::onnx::{NetWeights, Resnet18Weights, resnet18_model, write_model};

/// Writes `model` (in evaluation form: running statistics) to `path`.
pub fn write_actor(model: &Net, contract: &ModelContract, path: &Path) -> Result<(), TrainError> {
    write_net_weights(&model.clone().valid().to_weights()?, contract, path)
}

/// Writes either network's weights to `path` with `contract` in the metadata.
pub fn write_net_weights(
    weights: &NetWeights,
    contract: &ModelContract,
    path: &Path,
) -> Result<(), TrainError> {
    let proto = weights.model(contract.input_size, contract, env!("CARGO_PKG_VERSION"))?;
    write_model(path, &proto)?;
    Ok(())
}

/// Writes ResNet-18 weights to `path` with `contract` in the metadata.
pub fn write_weights(
    weights: &Resnet18Weights,
    contract: &ModelContract,
    path: &Path,
) -> Result<(), TrainError> {
    let proto = resnet18_model(
        contract.input_size,
        weights,
        contract,
        env!("CARGO_PKG_VERSION"),
    )?;
    write_model(path, &proto)?;
    Ok(())
}
