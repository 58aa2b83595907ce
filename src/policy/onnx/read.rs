//! Reading a network's weights back from an ONNX file: our exports and models exported from
//! PyTorch in torchvision's or the Lite0 port's layout, into [`NetWeights`] and the model
//! contract. Needs no deep-learning framework, so `train probe` and `model` read models in
//! the robot's own build.

use std::collections::BTreeSet;
use std::path::Path;

use prost::Message;
use prost::bytes::Bytes;

use super::proto::{ModelProto, TensorProto};
use super::resnet::META_ARCH;
use super::{Arch, Dim, NetWeights, OnnxError, TensorMap, inspect_bytes};
use crate::policy::ModelContract;

/// Reads a network's weights and contract from an ONNX file: our exports (`model init`,
/// `model import`, the trainer's) or one exported from PyTorch in torchvision's or the
/// Lite0 port's layout. The architecture is the metadata's `jetpilot.arch`, else the one
/// whose first tensor is among the initializers. Initializers are matched by name; a
/// common prefix in front of all of them (`model.`, `backbone.`, ..., as `torch.onnx.export`
/// writes for a wrapped module) is stripped. Values are float32, as `raw_data`
/// (little-endian) or `float_data`; other initializers (`num_batches_tracked`, ...) are
/// ignored.
///
/// The contract comes from the model's metadata; a model without one gets the default
/// contract with `input_size` taken from a fixed square input (else the default's 224).
///
/// PyTorch's exporter in eval mode folds BatchNorm into the preceding convolution and renames
/// the results (`onnx::Conv_123`); such a file has no BatchNorm tensors and is refused with
/// the name of the first missing one. Export with `training=torch.onnx.TrainingMode.PRESERVE`
/// (or `do_constant_folding=False`) from a model in eval mode to keep the names.
pub fn read_net_weights(path: &Path) -> Result<(NetWeights, ModelContract), OnnxError> {
    let shown = path.display().to_string();
    let bytes = Bytes::from(std::fs::read(path).map_err(|source| OnnxError::Read {
        path: shown.clone(),
        source,
    })?);
    let summary = inspect_bytes(bytes.clone(), &shown)?;
    if let Some(what) = summary.metadata.get(super::ensemble::META_ENSEMBLE) {
        return Err(OnnxError::NotAModel {
            path: shown,
            reason: format!(
                "it is an ensemble (`model ensemble`, {what}), not one network's weights: \
                 start from one of its models"
            ),
        });
    }
    let contract = match summary.contract() {
        Ok(Some(c)) => c,
        Ok(None) => {
            let dims: Vec<i64> = summary
                .inputs
                .first()
                .map(|input| {
                    input
                        .dims
                        .iter()
                        .map(|d| match d {
                            Dim::Fixed(n) => *n,
                            _ => -1,
                        })
                        .collect()
                })
                .unwrap_or_default();
            ModelContract::default().for_unlabelled_input(&dims)
        }
        Err(source) => {
            return Err(OnnxError::Contract {
                path: shown,
                source,
            });
        }
    };
    let model = ModelProto::decode(bytes).map_err(|source| OnnxError::Decode {
        path: shown.clone(),
        source,
    })?;
    let initializers = model.graph.map(|g| g.initializer).unwrap_or_default();
    let names = initializers.iter().map(|t| t.name.as_str());
    let arch = match summary.metadata.get(META_ARCH) {
        Some(name) => Arch::from_name(name).ok_or_else(|| OnnxError::UnknownArch {
            path: shown.clone(),
            name: name.clone(),
        })?,
        None => Arch::detect(names).unwrap_or(Arch::Resnet18),
    };
    let tensors = tensors_from_initializers(&initializers, arch)?;
    Ok((NetWeights::new(arch, tensors), contract))
}

/// The prefix in front of `arch`'s names ([`Arch::prefix_in`]), `""` when there is none.
fn common_prefix(names: &BTreeSet<&str>, arch: Arch) -> String {
    arch.prefix_in(names.iter().copied()).unwrap_or_default()
}

/// `arch`'s tensors among `initializers`, under their own names.
pub fn tensors_from_initializers(
    initializers: &[TensorProto],
    arch: Arch,
) -> Result<TensorMap, OnnxError> {
    const FLOAT: i32 = 1;
    const EXTERNAL: i32 = 1;
    let wanted: BTreeSet<String> = arch.param_shapes(1).into_iter().map(|(n, _)| n).collect();
    let names: BTreeSet<&str> = initializers.iter().map(|t| t.name.as_str()).collect();
    let prefix = common_prefix(&names, arch);
    let mut tensors = TensorMap::new();
    for t in initializers {
        let Some(name) = t.name.strip_prefix(prefix.as_str()) else {
            continue;
        };
        if !wanted.contains(name) {
            continue;
        }
        let bad = |reason: &str| OnnxError::TensorData {
            name: t.name.clone(),
            reason: reason.to_string(),
        };
        if t.data_type != FLOAT {
            return Err(bad(&format!(
                "element type {} is not float32 (1)",
                t.data_type
            )));
        }
        if t.data_location == EXTERNAL || !t.external_data.is_empty() {
            return Err(bad("external data files are not supported"));
        }
        let values: Vec<f32> = if t.raw_data.is_empty() {
            t.float_data.clone()
        } else {
            if t.raw_data.len() % 4 != 0 {
                return Err(bad("raw_data length is not a multiple of 4"));
            }
            t.raw_data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        tensors.insert(name.to_string(), (t.dims.clone(), values));
    }
    Ok(tensors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefix_is_found_and_stripped() {
        let names: BTreeSet<&str> = [
            "model.conv1.weight",
            "model.layer1.0.conv1.weight",
            "model.fc.weight",
        ]
        .into_iter()
        .collect();
        assert_eq!(common_prefix(&names, Arch::Resnet18), "model.");
        let names: BTreeSet<&str> = ["conv1.weight", "layer1.0.conv1.weight", "fc.weight"]
            .into_iter()
            .collect();
        assert_eq!(common_prefix(&names, Arch::Resnet18), "");
        let names: BTreeSet<&str> = ["m._conv_stem.weight", "m._fc.weight"]
            .into_iter()
            .collect();
        assert_eq!(common_prefix(&names, Arch::EfficientNetLite0), "m.");
    }
}
