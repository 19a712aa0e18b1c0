//! Fused pointwise kernels: GRU gates (forwards against the unfused formulas, f64 gradchecks, errors), the
//! iAFF attentional gate, and the vectorisable exp/tanh/sigmoid of `lanes`.
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

#[test]
fn vectorisable_exp_tanh_sigmoid_f32_are_within_a_few_ulp_of_libm() {
    use _core::ops::lanes::{exp, sigmoid, tanh};
    let ulp = |a: f32, b: f32| ((a - b).abs() / (b.abs().max(f32::MIN_POSITIVE) * f32::EPSILON)) as f64;
    let (mut worst_exp, mut worst_tanh, mut worst_sig) = (0f64, 0f64, 0f64);
    for i in 0..200_001 {
        let x = -40.0 + 80.0 * i as f32 / 200_000.0;
        worst_exp = worst_exp.max(ulp(exp(x), x.exp()));
        worst_tanh = worst_tanh.max(ulp(tanh(x), x.tanh()));
        worst_sig = worst_sig.max(ulp(sigmoid(x), 1.0 / (1.0 + (-x).exp())));
    }
    assert!(worst_exp <= 2.0 && worst_tanh <= 3.0 && worst_sig <= 3.0, "exp {worst_exp} tanh {worst_tanh} sigmoid {worst_sig} ulp");
    assert_eq!(exp(-100f32), exp(-87.4f32));
    assert!(exp(100f32).is_finite() && tanh(30f32) == 1.0 && tanh(-30f32) == -1.0 && tanh(0f32) == 0.0);
    // f64 is the platform's
    assert_eq!(tanh(0.3f64), 0.3f64.tanh());
}

#[test]
fn attention_gate_equals_formula_and_passes_gradcheck_f64() {
    use _core::ops::gate::*;
    let mut rng = Rng::new(64);
    let (n, c, h, w) = (2, 3, 2, 3);
    let (l, gl) = (rng.array(&[n, c, h, w], -2.0, 2.0), rng.array(&[n, c, 1, 1], -1.0, 1.0));
    let (x, y) = (rng.array(&[n, c, h, w], -1.0, 1.0), rng.array(&[n, c, h, w], -1.0, 1.0));
    let out = attention_gate_fwd(l.view(), gl.view(), x.view(), y.view()).unwrap().into_dyn();
    let wgt = (&l + &gl).mapv(sig);
    let want = &wgt * &x + &(1.0 - &wgt) * &y;
    assert!(max_abs_diff(&out, &want) < 1e-15);
    let g = rng.array(&[n, c, h, w], -1.0, 1.0);
    let r = attention_gate_bwd(l.view(), gl.view(), x.view(), y.view(), g.view()).unwrap();
    let loss = |a: &ArrayD<f64>, b: &ArrayD<f64>, cc: &ArrayD<f64>, d: &ArrayD<f64>| {
        dot(&attention_gate_fwd(a.view(), b.view(), cc.view(), d.view()).unwrap().into_dyn(), &g)
    };
    gradcheck("gate local", &l, &r.local.into_dyn(), |a| loss(a, &gl, &x, &y));
    gradcheck("gate global", &gl, &r.global.into_dyn(), |b| loss(&l, b, &x, &y));
    gradcheck("gate x", &x, &r.x.into_dyn(), |cc| loss(&l, &gl, cc, &y));
    gradcheck("gate y", &y, &r.y.into_dyn(), |d| loss(&l, &gl, &x, d));
    let err = attention_gate_fwd(l.view(), l.view(), x.view(), y.view()).unwrap_err().to_string();
    assert!(err.contains("attention_gate") && err.contains("global=[2, 3, 2, 3]"), "{err}");
}
