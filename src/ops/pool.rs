//! (family under construction)
