//! conv2d: forward against a direct sum and a closed form, f64 gradchecks of every gradient, every ISA
//! path (forced through the plan argument) against f64, the fused ReLU, thread-count independence,
//! layouts, and the errors.
mod common;

use _core::gemm::Isa;
use _core::ops::conv::{conv2d_bwd, conv2d_bwd_ex, conv2d_fwd, conv2d_fwd_ex, Conv2dCfg, Conv2dNeed, Conv2dRun, Winograd};
use common::{dot, gradcheck, max_abs_diff, Rng};
use ndarray::{ArrayD, Ix4, IxDyn};

/// y[n, o, i, j] = b[o] + Σ_{c, ki, kj} w[o, c, ki, kj] · x[n, c, i·sh + ki − ph, j·sw + kj − pw] (0 outside).
fn conv_ref(x: &ArrayD<f64>, w: &ArrayD<f64>, b: Option<&ArrayD<f64>>, cfg: &Conv2dCfg) -> ArrayD<f64> {
    let x = x.view().into_dimensionality::<Ix4>().unwrap();
    let w = w.view().into_dimensionality::<Ix4>().unwrap();
    let ((n, cin, h, wd), (cout, _, kh, kw)) = (x.dim(), w.dim());
    let ([sh, sw], [ph, pw]) = (cfg.stride, cfg.padding);
    let (ho, wo) = ((h + 2 * ph - kh) / sh + 1, (wd + 2 * pw - kw) / sw + 1);
    let mut y = ArrayD::<f64>::zeros(IxDyn(&[n, cout, ho, wo]));
    for ni in 0..n {
        for o in 0..cout {
            for i in 0..ho {
                for j in 0..wo {
                    let mut acc = b.map_or(0.0, |b| b[[o]]);
                    for c in 0..cin {
                        for ki in 0..kh {
                            for kj in 0..kw {
                                // input position (i·sh + ki − ph, j·sw + kj − pw), skipped in the padding
                                let (iy, ix) = ((i * sh + ki) as isize - ph as isize, (j * sw + kj) as isize - pw as isize);
                                if iy >= 0 && ix >= 0 && (iy as usize) < h && (ix as usize) < wd {
                                    acc += w[[o, c, ki, kj]] * x[[ni, c, iy as usize, ix as usize]];
                                }
                            }
                        }
                    }
                    y[[ni, o, i, j]] = acc;
                }
            }
        }
    }
    y
}

/// (x shape, w shape, stride, padding): every kernel shape MIPNet uses, odd sizes, stride 2,
/// asymmetric padding, the pointwise fast path, and a case large enough to span several tiles and
/// dX channel chunks.
/// (name, input shape, weight shape, stride, padding)
type Case = (&'static str, [usize; 4], [usize; 4], [usize; 2], [usize; 2]);

const CASES: &[Case] = &[
    ("7x7_stride2_pad3", [2, 3, 13, 11], [4, 3, 7, 7], [2, 2], [3, 3]),
    ("5x5_pad2", [1, 2, 9, 8], [3, 2, 5, 5], [1, 1], [2, 2]),
    ("3x3_pad1", [2, 4, 7, 9], [5, 4, 3, 3], [1, 1], [1, 1]),
    ("3x3_stride2_pad1", [2, 3, 9, 7], [4, 3, 3, 3], [2, 2], [1, 1]),
    ("1x1", [3, 6, 5, 7], [4, 6, 1, 1], [1, 1], [0, 0]),
    ("1x1_stride2", [2, 5, 7, 9], [3, 5, 1, 1], [2, 2], [0, 0]),
    ("1x5_pad0_2", [2, 3, 6, 9], [4, 3, 1, 5], [1, 1], [0, 2]),
    ("5x1_pad2_0", [2, 3, 9, 6], [4, 3, 5, 1], [1, 1], [2, 0]),
    ("3x3_stride1x2_pad0x1", [1, 2, 8, 9], [3, 2, 3, 3], [1, 2], [0, 1]),
    ("3x3_pad0x1", [2, 3, 7, 8], [4, 3, 3, 3], [1, 1], [0, 1]),
    ("3x3_pad1_tile_in_last_row", [1, 2, 11, 9], [3, 2, 3, 3], [1, 1], [1, 1]),
    ("1x1_tiled", [1, 8, 40, 50], [5, 8, 1, 1], [1, 1], [0, 0]),
    ("3x3_tiled_64ch", [2, 64, 53, 59], [6, 64, 3, 3], [1, 1], [1, 1]),
    // one or two output channels, stride 1: the tap-major path (pointwise GEMM + shift-add)
    ("3x3_pad1_two_outputs", [2, 5, 7, 9], [2, 5, 3, 3], [1, 1], [1, 1]),
    ("5x5_pad2_one_output", [1, 3, 9, 8], [1, 3, 5, 5], [1, 1], [2, 2]),
    ("3x3_pad0x2_two_outputs", [2, 3, 7, 6], [2, 3, 3, 3], [1, 1], [0, 2]),
    ("3x3_tiled_64ch_two_outputs", [2, 64, 53, 59], [2, 64, 3, 3], [1, 1], [1, 1]),
    // more outputs than K = Cin·taps: dW is computed as its transpose (less micro-tile padding)
    ("1x1_few_inputs_many_outputs", [2, 3, 6, 7], [40, 3, 1, 1], [1, 1], [0, 0]),
    ("5x5_pad2_two_inputs_many_outputs", [1, 2, 9, 8], [64, 2, 5, 5], [1, 1], [2, 2]),
];

/// The case of CASES named `name`.
fn case(name: &str) -> Case {
    *CASES.iter().find(|c| c.0 == name).expect("a case of CASES")
}

fn inputs(rng: &mut Rng, xs: &[usize], ws: &[usize]) -> (ArrayD<f64>, ArrayD<f64>, ArrayD<f64>) {
    (rng.array(xs, -1.0, 1.0), rng.array(ws, -1.0, 1.0), rng.array(&[ws[0]], -1.0, 1.0))
}

#[test]
fn conv2d_fwd_matches_direct_sum_for_every_kernel_shape_f64() {
    let mut rng = Rng::new(3);
    for &(name, xs, ws, stride, padding) in CASES {
        let cfg = Conv2dCfg::new(stride, padding);
        let (x, w, b) = inputs(&mut rng, &xs, &ws);
        let y = conv2d_fwd(x.view(), w.view(), Some(b.view()), &cfg).unwrap().into_dyn();
        let err = max_abs_diff(&y, &conv_ref(&x, &w, Some(&b), &cfg));
        assert!(err < 1e-12, "{name}: max abs err {err}");
        let y0 = conv2d_fwd(x.view(), w.view(), None, &cfg).unwrap().into_dyn();
        let err0 = max_abs_diff(&y0, &conv_ref(&x, &w, None, &cfg));
        assert!(err0 < 1e-12, "{name} without bias: max abs err {err0}");
    }
}

#[test]
fn conv2d_fwd_f32_matches_f64_direct_sum() {
    let mut rng = Rng::new(4);
    let (name, xs, ws, stride, padding) = case("3x3_tiled_64ch");
    let cfg = Conv2dCfg::new(stride, padding);
    let (x, w, b) = inputs(&mut rng, &xs, &ws);
    let (x32, w32, b32) = (x.mapv(|v| v as f32), w.mapv(|v| v as f32), b.mapv(|v| v as f32));
    let want = conv_ref(&x, &w, Some(&b), &cfg);
    // the direct convolution as before (the default here: too few tiles for Winograd), and
    // Winograd, which rounds its transforms too: measured 2.2e-4 here (outputs up to ~50,
    // unscaled weights), bound 5e-4
    for (winograd, bound) in [(Winograd::Off, 1e-4), (Winograd::On, 5e-4)] {
        let run = Conv2dRun { plan: _core::gemm::Plan::<f32>::selected(), winograd, reuse_kernels: false };
        let y = conv2d_fwd_ex(x32.view(), w32.view(), Some(b32.view()), &cfg, false, run).unwrap().into_dyn().mapv(f64::from);
        let err = max_abs_diff(&y, &want);
        assert!(err < bound, "{name} f32 {winograd:?}: max abs err {err}");
    }
}

#[test]
fn conv2d_ones_kernel_counts_taps_inside_the_image() {
    // All-ones 4x5 image, all-ones 3x3 kernel, padding 1, bias 0.5: each output is the number of taps
    // that land inside the image (4 at corners, 6 on edges, 9 inside) plus 0.5.
    let x = ArrayD::<f64>::ones(IxDyn(&[1, 1, 4, 5]));
    let w = ArrayD::<f64>::ones(IxDyn(&[1, 1, 3, 3]));
    let b = ndarray::arr1(&[0.5]).into_dyn();
    let y = conv2d_fwd(x.view(), w.view(), Some(b.view()), &Conv2dCfg::new([1, 1], [1, 1])).unwrap();
    let expect = [[4.5, 6.5, 6.5, 6.5, 4.5], [6.5, 9.5, 9.5, 9.5, 6.5], [6.5, 9.5, 9.5, 9.5, 6.5], [4.5, 6.5, 6.5, 6.5, 4.5]];
    for i in 0..4 {
        for j in 0..5 {
            assert_eq!(y[[0, 0, i, j]], expect[i][j], "at ({i}, {j})");
        }
    }
}

#[test]
fn conv2d_out_hw_follows_the_floor_formula() {
    // (H + 2p − k) / s + 1, floored: (13 + 6 − 7) / 2 + 1 = 7, (11 + 6 − 7) / 2 + 1 = 6
    assert_eq!(Conv2dCfg::new([2, 2], [3, 3]).out_hw(13, 11, 7, 7).unwrap(), (7, 6));
    assert_eq!(Conv2dCfg::new([1, 1], [0, 2]).out_hw(6, 9, 1, 5).unwrap(), (6, 9));
}

/// Gradchecks dx, dw and db of one case. The loss is linear in each argument, so there are no kinks.
fn gradcheck_case(name: &str, xs: [usize; 4], ws: [usize; 4], cfg: Conv2dCfg, seed: u64) {
    let mut rng = Rng::new(seed);
    let (x, w, b) = inputs(&mut rng, &xs, &ws);
    let y = conv2d_fwd(x.view(), w.view(), Some(b.view()), &cfg).unwrap();
    let g = rng.array(y.shape(), -1.0, 1.0);
    let grads = conv2d_bwd(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL).unwrap();
    let loss = |x: &ArrayD<f64>, w: &ArrayD<f64>, b: &ArrayD<f64>| {
        dot(&conv2d_fwd(x.view(), w.view(), Some(b.view()), &cfg).unwrap().into_dyn(), &g)
    };
    gradcheck(&format!("{name} dx"), &x, &grads.x.unwrap().into_dyn(), |xp| loss(xp, &w, &b));
    gradcheck(&format!("{name} dw"), &w, &grads.w.unwrap().into_dyn(), |wp| loss(&x, wp, &b));
    gradcheck(&format!("{name} db"), &b, &grads.b.unwrap().into_dyn(), |bp| loss(&x, &w, bp));
}

#[test]
fn conv2d_7x7_stride2_pad3_bwd_gradcheck_f64() {
    gradcheck_case("7x7 s2 p3", [2, 3, 13, 11], [4, 3, 7, 7], Conv2dCfg::new([2, 2], [3, 3]), 10);
}

#[test]
fn conv2d_5x5_pad2_bwd_gradcheck_f64() {
    gradcheck_case("5x5 p2", [1, 2, 9, 8], [3, 2, 5, 5], Conv2dCfg::new([1, 1], [2, 2]), 11);
}

#[test]
fn conv2d_3x3_pad1_bwd_gradcheck_f64() {
    gradcheck_case("3x3 p1", [2, 4, 7, 9], [5, 4, 3, 3], Conv2dCfg::new([1, 1], [1, 1]), 12);
}

#[test]
fn conv2d_3x3_stride2_pad1_odd_sizes_bwd_gradcheck_f64() {
    gradcheck_case("3x3 s2 p1", [2, 3, 9, 7], [4, 3, 3, 3], Conv2dCfg::new([2, 2], [1, 1]), 13);
}

#[test]
fn conv2d_3x3_pad0x1_rows_shrink_bwd_gradcheck_f64() {
    // stride 1 and Wo = W but Ho = H − 2: the flat-shift im2col with padding rows on neither side
    gradcheck_case("3x3 p(0,1)", [2, 3, 7, 8], [4, 3, 3, 3], Conv2dCfg::new([1, 1], [0, 1]), 23);
}

#[test]
fn conv2d_3x3_pad1_tile_within_padding_taps_bwd_gradcheck_f64() {
    // 99 pixels in tiles of 96 and 3: the last tile lies in the last output row, where the bottom
    // taps read only padding (an empty span of the flat-shift im2col)
    gradcheck_case("3x3 p1 99 px", [1, 2, 11, 9], [3, 2, 3, 3], Conv2dCfg::new([1, 1], [1, 1]), 24);
}

#[test]
fn conv2d_1x1_pointwise_bwd_gradcheck_f64() {
    gradcheck_case("1x1", [3, 6, 5, 7], [4, 6, 1, 1], Conv2dCfg::new([1, 1], [0, 0]), 14);
}

#[test]
fn conv2d_1x1_pointwise_many_tiles_bwd_gradcheck_f64() {
    gradcheck_case("1x1 tiled", [1, 8, 40, 50], [5, 8, 1, 1], Conv2dCfg::new([1, 1], [0, 0]), 19);
}

#[test]
fn conv2d_more_outputs_than_weight_columns_bwd_gradcheck_f64() {
    // dW taken as cols·dYᵀ into dWᵀ: Cout is wider than K = Cin·taps
    gradcheck_case("1x1 3 -> 40", [2, 3, 6, 7], [40, 3, 1, 1], Conv2dCfg::new([1, 1], [0, 0]), 28);
    gradcheck_case("5x5 p2 2 -> 64", [1, 2, 9, 8], [64, 2, 5, 5], Conv2dCfg::new([1, 1], [2, 2]), 29);
}

#[test]
fn conv2d_1x1_stride2_bwd_gradcheck_f64() {
    gradcheck_case("1x1 s2", [2, 5, 7, 9], [3, 5, 1, 1], Conv2dCfg::new([2, 2], [0, 0]), 15);
}

#[test]
fn conv2d_1x5_pad0_2_and_5x1_pad2_0_bwd_gradcheck_f64() {
    gradcheck_case("1x5 p(0,2)", [2, 3, 6, 9], [4, 3, 1, 5], Conv2dCfg::new([1, 1], [0, 2]), 16);
    gradcheck_case("5x1 p(2,0)", [2, 3, 9, 6], [4, 3, 5, 1], Conv2dCfg::new([1, 1], [2, 0]), 17);
}

#[test]
fn conv2d_3x3_many_tiles_and_channel_chunks_bwd_gradcheck_f64() {
    gradcheck_case("3x3 64ch tiled", [2, 64, 53, 59], [6, 64, 3, 3], Conv2dCfg::new([1, 1], [1, 1]), 18);
}

#[test]
fn conv2d_one_or_two_outputs_bwd_gradcheck_f64() {
    gradcheck_case("3x3 p1 2 outputs", [2, 5, 7, 9], [2, 5, 3, 3], Conv2dCfg::new([1, 1], [1, 1]), 25);
    gradcheck_case("5x5 p2 1 output", [1, 3, 9, 8], [1, 3, 5, 5], Conv2dCfg::new([1, 1], [2, 2]), 26);
    // padding wider than a tap's reach on the columns: output columns that read only padding
    gradcheck_case("3x3 p(0,2) 2 outputs", [2, 3, 7, 6], [2, 3, 3, 3], Conv2dCfg::new([1, 1], [0, 2]), 27);
}

#[test]
fn conv2d_bwd_computes_only_the_requested_grads() {
    let mut rng = Rng::new(20);
    let cfg = Conv2dCfg::new([1, 1], [2, 2]);
    let (x, w, _) = inputs(&mut rng, &[2, 2, 8, 9], &[3, 2, 5, 5]);
    let g = rng.array(&[2, 3, 8, 9], -1.0, 1.0);
    let all = conv2d_bwd(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL).unwrap();
    // the flow input of the motion encoder is detached: weight and bias grads only
    let some = conv2d_bwd(x.view(), w.view(), g.view(), &cfg, Conv2dNeed { x: false, w: true, b: true }).unwrap();
    assert!(some.x.is_none());
    assert_eq!(some.w.unwrap(), all.w.unwrap());
    assert_eq!(some.b.unwrap(), all.b.unwrap());
    let none = conv2d_bwd(x.view(), w.view(), g.view(), &cfg, Conv2dNeed { x: false, w: false, b: false }).unwrap();
    assert!(none.x.is_none() && none.w.is_none() && none.b.is_none());
}

#[test]
fn conv2d_results_do_not_depend_on_the_thread_count() {
    for name in ["3x3_tiled_64ch", "3x3_tiled_64ch_two_outputs"] {
        results_do_not_depend_on_the_thread_count(case(name));
    }
}

fn results_do_not_depend_on_the_thread_count((name, xs, ws, stride, padding): Case) {
    let mut rng = Rng::new(21);
    let cfg = Conv2dCfg::new(stride, padding);
    let (x, w, b) = inputs(&mut rng, &xs, &ws);
    let (x, w, b) = (x.mapv(|v| v as f32), w.mapv(|v| v as f32), b.mapv(|v| v as f32));
    let g = rng.array(&[xs[0], ws[0], xs[2], xs[3]], -1.0, 1.0).mapv(|v| v as f32);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let y = conv2d_fwd(x.view(), w.view(), Some(b.view()), &cfg).unwrap();
            (y, conv2d_bwd(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL).unwrap())
        })
    };
    let (y1, g1) = run(1);
    for threads in [2, 3, 5] {
        let (yt, gt) = run(threads);
        assert_eq!(y1, yt, "{name} forward, {threads} threads");
        assert_eq!(g1.x, gt.x, "{name} dx, {threads} threads");
        assert_eq!(g1.w, gt.w, "{name} dw, {threads} threads");
        assert_eq!(g1.b, gt.b, "{name} db, {threads} threads");
    }
}

#[test]
fn conv2d_accepts_non_contiguous_views() {
    let mut rng = Rng::new(22);
    let cfg = Conv2dCfg::new([2, 2], [1, 1]);
    let (x, w, b) = inputs(&mut rng, &[2, 3, 9, 7], &[4, 3, 3, 3]);
    // the same values stored with H and W swapped, seen through a transposed view
    let xt = x.view().permuted_axes(IxDyn(&[0, 1, 3, 2])).as_standard_layout().into_owned();
    let xv = xt.view().permuted_axes(IxDyn(&[0, 1, 3, 2]));
    let wt = w.view().permuted_axes(IxDyn(&[1, 0, 2, 3])).as_standard_layout().into_owned();
    let wv = wt.view().permuted_axes(IxDyn(&[1, 0, 2, 3]));
    assert!(!xv.is_standard_layout() && !wv.is_standard_layout());
    let y = conv2d_fwd(xv.view(), wv.view(), Some(b.view()), &cfg).unwrap();
    assert_eq!(y, conv2d_fwd(x.view(), w.view(), Some(b.view()), &cfg).unwrap());
    let g = rng.array(y.shape(), -1.0, 1.0);
    let gt = g.view().permuted_axes(IxDyn(&[3, 2, 1, 0])).as_standard_layout().into_owned();
    let gv = gt.view().permuted_axes(IxDyn(&[3, 2, 1, 0]));
    let a = conv2d_bwd(xv, wv, gv, &cfg, Conv2dNeed::ALL).unwrap();
    let c = conv2d_bwd(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL).unwrap();
    assert_eq!((a.x, a.w, a.b), (c.x, c.w, c.b));
}

/// (what, input shape, weight shape, bias shape, cfg, substrings the message must contain)
type ErrCase<'a> = (&'a str, &'a [usize], &'a [usize], Option<&'a [usize]>, Conv2dCfg, &'a [&'a str]);

/// The error message of a failing forward.
fn fwd_err(xs: &[usize], ws: &[usize], bs: Option<&[usize]>, cfg: Conv2dCfg) -> String {
    let x = ArrayD::<f32>::zeros(IxDyn(xs));
    let w = ArrayD::<f32>::zeros(IxDyn(ws));
    let b = bs.map(|s| ArrayD::<f32>::zeros(IxDyn(s)));
    conv2d_fwd(x.view(), w.view(), b.as_ref().map(|b| b.view()), &cfg).unwrap_err().to_string()
}

#[test]
fn conv2d_rejects_bad_shapes_naming_op_and_shapes() {
    let cfg = Conv2dCfg::new([1, 1], [1, 1]);
    let cases: &[ErrCase] = &[
        ("channel mismatch", &[2, 3, 8, 8], &[4, 5, 3, 3], None, cfg, &["[2, 3, 8, 8]", "[4, 5, 3, 3]", "weight.shape[1]"]),
        ("3-D input", &[3, 8, 8], &[4, 3, 3, 3], None, cfg, &["input", "[3, 8, 8]", "4-D"]),
        ("5-D weight", &[2, 3, 8, 8], &[4, 3, 3, 3, 1], None, cfg, &["weight", "[4, 3, 3, 3, 1]"]),
        ("2-D bias", &[2, 3, 8, 8], &[4, 3, 3, 3], Some(&[4, 1]), cfg, &["bias", "[4, 1]"]),
        ("bias length", &[2, 3, 8, 8], &[4, 3, 3, 3], Some(&[5]), cfg, &["bias", "[5]", "[4, 3, 3, 3]"]),
        ("kernel larger than padded input", &[1, 3, 4, 9], &[2, 3, 7, 7], None, cfg, &["[1, 3, 4, 9]", "[2, 3, 7, 7]", "padded"]),
        ("empty input", &[0, 3, 8, 8], &[4, 3, 3, 3], None, cfg, &["[0, 3, 8, 8]", "empty"]),
        ("empty weight", &[2, 3, 8, 8], &[0, 3, 3, 3], None, cfg, &["[0, 3, 3, 3]", "empty"]),
    ];
    for (what, xs, ws, bs, cfg, needles) in cases {
        let err = fwd_err(xs, ws, *bs, *cfg);
        assert!(err.contains("conv2d"), "{what}: {err}");
        for needle in *needles {
            assert!(err.contains(needle), "{what}: {needle:?} not in {err:?}");
        }
    }
}

#[test]
fn conv2d_rejects_zero_stride_and_overflowing_padding() {
    let err = fwd_err(&[1, 1, 5, 5], &[1, 1, 3, 3], None, Conv2dCfg::new([0, 1], [1, 1]));
    assert!(err.contains("conv2d") && err.contains("stride") && err.contains("[0, 1]"), "{err}");
    let err = fwd_err(&[1, 1, 5, 5], &[1, 1, 3, 3], None, Conv2dCfg::new([1, 1], [usize::MAX, 0]));
    assert!(err.contains("conv2d") && err.contains("padding"), "{err}");
}

#[test]
fn conv2d_bwd_rejects_grad_output_of_the_wrong_shape() {
    let x = ArrayD::<f64>::zeros(IxDyn(&[2, 3, 8, 8]));
    let w = ArrayD::<f64>::zeros(IxDyn(&[4, 3, 3, 3]));
    let g = ArrayD::<f64>::zeros(IxDyn(&[2, 4, 8, 7]));
    let err = conv2d_bwd(x.view(), w.view(), g.view(), &Conv2dCfg::new([1, 1], [1, 1]), Conv2dNeed::ALL)
        .unwrap_err()
        .to_string();
    for needle in ["conv2d", "grad_output", "[2, 4, 8, 7]", "[2, 4, 8, 8]", "[2, 3, 8, 8]", "[4, 3, 3, 3]"] {
        assert!(err.contains(needle), "{needle:?} not in {err:?}");
    }
}

#[test]
fn gemm_f32_matches_f64_product_for_layouts_edges_and_beta() {
    use _core::gemm::gemm;
    use ndarray::{Array2, ShapeBuilder};
    let mut rng = Rng::new(30);
    // sizes straddling the AVX-512 kernel's 8 x 48 tiles and 384 / 192 / 480 blocks, and tiny ones
    for &(m, k, n) in &[(128, 1152, 100), (7, 5, 3), (37, 800, 61), (200, 390, 1100), (1, 64, 2000), (130, 1, 50)] {
        for (ta, tb) in [(false, false), (true, false), (false, true), (true, true)] {
            let a64 = Array2::from_shape_simple_fn((m, k), || rng.uniform(-1.0, 1.0));
            let b64 = Array2::from_shape_simple_fn((k, n), || rng.uniform(-1.0, 1.0));
            let c64 = Array2::from_shape_simple_fn((m, n), || rng.uniform(-1.0, 1.0));
            // stored transposed (column-major) when ta / tb: the same matrices through other strides
            let store = |x: &Array2<f64>, t: bool| {
                let mut s = Array2::<f32>::zeros(x.dim().set_f(t));
                s.zip_mut_with(x, |d, &v| *d = v as f32);
                s
            };
            let (a, b) = (store(&a64, ta), store(&b64, tb));
            let mut c = c64.mapv(|v| v as f32);
            gemm(0.5f32, a.view(), b.view(), 2.0, c.view_mut());
            let a32 = a64.mapv(|v| v as f32 as f64);
            let b32 = b64.mapv(|v| v as f32 as f64);
            // C = 0.5·A·B + 2·C
            let want = a32.dot(&b32) * 0.5 + c64.mapv(|v| v as f32 as f64) * 2.0;
            let err = c.iter().zip(want.iter()).map(|(x, y)| (*x as f64 - y).abs()).fold(0.0, f64::max);
            assert!(err < 1e-4 * (k as f64).sqrt().max(1.0), "{m}x{k}x{n} ta={ta} tb={tb}: err {err}");
            // beta 0 must ignore NaN in C
            let mut cn = Array2::<f32>::from_elem((m, n), f32::NAN);
            gemm(1.0f32, a.view(), b.view(), 0.0, cn.view_mut());
            assert!(cn.iter().all(|v| v.is_finite()), "{m}x{k}x{n}: NaN leaked through beta 0");
        }
    }
}

#[test]
fn conv2d_pixel_major_weight_grad_for_strides_and_separable_kernels_gradcheck_f64() {
    // Cin >= 16 takes dW's pixel-major path: stride 2 (the downsampling resblocks), 1x5 / 5x1 (SepConvGRU)
    gradcheck_case("3x3 s2 16ch", [2, 16, 9, 11], [5, 16, 3, 3], Conv2dCfg::new([2, 2], [1, 1]), 25);
    gradcheck_case("1x5 p(0,2) 20ch", [1, 20, 6, 13], [4, 20, 1, 5], Conv2dCfg::new([1, 1], [0, 2]), 26);
    gradcheck_case("5x1 p(2,0) 20ch", [1, 20, 13, 6], [4, 20, 5, 1], Conv2dCfg::new([1, 1], [2, 0]), 27);
}

/// f32 forward and gradients of `case` on one ISA path against the f64 direct computation.
fn isa_case(isa: Isa, (name, xs, ws, stride, padding): Case, seed: u64) {
    use _core::gemm::Plan;
    let plan = Conv2dRun { plan: Plan::<f32>::for_isa(isa).unwrap(), winograd: Winograd::Off, reuse_kernels: false };
    let plan64 = Conv2dRun { plan: Plan::<f64>::for_isa(isa).unwrap(), winograd: Winograd::Off, reuse_kernels: false };
    let cfg = Conv2dCfg::new(stride, padding);
    let mut rng = Rng::new(seed);
    let (x, w, b) = inputs(&mut rng, &xs, &ws);
    let g = rng.array(conv_ref(&x, &w, None, &cfg).shape(), -1.0, 1.0);
    let f32v = |a: &ArrayD<f64>| a.mapv(|v| v as f32);
    let (x32, w32, b32, g32) = (f32v(&x), f32v(&w), f32v(&b), f32v(&g));
    let y = conv2d_fwd_ex(x32.view(), w32.view(), Some(b32.view()), &cfg, false, plan).unwrap().into_dyn().mapv(f64::from);
    let err = max_abs_diff(&y, &conv_ref(&x, &w, Some(&b), &cfg));
    assert!(err < 1e-4, "{} {name} fwd: err {err}", isa.name());
    // f32 gradients against the f64 ones of the same path (checked by the f64 gradchecks)
    let g32s = conv2d_bwd_ex(x32.view(), w32.view(), g32.view(), &cfg, Conv2dNeed::ALL, plan).unwrap();
    let g64s = conv2d_bwd_ex(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL, plan64).unwrap();
    let close = |a: ArrayD<f32>, b: ArrayD<f64>, what: &str| {
        let err = max_abs_diff(&a.mapv(f64::from), &b);
        assert!(err < 1e-3, "{} {name} {what}: err {err}", isa.name());
    };
    close(g32s.x.unwrap().into_dyn(), g64s.x.unwrap().into_dyn(), "dx");
    close(g32s.w.unwrap().into_dyn(), g64s.w.unwrap().into_dyn(), "dw");
    close(g32s.b.unwrap().into_dyn(), g64s.b.unwrap().into_dyn(), "db");
    // the f64 path itself: forward against the direct sum, and one gradcheck of its backward
    let y64 = conv2d_fwd_ex(x.view(), w.view(), Some(b.view()), &cfg, false, plan64).unwrap().into_dyn();
    let err = max_abs_diff(&y64, &conv_ref(&x, &w, Some(&b), &cfg));
    assert!(err < 1e-12, "{} {name} f64 fwd: err {err}", isa.name());
}

#[test]
fn conv2d_every_isa_path_matches_f64_forced_through_the_plan_argument() {
    for isa in Isa::ALL.into_iter().filter(|i| i.supported()) {
        for (i, &case) in [CASES[0], CASES[2], CASES[4], CASES[6], CASES[12]].iter().enumerate() {
            isa_case(isa, case, 40 + i as u64);
        }
    }
}

#[test]
fn conv2d_fused_relu_equals_relu_of_conv_bitwise() {
    use _core::gemm::Plan;
    let mut rng = Rng::new(50);
    for (name, xs, ws, stride, padding) in [CASES[2], CASES[4], case("3x3_tiled_64ch"), case("3x3_tiled_64ch_two_outputs")] {
        let cfg = Conv2dCfg::new(stride, padding);
        let (x, w, b) = inputs(&mut rng, &xs, &ws);
        let (x, w, b) = (x.mapv(|v| v as f32), w.mapv(|v| v as f32), b.mapv(|v| v as f32));
        for winograd in [Winograd::Off, Winograd::On] {
            let run = Conv2dRun { plan: Plan::selected(), winograd, reuse_kernels: false };
            let plain = conv2d_fwd_ex(x.view(), w.view(), Some(b.view()), &cfg, false, run).unwrap().mapv(|v| v.max(0.0));
            let fused = conv2d_fwd_ex(x.view(), w.view(), Some(b.view()), &cfg, true, run).unwrap();
            assert_eq!(plain, fused, "{name} {winograd:?}");
        }
    }
}

/// 3x3 stride-1 geometries for Winograd: paddings 0, 1, 2 and mixed, sizes that leave partial
/// 4 x 4 tiles, rows wider than a vector block of tiles, and one with many tiles and channels.
const WINOGRAD_CASES: &[Case] = &[
    ("3x3_p1_odd", [2, 3, 9, 7], [4, 3, 3, 3], [1, 1], [1, 1]),
    ("3x3_p0", [1, 2, 10, 13], [3, 2, 3, 3], [1, 1], [0, 0]),
    ("3x3_p2", [1, 2, 5, 6], [3, 2, 3, 3], [1, 1], [2, 2]),
    ("3x3_p0x1", [2, 3, 7, 8], [4, 3, 3, 3], [1, 1], [0, 1]),
    // 19 tiles per row: one vector block of the row transforms (16 tiles) and a tail of 3
    ("3x3_p1_wide", [1, 3, 6, 75], [4, 3, 3, 3], [1, 1], [1, 1]),
    ("3x3_p1_64ch", [2, 64, 29, 35], [24, 64, 3, 3], [1, 1], [1, 1]),
    // one band of 4 x 12 = 48 tiles, whole NR-column panels on every ISA path: the GEMM reads V in place
    ("3x3_p1_in_place", [1, 3, 16, 48], [4, 3, 3, 3], [1, 1], [1, 1]),
    // F(4, 5) along rows and along columns: the GRUs' paddings, wider and odd ones, the row
    // transforms' vector blocks (16 tiles) with tails, and padding rows of a 1x5 kernel
    ("1x5_p0x2", [2, 3, 5, 13], [4, 3, 1, 5], [1, 1], [0, 2]),
    ("1x5_p0x2_wide", [1, 3, 3, 75], [4, 3, 1, 5], [1, 1], [0, 2]),
    ("1x5_p1x4", [2, 3, 4, 9], [3, 3, 1, 5], [1, 1], [1, 4]),
    ("5x1_p2x0", [2, 3, 13, 7], [4, 3, 5, 1], [1, 1], [2, 0]),
    ("5x1_p2x0_wide", [1, 3, 9, 37], [4, 3, 5, 1], [1, 1], [2, 0]),
    ("5x1_p3x1", [1, 2, 7, 5], [3, 2, 5, 1], [1, 1], [3, 1]),
    ("1x5_p0x2_64ch", [2, 64, 9, 35], [24, 64, 1, 5], [1, 1], [0, 2]),
    ("5x1_p2x0_64ch", [2, 64, 29, 9], [24, 64, 5, 1], [1, 1], [2, 0]),
];

#[test]
fn conv2d_winograd_f64_matches_direct_sum() {
    // in f64 the transforms are exact up to rounding: the algorithm itself is checked, on every
    // ISA path (the row transforms are compiled once per ISA)
    let mut rng = Rng::new(60);
    for isa in Isa::ALL.into_iter().filter(|i| i.supported()) {
        let run = Conv2dRun { plan: _core::gemm::Plan::<f64>::for_isa(isa).unwrap(), winograd: Winograd::On, reuse_kernels: false };
        for &(name, xs, ws, stride, padding) in WINOGRAD_CASES {
            let cfg = Conv2dCfg::new(stride, padding);
            let (x, w, b) = inputs(&mut rng, &xs, &ws);
            for relu in [false, true] {
                let y = conv2d_fwd_ex(x.view(), w.view(), Some(b.view()), &cfg, relu, run).unwrap().into_dyn();
                let want = conv_ref(&x, &w, Some(&b), &cfg).mapv(|v| if relu { v.max(0.0) } else { v });
                let err = max_abs_diff(&y, &want);
                assert!(err < 1e-11, "{} {name} relu={relu}: max abs err {err}", isa.name());
            }
        }
    }
    // dX of a stride-1 3x3 conv is a Winograd forward too, and dW is Winograd's adjoint
    gradcheck_winograd("3x3 p1 winograd", [2, 4, 7, 9], [5, 4, 3, 3], Conv2dCfg::new([1, 1], [1, 1]), 61);
    gradcheck_winograd("3x3 p0x2 winograd", [1, 3, 6, 10], [2, 3, 3, 3], Conv2dCfg::new([1, 1], [0, 2]), 64);
    gradcheck_winograd("1x5 p0x2 winograd", [2, 3, 3, 11], [2, 3, 1, 5], Conv2dCfg::new([1, 1], [0, 2]), 67);
    gradcheck_winograd("5x1 p2x0 winograd", [2, 3, 9, 4], [2, 3, 5, 1], Conv2dCfg::new([1, 1], [2, 0]), 68);
}

/// dx and dw of one case with Winograd forced, against finite differences of the direct forward.
fn gradcheck_winograd(name: &str, xs: [usize; 4], ws: [usize; 4], cfg: Conv2dCfg, seed: u64) {
    let mut rng = Rng::new(seed);
    let (x, w, b) = inputs(&mut rng, &xs, &ws);
    let y = conv2d_fwd(x.view(), w.view(), Some(b.view()), &cfg).unwrap();
    let g = rng.array(y.shape(), -1.0, 1.0);
    let run = Conv2dRun { plan: _core::gemm::Plan::<f64>::selected(), winograd: Winograd::On, reuse_kernels: false };
    let grads = conv2d_bwd_ex(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL, run).unwrap();
    let loss_x = |xp: &ArrayD<f64>| dot(&conv2d_fwd(xp.view(), w.view(), Some(b.view()), &cfg).unwrap().into_dyn(), &g);
    gradcheck(&format!("{name} dx"), &x, &grads.x.unwrap().into_dyn(), loss_x);
    let loss_w = |wp: &ArrayD<f64>| dot(&conv2d_fwd(x.view(), wp.view(), Some(b.view()), &cfg).unwrap().into_dyn(), &g);
    gradcheck(&format!("{name} dw"), &w, &grads.w.unwrap().into_dyn(), loss_w);
}

/// dW of a case by the direct path and by Winograd (forced) on one ISA path, in the element type of
/// the inputs.
fn weight_grads<F: _core::Float>(isa: Isa, x: &ArrayD<F>, w: &ArrayD<F>, g: &ArrayD<F>, cfg: &Conv2dCfg) -> [ArrayD<F>; 2] {
    let need = Conv2dNeed { x: false, w: true, b: false };
    [Winograd::Off, Winograd::On].map(|winograd| {
        let run = Conv2dRun { plan: _core::gemm::Plan::<F>::for_isa(isa).unwrap(), winograd, reuse_kernels: false };
        conv2d_bwd_ex(x.view(), w.view(), g.view(), cfg, need, run).unwrap().w.unwrap().into_dyn()
    })
}

#[test]
fn conv2d_winograd_weight_grad_matches_direct_in_f64() {
    // every case, and a batch of 8 images whose tile rows span several chunks (so later chunks add
    // into the first one's sums)
    let mut rng = Rng::new(65);
    let chunked = [
        ("3x3_p1_64ch_batch8", [8, 64, 29, 35], [24, 64, 3, 3], [1, 1], [1, 1]),
        ("1x5_p0x2_64ch_batch8", [8, 64, 64, 35], [24, 64, 1, 5], [1, 1], [0, 2]),
    ];
    for isa in Isa::ALL.into_iter().filter(|i| i.supported()) {
        for &(name, xs, ws, stride, padding) in WINOGRAD_CASES.iter().chain(&chunked) {
            let cfg = Conv2dCfg::new(stride, padding);
            let (x, w, _) = inputs(&mut rng, &xs, &ws);
            let (ho, wo) = cfg.out_hw(xs[2], xs[3], ws[2], ws[3]).unwrap();
            let g = rng.array(&[xs[0], ws[0], ho, wo], -1.0, 1.0);
            let [direct, winograd] = weight_grads(isa, &x, &w, &g, &cfg);
            let scale = direct.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let err = max_abs_diff(&winograd, &direct) / scale;
            assert!(err < 1e-12, "{} {name}: winograd dW relative error {err:.2e}", isa.name());
        }
    }
}

#[test]
fn conv2d_winograd_weight_grad_f32_error_against_f64_is_small() {
    // the f32 rounding of the transforms and of the sums over tiles, relative to the largest dW
    let mut rng = Rng::new(66);
    for &(name, xs, ws, stride, padding) in WINOGRAD_CASES {
        let cfg = Conv2dCfg::new(stride, padding);
        let (x, w, _) = inputs(&mut rng, &xs, &ws);
        let (ho, wo) = cfg.out_hw(xs[2], xs[3], ws[2], ws[3]).unwrap();
        let g = rng.array(&[xs[0], ws[0], ho, wo], -1.0, 1.0);
        let isa = Isa::selected();
        let [want, _] = weight_grads(isa, &x, &w, &g, &cfg);
        let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let [direct, winograd] = weight_grads(isa, &x.mapv(|v| v as f32), &w.mapv(|v| v as f32), &g.mapv(|v| v as f32), &cfg);
        let errs = [direct, winograd].map(|d| max_abs_diff(&d.mapv(f64::from), &want) / scale);
        eprintln!("{name}: dW max error / max |dW|: direct {:.1e}, winograd {:.1e}", errs[0], errs[1]);
        assert!(errs[1] < 2e-5, "{name}: winograd dW relative error {:.2e}", errs[1]);
    }
}

#[test]
fn conv2d_winograd_f32_error_against_f64_is_small() {
    // the f32 rounding of the transforms: reported, and bounded relative to the output scale
    let mut rng = Rng::new(62);
    for &(name, xs, ws, stride, padding) in WINOGRAD_CASES {
        let cfg = Conv2dCfg::new(stride, padding);
        let (x, w, b) = inputs(&mut rng, &xs, &ws);
        // weights of a trained layer's scale (1 / sqrt(fan-in)), inputs in [-1, 1]
        let w = w.mapv(|v| v / ((ws[1] * 9) as f64).sqrt());
        let want = conv_ref(&x, &w, Some(&b), &cfg);
        let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let (x32, w32, b32) = (x.mapv(|v| v as f32), w.mapv(|v| v as f32), b.mapv(|v| v as f32));
        let mut errs = vec![];
        for winograd in [Winograd::Off, Winograd::On] {
            let run = Conv2dRun { plan: _core::gemm::Plan::<f32>::selected(), winograd, reuse_kernels: false };
            let y = conv2d_fwd_ex(x32.view(), w32.view(), Some(b32.view()), &cfg, false, run).unwrap().into_dyn();
            errs.push(max_abs_diff(&y.mapv(f64::from), &want) / scale);
        }
        eprintln!("{name}: max error / max |y|: direct {:.1e}, winograd {:.1e}", errs[0], errs[1]);
        assert!(errs[1] < 2e-5, "{name}: winograd relative error {:.2e}", errs[1]);
    }
}

#[test]
fn conv2d_winograd_results_do_not_depend_on_the_thread_count() {
    // the task split (bands, output-channel ranges) follows the threads; every output does not
    let mut rng = Rng::new(63);
    for &(name, xs, ws, stride, padding) in WINOGRAD_CASES.iter().filter(|c| c.0.ends_with("64ch")) {
        let cfg = Conv2dCfg::new(stride, padding);
        let (x, w, b) = inputs(&mut rng, &xs, &ws);
        let (x, w, b) = (x.mapv(|v| v as f32), w.mapv(|v| v as f32), b.mapv(|v| v as f32));
        let (ho, wo) = cfg.out_hw(xs[2], xs[3], ws[2], ws[3]).unwrap();
        let g = rng.array(&[xs[0], ws[0], ho, wo], -1.0, 1.0).mapv(|v| v as f32);
        let run = Conv2dRun { plan: _core::gemm::Plan::<f32>::selected(), winograd: Winograd::On, reuse_kernels: false };
        let at = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let y = conv2d_fwd_ex(x.view(), w.view(), Some(b.view()), &cfg, true, run).unwrap();
                let grads = conv2d_bwd_ex(x.view(), w.view(), g.view(), &cfg, Conv2dNeed::ALL, run).unwrap();
                (y, grads.x, grads.w)
            })
        };
        let (y1, dx1, dw1) = at(1);
        for threads in [2, 3, 7] {
            let (y, dx, dw) = at(threads);
            assert_eq!(y1, y, "{name} forward, {threads} threads");
            assert_eq!(dx1, dx, "{name} dx, {threads} threads");
            assert_eq!(dw1, dw, "{name} dw, {threads} threads");
        }
    }
}

#[test]
fn conv2d_winograd_kept_kernels_follow_the_weight_values() {
    // a run that keeps transformed kernels gives the fresh transform's result bitwise, and a kernel
    // changed in place (same buffer, as after an optimiser step) is transformed again, not reused
    let mut rng = Rng::new(64);
    for &(name, xs, ws, stride, padding) in WINOGRAD_CASES.iter().filter(|c| c.0.ends_with("64ch")) {
        let cfg = Conv2dCfg::new(stride, padding);
        let (x, w, b) = inputs(&mut rng, &xs, &ws);
        let (x, mut w, b) = (x.mapv(|v| v as f32), w.mapv(|v| v as f32), b.mapv(|v| v as f32));
        let fresh = Conv2dRun { plan: _core::gemm::Plan::<f32>::selected(), winograd: Winograd::On, reuse_kernels: false };
        let kept = Conv2dRun { reuse_kernels: true, ..fresh };
        let y = |w: &ArrayD<f32>, run| conv2d_fwd_ex(x.view(), w.view(), Some(b.view()), &cfg, false, run).unwrap();
        for _ in 0..2 {
            assert_eq!(y(&w, kept), y(&w, fresh), "{name}: kept kernel");
        }
        let before = y(&w, kept);
        w.iter_mut().step_by(7).for_each(|v| *v = -*v);
        let after = y(&w, kept);
        assert_eq!(after, y(&w, fresh), "{name}: kernel changed in place");
        assert_ne!(after, before, "{name}: the changed kernel changes the output");
    }
}
