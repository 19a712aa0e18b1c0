//! Spatial padding of (N, C, H, W) tensors: constant value or replicate (edge) padding.
//!
//! | op | forward | backward |
//! |---|---|---|
//! | pad2d, constant | `pad2d_fwd`: border filled with `value` | `pad2d_bwd`: the interior window of g |
//! | pad2d, replicate | `pad2d_fwd`: border copies the nearest edge pixel | `pad2d_bwd`: border grads summed into edge pixels |

use crate::tensor::{check_nonempty, fixed, zeros};
use crate::{Error, Float, Result};
use ndarray::{Array4, ArrayView4, ArrayViewD, Ix4};
use rayon::prelude::*;

const OP: &str = "pad";

/// What fills the border.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PadMode {
    /// Every border pixel holds the constant `value`.
    Zero,
    /// Every border pixel copies the nearest edge pixel of the input.
    Replicate,
}

impl PadMode {
    /// Parses torch's mode names: "constant" | "replicate".
    pub fn parse(name: &str) -> Result<PadMode> {
        match name {
            "constant" => Ok(PadMode::Zero),
            "replicate" => Ok(PadMode::Replicate),
            other => Err(Error::arg(OP, format!("unsupported mode {other:?} (expected \"constant\" or \"replicate\")"))),
        }
    }
}

/// Geometry and fill of a 2-D padding: `[left, right, top, bottom]` as torch's pad list.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pad2dCfg {
    pub pad: [usize; 4],
    pub mode: PadMode,
    /// The fill of constant padding (ignored by replicate).
    pub value: f64,
}

impl Pad2dCfg {
    /// Validates torch's `[left, right, top, bottom]` (non-negative) and builds the config.
    pub fn new(pad: &[i64], mode: PadMode, value: f64) -> Result<Self> {
        let p: [i64; 4] = pad
            .try_into()
            .map_err(|_| Error::arg(OP, format!("pad must have 4 entries [left, right, top, bottom], got {pad:?}")))?;
        if p.iter().any(|&v| v < 0) {
            return Err(Error::arg(OP, format!("negative padding is not supported, got {pad:?}")));
        }
        Ok(Pad2dCfg { pad: p.map(|v| v as usize), mode, value })
    }

    /// (H + top + bottom, W + left + right), or an error if that overflows.
    pub fn out_hw(&self, h: usize, w: usize) -> Result<(usize, usize)> {
        let [l, r, t, b] = self.pad;
        let add = |a: usize, p: usize, q: usize| a.checked_add(p)?.checked_add(q);
        add(h, t, b).zip(add(w, l, r)).ok_or_else(|| Error::arg(OP, format!("padding {:?} of a {h}x{w} input overflows", self.pad)))
    }

    /// The input index feeding padded index `o` along an axis of size `n` padded by `before` on its
    /// low side: `Some(o - before)` inside, the clamped edge for replicate, `None` for constant.
    fn source(&self, o: usize, before: usize, n: usize) -> Option<usize> {
        // i = o - before, clamped to [0, n-1] by replicate
        match (o.checked_sub(before), self.mode) {
            (Some(i), _) if i < n => Some(i),
            (_, PadMode::Zero) => None,
            (None, PadMode::Replicate) => Some(0),
            (Some(_), PadMode::Replicate) => Some(n - 1),
        }
    }
}

fn input4<'a, F>(x: ArrayViewD<'a, F>) -> Result<ArrayView4<'a, F>> {
    let x = fixed::<_, Ix4>(OP, "input", x)?;
    check_nonempty(OP, &[("input", x.shape())])?;
    Ok(x)
}

/// Pads the last two axes of x by `[left, right, top, bottom]`.
///
/// # Shapes
/// x (N, C, H, W) -> (N, C, H + top + bottom, W + left + right).
///
/// # Gradient
/// x: see [`pad2d_bwd`] (interior window of g; replicate also sums the border into the edges).
///
/// Torch: `F.pad(x, [l, r, t, b], mode='constant', value=v)` / `mode='replicate'`.
pub fn pad2d_fwd<F: Float>(x: ArrayViewD<F>, cfg: &Pad2dCfg) -> Result<Array4<F>> {
    let x = input4(x)?;
    let x = x.as_standard_layout();
    let (n, c, h, w) = x.dim();
    let (ho, wo) = cfg.out_hw(h, w)?;
    let (top, left) = (cfg.pad[2], cfg.pad[0]);
    let fill = F::c(cfg.value);
    let src = x.as_slice().expect("standard layout");
    let mut out = zeros(OP, (n, c, ho, wo))?;
    let dst = out.as_slice_mut().expect("fresh array");
    dst.par_chunks_mut(ho * wo).zip(src.par_chunks(h * w)).for_each(|(o, xp)| {
        for (oy, orow) in o.chunks_mut(wo).enumerate() {
            let Some(iy) = cfg.source(oy, top, h) else {
                orow.fill(fill);
                continue;
            };
            // input row iy occupies [iy·W, (iy+1)·W) of the plane
            let xrow = &xp[iy * w..(iy + 1) * w];
            for (ox, ov) in orow.iter_mut().enumerate() {
                *ov = cfg.source(ox, left, w).map_or(fill, |ix| xrow[ix]);
            }
        }
    });
    Ok(out)
}

/// Gradient of [`pad2d_fwd`] with respect to x.
///
/// # Shapes
/// g (N, C, H + top + bottom, W + left + right) -> dx (N, C, H, W).
///
/// # Gradient
/// constant: dx = g[.., top:top+H, left:left+W]; replicate: dx[i, j] = Σ g[o, p] over every padded
/// pixel (o, p) whose clamped source is (i, j) (edge pixels collect their border), summed in a fixed
/// order per (n, c) plane.
///
/// Torch: the backward of `F.pad(x, [l, r, t, b], mode=...)`.
pub fn pad2d_bwd<F: Float>(g: ArrayViewD<F>, input_hw: (usize, usize), cfg: &Pad2dCfg) -> Result<Array4<F>> {
    let g = fixed::<_, Ix4>(OP, "grad_output", g)?;
    let (h, w) = input_hw;
    let (n, c, gh, gw) = g.dim();
    let (ho, wo) = cfg.out_hw(h, w)?;
    if (gh, gw) != (ho, wo) || h == 0 || w == 0 {
        return Err(Error::shape(OP, format!("grad_output does not match a padded input of size {h}x{w}"), &[
            ("grad_output", g.shape()),
            ("input_hw", &[h, w]),
        ]));
    }
    let g = g.as_standard_layout();
    let (top, left) = (cfg.pad[2], cfg.pad[0]);
    let src = g.as_slice().expect("standard layout");
    let mut dx = zeros(OP, (n, c, h, w))?;
    let dst = dx.as_slice_mut().expect("fresh array");
    dst.par_chunks_mut(h * w).zip(src.par_chunks(ho * wo)).for_each(|(d, gp)| {
        for (oy, grow) in gp.chunks(wo).enumerate() {
            let Some(iy) = cfg.source(oy, top, h) else { continue };
            // dx row iy occupies [iy·W, (iy+1)·W) of the plane
            let drow = &mut d[iy * w..(iy + 1) * w];
            for (ox, &gv) in grow.iter().enumerate() {
                if let Some(ix) = cfg.source(ox, left, w) {
                    drow[ix] += gv;
                }
            }
        }
    });
    Ok(dx)
}
