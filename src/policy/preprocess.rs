//! Frame preprocessing: owns the path from an RGB8 camera frame of any size to the NCHW f32
//! tensor a policy network takes, as stated by its [`ModelContract`].
//!
//! Steps, in order:
//! 1. resize the whole frame to `input_size x input_size` (squashed, never cropped, as
//!    JetBot's camera pipeline does) with `fast_image_resize`'s bilinear convolution; the
//!    resize is skipped when the frame already has the target size;
//! 2. arrange the colour planes in the contract's channel order (RGB or BGR);
//! 3. normalise each value as `(v / 255 - mean[c]) / std[c]`, where `c` is the index of the
//!    plane in the *tensor* (as torchvision's `Normalize` and JetBot's notebooks do: a BGR
//!    model gets `mean[0]` on its blue plane);
//! 4. lay the result out as `[1, 3, S, S]` (plane after plane, rows top to bottom).
//!
//! Nothing is allocated per frame: the resizer (with its scratch buffers), the resized image
//! and the output tensor live in the [`Preprocessor`], and the normalisation is a 256-entry
//! lookup table per plane.

use fast_image_resize::images::{Image, ImageRef};
use fast_image_resize::{FilterType, PixelType, ResizeAlg, ResizeOptions, Resizer};

use super::contract::{ChannelOrder, ModelContract};

/// Why a frame could not be turned into a tensor.
#[derive(Debug, thiserror::Error)]
pub enum PreprocessError {
    /// The pixel buffer does not hold exactly `width * height * 3` bytes.
    #[error(
        "RGB8 frame {width}x{height} needs {expected} bytes (width * height * 3), the buffer has {found}"
    )]
    BufferLength {
        width: u32,
        height: u32,
        expected: u64,
        found: usize,
    },
    /// Width or height is zero.
    #[error("frame has zero size ({width}x{height})")]
    ZeroSize { width: u32, height: u32 },
    /// `fast_image_resize` refused the frame.
    #[error("resizing the {width}x{height} frame to {size}x{size} failed: {reason}")]
    Resize {
        width: u32,
        height: u32,
        size: u32,
        reason: String,
    },
}

/// Turns RGB8 frames into the input tensor of one model contract, reusing its buffers.
pub struct Preprocessor {
    size: u32,
    /// For each tensor plane, the index of the RGB component it takes.
    source_channel: [usize; 3],
    /// Per tensor plane: `lut[p][v] = (v / 255 - mean[p]) / std[p]`.
    lut: [[f32; 256]; 3],
    scaler: Scaler,
    /// The NCHW tensor, `3 * size * size` values; allocated once.
    output: Vec<f32>,
}

/// Step 1's state: the resizer with its scratch buffers and the resized image (kept apart
/// from the tables and the output so that both can be borrowed beside it).
struct Scaler {
    size: u32,
    resizer: Resizer,
    options: ResizeOptions,
    /// The frame resized to `size x size`, RGB8; allocated once.
    resized: Image<'static>,
}

impl Scaler {
    fn apply<'a>(
        &'a mut self,
        width: u32,
        height: u32,
        rgb: &'a [u8],
    ) -> Result<&'a [u8], PreprocessError> {
        if width == 0 || height == 0 {
            return Err(PreprocessError::ZeroSize { width, height });
        }
        let expected = u64::from(width)
            .saturating_mul(u64::from(height))
            .saturating_mul(3);
        if rgb.len() as u64 != expected {
            return Err(PreprocessError::BufferLength {
                width,
                height,
                expected,
                found: rgb.len(),
            });
        }
        let size = self.size;
        if width == size && height == size {
            return Ok(rgb);
        }
        let resize_err = |reason: String| PreprocessError::Resize {
            width,
            height,
            size,
            reason,
        };
        let src = ImageRef::new(width, height, rgb, PixelType::U8x3)
            .map_err(|e| resize_err(e.to_string()))?;
        self.resizer
            .resize(&src, &mut self.resized, &self.options)
            .map_err(|e| resize_err(e.to_string()))?;
        Ok(self.resized.buffer())
    }
}

impl std::fmt::Debug for Preprocessor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Preprocessor")
            .field("size", &self.size)
            .field("source_channel", &self.source_channel)
            .finish_non_exhaustive()
    }
}

impl Preprocessor {
    /// Builds the lookup tables and allocates the resized image and the output tensor.
    pub fn new(contract: &ModelContract) -> Self {
        let size = contract.input_size;
        let source_channel = match contract.channel_order {
            ChannelOrder::Rgb => [0, 1, 2],
            ChannelOrder::Bgr => [2, 1, 0],
        };
        let mut lut = [[0.0f32; 256]; 3];
        for (plane, table) in lut.iter_mut().enumerate() {
            let mean = f64::from(contract.mean[plane]);
            let std = f64::from(contract.std[plane]);
            for (v, entry) in table.iter_mut().enumerate() {
                *entry = ((v as f64 / 255.0 - mean) / std) as f32;
            }
        }
        let pixels = size as usize * size as usize;
        Self {
            size,
            source_channel,
            lut,
            scaler: Scaler {
                size,
                resizer: Resizer::new(),
                options: ResizeOptions::new()
                    .resize_alg(ResizeAlg::Convolution(FilterType::Bilinear)),
                resized: Image::new(size, size, PixelType::U8x3),
            },
            output: vec![0.0; 3 * pixels],
        }
    }

    /// The side of the square network input, in pixels.
    pub fn input_size(&self) -> u32 {
        self.size
    }

    /// Step 1 alone: the frame resized to `input_size x input_size`, RGB8 (the frame itself
    /// when it already has that size). The trainer caches these so that its inputs are the
    /// daemon's, pixel for pixel.
    pub fn resize<'a>(
        &'a mut self,
        width: u32,
        height: u32,
        rgb: &'a [u8],
    ) -> Result<&'a [u8], PreprocessError> {
        self.scaler.apply(width, height, rgb)
    }

    /// Preprocesses one RGB8 frame (`width * height * 3` bytes, rows top to bottom, no
    /// padding) and returns the NCHW tensor data, `3 * input_size * input_size` values.
    ///
    /// The returned slice is the preprocessor's own buffer: it is overwritten by the next
    /// call.
    pub fn run(&mut self, width: u32, height: u32, rgb: &[u8]) -> Result<&[f32], PreprocessError> {
        let size = self.size;
        let pixels = self.scaler.apply(width, height, rgb)?;
        let plane_len = size as usize * size as usize;
        let (p0, rest) = self.output.split_at_mut(plane_len);
        let (p1, p2) = rest.split_at_mut(plane_len);
        let [c0, c1, c2] = self.source_channel;
        let [l0, l1, l2] = &self.lut;
        for (((px, o0), o1), o2) in pixels
            .chunks_exact(3)
            .zip(p0.iter_mut())
            .zip(p1.iter_mut())
            .zip(p2.iter_mut())
        {
            *o0 = l0[usize::from(px[c0])];
            *o1 = l1[usize::from(px[c1])];
            *o2 = l2[usize::from(px[c2])];
        }
        Ok(&self.output)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::contract::{IMAGENET_MEAN, IMAGENET_STD, OutputKind};

    fn contract(size: u32, order: ChannelOrder) -> ModelContract {
        ModelContract {
            input_size: size,
            channel_order: order,
            mean: IMAGENET_MEAN,
            std: IMAGENET_STD,
            output: OutputKind::Xy,
        }
    }

    fn close(a: f32, b: f32, tol: f32) -> bool {
        (a - b).abs() <= tol
    }

    /// 2x2 frame, already at the target size (no resize):
    /// (255,0,128) (0,0,0)
    /// (255,255,255) (10,20,30)
    const FRAME_2X2: [u8; 12] = [255, 0, 128, 0, 0, 0, 255, 255, 255, 10, 20, 30];

    fn norm(v: u8, plane: usize) -> f32 {
        ((v as f64 / 255.0 - IMAGENET_MEAN[plane] as f64) / IMAGENET_STD[plane] as f64) as f32
    }

    #[test]
    fn rgb_exact_values_without_resize() {
        let mut p = Preprocessor::new(&contract(2, ChannelOrder::Rgb));
        assert_eq!(p.input_size(), 2);
        let t = p.run(2, 2, &FRAME_2X2).unwrap().to_vec();
        assert_eq!(t.len(), 12);
        // Pixel 0 = (255, 0, 128):
        // R plane: (1 - 0.485) / 0.229 = 2.2489083
        // G plane: (0 - 0.456) / 0.224 = -2.0357143
        // B plane: (128/255 - 0.406) / 0.225 = (0.5019608 - 0.406) / 0.225 = 0.4264924
        assert!(close(t[0], 2.2489083, 1e-5), "{}", t[0]);
        assert!(close(t[4], -2.0357143, 1e-5), "{}", t[4]);
        assert!(close(t[8], 0.4264924, 1e-5), "{}", t[8]);
        // Pixel 1 = black: -mean/std per plane.
        // R: -0.485/0.229 = -2.117904, G: -2.0357143, B: -0.406/0.225 = -1.8044444
        assert!(close(t[1], -2.117904, 1e-5), "{}", t[1]);
        assert!(close(t[5], -2.0357143, 1e-5), "{}", t[5]);
        assert!(close(t[9], -1.8044444, 1e-5), "{}", t[9]);
        // Pixel 2 = white: R (1-0.485)/0.229 = 2.2489083, G (1-0.456)/0.224 = 2.4285714,
        // B (1-0.406)/0.225 = 2.64
        assert!(close(t[2], 2.2489083, 1e-5), "{}", t[2]);
        assert!(close(t[6], 2.4285714, 1e-5), "{}", t[6]);
        assert!(close(t[10], 2.64, 1e-5), "{}", t[10]);
        // Every value against the formula, NCHW: t[c * 4 + y * 2 + x].
        for i in 0..4 {
            for c in 0..3 {
                assert!(close(t[c * 4 + i], norm(FRAME_2X2[i * 3 + c], c), 1e-6));
            }
        }
    }

    #[test]
    fn bgr_exact_values_without_resize() {
        let mut p = Preprocessor::new(&contract(2, ChannelOrder::Bgr));
        let t = p.run(2, 2, &FRAME_2X2).unwrap().to_vec();
        // Pixel 0 = (R 255, G 0, B 128); plane 0 is blue with mean[0]/std[0]:
        // plane 0: (128/255 - 0.485) / 0.229 = (0.5019608 - 0.485) / 0.229 = 0.0740646
        // plane 1: (0 - 0.456) / 0.224 = -2.0357143
        // plane 2: (255/255 - 0.406) / 0.225 = 2.64
        assert!(close(t[0], 0.0740646, 1e-5), "{}", t[0]);
        assert!(close(t[4], -2.0357143, 1e-5), "{}", t[4]);
        assert!(close(t[8], 2.64, 1e-5), "{}", t[8]);
        // Pixel 3 = (10, 20, 30): plane 0 takes 30, plane 2 takes 10.
        assert!(close(t[3], norm(30, 0), 1e-6));
        assert!(close(t[7], norm(20, 1), 1e-6));
        assert!(close(t[11], norm(10, 2), 1e-6));
    }

    #[test]
    fn uniform_frame_resizes_to_uniform_value() {
        let (r, g, b) = (37u8, 190u8, 99u8);
        let frame: Vec<u8> = std::iter::repeat_n([r, g, b], 640 * 480)
            .flatten()
            .collect();
        let mut p = Preprocessor::new(&contract(224, ChannelOrder::Rgb));
        let t = p.run(640, 480, &frame).unwrap();
        let n = 224 * 224;
        assert_eq!(t.len(), 3 * n);
        for (plane, v) in [r, g, b].into_iter().enumerate() {
            let want = norm(v, plane);
            for (i, got) in t[plane * n..(plane + 1) * n].iter().enumerate() {
                assert!(
                    close(*got, want, 1e-6),
                    "plane {plane} index {i}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn left_red_right_blue_keeps_sides_and_planes() {
        let (w, h) = (640u32, 480u32);
        let mut frame = Vec::with_capacity((w * h * 3) as usize);
        for _y in 0..h {
            for x in 0..w {
                if x < w / 2 {
                    frame.extend_from_slice(&[255, 0, 0]);
                } else {
                    frame.extend_from_slice(&[0, 0, 255]);
                }
            }
        }
        let s = 224usize;
        let n = s * s;
        let at = |t: &[f32], c: usize, y: usize, x: usize| t[c * n + y * s + x];

        let mut p = Preprocessor::new(&contract(224, ChannelOrder::Rgb));
        let t = p.run(w, h, &frame).unwrap().to_vec();
        for y in [0, 100, 223] {
            for x in [0, 50, 100] {
                // Left: pure red.
                assert!(close(at(&t, 0, y, x), norm(255, 0), 1e-6));
                assert!(close(at(&t, 2, y, x), norm(0, 2), 1e-6));
            }
            for x in [123, 180, 223] {
                // Right: pure blue.
                assert!(close(at(&t, 0, y, x), norm(0, 0), 1e-6));
                assert!(close(at(&t, 2, y, x), norm(255, 2), 1e-6));
            }
            for x in 0..s {
                // No green anywhere.
                assert!(close(at(&t, 1, y, x), norm(0, 1), 1e-6));
            }
        }

        // BGR: plane 0 is now blue, so it is high on the right.
        let mut p = Preprocessor::new(&contract(224, ChannelOrder::Bgr));
        let t = p.run(w, h, &frame).unwrap().to_vec();
        assert!(at(&t, 0, 10, 10) < 0.0 && at(&t, 0, 10, 200) > 2.0);
        assert!(at(&t, 2, 10, 10) > 2.0 && at(&t, 2, 10, 200) < 0.0);
    }

    #[test]
    fn wrong_length_and_zero_size_are_errors() {
        let mut p = Preprocessor::new(&contract(224, ChannelOrder::Rgb));
        let err = p.run(640, 480, &[0u8; 100]).unwrap_err();
        match &err {
            PreprocessError::BufferLength {
                width,
                height,
                expected,
                found,
            } => {
                assert_eq!(
                    (*width, *height, *expected, *found),
                    (640, 480, 921_600, 100)
                );
            }
            other => panic!("unexpected {other:?}"),
        }
        let msg = err.to_string();
        assert!(
            msg.contains("921600") && msg.contains("100") && msg.contains("640x480"),
            "{msg}"
        );
        // One byte too many is also wrong.
        assert!(matches!(
            p.run(2, 2, &[0u8; 13]),
            Err(PreprocessError::BufferLength { .. })
        ));
        assert!(matches!(
            p.run(0, 480, &[]),
            Err(PreprocessError::ZeroSize {
                width: 0,
                height: 480
            })
        ));
    }

    #[test]
    fn buffer_is_reused_between_runs() {
        let mut p = Preprocessor::new(&contract(224, ChannelOrder::Rgb));
        let a = vec![10u8; 320 * 240 * 3];
        let b = vec![200u8; 640 * 480 * 3];
        let c = vec![50u8; 224 * 224 * 3];
        let p1 = p.run(320, 240, &a).unwrap().as_ptr();
        let p2 = p.run(640, 480, &b).unwrap().as_ptr();
        let p3 = p.run(224, 224, &c).unwrap().as_ptr();
        assert_eq!(p1, p2);
        assert_eq!(p2, p3);
        let t = p.run(224, 224, &c).unwrap();
        assert_eq!(t.as_ptr(), p1);
        assert!(close(t[0], norm(50, 0), 1e-6));
    }
}
