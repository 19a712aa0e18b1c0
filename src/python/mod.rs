//! The `mipnet._core` extension module: one binding file per op family, each with `register`.

use pyo3::prelude::*;

mod act;
mod conv;
mod convert;
mod corr;
mod elementwise;
mod errors;
mod gemm;
mod gate;
mod gru;
mod loss;
mod norm;
mod pad;
mod pool;
mod sample;
mod shape;
mod softmax;
mod upsample;

/// Sets the number of threads mipnet's kernels use (>= 1).
#[pyfunction]
fn set_num_threads(n: usize) -> PyResult<()> {
    Ok(crate::parallel::set_num_threads(n)?)
}

/// The number of threads mipnet's kernels use.
#[pyfunction]
fn get_num_threads() -> usize {
    crate::parallel::num_threads()
}

/// The instruction set every kernel runs on: "avx512", "avx2" or "generic" (`MIPNET_ISA` lowers
/// it). Raises ArgumentError for a bad `MIPNET_ISA`, as every kernel call does.
#[pyfunction]
fn simd_isa() -> PyResult<&'static str> {
    Ok(crate::Isa::from_env()?.name())
}

/// Whether convolutions can take bfloat16 products here: AVX512_BF16 dot products on the AVX-512 path
/// (`MIPNET_ISA` unset or avx512). Raises ArgumentError for a bad `MIPNET_ISA`.
#[pyfunction]
fn bf16_supported() -> PyResult<bool> {
    crate::Isa::from_env()?;
    Ok(crate::gemm::Plan::<f32>::bf16().is_some())
}

/// Called by `os.register_at_fork(after_in_child=...)`: the child rebuilds the pool on first use.
#[pyfunction]
fn _reset_after_fork() {
    crate::parallel::reset_after_fork()
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(set_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(get_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(_reset_after_fork, m)?)?;
    m.add_function(wrap_pyfunction!(simd_isa, m)?)?;
    m.add_function(wrap_pyfunction!(bf16_supported, m)?)?;
    errors::register(m)?;
    act::register(m)?;
    conv::register(m)?;
    corr::register(m)?;
    elementwise::register(m)?;
    gemm::register(m)?;
    gate::register(m)?;
    gru::register(m)?;
    loss::register(m)?;
    norm::register(m)?;
    pad::register(m)?;
    pool::register(m)?;
    sample::register(m)?;
    shape::register(m)?;
    softmax::register(m)?;
    upsample::register(m)?;
    Ok(())
}
