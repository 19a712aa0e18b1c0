//! Vector helpers of the channels-last kernels (`warp_corr`, `gru`): a dot product and an axpy with a
//! fixed summation order, and the instruction set their loops are compiled for; blocked sums with
//! f64 totals (the norms' moments, the convolutions' bias gradient).
//!
//! A dot product keeps `LANES` running sums (element i goes to sum i mod `LANES`) and adds them
//! pairwise at the end. That order is part of the definition, not of the machine: the compiler maps
//! the sums onto one AVX-512 register, two AVX2 registers or four SSE2 registers, and without FMA
//! contraction every ISA computes the same bits. So results do not depend on the ISA or the thread count.
//!
//! The loops of `multiversion!` run on [`Isa::selected`](crate::Isa::selected), the one choice of
//! instruction set of the crate (`src/isa.rs`: `MIPNET_ISA`, else the widest the CPU has).

use crate::Float;

/// Running sums of [`dot`].
pub const LANES: usize = 16;

/// Σ a_i b_i over the common length, in the fixed order of the module doc.
#[inline(always)]
pub fn dot<F: Float>(a: &[F], b: &[F]) -> F {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [F::zero(); LANES];
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        let (x, y): (&[F; LANES], &[F; LANES]) = (x.try_into().expect("exact chunk"), y.try_into().expect("exact chunk"));
        for l in 0..LANES {
            // sum l collects the elements i with i mod LANES = l
            acc[l] += x[l] * y[l];
        }
    }
    for (l, (&x, &y)) in ra.iter().zip(rb).enumerate() {
        acc[l] += x * y;
    }
    // pairwise: sums l and l + half, halving until one is left
    let mut half = LANES / 2;
    while half > 0 {
        for l in 0..half {
            acc[l] = acc[l] + acc[l + half];
        }
        half /= 2;
    }
    acc[0]
}

/// y += alpha · x over the common length.
#[inline(always)]
pub fn axpy<F: Float>(alpha: F, x: &[F], y: &mut [F]) {
    y.iter_mut().zip(x).for_each(|(y, &x)| *y += alpha * x);
}

/// Elements a run of lane sums adds up in F before its total moves to the f64 running sum, which
/// bounds the growth of f32 rounding error (each lane sums BLOCK / LANES values).
const BLOCK: usize = 4096;

/// Σ_i term([run_0[i], .., run_K-1[i]]) over the runs' common length: per BLOCK, LANES running sums
/// in F (element i to sum i mod LANES) added up in f64, blocks in order. The order is fixed, so
/// results depend on neither the ISA nor the thread count.
#[inline(always)]
pub fn blocked_sum<F: Float, const K: usize>(runs: [&[F]; K], term: impl Fn([F; K]) -> F) -> f64 {
    let len = runs.iter().map(|r| r.len()).min().unwrap_or(0);
    let mut total = 0.0;
    for start in (0..len).step_by(BLOCK) {
        let end = (start + BLOCK).min(len);
        let mut acc = [F::zero(); LANES];
        let full = start + (end - start) / LANES * LANES;
        for i in (start..full).step_by(LANES) {
            let chunk: [&[F; LANES]; K] = std::array::from_fn(|k| runs[k][i..i + LANES].try_into().expect("LANES elements"));
            for (l, a) in acc.iter_mut().enumerate() {
                *a += term(std::array::from_fn(|k| chunk[k][l]));
            }
        }
        for (l, i) in (full..end).enumerate() {
            acc[l] += term(std::array::from_fn(|k| runs[k][i]));
        }
        total += acc.iter().map(|&a| a.to_f64().unwrap_or(f64::NAN)).sum::<f64>();
    }
    total
}

/// Defines `fn $name<F: Float>(args)` whose body is compiled three times (AVX-512F, AVX2, generic)
/// and dispatched on [`Isa::selected`](crate::Isa::selected). The body must only call
/// `#[inline(always)]` helpers for them to be compiled with the wider registers.
macro_rules! multiversion {
    ($(#[$meta:meta])* $vis:vis fn $name:ident<F: Float>($($arg:ident: $ty:ty),* $(,)?) $body:block) => {
        $(#[$meta])*
        $vis fn $name<F: $crate::Float>($($arg: $ty),*) {
            #[inline(always)]
            fn body<F: $crate::Float>($($arg: $ty),*) $body
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f")]
            unsafe fn avx512<F: $crate::Float>($($arg: $ty),*) {
                body($($arg),*)
            }
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2")]
            unsafe fn avx2<F: $crate::Float>($($arg: $ty),*) {
                body($($arg),*)
            }
            match $crate::Isa::selected() {
                // SAFETY: the selected ISA is one this CPU supports (AVX-512F here).
                #[cfg(target_arch = "x86_64")]
                $crate::Isa::Avx512 => unsafe { avx512($($arg),*) },
                // SAFETY: as above (AVX2, with FMA).
                #[cfg(target_arch = "x86_64")]
                $crate::Isa::Avx2 => unsafe { avx2($($arg),*) },
                _ => body($($arg),*),
            }
        }
    };
}
pub(crate) use multiversion;

multiversion! {
    /// out = Σ x_i over a run, in [`blocked_sum`]'s order (f64 across blocks).
    pub fn sum<F: Float>(x: &[F], out: &mut f64) {
        *out = blocked_sum([x], |[x]| x);
    }
}

/// e^x. f32: Cephes' `expf` (range reduction x = n·ln2 + r, degree-6 polynomial, about 1 ulp), written
/// without branches or calls so that loops over it vectorise; x is clamped to [-87.33, 88.37], the
/// range of normal results. f64: the platform's `exp`.
#[inline(always)]
pub fn exp<F: Float>(x: F) -> F {
    match as_f32(x) {
        Some(v) => from_f32(exp_f32(v)),
        None => x.exp(),
    }
}

/// σ(x) = 1 / (1 + e^-x), with [`exp`].
#[inline(always)]
pub fn sigmoid<F: Float>(x: F) -> F {
    F::one() / (F::one() + exp(-x))
}

/// tanh(x). f32: Cephes' `tanhf` (odd polynomial for |x| < 0.625, else 1 - 2 / (e^{2|x|} + 1), with
/// the sign of x; about 2 ulp), branch-free; f64: the platform's `tanh`.
#[inline(always)]
pub fn tanh<F: Float>(x: F) -> F {
    match as_f32(x) {
        Some(v) => from_f32(tanh_f32(v)),
        None => x.tanh(),
    }
}

#[inline(always)]
fn as_f32<F: Float>(x: F) -> Option<f32> {
    if std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>() {
        x.to_f32()
    } else {
        None
    }
}

#[inline(always)]
fn from_f32<F: Float>(v: f32) -> F {
    F::from(v).expect("F is f32")
}

#[inline(always)]
fn exp_f32(x: f32) -> f32 {
    let x = x.clamp(-87.336_54, 88.376_26);
    // n = round(x / ln 2); r = x - n·ln 2 in two parts (C1 + C2 = ln 2) for accuracy
    let n = (x * std::f32::consts::LOG2_E + 0.5).floor();
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let r2 = r * r;
    let p = (((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r + 1.666_666_5e-1) * r + 5.000_000_1e-1) * r2 + r + 1.0;
    // 2^n from its exponent bits (n + 127) << 23, n in [-126, 128]. The integer n + 127 is read from
    // the low mantissa bits of n + 127 + 2^23 (exact, and free of the float-to-int cast, whose
    // saturating semantics would not vectorise)
    let biased = (n + (127.0 + 8_388_608.0)).to_bits() - 8_388_608.0f32.to_bits();
    p * f32::from_bits(biased << 23)
}

#[inline(always)]
fn tanh_f32(x: f32) -> f32 {
    let a = x.abs();
    let z = x * x;
    // |x| < 0.625: x + x·z·P(z)
    let small = x + x * z * ((((-5.704_988_7e-3 * z + 2.063_908_9e-2) * z - 5.373_971_6e-2) * z + 1.333_144_2e-1) * z - 3.333_328_2e-1);
    // otherwise: sign(x)·(1 - 2 / (e^{2|x|} + 1))
    let large = (1.0 - 2.0 / (exp_f32(2.0 * a) + 1.0)).copysign(x);
    if a < 0.625 { small } else { large }
}
