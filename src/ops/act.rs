//! Activations: relu, sigmoid, tanh. Backward takes the forward *output* y (no input needed).
//!
//! | op | forward | backward |
//! |---|---|---|
//! | relu | max(x, 0) | g * (y > 0) |
//! | sigmoid | 1 / (1 + e^-x) | g * y * (1 - y) |
//! | tanh | tanh(x) | g * (1 - y^2) |

use super::lanes::{self, multiversion};
use crate::tensor::{check_same_shape, par_filled_in, zeroed};
use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD};

/// Elements per parallel task.
const CHUNK: usize = 1 << 14;

/// Which activation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Act {
    Relu,
    Sigmoid,
    Tanh,
}

impl Act {
    /// Parses "relu" | "sigmoid" | "tanh".
    pub fn parse(name: &str) -> Result<Act> {
        match name {
            "relu" => Ok(Act::Relu),
            "sigmoid" => Ok(Act::Sigmoid),
            "tanh" => Ok(Act::Tanh),
            other => Err(Error::arg("activation", format!("unknown activation {other:?}"))),
        }
    }
    /// The op name used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            Act::Relu => "relu",
            Act::Sigmoid => "sigmoid",
            Act::Tanh => "tanh",
        }
    }
}

multiversion! {
    /// y = act(x) over a run (one loop per activation, so each vectorises; sigmoid and tanh from
    /// `lanes`, the same functions the fused GRU kernels use).
    fn act_run<F: Float>(act: Act, y: &mut [F], x: &[F]) {
        let it = y.iter_mut().zip(x);
        match act {
            Act::Relu => it.for_each(|(y, &x)| *y = x.max(F::zero())),
            Act::Sigmoid => it.for_each(|(y, &x)| *y = lanes::sigmoid(x)),
            Act::Tanh => it.for_each(|(y, &x)| *y = lanes::tanh(x)),
        }
    }
}

multiversion! {
    /// dx = g · act'(x) over a run, with act' expressed through y: [y > 0], y(1 - y), 1 - y².
    fn act_grad_run<F: Float>(act: Act, dx: &mut [F], y: &[F], g: &[F]) {
        let it = dx.iter_mut().zip(y).zip(g);
        match act {
            Act::Relu => it.for_each(|((d, &y), &g)| *d = if y > F::zero() { g } else { F::zero() }),
            Act::Sigmoid => it.for_each(|((d, &y), &g)| *d = g * (y * (F::one() - y))),
            Act::Tanh => it.for_each(|((d, &y), &g)| *d = g * (F::one() - y * y)),
        }
    }
}

/// y = act(x), any shape. Errors as [`crate::tensor::zeros`] for shapes too large to allocate.
///
/// Torch: `F.relu(x)`, `torch.sigmoid(x)`, `torch.tanh(x)`.
pub fn unary_fwd<F: Float>(act: Act, x: ArrayViewD<F>) -> Result<ArrayD<F>> {
    let x = x.as_standard_layout();
    let xs = x.as_slice().expect("standard layout");
    // each chunk is zeroed in cache by its task and then overwritten (no serial zeroing pass first)
    par_filled_in(act.name(), x.shape(), CHUNK, |start, yc| {
        let end = start + yc.len();
        act_run(act, zeroed(yc), &xs[start..end])
    })
}

/// dx = g * act'(x), computed from y = act(x).
///
/// # Gradient
/// relu: g·[y>0]; sigmoid: g·y(1−y); tanh: g·(1−y²).
pub fn unary_bwd<F: Float>(act: Act, y: ArrayViewD<F>, g: ArrayViewD<F>) -> Result<ArrayD<F>> {
    check_same_shape(act.name(), ("output", y.shape()), ("grad_output", g.shape()))?;
    let (y, g) = (y.as_standard_layout(), g.as_standard_layout());
    let (ys, gs) = (y.as_slice().expect("standard layout"), g.as_slice().expect("standard layout"));
    // as in unary_fwd: no serial zeroing pass first; chunk k covers flat indices start..start + len
    par_filled_in(act.name(), y.shape(), CHUNK, |start, dc| {
        let end = start + dc.len();
        act_grad_run(act, zeroed(dc), &ys[start..end], &gs[start..end])
    })
}
