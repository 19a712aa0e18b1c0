//! The large-block cache of the crate's allocator: reuse of a freed block (of its class or a smaller one), zeroing of a reused one.
use _core as _;
use std::sync::Mutex;

/// The cache is shared by the process: the tests take turns so that one cannot take the other's block.
static TURN: Mutex<()> = Mutex::new(());

#[test]
fn a_freed_large_block_is_reused_and_zeroed_when_asked() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
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

#[test]
fn a_smaller_request_takes_a_larger_cached_block_which_comes_back_with_its_own_size() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    // 20 MiB of f32 (class 25.4 MB) and 16 MiB minus a little (class 20.3 MB: the class below)
    let (big, small) = (5 << 20, (4 << 20) - 1000);
    let a = vec![1f32; big];
    let p = a.as_ptr() as usize;
    drop(a);
    let b = vec![2f32; small];
    assert_eq!(b.as_ptr() as usize, p, "no block of the smaller class cached: the larger one serves");
    assert!(b.iter().all(|&v| v == 2.0));
    drop(b);
    let c = vec![0f32; big];
    assert_eq!(c.as_ptr() as usize, p, "cached again with its own size, so the larger request fits");
    assert!(c.iter().all(|&v| v == 0.0), "alloc_zeroed zeroes the whole reused block");
}
