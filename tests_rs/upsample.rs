//! Convex upsampling: hand-computed forwards, f64 gradchecks of both gradients, and errors.
mod common;

use _core::ops::upsample::*;
use common::{dot, gradcheck, Rng};
use ndarray::{ArrayD, IxDyn};

#[test]
fn convex_upsample_uniform_mask_averages_the_zero_padded_neighbourhood() {
    // mask = 0 -> weights 1/9; flow = 1 -> out = R·(#neighbours inside the map)/9
    let (r, h, w) = (4, 3, 4);
    let flow = ArrayD::<f64>::ones(IxDyn(&[1, 2, h, w]));
    let mask = ArrayD::<f64>::zeros(IxDyn(&[1, 9 * r * r, h, w]));
    let out = convex_upsample_fwd(flow.view(), mask.view(), &ConvexUpsampleCfg { rate: r }).unwrap();
    assert_eq!(out.shape(), &[1, 2, r * h, r * w]);
    let near = |y: usize, x: usize| (((y > 0) as usize + 1 + (y + 1 < h) as usize) * ((x > 0) as usize + 1 + (x + 1 < w) as usize)) as f64;
    for y in 0..h {
        for x in 0..w {
            for (i, j) in [(0, 0), (3, 1), (2, 3)] {
                let v = out[[0, 1, r * y + i, r * x + j]];
                assert!((v - r as f64 * near(y, x) / 9.0).abs() < 1e-12, "y={y} x={x}: {v}");
            }
        }
    }
}

#[test]
fn convex_upsample_one_hot_mask_selects_neighbour_k() {
    // a large logit on neighbour k for sub-pixel (i, j) picks R·flow[y + dy_k, x + dx_k]
    let (r, h, w) = (2, 3, 3);
    let flow = ArrayD::from_shape_fn(IxDyn(&[1, 1, h, w]), |i| (10 * i[2] + i[3]) as f64);
    let mut mask = ArrayD::<f64>::zeros(IxDyn(&[1, 9 * r * r, h, w]));
    for ij in 0..r * r {
        let k = [0, 2, 6, 8][ij];
        mask.slice_mut(ndarray::s![0, k * r * r + ij, .., ..]).fill(200.0);
    }
    let out = convex_upsample_fwd(flow.view(), mask.view(), &ConvexUpsampleCfg { rate: r }).unwrap();
    // centre pixel (1, 1): (i, j) = (0, 0) -> k 0 = (-1, -1) -> flow 0; (1, 1) -> k 8 = (+1, +1) -> flow 22
    assert!((out[[0, 0, 2, 2]] - 0.0).abs() < 1e-9);
    assert!((out[[0, 0, 2, 3]] - 2.0 * 2.0).abs() < 1e-9);
    assert!((out[[0, 0, 3, 2]] - 2.0 * 20.0).abs() < 1e-9);
    assert!((out[[0, 0, 3, 3]] - 2.0 * 22.0).abs() < 1e-9);
}

#[test]
fn convex_upsample_bwd_gradcheck_f64_flow_and_mask() {
    // softmax and the weighted sum are smooth; the zero padding is an index map, not a kink.
    let mut rng = Rng::new(51);
    for (n, d, h, w, r) in [(2, 2, 3, 4, 4), (1, 2, 5, 3, 4), (1, 1, 2, 2, 2), (1, 3, 1, 1, 1)] {
        let cfg = ConvexUpsampleCfg { rate: r };
        let flow = rng.array(&[n, d, h, w], -2.0, 2.0);
        let mask = rng.array(&[n, 9 * r * r, h, w], -2.0, 2.0);
        let go = rng.array(&[n, d, r * h, r * w], -1.0, 1.0);
        let grads = convex_upsample_bwd(flow.view(), mask.view(), go.view(), &cfg).unwrap();
        let loss = |f: &ArrayD<f64>, m: &ArrayD<f64>| dot(&convex_upsample_fwd(f.view(), m.view(), &cfg).unwrap().into_dyn(), &go);
        let name = format!("convex_upsample D={d} {h}x{w} R={r}");
        gradcheck(&format!("{name} flow"), &flow, &grads.flow.into_dyn(), |f| loss(f, &mask));
        gradcheck(&format!("{name} mask"), &mask, &grads.mask.into_dyn(), |m| loss(&flow, m));
    }
}

#[test]
fn convex_upsample_rejects_bad_mask_rate_and_grad() {
    let flow = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 3, 4]));
    let mask = ArrayD::<f32>::zeros(IxDyn(&[1, 143, 3, 4]));
    let err = convex_upsample_fwd(flow.view(), mask.view(), &ConvexUpsampleCfg { rate: 4 }).unwrap_err().to_string();
    assert!(err.contains("convex_upsample") && err.contains("144") && err.contains("[1, 143, 3, 4]") && err.contains("[1, 2, 3, 4]"), "{err}");
    let mask = ArrayD::<f32>::zeros(IxDyn(&[1, 144, 3, 4]));
    let err = convex_upsample_fwd(flow.view(), mask.view(), &ConvexUpsampleCfg { rate: 0 }).unwrap_err().to_string();
    assert!(err.contains("convex_upsample") && err.contains("rate"), "{err}");
    let err = convex_upsample_fwd(flow.view(), mask.view(), &ConvexUpsampleCfg { rate: 1 << 33 }).unwrap_err().to_string();
    assert!(err.contains("convex_upsample") && err.contains("too large"), "{err}");
    let g = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 12, 15]));
    let err = convex_upsample_bwd(flow.view(), mask.view(), g.view(), &ConvexUpsampleCfg { rate: 4 }).unwrap_err().to_string();
    assert!(err.contains("convex_upsample") && err.contains("[1, 2, 12, 15]"), "{err}");
    let empty = ArrayD::<f32>::zeros(IxDyn(&[1, 2, 0, 4]));
    let emask = ArrayD::<f32>::zeros(IxDyn(&[1, 144, 0, 4]));
    assert!(convex_upsample_fwd(empty.view(), emask.view(), &ConvexUpsampleCfg { rate: 4 }).unwrap_err().to_string().contains("empty"));
}
