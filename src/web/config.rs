//! `[web]`: the daemon's web page (off unless enabled; 127.0.0.1 by default; any other
//! address always needs the token).

use std::net::SocketAddr;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// `[web]` in the config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WebConfig {
    /// Serve the page (`jetpilot run`, `jetpilot record`). Off by default.
    pub enabled: bool,
    /// Address and port. `0.0.0.0:8887` reaches the robot from a laptop on its Wi-Fi; any
    /// address but loopback requires the token.
    pub bind: String,
    /// Ask for the token on loopback too (it is always asked for elsewhere).
    pub require_token: bool,
    /// Where the token is kept (created on first start, mode 0600). Default: the state
    /// directory (`$STATE_DIRECTORY` under systemd, else `$XDG_STATE_HOME/jetpilot` or
    /// `~/.local/state/jetpilot`), file `web-token`.
    pub token_path: Option<PathBuf>,
    /// Most video frames per second sent to each browser.
    pub video_fps: f32,
    /// JPEG quality of the video, 1..=100.
    pub jpeg_quality: u8,
    /// Draw the model's target point (or speed/steering) and the wheel commands on the video.
    pub overlay: bool,
    /// The dead-man: the page holding the controls must send within this many ms.
    pub heartbeat_ms: u64,
    /// Browser sticks to wheels: full throttle is this much of full speed.
    pub throttle_scale: f32,
    /// Browser sticks to wheels: full steering adds/subtracts this much per wheel.
    pub steering_scale: f32,
    /// Click-to-label, road following: JetBot's `xy_XXX_YYY_<uuid>.jpg` folder. Default:
    /// `dataset_xy` in the state directory. Made at the first click when its parent exists.
    pub xy_dir: Option<PathBuf>,
    /// Click-to-label, collision avoidance: the folder holding `free/` and `blocked/`.
    /// Default: `dataset` in the state directory.
    pub collision_dir: Option<PathBuf>,
    /// Most connections served at once (pages, video streams, sockets); more wait until
    /// one closes.
    pub max_connections: u64,
    /// A connection that gets no response within this many ms of opening (a request that
    /// never ends) is closed.
    pub request_timeout_ms: u64,
    /// A client that takes nothing sent to it for this many ms (a video client gone without
    /// a goodbye) is closed.
    pub stall_timeout_ms: u64,
    /// A connection the daemon has sent nothing to for this many ms is closed (the page's
    /// socket is pinged every 2 s, so an open page never is).
    pub idle_timeout_ms: u64,
    /// Largest message the page's WebSocket accepts, in bytes; a larger one closes it.
    pub max_message_bytes: u64,
}

impl Default for WebConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            bind: "127.0.0.1:8887".into(),
            require_token: false,
            token_path: None,
            video_fps: 10.0,
            jpeg_quality: 70,
            overlay: true,
            heartbeat_ms: 500,
            throttle_scale: 0.5,
            steering_scale: 0.3,
            xy_dir: None,
            collision_dir: None,
            max_connections: 32,
            request_timeout_ms: 10_000,
            stall_timeout_ms: 10_000,
            idle_timeout_ms: 60_000,
            max_message_bytes: 65_536,
        }
    }
}

impl WebConfig {
    /// The per-connection time limits.
    pub fn limits(&self) -> super::guard::Limits {
        use std::time::Duration;
        super::guard::Limits {
            request: Duration::from_millis(self.request_timeout_ms),
            stall: Duration::from_millis(self.stall_timeout_ms),
            idle: Duration::from_millis(self.idle_timeout_ms),
        }
    }

    /// The bind address, or what is wrong with it.
    pub fn addr(&self) -> Result<SocketAddr, String> {
        self.bind.parse::<SocketAddr>().map_err(|e| {
            format!("{e} (an address and port, like \"127.0.0.1:8887\" or \"0.0.0.0:8887\")")
        })
    }

    /// True when the page asks for the token: always, except on a loopback address with
    /// `require_token = false`.
    pub fn token_required(&self) -> bool {
        self.require_token || !self.addr().is_ok_and(|a| a.ip().is_loopback())
    }

    /// The token file: `token_path`, else `web-token` in the state directory.
    pub fn token_file(&self) -> PathBuf {
        if let Some(p) = &self.token_path {
            return p.clone();
        }
        state_dir().join("web-token")
    }

    /// Where road clicks go: `xy_dir`, else `dataset_xy` in the state directory.
    pub fn xy_folder(&self) -> PathBuf {
        self.xy_dir
            .clone()
            .unwrap_or_else(|| state_dir().join("dataset_xy"))
    }

    /// Where free/blocked clicks go: `collision_dir`, else `dataset` in the state directory.
    pub fn collision_folder(&self) -> PathBuf {
        self.collision_dir
            .clone()
            .unwrap_or_else(|| state_dir().join("dataset"))
    }
}

/// The daemon's state directory (see [`WebConfig::token_path`]).
pub fn state_dir() -> PathBuf {
    let env = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    if let Some(d) = env("STATE_DIRECTORY") {
        // systemd may list several, separated by ':'; the first is ours.
        let s = d.to_string_lossy().to_string();
        return PathBuf::from(s.split(':').next().unwrap_or(&s));
    }
    if let Some(d) = env("XDG_STATE_HOME") {
        return d.join("jetpilot");
    }
    match env("HOME") {
        Some(h) => h.join(".local/state/jetpilot"),
        None => PathBuf::from("/var/lib/jetpilot"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_token_is_required_off_loopback_or_when_asked() {
        let mut c = WebConfig::default();
        assert!(!c.token_required());
        c.bind = "[::1]:8887".into();
        assert!(!c.token_required());
        c.bind = "0.0.0.0:8887".into();
        assert!(c.token_required());
        c.bind = "192.168.1.20:80".into();
        assert!(c.token_required());
        c.bind = "127.0.0.1:8887".into();
        c.require_token = true;
        assert!(c.token_required());
        c.bind = "localhost:8887".into(); // not an address: refused by validation
        assert!(c.addr().is_err());
        assert!(c.token_required());
    }
}
