//! Bindings of `ops::gate`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::gate;

/// out = w * x + (1 - w) * y with w = sigmoid(local + global) (iAFF's gate).
///
/// Args:
///     local: float32/float64 array (N, C, H, W).
///     glob: (N, C, 1, 1), broadcast over H, W.
///     x, y: (N, C, H, W).
/// Returns:
///     (N, C, H, W).
#[pyfunction]
fn attention_gate_fwd<'py>(py: Python<'py>, local: &Bound<'py, PyAny>, glob: &Bound<'py, PyAny>, x: &Bound<'py, PyAny>,
                           y: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let op = "attention_gate";
    float_dispatch!(op, "local", local, F => {
        let (l, g, xa, ya) = (arr::<F>(op, "local", local)?, arr::<F>(op, "global", glob)?, arr::<F>(op, "x", x)?, arr::<F>(op, "y", y)?);
        let (lv, gv, xv, yv) = (l.as_array(), g.as_array(), xa.as_array(), ya.as_array());
        Ok(run_kernel(py, || gate::attention_gate_fwd(lv, gv, xv, yv))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `attention_gate_fwd`.
///
/// Args:
///     local, glob, x, y: as in the forward.
///     g: gradient of the output (N, C, H, W).
/// Returns:
///     (grad_local, grad_global, grad_x, grad_y).
#[pyfunction]
fn attention_gate_bwd<'py>(py: Python<'py>, local: &Bound<'py, PyAny>, glob: &Bound<'py, PyAny>, x: &Bound<'py, PyAny>,
                           y: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let op = "attention_gate";
    float_dispatch!(op, "local", local, F => {
        let (l, gl, xa, ya) = (arr::<F>(op, "local", local)?, arr::<F>(op, "global", glob)?, arr::<F>(op, "x", x)?, arr::<F>(op, "y", y)?);
        let ga = arr::<F>(op, "grad_output", g)?;
        let (lv, glv, xv, yv, gv) = (l.as_array(), gl.as_array(), xa.as_array(), ya.as_array(), ga.as_array());
        let r = run_kernel(py, || gate::attention_gate_bwd(lv, glv, xv, yv, gv))?;
        Ok((r.local.into_pyarray(py), r.global.into_pyarray(py), r.x.into_pyarray(py), r.y.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(attention_gate_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(attention_gate_bwd, m)?)?;
    Ok(())
}
