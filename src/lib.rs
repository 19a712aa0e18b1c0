//! mipnet's compiled core: stateless, validated forward/backward kernel pairs for every op of MIPNet.
//!
//! The crate owns no autograd graph. Each op family lives in one file under [`ops`] and exposes
//! `<op>_fwd` / `<op>_bwd` side by side; the Python package records the tape and calls these pairs.
//! All kernels are generic over [`Float`] (f32 for use, f64 for finite-difference gradient checks),
//! return [`Result`] on bad input (never panic on user data) and parallelise with rayon over disjoint
//! output planes, so results are deterministic.

pub mod alloc;
pub mod error;
pub mod float;
pub mod gemm;
pub mod isa;
pub mod ops;
pub mod parallel;
pub mod tensor;

#[cfg(feature = "python")]
mod python;

pub use error::{Error, Result};
pub use isa::{Isa, ISA_ENV};

#[global_allocator]
static GLOBAL: alloc::HugePageAlloc = alloc::HugePageAlloc;
pub use float::Float;
