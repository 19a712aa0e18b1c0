//! The only door to matrix multiplication. Transposes are stride swaps (`view.t()`), never copies.
//!
//! f32 products on AVX-512 CPUs (from OWN_KERNEL_MIN multiply-adds) run mipnet's own kernel
//! (`avx512`: 8-15% faster than matrixmultiply's on conv2d's shapes, about 30% when an operand is
//! transposed); everything else runs `Float::gemm_raw` (matrixmultiply).

#[cfg(target_arch = "x86_64")]
mod avx512;

use crate::Float;
use ndarray::{ArrayView2, ArrayViewMut2, Axis};
use rayon::prelude::*;

/// Multiply-adds (m·n·k) from which f32 products use the AVX-512 kernel (below, packing dominates).
const OWN_KERNEL_MIN: usize = 1 << 15;

/// C <- alpha * A·B + beta * C for strided 2-D views, on the calling thread.
///
/// Shapes are internal invariants of the calling kernel (validated before), so a mismatch is a bug
/// and panics rather than corrupting memory.
pub fn gemm<F: Float>(alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, beta: F, mut c: ArrayViewMut2<F>) {
    let (m, k) = a.dim();
    let (k2, n) = b.dim();
    assert!(k == k2 && c.dim() == (m, n), "gemm: inner dims {k} vs {k2}, C {:?} vs ({m},{n})", c.dim());
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        // A·B is the zero matrix: C <- beta * C (beta 0 must clear NaN garbage, as BLAS does).
        c.mapv_inplace(|v| if beta == F::zero() { F::zero() } else { beta * v });
        return;
    }
    let (sa, sb, sc) = (a.strides(), b.strides(), c.strides().to_vec());
    #[cfg(target_arch = "x86_64")]
    if std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>() && m * n * k >= OWN_KERNEL_MIN && avx512::available() {
        // F is f32 (checked above), so the casts only rename the element type.
        let f = |v: F| v.to_f32().unwrap_or(0.0);
        // SAFETY: AVX-512F is present; the views own valid memory of the checked shapes; C is a
        // unique mutable view, so it aliases neither A nor B.
        unsafe {
            avx512::sgemm(m, k, n, f(alpha), a.as_ptr().cast(), sa[0], sa[1], b.as_ptr().cast(), sb[0], sb[1],
                          f(beta), c.as_mut_ptr().cast(), sc[0], sc[1]);
        }
        return;
    }
    // SAFETY: the views own valid memory of the checked shapes; C is a unique mutable view.
    unsafe {
        F::gemm_raw(m, k, n, alpha, a.as_ptr(), sa[0], sa[1], b.as_ptr(), sb[0], sb[1], beta,
                    c.as_mut_ptr(), sc[0], sc[1]);
    }
}

/// Same as [`gemm`], with C split into column blocks (or row blocks when C is tall) that rayon
/// computes in parallel. Each block is an independent GEMM, so the result is deterministic.
pub fn gemm_par<F: Float>(alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, beta: F, mut c: ArrayViewMut2<F>) {
    let (m, n) = c.dim();
    let threads = rayon::current_num_threads();
    let flops = m * n * a.ncols();
    if threads <= 1 || flops < (1 << 20) {
        return gemm(alpha, a, b, beta, c);
    }
    // Blocks of at least 64 columns (or rows) keep each thread's packed panels full.
    if n >= m {
        let block = n.div_ceil(threads).max(64);
        c.axis_chunks_iter_mut(Axis(1), block)
            .into_par_iter()
            .zip(b.axis_chunks_iter(Axis(1), block).into_par_iter())
            .for_each(|(cb, bb)| gemm(alpha, a, bb, beta, cb));
    } else {
        let block = m.div_ceil(threads).max(64);
        c.axis_chunks_iter_mut(Axis(0), block)
            .into_par_iter()
            .zip(a.axis_chunks_iter(Axis(0), block).into_par_iter())
            .for_each(|(cb, ab)| gemm(alpha, ab, b, beta, cb));
    }
}
