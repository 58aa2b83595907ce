//! Test doubles and fixtures shared by the integration tests: small real models, synthetic
//! frame folders, scripted policies, stalling/failing frame sources and a fault-injecting
//! I2C bus.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use jetpilot::camera::synthetic::{render_road, sample_view};
use jetpilot::camera::{CameraError, Frame, FrameSource};
use jetpilot::clock::Clock;
use jetpilot::dataset::jetbot_xy;
use jetpilot::policy::onnx::{self, Resnet18Weights};
use jetpilot::policy::ort_policy::OrtOptions;
use jetpilot::policy::{ModelContract, OrtPolicy, Policy, PolicyError};

/// A random ResNet-18 at `size` x `size` with our contract in its metadata.
pub fn write_model(dir: &Path, size: u32, seed: u64) -> PathBuf {
    let contract = ModelContract {
        input_size: size,
        ..ModelContract::default()
    };
    let model = onnx::resnet18_model(size, &Resnet18Weights::random(2, seed), &contract, "test")
        .expect("model");
    let path = dir.join(format!("resnet18_{size}_{seed}.onnx"));
    onnx::write_model(&path, &model).expect("write model");
    path
}

/// `n` synthetic road frames (JPEG, 96x72) in `dir/frames`.
pub fn write_frames(dir: &Path, n: usize) -> PathBuf {
    let out = dir.join("frames");
    std::fs::create_dir_all(&out).unwrap();
    for i in 0..n {
        let rgb = render_road(96, 72, sample_view(i, n));
        image::save_buffer(
            out.join(format!("f{i:03}.png")),
            &rgb,
            96,
            72,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
    }
    out
}

/// A finished command's stdout then stderr, as one text for assertions.
pub fn log_of(o: &std::process::Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// `n` scattered simulator views of `config`'s track in JetBot's xy layout in `out`,
/// renamed as JetBot's notebook names its samples (uuid1, a second apart, in the order of
/// the simulator's names), so that `score --split-by-time` and the scripts can order them
/// by capture time.
pub fn scattered_xy_views(config: &Path, n: usize, out: &Path) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args([
            "-q",
            "sim",
            "--camera",
            "jetbot",
            "--randomise",
            "--scatter",
        ])
        .arg(n.to_string())
        .arg("--config")
        .arg(config)
        .arg("--record-xy")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut names: Vec<_> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    assert_eq!(names.len(), n, "{names:?}");
    for (i, name) in names.iter().enumerate() {
        let (px, py) = jetbot_xy::parse_file_name(name).unwrap();
        let taken = (1_796_342_400 + i as u64) * 10_000_000;
        let uuid = jetbot_xy::uuid1(taken, 0x1234, [0x01, 0x23, 0x45, 0x67, 0x89, 0xab]);
        std::fs::rename(
            out.join(name),
            out.join(jetbot_xy::file_name(px, py, &uuid)),
        )
        .unwrap();
    }
}

/// What a scripted policy does on its n-th call.
pub enum Step {
    Out([f32; 2]),
    Fail(&'static str),
    Panic,
}

/// A policy that follows a script (then repeats its last step).
pub struct ScriptedPolicy {
    contract: ModelContract,
    script: Box<dyn FnMut(usize) -> Step + Send>,
    calls: usize,
}

impl ScriptedPolicy {
    pub fn new(script: impl FnMut(usize) -> Step + Send + 'static) -> Self {
        Self {
            contract: ModelContract {
                input_size: 32,
                ..ModelContract::default()
            },
            script: Box::new(script),
            calls: 0,
        }
    }
}

impl Policy for ScriptedPolicy {
    fn contract(&self) -> &ModelContract {
        &self.contract
    }
    fn infer(&mut self, _input: &[f32]) -> Result<[f32; 2], PolicyError> {
        let n = self.calls;
        self.calls += 1;
        match (self.script)(n) {
            Step::Out(o) => Ok(o),
            Step::Fail(m) => Err(PolicyError::Inference(m.into())),
            Step::Panic => panic!("scripted policy panics on call {n}"),
        }
    }
    fn describe(&self) -> String {
        "scripted policy".into()
    }
}

/// Gives `frames` frames at `period`, then either stalls (blocks until `release`) or fails.
pub struct ScriptedSource {
    pub frames: u64,
    pub period: Duration,
    pub then_fail: bool,
    pub release: Arc<AtomicBool>,
    pub clock: Arc<dyn Clock>,
    seq: u64,
}

impl ScriptedSource {
    pub fn new(frames: u64, period: Duration, then_fail: bool, clock: Arc<dyn Clock>) -> Self {
        Self {
            frames,
            period,
            then_fail,
            release: Arc::new(AtomicBool::new(false)),
            clock,
            seq: 0,
        }
    }
}

impl ScriptedSource {
    /// Frames delivered so far.
    pub fn produced(&self) -> u64 {
        self.seq
    }
}

impl FrameSource for ScriptedSource {
    fn next_frame(&mut self) -> Result<Option<Frame>, CameraError> {
        if self.seq >= self.frames {
            if self.then_fail {
                return Err(CameraError::Other("camera unplugged (injected)".into()));
            }
            // A stalled camera: no frame, no error, until the test lets go.
            while !self.release.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(5));
            }
            return Ok(None);
        }
        std::thread::sleep(self.period);
        let f = Frame {
            seq: self.seq,
            captured_at: self.clock.now(),
            width: 32,
            height: 32,
            rgb: Arc::new(vec![128; 32 * 32 * 3]),
        };
        self.seq += 1;
        Ok(Some(f))
    }
    fn describe(&self) -> String {
        "scripted source".into()
    }
}

/// An I2C bus that records every write and fails the transactions whose index is in
/// `fail` (counting from 0), like a loose connector.
/// (address, bytes, whether the transaction was made to fail)
pub type WriteLog = Arc<Mutex<Vec<(u8, Vec<u8>, bool)>>>;

#[derive(Clone, Default)]
pub struct FlakyBus {
    pub writes: WriteLog,
    pub fail: Arc<Mutex<std::ops::Range<usize>>>,
}

#[derive(Debug)]
pub struct BusError;

impl embedded_hal::i2c::Error for BusError {
    fn kind(&self) -> embedded_hal::i2c::ErrorKind {
        embedded_hal::i2c::ErrorKind::Other
    }
}

impl embedded_hal::i2c::ErrorType for FlakyBus {
    type Error = BusError;
}

impl embedded_hal::i2c::I2c for FlakyBus {
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [embedded_hal::i2c::Operation<'_>],
    ) -> Result<(), BusError> {
        let mut w = self.writes.lock().unwrap();
        let idx = w.len();
        let failed = self.fail.lock().unwrap().contains(&idx);
        for op in operations.iter() {
            if let embedded_hal::i2c::Operation::Write(bytes) = op {
                w.push((address, bytes.to_vec(), failed));
            }
        }
        if failed { Err(BusError) } else { Ok(()) }
    }
}

/// A model on ONNX Runtime's CPU provider, one thread, the default fallback contract.
pub fn load_ort(path: &Path) -> OrtPolicy {
    try_load_ort(path)
        .expect("load model (is ONNX Runtime installed? scripts/install-onnxruntime.sh)")
}

/// [`load_ort`] for tests that expect the load to be refused.
pub fn try_load_ort(path: &Path) -> Result<OrtPolicy, PolicyError> {
    OrtPolicy::load(path, &OrtOptions::cpu(1, false, &ModelContract::default()))
}

/// With `JETPILOT_FAULT_TIMES=FILE` (set by `scripts/faults-under-load.sh`), appends one
/// fault round, `kind,round,delay_ms,stop_ms,drove,last_drive_ms`, for the script's
/// summary: the stop and the last drive command timed from the fault (the last drive may
/// come after it: a frame already in flight), `last_drive_ms` empty where not measured.
pub fn record_fault_time(
    kind: &str,
    round: usize,
    delay: Duration,
    stop: Option<Duration>,
    last_drive_ms: Option<f64>,
) {
    use std::io::Write;
    let Some(path) = std::env::var_os("JETPILOT_FAULT_TIMES") else {
        return;
    };
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .expect("open JETPILOT_FAULT_TIMES");
    writeln!(
        f,
        "{kind},{round},{},{:.3},{},{}",
        delay.as_millis(),
        stop.map_or(0.0, |d| d.as_secs_f64() * 1e3),
        stop.is_some(),
        last_drive_ms.map_or(String::new(), |v| format!("{v:.3}"))
    )
    .expect("append to JETPILOT_FAULT_TIMES");
}
