//! F(4, 5): the transforms of a 1x5 kernel over tiles of 4 output pixels along a row (`Along::X`),
//! or of a 5x1 kernel over tiles of 4 along a column (`Along::Y`), each from 8 input values:
//! 8 multiplies per (output, input) channel pair instead of 20. Toom-Cook points 0, ±1, ±2, ±1/2, ∞
//! (the points of F(6, 3)); the matrices were derived with exact fractions and are checked in f64
//! against the direct convolution by `tests_rs/conv.rs`.

use super::lanes::{map_tiles, merge_phases, per_isa, split_phases, strided_rows, strided_rows_mut, Lane, Rows, Transform1d};
use super::super::Geom;
use crate::gemm::Isa;
use crate::Float;

/// Output pixels per tile.
const TILE: usize = 4;

/// The axis the kernel and the tiles run along.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Along {
    /// A 1x5 kernel: a tile is 4 output pixels of one row; tile rows are output rows.
    X,
    /// A 5x1 kernel: a tile is 4 output pixels of one column; a tile row holds Wo tiles.
    Y,
}

/// v = Bᵀ d for one 8-vector d: the input transform.
struct InputTransform;

impl Transform1d<8, 8> for InputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(d: [T; 8]) -> [T; 8] {
        let (c2, c4, c5, c17, c21) = (F::c(2.0), F::c(4.0), F::c(5.0), F::c(17.0 / 4.0), F::c(21.0 / 4.0));
        let (h, q, c52, c54) = (F::c(0.5), F::c(0.25), F::c(5.0 / 2.0), F::c(5.0 / 4.0));
        // rows 2k − 1 and 2k of Bᵀ: an even part s (d2, d4, d6) plus or minus an odd part t (d1, d3, d5)
        let (s1, t1) = (d[2] + d[6] - d[4] * c17, d[1] + d[5] - d[3] * c17);
        let (s2, t2) = (d[2] * q - d[4] * c54 + d[6], d[1] * h - d[3] * c52 + d[5] * c2);
        let (s3, t3) = (d[2] * c4 - d[4] * c5 + d[6], d[1] * c2 - d[3] * c52 + d[5] * h);
        [d[0] - d[6] + (d[4] - d[2]) * c21, s1 + t1, s1 - t1, s2 + t2, s2 - t2, s3 + t3, s3 - t3, d[7] - d[1] + (d[3] - d[5]) * c21]
    }
}

/// y = Aᵀ m for one 8-vector m: the output transform.
struct OutputTransform;

impl Transform1d<8, 4> for OutputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(m: [T; 8]) -> [T; 4] {
        let (c2, c4, c8, h, q, e) = (F::c(2.0), F::c(4.0), F::c(8.0), F::c(0.5), F::c(0.25), F::c(0.125));
        // sums and differences of the pairs of points ±1, ±2, ±1/2
        let (s1, d1, s2, d2, s3, d3) = (m[1] + m[2], m[1] - m[2], m[3] + m[4], m[3] - m[4], m[5] + m[6], m[5] - m[6]);
        [m[0] + s1 + s2 + s3, d1 + d2 * c2 + d3 * h, s1 + s2 * c4 + s3 * q, d1 + d2 * c8 + d3 * e + m[7]]
    }
}

/// m = A y for one 4-vector y: the adjoint of [`OutputTransform`] (a tile of dY into the transform domain).
struct GradOutputTransform;

impl Transform1d<4, 8> for GradOutputTransform {
    #[inline(always)]
    fn apply<F: Float, T: Lane<F>>(y: [T; 4]) -> [T; 8] {
        let (c2, c4, c8, h, q, e) = (F::c(2.0), F::c(4.0), F::c(8.0), F::c(0.5), F::c(0.25), F::c(0.125));
        // at the points ±p: an even part (y0, y2) plus or minus an odd part (y1, y3)
        let (e1, o1) = (y[0] + y[2], y[1] + y[3]);
        let (e2, o2) = (y[0] + y[2] * c4, y[1] * c2 + y[3] * c8);
        let (e3, o3) = (y[0] + y[2] * q, y[1] * h + y[3] * e);
        [y[0], e1 + o1, e1 - o1, e2 + o2, e2 - o2, e3 + o3, e3 - o3, y[3]]
    }
}

/// G (8 x 5): u = G w transforms the 5 taps of one (output, input) channel pair.
const G: [[f64; 5]; 8] = [
    [1.0, 0.0, 0.0, 0.0, 0.0],
    [-2.0 / 9.0, -2.0 / 9.0, -2.0 / 9.0, -2.0 / 9.0, -2.0 / 9.0],
    [-2.0 / 9.0, 2.0 / 9.0, -2.0 / 9.0, 2.0 / 9.0, -2.0 / 9.0],
    [1.0 / 90.0, 1.0 / 45.0, 2.0 / 45.0, 4.0 / 45.0, 8.0 / 45.0],
    [1.0 / 90.0, -1.0 / 45.0, 2.0 / 45.0, -4.0 / 45.0, 8.0 / 45.0],
    [32.0 / 45.0, 16.0 / 45.0, 8.0 / 45.0, 4.0 / 45.0, 2.0 / 45.0],
    [32.0 / 45.0, -16.0 / 45.0, 8.0 / 45.0, -4.0 / 45.0, 2.0 / 45.0],
    [0.0, 0.0, 0.0, 0.0, 1.0],
];

/// `u[k]` = Σ_j G[k][j] · `w[j]` for the 5 taps w of one channel pair.
pub(super) fn weight<F: Float>(w: &[F], u: &mut [F]) {
    for (uk, gk) in u.iter_mut().zip(&G) {
        *uk = gk.iter().zip(w).fold(F::zero(), |acc, (&gkj, &wj)| acc + F::c(gkj) * wj);
    }
}

/// `dw[j]` = Σ_k G[k][j] · du(k): the adjoint of [`weight`].
pub(super) fn weight_grad<F: Float>(du: impl Fn(usize) -> F, dw: &mut [F]) {
    for (j, dwj) in dw.iter_mut().enumerate() {
        *dwj = G.iter().enumerate().fold(F::zero(), |acc, (k, gk)| acc + F::c(gk[j]) * du(k));
    }
}

/// Where the values of one row of tiles come from: along x one row (None: a row of zeros); along y
/// N whole rows, one per tile position, a row of zeros outside the plane. The input transform reads
/// either as zero-padded by `pw` columns in front (along y, the tile of column t at row column t − pw).
pub(super) enum Source<'a, F, const N: usize> {
    Row(Option<&'a [F]>),
    Rows([&'a [F]; N]),
}

/// `V[ξ]` rows of tile row ty: `v[ξ·xi_stride + at + t]` = (Bᵀ d)[ξ], d the 8 input values of tile t
/// (along x: `x[ty − ph, 4·t − pw ..]`; along y: `x[4·ty − ph .., t − pw]`; 0 outside the plane `xc`).
#[allow(clippy::too_many_arguments)]
pub(super) fn input_rows<F: Float>(along: Along, isa: Isa, g: &Geom, xc: &[F], ty: usize, tw: usize, v: &mut [F], at: usize,
                                   xi_stride: usize, buf: &mut Rows<F>) {
    let ph = g.pad[0] as isize;
    // input row iy, None above or below the image
    let input_row = |iy: isize| (iy >= 0 && (iy as usize) < g.h).then(|| &xc[iy as usize * g.w..(iy as usize + 1) * g.w]);
    let source = match along {
        // along x, the one input row ty − ph
        Along::X => Source::Row(input_row(ty as isize - ph)),
        // along y, tile position r of column t is input row 4·ty − ph + r
        Along::Y => Source::Rows(std::array::from_fn(|r| input_row((TILE * ty + r) as isize - ph).unwrap_or(&buf.zeros[..g.w]))),
    };
    input_row_isa(isa, source, g.pad[1], tw, &mut buf.phase, v, at, xi_stride);
}

per_isa!(
    /// [`input_row`] for the plan's ISA.
    input_row_isa => input_row (source: Source<'_, F, 8>, pw: usize, tw: usize, phase: &mut [F], v: &mut [F], at: usize,
                                xi_stride: usize)
);

/// The input transform of one row of tiles from `source` into `v[ξ·xi_stride + at + t]`.
#[inline(always)]
fn input_row<F: Float>(source: Source<'_, F, 8>, pw: usize, tw: usize, phase: &mut [F], v: &mut [F], at: usize, xi_stride: usize) {
    match source {
        Source::Row(x_row) => {
            // d_j[tx] = padded row[4·tx + j]: phase j % 4 from tile tx + j / 4
            split_phases(x_row, pw, tw + 1, phase);
            let d = std::array::from_fn(|j| &phase[(j % 4) * (tw + 1) + j / 4..][..tw]);
            map_tiles::<F, InputTransform, 8, 8>(d, &mut strided_rows_mut(v, at, xi_stride, tw));
        }
        Source::Rows(rows) => {
            // d_j[t] = row j at column t − pw, for the tiles pw .. pw + W over the plane's columns
            let width = rows[0].len();
            map_tiles::<F, InputTransform, 8, 8>(rows, &mut strided_rows_mut(v, at + pw, xi_stride, width));
            // the tiles over the padding columns transform zeros into zeros
            for k in 0..8 {
                let row = &mut v[k * xi_stride + at..][..tw];
                row[..pw].fill(F::zero());
                row[pw + width..].fill(F::zero());
            }
        }
    }
}

/// The output pixels of tile row ty: (Aᵀ m)[i] + b0 (then ReLU), m[ξ] = `m[ξ·xi_stride + at + t]`,
/// at output row ty, columns 4·t + i (along x) or at output rows 4·ty + i, column t (along y),
/// clipped to Ho x Wo, into the output plane `yo`.
#[allow(clippy::too_many_arguments)]
pub(super) fn output_rows<F: Float>(along: Along, isa: Isa, g: &Geom, m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F,
                                    relu: bool, ty: usize, yo: &mut [F], buf: &mut Rows<F>) {
    output_row_isa(isa, m, at, xi_stride, tw, buf);
    let q = strided_rows::<F, 4>(&buf.ex, 0, tw, tw);
    let out = |o: F| {
        let o = o + b0;
        if relu { o.max(F::zero()) } else { o }
    };
    match along {
        Along::X => {
            // y[ty, 4·tx + i] = q[i][tx], clipped to Wo
            merge_phases(q, &mut yo[ty * g.wo..(ty + 1) * g.wo], out);
        }
        Along::Y => {
            for (i, qi) in q.iter().enumerate() {
                // y[4·ty + i, ox] = q[i][ox], clipped to Ho
                let oy = TILE * ty + i;
                if oy >= g.ho {
                    break;
                }
                yo[oy * g.wo..(oy + 1) * g.wo].iter_mut().zip(qi.iter()).for_each(|(y, &v)| *y = out(v));
            }
        }
    }
}

per_isa!(
    /// [`output_row`] for the plan's ISA.
    output_row_isa => output_row (m: &[F], at: usize, xi_stride: usize, tw: usize, buf: &mut Rows<F>)
);

/// The output transform of one row of tiles: q[i][t] = (Aᵀ m)[i], m[ξ] = `m[ξ·xi_stride + at + t]`,
/// into `buf.ex` (4 rows of tw).
#[inline(always)]
fn output_row<F: Float>(m: &[F], at: usize, xi_stride: usize, tw: usize, buf: &mut Rows<F>) {
    let mut q = strided_rows_mut(&mut buf.ex, 0, tw, tw);
    map_tiles::<F, OutputTransform, 8, 4>(strided_rows(m, at, xi_stride, tw), &mut q);
}

/// `dM[ξ]` rows of tile row ty: `dm[ξ·xi_stride + at + t]` = (A y)[ξ], y the 4 dY values of tile t
/// (along x: `dY[ty, 4·t ..]`; along y: `dY[4·ty .., t]`; 0 outside Ho x Wo) of the plane `dyo`.
#[allow(clippy::too_many_arguments)]
pub(super) fn grad_output_rows<F: Float>(along: Along, isa: Isa, g: &Geom, dyo: &[F], ty: usize, tw: usize, dm: &mut [F],
                                         at: usize, xi_stride: usize, buf: &mut Rows<F>) {
    // dY row oy, None below the image
    let dy_row = |oy: usize| (oy < g.ho).then(|| &dyo[oy * g.wo..(oy + 1) * g.wo]);
    let source = match along {
        // along x, the one dY row ty
        Along::X => Source::Row(dy_row(ty)),
        // along y, tile position i of column t is dY row 4·ty + i
        Along::Y => Source::Rows(std::array::from_fn(|i| dy_row(TILE * ty + i).unwrap_or(&buf.zeros[..g.wo]))),
    };
    grad_output_row_isa(isa, source, tw, &mut buf.phase, dm, at, xi_stride);
}

per_isa!(
    /// [`grad_output_row`] for the plan's ISA.
    grad_output_row_isa => grad_output_row (source: Source<'_, F, 4>, tw: usize, phase: &mut [F], dm: &mut [F], at: usize,
                                            xi_stride: usize)
);

/// The adjoint output transform of one row of tiles from `source` (columns past Wo read as 0) into
/// `dm[ξ·xi_stride + at + t]`.
#[inline(always)]
fn grad_output_row<F: Float>(source: Source<'_, F, 4>, tw: usize, phase: &mut [F], dm: &mut [F], at: usize, xi_stride: usize) {
    let mut out_rows = strided_rows_mut(dm, at, xi_stride, tw);
    match source {
        Source::Row(x_row) => {
            // y_i[tx] = row[4·tx + i]
            split_phases(x_row, 0, tw, phase);
            map_tiles::<F, GradOutputTransform, 4, 8>(strided_rows(phase, 0, tw, tw), &mut out_rows);
        }
        // y_i[t] = row i of the tile row at column t
        Source::Rows(rows) => map_tiles::<F, GradOutputTransform, 4, 8>(rows.map(|row| &row[..tw]), &mut out_rows),
    }
}
