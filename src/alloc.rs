//! The allocator of every Rust-side buffer: the system allocator, with each large block advised to be
//! backed by transparent huge pages (Linux `MADV_HUGEPAGE`).
//!
//! A fresh multi-MB block is a new mapping, and touching it in 4 KiB pages costs one page fault per
//! page: on the virtual machines mipnet was profiled on, 10-20 µs each, so a 35 MB `cat` output took
//! 80 ms to fault in while its copy took 5 ms, and a training step (whose saved activations keep every
//! output fresh) spent a quarter of its time in page faults. With 2 MiB pages the faults are 512x fewer.
//! numpy advises its own large arrays the same way.

use std::alloc::{GlobalAlloc, Layout, System};

/// Blocks from this size on are advised.
const HUGE_MIN: usize = 4 << 20;

/// [`System`], advising large blocks to use huge pages.
pub struct HugePageAlloc;

// SAFETY: every call forwards to `System` with the same arguments; the advice only changes the
// paging policy of memory inside the block just returned.
unsafe impl GlobalAlloc for HugePageAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded contract of `GlobalAlloc::alloc`.
        let p = unsafe { System.alloc(layout) };
        advise_huge_pages(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded contract of `GlobalAlloc::alloc_zeroed`.
        let p = unsafe { System.alloc_zeroed(layout) };
        advise_huge_pages(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded contract of `GlobalAlloc::dealloc`.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded contract of `GlobalAlloc::realloc`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        advise_huge_pages(p, new_size);
        p
    }
}

/// Advises the kernel to back `[ptr, ptr + bytes)` with huge pages (only the whole pages inside; a no-op
/// for null, for blocks under `HUGE_MIN` and off Linux; failure is harmless).
pub fn advise_huge_pages(ptr: *mut u8, bytes: usize) {
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        const MADV_HUGEPAGE: std::ffi::c_int = 14;
        extern "C" {
            fn madvise(addr: *mut std::ffi::c_void, len: usize, advice: std::ffi::c_int) -> std::ffi::c_int;
        }
        if ptr.is_null() || bytes < HUGE_MIN {
            return;
        }
        // the whole 4 KiB pages inside the block: [round up(ptr), round down(ptr + bytes))
        let start = (ptr as usize).next_multiple_of(PAGE);
        let end = (ptr as usize + bytes) & !(PAGE - 1);
        if end > start {
            // SAFETY: the range lies inside a live allocation; madvise only changes paging policy.
            unsafe { madvise(start as *mut std::ffi::c_void, end - start, MADV_HUGEPAGE) };
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (ptr, bytes);
}
