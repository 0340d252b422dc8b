//! Geometry: cameras, meshes, the Fourier occupancy field, marching cubes, the silhouette-inflation prior,
//! rasterisation and the flow / Z-map of paper Eq. 4.

pub mod camera;
pub mod circle;
pub mod depth_centre;
pub mod fof;
pub mod inflate;
pub mod marching;
pub mod mesh;
pub mod raster;
pub mod shells;
pub mod surface_mesh;
pub mod zmap;

pub use camera::{Camera, Fov, Projection, Ray, RayGrid, SOURCE_RESOLUTION};
pub use mesh::{MeshError, TriMesh};
