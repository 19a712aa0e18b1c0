//! The single mapping of [`crate::Error`] to Python exceptions. All derive from `RuntimeError`,
//! as torch's shape errors do, so `except RuntimeError` catches them.

use pyo3::create_exception;
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

use crate::Error;

create_exception!(_core, MipnetError, PyRuntimeError, "Base class of every error mipnet raises for bad input.");
create_exception!(_core, ShapeError, MipnetError, "Ranks or sizes of the inputs do not fit the op.");
create_exception!(_core, ArgumentError, MipnetError, "A scalar argument (stride, padding, mode, ...) is invalid.");
create_exception!(_core, DTypeError, MipnetError, "An input is not float32 / float64, or dtypes are mixed.");
create_exception!(_core, ValueError_, MipnetError, "The input values are unusable (NaN where it matters, ...).");

impl From<Error> for PyErr {
    fn from(e: Error) -> PyErr {
        let msg = e.to_string();
        match e {
            Error::Shape { .. } => ShapeError::new_err(msg),
            Error::Arg { .. } => ArgumentError::new_err(msg),
            Error::Value { .. } => ValueError_::new_err(msg),
        }
    }
}

/// Adds the exception classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("MipnetError", py.get_type::<MipnetError>())?;
    m.add("ShapeError", py.get_type::<ShapeError>())?;
    m.add("ArgumentError", py.get_type::<ArgumentError>())?;
    m.add("DTypeError", py.get_type::<DTypeError>())?;
    m.add("InvalidValueError", py.get_type::<ValueError_>())?;
    Ok(())
}
