//! `cargo fuzz run glb`: `r2human::fuzzing::Target::Glb` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Glb);
