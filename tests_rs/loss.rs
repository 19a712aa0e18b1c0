//! masked L1 loss: closed form, NaN isolation, the no-valid case, f64 gradcheck, and errors.
mod common;

use _core::ops::loss::{masked_l1_bwd, masked_l1_fwd};
use common::{gradcheck, Rng};
use ndarray::{arr1, ArrayD, IxDyn};

#[test]
fn masked_l1_bwd_gradcheck_f64() {
    let mut rng = Rng::new(51);
    // |pred − gt| >= 0.05 everywhere: the kink of |·| at 0 is kept out of the samples.
    let gt = rng.array(&[2, 1, 5, 7], -2.0, 2.0);
    let offset = rng.array(&[2, 1, 5, 7], 0.05, 1.0).mapv(|d| if d > 0.5 { d } else { -d });
    let pred = &gt + &offset;
    let valid = rng.array(&[2, 1, 5, 7], 0.0, 1.0).mapv(|v| if v > 0.3 { 1.0 } else { 0.0 });
    let g = 0.7;
    let dpred = masked_l1_bwd(pred.view(), gt.view(), valid.view(), g).unwrap();
    gradcheck("masked_l1 dpred", &pred, &dpred, |p| g * masked_l1_fwd(p.view(), gt.view(), valid.view()).unwrap());
}

#[test]
fn masked_l1_matches_closed_form_and_ignores_invalid_nan() {
    // valid at 0, 1, 3: (|1 − 0| + |−2 − 1| + |5 − 5|) / 3 = 4/3; position 2 holds NaN gt, position 4 inf
    let pred = arr1(&[1.0f64, -2.0, 7.0, 5.0, 3.0]).into_dyn();
    let gt = arr1(&[0.0f64, 1.0, f64::NAN, 5.0, f64::INFINITY]).into_dyn();
    let valid = arr1(&[1.0f64, 1.0, 0.0, 1.0, 0.0]).into_dyn();
    let l = masked_l1_fwd(pred.view(), gt.view(), valid.view()).unwrap();
    assert!((l - 4.0 / 3.0).abs() < 1e-15, "{l}");
    let d = masked_l1_bwd(pred.view(), gt.view(), valid.view(), 3.0).unwrap();
    // g·sign(e)/count with count 3, sign(0) = 0, invalid positions 0
    assert_eq!(d.as_slice().unwrap(), &[1.0, -1.0, 0.0, 0.0, 0.0]);
}

#[test]
fn masked_l1_without_valid_pixels_is_zero_with_zero_grad() {
    let pred = ArrayD::<f32>::ones(IxDyn(&[2, 3]));
    let gt = ArrayD::<f32>::from_elem(IxDyn(&[2, 3]), f32::NAN);
    let valid = ArrayD::<f32>::zeros(IxDyn(&[2, 3]));
    assert_eq!(masked_l1_fwd(pred.view(), gt.view(), valid.view()).unwrap(), 0.0);
    assert!(masked_l1_bwd(pred.view(), gt.view(), valid.view(), 1.0).unwrap().iter().all(|&v| v == 0.0));
}

#[test]
fn masked_l1_large_input_sum_is_exact_for_integers() {
    // 3·2^14 + 5 elements span several summation chunks; |e| = 2 everywhere valid
    let n = 3 * (1 << 14) + 5;
    let pred = ArrayD::<f32>::from_elem(IxDyn(&[n]), 2.0);
    let gt = ArrayD::<f32>::zeros(IxDyn(&[n]));
    let valid = ArrayD::from_shape_fn(IxDyn(&[n]), |i| (i[0] % 2) as f32);
    assert_eq!(masked_l1_fwd(pred.view(), gt.view(), valid.view()).unwrap(), 2.0);
}

#[test]
fn masked_l1_errors_name_op_and_shapes() {
    let a = ArrayD::<f32>::zeros(IxDyn(&[2, 3]));
    let b = ArrayD::<f32>::zeros(IxDyn(&[3, 2]));
    let err = masked_l1_fwd(a.view(), b.view(), a.view()).unwrap_err().to_string();
    assert!(err.contains("masked_l1_loss") && err.contains("[2, 3]") && err.contains("[3, 2]"), "{err}");
    let err = masked_l1_bwd(a.view(), a.view(), b.view(), 1.0).unwrap_err().to_string();
    assert!(err.contains("masked_l1_loss") && err.contains("valid=[3, 2]"), "{err}");
    let e = ArrayD::<f32>::zeros(IxDyn(&[0, 3]));
    let err = masked_l1_fwd(e.view(), e.view(), e.view()).unwrap_err().to_string();
    assert!(err.contains("empty") && err.contains("[0, 3]"), "{err}");
}
