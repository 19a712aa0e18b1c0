//! Bindings of `ops::softmax`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::softmax;

/// Softmax along `dim`.
///
/// Args:
///     x: float32/float64 array of any shape.
///     dim: the axis, negative counting from the end.
/// Returns:
///     y, same shape and dtype.
#[pyfunction]
fn softmax_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, dim: isize) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("softmax", "input", x, F => {
        let x = arr::<F>("softmax", "input", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || softmax::softmax_fwd(xv, dim))?.into_pyarray(py).into_any())
    })
}

/// Grad of `softmax_fwd` w.r.t. its input, from the forward output y.
///
/// Args:
///     y: the forward output.
///     g: the gradient of y, same shape.
///     dim: the forward's axis.
/// Returns:
///     dx = y * (g - sum(g * y, dim)), same shape and dtype.
#[pyfunction]
fn softmax_bwd<'py>(py: Python<'py>, y: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, dim: isize) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("softmax", "output", y, F => {
        let (y, g) = (arr::<F>("softmax", "output", y)?, arr::<F>("softmax", "grad_output", g)?);
        let (yv, gv) = (y.as_array(), g.as_array());
        Ok(run_kernel(py, || softmax::softmax_bwd(yv, gv, dim))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(softmax_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(softmax_bwd, m)?)?;
    Ok(())
}
