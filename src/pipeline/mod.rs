//! The per-input and per-view stages as plain functions over images, each with its CPU reference.

pub mod fusion;
pub mod input;
pub mod warp;
