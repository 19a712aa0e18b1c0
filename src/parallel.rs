//! The rayon thread pool every kernel runs in, resizable at run time and safe after `fork()`.
//!
//! The size comes from `set_num_threads`, else the environment variable `MIPNET_NUM_THREADS`, else
//! `RAYON_NUM_THREADS`, else the number of available cores.

use rayon::{ThreadPool, ThreadPoolBuilder};
use std::sync::{Arc, RwLock};

use crate::{Error, Result};

static POOL: RwLock<Option<Arc<ThreadPool>>> = RwLock::new(None);

fn default_threads() -> usize {
    ["MIPNET_NUM_THREADS", "RAYON_NUM_THREADS"]
        .iter()
        .filter_map(|k| std::env::var(k).ok()?.trim().parse::<usize>().ok())
        .find(|&n| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1))
}

fn build(n: usize) -> Result<Arc<ThreadPool>> {
    ThreadPoolBuilder::new()
        .num_threads(n)
        .thread_name(|i| format!("mipnet-{i}"))
        .build()
        .map(Arc::new)
        .map_err(|e| Error::arg("set_num_threads", e.to_string()))
}

fn pool() -> Arc<ThreadPool> {
    if let Some(p) = POOL.read().unwrap_or_else(|e| e.into_inner()).as_ref() {
        return p.clone();
    }
    let mut slot = POOL.write().unwrap_or_else(|e| e.into_inner());
    slot.get_or_insert_with(|| build(default_threads()).expect("a thread pool of the default size"))
        .clone()
}

/// Runs `f` inside mipnet's pool, so its `par_iter`s use that pool's threads.
pub fn install<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    pool().install(f)
}

/// The number of threads kernels use.
pub fn num_threads() -> usize {
    pool().current_num_threads()
}

/// Replaces the pool by one of `n` threads (n >= 1).
pub fn set_num_threads(n: usize) -> Result<()> {
    if n == 0 {
        return Err(Error::arg("set_num_threads", "the number of threads must be at least 1"));
    }
    let new = build(n)?;
    *POOL.write().unwrap_or_else(|e| e.into_inner()) = Some(new);
    Ok(())
}

/// Called in a forked child: the parent's worker threads do not exist there, so the inherited pool
/// is leaked (never joined) and a fresh one is built on next use.
pub fn reset_after_fork() {
    let mut slot = POOL.write().unwrap_or_else(|e| e.into_inner());
    if let Some(old) = slot.take() {
        std::mem::forget(old);
    }
}
