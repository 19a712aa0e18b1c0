//! The transformed kernels of recent Winograd convolutions, found again by their content.
//!
//! At inference MIPNet runs its update block 6 + 6 times with the same weights (the GRUs' 3x3, 1x5
//! and 5x1 convolutions each time), and transforming and packing a kernel (`U_ξ` for every ξ) took
//! 80-97 ms of a 1.8 s eval at 384x512. A run that asks for it (`Conv2dRun::reuse_kernels`: the
//! convolutions of a no-grad pass, whose weights stay fixed) keeps the packed `U` of a kernel and
//! gets it again when a later call brings a kernel with the same bytes for the same scheme, shapes
//! and GEMM plan. Training does not: its weights change every step, and its dX kernels are fresh
//! arrays, so it would only hold memory (a 128x256 batch-4 step's peak grew from 1.34 to 1.6 GB);
//! and a Winograd forward that does not keep kernels empties the cache ([`release`]), so a training
//! run does not hold on to the kernels of its last validation pass.
//!
//! An entry is found by comparing the kernel's bytes with a copy kept in the entry, so a kernel
//! changed in place (an optimiser step) is transformed again, and a new kernel that reuses a freed
//! buffer is never confused with the old one. The entries' bytes (copy + packed `U`) are bounded by
//! [`CACHE_BYTES`]; the least recently used entry is dropped first.

use super::Scheme;
use crate::gemm::{Isa, Plan, Prepacked};
use crate::Float;
use std::any::{Any, TypeId};
use std::sync::{Arc, Mutex};

/// Most bytes the entries hold (kernel copies and packed `U`): the Winograd kernels of MIPNet take
/// about 86 MiB (66 MiB of `U`).
const CACHE_BYTES: usize = 128 << 20;

/// What besides the kernel's bytes decides its packed `U`.
#[derive(Clone, Copy, PartialEq, Eq)]
struct Key {
    float: TypeId,
    scheme: Scheme,
    isa: Isa,
    mr: usize,
    kc: usize,
    /// Whether U is packed as bf16 pairs (a bf16 plan).
    pairs: bool,
    cout: usize,
    cin: usize,
}

struct Entry {
    key: Key,
    /// Where the kernel was when it was cached: a miss at the same address with the same key replaces
    /// the entry (the kernel was changed in place, as when new weights are loaded into a model), so the
    /// cache holds one entry per kernel buffer.
    address: usize,
    /// The kernel's bytes.
    kernel: Box<[u8]>,
    /// `Arc<Vec<Prepacked<F>>>` for the key's F.
    u: Arc<dyn Any + Send + Sync>,
    bytes: usize,
    /// The lookup count at the last hit or insertion.
    used: u64,
}

struct Cache {
    entries: Vec<Entry>,
    bytes: usize,
    lookups: u64,
}

static CACHE: Mutex<Cache> = Mutex::new(Cache { entries: Vec::new(), bytes: 0, lookups: 0 });

/// The bytes of a slice of floats.
fn bytes_of<F: Float>(w: &[F]) -> &[u8] {
    // SAFETY: f32 and f64 have no padding or invalid bit patterns; the byte slice covers exactly w.
    unsafe { std::slice::from_raw_parts(w.as_ptr().cast::<u8>(), std::mem::size_of_val(w)) }
}

/// The packed `U` of kernel `w` ([Cout, Cin·taps]) for `scheme` and `plan`: a cached one if an
/// earlier call transformed the same bytes with the same scheme, shapes and plan, else `build()`'s,
/// then cached.
pub(super) fn transformed<F: Float>(scheme: Scheme, plan: &Plan<F>, w: &[F], cout: usize, cin: usize,
                                    build: impl FnOnce() -> Vec<Prepacked<F>>) -> Arc<Vec<Prepacked<F>>> {
    let key = Key { float: TypeId::of::<F>(), scheme, isa: plan.isa, mr: plan.mr, kc: plan.kc, pairs: plan.pairs, cout, cin };
    let kernel = bytes_of(w);
    {
        let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
        cache.lookups += 1;
        let now = cache.lookups;
        if let Some(e) = cache.entries.iter_mut().find(|e| e.key == key && *e.kernel == *kernel) {
            e.used = now;
            if let Ok(u) = Arc::clone(&e.u).downcast::<Vec<Prepacked<F>>>() {
                return u;
            }
        }
    }
    // built outside the lock: other threads' convolutions go on meanwhile
    let u = Arc::new(build());
    let bytes = kernel.len() + u.iter().map(Prepacked::bytes).sum::<usize>();
    let address = w.as_ptr() as usize;
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    // another thread may have cached the same kernel meanwhile
    if bytes <= CACHE_BYTES && !cache.entries.iter().any(|e| e.key == key && *e.kernel == *kernel) {
        if let Some(i) = cache.entries.iter().position(|e| e.key == key && e.address == address) {
            let e = cache.entries.swap_remove(i);
            cache.bytes -= e.bytes;
        }
        while cache.bytes + bytes > CACHE_BYTES {
            let Some(oldest) = (0..cache.entries.len()).min_by_key(|&i| cache.entries[i].used) else { break };
            let e = cache.entries.swap_remove(oldest);
            cache.bytes -= e.bytes;
        }
        let used = cache.lookups;
        cache.entries.push(Entry { key, address, kernel: kernel.into(), u: Arc::clone(&u) as Arc<dyn Any + Send + Sync>, bytes, used });
        cache.bytes += bytes;
    }
    u
}

/// Drops every entry (a run that does not keep kernels: the weights are being trained).
pub(super) fn release() {
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    if !cache.entries.is_empty() {
        let entries = std::mem::take(&mut cache.entries);
        cache.bytes = 0;
        drop(cache);
        drop(entries);
    }
}
