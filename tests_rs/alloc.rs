//! The large-block cache of the crate's allocator: reuse of a freed block, zeroing of a reused one.
use _core as _;

#[test]
fn a_freed_large_block_is_reused_and_zeroed_when_asked() {
    let n = 3 << 20; // 12 MB of f32
    let mut a = vec![0f32; n];
    a.iter_mut().for_each(|v| *v = 7.0);
    let p = a.as_ptr() as usize;
    drop(a);
    let b = vec![0f32; n];
    assert_eq!(b.as_ptr() as usize, p, "same size class: the cached block comes back");
    assert!(b.iter().all(|&v| v == 0.0), "alloc_zeroed zeroes a reused block");
    let c = vec![1f32; n - 1000]; // another block of the same class while b is alive
    assert_ne!(c.as_ptr() as usize, p);
    assert!(c.iter().all(|&v| v == 1.0));
}
