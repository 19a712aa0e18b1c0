//! Concatenation and slicing along one axis (channel or spatial).
//!
//! | op | forward | backward |
//! |---|---|---|
//! | cat, each input optionally through a ReLU | `cat_fwd` | slices of g (`slice_fwd`; the ReLU's mask from the output) |
//! | slice x[.., start:stop, ..] | `slice_fwd` | `slice_bwd`: g placed into zeros of the input shape |
//! | batched transpose (N, R, C) -> (N, C, R) | `transpose_fwd` | `transpose_fwd` of g |

use crate::tensor::{par_filled, par_filled_in};
use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD, CowArray, IxDyn};
use std::mem::MaybeUninit;

/// One run of an output built along an axis: `len` positions copied (through a ReLU with `relu`) from
/// positions from..from+len of a standard-layout source whose axis has `src_len` positions, or zeros.
enum Part<'a, F> {
    Copy { src: &'a [F], len: usize, from: usize, src_len: usize, relu: bool },
    Zero { len: usize },
}

impl<F> Part<'_, F> {
    fn len(&self) -> usize {
        match self {
            Part::Copy { len, .. } | Part::Zero { len } => *len,
        }
    }
}

/// The array of `shape` that is, along `axis`, the concatenation of `parts` (for every index of the
/// axes before it), filled in parallel. cat, slice and the slice's backward are all one such call.
fn assemble<F: Float>(op: &'static str, shape: &[usize], axis: usize, parts: &[Part<F>]) -> Result<ArrayD<F>> {
    let inner: usize = shape[axis + 1..].iter().product();
    // flat length of one outer block (all parts), and each part's start within it
    let block = shape[axis] * inner;
    let starts: Vec<usize> = parts.iter().scan(0, |acc, p| {
        let s = *acc;
        *acc += p.len() * inner;
        Some(s)
    }).collect();
    par_filled(op, shape, |start, chunk: &mut [MaybeUninit<F>]| {
        let mut pos = start;
        let mut out = chunk;
        while !out.is_empty() {
            // flat index pos = o·block + r; part i holds r in starts[i] .. starts[i] + len_i·inner
            let (o, r) = (pos / block, pos % block);
            let i = starts.partition_point(|&s| s <= r) - 1;
            let run = (starts[i] + parts[i].len() * inner - r).min(out.len());
            let (dst, rest) = out.split_at_mut(run);
            match &parts[i] {
                Part::Copy { src, from, src_len, relu, .. } => {
                    // source offset = o·src_len·inner + from·inner + (r - starts[i])
                    let s0 = o * src_len * inner + from * inner + (r - starts[i]);
                    let pairs = dst.iter_mut().zip(&src[s0..s0 + run]);
                    if *relu {
                        pairs.for_each(|(d, &v)| {
                            d.write(v.max(F::zero()));
                        });
                    } else {
                        pairs.for_each(|(d, &v)| {
                            d.write(v);
                        });
                    }
                }
                Part::Zero { .. } => dst.iter_mut().for_each(|d| {
                    d.write(F::zero());
                }),
            }
            out = rest;
            pos += run;
        }
    })
}

/// Concatenates arrays along `axis`; all other sizes must agree; input i goes through a ReLU where
/// `relu[i]` (an empty `relu`: none do). Torch: `torch.cat([F.relu(x) if r else x ...], dim=axis)`.
/// Copies run in parallel chunks.
pub fn cat_fwd<F: Float>(xs: &[ArrayViewD<F>], axis: usize, relu: &[bool]) -> Result<ArrayD<F>> {
    let op = "cat";
    let first = xs.first().ok_or_else(|| Error::arg(op, "needs at least one tensor"))?;
    let shapes: Vec<(&'static str, &[usize])> = xs.iter().map(|x| ("tensor", x.shape())).collect();
    if axis >= first.ndim() {
        return Err(Error::shape(op, format!("axis {axis} out of range"), &shapes));
    }
    let fits = |x: &ArrayViewD<F>| {
        x.ndim() == first.ndim() && (0..x.ndim()).all(|a| a == axis || x.shape()[a] == first.shape()[a])
    };
    if !xs.iter().all(fits) {
        return Err(Error::shape(op, format!("sizes must match except along axis {axis}"), &shapes));
    }
    if !relu.is_empty() && relu.len() != xs.len() {
        return Err(Error::arg(op, format!("relu needs one flag per tensor: {} flags for {} tensors", relu.len(), xs.len())));
    }
    let xs: Vec<CowArray<F, IxDyn>> = xs.iter().map(|x| x.as_standard_layout()).collect();
    let parts: Vec<Part<F>> = xs.iter().enumerate().map(|(i, x)| {
        let len = x.shape()[axis];
        Part::Copy { src: x.as_slice().expect("standard layout"), len, from: 0, src_len: len, relu: relu.get(i).copied().unwrap_or(false) }
    }).collect();
    let mut shape = first.shape().to_vec();
    shape[axis] = parts.iter().map(Part::len).sum();
    assemble(op, &shape, axis, &parts)
}


fn check_slice(op: &'static str, shape: &[usize], axis: usize, start: usize, stop: usize) -> Result<()> {
    if axis >= shape.len() || start > stop || stop > shape[axis] {
        return Err(Error::shape(op, format!("slice {start}:{stop} on axis {axis} is out of range"), &[("input", shape)]));
    }
    Ok(())
}

/// x[.., start:stop, ..] along `axis`, as a new contiguous array.
pub fn slice_fwd<F: Float>(x: ArrayViewD<F>, axis: usize, start: usize, stop: usize) -> Result<ArrayD<F>> {
    check_slice("slice", x.shape(), axis, start, stop)?;
    let x = x.as_standard_layout();
    let mut shape = x.shape().to_vec();
    shape[axis] = stop - start;
    let part = Part::Copy { src: x.as_slice().expect("standard layout"), len: stop - start, from: start, src_len: x.shape()[axis], relu: false };
    assemble("slice", &shape, axis, &[part])
}


/// # Gradient
/// dx = zeros(input_shape) with dx[.., start:start+len, ..] = g.
pub fn slice_bwd<F: Float>(g: ArrayViewD<F>, input_shape: &[usize], axis: usize, start: usize) -> Result<ArrayD<F>> {
    let stop = start + g.shape().get(axis).copied().unwrap_or(0);
    check_slice("slice", input_shape, axis, start, stop)?;
    let mut expect = input_shape.to_vec();
    expect[axis] = stop - start;
    if g.shape() != expect.as_slice() {
        return Err(Error::shape("slice", "grad_output does not fit the slice", &[("grad_output", g.shape()), ("input", input_shape)]));
    }
    let g = g.as_standard_layout();
    let len = stop - start;
    let parts = [
        Part::Zero { len: start },
        Part::Copy { src: g.as_slice().expect("standard layout"), len, from: 0, src_len: len, relu: false },
        Part::Zero { len: input_shape[axis] - stop },
    ];
    assemble("slice", input_shape, axis, &parts)
}


/// Output rows per task of [`transpose_fwd`]: one 64-byte line of f32 source columns.
const TRANSPOSE_BAND: usize = 16;
/// Source rows read per pass over a band (a band x block tile: 4 KiB of f32 lines stay in L1).
const TRANSPOSE_BLOCK: usize = 64;

/// out[n, c, r] = x[n, r, c]: the last two axes of a 3-D array swapped, materialised contiguous.
/// With x viewed as (N, C, H·W) it turns NCHW into NHWC, and back with (N, H·W, C).
///
/// Tasks are bands of output rows (source columns); a band reads the source in tiles of
/// `TRANSPOSE_BLOCK` rows, so each source line fetched serves the whole band.
///
/// Torch: `x.transpose(1, 2).contiguous()`.
pub fn transpose_fwd<F: Float>(x: ArrayViewD<F>) -> Result<ArrayD<F>> {
    let op = "transpose";
    if x.ndim() != 3 {
        return Err(Error::shape(op, "expected a 3-D array (N, R, C)", &[("x", x.shape())]));
    }
    let (n, rows, cols) = (x.shape()[0], x.shape()[1], x.shape()[2]);
    let x = x.as_standard_layout();
    let xs = x.as_slice().expect("standard layout");
    par_filled_in(op, &[n, cols, rows], TRANSPOSE_BAND * rows.max(1), |start, chunk: &mut [MaybeUninit<F>]| {
        // output rows start / rows .. : row q is (image q / cols, source column q % cols)
        let first = start / rows.max(1);
        let count = chunk.len() / rows.max(1);
        for r0 in (0..rows).step_by(TRANSPOSE_BLOCK) {
            let r1 = (r0 + TRANSPOSE_BLOCK).min(rows);
            for k in 0..count {
                let (img, c) = ((first + k) / cols, (first + k) % cols);
                // source element (img, r, c) at (img·rows + r)·cols + c
                let src = &xs[img * rows * cols + c..];
                for (r, o) in (r0..r1).zip(&mut chunk[k * rows + r0..k * rows + r1]) {
                    o.write(src[r * cols]);
                }
            }
        }
    })
}
