//! Times conv2d forward, dX and dW on the selected GEMM path for one shape (a profiling target).
//!
//! cargo run --release --example conv_time -- N CIN COUT H W KH KW STRIDE [REPEAT]
//!
//! `ONLY=fwd|dx|dw` times one of them; `WINOGRAD=off|on` overrides the automatic Winograd choice.

use _core::gemm::{fma_peak_gflops, Isa};
use _core::ops::conv::{conv2d_bwd_ex, conv2d_fwd_ex, Conv2dCfg, Conv2dNeed, Conv2dRun, Winograd};
use ndarray::{ArrayD, Dimension, IxDyn};
use std::time::Instant;

#[path = "common/cpu_time.rs"]
mod cpu_time;
use cpu_time::cpu_seconds;

fn main() -> Result<(), String> {
    let a: Vec<usize> = std::env::args().skip(1).map(|s| s.parse().map_err(|_| format!("{s}: not a number"))).collect::<Result<_, _>>()?;
    let [n, cin, cout, h, w, kh, kw, s] = a[..8] else { return Err("usage: conv_time N CIN COUT H W KH KW STRIDE [REPEAT]".into()) };
    let repeat = a.get(8).copied().unwrap_or(10);
    let cfg = Conv2dCfg::new([s, s], [kh / 2, kw / 2]);
    let fill = |shape: &[usize]| ArrayD::from_shape_fn(IxDyn(shape), |i| ((i.as_array_view().sum() * 7919) % 101) as f32 / 101.0 - 0.5);
    let (x, wt) = (fill(&[n, cin, h, w]), fill(&[cout, cin, kh, kw]));
    let winograd = match std::env::var("WINOGRAD").unwrap_or_default().as_str() {
        "off" => Winograd::Off,
        "on" => Winograd::On,
        _ => Winograd::Auto,
    };
    let run = Conv2dRun { winograd, ..Conv2dRun::selected() };
    let fwd = || conv2d_fwd_ex(x.view(), wt.view(), None, &cfg, false, run);
    let y = fwd().map_err(|e| e.to_string())?;
    let g = y.mapv(|v| v * 0.5).into_dyn();
    let bwd = |need| conv2d_bwd_ex(x.view(), wt.view(), g.view(), &cfg, need, run);
    let flops = 2.0 * (n * cout * cin * kh * kw * y.shape()[2] * y.shape()[3]) as f64;
    let threads = rayon::current_num_threads();
    let peak = fma_peak_gflops(threads, Isa::selected()).map_err(|e| e.to_string())?;
    let time = |what: &str, f: &dyn Fn()| {
        let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..repeat {
            let (t, c0) = (Instant::now(), cpu_seconds());
            f();
            best = best.min(t.elapsed().as_secs_f64());
            best_cpu = best_cpu.min(cpu_seconds() - c0);
        }
        println!("{what:4} {:8.2} ms {:6.1} GFLOP/s {:5.1}% of {peak:.0} | per CPU second {:6.1} GFLOP/s",
                 best * 1e3, flops / best / 1e9, 100.0 * flops / best / 1e9 / peak, flops / best_cpu / 1e9);
    };
    let only = std::env::var("ONLY").unwrap_or_default();
    if only.is_empty() || only == "fwd" {
        time("fwd", &|| drop(fwd()));
    }
    if only.is_empty() || only == "dx" {
        time("dx", &|| drop(bwd(Conv2dNeed { x: true, w: false, b: false })));
    }
    if only.is_empty() || only == "dw" {
        time("dw", &|| drop(bwd(Conv2dNeed { x: false, w: true, b: false })));
    }
    Ok(())
}
