//! Crossing the boundary: dtype dispatch, zero-copy array views, and the one GIL-releasing helper.

use numpy::{Element, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyReadwriteArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::errors::{ArgumentError, DTypeError};
use crate::Result;

/// The float type of an input array, decided by the first tensor argument of a call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    F32,
    F64,
}

/// The dtype of `obj`, or a `DTypeError` naming the op and the argument.
pub fn dtype_of(op: &str, name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Dtype> {
    if obj.cast::<PyArrayDyn<f32>>().is_ok() {
        Ok(Dtype::F32)
    } else if obj.cast::<PyArrayDyn<f64>>().is_ok() {
        Ok(Dtype::F64)
    } else {
        Err(DTypeError::new_err(format!(
            "{op}: {name} must be a float32 or float64 numpy array, got {}",
            describe(obj)
        )))
    }
}

fn describe(obj: &Bound<'_, PyAny>) -> String {
    match obj.cast::<numpy::PyUntypedArray>() {
        Ok(a) => format!("dtype {} with shape {:?}", a.dtype(), a.shape()),
        Err(_) => obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into()),
    }
}

/// A read-only, zero-copy view of `obj` as an array of `F`, or a `DTypeError` naming op and argument.
pub fn arr<'py, F: Element + crate::Float>(op: &str, name: &str, obj: &Bound<'py, PyAny>) -> PyResult<PyReadonlyArrayDyn<'py, F>> {
    match obj.cast::<PyArrayDyn<F>>() {
        Ok(a) => Ok(a.readonly()),
        Err(_) => Err(DTypeError::new_err(format!(
            "{op}: {name} must be a {} numpy array like the other inputs, got {}",
            F::NAME,
            describe(obj)
        ))),
    }
}

/// A writeable, zero-copy view of `obj` as an array of `F`: a `DTypeError` for another dtype, an
/// `ArgumentError` for a read-only array or one already borrowed (e.g. the same array passed twice).
pub fn arr_mut<'py, F: Element + crate::Float>(op: &str, name: &str, obj: &Bound<'py, PyAny>) -> PyResult<PyReadwriteArrayDyn<'py, F>> {
    let a = obj.cast::<PyArrayDyn<F>>().map_err(|_| {
        DTypeError::new_err(format!("{op}: {name} must be a {} numpy array like the other inputs, got {}", F::NAME, describe(obj)))
    })?;
    a.try_readwrite().map_err(|e| ArgumentError::new_err(format!("{op}: {name} must be a writeable array not passed twice ({e})")))
}

/// Runs a kernel with the GIL released, inside mipnet's thread pool, mapping its error once.
/// A bad `MIPNET_ISA` refuses every kernel (ArgumentError) before it runs, so that a forced ISA
/// never silently falls back to another.
/// Invariant: no numpy buffer borrowed by `f` is mutated by Python while it runs (the borrows
/// held by the caller make numpy refuse writes through other references).
pub fn run_kernel<T: Send>(py: Python<'_>, f: impl FnOnce() -> Result<T> + Send) -> PyResult<T> {
    crate::Isa::from_env()?;
    py.detach(|| crate::parallel::install(f)).map_err(Into::into)
}

/// Dispatches a body on the dtype of a first array argument, binding the type name `$F` to
/// `f32` or `f64` inside the body: `float_dispatch!(op, x, F => { ... })`.
macro_rules! float_dispatch {
    ($op:expr, $name:expr, $first:expr, $F:ident => $body:block) => {
        match $crate::python::convert::dtype_of($op, $name, $first)? {
            $crate::python::convert::Dtype::F32 => {
                type $F = f32;
                $body
            }
            $crate::python::convert::Dtype::F64 => {
                type $F = f64;
                $body
            }
        }
    };
}
pub(crate) use float_dispatch;
