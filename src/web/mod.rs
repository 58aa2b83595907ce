//! The daemon's web page (`[web]`): live video, gain sliders, modes, browser teleop with a
//! dead-man, a record toggle, click-to-label ([`label`]), and `/metrics`. axum on the daemon's tokio runtime, beside
//! the control loop and never in its way.
//!
//! ```text
//!  actuator --LiveFrame (watch)--> video::encoder --JPEG (watch)--> each /video client
//!                                       \--the frames sent--> label::RecentFrames <- a click
//!  actuator --DaemonStatus (watch)--> each /ws client, /api/status, /metrics
//!  each /ws client --RemoteMsg (bounded mpsc)--> actuator (drive::remote, drive::teleop)
//! ```
//!
//! Off unless `web.enabled`; on 127.0.0.1 unless `web.bind` says otherwise, and then only
//! with the token ([`auth`]).

pub mod auth;
pub mod config;
pub mod guard;
pub mod label;
pub mod metrics;
pub mod overlay;
pub mod save;
pub mod server;
pub mod video;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicU64;

use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

pub use config::WebConfig;

use crate::drive::remote::RemoteMsg;
use crate::drive::{DaemonStatus, LiveFrame};
use crate::policy::contract::OutputKind;

#[derive(Debug, thiserror::Error)]
pub enum WebError {
    #[error("config key `web.bind` = {bind:?}: {why}")]
    Bind { bind: String, why: String },
    #[error(transparent)]
    Token(#[from] auth::TokenError),
}

/// What the server needs from the daemon.
pub struct WebLinks {
    pub status: watch::Receiver<DaemonStatus>,
    pub live: watch::Receiver<Option<LiveFrame>>,
    pub remote: mpsc::Sender<RemoteMsg>,
}

/// A running server.
pub struct WebServer {
    pub addr: SocketAddr,
    /// The token the page asks for (`None` on loopback without `require_token`).
    pub token: Option<String>,
    task: tokio::task::JoinHandle<()>,
    cancel: CancellationToken,
}

impl WebServer {
    /// Binds `cfg.bind` and serves on the current tokio runtime until [`WebServer::stop`].
    /// `config_path`: the file "save to config" rewrites; `output`: the model's output,
    /// for the video overlay.
    pub async fn start(
        cfg: &WebConfig,
        config_path: Option<PathBuf>,
        output: OutputKind,
        links: WebLinks,
    ) -> Result<Self, WebError> {
        let bind_err = |why: String| WebError::Bind {
            bind: cfg.bind.clone(),
            why,
        };
        let addr = cfg.addr().map_err(bind_err)?;
        let token = if cfg.token_required() {
            let path = cfg.token_file();
            let (token, made) = auth::load_or_create(&path)?;
            if made {
                tracing::info!(
                    file = %path.display(),
                    "web page token made (shown this once; it stays in the file): {token}"
                );
            } else {
                tracing::info!(file = %path.display(), "web page token: in the file");
            }
            Some(token)
        } else {
            None
        };
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(|e| bind_err(e.to_string()))?;
        let addr = listener.local_addr().map_err(|e| bind_err(e.to_string()))?;
        let listener =
            guard::GuardedListener::new(listener, cfg.max_connections as usize, cfg.limits());
        let cancel = CancellationToken::new();
        let video_tx = Arc::new(watch::Sender::new(None));
        if cfg.xy_dir.is_none() || cfg.collision_dir.is_none() {
            // The default folders live in the state directory: make it, so a first click
            // works (a configured folder's parent must exist: a missing drive is an error).
            let state = config::state_dir();
            if let Err(e) = std::fs::create_dir_all(&state) {
                tracing::warn!(dir = %state.display(), error = %e, "web: cannot make the state directory; click-to-label will fail");
            }
        }
        let labels = Arc::new(label::Labeller::new(
            cfg.xy_folder(),
            cfg.collision_folder(),
            cfg.jpeg_quality,
        ));
        let params = video::VideoParams {
            fps: cfg.video_fps,
            quality: cfg.jpeg_quality,
            overlay: cfg.overlay.then_some(output),
        };
        tokio::spawn(video::encoder(
            links.live,
            video_tx.clone(),
            labels.clone(),
            params,
            cancel.clone(),
        ));
        let state = server::AppState {
            max_message_bytes: cfg.max_message_bytes as usize,
            token: token.as_deref().map(Arc::from),
            status: links.status,
            video: video_tx,
            remote: links.remote,
            config_path: config_path.clone().map(Arc::new),
            next_client: Arc::new(AtomicU64::new(0)),
            labels,
            page: Arc::new(server::PageInfo {
                heartbeat_ms: cfg.heartbeat_ms,
                output: output.as_str(),
                config: config_path.map(|p| p.display().to_string()),
            }),
        };
        let app = server::router(state);
        let stop = cancel.clone();
        let task = tokio::spawn(async move {
            let served = axum::serve(listener, app)
                .with_graceful_shutdown(stop.cancelled_owned())
                .await;
            if let Err(e) = served {
                tracing::error!(error = %e, "web server failed");
            }
        });
        let shown = if addr.ip().is_unspecified() {
            format!("http://<robot address>:{}/", addr.port())
        } else {
            format!("http://{addr}/")
        };
        tracing::info!(
            token = token.is_some(),
            "web page at {shown}{}",
            if token.is_some() {
                " (open it with ?token=<the token>, or log in)"
            } else {
                ""
            }
        );
        Ok(Self {
            addr,
            token,
            task,
            cancel,
        })
    }

    /// Stops serving (open video streams and sockets are cut after 1 s).
    pub async fn stop(self) {
        self.cancel.cancel();
        let abort = self.task.abort_handle();
        if tokio::time::timeout(std::time::Duration::from_secs(1), self.task)
            .await
            .is_err()
        {
            abort.abort();
        }
    }
}
