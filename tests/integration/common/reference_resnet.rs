//! A plain float64 ResNet-18 training step (forward with batch-statistics BatchNorm, MSE
//! loss, backward), written from the definitions with nested loops and nothing shared with
//! burn: the reference the backends' float32 gradients are checked against.
//!
//! A ReLU network's gradient jumps where a ReLU input crosses zero. Where the reference
//! has an input within float32 rounding of zero, a float32 backend may take the other
//! branch and is still right, so the caller can hand in the backend's own branch decisions
//! ([`Gates`]) and have the reference differentiate through those (see
//! `tests/integration/train_gradients.rs`).
#![allow(dead_code)]

use std::collections::BTreeMap;

use jetpilot::policy::onnx::Resnet18Weights;

/// BatchNorm epsilon, as torchvision and `jetpilot::train::resnet::BN_EPSILON`.
const EPS: f64 = 1e-5;

/// An NCHW tensor.
#[derive(Clone, Debug)]
pub struct T4 {
    pub dims: [usize; 4],
    pub data: Vec<f64>,
}

impl T4 {
    pub fn zeros(dims: [usize; 4]) -> Self {
        Self {
            dims,
            data: vec![0.0; dims.iter().product()],
        }
    }
    fn at(&self, b: usize, c: usize, y: usize, x: usize) -> usize {
        let [_, cc, h, w] = self.dims;
        ((b * cc + c) * h + y) * w + x
    }
}

/// The branch each ReLU input takes (`true`: passes), one vector per ReLU in forward
/// order: the stem, then per block the inner ReLU and the output ReLU.
pub type Gates = Vec<Vec<bool>>;

/// What one step computed.
pub struct Step {
    pub loss: f64,
    /// d loss / d parameter, by torchvision name (BatchNorm running statistics excluded).
    pub grads: BTreeMap<String, Vec<f64>>,
    /// Each ReLU's input, in the order of [`Gates`].
    pub relu_inputs: Vec<Vec<f64>>,
    /// The smallest gap between the largest and the second-largest value of a max-pool
    /// window whose largest value is positive (where the gradient goes there).
    pub maxpool_gap: f64,
}

struct Params<'a>(&'a Resnet18Weights);

impl Params<'_> {
    fn get(&self, name: &str) -> Vec<f64> {
        self.0.tensors[name].1.iter().map(|&v| v as f64).collect()
    }
}

fn conv_out(n: usize, k: usize, stride: usize, pad: usize) -> usize {
    (n + 2 * pad - k) / stride + 1
}

/// The outputs `o` of a convolution axis whose input `o * stride + k - pad` lies in
/// `0..n_in`.
fn valid(n_out: usize, k: usize, stride: usize, pad: usize, n_in: usize) -> std::ops::Range<usize> {
    let first = pad.saturating_sub(k).div_ceil(stride);
    let end = (n_in + pad).saturating_sub(k).div_ceil(stride).min(n_out);
    first..end.max(first)
}

/// Cross-correlation, `w` `[O,C,K,K]`, no bias.
fn conv(x: &T4, w: &[f64], o: usize, k: usize, stride: usize, pad: usize) -> T4 {
    let [n, c, h, wd] = x.dims;
    let (oh, ow) = (conv_out(h, k, stride, pad), conv_out(wd, k, stride, pad));
    let mut out = T4::zeros([n, o, oh, ow]);
    for b in 0..n {
        for oc in 0..o {
            let plane = &mut out.data[(b * o + oc) * oh * ow..][..oh * ow];
            for ic in 0..c {
                let src = &x.data[(b * c + ic) * h * wd..][..h * wd];
                for ky in 0..k {
                    for kx in 0..k {
                        let wv = w[((oc * c + ic) * k + ky) * k + kx];
                        let xs = valid(ow, kx, stride, pad, wd);
                        for oy in valid(oh, ky, stride, pad, h) {
                            let row = &src[(oy * stride + ky - pad) * wd..][..wd];
                            let dst = &mut plane[oy * ow..][..ow];
                            for ox in xs.clone() {
                                dst[ox] += wv * row[ox * stride + kx - pad];
                            }
                        }
                    }
                }
            }
        }
    }
    out
}

/// `(dx, dw)` of [`conv`] given `dy`.
fn conv_back(x: &T4, w: &[f64], dy: &T4, k: usize, stride: usize, pad: usize) -> (T4, Vec<f64>) {
    let [n, c, h, wd] = x.dims;
    let [_, o, oh, ow] = dy.dims;
    let mut dx = T4::zeros(x.dims);
    let mut dw = vec![0.0; w.len()];
    for b in 0..n {
        for oc in 0..o {
            let g_plane = &dy.data[(b * o + oc) * oh * ow..][..oh * ow];
            for ic in 0..c {
                let src = &x.data[(b * c + ic) * h * wd..][..h * wd];
                let d_src = &mut dx.data[(b * c + ic) * h * wd..][..h * wd];
                for ky in 0..k {
                    for kx in 0..k {
                        let wi = ((oc * c + ic) * k + ky) * k + kx;
                        let wv = w[wi];
                        let xs = valid(ow, kx, stride, pad, wd);
                        let mut acc = 0.0;
                        for oy in valid(oh, ky, stride, pad, h) {
                            let r = (oy * stride + ky - pad) * wd;
                            let g_row = &g_plane[oy * ow..][..ow];
                            for ox in xs.clone() {
                                let xi = r + ox * stride + kx - pad;
                                acc += g_row[ox] * src[xi];
                                d_src[xi] += wv * g_row[ox];
                            }
                        }
                        dw[wi] += acc;
                    }
                }
            }
        }
    }
    (dx, dw)
}

/// BatchNorm on batch statistics (biased variance), as in training.
struct Bn {
    xhat: T4,
    inv_std: Vec<f64>,
    gamma: Vec<f64>,
}

fn bn(x: &T4, gamma: Vec<f64>, beta: &[f64]) -> (T4, Bn) {
    let [n, c, h, w] = x.dims;
    let m = (n * h * w) as f64;
    let mut xhat = x.clone();
    let mut y = x.clone();
    let mut inv_std = vec![0.0; c];
    for ch in 0..c {
        let idx = |i: usize| {
            let (b, s) = (i / (h * w), i % (h * w));
            (b * c + ch) * h * w + s
        };
        let mean = (0..n * h * w).map(|i| x.data[idx(i)]).sum::<f64>() / m;
        let var = (0..n * h * w)
            .map(|i| (x.data[idx(i)] - mean).powi(2))
            .sum::<f64>()
            / m;
        inv_std[ch] = 1.0 / (var + EPS).sqrt();
        for i in 0..n * h * w {
            let j = idx(i);
            xhat.data[j] = (x.data[j] - mean) * inv_std[ch];
            y.data[j] = gamma[ch] * xhat.data[j] + beta[ch];
        }
    }
    (
        y,
        Bn {
            xhat,
            inv_std,
            gamma,
        },
    )
}

/// `(dx, dgamma, dbeta)`.
fn bn_back(cache: &Bn, dy: &T4) -> (T4, Vec<f64>, Vec<f64>) {
    let [n, c, h, w] = dy.dims;
    let m = (n * h * w) as f64;
    let mut dx = T4::zeros(dy.dims);
    let (mut dgamma, mut dbeta) = (vec![0.0; c], vec![0.0; c]);
    for ch in 0..c {
        let idx = |i: usize| {
            let (b, s) = (i / (h * w), i % (h * w));
            (b * c + ch) * h * w + s
        };
        let (mut sum_dxhat, mut sum_dxhat_xhat) = (0.0, 0.0);
        for i in 0..n * h * w {
            let j = idx(i);
            dbeta[ch] += dy.data[j];
            dgamma[ch] += dy.data[j] * cache.xhat.data[j];
            let dxhat = dy.data[j] * cache.gamma[ch];
            sum_dxhat += dxhat;
            sum_dxhat_xhat += dxhat * cache.xhat.data[j];
        }
        for i in 0..n * h * w {
            let j = idx(i);
            let dxhat = dy.data[j] * cache.gamma[ch];
            dx.data[j] = cache.inv_std[ch] / m
                * (m * dxhat - sum_dxhat - cache.xhat.data[j] * sum_dxhat_xhat);
        }
    }
    (dx, dgamma, dbeta)
}

/// ReLU through the given branch decisions (or its own: `v > 0`).
fn relu(x: &T4, gate: Option<&Vec<bool>>, inputs: &mut Vec<Vec<f64>>) -> (T4, Vec<bool>) {
    let mask: Vec<bool> = match gate {
        Some(g) => g.clone(),
        None => x.data.iter().map(|&v| v > 0.0).collect(),
    };
    inputs.push(x.data.clone());
    let mut y = x.clone();
    for (v, &on) in y.data.iter_mut().zip(&mask) {
        if !on {
            *v = 0.0;
        }
    }
    (y, mask)
}

fn relu_back(dy: &T4, mask: &[bool]) -> T4 {
    let mut dx = dy.clone();
    for (v, &on) in dx.data.iter_mut().zip(mask) {
        if !on {
            *v = 0.0;
        }
    }
    dx
}

/// Max pool 3x3, stride 2, padding 1: output and, per output, the input index it took.
fn maxpool(x: &T4, gap: &mut f64) -> (T4, Vec<usize>) {
    let [n, c, h, w] = x.dims;
    let (oh, ow) = (conv_out(h, 3, 2, 1), conv_out(w, 3, 2, 1));
    let mut out = T4::zeros([n, c, oh, ow]);
    let mut arg = vec![0; out.data.len()];
    for b in 0..n {
        for ch in 0..c {
            for oy in 0..oh {
                for ox in 0..ow {
                    let (mut best, mut second, mut at) = (f64::NEG_INFINITY, f64::NEG_INFINITY, 0);
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let (Some(iy), Some(ix)) = (
                                (oy * 2 + ky).checked_sub(1).filter(|&v| v < h),
                                (ox * 2 + kx).checked_sub(1).filter(|&v| v < w),
                            ) else {
                                continue;
                            };
                            let i = x.at(b, ch, iy, ix);
                            if x.data[i] > best {
                                second = best;
                                best = x.data[i];
                                at = i;
                            } else if x.data[i] > second {
                                second = x.data[i];
                            }
                        }
                    }
                    let o = out.at(b, ch, oy, ox);
                    out.data[o] = best;
                    arg[o] = at;
                    if best > 0.0 {
                        *gap = gap.min(best - second);
                    }
                }
            }
        }
    }
    (out, arg)
}

struct BlockTape {
    name: String,
    stride: usize,
    x: T4,
    bn1: Bn,
    mask1: Vec<bool>,
    h1: T4,
    bn2: Bn,
    down: Option<Bn>,
    mask_out: Vec<bool>,
}

/// One loss evaluation and its gradient for `x` `[B,3,S,S]` and targets `y` `[B,N]`.
pub fn training_step(
    w: &Resnet18Weights,
    x: &[f32],
    dims: [usize; 4],
    y: &[f32],
    gates: Option<&Gates>,
) -> Step {
    let p = Params(w);
    let mut inputs = Vec::new();
    let mut gap = f64::INFINITY;
    let mut gate_at = 0;
    let mut next_gate = || {
        gate_at += 1;
        gates.map(|g| &g[gate_at - 1])
    };
    let x0 = T4 {
        dims,
        data: x.iter().map(|&v| v as f64).collect(),
    };
    // Stem.
    let c1 = conv(&x0, &p.get("conv1.weight"), 64, 7, 2, 3);
    let (b1, stem_bn) = bn(&c1, p.get("bn1.weight"), &p.get("bn1.bias"));
    let (r1, stem_mask) = relu(&b1, next_gate(), &mut inputs);
    let (mut h, pool_arg) = maxpool(&r1, &mut gap);
    // Blocks.
    let mut tapes = Vec::new();
    for (l, ch) in [64usize, 128, 256, 512].into_iter().enumerate() {
        for blk in 0..2 {
            let name = format!("layer{}.{blk}", l + 1);
            let stride = if l > 0 && blk == 0 { 2 } else { 1 };
            let c_in = h.dims[1];
            let down = (c_in != ch || stride != 1).then(|| {
                let d = conv(
                    &h,
                    &p.get(&format!("{name}.downsample.0.weight")),
                    ch,
                    1,
                    stride,
                    0,
                );
                bn(
                    &d,
                    p.get(&format!("{name}.downsample.1.weight")),
                    &p.get(&format!("{name}.downsample.1.bias")),
                )
            });
            let a = conv(
                &h,
                &p.get(&format!("{name}.conv1.weight")),
                ch,
                3,
                stride,
                1,
            );
            let (a, bn1c) = bn(
                &a,
                p.get(&format!("{name}.bn1.weight")),
                &p.get(&format!("{name}.bn1.bias")),
            );
            let (h1, mask1) = relu(&a, next_gate(), &mut inputs);
            let b = conv(&h1, &p.get(&format!("{name}.conv2.weight")), ch, 3, 1, 1);
            let (mut b, bn2c) = bn(
                &b,
                p.get(&format!("{name}.bn2.weight")),
                &p.get(&format!("{name}.bn2.bias")),
            );
            let identity = down.as_ref().map(|(d, _)| &d.data).unwrap_or(&h.data);
            for (v, i) in b.data.iter_mut().zip(identity) {
                *v += i;
            }
            let (out, mask_out) = relu(&b, next_gate(), &mut inputs);
            tapes.push(BlockTape {
                name,
                stride,
                x: h,
                bn1: bn1c,
                mask1,
                h1,
                bn2: bn2c,
                down: down.map(|(_, cache)| cache),
                mask_out,
            });
            h = out;
        }
    }
    // Head: global average pool, fc, MSE.
    let [nb, c, hh, ww] = h.dims;
    let hw = (hh * ww) as f64;
    let feat: Vec<f64> = (0..nb * c)
        .map(|i| h.data[i * hh * ww..(i + 1) * hh * ww].iter().sum::<f64>() / hw)
        .collect();
    let fc_w = p.get("fc.weight"); // [N,512]
    let fc_b = p.get("fc.bias");
    let nout = fc_b.len();
    let mut dout = vec![0.0; nb * nout];
    let mut loss = 0.0;
    for b in 0..nb {
        for j in 0..nout {
            let o = fc_b[j]
                + (0..c)
                    .map(|i| feat[b * c + i] * fc_w[j * c + i])
                    .sum::<f64>();
            let e = o - y[b * nout + j] as f64;
            loss += e * e;
            dout[b * nout + j] = 2.0 * e / (nb * nout) as f64;
        }
    }
    loss /= (nb * nout) as f64;

    // Backward.
    let mut grads = BTreeMap::new();
    let mut d_fc_w = vec![0.0; fc_w.len()];
    let mut d_fc_b = vec![0.0; nout];
    let mut dh = T4::zeros(h.dims);
    for b in 0..nb {
        for j in 0..nout {
            let g = dout[b * nout + j];
            d_fc_b[j] += g;
            for i in 0..c {
                d_fc_w[j * c + i] += g * feat[b * c + i];
                for s in 0..hh * ww {
                    dh.data[(b * c + i) * hh * ww + s] += g * fc_w[j * c + i] / hw;
                }
            }
        }
    }
    grads.insert("fc.weight".into(), d_fc_w);
    grads.insert("fc.bias".into(), d_fc_b);
    for t in tapes.iter().rev() {
        let n = &t.name;
        let d_sum = relu_back(&dh, &t.mask_out);
        // Residual branch.
        let (d_b, dg, db) = bn_back(&t.bn2, &d_sum);
        grads.insert(format!("{n}.bn2.weight"), dg);
        grads.insert(format!("{n}.bn2.bias"), db);
        let (d_h1, dw) = conv_back(&t.h1, &p.get(&format!("{n}.conv2.weight")), &d_b, 3, 1, 1);
        grads.insert(format!("{n}.conv2.weight"), dw);
        let d_a = relu_back(&d_h1, &t.mask1);
        let (d_a, dg, db) = bn_back(&t.bn1, &d_a);
        grads.insert(format!("{n}.bn1.weight"), dg);
        grads.insert(format!("{n}.bn1.bias"), db);
        let (mut dx, dw) = conv_back(
            &t.x,
            &p.get(&format!("{n}.conv1.weight")),
            &d_a,
            3,
            t.stride,
            1,
        );
        grads.insert(format!("{n}.conv1.weight"), dw);
        // Identity path.
        match &t.down {
            Some(cache) => {
                let (d_d, dg, db) = bn_back(cache, &d_sum);
                grads.insert(format!("{n}.downsample.1.weight"), dg);
                grads.insert(format!("{n}.downsample.1.bias"), db);
                let (dxd, dw) = conv_back(
                    &t.x,
                    &p.get(&format!("{n}.downsample.0.weight")),
                    &d_d,
                    1,
                    t.stride,
                    0,
                );
                grads.insert(format!("{n}.downsample.0.weight"), dw);
                for (a, b) in dx.data.iter_mut().zip(&dxd.data) {
                    *a += b;
                }
            }
            None => {
                for (a, b) in dx.data.iter_mut().zip(&d_sum.data) {
                    *a += b;
                }
            }
        }
        dh = dx;
    }
    let mut d_r1 = T4::zeros(r1.dims);
    for (o, &i) in pool_arg.iter().enumerate() {
        d_r1.data[i] += dh.data[o];
    }
    let d_b1 = relu_back(&d_r1, &stem_mask);
    let (d_c1, dg, db) = bn_back(&stem_bn, &d_b1);
    grads.insert("bn1.weight".into(), dg);
    grads.insert("bn1.bias".into(), db);
    let (_, dw) = conv_back(&x0, &p.get("conv1.weight"), &d_c1, 7, 2, 3);
    grads.insert("conv1.weight".into(), dw);
    Step {
        loss,
        grads,
        relu_inputs: inputs,
        maxpool_gap: gap,
    }
}
