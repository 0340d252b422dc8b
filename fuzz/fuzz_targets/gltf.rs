//! `cargo fuzz run gltf`: `r2human::fuzzing::Target::Gltf` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::Gltf);
