//! The element types kernels run on: f32 (production) and f64 (gradient checks, float64 models).

use crate::gemm::{Kernels, Plan};
use std::fmt::Debug;
use std::iter::Sum;
use std::ops::{AddAssign, DivAssign, MulAssign, SubAssign};

/// A float type every kernel is generic over. `gemm_kernels` is the single place that picks the
/// GEMM micro-kernels for the type.
pub trait Float:
    num_traits::Float
    + num_traits::FromPrimitive
    + ndarray::LinalgScalar
    + ndarray::ScalarOperand
    + Send
    + Sync
    + Debug
    + Default
    + Sum
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
    + 'static
{
    /// "float32" or "float64", as numpy and torch name it.
    const NAME: &'static str;

    /// Converts an f64 constant (a literal in a formula) to this type.
    fn c(v: f64) -> Self {
        <Self as num_traits::FromPrimitive>::from_f64(v).expect("finite constant")
    }

    /// The GEMM's micro-kernels and plans for this type (see `gemm::Plan`).
    fn gemm_kernels() -> &'static Kernels<Self>;
    /// The plan of bfloat16 products for this type, where the CPU has one ([`Plan::bf16`]: f32 only).
    fn bf16_plan() -> Option<&'static Plan<Self>> {
        None
    }
}

impl Float for f32 {
    const NAME: &'static str = "float32";
    fn gemm_kernels() -> &'static Kernels<f32> {
        static K: Kernels<f32> = Kernels::new(crate::gemm::ukernel::<f32>);
        &K
    }
    fn bf16_plan() -> Option<&'static Plan<f32>> {
        Plan::<f32>::bf16()
    }
}

impl Float for f64 {
    const NAME: &'static str = "float64";
    fn gemm_kernels() -> &'static Kernels<f64> {
        static K: Kernels<f64> = Kernels::new(crate::gemm::ukernel::<f64>);
        &K
    }
}
