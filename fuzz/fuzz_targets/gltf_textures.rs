//! `cargo fuzz run gltf_textures`: `r2human::fuzzing::Target::GltfTextures` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::GltfTextures);
