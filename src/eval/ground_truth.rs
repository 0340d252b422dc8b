//! Ground-truth views of a textured subject: per-pixel albedo ([`TexturedMesh::albedo`]: the material of the
//! triangle seen, its texture at the interpolated UV, the interpolated vertex colour), coverage mask, view depth
//! and view-space normals, from the project rasteriser. No lighting: every view of a subject agrees on the colour of a surface point.

use glam::{Vec3, Vec4};

use crate::buffer::{premultiply, GrayImage, RgbaImage};
use crate::geometry::camera::Camera;
use crate::geometry::raster::{rasterize, rasterize_with_triangles, GBuffer};
use crate::io::mesh_io::{linear_to_srgb8, TexturedMesh};

/// Depth written to ground-truth depth maps where no surface covers the pixel (dataset convention).
pub const BACKGROUND_DEPTH: f32 = -1.0;

/// One rendered ground-truth view. Per-pixel vectors are row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct GroundTruthView {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Linear RGB albedo (zero where not covered).
    pub albedo: Vec<Vec3>,
    /// Coverage.
    pub mask: Vec<bool>,
    /// View depth (larger is nearer), [`BACKGROUND_DEPTH`] where not covered.
    pub depth: Vec<f32>,
    /// Unit view-space normal, zero where not covered.
    pub normal: Vec<Vec3>,
}

impl GroundTruthView {
    /// The coverage mask as a 0/1 float image (what the pipeline takes as the person's mask).
    pub fn mask_image(&self) -> GrayImage {
        GrayImage { width: self.width, height: self.height, data: self.mask.iter().map(|&m| m as u8 as f32).collect() }
    }

    /// 8-bit sRGB with straight alpha (alpha = mask), as written to `rgba.png`.
    pub fn to_srgba8(&self) -> image::RgbaImage {
        let mut img = image::RgbaImage::new(self.width as u32, self.height as u32);
        for (i, p) in img.pixels_mut().enumerate() {
            if self.mask[i] {
                let [r, g, b] = linear_to_srgb8(self.albedo[i]);
                *p = image::Rgba([r, g, b, 255]);
            }
        }
        img
    }

    /// Premultiplied linear RGBA (the pipeline's image convention).
    pub fn to_linear_rgba(&self) -> RgbaImage {
        RgbaImage::from_fn(self.width, self.height, |c, r| {
            let i = r * self.width + c;
            if self.mask[i] {
                premultiply(self.albedo[i], 1.0)
            } else {
                Vec4::ZERO
            }
        })
    }
}

/// Renders the ground truth of `mesh` seen by `camera`.
pub fn render_ground_truth(mesh: &TexturedMesh, camera: &Camera) -> GroundTruthView {
    // The rasteriser interpolates the per-vertex UVs (and colours, when present) itself; the triangle seen is only
    // needed when triangles differ in material.
    let g: GBuffer = match mesh.has_several_materials() {
        true => rasterize_with_triangles(&mesh.mesh, camera),
        false => rasterize(&mesh.mesh, camera),
    };
    let n = g.width * g.height;
    let uv = g.uv.as_deref();
    let color = g.color.as_deref();
    let triangle = g.triangle.as_deref();
    let mut albedo = vec![Vec3::ZERO; n];
    let mut depth = vec![BACKGROUND_DEPTH; n];
    let mut normal = vec![Vec3::ZERO; n];
    for i in 0..n {
        if !g.mask[i] {
            continue;
        }
        depth[i] = g.depth[i];
        normal[i] = g.normal[i].try_normalize().unwrap_or(Vec3::Z);
        let t = triangle.map_or(0, |t| t[i] as usize);
        let a = mesh.albedo(t, uv.map(|u| u[i]), color.map(|c| c[i].clamp(Vec3::ZERO, Vec3::ONE)));
        albedo[i] = if a.is_finite() { a.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
    }
    GroundTruthView { width: g.width, height: g.height, albedo, mask: g.mask, depth, normal }
}

impl GroundTruthView {
    /// A shaded preview for looking at shapes (not ground truth: the data is unlit albedo): albedo times
    /// `0.4 + 0.6 max(0, n . l)` for a light above-right of the camera, premultiplied linear RGBA.
    pub fn shaded(&self) -> RgbaImage {
        let light = Vec3::new(0.35, 0.5, 0.8).normalize();
        RgbaImage::from_fn(self.width, self.height, |c, r| {
            let i = r * self.width + c;
            if self.mask[i] {
                premultiply(self.albedo[i] * (0.4 + 0.6 * self.normal[i].dot(light).max(0.0)), 1.0)
            } else {
                Vec4::ZERO
            }
        })
    }
}

/// Writes a contact sheet of subjects (atomically): one row per mesh, one shaded view per yaw (pitch 0), each
/// `size` pixels square, for looking at what the generator makes.
pub fn write_contact_sheet(
    path: &std::path::Path,
    meshes: &[&TexturedMesh],
    yaws: &[f32],
    size: usize,
) -> Result<(), super::EvalError> {
    let frames: Vec<crate::buffer::RgbImage> = meshes
        .iter()
        .flat_map(|m| {
            yaws.iter().map(move |&yaw| {
                crate::compose::RenderedFrame::Ar(render_ground_truth(m, &Camera::orbit(yaw, 0.0, size, size)).shaded())
                    .preview()
            })
        })
        .collect();
    crate::io::sequence::write_contact_sheet(path, &frames, yaws.len().max(1), size)
        .map_err(|e| super::EvalError::io(path, std::io::Error::other(e)))
}
