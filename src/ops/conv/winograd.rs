//! Winograd F(4x4, 3x3) for stride-1 3x3 convolutions: each 4 x 4 block of output pixels (a tile)
//! from a 6 x 6 input patch with 36 multiplies per (output, input) channel pair instead of 144.
//!
//! `Y_tile[o]` = Aᵀ [ Σ_c U[o, c] ⊙ V[c] ] A with U[o, c] = G · `w[o, c]` · Gᵀ (6 x 6, once per call)
//! and V[c] = Bᵀ · `d[c]` · B (6 x 6, the input patch transformed): the channel sum is 36
//! independent GEMMs `M_ξ` = `U_ξ` · `V_ξ` ([Cout, Cin] · [Cin, tiles]) on the packed GEMM, one per
//! position ξ of the 6 x 6 transform. Matrices from Lavin & Gray (2016), points 0, ±1, ±2, ∞.
//!
//! Work is split into tasks (image, band of tile rows, range of output channels) fixed by the
//! shapes and the thread count; every output is computed from its own tile by the same sequence of
//! operations whatever the split, so results do not depend on it (nor on the threads). f32 rounds
//! differently from the direct convolution (the transforms add and scale); `tests_rs/conv.rs`
//! measures the error against f64.

use super::Geom;
use crate::gemm::{self, Init, Isa, Plan, Prepacked, SourceA, Strided};
use crate::{Float, Result};
use ndarray::Array3;
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

/// A 1-D transform of 6 values into N, written once for one value and for [`Lanes`].
trait Transform1d<const N: usize> {
    fn apply<F: Float, T: Lane<F>>(d: [T; 6]) -> [T; N];
}

/// v = Bᵀ d for one 6-vector d: the input transform along one axis.
struct InputTransform;

impl Transform1d<6> for InputTransform {
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

/// dst[k][tx] = X(src[0][tx], .., src[5][tx])[k] for every tile tx of the rows: blocks of LANES
/// tiles on [`Lanes`], the rest one tile at a time (the same operations on F).
#[inline(always)]
fn map_tiles<F: Float, X: Transform1d<N>, const N: usize>(src: [&[F]; 6], dst: &mut [&mut [F]; N]) {
    let tw = dst[0].len();
    let full = tw / LANES * LANES;
    for t0 in (0..full).step_by(LANES) {
        // tiles t0 .. t0 + LANES of every row
        let mut d = [Lanes([F::zero(); LANES]); 6];
        for (dj, sj) in d.iter_mut().zip(&src) {
            dj.0.copy_from_slice(&sj[t0..t0 + LANES]);
        }
        let out = X::apply::<F, Lanes<F>>(d);
        for (row, o) in dst.iter_mut().zip(&out) {
            row[t0..t0 + LANES].copy_from_slice(&o.0);
        }
    }
    for tx in full..tw {
        let out = X::apply::<F, F>([src[0][tx], src[1][tx], src[2][tx], src[3][tx], src[4][tx], src[5][tx]]);
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

impl Transform1d<4> for OutputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(m: [T; 6]) -> [T; 4] {
        let (c2, c4, c8) = (F::c(2.0), F::c(4.0), F::c(8.0));
        let (s12, d12, s34, d34) = (m[1] + m[2], m[1] - m[2], m[3] + m[4], m[3] - m[4]);
        [m[0] + s12 + s34, d12 + d34 * c2, s12 + s34 * c4, d12 + d34 * c8 + m[5]]
    }
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

/// Six disjoint rows of `len` elements of `buf`, row r at `first + r·stride` (stride >= len): the
/// destinations of a 1-D transform, as exact-length slices so the loops over them vectorise
/// (indexing `buf` at `first + r·stride + tx` kept a bounds check per element, which left the
/// transforms scalar).
fn six_rows_mut<F>(buf: &mut [F], first: usize, stride: usize, len: usize) -> [&mut [F]; 6] {
    assert!(stride >= len, "six_rows_mut: rows overlap");
    let mut rest = &mut buf[first..];
    std::array::from_fn(|r| {
        // row r spans first + r·stride .. + len; the next one starts stride after it
        let (row, tail) = std::mem::take(&mut rest).split_at_mut(len);
        rest = if r < 5 { &mut tail[stride - len..] } else { tail };
        row
    })
}

/// Six rows of `len` elements of `buf`, row r at `first + r·stride`, as exact-length slices.
fn six_rows<F>(buf: &[F], first: usize, stride: usize, len: usize) -> [&[F]; 6] {
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
        let mut e = six_rows_mut(ex, r * 6 * tw, tw, tw);
        map_tiles::<F, InputTransform, 6>([d0, d1, d2, d3, d4, d5], &mut e);
    }
    for b in 0..6 {
        // column b of every patch: ex[r][b][tx] for r = 0..6 (rows 6·tw apart), along y into ξ = 6a + b
        let c = six_rows(ex, b * tw, 6 * tw, tw);
        // V[6a + b] rows: at + (6a + b)·xi_stride, i.e. 6·xi_stride apart from b·xi_stride
        let mut out_rows = six_rows_mut(v, b * xi_stride + at, 6 * xi_stride, tw);
        map_tiles::<F, InputTransform, 6>(c, &mut out_rows);
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
        let mv = six_rows(m, b * xi_stride + at, 6 * xi_stride, tw);
        let [e0, e1, e2, e3, ..] = six_rows_mut(&mut ex[b * TILE * tw..], 0, tw, tw);
        map_tiles::<F, OutputTransform, 4>(mv, &mut [e0, e1, e2, e3]);
    }
    for r in 0..TILE {
        // output row r of every tile: (ex[b][r][tx] for b = 0..6, rows 4·tw apart) along x into
        // q[c][tx] (ex rows 24..28, free), then interleaved into columns 4·tx + c
        let (e, free) = ex.split_at_mut(6 * TILE * tw);
        let e = six_rows(e, r * tw, TILE * tw, tw);
        let [q0, q1, q2, q3, ..] = six_rows_mut(free, 0, tw, tw);
        let mut q = [q0, q1, q2, q3];
        map_tiles::<F, OutputTransform, 4>(e, &mut q);
        let out_row = &mut patch[r * TILE * tw..(r + 1) * TILE * tw];
        for (tx, quad) in out_row.chunks_exact_mut(TILE).enumerate() {
            for (c, slot) in quad.iter_mut().enumerate() {
                let o = q[c][tx] + b0;
                *slot = if relu { o.max(F::zero()) } else { o };
            }
        }
    }
}
