//! Softmax along one axis of a tensor of any rank.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | softmax | y = e^(x − max) / Σ e^(x − max) along the axis | `softmax_bwd` (x, from y): y·(g − Σ g·y) |

use crate::tensor::{check_nonempty, check_same_shape};
use crate::{Error, Float, Result};
use ndarray::{s, Array3, ArrayBase, ArrayD, ArrayView, ArrayView2, ArrayView3, ArrayViewD, ArrayViewMut2, ArrayViewMut3, Axis, Ix3, IxDyn, RawData};
use rayon::prelude::*;

/// A torch-style dim in [−ndim, ndim) (a 0-d tensor takes −1 and 0) as an axis of a rank-`ndim` array.
fn resolve_axis(op: &'static str, dim: isize, shape: &[usize]) -> Result<usize> {
    let n = shape.len().max(1) as isize;
    if dim < -n || dim >= n {
        return Err(Error::shape(op, format!("Dimension out of range (expected to be in range of [{}, {}], but got {dim})", -n, n - 1), &[("input", shape)]));
    }
    // negative dims count from the end
    Ok(dim.rem_euclid(n) as usize)
}

/// Columns (lanes) per block: a block is an (n, ≤ BLOCK) slab of the (outer, n, inner) view, and the
/// reductions along the softmax axis run row by row over it (contiguous rows unless inner = 1).
const BLOCK: usize = 512;

/// The C-order array seen as (outer, n, inner) with n the length of `axis` (0-d: (1, 1, 1)).
fn as_3d<'a, F>(x: ArrayView<'a, F, IxDyn>, axis: usize) -> Option<ArrayView3<'a, F>> {
    let s = x.shape();
    let (outer, n, inner) = if s.is_empty() { (1, 1, 1) } else { (s[..axis].iter().product(), s[axis], s[axis + 1..].iter().product()) };
    x.into_shape_with_order((outer, n, inner)).ok()
}

/// The lanes of an (outer, n, inner) view as the columns of its blocks: (outer, n, 1) (softmax over the
/// last axis) becomes the (1, n, outer) view of the same memory, so a block spans up to BLOCK lanes.
fn lanes_as_columns<S: RawData>(a: ArrayBase<S, Ix3>) -> ArrayBase<S, Ix3> {
    if a.dim().2 == 1 { a.permuted_axes([2, 1, 0]) } else { a }
}

/// Runs `f(out_block, in_blocks)` over (n, ≤ BLOCK) blocks of (outer, n, inner) views: in parallel over
/// outer indices and column blocks, each block written by exactly one task.
fn for_blocks<F: Float>(out: ArrayViewMut3<F>, ins: &[ArrayView3<F>], f: impl Fn(ArrayViewMut2<F>, &[ArrayView2<F>]) + Sync) {
    let (mut out, ins): (_, Vec<_>) = (lanes_as_columns(out), ins.iter().map(|a| lanes_as_columns(a.view())).collect());
    out.outer_iter_mut().into_par_iter().enumerate().for_each(|(o, mut out_o)| {
        let ins_o: Vec<ArrayView2<F>> = ins.iter().map(|a| a.index_axis(Axis(0), o)).collect();
        out_o.axis_chunks_iter_mut(Axis(1), BLOCK).into_par_iter().enumerate().for_each(|(b, out_b)| {
            let cols = b * BLOCK..(b * BLOCK + out_b.ncols());
            let ins_b: Vec<ArrayView2<F>> = ins_o.iter().map(|a| a.slice(s![.., cols.clone()])).collect();
            f(out_b, &ins_b);
        });
    });
}

/// Softmax along `dim`, numerically stable (the lane maximum is subtracted before exponentiating).
///
/// # Shapes
/// x: any non-empty shape; dim in [−ndim, ndim). Returns y of x's shape.
///
/// # Gradient
/// See `softmax_bwd`.
///
/// Torch: `torch.softmax(x, dim)`.
pub fn softmax_fwd<F: Float>(x: ArrayViewD<F>, dim: isize) -> Result<ArrayD<F>> {
    let op = "softmax";
    let axis = resolve_axis(op, dim, x.shape())?;
    check_nonempty(op, &[("input", x.shape())])?;
    let shape = x.raw_dim();
    let x = x.as_standard_layout();
    let x3 = as_3d(x.view(), axis).ok_or_else(|| Error::shape(op, "input not reshapeable", &[("input", x.shape())]))?;
    let mut y = Array3::<F>::zeros(x3.raw_dim());
    for_blocks(y.view_mut(), &[x3], |mut yb, xb| {
        let xb = &xb[0];
        // m[j] = max_i x[i, j]
        let mut m = vec![F::neg_infinity(); xb.ncols()];
        for xr in xb.rows() {
            m.iter_mut().zip(xr.iter()).for_each(|(m, &v)| *m = m.max(v));
        }
        // y[i, j] = e^(x[i, j] − m[j]), z[j] = Σ_i y[i, j]
        let mut z = vec![F::zero(); xb.ncols()];
        for (mut yr, xr) in yb.rows_mut().into_iter().zip(xb.rows()) {
            yr.iter_mut().zip(xr.iter()).zip(m.iter().zip(z.iter_mut())).for_each(|((y, &x), (&m, z))| {
                *y = (x - m).exp();
                *z += *y;
            });
        }
        // y[i, j] /= z[j]
        z.iter_mut().for_each(|v| *v = F::one() / *v);
        for mut yr in yb.rows_mut() {
            yr.iter_mut().zip(&z).for_each(|(y, &r)| *y *= r);
        }
    });
    y.into_shape_with_order(shape).map_err(|_| Error::shape(op, "output not reshapeable", &[("input", x.shape())]))
}

/// Grad of `softmax_fwd` w.r.t. x, from the forward output y.
///
/// # Shapes
/// y, g: the same shape; dim as in the forward. Returns dx of that shape.
///
/// # Gradient
/// dx = y·(g − Σ_dim g·y).
///
/// Torch: autograd of `torch.softmax(x, dim)` (`_softmax_backward_data`).
pub fn softmax_bwd<F: Float>(y: ArrayViewD<F>, g: ArrayViewD<F>, dim: isize) -> Result<ArrayD<F>> {
    let op = "softmax";
    check_same_shape(op, ("output", y.shape()), ("grad_output", g.shape()))?;
    let axis = resolve_axis(op, dim, y.shape())?;
    check_nonempty(op, &[("output", y.shape())])?;
    let shape = y.raw_dim();
    let (y, g) = (y.as_standard_layout(), g.as_standard_layout());
    let reshape_err = || Error::shape(op, "output not reshapeable", &[("output", y.shape())]);
    let (y3, g3) = (as_3d(y.view(), axis).ok_or_else(reshape_err)?, as_3d(g.view(), axis).ok_or_else(reshape_err)?);
    let mut dx = Array3::<F>::zeros(y3.raw_dim());
    for_blocks(dx.view_mut(), &[y3, g3], |mut db, yg| {
        let (yb, gb) = (&yg[0], &yg[1]);
        // s[j] = Σ_i g[i, j]·y[i, j]
        let mut sum = vec![F::zero(); yb.ncols()];
        for (yr, gr) in yb.rows().into_iter().zip(gb.rows()) {
            sum.iter_mut().zip(yr.iter().zip(gr.iter())).for_each(|(s, (&y, &g))| *s += g * y);
        }
        // dx[i, j] = y[i, j]·(g[i, j] − s[j])
        for ((mut dr, yr), gr) in db.rows_mut().into_iter().zip(yb.rows()).zip(gb.rows()) {
            dr.iter_mut().zip(yr.iter().zip(gr.iter())).zip(&sum).for_each(|((d, (&y, &g)), &s)| *d = y * (g - s));
        }
    });
    dx.into_shape_with_order(shape).map_err(|_| Error::shape(op, "grad not reshapeable", &[("output", y.shape())]))
}
