//! Softmax along one axis of a tensor of any rank.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | softmax | y = e^(x − max) / Σ e^(x − max) along the axis | `softmax_bwd` (x, from y): y·(g − Σ g·y) |

use crate::tensor::{check_nonempty, check_same_shape};
use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD, Axis, Zip};

/// A torch-style dim in [−ndim, ndim) (a 0-d tensor takes −1 and 0) as an axis of a rank-`ndim` array.
fn resolve_axis(op: &'static str, dim: isize, shape: &[usize]) -> Result<usize> {
    let n = shape.len().max(1) as isize;
    if dim < -n || dim >= n {
        return Err(Error::shape(op, format!("Dimension out of range (expected to be in range of [{}, {}], but got {dim})", -n, n - 1), &[("input", shape)]));
    }
    // negative dims count from the end
    Ok(dim.rem_euclid(n) as usize)
}

/// The array with a length-1 axis added when it is 0-d, so a 0-d softmax is a softmax over one element.
fn at_least_1d<'a, F>(x: ArrayViewD<'a, F>) -> ArrayViewD<'a, F> {
    if x.ndim() == 0 { x.insert_axis(Axis(0)) } else { x }
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
    let axis = Axis(resolve_axis(op, dim, x.shape())?);
    check_nonempty(op, &[("input", x.shape())])?;
    let shape = x.raw_dim();
    let x = at_least_1d(x);
    let x = x.as_standard_layout();
    let mut y = ArrayD::<F>::zeros(x.raw_dim());
    // One lane per position of the other axes, lanes in parallel.
    Zip::from(y.lanes_mut(axis)).and(x.lanes(axis)).par_for_each(|mut yl, xl| {
        let m = xl.fold(F::neg_infinity(), |m, &v| m.max(v));
        // y = e^(x − m) / Σ e^(x − m)
        Zip::from(&mut yl).and(&xl).for_each(|y, &x| *y = (x - m).exp());
        let inv = F::one() / yl.sum();
        yl.mapv_inplace(|v| v * inv);
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
    let axis = Axis(resolve_axis(op, dim, y.shape())?);
    check_nonempty(op, &[("output", y.shape())])?;
    let shape = y.raw_dim();
    let (y, g) = (at_least_1d(y), at_least_1d(g));
    let (y, g) = (y.as_standard_layout(), g.as_standard_layout());
    let mut dx = ArrayD::<F>::zeros(y.raw_dim());
    Zip::from(dx.lanes_mut(axis)).and(y.lanes(axis)).and(g.lanes(axis)).par_for_each(|mut dl, yl, gl| {
        // s = Σ g·y along the lane; dx = y·(g − s)
        let s = Zip::from(&yl).and(&gl).fold(F::zero(), |acc, &y, &g| acc + g * y);
        Zip::from(&mut dl).and(&yl).and(&gl).for_each(|d, &y, &g| *d = y * (g - s));
    });
    dx.into_shape_with_order(shape).map_err(|_| Error::shape(op, "grad not reshapeable", &[("output", y.shape())]))
}
