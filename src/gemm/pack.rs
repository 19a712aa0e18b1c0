//! Packing: copying a block of an operand into the layout the micro-kernel reads.
//!
//! A panel of width w over kc steps of depth is stored `dst[kk·w + j]` (depth-major), zero-padded
//! past the used width: A in MR-row panels, B as one panel as wide as the block (NC columns rounded
//! up to NR, so each depth row of the block is one contiguous run the kernel reads NR columns of).
//! A source describes where the operand's elements come from: a strided matrix ([`Strided`]), an
//! already packed A ([`Prepacked`]), or one that builds its values on the fly (conv's im2col, in
//! `ops/conv.rs`).

use super::Plan;
use crate::Float;
use rayon::prelude::*;

/// The A operand (m x k, broadcast along rows) of one GEMM call.
#[derive(Clone, Copy)]
pub(crate) enum SourceA<'a, E> {
    /// Packed by the GEMM, MC rows at a time.
    Strided(&'a Strided<E>),
    /// Packed once by the caller for this plan: its rows from the second field on (a multiple of MR).
    Rows(&'a Prepacked<E>, usize),
}

/// A source of the B operand (k x n, loaded as vectors along columns).
pub(crate) trait PackB<E>: Sync {
    /// Packs columns `j0..j0 + nc` over depth `p0..p0 + kc` into `dst` row-major with row stride
    /// `ldb` >= nc rounded up to NR: `dst[kk·ldb + j]` = B(p0 + kk, j0 + j), 0 for nc <= j < ldb.
    #[allow(clippy::too_many_arguments)]
    fn pack(&self, plan: &Plan<E>, p0: usize, kc: usize, j0: usize, nc: usize, dst: *mut E, ldb: usize);

    /// The block at depth p0, columns `j0..j0 + ldb`, read where it lies instead of packed: its
    /// first element and row stride, when B's storage already has the packed layout (row-major,
    /// unit column stride, all ldb columns present). None: [`PackB::pack`] it.
    fn in_place(&self, _p0: usize, _j0: usize, _ldb: usize) -> Option<(*const E, usize)> {
        None
    }

    /// For a bf16 plan: the block at depth p0 (even), columns `j0..j0 + ldb`, already as the panel of
    /// bf16 pairs the micro-kernel reads, where it lies: its first pair and the row stride of the pair
    /// rows. None: the block is packed (or read in place) as f32 and paired by the GEMM.
    fn paired_in_place(&self, _p0: usize, _j0: usize, _ldb: usize) -> Option<(*const E, usize)> {
        None
    }
}

/// A strided matrix `x[i, j]` = `*(ptr + i·rs + j·cs)` of rows x cols, scaled by `scale` when packed.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Strided<E> {
    pub ptr: *const E,
    pub rows: usize,
    pub cols: usize,
    pub rs: isize,
    pub cs: isize,
    pub scale: E,
}

// SAFETY: a Strided only reads through its pointer, which callers keep valid for the GEMM call;
// the GEMM's tasks share it read-only.
unsafe impl<E: Sync> Sync for Strided<E> {}

impl<E: Float> Strided<E> {
    /// A matrix view (any strides) as a GEMM operand, scaled by `scale` when packed.
    pub(crate) fn view(m: ndarray::ArrayView2<E>, scale: E) -> Self {
        let st = m.strides();
        Strided { ptr: m.as_ptr(), rows: m.nrows(), cols: m.ncols(), rs: st[0], cs: st[1], scale }
    }

    /// Address of element (i, j).
    pub(crate) fn at(&self, i: usize, j: usize) -> *const E {
        self.ptr.wrapping_offset(i as isize * self.rs + j as isize * self.cs)
    }
}

impl<E: Float> Strided<E> {
    /// Packs rows `i0..i0 + mc` over all of the depth into `dst` in the layout of [`Prepacked`]: K
    /// block (of `plan.kc_for(k)`) after K block (the block at depth p0 starts at p0·mpad, mpad = mc rounded up to MR),
    /// each holding the MR-row panels (kc·MR elements each, zero rows past mc).
    ///
    /// # Safety
    /// `dst` has room for mpad·max(k, 1) elements; rows i0..i0 + mc exist.
    pub(crate) unsafe fn pack_rows(&self, plan: &Plan<E>, i0: usize, mc: usize, dst: *mut E) {
        let (mr, k) = (plan.mr, self.cols);
        let mpad = mc.div_ceil(mr) * mr;
        let kcb = plan.kc_for(k);
        for p0 in (0..k).step_by(kcb) {
            let kc = kcb.min(k - p0);
            for (p, r0) in (i0..i0 + mc).step_by(mr).enumerate() {
                // panel p of block p0 at p0·mpad + p·kc·MR
                // SAFETY: the panel lies inside `dst` and rows r0.. < i0 + mc exist.
                unsafe { self.pack_panel(plan, p0, kc, r0, i0 + mc, dst.add(p0 * mpad + p * kc * mr)) };
            }
        }
    }

    /// One MR-row panel of the layout of [`Strided::pack_rows`]: rows r0..min(r0 + MR, end) (zero rows
    /// after) at depths p0..p0 + kc, row index i along rs, depth kk along cs, into `dst` (kc·MR elements).
    ///
    /// # Safety
    /// `dst` has room for kc·MR elements; rows r0..min(r0 + MR, end) and depths p0..p0 + kc exist.
    unsafe fn pack_panel(&self, plan: &Plan<E>, p0: usize, kc: usize, r0: usize, end: usize, dst: *mut E) {
        let mr = plan.mr;
        // SAFETY: forwarded contract.
        unsafe { panel(plan, kc, mr.min(end - r0), mr, self.at(r0, p0), self.rs, self.cs, self.scale, dst) };
    }
}

impl<E: Float> PackB<E> for Strided<E> {
    fn pack(&self, plan: &Plan<E>, p0: usize, kc: usize, j0: usize, nc: usize, dst: *mut E, ldb: usize) {
        // one panel of width ldb: index j along cs, depth kk along rs
        // SAFETY: the block lies inside `dst` (kc·ldb elements) and the elements read inside the matrix.
        unsafe { panel(plan, kc, nc, ldb, self.at(p0, j0), self.cs, self.rs, self.scale, dst) };
    }
}

/// A row-major B (unit column stride) whose blocks the micro-kernel reads in place: those with all
/// `ldb` columns inside the matrix (a last, narrower block is packed). For operands whose row
/// stride is short (a few KiB, not a power of two), so the block's rows do not collide in the
/// caches: the Winograd transforms' V, written just before the GEMM that reads it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct InPlace<E>(pub Strided<E>);

impl<E: Float> PackB<E> for InPlace<E> {
    fn pack(&self, plan: &Plan<E>, p0: usize, kc: usize, j0: usize, nc: usize, dst: *mut E, ldb: usize) {
        self.0.pack(plan, p0, kc, j0, nc, dst, ldb)
    }

    fn in_place(&self, p0: usize, j0: usize, ldb: usize) -> Option<(*const E, usize)> {
        let b = &self.0;
        let readable = b.cs == 1 && b.rs > 0 && b.scale == E::one() && j0 + ldb <= b.cols;
        readable.then(|| (b.at(p0, j0), b.rs as usize))
    }
}

/// A B stored as bf16 pairs of its depth rows, in the layout [`pair_panel`] writes: `pairs` (rows =
/// ceil(K / 2) pair rows, unit column stride) holds in element (q, j) the bits of B(2q, j) in its low
/// half and B(2q + 1, j) in its high half (0 past K). The Winograd transforms of a bf16 plan write V so,
/// and the micro-kernel then reads it in place; blocks with columns outside the storage are unpacked
/// to f32 and paired again by the GEMM.
#[derive(Clone, Copy, Debug)]
pub(crate) struct InPlacePairs<E> {
    pub pairs: Strided<E>,
    /// Depth rows of B (K).
    pub depth: usize,
}

impl<E: Float> PackB<E> for InPlacePairs<E> {
    fn pack(&self, _plan: &Plan<E>, p0: usize, kc: usize, j0: usize, nc: usize, dst: *mut E, ldb: usize) {
        debug_assert_eq!(std::mem::size_of::<E>(), 4, "bf16 pairs are 32-bit elements");
        for kk in 0..kc {
            let (q, high) = ((p0 + kk) / 2, (p0 + kk) % 2 == 1);
            for j in 0..ldb {
                // dst[kk·ldb + j] = B(p0 + kk, j0 + j): the pair's half widened to f32 (exact), 0 past nc
                let value = if j < nc {
                    // SAFETY: pair row q < ceil(K / 2) and column j0 + j < cols lie in the storage.
                    let bits = unsafe { *self.pairs.at(q, j0 + j).cast::<u32>() };
                    E::from_f32(f32::from_bits(if high { bits & 0xFFFF_0000 } else { bits << 16 })).unwrap_or_else(E::zero)
                } else {
                    E::zero()
                };
                // SAFETY: dst has kc rows of ldb elements (the trait's contract).
                unsafe { *dst.add(kk * ldb + j) = value };
            }
        }
    }

    fn paired_in_place(&self, p0: usize, j0: usize, ldb: usize) -> Option<(*const E, usize)> {
        let b = &self.pairs;
        let readable = p0 % 2 == 0 && p0 < self.depth.max(1) && b.cs == 1 && b.rs > 0 && j0 + ldb <= b.cols;
        readable.then(|| (b.at(p0 / 2, j0), b.rs as usize))
    }
}

/// A whole A packed once for a plan (conv weights: packed once per call, shared by its tasks), in
/// the layout of [`Strided::pack_rows`]; for a bf16 plan (`plan.pairs`) each panel is already the
/// panel of depth pairs that [`pair_panel`] makes of it, so the GEMM reads it as it is.
pub(crate) struct Prepacked<E> {
    data: Vec<E>,
    /// Rows rounded up to a multiple of MR.
    pub(crate) mpad: usize,
    mr: usize,
    kc: usize,
    /// Depth of A.
    k: usize,
    /// Panels of bf16 pairs (packed for a bf16 plan).
    pairs: bool,
}

impl<E: Float> Prepacked<E> {
    /// Packs `a` (m x k) for `plan`, panel by panel in parallel (the layout of [`Strided::pack_rows`],
    /// as bf16 pairs for a bf16 plan).
    pub(crate) fn new(plan: &Plan<E>, a: &Strided<E>) -> Self {
        let (mr, k, pairs) = (plan.mr, a.cols, plan.pairs);
        let mpad = a.rows.div_ceil(mr) * mr;
        // rows of a panel over depth kc: kc, or ceil(kc / 2) rows of pairs (every block but the last
        // has an even depth, so the pairs never straddle two blocks)
        let depth = |kc: usize| if pairs { kc.div_ceil(2) } else { kc };
        let len = mpad * depth(k).max(1);
        if k == 0 || a.rows == 0 {
            return Prepacked { data: vec![E::zero(); len], mpad, mr, kc: plan.kc, k, pairs };
        }
        // every panel below is written whole (padding rows included), so nothing is zeroed first
        let mut data = Vec::<E>::with_capacity(len);
        let kcb = plan.kc_for(k);
        // K block p0 = b·kcb is the b-th run of mpad·depth(kcb) elements, panel p of it (rows p·MR..)
        // the p-th run of depth(kc)·MR elements there
        data.spare_capacity_mut()[..len].par_chunks_mut(mpad * depth(kcb)).enumerate().for_each(|(b, block)| {
            let (p0, kc) = (b * kcb, kcb.min(k - b * kcb));
            block.par_chunks_mut(depth(kc) * mr).enumerate().for_each_init(Vec::new, |f32_panel: &mut Vec<E>, (p, dst)| {
                let dst = dst.as_mut_ptr().cast::<E>();
                // SAFETY: dst holds depth(kc)·MR elements (MaybeUninit<E> is laid out as E), all written
                // below; rows p·MR.. < a.rows and depths p0..p0 + kc exist. A bf16 plan is an f32 plan on a
                // CPU with AVX512_BF16 (`Plan::bf16`), which `pair_panel` needs.
                unsafe {
                    if pairs {
                        f32_panel.resize(kc * mr, E::zero());
                        a.pack_panel(plan, p0, kc, p * mr, a.rows, f32_panel.as_mut_ptr());
                        pair_panel(kc, mr, f32_panel.as_ptr().cast(), mr, dst.cast());
                    } else {
                        a.pack_panel(plan, p0, kc, p * mr, a.rows, dst);
                    }
                }
            });
        });
        // SAFETY: the blocks cover the first len elements and every panel was written whole.
        unsafe { data.set_len(len) };
        Prepacked { data, mpad, mr, kc: plan.kc, k, pairs }
    }

    /// Bytes of the packed data.
    pub(crate) fn bytes(&self) -> usize {
        std::mem::size_of_val(self.data.as_slice())
    }

    /// The packed data, after checking it was packed for `plan`'s MR, KC and pairing and for depth k,
    /// and that `row0` starts a panel.
    pub(crate) fn data(&self, plan: &Plan<E>, k: usize, row0: usize) -> Option<*const E> {
        let fits = plan.mr == self.mr && plan.kc == self.kc && plan.pairs == self.pairs && k == self.k
            && row0.is_multiple_of(self.mr) && row0 <= self.mpad;
        fits.then_some(self.data.as_ptr())
    }
}

/// Packs one panel: `dst[kk·w + j]` = scale · `src[j·ps + kk·ks]` for kk < kc, j < used (0 for
/// used <= j < w). A unit panel stride copies rows; a unit depth stride (a transpose) goes by 8 x 8
/// register transposes for f32 where the ISA has AVX. (The zero bits of 0.0 are written with
/// `write_bytes`.)
///
/// # Safety
/// `src` reads lie in the operand, `dst` has kc·w elements.
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn panel<E: Float>(plan: &Plan<E>, kc: usize, used: usize, w: usize, src: *const E, ps: isize, ks: isize,
                          scale: E, dst: *mut E) {
    let one = scale == E::one();
    // SAFETY: every access is within the ranges of the contract.
    unsafe {
        if ps == 1 && one {
            for kk in 0..kc {
                // dst row kk = src(kk, 0..used), contiguous
                std::ptr::copy_nonoverlapping(src.offset(kk as isize * ks), dst.add(kk * w), used);
            }
        } else {
            let (j0, k8) = if ks == 1 && one { transpose_blocks(plan, kc, used, w, src, ps, dst) } else { (0, 0) };
            for j in 0..used {
                // the rest element by element: columns past the 8-blocks, and the depth tail of the others
                let from = if j < j0 { k8 } else { 0 };
                for kk in from..kc {
                    *dst.add(kk * w + j) = scale * *src.offset(j as isize * ps + kk as isize * ks);
                }
            }
        }
        if used < w {
            for kk in 0..kc {
                // the padding columns used..w of row kk, one contiguous run
                std::ptr::write_bytes(dst.add(kk * w + used), 0, w - used);
            }
        }
    }
}

/// The part of a unit-depth-stride panel done by 8 x 8 register transposes (f32 on an x86 path
/// other than the portable one): `dst[(k0 + t)·w + j0 + i]` = `src[(j0 + i)·ps + k0 + t]` for whole
/// 8 x 8 blocks. Returns (columns, depth) covered: columns below the first from depth the second
/// on, and all columns past the first, are left to the caller.
///
/// # Safety
/// As [`panel`].
#[cfg(target_arch = "x86_64")]
unsafe fn transpose_blocks<E: Float>(plan: &Plan<E>, kc: usize, used: usize, w: usize, src: *const E, ps: isize,
                                     dst: *mut E) -> (usize, usize) {
    if std::any::TypeId::of::<E>() != std::any::TypeId::of::<f32>() || plan.isa == super::Isa::Generic {
        return (0, 0);
    }
    let (k8, j8) = (kc / 8 * 8, used / 8 * 8);
    // depth blocks outer: the 8 destination rows of a block are written whole before the next
    for k0 in (0..k8).step_by(8) {
        for j0 in (0..j8).step_by(8) {
            // E is f32 (checked above): the casts only rename the element type.
            // SAFETY: AVX is present on every non-portable x86 path; the block lies in the panel.
            unsafe { transpose8(src.offset(j0 as isize * ps + k0 as isize).cast(), ps, dst.add(k0 * w + j0).cast(), w) };
        }
    }
    (j8, k8)
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn transpose_blocks<E: Float>(_: &Plan<E>, _: usize, _: usize, _: usize, _: *const E, _: isize, _: *mut E)
                                     -> (usize, usize) {
    (0, 0)
}

/// dst[t·ds + i] = src[i·ss + t] for i, t in 0..8: an 8 x 8 transpose in AVX registers.
///
/// # Safety
/// AVX is available; 8 rows of 8 readable floats at `src` (stride ss) and writable at `dst` (stride ds).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn transpose8(src: *const f32, ss: isize, dst: *mut f32, ds: usize) {
    use std::arch::x86_64::*;
    // SAFETY: the reads and writes stay in the 8 x 8 blocks of the contract.
    unsafe {
        let r: [__m256; 8] = std::array::from_fn(|i| _mm256_loadu_ps(src.offset(i as isize * ss)));
        // pairs of rows interleaved, then pairs of pairs, then the 128-bit halves swapped into place
        let t: [__m256; 8] = std::array::from_fn(|i| {
            let (a, b) = (r[i / 2 * 2], r[i / 2 * 2 + 1]);
            if i % 2 == 0 { _mm256_unpacklo_ps(a, b) } else { _mm256_unpackhi_ps(a, b) }
        });
        let u: [__m256; 8] = std::array::from_fn(|i| {
            // u[4q + 2h + s] from t[4q + h] and t[4q + h + 2]: s = 0 takes the low pairs, s = 1 the high
            let (q, h, s) = (i / 4, (i / 2) % 2, i % 2);
            let (a, b) = (t[4 * q + h], t[4 * q + h + 2]);
            if s == 0 { _mm256_shuffle_ps::<0x44>(a, b) } else { _mm256_shuffle_ps::<0xEE>(a, b) }
        });
        for t in 0..8 {
            // output row t: 128-bit half t / 4 of u[t % 4] (rows 0-3) and of u[t % 4 + 4] (rows 4-7)
            let (lo, hi) = (u[t % 4], u[t % 4 + 4]);
            let o = if t < 4 { _mm256_permute2f128_ps::<0x20>(lo, hi) } else { _mm256_permute2f128_ps::<0x31>(lo, hi) };
            _mm256_storeu_ps(dst.add(t * ds), o);
        }
    }
}

/// The bf16 bits of x, rounded to nearest even (NaN stays a quiet NaN).
#[inline(always)]
pub(crate) fn bf16_bits(x: f32) -> u32 {
    let b = x.to_bits();
    if x.is_nan() {
        return 0x7FC0;
    }
    // add half an ulp of bf16 (less one, plus the kept lowest bit: ties to even), keep the high 16 bits
    b.wrapping_add(0x7FFF + ((b >> 16) & 1)) >> 16
}

/// `dst[q·w + j]` = the bf16 pair (src[2q·ld + j], src[(2q + 1)·ld + j]) for q < ceil(kc / 2), j < w, the
/// even depth in the low half, 0 past depth kc: a depth-major f32 panel (w wide, rows `ld` apart) as the
/// panel of bf16 pairs [`super::simd::Avx512Bf16`] reads, ceil(kc / 2) rows of w f32-sized elements.
/// Runs of 16 columns go through `vcvtne2ps2bf16` (the same rounding as [`bf16_bits`], denormals to 0).
///
/// # Safety
/// `src` has kc rows of w readable elements `ld` apart, `dst` room for ceil(kc / 2)·w elements; the CPU
/// has AVX512_BF16 (only the bf16 plan calls this).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
pub(crate) unsafe fn pair_panel(kc: usize, w: usize, src: *const f32, ld: usize, dst: *mut f32) {
    use std::arch::x86_64::*;
    // output element 2j takes bf16 j (the even row's column j), 2j + 1 takes bf16 16 + j (the odd row's)
    let interleave = _mm512_set_epi16(31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5,
                                      20, 4, 19, 3, 18, 2, 17, 1, 16, 0);
    let w16 = w / 16 * 16;
    for q in 0..kc.div_ceil(2) {
        // SAFETY: rows 2q and 2q + 1 < kc of src and row q of dst are in their buffers (the contract).
        unsafe {
            let even = src.add(2 * q * ld);
            let odd = (2 * q + 1 < kc).then(|| src.add((2 * q + 1) * ld));
            let out = dst.add(q * w);
            for j in (0..w16).step_by(16) {
                // columns j..j + 16 of both rows: 16 pairs, the odd row 0 past depth kc
                let e = _mm512_loadu_ps(even.add(j));
                let o = odd.map_or(_mm512_setzero_ps(), |o| _mm512_loadu_ps(o.add(j)));
                let halves: __m512i = std::mem::transmute(_mm512_cvtne2ps_pbh(o, e));
                _mm512_storeu_si512(out.add(j).cast(), _mm512_permutexvar_epi16(interleave, halves));
            }
            for j in w16..w {
                let high = odd.map_or(0, |o| bf16_bits(*o.add(j)) << 16);
                *out.add(j) = f32::from_bits(bf16_bits(*even.add(j)) | high);
            }
        }
    }
}

/// Off x86 there is no bf16 plan, so nothing calls this.
#[cfg(not(target_arch = "x86_64"))]
pub(crate) unsafe fn pair_panel(_: usize, _: usize, _: *const f32, _: usize, _: *mut f32) {
    unreachable!("pair_panel: no bf16 plan off x86")
}
