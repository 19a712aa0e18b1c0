//! The only door to matrix multiplication. Transposes are stride swaps (`view.t()`), never copies.
//!
//! Every f32 and f64 product runs mipnet's own packed GEMM (BLIS loop order), on the ISA path
//! [`Isa::selected`] picks (`MIPNET_ISA`, else the widest the CPU has) with a [`Plan`] derived at
//! run time from the CPU's caches:
//!
//! ```text
//! for ic in 0..m step MC':                MC' = MC·KC/K rows of A packed into MR-row panels over all of K
//!                                         (conv weights: packed once per call, `Prepacked`)
//!   for jc in 0..n step NC:
//!     for pc in 0..k step KC:             B block KC x NC packed row-major (or read in place): stays in L2
//!       for ir in 0..MC' step MR:         A micro-panel MR x KC: stays in L1 across the jr loop
//!         for jr in 0..NC step NR:        micro-kernel: MR x NR tile of C in registers, NR columns of B
//! ```
//!
//! Every element of C is its initial value (0, beta·C or its bias) plus, in increasing k, the
//! sums of runs of 64 multiply-adds (`kernel::SUB_K`, a chain each, added to C in turn): the
//! result does not depend on the block sizes, the micro-kernel shape or how callers tile C (so not
//! on the thread count either), and it is bitwise the same on the AVX-512 and AVX2 paths (both
//! fuse the multiply-add); the portable path rounds the product and the sum separately.

mod cpu;
mod simd;
mod kernel;
mod pack;
mod peak;

pub use cpu::{cpu_info, CpuInfo};
pub use crate::isa::{Isa, ISA_ENV};
pub(crate) use kernel::Init;
use kernel::{Tile, UKernel};
pub(crate) use pack::{pair_panel, InPlace, InPlacePairs, PackB, Prepacked, SourceA, Strided};
pub use peak::fma_peak_gflops;

use crate::{Error, Float, Result};
use ndarray::{Array2, ArrayView2, ArrayViewMut2};
use rayon::prelude::*;
use std::cell::RefCell;
use std::sync::OnceLock;

/// Instantiated micro-kernels: `pick!(mr, nv, entry; (MR, NV), ..)` maps (mr, nv) to
/// `kernel::entry::<E, MR, NV>`. The first shape of each path is its default (see [`ukernel`]); the
/// others are there for `examples/gemm_tune.rs` to compare on a new CPU.
macro_rules! pick {
    ($mr:expr, $nv:expr, $f:ident; $(($m:literal, $v:literal)),*) => {
        match ($mr, $nv) {
            $(($m, $v) => Some(kernel::$f::<E, $m, $v> as UKernel<E>),)*
            _ => None,
        }
    };
}

/// The micro-kernel compiled for (isa, MR, NV), if that shape is instantiated (called through
/// [`Kernels`], which each `Float` type builds with its own element type).
///
/// Default shapes, (MR, NV) with NR = NV · lanes:
/// - AVX-512 8 x 3 vectors (8 x 48 f32): 24 accumulators + 3 B vectors + 1 broadcast of the 32
///   registers; per k, 3 vector loads and 8 broadcasts for 24 FMAs, under the 2 loads per cycle of
///   Intel (2 FMA ports) and of Zen 4 (one 512-bit FMA per cycle, double-pumped, so half the loads
///   per FMA suffice there); 24 independent chains cover 4-cycle latency x 2 ports three times over.
///   Measured on a Xeon (model 207) at one thread, 1024x1152x2048 (`examples/gemm_tune.rs`, after the
///   accumulators were kept out of memory, see `kernel::run`): 8x48 72-87% (run to run, a shared VM),
///   6x64 84%, 14x32 76%, 12x32 67% of the FMA peak.
/// - AVX2 4 x 3 (4 x 24): 12 accumulators + 3 + 1 = the 16 registers; 85% against 81% for 6 x 16.
/// - Portable 4 x 2 vectors of 4.
#[cfg(target_arch = "x86_64")]
pub(crate) fn ukernel<E: Float>(isa: Isa, mr: usize, nv: usize) -> Option<UKernel<E>>
where
    simd::Avx512: simd::Simd<E>,
    simd::Avx2: simd::Simd<E>,
{
    match isa {
        Isa::Avx512 => pick!(mr, nv, avx512; (8, 3), (12, 2), (14, 2), (6, 4)),
        Isa::Avx2 => pick!(mr, nv, avx2; (4, 3), (6, 2)),
        Isa::Generic => pick!(mr, nv, generic; (4, 2)),
    }
}

/// The micro-kernel compiled for (isa, MR, NV): off x86 only the portable path exists.
#[cfg(not(target_arch = "x86_64"))]
pub(crate) fn ukernel<E: Float>(isa: Isa, mr: usize, nv: usize) -> Option<UKernel<E>> {
    match isa {
        Isa::Generic => pick!(mr, nv, generic; (4, 2)),
        _ => None,
    }
}

/// The default micro-kernel shape (MR, NV) of each path (the first of its list in [`ukernel`]).
fn default_shape(isa: Isa) -> (usize, usize) {
    match isa {
        Isa::Avx512 => (8, 3),
        Isa::Avx2 => (4, 3),
        Isa::Generic => (4, 2),
    }
}

/// Elements of E per vector register of `isa`.
fn lanes<E>(isa: Isa) -> usize {
    match isa {
        Isa::Generic => simd::GENERIC_LANES,
        _ => isa.vector_bits() / 8 / std::mem::size_of::<E>(),
    }
}

/// A `Float` type's micro-kernels and its plan per ISA path (one static per type, see
/// `Float::gemm_kernels`).
pub struct Kernels<E: 'static> {
    plans: [OnceLock<Plan<E>>; 3],
    pick: fn(Isa, usize, usize) -> Option<UKernel<E>>,
}

impl<E> Kernels<E> {
    /// The kernels of `pick` (`ukernel::<E>`), no plan built yet.
    pub(crate) const fn new(pick: fn(Isa, usize, usize) -> Option<UKernel<E>>) -> Self {
        Kernels { plans: [OnceLock::new(), OnceLock::new(), OnceLock::new()], pick }
    }
}

/// Bytes of the stack buffer an edge tile goes through (MR·NR elements at most).
const TILE_BYTES: usize = 4096;

/// How one ISA path multiplies: micro-kernel shape and block sizes.
#[derive(Clone, Copy, Debug)]
pub struct Plan<E> {
    pub isa: Isa,
    /// Rows of the micro-tile (A values broadcast per k).
    pub mr: usize,
    /// Columns of the micro-tile (B vectors per k times lanes).
    pub nr: usize,
    /// Depth of a packed block.
    pub kc: usize,
    /// Rows of A packed at a time.
    pub mc: usize,
    /// Columns of B packed at a time.
    pub nc: usize,
    /// Products in bfloat16 with f32 sums ([`Plan::bf16`]): the kernel reads panels of bf16 pairs.
    pub pairs: bool,
    kernel: UKernel<E>,
}

/// The block sizes for a micro-tile of MR x NR elements of `es` bytes, from the cache sizes.
///
/// - KC: the A micro-panel (MR x KC) fills half of L1d; it is reused from L1 by every micro-tile
///   of the jr loop while B rows and C lines stream through the other half. Capped so that a B
///   block of 4 micro-panels (KC x 4·NR) still fits half of L2 (small-L2 cores).
/// - NC: the packed B block (KC x NC) fills half of L2, read from there once per A micro-panel.
/// - MC: the A slab (MC x KC), read once per B block, fills half of this core's share of the last
///   level (4 x L2 when it is unknown); it bounds the packing buffer and B's repacking.
///
/// f32 on AVX-512 (8 x 48): Sapphire/Emerald Rapids (48 KiB L1d, 2 MiB L2) KC 768, NC 336; Zen 4
/// (32 KiB, 1 MiB) KC 512, NC 240: the same 16 KiB A micro-panel in L1 and 0.5 MiB B block in
/// L2 as BLIS's zen4 sgemm (its 480 x 12 B micro-panel, 512 x 480 A block, roles transposed).
/// AVX2 (4 x 24) on a 32 KiB / 256 KiB core (Haswell..Skylake client): KC 320, NC 96.
pub fn blocking(es: usize, mr: usize, nr: usize, l1d: usize, l2: usize, l3_share: usize) -> (usize, usize, usize) {
    // KC = min((L1d / 2) / (MR · es), (L2 / 2) / (4 · NR · es)), a multiple of SUB_K, in [64, 1024]
    let sub = kernel::SUB_K;
    let kc = ((l1d / 2 / (mr * es)).min(l2 / 2 / (4 * nr * es)) / sub * sub).clamp(sub, 1024);
    // NC = (L2 / 2) / (KC · es), whole NR panels, at least one
    let nc = (l2 / 2 / (kc * es) / nr * nr).max(nr);
    // MC = (share / 2) / (KC · es), whole MR panels, in [8 MR, 4096]
    let share = if l3_share > 0 { l3_share } else { 4 * l2 };
    let mc = (share / 2 / (kc * es) / mr * mr).clamp(8 * mr, 4096 / mr * mr);
    (kc, mc, nc)
}

impl<E: Float> Plan<E> {
    /// The plan of `isa` for this CPU: its default micro-kernel and the block sizes [`blocking`]
    /// derives from the cache sizes (built once per ISA).
    ///
    /// Fails when the CPU does not support `isa`.
    pub fn for_isa(isa: Isa) -> Result<&'static Plan<E>> {
        if !isa.supported() {
            return Err(Error::arg("gemm", format!("this CPU does not support {}", isa.name())));
        }
        let slot = &E::gemm_kernels().plans[isa.index()];
        Ok(slot.get_or_init(|| {
            let (mr, nv) = default_shape(isa);
            let nr = nv * lanes::<E>(isa);
            let cpu = cpu_info();
            let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
            let (kc, mc, nc) = blocking(std::mem::size_of::<E>(), mr, nr, cpu.l1d, cpu.l2, cpu.l3 / cores);
            // the default shapes are instantiated (tests_rs/gemm.rs builds every plan), so the
            // portable kernel never stands in for them
            let kernel = (E::gemm_kernels().pick)(isa, mr, nv).unwrap_or(kernel::generic::<E, 4, 2>);
            Plan { isa, mr, nr, kc, mc, nc, pairs: false, kernel }
        }))
    }

    /// The plan of [`Isa::selected`] (supported by construction: detected, or checked against the
    /// CPU when `MIPNET_ISA` was parsed), else the portable one.
    pub fn selected() -> &'static Plan<E> {
        match Plan::for_isa(Isa::selected()) {
            Ok(plan) => plan,
            Err(_) => Plan::portable(),
        }
    }

    /// The portable plan, which every CPU supports.
    fn portable() -> &'static Plan<E> {
        let (mr, nv) = default_shape(Isa::Generic);
        E::gemm_kernels().plans[Isa::Generic.index()].get_or_init(|| Plan {
            isa: Isa::Generic, mr, nr: nv * simd::GENERIC_LANES, kc: 256, mc: 256, nc: 256, pairs: false,
            kernel: kernel::generic::<E, 4, 2>,
        })
    }

    /// A plan with explicit sizes (for tuning): the shape must be one of the instantiated
    /// micro-kernels of `isa`, the block sizes non-zero.
    pub fn custom(isa: Isa, mr: usize, nr: usize, kc: usize, mc: usize, nc: usize) -> Result<Plan<E>> {
        let lanes = lanes::<E>(isa);
        let kernel = (nr.is_multiple_of(lanes) && mr * nr * std::mem::size_of::<E>() <= TILE_BYTES && mr <= MAX_MR)
            .then(|| (E::gemm_kernels().pick)(isa, mr, nr / lanes))
            .flatten();
        match kernel {
            Some(kernel) if isa.supported() && kc > 0 && mc > 0 && nc > 0 => {
                // MC and NC are whole panels
                let (mc, nc) = (mc.div_ceil(mr) * mr, nc.div_ceil(nr) * nr);
                Ok(Plan { isa, mr, nr, kc, mc, nc, pairs: false, kernel })
            }
            _ => Err(Error::arg("gemm", format!("no {} micro-kernel of {mr} x {nr} (or zero block sizes)", isa.name()))),
        }
    }

    /// The depth of the K blocks of a product of depth k: KC, or less so that the blocks are about
    /// equal (3168 = 4 x 640 + 608 rather than 4 x 768 + 96), a multiple of the micro-kernel's
    /// runs (`SUB_K`), which the blocks must not split for results independent of the blocking.
    pub fn kc_for(&self, k: usize) -> usize {
        let (sub, cap) = (kernel::SUB_K, (self.kc / kernel::SUB_K).max(1) * kernel::SUB_K);
        // ceil(k / blocks) rounded up to SUB_K, blocks = ceil(k / cap)
        k.div_ceil(k.div_ceil(cap).max(1)).next_multiple_of(sub).clamp(sub, cap)
    }

    /// The width of the column blocks of a product with n columns: NC, or less so that the blocks
    /// are equal in whole micro-panels (768 = 3 x 256 rather than 2 x 336 + 96).
    pub fn nc_for(&self, n: usize) -> usize {
        // ceil(n / blocks) rounded up to NR, blocks = ceil(n / NC)
        n.div_ceil(n.div_ceil(self.nc).max(1)).next_multiple_of(self.nr).min(self.nc)
    }

    /// "avx512 8x48 KC=768 MC=4096 NC=336".
    pub fn describe(&self) -> String {
        format!("{} {}x{} KC={} MC={} NC={}", self.isa.name(), self.mr, self.nr, self.kc, self.mc, self.nc)
    }
}

impl Plan<f32> {
    /// The plan of bfloat16 products: the AVX-512 plan (same blocks and micro-tile) whose kernel
    /// rounds A and B to bf16 as they are packed and sums their products in f32 with `vdpbf16ps`
    /// (AVX512_BF16: AMD Zen 4 and later, Intel Cooper Lake and Sapphire Rapids and later). None when
    /// the CPU lacks it or `MIPNET_ISA` chose a narrower path.
    pub fn bf16() -> Option<&'static Plan<f32>> {
        static PLAN: OnceLock<Option<Plan<f32>>> = OnceLock::new();
        PLAN.get_or_init(|| {
            #[cfg(target_arch = "x86_64")]
            if Isa::selected() == Isa::Avx512 && std::arch::is_x86_feature_detected!("avx512bf16") {
                let base = Plan::<f32>::for_isa(Isa::Avx512).ok()?;
                // the AVX-512 plan's default micro-tile is 8 x 3 vectors (`default_shape`)
                return Some(Plan { kernel: kernel::avx512_bf16::<f32, 8, 3>, pairs: true, ..*base });
            }
            None
        }).as_ref()
    }
}

/// x rounded to bfloat16 (nearest, ties to even), as the bf16 plan rounds its operands.
pub fn round_to_bf16(x: f32) -> f32 {
    f32::from_bits(pack::bf16_bits(x) << 16)
}

/// Most rows of a micro-tile (the size of the bias buffer of an edge tile).
const MAX_MR: usize = 16;

/// One 64-byte aligned line: the unit of the packing buffers.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct Line([u8; 64]);

thread_local! {
    /// This thread's packing buffers (A panels, B panels), reused across calls.
    static BUFS: RefCell<(Vec<Line>, Vec<Line>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// Runs `f` on this thread's packing buffers of at least `a` and `b` bytes (a fresh pair if the
/// thread's are in use by an outer call).
fn with_bufs<R>(a: usize, b: usize, f: impl FnOnce(*mut u8, *mut u8) -> R) -> R {
    let lines = |bytes: usize| bytes.div_ceil(64) + 1;
    BUFS.with(|bufs| match bufs.try_borrow_mut() {
        Ok(mut bufs) => {
            let (pa, pb) = &mut *bufs;
            if pa.len() < lines(a) {
                pa.resize(lines(a), Line([0; 64]));
            }
            if pb.len() < lines(b) {
                pb.resize(lines(b), Line([0; 64]));
            }
            f(pa.as_mut_ptr().cast(), pb.as_mut_ptr().cast())
        }
        Err(_) => {
            let (mut pa, mut pb) = (vec![Line([0; 64]); lines(a)], vec![Line([0; 64]); lines(b)]);
            f(pa.as_mut_ptr().cast(), pb.as_mut_ptr().cast())
        }
    })
}

/// C (m x n at `c`, strides rsc, csc) <- init + A·B, then ReLU when `relu`: the packed GEMM on the
/// calling thread. `init` starts the chains of the first K block: `Zero`, `Load` (C itself) or
/// `Bias(b)` with b[i] for row i (m values).
///
/// Loop order: A is packed for all of K, MC' rows at a time (MC' x K holds as many elements as the
/// plan's MC x KC); then for each NC block of columns, for each KC block of depth: B packed (L2;
/// or read in place where the source already has the packed layout, [`PackB::in_place`]),
/// then every A micro-panel (L1) against every B micro-panel. The C block (MC' x NC) stays in
/// cache across the K blocks.
///
/// # Safety
/// `a` has m rows and `b` n columns over depth k; C is valid, writable, and aliases neither.
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn run<E: Float>(plan: &Plan<E>, m: usize, n: usize, k: usize, a: SourceA<E>, b: &dyn PackB<E>,
                                   c: *mut E, rsc: isize, csc: isize, init: Init<E>, relu: bool) {
    if m == 0 || n == 0 {
        return;
    }
    let (mr, nr, es) = (plan.mr, plan.nr, std::mem::size_of::<E>());
    // rows of A packed at a time: MC' = MC·KC / K whole panels (all rows when prepacked)
    let chunk = match a {
        SourceA::Rows(..) => m,
        SourceA::Strided(_) => (plan.mc * plan.kc / k.max(1) / mr * mr).max(mr).min(m),
    };
    let a_len = match a {
        SourceA::Rows(..) => 0,
        SourceA::Strided(_) => chunk.div_ceil(mr) * mr * k.max(1),
    };
    // equal K blocks of kcb and column blocks of ncb (the chains do not depend on them)
    let (kcb, ncb) = (plan.kc_for(k), plan.nc_for(n));
    let (kc_max, nc_max) = (kcb.min(k.max(1)), ncb.min(n.div_ceil(nr) * nr));
    // bf16 plans also hold the chunk's A panels (a prepacked A has them already) and the B block as
    // pairs: every K block but the last has an even depth, so A's pairs take ceil(k / 2) rows of depth
    // and block p0 starts at (p0 / 2)·mpad
    let a_pairs = match (plan.pairs, a) {
        (true, SourceA::Strided(_)) => chunk.div_ceil(mr) * mr * k.div_ceil(2),
        _ => 0,
    };
    let b_pairs = if plan.pairs { kc_max.div_ceil(2) * nc_max } else { 0 };
    with_bufs((a_len + a_pairs) * es, (nc_max * kc_max + b_pairs) * es, |pa, pb| {
        let (pa, pb) = (pa.cast::<E>(), pb.cast::<E>());
        let (pa_pairs, pb_pairs) = (pa.wrapping_add(a_len), pb.wrapping_add(nc_max * kc_max));
        for ic in (0..m).step_by(chunk) {
            let mc = chunk.min(m - ic);
            // the packed rows, their count rounded up to MR, and the first row of this product in them
            let (apack, mpad, row0) = match a {
                SourceA::Rows(p, row0) => (p.data(plan, k, row0).expect("gemm: A prepacked for another plan or depth"), p.mpad, row0),
                SourceA::Strided(s) => {
                    let mpad = mc.div_ceil(mr) * mr;
                    // SAFETY: `pa` has room for the chunk's panels over all of K, `pa_pairs` (bf16 plans)
                    // for their pairs.
                    unsafe {
                        s.pack_rows(plan, ic, mc, pa);
                        if plan.pairs {
                            pair_rows(pa.cast(), mpad, k, kcb, mr, pa_pairs.cast());
                        }
                    }
                    (if plan.pairs { pa_pairs } else { pa }.cast_const(), mpad, 0)
                }
            };
            for jc in (0..n).step_by(ncb) {
                let nc = ncb.min(n - jc);
                // k = 0 still runs one empty block: it writes the initial values (and the ReLU)
                for p0 in (0..k.max(1)).step_by(kcb) {
                    let kc = kcb.min(k - p0.min(k));
                    let block_init = if p0 == 0 { init } else { Init::Load };
                    let last = p0 + kc >= k;
                    // B block width: nc rounded up to NR (the last micro-tile reads NR columns);
                    // the block read in place, or packed with row stride ldb
                    let width = nc.div_ceil(nr) * nr;
                    let f32_block = |pb: *mut E| {
                        b.in_place(p0, jc, width).unwrap_or_else(|| {
                            b.pack(plan, p0, kc, jc, nc, pb, width);
                            (pb.cast_const(), width)
                        })
                    };
                    // the kernel's depth steps, and where the block's A panels start (in units of mpad)
                    let (pb, ldb, depth, a_block) = if plan.pairs {
                        let (pairs, ldp) = b.paired_in_place(p0, jc, width).unwrap_or_else(|| {
                            let (pb, ldb) = f32_block(pb);
                            // SAFETY: the block has kc rows of width elements ldb apart; `pb_pairs` has room for its pairs.
                            unsafe { pack::pair_panel(kc, width, pb.cast(), ldb, pb_pairs.cast()) };
                            (pb_pairs.cast_const(), width)
                        });
                        (pairs, ldp, kc.div_ceil(2), p0 / 2)
                    } else {
                        let (pb, ldb) = f32_block(pb);
                        (pb, ldb, kc, p0)
                    };
                    for ir in (0..mc).step_by(mr) {
                        // A micro-panel of packed rows row0 + ir..: K block at a_block·mpad, its row r at r·depth
                        let ap = apack.wrapping_add(a_block * mpad + (row0 + ir) * depth);
                        let rows = mr.min(mc - ir);
                        let init = match block_init {
                            // bias of rows ic + ir..
                            Init::Bias(bias) => Init::Bias(bias.wrapping_add(ic + ir)),
                            other => other,
                        };
                        for jr in (0..nc).step_by(nr) {
                            // C tile (ic + ir, jc + jr): c + (ic + ir)·rsc + (jc + jr)·csc
                            let ct = c.wrapping_offset((ic + ir) as isize * rsc + (jc + jr) as isize * csc);
                            // the next tile along the row, or the first of the next row of tiles
                            let next = if jr + nr < nc { ct.wrapping_offset(nr as isize * csc) } else {
                                c.wrapping_offset((ic + ir + mr) as isize * rsc + jc as isize * csc)
                            };
                            let tile = Tile { c: ct, ldc: rsc, init, relu: relu && last, next };
                            let cols = nr.min(nc - jr);
                            // B columns jr.. of the block
                            let bp = pb.wrapping_add(jr);
                            // SAFETY: both micro-panels lie in packed storage; a full tile with unit
                            // column stride is valid C; an edge tile goes through a local buffer.
                            unsafe {
                                if rows == mr && cols == nr && csc == 1 {
                                    (plan.kernel)(depth, ap, bp, ldb, &tile);
                                } else {
                                    edge(plan, depth, ap, bp, ldb, &tile, rows, cols, csc);
                                }
                            }
                        }
                    }
                }
            }
        }
    });
}

/// An A packed by [`Strided::pack_rows`] (`mpad` rows, depth k in blocks of kcb) as bf16 pairs into
/// `dst`: block p0 at (p0 / 2)·mpad, panel p of it at p·MR·ceil(kc / 2).
///
/// # Safety
/// `src` holds the packed A; `dst` has room for mpad·ceil(k / 2) elements.
unsafe fn pair_rows(src: *const f32, mpad: usize, k: usize, kcb: usize, mr: usize, dst: *mut f32) {
    for p0 in (0..k).step_by(kcb) {
        let kc = kcb.min(k - p0);
        for p in 0..mpad / mr {
            // source panel: block p0 at p0·mpad, rows p·MR.. at p·MR·kc; MR wide, depth-major
            let from = src.wrapping_add(p0 * mpad + p * mr * kc);
            let to = dst.wrapping_add(p0 / 2 * mpad + p * mr * kc.div_ceil(2));
            // SAFETY: both panels lie in their buffers (the contract).
            unsafe { pack::pair_panel(kc, mr, from, mr, to) };
        }
    }
}

/// A tile of `rows` x `cols` (< MR x NR, or C with non-unit column stride): the micro-kernel runs on
/// a local MR x NR buffer, copied from C first when the chain continues from C, and back after.
///
/// # Safety
/// As for a full tile, for the rows x cols part of C that exists.
#[allow(clippy::too_many_arguments)]
unsafe fn edge<E: Float>(plan: &Plan<E>, kc: usize, ap: *const E, bp: *const E, ldb: usize, t: &Tile<E>, rows: usize,
                         cols: usize, csc: isize) {
    let (mr, nr) = (plan.mr, plan.nr);
    // written before it is read: by the kernel (Zero, Bias) or zeroed and copied from C here (Load)
    let mut buf = std::mem::MaybeUninit::<[Line; TILE_BYTES / 64]>::uninit();
    let bufp = buf.as_mut_ptr().cast::<E>();
    let mut bias = [E::zero(); MAX_MR];
    // element (i, j) of the C tile: c + i·ldc + j·csc
    let cij = |i: usize, j: usize| t.c.wrapping_offset(i as isize * t.ldc + j as isize * csc);
    // SAFETY: i < rows and j < cols stay inside C; the buffer holds MR·NR <= TILE_BYTES / es elements.
    unsafe {
        let init = match t.init {
            Init::Load => {
                for i in 0..mr {
                    for j in 0..nr {
                        // buf[i·NR + j] = C(i, j) inside C, 0 outside
                        *bufp.add(i * nr + j) = if i < rows && j < cols { *cij(i, j) } else { E::zero() };
                    }
                }
                Init::Load
            }
            Init::Bias(b) => {
                bias[..rows].copy_from_slice(std::slice::from_raw_parts(b, rows));
                Init::Bias(bias.as_ptr())
            }
            Init::Zero => Init::Zero,
        };
        let local = Tile { c: bufp, ldc: nr as isize, init, relu: t.relu, next: t.next };
        (plan.kernel)(kc, ap, bp, ldb, &local);
        for i in 0..rows {
            for j in 0..cols {
                *cij(i, j) = *bufp.add(i * nr + j);
            }
        }
    }
}

/// `dst[p·rows + r]` = `src[r·cols + p]`: the transpose of a row-major rows x cols matrix (packed
/// like a B block, by 8 x 8 register transposes where the plan allows).
pub(crate) fn transpose<E: Float>(plan: &Plan<E>, src: &[E], rows: usize, cols: usize, dst: &mut [E]) {
    assert!(src.len() >= rows * cols && dst.len() >= rows * cols, "transpose: buffers too small");
    // depth p along the unit stride of src, index r along its rows
    // SAFETY: both buffers hold rows·cols elements (checked above).
    unsafe { pack::panel(plan, cols, rows, rows, src.as_ptr(), cols as isize, 1, E::one(), dst.as_mut_ptr()) };
}

/// What follows the product in [`gemm_ex`]: a bias per row of C, then ReLU.
#[derive(Clone, Copy, Debug, Default)]
pub struct Epilogue<'a, E> {
    /// Added to row i of C (m values); only with beta = 0.
    pub bias: Option<&'a [E]>,
    pub relu: bool,
}

/// C <- alpha · A·B + beta · C for strided 2-D views, on the calling thread, on the selected path.
///
/// Shapes are internal invariants of the calling kernel (validated before), so a mismatch is a bug
/// and panics rather than corrupting memory.
pub fn gemm<F: Float>(alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, beta: F, c: ArrayViewMut2<F>) {
    gemm_ex(Plan::selected(), alpha, a, b, beta, c, Epilogue::default());
}

/// [`gemm`] on an explicit plan (any ISA path), followed by an epilogue.
pub fn gemm_ex<F: Float>(plan: &Plan<F>, alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, beta: F, mut c: ArrayViewMut2<F>,
                         epi: Epilogue<F>) {
    let (m, k) = a.dim();
    let (k2, n) = b.dim();
    assert!(k == k2 && c.dim() == (m, n), "gemm: inner dims {k} vs {k2}, C {:?} vs ({m},{n})", c.dim());
    assert!(epi.bias.is_none_or(|b| b.len() == m && beta == F::zero()), "gemm: bias needs m values and beta 0");
    if m == 0 || n == 0 {
        return;
    }
    let init = match epi.bias {
        Some(bias) => Init::Bias(bias.as_ptr()),
        None if scale_by_beta(beta, &mut c) => Init::Load,
        None => Init::Zero,
    };
    let sc = c.strides().to_vec();
    let (a, b) = (Strided::view(a, alpha), Strided::view(b, F::one()));
    // SAFETY: the views own valid memory of the checked shapes; C is a unique mutable view, so it
    // aliases neither A nor B; the bias has m values.
    unsafe { run(plan, m, n, k, SourceA::Strided(&a), &b, c.as_mut_ptr(), sc[0], sc[1], init, epi.relu) };
}

/// Same as [`gemm`], with C split into column blocks (or row blocks when C is tall) that rayon
/// computes in parallel. Each element's chain is the same whatever the split.
pub fn gemm_par<F: Float>(alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, beta: F, c: ArrayViewMut2<F>) {
    gemm_par_with(Plan::selected(), alpha, a, b, beta, c)
}

/// [`gemm_par`] on an explicit plan.
pub fn gemm_par_with<F: Float>(plan: &Plan<F>, alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, beta: F,
                               mut c: ArrayViewMut2<F>) {
    let (m, k) = a.dim();
    assert!(b.nrows() == k && c.dim() == (m, b.ncols()), "gemm: inner dims {k} vs {}, C {:?} vs ({m},{})", b.nrows(),
            c.dim(), b.ncols());
    let load = scale_by_beta(beta, &mut c);
    let sc = c.strides().to_vec();
    // SAFETY: the views own valid memory of the checked shapes; C is a unique mutable view.
    unsafe { run_par(plan, alpha, a, b, load, c.as_mut_ptr(), sc[0], sc[1]) }
}

/// C = beta·C before a product adds to it: whether C is read at all (beta is not 0); C itself is
/// scaled only for a beta other than 0 and 1.
fn scale_by_beta<F: Float>(beta: F, c: &mut ArrayViewMut2<F>) -> bool {
    if beta != F::zero() && beta != F::one() {
        c.mapv_inplace(|v| beta * v);
    }
    beta != F::zero()
}

/// A·B into a new array on every thread of the pool (C is written, never zeroed first): the
/// binding's matrix product. An output too large to allocate is an error naming `op`.
pub fn matmul_par<F: Float>(op: &'static str, a: ArrayView2<F>, b: ArrayView2<F>) -> Result<Array2<F>> {
    let (m, n) = (a.nrows(), b.ncols());
    assert_eq!(a.ncols(), b.nrows(), "gemm: inner dims");
    let (mut c, len) = crate::tensor::reserve::<F>(op, &[m, n])?;
    // SAFETY: C has room for m x n elements, row-major and unaliased; its chains start from 0, so
    // every element is written and none is read before.
    unsafe {
        run_par(Plan::selected(), F::one(), a, b, false, c.as_mut_ptr(), n as isize, 1);
        c.set_len(len);
    }
    Ok(Array2::from_shape_vec((m, n), c).expect("length equals the shape's size"))
}

/// C (m x n at `c`, strides rsc, csc) <- (C if `load`, else 0) + alpha·A·B over the pool's threads. Wide C: A is
/// packed once (in parallel) and shared, and each task multiplies it by a block of B's columns;
/// tall C: each task packs and multiplies its own block of A's rows by all of B. Blocks are whole
/// micro-panels, so no thread computes a partial panel it could have avoided.
///
/// # Safety
/// C is valid and writable for m x n elements at those strides and aliases neither A nor B.
#[allow(clippy::too_many_arguments)]
unsafe fn run_par<F: Float>(plan: &Plan<F>, alpha: F, a: ArrayView2<F>, b: ArrayView2<F>, load: bool, c: *mut F,
                            rsc: isize, csc: isize) {
    let init = || if load { Init::Load } else { Init::Zero };
    let ((m, k), n) = (a.dim(), b.ncols());
    let threads = rayon::current_num_threads();
    let (sa, sb) = (Strided::view(a, alpha), Strided::view(b, F::one()));
    let c = SendPtr(c);
    if threads <= 1 || m * n * k < (1 << 20) {
        // SAFETY: forwarded contract.
        return unsafe { run(plan, m, n, k, SourceA::Strided(&sa), &sb, c.get(), rsc, csc, init(), false) };
    }
    if n >= m {
        let packed = Prepacked::new(plan, &sa);
        let block = n.div_ceil(threads).next_multiple_of(plan.nr);
        (0..n.div_ceil(block)).into_par_iter().for_each(|t| {
            // task t: columns j0 = t·block ..
            let j0 = t * block;
            let cols = block.min(n - j0);
            // B columns j0.. and C columns j0..: b + j0·cs, c + j0·csc
            let bj = Strided { ptr: sb.at(0, j0), cols, ..sb };
            // SAFETY: each task writes its own columns of C; A's panels cover all of its rows over K.
            unsafe { run(plan, m, cols, k, SourceA::Rows(&packed, 0), &bj, c.get().wrapping_offset(j0 as isize * csc), rsc, csc,
                         init(), false) };
        });
    } else {
        let block = m.div_ceil(threads).next_multiple_of(plan.mr);
        (0..m.div_ceil(block)).into_par_iter().for_each(|t| {
            // task t: rows i0 = t·block ..
            let i0 = t * block;
            let rows = block.min(m - i0);
            // A rows i0.. and C rows i0..: a + i0·rs, c + i0·rsc
            let ai = Strided { ptr: sa.at(i0, 0), rows, ..sa };
            // SAFETY: each task writes its own rows of C.
            unsafe { run(plan, rows, n, k, SourceA::Strided(&ai), &sb, c.get().wrapping_offset(i0 as isize * rsc), rsc, csc,
                         init(), false) };
        });
    }
}

/// A raw pointer the tasks of [`run_par`] share, each writing its own part.
#[derive(Clone, Copy)]
struct SendPtr<E>(*mut E);

impl<E> SendPtr<E> {
    fn get(self) -> *mut E {
        self.0
    }
}
// SAFETY: the tasks that share it write disjoint elements.
unsafe impl<E> Send for SendPtr<E> {}
// SAFETY: as above.
unsafe impl<E> Sync for SendPtr<E> {}
