//! Shape helpers shared by all kernels: rank conversion with a named error, and common checks.

use crate::{Error, Result};
use ndarray::{ArrayView, ArrayViewD, Dimension};

/// Views a dynamic-rank array as rank `D`, or fails naming the op, the argument and its shape.
pub fn fixed<'a, F, D: Dimension>(op: &'static str, name: &'static str, v: ArrayViewD<'a, F>) -> Result<ArrayView<'a, F, D>> {
    let shape = v.shape().to_vec();
    v.into_dimensionality::<D>().map_err(|_| {
        Error::shape(op, format!("{name} must be a {}-D tensor", D::NDIM.unwrap_or(0)), &[(name, &shape)])
    })
}

/// Fails if any of the named arrays has no elements.
pub fn check_nonempty(op: &'static str, arrays: &[(&'static str, &[usize])]) -> Result<()> {
    if arrays.iter().any(|(_, s)| s.iter().product::<usize>() == 0) {
        return Err(Error::shape(op, "empty tensors are not supported", arrays));
    }
    Ok(())
}

/// Fails unless two arrays have identical shapes.
pub fn check_same_shape(op: &'static str, a: (&'static str, &[usize]), b: (&'static str, &[usize])) -> Result<()> {
    if a.1 != b.1 {
        return Err(Error::shape(op, format!("{} and {} must have the same shape", a.0, b.0), &[a, b]));
    }
    Ok(())
}
