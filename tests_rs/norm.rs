//! Instance norm and batch norm: closed-form forwards, running-stat updates, f64 gradchecks of every
//! grad the backwards return, and error messages.
mod common;

use _core::ops::norm::{batch_norm_bwd, batch_norm_fwd, instance_norm_bwd, instance_norm_fwd, BatchNormCfg};
use common::{dot, gradcheck, Rng};
use ndarray::{arr1, ArrayD, IxDyn};

const EPS: f64 = 1e-5;

fn train() -> BatchNormCfg {
    BatchNormCfg::new(true, 0.1, EPS).unwrap()
}

fn eval() -> BatchNormCfg {
    BatchNormCfg::new(false, 0.1, EPS).unwrap()
}

// Normalisation is smooth everywhere (variance + eps > 0), so no kinks need to be avoided.
#[test]
fn instance_norm_affine_bwd_gradcheck_f64() {
    let mut rng = Rng::new(11);
    let x = rng.array(&[2, 3, 4, 5], -2.0, 2.0);
    let (w, b) = (rng.array(&[3], 0.5, 1.5), rng.array(&[3], -1.0, 1.0));
    let g = rng.array(&[2, 3, 4, 5], -1.0, 1.0);
    let y = |x: &ArrayD<f64>, w: &ArrayD<f64>, b: &ArrayD<f64>| instance_norm_fwd(x.view(), Some(w.view()), Some(b.view()), EPS).unwrap().y.into_dyn();
    let out = instance_norm_fwd(x.view(), Some(w.view()), Some(b.view()), EPS).unwrap();
    let grads = instance_norm_bwd(x.view(), out.mean.view().into_dyn(), out.invstd.view().into_dyn(), Some(w.view()), g.view()).unwrap();
    gradcheck("instance_norm dx", &x, &grads.x.into_dyn(), |xp| dot(&y(xp, &w, &b), &g));
    gradcheck("instance_norm dweight", &w, &grads.weight.into_dyn(), |wp| dot(&y(&x, wp, &b), &g));
    gradcheck("instance_norm dbias", &b, &grads.bias.into_dyn(), |bp| dot(&y(&x, &w, bp), &g));
}

#[test]
fn instance_norm_no_affine_odd_plane_bwd_gradcheck_f64() {
    let mut rng = Rng::new(12);
    let x = rng.array(&[3, 2, 3, 7], -3.0, 1.0);
    let g = rng.array(&[3, 2, 3, 7], -1.0, 1.0);
    let out = instance_norm_fwd(x.view(), None, None, EPS).unwrap();
    let grads = instance_norm_bwd(x.view(), out.mean.view().into_dyn(), out.invstd.view().into_dyn(), None, g.view()).unwrap();
    gradcheck("instance_norm dx", &x, &grads.x.into_dyn(), |xp| dot(&instance_norm_fwd(xp.view(), None, None, EPS).unwrap().y.into_dyn(), &g));
}

#[test]
fn instance_norm_plane_1234_matches_closed_form() {
    // plane [1, 2, 3, 4]: mean 2.5, biased var 1.25
    let x = ArrayD::from_shape_vec(IxDyn(&[1, 1, 2, 2]), vec![1.0f64, 2.0, 3.0, 4.0]).unwrap();
    let out = instance_norm_fwd::<f64>(x.view(), None, None, EPS).unwrap();
    let s = 1.0 / (1.25f64 + EPS).sqrt();
    assert!((out.mean[[0, 0]] - 2.5).abs() < 1e-15 && (out.invstd[[0, 0]] - s).abs() < 1e-12);
    for (i, &v) in [1.0, 2.0, 3.0, 4.0].iter().enumerate() {
        assert!((out.y.as_slice().unwrap()[i] - (v - 2.5) * s).abs() < 1e-12);
    }
}

#[test]
fn batch_norm_train_bwd_gradcheck_f64() {
    let mut rng = Rng::new(21);
    let x = rng.array(&[3, 4, 3, 5], -2.0, 2.0);
    let (w, b) = (rng.array(&[4], 0.5, 1.5), rng.array(&[4], -1.0, 1.0));
    let g = rng.array(&[3, 4, 3, 5], -1.0, 1.0);
    let y = |x: &ArrayD<f64>, w: &ArrayD<f64>, b: &ArrayD<f64>| batch_norm_fwd(x.view(), Some(w.view()), Some(b.view()), None, None, &train()).unwrap().y.into_dyn();
    let out = batch_norm_fwd(x.view(), Some(w.view()), Some(b.view()), None, None, &train()).unwrap();
    let grads = batch_norm_bwd(x.view(), out.mean.view().into_dyn(), out.invstd.view().into_dyn(), Some(w.view()), g.view(), true).unwrap();
    gradcheck("batch_norm train dx", &x, &grads.x.into_dyn(), |xp| dot(&y(xp, &w, &b), &g));
    gradcheck("batch_norm train dweight", &w, &grads.weight.into_dyn(), |wp| dot(&y(&x, wp, &b), &g));
    gradcheck("batch_norm train dbias", &b, &grads.bias.into_dyn(), |bp| dot(&y(&x, &w, bp), &g));
}

#[test]
fn batch_norm_train_global_branch_2n_by_c_by_1x1_bwd_gradcheck_f64() {
    // The MS-CAM global branch: (2N, C, 1, 1), 2N = 4 values per channel, no affine.
    let mut rng = Rng::new(22);
    let x = rng.array(&[4, 6, 1, 1], -1.0, 1.0);
    let g = rng.array(&[4, 6, 1, 1], -1.0, 1.0);
    let out = batch_norm_fwd(x.view(), None, None, None, None, &train()).unwrap();
    let grads = batch_norm_bwd(x.view(), out.mean.view().into_dyn(), out.invstd.view().into_dyn(), None, g.view(), true).unwrap();
    gradcheck("batch_norm (2N,C,1,1) dx", &x, &grads.x.into_dyn(), |xp| {
        dot(&batch_norm_fwd(xp.view(), None, None, None, None, &train()).unwrap().y.into_dyn(), &g)
    });
}

#[test]
fn batch_norm_eval_bwd_gradcheck_f64() {
    let mut rng = Rng::new(23);
    let x = rng.array(&[2, 3, 4, 3], -2.0, 2.0);
    let (w, b) = (rng.array(&[3], 0.5, 1.5), rng.array(&[3], -1.0, 1.0));
    let (rm, rv) = (rng.array(&[3], -0.5, 0.5), rng.array(&[3], 0.5, 2.0));
    let g = rng.array(&[2, 3, 4, 3], -1.0, 1.0);
    let y = |x: &ArrayD<f64>, w: &ArrayD<f64>, b: &ArrayD<f64>| {
        batch_norm_fwd(x.view(), Some(w.view()), Some(b.view()), Some(rm.view()), Some(rv.view()), &eval()).unwrap().y.into_dyn()
    };
    let out = batch_norm_fwd(x.view(), Some(w.view()), Some(b.view()), Some(rm.view()), Some(rv.view()), &eval()).unwrap();
    assert!(out.running_mean.is_none() && out.running_var.is_none(), "eval must not update running stats");
    let grads = batch_norm_bwd(x.view(), out.mean.view().into_dyn(), out.invstd.view().into_dyn(), Some(w.view()), g.view(), false).unwrap();
    gradcheck("batch_norm eval dx", &x, &grads.x.into_dyn(), |xp| dot(&y(xp, &w, &b), &g));
    gradcheck("batch_norm eval dweight", &w, &grads.weight.into_dyn(), |wp| dot(&y(&x, wp, &b), &g));
    gradcheck("batch_norm eval dbias", &b, &grads.bias.into_dyn(), |bp| dot(&y(&x, &w, bp), &g));
}

#[test]
fn batch_norm_train_running_stats_use_unbiased_variance() {
    // channel 0 holds [1, 2, 3, 4] over (N=2, W=2): mean 2.5, biased var 1.25, unbiased var 5/3
    let x = ArrayD::from_shape_vec(IxDyn(&[2, 1, 1, 2]), vec![1.0, 2.0, 3.0, 4.0]).unwrap();
    let (rm, rv) = (arr1(&[1.0f64]).into_dyn(), arr1(&[2.0f64]).into_dyn());
    let (w, b) = (arr1(&[2.0f64]).into_dyn(), arr1(&[0.5f64]).into_dyn());
    let out = batch_norm_fwd(x.view(), Some(w.view()), Some(b.view()), Some(rm.view()), Some(rv.view()), &train()).unwrap();
    let (nrm, nrv) = (out.running_mean.unwrap(), out.running_var.unwrap());
    assert!((nrm[0] - (0.9 * 1.0 + 0.1 * 2.5)).abs() < 1e-15, "{nrm}");
    assert!((nrv[0] - (0.9 * 2.0 + 0.1 * 5.0 / 3.0)).abs() < 1e-15, "{nrv}");
    let s = 1.0 / (1.25f64 + EPS).sqrt();
    assert!((out.y[[1, 0, 0, 1]] - ((4.0 - 2.5) * s * 2.0 + 0.5)).abs() < 1e-12);
    // the inputs are never mutated
    assert_eq!((rm[0], rv[0]), (1.0, 2.0));
}

#[test]
fn batch_norm_eval_uses_running_stats() {
    let x = ArrayD::from_shape_vec(IxDyn(&[1, 2, 1, 1]), vec![3.0, -1.0]).unwrap();
    let (rm, rv) = (arr1(&[1.0f64, 0.0]).into_dyn(), arr1(&[4.0f64, 0.25]).into_dyn());
    let out = batch_norm_fwd(x.view(), None, None, Some(rm.view()), Some(rv.view()), &eval()).unwrap();
    // y = (x − rm) / sqrt(rv + eps): one value per channel is fine in eval
    assert!((out.y[[0, 0, 0, 0]] - 2.0 / (4.0f64 + EPS).sqrt()).abs() < 1e-12);
    assert!((out.y[[0, 1, 0, 0]] - -1.0 / (0.25f64 + EPS).sqrt()).abs() < 1e-12);
}

#[test]
fn batch_norm_train_one_value_per_channel_is_an_error() {
    let x = ArrayD::<f32>::zeros(IxDyn(&[1, 3, 1, 1]));
    let err = batch_norm_fwd(x.view(), None, None, None, None, &BatchNormCfg::new(true, 0.1, 1e-5).unwrap()).unwrap_err().to_string();
    assert!(err.contains("batch_norm") && err.contains("Expected more than 1 value per channel when training") && err.contains("[1, 3, 1, 1]"), "{err}");
}

#[test]
fn norm_errors_name_op_and_shapes() {
    let cfg = BatchNormCfg::new(false, 0.1, 1e-5).unwrap();
    let x3 = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 4]));
    let err = instance_norm_fwd(x3.view(), None, None, 1e-5).unwrap_err().to_string();
    assert!(err.contains("instance_norm") && err.contains("4-D") && err.contains("[2, 3, 4]"), "{err}");
    let x = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 4, 4]));
    let w = ArrayD::<f32>::zeros(IxDyn(&[4]));
    let err = batch_norm_fwd(x.view(), Some(w.view()), None, Some(w.view()), Some(w.view()), &cfg).unwrap_err().to_string();
    assert!(err.contains("batch_norm") && err.contains("[2, 3, 4, 4]") && err.contains("weight=[4]"), "{err}");
    let err = batch_norm_fwd(x.view(), None, None, None, None, &cfg).unwrap_err().to_string();
    assert!(err.contains("batch_norm") && err.contains("evaluation mode"), "{err}");
    let empty = ArrayD::<f32>::zeros(IxDyn(&[0, 3, 4, 4]));
    let err = instance_norm_fwd(empty.view(), None, None, 1e-5).unwrap_err().to_string();
    assert!(err.contains("instance_norm") && err.contains("empty") && err.contains("[0, 3, 4, 4]"), "{err}");
    let one = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 1, 1]));
    let err = instance_norm_fwd(one.view(), None, None, 1e-5).unwrap_err().to_string();
    assert!(err.contains("more than 1 spatial element") && err.contains("[2, 3, 1, 1]"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[2, 3, 4, 5]));
    let s = ArrayD::<f32>::zeros(IxDyn(&[2, 3]));
    let err = instance_norm_bwd(x.view(), s.view(), s.view(), None, g.view()).unwrap_err().to_string();
    assert!(err.contains("instance_norm") && err.contains("[2, 3, 4, 4]") && err.contains("[2, 3, 4, 5]"), "{err}");
    let err = batch_norm_bwd(x.view(), s.view(), s.view(), None, x.view(), true).unwrap_err().to_string();
    assert!(err.contains("batch_norm") && err.contains("mean=[2, 3]"), "{err}");
    assert!(BatchNormCfg::new(true, 0.1, -1.0).unwrap_err().to_string().contains("eps"));
}

/// max |a − b| / max |b| of an f32 result against its f64 counterpart.
fn rel_err(a: &ArrayD<f32>, b: &ArrayD<f64>) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter().zip(b).fold(0.0f64, |m, (&a, &b)| m.max((a as f64 - b).abs())) / scale
}

#[test]
fn f32_statistics_over_many_blocks_match_f64() {
    // planes of 3·4096 + 37 values around 100 (several summation blocks, a partial lane chunk, an
    // offset that a plain f32 running sum would lose digits to): forward and backward of both norms
    let mut rng = Rng::new(5);
    let x = rng.array(&[3, 2, 111, 111], 99.0, 101.0);
    let g = rng.array(&[3, 2, 111, 111], -1.0, 1.0);
    let (x32, g32) = (x.mapv(|v| v as f32), g.mapv(|v| v as f32));
    let inst64 = instance_norm_fwd(x.view(), None, None, EPS).unwrap();
    let inst32 = instance_norm_fwd(x32.view(), None, None, EPS).unwrap();
    assert!(rel_err(&inst32.y.into_dyn(), &inst64.y.into_dyn()) < 1e-4);
    let d64 = instance_norm_bwd(x.view(), inst64.mean.view().into_dyn(), inst64.invstd.view().into_dyn(), None, g.view()).unwrap();
    let d32 = instance_norm_bwd(x32.view(), inst32.mean.view().into_dyn(), inst32.invstd.view().into_dyn(), None, g32.view()).unwrap();
    assert!(rel_err(&d32.x.into_dyn(), &d64.x.into_dyn()) < 1e-4);
    assert!(rel_err(&d32.weight.into_dyn(), &d64.weight.into_dyn()) < 1e-4);
    let bn64 = batch_norm_fwd(x.view(), None, None, None, None, &train()).unwrap();
    let bn32 = batch_norm_fwd(x32.view(), None, None, None, None, &train()).unwrap();
    assert!(rel_err(&bn32.y.into_dyn(), &bn64.y.into_dyn()) < 1e-4);
    let b64 = batch_norm_bwd(x.view(), bn64.mean.view().into_dyn(), bn64.invstd.view().into_dyn(), None, g.view(), true).unwrap();
    let b32 = batch_norm_bwd(x32.view(), bn32.mean.view().into_dyn(), bn32.invstd.view().into_dyn(), None, g32.view(), true).unwrap();
    assert!(rel_err(&b32.x.into_dyn(), &b64.x.into_dyn()) < 1e-4);
    assert!(rel_err(&b32.bias.into_dyn(), &b64.bias.into_dyn()) < 1e-5);
}
