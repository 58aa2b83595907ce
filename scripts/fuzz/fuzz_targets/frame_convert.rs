//! Camera buffers to RGB: every pixel format (YUYV, MJPEG, RGB3, BGR3, GREY) with odd sizes
//! and strides, as V4L2 devices and capture commands deliver them.
#![no_main]
use jetpilot::camera::convert;
use jetpilot::config::PixelFormat;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if data.len() < 4 {
        return;
    }
    let format = match data[0] % 6 {
        0 => PixelFormat::Auto,
        1 => PixelFormat::Yuyv,
        2 => PixelFormat::Mjpeg,
        3 => PixelFormat::Rgb3,
        4 => PixelFormat::Bgr3,
        _ => PixelFormat::Grey,
    };
    // Up to 64x64 (a fuzz input is small), strides up to 255 bytes past the row.
    let width = u32::from(data[1] % 65);
    let height = u32::from(data[2] % 65);
    let stride = match convert::row_bytes(format, width) {
        Some(row) if data[3] > 0 => row + usize::from(data[3]) - 1,
        _ => 0,
    };
    let mut rgb = Vec::new();
    if convert::to_rgb(format, width, height, stride, &data[4..], &mut rgb).is_ok() {
        assert_eq!(rgb.len(), (width * height * 3) as usize);
    }
});
