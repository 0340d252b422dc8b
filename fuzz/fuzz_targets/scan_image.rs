//! `cargo fuzz run scan_image`: `r2human::fuzzing::Target::ScanImage` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::ScanImage);
