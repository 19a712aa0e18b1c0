//! Bindings of `ops::shape`.

use numpy::{IntoPyArray, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::ops::shape as sh;

/// Concatenation of a list of arrays along `axis`, input i through a ReLU where `relu[i]`.
#[pyfunction]
#[pyo3(signature = (xs, axis, relu = Vec::new()))]
fn cat_fwd<'py>(py: Python<'py>, xs: Vec<Bound<'py, PyAny>>, axis: usize, relu: Vec<bool>) -> PyResult<Bound<'py, PyAny>> {
    let first = xs.first().ok_or_else(|| crate::Error::arg("cat", "needs at least one tensor"))?.clone();
    float_dispatch!("cat", "tensors", &first, F => {
        let held: Vec<PyReadonlyArrayDyn<F>> = xs.iter().map(|x| arr::<F>("cat", "tensors", x)).collect::<PyResult<_>>()?;
        let views: Vec<_> = held.iter().map(|x| x.as_array()).collect();
        Ok(run_kernel(py, || sh::cat_fwd(&views, axis, &relu))?.into_pyarray(py).into_any())
    })
}

/// x[.., start:stop, ..] along `axis`.
#[pyfunction]
fn slice_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, axis: usize, start: usize, stop: usize) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("slice", "x", x, F => {
        let x = arr::<F>("slice", "x", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || sh::slice_fwd(xv, axis, start, stop))?.into_pyarray(py).into_any())
    })
}

/// Gradient of `slice_fwd`: g placed into zeros of `input_shape`.
#[pyfunction]
fn slice_bwd<'py>(py: Python<'py>, g: &Bound<'py, PyAny>, input_shape: Vec<usize>, axis: usize, start: usize) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("slice", "grad_output", g, F => {
        let g = arr::<F>("slice", "grad_output", g)?;
        let gv = g.as_array();
        Ok(run_kernel(py, || sh::slice_bwd(gv, &input_shape, axis, start))?.into_pyarray(py).into_any())
    })
}

/// (N, R, C) -> (N, C, R), contiguous.
#[pyfunction]
fn transpose_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("transpose", "x", x, F => {
        let x = arr::<F>("transpose", "x", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || sh::transpose_fwd(xv))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(cat_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(slice_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(slice_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(transpose_fwd, m)?)?;
    Ok(())
}
