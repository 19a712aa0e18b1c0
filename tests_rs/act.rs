//! Activations: forward values and f64 gradchecks of every backward.
mod common;

use _core::ops::act::{unary_bwd, unary_fwd, Act};
use common::{dot, gradcheck, Rng};

#[test]
fn relu_sigmoid_tanh_bwd_gradcheck_f64() {
    let mut rng = Rng::new(1);
    // relu's kink at 0 is kept out of the samples: |x| >= 0.05.
    let x = rng.array(&[2, 3, 4, 5], -2.0, 2.0).mapv(|v| if v.abs() < 0.05 { 0.5 } else { v });
    let g = rng.array(&[2, 3, 4, 5], -1.0, 1.0);
    for act in [Act::Relu, Act::Sigmoid, Act::Tanh] {
        let y = unary_fwd(act, x.view()).unwrap();
        let dx = unary_bwd(act, y.view(), g.view()).unwrap();
        gradcheck(act.name(), &x, &dx, |xp| dot(&unary_fwd(act, xp.view()).unwrap(), &g));
    }
}

#[test]
fn sigmoid_and_tanh_match_closed_forms() {
    let x = ndarray::arr1(&[-3.0f64, 0.0, 0.7]).into_dyn();
    let s = unary_fwd(Act::Sigmoid, x.view()).unwrap();
    let t = unary_fwd(Act::Tanh, x.view()).unwrap();
    for i in 0..3 {
        // sigmoid(x) = 1 / (1 + e^-x), tanh(x) = 2 sigmoid(2x) - 1
        assert!((s[i] - 1.0 / (1.0 + (-x[i]).exp())).abs() < 1e-15);
        assert!((t[i] - (2.0 / (1.0 + (-2.0 * x[i]).exp()) - 1.0)).abs() < 1e-15);
    }
}

#[test]
fn unary_bwd_rejects_mismatched_grad_shape() {
    let y = ndarray::ArrayD::<f32>::zeros(ndarray::IxDyn(&[2, 3]));
    let g = ndarray::ArrayD::<f32>::zeros(ndarray::IxDyn(&[3, 2]));
    let err = unary_bwd(Act::Tanh, y.view(), g.view()).unwrap_err().to_string();
    assert!(err.contains("tanh") && err.contains("[2, 3]") && err.contains("[3, 2]"), "{err}");
}

#[test]
fn f32_sigmoid_and_tanh_are_accurate_over_the_whole_range() {
    // the f32 kernels (Cephes-style exp with its 2^n from exponent bits) against f64 closed forms,
    // on a grid through both ends of exp's clamp (|x| up to 100) and the tanh polynomial's switch
    let xs: Vec<f32> = (-4000..=4000).map(|i| i as f32 * 0.025).chain([-87.4, -87.3, 88.3, 88.4, 0.625, -0.625]).collect();
    let x = ndarray::Array1::from_vec(xs).into_dyn();
    let (s, t) = (unary_fwd(Act::Sigmoid, x.view()).unwrap(), unary_fwd(Act::Tanh, x.view()).unwrap());
    for ((&xi, &si), &ti) in x.iter().zip(&s).zip(&t) {
        let v = xi as f64;
        let (es, et) = (1.0 / (1.0 + (-v).exp()), v.tanh());
        // a few f32 ulps relative (sigmoid below 1e-37, where exp's clamp acts, only absolutely)
        assert!((si as f64 - es).abs() <= 4e-7 * es + 1e-37, "sigmoid({xi}) = {si}, expected {es}");
        assert!((ti as f64 - et).abs() <= 4e-7 * et.abs().max(1e-3), "tanh({xi}) = {ti}, expected {et}");
    }
}
