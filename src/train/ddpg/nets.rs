//! The networks DDPG trains on top of the frozen backbone, as burn modules:
//!
//! ```text
//! actor head:  f [B,512] -> fc -> a [B,2]                    (the exported actor's fc)
//! critic:      concat(f [B,512], a [B,2]) -> 256 -> relu -> 256 -> relu -> 1   Q [B,1]
//! ```
//!
//! The critic is the paper's: ResNet-18 features with the action concatenated into the input
//! of its final fully connected layers. Target networks live on the plain (non-autodiff)
//! device and follow the online ones by Polyak averaging, `t <- (1 - tau) t + tau o`.

use burn::module::{Module, Param};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};

use super::features::{FEATURES, Head};
use crate::train::TrainError;

/// The actor's `fc`: 512 -> 2.
#[derive(Module, Debug)]
pub struct ActorHead {
    pub fc: Linear,
}

impl ActorHead {
    pub fn from_head(head: &Head, device: &Device) -> Self {
        // burn stores Linear weights [d_in, d_out]; Head holds torchvision's [2][512].
        let w = Tensor::<2>::from_data(TensorData::new(head.weight.clone(), [2, FEATURES]), device)
            .transpose();
        let b = Tensor::<1>::from_data(TensorData::new(head.bias.to_vec(), [2]), device);
        Self {
            fc: Linear {
                weight: Param::from_tensor(w),
                bias: Some(Param::from_tensor(b)),
            },
        }
    }

    pub fn forward(&self, f: Tensor<2>) -> Tensor<2> {
        self.fc.forward(f)
    }

    /// Back to a plain [`Head`] for acting and export.
    pub fn to_head(&self) -> Result<Head, TrainError> {
        let w = read(self.fc.weight.val().transpose())?; // [2,512] row-major
        let b = match &self.fc.bias {
            Some(b) => read(b.val())?,
            None => vec![0.0; 2],
        };
        Ok(Head {
            weight: w,
            bias: [b[0], b[1]],
        })
    }
}

/// Q(f, a).
#[derive(Module, Debug)]
pub struct Critic {
    pub l1: Linear,
    pub l2: Linear,
    pub out: Linear,
}

impl Critic {
    /// A critic with `hidden` units per layer; burn's default initialisation, then the
    /// seeded device RNG.
    pub fn new(hidden: usize, device: &Device) -> Self {
        Self {
            l1: LinearConfig::new(FEATURES + 2, hidden).init(device),
            l2: LinearConfig::new(hidden, hidden).init(device),
            out: LinearConfig::new(hidden, 1).init(device),
        }
    }

    pub fn forward(&self, f: Tensor<2>, a: Tensor<2>) -> Tensor<2> {
        let x = Tensor::cat(vec![f, a], 1);
        let x = relu(self.l1.forward(x));
        let x = relu(self.l2.forward(x));
        self.out.forward(x)
    }
}

/// Reads a tensor's values as f32.
pub fn read<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>, TrainError> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| TrainError::Backend(format!("{e:?}")))
}

/// `(1 - tau) * target + tau * online`, for one linear layer (`online` moved to the target's
/// device).
pub fn polyak_linear(target: &Linear, online: &Linear, tau: f32) -> Linear {
    let mix = |t: Tensor<2>, o: Tensor<2>| t.mul_scalar(1.0 - tau).add(o.mul_scalar(tau));
    let dev = target.weight.val().device();
    let weight = mix(target.weight.val(), online.weight.val().to_device(&dev));
    let bias = match (&target.bias, &online.bias) {
        (Some(t), Some(o)) => Some(Param::from_tensor(
            t.val()
                .mul_scalar(1.0 - tau)
                .add(o.val().to_device(&dev).mul_scalar(tau)),
        )),
        _ => None,
    };
    Linear {
        weight: Param::from_tensor(weight),
        bias,
    }
}

pub fn polyak_critic(target: &Critic, online: &Critic, tau: f32) -> Critic {
    Critic {
        l1: polyak_linear(&target.l1, &online.l1, tau),
        l2: polyak_linear(&target.l2, &online.l2, tau),
        out: polyak_linear(&target.out, &online.out, tau),
    }
}

pub fn polyak_actor(target: &ActorHead, online: &ActorHead, tau: f32) -> ActorHead {
    ActorHead {
        fc: polyak_linear(&target.fc, &online.fc, tau),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn head_round_trips_and_computes_w_f_plus_b() {
        let device = Device::flex();
        let mut weight = vec![0.0; 2 * FEATURES];
        weight[0] = 2.0; // out0 = 2 f0 + 0.5
        weight[FEATURES + 1] = -1.0; // out1 = -f1 - 0.25
        let head = Head {
            weight,
            bias: [0.5, -0.25],
        };
        let actor = ActorHead::from_head(&head, &device);
        assert_eq!(actor.to_head().unwrap(), head);
        let mut f = vec![0.0; FEATURES];
        f[0] = 3.0;
        f[1] = 4.0;
        let out = read(actor.forward(Tensor::<2>::from_data(
            TensorData::new(f.clone(), [1, FEATURES]),
            &device,
        )))
        .unwrap();
        assert_eq!(out, vec![6.5, -4.25]);
        assert_eq!(head.apply(&f), [6.5, -4.25]);
    }

    #[test]
    fn polyak_moves_a_tau_share_of_the_way() {
        let device = Device::flex();
        let a = Critic::new(4, &device);
        let b = Critic::new(4, &device);
        let m = polyak_critic(&a, &b, 0.25);
        let (wa, wb, wm) = (
            read(a.l1.weight.val()).unwrap(),
            read(b.l1.weight.val()).unwrap(),
            read(m.l1.weight.val()).unwrap(),
        );
        for i in 0..wa.len() {
            assert!((wm[i] - (0.75 * wa[i] + 0.25 * wb[i])).abs() < 1e-6);
        }
        let f = Tensor::<2>::zeros([3, FEATURES], &device);
        let act = Tensor::<2>::zeros([3, 2], &device);
        assert_eq!(m.forward(f, act).dims(), [3, 1]);
    }
}
