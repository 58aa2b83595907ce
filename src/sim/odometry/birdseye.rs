//! Bird's-eye views of the floor near the robot: each camera frame warped onto a metric
//! grid on the ground plane in the robot frame, through the calibrated camera model
//! (fisheye or pinhole, height, tilt). Pure.
//!
//! ```text
//! cell (i, j) -> ground point (forward, left) metres -> camera pixel (u, v) -> grey value
//! ```
//!
//! Row `i` runs forward from `forward_m.0`, column `j` runs left from `left_m.0`; a cell is
//! `cell_m` wide. The cell -> pixel table is built once per camera. Cells whose pixel is
//! outside the frame (or too near its border for the bilinear sample) are invalid.

use super::super::Pose2;
use super::super::camera::CameraModel;
use super::mask::PixelMask;

/// The ground patch a view covers, in the robot frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewGrid {
    /// Forward range (m), from the axle centre.
    pub forward_m: (f32, f32),
    /// Lateral range (m), positive to the left.
    pub left_m: (f32, f32),
    /// Cell size (m).
    pub cell_m: f32,
}

impl Default for ViewGrid {
    /// The floor JetBot's camera sees sharply: 12 to 36 cm ahead, 13 cm each side, 4 mm cells.
    fn default() -> Self {
        Self {
            forward_m: (0.12, 0.36),
            left_m: (-0.13, 0.13),
            cell_m: 0.004,
        }
    }
}

impl ViewGrid {
    /// The floor a DonkeyCar's wide-angle camera ([`CameraModel::donkeycar`]) resolves at
    /// 160x120: 17 to 49 cm ahead of the rear axle, 24 cm each side, 8 mm cells (a pixel
    /// spans 6 mm of floor at 20 cm and 2 cm at 45 cm).
    pub fn donkeycar() -> Self {
        Self {
            forward_m: (0.17, 0.49),
            left_m: (-0.24, 0.24),
            cell_m: 0.008,
        }
    }

    pub fn rows(&self) -> usize {
        ((self.forward_m.1 - self.forward_m.0) / self.cell_m)
            .round()
            .max(1.0) as usize
    }

    pub fn cols(&self) -> usize {
        ((self.left_m.1 - self.left_m.0) / self.cell_m)
            .round()
            .max(1.0) as usize
    }

    /// The ground point (forward, left) at the centre of cell `(row, col)`.
    pub fn ground(&self, row: f32, col: f32) -> (f32, f32) {
        (
            self.forward_m.0 + (row + 0.5) * self.cell_m,
            self.left_m.0 + (col + 0.5) * self.cell_m,
        )
    }

    /// The (fractional) cell `(row, col)` of a ground point.
    pub fn cell(&self, forward: f32, left: f32) -> (f32, f32) {
        (
            (forward - self.forward_m.0) / self.cell_m - 0.5,
            (left - self.left_m.0) / self.cell_m - 0.5,
        )
    }

    /// The same patch at twice the cell size (for the coarse levels).
    pub fn coarser(&self) -> ViewGrid {
        ViewGrid {
            cell_m: self.cell_m * 2.0,
            ..*self
        }
    }
}

/// A grey bird's-eye view: `rows * cols` values, `NaN` where the camera does not see.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    pub grid: ViewGrid,
    pub rows: usize,
    pub cols: usize,
    pub grey: Vec<f32>,
}

impl View {
    /// The value at `(row, col)`, or `NaN` outside or unseen.
    pub fn at(&self, row: usize, col: usize) -> f32 {
        if row < self.rows && col < self.cols {
            self.grey[row * self.cols + col]
        } else {
            f32::NAN
        }
    }

    /// Bilinear sample at a fractional cell; `NaN` if any of the four cells is unseen.
    pub fn sample(&self, row: f32, col: f32) -> f32 {
        if !(row >= 0.0 && col >= 0.0) {
            return f32::NAN;
        }
        let (r0, c0) = (row.floor() as usize, col.floor() as usize);
        if r0 + 1 >= self.rows || c0 + 1 >= self.cols {
            return f32::NAN;
        }
        let (fr, fc) = (row - r0 as f32, col - c0 as f32);
        let a = self.at(r0, c0);
        let b = self.at(r0, c0 + 1);
        let c = self.at(r0 + 1, c0);
        let d = self.at(r0 + 1, c0 + 1);
        (a * (1.0 - fc) + b * fc) * (1.0 - fr) + (c * (1.0 - fc) + d * fc) * fr
    }

    /// Mean and standard deviation of the seen cells, and how many there are.
    pub fn stats(&self) -> (f32, f32, usize) {
        let seen = || self.grey.iter().copied().filter(|v| v.is_finite());
        let n = seen().count();
        if n == 0 {
            return (0.0, 0.0, 0);
        }
        let mean = seen().sum::<f32>() / n as f32;
        let var = seen().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n as f32;
        (mean, var.sqrt(), n)
    }

    /// Zero mean, unit variance over the seen cells (a flat view stays flat, at 0).
    pub fn normalised(&self) -> View {
        let (mean, std, _) = self.stats();
        let scale = if std > 1e-6 { 1.0 / std } else { 0.0 };
        View {
            grey: self.grey.iter().map(|v| (v - mean) * scale).collect(),
            ..self.clone()
        }
    }

    /// Half the resolution: each cell the mean of a 2x2 block (unseen if any is unseen).
    pub fn halved(&self) -> View {
        let (rows, cols) = (self.rows / 2, self.cols / 2);
        let mut grey = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                let s = self.at(2 * r, 2 * c)
                    + self.at(2 * r, 2 * c + 1)
                    + self.at(2 * r + 1, 2 * c)
                    + self.at(2 * r + 1, 2 * c + 1);
                grey.push(s / 4.0);
            }
        }
        View {
            grid: self.grid.coarser(),
            rows,
            cols,
            grey,
        }
    }
}

/// The cell -> camera pixel table for one camera and grid.
#[derive(Debug, Clone)]
pub struct Warp {
    grid: ViewGrid,
    rows: usize,
    cols: usize,
    width: u32,
    height: u32,
    /// Per cell, the pixel `(u, v)`; `None` where the camera does not see it.
    pixel: Vec<Option<(f32, f32)>>,
}

impl Warp {
    pub fn new(camera: &CameraModel, grid: ViewGrid) -> Self {
        let (rows, cols) = (grid.rows(), grid.cols());
        let (w, h) = (camera.width as f32, camera.height as f32);
        let mut pixel = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                let (fwd, left) = grid.ground(r as f32, c as f32);
                let p = camera
                    .ground_to_pixel(&Pose2::default(), fwd, left)
                    .filter(|&(u, v)| u >= 0.5 && v >= 0.5 && u <= w - 1.5 && v <= h - 1.5);
                pixel.push(p);
            }
        }
        Self {
            grid,
            rows,
            cols,
            width: camera.width,
            height: camera.height,
            pixel,
        }
    }

    pub fn grid(&self) -> ViewGrid {
        self.grid
    }

    /// The same table with every cell whose bilinear sample touches a masked pixel made
    /// unseen (the chassis: [`super::mask`]). A mask of another size changes nothing.
    pub fn masked(mut self, mask: &PixelMask) -> Self {
        if (mask.width, mask.height) != (self.width, self.height) {
            return self;
        }
        for p in self.pixel.iter_mut() {
            if let Some((u, v)) = *p {
                let (x0, y0) = ((u - 0.5).floor() as usize, (v - 0.5).floor() as usize);
                if mask.at(x0, y0)
                    || mask.at(x0 + 1, y0)
                    || mask.at(x0, y0 + 1)
                    || mask.at(x0 + 1, y0 + 1)
                {
                    *p = None;
                }
            }
        }
        self
    }

    /// Cells the camera sees.
    pub fn seen(&self) -> usize {
        self.pixel.iter().filter(|p| p.is_some()).count()
    }

    /// The bird's-eye view of an RGB8 frame (grey = mean of R, G and B, 0..255). A frame
    /// of the wrong size gives an all-unseen view.
    pub fn view(&self, rgb: &[u8], width: u32, height: u32) -> View {
        let ok = (width, height) == (self.width, self.height)
            && rgb.len() == width as usize * height as usize * 3;
        let grey_at = |x: usize, y: usize| {
            let i = (y * width as usize + x) * 3;
            (f32::from(rgb[i]) + f32::from(rgb[i + 1]) + f32::from(rgb[i + 2])) / 3.0
        };
        let grey = self
            .pixel
            .iter()
            .map(|p| match p {
                Some((u, v)) if ok => {
                    // Pixel centres at integer + 0.5.
                    let (x, y) = (u - 0.5, v - 0.5);
                    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
                    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
                    let top = grey_at(x0, y0) * (1.0 - fx) + grey_at(x0 + 1, y0) * fx;
                    let bottom = grey_at(x0, y0 + 1) * (1.0 - fx) + grey_at(x0 + 1, y0 + 1) * fx;
                    top * (1.0 - fy) + bottom * fy
                }
                _ => f32::NAN,
            })
            .collect();
        View {
            grid: self.grid,
            rows: self.rows,
            cols: self.cols,
            grey,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_and_ground_points_round_trip() {
        let g = ViewGrid::default();
        assert_eq!((g.rows(), g.cols()), (60, 65));
        let (f, l) = g.ground(0.0, 0.0);
        assert!((f - 0.122).abs() < 1e-6 && (l + 0.128).abs() < 1e-6);
        let (r, c) = g.cell(0.2, 0.01);
        let (f2, l2) = g.ground(r, c);
        assert!((f2 - 0.2).abs() < 1e-5 && (l2 - 0.01).abs() < 1e-5);
    }

    #[test]
    fn the_jetbot_camera_sees_the_grid_and_a_ground_mark_lands_in_its_cell() {
        let cam = CameraModel::jetbot(224, 224);
        let warp = Warp::new(&cam, ViewGrid::default());
        let total = ViewGrid::default().rows() * ViewGrid::default().cols();
        assert!(
            warp.seen() as f32 > 0.9 * total as f32,
            "{} of {total}",
            warp.seen()
        );
        // A white dot on black ground at (0.25 m ahead, 0.05 m left).
        let mut rgb = vec![0u8; 224 * 224 * 3];
        let (u, v) = cam.ground_to_pixel(&Pose2::default(), 0.25, 0.05).unwrap();
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (x, y) = ((u as i32 + dx) as usize, (v as i32 + dy) as usize);
                rgb[(y * 224 + x) * 3..(y * 224 + x) * 3 + 3].copy_from_slice(&[255, 255, 255]);
            }
        }
        let view = warp.view(&rgb, 224, 224);
        let (mut best, mut at) = (0.0, (0, 0));
        for r in 0..view.rows {
            for c in 0..view.cols {
                if view.at(r, c) > best {
                    best = view.at(r, c);
                    at = (r, c);
                }
            }
        }
        let (f, l) = view.grid.ground(at.0 as f32, at.1 as f32);
        assert!(
            (f - 0.25).abs() < 0.012 && (l - 0.05).abs() < 0.008,
            "{f} {l}"
        );
        // A wrong-sized frame is unseen everywhere.
        assert_eq!(warp.view(&rgb, 100, 100).stats().2, 0);
        // Masking the rows from the dot's down hides the dot's cell and every cell nearer.
        let seen = warp.seen();
        let near = warp
            .clone()
            .masked(&PixelMask::below_row(224, 224, v as u32 - 1));
        assert!(near.view(&rgb, 224, 224).at(at.0, at.1).is_nan());
        assert!(near.seen() < seen && near.seen() > 0);
        let (u0, v0) = cam.ground_to_pixel(&Pose2::default(), 0.35, 0.0).unwrap();
        assert!(v0 < v - 1.0, "a far cell ({u0}, {v0}) stays");
        assert_eq!(warp.clone().masked(&PixelMask::none(10, 10)).seen(), seen);
    }

    #[test]
    fn halving_and_normalising() {
        let g = ViewGrid {
            forward_m: (0.0, 0.016),
            left_m: (0.0, 0.016),
            cell_m: 0.004,
        };
        let v = View {
            grid: g,
            rows: 4,
            cols: 4,
            grey: (0..16).map(|i| i as f32).collect(),
        };
        let h = v.halved();
        assert_eq!((h.rows, h.cols), (2, 2));
        assert_eq!(h.grey, vec![2.5, 4.5, 10.5, 12.5]);
        assert_eq!(h.grid.cell_m, 0.008);
        let n = v.normalised();
        let (m, s, count) = n.stats();
        assert!(m.abs() < 1e-5 && (s - 1.0).abs() < 1e-5 && count == 16);
        assert!((v.sample(1.5, 2.25) - (1.5 * 4.0 + 2.25)).abs() < 1e-5);
        assert!(v.sample(3.5, 0.0).is_nan());
    }
}
