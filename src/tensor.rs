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

/// An empty vector with room for the elements of `shape`, and their count, for a kernel to write; a size
/// that overflows or cannot be allocated is an error naming `op`.
pub fn reserve<F>(op: &'static str, shape: &[usize]) -> Result<(Vec<F>, usize)> {
    let too_big = || Error::shape(op, "the output is too large to allocate", &[("output", shape)]);
    let len = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&n| n.checked_mul(std::mem::size_of::<F>()).is_some_and(|b| b <= isize::MAX as usize)).ok_or_else(too_big)?;
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| too_big())?;
    Ok((v, len))
}

/// A zero-filled standard-layout array, like `Array::zeros`, for kernel outputs; a shape whose size
/// overflows or cannot be allocated is an error naming `op` instead of a panic or an abort.
///
/// Large buffers are zeroed in parallel (and backed by huge pages, as every large block of
/// [`crate::alloc::HugePageAlloc`]).
pub fn zeros<F: crate::Float, D: Dimension>(op: &'static str, shape: impl ndarray::IntoDimension<Dim = D>) -> Result<ndarray::Array<F, D>> {
    use rayon::prelude::*;
    let dim = shape.into_dimension();
    let (mut v, len) = reserve::<F>(op, dim.slice())?;
    v.spare_capacity_mut()[..len].par_chunks_mut(1 << 16).for_each(|c| {
        c.iter_mut().for_each(|x| {
            x.write(F::zero());
        })
    });
    // SAFETY: the first `len` elements were just initialised and the capacity is at least `len`.
    unsafe { v.set_len(len) };
    Ok(ndarray::Array::from_shape_vec(dim, v).expect("length equals the shape's size"))
}

/// `chunk` filled with zeros, as a slice of initialised elements (for a [`par_filled`] task that
/// accumulates into its chunk or writes only part of it).
pub fn zeroed<F: crate::Float>(chunk: &mut [std::mem::MaybeUninit<F>]) -> &mut [F] {
    chunk.fill(std::mem::MaybeUninit::new(F::zero()));
    // SAFETY: every element was just written, and MaybeUninit<F> has the size and alignment of F.
    unsafe { &mut *(chunk as *mut [std::mem::MaybeUninit<F>] as *mut [F]) }
}

/// Elements per task of [`par_filled`].
const FILL_CHUNK: usize = 1 << 16;

/// A standard-layout array of `shape` whose flat elements are written in parallel: `fill(start, chunk)`
/// must write every element of `chunk`, which holds the flat indices start..start + chunk.len().
/// Errors as [`zeros`] for shapes too large to allocate.
pub fn par_filled<F: crate::Float>(op: &'static str, shape: &[usize],
                                   fill: impl Fn(usize, &mut [std::mem::MaybeUninit<F>]) + Sync) -> Result<ndarray::ArrayD<F>> {
    par_filled_in(op, shape, FILL_CHUNK, fill)
}

/// [`par_filled`] with tasks of `chunk` elements (the last may be shorter), e.g. one innermost row each.
pub fn par_filled_in<F: crate::Float>(op: &'static str, shape: &[usize], chunk: usize,
                                      fill: impl Fn(usize, &mut [std::mem::MaybeUninit<F>]) + Sync) -> Result<ndarray::ArrayD<F>> {
    use rayon::prelude::*;
    let chunk = chunk.max(1);
    let (mut v, len) = reserve::<F>(op, shape)?;
    v.spare_capacity_mut()[..len].par_chunks_mut(chunk).enumerate().for_each(|(k, c)| fill(k * chunk, c));
    // SAFETY: `fill` wrote every element of every chunk, which together cover the first `len` elements.
    unsafe { v.set_len(len) };
    Ok(ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(shape), v).expect("length equals the shape's size"))
}
