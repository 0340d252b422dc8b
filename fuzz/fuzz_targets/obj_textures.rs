//! `cargo fuzz run obj_textures`: `r2human::fuzzing::Target::ObjTextures` (see `fuzz/README.md`).
#![no_main]
r2human_fuzz::target!(r2human::fuzzing::Target::ObjTextures);
