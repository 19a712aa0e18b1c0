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

/// A zero-filled standard-layout array, like `Array::zeros`, for kernel outputs; a shape whose size
/// overflows or cannot be allocated is an error naming `op` instead of a panic or an abort.
///
/// Large buffers are asked to be backed by transparent huge pages (Linux `MADV_HUGEPAGE`) and are
/// zeroed in parallel: a fresh multi-MB allocation is a new mapping, and touching it in 4 KiB pages
/// costs one page fault per page (tens of ms for the 63 MB warp of a 1280-channel stack).
pub fn zeros<F: crate::Float, D: Dimension>(op: &'static str, shape: impl ndarray::IntoDimension<Dim = D>) -> Result<ndarray::Array<F, D>> {
    use rayon::prelude::*;
    let dim = shape.into_dimension();
    let too_big = || Error::shape(op, "the output is too large to allocate", &[("output", dim.slice())]);
    let len = dim.size_checked().filter(|&n| n.checked_mul(std::mem::size_of::<F>()).is_some_and(|b| b <= isize::MAX as usize)).ok_or_else(too_big)?;
    let mut v = Vec::<F>::new();
    v.try_reserve_exact(len).map_err(|_| too_big())?;
    advise_huge_pages(v.as_mut_ptr().cast(), len * std::mem::size_of::<F>());
    v.spare_capacity_mut()[..len].par_chunks_mut(1 << 16).for_each(|c| {
        c.iter_mut().for_each(|x| {
            x.write(F::zero());
        })
    });
    // SAFETY: the first `len` elements were just initialised and the capacity is at least `len`.
    unsafe { v.set_len(len) };
    Ok(ndarray::Array::from_shape_vec(dim, v).expect("length equals the shape's size"))
}

/// Advises the kernel to back `[ptr, ptr + bytes)` with huge pages (only the whole pages inside; a no-op
/// for small buffers and off Linux; failure is harmless).
fn advise_huge_pages(ptr: *mut u8, bytes: usize) {
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        const MADV_HUGEPAGE: std::ffi::c_int = 14;
        extern "C" {
            fn madvise(addr: *mut std::ffi::c_void, len: usize, advice: std::ffi::c_int) -> std::ffi::c_int;
        }
        if bytes < (4 << 20) {
            return;
        }
        let start = (ptr as usize).next_multiple_of(PAGE);
        let end = (ptr as usize + bytes) & !(PAGE - 1);
        if end > start {
            // SAFETY: the range lies inside a live allocation; madvise only changes paging policy.
            unsafe { madvise(start as *mut std::ffi::c_void, end - start, MADV_HUGEPAGE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (ptr, bytes);
}
