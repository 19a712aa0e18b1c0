//! Bindings of `ops::pad`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::pad::{self, Pad2dCfg, PadMode};

/// Pads the last two axes of an (N, C, H, W) array.
///
/// Args:
///     x: float32/float64 array (N, C, H, W).
///     pad: [left, right, top, bottom], non-negative.
///     mode: "constant" or "replicate".
///     value: the fill of constant padding.
/// Returns:
///     (N, C, H + top + bottom, W + left + right), same dtype.
#[pyfunction]
#[pyo3(signature = (x, pad, mode="constant", value=0.0))]
fn pad2d_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, pad: Vec<i64>, mode: &str, value: f64) -> PyResult<Bound<'py, PyAny>> {
    let cfg = Pad2dCfg::new(&pad, PadMode::parse(mode)?, value)?;
    float_dispatch!("pad", "input", x, F => {
        let x = arr::<F>("pad", "input", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || pad::pad2d_fwd(xv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradient of `pad2d_fwd` with respect to its input.
///
/// Args:
///     g: gradient of the padded output (N, C, H + top + bottom, W + left + right).
///     input_hw: (H, W) of the unpadded input.
///     pad: [left, right, top, bottom].
///     mode: "constant" or "replicate".
/// Returns:
///     dx (N, C, H, W).
#[pyfunction]
#[pyo3(signature = (g, input_hw, pad, mode="constant"))]
fn pad2d_bwd<'py>(py: Python<'py>, g: &Bound<'py, PyAny>, input_hw: (usize, usize), pad: Vec<i64>, mode: &str) -> PyResult<Bound<'py, PyAny>> {
    let cfg = Pad2dCfg::new(&pad, PadMode::parse(mode)?, 0.0)?;
    float_dispatch!("pad", "grad_output", g, F => {
        let g = arr::<F>("pad", "grad_output", g)?;
        let gv = g.as_array();
        Ok(run_kernel(py, || pad::pad2d_bwd(gv, input_hw, &cfg))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(pad2d_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(pad2d_bwd, m)?)?;
    Ok(())
}
