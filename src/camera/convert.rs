//! Pixel-format conversion into RGB8: the formats a V4L2 camera or a capture command
//! delivers, turned into the row-major `width * height * 3` bytes a [`Frame`] carries.
//!
//! [`to_rgb`] writes into a caller-owned `Vec<u8>` and only resizes it, so converting
//! frame after frame of the same size allocates nothing. Every format takes a row stride
//! (V4L2's `bytesperline`; 0 means tightly packed); bytes past the last row (a driver's
//! `sizeimage` padding) are ignored, a buffer shorter than its rows is an error.
//!
//! | format | bytes per pixel | conversion |
//! |--------|-----------------|------------|
//! | `YUYV` | 2 (4 per pixel pair: Y0 U Y1 V) | BT.601 limited range, integer maths (below) |
//! | `RGB3` | 3 | copy |
//! | `BGR3` | 3 | swap R and B |
//! | `GREY` | 1 | R = G = B = Y |
//! | `MJPEG` | - | JPEG decode (zune-jpeg); corrupt or truncated -> error |
//!
//! # YUYV
//!
//! Each 4-byte group `Y0 U Y1 V` holds two pixels sharing one chroma pair. With an odd
//! width the device pads each row to whole groups (`(width + 1) / 2 * 4` bytes at least)
//! and the last group's second pixel is dropped. Studio-swing BT.601 (Y in 16..=235,
//! U/V in 16..=240), in fixed point with 8 fractional bits (the coefficients are the
//! real ones times 256, rounded):
//!
//! ```text
//! C = Y - 16,  D = U - 128,  E = V - 128
//! R = clamp((298 C           + 409 E + 128) >> 8)     298/256 = 1.164, 409/256 = 1.596
//! G = clamp((298 C - 100 D   - 208 E + 128) >> 8)     100/256 = 0.391, 208/256 = 0.813
//! B = clamp((298 C + 516 D           + 128) >> 8)     516/256 = 2.018
//! ```
//!
//! Worked: white `Y=235 U=V=128` -> `(298*219 + 128) >> 8 = 255`; black `Y=16` -> 0;
//! red `Y=81 U=90 V=240` -> (255, 0, 0); green `Y=144 U=54 V=34` -> (0, 254, 0);
//! blue `Y=41 U=240 V=110` -> (0, 0, 255). The tests check these.
//!
//! # MJPEG
//!
//! USB cameras send baseline JPEGs, often without Huffman tables (zune-jpeg fills in the
//! standard ones). zune-jpeg is lenient with a cut-short stream (it fills the rest with
//! grey), so a frame must also start with SOI and carry its EOI marker near the end
//! (trailing zero padding allowed): a frame cut short by a USB hiccup is an error here,
//! never a half-grey picture. A decoded size other than the negotiated one is an error.
//!
//! [`Frame`]: super::Frame

use std::path::Path;
use std::sync::Arc;

use zune_jpeg::JpegDecoder;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;

use super::CameraError;
use crate::config::PixelFormat;

/// A frame that cannot be converted; the message names the format, the size and what was
/// wrong with the bytes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ConvertError {
    #[error("{format} {width}x{height}: a frame must be at least 1x1")]
    EmptySize {
        format: &'static str,
        width: u32,
        height: u32,
    },
    #[error("`{format}` is not a concrete pixel format (one of yuyv, mjpeg, rgb3, bgr3, grey)")]
    NotAFormat { format: &'static str },
    #[error(
        "{format} {width}x{height}: row stride {stride} bytes is shorter than one row ({row} bytes)"
    )]
    Stride {
        format: &'static str,
        width: u32,
        height: u32,
        stride: usize,
        row: usize,
    },
    #[error(
        "{format} {width}x{height} (stride {stride}): expected at least {expected} bytes, found {found}"
    )]
    Length {
        format: &'static str,
        width: u32,
        height: u32,
        stride: usize,
        expected: usize,
        found: usize,
    },
    #[error("MJPEG {width}x{height}: corrupt or truncated JPEG ({found} bytes): {reason}")]
    Jpeg {
        width: u32,
        height: u32,
        found: usize,
        reason: String,
    },
    #[error("MJPEG {width}x{height}: the JPEG is {found_width}x{found_height}")]
    JpegSize {
        width: u32,
        height: u32,
        found_width: u32,
        found_height: u32,
    },
}

/// The format's name as V4L2 and the error messages spell it.
pub fn format_name(format: PixelFormat) -> &'static str {
    match format {
        PixelFormat::Auto => "auto",
        PixelFormat::Yuyv => "YUYV",
        PixelFormat::Mjpeg => "MJPEG",
        PixelFormat::Rgb3 => "RGB3",
        PixelFormat::Bgr3 => "BGR3",
        PixelFormat::Grey => "GREY",
    }
}

/// Bytes per pixel of a raw (uncompressed) format; `None` for MJPEG and `auto`.
pub fn bytes_per_pixel(format: PixelFormat) -> Option<usize> {
    match format {
        PixelFormat::Yuyv => Some(2),
        PixelFormat::Rgb3 | PixelFormat::Bgr3 => Some(3),
        PixelFormat::Grey => Some(1),
        PixelFormat::Mjpeg | PixelFormat::Auto => None,
    }
}

/// The bytes one row of a raw format needs at least (YUYV rounds an odd width up to a
/// whole pixel pair); `None` for MJPEG and `auto`.
pub fn row_bytes(format: PixelFormat, width: u32) -> Option<usize> {
    let w = width as usize;
    match format {
        PixelFormat::Yuyv => Some(w.div_ceil(2) * 4),
        f => bytes_per_pixel(f).map(|b| b * w),
    }
}

/// The bytes of a tightly packed raw frame (what a capture command writes per frame);
/// `None` for MJPEG and `auto`.
pub fn packed_frame_len(format: PixelFormat, width: u32, height: u32) -> Option<usize> {
    row_bytes(format, width).map(|r| r * height as usize)
}

/// Converts one frame of `format` into RGB8 in `dst`, resized to `width * height * 3`
/// (no allocation when its capacity already fits). `stride` is the distance between row
/// starts in `src` (0: tightly packed); it is ignored for MJPEG.
pub fn to_rgb(
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
    src: &[u8],
    dst: &mut Vec<u8>,
) -> Result<(), ConvertError> {
    let name = format_name(format);
    if width == 0 || height == 0 {
        return Err(ConvertError::EmptySize {
            format: name,
            width,
            height,
        });
    }
    if format == PixelFormat::Mjpeg {
        return mjpeg(width, height, src, dst);
    }
    let row = row_bytes(format, width).ok_or(ConvertError::NotAFormat { format: name })?;
    let stride = if stride == 0 { row } else { stride };
    if stride < row {
        return Err(ConvertError::Stride {
            format: name,
            width,
            height,
            stride,
            row,
        });
    }
    let (w, h) = (width as usize, height as usize);
    // The last row need not be padded to the full stride.
    let expected = stride * (h - 1) + row;
    if src.len() < expected {
        return Err(ConvertError::Length {
            format: name,
            width,
            height,
            stride,
            expected,
            found: src.len(),
        });
    }
    dst.resize(w * h * 3, 0);
    let rows = dst.chunks_exact_mut(w * 3).enumerate();
    match format {
        PixelFormat::Yuyv => {
            for (y, out) in rows {
                yuyv_row(&src[y * stride..y * stride + row], out);
            }
        }
        PixelFormat::Rgb3 => {
            for (y, out) in rows {
                out.copy_from_slice(&src[y * stride..y * stride + row]);
            }
        }
        PixelFormat::Bgr3 => {
            for (y, out) in rows {
                let line = &src[y * stride..y * stride + row];
                for (o, i) in out.chunks_exact_mut(3).zip(line.chunks_exact(3)) {
                    o[0] = i[2];
                    o[1] = i[1];
                    o[2] = i[0];
                }
            }
        }
        PixelFormat::Grey => {
            for (y, out) in rows {
                let line = &src[y * stride..y * stride + row];
                for (o, &v) in out.chunks_exact_mut(3).zip(line) {
                    o.fill(v);
                }
            }
        }
        PixelFormat::Mjpeg | PixelFormat::Auto => {
            return Err(ConvertError::NotAFormat { format: name });
        }
    }
    Ok(())
}

/// One YUYV row (whole pixel pairs) into one RGB row; an odd width drops the last pair's
/// second pixel (`out` is 3 bytes short of the pairs).
fn yuyv_row(line: &[u8], out: &mut [u8]) {
    for (group, px) in line.chunks_exact(4).zip(out.chunks_mut(6)) {
        let d = group[1] as i32 - 128;
        let e = group[3] as i32 - 128;
        let r_add = 409 * e + 128;
        let g_add = -100 * d - 208 * e + 128;
        let b_add = 516 * d + 128;
        let put = |dst: &mut [u8], yv: u8| {
            let c = 298 * (yv as i32 - 16);
            dst[0] = clamp8((c + r_add) >> 8);
            dst[1] = clamp8((c + g_add) >> 8);
            dst[2] = clamp8((c + b_add) >> 8);
        };
        put(&mut px[0..3], group[0]);
        if px.len() == 6 {
            put(&mut px[3..6], group[2]);
        }
    }
}

#[inline]
fn clamp8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// How far from the end of a frame the EOI marker may sit (the rest is padding).
const EOI_WINDOW: usize = 1024;

fn mjpeg(width: u32, height: u32, src: &[u8], dst: &mut Vec<u8>) -> Result<(), ConvertError> {
    let bad = |reason: String| ConvertError::Jpeg {
        width,
        height,
        found: src.len(),
        reason,
    };
    if src.len() < 4 || src[0] != 0xFF || src[1] != 0xD8 {
        return Err(bad("no start-of-image marker (FF D8)".into()));
    }
    // Entropy-coded data never holds FF D9 (an FF there is followed by 00 or a restart
    // marker), so finding it means the frame reached its end.
    let tail_start = src.len().saturating_sub(EOI_WINDOW).max(2);
    if !src[tail_start..].windows(2).any(|w| w == [0xFF, 0xD9]) {
        return Err(bad(
            "no end-of-image marker (FF D9): the frame was cut short".into(),
        ));
    }
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(ColorSpace::RGB)
        .set_max_width(width as usize)
        .set_max_height(height as usize);
    // zune-jpeg is fuzzed and returns errors, but a camera's bytes are untrusted input to a
    // process that drives motors: a panic in the decoder becomes a skipped frame.
    let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut decoder = JpegDecoder::new_with_options(src, options);
        decoder.decode_headers().map_err(|e| bad(e.to_string()))?;
        let (fw, fh) = decoder
            .dimensions()
            .ok_or_else(|| bad("no frame header".into()))?;
        if (fw, fh) != (width as usize, height as usize) {
            return Err(ConvertError::JpegSize {
                width,
                height,
                found_width: fw as u32,
                found_height: fh as u32,
            });
        }
        let pixels = fw * fh;
        dst.resize(pixels * 3, 0);
        match decoder.output_buffer_size() {
            Some(n) if n == pixels * 3 => decoder.decode_into(dst).map_err(|e| bad(e.to_string())),
            Some(n) if n == pixels => {
                // A greyscale JPEG comes out as luma only: decode into the front, then
                // spread each value over three bytes from the back (never overtaking a
                // value not yet read).
                decoder
                    .decode_into(&mut dst[..pixels])
                    .map_err(|e| bad(e.to_string()))?;
                for i in (0..pixels).rev() {
                    let v = dst[i];
                    dst[i * 3..i * 3 + 3].fill(v);
                }
                Ok(())
            }
            other => Err(bad(format!(
                "decoder output is {other:?} bytes, neither RGB ({}) nor grey ({pixels})",
                pixels * 3
            ))),
        }
    }));
    match decoded {
        Ok(result) => result,
        Err(_) => Err(bad("the JPEG decoder panicked".into())),
    }
}

/// RGB8 buffers shared with the frames handed out, reused once every frame holding one
/// has been dropped: converting into a free buffer allocates nothing.
#[derive(Debug)]
pub struct RgbPool {
    bufs: Vec<Arc<Vec<u8>>>,
    max: usize,
    next_evict: usize,
}

impl RgbPool {
    /// A pool keeping at most `max` buffers (at least 1).
    pub fn new(max: usize) -> Self {
        Self {
            bufs: Vec::new(),
            max: max.max(1),
            next_evict: 0,
        }
    }

    /// Runs `fill` on a buffer no frame holds any more (a new one when all are held) and
    /// returns it shared. When `fill` fails the buffer stays in the pool.
    pub fn fill<E>(
        &mut self,
        fill: impl FnOnce(&mut Vec<u8>) -> Result<(), E>,
    ) -> Result<Arc<Vec<u8>>, E> {
        let index = match self.bufs.iter_mut().position(|b| Arc::get_mut(b).is_some()) {
            Some(i) => i,
            None if self.bufs.len() < self.max => {
                self.bufs.push(Arc::new(Vec::new()));
                self.bufs.len() - 1
            }
            None => {
                // Every buffer is still held downstream: replace one; its holders keep it.
                let i = self.next_evict % self.max;
                self.next_evict = self.next_evict.wrapping_add(1);
                self.bufs[i] = Arc::new(Vec::new());
                i
            }
        };
        let slot = &mut self.bufs[index];
        match Arc::get_mut(slot) {
            Some(buf) => fill(buf)?,
            None => {
                // Unreachable by construction; stay correct anyway.
                let mut buf = Vec::new();
                fill(&mut buf)?;
                *slot = Arc::new(buf);
            }
        }
        Ok(slot.clone())
    }

    /// Buffers held by the pool (free or not).
    pub fn len(&self) -> usize {
        self.bufs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.bufs.is_empty()
    }
}

/// Writes an RGB8 image as PNG or JPEG (quality 90), chosen by `out`'s extension.
pub fn write_image(out: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<(), CameraError> {
    let err =
        |reason: String| CameraError::Other(format!("cannot write {}: {reason}", out.display()));
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let expected = width as usize * height as usize * 3;
    if rgb.len() != expected {
        return Err(err(format!(
            "{width}x{height} RGB8 needs {expected} bytes, got {}",
            rgb.len()
        )));
    }
    match ext.as_str() {
        "png" => image::save_buffer_with_format(
            out,
            rgb,
            width,
            height,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| err(e.to_string())),
        "jpg" | "jpeg" => {
            let file = std::fs::File::create(out).map_err(|e| err(e.to_string()))?;
            let mut w = std::io::BufWriter::new(file);
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut w, 90)
                .encode(rgb, width, height, image::ExtendedColorType::Rgb8)
                .map_err(|e| err(e.to_string()))?;
            std::io::Write::flush(&mut w).map_err(|e| err(e.to_string()))
        }
        _ => Err(err("unknown image type: name it .png, .jpg or .jpeg".into())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn yuyv(pairs: &[[u8; 4]]) -> Vec<u8> {
        pairs.concat()
    }

    fn convert(format: PixelFormat, w: u32, h: u32, stride: usize, src: &[u8]) -> Vec<u8> {
        let mut dst = Vec::new();
        to_rgb(format, w, h, stride, src, &mut dst).unwrap();
        dst
    }

    #[test]
    fn yuyv_primaries_with_worked_numbers() {
        // (Y, U, V) for one pixel pair -> both pixels' RGB, see the module doc.
        let cases: [([u8; 3], [u8; 3]); 6] = [
            ([235, 128, 128], [255, 255, 255]), // white
            ([16, 128, 128], [0, 0, 0]),        // black
            ([126, 128, 128], [128, 128, 128]), // mid grey: (298*110+128)>>8 = 128
            ([81, 90, 240], [255, 0, 0]),       // red
            ([144, 54, 34], [0, 254, 0]),       // green: (298*128+7400+19552+128)>>8 = 254
            ([41, 240, 110], [0, 0, 255]),      // blue
        ];
        for ([y, u, v], rgb) in cases {
            let out = convert(PixelFormat::Yuyv, 2, 1, 0, &yuyv(&[[y, u, y, v]]));
            assert_eq!(out, [rgb, rgb].concat(), "Y={y} U={u} V={v}");
        }
        // Out-of-range values clamp instead of wrapping.
        let out = convert(PixelFormat::Yuyv, 2, 1, 0, &[255, 255, 0, 255]);
        // Y=255: (298*239 + 409*127 + 128) >> 8 = 481 -> 255, G = 125, B = 534 -> 255;
        // Y=0: R = 184, G < 0 -> 0, B = 237.
        assert_eq!(out, vec![255, 125, 255, 184, 0, 237]);
    }

    #[test]
    fn yuyv_odd_width_with_stride_padding() {
        // 3x2: each row is two pixel pairs (8 bytes) padded to a 10-byte stride; the
        // second pair's second pixel is dropped. The last row is not padded.
        let mut src = Vec::new();
        src.extend_from_slice(&[235, 128, 16, 128, 81, 90, 99, 240]); // white black | red (x)
        src.extend_from_slice(&[0xEE, 0xEE]); // padding
        src.extend_from_slice(&[41, 240, 126, 110, 16, 128, 99, 128]); // blue ~blue | black (x)
        let out = convert(PixelFormat::Yuyv, 3, 2, 10, &src);
        let row0 = [255, 255, 255, 0, 0, 0, 255, 0, 0];
        // (126, U=240, V=110): C=110 -> R=(32780-7362+128)>>8=99, G=(32780-11200+3744+128)>>8=99,
        // B=(32780+57792+128)>>8=354 -> 255.
        let row1 = [0, 0, 255, 99, 99, 255, 0, 0, 0];
        assert_eq!(out, [row0, row1].concat());
        // Packed (stride 0) means 8 bytes a row; a 10-byte stride needs 18 bytes.
        let err = to_rgb(PixelFormat::Yuyv, 3, 2, 10, &src[..17], &mut Vec::new()).unwrap_err();
        assert!(
            matches!(
                err,
                ConvertError::Length {
                    expected: 18,
                    found: 17,
                    ..
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn rgb3_copy_and_bgr3_swap_with_stride() {
        // 2x2, stride 8 (2 padding bytes a row).
        let src = [
            1, 2, 3, 4, 5, 6, 0, 0, //
            7, 8, 9, 10, 11, 12, 0, 0,
        ];
        let rgb = convert(PixelFormat::Rgb3, 2, 2, 8, &src);
        assert_eq!(rgb, vec![1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
        let bgr = convert(PixelFormat::Bgr3, 2, 2, 8, &src);
        assert_eq!(bgr, vec![3, 2, 1, 6, 5, 4, 9, 8, 7, 12, 11, 10]);
    }

    #[test]
    fn grey_replicates() {
        // 3x2 with a stride of 4.
        let src = [10, 20, 30, 0, 40, 50, 60];
        let out = convert(PixelFormat::Grey, 3, 2, 4, &src);
        assert_eq!(
            out,
            vec![
                10, 10, 10, 20, 20, 20, 30, 30, 30, 40, 40, 40, 50, 50, 50, 60, 60, 60
            ]
        );
    }

    #[test]
    fn wrong_length_stride_and_format_are_errors() {
        let mut dst = Vec::new();
        let err = to_rgb(PixelFormat::Rgb3, 4, 4, 0, &[0; 47], &mut dst).unwrap_err();
        assert_eq!(
            err,
            ConvertError::Length {
                format: "RGB3",
                width: 4,
                height: 4,
                stride: 12,
                expected: 48,
                found: 47
            }
        );
        let msg = err.to_string();
        assert!(
            msg.contains("RGB3 4x4") && msg.contains("48") && msg.contains("47"),
            "{msg}"
        );
        let err = to_rgb(PixelFormat::Grey, 4, 4, 3, &[0; 64], &mut dst).unwrap_err();
        assert!(matches!(err, ConvertError::Stride { row: 4, .. }), "{err}");
        let err = to_rgb(PixelFormat::Auto, 4, 4, 0, &[0; 64], &mut dst).unwrap_err();
        assert!(matches!(err, ConvertError::NotAFormat { .. }), "{err}");
        let err = to_rgb(PixelFormat::Grey, 0, 4, 0, &[], &mut dst).unwrap_err();
        assert!(matches!(err, ConvertError::EmptySize { .. }), "{err}");
        // Driver padding past the last row is fine.
        to_rgb(PixelFormat::Grey, 4, 4, 0, &[0; 100], &mut dst).unwrap();
        assert_eq!(dst.len(), 48);
    }

    #[test]
    fn reuses_the_destination_buffer() {
        let src = vec![7u8; 64 * 48 * 2];
        let mut dst = Vec::new();
        to_rgb(PixelFormat::Yuyv, 64, 48, 0, &src, &mut dst).unwrap();
        let ptr = dst.as_ptr();
        let cap = dst.capacity();
        for _ in 0..3 {
            to_rgb(PixelFormat::Yuyv, 64, 48, 0, &src, &mut dst).unwrap();
        }
        assert_eq!((dst.as_ptr(), dst.capacity()), (ptr, cap));
        // A smaller frame reuses it too.
        to_rgb(PixelFormat::Grey, 8, 8, 0, &[1; 64], &mut dst).unwrap();
        assert_eq!((dst.as_ptr(), dst.len()), (ptr, 192));
    }

    /// A 32x16 test card: four colour bars on top, a grey ramp below.
    fn test_card() -> (u32, u32, Vec<u8>) {
        let (w, h) = (32u32, 16u32);
        let bars = [
            [230u8, 40, 40],
            [40, 200, 40],
            [40, 40, 220],
            [240, 240, 240],
        ];
        let mut rgb = Vec::new();
        for y in 0..h {
            for x in 0..w {
                if y < 8 {
                    rgb.extend_from_slice(&bars[(x / 8) as usize]);
                } else {
                    let v = (x * 8) as u8;
                    rgb.extend_from_slice(&[v, v, v]);
                }
            }
        }
        (w, h, rgb)
    }

    fn encode_jpeg(w: u32, h: u32, rgb: &[u8]) -> Vec<u8> {
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode(rgb, w, h, image::ExtendedColorType::Rgb8)
            .unwrap();
        jpeg
    }

    #[test]
    fn mjpeg_round_trip_within_jpeg_tolerance() {
        let (w, h, rgb) = test_card();
        let mut jpeg = encode_jpeg(w, h, &rgb);
        let out = convert(PixelFormat::Mjpeg, w, h, 0, &jpeg);
        assert_eq!(out.len(), rgb.len());
        let worst = out
            .iter()
            .zip(&rgb)
            .map(|(a, b)| (*a as i32 - *b as i32).abs())
            .max()
            .unwrap();
        let mean = out
            .iter()
            .zip(&rgb)
            .map(|(a, b)| (*a as i32 - *b as i32).abs() as f64)
            .sum::<f64>()
            / rgb.len() as f64;
        // Quality 95 with 4:2:0 chroma: colour edges blur a little, flat areas are exact-ish.
        assert!(mean < 4.0 && worst < 80, "mean {mean:.2}, worst {worst}");
        // A pixel in the middle of the red bar, one in the ramp.
        let px = |x: u32, y: u32| &out[((y * w + x) * 3) as usize..][..3];
        for (a, b) in px(3, 3).iter().zip([230, 40, 40]) {
            assert!((*a as i32 - b).abs() <= 6, "{:?}", px(3, 3));
        }
        for (a, b) in px(20, 12).iter().zip([160, 160, 160]) {
            assert!((*a as i32 - b).abs() <= 6, "{:?}", px(20, 12));
        }
        // Zero padding after EOI, as UVC buffers have, is accepted.
        jpeg.extend_from_slice(&[0; 100]);
        assert_eq!(convert(PixelFormat::Mjpeg, w, h, 0, &jpeg), out);
    }

    #[test]
    fn mjpeg_greyscale_jpeg_decodes_to_rgb() {
        let (w, h) = (16u32, 8u32);
        let luma: Vec<u8> = (0..w * h).map(|i| (i % 16 * 16) as u8).collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode(&luma, w, h, image::ExtendedColorType::L8)
            .unwrap();
        let out = convert(PixelFormat::Mjpeg, w, h, 0, &jpeg);
        assert_eq!(out.len(), (w * h * 3) as usize);
        for (px, l) in out.chunks_exact(3).zip(&luma) {
            assert_eq!(px[0], px[1]);
            assert!((px[0] as i32 - *l as i32).abs() <= 12, "{px:?} vs {l}");
        }
    }

    #[test]
    fn mjpeg_truncated_garbage_and_wrong_size_are_errors() {
        let (w, h, rgb) = test_card();
        let jpeg = encode_jpeg(w, h, &rgb);
        let mut dst = Vec::new();
        for cut in [2, 20, jpeg.len() / 2, jpeg.len() - 2] {
            let err = to_rgb(PixelFormat::Mjpeg, w, h, 0, &jpeg[..cut], &mut dst).unwrap_err();
            assert!(matches!(err, ConvertError::Jpeg { .. }), "cut {cut}: {err}");
            assert!(err.to_string().contains("MJPEG 32x16"), "{err}");
        }
        let garbage: Vec<u8> = (0..2000u32).map(|i| (i * 7919 % 251) as u8).collect();
        let err = to_rgb(PixelFormat::Mjpeg, w, h, 0, &garbage, &mut dst).unwrap_err();
        assert!(matches!(err, ConvertError::Jpeg { .. }), "{err}");
        // SOI + garbage + EOI: headers make no sense.
        let mut framed = vec![0xFF, 0xD8];
        framed.extend_from_slice(&garbage);
        framed.extend_from_slice(&[0xFF, 0xD9]);
        let err = to_rgb(PixelFormat::Mjpeg, w, h, 0, &framed, &mut dst).unwrap_err();
        assert!(matches!(err, ConvertError::Jpeg { .. }), "{err}");
        // Headers intact, scan data replaced by garbage.
        let mut scrambled = jpeg.clone();
        let n = scrambled.len();
        for (i, b) in scrambled[n / 2..n - 2].iter_mut().enumerate() {
            *b = (i * 31 % 256) as u8;
        }
        let _ = to_rgb(PixelFormat::Mjpeg, w, h, 0, &scrambled, &mut dst); // no panic
        // A JPEG of another size than negotiated.
        let err = to_rgb(PixelFormat::Mjpeg, 16, 16, 0, &jpeg, &mut dst).unwrap_err();
        assert!(
            matches!(
                err,
                ConvertError::JpegSize { .. } | ConvertError::Jpeg { .. }
            ),
            "{err}"
        );
        let err = to_rgb(PixelFormat::Mjpeg, 64, 32, 0, &jpeg, &mut dst).unwrap_err();
        assert_eq!(
            err,
            ConvertError::JpegSize {
                width: 64,
                height: 32,
                found_width: 32,
                found_height: 16
            }
        );
    }

    #[test]
    fn pool_reuses_buffers_once_frames_are_dropped() {
        let mut pool = RgbPool::new(2);
        let a = pool
            .fill(|b| to_rgb(PixelFormat::Grey, 2, 2, 0, &[1, 2, 3, 4], b))
            .unwrap();
        let a_ptr = a.as_ptr();
        drop(a);
        let b = pool
            .fill(|b| to_rgb(PixelFormat::Grey, 2, 2, 0, &[5, 6, 7, 8], b))
            .unwrap();
        assert_eq!(b.as_ptr(), a_ptr, "the free buffer is reused");
        assert_eq!(b[0], 5);
        // While `b` is held, a second buffer is used; the pool never grows past 2.
        let c = pool.fill(|v| -> Result<(), ()> {
            v.push(9);
            Ok(())
        });
        let c = c.unwrap();
        let d = pool
            .fill(|v| -> Result<(), ()> {
                v.push(10);
                Ok(())
            })
            .unwrap();
        assert_eq!((b[0], c[0], d[0], pool.len()), (5, 9, 10, 2));
        // A failed fill hands nothing out.
        assert!(pool.fill(|_| Err("bad frame")).is_err());
    }

    #[test]
    fn helpers_and_image_writer() {
        assert_eq!(row_bytes(PixelFormat::Yuyv, 3), Some(8));
        assert_eq!(packed_frame_len(PixelFormat::Bgr3, 224, 224), Some(150528));
        assert_eq!(packed_frame_len(PixelFormat::Mjpeg, 224, 224), None);
        let dir = tempfile::tempdir().unwrap();
        let (w, h, rgb) = test_card();
        for name in ["a.png", "b.JPG"] {
            let p = dir.path().join(name);
            write_image(&p, w, h, &rgb).unwrap();
            let back = image::open(&p).unwrap().to_rgb8();
            assert_eq!(back.dimensions(), (w, h));
        }
        let png = image::open(dir.path().join("a.png")).unwrap().to_rgb8();
        assert_eq!(png.into_raw(), rgb);
        let err = write_image(&dir.path().join("c.bmp"), w, h, &rgb).unwrap_err();
        assert!(err.to_string().contains(".png"), "{err}");
    }
}
