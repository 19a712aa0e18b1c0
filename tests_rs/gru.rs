//! GRU gate kernels: forwards against the unfused formulas, f64 gradchecks of every gradient, errors.
mod common;

use _core::ops::gru::*;
use common::{dot, gradcheck, max_abs_diff, Rng};
use ndarray::{s, ArrayD, Axis, IxDyn};

fn sig(v: f64) -> f64 {
    1.0 / (1.0 + (-v).exp())
}

#[test]
fn gru_gates_equal_the_unfused_formulas() {
    let mut rng = Rng::new(61);
    let (n, hid, x, h, w) = (2, 3, 4, 2, 5);
    let zr = rng.array(&[n, 2 * hid, h, w], -2.0, 2.0);
    let hx = rng.array(&[n, hid + x, h, w], -1.0, 1.0);
    let q = rng.array(&[n, hid, h, w], -2.0, 2.0);
    let (z, r) = (zr.slice(s![.., ..hid, .., ..]).mapv(sig), zr.slice(s![.., hid.., .., ..]).mapv(sig));
    let hh = hx.slice(s![.., ..hid, .., ..]).to_owned();
    let rhx = gru_reset_fwd(zr.view(), hx.view()).unwrap().into_dyn();
    let want = ndarray::concatenate(Axis(1), &[(&r * &hh).view(), hx.slice(s![.., hid.., .., ..])]).unwrap().into_dyn();
    assert!(max_abs_diff(&rhx, &want) < 1e-15);
    let hn = (&(1.0 - &z) * &hh + &z * &q.mapv(f64::tanh)).into_dyn();
    let out = gru_update_fwd(zr.view(), q.view(), hx.view(), false).unwrap().into_dyn();
    assert!(max_abs_diff(&out, &hn) < 1e-15);
    let out = gru_update_fwd(zr.view(), q.view(), hx.view(), true).unwrap().into_dyn();
    let want = ndarray::concatenate(Axis(1), &[hn.view(), hx.slice(s![.., hid.., .., ..]).into_dyn()]).unwrap();
    assert!(max_abs_diff(&out, &want) < 1e-15);
}

#[test]
fn gru_reset_bwd_gradcheck_f64() {
    let mut rng = Rng::new(62);
    let (n, hid, x, h, w) = (2, 2, 3, 2, 3);
    let zr = rng.array(&[n, 2 * hid, h, w], -2.0, 2.0);
    let hx = rng.array(&[n, hid + x, h, w], -1.0, 1.0);
    let g = rng.array(&[n, hid + x, h, w], -1.0, 1.0);
    let grads = gru_reset_bwd(zr.view(), hx.view(), g.view()).unwrap();
    let loss = |a: &ArrayD<f64>, b: &ArrayD<f64>| dot(&gru_reset_fwd(a.view(), b.view()).unwrap().into_dyn(), &g);
    gradcheck("gru_reset zr", &zr, &grads.zr.into_dyn(), |a| loss(a, &hx));
    gradcheck("gru_reset hx", &hx, &grads.hx.into_dyn(), |b| loss(&zr, b));
}

#[test]
fn gru_update_bwd_gradcheck_f64_with_and_without_x() {
    let mut rng = Rng::new(63);
    let (n, hid, x, h, w) = (1, 2, 3, 3, 4);
    for keep_x in [false, true] {
        let zr = rng.array(&[n, 2 * hid, h, w], -2.0, 2.0);
        let q = rng.array(&[n, hid, h, w], -2.0, 2.0);
        let hx = rng.array(&[n, hid + x, h, w], -1.0, 1.0);
        let g = rng.array(&[n, if keep_x { hid + x } else { hid }, h, w], -1.0, 1.0);
        let grads = gru_update_bwd(zr.view(), q.view(), hx.view(), g.view(), keep_x).unwrap();
        let loss = |a: &ArrayD<f64>, b: &ArrayD<f64>, c: &ArrayD<f64>| {
            dot(&gru_update_fwd(a.view(), b.view(), c.view(), keep_x).unwrap().into_dyn(), &g)
        };
        let name = format!("gru_update keep_x={keep_x}");
        gradcheck(&format!("{name} zr"), &zr, &grads.zr.into_dyn(), |a| loss(a, &q, &hx));
        gradcheck(&format!("{name} q"), &q, &grads.q.into_dyn(), |b| loss(&zr, b, &hx));
        gradcheck(&format!("{name} hx"), &hx, &grads.hx.into_dyn(), |c| loss(&zr, &q, c));
    }
}

#[test]
fn gru_gates_reject_mismatched_shapes() {
    let zr = ArrayD::<f32>::zeros(IxDyn(&[1, 6, 2, 2]));
    let hx = ArrayD::<f32>::zeros(IxDyn(&[1, 5, 2, 3]));
    let err = gru_reset_fwd(zr.view(), hx.view()).unwrap_err().to_string();
    assert!(err.contains("gru_reset") && err.contains("[1, 6, 2, 2]") && err.contains("[1, 5, 2, 3]"), "{err}");
    let hx = ArrayD::<f32>::zeros(IxDyn(&[1, 5, 2, 2]));
    let q = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 2, 2]));
    let err = gru_update_fwd(zr.view(), q.view(), hx.view(), false).unwrap_err().to_string();
    assert!(err.contains("gru_update") && err.contains("q=[1, 2, 2, 2]"), "{err}");
    let q = ArrayD::<f32>::zeros(IxDyn(&[1, 3, 2, 2]));
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 5, 2, 2]));
    let err = gru_update_bwd(zr.view(), q.view(), hx.view(), g.view(), false).unwrap_err().to_string();
    assert!(err.contains("gru_update") && err.contains("[1, 5, 2, 2]"), "{err}");
}
