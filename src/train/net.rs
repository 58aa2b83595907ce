//! Either architecture as one burn module ([`Net`]), and reading one from a file: our
//! ONNX exports, a torchvision- or port-layout ONNX exported from PyTorch, or a PyTorch
//! state dict (`.pth`), with the architecture taken from the file.
//!
//! `train il` trains a [`Net`]; the export writes its [`NetWeights`] through the ONNX writer.

use std::path::Path;

use burn::module::{Module, Param};
use burn::nn::BatchNorm;
use burn::tensor::{Device, Tensor};

use super::TrainError;
use super::lite0::EfficientNetLite0;
use super::resnet::Resnet18;
use crate::policy::ModelContract;
use crate::policy::onnx::{Arch, NetWeights, read_net_weights};

/// The BatchNorm momentum (burn's = PyTorch's convention) a [`Net`] is built with unless
/// told otherwise: PyTorch's default 0.1 (the Lite0 port's 0.01 is TensorFlow's 0.99).
pub const DEFAULT_BN_MOMENTUM: f64 = 0.1;

/// A policy network of either architecture.
// One per run, moved once per training step: a 1.3 kB move is nothing beside the step, and
// burn's derive takes the variants as they are.
#[allow(clippy::large_enum_variant)]
#[derive(Module, Debug)]
pub enum Net {
    Resnet18(Resnet18),
    Lite0(EfficientNetLite0),
}

impl Net {
    /// Builds the network of `weights`' architecture on `device` for inputs of
    /// `input_size`, BatchNorms with `bn_momentum`.
    pub fn from_weights(
        weights: &NetWeights,
        input_size: u32,
        bn_momentum: f64,
        device: &Device,
    ) -> Result<Self, TrainError> {
        Ok(match weights {
            NetWeights::Resnet18(w) => {
                let mut net = Resnet18::from_weights(w, device)?;
                net.for_each_batch_norm(&mut |bn| bn.momentum = bn_momentum);
                Net::Resnet18(net)
            }
            NetWeights::Lite0(w) => Net::Lite0(EfficientNetLite0::from_weights(
                w,
                input_size as usize,
                bn_momentum,
                device,
            )?),
        })
    }

    pub fn arch(&self) -> Arch {
        match self {
            Net::Resnet18(_) => Arch::Resnet18,
            Net::Lite0(_) => Arch::EfficientNetLite0,
        }
    }

    pub fn to_weights(&self) -> Result<NetWeights, TrainError> {
        Ok(match self {
            Net::Resnet18(n) => NetWeights::Resnet18(n.to_weights()?),
            Net::Lite0(n) => NetWeights::Lite0(n.to_weights()?),
        })
    }

    pub fn num_outputs(&self) -> usize {
        match self {
            Net::Resnet18(n) => n.num_outputs(),
            Net::Lite0(n) => n.num_outputs(),
        }
    }

    /// The output layer.
    pub fn head(&self) -> &burn::nn::Linear {
        match self {
            Net::Resnet18(n) => &n.fc,
            Net::Lite0(n) => &n.fc,
        }
    }

    /// What the output layer reads: the pooled features, or an EfficientNet-Lite0's whole
    /// final map flattened (a head from `train probe --grid 2|3`).
    pub fn head_input(&self, x: Tensor<4>) -> Tensor<2> {
        match self {
            Net::Resnet18(n) => n.features(x),
            Net::Lite0(n) => n.head_input(x),
        }
    }

    /// `[B,3,S,S] -> [B,N]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        match self {
            Net::Resnet18(n) => n.forward(x),
            Net::Lite0(n) => n.forward(x),
        }
    }

    /// Freezes every BatchNorm's statistics: they normalise with their running mean and
    /// variance, which no longer move, even while the rest trains (their scale and shift
    /// still learn). How a small data set keeps ImageNet's statistics.
    pub fn freeze_batch_norm_statistics(mut self) -> Self {
        let mut freeze = |bn: &mut BatchNorm| bn.training = Param::from_bool(false);
        match &mut self {
            Net::Resnet18(n) => n.for_each_batch_norm(&mut freeze),
            Net::Lite0(n) => n.for_each_batch_norm(&mut freeze),
        }
        self
    }
}

/// [`read_net_weights`]: a network's weights and contract from an ONNX file.
pub fn read_onnx(path: &Path) -> Result<(NetWeights, ModelContract), TrainError> {
    Ok(read_net_weights(path)?)
}

/// Reads a [`Net`] from an ONNX file ([`read_onnx`]) or a PyTorch state dict (`.pth`,
/// `.pt`: [`crate::policy::pytorch::read_state_dict`], architecture `pth_arch`), built for
/// `input_size` inputs with BatchNorm momentum `bn_momentum`. The contract is the file's for
/// ONNX, `None` for a state dict (which has none).
pub fn load_net(
    path: &Path,
    pth_arch: Arch,
    input_size: Option<u32>,
    bn_momentum: f64,
    device: &Device,
) -> Result<(Net, Option<ModelContract>), TrainError> {
    let is_pth = matches!(
        path.extension().and_then(|e| e.to_str()),
        Some("pth" | "pt")
    );
    let (weights, contract) = if is_pth {
        let w = crate::policy::pytorch::read_state_dict(path, pth_arch).map_err(|e| {
            TrainError::Data {
                path: path.display().to_string(),
                reason: e.to_string(),
            }
        })?;
        (w, None)
    } else {
        let (w, c) = read_onnx(path)?;
        (w, Some(c))
    };
    let size = input_size
        .or(contract.as_ref().map(|c| c.input_size))
        .unwrap_or(224);
    Ok((
        Net::from_weights(&weights, size, bn_momentum, device)?,
        contract,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::onnx::proto::TensorProto;
    use crate::policy::onnx::{Lite0Weights, Resnet18Weights, resnet18_model, write_model};
    use prost::bytes::Bytes;
    #[test]
    fn read_onnx_strips_a_common_prefix_and_ignores_other_initializers() {
        let w = Resnet18Weights::random(2, 4);
        let contract = ModelContract {
            input_size: 32,
            ..ModelContract::default()
        };
        let mut model = resnet18_model(32, &w, &contract, "t").unwrap();
        let graph = model.graph.as_mut().unwrap();
        for t in &mut graph.initializer {
            t.name = format!("model.{}", t.name);
        }
        graph.initializer.push(TensorProto {
            name: "model.bn1.num_batches_tracked".into(),
            data_type: 7, // int64
            raw_data: Bytes::from(vec![0u8; 8]),
            ..TensorProto::default()
        });
        model.metadata_props.clear();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("prefixed.onnx");
        write_model(&path, &model).unwrap();
        let (net, c) = super::super::load_onnx(&path, &Device::flex()).unwrap();
        assert_eq!(c.input_size, 32, "from the input shape without metadata");
        assert_eq!(net.to_weights().unwrap(), w);
    }

    #[test]
    fn a_lite0_export_reads_back_as_lite0_and_is_refused_where_resnet_is_needed() {
        let w = NetWeights::Lite0(Lite0Weights::random(2, 9));
        let contract = ModelContract {
            input_size: 64,
            ..ModelContract::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lite0.onnx");
        write_model(&path, &w.model(64, &contract, "t").unwrap()).unwrap();
        let (back, c) = read_onnx(&path).unwrap();
        assert_eq!((&back, c.input_size), (&w, 64));
        let (net, _) = load_net(&path, Arch::Resnet18, None, 0.1, &Device::flex()).unwrap();
        assert_eq!(net.arch(), Arch::EfficientNetLite0);
        assert_eq!(net.to_weights().unwrap(), w);
        let err = super::super::load_onnx(&path, &Device::flex())
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains("EfficientNet-Lite0"), "{err}");
    }
}
