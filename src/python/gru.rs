//! Bindings of `ops::gru`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::gru;

/// rhx = [sigmoid(zr[:, H:]) * hx[:, :H], hx[:, H:]].
///
/// Args:
///     zr: float32/float64 array (N, 2H, h, w), the stacked z and r pre-activations.
///     hx: (N, H+X, h, w), the GRU input [h, x].
/// Returns:
///     rhx, (N, H+X, h, w).
#[pyfunction]
fn gru_reset_fwd<'py>(py: Python<'py>, zr: &Bound<'py, PyAny>, hx: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let op = "gru_reset";
    float_dispatch!(op, "zr", zr, F => {
        let (zr, hx) = (arr::<F>(op, "zr", zr)?, arr::<F>(op, "hx", hx)?);
        let (zv, hv) = (zr.as_array(), hx.as_array());
        Ok(run_kernel(py, || gru::gru_reset_fwd(zv, hv))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `gru_reset_fwd`.
///
/// Args:
///     zr, hx: as in the forward.
///     g: gradient of the output (N, H+X, h, w).
/// Returns:
///     (grad_zr, grad_hx); grad_zr is zero in its z half.
#[pyfunction]
fn gru_reset_bwd<'py>(py: Python<'py>, zr: &Bound<'py, PyAny>, hx: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let op = "gru_reset";
    float_dispatch!(op, "zr", zr, F => {
        let (zr, hx, g) = (arr::<F>(op, "zr", zr)?, arr::<F>(op, "hx", hx)?, arr::<F>(op, "grad_output", g)?);
        let (zv, hv, gv) = (zr.as_array(), hx.as_array(), g.as_array());
        let grads = run_kernel(py, || gru::gru_reset_bwd(zv, hv, gv))?;
        Ok((grads.zr.into_pyarray(py), grads.hx.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// h' = (1 - z) * h + z * tanh(q) with z = sigmoid(zr[:, :H]), h = hx[:, :H]; [h', x] with keep_x.
///
/// Args:
///     zr: float32/float64 array (N, 2H, h, w).
///     q: (N, H, h, w), the candidate's pre-activation.
///     hx: (N, H+X, h, w).
///     keep_x: also copy x = hx[:, H:] after h' (the next pass's input).
/// Returns:
///     (N, H, h, w), or (N, H+X, h, w) with keep_x.
#[pyfunction]
fn gru_update_fwd<'py>(py: Python<'py>, zr: &Bound<'py, PyAny>, q: &Bound<'py, PyAny>, hx: &Bound<'py, PyAny>, keep_x: bool) -> PyResult<Bound<'py, PyAny>> {
    let op = "gru_update";
    float_dispatch!(op, "zr", zr, F => {
        let (zr, q, hx) = (arr::<F>(op, "zr", zr)?, arr::<F>(op, "q", q)?, arr::<F>(op, "hx", hx)?);
        let (zv, qv, hv) = (zr.as_array(), q.as_array(), hx.as_array());
        Ok(run_kernel(py, || gru::gru_update_fwd(zv, qv, hv, keep_x))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `gru_update_fwd`.
///
/// Args:
///     zr, q, hx, keep_x: as in the forward.
///     g: gradient of the output.
/// Returns:
///     (grad_zr, grad_q, grad_hx); grad_zr is zero in its r half.
#[pyfunction]
fn gru_update_bwd<'py>(py: Python<'py>, zr: &Bound<'py, PyAny>, q: &Bound<'py, PyAny>, hx: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>,
                       keep_x: bool) -> PyResult<Bound<'py, PyAny>> {
    let op = "gru_update";
    float_dispatch!(op, "zr", zr, F => {
        let (zr, q, hx) = (arr::<F>(op, "zr", zr)?, arr::<F>(op, "q", q)?, arr::<F>(op, "hx", hx)?);
        let g = arr::<F>(op, "grad_output", g)?;
        let (zv, qv, hv, gv) = (zr.as_array(), q.as_array(), hx.as_array(), g.as_array());
        let grads = run_kernel(py, || gru::gru_update_bwd(zv, qv, hv, gv, keep_x))?;
        Ok((grads.zr.into_pyarray(py), grads.q.into_pyarray(py), grads.hx.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(gru_reset_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(gru_reset_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(gru_update_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(gru_update_bwd, m)?)?;
    Ok(())
}
