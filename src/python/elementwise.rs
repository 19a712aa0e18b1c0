//! Bindings of `ops::elementwise`.

use numpy::IntoPyArray;
use pyo3::prelude::*;

use super::convert::{arr, arr_mut, float_dispatch, run_kernel};
use crate::ops::elementwise::{self as ew, Binary};
use crate::Float;

/// out = a ∘ b for op in "add" | "sub" | "mul", with broadcasting.
#[pyfunction]
fn binary_fwd<'py>(py: Python<'py>, a: &Bound<'py, PyAny>, b: &Bound<'py, PyAny>, op: &str) -> PyResult<Bound<'py, PyAny>> {
    let op = Binary::parse(op)?;
    float_dispatch!(op.name(), "a", a, F => {
        let (a, b) = (arr::<F>(op.name(), "a", a)?, arr::<F>(op.name(), "b", b)?);
        let (av, bv) = (a.as_array(), b.as_array());
        Ok(run_kernel(py, || ew::binary_fwd(op, av, bv))?.into_pyarray(py).into_any())
    })
}

/// (grad_a, grad_b) of `binary_fwd`, each summed to its input's shape.
#[pyfunction]
fn binary_bwd<'py>(py: Python<'py>, a: &Bound<'py, PyAny>, b: &Bound<'py, PyAny>, g: &Bound<'py, PyAny>, op: &str) -> PyResult<Bound<'py, PyAny>> {
    let op = Binary::parse(op)?;
    float_dispatch!(op.name(), "a", a, F => {
        let (a, b, g) = (arr::<F>(op.name(), "a", a)?, arr::<F>(op.name(), "b", b)?, arr::<F>(op.name(), "grad_output", g)?);
        let (av, bv, gv) = (a.as_array(), b.as_array(), g.as_array());
        let grads = run_kernel(py, || ew::binary_bwd(op, av, bv, gv))?;
        Ok((grads.a.into_pyarray(py), grads.b.into_pyarray(py)).into_pyobject(py)?.into_any())
    })
}

/// alpha * x + beta.
#[pyfunction]
fn affine_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, alpha: f64, beta: f64) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("affine", "x", x, F => {
        let x = arr::<F>("affine", "x", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || ew::affine_fwd(xv, F::c(alpha), F::c(beta)))?.into_pyarray(py).into_any())
    })
}

/// a += b in place (same shape, same dtype; a writeable).
#[pyfunction]
fn add_<'py>(py: Python<'py>, a: &Bound<'py, PyAny>, b: &Bound<'py, PyAny>) -> PyResult<()> {
    float_dispatch!("add_", "a", a, F => {
        let b = arr::<F>("add_", "b", b)?;
        let mut a = arr_mut::<F>("add_", "a", a)?;
        let (av, bv) = (a.as_array_mut(), b.as_array());
        run_kernel(py, || ew::add_assign(av, bv))
    })
}

/// Sums g down to `shape` (a shape it was broadcast from).
#[pyfunction]
fn sum_to_shape<'py>(py: Python<'py>, g: &Bound<'py, PyAny>, shape: Vec<usize>) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("sum_to_shape", "grad", g, F => {
        let g = arr::<F>("sum_to_shape", "grad", g)?;
        let gv = g.as_array();
        Ok(run_kernel(py, || ew::sum_to_shape(gv, &shape))?.into_pyarray(py).into_any())
    })
}

/// Mean of x over `axes`.
#[pyfunction]
#[pyo3(signature = (x, axes, keepdim=false))]
fn mean_fwd<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, axes: Vec<usize>, keepdim: bool) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("mean", "x", x, F => {
        let x = arr::<F>("mean", "x", x)?;
        let xv = x.as_array();
        Ok(run_kernel(py, || ew::mean_fwd(xv, &axes, keepdim))?.into_pyarray(py).into_any())
    })
}

/// Gradient of `mean_fwd` w.r.t. x.
#[pyfunction]
fn mean_bwd<'py>(py: Python<'py>, g: &Bound<'py, PyAny>, input_shape: Vec<usize>, axes: Vec<usize>) -> PyResult<Bound<'py, PyAny>> {
    float_dispatch!("mean", "grad_output", g, F => {
        let g = arr::<F>("mean", "grad_output", g)?;
        let gv = g.as_array();
        Ok(run_kernel(py, || ew::mean_bwd(gv, &input_shape, &axes))?.into_pyarray(py).into_any())
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(binary_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(binary_bwd, m)?)?;
    m.add_function(wrap_pyfunction!(affine_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(add_, m)?)?;
    m.add_function(wrap_pyfunction!(sum_to_shape, m)?)?;
    m.add_function(wrap_pyfunction!(mean_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(mean_bwd, m)?)?;
    Ok(())
}
