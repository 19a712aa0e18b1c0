//! Which instruction set the GEMM runs on, and the SIMD vocabulary its micro-kernel is written in.
//!
//! [`Isa::selected`] is the one run-time choice: the environment variable `MIPNET_ISA`
//! (`avx512`, `avx2` or `generic`), read once, else the widest ISA the CPU has. The micro-kernel is
//! written once, generic over [`Simd`]; each ISA implements `Simd` for f32 and f64.

use std::sync::OnceLock;

/// An instruction set the GEMM has a path for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Isa {
    /// AVX-512F: 32 registers of 16 f32.
    Avx512,
    /// AVX2 with FMA: 16 registers of 8 f32.
    Avx2,
    /// Portable Rust, no intrinsics (the compiler vectorises what it can with the baseline ISA).
    Generic,
}

/// Name of the environment variable that forces an ISA.
pub const ISA_ENV: &str = "MIPNET_ISA";

impl Isa {
    /// Every path, widest first.
    pub const ALL: [Isa; 3] = [Isa::Avx512, Isa::Avx2, Isa::Generic];

    /// Position in [`Isa::ALL`].
    pub fn index(self) -> usize {
        match self {
            Isa::Avx512 => 0,
            Isa::Avx2 => 1,
            Isa::Generic => 2,
        }
    }

    /// The name `MIPNET_ISA` takes.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Avx512 => "avx512",
            Isa::Avx2 => "avx2",
            Isa::Generic => "generic",
        }
    }

    /// Whether this CPU can run the path.
    pub fn supported(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => is_x86_feature_detected!("avx512f"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"),
            Isa::Generic => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The widest path this CPU supports.
    pub fn detected() -> Isa {
        Isa::ALL.into_iter().find(|i| i.supported()).unwrap_or(Isa::Generic)
    }

    /// The path named `s` (case-insensitive), if this CPU supports it.
    pub fn parse(s: &str) -> Result<Isa, String> {
        let want = s.trim().to_ascii_lowercase();
        let Some(isa) = Isa::ALL.into_iter().find(|i| i.name() == want) else {
            return Err(format!("{ISA_ENV}={s:?} is not an ISA mipnet has; use one of avx512, avx2, generic (or unset it)"));
        };
        if !isa.supported() {
            return Err(format!("{ISA_ENV}={s:?}: this CPU does not support {}; it supports {}", isa.name(),
                               Isa::ALL.into_iter().filter(|i| i.supported()).map(Isa::name).collect::<Vec<_>>().join(", ")));
        }
        Ok(isa)
    }

    /// `MIPNET_ISA` as read once at start-up: Ok(None) when unset or empty, Err with the reason when it
    /// names no ISA or one this CPU lacks (the Python module refuses to import then).
    pub fn from_env() -> Result<Option<Isa>, String> {
        static ENV: OnceLock<Result<Option<Isa>, String>> = OnceLock::new();
        ENV.get_or_init(|| match std::env::var(ISA_ENV) {
            Ok(v) if !v.trim().is_empty() => Isa::parse(&v).map(Some),
            _ => Ok(None),
        })
        .clone()
    }

    /// The path every GEMM takes: `MIPNET_ISA` if it is valid, else the detected one. (An invalid
    /// value is reported by [`Isa::from_env`]; the Python module refuses to import with it.)
    pub fn selected() -> Isa {
        static SEL: OnceLock<Isa> = OnceLock::new();
        *SEL.get_or_init(|| Isa::from_env().ok().flatten().unwrap_or_else(Isa::detected))
    }

    /// Bits of one vector register of this path.
    pub fn vector_bits(self) -> usize {
        match self {
            Isa::Avx512 => 512,
            Isa::Avx2 => 256,
            Isa::Generic => 128,
        }
    }
}

/// The vector operations the micro-kernel and the peak measurement use, for element type `E`.
///
/// # Safety
/// Implementations for an ISA may only be called where the CPU supports it (inside a function
/// compiled with that ISA's `target_feature`, reached after [`Isa::supported`]).
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
