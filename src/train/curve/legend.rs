//! Where a chart's legend goes: the corner of the plotting area whose box would hide the
//! fewest drawn pixels. A learning curve's best point is often at the top right, where a
//! fixed legend covered it.

use plotters::chart::SeriesLabelPosition;

/// A corner of the plotting area, in the order a tie is broken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Corner {
    UpperRight,
    UpperLeft,
    LowerRight,
    LowerLeft,
}

/// How far plotters puts the legend box in from the plotting area's edges, in pixels.
const INSET: i32 = 5;
/// Pixels around the box that count as covered too (half a line's width and a little air).
const PAD: i32 = 3;
/// What a lone point (drawn as a dot) counts for, against 1 per pixel of line.
const DOT_WEIGHT: usize = 9;

impl Corner {
    const ALL: [Corner; 4] = [
        Corner::UpperRight,
        Corner::UpperLeft,
        Corner::LowerRight,
        Corner::LowerLeft,
    ];

    /// plotters' name for it.
    pub(super) fn position(self) -> SeriesLabelPosition {
        match self {
            Corner::UpperRight => SeriesLabelPosition::UpperRight,
            Corner::UpperLeft => SeriesLabelPosition::UpperLeft,
            Corner::LowerRight => SeriesLabelPosition::LowerRight,
            Corner::LowerLeft => SeriesLabelPosition::LowerLeft,
        }
    }

    /// The box's pixels `[x0, x1) x [y0, y1)` in a plotting area of `area` pixels (y
    /// down), laid out as plotters lays it out, widened by [`PAD`].
    fn rect(self, (w, h): (i32, i32), (bw, bh): (i32, i32)) -> [i32; 4] {
        let x0 = match self {
            Corner::UpperLeft | Corner::LowerLeft => INSET,
            Corner::UpperRight | Corner::LowerRight => w - bw - INSET,
        };
        let y0 = match self {
            Corner::UpperLeft | Corner::UpperRight => INSET,
            Corner::LowerLeft | Corner::LowerRight => h - bh - INSET,
        };
        [x0 - PAD, x0 + bw + PAD, y0 - PAD, y0 + bh + PAD]
    }
}

/// The corner where a legend box of `size` pixels covers the least of `runs` (polylines
/// in the plotting area's pixels, y down), upper right first on a tie.
pub(super) fn quietest_corner(
    area: (i32, i32),
    size: (i32, i32),
    runs: &[Vec<(f64, f64)>],
) -> Corner {
    let mut best = (Corner::UpperRight, usize::MAX);
    for corner in Corner::ALL {
        let covered = covered(corner.rect(area, size), runs);
        if covered < best.1 {
            best = (corner, covered);
        }
    }
    best.0
}

/// How much of `runs` lies in `rect`: each segment sampled once per pixel of its length,
/// a run of one point counted [`DOT_WEIGHT`] times.
fn covered([x0, x1, y0, y1]: [i32; 4], runs: &[Vec<(f64, f64)>]) -> usize {
    let inside = |(x, y): (f64, f64)| {
        f64::from(x0) <= x && x < f64::from(x1) && f64::from(y0) <= y && y < f64::from(y1)
    };
    let mut n = 0;
    for run in runs {
        match run.as_slice() {
            [] => {}
            [p] => n += DOT_WEIGHT * usize::from(inside(*p)),
            [.., last] => {
                for pair in run.windows(2) {
                    let ((ax, ay), (bx, by)) = (pair[0], pair[1]);
                    let len = (bx - ax).hypot(by - ay);
                    let steps = if len.is_finite() {
                        len.ceil().clamp(1.0, 1e5) as usize
                    } else {
                        1
                    };
                    let k = steps as f64;
                    for i in 0..steps {
                        let i = i as f64;
                        n += usize::from(inside((ax + (bx - ax) * i / k, ay + (by - ay) * i / k)));
                    }
                }
                n += usize::from(inside(*last));
            }
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    const AREA: (i32, i32) = (200, 100);
    const BOX: (i32, i32) = (50, 30);

    #[test]
    fn the_boxes_sit_where_plotters_draws_them() {
        // Upper right: x from 200 - 50 - 5 = 145, y from 5; widened by 3 on every side.
        assert_eq!(Corner::UpperRight.rect(AREA, BOX), [142, 198, 2, 38]);
        assert_eq!(Corner::LowerLeft.rect(AREA, BOX), [2, 58, 62, 98]);
    }

    #[test]
    fn a_line_counts_one_per_pixel_and_a_dot_nine() {
        // y = 10 from x = 0 to 100: samples at x = 0, 1, ..., 100; [2, 58) holds 56 of them.
        let line = vec![vec![(0.0, 10.0), (100.0, 10.0)]];
        assert_eq!(covered(Corner::UpperLeft.rect(AREA, BOX), &line), 56);
        assert_eq!(covered(Corner::UpperRight.rect(AREA, BOX), &line), 0);
        let dots = vec![vec![(150.0, 20.0)], vec![(10.0, 90.0)]];
        assert_eq!(covered(Corner::UpperRight.rect(AREA, BOX), &dots), 9);
        assert_eq!(covered(Corner::LowerRight.rect(AREA, BOX), &dots), 0);
    }

    #[test]
    fn the_legend_goes_where_the_lines_are_not() {
        // Nothing drawn: upper right, plotters' usual place.
        assert_eq!(quietest_corner(AREA, BOX, &[]), Corner::UpperRight);
        // A curve that rises to the top right (pixel y is down): upper left and lower
        // right are both free, and upper left comes first.
        let rising = vec![vec![(0.0, 100.0), (200.0, 0.0)]];
        assert_eq!(quietest_corner(AREA, BOX, &rising), Corner::UpperLeft);
        // A loss that falls from the top left and stays low: the upper right is free.
        let falling = vec![vec![(0.0, 0.0), (60.0, 90.0), (200.0, 95.0)]];
        assert_eq!(quietest_corner(AREA, BOX, &falling), Corner::UpperRight);
        // One line along the top and one up the left side: the lower right.
        let top_and_left = vec![
            vec![(0.0, 10.0), (200.0, 10.0)],
            vec![(10.0, 0.0), (10.0, 100.0)],
        ];
        assert_eq!(
            quietest_corner(AREA, BOX, &top_and_left),
            Corner::LowerRight
        );
    }

    #[test]
    fn broken_coordinates_do_not_hang_or_panic() {
        let wild = vec![vec![(0.0, 0.0), (f64::INFINITY, 5.0), (1e12, 1e12)]];
        let _ = quietest_corner(AREA, BOX, &wild);
    }
}
