//! GEMM: both f32 paths (mipnet's AVX-512 kernel where the CPU has it, matrixmultiply everywhere
//! else) agree with an f64 product, for plain and transposed (stride-swapped) operands.
mod common;

use _core::gemm::gemm;
use _core::Float;
use common::Rng;
use ndarray::{Array2, ShapeBuilder};

fn random(rng: &mut Rng, r: usize, c: usize) -> Array2<f32> {
    Array2::from_shape_simple_fn((r, c), || rng.uniform(-1.0, 1.0) as f32)
}

/// C = A·B computed in f64 from the f32 inputs.
fn reference(a: &Array2<f32>, b: &Array2<f32>) -> Array2<f64> {
    a.mapv(f64::from).dot(&b.mapv(f64::from))
}

fn assert_close(c: &Array2<f32>, expected: &Array2<f64>, k: usize, what: &str) {
    // f32 accumulation over k terms of magnitude <= 1: error grows like sqrt(k) * eps
    let tol = 1e-6 * (k as f64).sqrt() * 8.0;
    for (x, y) in c.iter().zip(expected.iter()) {
        assert!((f64::from(*x) - y).abs() <= tol, "{what}: {x} vs {y}");
    }
}

#[test]
fn gemm_f32_dispatch_and_matrixmultiply_fallback_match_f64_product() {
    let mut rng = Rng::new(3);
    // sizes above and below the own-kernel threshold, with edge remainders
    for &(m, k, n) in &[(7, 5, 3), (64, 147, 200), (128, 1152, 515), (33, 352, 97)] {
        let a = random(&mut rng, m, k);
        let b_t = random(&mut rng, n, k); // B given transposed: a stride swap, no copy
        let b = b_t.t();
        let expected = reference(&a, &b.to_owned());
        let mut c = Array2::<f32>::zeros((m, n));
        gemm(1.0, a.view(), b, 0.0, c.view_mut());
        assert_close(&c, &expected, k, &format!("dispatch {m}x{k}x{n}"));
        // the portable path the dispatch takes on CPUs without AVX-512 (column-major C this time)
        let mut c2 = Array2::<f32>::zeros((m, n).f());
        let (sa, sb, sc) = (a.strides().to_vec(), b.strides().to_vec(), c2.strides().to_vec());
        // SAFETY: the views own valid memory of the shapes passed; c2 is unique.
        unsafe {
            f32::gemm_raw(m, k, n, 1.0, a.as_ptr(), sa[0], sa[1], b.as_ptr(), sb[0], sb[1], 0.0,
                          c2.as_mut_ptr(), sc[0], sc[1]);
        }
        assert_close(&c2, &expected, k, &format!("matrixmultiply {m}x{k}x{n}"));
    }
}
