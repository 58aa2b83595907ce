//! The picture `jetpilot score` writes: a grid of scored frames, each with the label drawn
//! in green and the model's answer in red, so a person sees where and how a model is wrong.
//!
//! xy heads: a disc at each target point and a line between them. speed_steering heads:
//! two bars along the bottom edge, from the centre to the steering (left is negative),
//! label above prediction, and a bar up the left edge for each speed.

use image::imageops::FilterType;
use image::{Rgb, RgbImage};

use crate::policy::OutputKind;

const LABEL: Rgb<u8> = Rgb([40, 220, 60]);
const PREDICTION: Rgb<u8> = Rgb([235, 40, 40]);
const GAP: u32 = 2;

/// One frame of the sheet.
pub struct Tile<'a> {
    /// RGB8 pixels, `width * height * 3`.
    pub rgb: &'a [u8],
    pub width: u32,
    pub height: u32,
    pub label: [f32; 2],
    pub prediction: [f32; 2],
}

/// Lays `tiles` out `columns` wide, each scaled to `tile_px` square.
pub fn draw(output: OutputKind, tiles: &[Tile<'_>], columns: u32, tile_px: u32) -> RgbImage {
    let columns = columns.max(1);
    let rows = (tiles.len() as u32).div_ceil(columns).max(1);
    let step = tile_px + GAP;
    let mut sheet =
        RgbImage::from_pixel(columns * step + GAP, rows * step + GAP, Rgb([24, 24, 24]));
    for (i, t) in tiles.iter().enumerate() {
        let Some(tile) = marked(output, t, tile_px) else {
            continue;
        };
        let (col, row) = (i as u32 % columns, i as u32 / columns);
        image::imageops::replace(
            &mut sheet,
            &tile,
            (GAP + col * step) as i64,
            (GAP + row * step) as i64,
        );
    }
    sheet
}

/// One frame scaled to `tile_px` square with its label and prediction drawn on it (`None`
/// when `rgb` is not `width * height * 3` bytes).
pub fn marked(output: OutputKind, t: &Tile<'_>, tile_px: u32) -> Option<RgbImage> {
    let src = RgbImage::from_raw(t.width, t.height, t.rgb.to_vec())?;
    let mut tile = image::imageops::resize(&src, tile_px, tile_px, FilterType::Triangle);
    match output {
        OutputKind::Xy => mark_points(&mut tile, t.label, t.prediction),
        OutputKind::SpeedSteering => mark_bars(&mut tile, t.label, t.prediction),
    }
    Some(tile)
}

/// -1..1 -> pixel of a `size`-pixel axis.
fn to_px(v: f32, size: u32) -> f32 {
    (v.clamp(-1.2, 1.2) + 1.0) / 2.0 * size as f32
}

fn mark_points(img: &mut RgbImage, label: [f32; 2], prediction: [f32; 2]) {
    let (w, h) = img.dimensions();
    let l = (to_px(label[0], w), to_px(label[1], h));
    let p = (to_px(prediction[0], w), to_px(prediction[1], h));
    line(img, l, p, Rgb([250, 250, 250]));
    let r = (w as f32 / 40.0).max(2.0);
    disc(img, l, r, LABEL);
    disc(img, p, r, PREDICTION);
}

fn mark_bars(img: &mut RgbImage, label: [f32; 2], prediction: [f32; 2]) {
    let (w, h) = img.dimensions();
    let thick = (h / 24).max(2);
    let centre = w as f32 / 2.0;
    for (k, (value, colour)) in [(label, LABEL), (prediction, PREDICTION)]
        .into_iter()
        .enumerate()
    {
        let y0 = h - (2 - k as u32) * (thick + 1);
        let x_end = to_px(value[1], w);
        let (a, b) = (centre.min(x_end) as u32, centre.max(x_end) as u32);
        fill(img, a, y0, b.saturating_sub(a).max(1), thick, colour);
        let speed_px = (value[0].clamp(0.0, 1.0) * h as f32 * 0.8) as u32;
        let x0 = 1 + k as u32 * (thick + 1);
        fill(img, x0, h.saturating_sub(speed_px), thick, speed_px, colour);
    }
}

fn fill(img: &mut RgbImage, x: u32, y: u32, w: u32, h: u32, c: Rgb<u8>) {
    let (iw, ih) = img.dimensions();
    for yy in y..(y + h).min(ih) {
        for xx in x..(x + w).min(iw) {
            img.put_pixel(xx, yy, c);
        }
    }
}

fn disc(img: &mut RgbImage, (cx, cy): (f32, f32), r: f32, c: Rgb<u8>) {
    let (w, h) = img.dimensions();
    let (x0, x1) = (
        (cx - r).floor().max(0.0) as u32,
        ((cx + r).ceil() as u32).min(w),
    );
    let (y0, y1) = (
        (cy - r).floor().max(0.0) as u32,
        ((cy + r).ceil() as u32).min(h),
    );
    for y in y0..y1 {
        for x in x0..x1 {
            let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
            if dx * dx + dy * dy <= r * r {
                img.put_pixel(x, y, c);
            }
        }
    }
}

fn line(img: &mut RgbImage, a: (f32, f32), b: (f32, f32), c: Rgb<u8>) {
    let (w, h) = img.dimensions();
    let steps = (b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil().max(1.0) as u32;
    for i in 0..=steps {
        let t = i as f32 / steps as f32;
        let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
        if x >= 0.0 && y >= 0.0 && (x as u32) < w && (y as u32) < h {
            img.put_pixel(x as u32, y as u32, c);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_label_and_the_prediction_are_drawn_where_they_point() {
        let rgb = vec![0u8; 224 * 224 * 3];
        let tile = Tile {
            rgb: &rgb,
            width: 224,
            height: 224,
            label: [-0.5, 0.0],
            prediction: [0.5, 0.5],
        };
        let sheet = draw(OutputKind::Xy, &[tile], 1, 112);
        assert_eq!(sheet.dimensions(), (112 + 2 * GAP, 112 + 2 * GAP));
        // Label (-0.5, 0) -> (28, 56) in the tile; prediction (0.5, 0.5) -> (84, 84).
        assert_eq!(*sheet.get_pixel(GAP + 28, GAP + 56), LABEL);
        assert_eq!(*sheet.get_pixel(GAP + 84, GAP + 84), PREDICTION);
        assert_eq!(*sheet.get_pixel(GAP + 100, GAP + 10), Rgb([0, 0, 0]));
    }
}
