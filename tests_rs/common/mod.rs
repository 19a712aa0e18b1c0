//! Shared test helpers: a seeded RNG, and the f64 finite-difference gradient check every `_bwd` must pass.
#![allow(dead_code)]

use ndarray::{ArrayD, IxDyn};

/// SplitMix64: small, seeded, dependency-free.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
    /// An array of the given shape, uniform in [lo, hi).
    pub fn array(&mut self, shape: &[usize], lo: f64, hi: f64) -> ArrayD<f64> {
        ArrayD::from_shape_simple_fn(IxDyn(shape), || self.uniform(lo, hi))
    }
}

/// <a, b> over all elements.
pub fn dot(a: &ArrayD<f64>, b: &ArrayD<f64>) -> f64 {
    a.iter().zip(b.iter()).map(|(x, y)| x * y).sum()
}

/// Central-difference check of an analytic gradient, torch.autograd.gradcheck style
/// (eps 1e-6, atol 1e-5, rtol 1e-3), on the scalar L(x) = <f(x), g> for a fixed random g.
///
/// `loss(x)` evaluates L at x; `grad` is the analytic dL/dx at `x`. Small inputs (<= 200 elements)
/// are checked coordinate by coordinate; larger ones along 6 random directions v:
/// <grad, v> against (L(x + eps v) - L(x - eps v)) / (2 eps).
pub fn gradcheck(name: &str, x: &ArrayD<f64>, grad: &ArrayD<f64>, loss: impl Fn(&ArrayD<f64>) -> f64) {
    let (eps, atol, rtol) = (1e-6, 1e-5, 1e-3);
    assert_eq!(x.shape(), grad.shape(), "{name}: gradient shape");
    let check = |analytic: f64, v: &ArrayD<f64>, what: &str| {
        let numeric = (loss(&(x + &(v * eps))) - loss(&(x - &(v * eps)))) / (2.0 * eps);
        assert!(
            (analytic - numeric).abs() <= atol + rtol * numeric.abs(),
            "{name}: {what}: analytic {analytic} vs numeric {numeric}"
        );
    };
    if x.len() <= 200 {
        for i in 0..x.len() {
            let mut v = ArrayD::<f64>::zeros(x.raw_dim());
            v.as_slice_mut().unwrap()[i] = 1.0;
            check(grad.as_slice().unwrap()[i], &v, &format!("coordinate {i}"));
        }
    } else {
        let mut rng = Rng::new(0xD1CE);
        for k in 0..6 {
            let v = rng.array(x.shape(), -1.0, 1.0);
            check(dot(grad, &v), &v, &format!("direction {k}"));
        }
    }
}

/// Max |a - b|.
pub fn max_abs_diff(a: &ArrayD<f64>, b: &ArrayD<f64>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    a.iter().zip(b.iter()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}
