//! Bindings of `ops::conv`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::conv::{self, Conv2dCfg, Conv2dNeed};
use crate::{Error, Result};

const OP: &str = "conv2d";

/// A config from Python's (possibly negative) integers.
fn cfg(stride: (i64, i64), padding: (i64, i64)) -> Result<Conv2dCfg> {
    let nonneg = |v: (i64, i64), what: &str| -> Result<[usize; 2]> {
        match (usize::try_from(v.0), usize::try_from(v.1)) {
            (Ok(a), Ok(b)) => Ok([a, b]),
            _ => Err(Error::arg(OP, format!("{what} must be non-negative, got {v:?}"))),
        }
    };
    Ok(Conv2dCfg::new(nonneg(stride, "stride")?, nonneg(padding, "padding")?))
}

/// The selected GEMM plan (its bfloat16 products when `bf16` and the CPU has them, else float32), with
/// Winograd allowed (f32) or not, keeping transformed kernels or not.
fn run<F: crate::Float>(winograd: bool, reuse_kernels: bool, bf16: bool) -> conv::Conv2dRun<'static, F> {
    let w = if winograd { conv::Winograd::Auto } else { conv::Winograd::Off };
    let selected = conv::Conv2dRun::selected();
    let plan = if bf16 { F::bf16_plan().unwrap_or(selected.plan) } else { selected.plan };
    conv::Conv2dRun { plan, winograd: w, reuse_kernels }
}

/// y = conv2d(x, weight) + bias, zero padding; then max(y, 0) when `relu` (fused into the GEMM).
///
/// Args:
///     x: (N, Cin, H, W) float32/float64 array.
///     weight: (Cout, Cin, kh, kw), same dtype.
///     bias: (Cout,) or None.
///     stride: (sh, sw), each >= 1.
///     padding: (ph, pw), each >= 0.
///     relu: apply ReLU to the output.
///     winograd: let stride-1 float32 convolutions with 3x3, 1x5 or 5x1 kernels use Winograd
///         F(4x4, 3x3) / F(4, 5) (False: direct).
///     reuse_kernels: keep a Winograd kernel's transform for later calls that bring the same weight
///         values (found by comparing them; for weights that stay fixed, as at inference).
///     bf16: float32 products rounded to bfloat16 with float32 sums where the CPU has bf16 dot
///         products (`bf16_supported()`), float32 elsewhere.
/// Returns:
///     y, (N, Cout, Ho, Wo).
#[pyfunction]
#[pyo3(signature = (x, weight, bias=None, stride=(1, 1), padding=(0, 0), relu=false, winograd=true, reuse_kernels=false,
                    bf16=false))]
#[allow(clippy::too_many_arguments)]
fn conv2d_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, weight: &Bound<'py, PyAny>, bias: Option<&Bound<'py, PyAny>>,
                   stride: (i64, i64), padding: (i64, i64), relu: bool, winograd: bool, reuse_kernels: bool, bf16: bool)
                   -> PyResult<Bound<'py, PyAny>> {
    let cfg = cfg(stride, padding)?;
    float_dispatch!(OP, "input", x, F => {
        let (x, w) = (arr::<F>(OP, "input", x)?, arr::<F>(OP, "weight", weight)?);
        let b = bias.map(|b| arr::<F>(OP, "bias", b)).transpose()?;
        let (xv, wv, bv) = (x.as_array(), w.as_array(), b.as_ref().map(|b| b.as_array()));
        let y = run_kernel(py, || conv::conv2d_fwd_ex(xv, wv, bv, &cfg, relu, run(winograd, reuse_kernels, bf16)))?;
        Ok(y.into_pyarray(py).into_any())
    })
}

/// Gradients of conv2d_fwd w.r.t. x, weight and bias; those not requested are None.
///
/// Args:
///     x: the forward input (N, Cin, H, W).
///     weight: the forward weight (Cout, Cin, kh, kw).
///     grad_output: (N, Cout, Ho, Wo).
///     stride: (sh, sw) of the forward.
///     padding: (ph, pw) of the forward.
///     need_x: compute dx.
///     need_w: compute dweight.
///     need_b: compute dbias.
///     winograd: let dx and dweight of a stride-1 float32 convolution with a 3x3, 1x5 or 5x1 kernel
///         use Winograd where it pays (False: direct).
/// Returns:
///     (dx or None, dweight or None, dbias or None).
#[pyfunction]
#[pyo3(signature = (x, weight, grad_output, stride=(1, 1), padding=(0, 0), need_x=true, need_w=true, need_b=true,
                    winograd=true))]
#[allow(clippy::too_many_arguments)]
fn conv2d_bwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, weight: &Bound<'py, PyAny>, grad_output: &Bound<'py, PyAny>,
                   stride: (i64, i64), padding: (i64, i64), need_x: bool, need_w: bool, need_b: bool, winograd: bool)
                   -> PyResult<Bound<'py, PyAny>> {
    let cfg = cfg(stride, padding)?;
    let need = Conv2dNeed { x: need_x, w: need_w, b: need_b };
    float_dispatch!(OP, "input", x, F => {
        let (x, w, g) = (arr::<F>(OP, "input", x)?, arr::<F>(OP, "weight", weight)?, arr::<F>(OP, "grad_output", grad_output)?);
        let (xv, wv, gv) = (x.as_array(), w.as_array(), g.as_array());
        let grads = run_kernel(py, || conv::conv2d_bwd_ex(xv, wv, gv, &cfg, need, run(winograd, false, false)))?;
        Ok((grads.x.map(|a| a.into_pyarray(py)), grads.w.map(|a| a.into_pyarray(py)), grads.b.map(|a| a.into_pyarray(py)))
            .into_pyobject(py)?
            .into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(conv2d_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(conv2d_bwd, m)?)?;
    Ok(())
}
