//! The element types kernels run on: f32 (production) and f64 (gradient checks, float64 models).

use std::fmt::Debug;
use std::iter::Sum;
use std::ops::{AddAssign, DivAssign, MulAssign, SubAssign};

/// A float type every kernel is generic over. `gemm_raw` is the single place that picks the
/// matrixmultiply routine (sgemm / dgemm) for the type.
pub trait Float:
    num_traits::Float
    + num_traits::FromPrimitive
    + ndarray::LinalgScalar
    + ndarray::ScalarOperand
    + Send
    + Sync
    + Debug
    + Default
    + Sum
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
    + 'static
{
    /// "float32" or "float64", as numpy and torch name it.
    const NAME: &'static str;

    /// Converts an f64 constant (a literal in a formula) to this type.
    fn c(v: f64) -> Self {
        <Self as num_traits::FromPrimitive>::from_f64(v).expect("finite constant")
    }

    /// C <- alpha * A·B + beta * C on raw strided storage (A: m x k, B: k x n, C: m x n).
    ///
    /// # Safety
    /// Pointers and strides must describe valid, non-aliasing (for C) memory of those sizes.
    #[allow(clippy::too_many_arguments)]
    unsafe fn gemm_raw(
        m: usize, k: usize, n: usize, alpha: Self,
        a: *const Self, rsa: isize, csa: isize,
        b: *const Self, rsb: isize, csb: isize,
        beta: Self, c: *mut Self, rsc: isize, csc: isize,
    );
}

impl Float for f32 {
    const NAME: &'static str = "float32";
    unsafe fn gemm_raw(
        m: usize, k: usize, n: usize, alpha: f32,
        a: *const f32, rsa: isize, csa: isize,
        b: *const f32, rsb: isize, csb: isize,
        beta: f32, c: *mut f32, rsc: isize, csc: isize,
    ) {
        unsafe { matrixmultiply::sgemm(m, k, n, alpha, a, rsa, csa, b, rsb, csb, beta, c, rsc, csc) }
    }
}

impl Float for f64 {
    const NAME: &'static str = "float64";
    unsafe fn gemm_raw(
        m: usize, k: usize, n: usize, alpha: f64,
        a: *const f64, rsa: isize, csa: isize,
        b: *const f64, rsb: isize, csb: isize,
        beta: f64, c: *mut f64, rsc: isize, csc: isize,
    ) {
        unsafe { matrixmultiply::dgemm(m, k, n, alpha, a, rsa, csa, b, rsb, csb, beta, c, rsc, csc) }
    }
}
