//! Bindings of `ops::upsample`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::upsample::{self as up, ConvexUpsampleCfg};

/// Convex upsampling (RAFT) of a field by `rate`.
///
/// Args:
///     flow: float32/float64 array (N, D, h, w).
///     mask: (N, 9*rate*rate, h, w), channel k*rate^2 + i*rate + j.
///     rate: the upsampling factor R.
/// Returns:
///     (N, D, R*h, R*w).
#[pyfunction]
#[pyo3(signature = (flow, mask, rate=4))]
fn convex_upsample_fwd<'py>(py: Python<'py>, flow: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>, rate: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = ConvexUpsampleCfg { rate };
    let op = "convex_upsample";
    float_dispatch!(op, "flow", flow, F => {
        let (flow, mask) = (arr::<F>(op, "flow", flow)?, arr::<F>(op, "mask", mask)?);
        let (fv, mv) = (flow.as_array(), mask.as_array());
        Ok(run_kernel(py, || up::convex_upsample_fwd(fv, mv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `convex_upsample_fwd`.
///
/// Args:
///     flow: (N, D, h, w).
///     mask: (N, 9*rate*rate, h, w).
///     g: gradient of the output (N, D, R*h, R*w).
///     rate: as in the forward.
/// Returns:
///     (grad_flow, grad_mask).
#[pyfunction]
#[pyo3(signature = (flow, mask, g, rate=4))]
fn convex_upsample_bwd<'py>(py: Python<'py>, flow: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, rate: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = ConvexUpsampleCfg { rate };
    let op = "convex_upsample";
    float_dispatch!(op, "flow", flow, F => {
        let (flow, mask, g) = (arr::<F>(op, "flow", flow)?, arr::<F>(op, "mask", mask)?, arr::<F>(op, "grad_output", g)?);
        let (fv, mv, gv) = (flow.as_array(), mask.as_array(), g.as_array());
        let grads = run_kernel(py, || up::convex_upsample_bwd(fv, mv, gv, &cfg))?;
        Ok((grads.flow.into_pyarray(py), grads.mask.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(convex_upsample_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(convex_upsample_bwd, m)?)?;
    Ok(())
}
