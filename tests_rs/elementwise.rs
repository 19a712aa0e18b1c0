//! Broadcasting arithmetic, sum-to-shape and means: f64 gradchecks of every backward, closed forms, errors.
mod common;

use _core::ops::elementwise::{add_assign, affine_fwd, binary_bwd, binary_fwd, mean_bwd, mean_fwd, sum_to_shape, Binary};
use common::{dot, gradcheck, Rng};

#[test]
fn binary_bwd_gradcheck_f64_with_broadcasting_on_both_sides() {
    let mut rng = Rng::new(7);
    // (2,3,4,5) with (1,3,1,1) as MS-CAM's L + G, and (3,1,5) against (2,1,4,1) broadcasting both ways
    for (sa, sb) in [(vec![2, 3, 4, 5], vec![1, 3, 1, 1]), (vec![3, 1, 5], vec![2, 1, 4, 1]), (vec![2, 3], vec![2, 3])] {
        let (a, b) = (rng.array(&sa, -2.0, 2.0), rng.array(&sb, -2.0, 2.0));
        let out_shape = binary_fwd(Binary::Add, a.view(), b.view()).unwrap().shape().to_vec();
        let g = rng.array(&out_shape, -1.0, 1.0);
        for op in [Binary::Add, Binary::Sub, Binary::Mul] {
            let grads = binary_bwd(op, a.view(), b.view(), g.view()).unwrap();
            assert_eq!(grads.a.shape(), a.shape());
            assert_eq!(grads.b.shape(), b.shape());
            gradcheck(op.name(), &a, &grads.a, |ap| dot(&binary_fwd(op, ap.view(), b.view()).unwrap(), &g));
            gradcheck(op.name(), &b, &grads.b, |bp| dot(&binary_fwd(op, a.view(), bp.view()).unwrap(), &g));
        }
    }
}

#[test]
fn same_shape_fast_path_equals_the_elementwise_definition_on_large_and_strided_inputs() {
    let mut rng = Rng::new(11);
    // 200,000 elements: several parallel chunks of the contiguous path
    let (a, b) = (rng.array(&[2, 4, 100, 250], -2.0, 2.0), rng.array(&[2, 4, 100, 250], -2.0, 2.0));
    let bt = b.view().reversed_axes().to_owned();
    for op in [Binary::Add, Binary::Sub, Binary::Mul] {
        let f = |x: f64, y: f64| match op { Binary::Add => x + y, Binary::Sub => x - y, Binary::Mul => x * y };
        let out = binary_fwd(op, a.view(), b.view()).unwrap();
        assert!(out.iter().zip(a.iter().zip(b.iter())).all(|(&o, (&x, &y))| o == f(x, y)), "{}", op.name());
        // a transposed (non-standard-layout) operand takes the broadcasting path: the same values
        let at = a.view().reversed_axes();
        let strided = binary_fwd(op, at.clone(), bt.view()).unwrap();
        assert!(strided.iter().zip(at.iter().zip(bt.iter())).all(|(&o, (&x, &y))| o == f(x, y)), "{} strided", op.name());
    }
}

#[test]
fn add_assign_adds_in_place_and_refuses_other_shapes() {
    let mut rng = Rng::new(12);
    let (a, b) = (rng.array(&[3, 70_000], -1.0, 1.0), rng.array(&[3, 70_000], -1.0, 1.0));
    let mut sum = a.clone();
    add_assign(sum.view_mut(), b.view()).unwrap();
    assert!(sum.iter().zip(a.iter().zip(b.iter())).all(|(&s, (&x, &y))| s == x + y));
    // a strided destination takes the element-wise path
    let mut t = a.clone();
    add_assign(t.view_mut().reversed_axes(), b.view().reversed_axes()).unwrap();
    assert_eq!(t, sum);
    let err = add_assign(sum.view_mut(), rng.array(&[3, 7], -1.0, 1.0).view()).unwrap_err().to_string();
    assert!(err.contains("add_") && err.contains("[3, 70000]") && err.contains("[3, 7]"), "{err}");
}

#[test]
fn affine_backward_is_affine_with_zero_shift_gradcheck_f64() {
    let mut rng = Rng::new(8);
    let x = rng.array(&[3, 4], -1.0, 1.0);
    let g = rng.array(&[3, 4], -1.0, 1.0);
    // d(alpha x + beta)/dx = alpha
    let dx = affine_fwd(g.view(), -2.5, 0.0).unwrap();
    gradcheck("affine", &x, &dx, |xp| dot(&affine_fwd(xp.view(), -2.5, 0.75).unwrap(), &g));
}

#[test]
fn mean_bwd_gradcheck_f64_for_spatial_and_channel_means() {
    let mut rng = Rng::new(9);
    let x = rng.array(&[2, 3, 4, 5], -1.0, 1.0);
    for (axes, keepdim) in [(vec![2, 3], true), (vec![1], false), (vec![0, 1, 2, 3], false)] {
        let y = mean_fwd(x.view(), &axes, keepdim).unwrap();
        let g = rng.array(y.shape(), -1.0, 1.0);
        let dx = mean_bwd(g.view(), x.shape(), &axes).unwrap();
        gradcheck("mean", &x, &dx, |xp| dot(&mean_fwd(xp.view(), &axes, keepdim).unwrap(), &g));
    }
}

#[test]
fn sum_to_shape_sums_leading_and_size_one_axes() {
    let g = ndarray::Array::from_shape_fn((2, 3, 2), |(i, j, k)| (i * 6 + j * 2 + k) as f64).into_dyn();
    let s = sum_to_shape(g.view(), &[3, 1]).unwrap();
    // s[j, 0] = Σ_{i,k} g[i, j, k]
    for j in 0..3 {
        let expected: f64 = (0..2).flat_map(|i| (0..2).map(move |k| (i * 6 + j * 2 + k) as f64)).sum();
        assert_eq!(s[[j, 0]], expected);
    }
    assert_eq!(s.shape(), &[3, 1]);
}

#[test]
fn elementwise_errors_name_op_and_shapes() {
    let a = ndarray::ArrayD::<f32>::zeros(ndarray::IxDyn(&[2, 3]));
    let b = ndarray::ArrayD::<f32>::zeros(ndarray::IxDyn(&[4, 3]));
    let err = binary_fwd(Binary::Mul, a.view(), b.view()).unwrap_err().to_string();
    assert!(err.contains("mul") && err.contains("[2, 3]") && err.contains("[4, 3]"), "{err}");
    let err = sum_to_shape(a.view(), &[5]).unwrap_err().to_string();
    assert!(err.contains("sum_to_shape"), "{err}");
    let err = mean_fwd(a.view(), &[2], false).unwrap_err().to_string();
    assert!(err.contains("mean") && err.contains("axis 2"), "{err}");
}
