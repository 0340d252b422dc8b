//! `cargo fuzz run panorama`: `r2human::fuzzing::Target::Panorama` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Panorama);
