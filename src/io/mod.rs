//! File input and output: images (with atomic writes), environments, meshes.
