//! The routes: the page, the login page, the video, the WebSocket, status JSON and
//! `/metrics`, all but the login page behind the token when one is required.
//!
//! ```text
//!  GET  /login          login page (public)          POST /login   token -> cookie
//!  GET  /               the page                     GET  /video   MJPEG
//!  GET  /ws             WebSocket: status out, controls in (see `ClientMsg`)
//!  GET  /api/status     the status as JSON           GET  /metrics Prometheus text
//! ```
//!
//! The server talks to the daemon only through channels: it reads the daemon's status and
//! the encoded video from `watch` slots and sends the page's requests over a bounded
//! `mpsc` channel that the actuator reads, so no client can hold the control loop up.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Form, Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::get;
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, watch};

use super::auth;
use super::label::{LabelKind, Labeller};
use super::video::{self, Jpeg};
use crate::control::SteeringGains;
use crate::drive::DaemonStatus;
use crate::drive::modes::Mode;
use crate::drive::remote::{ClientId, RemoteMsg, RemoteRequest};

const INDEX: &str = include_str!("assets/index.html");
const LOGIN: &str = include_str!("assets/login.html");

/// What the routes share.
#[derive(Clone)]
pub struct AppState {
    /// `None`: no token asked for (loopback).
    pub token: Option<Arc<str>>,
    pub status: watch::Receiver<DaemonStatus>,
    /// The encoder's slot; each video client subscribes (the encoder works only while
    /// someone does).
    pub video: Arc<watch::Sender<Option<Arc<Jpeg>>>>,
    pub remote: mpsc::Sender<RemoteMsg>,
    /// The config file "save to config" writes to (`None`: saving is off).
    pub config_path: Option<Arc<PathBuf>>,
    pub next_client: Arc<AtomicU64>,
    /// Sliders' and status' facts the page needs at start.
    pub page: Arc<PageInfo>,
    /// Click-to-label's folders and the frames sent last.
    pub labels: Arc<super::label::Labeller>,
    /// `web.max_message_bytes`: the largest WebSocket message (and frame) taken.
    pub max_message_bytes: usize,
}

/// Static facts for the page.
#[derive(Debug, Clone, Serialize)]
pub struct PageInfo {
    pub heartbeat_ms: u64,
    pub output: &'static str,
    pub config: Option<String>,
}

/// The router with every route.
pub fn router(state: AppState) -> Router {
    let protected = Router::new()
        .route("/", get(index))
        .route("/video", get(video_stream))
        .route("/ws", get(ws))
        .route("/api/status", get(status_json))
        .route("/metrics", get(metrics))
        .route_layer(middleware::from_fn_with_state(state.clone(), require_token));
    Router::new()
        .route("/login", get(login_page).post(login))
        .merge(protected)
        .layer(middleware::from_fn_with_state(state.clone(), same_origin))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            close_unless_authorised,
        ))
        .layer(header_if_absent(header::CACHE_CONTROL, "no-store"))
        // No other site may frame the page (clickjacking its buttons), nor sniff types.
        .layer(header_if_absent(header::X_FRAME_OPTIONS, "DENY"))
        .layer(header_if_absent(
            header::CONTENT_SECURITY_POLICY,
            "frame-ancestors 'none'",
        ))
        .layer(header_if_absent(header::X_CONTENT_TYPE_OPTIONS, "nosniff"))
        .with_state(state)
}

/// Sets `name: value` on every response that does not set it itself.
fn header_if_absent(
    name: header::HeaderName,
    value: &'static str,
) -> tower_http::set_header::SetResponseHeaderLayer<HeaderValue> {
    tower_http::set_header::SetResponseHeaderLayer::if_not_present(
        name,
        HeaderValue::from_static(value),
    )
}

/// Answers a request that does not carry the right token (the login page, a 401, a 403,
/// a 404), then closes its connection (`Connection: close`; hyper closes after such a
/// response). With keep-alive, a client that never had the token could hold one of
/// `web.max_connections` for as long as it asked again within `web.idle_timeout_ms`.
async fn close_unless_authorised(State(s): State<AppState>, req: Request, next: Next) -> Response {
    let authorised = s
        .token
        .as_deref()
        .is_none_or(|expected| carries_token(&req, expected));
    let mut r = next.run(req).await;
    if !authorised {
        r.headers_mut()
            .insert(header::CONNECTION, HeaderValue::from_static("close"));
    }
    r
}

/// Refuses requests another site's page could make through the user's browser:
/// - without a token (loopback), the `Host` must be a loopback name or address, so a web
///   site whose name resolves to 127.0.0.1 (DNS rebinding) cannot reach the page;
/// - a request that carries an `Origin` (browsers send one with every WebSocket upgrade
///   and form post) must come from this page's own origin.
async fn same_origin(State(s): State<AppState>, req: Request, next: Next) -> Response {
    if let Some(refusal) = cross_site(s.token.is_none(), req.headers()) {
        return (StatusCode::FORBIDDEN, refusal).into_response();
    }
    next.run(req).await
}

/// Why [`same_origin`] refuses a request with these headers, if it does.
fn cross_site(tokenless: bool, headers: &axum::http::HeaderMap) -> Option<&'static str> {
    let header = |n| headers.get(n).and_then(|v| v.to_str().ok());
    let host = header(header::HOST).unwrap_or("");
    if tokenless && !loopback_host(host) {
        return Some("this page answers only to 127.0.0.1 or localhost without a token");
    }
    if let Some(origin) = header(header::ORIGIN) {
        let authority = origin
            .strip_prefix("http://")
            .or_else(|| origin.strip_prefix("https://"))
            .unwrap_or("");
        if !authority.eq_ignore_ascii_case(host) {
            return Some("cross-origin request refused");
        }
    }
    None
}

/// `localhost`, `127.x.x.x` or `[::1]`, with or without a port.
pub fn loopback_host(host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(rest) => rest.split(']').next().unwrap_or(""),
        None => host.rsplit_once(':').map_or(host, |(h, _)| h),
    };
    name.eq_ignore_ascii_case("localhost")
        || name
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// The token check. A browser without it is sent to the login page; everything else gets
/// 401. `/?token=...` sets the cookie and redirects to `/` (the link printed in the log).
/// The request presents `expected` (cookie, `Authorization: Bearer` or `?token=`).
fn carries_token(req: &Request, expected: &str) -> bool {
    auth::presented(req.headers(), req.uri().query()).is_some_and(|g| auth::same(&g, expected))
}

async fn require_token(State(s): State<AppState>, req: Request, next: Next) -> Response {
    let Some(expected) = s.token.as_deref() else {
        return next.run(req).await;
    };
    if carries_token(&req, expected) {
        let from_query = auth::query_token(req.uri().query()).is_some();
        if req.uri().path() == "/" && from_query {
            let mut r = Redirect::to("/").into_response();
            if let Ok(v) = HeaderValue::from_str(&auth::cookie(expected)) {
                r.headers_mut().insert(header::SET_COOKIE, v);
            }
            return r;
        }
        return next.run(req).await;
    }
    if req.uri().path() == "/" {
        return Redirect::to("/login").into_response();
    }
    let why = if auth::presented(req.headers(), req.uri().query()).is_some() {
        "wrong token"
    } else {
        "token required"
    };
    (StatusCode::UNAUTHORIZED, why).into_response()
}

async fn login_page() -> Html<&'static str> {
    Html(LOGIN)
}

#[derive(Deserialize)]
struct LoginForm {
    token: String,
}

async fn login(State(s): State<AppState>, Form(f): Form<LoginForm>) -> Response {
    match s.token.as_deref() {
        Some(expected) if !auth::same(f.token.trim(), expected) => (
            StatusCode::UNAUTHORIZED,
            Html(LOGIN.replace("<!--error-->", "<p class=\"err\">Wrong token.</p>")),
        )
            .into_response(),
        Some(expected) => {
            let mut r = Redirect::to("/").into_response();
            if let Ok(v) = HeaderValue::from_str(&auth::cookie(expected)) {
                r.headers_mut().insert(header::SET_COOKIE, v);
            }
            r
        }
        None => Redirect::to("/").into_response(),
    }
}

async fn index(State(s): State<AppState>) -> Html<String> {
    // `<` escaped: a path with `</script>` in it cannot end the script early.
    let info = serde_json::to_string(s.page.as_ref())
        .unwrap_or_else(|_| "{}".into())
        .replace('<', "\\u003c");
    Html(INDEX.replace("/*PAGE_INFO*/{}", &info))
}

async fn video_stream(State(s): State<AppState>) -> Response {
    let body = Body::from_stream(video::stream(s.video.subscribe()));
    Response::builder()
        .header(
            header::CONTENT_TYPE,
            format!("multipart/x-mixed-replace; boundary={}", video::BOUNDARY),
        )
        .body(body)
        .unwrap_or_else(|_| StatusCode::INTERNAL_SERVER_ERROR.into_response())
}

async fn metrics(State(s): State<AppState>) -> impl IntoResponse {
    let text = super::metrics::render(&s.status.borrow());
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text)
}

async fn status_json(State(s): State<AppState>) -> impl IntoResponse {
    let view = StatusView::new(&s.status.borrow(), None);
    axum::Json(view)
}

/// The status as the page sees it.
#[derive(Debug, Serialize)]
pub struct StatusView {
    #[serde(rename = "type")]
    kind: &'static str,
    pub mode: String,
    pub elapsed_s: f32,
    pub fps: f32,
    pub frames_captured: u64,
    pub frames_skipped: u64,
    pub commands_written: u64,
    pub watchdog_stops: u64,
    pub interventions: u64,
    /// The paper's autonomy value so far, % (`None` before the first second).
    pub autonomy: Option<f32>,
    pub recording: bool,
    pub records: u64,
    /// Why recording stopped by itself (a full disk, the record limit), if it did.
    pub record_error: Option<String>,
    pub gains: SteeringGains,
    pub wheels: [f32; 2],
    /// preprocess, inference, control, actuate, frame age: mean ms over the last status period.
    pub latency_ms: [Option<f32>; 5],
    pub autopilot_available: bool,
    /// `free`, `yours` or `taken`.
    pub controls: &'static str,
}

impl StatusView {
    pub fn new(s: &DaemonStatus, me: Option<ClientId>) -> Self {
        let controls = match (s.remote_holder, me) {
            (None, _) => "free",
            (Some(h), Some(m)) if h == m => "yours",
            _ => "taken",
        };
        let autonomy = (s.elapsed_s >= 1.0)
            .then(|| crate::sim::reward::autonomy(s.interventions as u32, s.elapsed_s))
            .filter(|a| a.is_finite());
        Self {
            kind: "status",
            mode: s.mode.clone(),
            elapsed_s: s.elapsed_s,
            fps: s.commands_per_s,
            frames_captured: s.frames_captured,
            frames_skipped: s.frames_skipped,
            commands_written: s.commands_written,
            watchdog_stops: s.watchdog_stops,
            interventions: s.interventions,
            autonomy,
            recording: s.recording,
            records: s.records,
            record_error: s.record_error.clone(),
            gains: s.gains,
            wheels: [s.last.left, s.last.right],
            latency_ms: s.recent_ms,
            autopilot_available: s.autopilot_available,
            controls,
        }
    }
}

/// What a page sends over the WebSocket (JSON, `type` names the variant).
#[derive(Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientMsg {
    /// Sticks, -1..=1; at 10 Hz while the page holds the controls (also the heartbeat).
    Drive {
        throttle: f32,
        steering: f32,
    },
    Heartbeat,
    /// `manual`, `auto` or `stopped`.
    Mode {
        mode: String,
    },
    /// The emergency stop (any page may press it).
    Estop,
    Gains {
        speed_gain: f32,
        steering_gain: f32,
        steering_kd: f32,
        steering_bias: f32,
        steering_ki: f32,
    },
    Record {
        on: bool,
    },
    /// Write the daemon's gains into the config file.
    Save,
    /// Click-to-label: save frame `seq` (the `X-Frame-Seq` of the picture shown) as a
    /// `kind` sample; `x`, `y`: the clicked pixel of that picture.
    Label {
        kind: LabelKind,
        seq: u64,
        x: u32,
        y: u32,
    },
    /// Remove the last sample this page saved.
    UndoLabel,
    /// The folders and their counts.
    Labels,
}

impl ClientMsg {
    /// The daemon request, or what is wrong with the message.
    fn request(&self, current: &SteeringGains) -> Result<Option<RemoteRequest>, String> {
        Ok(Some(match self {
            ClientMsg::Drive { throttle, steering } => RemoteRequest::Drive {
                throttle: *throttle,
                steering: *steering,
            },
            ClientMsg::Heartbeat => RemoteRequest::Heartbeat,
            ClientMsg::Mode { mode } => RemoteRequest::Mode(match mode.as_str() {
                "manual" => Mode::Manual,
                "auto" => Mode::Auto,
                "stopped" => Mode::Stopped,
                other => return Err(format!("unknown mode {other:?} (manual, auto, stopped)")),
            }),
            ClientMsg::Estop => RemoteRequest::EmergencyStop,
            ClientMsg::Gains {
                speed_gain,
                steering_gain,
                steering_kd,
                steering_bias,
                steering_ki,
            } => RemoteRequest::Gains(SteeringGains {
                speed_gain: *speed_gain,
                steering_gain: *steering_gain,
                steering_kd: *steering_kd,
                steering_bias: *steering_bias,
                steering_ki: *steering_ki,
                integral_limit: current.integral_limit,
                mixing: current.mixing,
            }),
            ClientMsg::Record { on } => RemoteRequest::Record(*on),
            ClientMsg::Save
            | ClientMsg::Label { .. }
            | ClientMsg::UndoLabel
            | ClientMsg::Labels => return Ok(None),
        }))
    }
}

async fn ws(State(s): State<AppState>, upgrade: WebSocketUpgrade) -> Response {
    let id = s.next_client.fetch_add(1, Ordering::Relaxed) + 1;
    let max = s.max_message_bytes;
    upgrade
        .max_message_size(max)
        .max_frame_size(max)
        .on_upgrade(move |socket| client(socket, s, id))
}

/// Tells the daemon a page has gone, whatever way its task ends.
struct Goodbye {
    tx: mpsc::Sender<RemoteMsg>,
    id: ClientId,
}

impl Drop for Goodbye {
    fn drop(&mut self) {
        let msg = RemoteMsg {
            client: self.id,
            request: RemoteRequest::Closed,
        };
        if self.tx.try_send(msg).is_err() {
            // Full queue: deliver it from a task (the dead-man stops the car meanwhile).
            let tx = self.tx.clone();
            if let Ok(h) = tokio::runtime::Handle::try_current() {
                h.spawn(async move {
                    let _ = tx.send(msg).await;
                });
            }
        }
    }
}

/// Sending to a page that does not read for this long closes its socket.
const SEND_TIMEOUT: Duration = Duration::from_secs(2);

/// A ping this often keeps a quiet page's socket from `web.idle_timeout_ms`
/// ([`super::guard`]), and finds a page that is gone.
const PING_EVERY: Duration = Duration::from_secs(2);

async fn send(socket: &mut WebSocket, text: String) -> bool {
    matches!(
        tokio::time::timeout(SEND_TIMEOUT, socket.send(Message::Text(text.into()))).await,
        Ok(Ok(()))
    )
}

fn json<T: Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|_| "{}".into())
}

async fn client(mut socket: WebSocket, s: AppState, id: ClientId) {
    let _goodbye = Goodbye {
        tx: s.remote.clone(),
        id,
    };
    tracing::info!(client = id, "web page connected");
    let mut status = s.status.clone();
    status.mark_changed();
    // Replies of work done off this loop (saving), so a slow disk never stops this page's
    // messages, its heartbeat among them, from being read.
    let (reply_tx, mut reply_rx) = mpsc::channel::<String>(4);
    let mut last_gains: Option<tokio::time::Instant> = None;
    let mine = PageSamples::default();
    if !send(
        &mut socket,
        json(&serde_json::json!({"type": "hello", "client": id})),
    )
    .await
    {
        return;
    }
    let mut ping = tokio::time::interval_at(tokio::time::Instant::now() + PING_EVERY, PING_EVERY);
    ping.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = ping.tick() => {
                let sent = tokio::time::timeout(
                    SEND_TIMEOUT,
                    socket.send(Message::Ping(Default::default())),
                )
                .await;
                if !matches!(sent, Ok(Ok(()))) {
                    break;
                }
            }
            changed = status.changed() => {
                if changed.is_err() {
                    break;
                }
                let view = StatusView::new(&status.borrow_and_update(), Some(id));
                if !send(&mut socket, json(&view)).await {
                    break;
                }
            }
            Some(reply) = reply_rx.recv() => {
                if !send(&mut socket, reply).await {
                    break;
                }
            }
            msg = socket.recv() => {
                let text = match msg {
                    Some(Ok(Message::Text(t))) => t,
                    Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                    Some(Ok(_)) => continue,
                };
                let reply = handle(&s, id, text.as_str(), &reply_tx, &mut last_gains, &mine).await;
                if let Some(r) = reply
                    && !send(&mut socket, r).await
                {
                    break;
                }
            }
        }
    }
    tracing::info!(client = id, "web page disconnected");
}

/// One message from page `id`; returns a reply for the page, if any (a save replies later
/// through `later`).
async fn handle(
    s: &AppState,
    id: ClientId,
    text: &str,
    later: &mpsc::Sender<String>,
    last_gains: &mut Option<tokio::time::Instant>,
    mine: &PageSamples,
) -> Option<String> {
    let error = |m: String| Some(json(&serde_json::json!({"type": "error", "message": m})));
    let msg: ClientMsg = match serde_json::from_str(text) {
        Ok(m) => m,
        Err(e) => return error(format!("bad message: {e}")),
    };
    match msg {
        ClientMsg::Label { kind, seq, x, y } => {
            let (labels, mine) = (s.labels.clone(), mine.clone());
            return later_reply(later, move || label(&labels, &mine, kind, seq, x, y));
        }
        ClientMsg::UndoLabel => {
            let (labels, mine) = (s.labels.clone(), mine.clone());
            return later_reply(later, move || undo_label(&labels, &mine));
        }
        ClientMsg::Labels => {
            let labels = s.labels.clone();
            return later_reply(later, move || label_counts(&labels, "label_counts", None));
        }
        _ => {}
    }
    let (gains, holder) = {
        let st = s.status.borrow();
        (st.gains, st.remote_holder)
    };
    match msg.request(&gains) {
        Err(e) => error(e),
        Ok(Some(request)) => {
            if let Some(h) = holder.filter(|&h| h != id)
                && !matches!(request, RemoteRequest::EmergencyStop)
            {
                // The daemon refuses it too; say so once per message kind that needs control.
                if !matches!(
                    request,
                    RemoteRequest::Drive { .. } | RemoteRequest::Heartbeat
                ) {
                    return error(format!("another page (client {h}) holds the controls"));
                }
            }
            if matches!(request, RemoteRequest::Gains(_)) {
                *last_gains = Some(tokio::time::Instant::now());
            }
            if s.remote
                .send(RemoteMsg {
                    client: id,
                    request,
                })
                .await
                .is_err()
            {
                return error("the daemon is shutting down".into());
            }
            None
        }
        Ok(None) => {
            // Save: only the page holding the controls, or any page while nobody holds them.
            if let Some(h) = holder.filter(|&h| h != id) {
                return error(format!("another page (client {h}) holds the controls"));
            }
            let Some(path) = s.config_path.clone() else {
                return error(
                    "saving is off: the daemon was not started from a config file".into(),
                );
            };
            let mut status = s.status.clone();
            let recent = last_gains.is_some_and(|t| t.elapsed() < Duration::from_secs(1));
            let later = later.clone();
            tokio::spawn(async move {
                if recent {
                    // This page's last slider move may still be in the daemon's queue: the
                    // daemon publishes a status after each request it takes.
                    status.mark_unchanged();
                    let _ =
                        tokio::time::timeout(Duration::from_millis(300), status.changed()).await;
                }
                let gains = status.borrow().gains;
                let result = tokio::task::spawn_blocking(move || {
                    super::save::save_gains(&path, &gains).map(|()| (path, gains))
                })
                .await;
                let reply = match result {
                    Ok(Ok((path, gains))) => {
                        tracing::info!(path = %path.display(), ?gains, "web: gains saved to the config");
                        json(
                            &serde_json::json!({"type": "saved", "path": path.display().to_string()}),
                        )
                    }
                    Ok(Err(e)) => {
                        json(&serde_json::json!({"type": "error", "message": e.to_string()}))
                    }
                    Err(e) => json(
                        &serde_json::json!({"type": "error", "message": format!("saving failed: {e}")}),
                    ),
                };
                let _ = later.send(reply).await;
            });
            None
        }
    }
}

/// The samples one page saved, newest last (what its undo may remove).
#[derive(Clone, Default)]
struct PageSamples(Arc<std::sync::Mutex<Vec<PathBuf>>>);

impl PageSamples {
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<PathBuf>> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Runs blocking `work` (file I/O) off the async threads; its reply reaches the page
/// through `later`, so a slow disk never holds up this page's other messages.
fn later_reply(
    later: &mpsc::Sender<String>,
    work: impl FnOnce() -> String + Send + 'static,
) -> Option<String> {
    let later = later.clone();
    tokio::spawn(async move {
        let reply = tokio::task::spawn_blocking(work).await.unwrap_or_else(|e| {
            json(&serde_json::json!({"type": "error", "message": format!("labelling failed: {e}")}))
        });
        let _ = later.send(reply).await;
    });
    None
}

fn label_error(e: super::label::LabelError) -> String {
    tracing::warn!(error = %e, "web: click-to-label");
    json(&serde_json::json!({"type": "error", "message": e.to_string()}))
}

/// The counts reply (`kind`: `label_counts`, `labelled` or `unlabelled`), with the file
/// just saved or removed.
fn label_counts(labels: &Labeller, kind: &str, file: Option<&std::path::Path>) -> String {
    json(&serde_json::json!({
        "type": kind,
        "counts": labels.counts(),
        "file": file.map(|f| f.display().to_string()),
        "xy_dir": labels.xy_dir.display().to_string(),
        "collision_dir": labels.collision_dir.display().to_string(),
    }))
}

fn label(
    labels: &Labeller,
    mine: &PageSamples,
    kind: LabelKind,
    seq: u64,
    x: u32,
    y: u32,
) -> String {
    match labels.save(kind, seq, x, y) {
        Ok(path) => {
            tracing::info!(file = %path.display(), seq, "web: sample saved");
            mine.lock().push(path.clone());
            label_counts(labels, "labelled", Some(&path))
        }
        Err(e) => label_error(e),
    }
}

fn undo_label(labels: &Labeller, mine: &PageSamples) -> String {
    let Some(path) = mine.lock().pop() else {
        return label_error(super::label::LabelError::NothingToUndo);
    };
    match labels.undo(&path) {
        Ok(()) => {
            tracing::info!(file = %path.display(), "web: sample removed (undo)");
            label_counts(labels, "unlabelled", Some(&path))
        }
        Err(e) => label_error(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cross_site_requests_are_refused_with_or_without_a_token() {
        use axum::http::HeaderMap;
        let h = |host: Option<&'static str>, origin: Option<&'static str>| {
            let mut m = HeaderMap::new();
            if let Some(v) = host {
                m.insert(header::HOST, HeaderValue::from_static(v));
            }
            if let Some(v) = origin {
                m.insert(header::ORIGIN, HeaderValue::from_static(v));
            }
            m
        };
        let robot = Some("192.168.1.5:8887");
        // With a token: any Host; an Origin, when sent, must be the page's own.
        assert_eq!(cross_site(false, &h(robot, None)), None);
        assert_eq!(
            cross_site(false, &h(robot, Some("http://192.168.1.5:8887"))),
            None
        );
        assert_eq!(
            cross_site(
                false,
                &h(Some("jetbot.local:8887"), Some("https://JETBOT.local:8887"))
            ),
            None
        );
        for origin in [
            "http://evil.example",
            "http://192.168.1.5:8888",
            "http://192.168.1.5:8887.evil.example",
            "null",
            "file://",
            "ws://192.168.1.5:8887",
        ] {
            assert!(
                cross_site(false, &h(robot, Some(origin))).is_some(),
                "{origin}"
            );
        }
        assert!(cross_site(false, &h(None, Some("http://192.168.1.5:8887"))).is_some());
        // Without a token: a loopback Host, whatever the Origin.
        assert_eq!(cross_site(true, &h(Some("127.0.0.1:8887"), None)), None);
        assert_eq!(
            cross_site(
                true,
                &h(Some("localhost:8887"), Some("http://localhost:8887"))
            ),
            None
        );
        for host in [
            None,
            Some("evil.example:8887"),
            Some("127.0.0.1.nip.io:8887"),
            robot,
        ] {
            assert!(cross_site(true, &h(host, None)).is_some(), "{host:?}");
        }
        // DNS rebinding: the attacker's page is same-origin with itself, but its Host is
        // not loopback.
        assert!(
            cross_site(
                true,
                &h(Some("evil.example:8887"), Some("http://evil.example:8887"))
            )
            .is_some()
        );
    }

    #[test]
    fn the_pages_build_no_markup_from_data() {
        for (name, page) in [("index.html", INDEX), ("login.html", LOGIN)] {
            for sink in [
                "innerHTML",
                "outerHTML",
                "insertAdjacentHTML",
                "document.write",
            ] {
                assert!(!page.contains(sink), "{name} uses {sink}");
            }
        }
    }

    #[test]
    fn client_messages_parse_and_bad_ones_are_named() {
        let m: ClientMsg =
            serde_json::from_str(r#"{"type":"drive","throttle":0.5,"steering":-0.2}"#).unwrap();
        assert_eq!(
            m,
            ClientMsg::Drive {
                throttle: 0.5,
                steering: -0.2
            }
        );
        let g = SteeringGains::default();
        let m: ClientMsg = serde_json::from_str(r#"{"type":"mode","mode":"auto"}"#).unwrap();
        assert_eq!(m.request(&g), Ok(Some(RemoteRequest::Mode(Mode::Auto))));
        let m: ClientMsg = serde_json::from_str(r#"{"type":"mode","mode":"fast"}"#).unwrap();
        assert!(m.request(&g).unwrap_err().contains("fast"));
        assert!(serde_json::from_str::<ClientMsg>(r#"{"type":"fly"}"#).is_err());
        assert!(serde_json::from_str::<ClientMsg>(r#"{"type":"drive","throttle":1}"#).is_err());
        let m: ClientMsg = serde_json::from_str(r#"{"type":"save"}"#).unwrap();
        assert_eq!(m.request(&g), Ok(None));
        let m: ClientMsg =
            serde_json::from_str(r#"{"type":"label","kind":"blocked","seq":7,"x":150,"y":60}"#)
                .unwrap();
        assert_eq!(
            m,
            ClientMsg::Label {
                kind: LabelKind::Blocked,
                seq: 7,
                x: 150,
                y: 60
            }
        );
        assert_eq!(m.request(&g), Ok(None), "labels never reach the daemon");
        for bad in [
            r#"{"type":"label","kind":"road","seq":7,"x":1,"y":1}"#,
            r#"{"type":"label","kind":"xy","seq":7,"x":-1,"y":1}"#,
            r#"{"type":"label","kind":"xy","x":1,"y":1}"#,
        ] {
            assert!(serde_json::from_str::<ClientMsg>(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn loopback_hosts() {
        for h in [
            "127.0.0.1:8887",
            "localhost:8887",
            "LOCALHOST",
            "[::1]:8887",
            "127.0.0.2",
            "[::1]",
        ] {
            assert!(loopback_host(h), "{h}");
        }
        for h in [
            "evil.example:8887",
            "192.168.1.5:8887",
            "",
            "localhost.evil.example",
            "[::2]:80",
        ] {
            assert!(!loopback_host(h), "{h}");
        }
    }

    #[test]
    fn the_status_view_says_whose_controls_they_are() {
        let mut st = DaemonStatus {
            elapsed_s: 60.0,
            interventions: 1,
            ..Default::default()
        };
        assert_eq!(StatusView::new(&st, Some(3)).controls, "free");
        st.remote_holder = Some(3);
        assert_eq!(StatusView::new(&st, Some(3)).controls, "yours");
        assert_eq!(StatusView::new(&st, Some(4)).controls, "taken");
        // One intervention in 60 s: (1 - 6/60) * 100 = 90 %.
        let a = StatusView::new(&st, None).autonomy.unwrap();
        assert!((a - 90.0).abs() < 1e-4, "{a}");
    }
}
