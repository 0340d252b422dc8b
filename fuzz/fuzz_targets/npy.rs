//! `cargo fuzz run npy`: `r2human::fuzzing::Target::Npy` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Npy);
