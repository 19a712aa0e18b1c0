//! What the GEMM needs to know about the CPU: its name and its per-core data cache sizes.
//!
//! Cache sizes come from CPUID (leaf 4 on Intel, leaf 0x8000001D on AMD), else from
//! `/sys/devices/system/cpu/cpu0/cache`, else conservative defaults (32 KiB L1d, 512 KiB L2).

use std::sync::OnceLock;

/// The CPU as the GEMM sees it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CpuInfo {
    /// The brand string ("Intel(R) Xeon(R) Processor", "AMD EPYC 9654 96-Core Processor", ...).
    pub model: String,
    /// "GenuineIntel", "AuthenticAMD", ... ("unknown" off x86).
    pub vendor: String,
    /// L1 data cache per core, bytes.
    pub l1d: usize,
    /// L2 cache per core, bytes.
    pub l2: usize,
    /// Last-level cache (shared), bytes; 0 when unknown.
    pub l3: usize,
    /// Where the sizes came from: "cpuid", "sysfs" or "default".
    pub cache_source: &'static str,
}

/// Defaults when neither CPUID nor sysfs answers: small enough for any current core.
const DEFAULT_L1D: usize = 32 << 10;
const DEFAULT_L2: usize = 512 << 10;

/// The CPU this process runs on (queried once).
pub fn cpu_info() -> &'static CpuInfo {
    static INFO: OnceLock<CpuInfo> = OnceLock::new();
    INFO.get_or_init(|| {
        let (model, vendor) = names();
        let usable = |c: &Caches| c.l1d > 0 && c.l2 > 0;
        let (caches, cache_source) = match (cpuid_caches(&vendor).filter(usable), sysfs_caches().filter(usable)) {
            (Some(c), _) => (c, "cpuid"),
            (None, Some(c)) => (c, "sysfs"),
            (None, None) => (Caches { l1d: DEFAULT_L1D, l2: DEFAULT_L2, l3: 0 }, "default"),
        };
        CpuInfo { model, vendor, l1d: caches.l1d, l2: caches.l2, l3: caches.l3, cache_source }
    })
}

/// Data cache sizes per level, bytes.
#[derive(Clone, Copy, Debug)]
struct Caches {
    l1d: usize,
    l2: usize,
    l3: usize,
}

/// The brand string and vendor from CPUID (x86), else `/proc/cpuinfo`.
fn names() -> (String, String) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::__cpuid;
        let l0 = __cpuid(0);
        let v: Vec<u8> = [l0.ebx, l0.edx, l0.ecx].iter().flat_map(|r| r.to_le_bytes()).collect();
        let (vendor, max_ext) = (String::from_utf8_lossy(&v).into_owned(), __cpuid(0x8000_0000).eax);
        if max_ext >= 0x8000_0004 {
            // leaves 0x80000002..=0x80000004 (present, checked above) hold the brand string
            let bytes: Vec<u8> = (0x8000_0002u32..=0x8000_0004)
                .flat_map(|leaf| {
                    let r = __cpuid(leaf);
                    [r.eax, r.ebx, r.ecx, r.edx].into_iter().flat_map(u32::to_le_bytes)
                })
                .collect();
            let model = String::from_utf8_lossy(&bytes).trim_matches(char::from(0)).trim().to_string();
            if !model.is_empty() {
                return (model, vendor);
            }
        }
        (proc_cpuinfo_model().unwrap_or_else(|| "unknown x86-64".into()), vendor)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        (proc_cpuinfo_model().unwrap_or_else(|| std::env::consts::ARCH.into()), "unknown".into())
    }
}

/// The first "model name" (or "Model") line of /proc/cpuinfo.
fn proc_cpuinfo_model() -> Option<String> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    text.lines()
        .find(|l| l.starts_with("model name") || l.starts_with("Model"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, v)| v.trim().to_string())
}

/// Cache sizes from the deterministic cache parameters leaf: 4 on Intel, 0x8000001D on AMD/Hygon.
#[cfg(target_arch = "x86_64")]
fn cpuid_caches(vendor: &str) -> Option<Caches> {
    use std::arch::x86_64::{__cpuid, __cpuid_count};
    let amd = matches!(vendor, "AuthenticAMD" | "HygonGenuine");
    let leaf = if amd { 0x8000_001D } else { 4 };
    // each leaf is read only when the maximum leaf (basic or extended) says it exists
    {
        let max = __cpuid(if amd { 0x8000_0000 } else { 0 }).eax;
        if max < leaf {
            return None;
        }
        let mut c = Caches { l1d: 0, l2: 0, l3: 0 };
        for sub in 0..16 {
            let r = __cpuid_count(leaf, sub);
            // EAX[4:0] type (0 none, 1 data, 2 instruction, 3 unified), EAX[7:5] level
            let (kind, level) = (r.eax & 0x1f, (r.eax >> 5) & 0x7);
            if kind == 0 {
                break;
            }
            // size = ways · partitions · line size · sets, each field stored minus one
            let size = ((r.ebx >> 22) as usize + 1) * (((r.ebx >> 12) & 0x3ff) as usize + 1)
                * ((r.ebx & 0xfff) as usize + 1) * (r.ecx as usize + 1);
            match (level, kind) {
                (1, 1) | (1, 3) => c.l1d = size,
                (2, 1) | (2, 3) => c.l2 = size,
                (3, 1) | (3, 3) => c.l3 = size,
                _ => {}
            }
        }
        Some(c)
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn cpuid_caches(_vendor: &str) -> Option<Caches> {
    None
}

/// Cache sizes from Linux's sysfs description of cpu0.
fn sysfs_caches() -> Option<Caches> {
    let mut c = Caches { l1d: 0, l2: 0, l3: 0 };
    for i in 0..8 {
        let dir = format!("/sys/devices/system/cpu/cpu0/cache/index{i}");
        let read = |f: &str| std::fs::read_to_string(format!("{dir}/{f}")).ok().map(|s| s.trim().to_string());
        let (Some(level), Some(kind), Some(size)) = (read("level"), read("type"), read("size")) else { break };
        // "48K", "2048K", "260M"
        let bytes = match size.chars().last() {
            Some('K') => size[..size.len() - 1].parse::<usize>().ok().map(|v| v << 10),
            Some('M') => size[..size.len() - 1].parse::<usize>().ok().map(|v| v << 20),
            _ => size.parse::<usize>().ok(),
        }?;
        match (level.as_str(), kind.as_str()) {
            ("1", "Data" | "Unified") => c.l1d = bytes,
            ("2", "Data" | "Unified") => c.l2 = bytes,
            ("3", "Data" | "Unified") => c.l3 = bytes,
            _ => {}
        }
    }
    Some(c)
}
