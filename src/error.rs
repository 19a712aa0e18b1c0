//! The one error type of the crate. Every variant names the op; shape errors carry the shapes involved.
//! `src/python/errors.rs` maps each variant once to a Python exception (all `RuntimeError` subclasses).

/// A kernel's refusal of its input.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Ranks, sizes or broadcast rules do not fit.
    #[error("{op}: {msg} (got {})", fmt_shapes(.shapes))]
    Shape { op: &'static str, msg: String, shapes: Vec<(&'static str, Vec<usize>)> },
    /// A scalar argument is out of range (stride 0, negative padding, unknown mode, ...).
    #[error("{op}: {msg}")]
    Arg { op: &'static str, msg: String },
    /// The values themselves are unusable (NaN where it would silently corrupt indexing, ...).
    #[error("{op}: {msg}")]
    Value { op: &'static str, msg: String },
}

/// Result alias used by every kernel.
pub type Result<T> = std::result::Result<T, Error>;

fn fmt_shapes(shapes: &[(&'static str, Vec<usize>)]) -> String {
    shapes.iter().map(|(name, s)| format!("{name}={s:?}")).collect::<Vec<_>>().join(", ")
}

impl Error {
    /// A shape error naming the op, what is wrong, and every shape involved.
    pub fn shape(op: &'static str, msg: impl Into<String>, shapes: &[(&'static str, &[usize])]) -> Self {
        Error::Shape { op, msg: msg.into(), shapes: shapes.iter().map(|(n, s)| (*n, s.to_vec())).collect() }
    }
    /// An argument error.
    pub fn arg(op: &'static str, msg: impl Into<String>) -> Self {
        Error::Arg { op, msg: msg.into() }
    }
    /// A value error.
    pub fn value(op: &'static str, msg: impl Into<String>) -> Self {
        Error::Value { op, msg: msg.into() }
    }
}
