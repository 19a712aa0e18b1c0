//! Stride-1 convolutions with one or two output channels (MIPNet's disparity heads, 3x3 256->2 and
//! 128->2) as a pointwise GEMM over taps·Cout rows followed by a shift-add. The im2col GEMM gives
//! such a convolution an A of Cout rows (a quarter of the micro-kernel's 8 or fewer) and builds its
//! B of taps·Cin rows for every output pixel; here A has taps·Cout rows and B is x itself.
//!
//! - forward: `Z[n]` = W'·`x[n]` with W'[t·Cout + o, c] = `w[o, c, t]` ([taps·Cout, Cin] · [Cin, H·W],
//!   the pointwise forward), then `y[n, o, oy, ox]` = `b[o]` + Σ_t `Z[n, t·Cout + o, oy + ki − ph, ox + kj − pw]`
//!   over the taps t = ki·kw + kj in order, a tap reading outside the image adding nothing;
//! - dW: `D[n, t·Cout + o, iy, ix]` = `dY[n, o, iy − ki + ph, ix − kj + pw]` (0 where no output pixel
//!   reads (iy, ix) through tap t), then dW'[t·Cout + o, c] = Σ_n `D[n]` · `x[n]`ᵀ (the pointwise
//!   weight gradient) and `dW[o, c, t]` = dW'[t·Cout + o, c].
//!
//! The FLOPs are those of the direct convolution; results are deterministic and independent of the
//! threads as the pointwise paths' are, the shift-add summing each output in tap order.

use super::{forward as pointwise_forward, layout, weight_grad as pointwise_weight_grad, Conv2dRun, Geom};
use crate::{Float, Result};
use ndarray::{Array2, Array4, ArrayView2};
use rayon::prelude::*;
use std::ops::Range;

/// Most output channels for this path: the disparity heads' two (three or four outputs would still
/// leave half or more of an 8-row micro-panel empty on the direct path, but are not measured).
const MAX_COUT: usize = 2;

/// Whether a geometry takes this path: stride 1, not pointwise, at most [`MAX_COUT`] outputs.
pub(super) fn applies(g: &Geom) -> bool {
    g.stride == [1, 1] && !g.pointwise() && g.cout <= MAX_COUT
}

/// The geometry of Z: a pointwise convolution Cin -> taps·Cout on the input grid.
fn pointwise(g: &Geom) -> Geom {
    let rows = g.cout * g.kh * g.kw;
    Geom { n: g.n, cin: g.cin, h: g.h, w: g.w, cout: rows, kh: 1, kw: 1, ho: g.h, wo: g.w, stride: [1, 1], pad: [0, 0] }
}

/// Where output row oy meets tap (ki, kj): the input row iy = oy + ki − ph, if inside the image, and
/// the output columns ox whose input column ix = ox + kj − pw is inside [0, W).
fn overlap(g: &Geom, oy: usize, ki: usize, kj: usize) -> Option<(usize, Range<usize>)> {
    let iy = (oy + ki).checked_sub(g.pad[0]).filter(|&iy| iy < g.h)?;
    // ox + kj − pw >= 0 from ox = pw − kj; ox + kj − pw < W below ox = W + pw − kj
    let cols = g.pad[1].saturating_sub(kj)..(g.w + g.pad[1]).saturating_sub(kj).min(g.wo);
    (!cols.is_empty()).then_some((iy, cols))
}

/// y = conv2d(x, w) (+ b, then ReLU) for a geometry where [`applies`] holds; `wm` is W as
/// [Cout, Cin·taps].
pub(super) fn forward<F: Float>(run: Conv2dRun<F>, g: &Geom, xs: &[F], wm: ArrayView2<F>, bias: Option<&[F]>, relu: bool)
                                -> Result<Array4<F>> {
    let (taps, plane, pix) = (g.kh * g.kw, g.h * g.w, g.ho * g.wo);
    // W'[t·Cout + o, c] = W[o, c·taps + t]
    let wt = Array2::from_shape_fn((taps * g.cout, g.cin), |(r, c)| wm[[r % g.cout, c * taps + r / g.cout]]);
    let z = pointwise_forward(run, &pointwise(g), xs, wt.view(), None, false)?;
    let zs = z.as_slice().expect("fresh array");
    let mut y = Array4::<F>::zeros((g.n, g.cout, g.ho, g.wo));
    y.as_slice_mut().expect("fresh array").par_chunks_mut(pix).enumerate().for_each(|(i, yo)| {
        // plane i = n·Cout + o
        let (n, o) = (i / g.cout, i % g.cout);
        yo.fill(bias.map_or(F::zero(), |b| b[o]));
        for t in 0..taps {
            let (ki, kj) = (t / g.kw, t % g.kw);
            // Z[n, t·Cout + o] starts ((n·taps + t)·Cout + o)·H·W elements in
            let zp = &zs[((n * taps + t) * g.cout + o) * plane..][..plane];
            for oy in 0..g.ho {
                let Some((iy, cols)) = overlap(g, oy, ki, kj) else { continue };
                // y[oy, ox] += Z[iy, ox + kj − pw] over the overlapping columns
                let src = &zp[iy * g.w + cols.start + kj - g.pad[1]..][..cols.len()];
                yo[oy * g.wo + cols.start..oy * g.wo + cols.end].iter_mut().zip(src).for_each(|(y, &z)| *y += z);
            }
        }
        if relu {
            yo.iter_mut().for_each(|v| *v = v.max(F::zero()));
        }
    });
    Ok(y)
}

/// dW of a convolution where [`applies`] holds, as the matrix [Cout, Cin·taps].
pub(super) fn weight_grad<F: Float>(run: Conv2dRun<F>, g: &Geom, xs: &[F], dy: &[F]) -> Result<Array2<F>> {
    let (taps, plane, pix) = (g.kh * g.kw, g.h * g.w, g.ho * g.wo);
    let rows = taps * g.cout;
    let mut d = vec![F::zero(); g.n * rows * plane];
    d.par_chunks_mut(plane).enumerate().for_each(|(i, dp)| {
        // plane i = n·rows + t·Cout + o
        let (n, t, o) = (i / rows, i % rows / g.cout, i % g.cout);
        let (ki, kj) = (t / g.kw, t % g.kw);
        let dyo = &dy[(n * g.cout + o) * pix..][..pix];
        for oy in 0..g.ho {
            let Some((iy, cols)) = overlap(g, oy, ki, kj) else { continue };
            // D[iy, ox + kj − pw] = dY[oy, ox] over the overlapping columns
            dp[iy * g.w + cols.start + kj - g.pad[1]..][..cols.len()].copy_from_slice(&dyo[oy * g.wo + cols.start..oy * g.wo + cols.end]);
        }
    });
    let dwt = pointwise_weight_grad(run, &pointwise(g), xs, &d)?.into_shape_with_order((rows, g.cin)).map_err(layout)?;
    // dW[o, c·taps + t] = dW'[t·Cout + o, c]
    Ok(Array2::from_shape_fn((g.cout, g.cin * taps), |(o, k)| dwt[[(k % taps) * g.cout + o, k / taps]]))
}
