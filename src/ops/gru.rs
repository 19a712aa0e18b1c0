//! The gate arithmetic of a convolutional GRU step (architecture.md §2.7), fused around its two convolutions:
//! z̃ and r̃ come from one convolution of hx = [h, x] (weights of convz and convr stacked), q̃ from a
//! convolution of [r ⊙ h, x], and
//!
//!   z = σ(z̃), r = σ(r̃), q = tanh(q̃), h' = (1 - z) ⊙ h + z ⊙ q.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | reset: rhx = [σ(r̃) ⊙ h, x] | `gru_reset_fwd` | `gru_reset_bwd` (zr: the r̃ half, hx) |
//! | update: h' (or [h', x]) | `gru_update_fwd` | `gru_update_bwd` (zr: the z̃ half, q̃, hx) |
//!
//! Tensors are NCHW: zr (N, 2H, h, w) = [z̃, r̃], hx (N, H + X, h, w) = [h, x], q̃ (N, H, h, w).
//! Backwards recompute σ and tanh from the pre-activations (nothing else is saved); work is split by
//! output planes, so results are deterministic.

use super::lanes::{multiversion, sigmoid, tanh};
use crate::tensor::{check_nonempty, fixed, par_filled_in, zeroed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array4, ArrayView4, ArrayViewD, Ix4};
use rayon::prelude::*;

const RESET: &str = "gru_reset";
const UPDATE: &str = "gru_update";

multiversion! {
    /// o = σ(r̃) ⊙ h.
    fn reset_plane<F: Float>(o: &mut [F], r: &[F], h: &[F]) {
        o.iter_mut().zip(r).zip(h).for_each(|((o, &r), &h)| *o = sigmoid(r) * h);
    }
}

multiversion! {
    /// d r̃ = g · h · r(1 - r) with r = σ(r̃).
    fn reset_dr_plane<F: Float>(o: &mut [F], r: &[F], h: &[F], g: &[F]) {
        o.iter_mut().zip(r).zip(h).zip(g).for_each(|(((o, &r), &h), &g)| {
            let r = sigmoid(r);
            *o = g * h * (r * (F::one() - r));
        });
    }
}

multiversion! {
    /// d h = g · σ(r̃) (reset) or g · (1 - σ(z̃)) (update, `one_minus`).
    fn gate_dh_plane<F: Float>(o: &mut [F], a: &[F], g: &[F], one_minus: bool) {
        if one_minus {
            o.iter_mut().zip(a).zip(g).for_each(|((o, &a), &g)| *o = g * (F::one() - sigmoid(a)));
        } else {
            o.iter_mut().zip(a).zip(g).for_each(|((o, &a), &g)| *o = g * sigmoid(a));
        }
    }
}

multiversion! {
    /// h' = (1 - z)·h + z·tanh(q̃) with z = σ(z̃).
    fn update_plane<F: Float>(o: &mut [F], z: &[F], q: &[F], h: &[F]) {
        // two loops (tanh first, into o), each of which vectorises; one loop with both did not
        o.iter_mut().zip(q).for_each(|(o, &q)| *o = tanh(q));
        o.iter_mut().zip(z).zip(h).for_each(|((o, &z), &h)| {
            let z = sigmoid(z);
            *o = (F::one() - z) * h + z * *o;
        });
    }
}

multiversion! {
    /// d z̃ = g·(tanh(q̃) - h)·z(1 - z) into dz, d q̃ = g·z·(1 - tanh²(q̃)) into dq.
    fn update_dzq_plane<F: Float>(dz: &mut [F], dq: &mut [F], z: &[F], q: &[F], h: &[F], g: &[F]) {
        for i in 0..dz.len().min(dq.len()).min(z.len()).min(q.len()).min(h.len()).min(g.len()) {
            let (zs, t) = (sigmoid(z[i]), tanh(q[i]));
            dz[i] = g[i] * (t - h[i]) * (zs * (F::one() - zs));
            dq[i] = g[i] * zs * (F::one() - t * t);
        }
    }
}

/// Sizes of one call: batch, hidden channels H, input channels X, plane size h·w.
#[derive(Clone, Copy, Debug)]
struct Dims {
    n: usize,
    hid: usize,
    x: usize,
    plane: usize,
}

impl Dims {
    /// Plane (b, k) of an (N, K, h, w) standard-layout slice.
    #[inline(always)]
    fn plane<'a, F>(&self, s: &'a [F], k_total: usize, b: usize, k: usize) -> &'a [F] {
        // offset = (b·K + k)·h·w
        &s[(b * k_total + k) * self.plane..][..self.plane]
    }
}

/// Checks zr (N, 2H, h, w) against hx (N, H + X, h, w) (and q̃ (N, H, h, w) when given).
fn dims<F>(op: &'static str, zr: &ArrayView4<F>, hx: &ArrayView4<F>, q: Option<&ArrayView4<F>>) -> Result<Dims> {
    let mut shapes = vec![("zr", zr.shape()), ("hx", hx.shape())];
    if let Some(q) = q {
        shapes.push(("q", q.shape()));
    }
    check_nonempty(op, &shapes)?;
    let (n, c2) = (zr.shape()[0], zr.shape()[1]);
    let hid = c2 / 2;
    let fits = c2 % 2 == 0 && hx.shape()[0] == n && hx.shape()[2..] == zr.shape()[2..] && hx.shape()[1] >= hid
        && q.is_none_or(|q| q.shape() == [n, hid, zr.shape()[2], zr.shape()[3]]);
    if !fits {
        return Err(Error::shape(op, "expected zr (N, 2H, h, w), hx (N, H+X, h, w), q (N, H, h, w)", &shapes));
    }
    Ok(Dims { n, hid, x: hx.shape()[1] - hid, plane: zr.shape()[2] * zr.shape()[3] })
}

fn check_grad(op: &'static str, g: &ArrayViewD<impl Float>, expect: [usize; 4]) -> Result<()> {
    if g.shape() != expect {
        return Err(Error::shape(op, format!("grad_output must be {expect:?}"), &[("grad_output", g.shape())]));
    }
    Ok(())
}

fn view4<'a, F>(op: &'static str, name: &'static str, a: ArrayViewD<'a, F>) -> Result<ArrayView4<'a, F>> {
    fixed::<_, Ix4>(op, name, a)
}

/// Runs `f(b, k, plane)` for every plane of a fresh (N, K, h, w) array, in parallel. Each plane is
/// zeroed by its own task just before `f` (in cache, not as a separate pass over the whole array).
fn planes<F: Float>(op: &'static str, shape: [usize; 4], f: impl Fn(usize, usize, &mut [F]) + Sync) -> Result<Array4<F>> {
    let (k_total, plane) = (shape[1], shape[2] * shape[3]);
    let out = par_filled_in(op, &shape, plane, |start, p| {
        // plane i = start / plane is (image i / K, channel i % K)
        let i = start / plane.max(1);
        f(i / k_total, i % k_total, zeroed(p))
    })?;
    Ok(out.into_dimensionality().expect("4-D shape"))
}

/// rhx = [σ(r̃) ⊙ h, x]: the input of the candidate's convolution.
///
/// # Shapes
/// zr (N, 2H, h, w), hx (N, H + X, h, w) -> (N, H + X, h, w).
///
/// # Gradient
/// See [`gru_reset_bwd`].
///
/// Torch: `torch.cat([torch.sigmoid(zr[:, H:]) * hx[:, :H], hx[:, H:]], 1)`.
pub fn gru_reset_fwd<F: Float>(zr: ArrayViewD<F>, hx: ArrayViewD<F>) -> Result<Array4<F>> {
    let (zr, hx) = (view4(RESET, "zr", zr)?, view4(RESET, "hx", hx)?);
    let d = dims(RESET, &zr, &hx, None)?;
    let (zr, hx) = (zr.as_standard_layout(), hx.as_standard_layout());
    let (zs, hs) = (zr.as_slice().expect("standard layout"), hx.as_slice().expect("standard layout"));
    let k_hx = d.hid + d.x;
    planes(RESET, [d.n, k_hx, hx.shape()[2], hx.shape()[3]], |b, k, o| {
        let src = d.plane(hs, k_hx, b, k);
        if k < d.hid {
            // r = σ(zr[H + k]); out = r ⊙ h[k]
            reset_plane(o, d.plane(zs, 2 * d.hid, b, d.hid + k), src);
        } else {
            o.copy_from_slice(src);
        }
    })
}

/// Gradients of [`gru_reset_fwd`].
#[derive(Debug)]
pub struct GruResetGrads<F> {
    /// (N, 2H, h, w): zero in the z̃ half.
    pub zr: Array4<F>,
    pub hx: Array4<F>,
}

/// Gradients of [`gru_reset_fwd`] with respect to zr and hx.
///
/// # Shapes
/// zr (N, 2H, h, w), hx (N, H + X, h, w), g (N, H + X, h, w) -> zr, hx of their shapes.
///
/// # Gradient
/// With r = σ(r̃): d r̃[k] = g[k] · h[k] · r(1 - r); d h[k] = g[k] · r; d x = g[H..]; d z̃ = 0.
pub fn gru_reset_bwd<F: Float>(zr: ArrayViewD<F>, hx: ArrayViewD<F>, g: ArrayViewD<F>) -> Result<GruResetGrads<F>> {
    let (zr, hx) = (view4(RESET, "zr", zr)?, view4(RESET, "hx", hx)?);
    let d = dims(RESET, &zr, &hx, None)?;
    let shape_hx = [d.n, d.hid + d.x, hx.shape()[2], hx.shape()[3]];
    check_grad(RESET, &g, shape_hx)?;
    let (zr, hx, g) = (zr.as_standard_layout(), hx.as_standard_layout(), g.as_standard_layout());
    let (zs, hs, gs) = (zr.as_slice().expect("standard layout"), hx.as_slice().expect("standard layout"), g.as_slice().expect("standard layout"));
    let k_hx = d.hid + d.x;
    let dzr = planes(RESET, [d.n, 2 * d.hid, shape_hx[2], shape_hx[3]], |b, k, o| {
        if k >= d.hid {
            // d r̃ = g · h · r(1 - r)
            reset_dr_plane(o, d.plane(zs, 2 * d.hid, b, k), d.plane(hs, k_hx, b, k - d.hid), d.plane(gs, k_hx, b, k - d.hid));
        }
    })?;
    let dhx = planes(RESET, shape_hx, |b, k, o| {
        let go = d.plane(gs, k_hx, b, k);
        if k < d.hid {
            // d h = g · r
            gate_dh_plane(o, d.plane(zs, 2 * d.hid, b, d.hid + k), go, false);
        } else {
            o.copy_from_slice(go);
        }
    })?;
    Ok(GruResetGrads { zr: dzr, hx: dhx })
}

/// h' = (1 - z) ⊙ h + z ⊙ tanh(q̃) with z = σ(z̃) and h = hx[:, :H]; with `keep_x`, [h', x].
///
/// # Shapes
/// zr (N, 2H, h, w), q (N, H, h, w), hx (N, H + X, h, w) -> (N, H, h, w), or (N, H + X, h, w) with `keep_x`.
///
/// # Gradient
/// See [`gru_update_bwd`].
///
/// Torch: `z = torch.sigmoid(zr[:, :H]); (1 - z) * hx[:, :H] + z * torch.tanh(q)` (then `cat` with `hx[:, H:]`).
pub fn gru_update_fwd<F: Float>(zr: ArrayViewD<F>, q: ArrayViewD<F>, hx: ArrayViewD<F>, keep_x: bool) -> Result<Array4<F>> {
    let (zr, q, hx) = (view4(UPDATE, "zr", zr)?, view4(UPDATE, "q", q)?, view4(UPDATE, "hx", hx)?);
    let d = dims(UPDATE, &zr, &hx, Some(&q))?;
    let (zr, q, hx) = (zr.as_standard_layout(), q.as_standard_layout(), hx.as_standard_layout());
    let (zs, qs, hs) = (zr.as_slice().expect("standard layout"), q.as_slice().expect("standard layout"), hx.as_slice().expect("standard layout"));
    let k_hx = d.hid + d.x;
    let k_out = if keep_x { k_hx } else { d.hid };
    planes(UPDATE, [d.n, k_out, hx.shape()[2], hx.shape()[3]], |b, k, o| {
        let src = d.plane(hs, k_hx, b, k);
        if k < d.hid {
            // h' = (1 - z)·h + z·tanh(q̃)
            update_plane(o, d.plane(zs, 2 * d.hid, b, k), d.plane(qs, d.hid, b, k), src);
        } else {
            o.copy_from_slice(src);
        }
    })
}

/// Gradients of [`gru_update_fwd`].
#[derive(Debug)]
pub struct GruUpdateGrads<F> {
    /// (N, 2H, h, w): zero in the r̃ half.
    pub zr: Array4<F>,
    pub q: Array4<F>,
    pub hx: Array4<F>,
}

/// Gradients of [`gru_update_fwd`] with respect to zr, q̃ and hx.
///
/// # Shapes
/// zr (N, 2H, h, w), q (N, H, h, w), hx (N, H + X, h, w), g of the output's shape -> zr, q, hx of their shapes.
///
/// # Gradient
/// With z = σ(z̃), t = tanh(q̃): d z̃ = g·(t - h)·z(1 - z); d q̃ = g·z·(1 - t²); d h = g·(1 - z);
/// d x = g[H..] with `keep_x`, else 0; d r̃ = 0.
pub fn gru_update_bwd<F: Float>(zr: ArrayViewD<F>, q: ArrayViewD<F>, hx: ArrayViewD<F>, g: ArrayViewD<F>, keep_x: bool) -> Result<GruUpdateGrads<F>> {
    let (zr, q, hx) = (view4(UPDATE, "zr", zr)?, view4(UPDATE, "q", q)?, view4(UPDATE, "hx", hx)?);
    let d = dims(UPDATE, &zr, &hx, Some(&q))?;
    let (hh, ww) = (hx.shape()[2], hx.shape()[3]);
    let k_hx = d.hid + d.x;
    let k_out = if keep_x { k_hx } else { d.hid };
    check_grad(UPDATE, &g, [d.n, k_out, hh, ww])?;
    let (zr, q, hx, g) = (zr.as_standard_layout(), q.as_standard_layout(), hx.as_standard_layout(), g.as_standard_layout());
    let (zs, qs, hs, gs) = (
        zr.as_slice().expect("standard layout"),
        q.as_slice().expect("standard layout"),
        hx.as_slice().expect("standard layout"),
        g.as_slice().expect("standard layout"),
    );
    let mut dzr = zeros(UPDATE, (d.n, 2 * d.hid, hh, ww))?;
    let mut dq = zeros(UPDATE, (d.n, d.hid, hh, ww))?;
    {
        let (dzs, dqs) = (dzr.as_slice_mut().expect("fresh array"), dq.as_slice_mut().expect("fresh array"));
        // image b: dz̃ is the first H planes of dzr[b] (2H planes), dq̃ all H planes of dq[b]
        dzs.par_chunks_mut(2 * d.hid * d.plane).zip(dqs.par_chunks_mut(d.hid * d.plane)).enumerate().for_each(|(b, (dzi, dqi))| {
            dzi[..d.hid * d.plane].par_chunks_mut(d.plane).zip(dqi.par_chunks_mut(d.plane)).enumerate().for_each(|(k, (dz, dqp))| {
                update_dzq_plane(dz, dqp, d.plane(zs, 2 * d.hid, b, k), d.plane(qs, d.hid, b, k), d.plane(hs, k_hx, b, k), d.plane(gs, k_out, b, k));
            });
        });
    }
    let dhx = planes(UPDATE, [d.n, k_hx, hh, ww], |b, k, o| {
        if k < d.hid {
            // d h = g·(1 - z)
            gate_dh_plane(o, d.plane(zs, 2 * d.hid, b, k), d.plane(gs, k_out, b, k), true);
        } else if keep_x {
            o.copy_from_slice(d.plane(gs, k_out, b, k));
        }
    })?;
    Ok(GruUpdateGrads { zr: dzr, q: dq, hx: dhx })
}
