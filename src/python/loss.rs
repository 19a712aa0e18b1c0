//! Bindings of `ops::loss`.

use numpy::ndarray::arr0;
use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::loss;
use crate::Float;

/// Mean of |pred - gt| over the valid positions (0 when none is valid).
///
/// Args:
///     pred: float32/float64 array of any shape.
///     gt: the target, same shape and dtype (invalid positions may hold NaN/inf).
///     valid: 0/1 mask, same shape and dtype (>= 0.5 is valid).
/// Returns:
///     the loss as a 0-d array.
#[pyfunction]
fn masked_l1_fwd<'py>(py: Python<'py>, pred: &Bound<'py, PyAny>, gt: &Bound<'py, PyAny>, valid: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let op = "masked_l1_loss";
    float_dispatch!(op, "input", pred, F => {
        let (p, t, v) = (arr::<F>(op, "input", pred)?, arr::<F>(op, "target", gt)?, arr::<F>(op, "valid", valid)?);
        let (pv, tv, vv) = (p.as_array(), t.as_array(), v.as_array());
        let l = run_kernel(py, || loss::masked_l1_fwd(pv, tv, vv))?;
        Ok(arr0(l).into_dyn().into_pyarray(py).into_any())
    })
}

/// Grad of `masked_l1_fwd` w.r.t. pred.
///
/// Args:
///     pred, gt, valid: as in the forward.
///     g: the upstream gradient of the scalar loss.
/// Returns:
///     dpred = g * sign(pred - gt) * valid / count, pred's shape.
#[pyfunction]
fn masked_l1_bwd<'py>(py: Python<'py>, pred: &Bound<'py, PyAny>, gt: &Bound<'py, PyAny>, valid: &Bound<'py, PyAny>, g: f64) -> PyResult<Bound<'py, PyAny>> {
    let op = "masked_l1_loss";
    float_dispatch!(op, "input", pred, F => {
        let (p, t, v) = (arr::<F>(op, "input", pred)?, arr::<F>(op, "target", gt)?, arr::<F>(op, "valid", valid)?);
        let (pv, tv, vv) = (p.as_array(), t.as_array(), v.as_array());
        Ok(run_kernel(py, || loss::masked_l1_bwd(pv, tv, vv, F::c(g)))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(masked_l1_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(masked_l1_bwd, m)?)?;
    Ok(())
}
