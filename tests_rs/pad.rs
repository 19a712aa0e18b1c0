//! pad2d: hand-computed forwards, f64 gradchecks of the backward, and error messages.
mod common;

use _core::ops::pad::{pad2d_bwd, pad2d_fwd, Pad2dCfg, PadMode};
use common::{dot, gradcheck, Rng};
use ndarray::{arr2, ArrayD, IxDyn};

fn cfg(pad: [i64; 4], mode: PadMode, value: f64) -> Pad2dCfg {
    Pad2dCfg::new(&pad, mode, value).unwrap()
}

#[test]
fn pad2d_replicate_copies_edges_and_corners() {
    // x = [[1, 2], [3, 4]] padded [left 1, right 2, top 1, bottom 0]
    let x = arr2(&[[1.0f64, 2.0], [3.0, 4.0]]).into_shape_with_order((1, 1, 2, 2)).unwrap().into_dyn();
    let y = pad2d_fwd(x.view(), &cfg([1, 2, 1, 0], PadMode::Replicate, 0.0)).unwrap();
    let expect = arr2(&[[1.0, 1.0, 2.0, 2.0, 2.0], [1.0, 1.0, 2.0, 2.0, 2.0], [3.0, 3.0, 4.0, 4.0, 4.0]]);
    assert_eq!(y.shape(), &[1, 1, 3, 5]);
    assert_eq!(y.index_axis(ndarray::Axis(0), 0).index_axis(ndarray::Axis(0), 0), expect);
}

#[test]
fn pad2d_constant_fills_value() {
    let x = ArrayD::<f32>::ones(IxDyn(&[2, 3, 2, 2]));
    let y = pad2d_fwd(x.view(), &cfg([0, 1, 2, 0], PadMode::Zero, -1.5)).unwrap();
    assert_eq!(y.shape(), &[2, 3, 4, 3]);
    let sum: f32 = y.iter().sum();
    // 6 planes of 4 ones and 8 fills of -1.5
    assert_eq!(sum, 6.0 * (4.0 - 8.0 * 1.5));
}

#[test]
fn pad2d_replicate_bwd_accumulates_border_into_edges() {
    // a 1x1 input receives every padded pixel's gradient
    let g = ArrayD::<f64>::ones(IxDyn(&[1, 1, 4, 5]));
    let dx = pad2d_bwd(g.view(), (1, 1), &cfg([1, 3, 2, 1], PadMode::Replicate, 0.0)).unwrap();
    assert_eq!(dx[[0, 0, 0, 0]], 20.0);
}

#[test]
fn pad2d_bwd_gradcheck_f64_both_modes() {
    // pad is linear in x: no kinks anywhere.
    let mut rng = Rng::new(3);
    let x = rng.array(&[2, 3, 4, 5], -1.0, 1.0);
    for mode in [PadMode::Zero, PadMode::Replicate] {
        for pad in [[1, 2, 3, 0], [3, 3, 1, 1], [0, 0, 0, 0], [6, 0, 0, 5]] {
            let c = cfg(pad, mode, 0.7);
            let y = pad2d_fwd(x.view(), &c).unwrap();
            let g = rng.array(y.shape(), -1.0, 1.0);
            let dx = pad2d_bwd(g.view(), (4, 5), &c).unwrap().into_dyn();
            gradcheck(&format!("pad {mode:?} {pad:?}"), &x, &dx, |xp| dot(&pad2d_fwd(xp.view(), &c).unwrap().into_dyn(), &g));
        }
    }
}

#[test]
fn pad2d_rejects_bad_rank_pad_and_grad() {
    let x3 = ArrayD::<f32>::zeros(IxDyn(&[3, 4, 5]));
    let err = pad2d_fwd(x3.view(), &cfg([1, 1, 1, 1], PadMode::Zero, 0.0)).unwrap_err().to_string();
    assert!(err.contains("pad") && err.contains("[3, 4, 5]"), "{err}");
    let err = Pad2dCfg::new(&[1, -1, 0, 0], PadMode::Zero, 0.0).unwrap_err().to_string();
    assert!(err.contains("pad") && err.contains("negative"), "{err}");
    let err = Pad2dCfg::new(&[1, 1, 0], PadMode::Zero, 0.0).unwrap_err().to_string();
    assert!(err.contains("pad") && err.contains("4 entries"), "{err}");
    assert!(PadMode::parse("reflect").unwrap_err().to_string().contains("reflect"));
    let empty = ArrayD::<f32>::zeros(IxDyn(&[1, 0, 4, 5]));
    let err = pad2d_fwd(empty.view(), &cfg([1, 1, 1, 1], PadMode::Replicate, 0.0)).unwrap_err().to_string();
    assert!(err.contains("pad") && err.contains("[1, 0, 4, 5]"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 6, 6]));
    let err = pad2d_bwd(g.view(), (4, 5), &cfg([1, 1, 1, 1], PadMode::Replicate, 0.0)).unwrap_err().to_string();
    assert!(err.contains("pad") && err.contains("[1, 2, 6, 6]") && err.contains("[4, 5]"), "{err}");
    let huge = Pad2dCfg::new(&[i64::MAX, i64::MAX, 0, 0], PadMode::Zero, 0.0).unwrap();
    let ok = ArrayD::<f32>::zeros(IxDyn(&[1, 1, 2, 2]));
    assert!(pad2d_fwd(ok.view(), &huge).unwrap_err().to_string().contains("overflows"));
    let big = Pad2dCfg::new(&[1 << 40, 1 << 40, 0, 0], PadMode::Zero, 0.0).unwrap();
    let err = pad2d_fwd(ok.view(), &big).unwrap_err().to_string();
    assert!(err.contains("pad") && err.contains("too large to allocate"), "{err}");
}
