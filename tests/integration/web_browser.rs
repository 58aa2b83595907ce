//! The web page in a real browser: Debian's Chromium, headless, driven through chromedriver
//! (WebDriver, with fantoccini), against `jetpilot run` on the demo's frames with virtual
//! motors and the token required. It logs in with the token link, sees video frames
//! arrive, moves a slider and checks the daemon's gain, drives forward with the keyboard,
//! and closes the tab: the motors must stop. A screenshot goes to
//! `target/web-page.png` (or `$JETPILOT_WEB_SCREENSHOT`).
//!
//! Needs `chromium` and `chromium-driver` (scripts/install-build-deps.sh installs them).

use crate::common;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::actions::{InputSource, KeyAction, KeyActions};
use fantoccini::{ClientBuilder, Locator};
use serde_json::{Value, json};

/// Kills the child when dropped (a failed test leaves no daemon or driver behind).
struct Reaped(Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn wait_for(what: &str, secs: u64, mut ok: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !ok() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// GET `path` with the bearer token; the body parsed as JSON.
fn status(addr: SocketAddr, token: &str) -> Value {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "GET /api/status HTTP/1.1\r\nHost: robot\r\nAuthorization: Bearer {token}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let body = text.split("\r\n\r\n").nth(1).unwrap_or("");
    serde_json::from_str(body).unwrap_or_else(|e| panic!("{e}: {text}"))
}

/// The motor log's lines (JSON: `{"t","left","right"}` or `{"t","stop":true}`).
fn motor_log(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn chromium() -> (PathBuf, PathBuf) {
    let find = |names: &[&str]| {
        names
            .iter()
            .map(PathBuf::from)
            .find(|p| p.exists())
            .unwrap_or_else(|| panic!("none of {names:?}: run scripts/install-build-deps.sh (Debian's chromium and chromium-driver)"))
    };
    (
        find(&["/usr/bin/chromium", "/usr/bin/chromium-browser"]),
        find(&["/usr/bin/chromedriver", "/usr/lib/chromium/chromedriver"]),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_person_in_a_browser_sees_video_tunes_drives_and_the_motors_stop_when_the_tab_closes() {
    let (browser, driver) = chromium();
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 96, 1);
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let web_port = free_port();
    let motors = dir.path().join("motors.jsonl");
    let token_file = dir.path().join("state/web-token");
    let config = dir.path().join("robot.toml");
    std::fs::write(
        &config,
        format!(
            r#"[camera]
source = "folder"
path = "{frames}"
fps = 15.0
loop = true

[model]
path = "{model}"

[control]
speed_gain = 0.2   # JetBot's slider
steering_gain = 0.2

[motors]
backend = "log"
log_path = "{motors}"

[web]
enabled = true
bind = "127.0.0.1:{web_port}"
require_token = true
token_path = "{token}"
"#,
            frames = repo.join("config/samples/road").display(),
            model = model.display(),
            motors = motors.display(),
            token = token_file.display(),
        ),
    )
    .unwrap();

    let daemon = Reaped(
        Command::new(env!("CARGO_BIN_EXE_jetpilot"))
            .args(["run", "--config"])
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.path().join("daemon.log")).unwrap())
            .spawn()
            .unwrap(),
    );
    let addr = SocketAddr::from(([127, 0, 0, 1], web_port));
    wait_for("the daemon's web page", 60, || {
        token_file.exists() && TcpStream::connect(addr).is_ok()
    });
    let token = std::fs::read_to_string(&token_file)
        .unwrap()
        .trim()
        .to_string();
    let log = std::fs::read_to_string(dir.path().join("daemon.log")).unwrap();
    assert!(
        log.contains(&token),
        "the token is printed once to the log: {log}"
    );

    let driver_port = free_port();
    let _driver = Reaped(
        Command::new(&driver)
            .arg(format!("--port={driver_port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_for("chromedriver", 30, || {
        TcpStream::connect(("127.0.0.1", driver_port)).is_ok()
    });
    let profile = dir.path().join("chromium-profile");
    let mut caps = serde_json::Map::new();
    caps.insert(
        "goog:chromeOptions".into(),
        json!({
            "binary": browser,
            "args": [
                "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--disable-background-networking", "--disable-component-update",
                "--disable-sync", "--no-first-run", "--window-size=1100,1000",
                format!("--user-data-dir={}", profile.display()),
            ],
        }),
    );
    let client = ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&format!("http://127.0.0.1:{driver_port}"))
        .await
        .expect("chromedriver session");

    // Log in with the token link: the cookie is set and the page loads.
    client
        .goto(&format!("http://{addr}/?token={token}"))
        .await
        .unwrap();
    assert_eq!(client.current_url().await.unwrap().path(), "/");
    client
        .wait()
        .for_element(Locator::Id("estop"))
        .await
        .unwrap();

    // Video: the <img> shows frames, and they change (the replayed road moves).
    let frame_hash = r#"
        const img = document.getElementById('video');
        if (!img.naturalWidth) return null;
        const c = document.createElement('canvas');
        c.width = img.naturalWidth; c.height = img.naturalHeight;
        const g = c.getContext('2d'); g.drawImage(img, 0, 0);
        const d = g.getImageData(0, 0, c.width, c.height).data;
        let h = 0; for (let i = 0; i < d.length; i += 7) h = (h * 31 + d[i]) % 1000000007;
        return h;"#;
    let mut hashes = std::collections::HashSet::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while hashes.len() < 3 {
        assert!(
            Instant::now() < deadline,
            "video frames did not arrive: {hashes:?}"
        );
        if let Some(h) = client.execute(frame_hash, vec![]).await.unwrap().as_u64() {
            hashes.insert(h);
        }
        tokio::time::sleep(Duration::from_millis(150)).await;
    }
    // The status read-outs are live.
    let stats = client
        .find(Locator::Id("stats"))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(stats.contains("frames captured"), "{stats}");

    // A slider: a click in the middle of speed_gain (0..1) sets about 0.5.
    assert!(
        (status(addr, &token)["gains"]["speed_gain"]
            .as_f64()
            .unwrap()
            - 0.2)
            .abs()
            < 1e-6
    );
    client
        .find(Locator::Id("speed_gain"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    let shown: f64 = client
        .execute(
            "return Number(document.getElementById('speed_gain').value)",
            vec![],
        )
        .await
        .unwrap()
        .as_f64()
        .unwrap();
    assert!((shown - 0.5).abs() < 0.05, "the slider shows {shown}");
    let t0 = Instant::now();
    loop {
        let g = status(addr, &token)["gains"]["speed_gain"]
            .as_f64()
            .unwrap();
        if (g - shown).abs() < 1e-4 {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "the daemon's speed_gain is {g}, the slider {shown}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(
        status(addr, &token)["controls"],
        "taken",
        "this page holds the controls"
    );

    // Drive forward in Manual: hold W for 1.5 s (full throttle: 0.5 on both wheels).
    let before = motor_log(&motors).len();
    let keys = KeyActions::new("keyboard".into())
        .then(KeyAction::Down { value: 'w' })
        .pause(Duration::from_millis(1500))
        .then(KeyAction::Up { value: 'w' });
    client.perform_actions(keys).await.unwrap();
    let forward = motor_log(&motors)[before..]
        .iter()
        .filter(|v| v["left"].as_f64() == Some(0.5) && v["right"].as_f64() == Some(0.5))
        .count();
    assert!(forward >= 5, "{forward} forward commands while W was held");

    let shot = client.screenshot().await.unwrap();
    let out = std::env::var_os("JETPILOT_WEB_SCREENSHOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo.join("target/web-page.png"));
    std::fs::write(&out, &shot).unwrap();
    assert!(image::load_from_memory(&shot).unwrap().width() > 500);

    // Drive again, then close the tab while driving: the motors stop at once.
    let keys = KeyActions::new("keyboard".into()).then(KeyAction::Down { value: 'w' });
    client.perform_actions(keys).await.unwrap();
    tokio::time::sleep(Duration::from_millis(600)).await;
    let driving = motor_log(&motors).last().cloned().unwrap();
    assert_eq!(driving["left"].as_f64(), Some(0.5), "{driving}");
    client.close().await.unwrap();
    let closed = Instant::now();
    wait_for("the motors to stop after the tab closed", 5, || {
        motor_log(&motors).last().is_some_and(|v| v["stop"] == true)
    });
    let waited = closed.elapsed();
    assert!(
        waited < Duration::from_millis(700),
        "stopped {waited:?} after the tab closed"
    );
    assert_eq!(status(addr, &token)["mode"], "stopped");
    drop(daemon);
}
