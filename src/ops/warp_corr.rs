//! The IP and RLS correlations fused with their warp, for a flow with zero vertical component
//! (MIPNet's vertical constraint, architecture.md §2.3): the warp is then a 1-D horizontal interpolation, so warp,
//! products and channel means become one pass per pixel and the warped maps (the 1280-channel seed
//! stack of the IP block, the 256-channel warped map of the RLS block) are never stored.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | IP: grouped channel mean of F_L · W(S_s(F_R), f) for each seed s | `ip_warp_corr_fwd` | `ip_warp_corr_bwd` (fl, fr) |
//! | RLS: channel mean of F_L · W(F_R, f) at each shift of a (2rx+1)x(2ry+1) window | `rls_warp_corr_fwd` | `rls_warp_corr_bwd` (fl, fr) |
//!
//! Features are channels-last (N, h, w, C), so every product is a contiguous dot product over channels;
//! outputs and their gradients are (N, K, h, w). The flow is f_x (N, h, w), in pixels of the level:
//! pixel (y, x) samples row y at X = clamp(x + f_x, 0, w-1) (border padding, align_corners=True),
//! W(F)(y, x) = (1-a)·F(y, x0) + a·F(y, x1) with x0 = floor(X), x1 = min(x0+1, w-1), a = X - x0.
//! The flow gets no gradient (it is detached in MIPNet, architecture.md §2.9).
//!
//! Work is split by output rows (forward, d fl) and by rows of d fr, each owned by one task that sums
//! in a fixed order, so results are deterministic and independent of the thread count.

use super::lanes::{axpy, dot, multiversion};
use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array4, ArrayView3, ArrayView4, ArrayViewD, ArrayViewMut3, Axis, Ix3, Ix4};
use rayon::prelude::*;

const IP: &str = "ip_warp_correlation";
const RLS: &str = "rls_warp_correlation";

/// MIPNet's IP seeds (ox, oy) in stack order (architecture.md §2.5): centre, tl, tr, dl, dr.
pub const IP_SEEDS: [(isize, isize); 5] = [(0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1)];

/// `v` clamped to the indices 0..n-1.
#[inline(always)]
fn clampi(v: isize, n: usize) -> usize {
    v.clamp(0, n as isize - 1) as usize
}

/// The horizontal bilinear footprint of one pixel's warp.
#[derive(Clone, Copy, Debug)]
struct Tap<F> {
    x0: usize,
    x1: usize,
    a: F,
}

/// The validated operands of one call, as flat standard-layout slices.
struct Geo<'a, F> {
    n: usize,
    h: usize,
    w: usize,
    c: usize,
    fl: &'a [F],
    fr: &'a [F],
    fx: &'a [F],
}

impl<'a, F: Float> Geo<'a, F> {
    /// The C channels of pixel (b, y, x) of a channels-last map.
    #[inline(always)]
    fn pix(&self, m: &'a [F], b: usize, y: usize, x: usize) -> &'a [F] {
        // offset = ((b·h + y)·w + x)·C
        &m[((b * self.h + y) * self.w + x) * self.c..][..self.c]
    }

    /// The warp footprint of pixel (b, y, x).
    #[inline(always)]
    fn tap(&self, b: usize, y: usize, x: usize) -> Tap<F> {
        let wmax = F::from_usize(self.w - 1).unwrap_or_else(F::max_value);
        // X = clamp(x + f_x(b, y, x), 0, w - 1), f_x at offset (b·h + y)·w + x
        let xs = (F::from_usize(x).unwrap_or_else(F::max_value) + self.fx[(b * self.h + y) * self.w + x]).max(F::zero()).min(wmax);
        let x0f = xs.floor();
        let x0 = x0f.to_usize().unwrap_or(0).min(self.w - 1);
        Tap { x0, x1: (x0 + 1).min(self.w - 1), a: xs - x0f }
    }

    /// Rows per task of the row-split loops: about 4 tasks per thread over the whole batch.
    fn band(&self) -> usize {
        let per_image = (4 * rayon::current_num_threads()).div_ceil(self.n).max(1);
        self.h.div_ceil(per_image).max(1)
    }
}

/// Checks fl, fr (N, h, w, C) and f_x (N, h, w) (same sizes, non-empty, finite flow) and runs `f`
/// on their standard-layout slices.
fn with_geo<F: Float, T>(op: &'static str, fl: ArrayViewD<F>, fr: ArrayViewD<F>, fx: ArrayViewD<F>,
                         f: impl FnOnce(&Geo<'_, F>) -> Result<T>) -> Result<T> {
    let (fl, fr): (ArrayView4<F>, ArrayView4<F>) = (fixed::<_, Ix4>(op, "fl", fl)?, fixed::<_, Ix4>(op, "fr", fr)?);
    let fx: ArrayView3<F> = fixed::<_, Ix3>(op, "flow_x", fx)?;
    let shapes = [("fl", fl.shape()), ("fr", fr.shape()), ("flow_x", fx.shape())];
    check_nonempty(op, &shapes)?;
    if fl.shape() != fr.shape() || fx.shape() != &fl.shape()[..3] {
        return Err(Error::shape(op, "fl and fr must be (N, h, w, C) and flow_x (N, h, w)", &shapes));
    }
    if fx.iter().any(|v| !v.is_finite()) {
        return Err(Error::value(op, format!("flow_x contains NaN or infinite values (shape {:?})", fx.shape())));
    }
    let (n, h, w, c) = fl.dim();
    let (fl, fr, fx) = (fl.as_standard_layout(), fr.as_standard_layout(), fx.as_standard_layout());
    let geo = Geo {
        n, h, w, c,
        fl: fl.as_slice().expect("standard layout"),
        fr: fr.as_slice().expect("standard layout"),
        fx: fx.as_slice().expect("standard layout"),
    };
    f(&geo)
}

/// Fails unless the output gradient is (N, K, h, w).
fn check_grad<F: Float>(op: &'static str, g: &ArrayViewD<F>, geo: &Geo<'_, F>, k: usize) -> Result<()> {
    if g.shape() != [geo.n, k, geo.h, geo.w] {
        return Err(Error::shape(op, format!("grad_output must be (N, {k}, h, w) for fl (N, h, w, C)"), &[
            ("fl", &[geo.n, geo.h, geo.w, geo.c]),
            ("grad_output", g.shape()),
        ]));
    }
    Ok(())
}

/// Runs `f(b, y0, band)` over bands of output rows of an (N, K, h, w) array, in parallel; `band` is
/// the (K, rows, w) view of rows y0.. of image b.
fn for_each_band<F: Float>(out: &mut Array4<F>, rows: usize, f: impl Fn(usize, usize, ArrayViewMut3<F>) + Sync) {
    out.axis_iter_mut(Axis(0)).into_par_iter().enumerate().for_each(|(b, mut img)| {
        img.axis_chunks_iter_mut(Axis(1), rows).into_par_iter().enumerate().for_each(|(k, band)| f(b, k * rows, band));
    });
}

/// Runs `f(b, y0, band)` over bands of rows of a channels-last (N, h, w, C) array, in parallel;
/// `band` is the contiguous slice of rows y0.. of image b.
fn for_each_band_nhwc<F: Float>(a: &mut Array4<F>, rows: usize, f: impl Fn(usize, usize, &mut [F]) + Sync) {
    let (_, h, w, c) = a.dim();
    let s = a.as_slice_mut().expect("fresh array");
    s.par_chunks_mut(h * w * c).enumerate().for_each(|(b, img)| {
        img.par_chunks_mut(rows * w * c).enumerate().for_each(|(k, band)| f(b, k * rows, band));
    });
}

// ---------------------------------------------------------------------------------------------
// IP
// ---------------------------------------------------------------------------------------------

/// Channel groups and seed offsets of the fused IP correlation (MIPNet: 2 groups, [`IP_SEEDS`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IpWarpCfg {
    pub groups: usize,
    pub seeds: Vec<(isize, isize)>,
}

impl IpWarpCfg {
    /// Output channels G·S.
    pub fn channels(&self) -> usize {
        self.groups * self.seeds.len()
    }

    fn check<F>(&self, geo: &Geo<'_, F>) -> Result<()> {
        if self.groups == 0 || self.seeds.is_empty() {
            return Err(Error::arg(IP, format!("groups and the seed list must be non-empty, got groups={} and {} seeds",
                                              self.groups, self.seeds.len())));
        }
        if geo.c % self.groups != 0 {
            return Err(Error::shape(IP, format!("channels C must be divisible by groups={}", self.groups),
                                    &[("fl", &[geo.n, geo.h, geo.w, geo.c])]));
        }
        Ok(())
    }

    /// Row and columns of F_R that seed `s` reads for output row y and footprint t:
    /// S_s(y, x) = F_R(clamp(y + oy), clamp(x + ox)).
    #[inline(always)]
    fn seed_taps<F>(&self, s: usize, y: usize, t: &Tap<F>, h: usize, w: usize) -> (usize, usize, usize) {
        let (ox, oy) = self.seeds[s];
        (clampi(y as isize + oy, h), clampi(t.x0 as isize + ox, w), clampi(t.x1 as isize + ox, w))
    }
}

multiversion! {
    /// One band of the IP forward: out[S·g + s, y, x] = ((1-a)·<fl_g, F_R,g(ys, c0)> + a·<fl_g, F_R,g(ys, c1)>) / (C/G).
    fn ip_fwd_band<F: Float>(geo: &Geo<'_, F>, cfg: &IpWarpCfg, b: usize, y0: usize, out: &mut ArrayViewMut3<'_, F>) {
        let (s_n, cg) = (cfg.seeds.len(), geo.c / cfg.groups);
        let inv = F::one() / F::from_usize(cg).unwrap_or_else(F::max_value);
        for yy in 0..out.shape()[1] {
            let y = y0 + yy;
            for x in 0..geo.w {
                let t = geo.tap(b, y, x);
                let f = geo.pix(geo.fl, b, y, x);
                for s in 0..s_n {
                    let (ys, c0, c1) = cfg.seed_taps(s, y, &t, geo.h, geo.w);
                    let (r0, r1) = (geo.pix(geo.fr, b, ys, c0), geo.pix(geo.fr, b, ys, c1));
                    for g in 0..cfg.groups {
                        // channels of group g: g·C/G .. (g+1)·C/G
                        let ch = g * cg..(g + 1) * cg;
                        let (d0, d1) = (dot(&f[ch.clone()], &r0[ch.clone()]), dot(&f[ch.clone()], &r1[ch]));
                        out[[s_n * g + s, yy, x]] = ((F::one() - t.a) * d0 + t.a * d1) * inv;
                    }
                }
            }
        }
    }
}

/// IP correlation of the warped seed stack, fused (architecture.md §2.5 with the horizontal warp of §2.3).
///
/// # Shapes
/// fl, fr (N, h, w, C) channels-last, flow_x (N, h, w) -> (N, G·S, h, w), with
/// out[S·g + s, y, x] = (G/C) Σ_{k < C/G} fl[y, x, g·C/G + k] · W(S_s)(y, x)[g·C/G + k]
/// and S_s(y, x) = fr(clamp(y + oy_s), clamp(x + ox_s)).
///
/// # Gradient
/// fl and fr: see [`ip_warp_corr_bwd`]; flow_x gets none.
///
/// Torch: `ip_correlation(fl_nchw, F.grid_sample(build_ip_stack(fr_nchw), grid(flow), 'bilinear', 'border',
/// align_corners=True))` with `flow[:, 1] = 0` (tests_py/reference).
pub fn ip_warp_corr_fwd<F: Float>(fl: ArrayViewD<F>, fr: ArrayViewD<F>, flow_x: ArrayViewD<F>, cfg: &IpWarpCfg) -> Result<Array4<F>> {
    with_geo(IP, fl, fr, flow_x, |geo| {
        cfg.check(geo)?;
        let mut out = zeros(IP, (geo.n, cfg.channels(), geo.h, geo.w))?;
        for_each_band(&mut out, geo.band(), |b, y0, mut band| ip_fwd_band(geo, cfg, b, y0, &mut band));
        Ok(out)
    })
}

/// Gradients of the fused correlations with respect to fl and fr (both channels-last).
#[derive(Debug)]
pub struct WarpCorrGrads<F> {
    pub fl: Array4<F>,
    pub fr: Array4<F>,
}

multiversion! {
    /// One band of IP d fl: dfl[y, x, group g] += Σ_s u0·F_R,g(ys, c0) + u1·F_R,g(ys, c1), u = g_out·(1-a, a)/(C/G).
    fn ip_bwd_fl_band<F: Float>(geo: &Geo<'_, F>, cfg: &IpWarpCfg, gs: &[F], b: usize, y0: usize, band: &mut [F]) {
        let (s_n, cg, k) = (cfg.seeds.len(), geo.c / cfg.groups, cfg.channels());
        let inv = F::one() / F::from_usize(cg).unwrap_or_else(F::max_value);
        for (p, d) in band.chunks_exact_mut(geo.c).enumerate() {
            let (y, x) = (y0 + p / geo.w, p % geo.w);
            let t = geo.tap(b, y, x);
            for s in 0..s_n {
                let (ys, c0, c1) = cfg.seed_taps(s, y, &t, geo.h, geo.w);
                let (r0, r1) = (geo.pix(geo.fr, b, ys, c0), geo.pix(geo.fr, b, ys, c1));
                for g in 0..cfg.groups {
                    // g_out[b, S·g + s, y, x] at ((b·K + S·g + s)·h + y)·w + x
                    let go = gs[((b * k + s_n * g + s) * geo.h + y) * geo.w + x] * inv;
                    let ch = g * cg..(g + 1) * cg;
                    axpy(go * (F::one() - t.a), &r0[ch.clone()], &mut d[ch.clone()]);
                    axpy(go * t.a, &r1[ch.clone()], &mut d[ch]);
                }
            }
        }
    }
}

multiversion! {
    /// Row yt of IP d fr: every (y, s) whose seed row clamp(y + oy_s) is yt scatters u0·fl(y, x) to
    /// column c0 and u1·fl(y, x) to c1 (sources in (y, s, x) order).
    fn ip_bwd_fr_row<F: Float>(geo: &Geo<'_, F>, cfg: &IpWarpCfg, gs: &[F], b: usize, yt: usize, row: &mut [F]) {
        let (s_n, cg, k) = (cfg.seeds.len(), geo.c / cfg.groups, cfg.channels());
        let inv = F::one() / F::from_usize(cg).unwrap_or_else(F::max_value);
        for y in 0..geo.h {
            for s in 0..s_n {
                if clampi(y as isize + cfg.seeds[s].1, geo.h) != yt {
                    continue;
                }
                for x in 0..geo.w {
                    let t = geo.tap(b, y, x);
                    let (_, c0, c1) = cfg.seed_taps(s, y, &t, geo.h, geo.w);
                    let f = geo.pix(geo.fl, b, y, x);
                    for g in 0..cfg.groups {
                        // g_out[b, S·g + s, y, x]
                        let go = gs[((b * k + s_n * g + s) * geo.h + y) * geo.w + x] * inv;
                        let ch = g * cg..(g + 1) * cg;
                        // dfr(yt, c, group g) at c·C + g·C/G
                        axpy(go * (F::one() - t.a), &f[ch.clone()], &mut row[c0 * geo.c + g * cg..][..cg]);
                        axpy(go * t.a, &f[ch], &mut row[c1 * geo.c + g * cg..][..cg]);
                    }
                }
            }
        }
    }
}

/// Gradients of [`ip_warp_corr_fwd`] with respect to fl and fr.
///
/// # Shapes
/// fl, fr (N, h, w, C), flow_x (N, h, w), g (N, G·S, h, w) -> fl, fr (N, h, w, C).
///
/// # Gradient
/// With u_s = g[S·g + s, y, x] · (G/C) and the footprint (x0, x1, a) of (y, x):
/// dfl[y, x, g·C/G + k] = Σ_s u_s · ((1-a)·fr(ys, c0) + a·fr(ys, c1))[g·C/G + k];
/// dfr(ys, c0) += u_s (1-a) fl[y, x], dfr(ys, c1) += u_s a fl[y, x] (group g's channels), with
/// ys = clamp(y + oy_s), c0 = clamp(x0 + ox_s), c1 = clamp(x1 + ox_s).
///
/// Torch: the backward of the expression of [`ip_warp_corr_fwd`] with respect to fl and fr.
pub fn ip_warp_corr_bwd<F: Float>(fl: ArrayViewD<F>, fr: ArrayViewD<F>, flow_x: ArrayViewD<F>, g: ArrayViewD<F>,
                                  cfg: &IpWarpCfg) -> Result<WarpCorrGrads<F>> {
    with_geo(IP, fl, fr, flow_x, |geo| {
        cfg.check(geo)?;
        check_grad(IP, &g, geo, cfg.channels())?;
        let g = g.as_standard_layout();
        let gs = g.as_slice().expect("standard layout");
        let mut dfl = zeros(IP, (geo.n, geo.h, geo.w, geo.c))?;
        for_each_band_nhwc(&mut dfl, geo.band(), |b, y0, band| ip_bwd_fl_band(geo, cfg, gs, b, y0, band));
        let mut dfr = zeros(IP, (geo.n, geo.h, geo.w, geo.c))?;
        for_each_band_nhwc(&mut dfr, 1, |b, y, row| ip_bwd_fr_row(geo, cfg, gs, b, y, row));
        Ok(WarpCorrGrads { fl: dfl, fr: dfr })
    })
}

// ---------------------------------------------------------------------------------------------
// RLS
// ---------------------------------------------------------------------------------------------

/// Search radii of the fused RLS correlation (MIPNet: rx = 3, ry = 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RlsWarpCfg {
    pub rx: usize,
    pub ry: usize,
}

impl RlsWarpCfg {
    /// Output channels (2rx+1)(2ry+1), or an error if that overflows.
    pub fn channels(&self) -> Result<usize> {
        let side = |r: usize| r.checked_mul(2)?.checked_add(1);
        side(self.rx).zip(side(self.ry)).and_then(|(a, b)| a.checked_mul(b)).ok_or_else(|| {
            Error::arg(RLS, format!("search radii rx={} ry={} are too large", self.rx, self.ry))
        })
    }

    /// Source row of output row y for vertical shift j: clamp(y + j - ry, 0, h-1).
    #[inline(always)]
    fn src_row(&self, y: usize, j: usize, h: usize) -> usize {
        clampi(y as isize + j as isize - self.ry as isize, h)
    }

    /// Source column of output column x for horizontal shift i: clamp(x + i - rx, 0, w-1).
    #[inline(always)]
    fn src_col(&self, x: usize, i: usize, w: usize) -> usize {
        clampi(x as isize + i as isize - self.rx as isize, w)
    }
}

/// The rows of the warped map W(F_R) a band of output rows needs, computed once each: row yq lives
/// in slot yq mod (2ry+1), which is distinct for the 2ry+1 consecutive rows of a window.
struct WarpedRows<F> {
    data: Vec<F>,
    rows: Vec<Option<usize>>,
    len: usize,
}

impl<F: Float> WarpedRows<F> {
    fn new(ry: usize, w: usize, c: usize) -> Self {
        let slots = 2 * ry + 1;
        WarpedRows { data: vec![F::zero(); slots * w * c], rows: vec![None; slots], len: w * c }
    }

    /// W(F_R)(b, yq, ·), channels-last (w, C), warped now unless it already is.
    #[inline(always)]
    fn get(&mut self, geo: &Geo<'_, F>, b: usize, yq: usize) -> &[F] {
        let slot = yq % self.rows.len();
        let dst = &mut self.data[slot * self.len..][..self.len];
        if self.rows[slot] != Some(yq) {
            for (x, d) in dst.chunks_exact_mut(geo.c).enumerate() {
                let t = geo.tap(b, yq, x);
                let (r0, r1) = (geo.pix(geo.fr, b, yq, t.x0), geo.pix(geo.fr, b, yq, t.x1));
                // W(F_R)(yq, x) = (1-a)·F_R(yq, x0) + a·F_R(yq, x1)
                d.iter_mut().zip(r0).zip(r1).for_each(|((d, &v0), &v1)| *d = (F::one() - t.a) * v0 + t.a * v1);
            }
            self.rows[slot] = Some(yq);
        }
        &self.data[slot * self.len..][..self.len]
    }
}

multiversion! {
    /// One band of the RLS forward: out[(2ry+1)·i + j, y, x] = <fl(y, x), W(F_R)(src_row, src_col)> / C.
    fn rls_fwd_band<F: Float>(geo: &Geo<'_, F>, cfg: &RlsWarpCfg, b: usize, y0: usize, out: &mut ArrayViewMut3<'_, F>) {
        let (nx, ny, c) = (2 * cfg.rx + 1, 2 * cfg.ry + 1, geo.c);
        let inv = F::one() / F::from_usize(c).unwrap_or_else(F::max_value);
        let mut warped = WarpedRows::new(cfg.ry, geo.w, c);
        for yy in 0..out.shape()[1] {
            let y = y0 + yy;
            for j in 0..ny {
                let wrow = warped.get(geo, b, cfg.src_row(y, j, geo.h));
                for x in 0..geo.w {
                    let f = geo.pix(geo.fl, b, y, x);
                    for i in 0..nx {
                        // candidate (i, j) reads W(F_R) at column clamp(x + i - rx): offset col·C
                        let q = &wrow[cfg.src_col(x, i, geo.w) * c..][..c];
                        out[[ny * i + j, yy, x]] = dot(f, q) * inv;
                    }
                }
            }
        }
    }
}

/// RLS correlation of the warped right features, fused (architecture.md §2.6 with the horizontal warp of §2.3).
///
/// # Shapes
/// fl, fr (N, h, w, C) channels-last, flow_x (N, h, w) -> (N, (2rx+1)(2ry+1), h, w), with
/// out[(2ry+1)·i + j, y, x] = (1/C) Σ_c fl[y, x, c] · W(fr)[clamp(y + j - ry), clamp(x + i - rx), c].
///
/// # Gradient
/// fl and fr: see [`rls_warp_corr_bwd`]; flow_x gets none.
///
/// Torch: `rls_correlation(fl_nchw, F.grid_sample(fr_nchw, grid(flow), 'bilinear', 'border', align_corners=True), rx, ry)`
/// with `flow[:, 1] = 0` (tests_py/reference).
pub fn rls_warp_corr_fwd<F: Float>(fl: ArrayViewD<F>, fr: ArrayViewD<F>, flow_x: ArrayViewD<F>, cfg: &RlsWarpCfg) -> Result<Array4<F>> {
    let k = cfg.channels()?;
    with_geo(RLS, fl, fr, flow_x, |geo| {
        let mut out = zeros(RLS, (geo.n, k, geo.h, geo.w))?;
        for_each_band(&mut out, geo.band(), |b, y0, mut band| rls_fwd_band(geo, cfg, b, y0, &mut band));
        Ok(out)
    })
}

multiversion! {
    /// One band of RLS d fl: dfl[y, x] = Σ_{i,j} g[(2ry+1)·i + j, y, x] / C · W(F_R)(src_row, src_col).
    fn rls_bwd_fl_band<F: Float>(geo: &Geo<'_, F>, cfg: &RlsWarpCfg, gs: &[F], b: usize, y0: usize, band: &mut [F]) {
        let (nx, ny, c) = (2 * cfg.rx + 1, 2 * cfg.ry + 1, geo.c);
        let k = nx * ny;
        let inv = F::one() / F::from_usize(c).unwrap_or_else(F::max_value);
        let mut warped = WarpedRows::new(cfg.ry, geo.w, c);
        for (r, drow) in band.chunks_exact_mut(geo.w * c).enumerate() {
            let y = y0 + r;
            for j in 0..ny {
                let wrow = warped.get(geo, b, cfg.src_row(y, j, geo.h));
                for (x, d) in drow.chunks_exact_mut(c).enumerate() {
                    for i in 0..nx {
                        // g_out[b, (2ry+1)·i + j, y, x] at ((b·K + ny·i + j)·h + y)·w + x
                        let go = gs[((b * k + ny * i + j) * geo.h + y) * geo.w + x] * inv;
                        axpy(go, &wrow[cfg.src_col(x, i, geo.w) * c..][..c], d);
                    }
                }
            }
        }
    }
}

multiversion! {
    /// Row yq of RLS d fr: dW(yq, xq) = Σ g/C · fl(y, x) over the (y, j, x, i) reading (yq, xq), in that
    /// order; then dfr(yq, x0) += (1-a)·dW(yq, xq), dfr(yq, x1) += a·dW(yq, xq) for xq in order.
    fn rls_bwd_fr_row<F: Float>(geo: &Geo<'_, F>, cfg: &RlsWarpCfg, gs: &[F], b: usize, yq: usize, row: &mut [F]) {
        let (nx, ny, c) = (2 * cfg.rx + 1, 2 * cfg.ry + 1, geo.c);
        let k = nx * ny;
        let inv = F::one() / F::from_usize(c).unwrap_or_else(F::max_value);
        let mut dw = vec![F::zero(); geo.w * c];
        for y in 0..geo.h {
            for j in 0..ny {
                if cfg.src_row(y, j, geo.h) != yq {
                    continue;
                }
                for x in 0..geo.w {
                    let f = geo.pix(geo.fl, b, y, x);
                    for i in 0..nx {
                        // g_out[b, (2ry+1)·i + j, y, x]
                        let go = gs[((b * k + ny * i + j) * geo.h + y) * geo.w + x] * inv;
                        axpy(go, f, &mut dw[cfg.src_col(x, i, geo.w) * c..][..c]);
                    }
                }
            }
        }
        for (xq, d) in dw.chunks_exact(c).enumerate() {
            let t = geo.tap(b, yq, xq);
            // the warp's adjoint: W(yq, xq) = (1-a)·F_R(yq, x0) + a·F_R(yq, x1)
            axpy(F::one() - t.a, d, &mut row[t.x0 * c..][..c]);
            axpy(t.a, d, &mut row[t.x1 * c..][..c]);
        }
    }
}

/// Gradients of [`rls_warp_corr_fwd`] with respect to fl and fr.
///
/// # Shapes
/// fl, fr (N, h, w, C), flow_x (N, h, w), g (N, (2rx+1)(2ry+1), h, w) -> fl, fr (N, h, w, C).
///
/// # Gradient
/// With q_ij(y, x) = (clamp(y + j - ry), clamp(x + i - rx)) and u = g[(2ry+1)·i + j, y, x] / C:
/// dfl[y, x] = Σ_{i,j} u · W(fr)(q_ij); dW(q) = Σ_{(y, x, i, j): q_ij(y, x) = q} u · fl[y, x];
/// dfr(yq, x0_q) += (1-a_q)·dW(q), dfr(yq, x1_q) += a_q·dW(q) (the warp's adjoint, row by row).
///
/// Torch: the backward of the expression of [`rls_warp_corr_fwd`] with respect to fl and fr.
pub fn rls_warp_corr_bwd<F: Float>(fl: ArrayViewD<F>, fr: ArrayViewD<F>, flow_x: ArrayViewD<F>, g: ArrayViewD<F>,
                                   cfg: &RlsWarpCfg) -> Result<WarpCorrGrads<F>> {
    let k = cfg.channels()?;
    with_geo(RLS, fl, fr, flow_x, |geo| {
        check_grad(RLS, &g, geo, k)?;
        let g = g.as_standard_layout();
        let gs = g.as_slice().expect("standard layout");
        let mut dfl = zeros(RLS, (geo.n, geo.h, geo.w, geo.c))?;
        for_each_band_nhwc(&mut dfl, geo.band(), |b, y0, band| rls_bwd_fl_band(geo, cfg, gs, b, y0, band));
        let mut dfr = zeros(RLS, (geo.n, geo.h, geo.w, geo.c))?;
        for_each_band_nhwc(&mut dfr, 1, |b, y, row| rls_bwd_fr_row(geo, cfg, gs, b, y, row));
        Ok(WarpCorrGrads { fl: dfl, fr: dfr })
    })
}
