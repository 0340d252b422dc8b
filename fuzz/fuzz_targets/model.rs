//! `cargo fuzz run model`: `r2human::fuzzing::Target::Model` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Model);
