//! `train probe`: a pretrained backbone kept as it is, and its output layer fitted in
//! closed form ([`super::ridge`]) on the pooled features of labelled frames.
//!
//! Each frame goes through the daemon's own [`Preprocessor`] and the backbone on ONNX
//! Runtime once (a mirrored copy too, with `mirror`): a probe of 755 frames at 224x224
//! took 43 s on 2 cores, where ten epochs of fine-tuning at that size (4.7 images a
//! second) take about 27 minutes. The strength of the ridge is chosen by cross-validation
//! over contiguous blocks of capture time, on the training frames alone. The result is the
//! whole network with the fitted head: an ordinary jetpilot model for `score`, `run` and
//! `train il --init` (a linear probe, then a fine-tune: LP-FT).

use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::TensorRef;

use super::FitError;
use super::ridge::{self, LinearHead, Validated};
use crate::dataset::labelled::LabelledFrame;
use crate::policy::onnx::{NetWeights, encode_model};
use crate::policy::{ModelContract, OutputKind, Preprocessor, runtime};

/// Frames' features in time order, with their labels.
#[derive(Debug, Clone, Default)]
pub struct ProbeData {
    /// One row per image: its final feature map, or (after [`ProbeData::pooled`]) its
    /// pooled cells.
    pub features: Vec<Vec<f32>>,
    pub labels: Vec<[f32; 2]>,
    /// Which source frame each row came from (a mirrored copy shares its frame's).
    pub frame: Vec<usize>,
    /// `false` for mirrored copies: fitted on, never scored.
    pub original: Vec<bool>,
    /// Frames that could not be read, each with its reason.
    pub warnings: Vec<String>,
}

/// One row's error for `output`'s kind: pixels for xy, squared error for speed and steering.
fn row_error(output: OutputKind) -> impl Fn(&[f32], &[f64]) -> f64 {
    move |l: &[f32], p: &[f64]| {
        crate::score::frame_error(output, [l[0], l[1]], [p[0] as f32, p[1] as f32])
    }
}

impl ProbeData {
    /// Each row's fold: `folds` contiguous blocks of its frame in time order.
    pub fn row_folds(&self, folds: usize) -> Vec<usize> {
        let frames = self.frame.iter().max().map_or(0, |m| m + 1);
        let blocks = ridge::time_blocks(frames, folds);
        self.frame.iter().map(|&f| blocks[f]).collect()
    }

    /// The rows pooled into `grid` x `grid` cells ([`pool_cells`]) from maps of `channels`
    /// x `side` x `side`; without the mirrored copies unless `mirror`.
    pub fn pooled(&self, channels: usize, side: usize, grid: usize, mirror: bool) -> ProbeData {
        let keep: Vec<usize> = (0..self.features.len())
            .filter(|&i| mirror || self.original[i])
            .collect();
        ProbeData {
            features: keep
                .iter()
                .map(|&i| pool_cells(&self.features[i], channels, side, grid))
                .collect(),
            labels: keep.iter().map(|&i| self.labels[i]).collect(),
            frame: keep.iter().map(|&i| self.frame[i]).collect(),
            original: keep.iter().map(|&i| self.original[i]).collect(),
            warnings: Vec::new(),
        }
    }
}

/// How the final map becomes the head's input: `grid` x `grid` cells, and whether the
/// mirrored copies are fitted on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pooling {
    pub grid: usize,
    pub mirror: bool,
}

/// One pooling's probe.
#[derive(Debug, Clone)]
pub struct Tried {
    pub pooling: Pooling,
    pub probe: Probe,
}

impl Tried {
    /// Its cross-validation at its probe's strength (the lowest error of its table where
    /// that strength is not in it); `None` when it was not cross-validated.
    pub fn validated(&self) -> Option<Validated> {
        let v = &self.probe.validated;
        v.iter()
            .find(|v| v.strength == self.probe.strength)
            .or_else(|| v.iter().min_by(|a, b| a.error.total_cmp(&b.error)))
            .copied()
    }

    /// [`Tried::validated`]'s error, infinite when there is none.
    pub fn error(&self) -> f64 {
        self.validated().map_or(f64::INFINITY, |v| v.error)
    }
}

/// How [`choose`] picks among the cross-validated (pooling, strength) pairs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    /// The lowest cross-validated error.
    Lowest,
    /// Of every pair within one standard error of the lowest, the simplest: the fewest
    /// cells, then the strongest ridge, then without mirrored copies.
    OneStandardError,
}

/// [`choose`]'s result: every pooling tried, the chosen one first, and the constant
/// answer's cross-validation beside them.
#[derive(Debug, Clone)]
pub struct Chosen {
    pub tried: Vec<Tried>,
    /// The mean label's cross-validated error (`None` without cross-validation).
    pub constant: Option<Validated>,
    /// No pooling beat the constant by more than its standard error: the head written is
    /// the constant (zero weights, the mean label as the bias), `tried[0]`.
    pub fell_back: bool,
}

/// Fits every pooling of `poolings` on `data`'s maps (`channels` x `side` x `side`).
/// One pooling with a given `strength` is fitted without cross-validation. Otherwise each
/// pooling is cross-validated at that strength, or over [`ridge::default_strengths`] for
/// its width; `rule` picks the pair, which is refitted on every frame. A pick that does not
/// beat the constant answer (the mean label, cross-validated on the same folds) by more
/// than the constant's standard error is not trusted: the head becomes that constant.
pub fn choose(
    data: &ProbeData,
    (channels, side): (usize, usize),
    poolings: &[Pooling],
    output: OutputKind,
    folds: usize,
    strength: Option<f64>,
    rule: Rule,
) -> Result<Chosen, FitError> {
    if let Some(p) = poolings.iter().find(|p| p.grid == 0 || p.grid > side) {
        return Err(FitError::Grid { grid: p.grid, side });
    }
    let mut tried = Vec::with_capacity(poolings.len());
    for &pooling in poolings {
        let pooled = data.pooled(channels, side, pooling.grid, pooling.mirror);
        let (strength, strengths) = match (poolings.len(), strength) {
            (1, Some(s)) => (Some(s), Vec::new()),
            (_, Some(s)) => (None, vec![s]),
            (_, None) => (
                None,
                ridge::default_strengths(channels * pooling.grid * pooling.grid),
            ),
        };
        let probe = fit(&pooled, output, folds, strength, &strengths)?;
        tried.push(Tried { pooling, probe });
    }
    let picked = match rule {
        Rule::Lowest => lowest(&tried),
        Rule::OneStandardError => one_standard_error(&tried),
    };
    let Some((pick, strength)) = picked else {
        return Ok(Chosen {
            tried,
            constant: None,
            fell_back: false,
        });
    };
    let y: Vec<&[f32]> = data.labels.iter().map(|l| l.as_slice()).collect();
    let constant = ridge::cross_validate_constant(
        &y,
        &data.row_folds(folds),
        &data.original,
        row_error(output),
    );
    let picked_error = tried[pick]
        .probe
        .validated
        .iter()
        .find(|v| v.strength == strength)
        .map_or(f64::INFINITY, |v| v.error);
    let fell_back = picked_error >= constant.error - constant.standard_error;
    let chosen = if fell_back {
        constant_answer(data, channels, &constant)
    } else {
        // Refit the chosen pooling at the chosen strength, its table kept.
        let mut chosen = tried.remove(pick);
        let p = chosen.pooling;
        let validated = std::mem::take(&mut chosen.probe.validated);
        chosen.probe = fit(
            &data.pooled(channels, side, p.grid, p.mirror),
            output,
            folds,
            Some(strength),
            &[],
        )?;
        chosen.probe.validated = validated;
        chosen
    };
    tried.sort_by(|a, b| a.error().total_cmp(&b.error()));
    tried.insert(0, chosen);
    Ok(Chosen {
        tried,
        constant: Some(constant),
        fell_back,
    })
}

/// The head that answers the mean label of the frames (not their mirror images) whatever
/// it sees, on globally pooled features.
fn constant_answer(data: &ProbeData, channels: usize, cv: &Validated) -> Tried {
    let rows: Vec<&[f32; 2]> = data
        .labels
        .iter()
        .zip(&data.original)
        .filter_map(|(l, o)| o.then_some(l))
        .collect();
    let n = rows.len().max(1) as f64;
    let bias = (0..2)
        .map(|c| rows.iter().map(|l| l[c] as f64).sum::<f64>() / n)
        .collect();
    Tried {
        pooling: Pooling {
            grid: 1,
            mirror: false,
        },
        probe: Probe {
            validated: vec![*cv],
            strength: f64::INFINITY,
            head: LinearHead {
                weight: vec![vec![0.0; channels]; 2],
                bias,
            },
        },
    }
}

/// The lowest cross-validated error of `tried`: its index and strength.
fn lowest(tried: &[Tried]) -> Option<(usize, f64)> {
    tried
        .iter()
        .enumerate()
        .flat_map(|(i, t)| t.probe.validated.iter().map(move |v| (i, v)))
        .min_by(|a, b| a.1.error.total_cmp(&b.1.error))
        .map(|(i, v)| (i, v.strength))
}

/// The one-standard-error choice over every cross-validated (pooling, strength) of
/// `tried`: its index and strength; `None` when nothing was cross-validated.
fn one_standard_error(tried: &[Tried]) -> Option<(usize, f64)> {
    let all: Vec<(usize, &Validated)> = tried
        .iter()
        .enumerate()
        .flat_map(|(i, t)| t.probe.validated.iter().map(move |v| (i, v)))
        .collect();
    let best = all.iter().min_by(|a, b| a.1.error.total_cmp(&b.1.error))?;
    let limit = best.1.error + best.1.standard_error;
    all.iter()
        .filter(|(_, v)| v.error <= limit)
        .min_by(|(i, v), (j, w)| {
            let (a, b) = (tried[*i].pooling, tried[*j].pooling);
            a.grid
                .cmp(&b.grid)
                .then(w.strength.total_cmp(&v.strength))
                .then(a.mirror.cmp(&b.mirror))
        })
        .map(|(i, v)| (*i, v.strength))
}

/// The backbone of `weights` on ONNX Runtime, its output the final feature map.
pub struct FeatureSession {
    session: Session,
    pre: Preprocessor,
    size: usize,
    channels: usize,
    map: usize,
}

impl FeatureSession {
    /// `contract` gives the input size and normalisation; `threads` ONNX Runtime's
    /// intra-op threads (0: it decides).
    pub fn new(
        weights: &NetWeights,
        contract: &ModelContract,
        threads: usize,
    ) -> Result<Self, FitError> {
        let map = weights.arch().final_map(contract.input_size);
        let proto =
            weights.backbone_model(contract.input_size, contract, env!("CARGO_PKG_VERSION"))?;
        let (_, env) = runtime::environment(None)?;
        let session =
            runtime::session_builder(env, GraphOptimizationLevel::Level3, threads, false)?
                .commit_from_memory(&encode_model(&proto))?;
        Ok(Self {
            session,
            pre: Preprocessor::new(contract),
            size: contract.input_size as usize,
            channels: weights.arch().features(),
            map,
        })
    }

    /// Channels of the final map.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Side of the final map.
    pub fn map_side(&self) -> usize {
        self.map
    }

    /// The final feature map (`[channels, side, side]`, flattened) of one RGB8 image of
    /// any size.
    pub fn features(&mut self, width: u32, height: u32, rgb: &[u8]) -> Result<Vec<f32>, FitError> {
        let input = self.pre.run(width, height, rgb)?;
        let s = self.size;
        let tensor = TensorRef::from_array_view(([1usize, 3, s, s], input))?;
        let outputs = self.session.run(ort::inputs![tensor])?;
        let (_, data) = outputs[0].try_extract_tensor::<f32>()?;
        let (channels, side) = (self.channels, self.map);
        if data.len() != channels * side * side {
            return Err(FitError::MapSize {
                found: data.len(),
                channels,
                side,
            });
        }
        Ok(data.to_vec())
    }
}

/// Cell `i` of `grid` along a side of `s`: rows (or columns) `floor(i s / grid)` up to
/// `floor((i + 1) s / grid)`.
fn cell(i: usize, s: usize, grid: usize) -> std::ops::Range<usize> {
    i * s / grid..(i + 1) * s / grid
}

/// A `[channels, s, s]` map averaged over `grid` x `grid` cells ([`cell`]): `[channels,
/// grid, grid]` flattened, channel by channel (grid 1 is global average pooling; grid `s`
/// the map itself).
pub fn pool_cells(map: &[f32], channels: usize, s: usize, grid: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(channels * grid * grid);
    for c in 0..channels {
        let plane = &map[c * s * s..(c + 1) * s * s];
        for gy in 0..grid {
            for gx in 0..grid {
                let (rows, cols) = (cell(gy, s, grid), cell(gx, s, grid));
                let n = (rows.len() * cols.len()) as f32;
                let sum: f32 = rows
                    .flat_map(|y| plane[y * s..(y + 1) * s][cols.clone()].iter())
                    .sum();
                out.push(sum / n);
            }
        }
    }
    out
}

/// A head fitted on [`pool_cells`]'s features (`[outputs][channels * grid * grid]`) as the
/// same linear map on the whole flattened map (`[outputs][channels * s * s]`): each cell's
/// weight spread over its pixels, divided by their count. Grid 1 stays as it is (the
/// network's own pooled head).
pub fn unpool_head(head: &LinearHead, channels: usize, s: usize, grid: usize) -> LinearHead {
    if grid == 1 {
        return head.clone();
    }
    let weight = head
        .weight
        .iter()
        .map(|w| {
            let mut full = vec![0.0; channels * s * s];
            for c in 0..channels {
                for gy in 0..grid {
                    for gx in 0..grid {
                        let (rows, cols) = (cell(gy, s, grid), cell(gx, s, grid));
                        let v = w[(c * grid + gy) * grid + gx] / (rows.len() * cols.len()) as f64;
                        for y in rows {
                            for x in cols.clone() {
                                full[(c * s + y) * s + x] = v;
                            }
                        }
                    }
                }
            }
            full
        })
        .collect();
    LinearHead {
        weight,
        bias: head.bias.clone(),
    }
}

/// An RGB8 image mirrored left to right, in place.
pub fn mirror_rgb(width: u32, rgb: &mut [u8]) {
    let row = 3 * width as usize;
    if row == 0 {
        return;
    }
    for line in rgb.chunks_exact_mut(row) {
        for x in 0..width as usize / 2 {
            let (a, b) = (3 * x, row - 3 * (x + 1));
            for c in 0..3 {
                line.swap(a + c, b + c);
            }
        }
    }
}

/// Reads every frame (in the order given: time order, for the folds) and runs it, and with
/// `mirror` its mirror image whose label has component `mirrored` negated, through the
/// backbone. `progress(done, total)` after each frame. Unreadable files are skipped with a
/// warning; none readable is an error.
pub fn extract(
    session: &mut FeatureSession,
    frames: &[LabelledFrame],
    mirror: Option<usize>,
    mut progress: impl FnMut(usize, usize),
) -> Result<ProbeData, FitError> {
    let mut data = ProbeData::default();
    for (i, frame) in frames.iter().enumerate() {
        let (w, h, mut rgb) = match crate::dataset::load_rgb(&frame.path) {
            Ok(img) => img,
            Err(e) => {
                data.warnings.push(format!(
                    "{}: skipped, {}",
                    frame.path.display(),
                    crate::dataset::short_reason(&e)
                ));
                continue;
            }
        };
        let label = frame.label.value(w, h);
        data.features.push(session.features(w, h, &rgb)?);
        data.labels.push(label);
        data.frame.push(i);
        data.original.push(true);
        if let Some(c) = mirror {
            mirror_rgb(w, &mut rgb);
            let mut flipped = label;
            flipped[c] = -flipped[c];
            data.features.push(session.features(w, h, &rgb)?);
            data.labels.push(flipped);
            data.frame.push(i);
            data.original.push(false);
        }
        progress(i + 1, frames.len());
    }
    if data.features.is_empty() {
        return Err(FitError::Data {
            path: frames
                .first()
                .map(|f| f.path.display().to_string())
                .unwrap_or_default(),
            reason: format!("none of the {} frames could be read", frames.len()),
        });
    }
    Ok(data)
}

/// The probe's result: each strength's cross-validated error, the one chosen, its head.
#[derive(Debug, Clone)]
pub struct Probe {
    /// Empty when the strength was given, not chosen.
    pub validated: Vec<Validated>,
    pub strength: f64,
    pub head: LinearHead,
}

impl Probe {
    /// Whether the chosen strength is the smallest or largest of those cross-validated (a
    /// wider range might do better). Not `--grid`, the pooling cells.
    pub fn at_strength_edge(&self) -> bool {
        let first = self.validated.first().map(|v| v.strength);
        let last = self.validated.last().map(|v| v.strength);
        self.validated.len() > 1 && (first == Some(self.strength) || last == Some(self.strength))
    }
}

/// Fits the head on every row: with `strength`, or with the strength of `strengths` whose
/// `folds`-fold cross-validation over time blocks of the frames scores best (the error of
/// `output`'s kind: pixels for xy, squared error for speed and steering).
pub fn fit(
    data: &ProbeData,
    output: OutputKind,
    folds: usize,
    strength: Option<f64>,
    strengths: &[f64],
) -> Result<Probe, FitError> {
    let x: Vec<&[f32]> = data.features.iter().map(Vec::as_slice).collect();
    let y: Vec<&[f32]> = data.labels.iter().map(|l| l.as_slice()).collect();
    let (validated, strength) = match strength {
        Some(s) => (Vec::new(), s),
        None => {
            let row_folds = data.row_folds(folds);
            let v = ridge::cross_validate(
                &x,
                &y,
                &row_folds,
                &data.original,
                strengths,
                row_error(output),
            )?;
            let best = v
                .iter()
                .min_by(|a, b| a.error.total_cmp(&b.error))
                .map(|b| b.strength)
                .ok_or(ridge::RidgeError::NoStrengths)?;
            (v, best)
        }
    };
    let head = ridge::fit(&x, &y, strength)?;
    Ok(Probe {
        validated,
        strength,
        head,
    })
}

/// `weights`' backbone with the probe's head.
pub fn with_head(weights: &NetWeights, head: &LinearHead) -> NetWeights {
    let (w, b) = head.to_f32();
    weights.with_head(b.len(), w, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirroring_swaps_pixels_and_twice_is_the_original() {
        // 3x1 image: pixels (1,2,3) (4,5,6) (7,8,9) -> (7,8,9) (4,5,6) (1,2,3).
        let mut rgb: Vec<u8> = (1..=9).collect();
        mirror_rgb(3, &mut rgb);
        assert_eq!(rgb, vec![7, 8, 9, 4, 5, 6, 1, 2, 3]);
        mirror_rgb(3, &mut rgb);
        assert_eq!(rgb, (1..=9).collect::<Vec<u8>>());
        // Two rows of two: each row on its own.
        let mut rgb: Vec<u8> = (0..12).collect();
        mirror_rgb(2, &mut rgb);
        assert_eq!(rgb, vec![3, 4, 5, 0, 1, 2, 9, 10, 11, 6, 7, 8]);
    }

    #[test]
    fn cells_pool_and_the_unpooled_head_gives_the_same_output() {
        // One channel, 3x3 map 1..9, grid 2: cells rows/cols {0}, {1,2}.
        let map: Vec<f32> = (1..=9).map(|v| v as f32).collect();
        let pooled = pool_cells(&map, 1, 3, 2);
        // (1), (2+3)/2, (4+7)/2, (5+6+8+9)/4
        assert_eq!(pooled, vec![1.0, 2.5, 5.5, 7.0]);
        assert_eq!(pool_cells(&map, 1, 3, 1), vec![5.0]);
        assert_eq!(pool_cells(&map, 1, 3, 3), map);
        let head = LinearHead {
            weight: vec![vec![1.0, -2.0, 0.5, 3.0]],
            bias: vec![0.25],
        };
        let pooled_out = head.predict(&pooled)[0];
        let full = unpool_head(&head, 1, 3, 2);
        assert_eq!(full.weight[0].len(), 9);
        let full_out = full.predict(&map)[0];
        assert!(
            (pooled_out - full_out).abs() < 1e-9,
            "{pooled_out} {full_out}"
        );
        // 1 - 5 + 2.75 + 21 + 0.25
        assert!((pooled_out - 20.0).abs() < 1e-9);
    }

    #[test]
    fn pooled_data_keeps_or_drops_the_mirrored_copies() {
        // Two frames of a 1-channel 2x2 map, each with its mirrored copy.
        let data = ProbeData {
            features: vec![
                vec![1.0, 2.0, 3.0, 4.0],
                vec![2.0, 1.0, 4.0, 3.0],
                vec![1.0, 2.0, 3.0, 4.0],
                vec![2.0, 1.0, 4.0, 3.0],
            ],
            labels: vec![[0.5, 0.0], [-0.5, 0.0], [0.1, 0.2], [-0.1, 0.2]],
            frame: vec![0, 0, 1, 1],
            original: vec![true, false, true, false],
            warnings: Vec::new(),
        };
        let plain = data.pooled(1, 2, 1, false);
        assert_eq!(plain.features, vec![vec![2.5], vec![2.5]]);
        assert_eq!(plain.labels, vec![[0.5, 0.0], [0.1, 0.2]]);
        assert_eq!(plain.frame, vec![0, 1]);
        let both = data.pooled(1, 2, 2, true);
        assert_eq!(both.features.len(), 4);
        assert_eq!(both.features[1], vec![2.0, 1.0, 4.0, 3.0]);
        assert_eq!(both.original, data.original);
    }

    fn tried(grid: usize, mirror: bool, errors: &[(f64, f64, f64)]) -> Tried {
        Tried {
            pooling: Pooling { grid, mirror },
            probe: Probe {
                validated: errors
                    .iter()
                    .map(|&(strength, error, standard_error)| Validated {
                        strength,
                        error,
                        standard_error,
                    })
                    .collect(),
                strength: 0.0,
                head: LinearHead {
                    weight: vec![],
                    bias: vec![],
                },
            },
        }
    }

    #[test]
    fn the_one_standard_error_rule_takes_the_simplest_within_reach() {
        // Best: grid 3 at 10 (error 50, se 6): within 56 are grid 1 at 100 (55) and at 10
        // (56): grid 1 at the stronger ridge wins.
        let t = [
            tried(3, true, &[(10.0, 50.0, 6.0), (100.0, 58.0, 1.0)]),
            tried(
                1,
                false,
                &[(10.0, 56.0, 2.0), (100.0, 55.0, 2.0), (1000.0, 57.0, 1.0)],
            ),
        ];
        assert_eq!(one_standard_error(&t), Some((1, 100.0)));
        // A clear winner (se 1): grid 3 stays.
        let t = [
            tried(3, true, &[(10.0, 38.0, 1.0)]),
            tried(1, false, &[(100.0, 45.0, 1.0)]),
        ];
        assert_eq!(one_standard_error(&t), Some((0, 10.0)));
        // Level grid and strength: without mirrored copies first.
        let t = [
            tried(2, true, &[(10.0, 40.0, 1.0)]),
            tried(2, false, &[(10.0, 40.5, 1.0)]),
        ];
        assert_eq!(one_standard_error(&t), Some((1, 10.0)));
        assert_eq!(one_standard_error(&[tried(1, false, &[])]), None);
    }

    #[test]
    fn strength_edge_is_seen() {
        let head = LinearHead {
            weight: vec![],
            bias: vec![],
        };
        let v = |s| Validated {
            strength: s,
            error: 0.0,
            standard_error: 0.0,
        };
        let probe = Probe {
            validated: vec![v(1.0), v(10.0), v(100.0)],
            strength: 10.0,
            head: head.clone(),
        };
        assert!(!probe.at_strength_edge());
        let probe = Probe {
            strength: 100.0,
            ..probe
        };
        assert!(probe.at_strength_edge());
    }
}
