//! GEMM: every ISA path this CPU has (forced through the plan argument, not the environment)
//! against an f64 product, for plain and transposed (stride-swapped) operands, edge tiles, alpha,
//! beta, the bias + ReLU epilogue and k = 0; results independent of the plan's block sizes and
//! bitwise equal on the two FMA paths; the selected path; the measured peak.
mod common;

use _core::gemm::{cpu_info, fma_peak_gflops, gemm, gemm_ex, gemm_par_with, matmul_par, round_to_bf16, Epilogue, Isa, Plan};
use common::Rng;
use ndarray::{Array2, ShapeBuilder};

/// The paths this CPU runs (the portable one always).
fn paths() -> Vec<Isa> {
    let paths: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.supported()).collect();
    eprintln!("GEMM paths tested on this CPU: {:?}", paths.iter().map(|i| i.name()).collect::<Vec<_>>());
    paths
}

fn random(rng: &mut Rng, r: usize, c: usize, col_major: bool) -> Array2<f32> {
    let mut x = Array2::<f32>::zeros((r, c).set_f(col_major));
    x.iter_mut().for_each(|v| *v = rng.uniform(-1.0, 1.0) as f32);
    x
}

/// Largest |x − y| over the elements.
fn max_err(c: &Array2<f32>, want: &Array2<f64>) -> f64 {
    c.iter().zip(want.iter()).map(|(x, y)| (f64::from(*x) - y).abs()).fold(0.0, f64::max)
}

/// f32 accumulation over k terms of magnitude <= 1: error grows like sqrt(k)·eps (the portable path
/// rounds twice per step).
fn tol(k: usize) -> f64 {
    1e-6 * (k as f64).sqrt().max(1.0) * 8.0
}

/// Sizes straddling every micro-tile (8 x 48, 6 x 16, 4 x 8) and the block sizes (KC up to 1024,
/// NC of a few panels), tiny ones, and k = 1.
const SIZES: &[(usize, usize, usize)] =
    &[(7, 5, 3), (64, 147, 200), (128, 1152, 515), (33, 352, 97), (200, 1100, 390), (1, 64, 2000), (130, 1, 50), (9, 2100, 17)];

#[test]
fn gemm_every_path_matches_f64_product_for_layouts_alpha_beta() {
    let mut rng = Rng::new(3);
    for isa in paths() {
        let plan = Plan::<f32>::for_isa(isa).unwrap();
        for &(m, k, n) in SIZES {
            for (ta, tb, tc) in [(false, false, false), (true, false, false), (false, true, true), (true, true, false)] {
                let (a, b) = (random(&mut rng, m, k, ta), random(&mut rng, k, n, tb));
                let c0 = random(&mut rng, m, n, tc);
                let (a64, b64, c64) = (a.mapv(f64::from), b.mapv(f64::from), c0.mapv(f64::from));
                // C = 0.5·A·B + 2·C
                let mut c = c0.clone();
                gemm_ex(plan, 0.5, a.view(), b.view(), 2.0, c.view_mut(), Epilogue::default());
                let err = max_err(&c, &(a64.dot(&b64) * 0.5 + &c64 * 2.0));
                assert!(err < tol(k) * 2.0, "{} {m}x{k}x{n} ta={ta} tb={tb} tc={tc}: err {err}", isa.name());
                // C += A·B (beta 1), and C = A·B with NaN in C (beta 0 must not read C)
                let mut c1 = c0.clone();
                gemm_ex(plan, 1.0, a.view(), b.view(), 1.0, c1.view_mut(), Epilogue::default());
                assert!(max_err(&c1, &(a64.dot(&b64) + &c64)) < tol(k), "{} {m}x{k}x{n} beta 1", isa.name());
                let mut cn = Array2::<f32>::from_elem((m, n).set_f(tc), f32::NAN);
                gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, cn.view_mut(), Epilogue::default());
                assert!(max_err(&cn, &a64.dot(&b64)) < tol(k), "{} {m}x{k}x{n} beta 0 over NaN", isa.name());
            }
        }
    }
}

#[test]
fn bf16_plan_sums_products_of_bf16_rounded_operands_in_f32() {
    let Some(plan) = Plan::<f32>::bf16() else {
        // no AVX512_BF16 here (or MIPNET_ISA chose a narrower path): convolutions fall back to f32
        eprintln!("no bf16 plan on this CPU / path");
        #[cfg(target_arch = "x86_64")]
        assert!(!(Isa::selected() == Isa::Avx512 && std::arch::is_x86_feature_detected!("avx512bf16")));
        return;
    };
    assert!(plan.pairs && plan.isa == Isa::Avx512);
    let mut rng = Rng::new(5);
    for &(m, k, n) in SIZES {
        for (ta, tb) in [(false, false), (true, true)] {
            let (a, b) = (random(&mut rng, m, k, ta), random(&mut rng, k, n, tb));
            let c0 = random(&mut rng, m, n, false);
            // the exact product of the operands rounded to bf16, which is what the kernel multiplies
            let want = a.mapv(|x| f64::from(round_to_bf16(x))).dot(&b.mapv(|x| f64::from(round_to_bf16(x))));
            let mut c = Array2::<f32>::from_elem((m, n), f32::NAN);
            gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, c.view_mut(), Epilogue::default());
            let err = max_err(&c, &want);
            assert!(err < tol(k), "bf16 {m}x{k}x{n} ta={ta} tb={tb}: err {err}");
            let mut c1 = c0.clone();
            gemm_ex(plan, 1.0, a.view(), b.view(), 1.0, c1.view_mut(), Epilogue::default());
            assert!(max_err(&c1, &(want + c0.mapv(f64::from))) < tol(k), "bf16 {m}x{k}x{n} beta 1");
            // on 2 threads a wide C takes A prepacked once as bf16 pairs (`Prepacked`), a tall one packs
            // per task: the same chains, so the same bits as the one-call product
            let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
            let mut cp = Array2::<f32>::from_elem((m, n), f32::NAN);
            pool.install(|| gemm_par_with(plan, 1.0, a.view(), b.view(), 0.0, cp.view_mut()));
            assert_eq!(c, cp, "bf16 {m}x{k}x{n} ta={ta} tb={tb} on 2 threads");
        }
    }
}

#[test]
fn gemm_every_path_f64_matches_f64_product() {
    let mut rng = Rng::new(4);
    for isa in paths() {
        let plan = Plan::<f64>::for_isa(isa).unwrap();
        for &(m, k, n) in SIZES {
            let a = Array2::from_shape_simple_fn((m, k), || rng.uniform(-1.0, 1.0));
            let b = Array2::from_shape_simple_fn((n, k), || rng.uniform(-1.0, 1.0));
            let mut c = Array2::<f64>::zeros((m, n));
            // B transposed: a stride swap
            gemm_ex(plan, 1.0, a.view(), b.t(), 0.0, c.view_mut(), Epilogue::default());
            let want = a.dot(&b.t());
            let err = c.iter().zip(want.iter()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
            assert!(err < 1e-12 * (k as f64).sqrt().max(1.0), "{} f64 {m}x{k}x{n}: err {err}", isa.name());
        }
    }
}

#[test]
fn gemm_bias_relu_epilogue_and_empty_depth() {
    let mut rng = Rng::new(5);
    for isa in paths() {
        let plan = Plan::<f32>::for_isa(isa).unwrap();
        for &(m, k, n) in &[(13, 70, 101), (128, 1152, 96), (5, 0, 9)] {
            let (a, b) = (random(&mut rng, m, k, false), random(&mut rng, k, n, false));
            let bias: Vec<f32> = (0..m).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
            let mut c = Array2::<f32>::from_elem((m, n), f32::NAN);
            let epi = Epilogue { bias: Some(&bias), relu: true };
            gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, c.view_mut(), epi);
            // C = max(bias[i] + (A·B)[i, j], 0)
            let mut want = a.mapv(f64::from).dot(&b.mapv(f64::from));
            want.rows_mut().into_iter().zip(&bias).for_each(|(mut r, &bi)| r.mapv_inplace(|v| (v + f64::from(bi)).max(0.0)));
            assert!(max_err(&c, &want) < tol(k), "{} {m}x{k}x{n} bias+relu", isa.name());
        }
    }
}

#[test]
fn gemm_result_does_not_depend_on_block_sizes_or_split_and_fma_paths_agree_bitwise() {
    let mut rng = Rng::new(6);
    let (m, k, n) = (77, 1500, 301);
    let (a, b) = (random(&mut rng, m, k, false), random(&mut rng, k, n, true));
    let run = |plan: &Plan<f32>| {
        let mut c = Array2::<f32>::zeros((m, n));
        gemm_ex(plan, 1.0, a.view(), b.view(), 0.0, c.view_mut(), Epilogue::default());
        c
    };
    let mut fma_results = vec![];
    for isa in paths() {
        let base = Plan::<f32>::for_isa(isa).unwrap();
        let c = run(base);
        // other KC, MC, NC: every chain still runs over k in order
        for (kc, mc, nc) in [(64, 8, 16), (200, 40, 100), (1024, 4096, 4096)] {
            let plan = Plan::custom(isa, base.mr, base.nr, kc, mc, nc).unwrap();
            assert_eq!(c, run(&plan), "{} KC={kc} MC={mc} NC={nc}", isa.name());
        }
        // split over threads, as the conv and gemm_par do
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut cp = Array2::<f32>::zeros((m, n));
            pool.install(|| gemm_par_with(base, 1.0, a.view(), b.view(), 0.0, cp.view_mut()));
            assert_eq!(c, cp, "{} gemm_par on {threads} threads", isa.name());
        }
        if isa != Isa::Generic {
            fma_results.push((isa, c));
        }
    }
    // AVX-512 and AVX2 fuse every multiply-add of the same chains: the same bits
    for w in fma_results.windows(2) {
        assert_eq!(w[0].1, w[1].1, "{} vs {}", w[0].0.name(), w[1].0.name());
    }
}

#[test]
fn parallel_gemm_wide_and_tall_equals_the_one_thread_product_bitwise() {
    let mut rng = Rng::new(8);
    // wide C (A packed once and shared by the column tasks) and tall C (row tasks), transposed A
    for (m, k, n, a_col_major) in [(77, 1500, 301, false), (301, 700, 77, true), (40, 3000, 500, true)] {
        let (a, b) = (random(&mut rng, m, k, a_col_major), random(&mut rng, k, n, false));
        let c0 = random(&mut rng, m, n, false);
        for isa in paths() {
            let plan = Plan::<f32>::for_isa(isa).unwrap();
            // C = 0.5·A·B + beta·C0 on one thread
            let one = |beta: f32| {
                let mut c = c0.clone();
                gemm_ex(plan, 0.5, a.view(), b.view(), beta, c.view_mut(), Epilogue::default());
                c
            };
            for threads in [2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                for beta in [0.0, 1.0, 0.25] {
                    let mut cp = c0.clone();
                    pool.install(|| gemm_par_with(plan, 0.5, a.view(), b.view(), beta, cp.view_mut()));
                    assert_eq!(one(beta), cp, "{} {m}x{k}x{n} beta {beta} on {threads} threads", isa.name());
                }
            }
        }
        // the binding's product: the selected path, every element written
        let mut want = Array2::<f32>::zeros((m, n));
        gemm(1.0, a.view(), b.view(), 0.0, want.view_mut());
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        assert_eq!(pool.install(|| matmul_par("gemm", a.view(), b.view())).unwrap(), want, "matmul_par {m}x{k}x{n}");
    }
}

#[test]
fn gemm_selected_path_is_the_forced_or_widest_one() {
    let sel = Isa::selected();
    match std::env::var("MIPNET_ISA") {
        Ok(v) if !v.trim().is_empty() => assert_eq!(Ok(sel), Isa::parse(&v)),
        _ => assert_eq!(sel, Isa::detected()),
    }
    // the default door runs the selected plan
    let a = Array2::<f32>::ones((3, 4));
    let mut c = Array2::<f32>::zeros((3, 2));
    gemm(1.0, a.view(), Array2::<f32>::ones((4, 2)).view(), 0.0, c.view_mut());
    assert!(c.iter().all(|&v| v == 4.0));
}

#[test]
fn a_plan_shape_with_no_micro_kernel_is_rejected() {
    // the names MIPNET_ISA accepts are tested in tests_rs/isa.rs
    assert!(Plan::<f32>::custom(Isa::Generic, 5, 8, 64, 64, 64).is_err(), "a shape with no micro-kernel");
}

#[test]
fn cpu_info_and_measured_peak_are_plausible() {
    let cpu = cpu_info();
    assert!(cpu.l1d >= 8 << 10 && cpu.l2 >= cpu.l1d, "{cpu:?}");
    let one = fma_peak_gflops(1, Isa::detected()).unwrap();
    // from 1 GFLOP/s (a portable path on a slow core) to 1 TFLOP/s per core
    assert!(one > 1.0 && one < 1000.0, "peak {one}");
    assert!(fma_peak_gflops(0, Isa::Generic).is_err());
}

#[test]
fn blocking_follows_the_cache_sizes() {
    // (es, MR, NR, L1d, L2, L3 share) -> (KC, MC, NC), the figures `gemm::blocking` documents
    use _core::gemm::blocking;
    let (kc, _, nc) = blocking(4, 8, 48, 48 << 10, 2 << 20, 0);
    assert_eq!((kc, nc), (768, 336), "Sapphire/Emerald Rapids");
    let (kc, mc, nc) = blocking(4, 8, 48, 32 << 10, 1 << 20, 4 << 20);
    assert_eq!((kc, mc, nc), (512, 1024, 240), "Zen 4 (32 MiB L3 over 8 cores)");
    let (kc, _, nc) = blocking(4, 4, 24, 32 << 10, 256 << 10, 0);
    assert_eq!((kc, nc), (320, 96), "AVX2 client core");
    // every plan's micro-panel fits L1 and its B block L2
    let cpu = cpu_info();
    for isa in paths() {
        let p = Plan::<f32>::for_isa(isa).unwrap();
        assert!(p.mr * p.kc * 4 <= cpu.l1d && p.kc * p.nc * 4 <= cpu.l2, "{}", p.describe());
    }
}
