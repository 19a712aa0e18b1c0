//! The masked L1 term of MIPNet's sequence loss (architecture.md §3.1).
//!
//! | op | forward | backward (grads to) |
//! |---|---|---|
//! | masked L1 mean | Σ_valid \|pred − gt\| / #valid (0 when nothing is valid) | `masked_l1_bwd` (pred): g·sign(pred − gt)·valid / #valid |
//!
//! A position is valid where `valid >= 0.5`. Invalid positions are skipped entirely (their gt is
//! treated as 0 and their weight is 0), so NaN or inf in invalid gt reaches neither result nor gradient.
//! Sums run over fixed chunks in parallel, then over the chunks in order: deterministic.

use crate::tensor::{check_nonempty, check_same_shape};
use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD, Zip};
use rayon::prelude::*;

/// Elements per partial sum (fixed, so the summation order does not depend on the thread count).
const CHUNK: usize = 1 << 14;

fn is_valid<F: Float>(v: F) -> bool {
    v >= F::c(0.5)
}

/// sign(d) with sign(0) = 0 (torch's abs backward).
fn sign<F: Float>(d: F) -> F {
    if d > F::zero() {
        F::one()
    } else if d < F::zero() {
        -F::one()
    } else {
        F::zero()
    }
}

/// Fails unless the three inputs share one non-empty shape.
fn check<F: Float>(pred: &ArrayViewD<F>, gt: &ArrayViewD<F>, valid: &ArrayViewD<F>) -> Result<()> {
    let op = "masked_l1_loss";
    check_same_shape(op, ("input", pred.shape()), ("target", gt.shape()))?;
    check_same_shape(op, ("input", pred.shape()), ("valid", valid.shape()))?;
    check_nonempty(op, &[("input", pred.shape()), ("target", gt.shape()), ("valid", valid.shape())])
}

/// (Σ_valid |pred − gt|, #valid), accumulated in f64 per chunk, chunks summed in order.
fn sum_and_count<F: Float>(p: &[F], t: &[F], v: &[F]) -> (f64, usize) {
    let parts: Vec<(f64, usize)> = p
        .par_chunks(CHUNK)
        .zip(t.par_chunks(CHUNK))
        .zip(v.par_chunks(CHUNK))
        .map(|((p, t), v)| {
            let (mut s, mut n) = (0.0f64, 0usize);
            for ((&p, &t), &v) in p.iter().zip(t).zip(v) {
                if is_valid(v) {
                    s += (p - t).abs().to_f64().unwrap_or(f64::NAN);
                    n += 1;
                }
            }
            (s, n)
        })
        .collect();
    parts.into_iter().fold((0.0, 0), |(s, n), (ps, pn)| (s + ps, n + pn))
}

/// Mean of |pred − gt| over the valid positions (0 when there is none).
///
/// # Shapes
/// pred, gt, valid: one shape, any rank; valid holds 0/1 (>= 0.5 is valid). Returns a scalar.
///
/// # Gradient
/// See `masked_l1_bwd`.
///
/// Torch: `(pred - gt).abs()[valid.bool()].mean()` (which is NaN, not 0, with no valid position).
pub fn masked_l1_fwd<F: Float>(pred: ArrayViewD<F>, gt: ArrayViewD<F>, valid: ArrayViewD<F>) -> Result<F> {
    check(&pred, &gt, &valid)?;
    let (p, t, v) = (pred.as_standard_layout(), gt.as_standard_layout(), valid.as_standard_layout());
    let (Some(ps), Some(ts), Some(vs)) = (p.as_slice(), t.as_slice(), v.as_slice()) else {
        return Err(Error::shape("masked_l1_loss", "inputs are not contiguous", &[("input", p.shape())]));
    };
    let (sum, count) = sum_and_count(ps, ts, vs);
    // mean = Σ_valid |e| / #valid, 0 for no valid position
    Ok(if count == 0 { F::zero() } else { F::c(sum / count as f64) })
}

/// Grad of `masked_l1_fwd` w.r.t. pred for an upstream scalar gradient g.
///
/// # Shapes
/// pred, gt, valid: one shape; g: a scalar. Returns dpred of pred's shape.
///
/// # Gradient
/// dpred = g·sign(pred − gt)·[valid] / #valid (sign(0) = 0; all zeros when nothing is valid).
///
/// Torch: autograd of `(pred - gt).abs()[valid.bool()].mean()`.
pub fn masked_l1_bwd<F: Float>(pred: ArrayViewD<F>, gt: ArrayViewD<F>, valid: ArrayViewD<F>, g: F) -> Result<ArrayD<F>> {
    check(&pred, &gt, &valid)?;
    let (p, t, v) = (pred.as_standard_layout(), gt.as_standard_layout(), valid.as_standard_layout());
    let count = v.iter().filter(|&&v| is_valid(v)).count();
    let scale = if count == 0 { F::zero() } else { g / F::c(count as f64) };
    let mut d = ArrayD::<F>::zeros(p.raw_dim());
    // d = scale·sign(pred − gt) where valid, 0 elsewhere (gt of invalid positions never read)
    Zip::from(&mut d).and(&p).and(&t).and(&v).par_for_each(|d, &p, &t, &v| {
        if is_valid(v) {
            *d = scale * sign(p - t);
        }
    });
    Ok(d)
}
