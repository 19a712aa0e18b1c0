//! The one choice of instruction set (`src/isa.rs`): the names `MIPNET_ISA` accepts, the values it
//! rejects (an `Error::Arg` naming the variable, the value and the accepted values), and the default.

use _core::{Error, Isa, ISA_ENV};

/// `Isa::choose(value)`'s error as text, checked to be an argument error.
fn rejection(value: &str) -> String {
    match Isa::choose(Some(value)) {
        Err(e @ Error::Arg { .. }) => e.to_string(),
        other => panic!("MIPNET_ISA={value:?} should be an argument error, got {other:?}"),
    }
}

#[test]
fn every_isa_name_is_accepted_in_any_case_where_the_cpu_has_it() {
    for isa in Isa::ALL {
        for value in [isa.name().to_string(), isa.name().to_ascii_uppercase(), format!("  {} ", isa.name())] {
            if isa.supported() {
                assert_eq!(Isa::parse(&value), Ok(isa), "{value:?}");
                assert_eq!(Isa::choose(Some(&value)).ok(), Some(isa), "{value:?}");
            } else {
                let msg = rejection(&value);
                assert!(msg.contains("does not support") && msg.contains("generic"), "{msg}");
            }
        }
    }
    assert_eq!(Isa::parse("generic"), Ok(Isa::Generic), "every CPU has the portable path");
}

#[test]
fn unset_or_blank_selects_the_widest_isa_of_the_cpu() {
    for value in [None, Some(""), Some("  \t")] {
        assert_eq!(Isa::choose(value).ok(), Some(Isa::detected()), "{value:?}");
    }
    assert!(Isa::detected().supported());
}

#[test]
fn a_wrong_value_is_an_error_naming_the_variable_the_value_and_every_accepted_value() {
    for value in ["bogus", "avx3", "avx-512", "sse2", "generic,avx2", "0"] {
        let msg = rejection(value);
        assert!(msg.starts_with(&format!("{ISA_ENV}: ")), "{msg}");
        assert!(msg.contains(&format!("{value:?}")), "{msg}");
        assert!(msg.contains("avx512, avx2, generic"), "{msg}");
        assert!(!msg.contains('\n'), "one line: {msg}");
        let why = Isa::parse(value).unwrap_err();
        assert!(why.contains(&format!("{value:?}")) && why.contains("avx512, avx2, generic"), "{why}");
    }
}

#[test]
fn the_process_choice_follows_the_rule_and_every_kernel_path_is_supported() {
    let env = std::env::var_os(ISA_ENV).map(|v| v.to_string_lossy().into_owned());
    let rule = Isa::choose(env.as_deref()).map_err(|e| e.to_string());
    assert_eq!(Isa::from_env().map_err(|e| e.to_string()), rule);
    assert_eq!(Isa::selected(), rule.unwrap_or_else(|_| Isa::detected()));
    assert!(Isa::selected().supported());
}
