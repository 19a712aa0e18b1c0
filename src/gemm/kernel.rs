//! The micro-kernel: an MR x NR tile of C (NR = NV vectors) held in MR·NV registers while it sums
//! KC rank-1 updates from a packed A micro-panel (MR values broadcast per k) and NR columns of a
//! packed B block (NV vectors loaded per k, rows `ldb` elements apart).
//!
//! It is written once, generic over [`Simd`], and compiled per ISA by `isa_entry!` under that ISA's
//! `target_feature`. Every element of C is its initial value (0, its bias, or C itself when a later
//! K block continues) plus, in increasing k, the sums of runs of `SUB_K` fused multiply-adds, so
//! the result does not depend on MR, NR or the block sizes.

use super::simd::Simd;

/// How a tile's accumulators start.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Init<E> {
    /// From 0 (C is not read, so NaN there is ignored).
    Zero,
    /// From C (a later K block, or beta = 1).
    Load,
    /// From `bias[i]` for row i of the tile (MR readable values).
    Bias(*const E),
}

/// One micro-tile of C: row-major with unit column stride, full MR x NR.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Tile<E> {
    pub c: *mut E,
    /// Row stride of C, elements.
    pub ldc: isize,
    pub init: Init<E>,
    /// max(·, 0) before the last store (the last K block of a fused ReLU).
    pub relu: bool,
    /// The tile the next call will write (its lines are prefetched).
    pub next: *const E,
}

/// A micro-kernel: (kc, packed A micro-panel, first B column, B row stride, tile).
pub(crate) type UKernel<E> = unsafe fn(usize, *const E, *const E, usize, &Tile<E>);

/// Steps of one run of the accumulators: each run's sum starts from 0 and is added to C, so an
/// element of C is a sum of runs of at most `SUB_K` products (rounding error grows with the run
/// length; one chain over all of k = 1152 rounds 3x worse than torch). K blocks start at multiples
/// of it (`Plan::kc_for`), so the runs, and the result, do not depend on the block sizes.
pub(crate) const SUB_K: usize = 64;

/// Rows of B read ahead of the current k by the software prefetch.
const PREFETCH_K: usize = 8;

/// C tile <- init + Σ_kk A(:, kk) ⊗ B(kk, :), then ReLU if asked.
///
/// # Safety
/// `S`'s ISA is available; `pa` holds kc·MR elements, `pb` kc rows of NR elements `ldb` apart; the
/// tile is MR x NR valid elements at `c` with row stride `ldc`.
#[inline(always)]
pub(crate) unsafe fn micro<E: Copy, S: Simd<E>, const MR: usize, const NV: usize>(kc: usize, pa: *const E,
                                                                              pb: *const E, ldb: usize, t: &Tile<E>) {
    let nr = NV * S::LANES;
    // SAFETY: the caller's contract covers every pointer below: tile rows i < MR, vectors v < NV,
    // packed panels up to kc steps; prefetches never fault.
    unsafe {
        // element (i, v·LANES) of the tile: c + i·ldc + v·LANES
        let at = |i: usize, v: usize| t.c.offset(i as isize * t.ldc).add(v * S::LANES);
        // one prefetch per 64-byte line of the next tile's rows
        let line = 64 / std::mem::size_of::<E>();
        for i in 0..MR {
            for j in (0..nr).step_by(line) {
                S::prefetch(t.next.offset(i as isize * t.ldc).add(j));
            }
        }
        let (mut a, mut b) = (pa, pb);
        // k = 0 still runs one empty step: it writes the initial values (and the ReLU)
        let mut k0 = 0;
        loop {
            let steps = SUB_K.min(kc - k0);
            let acc = run::<E, S, MR, NV>(steps, &mut a, &mut b, ldb);
            let last = k0 + steps >= kc;
            for (i, row) in acc.iter().enumerate() {
                for (v, &r) in row.iter().enumerate() {
                    // C = (init, or C after the first SUB_K steps) + this run's sum
                    let base = match (k0, t.init) {
                        (0, Init::Zero) => S::zero(),
                        (0, Init::Bias(bias)) => S::splat(*bias.add(i)),
                        _ => S::load(at(i, v)),
                    };
                    let sum = S::add(base, r);
                    S::store(at(i, v), if t.relu && last { S::relu(sum) } else { sum });
                }
            }
            k0 += steps;
            if last {
                break;
            }
        }
    }
}

/// One run of the accumulators: Σ over `steps` depth steps of A(:, kk) ⊗ B(kk, :) from 0, advancing
/// `a` and `b` past them. Its own function so that the accumulators, indexed only by constants
/// here, stay in registers (in `micro` the epilogue's loops index them, and LLVM then kept a stack
/// copy it stored to after every FMA, which halved the kernel's speed).
///
/// # Safety
/// As [`micro`], for `steps` depth steps from `a` and `b`.
#[inline(always)]
unsafe fn run<E: Copy, S: Simd<E>, const MR: usize, const NV: usize>(steps: usize, a: &mut *const E, b: &mut *const E,
                                                                    ldb: usize) -> [[S::V; NV]; MR] {
    let nr = NV * S::LANES;
    let line = 64 / std::mem::size_of::<E>();
    let (mut pa, mut pb) = (*a, *b);
    let mut acc = [[S::zero(); NV]; MR];
    // SAFETY: the caller's contract covers `steps` steps of both panels; prefetches never fault.
    unsafe {
        for _ in 0..steps {
            // acc[i][v] += A(i, kk) · B(kk, v·LANES .. (v + 1)·LANES)
            let bv: [S::V; NV] = std::array::from_fn(|v| S::load(pb.add(v * S::LANES)));
            for j in (0..nr).step_by(line) {
                S::prefetch(pb.wrapping_add(PREFETCH_K * ldb + j));
            }
            for (i, row) in acc.iter_mut().enumerate() {
                let ai = S::splat(*pa.add(i));
                for (r, &bb) in row.iter_mut().zip(&bv) {
                    *r = S::fma(ai, bb, *r);
                }
            }
            pa = pa.add(MR);
            pb = pb.add(ldb);
        }
    }
    (*a, *b) = (pa, pb);
    acc
}

/// Defines `$name::<E, MR, NV>`: [`micro`] compiled for one ISA (`$feat` is its `target_feature`).
macro_rules! isa_entry {
    ($name:ident, $isa:ty, $feat:literal) => {
        /// [`micro`] compiled with this ISA's target features.
        ///
        /// # Safety
        /// As [`micro`]; the CPU supports the ISA.
        #[target_feature(enable = $feat)]
        pub(crate) unsafe fn $name<E: Copy, const MR: usize, const NV: usize>(kc: usize, pa: *const E, pb: *const E,
                                                                          ldb: usize, t: &Tile<E>)
        where
            $isa: Simd<E>,
        {
            // SAFETY: forwarded contract; the target feature is enabled for this body.
            unsafe { micro::<E, $isa, MR, NV>(kc, pa, pb, ldb, t) }
        }
    };
}

#[cfg(target_arch = "x86_64")]
isa_entry!(avx512, super::simd::Avx512, "avx512f");
#[cfg(target_arch = "x86_64")]
isa_entry!(avx2, super::simd::Avx2, "avx2,fma");
#[cfg(target_arch = "x86_64")]
isa_entry!(avx512_bf16, super::simd::Avx512Bf16, "avx512f,avx512bf16");

/// [`micro`] on the portable path.
///
/// # Safety
/// As [`micro`].
pub(crate) unsafe fn generic<E: crate::Float, const MR: usize, const NV: usize>(kc: usize, pa: *const E, pb: *const E,
                                                                             ldb: usize, t: &Tile<E>) {
    // SAFETY: forwarded contract; the portable path needs no CPU feature.
    unsafe { micro::<E, super::simd::Generic, MR, NV>(kc, pa, pb, ldb, t) }
}
