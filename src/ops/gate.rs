//! iAFF's attentional gate (architecture.md §2.2), fused: out = w ⊙ x + (1 - w) ⊙ y with w = σ(L + G), where L is
//! the local branch (N, C, H, W) and G the global branch (N, C, 1, 1), broadcast over H, W.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | attention gate | `attention_gate_fwd` | `attention_gate_bwd` (local, global, x, y) |
//!
//! Work is split by (n, c) planes; the global gradient sums its plane in a fixed order (vectorised lane
//! sums, f64 across blocks).

use super::lanes::{self, multiversion, sigmoid};
use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array4, ArrayView4, ArrayViewD, Ix4};
use rayon::prelude::*;

const OP: &str = "attention_gate";

/// Checks local, x, y (N, C, H, W) and global (N, C, 1, 1); returns the four views.
fn inputs<'a, F>(l: ArrayViewD<'a, F>, gl: ArrayViewD<'a, F>, x: ArrayViewD<'a, F>, y: ArrayViewD<'a, F>) -> Result<[ArrayView4<'a, F>; 4]> {
    let v = [fixed::<_, Ix4>(OP, "local", l)?, fixed::<_, Ix4>(OP, "global", gl)?, fixed::<_, Ix4>(OP, "x", x)?, fixed::<_, Ix4>(OP, "y", y)?];
    let shapes = [("local", v[0].shape()), ("global", v[1].shape()), ("x", v[2].shape()), ("y", v[3].shape())];
    check_nonempty(OP, &shapes)?;
    let s = v[0].shape();
    if v[2].shape() != s || v[3].shape() != s || v[1].shape() != [s[0], s[1], 1, 1] {
        return Err(Error::shape(OP, "expected local, x, y (N, C, H, W) and global (N, C, 1, 1)", &shapes));
    }
    Ok(v)
}

multiversion! {
    /// out = w·x + (1 - w)·y over one plane, w = σ(l + gv).
    fn gate_plane<F: Float>(o: &mut [F], l: &[F], gv: F, x: &[F], y: &[F]) {
        o.iter_mut().zip(l).zip(x).zip(y).for_each(|(((o, &l), &x), &y)| {
            let w = sigmoid(l + gv);
            *o = w * x + (F::one() - w) * y;
        });
    }
}

multiversion! {
    /// One plane of the backward: dl = g·(x - y)·w(1 - w), dx = g·w, dy = g·(1 - w).
    fn gate_grad_plane<F: Float>(dl: &mut [F], dx: &mut [F], dy: &mut [F], l: &[F], gv: F, x: &[F], y: &[F], g: &[F]) {
        for i in 0..dl.len().min(dx.len()).min(dy.len()).min(l.len()).min(x.len()).min(y.len()).min(g.len()) {
            let w = sigmoid(l[i] + gv);
            dl[i] = g[i] * (x[i] - y[i]) * (w * (F::one() - w));
            dx[i] = g[i] * w;
            dy[i] = g[i] * (F::one() - w);
        }
    }
}

/// The attentional gate of iAFF.
///
/// # Shapes
/// local, x, y (N, C, H, W), global (N, C, 1, 1) -> (N, C, H, W).
///
/// # Gradient
/// See [`attention_gate_bwd`].
///
/// Torch: `w = torch.sigmoid(local + glob); w * x + (1 - w) * y`.
pub fn attention_gate_fwd<F: Float>(local: ArrayViewD<F>, global: ArrayViewD<F>, x: ArrayViewD<F>, y: ArrayViewD<F>) -> Result<Array4<F>> {
    let [l, gl, x, y] = inputs(local, global, x, y)?;
    let (l, gl, x, y) = (l.as_standard_layout(), gl.as_standard_layout(), x.as_standard_layout(), y.as_standard_layout());
    let (ls, gs, xs, ys) = (l.as_slice().expect("standard layout"), gl.as_slice().expect("standard layout"),
                            x.as_slice().expect("standard layout"), y.as_slice().expect("standard layout"));
    let plane = l.shape()[2] * l.shape()[3];
    let mut out = zeros(OP, l.raw_dim())?;
    // plane i = n·C + c: its global value is gs[i]
    out.as_slice_mut().expect("fresh array").par_chunks_mut(plane).enumerate().for_each(|(i, o)| {
        let r = i * plane..(i + 1) * plane;
        gate_plane(o, &ls[r.clone()], gs[i], &xs[r.clone()], &ys[r]);
    });
    Ok(out)
}

/// Gradients of [`attention_gate_fwd`].
#[derive(Debug)]
pub struct AttentionGateGrads<F> {
    pub local: Array4<F>,
    pub global: Array4<F>,
    pub x: Array4<F>,
    pub y: Array4<F>,
}

/// Gradients of [`attention_gate_fwd`] with respect to all four inputs.
///
/// # Shapes
/// As the forward, g (N, C, H, W) -> local, x, y (N, C, H, W), global (N, C, 1, 1).
///
/// # Gradient
/// With w = σ(local + global): d local = g·(x - y)·w(1 - w); d global[n, c] = Σ_{h,w} d local[n, c];
/// d x = g·w; d y = g·(1 - w).
pub fn attention_gate_bwd<F: Float>(local: ArrayViewD<F>, global: ArrayViewD<F>, x: ArrayViewD<F>, y: ArrayViewD<F>,
                                    g: ArrayViewD<F>) -> Result<AttentionGateGrads<F>> {
    let [l, gl, x, y] = inputs(local, global, x, y)?;
    if g.shape() != l.shape() {
        return Err(Error::shape(OP, "grad_output must have the shape of local", &[("local", l.shape()), ("grad_output", g.shape())]));
    }
    let (l, gl, x, y, g) = (l.as_standard_layout(), gl.as_standard_layout(), x.as_standard_layout(), y.as_standard_layout(), g.as_standard_layout());
    let (ls, gls, xs, ys, gs) = (l.as_slice().expect("standard layout"), gl.as_slice().expect("standard layout"),
                                 x.as_slice().expect("standard layout"), y.as_slice().expect("standard layout"), g.as_slice().expect("standard layout"));
    let plane = l.shape()[2] * l.shape()[3];
    let (mut dl, mut dx, mut dy) = (zeros(OP, l.raw_dim())?, zeros(OP, l.raw_dim())?, zeros(OP, l.raw_dim())?);
    let mut dg = zeros(OP, gl.raw_dim())?;
    dl.as_slice_mut().expect("fresh array").par_chunks_mut(plane)
        .zip(dx.as_slice_mut().expect("fresh array").par_chunks_mut(plane))
        .zip(dy.as_slice_mut().expect("fresh array").par_chunks_mut(plane))
        .zip(dg.as_slice_mut().expect("fresh array").par_iter_mut())
        .enumerate()
        .for_each(|(i, (((dlp, dxp), dyp), dgv))| {
            let r = i * plane..(i + 1) * plane;
            gate_grad_plane(dlp, dxp, dyp, &ls[r.clone()], gls[i], &xs[r.clone()], &ys[r.clone()], &gs[r]);
            // d global = Σ d local over the plane, in lane sum order (f64 across blocks)
            let mut total = 0.0;
            lanes::sum(dlp, &mut total);
            *dgv = F::c(total);
        });
    Ok(AttentionGateGrads { local: dl, global: dg, x: dx, y: dy })
}
