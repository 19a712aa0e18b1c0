//! avg_pool2d: closed-form forwards, f64 gradchecks of the backward for every option, and errors.
mod common;

use _core::ops::pool::{avg_pool2d_bwd, avg_pool2d_fwd, AvgPool2dCfg};
use common::{dot, gradcheck, Rng};
use ndarray::{ArrayD, IxDyn};

fn cfg(k: i64, s: i64, p: i64, ceil: bool, include_pad: bool, divisor: Option<i64>) -> AvgPool2dCfg {
    AvgPool2dCfg::new([k, k], [s, s], [p, p], ceil, include_pad, divisor).unwrap()
}

// Average pooling is linear in x: no kinks anywhere.
#[test]
fn avg_pool2d_all_options_bwd_gradcheck_f64() {
    let mut rng = Rng::new(31);
    let cases = [
        (vec![2, 3, 8, 9], cfg(4, 4, 0, false, true, None)),
        (vec![1, 2, 7, 6], cfg(3, 2, 1, false, true, None)),
        (vec![1, 2, 7, 6], cfg(3, 2, 1, true, false, None)),
        (vec![2, 1, 6, 7], cfg(2, 3, 1, true, true, None)),
        (vec![3, 5, 5], cfg(2, 2, 0, true, true, Some(3))),
        (vec![1, 1, 5, 9], AvgPool2dCfg::new([2, 3], [1, 2], [1, 0], false, false, None).unwrap()),
    ];
    for (shape, c) in cases {
        let x = rng.array(&shape, -2.0, 2.0);
        let y = avg_pool2d_fwd(x.view(), &c).unwrap();
        let g = rng.array(y.shape(), -1.0, 1.0);
        let dx = avg_pool2d_bwd(g.view(), &shape, &c).unwrap();
        gradcheck(&format!("avg_pool2d {shape:?} {c:?}"), &x, &dx, |xp| dot(&avg_pool2d_fwd(xp.view(), &c).unwrap(), &g));
    }
}

#[test]
fn avg_pool2d_4x4_stride4_matches_block_means() {
    // x[h, w] = 8h + w on an 8x8 plane: the mean of block (i, j) is 8(4i + 1.5) + 4j + 1.5
    let x = ArrayD::from_shape_fn(IxDyn(&[1, 1, 8, 8]), |i| (8 * i[2] + i[3]) as f64);
    let y = avg_pool2d_fwd(x.view(), &cfg(4, 4, 0, false, true, None)).unwrap();
    assert_eq!(y.shape(), &[1, 1, 2, 2]);
    for (i, j) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
        assert_eq!(y[[0, 0, i, j]], 8.0 * (4.0 * i as f64 + 1.5) + 4.0 * j as f64 + 1.5);
    }
}

#[test]
fn avg_pool2d_padding_divisor_counts_padding_only_with_count_include_pad() {
    // ones(3x3), 3x3 window, stride 1, padding 1: corners see 4 ones, edges 6, centre 9
    let x = ArrayD::<f64>::ones(IxDyn(&[1, 1, 3, 3]));
    let inc = avg_pool2d_fwd(x.view(), &cfg(3, 1, 1, false, true, None)).unwrap();
    let exc = avg_pool2d_fwd(x.view(), &cfg(3, 1, 1, false, false, None)).unwrap();
    let over = avg_pool2d_fwd(x.view(), &cfg(3, 1, 1, false, true, Some(2))).unwrap();
    assert_eq!((inc[[0, 0, 0, 0]], inc[[0, 0, 0, 1]], inc[[0, 0, 1, 1]]), (4.0 / 9.0, 6.0 / 9.0, 1.0));
    assert!(exc.iter().all(|&v| v == 1.0));
    assert_eq!((over[[0, 0, 0, 0]], over[[0, 0, 1, 1]]), (2.0, 4.5));
}

#[test]
fn avg_pool2d_ceil_mode_adds_a_partial_window() {
    // 5 wide, 2x2 stride 2: floor gives 2 outputs, ceil 3 (the last window holds column 4 only)
    let x = ArrayD::from_shape_fn(IxDyn(&[1, 1, 2, 5]), |i| i[3] as f64);
    let floor = avg_pool2d_fwd(x.view(), &cfg(2, 2, 0, false, true, None)).unwrap();
    let ceil = avg_pool2d_fwd(x.view(), &cfg(2, 2, 0, true, true, None)).unwrap();
    assert_eq!(floor.shape(), &[1, 1, 1, 2]);
    assert_eq!(ceil.shape(), &[1, 1, 1, 3]);
    assert_eq!(ceil[[0, 0, 0, 2]], 4.0);
}

#[test]
fn avg_pool2d_errors_name_op_and_shapes() {
    let x = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 3, 3]));
    let err = avg_pool2d_fwd(x.view(), &cfg(4, 4, 0, false, true, None)).unwrap_err().to_string();
    assert!(err.contains("avg_pool2d") && err.contains("larger than the padded input") && err.contains("[2, 3, 3, 3]"), "{err}");
    let x2 = ArrayD::<f32>::zeros(IxDyn(&[3, 3]));
    let err = avg_pool2d_fwd(x2.view(), &cfg(2, 2, 0, false, true, None)).unwrap_err().to_string();
    assert!(err.contains("avg_pool2d") && err.contains("[3, 3]"), "{err}");
    let empty = ArrayD::<f32>::zeros(IxDyn(&[0, 3, 4, 4]));
    let err = avg_pool2d_fwd(empty.view(), &cfg(2, 2, 0, false, true, None)).unwrap_err().to_string();
    assert!(err.contains("empty") && err.contains("[0, 3, 4, 4]"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 2, 2]));
    let err = avg_pool2d_bwd(g.view(), &[2, 3, 3, 3], &cfg(2, 2, 0, false, true, None)).unwrap_err().to_string();
    assert!(err.contains("avg_pool2d") && err.contains("[2, 3, 3, 3]") && err.contains("[2, 3, 2, 2]"), "{err}");
    for (k, s, p, d) in [(0, 1, 0, None), (2, 0, 0, None), (2, 2, 2, None), (2, 2, -1, None), (2, 2, 0, Some(0))] {
        let err = AvgPool2dCfg::new([k, k], [s, s], [p, p], false, true, d).unwrap_err().to_string();
        assert!(err.starts_with("avg_pool2d:"), "{err}");
    }
}
