//! Drawing on a video frame (RGB8, in place): the model's target point or its
//! (speed, steering), and the two wheel commands as bars at the sides. Pure.

use crate::control::WheelCommand;
use crate::policy::contract::OutputKind;

const GREEN: [u8; 3] = [40, 230, 80];
const RED: [u8; 3] = [240, 60, 50];
const YELLOW: [u8; 3] = [255, 210, 0];
const DARK: [u8; 3] = [10, 10, 10];

struct Canvas<'a> {
    rgb: &'a mut [u8],
    w: i64,
    h: i64,
}

impl Canvas<'_> {
    fn put(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if (0..self.w).contains(&x) && (0..self.h).contains(&y) {
            let i = ((y * self.w + x) * 3) as usize;
            if let Some(px) = self.rgb.get_mut(i..i + 3) {
                px.copy_from_slice(&c);
            }
        }
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        for y in y0.min(y1)..=y0.max(y1) {
            for x in x0.min(x1)..=x0.max(x1) {
                self.put(x, y, c);
            }
        }
    }

    fn disc(&mut self, cx: i64, cy: i64, r: i64, c: [u8; 3]) {
        for y in -r..=r {
            for x in -r..=r {
                if x * x + y * y <= r * r {
                    self.put(cx + x, cy + y, c);
                }
            }
        }
    }

    fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: [u8; 3]) {
        let n = (x1 - x0).abs().max((y1 - y0).abs()).max(1);
        for i in 0..=n {
            let x = x0 + (x1 - x0) * i / n;
            let y = y0 + (y1 - y0) * i / n;
            self.rect(x, y, x + 1, y + 1, c);
        }
    }
}

/// The pixel of a target point `(x, y)` in -1..1 (JetBot: `x = (px - w/2) / (w/2)`).
pub fn target_pixel(x: f32, y: f32, w: u32, h: u32) -> (i64, i64) {
    let px = (x.clamp(-1.0, 1.0) + 1.0) / 2.0 * w as f32;
    let py = (y.clamp(-1.0, 1.0) + 1.0) / 2.0 * h as f32;
    (
        (px.round() as i64).min(i64::from(w) - 1),
        (py.round() as i64).min(i64::from(h) - 1),
    )
}

/// Draws the overlay. A buffer of the wrong size is left alone.
pub fn draw(
    rgb: &mut [u8],
    w: u32,
    h: u32,
    kind: OutputKind,
    outputs: [f32; 2],
    wheels: WheelCommand,
) {
    if rgb.len() != w as usize * h as usize * 3 || w < 8 || h < 8 {
        return;
    }
    let mut c = Canvas {
        rgb,
        w: i64::from(w),
        h: i64::from(h),
    };
    let unit = (i64::from(w.min(h)) / 40).max(2);
    let finite = outputs.iter().all(|v| v.is_finite());
    match kind {
        OutputKind::Xy if finite => {
            let (tx, ty) = target_pixel(outputs[0], outputs[1], w, h);
            c.line((c.w / 2, c.h - 1), (tx, ty), YELLOW);
            c.disc(tx, ty, unit + 2, DARK);
            c.disc(tx, ty, unit, GREEN);
        }
        OutputKind::SpeedSteering if finite => {
            // Steering: a bar from the top centre, right for positive.
            let half = c.w / 2;
            let len = (outputs[1].clamp(-1.0, 1.0) * half as f32) as i64;
            c.rect(half, unit, half + len, 2 * unit, YELLOW);
            // Speed: a bar up from the bottom centre.
            let up = (outputs[0].clamp(0.0, 1.0) * (c.h / 2) as f32) as i64;
            c.rect(
                half - unit / 2,
                c.h - 1 - up,
                half + unit / 2,
                c.h - 1,
                GREEN,
            );
        }
        _ => {}
    }
    // Wheels: a bar per side from the middle, up (green) forward, down (red) backward.
    let mid = c.h / 2;
    for (x0, v) in [(0, wheels.left), (c.w - unit - 1, wheels.right)] {
        if !v.is_finite() {
            continue;
        }
        let len = (v.clamp(-1.0, 1.0) * (c.h / 2 - 1) as f32) as i64;
        let colour = if v >= 0.0 { GREEN } else { RED };
        c.rect(x0, mid, x0 + unit, mid - len, colour);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn px(rgb: &[u8], w: u32, x: u32, y: u32) -> [u8; 3] {
        let i = ((y * w + x) * 3) as usize;
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    }

    #[test]
    fn the_target_point_lands_where_jetbot_puts_it() {
        assert_eq!(target_pixel(0.0, 0.0, 224, 224), (112, 112));
        assert_eq!(target_pixel(-1.0, -1.0, 224, 224), (0, 0));
        assert_eq!(target_pixel(1.0, 1.0, 224, 224), (223, 223));
        assert_eq!(target_pixel(0.5, -0.25, 200, 100), (150, 38));
        let (w, h) = (64, 64);
        let mut rgb = vec![0u8; 64 * 64 * 3];
        draw(
            &mut rgb,
            w,
            h,
            OutputKind::Xy,
            [0.5, -0.5],
            WheelCommand::new(0.5, -0.5),
        );
        let (tx, ty) = target_pixel(0.5, -0.5, w, h);
        assert_eq!(px(&rgb, w, tx as u32, ty as u32), GREEN);
        // Left wheel forward: green above the middle; right backward: red below it.
        assert_eq!(px(&rgb, w, 0, 20), GREEN);
        assert_eq!(px(&rgb, w, 63, 44), RED);
        assert_eq!(px(&rgb, w, 0, 44), [0, 0, 0]);
    }

    #[test]
    fn bad_sizes_and_non_finite_outputs_draw_nothing_harmful() {
        let mut small = vec![7u8; 10];
        draw(
            &mut small,
            64,
            64,
            OutputKind::Xy,
            [0.0, 0.0],
            WheelCommand::STOP,
        );
        assert_eq!(small, vec![7u8; 10]);
        let mut rgb = vec![0u8; 32 * 32 * 3];
        draw(
            &mut rgb,
            32,
            32,
            OutputKind::SpeedSteering,
            [f32::NAN, 0.0],
            WheelCommand::new(f32::NAN, 0.0),
        );
        // Only the right wheel's zero-length bar (at the middle row) is drawn.
        assert!(rgb.iter().filter(|&&b| b != 0).count() <= 3 * 3 * 2);
    }
}
