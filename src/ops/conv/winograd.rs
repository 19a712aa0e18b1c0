//! Winograd F(4x4, 3x3) for stride-1 3x3 convolutions: each 4 x 4 block of output pixels (a tile)
//! from a 6 x 6 input patch with 36 multiplies per (output, input) channel pair instead of 144.
//!
//! `Y_tile[o]` = Aᵀ [ Σ_c U[o, c] ⊙ V[c] ] A with U[o, c] = G · `w[o, c]` · Gᵀ (6 x 6, once per call)
//! and V[c] = Bᵀ · `d[c]` · B (6 x 6, the input patch transformed): the channel sum is 36
//! independent GEMMs `M_ξ` = `U_ξ` · `V_ξ` ([Cout, Cin] · [Cin, tiles]) on the packed GEMM, one per
//! position ξ of the 6 x 6 transform. Matrices from Lavin & Gray (2016), points 0, ±1, ±2, ∞.
//! The weight gradient is the adjoint of the same algorithm (see [`weight_grad`]): 36 GEMMs over
//! the tiles, then `dW[o, c]` = Gᵀ · `dU[o, c]` · G.
//!
//! Work is split into tasks (image, band of tile rows, range of output channels) fixed by the
//! shapes and the thread count; every output is computed from its own tile by the same sequence of
//! operations whatever the split, so results do not depend on it (nor on the threads). f32 rounds
//! differently from the direct convolution (the transforms add and scale); `tests_rs/conv.rs`
//! measures the error against f64.

use super::Geom;
use crate::gemm::{self, Init, Isa, Plan, Prepacked, SourceA, Strided};
use crate::{Float, Result};
use ndarray::{Array2, Array3};
use rayon::prelude::*;
use std::ops::{Add, Mul, Range, Sub};

/// Positions of the 6 x 6 transform.
const XI: usize = 36;
/// Output pixels per tile side.
const TILE: usize = 4;

/// Fewest channels (in and out) for Winograd: below, its per-channel transforms outweigh the
/// multiplies it saves.
const MIN_CHANNELS: usize = 32;
/// Fewest tiles over the batch: the weight transform (per channel pair, about as costly as the
/// GEMM work of 100 tiles) must be amortised.
const MIN_TILES: usize = 512;

/// Whether Winograd can compute this convolution: a 3x3 kernel, stride 1, padding at most 2 per
/// axis (a patch then always overlaps the image).
pub(super) fn applies(g: &Geom) -> bool {
    g.kh == 3 && g.kw == 3 && g.stride == [1, 1] && g.pad[0] <= 2 && g.pad[1] <= 2
}

/// Whether it pays: enough channels and tiles for the transforms to cost less than they save.
pub(super) fn pays(g: &Geom) -> bool {
    let tiles = g.n * g.ho.div_ceil(TILE) * g.wo.div_ceil(TILE);
    g.cin.min(g.cout) >= MIN_CHANNELS && tiles >= MIN_TILES
}

/// Least Cin·Cout / (Cin + Cout) for the Winograd weight gradient: per tile it transforms Cin + Cout
/// planes and then saves GEMM work in proportion to Cin·Cout, and its two GEMM operands are both
/// packed per call (the forward's weights are packed once). Measured on an AMD Zen 4 (2 threads),
/// dW against the direct path: 64->64 and 96->96 (32, 48) slower, 128->94 (54) even,
/// 128->128 (64) 1.2x faster, 128->256 (85) 1.35x, 352->256 (148) 1.9x.
const MIN_DW_CHANNEL_RATIO: usize = 56;

/// Whether the Winograd weight gradient pays (see [`MIN_DW_CHANNEL_RATIO`]).
pub(super) fn weight_grad_pays(g: &Geom) -> bool {
    pays(g) && g.cin * g.cout >= MIN_DW_CHANNEL_RATIO * (g.cin + g.cout)
}

/// What the 1-D transforms compute on: one value F, or [`Lanes`] of F (one per tile).
trait Lane<F>: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<F, Output = Self> {}
impl<F: Float> Lane<F> for F {}
impl<F: Float> Lane<F> for Lanes<F> {}

/// Tiles per block of the row transforms: one 512-bit register of f32.
const LANES: usize = 16;

/// One value per tile for LANES tiles. Its operations are fixed-length loops, which the compiler
/// turns into vector instructions; each lane computes exactly what the scalar path computes.
#[derive(Clone, Copy)]
struct Lanes<F>([F; LANES]);

/// `impl $tr for Lanes<F>`: the lane-wise binary operation `$op`.
macro_rules! lanes_op {
    ($tr:ident, $method:ident, $op:tt) => {
        impl<F: Float> $tr for Lanes<F> {
            type Output = Self;
            #[inline(always)]
            fn $method(self, o: Self) -> Self {
                let mut r = self.0;
                for (x, &y) in r.iter_mut().zip(&o.0) {
                    *x = *x $op y;
                }
                Lanes(r)
            }
        }
    };
}

lanes_op!(Add, add, +);
lanes_op!(Sub, sub, -);

impl<F: Float> Mul<F> for Lanes<F> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, k: F) -> Self {
        let mut r = self.0;
        for x in r.iter_mut() {
            *x = *x * k;
        }
        Lanes(r)
    }
}

/// A 1-D transform of M values into N, written once for one value and for [`Lanes`].
trait Transform1d<const M: usize, const N: usize> {
    fn apply<F: Float, T: Lane<F>>(d: [T; M]) -> [T; N];
}

/// v = Bᵀ d for one 6-vector d: the input transform along one axis.
struct InputTransform;

impl Transform1d<6, 6> for InputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(d: [T; 6]) -> [T; 6] {
        let (c2, c4, c5, m2, m4) = (F::c(2.0), F::c(4.0), F::c(5.0), F::c(-2.0), F::c(-4.0));
        [
            d[0] * c4 - d[2] * c5 + d[4],
            d[1] * m4 - d[2] * c4 + d[3] + d[4],
            d[1] * c4 - d[2] * c4 - d[3] + d[4],
            d[1] * m2 - d[2] + d[3] * c2 + d[4],
            d[1] * c2 - d[2] - d[3] * c2 + d[4],
            d[1] * c4 - d[3] * c5 + d[5],
        ]
    }
}

/// dst[k][tx] = X(src[0][tx], .., src[M − 1][tx])[k] for every tile tx of the rows: blocks of LANES
/// tiles on [`Lanes`], the rest one tile at a time (the same operations on F).
#[inline(always)]
fn map_tiles<F: Float, X: Transform1d<M, N>, const M: usize, const N: usize>(src: [&[F]; M], dst: &mut [&mut [F]; N]) {
    let tw = dst[0].len();
    let full = tw / LANES * LANES;
    for t0 in (0..full).step_by(LANES) {
        // tiles t0 .. t0 + LANES of every row
        let mut d = [Lanes([F::zero(); LANES]); M];
        for (dj, sj) in d.iter_mut().zip(&src) {
            dj.0.copy_from_slice(&sj[t0..t0 + LANES]);
        }
        let out = X::apply::<F, Lanes<F>>(d);
        for (row, o) in dst.iter_mut().zip(&out) {
            row[t0..t0 + LANES].copy_from_slice(&o.0);
        }
    }
    for tx in full..tw {
        let out = X::apply::<F, F>(std::array::from_fn(|j| src[j][tx]));
        for (row, &o) in dst.iter_mut().zip(&out) {
            row[tx] = o;
        }
    }
}

/// u = G g for one 3-vector g: the weight transform along one axis.
#[inline(always)]
fn weight_1d<F: Float>(g: [F; 3]) -> [F; 6] {
    let (q, s, t) = (F::c(0.25), F::c(1.0 / 6.0), F::c(1.0 / 12.0));
    let e = F::c(1.0 / 24.0);
    [q * g[0], -s * (g[0] + g[1] + g[2]), -s * (g[0] - g[1] + g[2]), e * g[0] + t * g[1] + s * g[2],
     e * g[0] - t * g[1] + s * g[2], g[2]]
}

/// y = Aᵀ m for one 6-vector m: the output transform along one axis.
struct OutputTransform;

impl Transform1d<6, 4> for OutputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(m: [T; 6]) -> [T; 4] {
        let (c2, c4, c8) = (F::c(2.0), F::c(4.0), F::c(8.0));
        let (s12, d12, s34, d34) = (m[1] + m[2], m[1] - m[2], m[3] + m[4], m[3] - m[4]);
        [m[0] + s12 + s34, d12 + d34 * c2, s12 + s34 * c4, d12 + d34 * c8 + m[5]]
    }
}

/// m = A y for one 4-vector y: the adjoint of [`OutputTransform`] along one axis (a tile of dY
/// into the transform domain).
struct GradOutputTransform;

impl Transform1d<4, 6> for GradOutputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(y: [T; 4]) -> [T; 6] {
        let (c2, c4, c8) = (F::c(2.0), F::c(4.0), F::c(8.0));
        let (s02, d13) = (y[0] + y[2] * c4, y[1] * c2 + y[3] * c8);
        [y[0], y[0] + y[1] + y[2] + y[3], y[0] - y[1] + y[2] - y[3], s02 + d13, s02 - d13, y[3]]
    }
}

/// g = Gᵀ u for one 6-vector u: the adjoint of [`weight_1d`] along one axis.
#[inline(always)]
fn weight_grad_1d<F: Float>(u: [F; 6]) -> [F; 3] {
    let (q, s, t) = (F::c(0.25), F::c(1.0 / 6.0), F::c(1.0 / 12.0));
    let e = F::c(1.0 / 24.0);
    let (s12, d12, s34, d34) = (u[1] + u[2], u[1] - u[2], u[3] + u[4], u[3] - u[4]);
    [q * u[0] - s * s12 + e * s34, -s * d12 + t * d34, -s * s12 + s * s34 + u[5]]
}

/// The transformed weights: `U_ξ` = (G · `w[o, c]` · Gᵀ)[ξ] as 36 matrices [Cout, Cin], packed for `plan`.
fn weights<F: Float>(plan: &Plan<F>, w: &[F], cout: usize, cin: usize) -> Vec<Prepacked<F>> {
    // t[oc][ξ] = (G · w[oc] · Gᵀ)[ξ], oc = o·Cin + c, pair by pair in parallel
    let mut t = vec![F::zero(); cout * cin * XI];
    t.par_chunks_mut(XI).zip(w.par_chunks_exact(9)).for_each(|(u, g)| {
        // rows of G·g (6 x 3), then each of its rows times Gᵀ: (G g Gᵀ)[a][b] at ξ = 6a + b
        let cols: [[F; 6]; 3] = std::array::from_fn(|j| weight_1d([g[j], g[3 + j], g[6 + j]]));
        for (a, ua) in u.chunks_exact_mut(6).enumerate() {
            ua.copy_from_slice(&weight_1d([cols[0][a], cols[1][a], cols[2][a]]));
        }
    });
    // U_ξ[o, c] = t[(o·Cin + c)·36 + ξ], gathered into a plane and packed, plane by plane in parallel
    (0..XI)
        .into_par_iter()
        .map(|xi| {
            let plane: Vec<F> = t[xi..].iter().step_by(XI).copied().collect();
            let view = Strided { ptr: plane.as_ptr(), rows: cout, cols: cin, rs: cin as isize, cs: 1, scale: F::one() };
            Prepacked::new(plan, &view)
        })
        .collect()
}

/// A pointer to y shared by the tasks, each writing its own (channels x rows) part.
#[derive(Clone, Copy)]
struct YPtr<F>(*mut F);
// SAFETY: tasks write disjoint elements of y (distinct output channels or tile rows) and nothing
// reads y until all of them have finished.
unsafe impl<F> Send for YPtr<F> {}
// SAFETY: as above.
unsafe impl<F> Sync for YPtr<F> {}

impl<F> YPtr<F> {
    /// The pointer (a method, so closures capture the whole Send + Sync wrapper).
    fn get(self) -> *mut F {
        self.0
    }
}

/// One task: image n, tile rows `rows`, output channels `outs`.
#[derive(Clone, Debug)]
struct Task {
    n: usize,
    rows: Range<usize>,
    outs: Range<usize>,
}

/// The tasks: bands of tile rows holding about `band_tiles` tiles, and the output channels split
/// (in whole MR panels) when there are fewer bands than two per thread.
fn tasks<F>(plan: &Plan<F>, g: &Geom, tw: usize, th: usize, band_tiles: usize) -> Vec<Task> {
    let threads = rayon::current_num_threads();
    let rows_per_band = (band_tiles / tw).clamp(1, th);
    let bands = th.div_ceil(rows_per_band);
    let splits = (2 * threads).div_ceil(g.n * bands).min(g.cout.div_ceil(plan.mr)).max(1);
    // output channels per split: whole MR panels
    let per = g.cout.div_ceil(splits).next_multiple_of(plan.mr);
    let mut out = vec![];
    for n in 0..g.n {
        for b in 0..bands {
            for o0 in (0..g.cout).step_by(per) {
                out.push(Task { n, rows: b * rows_per_band..((b + 1) * rows_per_band).min(th), outs: o0..(o0 + per).min(g.cout) });
            }
        }
    }
    out
}

/// y = conv2d(x, w) (+ b, then ReLU) for a geometry where [`applies`] holds.
pub(super) fn forward<F: Float>(plan: &Plan<F>, g: &Geom, xs: &[F], w: &[F], bias: Option<&[F]>, relu: bool)
                                -> Result<Array3<F>> {
    let (tw, th) = (g.wo.div_ceil(TILE), g.ho.div_ceil(TILE));
    let u = weights(plan, w, g.cout, g.cin);
    // a band's V (36 x Cin x T) and M (36 x Cout x T) fill about the L2 cache, at least 2 micro-panels
    let l2 = gemm::cpu_info().l2;
    let band_tiles = (l2 / (XI * std::mem::size_of::<F>() * (g.cin + g.cout))).max(4 * plan.nr);
    let work = tasks(plan, g, tw, th, band_tiles);
    let mut y = Array3::<F>::zeros((g.n, g.cout, g.ho * g.wo));
    let yp = YPtr(y.as_mut_ptr());
    work.par_iter().for_each(|t| {
        let xn = &xs[t.n * g.img()..(t.n + 1) * g.img()];
        // SAFETY: y[n] starts n·Cout·Ho·Wo elements in; the task writes only its own part.
        let yn = unsafe { yp.get().add(t.n * g.cout * g.ho * g.wo) };
        // SAFETY: as above.
        unsafe { band(plan, g, xn, &u, bias, relu, t, tw, YPtr(yn)) };
    });
    Ok(y)
}

/// One task: input transform of its band into V, the 36 GEMMs into M, output transform into y.
///
/// # Safety
/// `yn` is y[n] (Cout x Ho x Wo); no other task writes the task's (channels, rows) part.
#[allow(clippy::too_many_arguments)]
unsafe fn band<F: Float>(plan: &Plan<F>, g: &Geom, xn: &[F], u: &[Prepacked<F>], bias: Option<&[F]>, relu: bool, t: &Task,
                         tw: usize, yn: YPtr<F>) {
    let tiles = t.rows.len() * tw;
    let outs = t.outs.len();
    super::with_scratch(XI * tiles * (g.cin + outs), |buf: &mut [F]| {
        let (v, m) = buf.split_at_mut(XI * g.cin * tiles);
        // V[ξ][c][tile]
        let plane = g.h * g.w;
        let mut rows = Rows::new(tw);
        for (c, xc) in xn.chunks_exact(plane).enumerate() {
            input_transform(plan, g, xc, t.rows.clone(), tw, v, c * tiles, g.cin * tiles, &mut rows);
        }
        for xi in 0..XI {
            // M_ξ[outs][tile] = U_ξ[outs, :] · V_ξ
            let b = Strided { ptr: v[xi * g.cin * tiles..].as_ptr(), rows: g.cin, cols: tiles, rs: tiles as isize, cs: 1, scale: F::one() };
            let c = m[xi * outs * tiles..].as_mut_ptr();
            // SAFETY: M_ξ is outs x tiles in this task's buffer; U_ξ has Cout >= t.outs.end rows and
            // V_ξ Cin x tiles, both over Cin.
            unsafe {
                gemm::run(plan, outs, tiles, g.cin, SourceA::Rows(&u[xi], t.outs.start), &b, c, tiles as isize, 1, Init::Zero,
                          false)
            };
        }
        for (oi, o) in t.outs.clone().enumerate() {
            // SAFETY: channel o of y[n] is Ho·Wo elements at o·Ho·Wo, written only by this task
            // for its tile rows.
            let yo = unsafe { std::slice::from_raw_parts_mut(yn.get().add(o * g.ho * g.wo), g.ho * g.wo) };
            let b0 = bias.map_or(F::zero(), |b| b[o]);
            output_transform(plan, g, m, oi, outs * tiles, tiles, t.rows.clone(), tw, b0, relu, yo, &mut rows);
        }
    });
}

/// Per-thread buffers of the transforms of one tile row (a few KiB, reused across calls).
struct Rows<F> {
    /// The 6 input rows of the patches, zero-padded: 6 x width.
    patch: Vec<F>,
    /// Phases of a padded row: `phase[m][tx]` = row[4·tx + m], m < 4, tx <= tw.
    phase: Vec<F>,
    /// A transform along x, per patch row or per output row: 6 x 6 x tw.
    ex: Vec<F>,
}

impl<F: Float> Rows<F> {
    fn new(tw: usize) -> Self {
        Rows { patch: vec![F::zero(); 6 * (TILE * tw + 2 + TILE)], phase: vec![F::zero(); 4 * (tw + 1)], ex: vec![F::zero(); 36 * tw] }
    }
}

/// Defines `$name`: [`input_row`] or [`output_row`] compiled with one ISA's target features, so
/// that the loops over the tiles of a row are vectorised with that ISA's registers.
macro_rules! isa_version {
    ($name:ident, $body:ident, $feat:literal, ($($arg:ident: $ty:ty),*)) => {
        /// The generic body compiled for one ISA.
        ///
        /// # Safety
        /// The CPU has the ISA.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $feat)]
        unsafe fn $name<F: Float>($($arg: $ty),*) {
            $body($($arg),*)
        }
    };
}

/// `V[ξ][c][tile]` (at `v[ξ·xi_stride + off + tile]`) = (Bᵀ d B)[ξ] for the tiles of rows `rows`,
/// d the 6 x 6 patch of channel plane `xc` at input rows 4·ty − ph.., columns 4·tx − pw.. (0 outside).
#[allow(clippy::too_many_arguments)]
fn input_transform<F: Float>(plan: &Plan<F>, g: &Geom, xc: &[F], rows: Range<usize>, tw: usize, v: &mut [F], off: usize,
                             xi_stride: usize, buf: &mut Rows<F>) {
    let (ph, pw) = (g.pad[0] as isize, g.pad[1] as isize);
    // one padded input row: r[s] = x[iy, s − pw] for s in 0..width (a whole number of tiles + 4)
    let width = TILE * (tw + 1) + 2;
    for (band_row, ty) in rows.enumerate() {
        for (r, row) in buf.patch.chunks_exact_mut(width).enumerate() {
            // input row iy = 4·ty + r − ph; columns s − pw for s in [pw, pw + W) ∩ [0, width)
            let iy = (TILE * ty) as isize + r as isize - ph;
            row.fill(F::zero());
            if iy >= 0 && (iy as usize) < g.h {
                let src = &xc[iy as usize * g.w..(iy as usize + 1) * g.w];
                let (s0, s1) = (pw as usize, (pw as usize + g.w).min(width));
                row[s0..s1].copy_from_slice(&src[..s1 - s0]);
            }
        }
        // V[ξ][c][band_row·tw + tx]
        let at = off + band_row * tw;
        match plan.isa {
            // SAFETY: the plan's ISA is supported by this CPU.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => unsafe { input_row_avx512(width, tw, buf, v, at, xi_stride) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => unsafe { input_row_avx2(width, tw, buf, v, at, xi_stride) },
            _ => input_row(width, tw, buf, v, at, xi_stride),
        }
    }
}

isa_version!(input_row_avx512, input_row, "avx512f", (width: usize, tw: usize, buf: &mut Rows<F>, v: &mut [F], at: usize, xi_stride: usize));
isa_version!(input_row_avx2, input_row, "avx2,fma", (width: usize, tw: usize, buf: &mut Rows<F>, v: &mut [F], at: usize, xi_stride: usize));

/// N disjoint rows of `len` elements of `buf`, row r at `first + r·stride` (stride >= len): the
/// destinations of a 1-D transform, as exact-length slices so the loops over them vectorise
/// (indexing `buf` at `first + r·stride + tx` kept a bounds check per element, which left the
/// transforms scalar).
#[inline(always)]
fn strided_rows_mut<F, const N: usize>(buf: &mut [F], first: usize, stride: usize, len: usize) -> [&mut [F]; N] {
    assert!(stride >= len, "strided_rows_mut: rows overlap");
    let mut rest = &mut buf[first..];
    std::array::from_fn(|r| {
        // row r spans first + r·stride .. + len; the next one starts stride after it
        let (row, tail) = std::mem::take(&mut rest).split_at_mut(len);
        rest = if r + 1 < N { &mut tail[stride - len..] } else { tail };
        row
    })
}

/// N rows of `len` elements of `buf`, row r at `first + r·stride`, as exact-length slices.
#[inline(always)]
fn strided_rows<F, const N: usize>(buf: &[F], first: usize, stride: usize, len: usize) -> [&[F]; N] {
    std::array::from_fn(|r| &buf[first + r * stride..first + r * stride + len])
}

/// The input transform of one row of tiles from its 6 padded input rows (`buf.patch`): along x per
/// patch row (into `buf.ex`), then along y into `v[ξ·xi_stride + at + tx]`. Every loop runs over
/// the tiles tx of the row on contiguous arrays.
#[inline(always)]
fn input_row<F: Float>(width: usize, tw: usize, buf: &mut Rows<F>, v: &mut [F], at: usize, xi_stride: usize) {
    let Rows { patch, phase, ex } = buf;
    for (r, row) in patch.chunks_exact(width).enumerate() {
        // phase[m][tx] = row[4·tx + m]: the patch columns j = m (and j = 4 + m from tile tx + 1)
        let (p0, rest) = phase.split_at_mut(tw + 1);
        let (p1, rest) = rest.split_at_mut(tw + 1);
        let (p2, p3) = rest.split_at_mut(tw + 1);
        for (tx, q) in row.chunks_exact(TILE).take(tw + 1).enumerate() {
            (p0[tx], p1[tx], p2[tx], p3[tx]) = (q[0], q[1], q[2], q[3]);
        }
        // d_j[tx] = row[4·tx + j]: phase j % 4 from tile tx + j / 4
        let p = |m: usize, shift: usize| &phase[m * (tw + 1) + shift..m * (tw + 1) + shift + tw];
        let (d0, d1, d2, d3, d4, d5) = (p(0, 0), p(1, 0), p(2, 0), p(3, 0), p(0, 1), p(1, 1));
        // ex[r][k][tx] = (Bᵀ d_row)[k] for the 6 values d_j = row[4·tx + j]
        let mut e = strided_rows_mut(ex, r * 6 * tw, tw, tw);
        map_tiles::<F, InputTransform, 6, 6>([d0, d1, d2, d3, d4, d5], &mut e);
    }
    for b in 0..6 {
        // column b of every patch: ex[r][b][tx] for r = 0..6 (rows 6·tw apart), along y into ξ = 6a + b
        let c = strided_rows(ex, b * tw, 6 * tw, tw);
        // V[6a + b] rows: at + (6a + b)·xi_stride, i.e. 6·xi_stride apart from b·xi_stride
        let mut out_rows = strided_rows_mut(v, b * xi_stride + at, 6 * xi_stride, tw);
        map_tiles::<F, InputTransform, 6, 6>(c, &mut out_rows);
    }
}

/// Output channel `oi` of the task: y[oy, ox] = (Aᵀ m A)[oy − 4·ty, ox − 4·tx] + b (then ReLU) for the
/// tiles of rows `rows`, m[ξ] = `M[ξ·xi_stride + oi·tiles + tile]`, clipped to Ho x Wo.
#[allow(clippy::too_many_arguments)]
fn output_transform<F: Float>(plan: &Plan<F>, g: &Geom, m: &[F], oi: usize, xi_stride: usize, tiles: usize,
                              rows: Range<usize>, tw: usize, b0: F, relu: bool, yo: &mut [F], buf: &mut Rows<F>) {
    for (band_row, ty) in rows.enumerate() {
        let at = oi * tiles + band_row * tw;
        match plan.isa {
            // SAFETY: the plan's ISA is supported by this CPU.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => unsafe { output_row_avx512(m, at, xi_stride, tw, b0, relu, buf) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => unsafe { output_row_avx2(m, at, xi_stride, tw, b0, relu, buf) },
            _ => output_row(m, at, xi_stride, tw, b0, relu, buf),
        }
        for r in 0..TILE {
            // output row 4·ty + r from the row's 4·tw values in buf.patch, clipped to Wo
            let oy = TILE * ty + r;
            if oy >= g.ho {
                break;
            }
            yo[oy * g.wo..(oy + 1) * g.wo].copy_from_slice(&buf.patch[r * TILE * tw..r * TILE * tw + g.wo]);
        }
    }
}

isa_version!(output_row_avx512, output_row, "avx512f", (m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F, relu: bool, buf: &mut Rows<F>));
isa_version!(output_row_avx2, output_row, "avx2,fma", (m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F, relu: bool, buf: &mut Rows<F>));

/// The output transform of one row of tiles: m[ξ][tx] = `m[ξ·xi_stride + at + tx]` along y (into
/// `buf.ex`), then along x, + b0 and ReLU, into 4 output rows of 4·tw values in `buf.patch`.
#[inline(always)]
fn output_row<F: Float>(m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F, relu: bool, buf: &mut Rows<F>) {
    let Rows { patch, ex, .. } = buf;
    for b in 0..6 {
        // column b: m[6a + b] for a = 0..6 (rows 6·xi_stride apart), along y into ex[b][r][tx], r < 4
        let mv = strided_rows(m, b * xi_stride + at, 6 * xi_stride, tw);
        let mut e = strided_rows_mut(&mut ex[b * TILE * tw..], 0, tw, tw);
        map_tiles::<F, OutputTransform, 6, 4>(mv, &mut e);
    }
    for r in 0..TILE {
        // output row r of every tile: (ex[b][r][tx] for b = 0..6, rows 4·tw apart) along x into
        // q[c][tx] (ex rows 24..28, free), then interleaved into columns 4·tx + c
        let (e, free) = ex.split_at_mut(6 * TILE * tw);
        let e = strided_rows(e, r * tw, TILE * tw, tw);
        let mut q = strided_rows_mut(free, 0, tw, tw);
        map_tiles::<F, OutputTransform, 6, 4>(e, &mut q);
        let out_row = &mut patch[r * TILE * tw..(r + 1) * TILE * tw];
        for (tx, quad) in out_row.chunks_exact_mut(TILE).enumerate() {
            for (c, slot) in quad.iter_mut().enumerate() {
                let o = q[c][tx] + b0;
                *slot = if relu { o.max(F::zero()) } else { o };
            }
        }
    }
}

/// V and dM bytes of one chunk of tile rows in the weight gradient (a chunk's 36 GEMMs then have
/// K = its tiles; the chunks are fixed by the shapes, so dW does not depend on the threads).
const DW_CHUNK_BYTES: usize = 12 << 20;

/// dW of a convolution where [`applies`] holds, as the matrix `[Cout, Cin·9]`: with M = U ⊙ V per
/// tile (see the module doc), dU_ξ = Σ_tiles dM_ξ · V_ξᵀ ([Cout, tiles] · [tiles, Cin]) where
/// dM = A · `dY_tile` · Aᵀ (the adjoint of the output transform), then `dW[o, c]` = Gᵀ · `dU[o, c]` · G.
///
/// The tiles (image-major, whole tile rows) are taken in chunks: per chunk, V and dM are
/// transformed in parallel over channels, then the 36 GEMMs run in parallel over ξ, each summing
/// into its own dU_ξ (the first chunk overwrites, the others add), in chunk order.
pub(super) fn weight_grad<F: Float>(plan: &Plan<F>, g: &Geom, xs: &[F], dy: &[F]) -> Array2<F> {
    let (tw, th) = (g.wo.div_ceil(TILE), g.ho.div_ceil(TILE));
    let (plane, pix) = (g.h * g.w, g.ho * g.wo);
    let row_bytes = XI * tw * (g.cin + g.cout) * std::mem::size_of::<F>();
    let chunk_rows = (DW_CHUNK_BYTES / row_bytes).max(1).min(g.n * th);
    let mut v = vec![F::zero(); g.cin * XI * chunk_rows * tw];
    let mut dm = vec![F::zero(); g.cout * XI * chunk_rows * tw];
    let mut du = vec![F::zero(); XI * g.cout * g.cin];
    for (ci, r0) in (0..g.n * th).step_by(chunk_rows).enumerate() {
        let chunk = r0..(r0 + chunk_rows).min(g.n * th);
        let tiles = chunk.len() * tw;
        // the chunk's pieces (image n, its tile rows, first tile in the chunk): global row q = n·th + ty
        let pieces: Vec<(usize, Range<usize>, usize)> = (chunk.start / th..chunk.end.div_ceil(th))
            .map(|n| {
                let (a, b) = (chunk.start.max(n * th), chunk.end.min((n + 1) * th));
                (n, a - n * th..b - n * th, (a - chunk.start) * tw)
            })
            .collect();
        // V[c][ξ][tile] for the chunk, channel by channel
        v[..g.cin * XI * tiles].par_chunks_mut(XI * tiles).enumerate().for_each_init(
            || Rows::new(tw),
            |buf, (c, vc)| {
                for (n, rows, off) in &pieces {
                    let xc = &xs[n * g.img() + c * plane..][..plane];
                    input_transform(plan, g, xc, rows.clone(), tw, vc, *off, tiles, buf);
                }
            },
        );
        // dM[o][ξ][tile] for the chunk, output channel by output channel
        dm[..g.cout * XI * tiles].par_chunks_mut(XI * tiles).enumerate().for_each_init(
            || Rows::new(tw),
            |buf, (o, mo)| {
                for (n, rows, off) in &pieces {
                    let dyo = &dy[(n * g.cout + o) * pix..][..pix];
                    grad_output_transform(plan, g, dyo, rows.clone(), tw, mo, *off, tiles, buf);
                }
            },
        );
        let (vs, ms) = (&v, &dm);
        du.par_chunks_mut(g.cout * g.cin).enumerate().for_each(|(xi, dux)| {
            let init = if ci == 0 { Init::Zero } else { Init::Load };
            // dU_ξ (+)= dM_ξ · V_ξᵀ: dM_ξ[o, t] at o·36·T + ξ·T + t, V_ξᵀ[t, c] at c·36·T + ξ·T + t
            let a = Strided { ptr: ms[xi * tiles..].as_ptr(), rows: g.cout, cols: tiles, rs: (XI * tiles) as isize, cs: 1, scale: F::one() };
            let b = Strided { ptr: vs[xi * tiles..].as_ptr(), rows: tiles, cols: g.cin, rs: 1, cs: (XI * tiles) as isize, scale: F::one() };
            // SAFETY: dU_ξ is this task's own Cout x Cin plane; A and B lie inside the chunk's dM and V.
            unsafe { gemm::run(plan, g.cout, g.cin, tiles, SourceA::Strided(&a), &b, dux.as_mut_ptr(), g.cin as isize, 1, init, false) };
        });
    }
    let mut dw = Array2::<F>::zeros((g.cout, g.cin * 9));
    let pairs = g.cout * g.cin;
    if let Some(d) = dw.as_slice_mut() {
        d.par_chunks_mut(9).enumerate().for_each(|(oc, w9)| {
            // dU[o, c] = (dU_ξ[o, c] for ξ = 6a + b), oc = o·Cin + c; rows of Gᵀ·dU (over b), then
            // dW[o, c][i][j] = (Gᵀ · column j of them)[i]
            let r: [[F; 3]; 6] = std::array::from_fn(|a| weight_grad_1d(std::array::from_fn(|b| du[(6 * a + b) * pairs + oc])));
            for j in 0..3 {
                let col = weight_grad_1d(std::array::from_fn(|a| r[a][j]));
                for (i, &value) in col.iter().enumerate() {
                    w9[3 * i + j] = value;
                }
            }
        });
    }
    dw
}

/// `dM[ξ][tile]` (at `dm[ξ·xi_stride + off + tile]`) = (A · y · Aᵀ)[ξ] for the tiles of rows `rows`,
/// y the 4 x 4 block of the dY plane `dyo` at rows 4·ty.., columns 4·tx.. (0 outside Ho x Wo).
#[allow(clippy::too_many_arguments)]
fn grad_output_transform<F: Float>(plan: &Plan<F>, g: &Geom, dyo: &[F], rows: Range<usize>, tw: usize, dm: &mut [F],
                                   off: usize, xi_stride: usize, buf: &mut Rows<F>) {
    let width = TILE * tw;
    for (band_row, ty) in rows.enumerate() {
        for (r, row) in buf.patch.chunks_exact_mut(width).take(TILE).enumerate() {
            // dY row oy = 4·ty + r, columns 0..Wo, zero beyond
            let oy = TILE * ty + r;
            row.fill(F::zero());
            if oy < g.ho {
                row[..g.wo].copy_from_slice(&dyo[oy * g.wo..(oy + 1) * g.wo]);
            }
        }
        let at = off + band_row * tw;
        match plan.isa {
            // SAFETY: the plan's ISA is supported by this CPU.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => unsafe { grad_output_row_avx512(tw, buf, dm, at, xi_stride) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => unsafe { grad_output_row_avx2(tw, buf, dm, at, xi_stride) },
            _ => grad_output_row(tw, buf, dm, at, xi_stride),
        }
    }
}

isa_version!(grad_output_row_avx512, grad_output_row, "avx512f", (tw: usize, buf: &mut Rows<F>, dm: &mut [F], at: usize, xi_stride: usize));
isa_version!(grad_output_row_avx2, grad_output_row, "avx2,fma", (tw: usize, buf: &mut Rows<F>, dm: &mut [F], at: usize, xi_stride: usize));

/// The adjoint output transform of one row of tiles from its 4 dY rows (`buf.patch`, 4·tw values
/// each): along x per row (into `buf.ex`), then along y into `dm[ξ·xi_stride + at + tx]`.
#[inline(always)]
fn grad_output_row<F: Float>(tw: usize, buf: &mut Rows<F>, dm: &mut [F], at: usize, xi_stride: usize) {
    let Rows { patch, phase, ex } = buf;
    for (r, row) in patch.chunks_exact(TILE * tw).take(TILE).enumerate() {
        // phase[m][tx] = row[4·tx + m]: the tile's column m
        for (tx, q) in row.chunks_exact(TILE).enumerate() {
            for (m, &value) in q.iter().enumerate() {
                phase[m * tw + tx] = value;
            }
        }
        // ex[r][k][tx] = (A y_row)[k] for the 4 values y_m = row[4·tx + m]
        let y = strided_rows(phase, 0, tw, tw);
        let mut e = strided_rows_mut(ex, r * 6 * tw, tw, tw);
        map_tiles::<F, GradOutputTransform, 4, 6>(y, &mut e);
    }
    for b in 0..6 {
        // column b of every tile: ex[r][b][tx] for r = 0..4 (rows 6·tw apart), along y into ξ = 6a + b
        let c = strided_rows(ex, b * tw, 6 * tw, tw);
        // dM[6a + b] rows: at + (6a + b)·xi_stride, i.e. 6·xi_stride apart from b·xi_stride
        let mut out_rows = strided_rows_mut(dm, b * xi_stride + at, 6 * xi_stride, tw);
        map_tiles::<F, GradOutputTransform, 4, 6>(c, &mut out_rows);
    }
}
