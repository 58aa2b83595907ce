//! Named tensors in and out of burn layers: what both networks' `from_weights` and
//! `to_weights` share. [`Source`] builds convolutions, BatchNorms and tensors from a
//! [`TensorMap`] and checks each against the architecture's expected shape; [`put_conv`],
//! [`put_bn`] and [`put`] read layers back under the same names.

use std::collections::BTreeMap;

use burn::module::{Param, RunningState};
use burn::nn::conv::Conv2d;
use burn::nn::{BatchNorm, Linear, PaddingConfig2d};
use burn::tensor::{Device, Tensor, TensorData};

use super::TrainError;
use crate::policy::onnx::{TensorMap, shape_to_string};

/// Looks up tensors by name and checks them against the expected shapes.
pub struct Source<'a> {
    pub tensors: &'a TensorMap,
    pub shapes: BTreeMap<String, Vec<i64>>,
    pub device: &'a Device,
    /// The architecture, for errors (`not a ResNet-18 tensor`).
    pub title: &'static str,
}

impl Source<'_> {
    pub fn tensor<const D: usize>(&self, name: &str) -> Result<Tensor<D>, TrainError> {
        let expected = self
            .shapes
            .get(name)
            .ok_or_else(|| TrainError::TensorData {
                name: name.to_string(),
                reason: format!("not a {} tensor", self.title),
            })?;
        let (dims, values) = self
            .tensors
            .get(name)
            .ok_or_else(|| TrainError::MissingTensor {
                name: name.to_string(),
                expected: shape_to_string(expected),
            })?;
        if dims != expected || dims.len() != D {
            return Err(TrainError::TensorShape {
                name: name.to_string(),
                expected: shape_to_string(expected),
                found: shape_to_string(dims),
            });
        }
        let shape: Vec<usize> = dims.iter().map(|&d| d as usize).collect();
        let count: usize = shape.iter().product();
        if values.len() != count {
            return Err(TrainError::TensorData {
                name: name.to_string(),
                reason: format!(
                    "{} values, its shape {} needs {count}",
                    values.len(),
                    shape_to_string(dims)
                ),
            });
        }
        Ok(Tensor::from_data(
            TensorData::new(values.clone(), shape),
            self.device,
        ))
    }

    /// `{name}.weight` `[O,I/groups,k,k]` as a convolution without bias.
    pub fn conv(
        &self,
        name: &str,
        stride: usize,
        padding: PaddingConfig2d,
        groups: usize,
    ) -> Result<Conv2d, TrainError> {
        let weight: Tensor<4> = self.tensor(&format!("{name}.weight"))?; // [O,I/g,k,k]
        let [_, _, kh, kw] = weight.dims();
        Ok(Conv2d {
            weight: Param::from_tensor(weight),
            bias: None,
            stride: [stride, stride],
            kernel_size: [kh, kw],
            dilation: [1, 1],
            groups,
            padding,
        })
    }

    /// `{name}.{weight,bias,running_mean,running_var}` as a BatchNorm.
    pub fn bn(&self, name: &str, epsilon: f64, momentum: f64) -> Result<BatchNorm, TrainError> {
        let t = |p: &str| self.tensor::<1>(&format!("{name}.{p}")); // [C]
        Ok(BatchNorm {
            gamma: Param::from_tensor(t("weight")?),
            beta: Param::from_tensor(t("bias")?),
            training: Param::from_bool(true),
            running_mean: RunningState::new(t("running_mean")?),
            running_var: RunningState::new(t("running_var")?),
            momentum,
            epsilon,
        })
    }

    /// `{name}.weight` `[N,F]` (PyTorch's layout) and `{name}.bias` `[N]` as a linear layer.
    pub fn linear(&self, name: &str) -> Result<Linear, TrainError> {
        let weight: Tensor<2> = self.tensor(&format!("{name}.weight"))?; // [N,F]
        Ok(Linear {
            // [F,N], stored contiguously (as a trained layer's is: the arithmetic, and so
            // the rounding, then matches a model that never left memory).
            weight: Param::from_tensor(Tensor::from_data(
                weight.transpose().into_data(),
                self.device,
            )),
            bias: Some(Param::from_tensor(self.tensor(&format!("{name}.bias"))?)), // [N]
        })
    }
}

/// Whether the output layer `{head}.weight` `[N,W]` reads the whole `s` x `s` final map of
/// `features` channels that an `input` x `input` picture gives (`W = features * s * s`,
/// flattened channel by channel, as `train probe --grid 2|3` writes it) rather than its
/// average (`W = features`). A missing tensor is left to the shape check; any other width
/// is an error naming both it and the input size's two choices.
pub fn head_reads_whole_map(
    tensors: &TensorMap,
    head: &str,
    features: usize,
    s: usize,
    input: usize,
) -> Result<bool, TrainError> {
    let name = format!("{head}.weight");
    let Some((dims, _)) = tensors.get(&name) else {
        return Ok(false);
    };
    let (n, width) = match dims.as_slice() {
        [n, w] => (*n, *w as usize),
        _ => return Ok(false),
    };
    if width == features {
        return Ok(false);
    }
    if s > 1 && width == features * s * s {
        return Ok(true);
    }
    Err(TrainError::TensorShape {
        name,
        expected: format!(
            "[{n},{features}] (pooled) or [{n},{}] (the whole {s}x{s} final map of a \
             {input}x{input} input; a head on the whole map needs the input size it was made \
             at: --input-size)",
            features * s * s
        ),
        found: shape_to_string(dims),
    })
}

pub fn put<const D: usize>(
    out: &mut TensorMap,
    name: &str,
    t: Tensor<D>,
) -> Result<(), TrainError> {
    let dims: Vec<i64> = t.dims().iter().map(|&d| d as i64).collect();
    let values = t
        .try_into_data_as::<f32>()
        .map_err(|e| TrainError::Backend(format!("reading `{name}`: {e:?}")))?
        .try_into_vec::<f32>()
        .map_err(|e| TrainError::Backend(format!("reading `{name}`: {e:?}")))?;
    out.insert(name.to_string(), (dims, values));
    Ok(())
}

pub fn put_conv(out: &mut TensorMap, name: &str, conv: &Conv2d) -> Result<(), TrainError> {
    put(out, &format!("{name}.weight"), conv.weight.val())
}

/// BatchNorm running statistics are read with `value_sync`, so the latest training step's
/// update is included (burn's `RunningState::value` may lag one update behind).
pub fn put_bn(out: &mut TensorMap, name: &str, bn: &BatchNorm) -> Result<(), TrainError> {
    put(out, &format!("{name}.weight"), bn.gamma.val())?;
    put(out, &format!("{name}.bias"), bn.beta.val())?;
    put(
        out,
        &format!("{name}.running_mean"),
        bn.running_mean.value_sync(),
    )?;
    put(
        out,
        &format!("{name}.running_var"),
        bn.running_var.value_sync(),
    )
}

/// `{name}.weight` `[N,F]` and `{name}.bias`, back in PyTorch's layout.
pub fn put_linear(out: &mut TensorMap, name: &str, fc: &Linear) -> Result<(), TrainError> {
    put(out, &format!("{name}.weight"), fc.weight.val().transpose())?; // [N,F]
    if let Some(bias) = &fc.bias {
        put(out, &format!("{name}.bias"), bias.val())?;
    }
    Ok(())
}
