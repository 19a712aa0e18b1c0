//! The allocator of every Rust-side buffer: the system allocator, plus a cache of large blocks.
//!
//! A fresh multi-MB block is a new mapping, and touching it costs one page fault per 4 KiB page. On
//! the virtual machines mipnet was profiled on that is 10-20 µs a page: a 35 MB `cat` output took
//! 80 ms to fault in while its copy took 5 ms, and freeing it again (`munmap`) flushes the TLBs of
//! every core. MIPNet allocates the same sizes over and over (every sub-update of a level has the same
//! shapes, every training step the same activations and gradients), so freed large blocks are kept,
//! already mapped, and handed out again for a request of the same size class (classes 25% apart, see
//! [`class`]), or of a class up to `REUSE_LARGER` smaller when none of its own is cached (the
//! activations of one phase of a step are freed as blocks of other sizes than the next phase asks for).
//!
//! The cache never raises the peak: the large bytes in use plus the bytes cached stay within the
//! most large bytes ever in use at once (or `CACHE_FLOOR`, whichever is more), so a training step's
//! backward, which frees activations while it allocates gradients, keeps them mapped for the next
//! step's forward instead of unmapping and faulting them in again (at 192x384 batch 2 that was
//! 100,000 page faults and a second of system time a step). A block not reused within `CACHE_AGE`
//! large allocations is freed, so sizes nobody asks for any more (another image size) do not stay
//! mapped. Large blocks are also advised to be backed by transparent huge pages (Linux
//! `MADV_HUGEPAGE`), as numpy does.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;

/// Blocks from this size on are advised and cached.
const HUGE_MIN: usize = 4 << 20;
/// Bytes in use plus cached allowed even below the high-water mark of bytes in use.
const CACHE_FLOOR: usize = 512 << 20;
/// Large allocations after which an unused cached block is freed (a sub-update of MIPNet makes
/// about 40 to 80, a training step at 192x384 some thousands).
const CACHE_AGE: u64 = 8192;
/// Most blocks the cache holds.
const CACHE_SLOTS: usize = 256;
/// Alignment of every cached block (malloc's own for large blocks).
const ALIGN: usize = 16;
/// A request with no cached block of its class takes the smallest cached block up to this factor
/// larger (num, den), rather than mapping and faulting in a fresh one.
const REUSE_LARGER: (usize, usize) = (8, 5);
/// Most blocks out at once that are larger than the class they were handed out for.
const LARGER_SLOTS: usize = 128;

/// Cached blocks: (bytes, address, tick when cached); address 0 marks a free slot. `tick` counts
/// large allocations; `live` is the large bytes handed out and not freed, `high` its maximum so far;
/// `larger` holds (address, bytes) of the blocks out for a smaller class than their own (0: free).
struct Cache {
    slots: [(usize, usize, u64); CACHE_SLOTS],
    larger: [(usize, usize); LARGER_SLOTS],
    bytes: usize,
    tick: u64,
    live: usize,
    high: usize,
}

static CACHE: Mutex<Cache> = Mutex::new(Cache {
    slots: [(0, 0, 0); CACHE_SLOTS],
    larger: [(0, 0); LARGER_SLOTS],
    bytes: 0,
    tick: 0,
    live: 0,
    high: 0,
});

/// Blocks the cache gave up, to free once its lock is released.
type Freed = [(usize, *mut u8); CACHE_SLOTS + 1];

/// Bytes reserved for a large request of `size`: the smallest class c_k >= size, with c_0 = HUGE_MIN
/// and c_{k+1} = c_k · 5/4 rounded up to 64 KiB, so that near sizes share blocks. A block only
/// becomes resident where it is written, so the unused tail of a class costs address space only.
fn class(size: usize) -> usize {
    let mut c = HUGE_MIN;
    while c < size {
        c = (c + c / 4).next_multiple_of(64 << 10);
    }
    c
}

impl Cache {
    /// Counts one large allocation of `bytes` (a class size) as in use; a cached block of exactly
    /// that size, else the smallest one up to `REUSE_LARGER` times larger (then counted with its own
    /// size and remembered in `larger`), removed from the cache; and the blocks that aged out, to free.
    fn take(&mut self, bytes: usize) -> (Option<*mut u8>, Freed) {
        self.tick += 1;
        let cached = |i: usize| self.slots[i].1 != 0;
        let exact = (0..CACHE_SLOTS).find(|&i| cached(i) && self.slots[i].0 == bytes);
        let free_larger = self.larger.iter().position(|l| l.0 == 0);
        let larger = || {
            // bytes < size <= bytes · REUSE_LARGER
            let fits = |i: usize| cached(i) && self.slots[i].0 > bytes && self.slots[i].0 * REUSE_LARGER.1 <= bytes * REUSE_LARGER.0;
            free_larger.and((0..CACHE_SLOTS).filter(|&i| fits(i)).min_by_key(|&i| self.slots[i].0))
        };
        let hit = exact.or_else(larger).map(|i| {
            let (size, addr, _) = std::mem::take(&mut self.slots[i]);
            self.bytes -= size;
            if let (true, Some(j)) = (size != bytes, free_larger) {
                self.larger[j] = (addr, size);
            }
            (size, addr as *mut u8)
        });
        self.live += hit.map_or(bytes, |h| h.0);
        self.high = self.high.max(self.live);
        (hit.map(|h| h.1), self.expire())
    }

    /// The bytes of the block at `ptr` freed as class `bytes`: its own size if it was handed out for
    /// a smaller class (then forgotten from `larger`).
    fn own_size(&mut self, bytes: usize, ptr: *mut u8) -> usize {
        match self.larger.iter_mut().find(|l| l.0 == ptr as usize) {
            Some(l) => std::mem::take(l).1,
            None => bytes,
        }
    }

    /// Counts `bytes` as no longer in use (a block that `take` counted but the system did not give).
    fn forget(&mut self, bytes: usize) {
        self.live -= bytes;
    }

    /// Keeps a freed block if it fits; returns what to free (aged-out blocks, the largest cached one
    /// when full, or the block itself).
    fn put(&mut self, bytes: usize, ptr: *mut u8) -> Freed {
        let bytes = self.own_size(bytes, ptr);
        self.live -= bytes;
        let mut out = self.expire();
        let mut n = out.iter().position(|b| b.1.is_null()).unwrap_or(CACHE_SLOTS);
        // in use + cached (this block included) may reach the high-water mark of in use, not beyond
        let limit = self.high.max(CACHE_FLOOR) - self.live;
        if self.bytes + bytes > limit || self.slots.iter().all(|s| s.1 != 0) {
            // evict the largest cached block (frees the most with one munmap)
            if let Some(i) = (0..CACHE_SLOTS).filter(|&i| self.slots[i].1 != 0).max_by_key(|&i| self.slots[i].0) {
                let (size, addr, _) = std::mem::take(&mut self.slots[i]);
                self.bytes -= size;
                out[n] = (size, addr as *mut u8);
                n += 1;
            }
        }
        match self.slots.iter().position(|s| s.1 == 0) {
            Some(i) if self.bytes + bytes <= limit => {
                self.slots[i] = (bytes, ptr as usize, self.tick);
                self.bytes += bytes;
            }
            _ => out[n] = (bytes, ptr),
        }
        out
    }

    /// Removes the blocks cached more than CACHE_AGE large allocations ago.
    fn expire(&mut self) -> Freed {
        let mut out: Freed = [(0, std::ptr::null_mut()); CACHE_SLOTS + 1];
        let mut n = 0;
        for slot in self.slots.iter_mut() {
            if slot.1 != 0 && slot.2 + CACHE_AGE < self.tick {
                out[n] = (slot.0, slot.1 as *mut u8);
                n += 1;
                self.bytes -= slot.0;
                *slot = (0, 0, 0);
            }
        }
        out
    }
}

/// A block of `bytes` fresh from the system, advised to use huge pages; when the system had none
/// (null), the bytes `take` counted as in use are given back.
fn fresh_block(p: *mut u8, bytes: usize) -> *mut u8 {
    if p.is_null() {
        CACHE.lock().unwrap_or_else(|e| e.into_inner()).forget(bytes);
    } else {
        advise_huge_pages(p, bytes);
    }
    p
}

/// [`System`], with large blocks cached and advised to use huge pages.
pub struct HugePageAlloc;

fn large(layout: &Layout) -> bool {
    layout.size() >= HUGE_MIN && layout.align() <= ALIGN
}

/// Frees blocks reserved by [`HugePageAlloc`] (null entries: nothing).
fn release_all(blocks: Freed) {
    for (bytes, ptr) in blocks {
        if !ptr.is_null() {
            // SAFETY: `ptr` was returned by System.alloc with exactly this size and alignment.
            unsafe { System.dealloc(ptr, Layout::from_size_align_unchecked(bytes, ALIGN)) }
        }
    }
}

// SAFETY: small blocks and over-aligned ones go to `System` unchanged. A large block is reserved from
// `System` with its class size and ALIGN, and only ever freed (or cached) with those: a layout always
// maps to the same class, and a block handed out for a smaller class is listed in `larger` with its
// own size until it comes back; a cached block is owned by the cache alone until `alloc` hands it out
// again, to one caller, for a layout of the same or a smaller class (so at most its size).
unsafe impl GlobalAlloc for HugePageAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !large(&layout) {
            // SAFETY: forwarded contract of `GlobalAlloc::alloc`.
            return unsafe { System.alloc(layout) };
        }
        let bytes = class(layout.size());
        let (hit, freed) = CACHE.lock().unwrap_or_else(|e| e.into_inner()).take(bytes);
        release_all(freed);
        if let Some(p) = hit {
            return p;
        }
        // SAFETY: non-zero size, valid power-of-two alignment.
        let p = unsafe { System.alloc(Layout::from_size_align_unchecked(bytes, ALIGN)) };
        fresh_block(p, bytes)
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !large(&layout) {
            // SAFETY: forwarded contract of `GlobalAlloc::alloc_zeroed`.
            return unsafe { System.alloc_zeroed(layout) };
        }
        let bytes = class(layout.size());
        let (hit, freed) = CACHE.lock().unwrap_or_else(|e| e.into_inner()).take(bytes);
        release_all(freed);
        if let Some(p) = hit {
            // SAFETY: the cached block has `bytes` >= layout.size() writable bytes, owned by us now.
            unsafe { std::ptr::write_bytes(p, 0, layout.size()) };
            return p;
        }
        // a fresh block from calloc: zero pages that are only faulted in when written
        // SAFETY: non-zero size, valid power-of-two alignment.
        let p = unsafe { System.alloc_zeroed(Layout::from_size_align_unchecked(bytes, ALIGN)) };
        fresh_block(p, bytes)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded contract of `GlobalAlloc::realloc` (new_size > 0, valid for layout.align()).
        let new = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
        if !large(&layout) && !large(&new) {
            // SAFETY: both small: System owns the block and its reallocation.
            return unsafe { System.realloc(ptr, layout, new_size) };
        }
        if large(&layout) && large(&new) && class(layout.size()) == class(new_size) {
            return ptr;
        }
        // SAFETY: a fresh block of the new layout, then the old one's bytes, then the old one freed.
        unsafe {
            let p = self.alloc(new);
            if !p.is_null() {
                std::ptr::copy_nonoverlapping(ptr, p, layout.size().min(new_size));
                self.dealloc(ptr, layout);
            }
            p
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if !large(&layout) {
            // SAFETY: forwarded contract of `GlobalAlloc::dealloc`.
            return unsafe { System.dealloc(ptr, layout) };
        }
        let freed = CACHE.lock().unwrap_or_else(|e| e.into_inner()).put(class(layout.size()), ptr);
        release_all(freed);
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
