//! Bindings of `ops::norm`.

use numpy::ndarray::ArrayViewD;
use numpy::{IntoPyArray, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::norm::{self, BatchNormCfg};

/// `arr` for an optional argument (Python None stays None).
fn opt_arr<'py, F: numpy::Element + crate::Float>(op: &str, name: &str, obj: Option<&Bound<'py, PyAny>>) -> PyResult<Option<PyReadonlyArrayDyn<'py, F>>> {
    obj.filter(|o| !o.is_none()).map(|o| arr::<F>(op, name, o)).transpose()
}

/// The view of an optional argument.
fn view<'a, F: numpy::Element>(a: &'a Option<PyReadonlyArrayDyn<'_, F>>) -> Option<ArrayViewD<'a, F>> {
    a.as_ref().map(|a| a.as_array())
}

/// Instance normalisation of each (n, c) plane, with an optional per-channel affine.
///
/// Args:
///     x: (N, C, H, W) float32/float64 array, H*W > 1.
///     weight: optional (C,) scale.
///     bias: optional (C,) shift.
///     eps: added to the variance.
/// Returns:
///     (y (N, C, H, W), mean (N, C), invstd (N, C)).
#[pyfunction]
#[pyo3(signature = (x, weight=None, bias=None, eps=1e-5))]
fn instance_norm_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, weight: Option<&Bound<'py, PyAny>>, bias: Option<&Bound<'py, PyAny>>, eps: f64) -> PyResult<Bound<'py, PyAny>> {
    let op = "instance_norm";
    float_dispatch!(op, "input", x, F => {
        let x = arr::<F>(op, "input", x)?;
        let (w, b) = (opt_arr::<F>(op, "weight", weight)?, opt_arr::<F>(op, "bias", bias)?);
        let (xv, wv, bv) = (x.as_array(), view(&w), view(&b));
        let out = run_kernel(py, || norm::instance_norm_fwd(xv, wv, bv, eps))?;
        Ok((out.y.into_pyarray(py), out.mean.into_pyarray(py), out.invstd.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// Grads of `instance_norm_fwd`.
///
/// Args:
///     x: the forward input (N, C, H, W).
///     mean: (N, C) from the forward.
///     invstd: (N, C) from the forward.
///     g: the gradient of y (N, C, H, W).
///     weight: the forward's optional (C,) weight.
/// Returns:
///     (dx (N, C, H, W), dweight (C,), dbias (C,)).
#[pyfunction]
#[pyo3(signature = (x, mean, invstd, g, weight=None))]
fn instance_norm_bwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, mean: &Bound<'py, PyAny>, invstd: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, weight: Option<&Bound<'py, PyAny>>) -> PyResult<Bound<'py, PyAny>> {
    let op = "instance_norm";
    float_dispatch!(op, "input", x, F => {
        let (x, m, s, g) = (arr::<F>(op, "input", x)?, arr::<F>(op, "mean", mean)?, arr::<F>(op, "invstd", invstd)?, arr::<F>(op, "grad_output", g)?);
        let w = opt_arr::<F>(op, "weight", weight)?;
        let (xv, mv, sv, gv, wv) = (x.as_array(), m.as_array(), s.as_array(), g.as_array(), view(&w));
        let grads = run_kernel(py, || norm::instance_norm_bwd(xv, mv, sv, wv, gv))?;
        Ok((grads.x.into_pyarray(py), grads.weight.into_pyarray(py), grads.bias.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// Batch normalisation (batch statistics in training, running statistics in eval).
///
/// Args:
///     x: (N, C, H, W) float32/float64 array (training: N*H*W > 1).
///     weight: optional (C,) scale.
///     bias: optional (C,) shift.
///     running_mean: optional (C,) running mean (required in eval); never modified.
///     running_var: optional (C,) running variance (required in eval); never modified.
///     training: batch statistics when True.
///     momentum: weight of the batch statistic in the running-stat update.
///     eps: added to the variance.
/// Returns:
///     (y (N, C, H, W), mean (C,), invstd (C,), new_running_mean or None, new_running_var or None);
///     the new running stats are given in training when running stats were passed.
#[pyfunction]
#[pyo3(signature = (x, weight=None, bias=None, running_mean=None, running_var=None, training=false, momentum=0.1, eps=1e-5))]
#[allow(clippy::too_many_arguments)]
fn batch_norm_fwd<'py>(
    py: Python<'py>, x: &Bound<'py, PyAny>, weight: Option<&Bound<'py, PyAny>>, bias: Option<&Bound<'py, PyAny>>,
    running_mean: Option<&Bound<'py, PyAny>>, running_var: Option<&Bound<'py, PyAny>>, training: bool, momentum: f64, eps: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let op = "batch_norm";
    let cfg = BatchNormCfg::new(training, momentum, eps)?;
    float_dispatch!(op, "input", x, F => {
        let x = arr::<F>(op, "input", x)?;
        let (w, b) = (opt_arr::<F>(op, "weight", weight)?, opt_arr::<F>(op, "bias", bias)?);
        let (rm, rv) = (opt_arr::<F>(op, "running_mean", running_mean)?, opt_arr::<F>(op, "running_var", running_var)?);
        let (xv, wv, bv, rmv, rvv) = (x.as_array(), view(&w), view(&b), view(&rm), view(&rv));
        let out = run_kernel(py, || norm::batch_norm_fwd(xv, wv, bv, rmv, rvv, &cfg))?;
        let (nrm, nrv) = (out.running_mean.map(|a| a.into_pyarray(py)), out.running_var.map(|a| a.into_pyarray(py)));
        Ok((out.y.into_pyarray(py), out.mean.into_pyarray(py), out.invstd.into_pyarray(py), nrm, nrv).into_pyobject(py)?.into_any())
    })
}

/// Grads of `batch_norm_fwd`.
///
/// Args:
///     x: the forward input (N, C, H, W).
///     mean: (C,) from the forward.
///     invstd: (C,) from the forward.
///     g: the gradient of y (N, C, H, W).
///     weight: the forward's optional (C,) weight.
///     training: the forward's mode (True: full backward through the batch statistics; False: affine only).
/// Returns:
///     (dx (N, C, H, W), dweight (C,), dbias (C,)).
#[pyfunction]
#[pyo3(signature = (x, mean, invstd, g, weight=None, training=false))]
fn batch_norm_bwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, mean: &Bound<'py, PyAny>, invstd: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, weight: Option<&Bound<'py, PyAny>>, training: bool) -> PyResult<Bound<'py, PyAny>> {
    let op = "batch_norm";
    float_dispatch!(op, "input", x, F => {
        let (x, m, s, g) = (arr::<F>(op, "input", x)?, arr::<F>(op, "mean", mean)?, arr::<F>(op, "invstd", invstd)?, arr::<F>(op, "grad_output", g)?);
        let w = opt_arr::<F>(op, "weight", weight)?;
        let (xv, mv, sv, gv, wv) = (x.as_array(), m.as_array(), s.as_array(), g.as_array(), view(&w));
        let grads = run_kernel(py, || norm::batch_norm_bwd(xv, mv, sv, wv, gv, training))?;
        Ok((grads.x.into_pyarray(py), grads.weight.into_pyarray(py), grads.bias.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(instance_norm_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(instance_norm_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(batch_norm_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(batch_norm_bwd, m)?)?;
    Ok(())
}
