//! Bindings of `ops::pool`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::pool::{self, AvgPool2dCfg};

/// Average pooling over the last two axes.
///
/// Args:
///     x: (N, C, H, W) or (C, H, W) float32/float64 array.
///     kernel_size: (kh, kw), >= 1.
///     stride: (sh, sw), >= 1.
///     padding: (ph, pw) zero padding, at most half the kernel.
///     ceil_mode: round the output size up.
///     count_include_pad: count padded positions in the divisor.
///     divisor_override: a fixed divisor, or None.
/// Returns:
///     the pooled array (.., OH, OW).
#[pyfunction]
#[pyo3(signature = (x, kernel_size, stride, padding=[0, 0], ceil_mode=false, count_include_pad=true, divisor_override=None))]
#[allow(clippy::too_many_arguments)]
fn avg_pool2d_fwd<'py>(
    py: Python<'py>, x: &Bound<'py, PyAny>, kernel_size: [i64; 2], stride: [i64; 2], padding: [i64; 2],
    ceil_mode: bool, count_include_pad: bool, divisor_override: Option<i64>,
) -> PyResult<Bound<'py, PyAny>> {
    let op = "avg_pool2d";
    let cfg = AvgPool2dCfg::new(kernel_size, stride, padding, ceil_mode, count_include_pad, divisor_override)?;
    float_dispatch!(op, "input", x, F => {
        let x = arr::<F>(op, "input", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || pool::avg_pool2d_fwd(xv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Grad of `avg_pool2d_fwd` w.r.t. its input.
///
/// Args:
///     g: the gradient of the output (.., OH, OW).
///     input_shape: the forward input's shape.
///     kernel_size, stride, padding, ceil_mode, count_include_pad, divisor_override: as in the forward.
/// Returns:
///     dx of input_shape.
#[pyfunction]
#[pyo3(signature = (g, input_shape, kernel_size, stride, padding=[0, 0], ceil_mode=false, count_include_pad=true, divisor_override=None))]
#[allow(clippy::too_many_arguments)]
fn avg_pool2d_bwd<'py>(
    py: Python<'py>, g: &Bound<'py, PyAny>, input_shape: Vec<usize>, kernel_size: [i64; 2], stride: [i64; 2], padding: [i64; 2],
    ceil_mode: bool, count_include_pad: bool, divisor_override: Option<i64>,
) -> PyResult<Bound<'py, PyAny>> {
    let op = "avg_pool2d";
    let cfg = AvgPool2dCfg::new(kernel_size, stride, padding, ceil_mode, count_include_pad, divisor_override)?;
    float_dispatch!(op, "grad_output", g, F => {
        let g = arr::<F>(op, "grad_output", g)?;
        let gv = g.as_array();
        Ok(run_kernel(py, || pool::avg_pool2d_bwd(gv, &input_shape, &cfg))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(avg_pool2d_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(avg_pool2d_bwd, m)?)?;
    Ok(())
}
