//! JetBot xy file names: the pixel coordinates and the uuid1 capture time, and the name the
//! writer makes for a parsed point parses back to that point.
#![no_main]
use jetpilot::dataset::jetbot_xy;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(name) = std::str::from_utf8(data) else {
        return;
    };
    let _ = jetbot_xy::capture_time_s(name);
    if let Some((px, py)) = jetbot_xy::parse_file_name(name) {
        let again = jetbot_xy::file_name(px, py, "u");
        assert_eq!(jetbot_xy::parse_file_name(&again), Some((px, py)), "{name}");
        let (x, y) = jetbot_xy::label(px, py, 224, 224);
        let _ = jetbot_xy::pixel_for_label(x, y, 224, 224);
    }
});
