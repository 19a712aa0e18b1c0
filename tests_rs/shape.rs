//! cat and slice: f64 gradchecks of the slice backward (cat's backward is slicing), values, errors.
mod common;

use _core::ops::shape::{cat_fwd, slice_bwd, slice_fwd, transpose_fwd};
use common::{dot, gradcheck, Rng};

#[test]
fn slice_bwd_gradcheck_f64_on_channel_and_spatial_axes() {
    let mut rng = Rng::new(11);
    let x = rng.array(&[2, 5, 4, 3], -1.0, 1.0);
    for (axis, start, stop) in [(1, 1, 4), (2, 0, 2), (3, 2, 3)] {
        let y = slice_fwd(x.view(), axis, start, stop).unwrap();
        let g = rng.array(y.shape(), -1.0, 1.0);
        let dx = slice_bwd(g.view(), x.shape(), axis, start).unwrap();
        gradcheck("slice", &x, &dx, |xp| dot(&slice_fwd(xp.view(), axis, start, stop).unwrap(), &g));
    }
}

#[test]
fn cat_then_slices_give_back_the_pieces() {
    let mut rng = Rng::new(12);
    let (a, b) = (rng.array(&[2, 3, 4], -1.0, 1.0), rng.array(&[2, 5, 4], -1.0, 1.0));
    let c = cat_fwd(&[a.view(), b.view()], 1, &[]).unwrap();
    assert_eq!(c.shape(), &[2, 8, 4]);
    // the gradient of cat w.r.t. each piece is the matching slice of the upstream gradient
    assert_eq!(slice_fwd(c.view(), 1, 0, 3).unwrap(), a);
    assert_eq!(slice_fwd(c.view(), 1, 3, 8).unwrap(), b);
}

#[test]
fn cat_with_relu_flags_rectifies_only_the_flagged_pieces() {
    let mut rng = Rng::new(13);
    let (a, b) = (rng.array(&[2, 3, 4], -1.0, 1.0), rng.array(&[2, 5, 4], -1.0, 1.0));
    let c = cat_fwd(&[a.view(), b.view()], 1, &[false, true]).unwrap();
    assert_eq!(slice_fwd(c.view(), 1, 0, 3).unwrap(), a);
    assert_eq!(slice_fwd(c.view(), 1, 3, 8).unwrap(), b.mapv(|v| v.max(0.0)));
    let err = cat_fwd(&[a.view(), b.view()], 1, &[true]).unwrap_err().to_string();
    assert!(err.contains("cat") && err.contains("1 flags for 2 tensors"), "{err}");
}

#[test]
fn transpose_swaps_the_last_two_axes_of_every_image() {
    // 70 x 33: several bands of 16 output rows and blocks of 64 source rows, with remainders
    let x = ndarray::Array::from_shape_fn((3, 70, 33), |(n, r, c)| (n * 10_000 + r * 100 + c) as f32).into_dyn();
    let t = transpose_fwd(x.view()).unwrap();
    assert_eq!(t.shape(), &[3, 33, 70]);
    // out[n, c, r] = x[n, r, c]
    assert!(t.indexed_iter().all(|(i, &v)| v == x[[i[0], i[2], i[1]]]));
    let back = transpose_fwd(t.view()).unwrap();
    assert_eq!(back, x);
    let err = transpose_fwd(x.view().into_shape_with_order(vec![3, 70, 33, 1]).unwrap()).unwrap_err().to_string();
    assert!(err.contains("transpose") && err.contains("[3, 70, 33, 1]"), "{err}");
}

#[test]
fn shape_errors_name_op_and_shapes() {
    let a = ndarray::ArrayD::<f32>::zeros(ndarray::IxDyn(&[2, 3, 4]));
    let b = ndarray::ArrayD::<f32>::zeros(ndarray::IxDyn(&[2, 3, 5]));
    let err = cat_fwd(&[a.view(), b.view()], 1, &[]).unwrap_err().to_string();
    assert!(err.contains("cat") && err.contains("[2, 3, 5]"), "{err}");
    let err = slice_fwd(a.view(), 1, 2, 9).unwrap_err().to_string();
    assert!(err.contains("slice") && err.contains("[2, 3, 4]"), "{err}");
    let err = slice_bwd(a.view(), &[2, 3, 4], 1, 1).unwrap_err().to_string();
    assert!(err.contains("slice"), "{err}");
}
