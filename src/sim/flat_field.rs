//! What a camera adds at the same pixel of every frame (vignetting, a light gradient, a
//! lamp's glare that travels with the robot), estimated from a recording with poses, so
//! that a replayed view keeps it where the camera puts it instead of carrying it along
//! with the floor it re-projects.
//!
//! The model is an affine response per pixel `u`, the same for the three channels: the
//! light `x` from the scene and the recorded 8-bit value `I` are related by
//!
//! ```text
//! x = gain(u) * I + offset(u)
//! ```
//!
//! This is exact for the simulator's looks (`I = shade(u) * y + flare(u)`,
//! [`super::appearance::Look::apply`], before clipping) and covers a real lens's vignetting.
//!
//! [`FlatField::fit`] takes pixel pairs that saw the same floor point in two frames (the
//! poses say which) and asks both to give the same light:
//!
//! ```text
//! gain(a) * I_a + offset(a) - gain(b) * I_b - offset(b) = 0
//! ```
//!
//! which is linear in the two fields. Each field is bilinear between the nodes of a coarse
//! grid; least squares with a second-difference smoothness term (a linear gradient costs
//! nothing) and a weak pull towards the identity, which also pins the overall scale and
//! zero that no pair can see. The caller leaves out clipped values and pixels on edges,
//! where a pose error of a pixel changes the value.
//!
//! A replay [`FlatField::flatten`]s each recorded frame once (light, not camera values)
//! and [`FlatField::restore`]s each synthesised view: the camera's effects are put back at
//! the view's own pixels.

use nalgebra::{DMatrix, DVector};

use super::SimError;

/// Two pixels that saw the same floor point: `(u, v)` pixel coordinates (centres at
/// integer + 0.5) and the RGB values there (8-bit levels, bilinear where between pixels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelPair {
    pub a: (f32, f32),
    pub a_rgb: [f32; 3],
    pub b: (f32, f32),
    pub b_rgb: [f32; 3],
}

/// Weight of the smoothness term per node, relative to the pairs' average weight on a
/// node: a second difference of 0.01 in gain costs as much as a 1.28-level mismatch on
/// `SMOOTHNESS` of a node's pairs.
const SMOOTHNESS: f64 = 0.02;

/// Weight of the pull towards the identity per node, relative as [`SMOOTHNESS`].
const PRIOR: f64 = 1e-3;

/// Share of a node's average load of pairs above which the fit counts a pixel as seen.
const SEEN_LOAD: f64 = 0.05;

/// Levels at which a unit of gain is weighed against a level of offset (mid-grey).
const MID_LEVEL: f64 = 128.0;

/// Gains outside this range mean the fit failed (pairs from a wrong pose, say).
const GAIN_RANGE: (f32, f32) = (0.2, 5.0);

/// A per-pixel affine camera response: `x = gain * I + offset`.
#[derive(Debug, Clone, PartialEq)]
pub struct FlatField {
    width: usize,
    height: usize,
    gain: Vec<f32>,
    offset: Vec<f32>,
    /// Per pixel: whether the fit had pairs there (a [`SEEN_LOAD`] share of a node's
    /// average), so the field there is measured rather than extrapolated.
    seen: Vec<bool>,
    /// Root mean square disagreement of the fit's pairs, levels: as recorded, and as
    /// light through this field.
    mismatch: (f32, f32),
    /// Per pixel and channel (as the frame's bytes), [`FlatField::restore`]'s `1 / gain`
    /// and `0.5 - offset / gain`: the light back to a camera value, plus a half for
    /// rounding. Laid out flat so the loop vectorises.
    inverse: (Vec<f32>, Vec<f32>),
}

/// The grid of nodes a field is bilinear between: node `(a, b)` sits at pixel coordinate
/// `(a * width / (nodes - 1), b * height / (nodes - 1))`.
#[derive(Debug, Clone, Copy)]
struct Grid {
    nodes: usize,
    step_u: f32,
    step_v: f32,
}

impl Grid {
    fn new(width: usize, height: usize, nodes: usize) -> Self {
        let spans = (nodes - 1) as f32;
        Self {
            nodes,
            step_u: width as f32 / spans,
            step_v: height as f32 / spans,
        }
    }

    fn len(&self) -> usize {
        self.nodes * self.nodes
    }

    /// The four nodes around `(u, v)` and their bilinear weights.
    fn weights(&self, u: f32, v: f32) -> [(usize, f32); 4] {
        let last = (self.nodes - 2) as f32;
        let tu = (u / self.step_u).clamp(0.0, last + 1.0);
        let tv = (v / self.step_v).clamp(0.0, last + 1.0);
        let (a, b) = (tu.floor().min(last), tv.floor().min(last));
        let (fu, fv) = (tu - a, tv - b);
        let k = b as usize * self.nodes + a as usize;
        [
            (k, (1.0 - fu) * (1.0 - fv)),
            (k + 1, fu * (1.0 - fv)),
            (k + self.nodes, (1.0 - fu) * fv),
            (k + self.nodes + 1, fu * fv),
        ]
    }
}

impl FlatField {
    /// The identity: flattening and restoring change nothing.
    pub fn identity(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            gain: vec![1.0; width * height],
            offset: vec![0.0; width * height],
            seen: vec![false; width * height],
            mismatch: (0.0, 0.0),
            inverse: (vec![1.0; width * height * 3], vec![0.5; width * height * 3]),
        }
    }

    /// Fits the field of a `width x height` camera to `pairs` on a `nodes x nodes` grid
    /// (at least 3). An error when there are no pairs, the system cannot be solved, or the
    /// gains leave 0.2..5 (pairs that do not see the same floor).
    pub fn fit(
        width: usize,
        height: usize,
        pairs: &[PixelPair],
        nodes: usize,
    ) -> Result<Self, SimError> {
        if nodes < 3 || width == 0 || height == 0 {
            return Err(SimError::Invalid(format!(
                "flat field: {nodes} nodes on a {width}x{height} frame (at least 3 nodes)"
            )));
        }
        if pairs.is_empty() {
            return Err(SimError::Invalid(
                "flat field: no pixel pairs saw the same floor".into(),
            ));
        }
        let grid = Grid::new(width, height, nodes);
        let n = grid.len();
        // Unknowns: gains at the nodes, then offsets (levels).
        let mut ata = DMatrix::<f64>::zeros(2 * n, 2 * n);
        let mut atb = DVector::<f64>::zeros(2 * n);
        let mut idx = [0usize; 16];
        let mut coef = [0f64; 16];
        for p in pairs {
            let wa = grid.weights(p.a.0, p.a.1);
            let wb = grid.weights(p.b.0, p.b.1);
            for (s, (&(ka, _), &(kb, _))) in wa.iter().zip(&wb).enumerate() {
                idx[s] = ka;
                idx[4 + s] = n + ka;
                idx[8 + s] = kb;
                idx[12 + s] = n + kb;
            }
            // The three channels' rows summed into one 16x16 block, then added once.
            let mut block = [[0f64; 16]; 16];
            for c in 0..3 {
                let (ia, ib) = (p.a_rgb[c] as f64, p.b_rgb[c] as f64);
                for (s, (&(_, wa), &(_, wb))) in wa.iter().zip(&wb).enumerate() {
                    let (wa, wb) = (wa as f64, wb as f64);
                    coef[s] = wa * ia;
                    coef[4 + s] = wa;
                    coef[8 + s] = -wb * ib;
                    coef[12 + s] = -wb;
                }
                for (row, &cr) in block.iter_mut().zip(&coef) {
                    for (cell, &cq) in row.iter_mut().zip(&coef) {
                        *cell += cr * cq;
                    }
                }
            }
            for (row, &r) in block.iter().zip(&idx) {
                for (&cell, &q) in row.iter().zip(&idx) {
                    ata[(r, q)] += cell;
                }
            }
        }
        // How much of the pairs' weight each node carries (3 rows per pair end).
        let mut node_load = vec![0f64; n];
        for p in pairs {
            for (k, w) in grid
                .weights(p.a.0, p.a.1)
                .into_iter()
                .chain(grid.weights(p.b.0, p.b.1))
            {
                node_load[k] += 3.0 * w as f64;
            }
        }
        let total: f64 = node_load.iter().sum();
        // Each node's share of the rows, the unit of the smoothness and prior weights.
        let load = total / 2.0 / n as f64;
        let smooth = [SMOOTHNESS * load * MID_LEVEL * MID_LEVEL, SMOOTHNESS * load];
        let prior = [PRIOR * load * MID_LEVEL * MID_LEVEL, PRIOR * load];
        for (field, base) in [0, n].into_iter().enumerate() {
            for b in 0..nodes {
                for a in 0..nodes {
                    let k = base + b * nodes + a;
                    // Second differences along the row and along the column.
                    if a > 0 && a + 1 < nodes {
                        add_second_difference(&mut ata, [k - 1, k, k + 1], smooth[field]);
                    }
                    if b > 0 && b + 1 < nodes {
                        add_second_difference(&mut ata, [k - nodes, k, k + nodes], smooth[field]);
                    }
                    ata[(k, k)] += prior[field];
                }
            }
        }
        for k in 0..n {
            atb[k] += prior[0];
        }
        // The pairs cannot see one scale and zero for the whole frame, and they would
        // rather shrink every gain towards 0 (their noise shrinks with it): where the pairs
        // are, the gain is 1 and the offset 0 on average, weighted by load (held as hard
        // constraints; the weights make them so). With the mean pinned, the noise favours
        // equal gains, not small ones.
        let c: Vec<f64> = node_load.iter().map(|l| l / total).collect();
        let hard = [1e4 * load * MID_LEVEL * MID_LEVEL, 1e4 * load];
        for (field, base) in [0, n].into_iter().enumerate() {
            for r in 0..n {
                for q in 0..n {
                    ata[(base + r, base + q)] += hard[field] * c[r] * c[q];
                }
            }
        }
        for r in 0..n {
            atb[r] += hard[0] * c[r];
        }
        let solution = ata
            .cholesky()
            .ok_or_else(|| SimError::Invalid("flat field: the fit is singular".into()))?
            .solve(&atb);
        let mut field = Self::identity(width, height);
        let light = |(u, v): (f32, f32), value: f32| -> f64 {
            grid.weights(u, v)
                .iter()
                .map(|&(k, w)| w as f64 * (solution[k] * value as f64 + solution[n + k]))
                .sum()
        };
        let (mut before, mut after) = (0f64, 0f64);
        for p in pairs {
            for c in 0..3 {
                before += ((p.a_rgb[c] - p.b_rgb[c]) as f64).powi(2);
                after += (light(p.a, p.a_rgb[c]) - light(p.b, p.b_rgb[c])).powi(2);
            }
        }
        let rows = (3 * pairs.len()) as f64;
        field.mismatch = ((before / rows).sqrt() as f32, (after / rows).sqrt() as f32);
        for j in 0..height {
            for i in 0..width {
                let (mut g, mut o) = (0.0f64, 0.0f64);
                for (k, w) in grid.weights(i as f32 + 0.5, j as f32 + 0.5) {
                    g += w as f64 * solution[k];
                    o += w as f64 * solution[n + k];
                }
                field.gain[j * width + i] = g as f32;
                field.offset[j * width + i] = o as f32;
                let here: f64 = grid
                    .weights(i as f32 + 0.5, j as f32 + 0.5)
                    .iter()
                    .map(|&(k, w)| w as f64 * node_load[k])
                    .sum();
                field.seen[j * width + i] = here >= SEEN_LOAD * load;
            }
        }
        let per_byte = |f: fn(f32, f32) -> f32| -> Vec<f32> {
            field
                .gain
                .iter()
                .zip(&field.offset)
                .flat_map(|(&g, &o)| [f(g, o); 3])
                .collect()
        };
        field.inverse = (per_byte(|g, _| 1.0 / g), per_byte(|g, o| 0.5 - o / g));
        let (lo, hi) = field
            .gain
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &g| {
                (l.min(g), h.max(g))
            });
        if !(lo >= GAIN_RANGE.0 && hi <= GAIN_RANGE.1) {
            return Err(SimError::Invalid(format!(
                "flat field: fitted gains {lo:.2}..{hi:.2} leave {}..{} (pairs that did not see the same floor?)",
                GAIN_RANGE.0, GAIN_RANGE.1
            )));
        }
        Ok(field)
    }

    /// Root mean square disagreement of the pairs it was fitted to, levels: between the
    /// recorded values, and between their light through this field. The identity: zeros.
    pub fn mismatch(&self) -> (f32, f32) {
        self.mismatch
    }

    /// The light at pixel `k` (row-major) for recorded value `value`.
    pub fn light(&self, k: usize, value: f32) -> f32 {
        self.gain[k] * value + self.offset[k]
    }

    /// Largest difference, in levels, between this field's light and the recorded value,
    /// for black and for white, over the pixels the fit had pairs at: how far from the
    /// identity it is where it was measured.
    pub fn largest_correction(&self) -> f32 {
        self.gain
            .iter()
            .zip(&self.offset)
            .zip(&self.seen)
            .filter(|(_, seen)| **seen)
            .map(|((&g, &o), _)| o.abs().max((g * 255.0 + o - 255.0).abs()))
            .fold(0.0, f32::max)
    }

    /// `rgb` (this field's size, RGB8) as light: `gain * I + offset`, rounded and clamped
    /// to 0..255.
    pub fn flatten(&self, rgb: &[u8]) -> Vec<u8> {
        assert_eq!(rgb.len(), self.width * self.height * 3, "frame size");
        let mut out = Vec::with_capacity(rgb.len());
        for ((px, &g), &o) in rgb.chunks_exact(3).zip(&self.gain).zip(&self.offset) {
            for &c in px {
                out.push((g * c as f32 + o).round().clamp(0.0, 255.0) as u8);
            }
        }
        out
    }

    /// Light back to camera values in place: `(x - offset) / gain` at each pixel, rounded
    /// and clamped to 0..255 (the float-to-byte cast saturates).
    pub fn restore(&self, rgb: &mut [u8]) {
        assert_eq!(rgb.len(), self.width * self.height * 3, "frame size");
        for ((c, &scale), &bias) in rgb.iter_mut().zip(&self.inverse.0).zip(&self.inverse.1) {
            *c = (*c as f32 * scale + bias) as u8;
        }
    }
}

/// Adds `weight * (x[k0] - 2 x[k1] + x[k2])^2` to the normal equations.
fn add_second_difference(ata: &mut DMatrix<f64>, k: [usize; 3], weight: f64) {
    let c = [1.0, -2.0, 1.0];
    for r in 0..3 {
        for q in 0..3 {
            ata[(k[r], k[q])] += weight * c[r] * c[q];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 64;
    const H: usize = 48;

    /// The scene: a smooth texture on the floor plane, at floor coordinates `(x, y)`
    /// (pixels of a frame at offset 0), 20..235 levels, per channel.
    fn scene(x: f32, y: f32, c: usize) -> f32 {
        let s = (0.21 * x + 0.7 * c as f32).sin() * (0.17 * y - 0.3 * c as f32).cos()
            + 0.5 * (0.05 * (x + 2.0 * y)).sin();
        128.0 + 70.0 * s
    }

    /// Vignetting, a gradient and a glare patch, as a simulated look.
    fn camera(u: f32, v: f32, x: f32) -> f32 {
        let (cx, cy) = (W as f32 / 2.0, H as f32 / 2.0);
        let (dx, dy) = (u - cx, v - cy);
        let shade = (1.0 - 0.5 * (dx * dx + dy * dy) / (cx * cx + cy * cy)) * (1.0 + 0.2 * dx / cx);
        let (gu, gv) = (u - 44.0, v - 14.0);
        let flare = 90.0 * (-(gu * gu + gv * gv) / (2.0 * 8.0 * 8.0)).exp();
        shade * x + flare
    }

    /// Pairs between frames that see the floor shifted by `(sx, sy)` pixels from each
    /// other, on every other pixel, with the camera's effects on both.
    fn pairs(shifts: &[(f32, f32)], effects: bool) -> Vec<PixelPair> {
        let look = |u: f32, v: f32, x: f32| if effects { camera(u, v, x) } else { x };
        let mut out = Vec::new();
        for &(sx, sy) in shifts {
            for j in (0..H).step_by(2) {
                for i in (0..W).step_by(2) {
                    let (ua, va) = (i as f32 + 0.5, j as f32 + 0.5);
                    let (ub, vb) = (ua - sx, va - sy);
                    if !(0.0..W as f32).contains(&ub) || !(0.0..H as f32).contains(&vb) {
                        continue;
                    }
                    let x = |c| scene(ua, va, c);
                    out.push(PixelPair {
                        a: (ua, va),
                        a_rgb: [0, 1, 2].map(|c| look(ua, va, x(c))),
                        b: (ub, vb),
                        b_rgb: [0, 1, 2].map(|c| look(ub, vb, x(c))),
                    });
                }
            }
        }
        out
    }

    const SHIFTS: [(f32, f32); 6] = [
        (7.0, 0.0),
        (-9.0, 3.0),
        (0.0, 8.0),
        (4.0, -11.0),
        (15.0, 6.0),
        (-5.0, -5.0),
    ];

    /// Root mean square of the two lights' difference over pairs.
    fn rms_mismatch(field: &FlatField, pairs: &[PixelPair]) -> f32 {
        let k = |(u, v): (f32, f32)| v as usize * W + u as usize;
        let mut se = 0.0f64;
        for p in pairs {
            for c in 0..3 {
                let d = field.light(k(p.a), p.a_rgb[c]) - field.light(k(p.b), p.b_rgb[c]);
                se += (d * d) as f64;
            }
        }
        (se / (3 * pairs.len()) as f64).sqrt() as f32
    }

    #[test]
    fn the_fit_makes_pixels_that_saw_the_same_floor_agree() {
        let train = pairs(&SHIFTS, true);
        // Pairs the fit never saw: other shifts.
        let check = pairs(&[(11.0, -2.0), (-3.0, 9.0)], true);
        let none = FlatField::identity(W, H);
        let before = rms_mismatch(&none, &check);
        let field = FlatField::fit(W, H, &train, 12).unwrap();
        let after = rms_mismatch(&field, &check);
        assert!(
            before > 20.0,
            "the camera's effects mismatch by {before:.1} levels"
        );
        assert!(after < 4.0, "{before:.1} -> {after:.1} levels");
        // The light it gives is the scene's up to one scale and zero for the whole frame:
        // their ratio varies little between the centre and a corner.
        let at = |u: usize, v: usize| {
            let (uf, vf) = (u as f32 + 0.5, v as f32 + 0.5);
            field.light(v * W + u, camera(uf, vf, 200.0))
                - field.light(v * W + u, camera(uf, vf, 50.0))
        };
        let (centre, corner) = (at(32, 24), at(4, 4));
        assert!(
            (corner / centre - 1.0).abs() < 0.1,
            "contrast at a corner {corner:.1}, centre {centre:.1}"
        );
    }

    #[test]
    fn a_camera_without_effects_fits_the_identity() {
        let field = FlatField::fit(W, H, &pairs(&SHIFTS, false), 12).unwrap();
        let c = field.largest_correction();
        assert!(c < 1.0, "largest correction {c:.2} levels");
    }

    #[test]
    fn flatten_then_restore_gives_the_frame_back() {
        let field = FlatField::fit(W, H, &pairs(&SHIFTS, true), 12).unwrap();
        // A frame this camera could take: the scene's light through its effects.
        let mut frame = Vec::with_capacity(W * H * 3);
        for j in 0..H {
            for i in 0..W {
                let (u, v) = (i as f32 + 0.5, j as f32 + 0.5);
                for c in 0..3 {
                    let x = scene(3.0 * u, 2.0 * v, c);
                    frame.push(camera(u, v, x).round().clamp(0.0, 255.0) as u8);
                }
            }
        }
        let mut back = field.flatten(&frame);
        field.restore(&mut back);
        let worst = frame
            .iter()
            .zip(&back)
            .map(|(&a, &b)| (a as i32 - b as i32).abs())
            .max()
            .unwrap();
        // Rounding to 8 bits in between: within a level where the gain is above 1.
        assert!(worst <= 2, "worst {worst} levels");
        let mut same = frame.clone();
        FlatField::identity(W, H).restore(&mut same);
        assert_eq!(same, frame);
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert!(FlatField::fit(W, H, &[], 12).is_err());
        assert!(FlatField::fit(W, H, &pairs(&SHIFTS, true), 2).is_err());
    }
}
