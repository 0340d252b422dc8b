//! File input and output: images (with atomic writes), environments, meshes (glTF/OBJ/PLY) and `.npy` arrays.

pub mod environment;
pub mod image_io;
pub mod mesh_io;
pub mod npy;
pub mod ply;
pub mod sequence;
