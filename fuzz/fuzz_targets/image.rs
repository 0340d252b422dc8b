//! `cargo fuzz run image`: `r2human::fuzzing::Target::Image` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Image);
