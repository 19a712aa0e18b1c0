//! CPU time of the example process, shared by the timing examples.

/// CPU time of all this process's threads, seconds (from /proc/self/task/*/schedstat: time on a CPU,
/// so another process sharing the cores does not count; Linux only, 0 elsewhere).
pub fn cpu_seconds() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else { return 0.0 };
    tasks
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .sum::<f64>()
        / 1e9
}
