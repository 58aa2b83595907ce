//! A DonkeyCar tub v2 as `train il`, `score` and `poses` open it: the input is the
//! `manifest.json` text, a NUL line, then the text of `catalog_0.catalog`.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let (manifest, catalog) = match data.windows(3).position(|w| w == b"\n\0\n") {
        Some(at) => (&data[..at], &data[at + 3..]),
        None => (data, &b""[..]),
    };
    let dir = std::env::temp_dir().join(format!("jetpilot-fuzz-tub-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    if std::fs::create_dir_all(dir.join("images")).is_err() {
        return;
    }
    if std::fs::write(dir.join("manifest.json"), manifest).is_ok()
        && std::fs::write(dir.join("catalog_0.catalog"), catalog).is_ok()
    {
        let _ = jetpilot::dataset::tub::TubReader::open(&dir);
    }
});
