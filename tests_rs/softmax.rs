//! softmax: closed forms, stability, f64 gradchecks along every axis, and errors.
mod common;

use _core::ops::softmax::{softmax_bwd, softmax_fwd};
use common::{dot, gradcheck, Rng};
use ndarray::{arr1, ArrayD, IxDyn};

// Softmax is smooth: no kinks to avoid.
#[test]
fn softmax_every_axis_bwd_gradcheck_f64() {
    let mut rng = Rng::new(41);
    let x = rng.array(&[2, 3, 4, 5], -3.0, 3.0);
    let g = rng.array(&[2, 3, 4, 5], -1.0, 1.0);
    for dim in [0isize, 1, 2, 3, -1, -3] {
        let y = softmax_fwd(x.view(), dim).unwrap();
        let dx = softmax_bwd(y.view(), g.view(), dim).unwrap();
        gradcheck(&format!("softmax dim {dim}"), &x, &dx, |xp| dot(&softmax_fwd(xp.view(), dim).unwrap(), &g));
    }
}

#[test]
fn softmax_convex_mask_shape_bwd_gradcheck_f64() {
    // (N, 1, 9, 4, 4, h, w) along dim 2, as in convex upsampling (rank 7, > 200 elements: random directions)
    let mut rng = Rng::new(42);
    let x = rng.array(&[1, 1, 9, 4, 4, 2, 3], -2.0, 2.0);
    let g = rng.array(x.shape(), -1.0, 1.0);
    let y = softmax_fwd(x.view(), 2).unwrap();
    let dx = softmax_bwd(y.view(), g.view(), 2).unwrap();
    gradcheck("softmax rank 7 dim 2", &x, &dx, |xp| dot(&softmax_fwd(xp.view(), 2).unwrap(), &g));
}

#[test]
fn softmax_of_logs_is_normalised_weights_and_stable() {
    // softmax(ln 1, ln 2, ln 3) = (1, 2, 3) / 6
    let x = arr1(&[0.0f64, 2f64.ln(), 3f64.ln()]).into_dyn();
    let y = softmax_fwd(x.view(), 0).unwrap();
    for i in 0..3 {
        assert!((y[i] - (i + 1) as f64 / 6.0).abs() < 1e-15);
    }
    // no overflow for large logits: e^1000 is inf, e^(1000 − max) is not
    let big = arr1(&[1000.0f32, 1000.0, -1000.0]).into_dyn();
    let yb = softmax_fwd(big.view(), -1).unwrap();
    assert_eq!((yb[0], yb[1], yb[2]), (0.5, 0.5, 0.0));
}

#[test]
fn softmax_errors_name_op_and_shapes() {
    let x = ArrayD::<f32>::zeros(IxDyn(&[2, 3]));
    let err = softmax_fwd(x.view(), 2).unwrap_err().to_string();
    assert!(err.contains("softmax") && err.contains("Dimension out of range") && err.contains("[2, 3]"), "{err}");
    let err = softmax_fwd(x.view(), -3).unwrap_err().to_string();
    assert!(err.contains("[-2, 1]"), "{err}");
    let empty = ArrayD::<f32>::zeros(IxDyn(&[0, 3]));
    let err = softmax_fwd(empty.view(), 1).unwrap_err().to_string();
    assert!(err.contains("softmax") && err.contains("empty") && err.contains("[0, 3]"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[3, 2]));
    let err = softmax_bwd(x.view(), g.view(), 1).unwrap_err().to_string();
    assert!(err.contains("softmax") && err.contains("[2, 3]") && err.contains("[3, 2]"), "{err}");
}
