//! Occlusion maps (`score --explain N`): what a policy looks at on a frame.
//!
//! A grey square (`patch` input pixels, moved `stride` at a time over the whole input)
//! replaces part of the preprocessed frame, the policy runs again, and the distance between
//! its answer and the answer on the whole frame is that position's *shift*. A part of the
//! frame the policy ignores shifts nothing; the road it steers by shifts a lot. Each input
//! pixel's heat is the mean shift of the patches that cover it.
//!
//! The grey is the tensor value of a mid-grey pixel (0.5 before the contract's
//! normalisation), so a patch looks like a grey card laid on the picture, the same for RGB
//! and BGR models. Shifts are in the score's units: pixels of JetBot's 224x224 frame for
//! `xy` heads, the distance in (speed, steering) for `speed_steering` heads.
//!
//! Pure: the policy is any `FnMut(&[f32]) -> Result<[f32; 2], E>`; `cli/score.rs` passes
//! the ONNX Runtime session. [`draw`] makes the picture.

use image::imageops::FilterType;
use image::{Rgb, RgbImage};

use super::sheet::{self, Tile};
use super::{JETBOT_FRAME_PX, pixel_error};
use crate::policy::{ModelContract, OutputKind};

/// Where the patches go, for an `input`-pixel square input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Patches {
    pub input: usize,
    pub patch: usize,
    pub stride: usize,
}

impl Patches {
    /// `patch` pixels (clamped to 1..=input), moved half a patch at a time.
    pub fn new(input: usize, patch: usize) -> Self {
        let patch = patch.clamp(1, input.max(1));
        Self {
            input,
            patch,
            stride: (patch / 2).max(1),
        }
    }

    /// The default: a seventh of the input (32 px at 224, 14 at 96), so the map is 13x13.
    pub fn default_for(input: usize) -> Self {
        Self::new(input, (input as f32 / 7.0).round() as usize)
    }

    /// The patches' first rows (and columns): every `stride` from 0, and the last one flush
    /// with the far edge so every pixel is covered.
    pub fn starts(&self) -> Vec<usize> {
        let last = self.input - self.patch;
        let mut s: Vec<usize> = (0..=last).step_by(self.stride).collect();
        if s.last() != Some(&last) {
            s.push(last);
        }
        s
    }
}

/// One frame's occlusion map.
#[derive(Debug, Clone, PartialEq)]
pub struct OcclusionMap {
    pub patches: Patches,
    /// The policy's answer on the whole frame.
    pub base: [f32; 2],
    /// Shift per patch, row-major over `starts() x starts()`.
    pub shifts: Vec<f32>,
}

/// The tensor value of a mid-grey pixel in each plane of `contract`'s input.
pub fn grey(contract: &ModelContract) -> [f32; 3] {
    std::array::from_fn(|c| (0.5 - contract.mean[c]) / contract.std[c])
}

/// How far apart two answers are, in the score's units (see the module doc).
pub fn shift(output: OutputKind, a: [f32; 2], b: [f32; 2]) -> f32 {
    match output {
        OutputKind::Xy => pixel_error(a, b, JETBOT_FRAME_PX) as f32,
        OutputKind::SpeedSteering => (a[0] - b[0]).hypot(a[1] - b[1]),
    }
}

/// The map of `input` (`[1,3,S,S]` planes, S = `patches.input`) under `infer`.
pub fn occlusion<E>(
    input: &[f32],
    patches: Patches,
    fill: [f32; 3],
    output: OutputKind,
    mut infer: impl FnMut(&[f32]) -> Result<[f32; 2], E>,
) -> Result<OcclusionMap, E> {
    let s = patches.input;
    debug_assert_eq!(input.len(), 3 * s * s);
    let base = infer(input)?;
    let starts = patches.starts();
    let mut work = input.to_vec();
    let mut shifts = Vec::with_capacity(starts.len() * starts.len());
    for &y0 in &starts {
        for &x0 in &starts {
            for (c, v) in fill.iter().enumerate() {
                for y in y0..y0 + patches.patch {
                    let row = c * s * s + y * s;
                    work[row + x0..row + x0 + patches.patch].fill(*v);
                }
            }
            shifts.push(shift(output, base, infer(&work)?));
            for c in 0..3 {
                for y in y0..y0 + patches.patch {
                    let row = c * s * s + y * s;
                    work[row + x0..row + x0 + patches.patch]
                        .copy_from_slice(&input[row + x0..row + x0 + patches.patch]);
                }
            }
        }
    }
    Ok(OcclusionMap {
        patches,
        base,
        shifts,
    })
}

impl OcclusionMap {
    /// The largest shift.
    pub fn max_shift(&self) -> f32 {
        self.shifts.iter().copied().fold(0.0, f32::max)
    }

    /// Per input pixel (row-major, `S*S`): the mean shift of the patches covering it.
    pub fn heat(&self) -> Vec<f32> {
        let p = self.patches;
        let s = p.input;
        let starts = p.starts();
        let mut sum = vec![0.0f32; s * s];
        let mut count = vec![0u32; s * s];
        for (i, &y0) in starts.iter().enumerate() {
            for (j, &x0) in starts.iter().enumerate() {
                let v = self.shifts[i * starts.len() + j];
                for y in y0..y0 + p.patch {
                    for x in x0..x0 + p.patch {
                        sum[y * s + x] += v;
                        count[y * s + x] += 1;
                    }
                }
            }
        }
        sum.iter()
            .zip(&count)
            .map(|(v, n)| if *n > 0 { v / *n as f32 } else { 0.0 })
            .collect()
    }

    /// The heat's centre of mass as fractions of the width and height (0, 0: top left);
    /// `None` when nothing shifts.
    pub fn centroid(&self) -> Option<[f32; 2]> {
        let s = self.patches.input;
        let heat = self.heat();
        let total: f32 = heat.iter().sum();
        if total <= 0.0 {
            return None;
        }
        let (mut cx, mut cy) = (0.0f32, 0.0f32);
        for (k, v) in heat.iter().enumerate() {
            cx += v * ((k % s) as f32 + 0.5);
            cy += v * ((k / s) as f32 + 0.5);
        }
        Some([cx / total / s as f32, cy / total / s as f32])
    }

    /// The share of the heat in the top third of the input: beyond the floor, in a JetBot's
    /// view (walls, furniture, people).
    pub fn top_third_share(&self) -> f32 {
        let s = self.patches.input;
        let heat = self.heat();
        let total: f32 = heat.iter().sum();
        if total <= 0.0 {
            return 0.0;
        }
        heat[..s * s.div_ceil(3)].iter().sum::<f32>() / total
    }
}

/// Heat 0..1 -> black, red, yellow, white.
fn colour(h: f32) -> [f32; 3] {
    let h = h.clamp(0.0, 1.0) * 3.0;
    [
        h.min(1.0),
        (h - 1.0).clamp(0.0, 1.0),
        (h - 2.0).clamp(0.0, 1.0),
    ]
    .map(|v| v * 255.0)
}

/// The picture: one row per frame, worst first: the frame with its label (green) and
/// prediction (red), the frame under its heat, and the heat alone. Each row's heat is
/// scaled to its own largest shift (printed and in the CSV), so a row shows where, not how
/// much.
pub fn draw(output: OutputKind, rows: &[(Tile<'_>, &OcclusionMap)], tile_px: u32) -> RgbImage {
    const GAP: u32 = 2;
    let step = tile_px + GAP;
    let mut out = RgbImage::from_pixel(
        3 * step + GAP,
        (rows.len() as u32).max(1) * step + GAP,
        Rgb([24, 24, 24]),
    );
    for (r, (tile, map)) in rows.iter().enumerate() {
        let Some(marked) = sheet::marked(output, tile, tile_px) else {
            continue;
        };
        let s = map.patches.input as u32;
        let max = map.max_shift().max(1e-12);
        let heat: Vec<u8> = map
            .heat()
            .iter()
            .map(|v| (v / max * 255.0).round() as u8)
            .collect();
        let Some(small) = image::GrayImage::from_raw(s, s, heat) else {
            continue;
        };
        let heat = image::imageops::resize(&small, tile_px, tile_px, FilterType::Triangle);
        let plain = RgbImage::from_raw(tile.width, tile.height, tile.rgb.to_vec())
            .map(|f| image::imageops::resize(&f, tile_px, tile_px, FilterType::Triangle))
            .unwrap_or_else(|| RgbImage::new(tile_px, tile_px));
        let mut over = RgbImage::new(tile_px, tile_px);
        let mut alone = RgbImage::new(tile_px, tile_px);
        for (x, y, p) in heat.enumerate_pixels() {
            let h = p.0[0] as f32 / 255.0;
            let c = colour(h);
            let f = plain.get_pixel(x, y).0;
            let a = 0.75 * h;
            over.put_pixel(
                x,
                y,
                Rgb(std::array::from_fn(|k| {
                    (f[k] as f32 * (1.0 - a) * 0.6 + c[k] * a).round() as u8
                })),
            );
            alone.put_pixel(x, y, Rgb(c.map(|v| v.round() as u8)));
        }
        let y = (GAP + r as u32 * step) as i64;
        for (col, img) in [&marked, &over, &alone].into_iter().enumerate() {
            image::imageops::replace(&mut out, img, (GAP + col as u32 * step) as i64, y);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::convert::Infallible;

    /// A policy blind to the right half: x = mean of plane 0's left half (columns 0..S/2).
    fn left_eyed(s: usize) -> impl FnMut(&[f32]) -> Result<[f32; 2], Infallible> {
        move |input: &[f32]| {
            let mut sum = 0.0;
            for y in 0..s {
                for x in 0..s / 2 {
                    sum += input[y * s + x];
                }
            }
            Ok([sum / (s * s / 2) as f32, 0.0])
        }
    }

    #[test]
    fn patches_cover_the_input_to_its_far_edge() {
        assert_eq!(Patches::default_for(224).patch, 32);
        assert_eq!(Patches::default_for(224).starts().len(), 13);
        assert_eq!(Patches::default_for(96).patch, 14);
        // 96 - 14 = 82 is not a multiple of 7: the last start is added flush with the edge.
        let s = Patches::default_for(96).starts();
        assert_eq!((s[0], s[1], *s.last().unwrap()), (0, 7, 82));
        assert_eq!(Patches::new(8, 20).starts(), vec![0]);
    }

    #[test]
    fn a_policy_blind_to_the_right_half_shifts_only_under_left_patches() {
        // S = 8, patches of 2 every 1: all ones, greyed to 0. A patch wholly in the left
        // half removes 2*2 of plane 0's 32 left pixels: x drops by 4/32 = 0.125, i.e.
        // 0.125 * 112 = 14 px. One straddling columns 3-4 removes 2: 7 px. Right: 0.
        let s = 8;
        let input = vec![1.0f32; 3 * s * s];
        let map = occlusion(
            &input,
            Patches::new(s, 2),
            [0.0; 3],
            OutputKind::Xy,
            left_eyed(s),
        )
        .unwrap();
        assert_eq!(map.base, [1.0, 0.0]);
        let starts = map.patches.starts();
        assert_eq!(starts.len(), 7);
        for (i, _) in starts.iter().enumerate() {
            let row = &map.shifts[i * 7..(i + 1) * 7];
            for (j, x0) in starts.iter().enumerate() {
                let want = match x0 {
                    0..=2 => 14.0,
                    3 => 7.0,
                    _ => 0.0,
                };
                assert!((row[j] - want).abs() < 1e-4, "patch at x {x0}: {}", row[j]);
            }
        }
        assert!((map.max_shift() - 14.0).abs() < 1e-4);
        let heat = map.heat();
        assert!(heat[..s / 2].iter().all(|v| *v > 0.0));
        assert_eq!(&heat[5..8], &[0.0, 0.0, 0.0]);
        // Column 4 is covered by patches at x 3 (7 px) and 4 (0 px): 3.5 px.
        assert!((heat[4] - 3.5).abs() < 1e-4);
        let c = map.centroid().unwrap();
        assert!(c[0] < 0.35 && (c[1] - 0.5).abs() < 1e-4, "{c:?}");
        assert!((map.top_third_share() - 3.0 / 8.0).abs() < 1e-4);
    }

    #[test]
    fn a_policy_that_ignores_its_input_has_no_map_centre() {
        let map = occlusion(
            &[0.3f32; 3 * 16],
            Patches::new(4, 2),
            [0.0; 3],
            OutputKind::SpeedSteering,
            |_| Ok::<_, Infallible>([0.2, -0.1]),
        )
        .unwrap();
        assert_eq!(map.max_shift(), 0.0);
        assert_eq!(map.centroid(), None);
    }

    #[test]
    fn grey_is_mid_grey_through_the_contract() {
        let c = ModelContract::default(); // ImageNet mean and std
        let g = grey(&c);
        assert!((g[0] - (0.5 - 0.485) / 0.229).abs() < 1e-6);
        assert!((g[2] - (0.5 - 0.406) / 0.225).abs() < 1e-6);
        assert!((shift(OutputKind::SpeedSteering, [0.0, 0.0], [0.3, 0.4]) - 0.5).abs() < 1e-6);
    }

    #[test]
    fn the_picture_has_three_tiles_per_row_and_heat_where_the_policy_looks() {
        let s = 8;
        let map = occlusion(
            &vec![1.0f32; 3 * s * s],
            Patches::new(s, 2),
            [0.0; 3],
            OutputKind::Xy,
            left_eyed(s),
        )
        .unwrap();
        let rgb = vec![100u8; 8 * 8 * 3];
        let tile = Tile {
            rgb: &rgb,
            width: 8,
            height: 8,
            label: [0.0, 0.0],
            prediction: [0.0, 0.0],
        };
        let img = draw(OutputKind::Xy, &[(tile, &map)], 64);
        assert_eq!(img.dimensions(), (3 * 66 + 2, 66 + 2));
        // The heat-alone tile: bright on the left, black on the right.
        let left = img.get_pixel(2 + 2 * 66 + 8, 2 + 32).0;
        let right = img.get_pixel(2 + 2 * 66 + 60, 2 + 32).0;
        assert!(left[0] > 200, "{left:?}");
        assert_eq!(right, [0, 0, 0]);
    }
}
