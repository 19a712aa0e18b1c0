//! Times mipnet's GEMM (`src/gemm.rs`), and its bfloat16 plan where the CPU has one, against the
//! `matrixmultiply` crate on the products a MIPNet
//! training step runs, one thread each (every task of a convolution is a one-thread GEMM), on the
//! same row-major operands. Prints one row per shape class: both times, GFLOP/s and the crate's time
//! over ours. The convolution rows time the im2col product alone: mipnet builds its columns inside
//! the GEMM's packing, the crate would need them built first, so those rows flatter the crate.
//!
//! cargo run --release --example gemm_compare [-- REPEATS]

use _core::gemm::{cpu_info, fma_peak_gflops, gemm_ex, Epilogue, Plan};
use ndarray::Array2;
use std::time::Instant;

/// (shape class, M, K, N): C[M, N] = A[M, K] · B[K, N].
const SHAPES: &[(&str, usize, usize, usize)] = &[
    ("Winograd ξ-GEMM, encoder 64->64 (192x256, a task's tiles)", 64, 64, 768),
    ("Winograd ξ-GEMM, encoder 128->128 (96x128)", 128, 128, 768),
    ("Winograd ξ-GEMM, 1/4 GRU z|r 384->256 (96x128)", 256, 384, 768),
    ("Winograd F(4,5) ξ-GEMM, 1/4 GRU q 384->128", 128, 384, 3072),
    ("im2col 3x3, 1/16 level 128->256 (24x32)", 256, 1152, 768),
    ("im2col 3x3, 1/16 level 352->128 (24x32)", 128, 3168, 768),
    ("im2col 7x7 stem 3->64 (192x256 band)", 64, 147, 4096),
    ("1x1 iAFF local 64->16 (192x256)", 16, 64, 49152),
    ("1x1 iAFF local 16->64 (192x256)", 64, 16, 49152),
    ("1x1 encoder out 128->256 (96x128)", 256, 128, 12288),
    ("dW 3x3 64->64 (192x256): dY·colsᵀ", 64, 49152, 576),
    ("dX 1/16 level 256->128·9 (24x32)", 1152, 256, 768),
];

fn time_best(repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    (0..repeats).map(|_| {
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64()
    }).fold(f64::INFINITY, f64::min)
}

fn main() -> Result<(), String> {
    let repeats: usize = std::env::args().nth(1).map_or(Ok(7), |a| a.parse().map_err(|_| format!("{a}: not a count")))?;
    let plan = Plan::<f32>::selected();
    let cpu = cpu_info();
    let peak = fma_peak_gflops(1, plan.isa).map_err(|e| e.to_string())?;
    println!("CPU: {} ({}); mipnet GEMM plan {}; FMA peak {peak:.0} GFLOP/s on 1 core; best of {repeats}", cpu.model,
             cpu.vendor, plan.describe());
    let bf16 = Plan::<f32>::bf16();
    println!("| shape class | M x K x N | mipnet ms (GFLOP/s) | matrixmultiply ms (GFLOP/s) | crate / mipnet | mipnet bf16 ms (GFLOP/s) |");
    println!("|---|---|---|---|---|---|");
    for &(name, m, k, n) in SHAPES {
        let a = Array2::from_shape_fn((m, k), |(i, j)| ((i * 7 + j * 3) % 17) as f32 / 17.0 - 0.5);
        let b = Array2::from_shape_fn((k, n), |(i, j)| ((i * 5 + j * 11) % 13) as f32 / 13.0 - 0.5);
        let mut ours = Array2::<f32>::zeros((m, n));
        let mut theirs = Array2::<f32>::zeros((m, n));
        let t_ours = time_best(repeats, || gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, ours.view_mut(), Epilogue::default()));
        let t_theirs = time_best(repeats, || {
            // SAFETY: row-major m x k, k x n and m x n buffers of the stated sizes, C unaliased.
            unsafe {
                matrixmultiply::sgemm(m, k, n, 1.0, a.as_ptr(), k as isize, 1, b.as_ptr(), n as isize, 1, 0.0,
                                      theirs.as_mut_ptr(), n as isize, 1)
            }
        });
        let diff = ours.iter().zip(theirs.iter()).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(diff <= 1e-3 * (k as f32).sqrt(), "{name}: the two products differ by {diff}");
        let gf = |t: f64| 2.0 * (m * k * n) as f64 / t / 1e9;
        let half = bf16.map_or("no bf16 on this CPU".to_string(), |plan| {
            let t = time_best(repeats, || gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, ours.view_mut(), Epilogue::default()));
            format!("{:.3} ({:.0})", t * 1e3, gf(t))
        });
        println!("| {name} | {m} x {k} x {n} | {:.3} ({:.0}) | {:.3} ({:.0}) | {:.2} | {half} |", t_ours * 1e3, gf(t_ours),
                 t_theirs * 1e3, gf(t_theirs), t_theirs / t_ours);
    }
    Ok(())
}
