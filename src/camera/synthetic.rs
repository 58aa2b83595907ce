//! Synthetic road frames: a flat-ground perspective view of a JetBot-mat road (yellow solid
//! edges, white dashed centre line) bending left or right. Used for the bundled sample
//! frames (`jetpilot samples`) and tests; the simulator's renderer replaces it for anything
//! that needs a real track.

/// Where the road is relative to the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoadView {
    /// Lateral position of the road centre under the camera, metres (positive: to the right).
    pub offset_m: f32,
    /// Bend: the centre moves `curvature * d^2 / 2` metres sideways at distance `d`
    /// (1/m; positive bends right).
    pub curvature: f32,
}

const CAMERA_HEIGHT_M: f32 = 0.1;
const ROAD_HALF_WIDTH_M: f32 = 0.15;
const LINE_WIDTH_M: f32 = 0.012;
const DASH_M: f32 = 0.05;

/// Renders a `width` x `height` RGB8 frame of the road.
pub fn render_road(width: u32, height: u32, view: RoadView) -> Vec<u8> {
    let (w, h) = (width as usize, height as usize);
    let mut out = vec![0u8; w * h * 3];
    // Focal length for a ~100 degree horizontal field of view; horizon at 30 % height.
    let focal = width as f32 / (2.0 * (50f32.to_radians()).tan());
    let horizon = height as f32 * 0.3;
    for y in 0..h {
        let below = y as f32 + 0.5 - horizon;
        for x in 0..w {
            let px = &mut out[(y * w + x) * 3..(y * w + x) * 3 + 3];
            if below <= 0.0 {
                px.copy_from_slice(&[200, 205, 210]); // wall
                continue;
            }
            let dist = focal * CAMERA_HEIGHT_M / below;
            let lateral = (x as f32 + 0.5 - width as f32 / 2.0) * dist / focal;
            let centre = view.offset_m + 0.5 * view.curvature * dist * dist;
            let u = lateral - centre;
            let fade = (1.0 - dist / 3.0).clamp(0.3, 1.0);
            let colour: [f32; 3] = if (u.abs() - ROAD_HALF_WIDTH_M).abs() < LINE_WIDTH_M {
                [230.0, 190.0, 40.0] // yellow edge
            } else if u.abs() < LINE_WIDTH_M * 0.6 && (dist / DASH_M) as i32 % 2 == 0 {
                [235.0, 235.0, 235.0] // white dash
            } else if u.abs() < ROAD_HALF_WIDTH_M {
                [70.0, 72.0, 75.0] // asphalt
            } else {
                [90.0, 140.0, 80.0] // green mat
            };
            for (c, v) in px.iter_mut().zip(colour) {
                *c = (v * fade + 200.0 * (1.0 - fade)) as u8;
            }
        }
    }
    out
}

/// The view for frame `i` of a sample sequence of `n`: one slow left-right sweep.
pub fn sample_view(i: usize, n: usize) -> RoadView {
    let phase = std::f32::consts::TAU * i as f32 / n.max(1) as f32;
    RoadView {
        offset_m: 0.04 * (2.0 * phase + 1.0).sin(),
        curvature: 1.2 * phase.sin(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_road_is_symmetric_and_curves_are_not() {
        let (w, h) = (64u32, 48u32);
        let img = render_road(
            w,
            h,
            RoadView {
                offset_m: 0.0,
                curvature: 0.0,
            },
        );
        assert_eq!(img.len(), (w * h * 3) as usize);
        let px = |img: &[u8], x: usize, y: usize| img[(y * w as usize + x) * 3];
        for y in 0..h as usize {
            for x in 0..w as usize / 2 {
                assert_eq!(px(&img, x, y), px(&img, w as usize - 1 - x, y), "({x},{y})");
            }
        }
        let right = render_road(
            w,
            h,
            RoadView {
                offset_m: 0.0,
                curvature: 1.0,
            },
        );
        assert_ne!(img, right);
    }
}
