//! The chassis mask: pixels that show the vehicle itself (a DonkeyCar's bumper and
//! camera mount at the bottom of every frame), which move with the camera and so read as
//! "no motion" to registration. They are found from the recording: over its frames such a
//! pixel hardly changes, while the floor sweeps past every other pixel below the horizon.
//! Pure.
//!
//! On `donkey_tub_tarp` (every third frame) the grey level's standard deviation over the
//! drive is 2.5-12 on the chassis and 20-33 on the tarp below the horizon: a threshold of
//! 12 separates them.

use serde::{Deserialize, Serialize};

/// How the mask is made (`[sim.chassis]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ChassisConfig {
    /// Find it from the recording ([`from_variance`]). Unset: for a car (a DonkeyCar's
    /// camera sees its bumper), not for a differential drive (JetBot's does not see itself,
    /// and on a short, slow drive over a plain mat most of its floor hardly changes).
    pub find: Option<bool>,
    /// With `find`: a pixel whose grey level varies less than this over the frames
    /// (standard deviation, 0..255) and that joins the bottom edge through such pixels is
    /// the chassis.
    pub max_std: f32,
    /// A found mask larger than this share of the frame is not a chassis (a drive too
    /// short or too plain for the variance to tell): it is dropped, with a warning.
    pub max_fraction: f32,
    /// Mask every row from this one down as well (0..height; unset: none).
    pub below_row: Option<u32>,
}

impl Default for ChassisConfig {
    fn default() -> Self {
        Self {
            find: None,
            max_std: 12.0,
            max_fraction: 0.25,
            below_row: None,
        }
    }
}

/// Which pixels registration must not use.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelMask {
    pub width: u32,
    pub height: u32,
    /// Row-major, `true`: masked.
    pub masked: Vec<bool>,
}

impl PixelMask {
    /// Nothing masked.
    pub fn none(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            masked: vec![false; width as usize * height as usize],
        }
    }

    /// Rows `row..height` masked.
    pub fn below_row(width: u32, height: u32, row: u32) -> Self {
        let mut m = Self::none(width, height);
        let start = (row.min(height) as usize) * width as usize;
        m.masked[start..].iter_mut().for_each(|v| *v = true);
        m
    }

    /// Whether pixel `(x, y)` is masked (outside the frame: yes).
    pub fn at(&self, x: usize, y: usize) -> bool {
        if x >= self.width as usize || y >= self.height as usize {
            return true;
        }
        self.masked[y * self.width as usize + x]
    }

    /// How many pixels are masked.
    pub fn count(&self) -> usize {
        self.masked.iter().filter(|m| **m).count()
    }

    /// The masked share of the frame, 0..1.
    pub fn fraction(&self) -> f32 {
        self.count() as f32 / self.masked.len().max(1) as f32
    }

    /// The union of two masks of the same size (`self` if the sizes differ).
    pub fn or(mut self, other: &PixelMask) -> Self {
        if (self.width, self.height) == (other.width, other.height) {
            for (a, b) in self.masked.iter_mut().zip(&other.masked) {
                *a |= *b;
            }
        }
        self
    }
}

/// Per-pixel grey statistics over a recording's frames, added one at a time.
#[derive(Debug, Clone)]
pub struct Variance {
    width: u32,
    height: u32,
    frames: usize,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
}

impl Variance {
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            frames: 0,
            sum: vec![0.0; n],
            sum_sq: vec![0.0; n],
        }
    }

    /// Adds an RGB8 frame (grey = the mean of R, G and B); one of another size is ignored.
    pub fn add(&mut self, rgb: &[u8], width: u32, height: u32) {
        if (width, height) != (self.width, self.height) || rgb.len() != self.sum.len() * 3 {
            return;
        }
        for (i, px) in rgb.chunks_exact(3).enumerate() {
            let g = (f64::from(px[0]) + f64::from(px[1]) + f64::from(px[2])) / 3.0;
            self.sum[i] += g;
            self.sum_sq[i] += g * g;
        }
        self.frames += 1;
    }

    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Each pixel's standard deviation over the frames added (all 0 before two).
    pub fn std(&self) -> Vec<f32> {
        let n = self.frames as f64;
        if self.frames < 2 {
            return vec![0.0; self.sum.len()];
        }
        self.sum
            .iter()
            .zip(&self.sum_sq)
            .map(|(s, s2)| {
                let m = s / n;
                (s2 / n - m * m).max(0.0).sqrt() as f32
            })
            .collect()
    }
}

/// The chassis from per-pixel standard deviations `std` (row-major, `width x height`):
/// the pixels under `max_std` that join the bottom row through pixels under `max_std`
/// (4-neighbours), grown by one pixel (JPEG blocks and the bilinear sample reach that far).
/// A still region elsewhere (a sky that never changes) is not the chassis.
pub fn from_variance(std: &[f32], width: u32, height: u32, max_std: f32) -> PixelMask {
    let (w, h) = (width as usize, height as usize);
    let mut mask = PixelMask::none(width, height);
    if std.len() != w * h || w == 0 || h == 0 {
        return mask;
    }
    let still = |i: usize| std[i] < max_std;
    let mut stack: Vec<usize> = ((h - 1) * w..h * w).filter(|&i| still(i)).collect();
    let mut found = vec![false; w * h];
    for &i in &stack {
        found[i] = true;
    }
    while let Some(i) = stack.pop() {
        let (x, y) = (i % w, i / w);
        let mut visit = |j: usize| {
            if !found[j] && still(j) {
                found[j] = true;
                stack.push(j);
            }
        };
        if x > 0 {
            visit(i - 1);
        }
        if x + 1 < w {
            visit(i + 1);
        }
        if y > 0 {
            visit(i - w);
        }
        if y + 1 < h {
            visit(i + w);
        }
    }
    for y in 0..h {
        for x in 0..w {
            let near = |dx: i64, dy: i64| {
                let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                xx >= 0
                    && yy >= 0
                    && (xx as usize) < w
                    && (yy as usize) < h
                    && found[yy as usize * w + xx as usize]
            };
            mask.masked[y * w + x] = (-1..=1).any(|dy| (-1..=1).any(|dx| near(dx, dy)));
        }
    }
    mask
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 12x10 drive: the floor's stripes move down a row per frame, and a chassis (grey
    /// 40) covers the bottom two rows and a post up column 3 to row 5. The top two rows
    /// (the sky) never change either.
    fn frame(t: usize) -> Vec<u8> {
        let (w, h) = (12, 10);
        let mut rgb = vec![0u8; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                let chassis = y >= 8 || (x == 3 && y >= 5);
                let g = if y < 2 {
                    200
                } else if chassis {
                    40
                } else if (y + 4 - t % 4) % 4 < 2 {
                    230
                } else {
                    90
                };
                rgb[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&[g, g, g]);
            }
        }
        rgb
    }

    #[test]
    fn the_still_pixels_joined_to_the_bottom_are_the_chassis() {
        let mut v = Variance::new(12, 10);
        for t in 0..20 {
            v.add(&frame(t), 12, 10);
        }
        v.add(&[0u8; 6], 2, 1);
        assert_eq!(v.frames(), 20);
        let std = v.std();
        // A floor pixel is 230 half the time and 90 the other half: sd 70.
        assert!((std[5 * 12 + 6] - 70.0).abs() < 1e-3, "{}", std[5 * 12 + 6]);
        assert_eq!(std[9 * 12], 0.0);
        let m = from_variance(&std, 12, 10, 12.0);
        // The chassis (24 + 3 post pixels) grown by one: rows 7-9 (36), the post's
        // columns 2-4 on rows 4-6 (9): 45. The sky (rows 0-1) is still but not joined to
        // the bottom: not masked.
        assert_eq!(m.count(), 45);
        assert!((m.fraction() - 0.375).abs() < 1e-6);
        assert!(m.at(3, 5) && m.at(2, 4) && m.at(0, 7) && !m.at(0, 6));
        assert!(!m.at(5, 0) && !m.at(6, 5));
        assert!(m.at(12, 0), "outside the frame");
        // Set by row instead, and the union.
        let r = PixelMask::below_row(12, 10, 9);
        assert_eq!(r.count(), 12);
        assert_eq!(m.clone().or(&r).count(), 45);
        assert_eq!(PixelMask::none(12, 10).or(&r).count(), 12);
        // Wrong sizes: nothing.
        assert_eq!(from_variance(&std[..5], 12, 10, 12.0).count(), 0);
    }
}
