//! The two stereo correlations of MIPNet (architecture.md §2.5, §2.6), fused: products and channel means are
//! computed in one pass, without the views, pads and slices of the PyTorch formulation.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | IP correlation: grouped channel mean of fl · seed stack | `ip_corr_fwd` | `ip_corr_bwd` (fl, stack) |
//! | RLS correlation: channel mean of fl · shifted warped map, (2rx+1)(2ry+1) shifts | `rls_corr_fwd` | `rls_corr_bwd` (fl, warped) |
//!
//! Work is split by (n, row) of the result being written, so every sum runs in a fixed order.

use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array4, ArrayView4, ArrayViewD, ArrayViewMut2, Axis, Ix4};
use rayon::prelude::*;

/// The contiguous row `y` of channel `ch` of batch element `b` in a standard-layout (N, C, h, w) slice.
#[inline(always)]
fn row<F>(s: &[F], c: usize, h: usize, w: usize, b: usize, ch: usize, y: usize) -> &[F] {
    // offset = ((b·C + ch)·h + y)·w
    &s[((b * c + ch) * h + y) * w..][..w]
}

/// Row `k` of a standard-layout (K, w) view.
#[inline(always)]
fn row_mut<'a, F>(v: &'a mut ArrayViewMut2<F>, k: usize) -> &'a mut [F] {
    v.row_mut(k).into_slice().expect("rows of a standard-layout array are contiguous")
}

/// Calls `f(b, y, rows)` for every (n, y) of a standard-layout (N, K, h, w) array, in parallel, where
/// `rows` is the (K, w) view of row y.
fn for_each_row<F: Float>(a: &mut Array4<F>, f: impl Fn(usize, usize, ArrayViewMut2<F>) + Sync) {
    a.axis_iter_mut(Axis(0)).into_par_iter().enumerate().for_each(|(b, mut an)| {
        an.axis_iter_mut(Axis(1)).into_par_iter().enumerate().for_each(|(y, rows)| f(b, y, rows));
    });
}

/// Like [`for_each_row`], over the rows of two arrays of the same (N, ·, h, ·) geometry at once.
fn for_each_row2<F: Float>(a: &mut Array4<F>, c: &mut Array4<F>, f: impl Fn(usize, usize, ArrayViewMut2<F>, ArrayViewMut2<F>) + Sync) {
    a.axis_iter_mut(Axis(0)).into_par_iter().zip(c.axis_iter_mut(Axis(0))).enumerate().for_each(|(b, (mut an, mut cn))| {
        an.axis_iter_mut(Axis(1))
            .into_par_iter()
            .zip(cn.axis_iter_mut(Axis(1)))
            .enumerate()
            .for_each(|(y, (ra, rc))| f(b, y, ra, rc));
    });
}

// ---------------------------------------------------------------------------------------------
// IP correlation
// ---------------------------------------------------------------------------------------------

const IP: &str = "ip_correlation";

/// Channel groups of the IP correlation (MIPNet: 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IpCorrCfg {
    pub groups: usize,
}

/// Sizes of one IP correlation call: batch, feature channels, seeds, channels per group, h, w.
#[derive(Clone, Copy, Debug)]
struct IpDims {
    n: usize,
    c: usize,
    s: usize,
    cg: usize,
    h: usize,
    w: usize,
}

impl IpCorrCfg {
    /// Validates fl (N, C, h, w) against stack (N, S·C, h, w) and derives S and C / G.
    fn dims(&self, fl: &[usize], stack: &[usize]) -> Result<IpDims> {
        let shapes = [("fl", fl), ("stack", stack)];
        check_nonempty(IP, &shapes)?;
        if self.groups == 0 {
            return Err(Error::arg(IP, "groups must be positive"));
        }
        let (n, c, h, w) = (fl[0], fl[1], fl[2], fl[3]);
        if stack[0] != n || stack[2..] != fl[2..] || !stack[1].is_multiple_of(c) {
            return Err(Error::shape(IP, "stack must be (N, S*C, h, w) for fl (N, C, h, w)", &shapes));
        }
        if c % self.groups != 0 {
            return Err(Error::shape(IP, format!("channels C must be divisible by groups={}", self.groups), &shapes));
        }
        Ok(IpDims { n, c, s: stack[1] / c, cg: c / self.groups, h, w })
    }
}

fn ip_inputs<'a, F>(fl: ArrayViewD<'a, F>, stack: ArrayViewD<'a, F>) -> Result<(ArrayView4<'a, F>, ArrayView4<'a, F>)> {
    Ok((fixed::<_, Ix4>(IP, "fl", fl)?, fixed::<_, Ix4>(IP, "stack", stack)?))
}

/// IP correlation: per group g and seed s, the mean over the group's channels of fl · stack.
///
/// # Shapes
/// fl (N, C, h, w), stack (N, S·C, h, w) -> (N, G·S, h, w), with
/// out[S·g + s] = (G/C) Σ_{k < C/G} fl[g·C/G + k] · stack[s·C + g·C/G + k].
///
/// # Gradient
/// fl and stack: see [`ip_corr_bwd`] (each operand gets g times the other, divided by C/G).
///
/// Torch: `(stack.view(N,S,G,C//G,h,w) * fl.view(N,1,G,C//G,h,w)).mean(3).permute(0,2,1,3,4).reshape(N,G*S,h,w)`.
pub fn ip_corr_fwd<F: Float>(fl: ArrayViewD<F>, stack: ArrayViewD<F>, cfg: &IpCorrCfg) -> Result<Array4<F>> {
    let (fl, stack) = ip_inputs(fl, stack)?;
    let d = cfg.dims(fl.shape(), stack.shape())?;
    let (fl, stack) = (fl.as_standard_layout(), stack.as_standard_layout());
    let (fs, ss) = (fl.as_slice().expect("standard layout"), stack.as_slice().expect("standard layout"));
    let inv = F::one() / F::from_usize(d.cg).unwrap_or_else(F::max_value);
    let mut out = zeros(IP, (d.n, cfg.groups * d.s, d.h, d.w))?;
    for_each_row(&mut out, |b, y, mut orow| {
        let mut acc = vec![F::zero(); d.s * d.w];
        for g in 0..cfg.groups {
            acc.fill(F::zero());
            for k in 0..d.cg {
                let ch = g * d.cg + k;
                let f = row(fs, d.c, d.h, d.w, b, ch, y);
                for (s, a) in acc.chunks_mut(d.w).enumerate() {
                    // acc[s] += fl[g·C/G + k] · stack[s·C + g·C/G + k]
                    let st = row(ss, d.s * d.c, d.h, d.w, b, s * d.c + ch, y);
                    a.iter_mut().zip(f).zip(st).for_each(|((a, &f), &st)| *a += f * st);
                }
            }
            for (s, a) in acc.chunks(d.w).enumerate() {
                row_mut(&mut orow, d.s * g + s).iter_mut().zip(a).for_each(|(o, &a)| *o = a * inv);
            }
        }
    });
    Ok(out)
}

/// Gradients of [`ip_corr_fwd`].
#[derive(Debug)]
pub struct IpCorrGrads<F> {
    pub fl: Array4<F>,
    pub stack: Array4<F>,
}

/// Gradients of [`ip_corr_fwd`] with respect to fl and stack.
///
/// # Shapes
/// fl (N, C, h, w), stack (N, S·C, h, w), g (N, G·S, h, w) -> fl (N, C, h, w), stack (N, S·C, h, w).
///
/// # Gradient
/// dfl[g·C/G + k] = (G/C) Σ_s g[S·g + s] · stack[s·C + g·C/G + k];
/// dstack[s·C + g·C/G + k] = (G/C) g[S·g + s] · fl[g·C/G + k].
///
/// Torch: the backward of the view/mul/mean expression of [`ip_corr_fwd`].
pub fn ip_corr_bwd<F: Float>(fl: ArrayViewD<F>, stack: ArrayViewD<F>, g: ArrayViewD<F>, cfg: &IpCorrCfg) -> Result<IpCorrGrads<F>> {
    let (fl, stack) = ip_inputs(fl, stack)?;
    let d = cfg.dims(fl.shape(), stack.shape())?;
    if g.shape() != [d.n, cfg.groups * d.s, d.h, d.w] {
        return Err(Error::shape(IP, "grad_output must be (N, G*S, h, w)", &[
            ("fl", fl.shape()),
            ("stack", stack.shape()),
            ("grad_output", g.shape()),
        ]));
    }
    let (fl, stack, g) = (fl.as_standard_layout(), stack.as_standard_layout(), g.as_standard_layout());
    let (fs, ss, gs) = (
        fl.as_slice().expect("standard layout"),
        stack.as_slice().expect("standard layout"),
        g.as_slice().expect("standard layout"),
    );
    let inv = F::one() / F::from_usize(d.cg).unwrap_or_else(F::max_value);
    let gsz = cfg.groups * d.s;
    let mut dfl = zeros(IP, (d.n, d.c, d.h, d.w))?;
    let mut dstack = zeros(IP, (d.n, d.s * d.c, d.h, d.w))?;
    for_each_row2(&mut dfl, &mut dstack, |b, y, mut dfrow, mut dsrow| {
        for g_ in 0..cfg.groups {
            for k in 0..d.cg {
                let ch = g_ * d.cg + k;
                let f = row(fs, d.c, d.h, d.w, b, ch, y);
                let df = row_mut(&mut dfrow, ch);
                for s in 0..d.s {
                    let go = row(gs, gsz, d.h, d.w, b, d.s * g_ + s, y);
                    let st = row(ss, d.s * d.c, d.h, d.w, b, s * d.c + ch, y);
                    // dfl += g[S·g + s] · stack[s·C + ch] / (C/G)
                    df.iter_mut().zip(go).zip(st).for_each(|((df, &go), &st)| *df += go * inv * st);
                    // dstack[s·C + ch] = g[S·g + s] · fl[ch] / (C/G)
                    row_mut(&mut dsrow, s * d.c + ch).iter_mut().zip(go).zip(f).for_each(|((ds, &go), &f)| *ds = go * inv * f);
                }
            }
        }
    });
    Ok(IpCorrGrads { fl: dfl, stack: dstack })
}

// ---------------------------------------------------------------------------------------------
// RLS correlation
// ---------------------------------------------------------------------------------------------

const RLS: &str = "rls_correlation";

/// Search radii of the RLS correlation (MIPNet: rx = 3, ry = 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RlsCorrCfg {
    pub rx: usize,
    pub ry: usize,
}

impl RlsCorrCfg {
    /// Number of candidates (2rx+1)(2ry+1) = output channels.
    pub fn candidates(&self) -> usize {
        (2 * self.rx + 1) * (2 * self.ry + 1)
    }

    /// Fails if (2rx+1)(2ry+1) overflows.
    fn check(&self) -> Result<()> {
        let side = |r: usize| r.checked_mul(2)?.checked_add(1);
        side(self.rx).zip(side(self.ry)).and_then(|(a, b)| a.checked_mul(b)).map(|_| ()).ok_or_else(|| {
            Error::arg(RLS, format!("search radii rx={} ry={} are too large", self.rx, self.ry))
        })
    }

    /// Output channel of horizontal shift i (outer) and vertical shift j (inner).
    fn chan(&self, i: usize, j: usize) -> usize {
        // k = (2ry+1)·i + j
        (2 * self.ry + 1) * i + j
    }

    /// Source row of output row y for vertical shift j: clamp(y + j - ry, 0, h-1).
    fn src_row(&self, y: usize, j: usize, h: usize) -> usize {
        (y + j).saturating_sub(self.ry).min(h - 1)
    }

    /// Writes the replicate-padded row ext[t] = r[clamp(t - rx, 0, w-1)], t in 0..w+2rx.
    fn extend<F: Float>(&self, r: &[F], ext: &mut [F]) {
        let (w, rx) = (r.len(), self.rx);
        ext[..rx].fill(r[0]);
        ext[rx..rx + w].copy_from_slice(r);
        ext[rx + w..].fill(r[w - 1]);
    }
}

fn rls_inputs<'a, F>(fl: ArrayViewD<'a, F>, warped: ArrayViewD<'a, F>, cfg: &RlsCorrCfg) -> Result<(ArrayView4<'a, F>, ArrayView4<'a, F>)> {
    cfg.check()?;
    let (fl, warped) = (fixed::<_, Ix4>(RLS, "fl", fl)?, fixed::<_, Ix4>(RLS, "warped", warped)?);
    let shapes = [("fl", fl.shape()), ("warped", warped.shape())];
    check_nonempty(RLS, &shapes)?;
    if fl.shape() != warped.shape() {
        return Err(Error::shape(RLS, "fl and warped must have the same shape", &shapes));
    }
    Ok((fl, warped))
}

/// RLS correlation: for each shift (i - rx, j - ry), the channel mean of fl times the replicate-padded
/// warped map shifted by it.
///
/// # Shapes
/// fl (N, C, h, w), warped (N, C, h, w) -> (N, (2rx+1)(2ry+1), h, w), with
/// out[(2ry+1)·i + j, y, x] = (1/C) Σ_c fl[c, y, x] · warped[c, clamp(y + j - ry), clamp(x + i - rx)].
///
/// # Gradient
/// fl and warped: see [`rls_corr_bwd`] (products with g, the warped one scattered back through the clamp).
///
/// Torch: `P = F.pad(warped, [rx, rx, ry, ry], mode='replicate')`, then for i (outer), j (inner):
/// `(fl * P[:, :, j:j+h, i:i+w]).mean(1, keepdim=True)`, concatenated along dim 1.
pub fn rls_corr_fwd<F: Float>(fl: ArrayViewD<F>, warped: ArrayViewD<F>, cfg: &RlsCorrCfg) -> Result<Array4<F>> {
    let (fl, warped) = rls_inputs(fl, warped, cfg)?;
    let (n, c, h, w) = fl.dim();
    let (fl, warped) = (fl.as_standard_layout(), warped.as_standard_layout());
    let (fs, ws) = (fl.as_slice().expect("standard layout"), warped.as_slice().expect("standard layout"));
    let inv = F::one() / F::from_usize(c).unwrap_or_else(F::max_value);
    let mut out = zeros(RLS, (n, cfg.candidates(), h, w))?;
    for_each_row(&mut out, |b, y, mut orow| {
        let mut ext = vec![F::zero(); w + 2 * cfg.rx];
        for j in 0..2 * cfg.ry + 1 {
            let yy = cfg.src_row(y, j, h);
            for ch in 0..c {
                let f = row(fs, c, h, w, b, ch, y);
                cfg.extend(row(ws, c, h, w, b, ch, yy), &mut ext);
                for i in 0..2 * cfg.rx + 1 {
                    // out[k(i, j), x] += fl[x] · warped[yy, clamp(x + i - rx)] = fl[x] · ext[x + i]
                    let o = row_mut(&mut orow, cfg.chan(i, j));
                    o.iter_mut().zip(f).zip(&ext[i..]).for_each(|((o, &f), &e)| *o += f * e);
                }
            }
        }
        orow.mapv_inplace(|v| v * inv);
    });
    Ok(out)
}

/// Gradients of [`rls_corr_fwd`].
#[derive(Debug)]
pub struct RlsCorrGrads<F> {
    pub fl: Array4<F>,
    pub warped: Array4<F>,
}

/// Gradients of [`rls_corr_fwd`] with respect to fl and warped.
///
/// # Shapes
/// fl, warped (N, C, h, w), g (N, (2rx+1)(2ry+1), h, w) -> fl, warped (N, C, h, w).
///
/// # Gradient
/// dfl[c, y, x] = (1/C) Σ_{i,j} g[k(i,j), y, x] · warped[c, clamp(y+j-ry), clamp(x+i-rx)];
/// dwarped[c, y', x'] = (1/C) Σ g[k(i,j), y, x] · fl[c, y, x] over every (i, j, y, x) whose clamped source
/// is (y', x') (edge pixels collect the replicated border), gathered per output row in a fixed order.
///
/// Torch: the backward of the pad/slice/mul/mean loop of [`rls_corr_fwd`].
pub fn rls_corr_bwd<F: Float>(fl: ArrayViewD<F>, warped: ArrayViewD<F>, g: ArrayViewD<F>, cfg: &RlsCorrCfg) -> Result<RlsCorrGrads<F>> {
    let (fl, warped) = rls_inputs(fl, warped, cfg)?;
    let (n, c, h, w) = fl.dim();
    let k = cfg.candidates();
    if g.shape() != [n, k, h, w] {
        return Err(Error::shape(RLS, format!("grad_output must be (N, {k}, h, w)"), &[
            ("fl", fl.shape()),
            ("warped", warped.shape()),
            ("grad_output", g.shape()),
        ]));
    }
    let (fl, warped, g) = (fl.as_standard_layout(), warped.as_standard_layout(), g.as_standard_layout());
    let (fs, ws, gs) = (
        fl.as_slice().expect("standard layout"),
        warped.as_slice().expect("standard layout"),
        g.as_slice().expect("standard layout"),
    );
    let inv = F::one() / F::from_usize(c).unwrap_or_else(F::max_value);
    let (nx, ny, rx) = (2 * cfg.rx + 1, 2 * cfg.ry + 1, cfg.rx);
    let mut dfl = zeros(RLS, (n, c, h, w))?;
    for_each_row(&mut dfl, |b, y, mut drow| {
        let mut ext = vec![F::zero(); w + 2 * rx];
        for ch in 0..c {
            let d = row_mut(&mut drow, ch);
            for j in 0..ny {
                cfg.extend(row(ws, c, h, w, b, ch, cfg.src_row(y, j, h)), &mut ext);
                for i in 0..nx {
                    // dfl[x] += g[k(i, j), x] · ext[x + i]
                    let go = row(gs, k, h, w, b, cfg.chan(i, j), y);
                    d.iter_mut().zip(go).zip(&ext[i..]).for_each(|((d, &go), &e)| *d += go * e);
                }
            }
            d.iter_mut().for_each(|v| *v *= inv);
        }
    });
    let mut dwarped = zeros(RLS, (n, c, h, w))?;
    for_each_row(&mut dwarped, |b, yt, mut drow| {
        // the (y, j) whose clamped source row is yt
        let sources: Vec<(usize, usize)> = (0..h).flat_map(|y| (0..ny).map(move |j| (y, j))).filter(|&(y, j)| cfg.src_row(y, j, h) == yt).collect();
        let mut ext = vec![F::zero(); w + 2 * rx];
        for ch in 0..c {
            ext.fill(F::zero());
            for &(y, j) in &sources {
                let f = row(fs, c, h, w, b, ch, y);
                for i in 0..nx {
                    // ext[x + i] += g[k(i, j), y, x] · fl[y, x]   (ext index t <-> source column t - rx)
                    let go = row(gs, k, h, w, b, cfg.chan(i, j), y);
                    ext[i..].iter_mut().zip(go).zip(f).for_each(|((e, &go), &f)| *e += go * f);
                }
            }
            // fold the padded row back: columns t < rx clamp to 0, t >= w + rx clamp to w - 1
            let d = row_mut(&mut drow, ch);
            d.copy_from_slice(&ext[rx..rx + w]);
            d[0] += ext[..rx].iter().fold(F::zero(), |a, &v| a + v);
            d[w - 1] += ext[rx + w..].iter().fold(F::zero(), |a, &v| a + v);
            d.iter_mut().for_each(|v| *v *= inv);
        }
    });
    Ok(RlsCorrGrads { fl: dfl, warped: dwarped })
}
