//! DDPG fine-tuning in the simulator, bootstrapped as in the paper: owns the training loop
//! of `jetpilot train ddpg`.
//!
//! ```text
//! actor  <- the imitation policy (--init: ResNet-18 or EfficientNet-Lite0), or a random
//!           ResNet-18 (from scratch)
//! replay <- the demonstrations with their rewards, kept for good (DDPGfD)
//! critic warm-up: `warmup_updates` critic-only updates on the demonstrations
//! evaluate (the 600 s protocol) -> best.onnx
//! repeat until the wall-clock budget or the episode limit:
//!     one episode: frame -> frozen backbone -> actor + exploration noise -> Env::step,
//!                  n-step transitions into the replay; leaving the road ends it
//!     updates between episodes: updates_per_step x the episode's steps
//!     every `eval_every` episodes: evaluate (on `select_cfg`'s world as written where
//!     given, random layouts too; else on the track, never a random layout); a
//!     higher autonomy (then more rewards) replaces best.onnx, unless it earns under half
//!     the start's rewards (it stopped)
//! ```
//!
//! The backbone is frozen by default (the CPU choice): features are computed once per frame
//! on ONNX Runtime, the replay holds them, and only the actor's `fc` and the critics train
//! (512 features for ResNet-18, 1280 for EfficientNet-Lite0, whose head is `_fc`).
//! With `train_backbone` (ResNet-18 only) the replay holds the preprocessed frames instead, the actor and
//! each critic train a ResNet-18 of their own (initialised from the actor), and the ONNX
//! Runtime session that acts is rebuilt from the actor after each round of updates (the
//! actor does not change during an episode). Files in the output folder:
//! `ddpg_episodes.csv`, `ddpg_eval.csv`, `ddpg_curve.png`, `best.onnx`, `last.onnx`.

pub mod agent;
pub mod demos;
pub mod eval;
pub mod features;
pub mod nets;
pub mod noise;
pub mod replay;

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use self::agent::{Agent, AgentConfig};
use self::eval::{EvalOutcome, evaluate, improves_on, test_world};
use self::features::{Backbone, FeatureActor, Head};
use self::noise::{Noise, NoiseKind};
use self::replay::{NStep, Replay, Step};
use super::curve::{CsvLog, Series, plot_png, read_csv};
use super::data::LabelMap;
use super::export::write_net_weights;
use super::{TrainDevice, TrainError, read_onnx};
use crate::config::Config;
use crate::policy::onnx::{Arch, NetWeights};
use crate::policy::{ModelContract, OutputKind, Preprocessor};
use crate::sim::env::Env;

/// Settings of one DDPG run.
#[derive(Debug, Clone)]
pub struct DdpgOptions {
    pub out: PathBuf,
    /// The simulator config (`[sim]`, `[control]` gains, `[model]` contract defaults).
    pub cfg: Config,
    /// Where the evaluations run, and so where `best.onnx` is chosen (default: `cfg`): a
    /// world held out from training, e.g. a middle part of a recording, so that the pick is
    /// not a selection among noisy evaluations of the world the actor fits.
    pub select_cfg: Option<Config>,
    /// The network's input size when starting from scratch (an `--init` model keeps its own).
    pub input_size: u32,
    pub init: Option<PathBuf>,
    pub demos: Vec<PathBuf>,
    pub seed: u64,
    /// Wall-clock budget in seconds (evaluations included).
    pub budget_s: f64,
    pub max_episodes: usize,
    /// Steps per training episode (then it is cut).
    pub episode_steps: u64,
    pub agent: AgentConfig,
    pub n_step: usize,
    pub noise: NoiseKind,
    /// Exploration sigma per action component `[speed, steering]`.
    pub sigma: [f32; 2],
    pub updates_per_step: f32,
    pub warmup_updates: usize,
    pub replay_capacity: usize,
    pub eval_every: usize,
    pub eval_seconds: f64,
    /// Stop once an evaluation has no intervention.
    pub stop_at_full_autonomy: bool,
    pub ort_threads: usize,
    /// Train the ResNet-18 trunks too (see the module doc); much slower on a CPU.
    pub train_backbone: bool,
    /// Where the actor and critics train (see [`TrainDevice`]).
    pub device: TrainDevice,
    /// Share of the training episodes that start shortly before a place where an earlier
    /// episode left the road (see [`Failures`]); 0: always a random place.
    pub failure_resets: f32,
}

impl DdpgOptions {
    pub fn new(out: PathBuf, cfg: Config) -> Self {
        Self {
            out,
            input_size: 96,
            cfg,
            select_cfg: None,
            init: None,
            demos: Vec::new(),
            seed: 0,
            budget_s: 1800.0,
            max_episodes: usize::MAX,
            episode_steps: 900,
            agent: AgentConfig::default(),
            n_step: 3,
            noise: NoiseKind::Gaussian,
            sigma: [0.1, 0.1],
            updates_per_step: 0.5,
            warmup_updates: 1000,
            replay_capacity: 100_000,
            eval_every: 10,
            eval_seconds: 600.0,
            stop_at_full_autonomy: false,
            ort_threads: 2,
            train_backbone: false,
            device: TrainDevice::Flex,
            failure_resets: 0.0,
        }
    }
}

/// One training episode's numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeStats {
    pub episode: usize,
    pub steps: u64,
    pub ret: f64,
    pub rewards: u64,
    pub interventions: u32,
    pub env_seconds: f64,
    pub update_seconds: f64,
    pub critic_loss: f64,
    pub mean_q: f64,
}

/// One evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalPoint {
    pub episode: usize,
    pub env_steps: u64,
    pub wall_s: f64,
    pub outcome: EvalOutcome,
}

/// What a run reached.
#[derive(Debug, Clone, PartialEq)]
pub struct DdpgReport {
    pub episodes: usize,
    pub env_steps: u64,
    pub updates: u64,
    pub wall_s: f64,
    /// Environment steps per second of training time (episodes + updates, evaluations not
    /// counted).
    pub steps_per_s: f64,
    pub evals: Vec<EvalPoint>,
    pub best: Option<EvalPoint>,
    pub best_path: PathBuf,
    pub demo_transitions: usize,
    pub plot_warning: Option<String>,
}

pub const EPISODE_HEADER: [&str; 9] = [
    "episode",
    "steps",
    "return",
    "rewards",
    "interventions",
    "env_seconds",
    "update_seconds",
    "critic_loss",
    "mean_q",
];
pub const EVAL_HEADER: [&str; 8] = [
    "episode",
    "env_steps",
    "wall_s",
    "interventions",
    "autonomy_percent",
    "rewards",
    "mean_reward",
    "laps",
];

pub fn best_path(out: &Path) -> PathBuf {
    out.join("best.onnx")
}
pub fn episodes_csv(out: &Path) -> PathBuf {
    out.join("ddpg_episodes.csv")
}
pub fn eval_csv(out: &Path) -> PathBuf {
    out.join("ddpg_eval.csv")
}
pub fn png_path(out: &Path) -> PathBuf {
    out.join("ddpg_curve.png")
}

/// The starting weights and contract.
fn initial(opts: &DdpgOptions) -> Result<(NetWeights, ModelContract), TrainError> {
    match &opts.init {
        Some(path) => {
            let (weights, contract) = read_onnx(path)?;
            if contract.output != OutputKind::SpeedSteering {
                return Err(TrainError::Data {
                    path: path.display().to_string(),
                    reason: format!(
                        "DDPG's actions are (speed, steering); this model outputs {} (train it with --head speed-steering)",
                        contract.output.as_str()
                    ),
                });
            }
            if opts.train_backbone && weights.arch() != Arch::Resnet18 {
                return Err(TrainError::Data {
                    path: path.display().to_string(),
                    reason: format!(
                        "a {} model; a backbone that trains (--train-backbone) is ResNet-18 only so far: leave the option out to train the head on frozen features",
                        weights.arch().title()
                    ),
                });
            }
            Ok((weights, contract))
        }
        None => {
            let mut contract = opts.cfg.model.fallback_contract();
            contract.input_size = opts.input_size;
            contract.output = OutputKind::SpeedSteering;
            Ok((NetWeights::random(Arch::Resnet18, 2, opts.seed), contract))
        }
    }
}

/// `a` clamped to the agent's bounds.
fn clamp_action(a: [f32; 2], cfg: &AgentConfig) -> [f32; 2] {
    [
        a[0].clamp(cfg.low[0], cfg.high[0]),
        a[1].clamp(cfg.low[1], cfg.high[1]),
    ]
}

/// Where earlier training episodes left the road, for resets before them (a curriculum
/// that practises the hard places): a ring of the latest failures' progress along the track.
struct Failures {
    at: Vec<f32>,
    next: usize,
}

impl Failures {
    const KEEP: usize = 32;
    /// How far before a failure an episode starts, metres along the track.
    const BEFORE_M: std::ops::Range<f32> = 0.3..1.5;

    fn new() -> Self {
        Self {
            at: Vec::new(),
            next: 0,
        }
    }

    fn push(&mut self, s: f32) {
        if self.at.len() < Self::KEEP {
            self.at.push(s);
        } else {
            self.at[self.next] = s;
        }
        self.next = (self.next + 1) % Self::KEEP;
    }

    /// A start (progress, metres) before a random remembered failure with probability
    /// `share`; `None`: a random place. `length` wraps it onto the lap (on an open road,
    /// `closed` false, it stops at the road's start).
    fn start(
        &self,
        share: f32,
        length: f32,
        closed: bool,
        rng: &mut impl rand::Rng,
    ) -> Option<f32> {
        if self.at.is_empty() || share <= 0.0 || rng.random::<f32>() >= share {
            return None;
        }
        let s = self.at[rng.random_range(0..self.at.len())];
        let s = s - rng.random_range(Self::BEFORE_M);
        Some(if closed {
            s.rem_euclid(length.max(1e-3))
        } else {
            s.max(0.0)
        })
    }
}

/// What the replay buffer holds as a state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// The frozen backbone's features (512 for ResNet-18, 1280 for Lite0).
    Features,
    /// The preprocessed frame (`3*S*S` values), for a backbone that trains.
    Frames,
}

impl State {
    fn of(self, input: &[f32], features: &[f32]) -> Vec<f32> {
        match self {
            Self::Features => features.to_vec(),
            Self::Frames => input.to_vec(),
        }
    }
}

/// The evaluations of one run: the log, the best so far and its export.
struct Evaluations<'a, F> {
    opts: &'a DdpgOptions,
    /// Where the tests drive ([`eval::test_world`]).
    world: Config,
    contract: &'a ModelContract,
    started: Instant,
    log: CsvLog,
    points: Vec<EvalPoint>,
    best: Option<EvalPoint>,
    on_eval: F,
}

/// The actor as it acts: the ONNX Runtime backbone, the linear head, and the weights the
/// two make up together (for export).
struct Acting {
    backbone: Backbone,
    head: Head,
    weights: NetWeights,
}

impl Acting {
    fn new(
        weights: NetWeights,
        contract: &ModelContract,
        threads: usize,
    ) -> Result<Self, TrainError> {
        Ok(Self {
            backbone: Backbone::new(&weights, contract, threads)?,
            head: Head::from_weights(&weights)?,
            weights,
        })
    }
}

impl<F: FnMut(&EvalPoint, bool)> Evaluations<'_, F> {
    /// The paper's protocol on `actor`; a new best is exported. True when the run should
    /// stop (full autonomy reached and asked to stop there).
    fn run(
        &mut self,
        episode: usize,
        env_steps: u64,
        actor: &mut Acting,
    ) -> Result<bool, TrainError> {
        let mut policy = FeatureActor::new(&mut actor.backbone, &actor.head, self.contract);
        let outcome = evaluate(&self.world, &mut policy, self.opts.eval_seconds)?;
        let point = EvalPoint {
            episode,
            env_steps,
            wall_s: self.started.elapsed().as_secs_f64(),
            outcome,
        };
        self.log.row(&[
            episode as f64,
            env_steps as f64,
            point.wall_s,
            f64::from(outcome.interventions),
            f64::from(outcome.autonomy_percent),
            outcome.rewards as f64,
            outcome.mean_reward,
            outcome.laps,
        ])?;
        let better = improves_on(
            outcome.score(),
            self.best.map(|b| b.outcome.score()),
            self.points.first().map(|p| p.outcome.score()),
        );
        if better {
            write_net_weights(&actor.weights, self.contract, &best_path(&self.opts.out))?;
            self.best = Some(point);
        }
        self.points.push(point);
        (self.on_eval)(&point, better);
        // Only a policy that drives (and so became best.onnx) ends the run at full autonomy.
        Ok(self.opts.stop_at_full_autonomy && outcome.interventions == 0 && better)
    }
}

/// Runs DDPG; `on_episode` and `on_eval` see progress as it happens.
pub fn train(
    opts: &DdpgOptions,
    mut on_episode: impl FnMut(&EpisodeStats),
    on_eval: impl FnMut(&EvalPoint, bool),
) -> Result<DdpgReport, TrainError> {
    let started = Instant::now();
    let device = opts.device.open()?;
    std::fs::create_dir_all(&opts.out).map_err(|e| TrainError::Data {
        path: opts.out.display().to_string(),
        reason: e.to_string(),
    })?;
    let (base, contract) = initial(opts)?;
    let state = if opts.train_backbone {
        State::Frames
    } else {
        State::Features
    };
    let mut actor = Acting::new(base, &contract, opts.ort_threads)?;
    let mut cfg = opts.cfg.clone();
    cfg.sim.seed = opts.seed;
    let labels = LabelMap::new(OutputKind::SpeedSteering, &cfg.control.gains());
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);

    let mut replay = Replay::new(opts.replay_capacity);
    let demo = demos::load(
        &opts.demos,
        &mut actor.backbone,
        state,
        &contract,
        &labels,
        opts.n_step,
        opts.agent.gamma,
    );
    let demo_transitions = match demo {
        Ok(ts) => {
            let n = ts.len();
            for t in ts {
                replay.push(t);
            }
            n
        }
        Err(e) if opts.demos.is_empty() => {
            tracing::debug!("no demonstrations: {e}");
            0
        }
        Err(e) => return Err(e),
    };

    let mut agent = match state {
        State::Features => Agent::new(opts.agent.clone(), &actor.head, opts.seed, &device),
        State::Frames => match &actor.weights {
            NetWeights::Resnet18(w) => Agent::trainable(opts.agent.clone(), w, opts.seed, &device)?,
            other => {
                return Err(TrainError::Backend(format!(
                    "a backbone that trains is ResNet-18 only so far, not {}",
                    other.arch().title()
                )));
            }
        },
    };
    // Critic warm-up on the demonstrations: the actor stays the imitation policy.
    if !replay.is_empty() {
        for _ in 0..opts.warmup_updates {
            agent.update(&replay, false, &mut rng)?;
        }
    }

    let mut episodes_log = CsvLog::open(&episodes_csv(&opts.out), &EPISODE_HEADER, false)?;
    let mut evals = Evaluations {
        opts,
        world: test_world(&opts.cfg, opts.select_cfg.as_ref()),
        contract: &contract,
        started,
        log: CsvLog::open(&eval_csv(&opts.out), &EVAL_HEADER, false)?,
        points: Vec::new(),
        best: None,
        on_eval,
    };
    let mut env =
        Env::new(&cfg, opts.episode_steps).map_err(|e| TrainError::Backend(e.to_string()))?;
    let (w, h) = (cfg.sim.camera.width, cfg.sim.camera.height);
    let mut pre = Preprocessor::new(&contract);
    let mut noise = Noise::new(
        opts.noise,
        opts.sigma,
        0.15 * cfg.sim.control_hz,
        1.0 / cfg.sim.control_hz,
    );
    let count_threshold = cfg.sim.reward.count_threshold;
    let sim_err = |e: crate::sim::SimError| TrainError::Backend(e.to_string());

    let mut env_steps = 0u64;
    let mut updates = 0u64;
    let mut train_seconds = 0.0f64;
    let mut episode = 0usize;
    let mut done_early = evals.run(0, 0, &mut actor)?;
    let mut features = vec![0.0f32; actor.backbone.width()];
    let mut failures = Failures::new();
    let track_length = env.world().track.length();
    let track_closed = env.world().track.is_closed();

    while !done_early
        && episode < opts.max_episodes
        && started.elapsed().as_secs_f64() < opts.budget_s
    {
        episode += 1;
        let t0 = Instant::now();
        let input = pre
            .run(
                w,
                h,
                env.reset(failures.start(
                    opts.failure_resets,
                    track_length,
                    track_closed,
                    &mut rng,
                ))
                .map_err(sim_err)?,
            )
            .map_err(|e| TrainError::Backend(e.to_string()))?;
        actor.backbone.features(input, &mut features)?;
        let mut current = state.of(input, &features);
        noise.reset();
        let mut nstep = NStep::new(opts.n_step, opts.agent.gamma);
        let mut stats = EpisodeStats {
            episode,
            steps: 0,
            ret: 0.0,
            rewards: 0,
            interventions: 0,
            env_seconds: 0.0,
            update_seconds: 0.0,
            critic_loss: f64::NAN,
            mean_q: f64::NAN,
        };
        loop {
            let a = actor.head.apply(&features);
            let n = noise.sample(&mut rng);
            let action = clamp_action([a[0] + n[0], a[1] + n[1]], &opts.agent);
            let o = env.step(action).map_err(sim_err)?;
            let input = pre
                .run(w, h, env.observation())
                .map_err(|e| TrainError::Backend(e.to_string()))?;
            actor.backbone.features(input, &mut features)?;
            let next = state.of(input, &features);
            stats.steps += 1;
            stats.ret += f64::from(o.reward);
            if o.reward >= count_threshold {
                stats.rewards += 1;
            }
            let step = Step {
                features: std::mem::take(&mut current),
                action,
                reward: o.reward,
            };
            if let Some(t) = nstep.push(step, &next, false) {
                replay.push(t);
            }
            current = next;
            if o.done || o.truncated {
                if o.done {
                    stats.interventions = 1;
                    failures.push(env.world().track.query(o.pose.x, o.pose.y).s);
                }
                for t in nstep.finish(&current, o.done, false) {
                    replay.push(t);
                }
                break;
            }
        }
        env_steps += stats.steps;
        stats.env_seconds = t0.elapsed().as_secs_f64();

        // Updates between episodes; the acting copy of the actor follows after them.
        let t1 = Instant::now();
        let n_updates = (stats.steps as f32 * opts.updates_per_step).round() as usize;
        let (mut closs, mut q, mut counted) = (0.0, 0.0, 0usize);
        if replay.len() >= opts.agent.batch {
            for _ in 0..n_updates {
                let u = agent.update(&replay, true, &mut rng)?;
                closs += u.critic_loss;
                q += u.mean_q;
                counted += 1;
            }
            updates += counted as u64;
            match state {
                State::Features => {
                    actor.head = agent.head()?;
                    actor.weights = actor.head.into_weights(&actor.weights);
                }
                State::Frames => {
                    actor = Acting::new(
                        agent.actor_weights(&actor.weights)?,
                        &contract,
                        opts.ort_threads,
                    )?;
                }
            }
        }
        if counted > 0 {
            stats.critic_loss = closs / counted as f64;
            stats.mean_q = q / counted as f64;
        }
        stats.update_seconds = t1.elapsed().as_secs_f64();
        train_seconds += t0.elapsed().as_secs_f64();
        episodes_log.row(&[
            episode as f64,
            stats.steps as f64,
            stats.ret,
            stats.rewards as f64,
            f64::from(stats.interventions),
            stats.env_seconds,
            stats.update_seconds,
            stats.critic_loss,
            stats.mean_q,
        ])?;
        on_episode(&stats);

        if opts.eval_every > 0 && episode % opts.eval_every == 0 {
            done_early = evals.run(episode, env_steps, &mut actor)?;
        }
    }
    // The last policy, and a final evaluation when the last episodes were not evaluated.
    write_net_weights(&actor.weights, &contract, &opts.out.join("last.onnx"))?;
    if !done_early && episode > 0 && (opts.eval_every == 0 || episode % opts.eval_every != 0) {
        evals.run(episode, env_steps, &mut actor)?;
    }
    let eval_world = opts.select_cfg.as_ref().unwrap_or(&opts.cfg);
    let plot_warning = plot_curve(
        &opts.out,
        (opts.eval_seconds * f64::from(eval_world.sim.control_hz)).round(),
    )?;
    Ok(DdpgReport {
        episodes: episode,
        env_steps,
        updates,
        wall_s: started.elapsed().as_secs_f64(),
        steps_per_s: env_steps as f64 / train_seconds.max(1e-9),
        evals: evals.points,
        best: evals.best,
        best_path: best_path(&opts.out),
        demo_transitions,
        plot_warning,
    })
}

/// `ddpg_curve.png`: each evaluation's autonomy value and the share of its control steps
/// that earned a reward (the paper's reward count over the test's `steps_per_test`), both in
/// percent, against environment steps.
fn plot_curve(out: &Path, steps_per_test: f64) -> Result<Option<String>, TrainError> {
    let (_, rows) = read_csv(&eval_csv(out))?;
    let autonomy = Series {
        name: "autonomy %".into(),
        points: rows.iter().map(|r| (r[1], r[4])).collect(),
    };
    let rewards = Series {
        name: "steps with a reward %".into(),
        points: rows
            .iter()
            .map(|r| (r[1], 100.0 * r[5] / steps_per_test.max(1.0)))
            .collect(),
    };
    Ok(plot_png(
        &png_path(out),
        "DDPG evaluations",
        "environment steps",
        "percent",
        &[autonomy, rewards],
        false,
        (800, 500),
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failure_resets_start_before_remembered_failures() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut f = Failures::new();
        assert_eq!(
            f.start(1.0, 6.0, true, &mut rng),
            None,
            "nothing remembered yet"
        );
        f.push(0.5);
        for _ in 0..200 {
            let s = f.start(1.0, 6.0, true, &mut rng).unwrap();
            // 0.3..1.5 m before 0.5, wrapped onto the 6 m lap: 5.0..6.0 or 0.0..0.2.
            assert!((5.0..6.0).contains(&s) || (0.0..=0.2).contains(&s), "{s}");
        }
        assert_eq!(f.start(0.0, 6.0, true, &mut rng), None);
        let share = (0..2000)
            .filter(|_| f.start(0.25, 6.0, true, &mut rng).is_some())
            .count();
        assert!((400..600).contains(&share), "{share}");
        // The ring keeps the latest KEEP failures.
        for i in 0..100 {
            f.push(i as f32);
        }
        assert_eq!(f.at.len(), Failures::KEEP);
        assert!(!f.at.contains(&0.5));
    }
}
