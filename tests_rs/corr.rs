//! IP and RLS correlations: hand-computed forwards, f64 gradchecks of both gradients of each backward
//! at the spec's channel layout (C = 8, S = 5, G = 2, rx = 3, ry = 1), determinism, and errors.
mod common;

use _core::ops::corr::*;
use common::{dot, gradcheck, Rng};
use ndarray::{ArrayD, IxDyn};

#[test]
fn ip_corr_channel_s_times_g_plus_s_is_the_group_mean() {
    // fl[c] = c + 1, stack[s·C + c] = s + 1  =>  out[S·g + s] = (s + 1) · mean_{c in group g}(c + 1)
    let (n, c, s, g, h, w) = (1, 8, 5, 2, 2, 3);
    let fl = ArrayD::from_shape_fn(IxDyn(&[n, c, h, w]), |i| i[1] as f64 + 1.0);
    let stack = ArrayD::from_shape_fn(IxDyn(&[n, s * c, h, w]), |i| (i[1] / c) as f64 + 1.0);
    let out = ip_corr_fwd(fl.view(), stack.view(), &IpCorrCfg { groups: g }).unwrap();
    assert_eq!(out.shape(), &[n, g * s, h, w]);
    for gi in 0..g {
        let mean = (gi * 4 + 1..=gi * 4 + 4).sum::<usize>() as f64 / 4.0;
        for si in 0..s {
            assert!((out[[0, s * gi + si, 1, 2]] - (si as f64 + 1.0) * mean).abs() < 1e-12);
        }
    }
}

#[test]
fn ip_corr_bwd_gradcheck_f64_both_operands() {
    // bilinear in (fl, stack): no kinks.
    let mut rng = Rng::new(21);
    for (n, c, s, g, h, w) in [(2, 8, 5, 2, 3, 4), (1, 16, 5, 2, 5, 3), (1, 6, 3, 3, 1, 7), (1, 4, 1, 1, 2, 2)] {
        let cfg = IpCorrCfg { groups: g };
        let fl = rng.array(&[n, c, h, w], -1.0, 1.0);
        let stack = rng.array(&[n, s * c, h, w], -1.0, 1.0);
        let go = rng.array(&[n, g * s, h, w], -1.0, 1.0);
        let grads = ip_corr_bwd(fl.view(), stack.view(), go.view(), &cfg).unwrap();
        let loss = |f: &ArrayD<f64>, st: &ArrayD<f64>| dot(&ip_corr_fwd(f.view(), st.view(), &cfg).unwrap().into_dyn(), &go);
        let name = format!("ip_corr C={c} S={s} G={g} {h}x{w}");
        gradcheck(&format!("{name} fl"), &fl, &grads.fl.into_dyn(), |f| loss(f, &stack));
        gradcheck(&format!("{name} stack"), &stack, &grads.stack.into_dyn(), |st| loss(&fl, st));
    }
}

#[test]
fn ip_corr_rejects_bad_channels_and_grad() {
    let fl = ArrayD::<f32>::zeros(IxDyn(&[1, 8, 3, 4]));
    let stack = ArrayD::<f32>::zeros(IxDyn(&[1, 36, 3, 4]));
    let err = ip_corr_fwd(fl.view(), stack.view(), &IpCorrCfg { groups: 2 }).unwrap_err().to_string();
    assert!(err.contains("ip_correlation") && err.contains("[1, 8, 3, 4]") && err.contains("[1, 36, 3, 4]"), "{err}");
    let stack = ArrayD::<f32>::zeros(IxDyn(&[1, 40, 3, 4]));
    let err = ip_corr_fwd(fl.view(), stack.view(), &IpCorrCfg { groups: 3 }).unwrap_err().to_string();
    assert!(err.contains("ip_correlation") && err.contains("groups=3"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 5, 3, 4]));
    let err = ip_corr_bwd(fl.view(), stack.view(), g.view(), &IpCorrCfg { groups: 2 }).unwrap_err().to_string();
    assert!(err.contains("ip_correlation") && err.contains("[1, 5, 3, 4]"), "{err}");
    let empty = ArrayD::<f32>::zeros(IxDyn(&[1, 8, 0, 4]));
    assert!(ip_corr_fwd(empty.view(), stack.view(), &IpCorrCfg { groups: 2 }).unwrap_err().to_string().contains("empty"));
}

#[test]
fn rls_corr_candidate_i_j_reads_the_clamped_shifted_column() {
    // fl = 1, warped[c, y, x] = 10·y + x  =>  out[(2ry+1)·i + j, y, x] = 10·clamp(y+j-ry) + clamp(x+i-rx)
    let (c, h, w, cfg) = (4, 3, 5, RlsCorrCfg { rx: 3, ry: 1 });
    let fl = ArrayD::<f64>::ones(IxDyn(&[1, c, h, w]));
    let warped = ArrayD::from_shape_fn(IxDyn(&[1, c, h, w]), |i| 10.0 * i[2] as f64 + i[3] as f64);
    let out = rls_corr_fwd(fl.view(), warped.view(), &cfg).unwrap();
    assert_eq!(out.shape(), &[1, 21, h, w]);
    let clamp = |v: i64, n: usize| v.clamp(0, n as i64 - 1) as f64;
    for i in 0..7 {
        for j in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    let expect = 10.0 * clamp(y as i64 + j as i64 - 1, h) + clamp(x as i64 + i as i64 - 3, w);
                    assert_eq!(out[[0, 3 * i + j, y, x]], expect, "i={i} j={j} y={y} x={x}");
                }
            }
        }
    }
}

#[test]
fn rls_corr_bwd_gradcheck_f64_both_operands() {
    // bilinear in (fl, warped); the replicate clamp is an index map, not a kink.
    let mut rng = Rng::new(31);
    for (n, c, h, w, rx, ry) in [(2, 8, 4, 9, 3, 1), (1, 16, 3, 2, 3, 1), (1, 5, 1, 1, 3, 1), (1, 3, 5, 4, 0, 2)] {
        let cfg = RlsCorrCfg { rx, ry };
        let fl = rng.array(&[n, c, h, w], -1.0, 1.0);
        let warped = rng.array(&[n, c, h, w], -1.0, 1.0);
        let go = rng.array(&[n, cfg.candidates(), h, w], -1.0, 1.0);
        let grads = rls_corr_bwd(fl.view(), warped.view(), go.view(), &cfg).unwrap();
        let loss = |f: &ArrayD<f64>, wp: &ArrayD<f64>| dot(&rls_corr_fwd(f.view(), wp.view(), &cfg).unwrap().into_dyn(), &go);
        let name = format!("rls_corr C={c} {h}x{w} rx={rx} ry={ry}");
        gradcheck(&format!("{name} fl"), &fl, &grads.fl.into_dyn(), |f| loss(f, &warped));
        gradcheck(&format!("{name} warped"), &warped, &grads.warped.into_dyn(), |wp| loss(&fl, wp));
    }
}

#[test]
fn rls_and_ip_bwd_are_bitwise_deterministic_across_thread_counts() {
    let mut rng = Rng::new(41);
    let fl = rng.array(&[2, 16, 7, 9], -1.0, 1.0).mapv(|v| v as f32);
    let warped = rng.array(&[2, 16, 7, 9], -1.0, 1.0).mapv(|v| v as f32);
    let stack = rng.array(&[2, 80, 7, 9], -1.0, 1.0).mapv(|v| v as f32);
    let g_rls = rng.array(&[2, 21, 7, 9], -1.0, 1.0).mapv(|v| v as f32);
    let g_ip = rng.array(&[2, 10, 7, 9], -1.0, 1.0).mapv(|v| v as f32);
    let run = |n: usize| {
        rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| {
            let r = rls_corr_bwd(fl.view(), warped.view(), g_rls.view(), &RlsCorrCfg { rx: 3, ry: 1 }).unwrap();
            let i = ip_corr_bwd(fl.view(), stack.view(), g_ip.view(), &IpCorrCfg { groups: 2 }).unwrap();
            (r.fl, r.warped, i.fl, i.stack)
        })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn rls_corr_rejects_mismatched_shapes_and_grad() {
    let fl = ArrayD::<f32>::zeros(IxDyn(&[1, 8, 3, 4]));
    let warped = ArrayD::<f32>::zeros(IxDyn(&[1, 8, 3, 5]));
    let cfg = RlsCorrCfg { rx: 3, ry: 1 };
    let err = rls_corr_fwd(fl.view(), warped.view(), &cfg).unwrap_err().to_string();
    assert!(err.contains("rls_correlation") && err.contains("[1, 8, 3, 4]") && err.contains("[1, 8, 3, 5]"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 20, 3, 4]));
    let err = rls_corr_bwd(fl.view(), fl.view(), g.view(), &cfg).unwrap_err().to_string();
    assert!(err.contains("rls_correlation") && err.contains("21") && err.contains("[1, 20, 3, 4]"), "{err}");
    let r5 = ArrayD::<f32>::zeros(IxDyn(&[8, 3, 4]));
    assert!(rls_corr_fwd(r5.view(), r5.view(), &cfg).unwrap_err().to_string().contains("[8, 3, 4]"));
    let err = rls_corr_fwd(fl.view(), fl.view(), &RlsCorrCfg { rx: usize::MAX / 2, ry: 1 }).unwrap_err().to_string();
    assert!(err.contains("rls_correlation") && err.contains("too large"), "{err}");
}
