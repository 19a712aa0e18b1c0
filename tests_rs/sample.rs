//! grid_sample, bilinear interpolate, unfold / fold: closed-form forwards, f64 gradchecks of every
//! backward, determinism across thread counts, and error messages.
mod common;

use _core::ops::sample::*;
use common::{dot, gradcheck, max_abs_diff, Rng};
use ndarray::{arr2, Array4, ArrayD, IxDyn};

const MODES: [GridPadding; 2] = [GridPadding::Zeros, GridPadding::Border];

/// Normalised coordinate of pixel coordinate `px` along an axis of `size` pixels.
fn normalise(px: f64, size: usize, align: bool) -> f64 {
    // align: px = (u + 1)(size - 1)/2; else px = ((u + 1) size - 1)/2
    if align { 2.0 * px / (size as f64 - 1.0) - 1.0 } else { (2.0 * px + 1.0) / size as f64 - 1.0 }
}

/// A grid (n, ho, wo, 2) reaching 2 pixels beyond every border (so zeros and border padding both
/// matter) whose pixel coordinates all have fractional parts in [0.15, 0.85]: no sample lies on an
/// integer position, where the bilinear weights and the border clamp at 0 and size-1 have kinks.
fn kink_free_grid(rng: &mut Rng, n: usize, ho: usize, wo: usize, h: usize, w: usize, align: bool) -> ArrayD<f64> {
    let mut g = ArrayD::<f64>::zeros(IxDyn(&[n, ho, wo, 2]));
    for p in g.as_slice_mut().unwrap().chunks_mut(2) {
        let px = rng.uniform(-2.0, w as f64 + 1.0).floor() + rng.uniform(0.15, 0.85);
        let py = rng.uniform(-2.0, h as f64 + 1.0).floor() + rng.uniform(0.15, 0.85);
        p[0] = normalise(px, w, align);
        p[1] = normalise(py, h, align);
    }
    g
}

#[test]
fn grid_sample_bwd_gradcheck_f64_input_and_grid_all_modes() {
    let mut rng = Rng::new(11);
    for padding in MODES {
        for align in [true, false] {
            let cfg = GridSampleCfg { padding, align_corners: align };
            let x = rng.array(&[2, 3, 5, 6], -1.0, 1.0);
            let grid = kink_free_grid(&mut rng, 2, 4, 3, 5, 6, align);
            let y = grid_sample_fwd(x.view(), grid.view(), &cfg).unwrap();
            let g = rng.array(y.shape(), -1.0, 1.0);
            let grads = grid_sample_bwd(x.view(), grid.view(), g.view(), &cfg, true, true).unwrap();
            let name = format!("grid_sample {padding:?} align={align}");
            let loss = |xp: &ArrayD<f64>, gp: &ArrayD<f64>| dot(&grid_sample_fwd(xp.view(), gp.view(), &cfg).unwrap().into_dyn(), &g);
            gradcheck(&format!("{name} input"), &x, &grads.input.unwrap().into_dyn(), |xp| loss(xp, &grid));
            gradcheck(&format!("{name} grid"), &grid, &grads.grid.unwrap().into_dyn(), |gp| loss(&x, gp));
        }
    }
}

#[test]
fn grid_sample_border_grid_grad_is_zero_beyond_the_border() {
    // points clamped by border padding get no grid gradient (torch's clip_coordinates_set_grad)
    let cfg = GridSampleCfg { padding: GridPadding::Border, align_corners: true };
    let x = Rng::new(2).array(&[1, 2, 4, 4], -1.0, 1.0);
    let grid = ArrayD::from_shape_vec(IxDyn(&[1, 1, 2, 2]), vec![-1.7, 0.1, 1.3, 0.2]).unwrap();
    let g = ArrayD::<f64>::ones(IxDyn(&[1, 2, 1, 2]));
    let dg = grid_sample_bwd(x.view(), grid.view(), g.view(), &cfg, false, true).unwrap();
    assert!(dg.input.is_none());
    let dg = dg.grid.unwrap();
    assert_eq!((dg[[0, 0, 0, 0]], dg[[0, 0, 1, 0]]), (0.0, 0.0));
    assert!(dg[[0, 0, 0, 1]] != 0.0 && dg[[0, 0, 1, 1]] != 0.0);
}

#[test]
fn grid_sample_pixel_centre_grid_reproduces_input() {
    let x = Rng::new(5).array(&[2, 3, 4, 7], -1.0, 1.0);
    for align in [true, false] {
        let grid = ArrayD::from_shape_fn(IxDyn(&[2, 4, 7, 2]), |i| {
            if i[3] == 0 { normalise(i[2] as f64, 7, align) } else { normalise(i[1] as f64, 4, align) }
        });
        for padding in MODES {
            let y = grid_sample_fwd(x.view(), grid.view(), &GridSampleCfg { padding, align_corners: align }).unwrap().into_dyn();
            assert!(max_abs_diff(&y, &x) < 1e-12, "align={align} {padding:?}");
        }
    }
}

#[test]
fn grid_sample_single_row_by_hand() {
    // x = [1, 2, 4] in one row; align_corners: u -> px = u + 1
    let x = ArrayD::from_shape_vec(IxDyn(&[1, 1, 1, 3]), vec![1.0f64, 2.0, 4.0]).unwrap();
    let us = [-3.0, 0.0, 0.5, 2.0, -1.5];
    let grid = ArrayD::from_shape_vec(IxDyn(&[1, 1, 5, 2]), us.iter().flat_map(|&u| [u, 0.0]).collect()).unwrap();
    let zeros = grid_sample_fwd(x.view(), grid.view(), &GridSampleCfg { padding: GridPadding::Zeros, align_corners: true }).unwrap();
    let border = grid_sample_fwd(x.view(), grid.view(), &GridSampleCfg { padding: GridPadding::Border, align_corners: true }).unwrap();
    // px = -2, 1, 1.5, 3, -0.5: zeros -> 0, 2, 3, 0, 0.5·1; border clamps to [0, 2] -> 1, 2, 3, 4, 1
    assert_eq!(zeros.iter().copied().collect::<Vec<_>>(), vec![0.0, 2.0, 3.0, 0.0, 0.5]);
    assert_eq!(border.iter().copied().collect::<Vec<_>>(), vec![1.0, 2.0, 3.0, 4.0, 1.0]);
}

/// Runs `f` in a rayon pool of `n` threads.
fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(f)
}

#[test]
fn grid_sample_bwd_is_bitwise_deterministic_across_thread_counts() {
    let mut rng = Rng::new(8);
    let cfg = GridSampleCfg { padding: GridPadding::Border, align_corners: true };
    let x = rng.array(&[2, 9, 12, 10], -1.0, 1.0).mapv(|v| v as f32);
    let grid = rng.array(&[2, 12, 10, 2], -1.2, 1.2).mapv(|v| v as f32);
    let g = rng.array(&[2, 9, 12, 10], -1.0, 1.0).mapv(|v| v as f32);
    let run = |n| with_threads(n, || grid_sample_bwd(x.view(), grid.view(), g.view(), &cfg, true, true).unwrap());
    let (a, b) = (run(1), run(3));
    assert_eq!(a.input, b.input);
    assert_eq!(a.grid, b.grid);
}

#[test]
fn grid_sample_rejects_nan_bad_shapes_and_empty() {
    let cfg = GridSampleCfg { padding: GridPadding::Zeros, align_corners: false };
    let x = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 4, 5]));
    let mut grid = ArrayD::<f32>::zeros(IxDyn(&[2, 6, 7, 2]));
    grid[[1, 2, 3, 0]] = f32::NAN;
    let err = grid_sample_fwd(x.view(), grid.view(), &cfg).unwrap_err().to_string();
    assert!(err.contains("grid_sample") && err.contains("NaN") && err.contains("[2, 6, 7, 2]"), "{err}");
    let bad = ArrayD::<f32>::zeros(IxDyn(&[2, 6, 7, 3]));
    let err = grid_sample_fwd(x.view(), bad.view(), &cfg).unwrap_err().to_string();
    assert!(err.contains("grid_sample") && err.contains("[2, 3, 4, 5]") && err.contains("[2, 6, 7, 3]"), "{err}");
    let bad = ArrayD::<f32>::zeros(IxDyn(&[3, 6, 7, 2]));
    assert!(grid_sample_fwd(x.view(), bad.view(), &cfg).unwrap_err().to_string().contains("[3, 6, 7, 2]"));
    let empty = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 0, 5]));
    let ok_grid = ArrayD::<f32>::zeros(IxDyn(&[2, 6, 7, 2]));
    assert!(grid_sample_fwd(empty.view(), ok_grid.view(), &cfg).unwrap_err().to_string().contains("empty"));
    let g = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 7, 6]));
    let err = grid_sample_bwd(x.view(), ok_grid.view(), g.view(), &cfg, true, true).unwrap_err().to_string();
    assert!(err.contains("grid_sample") && err.contains("[2, 3, 7, 6]"), "{err}");
    assert!(GridPadding::parse("reflection").unwrap_err().to_string().contains("reflection"));
}

#[test]
fn interpolate_bilinear_align_corners_by_hand() {
    let x = arr2(&[[0.0f64, 1.0], [2.0, 3.0]]).into_shape_with_order((1, 1, 2, 2)).unwrap().into_dyn();
    let cfg = InterpCfg { out_hw: (3, 3), align_corners: true, scales: [None, None] };
    let y = interpolate_bilinear_fwd(x.view(), &cfg).unwrap();
    let expect = Array4::from_shape_vec((1, 1, 3, 3), vec![0.0, 0.5, 1.0, 1.0, 1.5, 2.0, 2.0, 2.5, 3.0]).unwrap();
    assert_eq!(y, expect);
    // without align_corners, 2 -> 4 samples at -0.25 (clamped to 0), 0.25, 0.75, 1.25 (upper index clamped)
    let cfg = InterpCfg { out_hw: (1, 4), align_corners: false, scales: [None, None] };
    let row = ArrayD::from_shape_vec(IxDyn(&[1, 1, 1, 2]), vec![0.0f64, 1.0]).unwrap();
    let y = interpolate_bilinear_fwd(row.view(), &cfg).unwrap();
    assert_eq!(y.iter().copied().collect::<Vec<_>>(), vec![0.0, 0.25, 0.75, 1.0]);
}

#[test]
fn interpolate_bilinear_bwd_gradcheck_f64() {
    // linear in x: no kinks.
    let mut rng = Rng::new(4);
    let x = rng.array(&[2, 2, 5, 7], -1.0, 1.0);
    for align in [true, false] {
        for (out, scales) in [((9, 4), [None, None]), ((20, 28), [None, None]), ((8, 11), [Some(1.7), Some(1.6)]), ((1, 1), [None, None])] {
            let cfg = InterpCfg { out_hw: out, align_corners: align, scales };
            let y = interpolate_bilinear_fwd(x.view(), &cfg).unwrap();
            let g = rng.array(y.shape(), -1.0, 1.0);
            let dx = interpolate_bilinear_bwd(g.view(), (5, 7), &cfg).unwrap().into_dyn();
            gradcheck(&format!("interpolate align={align} {out:?}"), &x, &dx, |xp| dot(&interpolate_bilinear_fwd(xp.view(), &cfg).unwrap().into_dyn(), &g));
        }
    }
}

#[test]
fn interpolate_rejects_zero_size_and_mismatched_grad() {
    let x = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 3, 4]));
    let cfg = InterpCfg { out_hw: (0, 5), align_corners: true, scales: [None, None] };
    let err = interpolate_bilinear_fwd(x.view(), &cfg).unwrap_err().to_string();
    assert!(err.contains("interpolate") && err.contains("[1, 2, 3, 4]") && err.contains("[0, 5]"), "{err}");
    let cfg = InterpCfg { out_hw: (6, 8), align_corners: true, scales: [None, None] };
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 6, 7]));
    let err = interpolate_bilinear_bwd(g.view(), (3, 4), &cfg).unwrap_err().to_string();
    assert!(err.contains("interpolate") && err.contains("[1, 2, 6, 7]"), "{err}");
    let x3 = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 4]));
    assert!(interpolate_bilinear_fwd(x3.view(), &cfg).unwrap_err().to_string().contains("[2, 3, 4]"));
    let huge = InterpCfg { out_hw: (1 << 40, 1 << 40), align_corners: true, scales: [None, None] };
    let err = interpolate_bilinear_fwd(x.view(), &huge).unwrap_err().to_string();
    assert!(err.contains("interpolate") && err.contains("too large to allocate"), "{err}");
}

fn ucfg(k: [usize; 2], d: [usize; 2], p: [usize; 2], s: [usize; 2]) -> UnfoldCfg {
    UnfoldCfg::new("unfold", k, d, p, s).unwrap()
}

#[test]
fn unfold_3x3_pad1_and_fold_by_hand() {
    let x = arr2(&[[1.0f64, 2.0], [3.0, 4.0]]).into_shape_with_order((1, 1, 2, 2)).unwrap().into_dyn();
    let cfg = ucfg([3, 3], [1, 1], [1, 1], [1, 1]);
    let cols = unfold_fwd(x.view(), &cfg).unwrap();
    assert_eq!(cols.shape(), &[1, 9, 4]);
    // row 0 = kernel tap (0, 0): the up-left neighbour of each of the 4 blocks; row 4 = the centre
    assert_eq!(cols.slice(ndarray::s![0, 0, ..]).to_vec(), vec![0.0, 0.0, 0.0, 1.0]);
    assert_eq!(cols.slice(ndarray::s![0, 4, ..]).to_vec(), vec![1.0, 2.0, 3.0, 4.0]);
    let ones = ArrayD::<f64>::ones(IxDyn(&[1, 9, 4]));
    // every pixel of a 2x2 image lies in all 4 blocks
    assert_eq!(fold_fwd(ones.view(), (2, 2), &cfg).unwrap(), Array4::from_elem((1, 1, 2, 2), 4.0));
}

#[test]
fn unfold_and_fold_are_adjoint_gradcheck_f64() {
    let mut rng = Rng::new(9);
    let x = rng.array(&[2, 3, 7, 6], -1.0, 1.0);
    for cfg in [ucfg([3, 3], [1, 1], [1, 1], [1, 1]), ucfg([2, 3], [2, 1], [0, 2], [2, 3]), ucfg([1, 1], [1, 1], [0, 0], [1, 1]), ucfg([7, 6], [1, 1], [0, 0], [1, 1])] {
        let cols = unfold_fwd(x.view(), &cfg).unwrap().into_dyn();
        let g = rng.array(cols.shape(), -1.0, 1.0);
        // d<unfold(x), g>/dx = fold(g)
        let dx = fold_fwd(g.view(), (7, 6), &cfg).unwrap().into_dyn();
        gradcheck(&format!("unfold {cfg:?}"), &x, &dx, |xp| dot(&unfold_fwd(xp.view(), &cfg).unwrap().into_dyn(), &g));
        // d<fold(c), g2>/dc = unfold(g2)
        let c = rng.array(cols.shape(), -1.0, 1.0);
        let g2 = rng.array(x.shape(), -1.0, 1.0);
        let dc = unfold_fwd(g2.view(), &cfg).unwrap().into_dyn();
        gradcheck(&format!("fold {cfg:?}"), &c, &dc, |cp| dot(&fold_fwd(cp.view(), (7, 6), &cfg).unwrap().into_dyn(), &g2));
    }
}

#[test]
fn unfold_fold_reject_large_kernel_zero_stride_and_bad_columns() {
    let x = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 2, 2]));
    let err = unfold_fwd(x.view(), &ucfg([5, 5], [1, 1], [1, 1], [1, 1])).unwrap_err().to_string();
    assert!(err.contains("unfold") && err.contains("larger") && err.contains("[1, 2, 2, 2]"), "{err}");
    let err = UnfoldCfg::new("unfold", [3, 3], [1, 1], [0, 0], [0, 1]).unwrap_err().to_string();
    assert!(err.contains("unfold") && err.contains("stride"), "{err}");
    let cols = ArrayD::<f32>::zeros(IxDyn(&[1, 18, 5]));
    let err = fold_fwd(cols.view(), (2, 2), &ucfg([3, 3], [1, 1], [1, 1], [1, 1])).unwrap_err().to_string();
    assert!(err.contains("fold") && err.contains("[1, 18, 5]") && err.contains("[2, 2]"), "{err}");
    let cols = ArrayD::<f32>::zeros(IxDyn(&[1, 10, 4]));
    assert!(fold_fwd(cols.view(), (2, 2), &ucfg([3, 3], [1, 1], [1, 1], [1, 1])).unwrap_err().to_string().contains("[1, 10, 4]"));
    // absurd padding / kernels fail with an error, never an overflow
    let err = unfold_fwd(x.view(), &ucfg([1 << 40, 1 << 40], [1, 1], [1 << 40, 1 << 40], [1, 1])).unwrap_err().to_string();
    assert!(err.contains("unfold") && (err.contains("too large") || err.contains("overflow")), "{err}");
    let err = unfold_fwd(x.view(), &ucfg([3, 3], [usize::MAX, 1], [usize::MAX, 1], [1, 1])).unwrap_err().to_string();
    assert!(err.contains("unfold"), "{err}");
}
