//! JetBot's augmentation and the input tensor: owns turning cached RGB8 frames into the
//! normalised NCHW batch a training step takes, with a random horizontal flip (the label's
//! mirrored component negated), colour jitter and, for JetBot's xy head, a random shift.
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
//! The shift moves the picture by whole pixels (the uncovered edge repeats the border
//! pixels) and the xy label with it, so the target stays on the same spot of the road:
//!
//! ```text
//! out(x, y) = in(clamp(x - dx), clamp(y - dy))      label += (2 dx / size, 2 dy / size)
//! dx ~ U(-shift, shift) * size, narrowed so the label stays on the frame
//! ```
//!
//! It teaches the network that the target moves with the road, and spreads the labels over
//! the frame as people's clicks are spread; it has no meaning for a (speed, steering) head.
//!
//! A random convolution (RandConv, Xu et al. 2021), drawn for a share of the images, runs
//! last, on the normalised tensor: a 3 -> 3 channel filter of a random size, blended with
//! the picture, so colours and textures change and shapes (the road's edges) stay:
//!
//! ```text
//! out[o](x, y) = a in[o](x, y) + (1 - a) sum_{i, u, v} w[o][i][u][v] in[i](clamp(x + u), clamp(y + v))
//! k ~ {1, 3, 5, 7}, w ~ U(-1/k, 1/k) (variance 1 / (3 k^2): He's for 3 k^2 inputs), a ~ U(0, 1)
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
    /// Largest shift of the picture (and an xy label with it), as a fraction of its side.
    pub shift: f32,
    /// Share of the images (0..=1) that get a random convolution.
    pub rand_conv: f32,
}

impl Augment {
    pub const NONE: Augment = Augment {
        flip: false,
        brightness: 0.0,
        contrast: 0.0,
        saturation: 0.0,
        hue: 0.0,
        shift: 0.0,
        rand_conv: 0.0,
    };
    pub const JETBOT: Augment = Augment {
        flip: true,
        brightness: 0.3,
        contrast: 0.3,
        saturation: 0.3,
        hue: 0.3,
        shift: 0.0,
        rand_conv: 0.0,
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
    /// The picture's shift in pixels (x right, y down).
    pub shift: [i32; 2],
}

impl Draw {
    pub const IDENTITY: Draw = Draw {
        flip: false,
        brightness: 1.0,
        contrast: 1.0,
        saturation: 1.0,
        hue: 0.0,
        shift: [0, 0],
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
            shift: [0, 0],
        }
    }
}

/// A shift in whole pixels from a draw `u` in -1..1: `u * shift * size`, narrowed so that
/// `label + 2 d / size` stays on the frame's pixels, -1 ..= 1 - 2 / size (pixel 0 is -1,
/// pixel size - 1 is 1 - 2 / size). No shift where that leaves nothing to draw from.
pub fn shift_pixels(u: f32, shift: f32, label: f32, size: u32) -> i32 {
    let s = size as f32;
    let most = (shift * s).floor();
    let lo = (-most).max(((-1.0 - label) * s / 2.0).ceil());
    let hi = most.min(((1.0 - label) * s / 2.0 - 1.0).floor());
    if lo > hi {
        return 0;
    }
    let mid = (lo + hi) / 2.0;
    (mid + u * (hi - lo) / 2.0).round().clamp(lo, hi) as i32
}

/// Kernel sizes a random convolution draws from.
pub const RAND_CONV_SIZES: [usize; 4] = [1, 3, 5, 7];

/// One image's random convolution: `weights[((o * 3 + i) * k + v) * k + u]` for output
/// channel `o`, input channel `i`, kernel row `v`, column `u` (offsets `-k/2..=k/2`).
#[derive(Debug, Clone, PartialEq)]
pub struct RandConv {
    pub k: usize,
    pub weights: Vec<f32>,
    /// The original picture's weight in the blend.
    pub alpha: f32,
}

impl RandConv {
    /// Draws a kernel size, its weights and the blend.
    pub fn sample(rng: &mut impl Rng) -> Self {
        let k = RAND_CONV_SIZES[rng.random_range(0..RAND_CONV_SIZES.len())];
        let bound = 1.0 / k as f32;
        let weights = (0..9 * k * k)
            .map(|_| rng.random_range(-bound..=bound))
            .collect();
        Self {
            k,
            weights,
            alpha: rng.random_range(0.0..=1.0),
        }
    }

    /// Applies the filter to one image's NCHW planes (`3 * size * size` values) in place;
    /// pixels beyond the border repeat the border's.
    pub fn apply(&self, size: u32, planes: &mut [f32]) {
        let s = size as usize;
        let plane = s * s;
        let k = self.k;
        let half = (k / 2) as i32;
        let last = s as i32 - 1;
        let input = planes.to_vec();
        for o in 0..3 {
            for y in 0..s {
                for x in 0..s {
                    let mut acc = 0.0;
                    for i in 0..3 {
                        let w = &self.weights[(o * 3 + i) * k * k..][..k * k];
                        let src = &input[i * plane..][..plane];
                        for v in 0..k {
                            let sy = (y as i32 + v as i32 - half).clamp(0, last) as usize;
                            let row = &src[sy * s..][..s];
                            for u in 0..k {
                                let sx = (x as i32 + u as i32 - half).clamp(0, last) as usize;
                                acc += w[v * k + u] * row[sx];
                            }
                        }
                    }
                    let at = o * plane + y * s + x;
                    planes[at] = self.alpha * input[at] + (1.0 - self.alpha) * acc;
                }
            }
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
    let last = s as i32 - 1;
    let [dx, dy] = d.shift;
    for y in 0..s {
        let src_y = (y as i32 - dy).clamp(0, last) as usize;
        for x in 0..s {
            let shifted_x = (x as i32 - dx).clamp(0, last) as usize;
            let src_x = if d.flip { s - 1 - shifted_x } else { shifted_x };
            let p = &pixels[(src_y * s + src_x) * 3..][..3];
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
/// A shift (`augment.shift > 0`) moves the label as JetBot's xy target: the caller keeps
/// it to xy heads.
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
        let mut d = Draw::sample(augment, rng);
        let mut label = sample.label;
        if d.flip {
            label[mirrored] = -label[mirrored];
        }
        if augment.shift > 0.0 {
            for (c, v) in label.iter_mut().enumerate() {
                let u: f32 = rng.random_range(-1.0..=1.0);
                d.shift[c] = shift_pixels(u, augment.shift, *v, size);
                *v += 2.0 * d.shift[c] as f32 / size as f32;
            }
        }
        let planes = &mut batch.inputs[k * per..(k + 1) * per];
        write_input(&sample.pixels, size, contract, &d, planes);
        // Drawn only when on, so runs without it keep their seeded draws.
        if augment.rand_conv > 0.0 && rng.random_bool(f64::from(augment.rand_conv.min(1.0))) {
            RandConv::sample(rng).apply(size, planes);
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
    fn shift_pixels_worked_values() {
        // 96 px, at most a quarter (24 px); a centred label may go either way in full.
        assert_eq!(shift_pixels(1.0, 0.25, 0.0, 96), 24);
        assert_eq!(shift_pixels(-1.0, 0.25, 0.0, 96), -24);
        assert_eq!(shift_pixels(0.0, 0.25, 0.0, 96), 0);
        // A label at 0.8 (pixel 86.4) may move right to pixel 95 (1 - 2 / 96): 9.6 - 1 ->
        // 8 px, so the range is -24..=8.
        assert_eq!(shift_pixels(1.0, 0.25, 0.8, 96), 8);
        assert_eq!(shift_pixels(-1.0, 0.25, 0.8, 96), -24);
        assert_eq!(shift_pixels(0.0, 0.25, 0.8, 96), -8);
        // A label just outside is brought in; one too far out for the largest shift stays.
        assert_eq!(shift_pixels(1.0, 0.25, 1.25, 96), -13); // -24..=floor(-12 - 1)
        assert_eq!(shift_pixels(1.0, 0.25, 3.0, 96), 0);
        assert_eq!(shift_pixels(1.0, 0.0, 0.0, 96), 0);
    }

    #[test]
    fn shift_moves_the_label_with_the_picture() {
        // An 8x8 black frame with one white pixel at (5, 2), the xy label on it:
        // ((5 - 4) / 4, (2 - 4) / 4) = (0.25, -0.5).
        let size = 8usize;
        let mut pixels = vec![0u8; size * size * 3];
        pixels[(2 * size + 5) * 3..][..3].copy_from_slice(&[255, 255, 255]);
        let samples = vec![Sample {
            pixels,
            label: [0.25, -0.5],
        }];
        let c = ModelContract {
            mean: [0.0; 3],
            std: [1.0; 3],
            ..contract(ChannelOrder::Rgb)
        };
        let shift = Augment {
            shift: 0.4,
            ..Augment::NONE
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut moved = 0;
        for _ in 0..40 {
            let b = make_batch(&samples, &[0], size as u32, &c, &shift, 0, &mut rng);
            let [lx, ly] = [b.labels[0], b.labels[1]];
            assert!(
                (-1.0..=0.75).contains(&lx) && (-1.0..=0.75).contains(&ly),
                "{lx} {ly}"
            );
            // The label's pixel is white in the R plane, and nothing else is.
            let px = (lx * 4.0 + 4.0).round() as usize;
            let py = (ly * 4.0 + 4.0).round() as usize;
            assert!(
                (lx * 4.0 + 4.0 - px as f32).abs() < 1e-5,
                "whole pixels: {lx}"
            );
            let white: Vec<usize> = (0..size * size).filter(|&i| b.inputs[i] > 0.5).collect();
            assert_eq!(white, vec![py * size + px], "label ({lx}, {ly})");
            moved += usize::from(px != 5 || py != 2);
        }
        assert!(moved > 30, "the shift was drawn: {moved} of 40 moved");
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
            shift: [0, 0],
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
    fn rand_conv_worked_values() {
        // One channel's 3x3 picture 1..=9 (the others zero); the filter takes channel 0's
        // 3x3 box mean into output channel 0 and nothing else, blended half and half.
        let mut planes = vec![0.0; 27];
        for (i, v) in planes[..9].iter_mut().enumerate() {
            *v = (i + 1) as f32;
        }
        let mut weights = vec![0.0; 81];
        weights[..9].fill(1.0 / 9.0);
        let conv = RandConv {
            k: 3,
            weights,
            alpha: 0.5,
        };
        conv.apply(3, &mut planes);
        // Centre: box mean 5, blend (5 + 5) / 2 = 5. Corner (0, 0): the border repeats, so
        // its 3x3 is 1 1 2 / 1 1 2 / 4 4 5 = 21 / 9 = 2.333; (1 + 2.333) / 2 = 1.667.
        assert!((planes[4] - 5.0).abs() < 1e-5, "{:?}", &planes[..9]);
        assert!((planes[0] - (1.0 + 21.0 / 9.0) / 2.0).abs() < 1e-5);
        // Corner (2, 2): 5 6 6 / 8 9 9 / 8 9 9 = 69 / 9; (9 + 7.667) / 2.
        assert!((planes[8] - (9.0 + 69.0 / 9.0) / 2.0).abs() < 1e-5);
        // Channels 1 and 2 were zero and take nothing: still zero.
        assert!(planes[9..].iter().all(|v| *v == 0.0), "{:?}", &planes[9..]);

        // A 1x1 filter swapping channels 0 and 1, the picture's weight 0: a channel swap.
        let mut planes: Vec<f32> = (0..12).map(|v| v as f32).collect();
        let mut weights = vec![0.0; 9];
        weights[1] = 1.0; // out 0 <- in 1
        weights[3] = 1.0; // out 1 <- in 0
        weights[8] = 1.0; // out 2 <- in 2
        let swap = RandConv {
            k: 1,
            weights,
            alpha: 0.0,
        };
        swap.apply(2, &mut planes);
        assert_eq!(
            planes,
            vec![4.0, 5.0, 6.0, 7.0, 0.0, 1.0, 2.0, 3.0, 8.0, 9.0, 10.0, 11.0]
        );
    }

    #[test]
    fn rand_conv_draws_are_seeded_and_bounded() {
        let draw = |seed| RandConv::sample(&mut ChaCha8Rng::seed_from_u64(seed));
        assert_eq!(draw(7), draw(7));
        assert_ne!(draw(7), draw(8));
        let mut sizes = std::collections::BTreeSet::new();
        for seed in 0..64 {
            let c = draw(seed);
            assert!(RAND_CONV_SIZES.contains(&c.k));
            assert_eq!(c.weights.len(), 9 * c.k * c.k);
            let bound = 1.0 / c.k as f32;
            assert!(c.weights.iter().all(|w| w.abs() <= bound), "k {}", c.k);
            assert!((0.0..=1.0).contains(&c.alpha));
            sizes.insert(c.k);
        }
        assert_eq!(sizes.len(), RAND_CONV_SIZES.len(), "{sizes:?}");
    }

    #[test]
    fn rand_conv_changes_pictures_not_labels_for_its_share() {
        let c = contract(ChannelOrder::Rgb);
        let samples: Vec<Sample> = (0..4)
            .map(|i| Sample {
                pixels: FRAME.iter().map(|v| v.wrapping_add(i * 40)).collect(),
                label: [i as f32 / 4.0, 0.5],
            })
            .collect();
        let run = |a: &Augment| {
            let mut rng = ChaCha8Rng::seed_from_u64(11);
            make_batch(&samples, &[0, 1, 2, 3], 2, &c, a, 1, &mut rng)
        };
        let plain = run(&Augment::NONE);
        let always = run(&Augment {
            rand_conv: 1.0,
            ..Augment::NONE
        });
        assert_eq!(always.labels, plain.labels);
        let per = 12;
        for k in 0..4 {
            assert_ne!(
                always.inputs[k * per..][..per],
                plain.inputs[k * per..][..per],
                "image {k}"
            );
        }
        // A share of 0.5: about half of 200 images change (binomial sd 7).
        let idx: Vec<usize> = (0..200).map(|i| i % 4).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let half = Augment {
            rand_conv: 0.5,
            ..Augment::NONE
        };
        let b = make_batch(&samples, &idx, 2, &c, &half, 1, &mut rng);
        let changed = idx
            .iter()
            .enumerate()
            .filter(|&(n, &i)| b.inputs[n * per..][..per] != plain.inputs[i * per..][..per])
            .count();
        assert!((70..=130).contains(&changed), "{changed} of 200 changed");
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
