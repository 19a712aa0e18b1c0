//! Concatenation and slicing along one axis (channel or spatial).
//!
//! | op | forward | backward |
//! |---|---|---|
//! | cat | `cat_fwd` | slices of g (`slice_fwd`) |
//! | slice x[.., start:stop, ..] | `slice_fwd` | `slice_bwd`: g placed into zeros of the input shape |

use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD, Axis, IxDyn, Slice};

/// Concatenates arrays along `axis`; all other sizes must agree. Torch: `torch.cat(xs, dim=axis)`.
pub fn cat_fwd<F: Float>(xs: &[ArrayViewD<F>], axis: usize) -> Result<ArrayD<F>> {
    let op = "cat";
    let first = xs.first().ok_or_else(|| Error::arg(op, "needs at least one tensor"))?;
    let shapes: Vec<(&'static str, &[usize])> = xs.iter().map(|x| ("tensor", x.shape())).collect();
    if axis >= first.ndim() {
        return Err(Error::shape(op, format!("axis {axis} out of range"), &shapes));
    }
    let fits = |x: &ArrayViewD<F>| {
        x.ndim() == first.ndim() && (0..x.ndim()).all(|a| a == axis || x.shape()[a] == first.shape()[a])
    };
    if !xs.iter().all(fits) {
        return Err(Error::shape(op, format!("sizes must match except along axis {axis}"), &shapes));
    }
    Ok(ndarray::concatenate(Axis(axis), xs).expect("checked shapes").as_standard_layout().into_owned())
}

fn check_slice(op: &'static str, shape: &[usize], axis: usize, start: usize, stop: usize) -> Result<()> {
    if axis >= shape.len() || start > stop || stop > shape[axis] {
        return Err(Error::shape(op, format!("slice {start}:{stop} on axis {axis} is out of range"), &[("input", shape)]));
    }
    Ok(())
}

/// x[.., start:stop, ..] along `axis`, as a new contiguous array.
pub fn slice_fwd<F: Float>(x: ArrayViewD<F>, axis: usize, start: usize, stop: usize) -> Result<ArrayD<F>> {
    check_slice("slice", x.shape(), axis, start, stop)?;
    Ok(x.slice_axis(Axis(axis), Slice::from(start..stop)).as_standard_layout().into_owned())
}

/// # Gradient
/// dx = zeros(input_shape) with dx[.., start:start+len, ..] = g.
pub fn slice_bwd<F: Float>(g: ArrayViewD<F>, input_shape: &[usize], axis: usize, start: usize) -> Result<ArrayD<F>> {
    let stop = start + g.shape().get(axis).copied().unwrap_or(0);
    check_slice("slice", input_shape, axis, start, stop)?;
    let mut expect = input_shape.to_vec();
    expect[axis] = stop - start;
    if g.shape() != expect.as_slice() {
        return Err(Error::shape("slice", "grad_output does not fit the slice", &[("grad_output", g.shape()), ("input", input_shape)]));
    }
    let mut dx = ArrayD::<F>::zeros(IxDyn(input_shape));
    dx.slice_axis_mut(Axis(axis), Slice::from(start..stop)).assign(&g);
    Ok(dx)
}
