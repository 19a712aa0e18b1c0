//! Normalisations of (N, C, H, W) tensors, each with an optional per-channel affine (weight, bias).
//!
//! | op | statistics | forward | backward (grads to) |
//! |---|---|---|---|
//! | instance norm | each (n, c) plane over (h, w) | `instance_norm_fwd` | `instance_norm_bwd` (x, weight, bias) |
//! | batch norm, training | each channel over (n, h, w); running stats updated (unbiased var) | `batch_norm_fwd` | `batch_norm_bwd` (x, weight, bias) |
//! | batch norm, eval | the running stats | `batch_norm_fwd` | `batch_norm_bwd` (affine only: x, weight, bias) |
//!
//! Both run one core on a (N', C', L) view in which channel c' is normalised over (n', l): batch norm
//! views its input as (N, C, H·W), instance norm as (1, N·C, H·W), so every (n, c) plane is its own
//! channel there. Per-channel sums accumulate in f64 within one thread, so results are deterministic.

use crate::tensor::{check_nonempty, check_same_shape, fixed, par_filled_in};
use crate::{Error, Float, Result};
use ndarray::{Array1, Array2, Array3, Array4, ArrayView1, ArrayView3, ArrayViewD, Axis, Ix1, Ix2, Ix4, Zip};
use rayon::prelude::*;
use std::mem::MaybeUninit;

use super::lanes::{blocked_sum, multiversion};

/// Numeric settings of `batch_norm_fwd` (torch's `training`, `momentum`, `eps`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchNormCfg {
    /// Batch statistics (and running-stat update) when true; running statistics when false.
    pub training: bool,
    /// new_running = (1 − momentum) · running + momentum · batch_statistic.
    pub momentum: f64,
    /// Added to the variance under the square root.
    pub eps: f64,
}

impl BatchNormCfg {
    /// Validates `eps` (finite, >= 0) and `momentum` (finite).
    pub fn new(training: bool, momentum: f64, eps: f64) -> Result<Self> {
        check_eps("batch_norm", eps)?;
        if !momentum.is_finite() {
            return Err(Error::arg("batch_norm", format!("momentum must be finite, got {momentum}")));
        }
        Ok(BatchNormCfg { training, momentum, eps })
    }
}

fn check_eps(op: &'static str, eps: f64) -> Result<()> {
    if !(eps.is_finite() && eps >= 0.0) {
        return Err(Error::arg(op, format!("eps must be finite and >= 0, got {eps}")));
    }
    Ok(())
}

/// Output of `instance_norm_fwd`: y and the per-(n, c) statistics its backward needs.
#[derive(Debug)]
pub struct InstanceNormOut<F> {
    pub y: Array4<F>,
    /// (N, C) mean of each plane.
    pub mean: Array2<F>,
    /// (N, C) 1 / sqrt(biased variance + eps) of each plane.
    pub invstd: Array2<F>,
}

/// Output of `batch_norm_fwd`: y, the per-channel statistics used (batch or running), and the
/// updated running statistics (training with running stats given; the inputs are never mutated).
#[derive(Debug)]
pub struct BatchNormOut<F> {
    pub y: Array4<F>,
    /// (C,) mean used for normalising.
    pub mean: Array1<F>,
    /// (C,) 1 / sqrt(variance used + eps).
    pub invstd: Array1<F>,
    pub running_mean: Option<Array1<F>>,
    pub running_var: Option<Array1<F>>,
}

/// Grads of a normalisation w.r.t. its input and its per-channel affine parameters. `weight` and
/// `bias` are what those grads would be (Σ g·x̂ and Σ g per channel) even when the op had none.
#[derive(Debug)]
pub struct NormGrads<F> {
    pub x: Array4<F>,
    pub weight: Array1<F>,
    pub bias: Array1<F>,
}

fn to_f64<F: Float>(v: F) -> f64 {
    v.to_f64().unwrap_or(f64::NAN)
}

/// The (N, C, H, W) input as a 4-D view, non-empty.
fn input4<'a, F: Float>(op: &'static str, x: ArrayViewD<'a, F>) -> Result<ndarray::ArrayView4<'a, F>> {
    let x = fixed::<_, Ix4>(op, "input", x)?;
    check_nonempty(op, &[("input", x.shape())])?;
    Ok(x)
}

/// An optional per-channel parameter of shape (C,).
fn per_channel<'a, F: Float>(op: &'static str, name: &'static str, p: Option<ArrayViewD<'a, F>>, x_shape: &[usize]) -> Result<Option<ArrayView1<'a, F>>> {
    p.map(|p| {
        if p.shape() != [x_shape[1]] {
            return Err(Error::shape(op, format!("{name} must have shape [C] for C = input.shape[1]"), &[("input", x_shape), (name, p.shape())]));
        }
        fixed::<_, Ix1>(op, name, p)
    })
    .transpose()
}

/// A saved statistic of the shape the forward produced.
fn saved<'a, F: Float, D: ndarray::Dimension>(op: &'static str, name: &'static str, s: ArrayViewD<'a, F>, expected: &[usize], x_shape: &[usize]) -> Result<ndarray::ArrayView<'a, F, D>> {
    if s.shape() != expected {
        return Err(Error::shape(op, format!("{name} must have shape {expected:?}"), &[("input", x_shape), (name, s.shape())]));
    }
    fixed::<_, D>(op, name, s)
}

multiversion! {
    /// out = Σ (x_i − shift) over a run (`square` false) or Σ (x_i − shift)² (`square` true).
    fn deviation_sum<F: Float>(x: &[F], shift: F, square: bool, out: &mut f64) {
        *out = if square {
            blocked_sum([x], |[x]| (x - shift) * (x - shift))
        } else {
            blocked_sum([x], |[x]| x - shift)
        };
    }
}

multiversion! {
    /// out = (Σ g_i, Σ g_i·(x_i − shift)) over a run.
    fn gradient_sums<F: Float>(g: &[F], x: &[F], shift: F, out: &mut (f64, f64)) {
        *out = (blocked_sum([g], |[g]| g), blocked_sum([g, x], |[g, x]| g * (x - shift)));
    }
}

/// Row n of channel c of a standard-layout (N, C, L) view, as a slice.
fn row<'a, F>(x: &ArrayView3<'a, F>, n: usize, c: usize) -> &'a [F] {
    let l = x.dim().2;
    // element (n, c, i) of a standard (N, C, L) layout sits at (n·C + c)·L + i
    let start = (n * x.dim().1 + c) * l;
    &x.to_slice().expect("standard layout")[start..start + l]
}

/// Mean and biased variance of every channel c of a standard-layout (N, C, L) view over (n, l).
fn moments<F: Float>(x: ArrayView3<F>) -> (Array1<F>, Array1<F>) {
    let (rows, m) = (x.dim().0, (x.dim().0 * x.dim().2) as f64);
    let mv: Vec<(F, F)> = (0..x.dim().1)
        .into_par_iter()
        .map(|c| {
            let sum = |shift: F, square: bool| {
                (0..rows).map(|n| {
                    let mut s = 0.0;
                    deviation_sum(row(&x, n, c), shift, square, &mut s);
                    s
                }).sum::<f64>()
            };
            // mean = Σx / M, var = Σ(x − mean)² / M (two passes)
            let mean = F::c(sum(F::zero(), false) / m);
            (mean, F::c(sum(mean, true) / m))
        })
        .collect();
    let (mean, var): (Vec<F>, Vec<F>) = mv.into_iter().unzip();
    (Array1::from_vec(mean), Array1::from_vec(var))
}

/// A (N, C, L) array whose every lane (n, c) is written by `fill(n, c, lane)`, lanes in parallel.
fn map_lanes<F: Float>(op: &'static str, dim: (usize, usize, usize), fill: impl Fn(usize, usize, &mut [MaybeUninit<F>]) + Sync) -> Result<Array3<F>> {
    let (c, l) = (dim.1, dim.2);
    // the task starting at flat index s is lane s / L, i.e. (n, c) = (s / L / C, s / L mod C)
    let y = par_filled_in(op, &[dim.0, c, l], l, |s, lane| fill(s / l / c, s / l % c, lane))?;
    Ok(y.into_dimensionality().expect("rank 3"))
}

/// y[n,c,l] = (x[n,c,l] − mean[c]) · invstd[c] · w[c] + b[c] on a standard-layout (N, C, L) view, parallel over (n, c) lanes.
fn normalize<F: Float>(op: &'static str, x: ArrayView3<F>, mean: &Array1<F>, invstd: &Array1<F>, w: Option<&Array1<F>>, b: Option<&Array1<F>>) -> Result<Array3<F>> {
    map_lanes(op, x.dim(), |n, c, yl| {
        let scale = invstd[c] * w.map_or(F::one(), |w| w[c]);
        let shift = b.map_or(F::zero(), |b| b[c]);
        yl.iter_mut().zip(row(&x, n, c)).for_each(|(y, &x)| { y.write((x - mean[c]) * scale + shift); });
    })
}

/// Backward of `normalize` on a (N, C, L) view; `batch_stats` says whether mean and invstd were
/// computed from x (so they carry gradient) or were constants.
fn normalize_bwd<F: Float>(op: &'static str, x: ArrayView3<F>, g: ArrayView3<F>, mean: &Array1<F>, invstd: &Array1<F>, w: Option<&Array1<F>>, batch_stats: bool) -> Result<(Array3<F>, Array1<F>, Array1<F>)> {
    // Per channel: db = Σ g, dw = Σ g·x̂ = invstd·Σ g·(x − mean).
    let sums: Vec<(F, F)> = (0..x.dim().1)
        .into_par_iter()
        .map(|c| {
            let (mut db, mut dw) = (0.0f64, 0.0f64);
            for n in 0..x.dim().0 {
                let mut s = (0.0, 0.0);
                gradient_sums(row(&g, n, c), row(&x, n, c), mean[c], &mut s);
                db += s.0;
                dw += s.1;
            }
            (F::c(dw * to_f64(invstd[c])), F::c(db))
        })
        .collect();
    let (dw, db): (Vec<F>, Vec<F>) = sums.into_iter().unzip();
    let (dw, db) = (Array1::from_vec(dw), Array1::from_vec(db));
    let count = F::c((x.dim().0 * x.dim().2) as f64);
    let dx = map_lanes(op, x.dim(), |n, c, dxl| {
        let scale = invstd[c] * w.map_or(F::one(), |w| w[c]);
        let (xl, gl) = (row(&x, n, c), row(&g, n, c));
        if batch_stats {
            // dx = w·invstd·(g − mean(g) − x̂·mean(g·x̂)), means over the M = N·L values of channel c
            let (gm, gxm) = (db[c] / count, dw[c] / count);
            dxl.iter_mut().zip(xl).zip(gl).for_each(|((dx, &x), &g)| { dx.write(scale * (g - gm - (x - mean[c]) * invstd[c] * gxm)); });
        } else {
            // dx = w·invstd·g (statistics are constants)
            dxl.iter_mut().zip(gl).for_each(|(dx, &g)| { dx.write(scale * g); });
        }
    })?;
    Ok((dx, dw, db))
}

/// The (N·C,) tiling of a per-channel parameter, for the (1, N·C, L) instance-norm view.
fn tile<F: Float>(p: ArrayView1<F>, n: usize) -> Array1<F> {
    Array1::from_iter((0..n).flat_map(|_| p.iter().copied()))
}

/// Instance normalisation: each (n, c) plane minus its mean, over its standard deviation, then the affine.
///
/// # Shapes
/// x: (N, C, H, W) with H·W > 1; weight, bias: optional (C,). Returns y (N, C, H, W), mean and invstd (N, C).
///
/// # Gradient
/// See `instance_norm_bwd`.
///
/// Torch: `F.instance_norm(x, None, None, weight, bias, use_input_stats=True, momentum=0.1, eps=eps)`.
pub fn instance_norm_fwd<F: Float>(x: ArrayViewD<F>, weight: Option<ArrayViewD<F>>, bias: Option<ArrayViewD<F>>, eps: f64) -> Result<InstanceNormOut<F>> {
    let op = "instance_norm";
    check_eps(op, eps)?;
    let x = input4(op, x)?;
    let (w, b) = (per_channel(op, "weight", weight, x.shape())?, per_channel(op, "bias", bias, x.shape())?);
    let (n, c, h, wd) = x.dim();
    if h * wd <= 1 {
        return Err(Error::shape(op, "Expected more than 1 spatial element when training", &[("input", x.shape())]));
    }
    let x = x.as_standard_layout();
    // (N, C, H, W) -> (1, N·C, H·W): plane (n, c) is channel n·C + c
    let xv = x.view().into_shape_with_order((1, n * c, h * wd)).map_err(|_| Error::shape(op, "input not reshapeable", &[("input", x.shape())]))?;
    let (mean, var) = moments(xv);
    let invstd = var.mapv(|v| F::one() / (v + F::c(eps)).sqrt());
    let (wt, bt) = (w.map(|w| tile(w, n)), b.map(|b| tile(b, n)));
    let y = normalize(op, xv, &mean, &invstd, wt.as_ref(), bt.as_ref())?;
    let shaped = |a: Array1<F>| a.into_shape_with_order((n, c)).map_err(|_| Error::shape(op, "statistics not reshapeable", &[("input", x.shape())]));
    Ok(InstanceNormOut {
        y: y.into_shape_with_order((n, c, h, wd)).map_err(|_| Error::shape(op, "output not reshapeable", &[("input", x.shape())]))?,
        mean: shaped(mean)?,
        invstd: shaped(invstd)?,
    })
}

/// Grads of `instance_norm_fwd` from its input, saved statistics and weight.
///
/// # Shapes
/// x, g: (N, C, H, W); mean, invstd: (N, C); weight: optional (C,). Returns dx (N, C, H, W), dweight and dbias (C,).
///
/// # Gradient
/// x̂ = (x − mean)·invstd per plane, M = H·W:
/// dx = w·invstd·(g − mean_hw(g) − x̂·mean_hw(g·x̂)); dweight = Σ_{n,h,w} g·x̂; dbias = Σ_{n,h,w} g.
///
/// Torch: autograd of `F.instance_norm(x, None, None, weight, bias, use_input_stats=True)`.
pub fn instance_norm_bwd<F: Float>(x: ArrayViewD<F>, mean: ArrayViewD<F>, invstd: ArrayViewD<F>, weight: Option<ArrayViewD<F>>, g: ArrayViewD<F>) -> Result<NormGrads<F>> {
    let op = "instance_norm";
    check_same_shape(op, ("input", x.shape()), ("grad_output", g.shape()))?;
    let x = input4(op, x)?;
    let (n, c, h, wd) = x.dim();
    let stat_shape = [n, c];
    let mean = saved::<_, Ix2>(op, "mean", mean, &stat_shape, x.shape())?;
    let invstd = saved::<_, Ix2>(op, "invstd", invstd, &stat_shape, x.shape())?;
    let w = per_channel(op, "weight", weight, x.shape())?;
    let (x, g) = (x.as_standard_layout(), g.as_standard_layout());
    let reshape_err = |_| Error::shape(op, "input not reshapeable", &[("input", &[n, c, h, wd])]);
    // (N, C, H, W) -> (1, N·C, H·W), statistics (N, C) -> (N·C,)
    let xv = x.view().into_shape_with_order((1, n * c, h * wd)).map_err(reshape_err)?;
    let gv = g.view().into_shape_with_order((1, n * c, h * wd)).map_err(reshape_err)?;
    let flat = |s: ndarray::ArrayView2<F>| Array1::from_iter(s.iter().copied());
    let wt = w.map(|w| tile(w, n));
    let (dx, dw, db) = normalize_bwd(op, xv, gv, &flat(mean), &flat(invstd), wt.as_ref(), true)?;
    // per-plane affine grads (N·C,) summed over n in order: d(param)[c] = Σ_n d[n·C + c]
    let per_c = |d: Array1<F>| d.into_shape_with_order((n, c)).map(|d| d.sum_axis(Axis(0))).map_err(reshape_err);
    Ok(NormGrads {
        x: dx.into_shape_with_order((n, c, h, wd)).map_err(reshape_err)?,
        weight: per_c(dw)?,
        bias: per_c(db)?,
    })
}

/// Batch normalisation: per channel over (n, h, w) in training (updating running stats), with the
/// running statistics in eval; then the optional affine.
///
/// # Shapes
/// x: (N, C, H, W) (training needs N·H·W > 1); weight, bias, running_mean, running_var: optional (C,)
/// (running stats required in eval). Returns y (N, C, H, W), mean and invstd (C,) as used, and in
/// training with running stats given their new values (C,):
/// running_mean' = (1 − m)·running_mean + m·mean, running_var' = (1 − m)·running_var + m·var·M/(M − 1).
///
/// # Gradient
/// See `batch_norm_bwd`.
///
/// Torch: `F.batch_norm(x, running_mean, running_var, weight, bias, training, momentum, eps)`.
pub fn batch_norm_fwd<F: Float>(
    x: ArrayViewD<F>, weight: Option<ArrayViewD<F>>, bias: Option<ArrayViewD<F>>,
    running_mean: Option<ArrayViewD<F>>, running_var: Option<ArrayViewD<F>>, cfg: &BatchNormCfg,
) -> Result<BatchNormOut<F>> {
    let op = "batch_norm";
    let x = input4(op, x)?;
    let shape = x.shape().to_vec();
    let (w, b) = (per_channel(op, "weight", weight, &shape)?, per_channel(op, "bias", bias, &shape)?);
    let rm = per_channel(op, "running_mean", running_mean, &shape)?;
    let rv = per_channel(op, "running_var", running_var, &shape)?;
    if rm.is_some() != rv.is_some() {
        return Err(Error::arg(op, "running_mean and running_var must both be given or both be None"));
    }
    let (n, c, h, wd) = x.dim();
    let x = x.as_standard_layout();
    // (N, C, H, W) -> (N, C, H·W)
    let xv = x.view().into_shape_with_order((n, c, h * wd)).map_err(|_| Error::shape(op, "input not reshapeable", &[("input", &shape)]))?;
    let eps = F::c(cfg.eps);
    let (mean, invstd, new_rm, new_rv) = if cfg.training {
        let count = n * h * wd;
        if count <= 1 {
            return Err(Error::shape(op, "Expected more than 1 value per channel when training", &[("input", &shape)]));
        }
        let (mean, var) = moments(xv);
        let invstd = var.mapv(|v| F::one() / (v + eps).sqrt());
        let (m, unbias) = (F::c(cfg.momentum), F::c(count as f64 / (count - 1) as f64));
        // running' = (1 − m)·running + m·stat, with the unbiased variance var·M/(M − 1)
        let new_rm = rm.map(|rm| Zip::from(&rm).and(&mean).map_collect(|&r, &s| (F::one() - m) * r + m * s));
        let new_rv = rv.map(|rv| Zip::from(&rv).and(&var).map_collect(|&r, &s| (F::one() - m) * r + m * s * unbias));
        (mean, invstd, new_rm, new_rv)
    } else {
        let (Some(rm), Some(rv)) = (rm, rv) else {
            return Err(Error::arg(op, "running_mean and running_var must be given in evaluation mode (training=False)"));
        };
        (rm.to_owned(), rv.mapv(|v| F::one() / (v + eps).sqrt()), None, None)
    };
    let (wo, bo) = (w.map(|w| w.to_owned()), b.map(|b| b.to_owned()));
    let y = normalize(op, xv, &mean, &invstd, wo.as_ref(), bo.as_ref())?;
    Ok(BatchNormOut {
        y: y.into_shape_with_order((n, c, h, wd)).map_err(|_| Error::shape(op, "output not reshapeable", &[("input", &shape)]))?,
        mean,
        invstd,
        running_mean: new_rm,
        running_var: new_rv,
    })
}

/// Grads of `batch_norm_fwd` from its input, the statistics it used, and weight.
///
/// # Shapes
/// x, g: (N, C, H, W); mean, invstd: (C,) as returned by the forward; weight: optional (C,).
/// Returns dx (N, C, H, W), dweight and dbias (C,).
///
/// # Gradient
/// x̂ = (x − mean)·invstd, dweight = Σ_{n,h,w} g·x̂, dbias = Σ_{n,h,w} g, M = N·H·W.
/// training: dx = w·invstd·(g − dbias/M − x̂·dweight/M); eval: dx = w·invstd·g.
///
/// Torch: autograd of `F.batch_norm(x, running_mean, running_var, weight, bias, training)`.
pub fn batch_norm_bwd<F: Float>(x: ArrayViewD<F>, mean: ArrayViewD<F>, invstd: ArrayViewD<F>, weight: Option<ArrayViewD<F>>, g: ArrayViewD<F>, training: bool) -> Result<NormGrads<F>> {
    let op = "batch_norm";
    check_same_shape(op, ("input", x.shape()), ("grad_output", g.shape()))?;
    let x = input4(op, x)?;
    let (n, c, h, wd) = x.dim();
    let mean = saved::<_, Ix1>(op, "mean", mean, &[c], x.shape())?.to_owned();
    let invstd = saved::<_, Ix1>(op, "invstd", invstd, &[c], x.shape())?.to_owned();
    let w = per_channel(op, "weight", weight, x.shape())?.map(|w| w.to_owned());
    let (x, g) = (x.as_standard_layout(), g.as_standard_layout());
    let reshape_err = |_| Error::shape(op, "input not reshapeable", &[("input", &[n, c, h, wd])]);
    // (N, C, H, W) -> (N, C, H·W)
    let xv = x.view().into_shape_with_order((n, c, h * wd)).map_err(reshape_err)?;
    let gv = g.view().into_shape_with_order((n, c, h * wd)).map_err(reshape_err)?;
    let (dx, dw, db) = normalize_bwd(op, xv, gv, &mean, &invstd, w.as_ref(), training)?;
    Ok(NormGrads { x: dx.into_shape_with_order((n, c, h, wd)).map_err(reshape_err)?, weight: dw, bias: db })
}
