//! Triangle meshes in body-cube coordinates.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Why a mesh cannot be drawn ([`TriMesh::validate`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    /// A vertex position is NaN or infinite.
    #[error("vertex {index} is not finite ({position:?})")]
    NonFiniteVertex {
        /// The vertex.
        index: usize,
        /// Its position.
        position: Vec3,
    },
    /// A triangle names a vertex that does not exist.
    #[error("triangle {triangle} indexes past the {vertices} vertices")]
    IndexOutOfRange {
        /// The triangle.
        triangle: usize,
        /// Number of vertices.
        vertices: u32,
    },
    /// A textured mesh has a material index list of the wrong length.
    #[error("{indices} material indices for {triangles} triangles")]
    MaterialCount {
        /// Material indices given.
        indices: usize,
        /// Triangles.
        triangles: usize,
    },
    /// A triangle names a material that does not exist.
    #[error("material index {index} past the {materials} materials")]
    MaterialIndex {
        /// The index.
        index: u32,
        /// Number of materials.
        materials: usize,
    },
    /// A per-vertex attribute (UVs, colours) is neither absent nor one per vertex.
    #[error("{len} {what} for {vertices} vertices")]
    AttributeCount {
        /// Which attribute.
        what: &'static str,
        /// How many were given.
        len: usize,
        /// Number of vertices.
        vertices: usize,
    },
}

/// An indexed triangle mesh. Triangles are counter-clockwise seen from outside (outward normals).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions (body cube coordinates).
    pub positions: Vec<Vec3>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Unit vertex normals (area-weighted face normals); empty until [`TriMesh::compute_normals`].
    pub normals: Vec<Vec3>,
    /// Optional per-vertex linear RGB colour (for meshes that carry appearance); empty when absent.
    pub colors: Vec<Vec3>,
    /// Optional per-vertex texture coordinates (glTF convention: origin top-left, v down); empty when absent.
    /// Vertices on UV seams are duplicated so every vertex has one UV.
    pub uvs: Vec<Vec2>,
}

impl TriMesh {
    /// A mesh from positions and triangles, with vertex normals computed.
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        let mut mesh = Self { positions, triangles, normals: Vec::new(), colors: Vec::new(), uvs: Vec::new() };
        mesh.compute_normals();
        mesh
    }

    /// Recomputes unit vertex normals as the area-weighted sum of adjacent face normals. Vertices with no
    /// area around them get +z (the source view direction) rather than NaN.
    pub fn compute_normals(&mut self) {
        let mut normals = vec![Vec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize]);
            let n = (b - a).cross(c - a); // length = 2 * area: area weighting for free
            for &i in t {
                normals[i as usize] += n;
            }
        }
        for n in &mut normals {
            *n = n.try_normalize().unwrap_or(Vec3::Z);
        }
        self.normals = normals;
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Whether the mesh has no triangles.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// Whether the surface is closed and consistently wound: every directed edge is used by exactly one triangle
    /// and its reverse by exactly one other. Then, seen from outside, every triangle facing away from the camera
    /// is hidden behind one facing it, and a raster may skip them ([`super::raster::rasterize_front_into`]).
    /// False for an empty mesh. Sorts the `3 * triangles` directed edges once.
    pub fn is_closed(&self) -> bool {
        if self.triangles.is_empty() {
            return false;
        }
        let key = |a: u32, b: u32| (u64::from(a) << 32) | u64::from(b);
        let mut edges: Vec<u64> =
            self.triangles.par_iter().flat_map_iter(|t| (0..3).map(move |i| key(t[i], t[(i + 1) % 3]))).collect();
        edges.par_sort_unstable();
        if edges.windows(2).any(|w| w[0] == w[1]) {
            return false;
        }
        edges.par_iter().all(|&e| {
            let (a, b) = ((e >> 32) as u32, e as u32);
            a != b && edges.binary_search(&key(b, a)).is_ok()
        })
    }

    /// Axis-aligned bounds `(min, max)`; `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))))
    }

    /// Checks that every vertex is finite and every index in range.
    pub fn validate(&self) -> Result<(), MeshError> {
        if let Some(index) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(MeshError::NonFiniteVertex { index, position: self.positions[index] });
        }
        let vertices = self.positions.len() as u32;
        if let Some(triangle) = self.triangles.iter().position(|t| t.iter().any(|&i| i >= vertices)) {
            return Err(MeshError::IndexOutOfRange { triangle, vertices });
        }
        Ok(())
    }

    /// A UV sphere (for tests and analytic checks), outward-facing.
    pub fn uv_sphere(center: Vec3, radius: f32, stacks: u32, slices: u32) -> Self {
        let mut positions = Vec::new();
        for i in 0..=stacks {
            let theta = std::f32::consts::PI * i as f32 / stacks as f32;
            for j in 0..slices {
                let phi = std::f32::consts::TAU * j as f32 / slices as f32;
                positions
                    .push(center + radius * Vec3::new(theta.sin() * phi.sin(), theta.cos(), theta.sin() * phi.cos()));
            }
        }
        let mut triangles = Vec::new();
        for i in 0..stacks {
            for j in 0..slices {
                let a = i * slices + j;
                let b = i * slices + (j + 1) % slices;
                let c = (i + 1) * slices + j;
                let d = (i + 1) * slices + (j + 1) % slices;
                if i != 0 {
                    triangles.push([a, c, b]);
                }
                if i != stacks - 1 {
                    triangles.push([b, c, d]);
                }
            }
        }
        Self::new(positions, triangles)
    }

    /// An axis-aligned box (for tests and analytic checks), outward-facing.
    pub fn cuboid(min: Vec3, max: Vec3) -> Self {
        let c = |x: bool, y: bool, z: bool| {
            Vec3::new(if x { max.x } else { min.x }, if y { max.y } else { min.y }, if z { max.z } else { min.z })
        };
        let positions = vec![
            c(false, false, false),
            c(true, false, false),
            c(true, true, false),
            c(false, true, false),
            c(false, false, true),
            c(true, false, true),
            c(true, true, true),
            c(false, true, true),
        ];
        let quads = [[4, 5, 6, 7], [1, 0, 3, 2], [5, 1, 2, 6], [0, 4, 7, 3], [7, 6, 2, 3], [0, 1, 5, 4]];
        let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        Self::new(positions, triangles)
    }

    /// The mesh simplified to at most about `target_triangles` triangles by meshoptimizer's edge-collapse
    /// simplifier (`meshopt`, quadric error; positions only, so call it before UVs or colours are assigned),
    /// with unused vertices dropped and normals recomputed. Returns the mesh and the simplifier's error relative
    /// to the mesh extent. A mesh already at or under the target is returned unchanged with error 0. The result
    /// can stay above the target when topology forbids further collapses.
    pub fn simplified(&self, target_triangles: usize) -> (TriMesh, f32) {
        if self.triangles.len() <= target_triangles || self.positions.is_empty() {
            return (self.clone(), 0.0);
        }
        let positions: Vec<[f32; 3]> = self.positions.iter().map(|p| p.to_array()).collect();
        let indices: Vec<u32> = self.triangles.iter().flatten().copied().collect();
        let mut error = 0.0f32;
        // Target error 1 (the whole extent): the triangle count is the only limit.
        let mut kept = meshopt::simplify_decoder(
            &indices,
            &positions,
            target_triangles.max(1) * 3,
            1.0,
            meshopt::SimplifyOptions::None,
            Some(&mut error),
        );
        let compact = meshopt::optimize_vertex_fetch(&mut kept, &self.positions);
        let used = kept.iter().copied().max().map_or(0, |m| m as usize + 1);
        let triangles = kept.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
        (TriMesh::new(compact[..used.min(compact.len())].to_vec(), triangles), error)
    }

    /// Signed volume (positive for a closed outward-facing mesh).
    pub fn signed_volume(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitives_are_closed_and_outward() {
        let s = TriMesh::uv_sphere(Vec3::ZERO, 0.5, 32, 64);
        let v = s.signed_volume();
        let exact = 4.0 / 3.0 * std::f32::consts::PI * 0.125;
        assert!(v > 0.0 && (v - exact).abs() / exact < 0.02, "{v} vs {exact}");
        let b = TriMesh::cuboid(Vec3::splat(-0.5), Vec3::new(0.5, 0.5, 0.25));
        assert!((b.signed_volume() - 0.75).abs() < 1e-5);
        // Outward normals: the top vertex of the sphere points up.
        assert!(s.normals[0].y > 0.99);
        assert!(s.validate().is_ok());
    }

    #[test]
    fn simplified_keeps_the_shape_with_fewer_triangles() {
        let s = TriMesh::uv_sphere(Vec3::ZERO, 0.5, 48, 96);
        let n = s.triangle_count();
        let (d, error) = s.simplified(n / 10);
        assert!(d.triangle_count() <= n / 10 && d.triangle_count() > n / 40, "{} of {n}", d.triangle_count());
        assert!(d.validate().is_ok());
        assert!(d.positions.len() < s.positions.len() / 5, "unused vertices dropped");
        // Volume within 3 % of the sphere's, every vertex still on it, error small against the extent.
        let exact = 4.0 / 3.0 * std::f32::consts::PI * 0.125;
        assert!((d.signed_volume() - exact).abs() / exact < 0.03, "{}", d.signed_volume());
        assert!(d.positions.iter().all(|p| (p.length() - 0.5).abs() < 1e-4));
        assert!((0.0..0.05).contains(&error), "{error}");
        // Already small enough: unchanged.
        let (same, e) = s.simplified(n);
        assert_eq!(same, s);
        assert_eq!(e, 0.0);
    }

    #[test]
    fn closed_means_every_edge_once_each_way() {
        let cube = TriMesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5));
        assert!(cube.is_closed());
        // A hole: one triangle removed.
        let mut holed = cube.clone();
        holed.triangles.pop();
        assert!(!holed.is_closed());
        // One triangle wound the other way.
        let mut flipped = cube.clone();
        flipped.triangles[3].swap(1, 2);
        assert!(!flipped.is_closed());
        // A doubled triangle pair (each edge three times).
        let mut doubled = cube.clone();
        doubled.triangles.extend_from_slice(&cube.triangles[..2]);
        assert!(!doubled.is_closed());
        assert!(!TriMesh::default().is_closed());
    }
}
