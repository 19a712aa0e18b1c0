//! Activations: relu, sigmoid, tanh. Backward takes the forward *output* y (no input needed).
//!
//! | op | forward | backward |
//! |---|---|---|
//! | relu | max(x, 0) | g * (y > 0) |
//! | sigmoid | 1 / (1 + e^-x) | g * y * (1 - y) |
//! | tanh | tanh(x) | g * (1 - y^2) |

use crate::tensor::check_same_shape;
use crate::{Error, Float, Result};
use ndarray::{ArrayD, ArrayViewD, Zip};

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
    fn f<F: Float>(self, x: F) -> F {
        match self {
            Act::Relu => x.max(F::zero()),
            Act::Sigmoid => F::one() / (F::one() + (-x).exp()),
            Act::Tanh => x.tanh(),
        }
    }
    /// dy/dx expressed through y.
    fn df_from_y<F: Float>(self, y: F) -> F {
        match self {
            Act::Relu => if y > F::zero() { F::one() } else { F::zero() },
            Act::Sigmoid => y * (F::one() - y),
            Act::Tanh => F::one() - y * y,
        }
    }
}

/// y = act(x), any shape.
///
/// Torch: `F.relu(x)`, `torch.sigmoid(x)`, `torch.tanh(x)`.
pub fn unary_fwd<F: Float>(act: Act, x: ArrayViewD<F>) -> ArrayD<F> {
    let x = x.as_standard_layout();
    let mut y = ArrayD::<F>::zeros(x.raw_dim());
    Zip::from(&mut y).and(&x).par_for_each(|y, &x| *y = act.f(x));
    y
}

/// dx = g * act'(x), computed from y = act(x).
///
/// # Gradient
/// relu: g·[y>0]; sigmoid: g·y(1−y); tanh: g·(1−y²).
pub fn unary_bwd<F: Float>(act: Act, y: ArrayViewD<F>, g: ArrayViewD<F>) -> Result<ArrayD<F>> {
    check_same_shape(act.name(), ("output", y.shape()), ("grad_output", g.shape()))?;
    let (y, g) = (y.as_standard_layout(), g.as_standard_layout());
    let mut dx = ArrayD::<F>::zeros(y.raw_dim());
    Zip::from(&mut dx).and(&y).and(&g).par_for_each(|dx, &y, &g| *dx = g * act.df_from_y(y));
    Ok(dx)
}
