//! Convolution: 2-D cross-correlation with any kernel size, any stride, per-axis zero padding and an
//! optional bias (and optionally a ReLU), computed as GEMMs over im2col columns that are never stored.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | conv2d | `conv2d_fwd`: `Y[n]` = W · cols(`x[n]`) + b | `conv2d_bwd`: dX = col2im(Wᵀ · dY), dW = Σ dY · colsᵀ, db = Σ dY |
//!
//! W is the matrix `[Cout, K]` with K = Cin·kh·kw, and cols(`x[n]`) the matrix `[K, Ho·Wo]` whose column p
//! holds the receptive field of output pixel p. cols is never built whole (a 3x3 352->128 conv at
//! 272x480 would need 1.6 GB). Every result is deterministic and independent of the number of
//! threads (every output element is one chain of the GEMM, see `gemm.rs`):
//! - forward: tasks (image, tile of output pixels), one GEMM each with W packed once per call and
//!   shared; the GEMM's B blocks are filled by im2col straight from x (`Im2colB`), or are x itself
//!   for a pointwise conv; the bias starts the chains and the ReLU runs in the GEMM's epilogue;
//! - dX: for stride 1 with padding below the kernel size, itself a forward conv of dY with the
//!   flipped, transposed weights (`input_grad_as_conv`); otherwise tasks (image, input-channel
//!   chunk), each owning `dX[n, chunk]` and running over the tiles in order (in bands of
//!   `BAND_BYTES` of dY shared by all tasks): dcols = `W[:, chunk]ᵀ` · `dY[n][:, tile]`, scattered
//!   back by col2im;
//! - dW: `DW_GROUPS` partial sums fixed by the shapes, added in group order; B built from x in
//!   pixel-major layout with tap-major K (`NhwcColsT`), or from cols tiles in scratch for few
//!   input channels; Winograd's adjoint for the stride-1 3x3 convs where it pays;
//! - db: per output channel, Σ over images and pixels in order;
//! - stride 1 with one or two output channels (the disparity heads): forward and dW as a pointwise
//!   GEMM over taps·Cout rows and a shift-add (`tap_major`).

use super::lanes;
use crate::gemm::{self, gemm_ex, Epilogue, Init, PackB, Plan, Prepacked, SourceA, Strided};
use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{s, Array1, Array2, Array3, Array4, ArrayView, ArrayView2, ArrayViewD, ArrayViewMut2, Axis, CowArray, Dimension, Ix1, Ix4};
use rayon::prelude::*;
use std::any::Any;
use std::cell::RefCell;
use std::ops::Range;
use std::thread::LocalKey;

mod tap_major;
mod winograd;

const OP: &str = "conv2d";
/// Upper bound of one thread's im2col / col2im buffer.
const SCRATCH_BYTES: usize = 4 << 20;
/// Fewest output pixels in a tile (below this the GEMM's packing overhead dominates).
const MIN_TILE: usize = 64;
/// Most output pixels in a tile.
const MAX_TILE: usize = 1024;
/// dY read per band of the input gradient (so that it is reused from cache by every channel chunk).
const BAND_BYTES: usize = 2 << 20;
/// Partial dW sums (the parallelism of the weight gradient; fixed, so dW does not depend on the threads).
const DW_GROUPS: usize = 4;
/// Rows (channels · taps, whole channels) of a col2im dX task's dcols, about:
/// small enough for the block to stay in L2 while the GEMM packs it.
const CHUNK_ROWS: usize = 256;

/// Geometry of a convolution: stride and zero padding per axis (height, width).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Conv2dCfg {
    pub stride: [usize; 2],
    pub padding: [usize; 2],
}

impl Default for Conv2dCfg {
    fn default() -> Self {
        Conv2dCfg { stride: [1, 1], padding: [0, 0] }
    }
}

impl Conv2dCfg {
    /// A config from (stride_h, stride_w) and (pad_h, pad_w).
    pub fn new(stride: [usize; 2], padding: [usize; 2]) -> Self {
        Conv2dCfg { stride, padding }
    }

    /// The output size (Ho, Wo) for an input of H x W and a kernel of kh x kw.
    ///
    /// Fails for a zero stride, a padding so large that sizes overflow, and a kernel larger than the
    /// padded input.
    pub fn out_hw(&self, h: usize, w: usize, kh: usize, kw: usize) -> Result<(usize, usize)> {
        let [sh, sw] = self.stride;
        let [ph, pw] = self.padding;
        if sh == 0 || sw == 0 {
            return Err(Error::arg(OP, format!("stride must be at least 1 on both axes, got {:?}", self.stride)));
        }
        // padded size = size + 2·pad
        let padded = |size: usize, pad: usize| pad.checked_mul(2).and_then(|p| p.checked_add(size));
        let (Some(hp), Some(wp)) = (padded(h, ph), padded(w, pw)) else {
            return Err(Error::arg(OP, format!("padding {:?} is too large", self.padding)));
        };
        if kh == 0 || kw == 0 || kh > hp || kw > wp {
            return Err(Error::shape(OP, "the kernel must be non-empty and fit in the padded input",
                                    &[("padded input", &[hp, wp]), ("kernel", &[kh, kw])]));
        }
        // o = (padded − k) / s + 1
        Ok(((hp - kh) / sh + 1, (wp - kw) / sw + 1))
    }
}

/// Whether stride-1 3x3 convolutions (forward, the dX that is a forward, and dW) use Winograd F(4x4, 3x3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Winograd {
    /// For f32 where it pays (enough channels and tiles; for dW, enough channels on both sides); f64 (the gradient checks' type) stays
    /// on the direct convolution.
    Auto,
    /// Never: the direct convolution.
    Off,
    /// Whenever the geometry allows, f64 and small convolutions included (to check the transforms).
    On,
}

/// How a convolution runs: the GEMM plan (the ISA path), the Winograd choice, and whether a
/// Winograd forward keeps its transformed kernel for later calls with the same kernel bytes (for
/// weights that stay fixed over many calls, as at inference; see `winograd/cache.rs`).
#[derive(Clone, Copy, Debug)]
pub struct Conv2dRun<'a, F> {
    pub plan: &'a Plan<F>,
    pub winograd: Winograd,
    pub reuse_kernels: bool,
}

impl<F: Float> Conv2dRun<'static, F> {
    /// The selected plan (`MIPNET_ISA`, else the widest ISA), `Winograd::Auto`, no kernel reuse.
    pub fn selected() -> Self {
        Conv2dRun { plan: Plan::selected(), winograd: Winograd::Auto, reuse_kernels: false }
    }
}

impl<F: Float> Conv2dRun<'_, F> {
    /// Whether this run takes the Winograd path for geometry `g`, where `pays` says whether it pays
    /// (`Winograd::Auto` on f32).
    fn winograd_if(&self, g: &Geom, pays: fn(&Geom) -> bool) -> bool {
        let f32 = std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>();
        winograd::applies(g) && match self.winograd {
            Winograd::Auto => f32 && pays(g),
            Winograd::Off => false,
            Winograd::On => true,
        }
    }

    /// Whether the forward (and the dX that is a forward) of geometry `g` takes the Winograd path.
    fn winograd_for(&self, g: &Geom) -> bool {
        self.winograd_if(g, winograd::pays)
    }
}

/// Which gradients `conv2d_bwd` computes (the others are skipped and returned as None).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Conv2dNeed {
    pub x: bool,
    pub w: bool,
    pub b: bool,
}

impl Conv2dNeed {
    /// All three gradients.
    pub const ALL: Conv2dNeed = Conv2dNeed { x: true, w: true, b: true };
}

/// The gradients of `conv2d_fwd` w.r.t. input, weight and bias (None where not requested).
#[derive(Debug)]
pub struct Conv2dGrads<F> {
    pub x: Option<Array4<F>>,
    pub w: Option<Array4<F>>,
    pub b: Option<Array1<F>>,
}

/// All sizes of one call, validated.
#[derive(Clone, Copy, Debug)]
struct Geom {
    n: usize,
    cin: usize,
    h: usize,
    w: usize,
    cout: usize,
    kh: usize,
    kw: usize,
    ho: usize,
    wo: usize,
    stride: [usize; 2],
    pad: [usize; 2],
}

impl Geom {
    fn new(x: &[usize], w: &[usize], b: Option<&[usize]>, cfg: &Conv2dCfg) -> Result<Geom> {
        let shapes: Vec<(&'static str, &[usize])> =
            [("input", x), ("weight", w)].into_iter().chain(b.map(|b| ("bias", b))).collect();
        check_nonempty(OP, &shapes)?;
        let ([n, cin, h, wd], [cout, wcin, kh, kw]) = (to4(x), to4(w));
        if cin != wcin {
            return Err(Error::shape(OP, "input channels (input.shape[1]) must equal weight.shape[1]", &shapes));
        }
        if let Some(b) = b {
            if b != [cout] {
                return Err(Error::shape(OP, "bias must have weight.shape[0] elements", &shapes));
            }
        }
        let (ho, wo) = cfg.out_hw(h, wd, kh, kw).map_err(|e| match e {
            Error::Shape { msg, .. } => Error::shape(OP, format!("{msg} (padding {:?})", cfg.padding), &shapes),
            other => other,
        })?;
        Ok(Geom { n, cin, h, w: wd, cout, kh, kw, ho, wo, stride: cfg.stride, pad: cfg.padding })
    }
    /// Rows of cols: K = Cin·kh·kw.
    fn k(&self) -> usize {
        self.cin * self.kh * self.kw
    }
    /// Output pixels per image.
    fn pix(&self) -> usize {
        self.ho * self.wo
    }
    /// Elements of one input image.
    fn img(&self) -> usize {
        self.cin * self.h * self.w
    }
    /// 1x1, stride 1, no padding: cols(`x[n]`) is `x[n]` seen as `[Cin, H·W]`.
    fn pointwise(&self) -> bool {
        self.kh == 1 && self.kw == 1 && self.stride == [1, 1] && self.pad == [0, 0]
    }
}

/// A rank-4 shape as an array (callers checked the rank).
fn to4(s: &[usize]) -> [usize; 4] {
    [0, 1, 2, 3].map(|i| s.get(i).copied().unwrap_or(0))
}

/// An ndarray layout failure, which would be a bug of this file (all buffers are built here).
fn layout(e: ndarray::ShapeError) -> Error {
    Error::shape(OP, format!("internal layout error: {e}"), &[])
}

/// Pixels per tile: at most what fits `rows` x tile in the scratch budget, at least `min_tiles`
/// tiles per image, never below `MIN_TILE` (unless the image is smaller), a multiple of `align`.
fn tile_len<F>(pix: usize, rows: usize, min_tiles: usize, align: usize) -> usize {
    let budget = SCRATCH_BYTES / std::mem::size_of::<F>() / rows.max(1);
    let split = pix.div_ceil(min_tiles.max(1));
    let most = budget.min(split).clamp(MIN_TILE, MAX_TILE);
    // equal tiles: as few as `most` allows
    pix.div_ceil(pix.div_ceil(most)).next_multiple_of(align).min(pix).max(1)
}

/// The tiles of one image: consecutive ranges of `len` output pixels.
fn tiles(pix: usize, len: usize) -> impl Iterator<Item = Range<usize>> {
    (0..pix).step_by(len.max(1)).map(move |p| p..(p + len).min(pix))
}

/// A per-thread reusable buffer: a `Vec<F>` behind `dyn Any`, so f32 and f64 share the slot.
type Slot = RefCell<Option<Box<dyn Any>>>;

thread_local! {
    /// cols / dcols blocks of the task running on this thread.
    static SCRATCH: Slot = const { RefCell::new(None) };
    /// The partial dW sums of a weight gradient started on this thread.
    static PARTIALS: Slot = const { RefCell::new(None) };
}

/// Runs `f` on this thread's `slot` buffer of `len` elements (contents unspecified: stale values of
/// an earlier call). Callers must not re-enter the same slot on this thread; should it happen, the
/// inner call gets a fresh buffer.
fn with_buf<F: Float, R>(slot: &'static LocalKey<Slot>, len: usize, f: impl FnOnce(&mut [F]) -> R) -> R {
    slot.with(|slot| {
        let Ok(mut slot) = slot.try_borrow_mut() else {
            return f(&mut vec![F::zero(); len]);
        };
        let mut owned: Box<dyn Any> =
            slot.take().filter(|b| b.is::<Vec<F>>()).unwrap_or_else(|| Box::new(Vec::<F>::new()));
        let out = match owned.downcast_mut::<Vec<F>>() {
            Some(buf) => {
                if buf.len() < len {
                    buf.resize(len, F::zero());
                }
                f(&mut buf[..len])
            }
            None => f(&mut vec![F::zero(); len]),
        };
        *slot = Some(owned);
        out
    })
}

/// `with_buf` on `SCRATCH`. `f` must not call into rayon (a task stolen meanwhile would find the
/// buffer taken and allocate its own).
fn with_scratch<F: Float, R>(len: usize, f: impl FnOnce(&mut [F]) -> R) -> R {
    with_buf(&SCRATCH, len, f)
}

/// A run of consecutive output pixels of one output row, for one kernel tap (ki, kj): positions
/// `j0..j0 + lead + valid + trail` of a cols row. `lead` and `trail` pixels read the zero padding;
/// the `valid` ones read `x[iy, ix0 + t·sw]`, t = 0..valid. `iy` is None when the whole run reads a
/// padding row.
struct Run {
    j0: usize,
    lead: usize,
    valid: usize,
    trail: usize,
    iy: Option<usize>,
    ix0: usize,
}

/// Calls `f` on every run of the output pixels `tile` for the tap (ki, kj): the one place that maps
/// output pixels to input positions, shared by im2col and col2im.
fn for_each_run(g: &Geom, ki: usize, kj: usize, tile: Range<usize>, mut f: impl FnMut(Run)) {
    let ([sh, sw], [ph, pw]) = (g.stride, g.pad);
    // ix = ox·sw + kj − pw lies in [0, W) for ox in [lo, hi)
    let lo = pw.saturating_sub(kj).div_ceil(sw).min(g.wo);
    let hi = if g.w + pw > kj { ((g.w - 1 + pw - kj) / sw + 1).min(g.wo) } else { 0 }.max(lo);
    let mut p = tile.start;
    while p < tile.end {
        // (oy, ox) = (p / Wo, p % Wo); the run ends at the row's end or the tile's end
        let (oy, ox) = (p / g.wo, p % g.wo);
        let end = (oy * g.wo + g.wo).min(tile.end);
        let ox_end = ox + (end - p);
        // iy = oy·sh + ki − ph
        let iy = (oy * sh + ki).checked_sub(ph).filter(|&iy| iy < g.h);
        let (va, vb) = (ox.max(lo), ox_end.min(hi));
        let run = match iy {
            Some(_) if va < vb => Run { j0: p - tile.start, lead: va - ox, valid: vb - va, trail: ox_end - vb, iy, ix0: va * sw + kj - pw },
            _ => Run { j0: p - tile.start, lead: ox_end - ox, valid: 0, trail: 0, iy: None, ix0: 0 },
        };
        f(run);
        p = end;
    }
}

/// For stride 1 and Wo = W (padding (kw − 1) / 2 on each side of a row), tap (ki, kj) reads x at a
/// constant offset of the flat output index: `x_flat[p + d]`, d = (ki − ph)·W + (kj − pw). Returns
/// d and the part of `tile` where p + d lies in the plane; outside it the tap reads padding rows.
/// Within it, only the wrapped columns (see `wrapped_cols`) read padding.
fn shift_span(g: &Geom, ki: usize, kj: usize, tile: &Range<usize>) -> Option<(isize, Range<usize>)> {
    if g.stride != [1, 1] || g.wo != g.w {
        return None;
    }
    let (w, plane) = (g.w as isize, (g.h * g.w) as isize);
    // d = (ki − ph)·W + (kj − pw); p + d in [0, plane) <=> p in [−d, plane − d)
    let d = (ki as isize - g.pad[0] as isize) * w + kj as isize - g.pad[1] as isize;
    let (t0, t1) = (tile.start as isize, tile.end as isize);
    let lo = (-d).clamp(t0, t1);
    let hi = (plane - d).clamp(lo, t1);
    Some((d, lo as usize..hi as usize))
}

/// Calls `f(j range)` on the positions j of a cols row (p = tile.start + j) whose output column ox
/// reads across a row edge for tap column kj: ix = ox + kj − pw outside [0, W), i.e. ox below
/// pw − kj or from W + pw − kj on (only with Wo = W).
fn wrapped_cols(g: &Geom, kj: usize, tile: &Range<usize>, mut f: impl FnMut(Range<usize>)) {
    let left = g.pad[1].saturating_sub(kj).min(g.w);
    let right = (g.w + g.pad[1]).saturating_sub(kj).min(g.w);
    if left == 0 && right == g.w {
        return;
    }
    for oy in tile.start / g.w..tile.end.div_ceil(g.w) {
        // output columns [0, left) and [right, W) of output row oy, clipped to the tile
        for cols in [0..left, right..g.w] {
            let (a, b) = ((oy * g.w + cols.start).max(tile.start), (oy * g.w + cols.end).min(tile.end));
            if a < b {
                f(a - tile.start..b - tile.start);
            }
        }
    }
}

/// `cols[(c − c0)·kh·kw + ki·kw + kj, j]` = `x[c, oy·sh + ki − ph, ox·sw + kj − pw]` (0 in the padding)
/// for the output pixels p = tile.start + j, (oy, ox) = (p / Wo, p % Wo), and c in `chans`.
fn im2col<F: Float>(g: &Geom, xn: &[F], chans: Range<usize>, tile: Range<usize>, cols: &mut [F]) {
    let plane = g.h * g.w;
    let mut rows = cols.chunks_exact_mut(tile.len());
    for c in chans {
        let xc = &xn[c * plane..(c + 1) * plane];
        for ki in 0..g.kh {
            for kj in 0..g.kw {
                let Some(dst) = rows.next() else { return };
                im2col_row(g, xc, ki, kj, &tile, dst);
            }
        }
    }
}

/// Zeroes a run that is usually empty or a single padding element (a library call only for longer ones).
#[inline]
fn zero<F: Float>(run: &mut [F]) {
    match run {
        [] => {}
        [v] => *v = F::zero(),
        _ => run.fill(F::zero()),
    }
}

/// One row of cols: `dst[j]` = `xc[oy·sh + ki − ph, ox·sw + kj − pw]` (0 in the padding) for the output
/// pixels p = tile.start + j, (oy, ox) = (p / Wo, p % Wo), of the tap (ki, kj) of one channel plane xc.
fn im2col_row<F: Float>(g: &Geom, xc: &[F], ki: usize, kj: usize, tile: &Range<usize>, dst: &mut [F]) {
    let sw = g.stride[1];
    if let Some((d, span)) = shift_span(g, ki, kj, tile) {
        // dst[j] = x_flat[p + d] on the span, 0 around it and on the wrapped columns
        let (a, b) = (span.start - tile.start, span.end - tile.start);
        zero(&mut dst[..a]);
        zero(&mut dst[b..]);
        if a < b {
            let src = (span.start as isize + d) as usize;
            dst[a..b].copy_from_slice(&xc[src..src + (b - a)]);
        }
        wrapped_cols(g, kj, tile, |js| zero(&mut dst[js]));
        return;
    }
    for_each_run(g, ki, kj, tile.clone(), |r| {
        let d = &mut dst[r.j0..r.j0 + r.lead + r.valid + r.trail];
        let (lead, rest) = d.split_at_mut(r.lead);
        let (mid, trail) = rest.split_at_mut(r.valid);
        lead.fill(F::zero());
        trail.fill(F::zero());
        if let Some(iy) = r.iy {
            // x row iy from column ix0, every sw-th element
            let src = &xc[iy * g.w + r.ix0..];
            if sw == 1 {
                mid.copy_from_slice(&src[..r.valid]);
            } else {
                // first element of each sw-wide chunk (a form the compiler vectorises),
                // then the last few taps whose chunk would run past the plane
                let whole = (src.len() / sw).min(r.valid);
                mid[..whole].iter_mut().zip(src.chunks_exact(sw)).for_each(|(m, c)| *m = c[0]);
                mid[whole..].iter_mut().zip(src[whole * sw..].iter().step_by(sw)).for_each(|(m, &v)| *m = v);
            }
        }
    });
}

/// cols(`x[n]`)[:, tile] as the GEMM's B operand, built straight into its packed panels (im2col fused
/// with packing: no cols matrix is ever stored).
struct Im2colB<'a, F> {
    g: &'a Geom,
    xn: &'a [F],
    tile: Range<usize>,
}

impl<F: Float> PackB<F> for Im2colB<'_, F> {
    fn pack(&self, _plan: &Plan<F>, p0: usize, kc: usize, j0: usize, nc: usize, dst: *mut F, ldb: usize) {
        let (g, taps, plane) = (self.g, self.g.kh * self.g.kw, self.g.h * self.g.w);
        // output pixels of this block: tile.start + j0 ..
        let px = self.tile.start + j0..self.tile.start + j0 + nc;
        // SAFETY: the GEMM's buffer holds kc rows of ldb elements.
        let block = unsafe { std::slice::from_raw_parts_mut(dst, kc * ldb) };
        for (kk, row) in block.chunks_exact_mut(ldb).enumerate() {
            // cols row r = c·taps + ki·kw + kj
            let r = p0 + kk;
            let (c, t) = (r / taps, r % taps);
            im2col_row(g, &self.xn[c * plane..(c + 1) * plane], t / g.kw, t % g.kw, &px, &mut row[..nc]);
            zero(&mut row[nc..]);
        }
    }
}

/// The adjoint of `im2col`: `dx[c − c0, iy, ix]` += `dcols[row(c, ki, kj), j]` for every tap that
/// reads x (padding taps are dropped), in a fixed order (channel, tap, pixel).
fn col2im<F: Float>(g: &Geom, dcols: &mut [F], nchans: usize, tile: Range<usize>, dx: &mut [F]) {
    let (plane, len, sw) = (g.h * g.w, tile.len(), g.stride[1]);
    let mut rows = dcols.chunks_exact_mut(len);
    for dxc in dx.chunks_exact_mut(plane).take(nchans) {
        for ki in 0..g.kh {
            for kj in 0..g.kw {
                let Some(src) = rows.next() else { return };
                if let Some((d, span)) = shift_span(g, ki, kj, &tile) {
                    // dx_flat[p + d] += dcols[r, j] on the span, the wrapped columns zeroed first
                    wrapped_cols(g, kj, &tile, |js| src[js].fill(F::zero()));
                    let (a, b) = (span.start - tile.start, span.end - tile.start);
                    if a < b {
                        let dst = (span.start as isize + d) as usize;
                        dxc[dst..dst + (b - a)].iter_mut().zip(&src[a..b]).for_each(|(x, &v)| *x += v);
                    }
                    continue;
                }
                let src = &*src;
                for_each_run(g, ki, kj, tile.clone(), |r| {
                    if let Some(iy) = r.iy {
                        let s = &src[r.j0 + r.lead..r.j0 + r.lead + r.valid];
                        // dx row iy from column ix0, every sw-th element
                        let d = &mut dxc[iy * g.w + r.ix0..];
                        if sw == 1 {
                            d[..r.valid].iter_mut().zip(s).for_each(|(d, &v)| *d += v);
                        } else {
                            d.iter_mut().step_by(sw).zip(s).for_each(|(d, &v)| *d += v);
                        }
                    }
                });
            }
        }
    }
}

/// Calls `f(rows, cols)` on consecutive row blocks of `cols(x[n])[:, tile]` covering the input
/// channels `chans`, `cc` whole channels per block (rows c·taps..(c + 1)·taps for channel c): x itself
/// (one block) for a pointwise conv, else im2col of one block at a time into this thread's scratch,
/// so the GEMM packs it while it is still in cache.
fn for_each_cols_block<F: Float>(g: &Geom, xn: &[F], chans: Range<usize>, cc: usize, tile: Range<usize>,
                                 mut f: impl FnMut(Range<usize>, ArrayView2<F>)) -> Result<()> {
    if g.pointwise() {
        f(chans.clone(), mat(xn, g.cin, g.pix())?.slice_move(s![chans, tile]));
        return Ok(());
    }
    let (taps, len, cc) = (g.kh * g.kw, tile.len(), cc.max(1));
    with_scratch(cc * taps * len, |buf: &mut [F]| {
        for c0 in chans.clone().step_by(cc) {
            let block = c0..(c0 + cc).min(chans.end);
            // rows of cols for channels c: c·taps .. (c + 1)·taps
            let rows = block.start * taps..block.end * taps;
            let cols = &mut buf[..rows.len() * len];
            im2col(g, xn, block, tile.clone(), cols);
            f(rows.clone(), mat(cols, rows.len(), len)?);
        }
        Ok(())
    })
}

/// Rows of scratch per tile pixel that `for_each_cols_block` needs for blocks of `cc` channels.
fn scratch_rows(g: &Geom, cc: usize) -> usize {
    if g.pointwise() { 0 } else { cc * g.kh * g.kw }
}

/// A contiguous standard-layout slice seen as a `[rows, cols]` matrix.
fn mat<F>(data: &[F], rows: usize, cols: usize) -> Result<ArrayView2<'_, F>> {
    ArrayView2::from_shape((rows, cols), data).map_err(layout)
}

/// The view itself if it is in standard (C) layout, else a standard-layout copy.
fn standard<F: Float, D: Dimension>(v: ArrayView<'_, F, D>) -> CowArray<'_, F, D> {
    if v.is_standard_layout() { CowArray::from(v) } else { CowArray::from(v.as_standard_layout().into_owned()) }
}

/// Validated, standard-layout operands of one call.
struct Operands<'a, F: Float> {
    g: Geom,
    x: CowArray<'a, F, Ix4>,
    w: CowArray<'a, F, Ix4>,
}

impl<'a, F: Float> Operands<'a, F> {
    fn new(x: ArrayViewD<'a, F>, w: ArrayViewD<'a, F>, b: Option<&[usize]>, cfg: &Conv2dCfg) -> Result<Self> {
        let (x, w) = (fixed::<_, Ix4>(OP, "input", x)?, fixed::<_, Ix4>(OP, "weight", w)?);
        let g = Geom::new(x.shape(), w.shape(), b, cfg)?;
        Ok(Operands { g, x: standard(x), w: standard(w) })
    }
    fn x(&self) -> Result<&[F]> {
        self.x.as_slice().ok_or_else(|| Error::shape(OP, "internal layout error: input", &[]))
    }
    /// W as the matrix `[Cout, K]`.
    fn wmat(&self) -> Result<ArrayView2<'_, F>> {
        let ws = self.w.as_slice().ok_or_else(|| Error::shape(OP, "internal layout error: weight", &[]))?;
        mat(ws, self.g.cout, self.g.k())
    }
}

/// 2-D convolution (cross-correlation) with zero padding and an optional bias.
///
/// # Shapes
/// x (N, Cin, H, W), w (Cout, Cin, kh, kw), b (Cout) -> y (N, Cout, Ho, Wo) with
/// Ho = (H + 2·ph − kh) / sh + 1 and Wo = (W + 2·pw − kw) / sw + 1.
///
/// # Gradient
/// `y[n, o, i, j]` = `b[o]` + Σ_{c, ki, kj} `w[o, c, ki, kj]` · `x[n, c, i·sh + ki − ph, j·sw + kj − pw]`; see `conv2d_bwd`.
///
/// Torch: `F.conv2d(x, w, b, stride=cfg.stride, padding=cfg.padding)`.
pub fn conv2d_fwd<F: Float>(x: ArrayViewD<F>, w: ArrayViewD<F>, b: Option<ArrayViewD<F>>, cfg: &Conv2dCfg) -> Result<Array4<F>> {
    conv2d_fwd_ex(x, w, b, cfg, false, Conv2dRun::selected())
}

/// [`conv2d_fwd`] with the ReLU fused into the epilogue when `relu` (y = max(conv + b, 0), as
/// `F.relu(F.conv2d(..))`), on an explicit GEMM plan (any ISA path) and Winograd choice.
pub fn conv2d_fwd_ex<F: Float>(x: ArrayViewD<F>, w: ArrayViewD<F>, b: Option<ArrayViewD<F>>, cfg: &Conv2dCfg, relu: bool,
                               run: Conv2dRun<F>) -> Result<Array4<F>> {
    let b = b.map(|b| fixed::<_, Ix1>(OP, "bias", b)).transpose()?;
    let ops = Operands::new(x, w, b.as_ref().map(|b| b.shape()), cfg)?;
    let bias = b.as_ref().map(|b| b.to_vec());
    forward(run, &ops.g, ops.x()?, ops.wmat()?, bias.as_deref(), relu)
}

/// Output pixels per forward task: two tasks per thread over the batch at least, whole NR panels.
/// (Every output element is the same chain whatever the tiles, so they may follow the threads.)
fn forward_tile<F>(g: &Geom, plan: &Plan<F>) -> usize {
    let per_image = (2 * rayon::current_num_threads()).div_ceil(g.n);
    g.pix().div_ceil(per_image).next_multiple_of(plan.nr).min(g.pix()).max(1)
}

/// `Y[n][:, tile]` = W · cols(`x[n]`)[:, tile] (+ b, then ReLU) by tasks (image, tile): one GEMM per
/// task, W packed once for all of them, cols built straight into the GEMM's packed B panels (x
/// itself for a pointwise conv); Winograd or [`tap_major`] where they apply.
fn forward<F: Float>(run: Conv2dRun<F>, g: &Geom, xs: &[F], wm: ArrayView2<F>, bias: Option<&[F]>, relu: bool)
                     -> Result<Array4<F>> {
    let plan = run.plan;
    if let (true, Some(w)) = (run.winograd_for(g), wm.as_slice()) {
        return winograd::forward(plan, g, xs, w, bias, relu, run.reuse_kernels)?.into_shape_with_order((g.n, g.cout, g.ho, g.wo)).map_err(layout);
    }
    if tap_major::applies(g) {
        return tap_major::forward(run, g, xs, wm, bias, relu);
    }
    let wpack = Prepacked::new(plan, &Strided::view(wm, F::one()));
    let tile = forward_tile(g, plan);
    // every element is written by its task's GEMM (Init::Zero or Init::Bias starts each chain), so y
    // is not zeroed first
    let mut y = Array3::<F>::uninit((g.n, g.cout, g.pix()));
    y.outer_iter_mut().into_par_iter().enumerate().for_each(|(n, mut yn)| {
        let xn = &xs[n * g.img()..(n + 1) * g.img()];
        yn.axis_chunks_iter_mut(Axis(1), tile).into_par_iter().enumerate().for_each(|(t, mut yt)| {
            let px = t * tile..t * tile + yt.ncols();
            let (rsc, c) = (yt.strides()[0], yt.as_mut_ptr().cast::<F>());
            let init = bias.map_or(Init::Zero, |b| Init::Bias(b.as_ptr()));
            // x[n] as [Cin, H·W], columns of the tile (only a pointwise conv's output pixels are input pixels)
            let xt = g.pointwise().then(|| Strided {
                ptr: xn[px.start..].as_ptr(), rows: g.cin, cols: px.len(), rs: g.pix() as isize, cs: 1, scale: F::one(),
            });
            let cols = Im2colB { g, xn, tile: px.clone() };
            let b: &dyn PackB<F> = match &xt { Some(xt) => xt, None => &cols };
            // Y[n][:, tile] = W · cols[:, tile] (+ b, ReLU)
            // SAFETY: C is this task's own block of y (Cout x tile, row stride H·W); A has Cout rows,
            // B the tile's columns, both over K; the bias has Cout values.
            unsafe { gemm::run(plan, g.cout, px.len(), g.k(), SourceA::Rows(&wpack, 0), b, c, rsc, 1, init, relu) };
        });
    });
    // SAFETY: the tasks' tiles cover every image and pixel, and each GEMM writes all Cout rows of its tile.
    unsafe { y.assume_init() }.into_shape_with_order((g.n, g.cout, g.ho, g.wo)).map_err(layout)
}

/// Gradients of `conv2d_fwd` w.r.t. the input, the weight and the bias (only those in `need`).
///
/// # Shapes
/// x (N, Cin, H, W), w (Cout, Cin, kh, kw), g (N, Cout, Ho, Wo) -> dx like x, dw like w, db (Cout).
///
/// # Gradient
/// `dX[n]` = col2im(Wᵀ · `dY[n]`); dW = Σ_n `dY[n]` · cols(`x[n]`)ᵀ; `db[o]` = Σ_{n,i,j} `dY[n, o, i, j]`.
///
/// Torch: `torch.autograd.grad(F.conv2d(x, w, b, stride, padding), (x, w, b), g)`.
pub fn conv2d_bwd<F: Float>(x: ArrayViewD<F>, w: ArrayViewD<F>, g: ArrayViewD<F>, cfg: &Conv2dCfg,
                            need: Conv2dNeed) -> Result<Conv2dGrads<F>> {
    conv2d_bwd_ex(x, w, g, cfg, need, Conv2dRun::selected())
}

/// [`conv2d_bwd`] on an explicit GEMM plan (any ISA path) and Winograd choice (for dX and dW).
pub fn conv2d_bwd_ex<F: Float>(x: ArrayViewD<F>, w: ArrayViewD<F>, g: ArrayViewD<F>, cfg: &Conv2dCfg, need: Conv2dNeed,
                               run: Conv2dRun<F>) -> Result<Conv2dGrads<F>> {
    let gshape = g.shape().to_vec();
    let ops = Operands::new(x, w, None, cfg)?;
    let geo = ops.g;
    let expect = [geo.n, geo.cout, geo.ho, geo.wo];
    if gshape != expect {
        return Err(Error::shape(OP, format!("grad_output must have shape {expect:?}"),
                                &[("input", ops.x.shape()), ("weight", ops.w.shape()), ("grad_output", &gshape)]));
    }
    let dy = g.as_standard_layout();
    let dys = dy.as_slice().ok_or_else(|| Error::shape(OP, "internal layout error: grad_output", &[]))?;
    let dx = if need.x { Some(input_grad(run, &geo, ops.wmat()?, dys)?) } else { None };
    let dw = if need.w { Some(weight_grad(run, &geo, ops.x()?, dys)?) } else { None };
    let db = need.b.then(|| bias_grad(&geo, dys));
    Ok(Conv2dGrads { x: dx, w: dw, b: db })
}

/// For stride 1 with padding below the kernel size, dX is itself a convolution, computed by
/// [`forward`]: `dX[n, c, y, x]` = Σ_{o, ki, kj} `W[o, c, ki, kj]` · `dY[n, o, y − ki + ph, x − kj + pw]`
/// = conv(dY, W'), W'`[c, o, ki', kj']` = `W[o, c, kh−1−ki', kw−1−kj']`, padding (kh−1−ph, kw−1−pw).
/// None when that does not apply (stride > 1, or a pointwise conv, which is one plain GEMM).
fn input_grad_as_conv<F: Float>(run: Conv2dRun<F>, g: &Geom, wm: ArrayView2<F>, dy: &[F]) -> Option<Result<Array4<F>>> {
    if g.stride != [1, 1] || g.pointwise() || g.pad[0] >= g.kh || g.pad[1] >= g.kw {
        return None;
    }
    let pad = [g.kh - 1 - g.pad[0], g.kw - 1 - g.pad[1]];
    let (h, w) = Conv2dCfg::new([1, 1], pad).out_hw(g.ho, g.wo, g.kh, g.kw).ok()?;
    if (h, w) != (g.h, g.w) {
        return None;
    }
    let taps = g.kh * g.kw;
    let wm = wm.as_standard_layout();
    let w = wm.as_slice()?;
    // every element is written below, so W' is not zeroed first (a fresh zeroed block costs page faults)
    let mut wt = Array2::<F>::uninit((g.cin, g.cout * taps));
    wt.as_slice_mut()?.par_chunks_mut(g.cout * taps).enumerate().for_each(|(c, row)| {
        for (o, dst) in row.chunks_exact_mut(taps).enumerate() {
            // W'[c, o·taps + t'] = W[o, c·taps + taps − 1 − t'] (t' = ki'·kw + kj' runs the taps backwards)
            let src = &w[(o * g.cin + c) * taps..][..taps];
            dst.iter_mut().zip(src.iter().rev()).for_each(|(d, &v)| {
                d.write(v);
            });
        }
    });
    // SAFETY: the rows cover W' and each row's Cout chunks of `taps` values are all written.
    let wt = unsafe { wt.assume_init() };
    let gt = Geom { n: g.n, cin: g.cout, h: g.ho, w: g.wo, cout: g.cin, kh: g.kh, kw: g.kw, ho: g.h, wo: g.w, stride: [1, 1], pad };
    Some(forward(run, &gt, dy, wt.view(), None, false))
}

/// dX, by tasks (image, input-channel chunk) that each own `dX[n, chunk]`. The tiles are taken in
/// bands of about `BAND_BYTES` of dY, all tasks finishing one band before the next starts, so a
/// band of dY is read from memory once and then from cache by every chunk.
fn input_grad<F: Float>(run: Conv2dRun<F>, g: &Geom, wm: ArrayView2<F>, dy: &[F]) -> Result<Array4<F>> {
    if let Some(dx) = input_grad_as_conv(run, g, wm, dy) {
        return dx;
    }
    let plan = run.plan;
    let taps = g.kh * g.kw;
    let (plane, out_len) = (g.h * g.w, g.cout * g.pix());
    // Fewest chunks the row cap allows; more when the threads need more tasks (a multiple of them).
    let threads = rayon::current_num_threads();
    let min_chunks = g.k().div_ceil(CHUNK_ROWS).min(g.cin);
    let chunks = (2 * threads).div_ceil(g.n).max(min_chunks).next_multiple_of(threads).min(g.cin);
    let cc = g.cin.div_ceil(chunks);
    // The tile depends on the shapes only (the widest chunk), so the sums do not depend on the threads.
    let tile = tile_len::<F>(g.pix(), g.cin.div_ceil(min_chunks) * taps, 1, plan.nr);
    let band = tile * (BAND_BYTES / (g.cout * tile * std::mem::size_of::<F>()).max(1)).max(1);
    // Zeroed by both threads with writes (`tensor::zeros`): col2im's first access is a
    // read-modify-write, and writing a page first read as the shared zero page costs a copy-on-write
    // fault and a TLB flush on every CPU (a third of the time of a large dX on 2 cores).
    let mut dx = zeros::<F, _>(OP, (g.n, g.cin, plane))?;
    for b0 in (0..g.pix()).step_by(band) {
        let band = b0..(b0 + band).min(g.pix());
        dx.outer_iter_mut().into_par_iter().enumerate().try_for_each(|(n, mut dxn)| {
            let dyn_ = mat(&dy[n * out_len..(n + 1) * out_len], g.cout, g.pix())?;
            dxn.axis_chunks_iter_mut(Axis(0), cc).into_par_iter().enumerate().try_for_each(|(ci, mut dxc)| {
                let chans = ci * cc..ci * cc + dxc.nrows();
                let rows = chans.len() * taps;
                // W[:, chunk]ᵀ: [rows, Cout]
                let wt = wm.slice(s![.., chans.start * taps..chans.end * taps]).reversed_axes();
                for px in tiles(band.len(), tile).map(|t| band.start + t.start..band.start + t.end) {
                    let dyt = dyn_.slice(s![.., px.clone()]);
                    if g.pointwise() {
                        // dX[n, chunk, tile] = W[:, chunk]ᵀ · dY[n][:, tile]
                        gemm_ex(plan, F::one(), wt, dyt, F::zero(), dxc.slice_mut(s![.., px]), Epilogue::default());
                        continue;
                    }
                    let dxs = dxc.as_slice_mut().ok_or_else(|| Error::shape(OP, "internal layout error: dx", &[]))?;
                    with_scratch(rows * px.len(), |buf: &mut [F]| {
                        let dcols = ArrayViewMut2::from_shape((rows, px.len()), &mut *buf).map_err(layout)?;
                        // dcols = W[:, chunk]ᵀ · dY[n][:, tile]
                        gemm_ex(plan, F::one(), wt, dyt, F::zero(), dcols, Epilogue::default());
                        col2im(g, &mut buf[..rows * px.len()], chans.len(), px.clone(), dxs);
                        Ok::<_, Error>(())
                    })?;
                }
                Ok::<_, Error>(())
            })
        })?;
    }
    dx.into_shape_with_order((g.n, g.cin, g.h, g.w)).map_err(layout)
}

/// Input channels from which dW takes the pixel-major path (below, its rows of Cin contiguous
/// values are too short to beat im2col + transposed packing).
const NHWC_MIN_CIN: usize = 16;

/// dW as `DW_GROUPS` partial sums, fixed by the shapes and added in group order; each group is one
/// chain of GEMMs over its (image, pixel range) pieces in order. Group 0 sums straight into the
/// result, the others into this thread's reused `PARTIALS` buffer; the first piece of a group
/// overwrites (Init::Zero), so no buffer needs clearing.
///
/// Two ways to feed the GEMM `dW (+)= dY[n][:, range] · cols[:, range]ᵀ`:
/// - pixel-major (Cin >= `NHWC_MIN_CIN`, not pointwise): x is transposed once to `xᵀ[n][p, c]`, and
///   K is ordered tap-major (k' = t·Cin + c), so each B row (one pixel) is `taps` contiguous runs
///   of Cin values of xᵀ (zeros for taps in the padding); the result is permuted back to c·taps + t;
/// - otherwise: cols tiles in this thread's scratch (x itself when pointwise), packed transposed;
///   the GEMM computes dWᵀ instead where that pads less to the micro-tile (Cout wider than K).
///
/// A stride-1 3x3 f32 conv with enough channels takes [`winograd::weight_grad`] instead, a stride-1
/// conv with one or two output channels [`tap_major::weight_grad`].
fn weight_grad<F: Float>(run: Conv2dRun<F>, g: &Geom, xs: &[F], dy: &[F]) -> Result<Array4<F>> {
    let plan = run.plan;
    if run.winograd_if(g, winograd::weight_grad_pays) {
        return winograd::weight_grad(plan, g, xs, dy).into_shape_with_order((g.cout, g.cin, g.kh, g.kw)).map_err(layout);
    }
    if tap_major::applies(g) {
        return tap_major::weight_grad(run, g, xs, dy)?.into_shape_with_order((g.cout, g.cin, g.kh, g.kw)).map_err(layout);
    }
    let (pix, wlen, taps) = (g.pix(), g.cout * g.k(), g.kh * g.kw);
    let nhwc = g.cin >= NHWC_MIN_CIN && !g.pointwise();
    // the pieces: (image, pixel range), NHWC: the n·pix pixels cut in DW_GROUPS ranges; else tiles
    let pieces: Vec<Vec<(usize, Range<usize>)>> = if nhwc {
        let total = g.n * pix;
        let groups = DW_GROUPS.min(total).max(1);
        (0..groups)
            .map(|gi| {
                // global pixels [gi·total / groups, (gi + 1)·total / groups), split at image ends
                let (a, b) = (gi * total / groups, (gi + 1) * total / groups);
                (a / pix..b.div_ceil(pix)).map(|n| (n, a.max(n * pix) - n * pix..b.min(n * pix + pix) - n * pix))
                    .filter(|(_, r)| !r.is_empty())
                    .collect()
            })
            .collect()
    } else {
        let tile = tile_len::<F>(pix, scratch_rows(g, g.cin), DW_GROUPS.div_ceil(g.n), 8);
        let work: Vec<(usize, Range<usize>)> = (0..g.n).flat_map(|n| tiles(pix, tile).map(move |t| (n, t))).collect();
        let groups = DW_GROUPS.min(work.len()).max(1);
        (0..groups).map(|gi| work[gi * work.len() / groups..(gi + 1) * work.len() / groups].to_vec()).collect()
    };
    // xᵀ[n][q, c] = x[n][c, q] over the input pixels q
    let xt: Vec<F> = if nhwc {
        let mut xt = vec![F::zero(); xs.len()];
        xt.par_chunks_mut(g.img()).zip(xs.par_chunks(g.img())).for_each(|(t, x)| gemm::transpose(plan, x, g.cin, g.h * g.w, t));
        xt
    } else {
        Vec::new()
    };
    // the GEMM dY·colsᵀ (M = Cout, N = K) or its transpose cols·dYᵀ (M = K, N = Cout), whichever
    // pads less to whole MR x NR micro-tiles (same products summed in the same order either way)
    let padded = |rows: usize, cols: usize| rows.next_multiple_of(plan.mr) * cols.next_multiple_of(plan.nr);
    let transposed = !nhwc && padded(g.k(), g.cout) < padded(g.cout, g.k());
    let groups = pieces.len();
    let mut dw = Array2::<F>::zeros((g.cout, g.k()));
    with_buf(&PARTIALS, (groups - 1) * wlen, |rest: &mut [F]| {
        let mut parts = vec![dw.view_mut()];
        for chunk in rest.chunks_exact_mut(wlen) {
            parts.push(ArrayViewMut2::from_shape((g.cout, g.k()), chunk).map_err(layout)?);
        }
        parts.into_par_iter().zip(&pieces).try_for_each(|(mut part, pieces)| {
            for (t, (n, px)) in pieces.iter().enumerate() {
                let dyt = mat(&dy[n * g.cout * pix..(n + 1) * g.cout * pix], g.cout, pix)?.slice_move(s![.., px.clone()]);
                let beta = if t == 0 { F::zero() } else { F::one() };
                if nhwc {
                    // dW'[:, t·Cin + c] (+)= dY[n][:, range] · colsᵀ (tap-major K)
                    let a = Strided::view(dyt, F::one());
                    let b = NhwcColsT { g, xt: &xt[n * g.img()..(n + 1) * g.img()], px0: px.start };
                    let init = if t == 0 { Init::Zero } else { Init::Load };
                    let (rsc, c) = (part.strides()[0], part.as_mut_ptr());
                    // SAFETY: C is this group's own Cout x K matrix; A has Cout rows and B K columns,
                    // both over the range's pixels.
                    unsafe { gemm::run(plan, g.cout, g.k(), px.len(), SourceA::Strided(&a), &b, c, rsc, 1, init, false) };
                    continue;
                }
                let xn = &xs[n * g.img()..(n + 1) * g.img()];
                for_each_cols_block(g, xn, 0..g.cin, g.cin, px.clone(), |_, cols| {
                    if transposed {
                        // dW_groupᵀ (+)= cols[:, tile] · dY[n][:, tile]ᵀ
                        gemm_ex(plan, F::one(), cols, dyt.t(), beta, part.view_mut().reversed_axes(), Epilogue::default())
                    } else {
                        // dW_group (+)= dY[n][:, tile] · cols[:, tile]ᵀ
                        gemm_ex(plan, F::one(), dyt, cols.t(), beta, part.view_mut(), Epilogue::default())
                    }
                })?;
            }
            Ok::<_, Error>(())
        })?;
        // dW = Σ_groups partial, in group order, one output row per task
        let rest = mat(rest, (groups - 1) * g.cout, g.k())?;
        dw.axis_iter_mut(Axis(0)).into_par_iter().enumerate().for_each(|(o, mut row)| {
            (0..groups - 1).for_each(|p| row += &rest.row(p * g.cout + o));
        });
        Ok(())
    })?;
    if nhwc {
        let mut perm = Array2::<F>::zeros((g.cout, g.k()));
        perm.outer_iter_mut().into_par_iter().zip(dw.outer_iter()).for_each(|(mut dst, src)| {
            let (dst, src) = (dst.as_slice_mut(), src.as_slice());
            if let (Some(dst), Some(src)) = (dst, src) {
                for (c, d) in dst.chunks_exact_mut(taps).enumerate() {
                    // dW[o, c·taps + t] = dW'[o, t·Cin + c]
                    d.iter_mut().enumerate().for_each(|(t, d)| *d = src[t * g.cin + c]);
                }
            }
        });
        dw = perm;
    }
    dw.into_shape_with_order((g.cout, g.cin, g.kh, g.kw)).map_err(layout)
}

/// colsᵀ with tap-major K (k' = t·Cin + c) over pixels `px0 + ..` of one image, from xᵀ (`[H·W, Cin]`):
/// B(p, t·Cin + c) = xᵀ[q, c] with q the input pixel tap t of output pixel p reads (0 in the padding).
struct NhwcColsT<'a, F> {
    g: &'a Geom,
    xt: &'a [F],
    px0: usize,
}

impl<F: Float> PackB<F> for NhwcColsT<'_, F> {
    fn pack(&self, _plan: &Plan<F>, p0: usize, kc: usize, j0: usize, nc: usize, dst: *mut F, ldb: usize) {
        let (g, cin) = (self.g, self.g.cin);
        let ([sh, sw], [ph, pw]) = (g.stride, g.pad);
        // SAFETY: the GEMM's buffer holds kc rows of ldb elements.
        let block = unsafe { std::slice::from_raw_parts_mut(dst, kc * ldb) };
        for (kk, row) in block.chunks_exact_mut(ldb).enumerate() {
            // output pixel p = (oy, ox)
            let p = self.px0 + p0 + kk;
            let (oy, ox) = (p / g.wo, p % g.wo);
            let mut j = j0;
            while j < j0 + nc {
                // k' = j = t·Cin + c: the run of channels c.. of tap t = (ki, kj) inside this block
                let (t, c) = (j / cin, j % cin);
                let len = (cin - c).min(j0 + nc - j);
                // input pixel (iy, ix) = (oy·sh + ki − ph, ox·sw + kj − pw)
                let iy = (oy * sh + t / g.kw).checked_sub(ph).filter(|&iy| iy < g.h);
                let ix = (ox * sw + t % g.kw).checked_sub(pw).filter(|&ix| ix < g.w);
                let out = &mut row[j - j0..j - j0 + len];
                match (iy, ix) {
                    (Some(iy), Some(ix)) => out.copy_from_slice(&self.xt[(iy * g.w + ix) * cin + c..][..len]),
                    _ => out.fill(F::zero()),
                }
                j += len;
            }
            zero(&mut row[nc..]);
        }
    }
}

/// `db[o]` = Σ_n Σ_p `dY[n, o, p]`: each image's plane by [`lanes::sum`] (vectorised, f64 across
/// blocks), the images in order in f64.
fn bias_grad<F: Float>(g: &Geom, dy: &[F]) -> Array1<F> {
    let pix = g.pix();
    let sums: Vec<F> = (0..g.cout)
        .into_par_iter()
        .map(|o| {
            let total = (0..g.n).fold(0.0, |acc, n| {
                // plane (n, o) of dY starts at (n·Cout + o)·pix
                let start = (n * g.cout + o) * pix;
                let mut plane = 0.0;
                lanes::sum(&dy[start..start + pix], &mut plane);
                acc + plane
            });
            F::from_f64(total).unwrap_or(F::nan())
        })
        .collect();
    Array1::from(sums)
}
