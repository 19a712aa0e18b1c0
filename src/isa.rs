//! The instruction set every kernel runs on: the GEMM's micro-kernels (`gemm/simd.rs`), the
//! Winograd transforms and the multiversioned loops of `ops/lanes.rs`.
//!
//! One rule, [`Isa::choose`], decided once per process by [`Isa::from_env`]: the environment variable
//! `MIPNET_ISA` (`avx512`, `avx2` or `generic`, case-insensitive) when it is set and not blank, else
//! the widest ISA the CPU has. `MIPNET_ISA` only ever lowers the ISA: a value naming no ISA, or one
//! this CPU lacks, is an [`Error::Arg`] naming the variable, the value and the accepted values. The
//! Python bindings raise it (`ArgumentError`) from every kernel call, so a forced path never silently
//! falls back; Rust callers that do not check [`Isa::from_env`] run on [`Isa::selected`], which then
//! takes the widest ISA the CPU has.

use crate::{Error, Result};
use std::sync::OnceLock;

/// An instruction set mipnet has a path for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Isa {
    /// AVX-512F: 32 registers of 16 f32.
    Avx512,
    /// AVX2 with FMA: 16 registers of 8 f32.
    Avx2,
    /// Portable Rust, no intrinsics (the compiler vectorises what it can with the baseline ISA).
    Generic,
}

/// Name of the environment variable that forces an ISA.
pub const ISA_ENV: &str = "MIPNET_ISA";

impl Isa {
    /// Every path, widest first.
    pub const ALL: [Isa; 3] = [Isa::Avx512, Isa::Avx2, Isa::Generic];

    /// Position in [`Isa::ALL`].
    pub fn index(self) -> usize {
        match self {
            Isa::Avx512 => 0,
            Isa::Avx2 => 1,
            Isa::Generic => 2,
        }
    }

    /// The name `MIPNET_ISA` takes.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Avx512 => "avx512",
            Isa::Avx2 => "avx2",
            Isa::Generic => "generic",
        }
    }

    /// Whether this CPU can run the path.
    pub fn supported(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => is_x86_feature_detected!("avx512f"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"),
            Isa::Generic => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The widest path this CPU supports.
    pub fn detected() -> Isa {
        Isa::ALL.into_iter().find(|i| i.supported()).unwrap_or(Isa::Generic)
    }

    /// The path named `name` (case-insensitive, surrounding blanks ignored) if this CPU supports it;
    /// else why not, naming the value and the names accepted.
    pub fn parse(name: &str) -> std::result::Result<Isa, String> {
        let want = name.trim().to_ascii_lowercase();
        let Some(isa) = Isa::ALL.into_iter().find(|i| i.name() == want) else {
            return Err(format!("{name:?} is not an instruction set mipnet has; accepted values: {}", names(Isa::ALL)));
        };
        if !isa.supported() {
            return Err(format!("this CPU does not support {name:?}; accepted values on it: {}",
                               names(Isa::ALL.into_iter().filter(|i| i.supported()))));
        }
        Ok(isa)
    }

    /// The ISA a `MIPNET_ISA` of `value` selects (the rule of the module doc): None or blank gives
    /// the detected one, anything else must [`parse`](Isa::parse).
    pub fn choose(value: Option<&str>) -> Result<Isa> {
        choice(value).map_err(env_error)
    }

    /// [`Isa::choose`] of this process's `MIPNET_ISA`, read on the first call; Err for a bad value
    /// (a fresh [`Error::Arg`] each call, so every caller can raise it).
    pub fn from_env() -> Result<Isa> {
        env_choice().clone().map_err(env_error)
    }

    /// The path every kernel takes: [`Isa::from_env`], or the detected one where that is an error
    /// (which the Python bindings raise before any kernel runs). Always supported by this CPU.
    pub fn selected() -> Isa {
        match env_choice() {
            Ok(isa) => *isa,
            Err(_) => Isa::detected(),
        }
    }

    /// Bits of one vector register of this path.
    pub fn vector_bits(self) -> usize {
        match self {
            Isa::Avx512 => 512,
            Isa::Avx2 => 256,
            Isa::Generic => 128,
        }
    }
}

/// The names of `isas`, comma-separated.
fn names(isas: impl IntoIterator<Item = Isa>) -> String {
    isas.into_iter().map(Isa::name).collect::<Vec<_>>().join(", ")
}

/// [`Isa::choose`] with the message of its error.
fn choice(value: Option<&str>) -> std::result::Result<Isa, String> {
    match value.filter(|v| !v.trim().is_empty()) {
        None => Ok(Isa::detected()),
        Some(v) => Isa::parse(v).map_err(|why| format!("{why} (unset: the widest this CPU has)")),
    }
}

/// The error of a bad `MIPNET_ISA`: names the variable, then the value and the accepted values.
fn env_error(msg: String) -> Error {
    Error::arg(ISA_ENV, msg)
}

/// The process's choice, made once: the ISA, or the message of its error.
fn env_choice() -> &'static std::result::Result<Isa, String> {
    static CHOICE: OnceLock<std::result::Result<Isa, String>> = OnceLock::new();
    CHOICE.get_or_init(|| {
        // a value that is not UTF-8 is kept (lossily) so that it is reported, not taken for unset
        let value = std::env::var_os(ISA_ENV).map(|v| v.to_string_lossy().into_owned());
        choice(value.as_deref())
    })
}
