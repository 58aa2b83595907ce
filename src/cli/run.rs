//! `jetpilot run` (the daemon) and `jetpilot stop`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use jetpilot::clock::{Clock, MonotonicClock};
use jetpilot::config::Config;
use jetpilot::drive::remote::{RemoteControl, RemoteMsg, RemoteScales};
use jetpilot::drive::{self, DriveParams, Parts, RunEnd, setup};
use jetpilot::policy::Policy;
use jetpilot::web::{WebLinks, WebServer};

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Config file (see config/jetbot.toml, waveshare.toml, yahboom.toml, demo.toml).
    #[arg(short, long, value_name = "FILE")]
    config: PathBuf,
    /// Model to run instead of the config's `model.path`.
    #[arg(short, long, value_name = "FILE")]
    model: Option<PathBuf>,
    /// Stop after this many seconds (default: run until SIGINT/SIGTERM or the end of a replay).
    #[arg(long, value_name = "SECS")]
    duration: Option<f64>,
    /// Load the config, the model and the frame source, print the pipeline, and exit
    /// without touching the motors.
    #[arg(long)]
    dry_run: bool,
    /// Serve the web page (video, gain sliders, modes, browser driving), as `[web]
    /// enabled = true`; ADDR overrides `web.bind` (default 127.0.0.1:8887; any other
    /// address needs the token, printed to the log when it is made).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "")]
    web: Option<String>,
}

#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Config file; it needs a `[gamepad]` section (or the web page: `--web`), and
    /// `[record] path` says where the tub goes.
    #[arg(short, long, value_name = "FILE")]
    config: PathBuf,
    /// A model for the autopilot button (default: none; the autopilot is then unavailable).
    #[arg(short, long, value_name = "FILE")]
    model: Option<PathBuf>,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long, value_name = "SECS")]
    duration: Option<f64>,
    /// Serve the web page as well (see `jetpilot run --help`); ADDR overrides `web.bind`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "")]
    web: Option<String>,
}

/// `--web [ADDR]` onto the config's `[web]`.
pub(super) fn with_web(mut cfg: Config, web: Option<&str>) -> anyhow::Result<Config> {
    if let Some(addr) = web {
        cfg.web.enabled = true;
        if !addr.is_empty() {
            cfg.web.bind = addr.to_string();
        }
        cfg.web
            .addr()
            .map_err(|e| anyhow::anyhow!("--web {addr:?}: {e}"))?;
    }
    Ok(cfg)
}

pub fn run(args: RunArgs) -> anyhow::Result<ExitCode> {
    let cfg = with_web(Config::load(&args.config)?, args.web.as_deref())?;
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let policy = setup::load_policy(&cfg, args.model.as_deref())?;
    let source = setup::open_source(&cfg, clock.clone())?;
    if args.dry_run {
        super::say(format_args!(
            "{}",
            pipeline(&cfg, &policy, source.describe())
        ));
        return Ok(ExitCode::SUCCESS);
    }
    let model = args.model.clone().unwrap_or_else(|| cfg.model.path.clone());
    drive_with(
        &cfg,
        Some(&args.config),
        Box::new(policy),
        Some(&model),
        source,
        None,
        clock,
        args.duration,
        Start::Waiting,
    )
}

/// `jetpilot record`: drive with the gamepad and write demonstrations (tub v2).
pub fn record(args: RecordArgs) -> anyhow::Result<ExitCode> {
    let cfg = with_web(Config::load(&args.config)?, args.web.as_deref())?;
    if cfg.gamepad.is_none() && !cfg.web.enabled {
        anyhow::bail!(
            "config {}: recording needs someone to drive: add a [gamepad] section (profile = \"xbox\", \"f710\" or \"generic\"), or drive from the web page (--web, or [web] enabled = true)",
            args.config.display()
        );
    }
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let policy: Box<dyn Policy + Send> = match &args.model {
        Some(m) => Box::new(setup::load_policy(&cfg, Some(m))?),
        None => Box::new(jetpilot::policy::null::NullPolicy::new(
            cfg.model.fallback_contract(),
        )),
    };
    let source = setup::open_source(&cfg, clock.clone())?;
    drive_with(
        &cfg,
        Some(&args.config),
        policy,
        args.model.as_deref(),
        source,
        None,
        clock,
        args.duration,
        Start::Recording,
    )
}

/// The human side of a run: when `[gamepad]` is configured, or a web page can drive.
fn teleop_parts(
    cfg: &Config,
    model: Option<&Path>,
    recording: bool,
    cancel: &tokio_util::sync::CancellationToken,
    remote: Option<(RemoteControl, tokio::sync::mpsc::Receiver<RemoteMsg>)>,
) -> anyhow::Result<Option<jetpilot::drive::teleop::TeleopParts>> {
    use jetpilot::dataset::tub::{TubInputs, TubWriter};
    use jetpilot::drive::interventions::{InterventionLog, SessionInfo, fnv1a64_file};
    use jetpilot::drive::modes::{ModeParams, Modes};
    use jetpilot::drive::recorder::Recorder;
    use jetpilot::drive::teleop::{OpenRecorder, TeleopParts, spawn_reader};
    use jetpilot::hw::gamepad::{GamepadMap, GamepadState};

    if cfg.gamepad.is_none() && remote.is_none() {
        return Ok(None);
    }
    if cfg.control.mixing == jetpilot::control::Mixing::Car {
        anyhow::bail!(
            "control.mixing = \"car\" (the simulated DonkeyCar) drives without [gamepad] and \
             [web] only: manual driving and the recorder mix and store a JetBot's wheel \
             commands, which would reach the car as half its throttle and angle"
        );
    }
    let events = match cfg.gamepad.clone() {
        Some(g) => {
            let (tx, events) = tokio::sync::mpsc::channel(256);
            spawn_reader(g, tx, cancel.clone()).context("cannot start the gamepad thread")?;
            Some(events)
        }
        None => None,
    };
    let g = cfg.gamepad.clone().unwrap_or_default();
    let params = match &cfg.gamepad {
        Some(g) => ModeParams::from_gamepad(g),
        None => ModeParams::default(),
    };
    let model_hash = match model {
        Some(m) => fnv1a64_file(m)?,
        None => "none".to_string(),
    };
    let log = match &cfg.interventions.log_path {
        Some(p) => {
            let info = match model {
                Some(m) => SessionInfo::for_model(m)?,
                None => SessionInfo::new("none".into(), model_hash.clone()),
            };
            Some(InterventionLog::open(p, info)?)
        }
        None => None,
    };
    let rec = cfg.record.clone();
    let open = move || -> anyhow::Result<Recorder> {
        let tub = TubWriter::create(&rec.path, &TubInputs::ALL, super::unix_now())
            .with_context(|| format!("recording to {}", rec.path.display()))?;
        Recorder::start(Box::new(tub), rec.max_records, rec.jetbot_xy.clone())
            .context("cannot start the recorder thread")
    };
    // With a gamepad (or `jetpilot record`) the tub is opened now, so a bad path fails at
    // start; a web page alone opens it at its first press of record.
    let (recorder, open_recorder): (Option<Recorder>, Option<OpenRecorder>) =
        if cfg.gamepad.is_some() || recording {
            (Some(open()?), None)
        } else {
            (
                None,
                Some(Box::new(move || open().map_err(|e| format!("{e:#}")))),
            )
        };
    let (remote, remote_rx) = match remote {
        Some((c, rx)) => (Some(c), Some(rx)),
        None => (None, None),
    };
    Ok(Some(TeleopParts {
        events,
        remote,
        remote_rx,
        pad: GamepadState::new(GamepadMap::from_config(&g)?),
        modes: Modes::new(params, cfg.control.gains()),
        autopilot_available: model.is_some(),
        log,
        model_hash,
        recorder,
        open_recorder,
        recording,
    }))
}

/// How a run with a gamepad or web page begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Start {
    /// In Manual, waiting for the human (a real robot: nothing moves until asked).
    Waiting,
    /// `jetpilot record`: in Manual, the tub opened now.
    Recording,
    /// The autopilot engaged from the start, the page or pad able to take over (the
    /// simulator, where nothing can be hurt).
    Autopilot,
}

/// The daemon with the config's human side (gamepad, web page, panel); `motors` `None`
/// opens the config's motor driver. `config_path`: the file the web page's "save to
/// config" rewrites (`None`, a built-in config: the page cannot save).
#[allow(clippy::too_many_arguments)]
pub(super) fn drive_with(
    cfg: &Config,
    config_path: Option<&Path>,
    policy: Box<dyn Policy + Send>,
    model: Option<&Path>,
    source: Box<dyn jetpilot::camera::FrameSource>,
    motors: Option<Box<dyn jetpilot::hw::MotorOutput>>,
    clock: Arc<dyn Clock>,
    duration: Option<f64>,
    start: Start,
) -> anyhow::Result<ExitCode> {
    let recording = start == Start::Recording;
    let cancel = tokio_util::sync::CancellationToken::new();
    let _stop_reader = cancel.clone().drop_guard();
    // The web page: its requests go to the actuator, the frames it acted on come back.
    let (remote_tx, remote_rx) = tokio::sync::mpsc::channel(64);
    let (live_tx, live_rx) = tokio::sync::watch::channel(None);
    let remote = cfg.web.enabled.then(|| {
        let scales = RemoteScales {
            throttle_scale: cfg.web.throttle_scale,
            steering_scale: cfg.web.steering_scale,
        };
        let hb = Duration::from_millis(cfg.web.heartbeat_ms);
        (RemoteControl::new(hb, scales), remote_rx)
    });
    let output = policy.contract().output;
    let mut teleop = teleop_parts(cfg, model, recording, &cancel, remote)?;
    if start == Start::Autopilot
        && let Some(t) = teleop.as_mut()
    {
        t.modes = t.modes.clone().engaged();
    }
    let motors = match motors {
        Some(m) => m,
        None => setup::open_motors_to_drive(cfg, clock.clone())?,
    };
    let (status_tx, status_rx) = tokio::sync::watch::channel(Default::default());
    let status_rx_web = status_tx.subscribe();
    let panel = if cfg.oled.enabled || cfg.buzzer.enabled {
        Some(super::panel::spawn(
            cfg,
            clock.clone(),
            status_rx,
            cancel.clone(),
        )?)
    } else {
        None
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let parts = Parts {
        source,
        policy,
        motors,
        clock,
        teleop,
        live: cfg.web.enabled.then_some(live_tx),
        status: Some(status_tx),
    };
    let params = DriveParams::from_config(cfg);
    let duration = duration.map(Duration::from_secs_f64);
    let outcome = runtime.block_on(async {
        let web = if cfg.web.enabled {
            let links = WebLinks {
                status: status_rx_web,
                live: live_rx,
                remote: remote_tx,
            };
            let config_path = config_path.and_then(|p| std::fs::canonicalize(p).ok());
            Some(WebServer::start(&cfg.web, config_path, output, links).await?)
        } else {
            drop(remote_tx);
            None
        };
        let outcome = drive::run(parts, params, shutdown_signal(duration)).await;
        if let Some(w) = web {
            w.stop().await;
        }
        anyhow::Ok(outcome)
    })?;
    cancel.cancel();
    if let Some(p) = panel {
        let _ = p.join();
    }
    match outcome {
        Ok((end, report)) => {
            let why = match end {
                RunEnd::Shutdown => "stopped",
                RunEnd::SourceFinished => "frame source finished",
            };
            super::say(format_args!("{why}: {report}"));
            Ok(ExitCode::SUCCESS)
        }
        Err((e, report)) => {
            super::say(format_args!("fault: {report}"));
            Err(e.into())
        }
    }
}

/// Completes on SIGINT, SIGTERM, or after `limit`.
async fn shutdown_signal(limit: Option<Duration>) {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = match signal(SignalKind::terminate()) {
        Ok(s) => Some(s),
        Err(e) => {
            tracing::warn!(error = %e, "cannot watch SIGTERM");
            None
        }
    };
    let term = async {
        match term.as_mut() {
            Some(s) => {
                s.recv().await;
            }
            None => std::future::pending::<()>().await,
        }
    };
    let limit = async {
        match limit {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => tracing::info!("SIGINT"),
        _ = term => tracing::info!("SIGTERM"),
        _ = limit => tracing::info!("--duration reached"),
    }
}

/// The pipeline, one stage a line with the message on each edge.
fn pipeline(cfg: &Config, policy: &jetpilot::policy::OrtPolicy, source: String) -> String {
    let c = policy.contract();
    let g = cfg.control.gains();
    let motors = match cfg.motors.backend {
        jetpilot::config::MotorBackend::Log => "log backend (virtual motors)".to_string(),
        jetpilot::config::MotorBackend::Gpio => match &cfg.motors.gpio {
            Some(g) => g.summary(),
            None => "gpio backend without a [motors.gpio] section".to_string(),
        },
        _ => {
            let h = cfg.motors.hat_settings();
            format!(
                "{} motor HAT, PCA9685 at {:#04x} on {}, {} Hz",
                h.layout.as_str(),
                h.address,
                h.bus_name,
                h.pwm_hz
            )
        }
    };
    let s = c.input_size;
    [
        format!("capture     {source}"),
        "              | Frame {seq, captured_at, RGB8}".into(),
        "latest      one-frame slot: the newest frame wins, skipped frames are counted".into(),
        "              | Frame".into(),
        format!(
            "preprocess  resize to {s}x{s}, {} planes, normalise mean {:?} std {:?}",
            c.channel_order.as_str(),
            c.mean,
            c.std
        ),
        format!("              | [1,3,{s},{s}] f32 NCHW"),
        format!("policy      {}", policy.describe()),
        format!("              | [2] f32 ({})", c.output.as_str()),
        format!(
            "control     JetBot steering law: speed_gain {} steering_gain {} kd {} bias {} ki {}",
            g.speed_gain, g.steering_gain, g.steering_kd, g.steering_bias, g.steering_ki
        ),
        "              | Command {seq, captured_at, left, right}".into(),
        format!(
            "actuate     {motors}; watchdog {} ms, frames older than {} ms dropped",
            cfg.safety.watchdog_ms, cfg.safety.max_frame_age_ms
        ),
    ]
    .join("\n")
}

pub fn stop(config: &Path) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(config)?;
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    // Opening initialises the HAT and releases both motors; stop once more to be explicit.
    let mut motors = setup::open_motors(&cfg, clock)?;
    motors.stop()?;
    super::say(format_args!("motors stopped ({})", motors.describe()));
    Ok(ExitCode::SUCCESS)
}
