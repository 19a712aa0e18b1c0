//! Bindings of `ops::act`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::act::{self, Act};

/// y = act(x) for act in "relu" | "sigmoid" | "tanh".
///
/// Args:
///     x: float32/float64 array of any shape.
///     act: the activation name.
/// Returns:
///     y, same shape and dtype.
#[pyfunction]
fn unary_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, act: &str) -> PyResult<Bound<'py, PyAny>> {
    let act = Act::parse(act)?;
    float_dispatch!(act.name(), "x", x, F => {
        let x = arr::<F>(act.name(), "x", x)?;
        let xv = x.as_array();
        let y = run_kernel(py, || act::unary_fwd(act, xv))?;
        Ok(y.into_pyarray(py).into_any())
    })
}

/// dx = g * act'(x), from the forward output y.
///
/// Args:
///     y: the forward output.
///     g: the gradient of the output, same shape.
///     act: the activation name.
/// Returns:
///     dx, same shape and dtype.
#[pyfunction]
fn unary_bwd<'py>(py: Python<'py>, y: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, act: &str) -> PyResult<Bound<'py, PyAny>> {
    let act = Act::parse(act)?;
    let op = act.name();
    float_dispatch!(op, "output", y, F => {
        let (y, g) = (arr::<F>(op, "output", y)?, arr::<F>(op, "grad_output", g)?);
        let (yv, gv) = (y.as_array(), g.as_array());
        let dx = run_kernel(py, || act::unary_bwd(act, yv, gv))?;
        Ok(dx.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(unary_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(unary_bwd, m)?)?;
    Ok(())
}
