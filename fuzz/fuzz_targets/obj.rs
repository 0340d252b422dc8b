//! `cargo fuzz run obj`: `r2human::fuzzing::Target::Obj` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Obj);
