//! 2-D average pooling over the last two axes of (N, C, H, W) or (C, H, W) tensors.
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | avg_pool2d (kernel, stride, zero padding, ceil_mode, count_include_pad, divisor_override) | `avg_pool2d_fwd` | `avg_pool2d_bwd` (x): g / divisor spread over each window |
//!
//! Global average pooling (`F.adaptive_avg_pool2d(x, 1)`) is `elementwise::mean_fwd` over (H, W).

use crate::tensor::check_nonempty;
use crate::{Error, Float, Result};
use ndarray::{Array3, ArrayD, ArrayViewD, IxDyn, Zip};

/// Geometry of `avg_pool2d`, shared by forward, backward and binding (torch's argument semantics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AvgPool2dCfg {
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    pub padding: [usize; 2],
    pub ceil_mode: bool,
    pub count_include_pad: bool,
    pub divisor_override: Option<usize>,
}

/// One pooling window along an axis: input range [start, end) clipped to the input, and the length
/// of the window clipped to the padded input only (torch's `pool_size` factor).
struct Window {
    start: usize,
    end: usize,
    padded_len: usize,
}

impl AvgPool2dCfg {
    /// Validates torch's constraints: kernel, stride >= 1, padding >= 0 and at most half the kernel,
    /// divisor_override >= 1.
    pub fn new(kernel: [i64; 2], stride: [i64; 2], padding: [i64; 2], ceil_mode: bool, count_include_pad: bool, divisor_override: Option<i64>) -> Result<Self> {
        let op = "avg_pool2d";
        let to_usize = |v: [i64; 2], name: &str, min: i64| -> Result<[usize; 2]> {
            if v.iter().any(|&x| x < min) {
                return Err(Error::arg(op, format!("{name} must be >= {min}, got {v:?}")));
            }
            Ok([v[0] as usize, v[1] as usize])
        };
        let (kernel, stride, padding) = (to_usize(kernel, "kernel_size", 1)?, to_usize(stride, "stride", 1)?, to_usize(padding, "padding", 0)?);
        if padding[0] > kernel[0] / 2 || padding[1] > kernel[1] / 2 {
            return Err(Error::arg(op, format!("pad should be at most half of kernel size, but got padding={padding:?} and kernel_size={kernel:?}")));
        }
        let divisor_override = match divisor_override {
            Some(d) if d < 1 => return Err(Error::arg(op, format!("divisor_override must be >= 1, got {d}"))),
            d => d.map(|d| d as usize),
        };
        Ok(AvgPool2dCfg { kernel, stride, padding, ceil_mode, count_include_pad, divisor_override })
    }

    /// Output length along axis `a` for input length `len` (torch's `pooling_output_shape`), >= 1.
    fn out_len(&self, len: usize, a: usize) -> Option<usize> {
        let (k, s, p) = (self.kernel[a], self.stride[a], self.padding[a]);
        // out = ⌊(len + 2p − k [+ s − 1 if ceil]) / s⌋ + 1
        let span = (len + 2 * p).checked_sub(k)? + if self.ceil_mode { s - 1 } else { 0 };
        let mut out = span / s + 1;
        // in ceil mode the last window must start inside the input or the left padding
        if self.ceil_mode && (out - 1) * s >= len + p {
            out -= 1;
        }
        Some(out)
    }

    /// (OH, OW) for an input (.., H, W), or an error when the kernel does not fit the padded input.
    pub fn out_hw(&self, shape: &[usize]) -> Result<(usize, usize)> {
        let &[.., h, w] = shape else {
            return Err(Error::shape("avg_pool2d", "input must have at least 2 dimensions", &[("input", shape)]));
        };
        match (self.out_len(h, 0), self.out_len(w, 1)) {
            (Some(oh), Some(ow)) => Ok((oh, ow)),
            _ => Err(Error::shape("avg_pool2d", format!("kernel_size {:?} is larger than the padded input (padding {:?})", self.kernel, self.padding), &[("input", shape)])),
        }
    }

    /// Window of output index `o` along axis `a` of an input of length `len`.
    fn window(&self, o: usize, len: usize, a: usize) -> Window {
        let (k, s, p) = (self.kernel[a], self.stride[a], self.padding[a]);
        // padded coordinates: [o·s, min(o·s + k, len + 2p)), shifted back by p into the input
        let (start_p, end_p) = (o * s, (o * s + k).min(len + 2 * p));
        Window { start: start_p.saturating_sub(p).min(len), end: end_p.saturating_sub(p).min(len), padded_len: end_p - start_p }
    }

    /// The row windows (OH of them) and column windows (OW) of an (H, W) input.
    fn windows(&self, h: usize, w: usize, oh: usize, ow: usize) -> (Vec<Window>, Vec<Window>) {
        ((0..oh).map(|i| self.window(i, h, 0)).collect(), (0..ow).map(|j| self.window(j, w, 1)).collect())
    }

    /// The divisor of the window at (oh, ow).
    fn divisor(&self, wh: &Window, ww: &Window) -> usize {
        match self.divisor_override {
            Some(d) => d,
            None if self.count_include_pad => wh.padded_len * ww.padded_len,
            None => (wh.end - wh.start) * (ww.end - ww.start),
        }
    }
}

/// Validated geometry of a call: (P, H, W) planes of the input (P = N·C or C) and the output shape.
fn geometry(input_shape: &[usize], cfg: &AvgPool2dCfg) -> Result<([usize; 3], Vec<usize>)> {
    let op = "avg_pool2d";
    let s = input_shape;
    if !(3..=4).contains(&s.len()) {
        return Err(Error::shape(op, "input must be a 3-D (C, H, W) or 4-D (N, C, H, W) tensor", &[("input", s)]));
    }
    check_nonempty(op, &[("input", s)])?;
    let (oh, ow) = cfg.out_hw(s)?;
    let (lead, hw) = s.split_at(s.len() - 2);
    let mut out_shape = lead.to_vec();
    out_shape.extend([oh, ow]);
    Ok(([lead.iter().product(), hw[0], hw[1]], out_shape))
}

/// Average of each (possibly padded) window.
///
/// # Shapes
/// x: (N, C, H, W) or (C, H, W). Returns (.., OH, OW) with OH = ⌊(H + 2·ph − kh) / sh⌋ + 1 (rounded up
/// in ceil_mode, the last window starting inside the input or left padding), OW likewise.
///
/// # Gradient
/// See `avg_pool2d_bwd`.
///
/// Torch: `F.avg_pool2d(x, kernel_size, stride, padding, ceil_mode, count_include_pad, divisor_override)`.
pub fn avg_pool2d_fwd<F: Float>(x: ArrayViewD<F>, cfg: &AvgPool2dCfg) -> Result<ArrayD<F>> {
    let ([p, h, w], out_shape) = geometry(x.shape(), cfg)?;
    let x = x.as_standard_layout();
    // (.., H, W) -> (P, H, W)
    let xp = x.view().into_shape_with_order((p, h, w)).map_err(|_| Error::shape("avg_pool2d", "input not reshapeable", &[("input", x.shape())]))?;
    let (oh, ow) = (out_shape[out_shape.len() - 2], out_shape[out_shape.len() - 1]);
    let (rows, cols) = cfg.windows(h, w, oh, ow);
    let mut out = Array3::<F>::zeros((p, oh, ow));
    Zip::from(out.outer_iter_mut()).and(xp.outer_iter()).par_for_each(|mut o, xpl| {
        let mut colsum = vec![F::zero(); w];
        for (wh, mut orow) in rows.iter().zip(o.rows_mut()) {
            // colsum[c] = Σ_{r in window rows} x[r, c]
            colsum.iter_mut().for_each(|v| *v = F::zero());
            for r in wh.start..wh.end {
                colsum.iter_mut().zip(xpl.row(r)).for_each(|(a, &v)| *a += v);
            }
            // out[i, j] = Σ_{c in window cols} colsum[c] / divisor(i, j)
            for (ww, o) in cols.iter().zip(orow.iter_mut()) {
                *o = colsum[ww.start..ww.end].iter().copied().sum::<F>() / F::c(cfg.divisor(wh, ww) as f64);
            }
        }
    });
    out.into_shape_with_order(IxDyn(&out_shape)).map_err(|_| Error::shape("avg_pool2d", "output not reshapeable", &[("input", x.shape())]))
}

/// Grad of `avg_pool2d_fwd` w.r.t. x.
///
/// # Shapes
/// input_shape: x's shape (N, C, H, W) or (C, H, W); g: the output's shape. Returns dx of input_shape.
///
/// # Gradient
/// dx[h, w] = Σ over windows (i, j) containing (h, w) of g[i, j] / divisor(i, j).
///
/// Torch: autograd of `F.avg_pool2d(...)` (`avg_pool2d_backward`).
pub fn avg_pool2d_bwd<F: Float>(g: ArrayViewD<F>, input_shape: &[usize], cfg: &AvgPool2dCfg) -> Result<ArrayD<F>> {
    let op = "avg_pool2d";
    let ([p, h, w], out_shape) = geometry(input_shape, cfg)?;
    if g.shape() != out_shape.as_slice() {
        return Err(Error::shape(op, format!("grad_output must have the output shape {out_shape:?}"), &[("input", input_shape), ("grad_output", g.shape())]));
    }
    let (oh, ow) = (out_shape[out_shape.len() - 2], out_shape[out_shape.len() - 1]);
    let g = g.as_standard_layout();
    // (.., OH, OW) -> (P, OH, OW)
    let gp = g.view().into_shape_with_order((p, oh, ow)).map_err(|_| Error::shape(op, "grad_output not reshapeable", &[("grad_output", g.shape())]))?;
    let (rows, cols) = cfg.windows(h, w, oh, ow);
    let mut dx = Array3::<F>::zeros((p, h, w));
    // One thread per (n, c) plane: the windows of a plane scatter into that plane only.
    Zip::from(dx.outer_iter_mut()).and(gp.outer_iter()).par_for_each(|mut d, gpl| {
        let mut share = vec![F::zero(); w];
        for (wh, grow) in rows.iter().zip(gpl.rows()) {
            // share[c] = Σ_{j: c in window j} g[i, j] / divisor(i, j)
            share.iter_mut().for_each(|v| *v = F::zero());
            for (ww, &gv) in cols.iter().zip(grow) {
                let v = gv / F::c(cfg.divisor(wh, ww) as f64);
                share[ww.start..ww.end].iter_mut().for_each(|s| *s += v);
            }
            // dx[r, :] += share for every row r of window i
            for r in wh.start..wh.end {
                d.row_mut(r).iter_mut().zip(&share).for_each(|(d, &s)| *d += s);
            }
        }
    });
    dx.into_shape_with_order(IxDyn(input_shape)).map_err(|_| Error::shape(op, "grad not reshapeable", &[("input", input_shape)]))
}
