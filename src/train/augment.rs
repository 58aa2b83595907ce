//! JetBot's augmentation and the input tensor: owns turning cached RGB8 frames into the
//! normalised NCHW batch a training step takes, with a random horizontal flip (the label's
//! mirrored component negated) and colour jitter.
//!
//! Jitter follows torchvision's `ColorJitter(b, c, s, h)` that JetBot's notebook uses, with
//! its factors drawn per image, applied in a fixed order on values in 0..1:
//!
//! ```text
//! brightness: v * fb                              fb ~ U(1 - b, 1 + b)
//! contrast:   mean_gray + (v - mean_gray) * fc    fc ~ U(1 - c, 1 + c)
//! saturation: gray + (v - gray) * fs              fs ~ U(1 - s, 1 + s)
//! hue:        rotate the chroma by 2 pi * fh      fh ~ U(-h, h)   (YIQ rotation)
//! clamp to 0..1, then (v - mean[c]) / std[c] in the contract's channel order
//! ```
//!
//! With no augmentation the tensor equals the daemon's [`Preprocessor`] output on the
//! same frame (to float rounding).
//!
//! [`Preprocessor`]: crate::policy::Preprocessor

use rand::Rng;

use super::data::Sample;
use crate::policy::{ChannelOrder, ModelContract};

/// Augmentation settings (JetBot's: flip on, jitter 0.3 each).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Augment {
    /// Mirror half of the images left-right, negating the label's `mirrored` component.
    pub flip: bool,
    pub brightness: f32,
    pub contrast: f32,
    pub saturation: f32,
    pub hue: f32,
}

impl Augment {
    pub const NONE: Augment = Augment {
        flip: false,
        brightness: 0.0,
        contrast: 0.0,
        saturation: 0.0,
        hue: 0.0,
    };
    pub const JETBOT: Augment = Augment {
        flip: true,
        brightness: 0.3,
        contrast: 0.3,
        saturation: 0.3,
        hue: 0.3,
    };
}

/// The factors drawn for one image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Draw {
    pub flip: bool,
    pub brightness: f32,
    pub contrast: f32,
    pub saturation: f32,
    /// Fraction of a full turn.
    pub hue: f32,
}

impl Draw {
    pub const IDENTITY: Draw = Draw {
        flip: false,
        brightness: 1.0,
        contrast: 1.0,
        saturation: 1.0,
        hue: 0.0,
    };

    pub fn sample(a: &Augment, rng: &mut impl Rng) -> Self {
        fn factor(rng: &mut impl Rng, j: f32) -> f32 {
            if j > 0.0 {
                rng.random_range((1.0 - j).max(0.0)..=1.0 + j)
            } else {
                1.0
            }
        }
        Self {
            flip: a.flip && rng.random_bool(0.5),
            brightness: factor(rng, a.brightness),
            contrast: factor(rng, a.contrast),
            saturation: factor(rng, a.saturation),
            hue: if a.hue > 0.0 {
                rng.random_range(-a.hue..=a.hue)
            } else {
                0.0
            },
        }
    }
}

fn gray(r: f32, g: f32, b: f32) -> f32 {
    0.299 * r + 0.587 * g + 0.114 * b
}

/// Writes one image's tensor (`3 * size * size` values, NCHW plane order) into `out`.
pub fn write_input(pixels: &[u8], size: u32, contract: &ModelContract, d: &Draw, out: &mut [f32]) {
    let s = size as usize;
    let plane = s * s;
    let jitter = d.brightness != 1.0 || d.contrast != 1.0 || d.saturation != 1.0 || d.hue != 0.0;
    let mean_gray = if d.contrast != 1.0 {
        let sum: f32 = pixels
            .chunks_exact(3)
            .map(|p| gray(f32::from(p[0]), f32::from(p[1]), f32::from(p[2])))
            .sum();
        d.brightness * sum / (255.0 * plane as f32)
    } else {
        0.0
    };
    let (sin_h, cos_h) = (d.hue * std::f32::consts::TAU).sin_cos();
    let order = match contract.channel_order {
        ChannelOrder::Rgb => [0, 1, 2],
        ChannelOrder::Bgr => [2, 1, 0],
    };
    for y in 0..s {
        for x in 0..s {
            let src_x = if d.flip { s - 1 - x } else { x };
            let p = &pixels[(y * s + src_x) * 3..][..3];
            let mut rgb = [
                f32::from(p[0]) / 255.0,
                f32::from(p[1]) / 255.0,
                f32::from(p[2]) / 255.0,
            ];
            if jitter {
                rgb = jitter_pixel(rgb, d, mean_gray, sin_h, cos_h);
            }
            for (t, &c) in order.iter().enumerate() {
                out[t * plane + y * s + x] = (rgb[c] - contract.mean[t]) / contract.std[t];
            }
        }
    }
}

fn jitter_pixel(rgb: [f32; 3], d: &Draw, mean_gray: f32, sin_h: f32, cos_h: f32) -> [f32; 3] {
    let [mut r, mut g, mut b] = rgb.map(|v| (v * d.brightness).clamp(0.0, 1.0));
    if d.contrast != 1.0 {
        [r, g, b] = [r, g, b].map(|v| (mean_gray + (v - mean_gray) * d.contrast).clamp(0.0, 1.0));
    }
    if d.saturation != 1.0 {
        let l = gray(r, g, b);
        [r, g, b] = [r, g, b].map(|v| (l + (v - l) * d.saturation).clamp(0.0, 1.0));
    }
    if d.hue != 0.0 {
        // RGB -> YIQ, rotate (I, Q), back.
        let yy = 0.299 * r + 0.587 * g + 0.114 * b;
        let i = 0.596 * r - 0.274 * g - 0.322 * b;
        let q = 0.211 * r - 0.523 * g + 0.312 * b;
        let (i, q) = (i * cos_h - q * sin_h, i * sin_h + q * cos_h);
        r = yy + 0.956 * i + 0.621 * q;
        g = yy - 0.272 * i - 0.647 * q;
        b = yy - 1.106 * i + 1.703 * q;
    }
    [r, g, b].map(|v| v.clamp(0.0, 1.0))
}

/// A batch: inputs `[n, 3, size, size]` and labels `[n, 2]`, flattened.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Batch {
    pub inputs: Vec<f32>,
    pub labels: Vec<f32>,
    pub len: usize,
}

/// Builds the batch of `samples[idx]`, drawing augmentation from `rng` in index order (so
/// the same seed gives the same batch). `mirrored`: the label component a flip negates.
pub fn make_batch(
    samples: &[Sample],
    idx: &[usize],
    size: u32,
    contract: &ModelContract,
    augment: &Augment,
    mirrored: usize,
    rng: &mut impl Rng,
) -> Batch {
    let per = 3 * (size as usize) * (size as usize);
    let mut batch = Batch {
        inputs: vec![0.0; per * idx.len()],
        labels: Vec::with_capacity(2 * idx.len()),
        len: idx.len(),
    };
    for (k, &i) in idx.iter().enumerate() {
        let sample = &samples[i];
        let d = Draw::sample(augment, rng);
        write_input(
            &sample.pixels,
            size,
            contract,
            &d,
            &mut batch.inputs[k * per..(k + 1) * per],
        );
        let mut label = sample.label;
        if d.flip {
            label[mirrored] = -label[mirrored];
        }
        batch.labels.extend_from_slice(&label);
    }
    batch
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::{OutputKind, Preprocessor};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn contract(order: ChannelOrder) -> ModelContract {
        ModelContract {
            input_size: 2,
            channel_order: order,
            output: OutputKind::SpeedSteering,
            ..ModelContract::default()
        }
    }

    /// (255,0,128) (0,0,0) / (255,255,255) (10,20,30)
    const FRAME: [u8; 12] = [255, 0, 128, 0, 0, 0, 255, 255, 255, 10, 20, 30];

    #[test]
    fn without_augmentation_it_equals_the_daemons_preprocessing() {
        for order in [ChannelOrder::Rgb, ChannelOrder::Bgr] {
            let c = contract(order);
            let mut out = vec![0.0; 12];
            write_input(&FRAME, 2, &c, &Draw::IDENTITY, &mut out);
            let want = Preprocessor::new(&c).run(2, 2, &FRAME).unwrap().to_vec();
            for (a, b) in out.iter().zip(&want) {
                assert!((a - b).abs() < 1e-5, "{out:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn flip_mirrors_rows_and_negates_the_label() {
        let c = contract(ChannelOrder::Rgb);
        let samples = vec![Sample {
            pixels: FRAME.to_vec(),
            label: [0.7, 0.25],
        }];
        let always = Augment {
            flip: true,
            ..Augment::NONE
        };
        // Draw until a flip comes up (p = 0.5 each); the seed makes it deterministic.
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let b = loop {
            let b = make_batch(&samples, &[0], 2, &c, &always, 1, &mut rng);
            if b.labels[1] < 0.0 {
                break b;
            }
        };
        assert_eq!(b.labels, vec![0.7, -0.25]);
        // R plane, row 0: pixel 1 (0) then pixel 0 (255): (0 - .485)/.229, (1 - .485)/.229.
        assert!(
            (b.inputs[0] + 2.117_904).abs() < 1e-5,
            "{:?}",
            &b.inputs[..4]
        );
        assert!((b.inputs[1] - 2.248_908).abs() < 1e-5);
        // Row 1: (10,20,30) then (255,255,255).
        assert!((b.inputs[2] - (10.0 / 255.0 - 0.485) / 0.229).abs() < 1e-5);
    }

    #[test]
    fn jitter_worked_values() {
        // Brightness 0.5 on a mid-grey (128) pixel: 0.2510; contrast and saturation leave a
        // uniform grey image as it is; a hue turn leaves grey as grey.
        let grey = [128u8; 12];
        let c = ModelContract {
            mean: [0.0; 3],
            std: [1.0; 3],
            ..contract(ChannelOrder::Rgb)
        };
        let d = Draw {
            flip: false,
            brightness: 0.5,
            contrast: 1.7,
            saturation: 0.2,
            hue: 0.25,
        };
        let mut out = vec![0.0; 12];
        write_input(&grey, 2, &c, &d, &mut out);
        for v in &out {
            assert!((v - 128.0 / 255.0 * 0.5).abs() < 1e-3, "{out:?}");
        }
        // Saturation 0 turns red into its grey 0.299.
        let red = [255u8, 0, 0].repeat(4);
        let d = Draw {
            saturation: 0.0,
            ..Draw::IDENTITY
        };
        write_input(&red, 2, &c, &d, &mut out);
        assert!(out.iter().all(|v| (v - 0.299).abs() < 1e-5), "{out:?}");
        // Contrast 0 on a half-black, half-white image: every value becomes the mean grey 0.5.
        let bw = [0u8, 0, 0, 255, 255, 255, 0, 0, 0, 255, 255, 255];
        let d = Draw {
            contrast: 0.0,
            ..Draw::IDENTITY
        };
        write_input(&bw, 2, &c, &d, &mut out);
        assert!(out.iter().all(|v| (v - 0.5).abs() < 1e-5), "{out:?}");
    }

    #[test]
    fn batches_are_seeded() {
        let c = contract(ChannelOrder::Rgb);
        let samples: Vec<Sample> = (0..4)
            .map(|i| Sample {
                pixels: FRAME.iter().map(|v| v.wrapping_add(i * 40)).collect(),
                label: [i as f32, 0.5],
            })
            .collect();
        let run = |seed| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            make_batch(&samples, &[3, 1, 2], 2, &c, &Augment::JETBOT, 1, &mut rng)
        };
        assert_eq!(run(5), run(5));
        assert_ne!(run(5).inputs, run(6).inputs);
        assert_eq!(run(5).len, 3);
        assert_eq!(run(5).labels[0], 3.0);
    }
}
