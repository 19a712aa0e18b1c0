//! IP and RLS correlations: hand-computed forwards, f64 gradchecks of both gradients of each backward
//! at the network's channel layout (C = 8, S = 5, G = 2, rx = 3, ry = 1), determinism, and errors.
mod common;

use _core::ops::corr::*;
use common::{dot, gradcheck, max_abs_diff, Rng};
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

// ---- fused warp + correlation (vertical flow zero) -------------------------------------------------

use _core::ops::sample::{grid_sample_fwd, GridPadding, GridSampleCfg};
use _core::ops::warp_corr::*;

/// (N, C, h, w) -> (N, h, w, C).
fn nhwc(a: &ArrayD<f64>) -> ArrayD<f64> {
    a.view().permuted_axes(IxDyn(&[0, 2, 3, 1])).as_standard_layout().to_owned()
}

/// A horizontal flow that also samples beyond both borders (clamped there): f_x in [-(w+1), 2].
fn flow_x(rng: &mut Rng, n: usize, h: usize, w: usize) -> ArrayD<f64> {
    rng.array(&[n, h, w], -(w as f64) - 1.0, 2.0)
}

/// W(F, f) by grid_sample (border, align_corners) with f = (f_x, 0), as the reference model builds its grid.
fn warp_by_grid_sample(x: &ArrayD<f64>, fx: &ArrayD<f64>) -> ArrayD<f64> {
    let (n, h, w) = (fx.shape()[0], fx.shape()[1], fx.shape()[2]);
    let grid = ArrayD::from_shape_fn(IxDyn(&[n, h, w, 2]), |i| {
        // g = 2 (p + f) / (size - 1) - 1 per axis
        if i[3] == 0 {
            2.0 * (i[2] as f64 + fx[[i[0], i[1], i[2]]]) / (w.max(2) - 1) as f64 - 1.0
        } else {
            2.0 * i[1] as f64 / (h.max(2) - 1) as f64 - 1.0
        }
    });
    let cfg = GridSampleCfg { padding: GridPadding::Border, align_corners: true };
    grid_sample_fwd(x.view(), grid.view(), &cfg).unwrap().into_dyn()
}

/// The seed stack of architecture.md §2.5: stack[s·C + c, y, x] = fr[c, clamp(y + oy), clamp(x + ox)].
fn seed_stack(fr: &ArrayD<f64>, seeds: &[(isize, isize)]) -> ArrayD<f64> {
    let (n, c, h, w) = (fr.shape()[0], fr.shape()[1], fr.shape()[2], fr.shape()[3]);
    let cl = |v: isize, m: usize| v.clamp(0, m as isize - 1) as usize;
    ArrayD::from_shape_fn(IxDyn(&[n, seeds.len() * c, h, w]), |i| {
        let (ox, oy) = seeds[i[1] / c];
        fr[[i[0], i[1] % c, cl(i[2] as isize + oy, h), cl(i[3] as isize + ox, w)]]
    })
}

#[test]
fn ip_warp_corr_equals_grid_sample_of_the_seed_stack_then_ip_corr() {
    let mut rng = Rng::new(51);
    for (n, c, g, h, w) in [(2, 8, 2, 4, 7), (1, 16, 2, 1, 5), (1, 6, 3, 3, 1), (1, 40, 2, 5, 6)] {
        let (fl, fr, fx) = (rng.array(&[n, c, h, w], -1.0, 1.0), rng.array(&[n, c, h, w], -1.0, 1.0), flow_x(&mut rng, n, h, w));
        let cfg = IpWarpCfg { groups: g, seeds: IP_SEEDS.to_vec() };
        let fused = ip_warp_corr_fwd(nhwc(&fl).view(), nhwc(&fr).view(), fx.view(), &cfg).unwrap().into_dyn();
        let warped = warp_by_grid_sample(&seed_stack(&fr, &IP_SEEDS), &fx);
        let unfused = ip_corr_fwd(fl.view(), warped.view(), &IpCorrCfg { groups: g }).unwrap().into_dyn();
        assert!(max_abs_diff(&fused, &unfused) < 1e-12, "C={c} G={g} {h}x{w}: {}", max_abs_diff(&fused, &unfused));
    }
}

#[test]
fn rls_warp_corr_equals_grid_sample_then_rls_corr() {
    let mut rng = Rng::new(52);
    for (n, c, h, w, rx, ry) in [(2, 8, 4, 9, 3, 1), (1, 16, 3, 2, 3, 1), (1, 5, 1, 1, 3, 1), (1, 3, 5, 4, 0, 2), (1, 20, 6, 5, 1, 0)] {
        let (fl, fr, fx) = (rng.array(&[n, c, h, w], -1.0, 1.0), rng.array(&[n, c, h, w], -1.0, 1.0), flow_x(&mut rng, n, h, w));
        let fused = rls_warp_corr_fwd(nhwc(&fl).view(), nhwc(&fr).view(), fx.view(), &RlsWarpCfg { rx, ry }).unwrap().into_dyn();
        let warped = warp_by_grid_sample(&fr, &fx);
        let unfused = rls_corr_fwd(fl.view(), warped.view(), &RlsCorrCfg { rx, ry }).unwrap().into_dyn();
        assert!(max_abs_diff(&fused, &unfused) < 1e-12, "C={c} {h}x{w} rx={rx} ry={ry}: {}", max_abs_diff(&fused, &unfused));
    }
}

#[test]
fn ip_warp_corr_bwd_gradcheck_f64_fl_and_fr() {
    // bilinear in (fl, fr) for a fixed flow: no kinks (the flow gets no gradient).
    let mut rng = Rng::new(53);
    for (n, c, g, h, w) in [(2, 4, 2, 3, 4), (1, 6, 3, 4, 3), (1, 2, 1, 1, 6)] {
        let (fl, fr, fx) = (nhwc(&rng.array(&[n, c, h, w], -1.0, 1.0)), nhwc(&rng.array(&[n, c, h, w], -1.0, 1.0)), flow_x(&mut rng, n, h, w));
        let cfg = IpWarpCfg { groups: g, seeds: IP_SEEDS.to_vec() };
        let go = rng.array(&[n, cfg.channels(), h, w], -1.0, 1.0);
        let grads = ip_warp_corr_bwd(fl.view(), fr.view(), fx.view(), go.view(), &cfg).unwrap();
        let loss = |a: &ArrayD<f64>, b: &ArrayD<f64>| dot(&ip_warp_corr_fwd(a.view(), b.view(), fx.view(), &cfg).unwrap().into_dyn(), &go);
        let name = format!("ip_warp_corr C={c} G={g} {h}x{w}");
        gradcheck(&format!("{name} fl"), &fl, &grads.fl.into_dyn(), |a| loss(a, &fr));
        gradcheck(&format!("{name} fr"), &fr, &grads.fr.into_dyn(), |b| loss(&fl, b));
    }
}

#[test]
fn rls_warp_corr_bwd_gradcheck_f64_fl_and_fr() {
    // bilinear in (fl, fr) for a fixed flow; the clamps are index maps, not kinks.
    let mut rng = Rng::new(54);
    for (n, c, h, w, rx, ry) in [(2, 4, 3, 5, 3, 1), (1, 3, 4, 2, 1, 2), (1, 2, 1, 1, 3, 1), (1, 5, 2, 6, 0, 0)] {
        let (fl, fr, fx) = (nhwc(&rng.array(&[n, c, h, w], -1.0, 1.0)), nhwc(&rng.array(&[n, c, h, w], -1.0, 1.0)), flow_x(&mut rng, n, h, w));
        let cfg = RlsWarpCfg { rx, ry };
        let go = rng.array(&[n, cfg.channels().unwrap(), h, w], -1.0, 1.0);
        let grads = rls_warp_corr_bwd(fl.view(), fr.view(), fx.view(), go.view(), &cfg).unwrap();
        let loss = |a: &ArrayD<f64>, b: &ArrayD<f64>| dot(&rls_warp_corr_fwd(a.view(), b.view(), fx.view(), &cfg).unwrap().into_dyn(), &go);
        let name = format!("rls_warp_corr C={c} {h}x{w} rx={rx} ry={ry}");
        gradcheck(&format!("{name} fl"), &fl, &grads.fl.into_dyn(), |a| loss(a, &fr));
        gradcheck(&format!("{name} fr"), &fr, &grads.fr.into_dyn(), |b| loss(&fl, b));
    }
}

#[test]
fn warp_corr_fwd_and_bwd_are_bitwise_deterministic_across_thread_counts() {
    let mut rng = Rng::new(55);
    let f32s = |a: ArrayD<f64>| a.mapv(|v| v as f32);
    let (fl, fr) = (f32s(rng.array(&[2, 9, 11, 40], -1.0, 1.0)), f32s(rng.array(&[2, 9, 11, 40], -1.0, 1.0)));
    let fx = f32s(rng.array(&[2, 9, 11], -12.0, 2.0));
    let (g_ip, g_rls) = (f32s(rng.array(&[2, 10, 9, 11], -1.0, 1.0)), f32s(rng.array(&[2, 21, 9, 11], -1.0, 1.0)));
    let (ip, rls) = (IpWarpCfg { groups: 2, seeds: IP_SEEDS.to_vec() }, RlsWarpCfg { rx: 3, ry: 1 });
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            let a = ip_warp_corr_fwd(fl.view(), fr.view(), fx.view(), &ip).unwrap();
            let b = rls_warp_corr_fwd(fl.view(), fr.view(), fx.view(), &rls).unwrap();
            let gi = ip_warp_corr_bwd(fl.view(), fr.view(), fx.view(), g_ip.view(), &ip).unwrap();
            let gr = rls_warp_corr_bwd(fl.view(), fr.view(), fx.view(), g_rls.view(), &rls).unwrap();
            (a, b, gi.fl, gi.fr, gr.fl, gr.fr)
        })
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn warp_corr_errors_name_op_and_shapes() {
    let (fl, fx) = (ArrayD::<f32>::zeros(IxDyn(&[1, 3, 4, 8])), ArrayD::<f32>::zeros(IxDyn(&[1, 3, 4])));
    let ip = IpWarpCfg { groups: 2, seeds: IP_SEEDS.to_vec() };
    let fr = ArrayD::<f32>::zeros(IxDyn(&[1, 3, 5, 8]));
    let err = ip_warp_corr_fwd(fl.view(), fr.view(), fx.view(), &ip).unwrap_err().to_string();
    assert!(err.contains("ip_warp_correlation") && err.contains("[1, 3, 4, 8]") && err.contains("[1, 3, 5, 8]"), "{err}");
    let bad_fx = ArrayD::<f32>::zeros(IxDyn(&[1, 4, 3]));
    let err = rls_warp_corr_fwd(fl.view(), fl.view(), bad_fx.view(), &RlsWarpCfg { rx: 3, ry: 1 }).unwrap_err().to_string();
    assert!(err.contains("rls_warp_correlation") && err.contains("flow_x=[1, 4, 3]"), "{err}");
    let err = ip_warp_corr_fwd(fl.view(), fl.view(), fx.view(), &IpWarpCfg { groups: 3, ..ip.clone() }).unwrap_err().to_string();
    assert!(err.contains("ip_warp_correlation") && err.contains("groups=3"), "{err}");
    let nan = fx.mapv(|_| f32::NAN);
    assert!(ip_warp_corr_fwd(fl.view(), fl.view(), nan.view(), &ip).unwrap_err().to_string().contains("NaN"));
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 21, 3, 4]));
    let err = ip_warp_corr_bwd(fl.view(), fl.view(), fx.view(), g.view(), &ip).unwrap_err().to_string();
    assert!(err.contains("ip_warp_correlation") && err.contains("(N, 10, h, w)") && err.contains("[1, 21, 3, 4]"), "{err}");
    let err = rls_warp_corr_fwd(fl.view(), fl.view(), fx.view(), &RlsWarpCfg { rx: usize::MAX / 2, ry: 1 }).unwrap_err().to_string();
    assert!(err.contains("too large"), "{err}");
}
