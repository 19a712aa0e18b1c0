//! Vector helpers of the channels-last kernels (`warp_corr`, `gru`): a dot product and an axpy with a
//! fixed summation order, and the instruction set their loops are compiled for.
//!
//! A dot product keeps `LANES` running sums (element i goes to sum i mod `LANES`) and adds them
//! pairwise at the end. That order is part of the definition, not of the machine: the compiler maps
//! the sums onto one AVX-512 register, two AVX2 registers or four SSE2 registers, and without FMA
//! contraction every ISA computes the same bits. So results do not depend on the ISA or the thread count.
//!
//! `MIPNET_ISA` (`avx512`, `avx2`, `generic`) lowers the instruction set below what the CPU offers.

use crate::Float;
use std::sync::OnceLock;

/// Running sums of [`dot`].
pub const LANES: usize = 16;

/// The instruction set the multiversioned loops run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    Generic,
    Avx2,
    Avx512,
}

/// The best instruction set of this CPU, capped by `MIPNET_ISA`; decided once per process.
pub fn isa() -> Isa {
    static ISA: OnceLock<Isa> = OnceLock::new();
    *ISA.get_or_init(|| {
        let cpu = detect();
        match std::env::var("MIPNET_ISA").ok().as_deref().map(str::trim) {
            Some("generic") => Isa::Generic,
            Some("avx2") => cpu.min(Isa::Avx2),
            _ => cpu,
        }
    })
}

fn detect() -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        if is_x86_feature_detected!("avx512f") {
            return Isa::Avx512;
        }
        if is_x86_feature_detected!("avx2") {
            return Isa::Avx2;
        }
    }
    Isa::Generic
}

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

/// Defines `fn $name<F: Float>(args)` whose body is compiled three times (AVX-512F, AVX2, generic)
/// and dispatched on [`isa`]. The body must only call `#[inline(always)]` helpers for them to be
/// compiled with the wider registers.
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
            match $crate::ops::lanes::isa() {
                // SAFETY: isa() reports AVX-512F only where the CPU has it.
                #[cfg(target_arch = "x86_64")]
                $crate::ops::lanes::Isa::Avx512 => unsafe { avx512($($arg),*) },
                // SAFETY: isa() reports AVX2 only where the CPU has it.
                #[cfg(target_arch = "x86_64")]
                $crate::ops::lanes::Isa::Avx2 => unsafe { avx2($($arg),*) },
                _ => body($($arg),*),
            }
        }
    };
}
pub(crate) use multiversion;
