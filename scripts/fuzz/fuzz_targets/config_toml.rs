//! The whole config, parsed and validated as `jetpilot run --config` does.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = jetpilot::config::Config::parse(text, "fuzz.toml");
    }
});
