//! The web page against the running daemon on replayed frames with virtual motors: the
//! token on every route (WebSocket upgrade included), the dead-man (a page that falls
//! silent, a page that closes), sliders reaching the steering law, and clients that never
//! read costing the control loop nothing, and the connection limits (slow requests, stalled
//! video clients, garbage, oversized messages).

use crate::common;

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use jetpilot::camera::folder::FolderSource;
use jetpilot::clock::{Clock, MonotonicClock};
use jetpilot::control::{SteeringGains, WheelCommand};
use jetpilot::drive::modes::{ModeParams, Modes};
use jetpilot::drive::remote::{RemoteControl, RemoteScales};
use jetpilot::drive::teleop::TeleopParts;
use jetpilot::drive::{self, DaemonStatus, DriveParams, Outcome, Parts};
use jetpilot::hw::LogMotors;
use jetpilot::hw::gamepad::{GamepadConfig, GamepadMap, GamepadState};
use jetpilot::hw::motors::{MotorEvent, MotorRecord};
use jetpilot::policy::ModelContract;
use jetpilot::policy::contract::OutputKind;
use jetpilot::policy::null::NullPolicy;
use jetpilot::web::{WebConfig, WebLinks, WebServer};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{oneshot, watch};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

const WATCHDOG: Duration = Duration::from_millis(200);
const HEARTBEAT: Duration = Duration::from_millis(500);

/// The daemon with a web page, on a looping folder of frames.
struct Rig {
    addr: SocketAddr,
    token: Option<String>,
    record: MotorRecord,
    status: watch::Receiver<DaemonStatus>,
    clock: Arc<dyn Clock>,
    stop: Option<oneshot::Sender<()>>,
    run: Option<tokio::task::JoinHandle<Outcome>>,
    server: Option<WebServer>,
    _dir: tempfile::TempDir,
}

fn gains() -> SteeringGains {
    SteeringGains {
        speed_gain: 0.3,
        ..SteeringGains::default()
    }
}

/// Noise frames (`w` x `h`) in `dir/frames`: big JPEGs for the video tests.
fn noise_frames(dir: &Path, n: usize, w: u32, h: u32) -> std::path::PathBuf {
    use rand::{Rng, SeedableRng};
    let out = dir.join("noise");
    std::fs::create_dir_all(&out).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for i in 0..n {
        let rgb: Vec<u8> = (0..w * h * 3).map(|_| rng.random()).collect();
        image::save_buffer(
            out.join(format!("n{i:02}.png")),
            &rgb,
            w,
            h,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
    }
    out
}

impl Rig {
    async fn start(web: WebConfig, noise: bool) -> Rig {
        Rig::start_with(web, noise, None).await
    }

    /// [`Rig::start`] with a recorder for the page's Record button.
    async fn start_with(
        web: WebConfig,
        noise: bool,
        recorder: Option<jetpilot::drive::recorder::Recorder>,
    ) -> Rig {
        let dir = tempfile::tempdir().unwrap();
        let frames = if noise {
            noise_frames(dir.path(), 4, 320, 240)
        } else {
            common::write_frames(dir.path(), 8)
        };
        let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
        let source = FolderSource::open(&frames, 20.0, true, clock.clone()).unwrap();
        let contract = ModelContract {
            input_size: 32,
            ..ModelContract::default()
        };
        let motors = LogMotors::new(clock.clone());
        let record = motors.record();
        let (remote_tx, remote_rx) = tokio::sync::mpsc::channel(64);
        let (live_tx, live_rx) = watch::channel(None);
        let (status_tx, status) = watch::channel(DaemonStatus::default());
        let scales = RemoteScales {
            throttle_scale: 0.5,
            steering_scale: 0.3,
        };
        let pad_cfg = GamepadConfig::default();
        let teleop = TeleopParts {
            events: None,
            remote: Some(RemoteControl::new(HEARTBEAT, scales)),
            remote_rx: Some(remote_rx),
            pad: GamepadState::new(GamepadMap::from_config(&pad_cfg).unwrap()),
            modes: Modes::new(ModeParams::default(), gains()),
            autopilot_available: true,
            log: None,
            model_hash: "test".into(),
            recorder,
            open_recorder: None,
            recording: false,
        };
        let parts = Parts {
            source: Box::new(source),
            policy: Box::new(NullPolicy::new(contract)),
            motors: Box::new(motors),
            clock: clock.clone(),
            teleop: Some(teleop),
            status: Some(status_tx),
            live: Some(live_tx),
        };
        let params = DriveParams {
            gains: gains(),
            watchdog: WATCHDOG,
            max_frame_age: Duration::from_secs(1),
            max_abs_output: 10.0,
            stats_interval: Duration::ZERO,
        };
        let links = WebLinks {
            status: status.clone(),
            live: live_rx,
            remote: remote_tx,
        };
        let cfg_path = dir.path().join("robot.toml");
        std::fs::write(&cfg_path, "[control]\nspeed_gain = 0.3 # base speed\n").unwrap();
        let server = WebServer::start(&web, Some(cfg_path), OutputKind::Xy, links)
            .await
            .unwrap();
        let (stop_tx, stop_rx) = oneshot::channel::<()>();
        let run = tokio::spawn(drive::run(parts, params, async {
            let _ = stop_rx.await;
        }));
        Rig {
            addr: server.addr,
            token: server.token.clone(),
            record,
            status,
            clock,
            stop: Some(stop_tx),
            run: Some(run),
            server: Some(server),
            _dir: dir,
        }
    }

    async fn finish(mut self) -> DaemonStatus {
        let last = self.status.borrow().clone();
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(r) = self.run.take() {
            let outcome = r.await.unwrap();
            assert!(
                outcome.is_ok(),
                "the run failed: {:?}",
                outcome.err().map(|e| e.0)
            );
        }
        if let Some(s) = self.server.take() {
            s.stop().await;
        }
        // Every run ends with the motors stopped.
        let rec = self.record.lock().unwrap();
        assert_eq!(rec.last().map(|e| e.1), Some(MotorEvent::Stop));
        last
    }

    fn events(&self) -> Vec<(Duration, MotorEvent)> {
        self.record.lock().unwrap().clone()
    }

    async fn ws(&self, cookie: Option<&str>) -> Result<Ws, tokio_tungstenite::tungstenite::Error> {
        let mut req = format!("ws://{}/ws", self.addr)
            .into_client_request()
            .unwrap();
        if let Some(c) = cookie {
            req.headers_mut()
                .insert("Cookie", format!("jetpilot_token={c}").parse().unwrap());
        }
        let (ws, _) = tokio_tungstenite::connect_async(req).await?;
        Ok(ws)
    }

    /// Waits up to `secs` for the status to satisfy `ok`.
    async fn wait_status(&mut self, secs: f32, ok: impl Fn(&DaemonStatus) -> bool) -> DaemonStatus {
        let deadline = tokio::time::Instant::now() + Duration::from_secs_f32(secs);
        loop {
            {
                let s = self.status.borrow_and_update();
                if ok(&s) {
                    return s.clone();
                }
            }
            if tokio::time::timeout_at(deadline, self.status.changed())
                .await
                .is_err()
            {
                panic!("status never got there: {:?}", self.status.borrow());
            }
        }
    }
}

type Ws = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<TcpStream>>;

async fn say(ws: &mut Ws, json: &str) {
    ws.send(Message::Text(json.to_string().into()))
        .await
        .unwrap();
}

/// Sends `drive` messages at 10 Hz for `secs`; returns when the last went out.
async fn drive_for(ws: &mut Ws, clock: &Arc<dyn Clock>, throttle: f32, secs: f32) -> Duration {
    let n = (secs * 10.0) as usize;
    let mut last = clock.now();
    for _ in 0..n {
        say(
            ws,
            &format!(r#"{{"type":"drive","throttle":{throttle},"steering":0}}"#),
        )
        .await;
        last = clock.now();
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    last
}

/// A raw HTTP/1.1 request; returns the status code and the head (headers).
async fn http(addr: SocketAddr, request: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(request.as_bytes()).await.unwrap();
    let mut buf = vec![0u8; 8192];
    let mut got = Vec::new();
    // Read the head (and whatever follows in the same packets); video streams never end.
    while !String::from_utf8_lossy(&got).contains("\r\n\r\n") {
        let n = tokio::time::timeout(Duration::from_secs(5), s.read(&mut buf))
            .await
            .expect("no response")
            .unwrap();
        if n == 0 {
            break;
        }
        got.extend_from_slice(&buf[..n]);
    }
    let text = String::from_utf8_lossy(&got).to_string();
    let code = text
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    (code, text)
}

fn get(path: &str, extra: &str) -> String {
    format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{extra}Connection: close\r\n\r\n")
}

/// The first stop written after `t`, and whether anything but a stop went out after it.
fn stop_after(events: &[(Duration, MotorEvent)], t: Duration) -> (Duration, bool) {
    let stop = events
        .iter()
        .find(|(at, e)| *at >= t && *e == MotorEvent::Stop)
        .map(|(at, _)| *at)
        .unwrap_or_else(|| {
            panic!(
                "no stop after {t:?}: {:?}",
                &events[events.len().saturating_sub(5)..]
            )
        });
    let moved = events
        .iter()
        .any(|(at, e)| *at > stop && matches!(e, MotorEvent::Drive(c) if !c.is_stop()));
    (stop, moved)
}

fn drove(events: &[(Duration, MotorEvent)], w: WheelCommand) -> usize {
    events
        .iter()
        .filter(|(_, e)| matches!(e, MotorEvent::Drive(c) if (c.left - w.left).abs() < 1e-4 && (c.right - w.right).abs() < 1e-4))
        .count()
}

fn token_cfg(dir: &Path) -> WebConfig {
    WebConfig {
        enabled: true,
        bind: "127.0.0.1:0".into(),
        require_token: true,
        token_path: Some(dir.join("state/web-token")),
        ..WebConfig::default()
    }
}

fn open_cfg() -> WebConfig {
    WebConfig {
        enabled: true,
        bind: "127.0.0.1:0".into(),
        ..WebConfig::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_route_but_login_asks_for_the_token() {
    let state = tempfile::tempdir().unwrap();
    let rig = Rig::start(token_cfg(state.path()), false).await;
    let token = rig.token.clone().expect("a token");
    let file = std::fs::read_to_string(state.path().join("state/web-token")).unwrap();
    assert_eq!(file.trim(), token);
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(state.path().join("state/web-token"))
        .unwrap()
        .permissions()
        .mode();
    assert_eq!(mode & 0o777, 0o600);

    let cookie = format!("Cookie: jetpilot_token={token}\r\n");
    let bearer = format!("Authorization: Bearer {token}\r\n");
    for path in ["/video", "/api/status", "/metrics", "/ws"] {
        let (code, _) = http(rig.addr, &get(path, "")).await;
        assert_eq!(code, 401, "{path} without a token");
        let (code, _) = http(rig.addr, &get(path, "Cookie: jetpilot_token=nope\r\n")).await;
        assert_eq!(code, 401, "{path} with a wrong cookie");
        let (code, _) = http(rig.addr, &get(&format!("{path}?token=nope"), "")).await;
        assert_eq!(code, 401, "{path} with a wrong query token");
    }
    // The page sends a browser to the login page.
    let (code, head) = http(rig.addr, &get("/", "")).await;
    assert_eq!(code, 303);
    assert!(head.contains("location: /login"), "{head}");
    // With the token: cookie, bearer or query.
    for (path, how) in [
        ("/", &cookie),
        ("/api/status", &bearer),
        ("/metrics", &cookie),
        ("/video", &bearer),
    ] {
        let (code, head) = http(rig.addr, &get(path, how)).await;
        assert_eq!(code, 200, "{path}: {head}");
    }
    let (code, _) = http(rig.addr, &get(&format!("/metrics?token={token}"), "")).await;
    assert_eq!(code, 200);
    // `/?token=` sets the cookie and redirects to the page.
    let (code, head) = http(rig.addr, &get(&format!("/?token={token}"), "")).await;
    assert_eq!(code, 303);
    assert!(
        head.contains(&format!(
            "set-cookie: jetpilot_token={token}; Path=/; HttpOnly; SameSite=Strict"
        )),
        "{head}"
    );
    // The login page is public; a wrong token is refused, the right one sets the cookie.
    let (code, _) = http(rig.addr, &get("/login", "")).await;
    assert_eq!(code, 200);
    let post = |body: String| {
        format!(
            "POST /login HTTP/1.1\r\nHost: robot\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        )
    };
    let (code, _) = http(rig.addr, &post("token=nope".into())).await;
    assert_eq!(code, 401);
    let (code, head) = http(rig.addr, &post(format!("token={token}"))).await;
    assert_eq!(code, 303);
    assert!(head.contains("set-cookie: jetpilot_token="), "{head}");

    // The WebSocket upgrade: refused without or with a wrong token, accepted with it.
    match rig.ws(None).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(r)) => assert_eq!(r.status(), 401),
        other => panic!("upgrade without a token: {:?}", other.map(|_| ())),
    }
    match rig.ws(Some("nope")).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(r)) => assert_eq!(r.status(), 401),
        other => panic!("upgrade with a wrong token: {:?}", other.map(|_| ())),
    }
    let mut ws = rig.ws(Some(&token)).await.unwrap();
    let hello = ws.next().await.unwrap().unwrap();
    assert!(hello.to_text().unwrap().contains("\"hello\""), "{hello:?}");
    drop(ws);
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn loopback_needs_no_token_and_other_addresses_always_do() {
    assert!(!open_cfg().token_required());
    let rig = Rig::start(open_cfg(), false).await;
    assert!(rig.token.is_none());
    let (code, _) = http(rig.addr, &get("/api/status", "")).await;
    assert_eq!(code, 200);
    // Without a token only loopback names are answered (a site whose name resolves to
    // 127.0.0.1 gets nothing), and a page from another origin cannot open the WebSocket.
    let rebound =
        "GET /api/status HTTP/1.1\r\nHost: evil.example:8887\r\nConnection: close\r\n\r\n";
    assert_eq!(http(rig.addr, rebound).await.0, 403);
    let upgrade = |origin: &str| {
        format!(
            "GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nOrigin: {origin}\r\nConnection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n",
            rig.addr.port()
        )
    };
    assert_eq!(http(rig.addr, &upgrade("http://evil.example")).await.0, 403);
    let own = format!("http://127.0.0.1:{}", rig.addr.port());
    assert_eq!(http(rig.addr, &upgrade(&own)).await.0, 101);
    rig.finish().await;
    let state = tempfile::tempdir().unwrap();
    let any = WebConfig {
        bind: "0.0.0.0:0".into(),
        require_token: false,
        ..token_cfg(state.path())
    };
    assert!(any.token_required());
    let rig = Rig::start(any, false).await;
    assert!(rig.token.is_some());
    let local = SocketAddr::from(([127, 0, 0, 1], rig.addr.port()));
    let (code, _) = http(local, &get("/api/status", "")).await;
    assert_eq!(code, 401);
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_that_falls_silent_stops_the_motors() {
    let mut rig = Rig::start(open_cfg(), false).await;
    let mut ws = rig.ws(None).await.unwrap();
    let last = drive_for(&mut ws, &rig.clock, 1.0, 1.0).await;
    // Full throttle: 0.5 on both wheels (throttle_scale), while the page drives.
    assert!(
        drove(&rig.events(), WheelCommand::new(0.5, 0.5)) >= 5,
        "{:?}",
        rig.events()
    );
    // Silence, with the socket still open.
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let (stop, moved) = stop_after(&rig.events(), last);
    let after = stop.saturating_sub(last);
    eprintln!("stop written {after:?} after the page's last message");
    assert!(
        after <= HEARTBEAT + WATCHDOG,
        "stopped {after:?} after the last message"
    );
    assert!(
        after >= HEARTBEAT - Duration::from_millis(100),
        "stopped too early: {after:?}"
    );
    assert!(!moved, "the motors moved after the dead-man stop");
    let s = rig.wait_status(2.0, |s| s.mode == "stopped").await;
    assert_eq!(s.remote_holder, None);
    // Latched: driving again does nothing until the stop is cleared.
    let t = drive_for(&mut ws, &rig.clock, 1.0, 0.5).await;
    assert!(
        !rig.events()
            .iter()
            .any(|(at, e)| *at > t - Duration::from_millis(500)
                && matches!(e, MotorEvent::Drive(c) if !c.is_stop()))
    );
    say(&mut ws, r#"{"type":"mode","mode":"manual"}"#).await;
    let before = drove(&rig.events(), WheelCommand::new(0.5, 0.5));
    drive_for(&mut ws, &rig.clock, 1.0, 0.6).await;
    assert!(drove(&rig.events(), WheelCommand::new(0.5, 0.5)) > before);
    drop(ws);
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_that_closes_stops_the_motors() {
    let rig = Rig::start(open_cfg(), false).await;
    let mut ws = rig.ws(None).await.unwrap();
    drive_for(&mut ws, &rig.clock, 0.6, 1.0).await;
    let w = WheelCommand::new(0.3, 0.3);
    assert!(drove(&rig.events(), w) >= 5);
    let closed = rig.clock.now();
    ws.close(None).await.unwrap();
    drop(ws);
    tokio::time::sleep(Duration::from_millis(800)).await;
    let (stop, moved) = stop_after(&rig.events(), closed);
    let after = stop.saturating_sub(closed);
    eprintln!("stop written {after:?} after the page closed");
    // The deadline is 0.5 s + one watchdog period; a close is seen at once, not by the
    // heartbeat's timeout.
    assert!(
        after <= HEARTBEAT + WATCHDOG,
        "stopped {after:?} after the close"
    );
    assert!(
        after < WATCHDOG,
        "the close was not seen at once: {after:?}"
    );
    assert!(!moved);
    let s = rig.finish().await;
    assert_eq!(s.mode, "stopped");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slider_changes_the_gains_the_autopilot_drives_with_and_save_writes_them() {
    let mut rig = Rig::start(open_cfg(), false).await;
    let mut ws = rig.ws(None).await.unwrap();
    say(&mut ws, r#"{"type":"mode","mode":"auto"}"#).await;
    // The null policy points straight ahead: both wheels get speed_gain.
    for _ in 0..8 {
        say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        drove(&rig.events(), WheelCommand::new(0.3, 0.3)) >= 3,
        "{:?}",
        &rig.events()
    );
    say(&mut ws, r#"{"type":"gains","speed_gain":0.45,"steering_gain":0.25,"steering_kd":0.01,"steering_bias":0.0,"steering_ki":0.0}"#).await;
    let s = rig
        .wait_status(2.0, |s| (s.gains.speed_gain - 0.45).abs() < 1e-6)
        .await;
    assert_eq!(s.gains.steering_gain, 0.25);
    assert_eq!(s.mode, "auto");
    for _ in 0..8 {
        say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        drove(&rig.events(), WheelCommand::new(0.45, 0.45)) >= 3,
        "the autopilot did not take the new speed_gain"
    );
    // Out of range is clamped to the config's range.
    say(&mut ws, r#"{"type":"gains","speed_gain":3.0,"steering_gain":0.25,"steering_kd":0.01,"steering_bias":0.0,"steering_ki":0.0}"#).await;
    rig.wait_status(2.0, |s| s.gains.speed_gain == 1.0).await;
    say(&mut ws, r#"{"type":"gains","speed_gain":0.45,"steering_gain":0.25,"steering_kd":0.01,"steering_bias":0.0,"steering_ki":0.0}"#).await;
    rig.wait_status(2.0, |s| s.gains.speed_gain == 0.45).await;
    // Save: the config file gets the gains, its comment kept.
    say(&mut ws, r#"{"type":"save"}"#).await;
    let reply = loop {
        let m = tokio::time::timeout(Duration::from_secs(5), ws.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        let t = m.to_text().unwrap().to_string();
        if t.contains("\"saved\"") || t.contains("\"error\"") {
            break t;
        }
    };
    assert!(reply.contains("\"saved\""), "{reply}");
    let text = std::fs::read_to_string(rig._dir.path().join("robot.toml")).unwrap();
    assert!(text.contains("speed_gain = 0.45 # base speed"), "{text}");
    assert!(text.contains("steering_gain = 0.25"), "{text}");
    // A second page watches: its control messages are refused, its emergency stop is not.
    let mut other = rig.ws(None).await.unwrap();
    say(&mut other, r#"{"type":"mode","mode":"manual"}"#).await;
    let refused = loop {
        let m = tokio::time::timeout(Duration::from_secs(5), other.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        let t = m.to_text().unwrap().to_string();
        if t.contains("\"error\"") {
            break t;
        }
    };
    assert!(refused.contains("holds the controls"), "{refused}");
    assert_eq!(rig.status.borrow().mode, "auto");
    say(&mut other, r#"{"type":"estop"}"#).await;
    let s = rig.wait_status(2.0, |s| s.mode == "stopped").await;
    assert_eq!(
        s.interventions, 1,
        "an emergency stop in Auto is an intervention"
    );
    drop(other);
    drop(ws);
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_that_never_read_cost_the_control_loop_nothing() {
    let mut rig = Rig::start(
        WebConfig {
            video_fps: 30.0,
            jpeg_quality: 95,
            ..open_cfg()
        },
        true,
    )
    .await;
    let mut ws = rig.ws(None).await.unwrap();
    say(&mut ws, r#"{"type":"mode","mode":"auto"}"#).await;
    // Three video clients with tiny receive buffers that never read a byte, and a
    // WebSocket that never reads its status messages.
    let mut stuck = Vec::new();
    for _ in 0..3 {
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.set_recv_buffer_size(2048).unwrap();
        let mut s = sock.connect(rig.addr).await.unwrap();
        s.write_all(get("/video", "").as_bytes()).await.unwrap();
        stuck.push(s);
    }
    let deaf = rig.ws(None).await.unwrap();
    let start = rig.clock.now();
    for _ in 0..30 {
        say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let end = rig.clock.now();
    let s = rig.wait_status(2.0, |_| true).await;
    assert_eq!(s.watchdog_stops, 0);
    assert_eq!(s.mode, "auto");
    // Commands kept coming at the camera's pace (20 fps): no gap near the watchdog.
    let writes: Vec<Duration> = rig
        .events()
        .iter()
        .filter(|(at, e)| {
            *at > start + Duration::from_millis(300)
                && *at < end
                && matches!(e, MotorEvent::Drive(_))
        })
        .map(|(at, _)| *at)
        .collect();
    let span = end
        .saturating_sub(start + Duration::from_millis(300))
        .as_secs_f32();
    assert!(
        writes.len() as f32 >= span * 20.0 * 0.6,
        "{} writes in {span:.1} s",
        writes.len()
    );
    let gap = writes.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert!(gap < WATCHDOG, "a {gap:?} gap between motor writes");
    drop(stuck);
    drop(deaf);
    drop(ws);
    rig.finish().await;
}

/// Reads until the server closes the connection (EOF or reset); the time it took, or `None`
/// if it was still open after `secs`.
async fn closed_within(s: &mut TcpStream, secs: f32) -> Option<Duration> {
    let t0 = tokio::time::Instant::now();
    let deadline = t0 + Duration::from_secs_f32(secs);
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match tokio::time::timeout_at(deadline, s.read(&mut buf)).await {
            Err(_) => return None,
            Ok(Ok(0)) | Ok(Err(_)) => return Some(t0.elapsed()),
            Ok(Ok(_)) => {}
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_stalled_and_oversized_clients_are_closed_and_the_page_still_answers() {
    let mut rig = Rig::start(
        WebConfig {
            max_connections: 3,
            request_timeout_ms: 400,
            stall_timeout_ms: 500,
            max_message_bytes: 1024,
            video_fps: 30.0,
            jpeg_quality: 95,
            ..open_cfg()
        },
        true,
    )
    .await;
    // Slowloris: three requests that never end take every connection...
    let mut slow = Vec::new();
    for _ in 0..3 {
        let mut s = TcpStream::connect(rig.addr).await.unwrap();
        s.write_all(b"GET / HTTP/1.1\r\nHost: 1").await.unwrap();
        slow.push(s);
    }
    tokio::time::sleep(Duration::from_millis(50)).await;
    // ... so a real request waits for a slot, which the request limit frees.
    let t0 = tokio::time::Instant::now();
    let (code, _) = http(rig.addr, &get("/api/status", "")).await;
    let waited = t0.elapsed();
    assert_eq!(code, 200);
    assert!(
        waited >= Duration::from_millis(250) && waited < Duration::from_secs(3),
        "answered after {waited:?}"
    );
    for s in &mut slow {
        let closed = closed_within(s, 2.0).await;
        assert!(closed.is_some(), "a slow request was kept open");
    }

    // Garbage instead of HTTP: closed, and the server goes on.
    let mut junk = TcpStream::connect(rig.addr).await.unwrap();
    junk.write_all(&[0xff; 4096]).await.unwrap();
    assert!(closed_within(&mut junk, 2.0).await.is_some());

    // A video client that never reads (a tiny receive window, as a phone that left the
    // Wi-Fi): its sends stall and it is closed, not left holding the encoder.
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.set_recv_buffer_size(2048).unwrap();
    let mut gone = sock.connect(rig.addr).await.unwrap();
    gone.write_all(get("/video", "").as_bytes()).await.unwrap();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let closed = closed_within(&mut gone, 3.0).await;
    assert!(closed.is_some(), "a stalled video client was kept open");

    // A WebSocket message over web.max_message_bytes closes that socket.
    let mut big = rig.ws(None).await.unwrap();
    big.send(Message::Text("x".repeat(2000).into()))
        .await
        .unwrap();
    let ended = tokio::time::timeout(Duration::from_secs(2), async {
        loop {
            match big.next().await {
                None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return,
                Some(Ok(_)) => {}
            }
        }
    })
    .await;
    assert!(ended.is_ok(), "an oversized message was taken");

    // After all that: a page connects and hears its hello, and the control loop never
    // missed its watchdog.
    let mut ws = rig.ws(None).await.unwrap();
    let hello = tokio::time::timeout(Duration::from_secs(2), ws.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert!(hello.to_text().unwrap().contains("hello"), "{hello:?}");
    let s = rig.wait_status(2.0, |_| true).await;
    assert_eq!(s.watchdog_stops, 0);
    drop(ws);
    rig.finish().await;
}

/// This process's resident memory, kB (`/proc/self/status`).
fn rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// Issue 51's load, bounded: 20 video clients reading, 5 sockets flooding messages, 50
/// requests that never end and garbage every 100 ms, all on loopback. Meanwhile the
/// autopilot's motor writes keep their cadence, and the page holding the controls that
/// falls silent is still stopped by the dead-man in time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn under_load_the_autopilot_keeps_its_cadence_and_a_silent_holder_is_still_stopped() {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    let mut rig = Rig::start(
        WebConfig {
            max_connections: 128,
            video_fps: 30.0,
            ..open_cfg()
        },
        true,
    )
    .await;
    let addr = rig.addr;
    // This page holds the controls before the load starts (the flooders' messages are then
    // refused) and keeps them with a heartbeat between the load's steps.
    let mut ws = rig.ws(None).await.unwrap();
    say(&mut ws, r#"{"type":"mode","mode":"auto"}"#).await;
    // Taken before any flooder connects: on a busy machine a flooder's first message could
    // otherwise reach the daemon first and hold the controls (seen once in CI).
    rig.wait_status(10.0, |s| s.mode == "auto").await;
    let done = Arc::new(AtomicBool::new(false));
    let video_bytes = Arc::new(AtomicU64::new(0));
    let flood_sent = Arc::new(AtomicU64::new(0));
    let mut load = Vec::new();
    for _ in 0..20 {
        say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        let (done, bytes) = (done.clone(), video_bytes.clone());
        load.push(tokio::spawn(async move {
            let mut s = TcpStream::connect(addr).await.unwrap();
            s.write_all(get("/video", "").as_bytes()).await.unwrap();
            let mut buf = vec![0u8; 1 << 16];
            while !done.load(Ordering::Relaxed) {
                match tokio::time::timeout(Duration::from_millis(200), s.read(&mut buf)).await {
                    Ok(Ok(0)) | Ok(Err(_)) => break,
                    Ok(Ok(n)) => {
                        bytes.fetch_add(n as u64, Ordering::Relaxed);
                    }
                    Err(_) => {}
                }
            }
        }));
    }
    for k in 0..5 {
        say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        let (done, sent) = (done.clone(), flood_sent.clone());
        let ws = rig.ws(None).await.unwrap();
        load.push(tokio::spawn(async move {
            let (mut tx, mut rx) = ws.split();
            let drain = tokio::spawn(async move { while let Some(Ok(_)) = rx.next().await {} });
            let msgs = [
                r#"{"type":"heartbeat"}"#,
                r#"{"type":"bogus"}"#,
                "not json at all",
                r#"{"type":"gains","speed_gain":9}"#,
            ];
            let mut i = k;
            while !done.load(Ordering::Relaxed) {
                if tx
                    .send(Message::Text(msgs[i % msgs.len()].into()))
                    .await
                    .is_err()
                {
                    break;
                }
                sent.fetch_add(1, Ordering::Relaxed);
                i += 1;
                if i % 64 == 0 {
                    tokio::task::yield_now().await;
                }
            }
            drain.abort();
        }));
    }
    let mut stalled = Vec::new();
    for k in 0..50 {
        if k % 10 == 0 {
            say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        }
        let mut s = TcpStream::connect(addr).await.unwrap();
        s.write_all(b"GET /api/status HTTP/1.1\r\nHo")
            .await
            .unwrap();
        stalled.push(s);
    }
    {
        let done = done.clone();
        load.push(tokio::spawn(async move {
            while !done.load(Ordering::Relaxed) {
                if let Ok(mut s) = TcpStream::connect(addr).await {
                    let _ = s.write_all(&[0x16, 0x03, 0x01, 0xff, 0x00, 0x13]).await;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }));
    }
    let rss_loaded = rss_kb();

    // The autopilot under that load, its page sending heartbeats.
    say(&mut ws, r#"{"type":"heartbeat"}"#).await;
    assert_eq!(
        rig.wait_status(2.0, |s| s.mode == "auto").await.mode,
        "auto"
    );
    let start = rig.clock.now();
    for _ in 0..30 {
        say(&mut ws, r#"{"type":"heartbeat"}"#).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let end = rig.clock.now();
    let writes: Vec<Duration> = rig
        .events()
        .iter()
        .filter(|(at, e)| *at > start && *at < end && matches!(e, MotorEvent::Drive(_)))
        .map(|(at, _)| *at)
        .collect();
    let span = (end - start).as_secs_f32();
    assert!(
        writes.len() as f32 >= span * 20.0 * 0.6,
        "{} motor writes in {span:.1} s under load",
        writes.len()
    );
    let gap = writes.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    eprintln!(
        "under load: {} motor writes in {span:.1} s, largest gap {gap:?}",
        writes.len()
    );
    assert!(
        gap < WATCHDOG,
        "a {gap:?} gap between motor writes under load"
    );

    // The page takes the wheels, then falls silent with its socket open.
    say(&mut ws, r#"{"type":"mode","mode":"manual"}"#).await;
    let last = drive_for(&mut ws, &rig.clock, 1.0, 1.0).await;
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let (stop, moved) = stop_after(&rig.events(), last);
    let after = stop.saturating_sub(last);
    eprintln!("under load: stop written {after:?} after the page's last message");
    assert!(
        after <= HEARTBEAT + WATCHDOG,
        "stopped {after:?} after the last message"
    );
    assert!(!moved, "the motors moved after the dead-man stop");

    done.store(true, Ordering::Relaxed);
    for t in load {
        let _ = tokio::time::timeout(Duration::from_secs(3), t).await;
    }
    drop(stalled);
    let rss_end = rss_kb();
    eprintln!(
        "video {} kB read, {} flood messages sent, RSS {rss_loaded} kB loaded -> {rss_end} kB",
        video_bytes.load(Ordering::Relaxed) / 1024,
        flood_sent.load(Ordering::Relaxed)
    );
    assert!(
        video_bytes.load(Ordering::Relaxed) > 0,
        "no video reached the clients"
    );
    assert!(flood_sent.load(Ordering::Relaxed) > 1000);
    // Bounded: the load's connections hold no queues that grow.
    assert!(
        rss_end < rss_loaded + 64 * 1024,
        "RSS grew from {rss_loaded} to {rss_end} kB"
    );
    let s = rig.wait_status(2.0, |_| true).await;
    assert_eq!(s.watchdog_stops, 0);
    drop(ws);
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn another_sites_page_gets_nothing_even_with_the_cookie() {
    let state = tempfile::tempdir().unwrap();
    let rig = Rig::start(token_cfg(state.path()), false).await;
    let token = rig.token.clone().expect("a token");
    let port = rig.addr.port();
    let upgrade = |origin: &str| {
        format!(
            "GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: {origin}\r\nCookie: jetpilot_token={token}\r\nConnection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
        )
    };
    for origin in [
        "http://evil.example".to_string(),
        "null".into(),
        format!("http://localhost:{port}"),
    ] {
        let (code, head) = http(rig.addr, &upgrade(&origin)).await;
        assert_eq!(code, 403, "{origin}: {head}");
    }
    let (code, _) = http(rig.addr, &upgrade(&format!("http://127.0.0.1:{port}"))).await;
    assert_eq!(code, 101);
    // Login CSRF: another site's form posting a token gets no cookie.
    let body = format!("token={token}");
    let post = format!(
        "POST /login HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: http://evil.example\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let (code, head) = http(rig.addr, &post).await;
    assert_eq!(code, 403);
    assert!(!head.to_ascii_lowercase().contains("set-cookie"), "{head}");
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_without_the_token_keeps_no_connection_open() {
    let state = tempfile::tempdir().unwrap();
    let rig = Rig::start(token_cfg(state.path()), false).await;
    // Keep-alive requests (no `Connection: close` from the client): answered, then closed.
    for path in ["/login", "/api/status", "/nowhere"] {
        let mut s = TcpStream::connect(rig.addr).await.unwrap();
        s.write_all(format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").as_bytes())
            .await
            .unwrap();
        assert!(
            closed_within(&mut s, 2.0).await.is_some(),
            "{path}: left open"
        );
    }
    // With the token the connection stays open for the next request.
    let token = rig.token.clone().unwrap();
    let mut s = TcpStream::connect(rig.addr).await.unwrap();
    s.write_all(
        format!(
            "GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n\r\n"
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    assert!(
        closed_within(&mut s, 1.0).await.is_none(),
        "an authorised keep-alive was closed"
    );
    drop(s);
    rig.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_other_site_may_frame_the_page() {
    let rig = Rig::start(open_cfg(), false).await;
    for path in ["/", "/login"] {
        let (code, head) = http(rig.addr, &get(path, "")).await;
        assert_eq!(code, 200, "{path}");
        let head = head.to_ascii_lowercase();
        for h in [
            "x-frame-options: deny",
            "content-security-policy: frame-ancestors 'none'",
            "x-content-type-options: nosniff",
        ] {
            assert!(head.contains(h), "{path}: no {h}: {head}");
        }
    }
    rig.finish().await;
}

/// Unmounts a file system when dropped.
struct Mounted(std::path::PathBuf);

impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_while_recording_keeps_the_tub_and_the_page_says_why() {
    use jetpilot::dataset::tub::{TubInputs, TubReader, TubWriter};
    use jetpilot::drive::recorder::Recorder;
    // A real full file system: a 1 MiB tmpfs. Mounting needs root (CI's machine is); where
    // it is refused the test says so and has nothing to check.
    let mnt = tempfile::tempdir().unwrap();
    let mounted = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=1m", "tmpfs"])
        .arg(mnt.path())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        eprintln!("SKIPPED: cannot mount a tmpfs here (not root?)");
        return;
    }
    let _unmount = Mounted(mnt.path().to_path_buf());
    let tub_dir = mnt.path().join("tub");
    let tub = TubWriter::create(&tub_dir, &TubInputs::ALL, 1.0e9).unwrap();
    let recorder = Recorder::start(Box::new(tub), 1_000_000, None).unwrap();
    // Noise frames (320x240) make JPEGs of tens of KB: the card is full within seconds.
    let rig = Rig::start_with(open_cfg(), true, Some(recorder)).await;
    let mut ws = rig.ws(None).await.unwrap();
    say(&mut ws, r#"{"type":"record","on":true}"#).await;
    let mut full = None;
    for _ in 0..100 {
        drive_for(&mut ws, &rig.clock, 0.6, 0.2).await;
        let s = rig.status.borrow().clone();
        if s.record_error.is_some() {
            full = Some(s);
            break;
        }
    }
    let s = full.expect("the 1 MiB card never filled");
    let why = s.record_error.clone().unwrap();
    eprintln!("{} records, then: {why}", s.records);
    assert!(why.contains("No space left on device"), "{why}");
    assert!(
        why.contains(&*mnt.path().to_string_lossy()),
        "names the file: {why}"
    );
    assert!(!s.recording, "the page still says recording");
    assert!(s.records > 0, "nothing was recorded before the card filled");
    // Driving goes on: the page's sticks still reach the motors.
    let before = rig.clock.now();
    drive_for(&mut ws, &rig.clock, 0.6, 0.5).await;
    let w = WheelCommand::new(0.3, 0.3);
    let after: Vec<_> = rig
        .events()
        .into_iter()
        .filter(|(t, _)| *t > before)
        .collect();
    assert!(drove(&after, w) >= 2, "no driving after the card filled");
    drop(ws);
    let end = rig.finish().await;
    // Everything written before the card filled reads back.
    let tub = TubReader::open(&tub_dir).unwrap();
    assert_eq!(tub.records().count() as u64, end.records);
}
