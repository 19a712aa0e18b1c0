//! Elementwise arithmetic with numpy/torch broadcasting, reductions back to a broadcast shape,
//! and means over axes.
//!
//! | op | forward | backward |
//! |---|---|---|
//! | add / sub / mul | `binary_fwd` | `binary_bwd`: (g, ±g) or (g·b, g·a), each summed to its input's shape |
//! | alpha·x + beta | `affine_fwd` | alpha·g (`affine_fwd` with beta 0) |
//! | a += b in place | `add_assign` | (gradient accumulation, not differentiated) |
//! | sum to shape | `sum_to_shape` | broadcast of g |
//! | mean over axes | `mean_fwd` | `mean_bwd`: g / count broadcast over the reduced axes |

use super::lanes;
use crate::tensor::{check_same_shape, par_filled, zeros};
use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, Axis, IxDyn, Zip};
use rayon::prelude::*;

/// Which binary op.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binary {
    Add,
    Sub,
    Mul,
}

impl Binary {
    /// Parses "add" | "sub" | "mul".
    pub fn parse(name: &str) -> Result<Binary> {
        match name {
            "add" => Ok(Binary::Add),
            "sub" => Ok(Binary::Sub),
            "mul" => Ok(Binary::Mul),
            other => Err(Error::arg("binary", format!("unknown binary op {other:?}"))),
        }
    }
    /// The op name used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            Binary::Add => "add",
            Binary::Sub => "sub",
            Binary::Mul => "mul",
        }
    }
}

/// The broadcast shape of two shapes (numpy rules: align right, sizes equal or 1).
pub fn broadcast_shape(op: &'static str, a: &[usize], b: &[usize]) -> Result<Vec<usize>> {
    let n = a.len().max(b.len());
    // Right-aligned size of `s` at output axis i (1 where `s` has no such axis).
    let at = |s: &[usize], i: usize| if i + s.len() >= n { s[i + s.len() - n] } else { 1 };
    (0..n)
        .map(|i| match (at(a, i), at(b, i)) {
            (x, y) if x == y || y == 1 => Ok(x),
            (1, y) => Ok(y),
            _ => Err(Error::shape(op, "shapes cannot be broadcast together", &[("a", a), ("b", b)])),
        })
        .collect()
}

/// out = a ∘ b with broadcasting.
///
/// Torch: `a + b`, `a - b`, `a * b`.
pub fn binary_fwd<F: Float>(op: Binary, a: ArrayViewD<F>, b: ArrayViewD<F>) -> Result<ArrayD<F>> {
    match op {
        Binary::Add => elementwise(op.name(), a, b, |x, y| x + y),
        Binary::Sub => elementwise(op.name(), a, b, |x, y| x - y),
        Binary::Mul => elementwise(op.name(), a, b, |x, y| x * y),
    }
}

/// out = f(a, b) with broadcasting; two contiguous arrays of the same shape take one parallel pass
/// over their flat elements into an output that is not zeroed first.
fn elementwise<F: Float>(op: &'static str, a: ArrayViewD<F>, b: ArrayViewD<F>, f: impl Fn(F, F) -> F + Sync + Send) -> Result<ArrayD<F>> {
    let shape = broadcast_shape(op, a.shape(), b.shape())?;
    let whole = |v: &ArrayViewD<F>| v.shape() == shape.as_slice() && v.is_standard_layout();
    if let (true, true, Some(xs), Some(ys)) = (whole(&a), whole(&b), a.to_slice(), b.to_slice()) {
        return par_filled(op, &shape, |start, chunk| {
            // flat elements start .. start + chunk.len() of all three arrays
            let (xs, ys) = (&xs[start..start + chunk.len()], &ys[start..start + chunk.len()]);
            for ((o, &x), &y) in chunk.iter_mut().zip(xs).zip(ys) {
                o.write(f(x, y));
            }
        });
    }
    let (ab, bb) = (a.broadcast(shape.clone()).unwrap(), b.broadcast(shape.clone()).unwrap());
    let mut out = zeros(op, IxDyn(&shape))?;
    Zip::from(&mut out).and(&ab).and(&bb).par_for_each(|o, &x, &y| *o = f(x, y));
    Ok(out)
}

/// Grads of `binary_fwd` w.r.t. a and b, each summed back to its input's shape.
pub struct BinaryGrads<F> {
    pub a: ArrayD<F>,
    pub b: ArrayD<F>,
}

/// # Gradient
/// add: (g, g); sub: (g, −g); mul: (g·b, g·a); then each is summed over its broadcast axes.
pub fn binary_bwd<F: Float>(op: Binary, a: ArrayViewD<F>, b: ArrayViewD<F>, g: ArrayViewD<F>) -> Result<BinaryGrads<F>> {
    let shape = broadcast_shape(op.name(), a.shape(), b.shape())?;
    if g.shape() != shape.as_slice() {
        return Err(Error::shape(op.name(), "grad_output must have the broadcast shape",
                                &[("a", a.shape()), ("b", b.shape()), ("grad_output", g.shape())]));
    }
    let (ga, gb) = match op {
        Binary::Add => (g.to_owned(), g.to_owned()),
        Binary::Sub => (g.to_owned(), g.mapv(|v| -v)),
        Binary::Mul => (binary_fwd(Binary::Mul, g.view(), b.view())?, binary_fwd(Binary::Mul, g.view(), a.view())?),
    };
    Ok(BinaryGrads { a: sum_to_shape(ga.view(), a.shape())?, b: sum_to_shape(gb.view(), b.shape())? })
}

/// y = alpha·x + beta (scalar alpha, beta). Its backward is `affine_fwd(g, alpha, 0)`.
pub fn affine_fwd<F: Float>(x: ArrayViewD<F>, alpha: F, beta: F) -> Result<ArrayD<F>> {
    let x = x.as_standard_layout();
    let xs = x.as_slice().expect("standard layout");
    par_filled("affine", x.shape(), |start, chunk| {
        // flat elements start .. start + chunk.len()
        let xs = &xs[start..start + chunk.len()];
        for (y, &x) in chunk.iter_mut().zip(xs) {
            y.write(alpha * x + beta);
        }
    })
}

/// a += b in place, for arrays of the same shape (gradient accumulation). Torch: `a.add_(b)`.
pub fn add_assign<F: Float>(mut a: ArrayViewMutD<F>, b: ArrayViewD<F>) -> Result<()> {
    check_same_shape("add_", ("a", a.shape()), ("b", b.shape()))?;
    if let (true, Some(ys)) = (a.is_standard_layout(), b.to_slice()) {
        let xs = a.as_slice_mut().expect("standard layout");
        xs.par_chunks_mut(1 << 16).zip(ys.par_chunks(1 << 16)).for_each(|(xs, ys)| {
            xs.iter_mut().zip(ys).for_each(|(x, &y)| *x += y);
        });
    } else {
        Zip::from(&mut a).and(&b).par_for_each(|x, &y| *x += y);
    }
    Ok(())
}

/// Sums `g` down to `shape`, a shape `g`'s shape was broadcast from (leading axes dropped,
/// size-1 axes kept as 1). Torch: `g.sum_to_size(shape)`.
pub fn sum_to_shape<F: Float>(g: ArrayViewD<F>, shape: &[usize]) -> Result<ArrayD<F>> {
    let op = "sum_to_shape";
    let lead = g.ndim().checked_sub(shape.len())
        .ok_or_else(|| Error::shape(op, "target has more axes than the gradient", &[("grad", g.shape()), ("target", shape)]))?;
    if broadcast_shape(op, g.shape(), shape)? != g.shape() {
        return Err(Error::shape(op, "target is not a broadcast source of the gradient", &[("grad", g.shape()), ("target", shape)]));
    }
    let mut out = g.to_owned();
    // Leading axes vanish; then axes where the target has size 1 (and g does not) are summed, keeping them.
    for _ in 0..lead {
        out = out.sum_axis(Axis(0));
    }
    for (ax, &s) in shape.iter().enumerate() {
        if s == 1 && out.shape()[ax] != 1 {
            out = out.sum_axis(Axis(ax)).insert_axis(Axis(ax));
        }
    }
    Ok(out)
}

fn check_axes(op: &'static str, shape: &[usize], axes: &[usize]) -> Result<()> {
    let mut seen = vec![false; shape.len()];
    for &a in axes {
        if a >= shape.len() || std::mem::replace(&mut seen[a], true) {
            return Err(Error::shape(op, format!("invalid or repeated axis {a} in {axes:?}"), &[("input", shape)]));
        }
    }
    if axes.iter().any(|&a| shape[a] == 0) {
        return Err(Error::shape(op, "mean over an empty axis", &[("input", shape)]));
    }
    Ok(())
}

/// Mean over `axes`, keeping them as size-1 axes when `keepdim`.
///
/// Torch: `x.mean(dim=axes, keepdim=keepdim)`.
pub fn mean_fwd<F: Float>(x: ArrayViewD<F>, axes: &[usize], keepdim: bool) -> Result<ArrayD<F>> {
    check_axes("mean", x.shape(), axes)?;
    let count: usize = axes.iter().map(|&a| x.shape()[a]).product();
    let kept: Vec<usize> = (0..x.ndim()).filter(|a| !axes.contains(a)).map(|a| x.shape()[a]).collect();
    let mut out = if trailing(x.ndim(), axes) {
        // the reduced axes are the last ones: one contiguous run of `count` values per output element,
        // summed in blocks with an f64 total (a spatial mean over a 1/2-resolution map adds ~10^5 values)
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard layout");
        let means: Vec<F> = xs.par_chunks(count.max(1)).map(|run| {
            let mut total = 0.0;
            lanes::sum(run, &mut total);
            F::from_f64(total / count as f64).unwrap()
        }).collect();
        ArrayD::from_shape_vec(IxDyn(&kept), means).expect("one value per kept index")
    } else {
        let mut out = x.to_owned();
        for &a in axes {
            out = out.sum_axis(Axis(a)).insert_axis(Axis(a));
        }
        out.mapv_inplace(|v| v / F::from_usize(count).unwrap());
        out.into_shape_with_order(IxDyn(&kept)).expect("same element count")
    };
    if keepdim {
        let shape: Vec<usize> = (0..x.ndim()).map(|a| if axes.contains(&a) { 1 } else { x.shape()[a] }).collect();
        out = out.into_shape_with_order(IxDyn(&shape)).expect("same element count");
    }
    Ok(out)
}

/// Whether `axes` (sorted, distinct) are the last axes of an `ndim`-axis array.
fn trailing(ndim: usize, axes: &[usize]) -> bool {
    !axes.is_empty() && axes.iter().enumerate().all(|(i, &a)| a == ndim - axes.len() + i)
}

/// # Gradient
/// dx = g / count, broadcast over the reduced axes (g with or without the kept axes).
pub fn mean_bwd<F: Float>(g: ArrayViewD<F>, input_shape: &[usize], axes: &[usize]) -> Result<ArrayD<F>> {
    check_axes("mean", input_shape, axes)?;
    let count: usize = axes.iter().map(|&a| input_shape[a]).product();
    let kept: Vec<usize> = (0..input_shape.len()).map(|a| if axes.contains(&a) { 1 } else { input_shape[a] }).collect();
    let g = g.as_standard_layout();
    let g = g.view().into_shape_with_order(IxDyn(&kept))
        .map_err(|_| Error::shape("mean", "grad_output does not fit the reduced shape", &[("grad_output", g.shape()), ("input", input_shape)]))?;
    let scale = F::one() / F::from_usize(count).unwrap();
    if trailing(input_shape.len(), axes) {
        // dx[k·count + i] = g[k] / count: one contiguous run per gradient value
        let gs = g.as_slice().expect("standard layout");
        let mut dx = ArrayD::<F>::zeros(IxDyn(input_shape));
        let ds = dx.as_slice_mut().expect("fresh array");
        ds.par_chunks_mut(count.max(1)).zip(gs.par_iter()).for_each(|(run, &v)| run.fill(v * scale));
        return Ok(dx);
    }
    Ok(g.broadcast(input_shape).unwrap().mapv(|v| v * scale))
}

