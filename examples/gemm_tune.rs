//! Times the GEMM on one thread for several plans against the measured FMA peak, to check (or
//! re-derive) the block sizes `gemm::blocking` picks on a new CPU.
//!
//! cargo run --release --example gemm_tune -- M K N [ISA:MRxNR:KC:MC:NC ...]
//! (no plan: the selected one; KC, MC or NC given as 0 take the selected plan's value)

use _core::gemm::{cpu_info, fma_peak_gflops, gemm_ex, Epilogue, Isa, Plan};
use ndarray::Array2;
use std::time::Instant;

#[path = "common/cpu_time.rs"]
mod cpu_time;
use cpu_time::cpu_seconds;

fn parse_plan(s: &str) -> Result<Plan<f32>, String> {
    let f: Vec<&str> = s.split(':').collect();
    let [isa, shape, kc, mc, nc] = f[..] else { return Err(format!("{s}: want ISA:MRxNR:KC:MC:NC")) };
    let isa = Isa::parse(isa)?;
    let base = Plan::<f32>::for_isa(isa).map_err(|e| e.to_string())?;
    let (mr, nr) = shape.split_once('x').ok_or(format!("{shape}: want MRxNR"))?;
    let num = |v: &str, d: usize| v.parse::<usize>().map(|x| if x == 0 { d } else { x }).map_err(|e| e.to_string());
    Plan::custom(isa, num(mr, 0)?, num(nr, 0)?, num(kc, base.kc)?, num(mc, base.mc)?, num(nc, base.nc)?)
        .map_err(|e| e.to_string())
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dims: Vec<usize> = args.iter().take(3).map(|a| a.parse().map_err(|_| format!("{a}: not a size"))).collect::<Result<_, _>>()?;
    let [m, k, n] = dims[..] else { return Err("usage: gemm_tune M K N [ISA:MRxNR:KC:MC:NC ...]".into()) };
    let plans: Vec<Plan<f32>> = if args.len() > 3 { args[3..].iter().map(|s| parse_plan(s)).collect::<Result<_, _>>()? } else { vec![*Plan::selected()] };
    let cpu = cpu_info();
    println!("{} ({}): L1d {} KiB, L2 {} KiB, caches from {}", cpu.model, cpu.vendor, cpu.l1d >> 10, cpu.l2 >> 10, cpu.cache_source);
    let a = Array2::from_shape_fn((m, k), |(i, j)| ((i * 7 + j * 3) % 17) as f32 / 17.0 - 0.5);
    let b = Array2::from_shape_fn((k, n), |(i, j)| ((i * 5 + j * 11) % 13) as f32 / 13.0 - 0.5);
    let mut c = Array2::<f32>::zeros((m, n));
    for plan in &plans {
        let peak = fma_peak_gflops(1, plan.isa).map_err(|e| e.to_string())?;
        let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..7 {
            let (t, c0) = (Instant::now(), cpu_seconds());
            gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, c.view_mut(), Epilogue::default());
            best = best.min(t.elapsed().as_secs_f64());
            best_cpu = best_cpu.min(cpu_seconds() - c0);
        }
        let (gf, gf_cpu) = (2.0 * (m * k * n) as f64 / best / 1e9, 2.0 * (m * k * n) as f64 / best_cpu / 1e9);
        println!("{:<40} {m}x{k}x{n}: {:7.2} ms {gf:6.1} GFLOP/s = {:5.1}% of {peak:.1} | per CPU second {gf_cpu:6.1}",
                 plan.describe(), best * 1e3, 100.0 * gf / peak);
    }
    Ok(())
}
