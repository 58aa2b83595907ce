//! The networks DDPG trains, as burn modules:
//!
//! ```text
//! encoder:     x [B,D] -> f [B,F]        frozen backbone: x *is* f (D = F: ResNet-18's 512,
//!                                        EfficientNet-Lite0's 1280), computed once per frame
//!                                        on ONNX Runtime (the CPU default);
//!                                        trainable: x = the preprocessed frame (D = 3*S*S),
//!                                        reshaped to [B,3,S,S] -> the network's own ResNet-18
//!                                        (ResNet-18 only)
//! actor:       f -> fc -> a [B,2]                                  (the exported actor's fc)
//! critic:      concat(f, a [B,2]) -> 256 -> relu -> 256 -> relu -> 1   Q [B,1]
//! ```
//!
//! The critic is the paper's: the backbone's features with the action concatenated into the input
//! of its final fully connected layers. A trainable trunk keeps its batch-norm layers in
//! inference mode (the imitation run's running statistics; a replay batch mixes states from
//! many episodes, and the target networks must see the same normalisation), while its
//! convolution and batch-norm affine weights train. Target networks live on the plain
//! (non-autodiff) device and follow the online ones by Polyak averaging,
//! `t <- (1 - tau) t + tau o`, over every float tensor of the module ([`polyak`]).

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};

use super::features::Head;
use crate::policy::onnx::{NetWeights, Resnet18Weights};
use crate::train::TrainError;
use crate::train::resnet::Resnet18;

/// A trainable ResNet-18 trunk from `weights`: batch norm frozen to its running statistics,
/// every weight trainable (see the module doc).
pub fn trainable_trunk(weights: &Resnet18Weights, device: &Device) -> Result<Resnet18, TrainError> {
    Ok(Resnet18::from_weights(weights, device)?
        .freeze()
        .set_require_grad(true))
}

/// `x [B,D]` to features `[B,F]`: the identity without a trunk, else the trunk's pooled
/// features of `x` seen as `[B,3,S,S]`.
fn encode(trunk: &Option<Resnet18>, x: Tensor<2>) -> Tensor<2> {
    match trunk {
        None => x,
        Some(t) => {
            let [b, d] = x.dims();
            let s = ((d / 3) as f64).sqrt().round() as usize;
            t.features(x.reshape([b, 3, s, s]))
        }
    }
}

/// The actor: an optional trainable trunk, then `fc`: F -> 2.
#[derive(Module, Debug)]
pub struct ActorHead {
    /// `Some` when the backbone trains (its own `fc` is not used).
    pub trunk: Option<Resnet18>,
    pub fc: Linear,
}

impl ActorHead {
    /// A head on frozen features.
    pub fn from_head(head: &Head, device: &Device) -> Self {
        // burn stores Linear weights [d_in, d_out]; Head holds torchvision's [2][F].
        let w = Tensor::<2>::from_data(
            TensorData::new(head.weight.clone(), [2, head.width()]),
            device,
        )
        .transpose();
        let b = Tensor::<1>::from_data(TensorData::new(head.bias.to_vec(), [2]), device);
        Self {
            trunk: None,
            fc: Linear {
                weight: Param::from_tensor(w),
                bias: Some(Param::from_tensor(b)),
            },
        }
    }

    /// The whole network of `weights`, trunk trainable.
    pub fn trainable(weights: &Resnet18Weights, device: &Device) -> Result<Self, TrainError> {
        let head = Head::from_weights(&NetWeights::Resnet18(weights.clone()))?;
        Ok(Self {
            trunk: Some(trainable_trunk(weights, device)?),
            ..Self::from_head(&head, device)
        })
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        self.fc.forward(encode(&self.trunk, x))
    }

    /// Back to a plain [`Head`] for acting and export.
    pub fn to_head(&self) -> Result<Head, TrainError> {
        let w = read(self.fc.weight.val().transpose())?; // [2,F] row-major
        let b = match &self.fc.bias {
            Some(b) => read(b.val())?,
            None => vec![0.0; 2],
        };
        Ok(Head {
            weight: w,
            bias: [b[0], b[1]],
        })
    }

    /// The whole actor's weights: the trunk's own when it trains, else `base`'s (the frozen
    /// backbone), with this `fc`.
    pub fn to_weights(&self, base: &NetWeights) -> Result<NetWeights, TrainError> {
        let head = self.to_head()?;
        Ok(match &self.trunk {
            Some(t) => head.into_weights(&NetWeights::Resnet18(t.to_weights()?)),
            None => head.into_weights(base),
        })
    }
}

/// Q(f, a), with an optional trainable trunk of its own.
#[derive(Module, Debug)]
pub struct Critic {
    pub trunk: Option<Resnet18>,
    pub l1: Linear,
    pub l2: Linear,
    pub out: Linear,
}

impl Critic {
    /// A critic with `hidden` units per layer on `features` of `trunk` (or frozen
    /// features); burn's default initialisation from the seeded device RNG.
    pub fn new(hidden: usize, features: usize, trunk: Option<Resnet18>, device: &Device) -> Self {
        Self {
            trunk,
            l1: LinearConfig::new(features + 2, hidden).init(device),
            l2: LinearConfig::new(hidden, hidden).init(device),
            out: LinearConfig::new(hidden, 1).init(device),
        }
    }

    pub fn forward(&self, x: Tensor<2>, a: Tensor<2>) -> Tensor<2> {
        let x = Tensor::cat(vec![encode(&self.trunk, x), a], 1);
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

/// Every float tensor of a module, in visiting order, flattened.
struct Collect(Vec<Tensor<1>>);

impl ModuleVisitor for Collect {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let t = param.val();
        let n = t.shape().num_elements();
        self.0.push(t.reshape([n]));
    }
}

/// `t <- (1 - tau) t + tau o` for each float tensor, `o` taken in visiting order.
struct Mix {
    online: std::vec::IntoIter<Tensor<1>>,
    tau: f32,
}

impl ModuleMapper for Mix {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some(o) = self.online.next() else {
            return param;
        };
        let tau = self.tau;
        param.map(|t| {
            let (shape, dev) = (t.shape(), t.device());
            let o: Tensor<D> = o.to_device(&dev).reshape(shape);
            t.mul_scalar(1.0 - tau).add(o.mul_scalar(tau))
        })
    }
}

/// Polyak averaging of `target` towards `online` (same architecture; `online` may be on
/// the autodiff device: only its detached values are read).
pub fn polyak<M: Module>(target: M, online: &M, tau: f32) -> M {
    let mut c = Collect(Vec::new());
    online.valid().visit(&mut c);
    let mut mix = Mix {
        online: c.0.into_iter(),
        tau,
    };
    target.map(&mut mix)
}

/// Forces every lazily initialised parameter into existence where it is.
struct Materialise;

impl ModuleVisitor for Materialise {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let _ = param.val();
    }
}

/// `m`, its parameters initialised where it was built, forked to `device` (an autodiff
/// device: the copy trains there). Networks are built on Flex with burn's seeded RNG and then
/// moved, so one seed starts from the same weights on every device.
pub fn forked_to<M: Module>(m: M, device: &Device) -> M {
    m.visit(&mut Materialise);
    m.fork(device)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ResNet-18's feature width.
    const FEATURES: usize = 512;

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
        let a = Critic::new(4, FEATURES, None, &device);
        let b = Critic::new(4, FEATURES, None, &device);
        let m = polyak(a.clone(), &b, 0.25);
        for (x, y, z) in [
            (&a.l1.weight, &b.l1.weight, &m.l1.weight),
            (&a.out.weight, &b.out.weight, &m.out.weight),
        ] {
            let (wa, wb, wm) = (
                read(x.val()).unwrap(),
                read(y.val()).unwrap(),
                read(z.val()).unwrap(),
            );
            for i in 0..wa.len() {
                assert!((wm[i] - (0.75 * wa[i] + 0.25 * wb[i])).abs() < 1e-6);
            }
        }
        let ba = read(a.l2.bias.as_ref().unwrap().val()).unwrap();
        let bb = read(b.l2.bias.as_ref().unwrap().val()).unwrap();
        let bm = read(m.l2.bias.as_ref().unwrap().val()).unwrap();
        assert!((bm[3] - (0.75 * ba[3] + 0.25 * bb[3])).abs() < 1e-6);
        let f = Tensor::<2>::zeros([3, FEATURES], &device);
        let act = Tensor::<2>::zeros([3, 2], &device);
        assert_eq!(m.forward(f, act).dims(), [3, 1]);
    }

    #[test]
    fn a_trainable_actor_computes_the_network_in_inference_mode_and_trains_its_trunk() {
        // Same numbers as the plain ResNet-18 forward pass (batch norm on running statistics)
        // although it runs on the autodiff device, and its conv weights get gradients.
        let weights = Resnet18Weights::random(2, 7);
        let plain = Device::flex();
        let ad = plain.clone().autodiff();
        let actor = ActorHead::trainable(&weights, &ad).unwrap();
        let reference = Resnet18::from_weights(&weights, &plain).unwrap();
        let s = 32;
        let x: Vec<f32> = (0..2 * 3 * s * s)
            .map(|i| ((i % 97) as f32 / 48.0) - 1.0)
            .collect();
        let want = read(reference.forward(Tensor::<4>::from_data(
            TensorData::new(x.clone(), [2, 3, s, s]),
            &plain,
        )))
        .unwrap();
        let out = actor.forward(Tensor::<2>::from_data(
            TensorData::new(x, [2, 3 * s * s]),
            &ad,
        ));
        let got = read(out.clone()).unwrap();
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 1e-4, "{got:?} vs {want:?}");
        }
        let grads = out.sum().backward();
        let trunk = actor.trunk.as_ref().unwrap();
        assert!(trunk.conv1.weight.grad(&grads).is_some());
        assert!(trunk.layer4[1].bn2.gamma.grad(&grads).is_some());
        // Export: the trunk's weights with this fc.
        let back = actor
            .to_weights(&NetWeights::Resnet18(Resnet18Weights::random(2, 8)))
            .unwrap();
        assert_eq!(
            back.tensors()["conv1.weight"].1,
            weights.tensors["conv1.weight"].1
        );
        assert_eq!(back.tensors()["fc.bias"].1, weights.tensors["fc.bias"].1);
    }
}
