//! `jetpilot train ddpg`: DDPG fine-tuning in the simulator from the imitation policy and
//! the demonstrations.

use std::path::PathBuf;
use std::process::ExitCode;

use jetpilot::train::ddpg::noise::NoiseKind;
use jetpilot::train::ddpg::{self, DdpgOptions};

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Noise {
    Gaussian,
    Ou,
}

#[derive(Debug, clap::Args)]
pub struct DdpgArgs {
    /// Simulator config (`[sim]`, the steering gains; see config/sim.toml).
    #[arg(long, value_name = "FILE")]
    sim: PathBuf,
    /// Output folder (created): best.onnx, last.onnx, ddpg_episodes.csv, ddpg_eval.csv,
    /// ddpg_curve.png.
    #[arg(short, long, value_name = "DIR")]
    out: PathBuf,
    /// The imitation policy to start from (a speed_steering ResNet-18 or EfficientNet-Lite0,
    /// e.g. from `train il`); without it the actor starts a random ResNet-18 (DDPG from
    /// scratch).
    #[arg(long, value_name = "FILE")]
    init: Option<PathBuf>,
    /// Demonstration tubs whose transitions and rewards stay in the replay buffer for good.
    #[arg(long, value_name = "DIR")]
    demos: Vec<PathBuf>,
    /// Input size when starting from scratch (an --init model keeps its own).
    #[arg(long, default_value_t = 96, value_parser = clap::value_parser!(u32).range(32..=1024))]
    input_size: u32,
    /// Wall-clock budget in minutes, evaluations included.
    #[arg(long, default_value_t = 30.0)]
    minutes: f64,
    /// Stop after this many training episodes.
    #[arg(long)]
    episodes: Option<usize>,
    /// Control steps per training episode before it is cut (30 per simulated second).
    #[arg(long, default_value_t = 900)]
    episode_steps: u64,
    /// Evaluate every this many episodes (0: only at the start and the end).
    #[arg(long, default_value_t = 10)]
    eval_every: usize,
    /// Simulated seconds per evaluation (the paper: 600).
    #[arg(long, default_value_t = 600.0)]
    eval_seconds: f64,
    /// Run the evaluations, and so choose best.onnx, in this simulator config's world instead
    /// of --sim's: a world held out from training (scripts/real-replay.sh passes a middle
    /// part of the recording, or a config whose `[sim.layouts]` is on with another `seed`:
    /// roads none of the training episodes drove). Taken as written: --track,
    /// --random-layouts and the other world flags change the training world only. Its
    /// `[model]` and `[control]` should match --sim's.
    #[arg(long, value_name = "FILE")]
    select_sim: Option<PathBuf>,
    /// Stop as soon as an evaluation has no intervention.
    #[arg(long)]
    stop_at_full_autonomy: bool,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long, value_enum, default_value = "gaussian")]
    noise: Noise,
    /// Exploration noise on the speed output.
    #[arg(long, default_value_t = 0.1)]
    sigma_speed: f32,
    /// Exploration noise on the steering output.
    #[arg(long, default_value_t = 0.1)]
    sigma_steering: f32,
    /// n-step returns.
    #[arg(long, default_value_t = 3)]
    n_step: usize,
    #[arg(long, default_value_t = 0.98)]
    gamma: f32,
    #[arg(long, default_value_t = 1e-5)]
    actor_lr: f64,
    #[arg(long, default_value_t = 1e-3)]
    critic_lr: f64,
    #[arg(long, default_value_t = 128)]
    batch: usize,
    /// Gradient updates per environment step, run between episodes.
    #[arg(long, default_value_t = 0.5)]
    updates_per_step: f32,
    /// Critic-only updates on the demonstrations before the first episode.
    #[arg(long, default_value_t = 1000)]
    warmup_updates: usize,
    /// Weight of the Q-filtered behaviour-cloning loss on demonstrations (0: off).
    #[arg(long, default_value_t = 1.0)]
    bc_weight: f32,
    /// Apply the behaviour-cloning loss everywhere, not only where the critic prefers the
    /// demonstrated action.
    #[arg(long)]
    no_q_filter: bool,
    /// Weight of the pull towards the --init policy on every sampled state (default 5 with
    /// --init, 0 without).
    #[arg(long)]
    anchor_weight: Option<f32>,
    /// Let the anchor's weight fall linearly to 0 over this many updates (0: it stays).
    #[arg(long, default_value_t = 0)]
    anchor_decay_updates: u64,
    /// Improve the actor by search instead of the critic's gradient: regress towards the
    /// best-rated of its action and neighbours this far apart on steering (0: off; see
    /// docs/results/paper-experiment.md).
    #[arg(long, default_value_t = 0.0)]
    search_step: f32,
    /// Start this share of the training episodes shortly before a place where an earlier
    /// episode left the road (0: always at a random place), as curriculum RL does.
    #[arg(long, default_value_t = 0.0)]
    failure_resets: f32,
    /// Plain DDPG: one critic, actor updated every step, no target smoothing (default: TD3's
    /// twin critics, delay 2, smoothing 0.1).
    #[arg(long)]
    no_td3: bool,
    /// ONNX Runtime threads for the backbone.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Train the ResNet-18 backbones too (actor and critics; ResNet-18 only), not only the actor's fc and
    /// the critics' layers on frozen features. The replay then holds whole frames; each
    /// update runs several ResNet-18 passes per sample, which wants a GPU (on a 2-core CPU
    /// one update of batch 32 at 96x96 took 3.5 s, `jetpilot train bench`): lower --batch
    /// and --updates-per-step to try it on a CPU.
    #[arg(long)]
    train_backbone: bool,
    /// Replay buffer size in transitions (default 100000; 10000 with --train-backbone,
    /// where one transition holds two frames: about 220 KB at 96x96).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    replay_capacity: Option<u64>,
    #[command(flatten)]
    road: super::sim::WorldArgs,
    #[command(flatten)]
    target: super::train_il::DeviceArg,
}

pub fn main(args: DdpgArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = super::train::config(Some(&args.sim))?;
    args.road.apply(&mut cfg);
    let mut opts = DdpgOptions::new(args.out.clone(), cfg);
    if let Some(path) = &args.select_sim {
        let select = super::train::config(Some(path))?;
        let (a, b) = (&opts.cfg, &select);
        if a.control.gains() != b.control.gains() || a.sim.control_hz != b.sim.control_hz {
            tracing::warn!(
                "--select-sim {}: its steering gains or sim.control_hz differ from --sim's, so \
                 best.onnx is chosen for another controller than the one it trains with",
                path.display()
            );
        }
        opts.select_cfg = Some(select);
    }
    opts.input_size = args.input_size;
    opts.init = args.init;
    opts.demos = args.demos;
    opts.seed = args.seed;
    opts.budget_s = args.minutes * 60.0;
    opts.max_episodes = args.episodes.unwrap_or(usize::MAX);
    opts.episode_steps = args.episode_steps;
    opts.eval_every = args.eval_every;
    opts.eval_seconds = args.eval_seconds;
    opts.stop_at_full_autonomy = args.stop_at_full_autonomy;
    opts.noise = match args.noise {
        Noise::Gaussian => NoiseKind::Gaussian,
        Noise::Ou => NoiseKind::Ou,
    };
    opts.sigma = [args.sigma_speed, args.sigma_steering];
    opts.n_step = args.n_step;
    opts.updates_per_step = args.updates_per_step;
    opts.warmup_updates = args.warmup_updates;
    opts.ort_threads = args.threads;
    opts.train_backbone = args.train_backbone;
    if !(0.0..=1.0).contains(&args.failure_resets) {
        anyhow::bail!(
            "--failure-resets is a share of the episodes, 0..1; got {}",
            args.failure_resets
        );
    }
    opts.failure_resets = args.failure_resets;
    opts.device = args.target.device;
    opts.replay_capacity = match args.replay_capacity {
        Some(n) => n as usize,
        None if args.train_backbone => 10_000,
        None => opts.replay_capacity,
    };
    let a = &mut opts.agent;
    a.gamma = args.gamma;
    a.actor_lr = args.actor_lr;
    a.critic_lr = args.critic_lr;
    a.batch = args.batch;
    a.bc_weight = args.bc_weight;
    a.q_filter = !args.no_q_filter;
    a.anchor_weight = args
        .anchor_weight
        .unwrap_or(if opts.init.is_some() { 5.0 } else { 0.0 });
    a.anchor_decay_updates = args.anchor_decay_updates;
    a.search_step = args.search_step;
    if args.no_td3 {
        a.twin = false;
        a.policy_delay = 1;
        a.target_noise = 0.0;
    }
    let bar = indicatif::ProgressBar::new(opts.budget_s.round() as u64);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("[{elapsed_precise}] [{bar:30}] {msg}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    let started = std::time::Instant::now();
    let report = ddpg::train(
        &opts,
        |e| {
            bar.set_position(started.elapsed().as_secs());
            bar.set_message(format!(
                "episode {}: {} steps, return {:.1}, {} rewards{}",
                e.episode,
                e.steps,
                e.ret,
                e.rewards,
                if e.interventions > 0 {
                    ", left the road"
                } else {
                    ""
                }
            ));
            tracing::debug!(
                episode = e.episode,
                steps = e.steps,
                ret = format!("{:.1}", e.ret),
                rewards = e.rewards,
                left_road = e.interventions,
                critic_loss = format!("{:.4}", e.critic_loss),
                mean_q = format!("{:.2}", e.mean_q),
                seconds = format!("{:.1}", e.env_seconds + e.update_seconds),
                "episode"
            );
        },
        |p, best| {
            bar.suspend(|| {
                tracing::info!(
                    episode = p.episode,
                    env_steps = p.env_steps,
                    interventions = p.outcome.interventions,
                    off_road = p.outcome.causes.off_road,
                    replay_bounds = p.outcome.causes.replay(),
                    stalled = p.outcome.causes.stalled,
                    autonomy = format!("{:.1}%", p.outcome.autonomy_percent),
                    rewards = p.outcome.rewards,
                    laps = format!("{:.2}", p.outcome.laps),
                    wall = format!("{:.0}s", p.wall_s),
                    best,
                    "evaluation ({:.0} s test)",
                    p.outcome.seconds
                );
            });
        },
    )?;
    bar.finish_and_clear();
    if let Some(w) = &report.plot_warning {
        tracing::warn!("{w}");
    }
    println!(
        "DDPG: {} episodes, {} environment steps ({:.1} steps/s with updates), {} updates, {} demonstration transitions, {:.0} s",
        report.episodes,
        report.env_steps,
        report.steps_per_s,
        report.updates,
        report.demo_transitions,
        report.wall_s
    );
    if let Some(b) = &report.best {
        let world = match &args.select_sim {
            Some(p) => format!(" in {}", p.display()),
            None => String::new(),
        };
        println!(
            "best{world}: episode {} -> {} interventions in {:.0} s, autonomy {:.1}%, {} rewards, {:.2} laps -> {}",
            b.episode,
            b.outcome.interventions,
            b.outcome.seconds,
            b.outcome.autonomy_percent,
            b.outcome.rewards,
            b.outcome.laps,
            report.best_path.display()
        );
    }
    println!(
        "logs: {}, {}  curve: {}",
        ddpg::episodes_csv(&args.out).display(),
        ddpg::eval_csv(&args.out).display(),
        ddpg::png_path(&args.out).display()
    );
    Ok(ExitCode::SUCCESS)
}
