//! F(4x4, 3x3): the transforms of a 3x3 kernel over 4 x 4 tiles of output pixels, each from a
//! 6 x 6 input patch (36 transform positions ξ = 6a + b, a along y and b along x). Matrices from
//! Lavin & Gray (2016), points 0, ±1, ±2, ∞.

use super::lanes::{map_tiles, merge_phases, per_isa, split_phases, strided_rows, strided_rows_mut, Lane, Rows, Transform1d};
use super::super::Geom;
use crate::gemm::Isa;
use crate::Float;

/// Output pixels per tile side.
const TILE: usize = 4;

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

/// u = G g for one 3-vector g: the weight transform along one axis.
#[inline(always)]
fn weight_1d<F: Float>(g: [F; 3]) -> [F; 6] {
    let (q, s, t) = (F::c(0.25), F::c(1.0 / 6.0), F::c(1.0 / 12.0));
    let e = F::c(1.0 / 24.0);
    [q * g[0], -s * (g[0] + g[1] + g[2]), -s * (g[0] - g[1] + g[2]), e * g[0] + t * g[1] + s * g[2],
     e * g[0] - t * g[1] + s * g[2], g[2]]
}

/// g = Gᵀ u for one 6-vector u: the adjoint of [`weight_1d`] along one axis.
#[inline(always)]
fn weight_grad_1d<F: Float>(u: [F; 6]) -> [F; 3] {
    let (q, s, t) = (F::c(0.25), F::c(1.0 / 6.0), F::c(1.0 / 12.0));
    let e = F::c(1.0 / 24.0);
    let (s12, d12, s34, d34) = (u[1] + u[2], u[1] - u[2], u[3] + u[4], u[3] - u[4]);
    [q * u[0] - s * s12 + e * s34, -s * d12 + t * d34, -s * s12 + s * s34 + u[5]]
}

/// `u[ξ]` = (G · w · Gᵀ)[ξ] for the 3 x 3 kernel w of one (output, input) channel pair.
pub(super) fn weight<F: Float>(w: &[F], u: &mut [F]) {
    // rows of G·w (6 x 3), then each of its rows times Gᵀ: (G w Gᵀ)[a][b] at ξ = 6a + b
    let cols: [[F; 6]; 3] = std::array::from_fn(|j| weight_1d([w[j], w[3 + j], w[6 + j]]));
    for (a, ua) in u.chunks_exact_mut(6).enumerate() {
        ua.copy_from_slice(&weight_1d([cols[0][a], cols[1][a], cols[2][a]]));
    }
}

/// `dw[3i + j]` = (Gᵀ · du · G)[i][j] for the 36 values `du(ξ)` of one channel pair: the adjoint of [`weight`].
pub(super) fn weight_grad<F: Float>(du: impl Fn(usize) -> F, dw: &mut [F]) {
    // rows of Gᵀ·du over b (6 x 3), then dW[i][j] = (Gᵀ · column j of them)[i]
    let r: [[F; 3]; 6] = std::array::from_fn(|a| weight_grad_1d(std::array::from_fn(|b| du(6 * a + b))));
    for j in 0..3 {
        let col = weight_grad_1d(std::array::from_fn(|a| r[a][j]));
        for (i, &value) in col.iter().enumerate() {
            dw[3 * i + j] = value;
        }
    }
}

/// `V[ξ]` rows of tile row ty: `v[ξ·xi_stride + at + tx]` = (Bᵀ d B)[ξ], d the 6 x 6 patch of the
/// channel plane `xc` at input rows 4·ty − ph.., columns 4·tx − pw.. (0 outside).
#[allow(clippy::too_many_arguments)]
pub(super) fn input_rows<F: Float>(isa: Isa, g: &Geom, xc: &[F], ty: usize, tw: usize, v: &mut [F], at: usize,
                                   xi_stride: usize, buf: &mut Rows<F>) {
    let ph = g.pad[0] as isize;
    // patch row r is input row iy = 4·ty + r − ph (None above or below the image)
    let rows: [Option<&[F]>; 6] = std::array::from_fn(|r| {
        let iy = (TILE * ty + r) as isize - ph;
        (iy >= 0 && (iy as usize) < g.h).then(|| &xc[iy as usize * g.w..(iy as usize + 1) * g.w])
    });
    input_row_isa(isa, &rows, g.pad[1], tw, buf, v, at, xi_stride);
}

per_isa!(
    /// [`input_row`] for the plan's ISA.
    input_row_isa => input_row (rows: &[Option<&[F]>; 6], pw: usize, tw: usize, buf: &mut Rows<F>, v: &mut [F], at: usize,
                                xi_stride: usize)
);

/// The input transform of one row of tiles from its 6 input rows (`rows`, read as padded by `pw`
/// columns in front): along x per patch row (into `buf.ex`), then along y into
/// `v[ξ·xi_stride + at + tx]`. Every loop runs over the tiles tx of the row on contiguous arrays.
#[inline(always)]
fn input_row<F: Float>(rows: &[Option<&[F]>; 6], pw: usize, tw: usize, buf: &mut Rows<F>, v: &mut [F], at: usize,
                       xi_stride: usize) {
    let Rows { phase, ex, .. } = buf;
    for (r, &row) in rows.iter().enumerate() {
        // phase[m][tx] = padded row[4·tx + m]: the patch columns j = m (and j = 4 + m from tile tx + 1)
        split_phases(row, pw, tw + 1, phase);
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

/// The output rows 4·ty.. of tile row ty: y[oy, ox] = (Aᵀ m A)[oy − 4·ty, ox − 4·tx] + b0 (then
/// ReLU), m[ξ] = `m[ξ·xi_stride + at + tx]`, clipped to Ho x Wo, into the output plane `yo`.
#[allow(clippy::too_many_arguments)]
pub(super) fn output_rows<F: Float>(isa: Isa, g: &Geom, m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F, relu: bool,
                                    ty: usize, yo: &mut [F], buf: &mut Rows<F>) {
    // output rows 4·ty .. min(4·ty + 4, Ho), Wo values each
    let out = &mut yo[TILE * ty * g.wo..(TILE * ty + TILE).min(g.ho) * g.wo];
    output_row_isa(isa, m, at, xi_stride, tw, b0, relu, out, g.wo, buf);
}

per_isa!(
    /// [`output_row`] for the plan's ISA.
    output_row_isa => output_row (m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F, relu: bool, out: &mut [F], wo: usize,
                                  buf: &mut Rows<F>)
);

/// The output transform of one row of tiles: m[ξ][tx] = `m[ξ·xi_stride + at + tx]` along y (into
/// `buf.ex`), then along x, + b0 and ReLU, into the output rows `out` (rows of `wo` values, at most
/// 4: row r of the tiles, clipped to Wo, goes to row r of `out` while there is one).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn output_row<F: Float>(m: &[F], at: usize, xi_stride: usize, tw: usize, b0: F, relu: bool, out: &mut [F], wo: usize,
                        buf: &mut Rows<F>) {
    let ex = &mut buf.ex;
    for b in 0..6 {
        // column b: m[6a + b] for a = 0..6 (rows 6·xi_stride apart), along y into ex[b][r][tx], r < 4
        let mv = strided_rows(m, b * xi_stride + at, 6 * xi_stride, tw);
        let mut e = strided_rows_mut(&mut ex[b * TILE * tw..], 0, tw, tw);
        map_tiles::<F, OutputTransform, 6, 4>(mv, &mut e);
    }
    let act = |v: F| {
        let o = v + b0;
        if relu { o.max(F::zero()) } else { o }
    };
    for (r, out_row) in out.chunks_exact_mut(wo).enumerate() {
        // output row r of every tile: (ex[b][r][tx] for b = 0..6, rows 4·tw apart) along x into
        // q[c][tx] (ex rows 24..28, free), then interleaved into columns 4·tx + c < Wo
        let (e, free) = ex.split_at_mut(6 * TILE * tw);
        let e = strided_rows(e, r * tw, TILE * tw, tw);
        let mut q = strided_rows_mut(free, 0, tw, tw);
        map_tiles::<F, OutputTransform, 6, 4>(e, &mut q);
        // out_row[4·tx + c] = q[c][tx], clipped to Wo
        merge_phases([&*q[0], &*q[1], &*q[2], &*q[3]], out_row, act);
    }
}

/// `dM[ξ]` rows of tile row ty: `dm[ξ·xi_stride + at + tx]` = (A · y · Aᵀ)[ξ], y the 4 x 4 block of
/// the dY plane `dyo` at rows 4·ty.., columns 4·tx.. (0 outside Ho x Wo).
#[allow(clippy::too_many_arguments)]
pub(super) fn grad_output_rows<F: Float>(isa: Isa, g: &Geom, dyo: &[F], ty: usize, tw: usize, dm: &mut [F], at: usize,
                                         xi_stride: usize, buf: &mut Rows<F>) {
    // dY row oy = 4·ty + r (None below the image); columns past Wo read as 0
    let rows: [Option<&[F]>; TILE] = std::array::from_fn(|r| {
        let oy = TILE * ty + r;
        (oy < g.ho).then(|| &dyo[oy * g.wo..(oy + 1) * g.wo])
    });
    grad_output_row_isa(isa, &rows, tw, buf, dm, at, xi_stride);
}

per_isa!(
    /// [`grad_output_row`] for the plan's ISA.
    grad_output_row_isa => grad_output_row (rows: &[Option<&[F]>; TILE], tw: usize, buf: &mut Rows<F>, dm: &mut [F], at: usize,
                                            xi_stride: usize)
);

/// The adjoint output transform of one row of tiles from its 4 dY rows (`rows`): along x per row
/// (into `buf.ex`), then along y into `dm[ξ·xi_stride + at + tx]`.
#[inline(always)]
fn grad_output_row<F: Float>(rows: &[Option<&[F]>; TILE], tw: usize, buf: &mut Rows<F>, dm: &mut [F], at: usize,
                             xi_stride: usize) {
    let Rows { phase, ex, .. } = buf;
    for (r, &row) in rows.iter().enumerate() {
        // phase[m][tx] = row[4·tx + m]: the tile's column m
        split_phases(row, 0, tw, phase);
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
