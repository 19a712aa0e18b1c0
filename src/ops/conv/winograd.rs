//! Winograd convolution for stride-1 convolutions with the kernels MIPNet uses most: F(4x4, 3x3)
//! for 3x3 kernels (4 x 4 output pixels from a 6 x 6 input patch, 36 multiplies per channel pair
//! instead of 144) and F(4, 5) for the 1x5 and 5x1 kernels of the GRUs (4 output pixels from 8
//! input values, 8 multiplies instead of 20). The schemes' transforms live in their own files.
//!
//! `Y_tile[o]` = Aᵀ [ Σ_c U[o, c] ⊙ V[c] ] (A) with U[o, c] the transformed kernel (once per call)
//! and V[c] the transformed input patch: the channel sum is one GEMM `M_ξ` = `U_ξ` · `V_ξ`
//! ([Cout, Cin] · [Cin, tiles]) on the packed GEMM for each position ξ of the transform (36 or 8).
//! The weight gradient is the adjoint of the same algorithm (see [`weight_grad`]): one GEMM per ξ
//! over the tiles, then the adjoint of the kernel transform.
//!
//! Work is split into tasks (image, band of tile rows, range of output channels) fixed by the
//! shapes and the thread count; every output is computed from its own tile by the same sequence of
//! operations whatever the split, so results do not depend on it (nor on the threads). f32 rounds
//! differently from the direct convolution (the transforms add and scale); `tests_rs/conv.rs`
//! measures the error against f64.

use super::Geom;
use crate::gemm::{self, InPlace, InPlacePairs, Init, PackB, Plan, Prepacked, SourceA, Strided};
use crate::{Float, Result};
use f4_5::Along;
use lanes::Rows;
use ndarray::{Array2, Array3};
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::ops::Range;
use std::sync::Arc;

mod cache;
mod f4_5;
mod f4x4_3x3;
mod lanes;

/// Fewest channels (in and out) for Winograd: below, its per-channel transforms outweigh the
/// multiplies it saves.
const MIN_CHANNELS: usize = 32;

/// A Winograd algorithm and the convolutions it computes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scheme {
    /// F(4x4, 3x3): a 3x3 kernel, padding at most 2 per axis.
    F4x4K3x3,
    /// F(4, 5) along rows (a 1x5 kernel) or along columns (a 5x1 kernel), padding at most 4 per axis.
    F4K5(Along),
}

impl Scheme {
    /// The scheme for a stride-1 geometry, if any.
    fn of(g: &Geom) -> Option<Scheme> {
        let pad_at_most = |p: usize| g.pad[0] <= p && g.pad[1] <= p;
        match (g.kh, g.kw) {
            _ if g.stride != [1, 1] => None,
            (3, 3) if pad_at_most(2) => Some(Scheme::F4x4K3x3),
            (1, 5) if pad_at_most(4) => Some(Scheme::F4K5(Along::X)),
            (5, 1) if pad_at_most(4) => Some(Scheme::F4K5(Along::Y)),
            _ => None,
        }
    }

    /// Positions ξ of the transform.
    fn xi(self) -> usize {
        match self {
            Scheme::F4x4K3x3 => 36,
            Scheme::F4K5(_) => 8,
        }
    }

    /// (tile rows, tiles per tile row) of one image.
    fn tiles(self, g: &Geom) -> (usize, usize) {
        match self {
            Scheme::F4x4K3x3 => (g.ho.div_ceil(4), g.wo.div_ceil(4)),
            Scheme::F4K5(Along::X) => (g.ho, g.wo.div_ceil(4)),
            Scheme::F4K5(Along::Y) => (g.ho.div_ceil(4), g.wo),
        }
    }

    /// Fewest tiles per image for Winograd to pay. Counted per image, not over the batch, so that
    /// the choice does not depend on how a batch is split: data-parallel workers with part of a
    /// batch compute what one process computes (`tests_py/test_distributed.py`). In the forward (and
    /// the dX that is a forward) the kernel transform, per channel pair about as costly as the GEMM
    /// work of 100 tiles, must be amortised; the weight gradient transforms no kernel (its adjoint at
    /// the end is cheap), so F(4x4, 3x3) pays there from fewer tiles. Measured with `WINOGRAD=off|on
    /// ./target/release/examples/conv_time N CIN COUT H W KH KW 1 30` on AMD Zen 4, 2 threads, nothing
    /// else running, Winograd's speed-up (fwd, dX, dW) on the 1/16 level's shapes, tiles per image:
    /// - 3x3, 8 tiles (8x16, N=4): 128->128 0.53, 0.71, 1.54; 128->256 0.47, 0.70, 1.38; 352->256
    ///   0.53, 0.68, 1.25;
    /// - 3x3, 32 tiles (16x32, N=2): 128->256 0.96, 0.99, 1.68; 352->256 0.86, 1.17, 1.57;
    /// - 3x3, 48 tiles (24x32, N=2): 128->128 0.93, 1.04, 1.37; 128->256 1.07, 1.06, 1.61; 352->256
    ///   1.13, 1.42, 1.70;
    /// - 1x5 / 5x1, 32 tiles (1x5 at 8x16, N=4): 1.18, 1.54, 1.13; 192 (1x5 at 24x32, N=2): 1.23,
    ///   1.61, 1.32; 128 (5x1 at 16x32, N=2): 1.49, 1.59, 1.03.
    fn min_tiles(self, weight_grad: bool) -> usize {
        match (self, weight_grad) {
            (Scheme::F4x4K3x3, false) => 48,
            (Scheme::F4x4K3x3, true) => 8,
            (Scheme::F4K5(_), _) => 32,
        }
    }

    /// `u[ξ]`: the transform of the kernel `w` (kh·kw taps) of one channel pair.
    fn weight<F: Float>(self, w: &[F], u: &mut [F]) {
        match self {
            Scheme::F4x4K3x3 => f4x4_3x3::weight(w, u),
            Scheme::F4K5(_) => f4_5::weight(w, u),
        }
    }

    /// The adjoint of [`Scheme::weight`]: the kh·kw taps `dw` from the ξ values `du(ξ)`.
    fn weight_grad<F: Float>(self, du: impl Fn(usize) -> F, dw: &mut [F]) {
        match self {
            Scheme::F4x4K3x3 => f4x4_3x3::weight_grad(du, dw),
            Scheme::F4K5(_) => f4_5::weight_grad(du, dw),
        }
    }

    /// `V[ξ]` of tile row ty of the channel plane `xc`, at `v[ξ·xi_stride + at + t]`.
    #[allow(clippy::too_many_arguments)]
    fn input_rows<F: Float>(self, plan: &Plan<F>, g: &Geom, xc: &[F], ty: usize, tw: usize, v: &mut [F], at: usize,
                            xi_stride: usize, buf: &mut Rows<F>) {
        match self {
            Scheme::F4x4K3x3 => f4x4_3x3::input_rows(plan.isa, g, xc, ty, tw, v, at, xi_stride, buf),
            Scheme::F4K5(along) => f4_5::input_rows(along, plan.isa, g, xc, ty, tw, v, at, xi_stride, buf),
        }
    }

    /// The output pixels of tile row ty from `M[ξ]` at `m[ξ·xi_stride + at + t]`, + b0 (then ReLU),
    /// into the output plane `yo`.
    #[allow(clippy::too_many_arguments)]
    fn output_rows<F: Float>(self, plan: &Plan<F>, g: &Geom, m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F,
                             relu: bool, ty: usize, yo: &mut [F], buf: &mut Rows<F>) {
        match self {
            Scheme::F4x4K3x3 => f4x4_3x3::output_rows(plan.isa, g, m, at, xi_stride, tw, b0, relu, ty, yo, buf),
            Scheme::F4K5(along) => f4_5::output_rows(along, plan.isa, g, m, at, xi_stride, tw, b0, relu, ty, yo, buf),
        }
    }

    /// `dM[ξ]` of tile row ty of the dY plane `dyo`, at `dm[ξ·xi_stride + at + t]`.
    #[allow(clippy::too_many_arguments)]
    fn grad_output_rows<F: Float>(self, plan: &Plan<F>, g: &Geom, dyo: &[F], ty: usize, tw: usize, dm: &mut [F], at: usize,
                                  xi_stride: usize, buf: &mut Rows<F>) {
        match self {
            Scheme::F4x4K3x3 => f4x4_3x3::grad_output_rows(plan.isa, g, dyo, ty, tw, dm, at, xi_stride, buf),
            Scheme::F4K5(along) => f4_5::grad_output_rows(along, plan.isa, g, dyo, ty, tw, dm, at, xi_stride, buf),
        }
    }

    /// The scheme of a geometry where [`applies`] holds.
    fn expect(g: &Geom) -> Scheme {
        Scheme::of(g).expect("winograd: called on a geometry it does not apply to")
    }
}

/// Whether Winograd can compute this convolution (see [`Scheme`]): stride 1, a 3x3, 1x5 or 5x1
/// kernel, padding below the kernel size (a patch then always overlaps the image).
pub(super) fn applies(g: &Geom) -> bool {
    Scheme::of(g).is_some()
}

/// Whether the forward pays: enough channels and tiles for the transforms to cost less than they save.
pub(super) fn pays(g: &Geom) -> bool {
    enough_channels_and_tiles(g, false)
}

/// Whether Winograd applies to `g` with at least [`MIN_CHANNELS`] in and out and the scheme's
/// [`Scheme::min_tiles`] per image.
fn enough_channels_and_tiles(g: &Geom, weight_grad: bool) -> bool {
    let Some(scheme) = Scheme::of(g) else { return false };
    let (th, tw) = scheme.tiles(g);
    g.cin.min(g.cout) >= MIN_CHANNELS && th * tw >= scheme.min_tiles(weight_grad)
}

/// Least Cin·Cout / (Cin + Cout) for the Winograd weight gradient: per tile it transforms Cin + Cout
/// planes and then saves GEMM work in proportion to Cin·Cout, and its two GEMM operands are both
/// packed per call (the forward's weights are packed once). Measured for F(4x4, 3x3), dW against the
/// direct path, 2 threads (`WINOGRAD=on|off cargo run --release --example conv_time`):
/// - AMD Zen 4, a training run in the background: 64->64 and 96->96 (32, 48) slower, 128->94 (54)
///   even, 128->128 (64) 1.2x faster, 128->256 (85) 1.35x, 352->256 (148) 1.9x;
/// - AMD Zen 5, nothing else running, each shape twice: 64->64 (32) at 128x256 N=4 1.9-2.0x faster,
///   at 64x128 N=4 1.3x, N=2 1.05x; 96->96 (48) 1.9x, 64->128 (43) 1.35x, 128->94 (54) 2.0x,
///   96->128 (55) 1.8x; 64->32 (21) 1.26x, 32->64 (21) 0.9x. A training step at 256x512, batch 2,
///   (4, 4): 5.78 s with the threshold at 56, 5.48 s at 32 (median of 3);
/// - AMD Zen 4 again, the training run paused, each shape twice (best of 5): 64->64 at 128x256 N=4
///   62-70 -> 45 ms (1.4-1.5x), at 64x128 N=4 16.2-16.7 -> 13.0-13.3 (1.25x), N=2 7.5-10.8 ->
///   6.6-7.6 (1.0-1.6x); 96->96 33-34 -> 16-18 (2.0x); 128->94 23.1 -> 12.1-12.7 (1.85x); 64->128
///   27.8-28.2 -> 17-22 (1.3-1.6x); 64->32 (21) 0.95-1.3x, 32->64 (21) 1.4-1.5x.
///
/// The earlier Zen 4 figures were taken beside a training run; both quiet machines agree on 32.
const MIN_DW_CHANNEL_RATIO: usize = 32;

/// Whether the Winograd weight gradient pays (see [`MIN_DW_CHANNEL_RATIO`]).
pub(super) fn weight_grad_pays(g: &Geom) -> bool {
    enough_channels_and_tiles(g, true) && g.cin * g.cout >= MIN_DW_CHANNEL_RATIO * (g.cin + g.cout)
}

/// Channel pairs per task in the kernel transform ([`weights`]) and its adjoint ([`weight_grad`]):
/// each task moves its block between the ξ planes and a [pair][ξ] buffer in runs of this length.
const WEIGHT_BLOCK_PAIRS: usize = 64;

/// The transformed weights: `U_ξ`[o, c] = (transform of `w[o, c]`)[ξ] as one matrix [Cout, Cin]
/// per ξ, packed for `plan`.
fn weights<F: Float>(scheme: Scheme, plan: &Plan<F>, w: &[F], cout: usize, cin: usize) -> Vec<Prepacked<F>> {
    let (xi, pairs) = (scheme.xi(), cout * cin);
    let taps = w.len() / pairs.max(1);
    // planes[ξ·pairs + oc] for oc = o·Cin + c: blocks of pairs in parallel, each transformed into
    // its own [pair][ξ] buffer and then copied into every ξ plane as one run of consecutive pairs
    // (one strided gather per plane instead touched every cache line of the transform 36 times)
    // every run of every plane is written below, so the planes are not zeroed first (a serial pass
    // over up to tens of MB)
    let mut planes = Vec::<MaybeUninit<F>>::with_capacity(pairs * xi);
    // SAFETY: MaybeUninit elements need no initialisation; the capacity is pairs·XI.
    unsafe { planes.set_len(pairs * xi) };
    let dst = SharedPtr(planes.as_mut_ptr());
    w.par_chunks(WEIGHT_BLOCK_PAIRS * taps).enumerate().for_each_init(|| vec![F::zero(); WEIGHT_BLOCK_PAIRS * xi], |u, (b, wb)| {
        let n = wb.len() / taps;
        for (wk, uk) in wb.chunks_exact(taps).zip(u.chunks_exact_mut(xi)) {
            scheme.weight(wk, uk);
        }
        for k in 0..xi {
            // the run of plane ξ = k: planes[ξ·pairs + b·BLOCK ..][..n] = u[i·XI + ξ] for i < n
            // SAFETY: b·BLOCK + n <= pairs and ξ < XI, so the run lies in planes; each run belongs to
            // the one task of block b, and nothing reads planes until all tasks finish.
            let run = unsafe { std::slice::from_raw_parts_mut(dst.get().add(k * pairs + b * WEIGHT_BLOCK_PAIRS), n) };
            for (r, uk) in run.iter_mut().zip(u.chunks_exact(xi)) {
                r.write(uk[k]);
            }
        }
    });
    planes
        .par_chunks(pairs.max(1))
        .map(|plane| {
            // the plane was written in full above (MaybeUninit<F> has the layout of F)
            let view = Strided { ptr: plane.as_ptr().cast::<F>(), rows: cout, cols: cin, rs: cin as isize, cs: 1, scale: F::one() };
            Prepacked::new(plan, &view)
        })
        .collect()
}

/// A pointer to an output shared by the tasks, each writing its own elements (y: its (channels x
/// rows) part; the weight planes: its pairs).
#[derive(Clone, Copy)]
struct SharedPtr<F>(*mut F);
// SAFETY: tasks write disjoint elements (distinct output channels or tile rows of y, distinct pairs
// of the weight planes) and nothing reads them until all of them have finished.
unsafe impl<F> Send for SharedPtr<F> {}
// SAFETY: as above.
unsafe impl<F> Sync for SharedPtr<F> {}

impl<F> SharedPtr<F> {
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

/// y = conv2d(x, w) (+ b, then ReLU) for a geometry where [`applies`] holds; with `reuse_kernels`
/// the transformed kernel comes from (or goes to) the [`cache`], without it the cache is emptied.
pub(super) fn forward<F: Float>(plan: &Plan<F>, g: &Geom, xs: &[F], w: &[F], bias: Option<&[F]>, relu: bool,
                                reuse_kernels: bool) -> Result<Array3<F>> {
    let scheme = Scheme::expect(g);
    let (th, tw) = scheme.tiles(g);
    let transform = || weights(scheme, plan, w, g.cout, g.cin);
    let u = if reuse_kernels {
        cache::transformed(scheme, plan, w, g.cout, g.cin, transform)
    } else {
        cache::release();
        Arc::new(transform())
    };
    // a band's V (XI x Cin x T) and M (XI x Cout x T) fill about the L2 cache, at least 2 micro-panels
    let l2 = gemm::cpu_info().l2;
    let band_tiles = (l2 / (scheme.xi() * std::mem::size_of::<F>() * (g.cin + g.cout))).max(4 * plan.nr);
    let work = tasks(plan, g, tw, th, band_tiles);
    // every element is written below (all channels, all tile rows, each tile clipped to the image),
    // so y is not zeroed first
    let mut y = Array3::<F>::uninit((g.n, g.cout, g.ho * g.wo));
    let yp = SharedPtr(y.as_mut_ptr().cast::<F>());
    work.par_iter().for_each(|t| {
        let xn = &xs[t.n * g.img()..(t.n + 1) * g.img()];
        // SAFETY: y[n] starts n·Cout·Ho·Wo elements in; the task writes only its own part.
        let yn = unsafe { yp.get().add(t.n * g.cout * g.ho * g.wo) };
        // SAFETY: as above.
        unsafe { band(scheme, plan, g, xn, &u, bias, relu, t, tw, SharedPtr(yn)) };
    });
    // SAFETY: the tasks cover every (image, output channel, tile row), and a tile row's output
    // transform writes each of its pixels.
    Ok(unsafe { y.assume_init() })
}

/// One task: input transform of its band into V, the XI GEMMs into M, output transform into y.
///
/// V is float32, V[ξ][c][tile], read in place by the GEMM; for a bf16 plan it is written as the bf16
/// pairs of channels (2q, 2q + 1) that the micro-kernel reads (`gemm::InPlacePairs`), V[ξ][q][tile] in
/// rows of `ldv` (the tiles rounded up to NR, zero past them), so the GEMM reads it in place too.
///
/// # Safety
/// `yn` is y[n] (Cout x Ho x Wo); no other task writes the task's (channels, rows) part.
#[allow(clippy::too_many_arguments)]
unsafe fn band<F: Float>(scheme: Scheme, plan: &Plan<F>, g: &Geom, xn: &[F], u: &[Prepacked<F>], bias: Option<&[F]>,
                         relu: bool, t: &Task, tw: usize, yn: SharedPtr<F>) {
    let (tiles, outs, xi) = (t.rows.len() * tw, t.outs.len(), scheme.xi());
    // rows of V_ξ and their stride: channels, or channel pairs (bf16 plan)
    let (vrows, ldv) = if plan.pairs { (g.cin.div_ceil(2), tiles.next_multiple_of(plan.nr)) } else { (g.cin, tiles) };
    // a bf16 plan's float32 V of one channel pair, [ξ][2][tile], before it is paired
    let staging = if plan.pairs { xi * 2 * tiles } else { 0 };
    super::with_scratch(xi * vrows * ldv + staging + xi * outs * tiles, |buf: &mut [F]| {
        let (v, rest) = buf.split_at_mut(xi * vrows * ldv);
        let (staged, m) = rest.split_at_mut(staging);
        let plane = g.h * g.w;
        let mut rows = Rows::new(tw);
        // the input transform of channel c into `out`: out[ξ·stride + at + tile], tile = band_row·tw + t
        let mut transform = |c: usize, out: &mut [F], at: usize, stride: usize| {
            for (band_row, ty) in t.rows.clone().enumerate() {
                scheme.input_rows(plan, g, &xn[c * plane..][..plane], ty, tw, out, at + band_row * tw, stride, &mut rows);
            }
        };
        if plan.pairs {
            for q in 0..vrows {
                let pair = 2 * q..(2 * q + 2).min(g.cin);
                for c in pair.clone() {
                    transform(c, staged, (c - 2 * q) * tiles, 2 * tiles);
                }
                for k in 0..xi {
                    // pair row q of V_ξ (at k·vrows·ldv + q·ldv) from staged[ξ][0..2][tile]
                    let row = &mut v[(k * vrows + q) * ldv..][..ldv];
                    // SAFETY: a bf16 plan runs on AVX512_BF16 with F = f32; staged holds the pair's
                    // rows (one or two) of `tiles` values `tiles` apart, the row `tiles` pairs.
                    unsafe { gemm::pair_panel(pair.len(), tiles, staged[k * 2 * tiles..].as_ptr().cast(), tiles, row.as_mut_ptr().cast()) };
                    row[tiles..].fill(F::zero());
                }
            }
        } else {
            for c in 0..g.cin {
                transform(c, v, c * tiles, g.cin * tiles);
            }
        }
        for k in 0..xi {
            // M_ξ[outs][tile] = U_ξ[outs, :] · V_ξ
            let view = Strided { ptr: v[k * vrows * ldv..].as_ptr(), rows: vrows, cols: ldv, rs: ldv as isize, cs: 1, scale: F::one() };
            let (paired, plain) = (InPlacePairs { pairs: view, depth: g.cin }, InPlace(view));
            let b: &dyn PackB<F> = if plan.pairs { &paired } else { &plain };
            let c = m[k * outs * tiles..].as_mut_ptr();
            // SAFETY: M_ξ is outs x tiles in this task's buffer; U_ξ has Cout >= t.outs.end rows and
            // V_ξ Cin x tiles (or its pairs), both over Cin.
            unsafe {
                gemm::run(plan, outs, tiles, g.cin, SourceA::Rows(&u[k], t.outs.start), b, c, tiles as isize, 1, Init::Zero,
                          false)
            };
        }
        for (oi, o) in t.outs.clone().enumerate() {
            // SAFETY: channel o of y[n] is Ho·Wo elements at o·Ho·Wo, written only by this task
            // for its tile rows.
            let yo = unsafe { std::slice::from_raw_parts_mut(yn.get().add(o * g.ho * g.wo), g.ho * g.wo) };
            let b0 = bias.map_or(F::zero(), |b| b[o]);
            for (band_row, ty) in t.rows.clone().enumerate() {
                scheme.output_rows(plan, g, m, oi * tiles + band_row * tw, outs * tiles, tw, b0, relu, ty, yo, &mut rows);
            }
        }
    });
}

/// V and dM bytes of one chunk of tile rows in the weight gradient (a chunk's XI GEMMs then have
/// K = its tiles; the chunks are fixed by the shapes, so dW does not depend on the threads).
const DW_CHUNK_BYTES: usize = 12 << 20;

/// dW of a convolution where [`applies`] holds, as the matrix `[Cout, Cin·kh·kw]`: with M = U ⊙ V
/// per tile (see the module doc), dU_ξ = Σ_tiles dM_ξ · V_ξᵀ ([Cout, tiles] · [tiles, Cin]) where
/// dM is the adjoint output transform of the dY tile (A · `dY_tile` · Aᵀ in 2-D), then `dW[o, c]` is
/// the adjoint kernel transform of `dU[o, c]` (Gᵀ · dU · G in 2-D).
///
/// The tiles (image-major, whole tile rows) are taken in chunks: per chunk, V and dM are
/// transformed in parallel over channels, then the XI GEMMs run in parallel over ξ, each summing
/// into its own dU_ξ (the first chunk overwrites, the others add), in chunk order.
pub(super) fn weight_grad<F: Float>(plan: &Plan<F>, g: &Geom, xs: &[F], dy: &[F]) -> Array2<F> {
    let scheme = Scheme::expect(g);
    let ((th, tw), xi, taps) = (scheme.tiles(g), scheme.xi(), g.kh * g.kw);
    let (plane, pix) = (g.h * g.w, g.ho * g.wo);
    let row_bytes = xi * tw * (g.cin + g.cout) * std::mem::size_of::<F>();
    let chunk_rows = (DW_CHUNK_BYTES / row_bytes).max(1).min(g.n * th);
    let mut v = vec![F::zero(); g.cin * xi * chunk_rows * tw];
    let mut dm = vec![F::zero(); g.cout * xi * chunk_rows * tw];
    // the first chunk's GEMMs overwrite every dU_ξ (Init::Zero), so dU is not zeroed first
    let mut du = Vec::<MaybeUninit<F>>::with_capacity(xi * g.cout * g.cin);
    // SAFETY: MaybeUninit elements need no initialisation; the capacity is XI·Cout·Cin.
    unsafe { du.set_len(xi * g.cout * g.cin) };
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
        v[..g.cin * xi * tiles].par_chunks_mut(xi * tiles).enumerate().for_each_init(
            || Rows::new(tw),
            |buf, (c, vc)| {
                for (n, rows, off) in &pieces {
                    let xc = &xs[n * g.img() + c * plane..][..plane];
                    for (band_row, ty) in rows.clone().enumerate() {
                        scheme.input_rows(plan, g, xc, ty, tw, vc, off + band_row * tw, tiles, buf);
                    }
                }
            },
        );
        // dM[o][ξ][tile] for the chunk, output channel by output channel
        dm[..g.cout * xi * tiles].par_chunks_mut(xi * tiles).enumerate().for_each_init(
            || Rows::new(tw),
            |buf, (o, mo)| {
                for (n, rows, off) in &pieces {
                    let dyo = &dy[(n * g.cout + o) * pix..][..pix];
                    for (band_row, ty) in rows.clone().enumerate() {
                        scheme.grad_output_rows(plan, g, dyo, ty, tw, mo, off + band_row * tw, tiles, buf);
                    }
                }
            },
        );
        let (vs, ms) = (&v, &dm);
        du.par_chunks_mut(g.cout * g.cin).enumerate().for_each(|(k, duk)| {
            let init = if ci == 0 { Init::Zero } else { Init::Load };
            // dU_ξ (+)= dM_ξ · V_ξᵀ for ξ = k: dM_ξ[o, t] at o·XI·T + ξ·T + t, V_ξᵀ[t, c] at c·XI·T + ξ·T + t
            let a = Strided { ptr: ms[k * tiles..].as_ptr(), rows: g.cout, cols: tiles, rs: (xi * tiles) as isize, cs: 1, scale: F::one() };
            let b = Strided { ptr: vs[k * tiles..].as_ptr(), rows: tiles, cols: g.cin, rs: 1, cs: (xi * tiles) as isize, scale: F::one() };
            // SAFETY: dU_ξ is this task's own Cout x Cin plane; A and B lie inside the chunk's dM and V.
            unsafe { gemm::run(plan, g.cout, g.cin, tiles, SourceA::Strided(&a), &b, duk.as_mut_ptr().cast::<F>(), g.cin as isize, 1, init, false) };
        });
    }
    // SAFETY: every element of dU was written by the first chunk's GEMMs (MaybeUninit<F> has the layout of F).
    let du = unsafe { std::slice::from_raw_parts(du.as_ptr().cast::<F>(), du.len()) };
    let mut dw = Array2::<F>::uninit((g.cout, g.cin * taps));
    let pairs = g.cout * g.cin;
    {
        let d = dw.as_slice_mut().expect("a new array is contiguous");
        // dW[o, c] from dU[o, c] = (dU_ξ[o, c] for every ξ), oc = o·Cin + c, by blocks of pairs: each
        // block first gathers its run of every ξ plane into a [pair][ξ] buffer
        d.par_chunks_mut(WEIGHT_BLOCK_PAIRS * taps).enumerate().for_each_init(|| vec![F::zero(); WEIGHT_BLOCK_PAIRS * xi], |block, (b, dwb)| {
            // zeroed in cache, then every value written by the adjoint transform below
            let dwb = crate::tensor::zeroed(dwb);
            let (first, n) = (b * WEIGHT_BLOCK_PAIRS, dwb.len() / taps);
            for k in 0..xi {
                // block[i·XI + ξ] = dU_ξ[first + i], dU_ξ at du[ξ·pairs ..]
                for (i, &value) in du[k * pairs + first..][..n].iter().enumerate() {
                    block[i * xi + k] = value;
                }
            }
            for (wk, duk) in dwb.chunks_exact_mut(taps).zip(block.chunks_exact(xi)) {
                scheme.weight_grad(|k| duk[k], wk);
            }
        });
    }
    // SAFETY: the blocks cover dW and each was zeroed, then written, by its task.
    unsafe { dw.assume_init() }
}

