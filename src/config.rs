//! The typed configuration (TOML), with JetBot defaults for every key.
//!
//! Unknown keys, wrong types and out-of-range values are errors that name the file, the key
//! path, the bad value and what is allowed. Relative paths in a config file are taken
//! relative to that file's folder, so `config/demo.toml` can point at `samples/frames`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::control::SteeringGains;
use crate::hw::HatLayout;
use crate::hw::motor_hat::{HatSettings, MotorTrim};
use crate::policy::providers::{CudaOptions, GpuOptions, TensorrtOptions};
pub use crate::policy::runtime::Provider;
use crate::policy::{ChannelOrder, ModelContract, OutputKind};

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("config {path}: cannot read: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("config {path}{line}: key `{key}`: {message}")]
    Parse {
        path: String,
        /// `" line N"` when known.
        line: String,
        key: String,
        message: String,
    },
    #[error("config {path}: key `{key}` = {value} is out of range: allowed {allowed}")]
    OutOfRange {
        path: String,
        key: String,
        value: String,
        allowed: String,
    },
}

pub type Result<T> = std::result::Result<T, ConfigError>;

/// Floats that are exactly an `f32` (every float key today) as the shortest decimal of
/// that `f32`; any other float is left as it is.
fn shortest_floats(v: &mut toml::Value) {
    match v {
        toml::Value::Float(f) => {
            let single = *f as f32;
            if f64::from(single) == *f
                && let Ok(g) = single.to_string().parse::<f64>()
            {
                *f = g;
            }
        }
        toml::Value::Array(items) => items.iter_mut().for_each(shortest_floats),
        toml::Value::Table(t) => t.iter_mut().for_each(|(_, v)| shortest_floats(v)),
        _ => {}
    }
}

/// The whole configuration. Every section and key is optional in the file.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub camera: CameraConfig,
    pub model: ModelConfig,
    pub runtime: RuntimeConfig,
    pub control: ControlConfig,
    pub motors: MotorsConfig,
    pub safety: SafetyConfig,
    pub log: LogConfig,
    /// The simulator (`jetpilot sim`, `jetpilot eval`).
    pub sim: crate::sim::setup::SimConfig,
    /// A gamepad for teleoperation, takeovers and the mode buttons; absent: no gamepad,
    /// the autopilot drives from the start.
    pub gamepad: Option<crate::hw::gamepad::GamepadConfig>,
    pub record: RecordConfig,
    pub interventions: InterventionsConfig,
    pub oled: OledConfig,
    pub buzzer: crate::hw::buzzer::BuzzerConfig,
    /// The web page: live video, gain sliders, modes and browser teleop.
    pub web: crate::web::WebConfig,
}

/// `[oled]`: the SSD1306 128x32 status display (JetBot, Waveshare, Yahboom boards).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OledConfig {
    /// Off by default; an enabled display that does not answer is a warning, not an error.
    pub enabled: bool,
    /// The I2C bus number: `/dev/i2c-N` (1 on the Jetson Nano's 40-pin header).
    pub i2c_bus: u8,
    /// The display's 7-bit I2C address (0x3C; 60 in TOML's decimal).
    pub address: u8,
}

impl Default for OledConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            i2c_bus: 1,
            address: 0x3C,
        }
    }
}

/// `[record]`: demonstrations written while driving (DonkeyCar tub v2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordConfig {
    /// The tub folder (a new session is appended to an existing tub).
    pub path: PathBuf,
    /// Stop recording after this many records (bounds disk use: ~10 kB each at 224x224).
    pub max_records: u64,
    /// Also write JetBot's road-following folder here (`xy_XXX_YYY_<uuid>.jpg`); see
    /// `drive::recorder` for how a gamepad command becomes a target point.
    pub jetbot_xy: Option<PathBuf>,
}

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            path: PathBuf::from("tub"),
            max_records: 100_000,
            jetbot_xy: None,
        }
    }
}

/// `[interventions]`: the log of human takeovers (the paper's measure).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InterventionsConfig {
    /// Append-only JSON lines; unset: interventions are counted but not written.
    pub log_path: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraSource {
    /// A folder of JPEG/PNG images replayed in name order.
    Folder,
    /// A V4L2 device (USB cameras): `device`, `width`, `height`, `fps`, `format`.
    V4l2,
    /// Raw frames of `width` x `height` in `format` read from the standard output of
    /// `command` (Jetson CSI cameras through GStreamer's nvarguscamerasrc).
    Pipe,
}

/// Pixel formats a camera may deliver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelFormat {
    /// Let the device choose among the ones below (MJPEG first at high resolutions).
    Auto,
    Yuyv,
    Mjpeg,
    Rgb3,
    Bgr3,
    Grey,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Where frames come from: `folder` (images replayed in name order), `v4l2` (a USB camera),
    /// `pipe` (raw frames from `command`'s standard output: CSI cameras through GStreamer).
    pub source: CameraSource,
    /// Folder of frames (`folder` source).
    pub path: PathBuf,
    /// Frames per second delivered by the source.
    pub fps: f32,
    /// Start again at the first frame after the last (`folder` source).
    #[serde(rename = "loop")]
    pub repeat: bool,
    /// `v4l2`: the device node.
    pub device: PathBuf,
    /// `v4l2`, `pipe`: frame width asked for (v4l2) or delivered (pipe), pixels.
    pub width: u32,
    /// `v4l2`, `pipe`: frame height asked for (v4l2) or delivered (pipe), pixels.
    pub height: u32,
    /// `v4l2`: the format to ask for; `pipe`: the raw format the command writes
    /// (`rgb3`, `bgr3`, `yuyv` or `grey`; not `mjpeg` or `auto`).
    pub format: PixelFormat,
    /// `pipe`: the command line, run with `sh -c`.
    pub command: String,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            source: CameraSource::Folder,
            path: PathBuf::from("frames"),
            fps: 30.0,
            repeat: true,
            device: PathBuf::from("/dev/video0"),
            width: 640,
            height: 480,
            format: PixelFormat::Auto,
            command: String::new(),
        }
    }
}

/// The model file, and the contract to use when the file does not carry one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// The ONNX policy file (relative paths from the working directory).
    pub path: PathBuf,
    /// Side of the square input, pixels, when the model carries no contract.
    pub input_size: u32,
    /// `rgb` or `bgr`, when the model carries no contract.
    pub channel_order: ChannelOrder,
    /// Per-channel mean subtracted after scaling to 0..=1 (ImageNet's by default).
    pub mean: [f32; 3],
    /// Per-channel standard deviation divided by after the mean (ImageNet's by default).
    pub std: [f32; 3],
    /// What the two outputs are: `xy` (JetBot's target point) or `speed_steering`.
    pub output: OutputKind,
}

impl Default for ModelConfig {
    fn default() -> Self {
        let c = ModelContract::default();
        Self {
            path: PathBuf::from("model.onnx"),
            input_size: c.input_size,
            channel_order: c.channel_order,
            mean: c.mean,
            std: c.std,
            output: c.output,
        }
    }
}

impl ModelConfig {
    /// The contract for models without jetpilot metadata.
    pub fn fallback_contract(&self) -> ModelContract {
        ModelContract {
            input_size: self.input_size,
            channel_order: self.channel_order,
            mean: self.mean,
            std: self.std,
            output: self.output,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RuntimeConfig {
    /// Path to `libonnxruntime.so`; unset: `ORT_DYLIB_PATH`, then the standard places.
    pub library: Option<PathBuf>,
    pub providers: Vec<Provider>,
    /// Threads inside one operator (0: ONNX Runtime decides).
    pub intra_threads: usize,
    /// Let ONNX Runtime's worker threads spin-wait for work after each run (its own
    /// default). Off: they block at once, which costs a little latency per frame but no
    /// core between frames; `jetpilot bench` shows both.
    pub allow_spinning: bool,
    /// The TensorRT provider (ONNX Runtime's GPU build: Jetson Orin, desktop GPUs).
    pub tensorrt: TensorrtOptions,
    /// The CUDA provider (the same builds).
    pub cuda: CudaOptions,
}

impl RuntimeConfig {
    /// Both GPU providers' settings, as sessions are built with them.
    pub fn gpu(&self) -> GpuOptions {
        GpuOptions {
            tensorrt: self.tensorrt.clone(),
            cuda: self.cuda.clone(),
        }
    }
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        Self {
            library: None,
            providers: vec![Provider::Cpu],
            intra_threads: 2,
            allow_spinning: false,
            tensorrt: TensorrtOptions::default(),
            cuda: CudaOptions::default(),
        }
    }
}

/// The steering law's gains (JetBot's sliders), see `control::steering`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControlConfig {
    pub speed_gain: f32,
    pub steering_gain: f32,
    pub steering_kd: f32,
    pub steering_bias: f32,
    pub steering_ki: f32,
    pub integral_limit: f32,
    /// `"differential"` (JetBot, the default) or `"car"`: the simulator's car-like vehicle
    /// (`sim.vehicle = "car"`, a DonkeyCar replay) gets DonkeyCar's throttle and angle
    /// (`control::Mixing`).
    pub mixing: crate::control::Mixing,
}

impl Default for ControlConfig {
    fn default() -> Self {
        let g = SteeringGains::default();
        Self {
            speed_gain: g.speed_gain,
            steering_gain: g.steering_gain,
            steering_kd: g.steering_kd,
            steering_bias: g.steering_bias,
            steering_ki: g.steering_ki,
            integral_limit: g.integral_limit,
            mixing: g.mixing,
        }
    }
}

impl ControlConfig {
    pub fn gains(&self) -> SteeringGains {
        SteeringGains {
            speed_gain: self.speed_gain,
            steering_gain: self.steering_gain,
            steering_kd: self.steering_kd,
            steering_bias: self.steering_bias,
            steering_ki: self.steering_ki,
            integral_limit: self.integral_limit,
            mixing: self.mixing,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MotorBackend {
    /// The motor HAT on `/dev/i2c-<i2c_bus>` through linux-embedded-hal.
    I2c,
    /// The motor HAT through rppal (Raspberry Pi; needs the `rpi` build feature).
    Rppal,
    /// No hardware: log and record the commands.
    Log,
    /// An H-bridge (L298N, TB6612FNG, DRV8833) on GPIO lines and sysfs PWM: `[motors.gpio]`.
    Gpio,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrimConfig {
    /// Scale on this motor's command, as JetBot's `Motor.alpha` (1.0: none); match a slower
    /// motor to a faster one.
    pub alpha: f32,
    /// Offset added after scaling, as JetBot's `Motor.beta` (0.0: none).
    pub beta: f32,
    /// Unset: the layout's default (true on the NVIDIA JetBot's Adafruit HAT).
    pub invert: Option<bool>,
}

impl Default for TrimConfig {
    fn default() -> Self {
        Self {
            alpha: 1.0,
            beta: 0.0,
            invert: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotorsConfig {
    pub backend: MotorBackend,
    pub layout: HatLayout,
    pub i2c_bus: u8,
    /// Unset: the layout's address (0x60 Adafruit/Waveshare, 0x40 Yahboom).
    pub address: Option<u8>,
    /// Unset: 1600 Hz.
    pub pwm_hz: Option<f32>,
    /// Extra attempts for a failed I2C write before it becomes a fault.
    pub retries: u32,
    pub left: TrimConfig,
    pub right: TrimConfig,
    /// `log` backend: also append each command as a JSON line to this file.
    pub log_path: Option<PathBuf>,
    /// `gpio` backend: the H-bridge's chip and pins.
    pub gpio: Option<crate::hw::hbridge::GpioMotorsConfig>,
}

impl Default for MotorsConfig {
    fn default() -> Self {
        Self {
            backend: MotorBackend::I2c,
            layout: HatLayout::Adafruit,
            i2c_bus: 1,
            address: None,
            pwm_hz: None,
            retries: 2,
            left: TrimConfig::default(),
            right: TrimConfig::default(),
            log_path: None,
            gpio: None,
        }
    }
}

impl MotorsConfig {
    /// The per-motor trims. `invert` unset means the HAT layout's default on a HAT, and
    /// false on an H-bridge (wire it the right way round, or set it).
    pub fn trims(&self) -> (MotorTrim, MotorTrim) {
        let (li, ri) = match self.backend {
            MotorBackend::Gpio => (false, false),
            _ => self.layout.default_invert(),
        };
        let trim = |t: &TrimConfig, default_invert| MotorTrim {
            alpha: t.alpha,
            beta: t.beta,
            invert: t.invert.unwrap_or(default_invert),
        };
        (trim(&self.left, li), trim(&self.right, ri))
    }

    pub fn hat_settings(&self) -> HatSettings {
        let mut s = HatSettings::for_layout(self.layout);
        if let Some(a) = self.address {
            s.address = a;
        }
        if let Some(f) = self.pwm_hz {
            s.pwm_hz = f;
        }
        let (li, ri) = self.layout.default_invert();
        s.left = MotorTrim {
            alpha: self.left.alpha,
            beta: self.left.beta,
            invert: self.left.invert.unwrap_or(li),
        };
        s.right = MotorTrim {
            alpha: self.right.alpha,
            beta: self.right.beta,
            invert: self.right.invert.unwrap_or(ri),
        };
        s.retries = self.retries;
        s.bus_name = format!("/dev/i2c-{}", self.i2c_bus);
        s
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Stop the motors when no fresh command was written for this long.
    pub watchdog_ms: u64,
    /// Never act on a frame older than this (the command is dropped, the watchdog runs on).
    pub max_frame_age_ms: u64,
    /// A model output beyond +-this (or NaN/inf) is a fault.
    pub max_abs_output: f32,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            watchdog_ms: 250,
            max_frame_age_ms: 500,
            max_abs_output: 10.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LogConfig {
    /// Seconds between stage-latency reports (0: never).
    pub stats_interval_s: f32,
    /// Log every motor command at INFO (the `log` backend).
    pub print_commands: bool,
}

impl Default for LogConfig {
    fn default() -> Self {
        Self {
            stats_interval_s: 5.0,
            print_commands: true,
        }
    }
}

impl Config {
    /// Reads, parses and validates a config file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        let mut cfg = Self::parse(&text, &path.display().to_string())?;
        if let Some(dir) = path.parent() {
            cfg.resolve_paths(dir);
        }
        Ok(cfg)
    }

    /// Parses and validates config text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self> {
        let parse_err = |key: String, line: Option<usize>, message: String| ConfigError::Parse {
            path: origin.to_string(),
            line: line.map(|l| format!(" line {l}")).unwrap_or_default(),
            key,
            message,
        };
        let de = toml::Deserializer::parse(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start));
            parse_err("(syntax)".into(), line, e.message().trim().to_string())
        })?;
        let cfg: Config = serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            let inner = e.into_inner();
            let line = inner.span().map(|s| line_of(text, s.start));
            parse_err(key, line, inner.message().trim().to_string())
        })?;
        cfg.validate(origin)?;
        Ok(cfg)
    }

    /// The config as TOML that [`Config::parse`] reads back to the same value: every key
    /// written, each number in the shortest form that is the same `f32` (`0.1`, not the
    /// `0.10000000149011612` that f32's widening would print).
    pub fn to_toml(&self) -> std::result::Result<String, toml::ser::Error> {
        let mut value = toml::Value::try_from(self)?;
        shortest_floats(&mut value);
        toml::to_string_pretty(&value)
    }

    /// Makes every relative path key (`camera.path`, `model.path`, `sim.recording`, ...)
    /// relative to `dir` instead: with `dir` absolute, the config means the same files
    /// wherever it is read from. [`Config::load`] does this with the file's folder.
    pub fn resolve_paths(&mut self, dir: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        };
        fix(&mut self.camera.path);
        if let Some(p) = self.sim.track.as_mut() {
            fix(p);
        }
        if let Some(p) = self.sim.recording.as_mut() {
            fix(p);
        }
        fix(&mut self.model.path);
        if let Some(p) = self.runtime.library.as_mut() {
            fix(p);
        }
        if let Some(p) = self.motors.log_path.as_mut() {
            fix(p);
        }
        fix(&mut self.record.path);
        if let Some(p) = self.record.jetbot_xy.as_mut() {
            fix(p);
        }
        if let Some(p) = self.interventions.log_path.as_mut() {
            fix(p);
        }
        if let Some(p) = self.web.token_path.as_mut() {
            fix(p);
        }
    }

    /// Checks every numeric key against its allowed range.
    pub fn validate(&self, origin: &str) -> Result<()> {
        let mut v = Validator { origin };
        v.range("camera.fps", self.camera.fps, 0.1, 240.0)?;
        v.range_u("camera.width", self.camera.width as u64, 16, 4096)?;
        v.range_u("camera.height", self.camera.height as u64, 16, 4096)?;
        if self.camera.source == CameraSource::Pipe {
            if self.camera.command.trim().is_empty() {
                return Err(v.err(
                    "camera.command",
                    "\"\"",
                    "a command line that writes raw frames to its standard output",
                ));
            }
            if matches!(self.camera.format, PixelFormat::Auto | PixelFormat::Mjpeg) {
                return Err(v.err(
                    "camera.format",
                    &format!("{:?}", self.camera.format).to_lowercase(),
                    "\"rgb3\", \"bgr3\", \"yuyv\" or \"grey\" for a pipe source",
                ));
            }
        }
        v.range_u("model.input_size", self.model.input_size as u64, 32, 1024)?;
        for (i, s) in self.model.std.iter().enumerate() {
            v.range(&format!("model.std[{i}]"), *s, 1e-3, 1e3)?;
        }
        for (i, m) in self.model.mean.iter().enumerate() {
            v.range(&format!("model.mean[{i}]"), *m, -10.0, 10.0)?;
        }
        if self.runtime.providers.is_empty() {
            return Err(v.err(
                "runtime.providers",
                "[]",
                "a non-empty list of \"tensorrt\", \"cuda\", \"cpu\"",
            ));
        }
        v.range_u(
            "runtime.intra_threads",
            self.runtime.intra_threads as u64,
            0,
            64,
        )?;
        let (trt, cuda) = (&self.runtime.tensorrt, &self.runtime.cuda);
        v.range_u(
            "runtime.tensorrt.max_workspace_mib",
            trt.max_workspace_mib.into(),
            16,
            65536,
        )?;
        v.range_u("runtime.tensorrt.device_id", trt.device_id.into(), 0, 15)?;
        v.range_u("runtime.cuda.device_id", cuda.device_id.into(), 0, 15)?;
        v.range_u(
            "runtime.cuda.memory_limit_mib",
            cuda.memory_limit_mib.into(),
            0,
            1 << 20,
        )?;
        let c = &self.control;
        v.range("control.speed_gain", c.speed_gain, 0.0, 1.0)?;
        v.range("control.steering_gain", c.steering_gain, 0.0, 2.0)?;
        v.range("control.steering_kd", c.steering_kd, 0.0, 1.0)?;
        v.range("control.steering_bias", c.steering_bias, -0.5, 0.5)?;
        v.range("control.steering_ki", c.steering_ki, 0.0, 2.0)?;
        v.range("control.integral_limit", c.integral_limit, 0.0, 1.0)?;
        if c.mixing == crate::control::Mixing::Car {
            // The car's channels carry throttle and angle: a wheel's scale or offset would
            // mix one into the other.
            for (side, t) in [("left", &self.motors.left), ("right", &self.motors.right)] {
                if t.alpha != 1.0 || t.beta != 0.0 {
                    return Err(v.err(
                        &format!("motors.{side}.alpha"),
                        &format!("{} (beta {})", t.alpha, t.beta),
                        "alpha 1 and beta 0 with control.mixing = \"car\": the channels carry the car's throttle and angle, not two wheels",
                    ));
                }
            }
        }
        let car_sim = self.sim.vehicle == crate::sim::setup::SimVehicle::Car;
        if (c.mixing == crate::control::Mixing::Car) != car_sim {
            let mixing = format!("{:?}", c.mixing).to_lowercase();
            return Err(v.err(
                "control.mixing",
                &format!("{mixing:?} with sim.vehicle = {:?}", format!("{:?}", self.sim.vehicle).to_lowercase()),
                "\"car\" together with sim.vehicle = \"car\" (the simulated DonkeyCar: its throttle and angle on the motor channels), else \"differential\"; no motor driver for a steering servo and an ESC exists yet",
            ));
        }
        let m = &self.motors;
        if let Some(a) = m.address {
            v.range_u("motors.address", a as u64, 0x08, 0x77)?;
        }
        if let Some(f) = m.pwm_hz {
            v.range("motors.pwm_hz", f, 24.0, 1600.0)?;
        }
        v.range_u("motors.retries", m.retries as u64, 0, 10)?;
        match (m.backend, &m.gpio) {
            (MotorBackend::Gpio, None) => {
                return Err(v.err(
                    "motors.gpio",
                    "(missing)",
                    "a [motors.gpio] section with the chip and pins (config/l298n-nano.toml shows one)",
                ));
            }
            (MotorBackend::Gpio, Some(g)) => g.check().map_err(|e| ConfigError::Parse {
                path: v.origin.to_string(),
                line: String::new(),
                key: e.key,
                message: e.message,
            })?,
            _ => {}
        }
        for (side, t) in [("left", &m.left), ("right", &m.right)] {
            v.range(&format!("motors.{side}.alpha"), t.alpha, 0.0, 2.0)?;
            v.range(&format!("motors.{side}.beta"), t.beta, -0.5, 0.5)?;
        }
        let s = &self.safety;
        v.range_u("safety.watchdog_ms", s.watchdog_ms, 20, 5000)?;
        v.range_u("safety.max_frame_age_ms", s.max_frame_age_ms, 10, 10_000)?;
        v.range("safety.max_abs_output", s.max_abs_output, 0.1, 1e6)?;
        v.range(
            "log.stats_interval_s",
            self.log.stats_interval_s,
            0.0,
            3600.0,
        )?;
        let w = &self.web;
        if let Err(e) = w.addr() {
            return Err(v.err("web.bind", &format!("{:?}", w.bind), &e));
        }
        v.range("web.video_fps", w.video_fps, 0.5, 30.0)?;
        v.range_u("web.jpeg_quality", w.jpeg_quality as u64, 1, 100)?;
        v.range_u("web.heartbeat_ms", w.heartbeat_ms, 100, 2000)?;
        v.range("web.throttle_scale", w.throttle_scale, 0.0, 1.0)?;
        v.range("web.steering_scale", w.steering_scale, 0.0, 1.0)?;
        v.range_u("web.max_connections", w.max_connections, 1, 1024)?;
        v.range_u("web.request_timeout_ms", w.request_timeout_ms, 100, 600_000)?;
        v.range_u("web.stall_timeout_ms", w.stall_timeout_ms, 100, 600_000)?;
        // Above the socket's 2 s ping, so an open page is never closed for idling.
        v.range_u("web.idle_timeout_ms", w.idle_timeout_ms, 5_000, 3_600_000)?;
        v.range_u("web.max_message_bytes", w.max_message_bytes, 1024, 16 << 20)?;
        Ok(())
    }
}

struct Validator<'a> {
    origin: &'a str,
}

impl Validator<'_> {
    fn err(&self, key: &str, value: &str, allowed: &str) -> ConfigError {
        ConfigError::OutOfRange {
            path: self.origin.to_string(),
            key: key.to_string(),
            value: value.to_string(),
            allowed: allowed.to_string(),
        }
    }

    fn range(&mut self, key: &str, value: f32, lo: f32, hi: f32) -> Result<()> {
        if value.is_finite() && (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(self.err(key, &value.to_string(), &format!("{lo} ..= {hi}")))
        }
    }

    fn range_u(&mut self, key: &str, value: u64, lo: u64, hi: u64) -> Result<()> {
        if (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(self.err(key, &value.to_string(), &format!("{lo} ..= {hi}")))
        }
    }
}

/// 1-based line number of a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text.get(..offset.min(text.len()))
        .map(|s| s.matches('\n').count() + 1)
        .unwrap_or(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_file_gives_jetbot_defaults() {
        let cfg = Config::parse("", "t.toml").unwrap();
        assert_eq!(cfg, Config::default());
        assert_eq!(cfg.control.steering_gain, 0.2);
        assert_eq!(cfg.control.speed_gain, 0.0);
        assert_eq!(cfg.safety.watchdog_ms, 250);
        let hat = cfg.motors.hat_settings();
        assert_eq!(hat.address, 0x60);
        assert_eq!(hat.pwm_hz, 1600.0);
        assert!(hat.left.invert && hat.right.invert);
    }

    #[test]
    fn spinning_is_off_unless_the_runtime_section_allows_it() {
        assert!(!Config::default().runtime.allow_spinning);
        let cfg = Config::parse("[runtime]\nallow_spinning = true\n", "t.toml").unwrap();
        assert!(cfg.runtime.allow_spinning);
        let err = Config::parse("[runtime]\nallow_spinning = 1\n", "t.toml").unwrap_err();
        assert!(err.to_string().contains("runtime.allow_spinning"), "{err}");
    }

    #[test]
    fn gpu_provider_sections_parse_and_bad_values_are_named() {
        let text = "[runtime]\nproviders = [\"tensorrt\", \"cuda\", \"cpu\"]\n\n\
                    [runtime.tensorrt]\nfp16 = false\ncache_dir = \"/var/cache/jp\"\n\
                    max_workspace_mib = 512\n\n[runtime.cuda]\nmemory_limit_mib = 2048\n";
        let cfg = Config::parse(text, "orin.toml").unwrap();
        let gpu = cfg.runtime.gpu();
        assert!(!gpu.tensorrt.fp16 && gpu.tensorrt.engine_cache);
        assert_eq!(
            gpu.tensorrt.cache_dir.as_deref(),
            Some(Path::new("/var/cache/jp"))
        );
        assert_eq!(gpu.tensorrt.max_workspace_mib, 512);
        assert_eq!((gpu.cuda.device_id, gpu.cuda.memory_limit_mib), (0, 2048));
        // Defaults: fp16 and the engine cache on, a 1 GiB workspace.
        let d = Config::default().runtime.gpu();
        assert!(d.tensorrt.fp16 && d.tensorrt.engine_cache);
        assert_eq!(d.tensorrt.max_workspace_mib, 1024);

        let err = Config::parse("[runtime.tensorrt]\nmax_workspace_mib = 0\n", "t.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("runtime.tensorrt.max_workspace_mib"), "{err}");
        let err = Config::parse("[runtime.tensorrt]\nfp61 = true\n", "t.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("fp61") && err.contains("line 2"), "{err}");
    }

    #[test]
    fn unknown_key_is_named_with_its_line() {
        let err = Config::parse(
            "[control]\nspeed_gain = 0.2\nsteering_gian = 0.1\n",
            "x.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("x.toml line 3"), "{err}");
        assert!(err.contains("control"), "{err}");
        assert!(err.contains("steering_gian"), "{err}");
    }

    #[test]
    fn the_replay_fill_and_flat_field_are_read_and_a_wrong_fill_named() {
        use crate::sim::setup::ReplayFill;
        assert_eq!(
            Config::parse("", "t.toml").unwrap().sim.replay_fill,
            ReplayFill::Earlier
        );
        let cfg = Config::parse("[sim]\nreplay_fill = \"edge\"\n", "t.toml").unwrap();
        assert_eq!(cfg.sim.replay_fill, ReplayFill::Edge);
        let err = Config::parse("[sim]\nreplay_fill = \"mirror\"\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("sim.replay_fill"), "{err}");
        assert!(Config::parse("", "t.toml").unwrap().sim.replay_flat_field);
        let cfg = Config::parse("[sim]\nreplay_flat_field = false\n", "t.toml").unwrap();
        assert!(!cfg.sim.replay_flat_field);
    }

    #[test]
    fn wrong_type_names_the_key() {
        let err = Config::parse("[safety]\nwatchdog_ms = \"fast\"\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("safety.watchdog_ms"), "{err}");
    }

    #[test]
    fn out_of_range_names_key_value_and_range() {
        let err = Config::parse("[control]\nspeed_gain = 1.5\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert_eq!(
            err,
            "config x.toml: key `control.speed_gain` = 1.5 is out of range: allowed 0 ..= 1"
        );
        let err = Config::parse("[motors]\naddress = 0x90\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("motors.address` = 144"), "{err}");
    }

    #[test]
    fn bad_enum_value_lists_the_choices() {
        let err = Config::parse("[motors]\nlayout = \"sparkfun\"\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("motors.layout"), "{err}");
        assert!(err.contains("adafruit"), "{err}");
    }

    #[test]
    fn syntax_error_has_a_line() {
        let err = Config::parse("[control\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("x.toml line 1"), "{err}");
    }

    #[test]
    fn layout_defaults_and_overrides() {
        let cfg = Config::parse(
            "[motors]\nlayout = \"yahboom\"\n[motors.left]\ninvert = true\nalpha = 0.9\n",
            "x.toml",
        )
        .unwrap();
        let hat = cfg.motors.hat_settings();
        assert_eq!(hat.address, 0x40);
        assert!(hat.left.invert);
        assert!(!hat.right.invert);
        assert_eq!(hat.left.alpha, 0.9);
    }

    #[test]
    fn relative_paths_follow_the_config_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(
            &p,
            "[camera]\npath = \"frames\"\n[model]\npath = \"/abs/m.onnx\"\n",
        )
        .unwrap();
        let cfg = Config::load(&p).unwrap();
        assert_eq!(cfg.camera.path, dir.path().join("frames"));
        assert_eq!(cfg.model.path, PathBuf::from("/abs/m.onnx"));
    }

    #[test]
    fn every_shipped_config_written_as_toml_reads_back_the_same() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
        let mut seen = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let cfg = Config::load(&path).unwrap();
            let text = cfg.to_toml().unwrap();
            let back = Config::parse(&text, "written").unwrap();
            assert_eq!(back, cfg, "{}", path.display());
            seen += 1;
        }
        assert!(seen >= 5, "{seen} configs");
        // Numbers as a person would write them.
        let text = Config::default().to_toml().unwrap();
        assert!(text.contains("steering_gain = 0.2\n"), "{text}");
        assert!(!text.contains("0000000"), "{text}");
    }

    #[test]
    fn resolving_against_another_folder_moves_only_relative_paths() {
        let mut cfg = Config::parse(
            "[camera]\npath = \"frames\"\n[model]\npath = \"/abs/m.onnx\"\n[sim]\nrecording = \"tub\"\n",
            "t",
        )
        .unwrap();
        cfg.resolve_paths(Path::new("/base"));
        assert_eq!(cfg.camera.path, PathBuf::from("/base/frames"));
        assert_eq!(cfg.sim.recording, Some(PathBuf::from("/base/tub")));
        assert_eq!(cfg.model.path, PathBuf::from("/abs/m.onnx"));
    }

    #[test]
    fn missing_file_is_named() {
        let err = Config::load(Path::new("/nonexistent/j.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/j.toml"), "{err}");
    }
}
