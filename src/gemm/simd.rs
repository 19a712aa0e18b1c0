//! The SIMD vocabulary the GEMM's micro-kernel and the peak measurement are written in: one
//! implementation of [`Simd`] per [`Isa`](crate::Isa) path, for f32 and f64. Which path runs is
//! [`Isa::selected`](crate::Isa::selected)'s choice (`src/isa.rs`).

/// The vector operations the micro-kernel and the peak measurement use, for element type `E`.
///
/// # Safety
/// Implementations for an ISA may only be called where the CPU supports it (inside a function
/// compiled with that ISA's `target_feature`, reached after [`Isa::supported`](crate::Isa::supported)).
pub(crate) unsafe trait Simd<E: Copy>: Copy {
    /// One register of `LANES` elements.
    type V: Copy;
    const LANES: usize;
    unsafe fn zero() -> Self::V;
    unsafe fn splat(x: E) -> Self::V;
    /// Loads `LANES` elements from `p` (any alignment).
    unsafe fn load(p: *const E) -> Self::V;
    /// Stores `LANES` elements to `p` (any alignment).
    unsafe fn store(p: *mut E, v: Self::V);
    /// a + b.
    unsafe fn add(a: Self::V, b: Self::V) -> Self::V;
    /// a · b + c, rounded once where the ISA has FMA.
    unsafe fn fma(a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    /// max(a, 0) per lane; NaN gives 0, as `Float::max` in the relu op.
    unsafe fn relu(a: Self::V) -> Self::V;
    /// Hints that the cache line of `p` is read soon (no effect where the ISA has no prefetch).
    unsafe fn prefetch(p: *const E);
    /// The sum of the lanes (only the peak measurement uses it).
    unsafe fn sum(v: Self::V) -> E;
}

/// The AVX-512F path.
#[derive(Clone, Copy)]
pub(crate) struct Avx512;
/// The AVX2 + FMA path.
#[derive(Clone, Copy)]
pub(crate) struct Avx2;
/// The portable path.
#[derive(Clone, Copy)]
pub(crate) struct Generic;
/// AVX-512 with AVX512_BF16 on panels of bf16 pairs: each f32-sized element of A and B holds two bf16
/// values of consecutive depths (`pack::pair_panel`), and `fma` is `vdpbf16ps` (both products of a pair
/// added to the f32 accumulator). Loads, stores and the epilogue are those of [`Avx512`] on f32.
#[derive(Clone, Copy)]
pub(crate) struct Avx512Bf16;

/// Implements `Simd<$e>` for an x86 ISA from its intrinsics (one line per operation).
#[cfg(target_arch = "x86_64")]
macro_rules! x86_simd {
    ($isa:ty, $e:ty, $v:ty, $lanes:expr, zero $zero:ident, set1 $set1:ident, loadu $loadu:ident, storeu $storeu:ident,
     add $add:ident, fmadd $fmadd:ident, max $max:ident, sum $sum:expr) => {
        // SAFETY: every method is an intrinsic of the ISA; callers guarantee the CPU supports it.
        unsafe impl Simd<$e> for $isa {
            type V = $v;
            const LANES: usize = $lanes;
            #[inline(always)]
            unsafe fn zero() -> $v {
                // SAFETY: the caller runs on a CPU with this ISA.
                unsafe { std::arch::x86_64::$zero() }
            }
            #[inline(always)]
            unsafe fn splat(x: $e) -> $v {
                // SAFETY: as above.
                unsafe { std::arch::x86_64::$set1(x) }
            }
            #[inline(always)]
            unsafe fn load(p: *const $e) -> $v {
                // SAFETY: as above; the caller passes `LANES` readable elements.
                unsafe { std::arch::x86_64::$loadu(p) }
            }
            #[inline(always)]
            unsafe fn store(p: *mut $e, v: $v) {
                // SAFETY: as above; the caller passes `LANES` writable elements.
                unsafe { std::arch::x86_64::$storeu(p, v) }
            }
            #[inline(always)]
            unsafe fn add(a: $v, b: $v) -> $v {
                // SAFETY: as above.
                unsafe { std::arch::x86_64::$add(a, b) }
            }
            #[inline(always)]
            unsafe fn fma(a: $v, b: $v, c: $v) -> $v {
                // SAFETY: as above (the AVX2 path requires FMA too).
                unsafe { std::arch::x86_64::$fmadd(a, b, c) }
            }
            #[inline(always)]
            unsafe fn relu(a: $v) -> $v {
                // SAFETY: as above.
                // max returns its second operand (0) when a is NaN, as Float::max does
                unsafe { std::arch::x86_64::$max(a, std::arch::x86_64::$zero()) }
            }
            #[inline(always)]
            unsafe fn prefetch(p: *const $e) {
                // SAFETY: a prefetch never faults, whatever the address.
                unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p.cast()) }
            }
            #[inline(always)]
            unsafe fn sum(v: $v) -> $e {
                // SAFETY: as above.
                unsafe { $sum(v) }
            }
        }
    };
}

#[cfg(target_arch = "x86_64")]
x86_simd!(Avx512, f32, std::arch::x86_64::__m512, 16, zero _mm512_setzero_ps, set1 _mm512_set1_ps, loadu _mm512_loadu_ps,
          storeu _mm512_storeu_ps, add _mm512_add_ps, fmadd _mm512_fmadd_ps, max _mm512_max_ps, sum std::arch::x86_64::_mm512_reduce_add_ps);
#[cfg(target_arch = "x86_64")]
x86_simd!(Avx512, f64, std::arch::x86_64::__m512d, 8, zero _mm512_setzero_pd, set1 _mm512_set1_pd, loadu _mm512_loadu_pd,
          storeu _mm512_storeu_pd, add _mm512_add_pd, fmadd _mm512_fmadd_pd, max _mm512_max_pd, sum std::arch::x86_64::_mm512_reduce_add_pd);
#[cfg(target_arch = "x86_64")]
x86_simd!(Avx2, f32, std::arch::x86_64::__m256, 8, zero _mm256_setzero_ps, set1 _mm256_set1_ps, loadu _mm256_loadu_ps,
          storeu _mm256_storeu_ps, add _mm256_add_ps, fmadd _mm256_fmadd_ps, max _mm256_max_ps, sum sum_lanes::<f32, Avx2>);
#[cfg(target_arch = "x86_64")]
x86_simd!(Avx2, f64, std::arch::x86_64::__m256d, 4, zero _mm256_setzero_pd, set1 _mm256_set1_pd, loadu _mm256_loadu_pd,
          storeu _mm256_storeu_pd, add _mm256_add_pd, fmadd _mm256_fmadd_pd, max _mm256_max_pd, sum sum_lanes::<f64, Avx2>);

/// The lanes of `v` added in order, through memory (for paths without a reduction intrinsic).
#[cfg(target_arch = "x86_64")]
unsafe impl Simd<f32> for Avx512Bf16 {
    type V = std::arch::x86_64::__m512;
    const LANES: usize = 16;
    #[inline(always)]
    unsafe fn zero() -> Self::V {
        unsafe { <Avx512 as Simd<f32>>::zero() }
    }
    #[inline(always)]
    unsafe fn splat(x: f32) -> Self::V {
        // the pair's bits, broadcast unchanged (never an arithmetic operation on them)
        unsafe { std::arch::x86_64::_mm512_castsi512_ps(std::arch::x86_64::_mm512_set1_epi32(x.to_bits() as i32)) }
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> Self::V {
        unsafe { <Avx512 as Simd<f32>>::load(p) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: Self::V) {
        unsafe { <Avx512 as Simd<f32>>::store(p, v) }
    }
    #[inline(always)]
    unsafe fn add(a: Self::V, b: Self::V) -> Self::V {
        unsafe { <Avx512 as Simd<f32>>::add(a, b) }
    }
    #[inline(always)]
    unsafe fn fma(a: Self::V, b: Self::V, c: Self::V) -> Self::V {
        // c + a.bf16[2l]·b.bf16[2l] + a.bf16[2l+1]·b.bf16[2l+1] in lane l
        use std::arch::x86_64::{__m512bh, _mm512_dpbf16_ps};
        unsafe { _mm512_dpbf16_ps(c, std::mem::transmute::<Self::V, __m512bh>(a), std::mem::transmute::<Self::V, __m512bh>(b)) }
    }
    #[inline(always)]
    unsafe fn relu(a: Self::V) -> Self::V {
        unsafe { <Avx512 as Simd<f32>>::relu(a) }
    }
    #[inline(always)]
    unsafe fn prefetch(p: *const f32) {
        unsafe { <Avx512 as Simd<f32>>::prefetch(p) }
    }
    #[inline(always)]
    unsafe fn sum(v: Self::V) -> f32 {
        unsafe { <Avx512 as Simd<f32>>::sum(v) }
    }
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn sum_lanes<E: crate::Float, S: Simd<E>>(v: S::V) -> E {
    let mut lanes = [E::zero(); 16];
    // SAFETY: `lanes` holds 16 >= LANES elements.
    unsafe { S::store(lanes.as_mut_ptr(), v) };
    lanes[..S::LANES].iter().fold(E::zero(), |a, &x| a + x)
}

/// Lanes of the portable path's "register" (a plain array the compiler may keep in SIMD registers).
pub(crate) const GENERIC_LANES: usize = 4;

// SAFETY: plain Rust arithmetic on arrays; every pointer access is in-bounds by the caller's contract.
unsafe impl<E: crate::Float> Simd<E> for Generic {
    type V = [E; GENERIC_LANES];
    const LANES: usize = GENERIC_LANES;
    #[inline(always)]
    unsafe fn zero() -> Self::V {
        [E::zero(); GENERIC_LANES]
    }
    #[inline(always)]
    unsafe fn splat(x: E) -> Self::V {
        [x; GENERIC_LANES]
    }
    #[inline(always)]
    unsafe fn load(p: *const E) -> Self::V {
        // SAFETY: the caller passes LANES readable elements.
        unsafe { std::ptr::read_unaligned(p.cast()) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut E, v: Self::V) {
        // SAFETY: the caller passes LANES writable elements.
        unsafe { std::ptr::write_unaligned(p.cast(), v) }
    }
    #[inline(always)]
    unsafe fn add(a: Self::V, b: Self::V) -> Self::V {
        std::array::from_fn(|l| a[l] + b[l])
    }
    #[inline(always)]
    unsafe fn fma(a: Self::V, b: Self::V, c: Self::V) -> Self::V {
        // a·b + c with two roundings (a fused multiply-add would be a slow library call without FMA)
        std::array::from_fn(|l| a[l] * b[l] + c[l])
    }
    #[inline(always)]
    unsafe fn relu(a: Self::V) -> Self::V {
        a.map(|x| x.max(E::zero()))
    }
    #[inline(always)]
    unsafe fn prefetch(_: *const E) {}
    #[inline(always)]
    unsafe fn sum(v: Self::V) -> E {
        v.iter().fold(E::zero(), |a, &x| a + x)
    }
}
