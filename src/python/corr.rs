//! Bindings of `ops::corr`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::corr::{self, IpCorrCfg, RlsCorrCfg};
use crate::ops::warp_corr::{self, IpWarpCfg, RlsWarpCfg, IP_SEEDS};

/// IP correlation: grouped channel mean of fl times every seed of the stack.
///
/// Args:
///     fl: float32/float64 array (N, C, h, w).
///     stack: (N, S*C, h, w), seed s in channels s*C .. (s+1)*C.
///     groups: channel groups G (C divisible by G).
/// Returns:
///     (N, G*S, h, w), channel S*g + s.
#[pyfunction]
#[pyo3(signature = (fl, stack, groups=2))]
fn ip_corr_fwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, stack: &Bound<'py, PyAny>, groups: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = IpCorrCfg { groups };
    let op = "ip_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, stack) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "stack", stack)?);
        let (fv, sv) = (fl.as_array(), stack.as_array());
        Ok(run_kernel(py, || corr::ip_corr_fwd(fv, sv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `ip_corr_fwd`.
///
/// Args:
///     fl: (N, C, h, w).
///     stack: (N, S*C, h, w).
///     g: gradient of the output (N, G*S, h, w).
///     groups: as in the forward.
/// Returns:
///     (grad_fl, grad_stack).
#[pyfunction]
#[pyo3(signature = (fl, stack, g, groups=2))]
fn ip_corr_bwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, stack: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, groups: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = IpCorrCfg { groups };
    let op = "ip_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, stack, g) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "stack", stack)?, arr::<F>(op, "grad_output", g)?);
        let (fv, sv, gv) = (fl.as_array(), stack.as_array(), g.as_array());
        let grads = run_kernel(py, || corr::ip_corr_bwd(fv, sv, gv, &cfg))?;
        Ok((grads.fl.into_pyarray(py), grads.stack.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// RLS correlation over a (2rx+1) x (2ry+1) window of the replicate-padded warped map.
///
/// Args:
///     fl: float32/float64 array (N, C, h, w).
///     warped: (N, C, h, w).
///     rx: horizontal radius.
///     ry: vertical radius.
/// Returns:
///     (N, (2rx+1)(2ry+1), h, w), channel (2ry+1)*i + j for the shift (i - rx, j - ry).
#[pyfunction]
#[pyo3(signature = (fl, warped, rx=3, ry=1))]
fn rls_corr_fwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, warped: &Bound<'py, PyAny>, rx: usize, ry: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = RlsCorrCfg { rx, ry };
    let op = "rls_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, warped) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "warped", warped)?);
        let (fv, wv) = (fl.as_array(), warped.as_array());
        Ok(run_kernel(py, || corr::rls_corr_fwd(fv, wv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `rls_corr_fwd`.
///
/// Args:
///     fl: (N, C, h, w).
///     warped: (N, C, h, w).
///     g: gradient of the output (N, (2rx+1)(2ry+1), h, w).
///     rx, ry: as in the forward.
/// Returns:
///     (grad_fl, grad_warped).
#[pyfunction]
#[pyo3(signature = (fl, warped, g, rx=3, ry=1))]
fn rls_corr_bwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, warped: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, rx: usize, ry: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = RlsCorrCfg { rx, ry };
    let op = "rls_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, warped, g) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "warped", warped)?, arr::<F>(op, "grad_output", g)?);
        let (fv, wv, gv) = (fl.as_array(), warped.as_array(), g.as_array());
        let grads = run_kernel(py, || corr::rls_corr_bwd(fv, wv, gv, &cfg))?;
        Ok((grads.fl.into_pyarray(py), grads.warped.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// IP correlation fused with the horizontal warp of the seed stack (vertical flow zero).
///
/// Args:
///     fl: float32/float64 array (N, h, w, C), channels-last left features.
///     fr: (N, h, w, C), channels-last right features.
///     flow_x: (N, h, w), horizontal flow in pixels of the level.
///     groups: channel groups G (C divisible by G).
///     seeds: the seed offsets (ox, oy), default MIPNet's centre, tl, tr, dl, dr.
/// Returns:
///     (N, G*S, h, w), channel S*g + s.
#[pyfunction]
#[pyo3(signature = (fl, fr, flow_x, groups=2, seeds=None))]
fn ip_warp_corr_fwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, fr: &Bound<'py, PyAny>, flow_x: &Bound<'py, PyAny>, groups: usize,
                         seeds: Option<Vec<(isize, isize)>>) -> PyResult<Bound<'py, PyAny>> {
    let cfg = IpWarpCfg { groups, seeds: seeds.unwrap_or_else(|| IP_SEEDS.to_vec()) };
    let op = "ip_warp_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, fr, fx) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "fr", fr)?, arr::<F>(op, "flow_x", flow_x)?);
        let (lv, rv, xv) = (fl.as_array(), fr.as_array(), fx.as_array());
        Ok(run_kernel(py, || warp_corr::ip_warp_corr_fwd(lv, rv, xv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `ip_warp_corr_fwd` with respect to fl and fr.
///
/// Args:
///     fl, fr, flow_x, groups, seeds: as in the forward.
///     g: gradient of the output (N, G*S, h, w).
/// Returns:
///     (grad_fl, grad_fr), channels-last.
#[pyfunction]
#[pyo3(signature = (fl, fr, flow_x, g, groups=2, seeds=None))]
fn ip_warp_corr_bwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, fr: &Bound<'py, PyAny>, flow_x: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>,
                         groups: usize, seeds: Option<Vec<(isize, isize)>>) -> PyResult<Bound<'py, PyAny>> {
    let cfg = IpWarpCfg { groups, seeds: seeds.unwrap_or_else(|| IP_SEEDS.to_vec()) };
    let op = "ip_warp_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, fr, fx) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "fr", fr)?, arr::<F>(op, "flow_x", flow_x)?);
        let g = arr::<F>(op, "grad_output", g)?;
        let (lv, rv, xv, gv) = (fl.as_array(), fr.as_array(), fx.as_array(), g.as_array());
        let grads = run_kernel(py, || warp_corr::ip_warp_corr_bwd(lv, rv, xv, gv, &cfg))?;
        Ok((grads.fl.into_pyarray(py), grads.fr.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// RLS correlation fused with the horizontal warp of the right features (vertical flow zero).
///
/// Args:
///     fl: float32/float64 array (N, h, w, C), channels-last left features.
///     fr: (N, h, w, C), channels-last right features.
///     flow_x: (N, h, w), horizontal flow in pixels of the level.
///     rx: horizontal radius.
///     ry: vertical radius.
/// Returns:
///     (N, (2rx+1)(2ry+1), h, w), channel (2ry+1)*i + j for the shift (i - rx, j - ry).
#[pyfunction]
#[pyo3(signature = (fl, fr, flow_x, rx=3, ry=1))]
fn rls_warp_corr_fwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, fr: &Bound<'py, PyAny>, flow_x: &Bound<'py, PyAny>, rx: usize,
                          ry: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = RlsWarpCfg { rx, ry };
    let op = "rls_warp_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, fr, fx) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "fr", fr)?, arr::<F>(op, "flow_x", flow_x)?);
        let (lv, rv, xv) = (fl.as_array(), fr.as_array(), fx.as_array());
        Ok(run_kernel(py, || warp_corr::rls_warp_corr_fwd(lv, rv, xv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `rls_warp_corr_fwd` with respect to fl and fr.
///
/// Args:
///     fl, fr, flow_x, rx, ry: as in the forward.
///     g: gradient of the output (N, (2rx+1)(2ry+1), h, w).
/// Returns:
///     (grad_fl, grad_fr), channels-last.
#[pyfunction]
#[pyo3(signature = (fl, fr, flow_x, g, rx=3, ry=1))]
fn rls_warp_corr_bwd<'py>(py: Python<'py>, fl: &Bound<'py, PyAny>, fr: &Bound<'py, PyAny>, flow_x: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>,
                          rx: usize, ry: usize) -> PyResult<Bound<'py, PyAny>> {
    let cfg = RlsWarpCfg { rx, ry };
    let op = "rls_warp_correlation";
    float_dispatch!(op, "fl", fl, F => {
        let (fl, fr, fx) = (arr::<F>(op, "fl", fl)?, arr::<F>(op, "fr", fr)?, arr::<F>(op, "flow_x", flow_x)?);
        let g = arr::<F>(op, "grad_output", g)?;
        let (lv, rv, xv, gv) = (fl.as_array(), fr.as_array(), fx.as_array(), g.as_array());
        let grads = run_kernel(py, || warp_corr::rls_warp_corr_bwd(lv, rv, xv, gv, &cfg))?;
        Ok((grads.fl.into_pyarray(py), grads.fr.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(ip_corr_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(ip_corr_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(rls_corr_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(rls_corr_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(ip_warp_corr_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(ip_warp_corr_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(rls_warp_corr_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(rls_warp_corr_bwd, m)?)?;
    Ok(())
}
