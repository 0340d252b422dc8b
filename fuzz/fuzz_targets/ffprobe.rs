//! `cargo fuzz run ffprobe`: `r2human::fuzzing::Target::Ffprobe` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Ffprobe);
