//! What the Winograd transforms are built from: 1-D transforms written once for one value and for
//! [`Lanes`] of values (one per tile), run over whole rows of tiles by [`map_tiles`], and compiled
//! per ISA by [`per_isa!`].

use crate::Float;
use std::ops::{Add, Mul, Sub};

/// What the 1-D transforms compute on: one value F, or [`Lanes`] of F (one per tile).
pub(super) trait Lane<F>: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<F, Output = Self> {}
impl<F: Float> Lane<F> for F {}
impl<F: Float> Lane<F> for Lanes<F> {}

/// Tiles per block of the row transforms: one 512-bit register of f32.
const LANES: usize = 16;

/// One value per tile for LANES tiles. Its operations are fixed-length loops, which the compiler
/// turns into vector instructions; each lane computes exactly what the scalar path computes.
#[derive(Clone, Copy)]
pub(super) struct Lanes<F>([F; LANES]);

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
pub(super) trait Transform1d<const M: usize, const N: usize> {
    fn apply<F: Float, T: Lane<F>>(d: [T; M]) -> [T; N];
}

/// dst[k][tx] = X(src[0][tx], .., src[M − 1][tx])[k] for every tile tx of the rows: blocks of LANES
/// tiles on [`Lanes`], the rest one tile at a time (the same operations on F).
#[inline(always)]
pub(super) fn map_tiles<F: Float, X: Transform1d<M, N>, const M: usize, const N: usize>(src: [&[F]; M],
                                                                                       dst: &mut [&mut [F]; N]) {
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

/// N disjoint rows of `len` elements of `buf`, row r at `first + r·stride` (stride >= len): the
/// destinations of a 1-D transform, as exact-length slices so the loops over them vectorise
/// (indexing `buf` at `first + r·stride + tx` kept a bounds check per element, which left the
/// transforms scalar).
#[inline(always)]
pub(super) fn strided_rows_mut<F, const N: usize>(buf: &mut [F], first: usize, stride: usize, len: usize) -> [&mut [F]; N] {
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
pub(super) fn strided_rows<F, const N: usize>(buf: &[F], first: usize, stride: usize, len: usize) -> [&[F]; N] {
    std::array::from_fn(|r| &buf[first + r * stride..first + r * stride + len])
}

/// Per-thread buffers of the transforms of one tile row (a few KiB, reused across calls), sized
/// for every scheme (every scheme reads its input and dY rows in place; a column scheme's row has
/// tw = Wo tiles).
pub(super) struct Rows<F> {
    /// A row of zeros (a column scheme's rows outside the plane; tw = Wo there).
    pub zeros: Vec<F>,
    /// Phases of a padded row: `phase[m][tx]` = row[4·tx + m], m < 4, tx <= tw.
    pub phase: Vec<F>,
    /// A transform along x, per patch row or per output row: 36 x tw.
    pub ex: Vec<F>,
}

impl<F: Float> Rows<F> {
    pub fn new(tw: usize) -> Self {
        Rows { zeros: vec![F::zero(); tw], phase: vec![F::zero(); 4 * (tw + 1)], ex: vec![F::zero(); 36 * tw] }
    }
}

/// The 4 phases of a row that is zero-padded by `pad` values in front, read straight from the
/// unpadded row `x` (None: a row of zeros): `phase[m·n + tx]` = x[4·tx + m − pad] for tx < n, 0
/// where that index lies outside x.
#[inline(always)]
pub(super) fn split_phases<F: Float>(x: Option<&[F]>, pad: usize, n: usize, phase: &mut [F]) {
    let phase = &mut phase[..4 * n];
    let Some(x) = x else {
        phase.fill(F::zero());
        return;
    };
    // tiles lo..hi read their 4 values inside x: 4·lo − pad >= 0 and 4·hi − pad <= x.len()
    let lo = pad.div_ceil(4).min(n);
    let hi = ((x.len() + pad) / 4).clamp(lo, n);
    for tx in (0..lo).chain(hi..n) {
        for m in 0..4 {
            // padded column 4·tx + m is x[4·tx + m − pad] when that lies in 0..x.len()
            let s = (4 * tx + m).checked_sub(pad).filter(|&s| s < x.len());
            phase[m * n + tx] = s.map_or(F::zero(), |s| x[s]);
        }
    }
    let (p0, rest) = phase.split_at_mut(n);
    let (p1, rest) = rest.split_at_mut(n);
    let (p2, p3) = rest.split_at_mut(n);
    // tile tx reads x[4·tx − pad ..][..4] (zipped slices, no index checks, so the loop vectorises)
    let quads = x[4 * lo - pad..4 * hi - pad].chunks_exact(4);
    let phases = p0[lo..hi].iter_mut().zip(&mut p1[lo..hi]).zip(p2[lo..hi].iter_mut().zip(&mut p3[lo..hi]));
    for (q, ((a, b), (c, d))) in quads.zip(phases) {
        (*a, *b, *c, *d) = (q[0], q[1], q[2], q[3]);
    }
}

/// The inverse of [`split_phases`] for an output row: `out[4·tx + m]` = f(`q[m][tx]`) for every
/// column of `out` (its last tile may be cut short).
#[inline(always)]
pub(super) fn merge_phases<F: Float>(q: [&[F]; 4], out: &mut [F], f: impl Fn(F) -> F) {
    let (whole, part) = out.split_at_mut(out.len() / 4 * 4);
    let n = whole.len() / 4;
    // zipped slices, no index checks, so the loop vectorises
    let phases = q[0][..n].iter().zip(&q[1][..n]).zip(q[2][..n].iter().zip(&q[3][..n]));
    for (quad, ((&a, &b), (&c, &d))) in whole.chunks_exact_mut(4).zip(phases) {
        (quad[0], quad[1], quad[2], quad[3]) = (f(a), f(b), f(c), f(d));
    }
    for (m, slot) in part.iter_mut().enumerate() {
        // the cut tile n: columns 4·n + m
        *slot = f(q[m][n]);
    }
}

/// Defines `fn $name<F: Float>(isa: Isa, args..)`: `$body(args..)` compiled for the plan's ISA
/// (AVX-512, AVX2 + FMA, or portable), so that its loops over the tiles of a row are vectorised
/// with that ISA's registers.
macro_rules! per_isa {
    ($(#[$doc:meta])* $name:ident => $body:ident ($($arg:ident: $ty:ty),*)) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        pub(super) fn $name<F: Float>(isa: Isa, $($arg: $ty),*) {
            /// The body compiled with AVX-512. Safety: the CPU has AVX-512F.
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx512f")]
            #[allow(clippy::too_many_arguments)]
            unsafe fn avx512<F: Float>($($arg: $ty),*) {
                $body($($arg),*)
            }
            /// The body compiled with AVX2 and FMA. Safety: the CPU has both.
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            #[allow(clippy::too_many_arguments)]
            unsafe fn avx2<F: Float>($($arg: $ty),*) {
                $body($($arg),*)
            }
            match isa {
                // SAFETY: the plan's ISA is supported by this CPU.
                #[cfg(target_arch = "x86_64")]
                Isa::Avx512 => unsafe { avx512($($arg),*) },
                // SAFETY: as above.
                #[cfg(target_arch = "x86_64")]
                Isa::Avx2 => unsafe { avx2($($arg),*) },
                _ => $body($($arg),*),
            }
        }
    };
}
pub(super) use per_isa;
