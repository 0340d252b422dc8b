//! `cargo fuzz run mask`: `r2human::fuzzing::Target::Mask` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Mask);
