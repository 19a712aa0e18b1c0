//! Bindings of `gemm`: the benchmark's handle on the GEMM (`gemm_fwd`), the CPU it runs on, the
//! ISA path and plan it takes, and the measured FMA peak.

use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{arr, float_dispatch, run_kernel};
use crate::gemm::{cpu_info, fma_peak_gflops as peak, Isa, Plan};
use crate::Error;

/// a · b through mipnet's GEMM (`matmul_par`), for benchmarking it.
///
/// Args:
///     a: (m, k) float32/float64 array.
///     b: (k, n), same dtype.
/// Returns:
///     (m, n) product.
#[pyfunction]
fn gemm_fwd<'py>(py: Python<'py>, a: &Bound<'py, PyAny>, b: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    const GEMM: &str = "gemm";
    float_dispatch!(GEMM, "a", a, F => {
        let (a, b) = (arr::<F>(GEMM, "a", a)?, arr::<F>(GEMM, "b", b)?);
        let (av, bv) = (a.as_array(), b.as_array());
        let c = run_kernel(py, || {
            let (a2, b2) = (crate::tensor::fixed::<_, numpy::ndarray::Ix2>(GEMM, "a", av)?,
                            crate::tensor::fixed::<_, numpy::ndarray::Ix2>(GEMM, "b", bv)?);
            if a2.ncols() != b2.nrows() {
                return Err(Error::shape(GEMM, "a.shape[1] must equal b.shape[0]", &[("a", a2.shape()), ("b", b2.shape())]));
            }
            // C = A · B
            crate::gemm::matmul_par(GEMM, a2, b2)
        })?;
        Ok(c.into_pyarray(py).into_any())
    })
}

/// The path named `isa`, or the selected one for None (ArgumentError for a bad `MIPNET_ISA`).
fn isa_arg(isa: Option<&str>) -> PyResult<Isa> {
    match isa {
        None => Ok(Isa::from_env()?),
        Some(name) => Isa::parse(name).map_err(|e| Error::arg("isa", e).into()),
    }
}

/// The CPU and the GEMM path mipnet uses on it.
///
/// Returns:
///     dict with "model", "vendor", "l1d", "l2", "l3" (bytes), "cache_source" ("cpuid", "sysfs"
///     or "default"), "isa" (the selected path), "isa_detected" (the widest this CPU has),
///     "isa_supported" (list), "vector_bits" and "plan" (micro-tile and block sizes, f32).
#[pyfunction]
fn cpu_info_dict(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let isa = Isa::from_env()?;
    let cpu = cpu_info();
    let d = PyDict::new(py);
    d.set_item("model", &cpu.model)?;
    d.set_item("vendor", &cpu.vendor)?;
    d.set_item("l1d", cpu.l1d)?;
    d.set_item("l2", cpu.l2)?;
    d.set_item("l3", cpu.l3)?;
    d.set_item("cache_source", cpu.cache_source)?;
    d.set_item("isa", isa.name())?;
    d.set_item("isa_detected", Isa::detected().name())?;
    d.set_item("isa_supported", Isa::ALL.into_iter().filter(|i| i.supported()).map(Isa::name).collect::<Vec<_>>())?;
    d.set_item("vector_bits", isa.vector_bits())?;
    d.set_item("plan", Plan::<f32>::selected().describe())?;
    Ok(d)
}

/// The measured f32 FMA throughput of `threads` threads running at once, GFLOP/s (about 0.15 s).
///
/// Args:
///     threads: threads running the FMA loop together (>= 1); 1 gives the peak of one core.
///     isa: "avx512", "avx2" or "generic"; None: the selected path.
#[pyfunction]
#[pyo3(signature = (threads=1, isa=None))]
fn fma_peak_gflops(py: Python<'_>, threads: usize, isa: Option<&str>) -> PyResult<f64> {
    let isa = isa_arg(isa)?;
    Ok(py.detach(|| peak(threads, isa))?)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(gemm_fwd, m)?)?;
    m.add_function(wrap_pyfunction!(fma_peak_gflops, m)?)?;
    m.add("cpu_info", wrap_pyfunction!(cpu_info_dict, m)?)?;
    Ok(())
}
