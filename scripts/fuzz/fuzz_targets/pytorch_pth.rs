//! PyTorch checkpoints for `jetpilot model import` (ZIP and legacy pickle): a pickle may
//! not run code, and a bad file is an error, never a crash.
#![no_main]
use jetpilot::policy::onnx::Arch;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let dir = std::env::temp_dir().join(format!("jetpilot-fuzz-pth-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("model.pth");
    if std::fs::write(&path, data).is_ok() {
        let _ = jetpilot::policy::pytorch::read_state_dict(&path, Arch::EfficientNetLite0);
    }
});
