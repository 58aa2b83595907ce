//! Ridge regression, the maths of `train probe`: a linear output layer fitted in closed
//! form on frozen features, its strength chosen by cross-validation over blocks of
//! capture time.
//!
//! Features are standardised (each column to mean 0, sd 1, on the rows it is fitted on),
//! labels centred, and the weights solved in the dual, `W = Zᵀ (Z Zᵀ + λI)⁻¹ (Y - ȳ)`,
//! which is the cheaper side when there are fewer frames than features (hundreds against
//! 512 or 1280). One eigendecomposition of `Z Zᵀ` per fold gives every λ of the grid. The
//! standardisation is folded into the result, so the head is one `y = W f + b` on the raw
//! features: an ONNX `Gemm`.

use nalgebra::{DMatrix, SymmetricEigen};

/// Errors of a fit.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RidgeError {
    #[error("ridge: {0}")]
    Shape(String),
    #[error("ridge: the strength must be positive and finite, got {0}")]
    Strength(f64),
    #[error("ridge: cross-validation needs at least 2 folds with frames in each, got {0}")]
    Folds(usize),
    #[error("ridge: no strengths to choose from")]
    NoStrengths,
}

/// `y = weight · f + bias` on raw features.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearHead {
    /// `[outputs][features]`.
    pub weight: Vec<Vec<f64>>,
    pub bias: Vec<f64>,
}

impl LinearHead {
    pub fn predict(&self, features: &[f32]) -> Vec<f64> {
        self.weight
            .iter()
            .zip(&self.bias)
            .map(|(w, b)| {
                b + w
                    .iter()
                    .zip(features)
                    .map(|(w, f)| w * *f as f64)
                    .sum::<f64>()
            })
            .collect()
    }

    /// The weight row-major as f32 (`[outputs, features]`) and the bias: an ONNX head's.
    pub fn to_f32(&self) -> (Vec<f32>, Vec<f32>) {
        (
            self.weight.iter().flatten().map(|&w| w as f32).collect(),
            self.bias.iter().map(|&b| b as f32).collect(),
        )
    }
}

/// The default grid of strengths for `features` columns: `features * 10^e`,
/// `e = -3, -2.5, ..., 3` (standardised columns make `Z Zᵀ`'s diagonal about `features`).
pub fn default_strengths(features: usize) -> Vec<f64> {
    (-6..=6)
        .map(|e| features as f64 * 10f64.powf(e as f64 / 2.0))
        .collect()
}

/// Columns to mean 0 and sd 1 on the rows given; constant columns keep a scale of 1 (they
/// are all zero after centring).
struct Standardiser {
    mean: Vec<f64>,
    scale: Vec<f64>,
}

impl Standardiser {
    fn of(x: &[&[f32]]) -> Self {
        let d = x.first().map_or(0, |r| r.len());
        let n = x.len().max(1) as f64;
        let mut mean = vec![0.0; d];
        for r in x {
            for (m, v) in mean.iter_mut().zip(r.iter()) {
                *m += *v as f64 / n;
            }
        }
        let mut var = vec![0.0; d];
        for r in x {
            for ((s, v), m) in var.iter_mut().zip(r.iter()).zip(&mean) {
                *s += (*v as f64 - m).powi(2) / n;
            }
        }
        let scale = var
            .into_iter()
            .map(|v| if v > 1e-12 { v.sqrt() } else { 1.0 })
            .collect();
        Self { mean, scale }
    }

    fn apply(&self, x: &[&[f32]]) -> DMatrix<f64> {
        let d = self.mean.len();
        DMatrix::from_fn(x.len(), d, |i, j| {
            (x[i][j] as f64 - self.mean[j]) / self.scale[j]
        })
    }
}

/// One fold's training side, decomposed once for every strength.
struct Dual {
    standardiser: Standardiser,
    z: DMatrix<f64>,
    y_mean: Vec<f64>,
    eigen: SymmetricEigen<f64, nalgebra::Dyn>,
    /// `Uᵀ (Y - ȳ)`.
    uty: DMatrix<f64>,
}

impl Dual {
    fn new(x: &[&[f32]], y: &[&[f32]]) -> Self {
        let standardiser = Standardiser::of(x);
        let z = standardiser.apply(x);
        let k = y.first().map_or(0, |r| r.len());
        let n = y.len().max(1) as f64;
        let y_mean: Vec<f64> = (0..k)
            .map(|c| y.iter().map(|r| r[c] as f64).sum::<f64>() / n)
            .collect();
        let yc = DMatrix::from_fn(y.len(), k, |i, c| y[i][c] as f64 - y_mean[c]);
        let gram = &z * z.transpose();
        let eigen = SymmetricEigen::new(gram);
        let uty = eigen.eigenvectors.transpose() * yc;
        Self {
            standardiser,
            z,
            y_mean,
            eigen,
            uty,
        }
    }

    /// The standardised-space weights `Zᵀ U (Λ + λ)⁻¹ Uᵀ Yc`, `[features, outputs]`.
    fn weights(&self, strength: f64) -> DMatrix<f64> {
        let mut scaled = self.uty.clone();
        for (i, mut row) in scaled.row_iter_mut().enumerate() {
            // Eigenvalues of a Gram matrix are >= 0; rounding can leave tiny negatives.
            row /= self.eigen.eigenvalues[i].max(0.0) + strength;
        }
        self.z.transpose() * (&self.eigen.eigenvectors * scaled)
    }

    /// The head on raw features for `strength`.
    fn head(&self, strength: f64) -> LinearHead {
        let w = self.weights(strength);
        let s = &self.standardiser;
        let weight: Vec<Vec<f64>> = (0..w.ncols())
            .map(|c| (0..w.nrows()).map(|j| w[(j, c)] / s.scale[j]).collect())
            .collect();
        let bias = weight
            .iter()
            .zip(&self.y_mean)
            .map(|(row, ym)| ym - row.iter().zip(&s.mean).map(|(w, m)| w * m).sum::<f64>())
            .collect();
        LinearHead { weight, bias }
    }
}

fn check(x: &[&[f32]], y: &[&[f32]]) -> Result<(), RidgeError> {
    if x.is_empty() || x.len() != y.len() {
        return Err(RidgeError::Shape(format!(
            "{} feature rows and {} label rows (need the same number, at least 1)",
            x.len(),
            y.len()
        )));
    }
    let (d, k) = (x[0].len(), y[0].len());
    if let Some(i) = x.iter().position(|r| r.len() != d) {
        return Err(RidgeError::Shape(format!(
            "feature row {i} has {} values, row 0 has {d}",
            x[i].len()
        )));
    }
    if let Some(i) = y.iter().position(|r| r.len() != k) {
        return Err(RidgeError::Shape(format!(
            "label row {i} has {} values, row 0 has {k}",
            y[i].len()
        )));
    }
    Ok(())
}

/// Fits `y ≈ W f + b` with strength `strength` on every row.
pub fn fit(x: &[&[f32]], y: &[&[f32]], strength: f64) -> Result<LinearHead, RidgeError> {
    if !(strength.is_finite() && strength > 0.0) {
        return Err(RidgeError::Strength(strength));
    }
    check(x, y)?;
    Ok(Dual::new(x, y).head(strength))
}

/// One strength's cross-validated error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Validated {
    pub strength: f64,
    /// Mean of `error` over the scored rows, each predicted by the fit without its fold.
    pub error: f64,
    /// The standard error of `error`: the spread of the folds' own means over the square
    /// root of their count (rows of one fold are near-duplicates, not independent).
    pub standard_error: f64,
}

/// K-fold cross-validation: row `i` is in fold `folds[i]`; for each fold, fits on the
/// others and predicts its rows. Only rows with `scored[i]` count (mirrored copies of a
/// frame are fitted on, not scored). `error(label, prediction)` is one row's error.
pub fn cross_validate(
    x: &[&[f32]],
    y: &[&[f32]],
    folds: &[usize],
    scored: &[bool],
    strengths: &[f64],
    error: impl Fn(&[f32], &[f64]) -> f64,
) -> Result<Vec<Validated>, RidgeError> {
    check(x, y)?;
    if folds.len() != x.len() || scored.len() != x.len() {
        return Err(RidgeError::Shape(format!(
            "{} rows, {} fold numbers, {} scored flags",
            x.len(),
            folds.len(),
            scored.len()
        )));
    }
    if let Some(s) = strengths.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
        return Err(RidgeError::Strength(*s));
    }
    let k = folds.iter().max().map_or(0, |m| m + 1);
    let used = (0..k).filter(|f| folds.contains(f)).count();
    if used < 2 {
        return Err(RidgeError::Folds(used));
    }
    let mut sums = vec![0.0; strengths.len()];
    let mut fold_means: Vec<Vec<f64>> = vec![Vec::new(); strengths.len()];
    let mut count = 0usize;
    for fold in 0..k {
        let (train, test): (Vec<usize>, Vec<usize>) = (0..x.len()).partition(|&i| folds[i] != fold);
        let test: Vec<usize> = test.into_iter().filter(|&i| scored[i]).collect();
        if test.is_empty() || train.is_empty() {
            continue;
        }
        let dual = Dual::new(&pick(&train, x), &pick(&train, y));
        for (j, s) in strengths.iter().enumerate() {
            let head = dual.head(*s);
            let sum = test
                .iter()
                .map(|&i| error(y[i], &head.predict(x[i])))
                .sum::<f64>();
            sums[j] += sum;
            fold_means[j].push(sum / test.len() as f64);
        }
        count += test.len();
    }
    Ok(strengths
        .iter()
        .zip(sums)
        .zip(fold_means)
        .map(|((&strength, sum), means)| Validated {
            strength,
            error: sum / count.max(1) as f64,
            standard_error: standard_error(&means),
        })
        .collect())
}

/// The same cross-validation of the constant answer, the mean label of each fold's other
/// scored rows (what a ridge of infinite strength answers): the error a probe has to beat.
pub fn cross_validate_constant(
    y: &[&[f32]],
    folds: &[usize],
    scored: &[bool],
    error: impl Fn(&[f32], &[f64]) -> f64,
) -> Validated {
    let k = folds.iter().max().map_or(0, |m| m + 1);
    let width = y.first().map_or(0, |r| r.len());
    let (mut sum, mut count, mut means) = (0.0, 0usize, Vec::new());
    for fold in 0..k {
        let rows =
            |inside: bool| (0..y.len()).filter(move |&i| scored[i] && (folds[i] == fold) == inside);
        let train: Vec<usize> = rows(false).collect();
        let test: Vec<usize> = rows(true).collect();
        if train.is_empty() || test.is_empty() {
            continue;
        }
        let mean: Vec<f64> = (0..width)
            .map(|c| train.iter().map(|&i| y[i][c] as f64).sum::<f64>() / train.len() as f64)
            .collect();
        let fold_sum: f64 = test.iter().map(|&i| error(y[i], &mean)).sum();
        sum += fold_sum;
        count += test.len();
        means.push(fold_sum / test.len() as f64);
    }
    Validated {
        strength: f64::INFINITY,
        error: sum / count.max(1) as f64,
        standard_error: standard_error(&means),
    }
}

/// The standard error of the mean of `values`: their sample sd over `sqrt(n)`; 0 for
/// fewer than two.
pub fn standard_error(values: &[f64]) -> f64 {
    let n = values.len();
    if n < 2 {
        return 0.0;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (var / n as f64).sqrt()
}

fn pick<'a>(rows: &[usize], m: &[&'a [f32]]) -> Vec<&'a [f32]> {
    rows.iter().map(|&i| m[i]).collect()
}

/// `n` rows in time order cut into `k` contiguous blocks of (nearly) equal size: near-
/// duplicate neighbours stay in one fold.
pub fn time_blocks(n: usize, k: usize) -> Vec<usize> {
    let k = k.max(1);
    (0..n).map(|i| i * k / n.max(1)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(v: &[Vec<f32>]) -> Vec<&[f32]> {
        v.iter().map(Vec::as_slice).collect()
    }

    #[test]
    fn one_feature_worked_by_hand() {
        // f = 1, 2, 3 (mean 2, sd sqrt(2/3)), y = 2, 4, 9 (mean 5). Standardised
        // z = (-1, 0, 1) / sd; ridge slope on z is (z·yc) / (z·z + λ) = (7 / sd) / (2 / sd² + λ).
        // With λ = 1: sd² = 2/3, z·z = 3, so slope_z = (7 / sd) / 4; on raw f the slope is
        // slope_z / sd = 7 / (4 sd²) = 7 * 3 / 8 = 2.625, and the bias 5 - 2.625 * 2 = -0.25.
        // (The dual with one column is the same fit: Zᵀ (Z Zᵀ + λ)⁻¹ yc = (ZᵀZ + λ)⁻¹ Zᵀ yc.)
        let x = vec![vec![1.0], vec![2.0], vec![3.0]];
        let y = vec![vec![2.0], vec![4.0], vec![9.0]];
        let head = fit(&rows(&x), &rows(&y), 1.0).unwrap();
        assert!((head.weight[0][0] - 2.625).abs() < 1e-9, "{head:?}");
        assert!((head.bias[0] + 0.25).abs() < 1e-9, "{head:?}");
        assert!((head.predict(&[2.0])[0] - 5.0).abs() < 1e-9);
    }

    #[test]
    fn a_weak_ridge_recovers_an_exact_linear_map_and_a_strong_one_the_mean() {
        // y0 = 3 f0 - 2 f1 + 1, y1 = f2 + 0.5, from 12 rows of 3 features.
        let x: Vec<Vec<f32>> = (0..12)
            .map(|i| {
                let t = i as f32;
                vec![t.sin(), (1.3 * t).cos(), 0.1 * t * t - t]
            })
            .collect();
        let y: Vec<Vec<f32>> = x
            .iter()
            .map(|f| vec![3.0 * f[0] - 2.0 * f[1] + 1.0, f[2] + 0.5])
            .collect();
        let head = fit(&rows(&x), &rows(&y), 1e-9).unwrap();
        for (w, want) in head.weight[0].iter().zip([3.0, -2.0, 0.0]) {
            assert!((w - want).abs() < 1e-4, "{:?}", head.weight);
        }
        assert!((head.bias[0] - 1.0).abs() < 1e-4 && (head.bias[1] - 0.5).abs() < 1e-4);
        let flat = fit(&rows(&x), &rows(&y), 1e12).unwrap();
        let mean0 = y.iter().map(|r| r[0] as f64).sum::<f64>() / 12.0;
        assert!((flat.predict(&x[3])[0] - mean0).abs() < 1e-6);
    }

    #[test]
    fn cross_validation_prefers_the_strength_that_ignores_noise_columns() {
        // 40 rows: y = f0 + noise-free; 30 more columns of deterministic junk that only a
        // weak ridge fits. Held-out blocks score the weak fit worse than a moderate one.
        let x: Vec<Vec<f32>> = (0..40)
            .map(|i| {
                let mut r = vec![(i as f32 * 0.37).sin()];
                r.extend((1..31).map(|j| ((i * j * 7919 % 101) as f32 / 50.0) - 1.0));
                r
            })
            .collect();
        let y: Vec<Vec<f32>> = x
            .iter()
            .enumerate()
            .map(|(i, f)| vec![f[0] + 0.3 * ((i * 31 % 17) as f32 / 8.0 - 1.0)])
            .collect();
        let folds = time_blocks(40, 4);
        let scored = vec![true; 40];
        let strengths = [1e-6, 10.0];
        let err = |l: &[f32], p: &[f64]| (l[0] as f64 - p[0]).abs();
        let cv = cross_validate(&rows(&x), &rows(&y), &folds, &scored, &strengths, err).unwrap();
        assert!(cv[1].error < cv[0].error, "{cv:?}");
    }

    #[test]
    fn the_constant_answer_is_cross_validated_on_the_scored_rows() {
        // Folds {0,1} and {2,3}; row 3 is a mirrored copy (not scored, not averaged).
        // Fold 0 predicts rows 0, 1 with row 2's label 4: errors 3, 2. Fold 1 predicts
        // row 2 with the mean of rows 0, 1 (1.5): error 2.5. Mean over 3 rows: 7.5 / 3.
        let y = [vec![1.0f32], vec![2.0], vec![4.0], vec![-4.0]];
        let y: Vec<&[f32]> = y.iter().map(Vec::as_slice).collect();
        let err = |l: &[f32], p: &[f64]| (l[0] as f64 - p[0]).abs();
        let v = cross_validate_constant(&y, &[0, 0, 1, 1], &[true, true, true, false], err);
        assert!((v.error - 2.5).abs() < 1e-12, "{v:?}");
        // Fold means 2.5 and 2.5: no spread.
        assert_eq!(v.standard_error, 0.0);
        assert!(v.strength.is_infinite());
    }

    #[test]
    fn standard_error_worked_by_hand() {
        // 1, 2, 3, 6: mean 3, sample variance (4 + 1 + 0 + 9) / 3 = 14/3, se sqrt(14/12).
        assert!((standard_error(&[1.0, 2.0, 3.0, 6.0]) - (14.0f64 / 12.0).sqrt()).abs() < 1e-12);
        assert_eq!(standard_error(&[5.0]), 0.0);
    }

    #[test]
    fn blocks_are_contiguous_and_balanced() {
        assert_eq!(time_blocks(7, 3), vec![0, 0, 0, 1, 1, 2, 2]);
        assert_eq!(time_blocks(4, 4), vec![0, 1, 2, 3]);
    }

    #[test]
    fn bad_input_is_refused_by_name() {
        let x = vec![vec![1.0, 2.0], vec![1.0]];
        let y = vec![vec![0.0], vec![1.0]];
        assert!(
            matches!(fit(&rows(&x), &rows(&y), 1.0), Err(RidgeError::Shape(m)) if m.contains("row 1"))
        );
        assert_eq!(
            fit(&rows(&y), &rows(&y), 0.0),
            Err(RidgeError::Strength(0.0))
        );
        let err = |_: &[f32], _: &[f64]| 0.0;
        assert_eq!(
            cross_validate(&rows(&y), &rows(&y), &[0, 0], &[true, true], &[1.0], err),
            Err(RidgeError::Folds(1))
        );
    }
}
