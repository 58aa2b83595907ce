//! The web page in a real browser: Debian's Chromium, headless, driven through chromedriver
//! (WebDriver, with fantoccini), against `jetpilot run` on the demo's frames with virtual
//! motors and the token required. It logs in with the token link, sees video frames
//! arrive, moves a slider and checks the daemon's gain, drives forward with the keyboard,
//! and closes the tab: the motors must stop. A screenshot goes to
//! `target/web-page.png` (or `$JETPILOT_WEB_SCREENSHOT`).
//!
//! And as a phone: a 390 px wide touch screen, where the layout must fit, a tap on the video
//! saves JetBot's xy sample of the frame on screen (undo, free/blocked, a missing drive),
//! and the drive pad drives by touch. Its screenshot: `target/web-phone.png`.
//!
//! Needs `chromium` and `chromium-driver` (scripts/install-build-deps.sh installs them).

use crate::common;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::actions::{
    InputSource, KeyAction, KeyActions, MOUSE_BUTTON_LEFT, PointerAction, TouchActions,
};
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
        "GET /api/status HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\nConnection: close\r\n\r\n"
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

/// A daemon on the demo's frames with virtual motors (a log) and the web page.
struct Robot {
    _daemon: Reaped,
    addr: SocketAddr,
    motors: PathBuf,
}

/// Starts `jetpilot run` in `dir` with `web` appended to the `[web]` table.
fn start_robot(dir: &Path, web: &str) -> Robot {
    let model = common::write_model(dir, 96, 1);
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let web_port = free_port();
    let motors = dir.join("motors.jsonl");
    let config = dir.join("robot.toml");
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
{web}
"#,
            frames = repo.join("config/samples/road").display(),
            model = model.display(),
            motors = motors.display(),
        ),
    )
    .unwrap();
    let daemon = Reaped(
        Command::new(env!("CARGO_BIN_EXE_jetpilot"))
            .args(["run", "--config"])
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("daemon.log")).unwrap())
            .spawn()
            .unwrap(),
    );
    let addr = SocketAddr::from(([127, 0, 0, 1], web_port));
    Robot {
        _daemon: daemon,
        addr,
        motors,
    }
}

/// Headless Chromium through chromedriver; `options` join `goog:chromeOptions`.
async fn browser(dir: &Path, window: (u32, u32), options: Value) -> (Reaped, fantoccini::Client) {
    let (browser, driver) = chromium();
    let driver_port = free_port();
    let driver = Reaped(
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
    let profile = dir.join("chromium-profile");
    let mut chrome = json!({
        "binary": browser,
        "args": [
            "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
            "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--no-first-run",
            format!("--window-size={},{}", window.0, window.1),
            format!("--user-data-dir={}", profile.display()),
        ],
    });
    if let (Some(c), Value::Object(extra)) = (chrome.as_object_mut(), options) {
        c.extend(extra);
    }
    let mut caps = serde_json::Map::new();
    caps.insert("goog:chromeOptions".into(), chrome);
    let client = ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&format!("http://127.0.0.1:{driver_port}"))
        .await
        .expect("chromedriver session");
    (driver, client)
}

fn screenshot_path(var: &str, default: &str) -> PathBuf {
    std::env::var_os(var)
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(default))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_person_in_a_browser_sees_video_tunes_drives_and_the_motors_stop_when_the_tab_closes() {
    let dir = tempfile::tempdir().unwrap();
    let token_file = dir.path().join("state/web-token");
    let robot = start_robot(
        dir.path(),
        &format!(
            "require_token = true\ntoken_path = \"{}\"",
            token_file.display()
        ),
    );
    let (addr, motors) = (robot.addr, robot.motors.clone());
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
    let (_driver, client) = browser(dir.path(), (1100, 1000), json!({})).await;

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
    let out = screenshot_path("JETPILOT_WEB_SCREENSHOT", "target/web-page.png");
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
    drop(robot);
}

/// The page's `#msg` and `#labelcount` texts.
async fn page_text(client: &fantoccini::Client, id: &str) -> String {
    client
        .execute(
            &format!("return document.getElementById('{id}').textContent"),
            vec![],
        )
        .await
        .unwrap()
        .as_str()
        .unwrap_or("")
        .to_string()
}

/// A tap (touch down and up) at `(dx, dy)` CSS px from the centre of the element with this
/// CSS selector. Relative to an element, so chromedriver scrolls it into view and measures
/// it itself (viewport points land elsewhere under touch emulation once the page scrolled).
async fn tap_on(client: &fantoccini::Client, selector: &str, dx: f64, dy: f64) {
    let element = client.find(Locator::Css(selector)).await.unwrap();
    let touch = TouchActions::new("finger".into())
        .then(PointerAction::MoveToElement {
            element,
            duration: None,
            x: dx.round(),
            y: dy.round(),
        })
        .then(PointerAction::Down {
            button: MOUSE_BUTTON_LEFT,
        })
        .then(PointerAction::Pause {
            duration: Duration::from_millis(50),
        })
        .then(PointerAction::Up {
            button: MOUSE_BUTTON_LEFT,
        });
    client.perform_actions(touch).await.unwrap();
}

/// `[left, top, width, height]` of the element in the viewport.
async fn rect(client: &fantoccini::Client, selector: &str) -> [f64; 4] {
    let v = client
        .execute(
            "const e = document.querySelector(arguments[0]);
             const r = e.getBoundingClientRect();
             return [r.left, r.top, r.width, r.height];",
            vec![json!(selector)],
        )
        .await
        .unwrap();
    let n = |i: usize| v[i].as_f64().unwrap();
    [n(0), n(1), n(2), n(3)]
}

fn files_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.path()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_a_phone_a_tap_on_the_video_saves_the_frame_shown_as_a_jetbot_xy_sample_and_the_pad_drives()
 {
    let dir = tempfile::tempdir().unwrap();
    let xy = dir.path().join("dataset_xy");
    // The collision folder is on a "USB stick" that is not mounted yet.
    let stick = dir.path().join("stick");
    let robot = start_robot(
        dir.path(),
        &format!(
            "overlay = false\nxy_dir = \"{}\"\ncollision_dir = \"{}\"",
            xy.display(),
            stick.join("dataset").display()
        ),
    );
    let addr = robot.addr;
    wait_for("the daemon's web page", 60, || {
        TcpStream::connect(addr).is_ok()
    });
    // A phone's width, 390 CSS px, with touch; tall enough that the whole page shows without
    // scrolling (the screenshot shows all of it, and under touch emulation a touch after a
    // scroll lands off its mark).
    let phone = json!({"mobileEmulation": {"deviceMetrics":
        {"width": 390, "height": 2000, "pixelRatio": 2.0, "touch": true}}});
    let (_driver, client) = browser(dir.path(), (390, 2000), phone).await;
    client.goto(&format!("http://{addr}/")).await.unwrap();
    wait_for_js(
        &client,
        "the first video frame",
        "return document.getElementById('video').naturalWidth > 0",
    )
    .await;

    // The layout fits: nothing wider than the screen, the video fills the column.
    let fit = client
        .execute(
            "return [document.documentElement.scrollWidth, window.innerWidth,
                     document.documentElement.scrollHeight, window.innerHeight,
                     document.getElementById('video').getBoundingClientRect().width,
                     document.getElementById('estop').getBoundingClientRect().right]",
            vec![],
        )
        .await
        .unwrap();
    let f = |i: usize| fit[i].as_f64().unwrap();
    assert_eq!(f(1), 390.0, "the viewport is a phone's: {fit}");
    assert!(f(0) <= f(1), "the page scrolls sideways on a phone: {fit}");
    assert!(
        f(2) <= f(3),
        "the page is taller than the test's screen: {fit}"
    );
    assert!(
        f(4) > 300.0 && f(4) <= 390.0,
        "the video is {} px wide",
        f(4)
    );
    assert!(f(5) <= 390.0, "STOP is cut off: {fit}");
    let shot = client.screenshot().await.unwrap();
    std::fs::write(
        screenshot_path("JETPILOT_WEB_PHONE_SCREENSHOT", "target/web-phone.png"),
        &shot,
    )
    .unwrap();
    assert_eq!(image::load_from_memory(&shot).unwrap().width(), 780);
    wait_for_js(
        &client,
        "the label counts",
        "return document.getElementById('labelcount').textContent === 'xy 0 · free 0 · blocked 0'",
    )
    .await;

    // Tap the centre of picture pixel (150, 60): the sample is xy_150_060_<uuid1>.jpg and
    // holds the very JPEG the page showed when tapped (the overlay is off).
    let v = rect(&client, "#video").await;
    let (w, h) = (224.0, 168.0); // config/samples/road
    let scale = (v[2] / w).min(v[3] / h);
    // From the element's centre (the picture is centred in it: object-fit: contain).
    let at = |px: f64, py: f64| ((px + 0.5 - w / 2.0) * scale, (py + 0.5 - h / 2.0) * scale);
    let (x, y) = at(150.0, 60.0);
    tap_on(&client, "#video", x, y).await;
    wait_for_js(
        &client,
        "the xy sample",
        "return document.getElementById('msg').textContent.startsWith('saved ')",
    )
    .await;
    assert_eq!(files_in(&xy).len(), 1, "{:?}", files_in(&xy));
    let sample = files_in(&xy).remove(0);
    let name = sample.file_name().unwrap().to_string_lossy().to_string();
    assert!(
        name.starts_with("xy_150_060_") && name.ends_with(".jpg"),
        "{name}"
    );
    assert!(
        jetpilot::dataset::jetbot_xy::capture_time_s(&name).is_some(),
        "{name}: a uuid1, as JetBot's notebook names samples"
    );
    let shown: Vec<u8> = client
        .execute(
            "return window.lastLabel.blob.arrayBuffer().then(a => Array.from(new Uint8Array(a)))",
            vec![],
        )
        .await
        .unwrap()
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_u64().unwrap() as u8)
        .collect();
    assert_eq!(
        std::fs::read(&sample).unwrap(),
        shown,
        "the file is the frame shown"
    );
    wait_for_js(
        &client,
        "the count after a tap",
        "return document.getElementById('labelcount').textContent.startsWith('xy 1 ')",
    )
    .await;

    // A tap while the next frame is still loading labels the frame on screen. Chromium's
    // naturalWidth is 0 from a src swap until the new frame decodes, which the page does 30
    // times a second; the page once mapped such a tap off the picture ("click on the
    // picture"), and under load that lost taps. Here the click comes in the image's error
    // event (naturalWidth 0 for sure), on the centre of picture pixel (112, 84). The click
    // comes twice, as a browser under load can double a tap: the page saves one sample.
    let natural_width = client
        .execute_async(
            "const done = arguments[arguments.length - 1];
             const v = document.getElementById('video'), r = v.getBoundingClientRect();
             const half = Math.min(r.width / 224, r.height / 168) / 2;
             v.addEventListener('error', () => {
               const w = v.naturalWidth;
               for (let i = 0; i < 2; i++) {
                 // Whole CSS pixels, as a browser may truncate a synthetic click's
                 // fractional coordinates (half a picture pixel is more than 0.5).
                 v.dispatchEvent(new MouseEvent('click', { bubbles: true,
                   clientX: Math.round(r.left + r.width / 2 + half),
                   clientY: Math.round(r.top + r.height / 2 + half) }));
               }
               done(w);
             }, { once: true });
             v.src = 'data:image/jpeg;base64,AAAA';",
            vec![],
        )
        .await
        .unwrap();
    assert_eq!(
        natural_width,
        json!(0),
        "the click came while no frame was loaded"
    );
    wait_for_js(
        &client,
        "the count after a tap while loading",
        "return document.getElementById('labelcount').textContent.startsWith('xy 2 ')",
    )
    .await;
    let second: Vec<String> = files_in(&xy)
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().to_string())
        .filter(|n| n.starts_with("xy_112_084_"))
        .collect();
    assert_eq!(second.len(), 1, "{:?}", files_in(&xy));
    let msg = client
        .execute("return document.getElementById('msg').textContent", vec![])
        .await
        .unwrap();
    assert!(
        msg.as_str().is_some_and(|m| m.starts_with("saved ")),
        "the doubled click is not reported over the save: {msg}"
    );

    // Undo removes them, newest first.
    tap_on(&client, "#undo", 0.0, 0.0).await;
    wait_for_js(
        &client,
        "the count after an undo",
        "return document.getElementById('labelcount').textContent.startsWith('xy 1 ')",
    )
    .await;
    assert_eq!(files_in(&xy), vec![sample.clone()]);
    tap_on(&client, "#undo", 0.0, 0.0).await;
    wait_for_js(
        &client,
        "the count after undo",
        "return document.getElementById('labelcount').textContent.startsWith('xy 0 ')",
    )
    .await;
    assert!(files_in(&xy).is_empty(), "{:?}", files_in(&xy));

    // Blocked, with the stick not mounted: a clear error on the page, and the run goes on.
    tap_on(&client, "[data-label=blocked]", 0.0, 0.0).await;
    wait_for_js(
        &client,
        "Blocked to be selected",
        "return document.querySelector('[data-label=blocked]').classList.contains('on')",
    )
    .await;
    let (x, y) = at(100.0, 100.0);
    tap_on(&client, "#video", x, y).await;
    wait_for_js(
        &client,
        "the missing-drive error",
        "return document.getElementById('msg').textContent.includes('is the drive mounted?')",
    )
    .await;
    let msg = page_text(&client, "msg").await;
    assert!(msg.contains(&stick.display().to_string()), "{msg}");
    let before = status_anon(addr)["frames_captured"].as_u64().unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!(
        status_anon(addr)["frames_captured"].as_u64().unwrap() > before,
        "the daemon goes on capturing"
    );
    // The stick is mounted: the next tap saves (Free; the key C moves on to Blocked).
    std::fs::create_dir(&stick).unwrap();
    tap_on(&client, "[data-label=free]", 0.0, 0.0).await;
    wait_for_js(
        &client,
        "Free to be selected",
        "return document.querySelector('[data-label=free]').classList.contains('on')",
    )
    .await;
    tap_on(&client, "#video", x, y).await;
    wait_for_js(
        &client,
        "the free count",
        "return document.getElementById('labelcount').textContent === 'xy 0 · free 1 · blocked 0'",
    )
    .await;
    assert_eq!(files_in(&stick.join("dataset/free")).len(), 1);
    assert!(files_in(&stick.join("dataset/blocked")).is_empty());
    let keys = KeyActions::new("keyboard".into())
        .then(KeyAction::Down { value: 'c' })
        .then(KeyAction::Up { value: 'c' });
    client.perform_actions(keys).await.unwrap();
    wait_for_js(
        &client,
        "C to select Blocked",
        "return document.querySelector('[data-label=blocked]').classList.contains('on')",
    )
    .await;

    // The drive pad by touch: drag up by two thirds of its radius (60 px) for 1.2 s.
    let pad = client.find(Locator::Id("pad")).await.unwrap();
    let before = motor_log(&robot.motors).len();
    let drag = TouchActions::new("thumb".into())
        .then(PointerAction::MoveToElement {
            element: pad,
            duration: None,
            x: 0.0,
            y: 0.0,
        })
        .then(PointerAction::Down {
            button: MOUSE_BUTTON_LEFT,
        })
        .then(PointerAction::MoveBy {
            duration: Some(Duration::from_millis(100)),
            x: 0.0,
            y: -60.0,
        });
    client.perform_actions(drag).await.unwrap();
    // The page's pad reads the touch: held, straight up, 60 of its 90 px radius.
    let held = client
        .execute("return [pad.held, pad.x, pad.y]", vec![])
        .await
        .unwrap();
    assert_eq!(held[0], true, "{held}");
    let (px, py) = (held[1].as_f64().unwrap(), held[2].as_f64().unwrap());
    assert!(px.abs() < 0.03 && (py - 60.0 / 90.0).abs() < 0.03, "{held}");
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let up = TouchActions::new("thumb".into()).then(PointerAction::Up {
        button: MOUSE_BUTTON_LEFT,
    });
    client.perform_actions(up).await.unwrap();
    let log = motor_log(&robot.motors);
    let forward = log[before..]
        .iter()
        .filter(|v| {
            let (l, r) = (v["left"].as_f64(), v["right"].as_f64());
            matches!((l, r), (Some(l), Some(r)) if l > 0.25 && (l - r).abs() < 0.02)
        })
        .count();
    assert!(
        forward >= 5,
        "{forward} forward commands while the pad was held: {:?}",
        &log[before..]
    );
    client.close().await.unwrap();
    drop(robot);
}

/// `/api/status` without a token (loopback).
fn status_anon(addr: SocketAddr) -> Value {
    status(addr, "")
}

async fn wait_for_js(client: &fantoccini::Client, what: &str, script: &str) {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if client.execute(script, vec![]).await.unwrap() == Value::Bool(true) {
            return;
        }
        let msg = page_text(client, "msg").await;
        assert!(
            Instant::now() < deadline,
            "timed out waiting for {what} (page says {msg:?})"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}
