//! Convex upsampling (RAFT; architecture.md §2.8), fused: the softmax over the 9 neighbours, the zero-padded 3x3
//! unfold of R·flow, the weighted sum and the (i, j) sub-pixel interleave in one pass.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | convex upsampling by rate R | `convex_upsample_fwd` | `convex_upsample_bwd` (flow, mask) |

use crate::ops::lanes::{self, multiversion};
use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array4, ArrayView4, ArrayViewD, ArrayViewMut2, Axis, Ix4};
use rayon::prelude::*;

const OP: &str = "convex_upsample";

/// Upsampling rate R (MIPNet: 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvexUpsampleCfg {
    pub rate: usize,
}

/// Sizes of one call: batch, flow channels D, h, w.
#[derive(Clone, Copy, Debug)]
struct Dims {
    n: usize,
    d: usize,
    h: usize,
    w: usize,
}

impl ConvexUpsampleCfg {
    /// Validates flow (N, D, h, w) and mask (N, 9·R², h, w).
    fn dims(&self, flow: &[usize], mask: &[usize]) -> Result<Dims> {
        let shapes = [("flow", flow), ("mask", mask)];
        if self.rate == 0 {
            return Err(Error::arg(OP, "rate must be positive"));
        }
        check_nonempty(OP, &shapes)?;
        // mask channels 9·R², output (R·h, R·w)
        let checked = || Some((self.rate.checked_mul(self.rate)?.checked_mul(9)?, self.rate.checked_mul(flow[2])?, self.rate.checked_mul(flow[3])?));
        let Some((channels, _, _)) = checked() else {
            return Err(Error::arg(OP, format!("rate {} is too large", self.rate)));
        };
        if mask[0] != flow[0] || mask[1] != channels || mask[2..] != flow[2..] {
            return Err(Error::shape(OP, format!("mask must be (N, 9*rate^2 = {channels}, h, w) for flow (N, D, h, w)"), &shapes));
        }
        Ok(Dims { n: flow[0], d: flow[1], h: flow[2], w: flow[3] })
    }

    /// out (N, D, R·h, R·w) viewed as (N, D, h, R·R·w): rows R·y .. R·y+R of every channel are one
    /// contiguous run, so (n, y) owns a (D, R·R·w) block.
    fn out_shape(&self, d: &Dims) -> (usize, usize, usize, usize) {
        (d.n, d.d, self.rate * d.h, self.rate * d.w)
    }
}

/// Per (n, y): the 9 softmax weights of every (sub-pixel, x), and R·flow of the 3 neighbour rows.
struct RowCtx<F> {
    /// wts[(ij·9 + k)·w + x] = softmax_k(mask[k·R² + ij, y, x]).
    wts: Vec<F>,
    /// nb[(d·3 + r)·(w+2) + 1 + x] = R·flow[d, y + r - 1, x], zero outside the map.
    nb: Vec<F>,
}

multiversion! {
    /// e = exp(m - max) over a run, added into sum (the softmax's numerators, with `lanes::exp`).
    fn exp_shifted_run<F: Float>(e: &mut [F], m: &[F], max: &[F], sum: &mut [F]) {
        e.iter_mut().zip(m).zip(max).zip(sum.iter_mut()).for_each(|(((e, &v), &mv), s)| {
            *e = lanes::exp(v - mv);
            *s += *e;
        });
    }
}

impl<F: Float> RowCtx<F> {
    fn new(cfg: &ConvexUpsampleCfg, dm: &Dims, flow: &[F], mask: &[F], b: usize, y: usize) -> Self {
        let (rr, w, h, hw) = (cfg.rate * cfg.rate, dm.w, dm.h, dm.h * dm.w);
        let rate = F::from_usize(cfg.rate).unwrap_or_else(F::max_value);
        let mut nb = vec![F::zero(); dm.d * 3 * (w + 2)];
        for (dr, seg) in nb.chunks_mut(w + 2).enumerate() {
            let (ch, r) = (dr / 3, dr % 3);
            // neighbour row y + r - 1, zero padded
            if let Some(yy) = (y + r).checked_sub(1).filter(|&yy| yy < h) {
                let src = &flow[(b * dm.d + ch) * hw + yy * w..][..w];
                seg[1..=w].iter_mut().zip(src).for_each(|(s, &f)| *s = rate * f);
            }
        }
        let mut wts = vec![F::zero(); rr * 9 * w];
        let mbase = b * 9 * rr * hw + y * w;
        for (ij, wij) in wts.chunks_mut(9 * w).enumerate() {
            // mask channel k·R² + ij, row y
            let m = |k: usize| &mask[mbase + (k * rr + ij) * hw..][..w];
            let mut mx = m(0).to_vec();
            for k in 1..9 {
                mx.iter_mut().zip(m(k)).for_each(|(a, &v)| *a = a.max(v));
            }
            let mut sum = vec![F::zero(); w];
            for (k, wk) in wij.chunks_mut(w).enumerate() {
                exp_shifted_run(wk, m(k), &mx, &mut sum);
            }
            for wk in wij.chunks_mut(w) {
                // softmax_k = e_k / Σ e
                wk.iter_mut().zip(&sum).for_each(|(e, &s)| *e /= s);
            }
        }
        RowCtx { wts, nb }
    }

    /// R·flow[d, y + dy, x + dx] for neighbour k = (dy+1)·3 + (dx+1), as a slice over x.
    fn neighbour(&self, w: usize, ch: usize, k: usize) -> &[F] {
        let (r, col) = (k / 3, k % 3);
        &self.nb[(ch * 3 + r) * (w + 2) + col..][..w]
    }

    fn weights(&self, w: usize, ij: usize, k: usize) -> &[F] {
        &self.wts[(ij * 9 + k) * w..][..w]
    }
}

fn inputs<'a, F>(flow: ArrayViewD<'a, F>, mask: ArrayViewD<'a, F>) -> Result<(ArrayView4<'a, F>, ArrayView4<'a, F>)> {
    Ok((fixed::<_, Ix4>(OP, "flow", flow)?, fixed::<_, Ix4>(OP, "mask", mask)?))
}

/// Index of output pixel (R·y + i, R·x + j) inside the (n, d, y) block of R rows of width R·w.
#[inline(always)]
fn sub(rate: usize, w: usize, i: usize, j: usize, x: usize) -> usize {
    // offset = i·(R·w) + R·x + j
    i * rate * w + rate * x + j
}

/// Convex combination of the 3x3 neighbourhood of R·flow, weighted by a softmax of the mask.
///
/// # Shapes
/// flow (N, D, h, w), mask (N, 9·R², h, w) -> (N, D, R·h, R·w), with
/// out[d, R·y + i, R·x + j] = Σ_k softmax_k(mask[k·R² + i·R + j, y, x]) · R · flow[d, y + dy_k, x + dx_k],
/// k = (dy+1)·3 + (dx+1), flow read as 0 outside the map.
///
/// # Gradient
/// flow and mask: see [`convex_upsample_bwd`] (softmax Jacobian for the mask, fold of the weighted grads for the flow).
///
/// Torch (RAFT `upsample_flow`): `softmax(mask.view(N,1,9,R,R,h,w), dim=2)` times
/// `F.unfold(R*flow, [3,3], padding=1).view(N,D,9,1,1,h,w)`, summed over dim 2,
/// `.permute(0,1,4,2,5,3).reshape(N,D,R*h,R*w)`.
pub fn convex_upsample_fwd<F: Float>(flow: ArrayViewD<F>, mask: ArrayViewD<F>, cfg: &ConvexUpsampleCfg) -> Result<Array4<F>> {
    let (flow, mask) = inputs(flow, mask)?;
    let dm = cfg.dims(flow.shape(), mask.shape())?;
    let (flow, mask) = (flow.as_standard_layout(), mask.as_standard_layout());
    let (fs, ms) = (flow.as_slice().expect("standard layout"), mask.as_slice().expect("standard layout"));
    let (rate, w) = (cfg.rate, dm.w);
    let mut out = zeros(OP, cfg.out_shape(&dm))?;
    {
        let mut blocks = out.view_mut().into_shape_with_order((dm.n, dm.d, dm.h, rate * rate * w)).expect("contiguous");
        blocks.axis_iter_mut(Axis(0)).into_par_iter().enumerate().for_each(|(b, mut bn)| {
            bn.axis_iter_mut(Axis(1)).into_par_iter().enumerate().for_each(|(y, mut rows): (usize, ArrayViewMut2<F>)| {
                let ctx = RowCtx::new(cfg, &dm, fs, ms, b, y);
                let mut acc = vec![F::zero(); w];
                for ch in 0..dm.d {
                    let o = rows.row_mut(ch).into_slice().expect("contiguous block");
                    for ij in 0..rate * rate {
                        acc.fill(F::zero());
                        for k in 0..9 {
                            // acc[x] += w_k(ij, x) · R·flow[d, y + dy_k, x + dx_k]
                            let (wk, u) = (ctx.weights(w, ij, k), ctx.neighbour(w, ch, k));
                            acc.iter_mut().zip(wk).zip(u).for_each(|((a, &wv), &uv)| *a += wv * uv);
                        }
                        let (i, j) = (ij / rate, ij % rate);
                        for (x, &a) in acc.iter().enumerate() {
                            o[sub(rate, w, i, j, x)] = a;
                        }
                    }
                }
            });
        });
    }
    Ok(out)
}

/// Gradients of [`convex_upsample_fwd`].
#[derive(Debug)]
pub struct ConvexUpsampleGrads<F> {
    pub flow: Array4<F>,
    pub mask: Array4<F>,
}

/// Gradients of [`convex_upsample_fwd`] with respect to flow and mask.
///
/// # Shapes
/// flow (N, D, h, w), mask (N, 9·R², h, w), g (N, D, R·h, R·w) -> flow (N, D, h, w), mask (N, 9·R², h, w).
///
/// # Gradient
/// with W_k the softmax weights and U_k = R·flow[y + dy_k, x + dx_k]:
/// dW_k = Σ_d g · U_k, dmask_k = W_k (dW_k - Σ_k' W_k' dW_k');
/// dU_k[d, y, x] = Σ_{i,j} g[d, R·y+i, R·x+j] · W_k, dflow[d, y', x'] = R Σ_k dU_k[d, y' - dy_k, x' - dx_k]
/// (the fold of the unfold, gathered per (n, d) plane in a fixed order).
///
/// Torch: the backward of RAFT's `upsample_flow` expression of [`convex_upsample_fwd`].
pub fn convex_upsample_bwd<F: Float>(
    flow: ArrayViewD<F>,
    mask: ArrayViewD<F>,
    g: ArrayViewD<F>,
    cfg: &ConvexUpsampleCfg,
) -> Result<ConvexUpsampleGrads<F>> {
    let (flow, mask) = inputs(flow, mask)?;
    let dm = cfg.dims(flow.shape(), mask.shape())?;
    let (n, nd, h, w) = (dm.n, dm.d, dm.h, dm.w);
    let os = cfg.out_shape(&dm);
    if g.shape() != [os.0, os.1, os.2, os.3] {
        return Err(Error::shape(OP, "grad_output must be (N, D, rate*h, rate*w)", &[
            ("flow", flow.shape()),
            ("mask", mask.shape()),
            ("grad_output", g.shape()),
        ]));
    }
    let (flow, mask, g) = (flow.as_standard_layout(), mask.as_standard_layout(), g.as_standard_layout());
    let (fs, ms, gs) = (
        flow.as_slice().expect("standard layout"),
        mask.as_slice().expect("standard layout"),
        g.as_slice().expect("standard layout"),
    );
    let (rate, rr) = (cfg.rate, cfg.rate * cfg.rate);
    let block = rr * w;
    let mut dmask = zeros(OP, (n, 9 * rr, h, w))?;
    // du[((b·h + y)·9 + k)·D + d][x] = dU_k[d, y, x]
    let mut du = vec![F::zero(); n * h * 9 * nd * w];
    dmask.axis_iter_mut(Axis(0)).into_par_iter().zip(du.par_chunks_mut(h * 9 * nd * w)).enumerate().for_each(|(b, (mut dmn, dun))| {
        dmn.axis_iter_mut(Axis(1)).into_par_iter().zip(dun.par_chunks_mut(9 * nd * w)).enumerate().for_each(
            |(y, (mut dmrow, durow)): (usize, (ArrayViewMut2<F>, &mut [F]))| {
                let ctx = RowCtx::new(cfg, &dm, fs, ms, b, y);
                let mut dwk = vec![F::zero(); 9 * w];
                let mut dot = vec![F::zero(); w];
                for ij in 0..rr {
                    let (i, j) = (ij / rate, ij % rate);
                    dwk.fill(F::zero());
                    for ch in 0..nd {
                        let gb = &gs[((b * nd + ch) * h + y) * block..][..block];
                        for k in 0..9 {
                            let (u, wk) = (ctx.neighbour(w, ch, k), ctx.weights(w, ij, k));
                            let dus = &mut durow[(k * nd + ch) * w..][..w];
                            for x in 0..w {
                                let gv = gb[sub(rate, w, i, j, x)];
                                // dW_k += g · U_k;  dU_k += g · W_k
                                dwk[k * w + x] += gv * u[x];
                                dus[x] += gv * wk[x];
                            }
                        }
                    }
                    // softmax backward: dmask_k = W_k (dW_k - Σ_k' W_k' dW_k')
                    dot.fill(F::zero());
                    for k in 0..9 {
                        let wk = ctx.weights(w, ij, k);
                        dot.iter_mut().zip(wk).zip(&dwk[k * w..][..w]).for_each(|((s, &wv), &dv)| *s += wv * dv);
                    }
                    for k in 0..9 {
                        let wk = ctx.weights(w, ij, k);
                        let dm_row = dmrow.row_mut(k * rr + ij).into_slice().expect("contiguous row");
                        dm_row.iter_mut().zip(wk).zip(&dwk[k * w..][..w]).zip(&dot).for_each(|(((o, &wv), &dv), &s)| *o = wv * (dv - s));
                    }
                }
            },
        );
    });
    let rate_f = F::from_usize(rate).unwrap_or_else(F::max_value);
    let mut dflow = zeros(OP, (n, nd, h, w))?;
    let dfs = dflow.as_slice_mut().expect("fresh array");
    dfs.par_chunks_mut(h * w).enumerate().for_each(|(p, plane)| {
        let (b, ch) = (p / nd, p % nd);
        for (yt, drow) in plane.chunks_mut(w).enumerate() {
            for k in 0..9 {
                let (dy, dx) = (k / 3, k % 3);
                // flow[y'] feeds U_k at y = y' - (dy - 1), x = x' - (dx - 1)
                let Some(y) = (yt + 1).checked_sub(dy).filter(|&y| y < h) else { continue };
                let src = &du[(((b * h + y) * 9 + k) * nd + ch) * w..][..w];
                for (xt, dv) in drow.iter_mut().enumerate() {
                    if let Some(x) = (xt + 1).checked_sub(dx).filter(|&x| x < w) {
                        *dv += rate_f * src[x];
                    }
                }
            }
        }
    });
    Ok(ConvexUpsampleGrads { flow: dflow, mask: dmask })
}
