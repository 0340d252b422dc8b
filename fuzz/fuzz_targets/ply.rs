//! `cargo fuzz run ply`: `r2human::fuzzing::Target::Ply` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Ply);
