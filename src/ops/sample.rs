//! Resampling: bilinear grid sampling (the warp), bilinear resizing, and unfold / fold (im2col / col2im).
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | grid_sample, bilinear, zeros / border, align_corners | `grid_sample_fwd` | `grid_sample_bwd` (input, grid) |
//! | interpolate, bilinear, align_corners | `interpolate_bilinear_fwd` | `interpolate_bilinear_bwd` (input) |
//! | unfold (sliding blocks -> columns) | `unfold_fwd` | `fold_fwd` (the adjoint) |
//! | fold (columns -> summed blocks) | `fold_fwd` | `unfold_fwd` (the adjoint) |
//!
//! Every scatter-style backward owns whole (n, c) planes of its result, so sums run in a fixed order
//! and results do not depend on the thread count.

use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array3, Array4, ArrayView4, ArrayViewD, Ix3, Ix4};
use rayon::prelude::*;

// ---------------------------------------------------------------------------------------------
// grid_sample
// ---------------------------------------------------------------------------------------------

const GS: &str = "grid_sample";

/// How grid_sample treats points outside the input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridPadding {
    /// Corners outside the input read as 0.
    Zeros,
    /// Coordinates are clamped to the input (no gradient to the grid where clamped).
    Border,
}

impl GridPadding {
    /// Parses torch's `padding_mode`: "zeros" | "border".
    pub fn parse(name: &str) -> Result<GridPadding> {
        match name {
            "zeros" => Ok(GridPadding::Zeros),
            "border" => Ok(GridPadding::Border),
            other => Err(Error::arg(GS, format!("unsupported padding_mode {other:?} (expected \"zeros\" or \"border\")"))),
        }
    }
}

/// Options of bilinear grid sampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridSampleCfg {
    pub padding: GridPadding,
    pub align_corners: bool,
}

/// One grid point's bilinear footprint in an input plane of width `w`.
#[derive(Clone, Copy, Debug, Default)]
struct Tap<F> {
    /// Flat index y0 * w + x0 of the north-west corner (wrapping arithmetic; read only for inside corners).
    base: usize,
    /// Weights of the nw, ne, sw, se corners.
    wt: [F; 4],
    /// Bit k set when corner k lies inside the plane.
    inside: u8,
}

/// What the grid gradient needs beyond the tap.
#[derive(Clone, Copy, Debug, Default)]
struct Slope<F> {
    /// Fractional offsets (x - x0, y - y0).
    frac: [F; 2],
    /// d(pixel coordinate)/d(grid value) per axis, 0 where border clamping is active.
    mult: [F; 2],
}

const ALL_INSIDE: u8 = 0b1111;

/// Maps normalised coordinates of one axis to pixel coordinates, as torch's CPU kernel does.
#[derive(Clone, Copy)]
struct Axis1<F> {
    size: usize,
    scale: F,
    shift: F,
    max: F,
    border: bool,
}

impl<F: Float> Axis1<F> {
    fn new(size: usize, cfg: &GridSampleCfg) -> Self {
        let s = F::from_usize(size).unwrap_or_else(F::max_value);
        // align_corners: x = (u + 1)·(size-1)/2; otherwise x = (u + 1)·size/2 - 1/2
        let (scale, shift) = if cfg.align_corners { ((s - F::one()) / F::c(2.0), F::zero()) } else { (s / F::c(2.0), F::c(0.5)) };
        Axis1 { size, scale, shift, max: s - F::one(), border: cfg.padding == GridPadding::Border }
    }

    /// (pixel coordinate, d coordinate / d u) of the normalised coordinate u.
    fn locate(&self, u: F) -> (F, F) {
        let x = (u + F::one()) * self.scale - self.shift;
        if !self.border {
            return (x, self.scale);
        }
        // border: x clamped to [0, size-1]; the grid gets no gradient on or beyond the clamp
        let x = x.max(F::zero()).min(self.max);
        let d = if x > F::zero() && x < self.max { self.scale } else { F::zero() };
        (x, d)
    }

    /// floor(x) as an index clamped to [-2, size + 1] (far outside stays outside), and whether
    /// index i and i + 1 lie inside [0, size).
    fn corner(&self, x0: F) -> (isize, bool, bool) {
        let hi = F::from_usize(self.size + 1).unwrap_or_else(F::max_value);
        let i = x0.max(F::c(-2.0)).min(hi).to_isize().unwrap_or(-2);
        let inside = |j: isize| j >= 0 && (j as usize) < self.size;
        (i, inside(i), inside(i + 1))
    }
}

/// The bilinear taps of the grid points of one batch element, in the input's (h, w) plane.
struct Locator<F> {
    ax: Axis1<F>,
    ay: Axis1<F>,
    w: usize,
}

impl<F: Float> Locator<F> {
    fn new(h: usize, w: usize, cfg: &GridSampleCfg) -> Self {
        Locator { ax: Axis1::new(w, cfg), ay: Axis1::new(h, cfg), w }
    }

    /// Corner offsets nw, ne, sw, se relative to `base`.
    fn offsets(&self) -> [usize; 4] {
        [0, 1, self.w, self.w + 1]
    }

    fn tap(&self, gx: F, gy: F) -> (Tap<F>, Slope<F>) {
        let ((x, mx), (y, my)) = (self.ax.locate(gx), self.ay.locate(gy));
        let (x0, y0) = (x.floor(), y.floor());
        // fractions: w = x - x0 (west distance), n = y - y0; e = 1 - w, s = 1 - n
        let (fw, fnn) = (x - x0, y - y0);
        let (e, s) = (F::one() - fw, F::one() - fnn);
        let (ix, xin0, xin1) = self.ax.corner(x0);
        let (iy, yin0, yin1) = self.ay.corner(y0);
        let inside = (xin0 && yin0) as u8 | ((xin1 && yin0) as u8) << 1 | ((xin0 && yin1) as u8) << 2 | ((xin1 && yin1) as u8) << 3;
        // base = y0·w + x0 (wrapping: only corners inside the plane are ever read)
        let base = (iy as usize).wrapping_mul(self.w).wrapping_add(ix as usize);
        (Tap { base, wt: [s * e, s * fw, fnn * e, fnn * fw], inside }, Slope { frac: [fw, fnn], mult: [mx, my] })
    }

    /// Taps of a run of grid points stored as (x, y) pairs.
    fn taps(&self, grid: &[F]) -> Vec<Tap<F>> {
        grid.chunks_exact(2).map(|p| self.tap(p[0], p[1]).0).collect()
    }

    /// Taps and slopes of a run of grid points.
    fn taps_slopes(&self, grid: &[F]) -> Vec<(Tap<F>, Slope<F>)> {
        grid.chunks_exact(2).map(|p| self.tap(p[0], p[1])).collect()
    }
}

/// The 4 corner values of a tap (0 for corners outside the plane).
#[inline(always)]
fn corners<F: Float>(plane: &[F], t: &Tap<F>, off: &[usize; 4]) -> [F; 4] {
    if t.inside == ALL_INSIDE {
        let b = t.base;
        [plane[b], plane[b + off[1]], plane[b + off[2]], plane[b + off[3]]]
    } else {
        let v = |k: usize| if t.inside >> k & 1 == 1 { plane[t.base.wrapping_add(off[k])] } else { F::zero() };
        [v(0), v(1), v(2), v(3)]
    }
}

/// dx(corner_k) += w_k · g for the corners inside the plane.
#[inline(always)]
fn scatter<F: Float>(dp: &mut [F], t: &Tap<F>, off: &[usize; 4], g: F) {
    if t.inside == ALL_INSIDE {
        let b = t.base;
        dp[b] += t.wt[0] * g;
        dp[b + off[1]] += t.wt[1] * g;
        dp[b + off[2]] += t.wt[2] * g;
        dp[b + off[3]] += t.wt[3] * g;
    } else {
        for k in 0..4 {
            if t.inside >> k & 1 == 1 {
                dp[t.base.wrapping_add(off[k])] += t.wt[k] * g;
            }
        }
    }
}

fn check_grid_sample<'a, F: Float>(x: ArrayViewD<'a, F>, grid: ArrayViewD<'a, F>) -> Result<(ArrayView4<'a, F>, ArrayView4<'a, F>)> {
    let x = fixed::<_, Ix4>(GS, "input", x)?;
    let grid = fixed::<_, Ix4>(GS, "grid", grid)?;
    let shapes = [("input", x.shape()), ("grid", grid.shape())];
    check_nonempty(GS, &shapes)?;
    if grid.shape()[3] != 2 || grid.shape()[0] != x.shape()[0] {
        return Err(Error::shape(GS, "grid must be (N, H_out, W_out, 2) with the batch size of input", &shapes));
    }
    if grid.iter().any(|v| !v.is_finite()) {
        return Err(Error::value(GS, format!("grid contains NaN or infinite values (grid shape {:?})", grid.shape())));
    }
    Ok((x, grid))
}

/// Channels per work item and output pixels per tile: a tile's taps stay in L1 while a block of
/// channel planes is swept.
const TILE: usize = 2048;

fn channel_block(c: usize, n: usize) -> usize {
    let items = 4 * rayon::current_num_threads();
    c.div_ceil(items.div_ceil(n.max(1))).clamp(1, c.max(1))
}

/// Bilinear sampling of x at the normalised points of grid (x then y, in [-1, 1] across the input).
///
/// # Shapes
/// x (N, C, H, W), grid (N, H_out, W_out, 2) -> (N, C, H_out, W_out).
///
/// # Gradient
/// input and grid: see [`grid_sample_bwd`] (scatter of the bilinear weights; Σ_c g · ∂sample/∂(x, y) · scale).
///
/// Torch: `F.grid_sample(x, grid, mode='bilinear', padding_mode='zeros'|'border', align_corners=a)`.
pub fn grid_sample_fwd<F: Float>(x: ArrayViewD<F>, grid: ArrayViewD<F>, cfg: &GridSampleCfg) -> Result<Array4<F>> {
    let (x, grid) = check_grid_sample(x, grid)?;
    let (x, grid) = (x.as_standard_layout(), grid.as_standard_layout());
    let (n, c, h, w) = x.dim();
    let (ho, wo) = (grid.shape()[1], grid.shape()[2]);
    let (plane, pix) = (h * w, ho * wo);
    let loc = Locator::new(h, w, cfg);
    let off = loc.offsets();
    let gs = grid.as_slice().expect("standard layout");
    let taps: Vec<Vec<Tap<F>>> = gs.par_chunks(2 * pix).map(|g| loc.taps(g)).collect();
    let xs = x.as_slice().expect("standard layout");
    let mut out = zeros(GS, (n, c, ho, wo))?;
    let cb = channel_block(c, n);
    let os = out.as_slice_mut().expect("fresh array");
    // work item = (n, block of cb channels); a block never straddles two batch elements
    let items = os.par_chunks_mut(c * pix).enumerate().flat_map(|(b, on)| {
        on.par_chunks_mut(cb * pix).enumerate().map(move |(k, o)| (b, k * cb, o))
    });
    items.for_each(|(b, c0, o)| {
        let t = &taps[b];
        for p0 in (0..pix).step_by(TILE) {
            let p1 = (p0 + TILE).min(pix);
            for (k, orow) in o.chunks_mut(pix).enumerate() {
                // input plane (b, c0 + k) starts at ((b·C + c0 + k)·H·W)
                let xp = &xs[(b * c + c0 + k) * plane..][..plane];
                for (ov, tp) in orow[p0..p1].iter_mut().zip(&t[p0..p1]) {
                    let v = corners(xp, tp, &off);
                    // out = Σ_k w_k · x[corner_k]
                    *ov = v[0] * tp.wt[0] + v[1] * tp.wt[1] + v[2] * tp.wt[2] + v[3] * tp.wt[3];
                }
            }
        }
    });
    Ok(out)
}

/// Gradients of [`grid_sample_fwd`]; each is computed only when asked for.
#[derive(Debug)]
pub struct GridSampleGrads<F> {
    pub input: Option<Array4<F>>,
    pub grid: Option<Array4<F>>,
}

/// Gradients of [`grid_sample_fwd`] with respect to the input and the grid.
///
/// # Shapes
/// x (N, C, H, W), grid (N, H_out, W_out, 2), g (N, C, H_out, W_out) -> input (N, C, H, W),
/// grid (N, H_out, W_out, 2).
///
/// # Gradient
/// input: dx(corner_k) += w_k · g (scatter-add of the bilinear weights, per (n, c) plane);
/// grid: d/dgx = Σ_c g · ((ne - nw)(1 - fy) + (se - sw) fy) · dx/dgx and
/// d/dgy = Σ_c g · ((sw - nw)(1 - fx) + (se - ne) fx) · dy/dgy, with dx/dgx = (W-1)/2 (align_corners)
/// or W/2, and 0 where border padding clamps the coordinate (on or beyond the border).
///
/// Torch: the backward of `F.grid_sample(x, grid, 'bilinear', padding_mode, align_corners)`.
pub fn grid_sample_bwd<F: Float>(
    x: ArrayViewD<F>,
    grid: ArrayViewD<F>,
    g: ArrayViewD<F>,
    cfg: &GridSampleCfg,
    need_input: bool,
    need_grid: bool,
) -> Result<GridSampleGrads<F>> {
    let (x, grid) = check_grid_sample(x, grid)?;
    let (n, c, h, w) = x.dim();
    let (ho, wo) = (grid.shape()[1], grid.shape()[2]);
    if g.shape() != [n, c, ho, wo] {
        return Err(Error::shape(GS, "grad_output must be (N, C, H_out, W_out)", &[
            ("input", x.shape()),
            ("grid", grid.shape()),
            ("grad_output", g.shape()),
        ]));
    }
    let (x, grid, g) = (x.as_standard_layout(), grid.as_standard_layout(), g.as_standard_layout());
    let (plane, pix) = (h * w, ho * wo);
    let loc = Locator::new(h, w, cfg);
    let off = loc.offsets();
    let (xs, gs, grs) = (
        x.as_slice().expect("standard layout"),
        g.as_slice().expect("standard layout"),
        grid.as_slice().expect("standard layout"),
    );
    let dinput = need_input.then(|| -> Result<Array4<F>> {
        let taps: Vec<Vec<Tap<F>>> = grs.par_chunks(2 * pix).map(|gr| loc.taps(gr)).collect();
        let mut dx = zeros(GS, (n, c, h, w))?;
        let dxs = dx.as_slice_mut().expect("fresh array");
        let cb = channel_block(c, n);
        // work item = (n, block of cb channel planes); within a plane the scatter runs in pixel order
        let items = dxs.par_chunks_mut(c * plane).enumerate().flat_map(|(b, dn)| {
            dn.par_chunks_mut(cb * plane).enumerate().map(move |(k, d)| (b, k * cb, d))
        });
        items.for_each(|(b, c0, d)| {
            let t = &taps[b];
            for p0 in (0..pix).step_by(TILE) {
                let p1 = (p0 + TILE).min(pix);
                for (k, dp) in d.chunks_mut(plane).enumerate() {
                    // grad plane (b, c0 + k) starts at ((b·C + c0 + k)·H_out·W_out)
                    let gp = &gs[(b * c + c0 + k) * pix..][p0..p1];
                    for (tp, &gv) in t[p0..p1].iter().zip(gp) {
                        scatter(dp, tp, &off, gv);
                    }
                }
            }
        });
        Ok(dx)
    });
    let dgrid = need_grid.then(|| -> Result<Array4<F>> {
        let mut dg = zeros(GS, (n, ho, wo, 2))?;
        let dgs = dg.as_slice_mut().expect("fresh array");
        // one (n, output row) per work item, channels summed in order
        dgs.par_chunks_mut(2 * wo).enumerate().for_each(|(r, drow)| {
            let (b, oy) = (r / ho, r % ho);
            // grid row (b, oy) starts at ((b·H_out + oy)·W_out)·2
            let taps = loc.taps_slopes(&grs[(b * pix + oy * wo) * 2..][..2 * wo]);
            let mut acc = vec![[F::zero(); 2]; wo];
            for ch in 0..c {
                // plane (b, ch) of x, and row oy of plane (b, ch) of g
                let xp = &xs[(b * c + ch) * plane..][..plane];
                let grow = &gs[(b * c + ch) * pix + oy * wo..][..wo];
                for ((a, (tp, sl)), &gv) in acc.iter_mut().zip(&taps).zip(grow) {
                    let v = corners(xp, tp, &off);
                    let [fx, fy] = sl.frac;
                    // ∂out/∂x = (ne - nw)(1 - fy) + (se - sw) fy;  ∂out/∂y = (sw - nw)(1 - fx) + (se - ne) fx
                    a[0] += ((v[1] - v[0]) * (F::one() - fy) + (v[3] - v[2]) * fy) * gv;
                    a[1] += ((v[2] - v[0]) * (F::one() - fx) + (v[3] - v[1]) * fx) * gv;
                }
            }
            for ((d, a), (_, sl)) in drow.chunks_exact_mut(2).zip(&acc).zip(&taps) {
                d[0] = a[0] * sl.mult[0];
                d[1] = a[1] * sl.mult[1];
            }
        });
        Ok(dg)
    });
    Ok(GridSampleGrads { input: dinput.transpose()?, grid: dgrid.transpose()? })
}

// ---------------------------------------------------------------------------------------------
// interpolate (bilinear)
// ---------------------------------------------------------------------------------------------

const INTERP: &str = "interpolate";

/// Output size and coordinate convention of a bilinear resize.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InterpCfg {
    pub out_hw: (usize, usize),
    pub align_corners: bool,
    /// torch's `scale_factor` per axis (h, w), when the size came from one; without align_corners
    /// the source coordinate then uses 1/scale instead of in/out.
    pub scales: [Option<f64>; 2],
}

/// Per output index along one axis: the two source indices and their weights.
struct Lerp<F> {
    i0: usize,
    i1: usize,
    l0: F,
    l1: F,
}

impl InterpCfg {
    fn lerps<F: Float>(&self, input: usize, output: usize, scale: Option<f64>) -> Vec<Lerp<F>> {
        let (fi, fo) = (F::from_usize(input).unwrap_or_else(F::max_value), F::from_usize(output).unwrap_or_else(F::max_value));
        // align_corners: src = dst·(in-1)/(out-1); else src = max((dst + 1/2)·r - 1/2, 0), r = 1/scale or in/out
        let ratio = if self.align_corners {
            if output > 1 { (fi - F::one()) / (fo - F::one()) } else { F::zero() }
        } else {
            match scale {
                Some(s) if s > 0.0 => F::c(1.0 / s),
                _ => fi / fo,
            }
        };
        (0..output)
            .map(|d| {
                let df = F::from_usize(d).unwrap_or_else(F::max_value);
                let src = if self.align_corners { ratio * df } else { (ratio * (df + F::c(0.5)) - F::c(0.5)).max(F::zero()) };
                let i0 = src.floor().to_usize().unwrap_or(0).min(input - 1);
                let l1 = (src - F::from_usize(i0).unwrap_or_else(F::zero)).max(F::zero()).min(F::one());
                // the upper neighbour is i0 + 1, or i0 itself on the last index
                Lerp { i0, i1: if i0 + 1 < input { i0 + 1 } else { i0 }, l0: F::one() - l1, l1 }
            })
            .collect()
    }

    fn check<'a, F>(&self, x: ArrayViewD<'a, F>) -> Result<ArrayView4<'a, F>> {
        let x = fixed::<_, Ix4>(INTERP, "input", x)?;
        check_nonempty(INTERP, &[("input", x.shape())])?;
        if self.out_hw.0 == 0 || self.out_hw.1 == 0 {
            let out = [self.out_hw.0, self.out_hw.1];
            return Err(Error::shape(INTERP, "output size must be positive", &[("input", x.shape()), ("size", &out)]));
        }
        Ok(x)
    }
}

/// Bilinear resize of the last two axes to `cfg.out_hw`.
///
/// # Shapes
/// x (N, C, H, W) -> (N, C, H_out, W_out).
///
/// # Gradient
/// x: see [`interpolate_bilinear_bwd`] (scatter of ly·lx·g onto the 4 source pixels).
///
/// Torch: `F.interpolate(x, size=(H_out, W_out), mode='bilinear', align_corners=a)`.
pub fn interpolate_bilinear_fwd<F: Float>(x: ArrayViewD<F>, cfg: &InterpCfg) -> Result<Array4<F>> {
    let x = cfg.check(x)?;
    let x = x.as_standard_layout();
    let (n, c, h, w) = x.dim();
    let (ho, wo) = cfg.out_hw;
    let mut out = zeros(INTERP, (n, c, ho, wo))?;
    let (ly, lx) = (cfg.lerps::<F>(h, ho, cfg.scales[0]), cfg.lerps::<F>(w, wo, cfg.scales[1]));
    let os = out.as_slice_mut().expect("fresh array");
    let xs = x.as_slice().expect("standard layout");
    os.par_chunks_mut(ho * wo).zip(xs.par_chunks(h * w)).for_each(|(o, xp)| {
        for (orow, a) in o.chunks_mut(wo).zip(&ly) {
            // source rows y0 and y1
            let (r0, r1) = (&xp[a.i0 * w..][..w], &xp[a.i1 * w..][..w]);
            for (ov, b) in orow.iter_mut().zip(&lx) {
                // out = ly0·(lx0·x00 + lx1·x01) + ly1·(lx0·x10 + lx1·x11)
                *ov = a.l0 * (b.l0 * r0[b.i0] + b.l1 * r0[b.i1]) + a.l1 * (b.l0 * r1[b.i0] + b.l1 * r1[b.i1]);
            }
        }
    });
    Ok(out)
}

/// Gradient of [`interpolate_bilinear_fwd`] with respect to its input.
///
/// # Shapes
/// g (N, C, H_out, W_out) -> dx (N, C, H, W).
///
/// # Gradient
/// dx[y_a, x_b] += ly_a · lx_b · g[oy, ox] for the 4 source pixels of every output pixel, summed in a
/// fixed order per (n, c) plane.
///
/// Torch: the backward of `F.interpolate(x, size, mode='bilinear', align_corners=a)`.
pub fn interpolate_bilinear_bwd<F: Float>(g: ArrayViewD<F>, input_hw: (usize, usize), cfg: &InterpCfg) -> Result<Array4<F>> {
    let g = fixed::<_, Ix4>(INTERP, "grad_output", g)?;
    let (h, w) = input_hw;
    let (n, c, gh, gw) = g.dim();
    if (gh, gw) != cfg.out_hw || h == 0 || w == 0 {
        return Err(Error::shape(INTERP, "grad_output does not match the output size", &[
            ("grad_output", g.shape()),
            ("input_hw", &[h, w]),
            ("size", &[cfg.out_hw.0, cfg.out_hw.1]),
        ]));
    }
    let g = g.as_standard_layout();
    let (ho, wo) = cfg.out_hw;
    let (ly, lx) = (cfg.lerps::<F>(h, ho, cfg.scales[0]), cfg.lerps::<F>(w, wo, cfg.scales[1]));
    let mut dx = zeros(INTERP, (n, c, h, w))?;
    let ds = dx.as_slice_mut().expect("fresh array");
    let gs = g.as_slice().expect("standard layout");
    ds.par_chunks_mut(h * w).zip(gs.par_chunks(ho * wo)).for_each(|(d, gp)| {
        for (grow, a) in gp.chunks(wo).zip(&ly) {
            for (&gv, b) in grow.iter().zip(&lx) {
                // each source pixel (y_a, x_b) receives ly_a · lx_b · g
                d[a.i0 * w + b.i0] += a.l0 * b.l0 * gv;
                d[a.i0 * w + b.i1] += a.l0 * b.l1 * gv;
                d[a.i1 * w + b.i0] += a.l1 * b.l0 * gv;
                d[a.i1 * w + b.i1] += a.l1 * b.l1 * gv;
            }
        }
    });
    Ok(dx)
}

// ---------------------------------------------------------------------------------------------
// unfold / fold
// ---------------------------------------------------------------------------------------------

/// Geometry of sliding blocks: kernel, dilation, zero padding and stride, each (h, w).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnfoldCfg {
    pub kernel: [usize; 2],
    pub dilation: [usize; 2],
    pub padding: [usize; 2],
    pub stride: [usize; 2],
}

impl UnfoldCfg {
    /// Validates the scalars (kernel, dilation and stride at least 1).
    pub fn new(op: &'static str, kernel: [usize; 2], dilation: [usize; 2], padding: [usize; 2], stride: [usize; 2]) -> Result<Self> {
        for (name, v) in [("kernel_size", kernel), ("dilation", dilation), ("stride", stride)] {
            if v.contains(&0) {
                return Err(Error::arg(op, format!("{name} must be positive, got {v:?}")));
            }
        }
        Ok(UnfoldCfg { kernel, dilation, padding, stride })
    }

    /// Number of block positions (L_h, L_w) over an (h, w) input:
    /// L = (size + 2·pad - dil·(k - 1) - 1) / stride + 1.
    pub fn blocks(&self, op: &'static str, h: usize, w: usize, shapes: &[(&'static str, &[usize])]) -> Result<(usize, usize)> {
        let overflow = || Error::shape(op, format!("kernel {:?}, dilation {:?}, padding {:?} overflow the index range", self.kernel, self.dilation, self.padding), shapes);
        let axis = |size: usize, a: usize| -> Result<usize> {
            // span = dil·(k - 1) + 1, padded = size + 2·pad (checked: every index below stays < padded)
            let span = self.dilation[a].checked_mul(self.kernel[a] - 1).and_then(|v| v.checked_add(1)).ok_or_else(overflow)?;
            let padded = self.padding[a].checked_mul(2).and_then(|v| v.checked_add(size)).ok_or_else(overflow)?;
            if padded < span {
                return Err(Error::shape(op, format!("kernel {:?} (dilation {:?}) is larger than the padded input {h}x{w} (padding {:?})", self.kernel, self.dilation, self.padding), shapes));
            }
            Ok((padded - span) / self.stride[a] + 1)
        };
        let (lh, lw) = (axis(h, 0)?, axis(w, 1)?);
        lh.checked_mul(lw).ok_or_else(overflow)?;
        Ok((lh, lw))
    }

    /// C·kh·kw, the column rows of C channels, or an error if that overflows.
    fn rows(&self, op: &'static str, c: usize, shape: &[usize]) -> Result<usize> {
        c.checked_mul(self.kernel[0]).and_then(|v| v.checked_mul(self.kernel[1]))
            .ok_or_else(|| Error::shape(op, format!("kernel {:?} is too large", self.kernel), &[("input", shape)]))
    }

    /// For block row l and kernel row k along axis a: the input index l·stride - pad + k·dil, if inside.
    fn source(&self, a: usize, l: usize, k: usize, size: usize) -> Option<usize> {
        // i = l·stride + k·dil - pad
        (l * self.stride[a] + k * self.dilation[a]).checked_sub(self.padding[a]).filter(|&i| i < size)
    }
}

/// Extracts sliding blocks as columns.
///
/// # Shapes
/// x (N, C, H, W) -> (N, C·kh·kw, L_h·L_w); row (c·kh + i)·kw + j holds x[c, l_h·s_h - p_h + i·d_h,
/// l_w·s_w - p_w + j·d_w] (0 in the padding) at column l_h·L_w + l_w.
///
/// # Gradient
/// dx = [`fold_fwd`] of g with the same geometry (the adjoint).
///
/// Torch: `F.unfold(x, kernel_size, dilation, padding, stride)`.
pub fn unfold_fwd<F: Float>(x: ArrayViewD<F>, cfg: &UnfoldCfg) -> Result<Array3<F>> {
    const OP: &str = "unfold";
    let x = fixed::<_, Ix4>(OP, "input", x)?;
    check_nonempty(OP, &[("input", x.shape())])?;
    let x = x.as_standard_layout();
    let (n, c, h, w) = x.dim();
    let (lh, lw) = cfg.blocks(OP, h, w, &[("input", x.shape())])?;
    let [kh, kw] = cfg.kernel;
    let (l, rows) = (lh * lw, cfg.rows(OP, c, x.shape())?);
    let mut out = zeros(OP, (n, rows, l))?;
    let os = out.as_slice_mut().expect("fresh array");
    let xs = x.as_slice().expect("standard layout");
    // one (n, c) input plane <-> kh·kw contiguous output rows
    os.par_chunks_mut(kh * kw * l).zip(xs.par_chunks(h * w)).for_each(|(o, xp)| {
        for (r, orow) in o.chunks_mut(l).enumerate() {
            // row r = i·kw + j within the channel's kh·kw rows
            let (i, j) = (r / kw, r % kw);
            for (bh, oseg) in orow.chunks_mut(lw).enumerate() {
                let Some(y) = cfg.source(0, bh, i, h) else { continue };
                for (bw, ov) in oseg.iter_mut().enumerate() {
                    if let Some(xx) = cfg.source(1, bw, j, w) {
                        *ov = xp[y * w + xx];
                    }
                }
            }
        }
    });
    Ok(out)
}

/// Sums columns of sliding blocks back into an image (overlaps add up).
///
/// # Shapes
/// cols (N, C·kh·kw, L_h·L_w), output_hw (H, W) -> (N, C, H, W).
///
/// # Gradient
/// dcols = [`unfold_fwd`] of g with the same geometry (the adjoint).
///
/// Torch: `F.fold(cols, output_size, kernel_size, dilation, padding, stride)`.
pub fn fold_fwd<F: Float>(cols: ArrayViewD<F>, output_hw: (usize, usize), cfg: &UnfoldCfg) -> Result<Array4<F>> {
    const OP: &str = "fold";
    let cols = fixed::<_, Ix3>(OP, "input", cols)?;
    let (h, w) = output_hw;
    let shapes = [("input", cols.shape()), ("output_size", &[h, w][..])];
    check_nonempty(OP, &shapes)?;
    let [kh, kw] = cfg.kernel;
    let (lh, lw) = cfg.blocks(OP, h, w, &shapes)?;
    let (n, ck, l) = cols.dim();
    let taps = cfg.rows(OP, 1, cols.shape())?;
    if ck % taps != 0 || l != lh * lw {
        return Err(Error::shape(OP, format!(
            "input must be (N, C·{kh}·{kw}, {}) for output_size {h}x{w} and kernel {:?}", lh * lw, cfg.kernel
        ), &shapes));
    }
    let c = ck / taps;
    let cols = cols.as_standard_layout();
    let mut out = zeros(OP, (n, c, h, w))?;
    let os = out.as_slice_mut().expect("fresh array");
    let cs = cols.as_slice().expect("standard layout");
    // one (n, c) output plane <-> kh·kw contiguous input rows, summed in a fixed order
    os.par_chunks_mut(h * w).zip(cs.par_chunks(kh * kw * l)).for_each(|(op, cp)| {
        for (r, crow) in cp.chunks(l).enumerate() {
            // row r = i·kw + j within the channel's kh·kw rows
            let (i, j) = (r / kw, r % kw);
            for (bh, cseg) in crow.chunks(lw).enumerate() {
                let Some(y) = cfg.source(0, bh, i, h) else { continue };
                for (bw, &cv) in cseg.iter().enumerate() {
                    if let Some(xx) = cfg.source(1, bw, j, w) {
                        op[y * w + xx] += cv;
                    }
                }
            }
        }
    });
    Ok(out)
}
