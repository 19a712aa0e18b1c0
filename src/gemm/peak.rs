//! The measured FMA peak: what the GEMM's GFLOP/s are a share of.
//!
//! Each thread runs `CHAINS` independent chains acc <- acc·x + y on full vectors of the ISA, enough
//! chains to cover the FMA latency times the FMA ports of any current core (4 cycles x 2 ports),
//! so the loop is bound by FMA throughput alone. Threads start together behind a barrier; the
//! result is the best of several timed repetitions.

use super::simd::Simd;
use super::Isa;
use crate::{Error, Result};
use std::sync::Barrier;
use std::time::Instant;

/// Independent accumulators per thread (registers: 16 of AVX-512's 32, 12 of AVX2's 16).
const CHAINS_WIDE: usize = 16;
const CHAINS_AVX2: usize = 12;
const CHAINS_GENERIC: usize = 8;
/// Timed repetitions (the best counts) after one untimed warm-up repetition.
const REPS: usize = 5;
/// Wall time of one repetition, about.
const REP_SECONDS: f64 = 0.02;

/// `iters` steps of `C` chains acc[c] <- acc[c]·x + y; returns a sum of the accumulators so the
/// work cannot be optimised away.
#[inline(always)]
unsafe fn chains<S: Simd<f32>, const C: usize>(iters: usize) -> f32 {
    // SAFETY: the caller runs on a CPU with S's ISA; there is no memory access.
    unsafe {
        // x < 1 and y > 0: each chain converges to y / (1 − x), no overflow and no denormals
        let (x, y) = (S::splat(1.0 - 1.0 / 1024.0), S::splat(1.0 / 1024.0));
        let mut acc = [S::zero(); C];
        for _ in 0..iters {
            for a in acc.iter_mut() {
                *a = S::fma(*a, x, y);
            }
        }
        acc.iter().fold(0.0, |s, &a| s + S::sum(a))
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn chains_avx512(iters: usize) -> f32 {
    // SAFETY: AVX-512F is enabled for this body; the caller checked the CPU has it.
    unsafe { chains::<super::simd::Avx512, CHAINS_WIDE>(iters) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn chains_avx2(iters: usize) -> f32 {
    // SAFETY: AVX2 and FMA are enabled for this body; the caller checked the CPU has them.
    unsafe { chains::<super::simd::Avx2, CHAINS_AVX2>(iters) }
}

fn chains_generic(iters: usize) -> f32 {
    // SAFETY: the portable path needs no CPU feature.
    unsafe { chains::<super::simd::Generic, CHAINS_GENERIC>(iters) }
}

/// Runs [`chains`] on AVX-512 (reached only after `Isa::supported`).
#[cfg(target_arch = "x86_64")]
fn run_avx512(iters: usize) -> f32 {
    // SAFETY: `fma_peak_gflops` picks this loop only when the CPU has AVX-512F.
    unsafe { chains_avx512(iters) }
}

/// Runs [`chains`] on AVX2 + FMA (reached only after `Isa::supported`).
#[cfg(target_arch = "x86_64")]
fn run_avx2(iters: usize) -> f32 {
    // SAFETY: `fma_peak_gflops` picks this loop only when the CPU has AVX2 and FMA.
    unsafe { chains_avx2(iters) }
}

/// The loop of `isa` and the floating-point operations of one of its iterations
/// (2 per lane per chain: one multiply, one add).
fn kernel(isa: Isa) -> (fn(usize) -> f32, f64) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => (run_avx512, 2.0 * (CHAINS_WIDE * 16) as f64),
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => (run_avx2, 2.0 * (CHAINS_AVX2 * 8) as f64),
        _ => (chains_generic, 2.0 * (CHAINS_GENERIC * super::simd::GENERIC_LANES) as f64),
    }
}

/// The f32 FMA throughput of `threads` threads running at once on `isa`, in GFLOP/s (all threads
/// together; with one thread, the peak of one core). Takes about 0.15 s.
///
/// Fails for 0 threads or an ISA this CPU lacks.
pub fn fma_peak_gflops(threads: usize, isa: Isa) -> Result<f64> {
    const OP: &str = "fma_peak_gflops";
    if threads == 0 {
        return Err(Error::arg(OP, "threads must be at least 1"));
    }
    if !isa.supported() {
        return Err(Error::arg(OP, format!("this CPU does not support {}", isa.name())));
    }
    let (run, flops_per_iter) = kernel(isa);
    // iterations of one repetition, from a short calibration run
    let t0 = Instant::now();
    std::hint::black_box(run(1 << 16));
    let per_iter = t0.elapsed().as_secs_f64().max(1e-9) / f64::from(1 << 16);
    let iters = ((REP_SECONDS / per_iter) as usize).max(1 << 16);
    let barrier = Barrier::new(threads);
    let best = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    (0..=REPS)
                        .map(|_| {
                            barrier.wait();
                            let t = Instant::now();
                            std::hint::black_box(run(std::hint::black_box(iters)));
                            let dt = t.elapsed().as_secs_f64();
                            barrier.wait();
                            dt
                        })
                        .collect::<Vec<f64>>()
                })
            })
            .collect();
        let times: Vec<Vec<f64>> = workers.into_iter().map(|w| w.join().unwrap_or_default()).collect();
        // repetition r lasts as long as its slowest thread; the first one is the warm-up
        (1..=REPS)
            .map(|r| times.iter().map(|t| t.get(r).copied().unwrap_or(f64::INFINITY)).fold(0.0, f64::max))
            .fold(f64::INFINITY, f64::min)
    });
    // GFLOP/s = threads · iterations · flops per iteration / seconds / 1e9
    Ok(threads as f64 * iters as f64 * flops_per_iter / best / 1e9)
}
