//! User scans (`--scan FILE`): textured glTF/GLB or OBJ+MTL (THuman2.0, 2K2K), normalised into the body cube
//! like the reference (height 1.8, xz centred on the minimal enclosing circle).

use std::path::Path;

use glam::Vec3;

use super::normalize::{self, Normalization};
use super::SynthError;
use crate::io::mesh_io::{read_mesh, TexturedMesh};

/// Largest coordinate magnitude accepted before normalisation (beyond it f32 precision is gone and the file is
/// almost certainly corrupt or in the wrong units).
pub const MAX_ABS_COORDINATE: f32 = 1e6;

/// A scan in the body cube.
#[derive(Clone, Debug)]
pub struct Scan {
    /// The normalised textured mesh.
    pub mesh: TexturedMesh,
    /// The transform applied (file units to body cube).
    pub normalization: Normalization,
}

/// Reads and normalises a scan. Errors (each naming the file): unreadable/corrupt/truncated files, missing
/// textures, empty meshes, NaN vertices, absurd coordinates, and meshes that do not fit the body cube after
/// normalisation (a floor plane or a second object wider than the person).
pub fn load_scan(path: &Path) -> Result<Scan, SynthError> {
    let mut m = read_mesh(path)?;
    normalize_scan(path, &mut m).map(|normalization| Scan { mesh: m, normalization })
}

/// Normalises a mesh in place (see [`load_scan`]); `path` labels errors.
pub fn normalize_scan(path: &Path, m: &mut TexturedMesh) -> Result<Normalization, SynthError> {
    let err = |message: String| SynthError::Scan { path: path.to_path_buf(), message };
    // Only vertices used by triangles count (OBJ files may carry stray vertices).
    let mut used = vec![false; m.mesh.positions.len()];
    for t in &m.mesh.triangles {
        for &i in t {
            used[i as usize] = true;
        }
    }
    let pts: Vec<Vec3> = m.mesh.positions.iter().zip(&used).filter(|(_, &u)| u).map(|(p, _)| *p).collect();
    if let Some(p) = pts.iter().find(|p| p.abs().max_element() > MAX_ABS_COORDINATE) {
        return Err(err(format!(
            "vertex {p} is far outside any plausible unit box (|coordinate| > {MAX_ABS_COORDINATE:e})"
        )));
    }
    let n = normalize::compute(&pts).ok_or_else(|| err("the mesh has no height (all vertices at one y)".into()))?;
    if n.xz_radius > 1.0 {
        return Err(err(format!(
            "after scaling to height {} the mesh is {:.2} wide (xz radius {:.2} > 1): it does not fit the body \
             cube; remove floors or other objects, and check that +Y is up",
            normalize::BODY_HEIGHT,
            2.0 * n.xz_radius,
            n.xz_radius
        )));
    }
    for p in &mut m.mesh.positions {
        *p = n.apply(*p);
    }
    m.mesh.compute_normals();
    Ok(n)
}
