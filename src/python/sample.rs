//! Bindings of `ops::sample`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::sample::{self as sm, GridPadding, GridSampleCfg, InterpCfg, UnfoldCfg};

/// Bilinear sampling of x at normalised grid points.
///
/// Args:
///     x: float32/float64 array (N, C, H, W).
///     grid: (N, H_out, W_out, 2), x then y, -1..1 spanning the input.
///     padding_mode: "zeros" or "border".
///     align_corners: whether -1 and 1 are the centres (True) or the outer edges (False) of the corner pixels.
/// Returns:
///     (N, C, H_out, W_out).
#[pyfunction]
#[pyo3(signature = (x, grid, padding_mode="zeros", align_corners=false))]
fn grid_sample_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, grid: &Bound<'py, PyAny>, padding_mode: &str, align_corners: bool) -> PyResult<Bound<'py, PyAny>> {
    let cfg = GridSampleCfg { padding: GridPadding::parse(padding_mode)?, align_corners };
    float_dispatch!("grid_sample", "input", x, F => {
        let (x, grid) = (arr::<F>("grid_sample", "input", x)?, arr::<F>("grid_sample", "grid", grid)?);
        let (xv, gv) = (x.as_array(), grid.as_array());
        Ok(run_kernel(py, || sm::grid_sample_fwd(xv, gv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradients of `grid_sample_fwd`.
///
/// Args:
///     x: the input (N, C, H, W).
///     grid: the grid (N, H_out, W_out, 2).
///     g: gradient of the output (N, C, H_out, W_out).
///     padding_mode: "zeros" or "border".
///     align_corners: as in the forward.
///     need_input: compute the input gradient.
///     need_grid: compute the grid gradient.
/// Returns:
///     (grad_input or None, grad_grid or None).
#[pyfunction]
#[pyo3(signature = (x, grid, g, padding_mode="zeros", align_corners=false, need_input=true, need_grid=true))]
#[allow(clippy::too_many_arguments)]
fn grid_sample_bwd<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    grid: &Bound<'py, PyAny>,
    g: &Bound<'py, PyAny>,
    padding_mode: &str,
    align_corners: bool,
    need_input: bool,
    need_grid: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let cfg = GridSampleCfg { padding: GridPadding::parse(padding_mode)?, align_corners };
    let op = "grid_sample";
    float_dispatch!(op, "input", x, F => {
        let (x, grid, g) = (arr::<F>(op, "input", x)?, arr::<F>(op, "grid", grid)?, arr::<F>(op, "grad_output", g)?);
        let (xv, grv, gv) = (x.as_array(), grid.as_array(), g.as_array());
        let grads = run_kernel(py, || sm::grid_sample_bwd(xv, grv, gv, &cfg, need_input, need_grid))?;
        Ok((grads.input.map(|a| a.into_pyarray(py)), grads.grid.map(|a| a.into_pyarray(py))).into_pyobject(py)?.into_any())
    })
}

/// Bilinear resize of the last two axes.
///
/// Args:
///     x: float32/float64 array (N, C, H, W).
///     size: (H_out, W_out).
///     align_corners: torch's align_corners.
///     scales: torch's scale_factor per axis (h, w) when the size came from one, else None.
/// Returns:
///     (N, C, H_out, W_out).
#[pyfunction]
#[pyo3(signature = (x, size, align_corners=false, scales=(None, None)))]
fn interpolate_bilinear_fwd<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    size: (usize, usize),
    align_corners: bool,
    scales: (Option<f64>, Option<f64>),
) -> PyResult<Bound<'py, PyAny>> {
    let cfg = InterpCfg { out_hw: size, align_corners, scales: [scales.0, scales.1] };
    float_dispatch!("interpolate", "input", x, F => {
        let x = arr::<F>("interpolate", "input", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || sm::interpolate_bilinear_fwd(xv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Gradient of `interpolate_bilinear_fwd` with respect to its input.
///
/// Args:
///     g: gradient of the output (N, C, H_out, W_out).
///     input_hw: (H, W) of the input.
///     align_corners: as in the forward.
///     scales: as in the forward.
/// Returns:
///     (N, C, H, W).
#[pyfunction]
#[pyo3(signature = (g, input_hw, align_corners=false, scales=(None, None)))]
fn interpolate_bilinear_bwd<'py>(
    py: Python<'py>,
    g: &Bound<'py, PyAny>,
    input_hw: (usize, usize),
    align_corners: bool,
    scales: (Option<f64>, Option<f64>),
) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("interpolate", "grad_output", g, F => {
        let g = arr::<F>("interpolate", "grad_output", g)?;
        let gv = g.as_array();
        let size = (gv.shape().get(2).copied().unwrap_or(0), gv.shape().get(3).copied().unwrap_or(0));
        let cfg = InterpCfg { out_hw: size, align_corners, scales: [scales.0, scales.1] };
        Ok(run_kernel(py, || sm::interpolate_bilinear_bwd(gv, input_hw, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Sliding blocks of an (N, C, H, W) array as columns (N, C·kh·kw, L).
///
/// Args:
///     x: float32/float64 array (N, C, H, W).
///     kernel_size, dilation, padding, stride: (h, w) pairs.
/// Returns:
///     (N, C·kh·kw, L_h·L_w).
#[pyfunction]
fn unfold_fwd<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    kernel_size: [usize; 2],
    dilation: [usize; 2],
    padding: [usize; 2],
    stride: [usize; 2],
) -> PyResult<Bound<'py, PyAny>> {
    let cfg = UnfoldCfg::new("unfold", kernel_size, dilation, padding, stride)?;
    float_dispatch!("unfold", "input", x, F => {
        let x = arr::<F>("unfold", "input", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || sm::unfold_fwd(xv, &cfg))?.into_pyarray(py).into_any())
    })
}

/// Sums columns (N, C·kh·kw, L) of sliding blocks into an (N, C, H, W) array.
///
/// Args:
///     cols: float32/float64 array (N, C·kh·kw, L).
///     output_size: (H, W).
///     kernel_size, dilation, padding, stride: (h, w) pairs.
/// Returns:
///     (N, C, H, W).
#[pyfunction]
fn fold_fwd<'py>(
    py: Python<'py>,
    cols: &Bound<'py, PyAny>,
    output_size: (usize, usize),
    kernel_size: [usize; 2],
    dilation: [usize; 2],
    padding: [usize; 2],
    stride: [usize; 2],
) -> PyResult<Bound<'py, PyAny>> {
    let cfg = UnfoldCfg::new("fold", kernel_size, dilation, padding, stride)?;
    float_dispatch!("fold", "input", cols, F => {
        let c = arr::<F>("fold", "input", cols)?;
        let cv = c.as_array();
        Ok(run_kernel(py, || sm::fold_fwd(cv, output_size, &cfg))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(grid_sample_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(grid_sample_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(interpolate_bilinear_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(interpolate_bilinear_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(unfold_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(fold_fwd, m)?)?;
    Ok(())
}
