//! How well a folder's labels agree with themselves: the error no model can be expected to
//! beat on it.
//!
//! JetBot's data-collection notebook saves one frame per click, so a person who clicks
//! several times without moving the robot leaves near-duplicate frames with different
//! labels. Frames are compared with their next [`WINDOW`] neighbours in capture order, as
//! grey [`THUMB_PX`]x[`THUMB_PX`] thumbnails:
//!
//! ```text
//! near-duplicates:  mean |grey_a - grey_b| < NEAR_DUPLICATE (of 255), grouped transitively
//! disagreement:     for each frame in a group of n, frame_error(its label, the mean of
//!                   the other n - 1 labels), times sqrt((n - 1) / n) for a pixel
//!                   distance ((n - 1) / n for a squared error)
//! ```
//!
//! A label is the view's own mean label plus the person's noise; against the others' mean
//! the difference also carries their noise, 1 / (n - 1) of it in variance, which the
//! factor takes out. What is left is how far a label lies from its view's mean label: the
//! error of a model that answered every view perfectly. The spread of the disagreements is
//! the labels' noise floor.

use super::{Spread, frame_error, mean_label};
use crate::policy::OutputKind;

/// Side of the grey thumbnail frames are compared at.
pub const THUMB_PX: usize = 56;
/// Largest mean absolute grey difference (0..255) of two views of the same scene.
pub const NEAR_DUPLICATE: f64 = 3.0;
/// How many later frames (in capture order) each frame is compared with.
pub const WINDOW: usize = 8;

/// A frame's grey thumbnail: box averages of `THUMB_PX`x`THUMB_PX` cells of an RGB8 image.
pub fn thumbnail(width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
    let (w, h) = (width as usize, height as usize);
    let mut out = Vec::with_capacity(THUMB_PX * THUMB_PX);
    for cy in 0..THUMB_PX {
        let (y0, y1) = (
            cy * h / THUMB_PX,
            ((cy + 1) * h / THUMB_PX).max(cy * h / THUMB_PX + 1),
        );
        for cx in 0..THUMB_PX {
            let (x0, x1) = (
                cx * w / THUMB_PX,
                ((cx + 1) * w / THUMB_PX).max(cx * w / THUMB_PX + 1),
            );
            let (mut sum, mut n) = (0u64, 0u64);
            for y in y0..y1.min(h) {
                for x in x0..x1.min(w) {
                    let p = &rgb[(y * w + x) * 3..][..3];
                    sum += 299 * u64::from(p[0]) + 587 * u64::from(p[1]) + 114 * u64::from(p[2]);
                    n += 1000;
                }
            }
            out.push(sum.checked_div(n).unwrap_or(0) as u8);
        }
    }
    out
}

/// Mean absolute difference of two equally long images or thumbnails, in levels (0..255;
/// 0 for two empty ones). `eval --compare-render` reports it as `pixel_diff`.
pub fn mean_abs_difference(a: &[u8], b: &[u8]) -> f64 {
    let sum: u64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| u64::from(x.abs_diff(y)))
        .sum();
    sum as f64 / a.len().max(1) as f64
}

/// The labels' agreement over a folder.
#[derive(Debug, Clone, PartialEq)]
pub struct Agreement {
    /// Frames compared.
    pub frames: usize,
    /// Groups of two or more near-duplicates.
    pub groups: usize,
    /// Frames in those groups.
    pub duplicated: usize,
    /// Each duplicated frame's label against the mean of its group's other labels; `None`
    /// when no frame has a near-duplicate.
    pub disagreement: Option<Spread>,
}

/// The agreement of `labels` on frames given by their `thumbs`, both in capture order.
pub fn agreement(output: OutputKind, thumbs: &[Vec<u8>], labels: &[[f32; 2]]) -> Agreement {
    let n = thumbs.len().min(labels.len());
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for i in 0..n {
        for j in i + 1..(i + 1 + WINDOW).min(n) {
            if mean_abs_difference(&thumbs[i], &thumbs[j]) < NEAR_DUPLICATE {
                let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                parent[a] = b;
            }
        }
    }
    let mut members: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for i in 0..n {
        members.entry(root(&mut parent, i)).or_default().push(i);
    }
    let groups: Vec<&Vec<usize>> = members.values().filter(|g| g.len() > 1).collect();
    let mut errors = Vec::new();
    for g in &groups {
        for &i in g.iter() {
            let others: Vec<[f32; 2]> = g.iter().filter(|&&k| k != i).map(|&k| labels[k]).collect();
            let views = g.len() as f64;
            let error = frame_error(output, labels[i], mean_label(&others));
            errors.push(match output {
                OutputKind::Xy => error * ((views - 1.0) / views).sqrt(),
                OutputKind::SpeedSteering => error * (views - 1.0) / views,
            });
        }
    }
    Agreement {
        frames: n,
        groups: groups.len(),
        duplicated: errors.len(),
        disagreement: Spread::of(&errors),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(grey: u8) -> Vec<u8> {
        vec![grey; THUMB_PX * THUMB_PX]
    }

    #[test]
    fn pixel_diff_is_the_mean_absolute_level_difference() {
        // |10 - 14| + |200 - 190| + |0 - 0| + |255 - 0| = 4 + 10 + 0 + 255 = 269, over 4.
        assert_eq!(
            mean_abs_difference(&[10, 200, 0, 255], &[14, 190, 0, 0]),
            67.25
        );
        assert_eq!(mean_abs_difference(&[7; 12], &[7; 12]), 0.0);
        assert_eq!(mean_abs_difference(&[], &[]), 0.0);
    }

    #[test]
    fn thumbnail_averages_cells_to_grey() {
        // 112x112: each cell is 2x2. A red image: grey 0.299 * 255 = 76.2 -> 76.
        let red = [255u8, 0, 0].repeat(112 * 112);
        let t = thumbnail(112, 112, &red);
        assert_eq!(t.len(), THUMB_PX * THUMB_PX);
        assert!(t.iter().all(|&v| v == 76), "{:?}", &t[..4]);
        // Left half white, right half black: the middle cells split exactly.
        let mut half = vec![0u8; 112 * 112 * 3];
        for y in 0..112 {
            half[y * 112 * 3..][..56 * 3].fill(255);
        }
        let t = thumbnail(112, 112, &half);
        assert_eq!((t[0], t[27], t[28], t[55]), (255, 255, 0, 0));
    }

    #[test]
    fn near_duplicates_are_grouped_and_their_labels_compared() {
        // Frames 0, 1, 2 show one view (grey 100, 101, 102: differences 1 and 2 < 3),
        // frame 3 another (grey 200), frames 4 and 5 a third (grey 50, 50).
        let thumbs = [100, 101, 102, 200, 50, 50].map(flat).to_vec();
        // Labels in -1..1: 112 px per unit.
        let labels = [
            [0.0, 0.0],
            [0.3, 0.0],
            [0.0, 0.3],
            [0.9, 0.9],
            [-0.5, 0.0],
            [-0.5, 0.25],
        ];
        let a = agreement(OutputKind::Xy, &thumbs, &labels);
        assert_eq!((a.frames, a.groups, a.duplicated), (6, 2, 5));
        // Frame 0 against (0.15, 0.15): 112 * 0.2121 = 23.76 px, times sqrt(2/3): 19.40;
        // frame 1 against (0, 0.15): 112 * hypot(0.3, 0.15) = 37.57 -> 30.67; frame 2
        // likewise; frames 4 and 5 against each other: 112 * 0.25 = 28.0, times sqrt(1/2):
        // 19.80 each.
        let s = a.disagreement.unwrap();
        let want = [19.399, 30.673, 30.673, 19.799, 19.799];
        let mean = want.iter().sum::<f64>() / 5.0;
        assert!((s.mean - mean).abs() < 1e-2, "{s:?}");
        assert!((s.median - 19.799).abs() < 1e-3, "{s:?}");
    }

    #[test]
    fn frames_further_apart_than_the_window_are_not_compared() {
        let mut thumbs: Vec<Vec<u8>> = (0..=WINDOW).map(|k| flat(10 * k as u8 + 20)).collect();
        thumbs[WINDOW] = flat(20); // the same view as frame 0, WINDOW frames later
        thumbs.push(flat(20)); // and again, WINDOW + 1 later
        let labels = vec![[0.0, 0.0]; thumbs.len()];
        let a = agreement(OutputKind::Xy, &thumbs, &labels);
        // Frame 0 joins frame WINDOW (in reach), which joins frame WINDOW + 1.
        assert_eq!((a.groups, a.duplicated), (1, 3));
        let a = agreement(OutputKind::Xy, &thumbs[1..], &labels[1..]);
        assert_eq!((a.groups, a.duplicated), (1, 2));
        let none = agreement(OutputKind::Xy, &thumbs[..WINDOW], &labels[..WINDOW]);
        assert_eq!((none.groups, none.disagreement), (0, None));
    }
}
