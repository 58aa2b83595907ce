//! One DDPG learner: owns the online and target networks, their optimisers and the update
//! step, with DDPGfD's and TD3's options.
//!
//! ```text
//! target:  a' = clip(pi'(f') + clip(N(0, s), -c, c), low, high)       (TD3 smoothing; s = 0: DDPG)
//!          y  = R + discount * min_i Q'_i(f', a')                      (one critic: DDPG)
//! critic:  L_Q  = mean_i mean (Q_i(f, a) - y)^2
//! actor:   every `policy_delay` updates (TD3's delayed actor; 1: DDPG)
//!          L_pi = -mean Q_1(f, pi(f)) / mean|Q_1| (detached scale, as TD3+BC)
//!                 + bc_weight * sum_demo [Q_1(f, a_demo) > Q_1(f, pi(f))] |pi(f) - a_demo|^2 / n_demo
//!                 + anchor_weight * mean |pi(f) - pi_0(f)|^2       (stay near the imitation policy)
//!                 + mean relu(|pi(f) - mid| - half_range)^2        (keep outputs in range)
//! targets: Polyak averaging with tau after each update
//! ```
//!
//! The bracket is the Q-filter: the behaviour-cloning pull towards a demonstration applies
//! only where the critic still rates the demonstrated action above the actor's own.

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use super::features::Head;
use super::nets::{ActorHead, Critic, forked_to, polyak, read, trainable_trunk};
use super::replay::Replay;
use crate::policy::onnx::{NetWeights, Resnet18Weights};
use crate::train::TrainError;

/// Learner settings.
#[derive(Debug, Clone, PartialEq)]
pub struct AgentConfig {
    pub gamma: f32,
    pub tau: f32,
    pub actor_lr: f64,
    pub critic_lr: f64,
    pub batch: usize,
    pub hidden: usize,
    /// TD3: two critics, the minimum in the target.
    pub twin: bool,
    /// TD3: update the actor every this many critic updates.
    pub policy_delay: usize,
    /// TD3 target smoothing noise and its clip (0: off).
    pub target_noise: f32,
    pub target_noise_clip: f32,
    /// Weight of the Q-filtered behaviour-cloning loss on demonstrations (0: off).
    pub bc_weight: f32,
    pub q_filter: bool,
    /// Weight of the pull towards the initial (imitation) policy on every sampled state,
    /// `mean |pi(f) - pi_0(f)|^2` (0: off). Without it a critic trained on a few thousand
    /// near-on-policy transitions drags all 512 head weights at once and the policy drifts
    /// off the road within a few hundred updates (measured).
    pub anchor_weight: f32,
    /// The anchor's weight falls linearly to 0 over this many critic updates after the
    /// warm-up (0: it stays), so the imitation policy guides the start and the critic,
    /// once trained, decides.
    pub anchor_decay_updates: u64,
    /// Policy improvement by search instead of the critic's gradient (0: off): on each
    /// sampled state the twin critics' minimum rates the actor's action moved by
    /// {-2,-1,0,1,2} x this on steering and {-1,0,1} x half of it on speed, and the actor
    /// regresses towards the best of the 15 (a step of bounded size, like supervised
    /// learning, where the gradient of a critic fitted on a few thousand transitions can
    /// point anywhere).
    pub search_step: f32,
    /// Action bounds `[speed, steering]`.
    pub low: [f32; 2],
    pub high: [f32; 2],
}

impl Default for AgentConfig {
    fn default() -> Self {
        Self {
            gamma: 0.98,
            tau: 0.005,
            actor_lr: 1e-5,
            critic_lr: 1e-3,
            batch: 128,
            hidden: 256,
            twin: true,
            policy_delay: 2,
            target_noise: 0.1,
            target_noise_clip: 0.25,
            bc_weight: 1.0,
            q_filter: true,
            anchor_weight: 0.0,
            anchor_decay_updates: 0,
            search_step: 0.0,
            low: [0.0, -1.0],
            high: [1.0, 1.0],
        }
    }
}

/// Losses of one update (actor loss only when the actor was updated).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UpdateStats {
    pub critic_loss: f64,
    pub actor_loss: Option<f64>,
    pub mean_q: f64,
}

pub struct Agent {
    cfg: AgentConfig,
    device: Device,
    inner: Device,
    actor: ActorHead,
    actor_target: ActorHead,
    /// The initial actor, frozen, on the plain device.
    anchor: ActorHead,
    critics: Vec<Critic>,
    critic_targets: Vec<Critic>,
    actor_opt: burn::optim::ModuleOptimizer,
    critic_opts: Vec<burn::optim::ModuleOptimizer>,
    updates: u64,
    /// Updates that trained the actor's side (after the warm-up): the anchor's clock.
    acting_updates: u64,
}

/// A sampled batch, as tensors on one device.
struct BatchTensors {
    f: Tensor<2>,
    a: Tensor<2>,
    r: Tensor<2>,
    next: Tensor<2>,
    discount: Tensor<2>,
    demo: Tensor<2>,
    n_demo: usize,
}

impl Agent {
    /// Networks on frozen features (states are the backbone's `head.width()` features), actor from
    /// `head`, on `device` (a plain one; see [`crate::train::TrainDevice`]); seeds burn's RNG.
    pub fn new(cfg: AgentConfig, head: &Head, seed: u64, device: &Device) -> Self {
        let init = Self::init_device(seed);
        let actor = ActorHead::from_head(head, &init);
        let n_critics = if cfg.twin { 2 } else { 1 };
        let critics = (0..n_critics)
            .map(|_| Critic::new(cfg.hidden, head.width(), None, &init))
            .collect();
        Self::assemble(cfg, actor, critics, device, seed)
    }

    /// Networks with trainable backbones (states are preprocessed frames): the actor is
    /// `weights`' whole ResNet-18, and each critic gets its own copy of its trunk.
    pub fn trainable(
        cfg: AgentConfig,
        weights: &Resnet18Weights,
        seed: u64,
        device: &Device,
    ) -> Result<Self, TrainError> {
        let init = Self::init_device(seed);
        let actor = ActorHead::trainable(weights, &init)?;
        let n_critics = if cfg.twin { 2 } else { 1 };
        let critics = (0..n_critics)
            .map(|_| {
                Ok(Critic::new(
                    cfg.hidden,
                    crate::train::resnet::FEATURES,
                    Some(trainable_trunk(weights, &init)?),
                    &init,
                ))
            })
            .collect::<Result<Vec<_>, TrainError>>()?;
        Ok(Self::assemble(cfg, actor, critics, device, seed))
    }

    /// Where the networks are built: Flex's autodiff device, burn's RNG seeded, whatever
    /// the training device (so one seed gives the same initial networks on all of them).
    fn init_device(seed: u64) -> Device {
        let init = Device::flex().autodiff();
        init.seed(seed);
        init
    }

    /// The agent training on `plain` (its autodiff twin), the networks moved there.
    fn assemble(
        cfg: AgentConfig,
        actor: ActorHead,
        critics: Vec<Critic>,
        plain: &Device,
        seed: u64,
    ) -> Self {
        let inner = plain.clone();
        let device = inner.clone().autodiff();
        let (actor, critics) = if inner == Device::flex() {
            (actor, critics)
        } else {
            device.seed(seed);
            (
                forked_to(actor, &device),
                critics.into_iter().map(|c| forked_to(c, &device)).collect(),
            )
        };
        let n_critics = critics.len();
        Self {
            actor_target: actor.clone().valid(),
            anchor: actor.clone().valid(),
            critic_targets: critics.iter().map(|c| c.clone().valid()).collect(),
            actor,
            critics,
            actor_opt: AdamConfig::new().init(),
            critic_opts: (0..n_critics).map(|_| AdamConfig::new().init()).collect(),
            cfg,
            device,
            inner,
            updates: 0,
            acting_updates: 0,
        }
    }

    pub fn config(&self) -> &AgentConfig {
        &self.cfg
    }

    /// The actor's `fc` as a plain head.
    pub fn head(&self) -> Result<Head, TrainError> {
        self.actor.clone().valid().to_head()
    }

    /// The whole actor's weights (`base` supplies the frozen backbone).
    pub fn actor_weights(&self, base: &NetWeights) -> Result<NetWeights, TrainError> {
        self.actor.clone().valid().to_weights(base)
    }

    fn tensors(&self, replay: &Replay, idx: &[usize], device: &Device) -> BatchTensors {
        let n = idx.len();
        // Frozen features (F) or preprocessed frames (3*S*S), whatever the replay holds.
        let width = idx.first().map_or(0, |&i| replay.get(i).features.len());
        let mut f = Vec::with_capacity(n * width);
        let mut next = Vec::with_capacity(n * width);
        let (mut a, mut r, mut d, mut demo) = (
            Vec::with_capacity(2 * n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        for &i in idx {
            let t = replay.get(i);
            f.extend_from_slice(&t.features);
            next.extend_from_slice(&t.next_features);
            a.extend_from_slice(&t.action);
            r.push(t.reward);
            d.push(t.discount);
            demo.push(if t.demo { 1.0f32 } else { 0.0 });
        }
        let n_demo = demo.iter().filter(|v| **v > 0.0).count();
        let t2 = |v: Vec<f32>, w: usize| Tensor::<2>::from_data(TensorData::new(v, [n, w]), device);
        BatchTensors {
            f: t2(f, width),
            a: t2(a, 2),
            r: t2(r, 1),
            next: t2(next, width),
            discount: t2(d, 1),
            demo: t2(demo, 1),
            n_demo,
        }
    }

    fn clamp_actions(&self, a: Tensor<2>) -> Tensor<2> {
        let [n, _] = a.dims();
        let dev = a.device();
        let low = Tensor::<2>::from_data(TensorData::new(self.cfg.low.to_vec(), [1, 2]), &dev)
            .expand([n, 2]);
        let high = Tensor::<2>::from_data(TensorData::new(self.cfg.high.to_vec(), [1, 2]), &dev)
            .expand([n, 2]);
        a.max_pair(low).min_pair(high)
    }

    /// The TD target `y` for a batch, on the plain device.
    fn targets(&self, b: &BatchTensors, rng: &mut impl Rng) -> Tensor<2> {
        let mut a_next = self.actor_target.forward(b.next.clone());
        if self.cfg.target_noise > 0.0 {
            let [n, _] = a_next.dims();
            let c = self.cfg.target_noise_clip;
            let noise: Vec<f32> = (0..2 * n)
                .map(|_| {
                    let z: f32 = StandardNormal.sample(rng);
                    (z * self.cfg.target_noise).clamp(-c, c)
                })
                .collect();
            a_next = a_next + Tensor::<2>::from_data(TensorData::new(noise, [n, 2]), &self.inner);
        }
        let a_next = self.clamp_actions(a_next);
        let mut q_next = self.critic_targets[0].forward(b.next.clone(), a_next.clone());
        for t in &self.critic_targets[1..] {
            q_next = q_next.min_pair(t.forward(b.next.clone(), a_next.clone()));
        }
        b.r.clone() + b.discount.clone() * q_next
    }

    /// One update from a batch sampled from `replay`. `train_actor = false` trains only the
    /// critics (the warm-up that keeps a random critic from wrecking the imitation policy).
    pub fn update(
        &mut self,
        replay: &Replay,
        train_actor: bool,
        rng: &mut impl Rng,
    ) -> Result<UpdateStats, TrainError> {
        let idx = replay.sample(self.cfg.batch, rng);
        if idx.is_empty() {
            return Ok(UpdateStats::default());
        }
        let plain = self.tensors(replay, &idx, &self.inner);
        let y = self.targets(&plain, rng);
        let y = Tensor::<2>::from_data(y.into_data(), &self.device);
        let b = self.tensors(replay, &idx, &self.device);

        // Critics.
        let mut loss: Option<Tensor<1>> = None;
        let mut mean_q = 0.0;
        for (i, c) in self.critics.iter().enumerate() {
            let q = c.forward(b.f.clone(), b.a.clone());
            if i == 0 {
                mean_q = scalar(q.clone().detach().mean())?;
            }
            let l = (q - y.clone()).powi_scalar(2).mean();
            loss = Some(match loss {
                Some(acc) => acc + l,
                None => l,
            });
        }
        let Some(loss) = loss else {
            return Ok(UpdateStats::default());
        };
        let critic_loss = scalar(loss.clone().detach())?;
        if !critic_loss.is_finite() {
            return Err(TrainError::Backend(format!(
                "critic loss became {critic_loss}; lower --critic-lr"
            )));
        }
        let mut grads = loss.backward();
        let mut new_critics = Vec::with_capacity(self.critics.len());
        for (c, opt) in self.critics.drain(..).zip(self.critic_opts.iter_mut()) {
            let g = GradientsParams::from_module(&mut grads, &c);
            new_critics.push(opt.step(self.cfg.critic_lr, c, g));
        }
        self.critics = new_critics;
        self.updates += 1;

        if train_actor {
            self.acting_updates += 1;
        }
        let mut actor_loss = None;
        if train_actor && self.updates % self.cfg.policy_delay.max(1) as u64 == 0 {
            actor_loss = Some(self.update_actor(&b)?);
            self.actor_target = polyak(self.actor_target.clone(), &self.actor, self.cfg.tau);
        }
        for (t, o) in self.critic_targets.iter_mut().zip(&self.critics) {
            *t = polyak(t.clone(), o, self.cfg.tau);
        }
        Ok(UpdateStats {
            critic_loss,
            actor_loss,
            mean_q,
        })
    }

    /// The search's targets (see [`AgentConfig::search_step`]): per sample, the best-rated
    /// of the actor's action and its 14 neighbours, clamped to the bounds (a tie keeps the
    /// actor's own).
    fn searched_actions(&self, f: &Tensor<2>, a_pi: &Tensor<2>) -> Result<Tensor<2>, TrainError> {
        let [n, _] = a_pi.dims();
        let h = self.cfg.search_step;
        let mut deltas = vec![[0.0f32, 0.0]];
        for ds in [-1.0f32, 0.0, 1.0] {
            for dt in [-2.0f32, -1.0, 0.0, 1.0, 2.0] {
                if ds != 0.0 || dt != 0.0 {
                    deltas.push([ds * h / 2.0, dt * h]);
                }
            }
        }
        let k = deltas.len();
        let now = read(a_pi.clone().detach())?;
        let mut candidates = Vec::with_capacity(k * n * 2);
        for d in &deltas {
            for i in 0..n {
                let a = super::clamp_action([now[2 * i] + d[0], now[2 * i + 1] + d[1]], &self.cfg);
                candidates.extend_from_slice(&a);
            }
        }
        let fk = f.clone().detach().repeat_dim(0, k);
        let ak =
            Tensor::<2>::from_data(TensorData::new(candidates.clone(), [k * n, 2]), &f.device());
        let mut q: Option<Tensor<2>> = None;
        for c in &self.critics {
            let qi = c.forward(fk.clone(), ak.clone()).detach();
            q = Some(match q {
                Some(acc) => acc.min_pair(qi),
                None => qi,
            });
        }
        let q = match q {
            Some(q) => read(q)?,
            None => return Ok(a_pi.clone().detach()),
        };
        let mut target = Vec::with_capacity(2 * n);
        for i in 0..n {
            let mut best = 0;
            for j in 1..k {
                if q[j * n + i] > q[best * n + i] {
                    best = j;
                }
            }
            target.extend_from_slice(&candidates[2 * (best * n + i)..2 * (best * n + i) + 2]);
        }
        Ok(Tensor::<2>::from_data(
            TensorData::new(target, [n, 2]),
            &a_pi.device(),
        ))
    }

    /// The anchor's weight now: `anchor_weight`, falling linearly to 0 over
    /// `anchor_decay_updates` updates after the warm-up when that is set.
    pub fn anchor_weight(&self) -> f32 {
        let w = self.cfg.anchor_weight;
        match self.cfg.anchor_decay_updates {
            0 => w,
            n => w * (1.0 - self.acting_updates as f32 / n as f32).max(0.0),
        }
    }

    fn update_actor(&mut self, b: &BatchTensors) -> Result<f64, TrainError> {
        let critic = &self.critics[0];
        let a_pi = self.actor.forward(b.f.clone());
        let q_pi = critic.forward(b.f.clone(), a_pi.clone());
        let mut loss = if self.cfg.search_step > 0.0 {
            let target = self.searched_actions(&b.f, &a_pi)?;
            (a_pi.clone() - target).powi_scalar(2).sum_dim(1).mean()
        } else {
            let scale = scalar(q_pi.clone().detach().abs().mean())?.max(1e-3);
            q_pi.clone().mean().mul_scalar(-1.0 / scale)
        };

        if self.cfg.bc_weight > 0.0 && b.n_demo > 0 {
            let mut mask = b.demo.clone();
            if self.cfg.q_filter {
                let q_demo = critic.forward(b.f.clone(), b.a.clone()).detach();
                let better = q_demo.greater(q_pi.clone().detach()).float();
                mask = mask * better;
            }
            let sq = (a_pi.clone() - b.a.clone()).powi_scalar(2).sum_dim(1); // [B,1]
            let bc = (sq * mask).sum().div_scalar(b.n_demo as f32);
            loss = loss + bc.mul_scalar(self.cfg.bc_weight);
        }
        let anchor_weight = self.anchor_weight();
        if anchor_weight > 0.0 {
            let f_plain = Tensor::<2>::from_data(b.f.clone().into_data(), &self.inner);
            let a0 = self.anchor.forward(f_plain);
            let a0 = Tensor::<2>::from_data(a0.into_data(), &self.device);
            let drift = (a_pi.clone() - a0).powi_scalar(2).sum_dim(1).mean();
            loss = loss + drift.mul_scalar(anchor_weight);
        }
        // Keep the outputs inside the action range.
        let [n, _] = a_pi.dims();
        let mid: Vec<f32> = (0..2)
            .map(|i| (self.cfg.low[i] + self.cfg.high[i]) / 2.0)
            .collect();
        let half: Vec<f32> = (0..2)
            .map(|i| (self.cfg.high[i] - self.cfg.low[i]) / 2.0)
            .collect();
        let mid = Tensor::<2>::from_data(TensorData::new(mid, [1, 2]), &self.device).expand([n, 2]);
        let half =
            Tensor::<2>::from_data(TensorData::new(half, [1, 2]), &self.device).expand([n, 2]);
        let out_of_range = relu((a_pi - mid).abs() - half).powi_scalar(2).mean();
        loss = loss + out_of_range;

        let value = scalar(loss.clone().detach())?;
        let grads = GradientsParams::from_grads(loss.backward(), &self.actor);
        self.actor = self
            .actor_opt
            .step(self.cfg.actor_lr, self.actor.clone(), grads);
        Ok(value)
    }
}

fn scalar(t: Tensor<1>) -> Result<f64, TrainError> {
    read(t)?
        .first()
        .map(|v| f64::from(*v))
        .ok_or_else(|| TrainError::Backend("empty tensor".into()))
}

#[cfg(test)]
mod tests {
    use super::super::replay::Transition;
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// ResNet-18's feature width.
    const FEATURES: usize = 512;

    fn head() -> Head {
        Head {
            weight: vec![0.0; 2 * FEATURES],
            bias: [0.5, 0.0],
        }
    }

    /// A one-state bandit: feature 1.0 in slot 0; reward = 1 - (steering - 0.3)^2, terminal.
    fn bandit(rng: &mut ChaCha8Rng) -> Replay {
        let mut r = Replay::new(10_000);
        let mut f = vec![0.0; FEATURES];
        f[0] = 1.0;
        for _ in 0..2000 {
            let a = [rng.random_range(0.0..1.0), rng.random_range(-1.0..1.0)];
            r.push(Transition {
                features: f.clone(),
                action: a,
                reward: 1.0 - (a[1] - 0.3f32).powi(2),
                next_features: f.clone(),
                discount: 0.0,
                demo: false,
            });
        }
        r
    }

    #[test]
    fn learns_the_best_action_of_a_bandit() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let replay = bandit(&mut rng);
        let cfg = AgentConfig {
            batch: 64,
            hidden: 32,
            actor_lr: 3e-3,
            bc_weight: 0.0,
            anchor_weight: 0.0,
            policy_delay: 1,
            ..AgentConfig::default()
        };
        let mut agent = Agent::new(cfg, &head(), 0, &Device::flex());
        for i in 0..600 {
            agent.update(&replay, i >= 200, &mut rng).unwrap();
        }
        let mut f = vec![0.0; FEATURES];
        f[0] = 1.0;
        let a = agent.head().unwrap().apply(&f);
        assert!((a[1] - 0.3).abs() < 0.15, "steering {a:?}");
    }

    #[test]
    fn policy_improvement_by_search_finds_the_best_action_of_a_bandit() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let replay = bandit(&mut rng);
        let cfg = AgentConfig {
            batch: 64,
            hidden: 32,
            actor_lr: 3e-3,
            bc_weight: 0.0,
            search_step: 0.1,
            policy_delay: 1,
            ..AgentConfig::default()
        };
        let mut agent = Agent::new(cfg, &head(), 0, &Device::flex());
        for i in 0..1200 {
            agent.update(&replay, i >= 300, &mut rng).unwrap();
        }
        let mut f = vec![0.0; FEATURES];
        f[0] = 1.0;
        let a = agent.head().unwrap().apply(&f);
        assert!((a[1] - 0.3).abs() < 0.1, "steering {a:?}");
    }

    /// A strong anchor holds the actor at the initial steering 0 on the bandit; decayed over
    /// 200 updates it lets go, and the actor finds the best steering 0.3.
    #[test]
    fn a_decaying_anchor_lets_the_critic_decide() {
        let run = |decay: u64| {
            let mut rng = ChaCha8Rng::seed_from_u64(1);
            let replay = bandit(&mut rng);
            let cfg = AgentConfig {
                batch: 64,
                hidden: 32,
                actor_lr: 3e-3,
                bc_weight: 0.0,
                anchor_weight: 50.0,
                anchor_decay_updates: decay,
                policy_delay: 1,
                ..AgentConfig::default()
            };
            let mut agent = Agent::new(cfg, &head(), 0, &Device::flex());
            for i in 0..600 {
                agent.update(&replay, i >= 200, &mut rng).unwrap();
            }
            let mut f = vec![0.0; FEATURES];
            f[0] = 1.0;
            (agent.head().unwrap().apply(&f)[1], agent.anchor_weight())
        };
        let (held, w) = run(0);
        assert!(held.abs() < 0.05, "steering {held}");
        assert_eq!(w, 50.0);
        let (free, w) = run(200);
        assert!((free - 0.3).abs() < 0.15, "steering {free}");
        assert_eq!(w, 0.0);
    }

    #[test]
    fn the_q_filtered_bc_loss_pulls_towards_demonstrations() {
        // Only demonstrations, all with steering -0.5 and the best reward: with BC the actor
        // moves there from 0.
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut replay = bandit(&mut rng);
        let mut f = vec![0.0; FEATURES];
        f[0] = 1.0;
        for _ in 0..500 {
            replay.push(Transition {
                features: f.clone(),
                action: [0.5, -0.5],
                reward: 1.0,
                next_features: f.clone(),
                discount: 0.0,
                demo: true,
            });
        }
        let cfg = AgentConfig {
            batch: 64,
            hidden: 32,
            actor_lr: 3e-3,
            bc_weight: 5.0,
            q_filter: false,
            policy_delay: 1,
            ..AgentConfig::default()
        };
        let mut agent = Agent::new(cfg, &head(), 0, &Device::flex());
        for _ in 0..300 {
            agent.update(&replay, true, &mut rng).unwrap();
        }
        let a = agent.head().unwrap().apply(&f);
        assert!(a[1] < -0.2, "steering {a:?}");
    }

    #[test]
    fn a_trainable_update_moves_the_trunks_but_not_the_batch_norm_statistics() {
        let weights = Resnet18Weights::random(2, 3);
        let cfg = AgentConfig {
            batch: 4,
            hidden: 16,
            actor_lr: 1e-3,
            policy_delay: 1,
            ..AgentConfig::default()
        };
        let mut agent = Agent::trainable(cfg, &weights, 0, &Device::flex()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let px = 3 * 32 * 32;
        let mut replay = Replay::new(16);
        for i in 0..8 {
            replay.push(Transition {
                features: (0..px).map(|_| rng.random_range(-2.0..2.0)).collect(),
                action: [0.5, 0.1 * i as f32 - 0.4],
                reward: 1.0,
                next_features: (0..px).map(|_| rng.random_range(-2.0..2.0)).collect(),
                discount: 0.9,
                demo: i % 2 == 0,
            });
        }
        let stats = agent.update(&replay, true, &mut rng).unwrap();
        assert!(stats.actor_loss.is_some() && stats.critic_loss.is_finite());
        let after = agent
            .actor_weights(&NetWeights::Resnet18(weights.clone()))
            .unwrap();
        let changed = |name: &str| after.tensors()[name].1 != weights.tensors[name].1;
        assert!(changed("conv1.weight"), "actor trunk did not train");
        assert!(changed("layer4.1.conv2.weight"));
        assert!(changed("fc.weight"));
        assert!(!changed("bn1.running_mean") && !changed("layer3.0.bn1.running_var"));
        let critic_trunk = agent.critics[0]
            .trunk
            .as_ref()
            .unwrap()
            .to_weights()
            .unwrap();
        assert_ne!(
            critic_trunk.tensors["conv1.weight"].1,
            weights.tensors["conv1.weight"].1
        );
    }
}
