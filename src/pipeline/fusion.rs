//! Spatial fusion (paper Eq. 8): while the view moves, blend each new rendering with the previous output warped
//! into the new view, so surfaces keep their colour from frame to frame.
//!
//! # The blend and its weight
//! Where a current pixel's surface point was also visible in the previous view (Eq. 9 with
//! [`VISIBILITY_LAMBDA`], and covered in both images):
//! `I = (1 - w) * I_t + w * I_pre`, `w = beta * |sin(phi / 2)|`, `beta` = [`FUSION_BETA`], `phi` the current view's
//! rotation from the input view ([`Camera::angle_from_source`]). Elsewhere `I = I_t`.
//!
//! Eq. 8 of the paper writes `alpha = beta |sin(phi/2)|` as the weight of `I_t`, but its own text says the
//! opposite ("the closer the current view is to the input view, the more we prefer I_t; the farther, the more
//! I_pre"), and the reference's test script does what the text says: the previous frame's weight grows from 0
//! at the input view to 1 at 180 degrees. `beta |sin(phi/2)|` is therefore used as the weight of the
//! **previous** output `w` (0 at the input view, 0.8 at 180 degrees); see [`previous_weight`].
//!
//! Colours are blended un-premultiplied and re-premultiplied with the current alpha (the current mask defines the
//! person's shape). When the camera has not moved the work is skipped: the cached result is returned for an
//! identical input, and the input itself otherwise.

use glam::{Vec3, Vec4};
use rayon::prelude::*;

use crate::buffer::{sample_bilinear, RgbaImage};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::{flow_and_zmap_into, visibility_into, FlowZ, VISIBILITY_LAMBDA};
use crate::geometry::Camera;

/// `beta` of paper Eq. 8.
pub const FUSION_BETA: f32 = 0.8;

/// Smallest alpha of the warped previous output accepted as "the previous frame had the person here".
const MIN_PREVIOUS_ALPHA: f32 = 0.5;

/// Weight of the previous output at view rotation `phi` (radians) from the input view: `beta * |sin(phi / 2)|`
/// (see the module docs for why it weights the previous output, not the current one).
pub fn previous_weight(phi: f32) -> f32 {
    if phi.is_finite() {
        (FUSION_BETA * (0.5 * phi).sin().abs()).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The previous output and what it was rendered with.
#[derive(Clone, Debug)]
struct Previous {
    /// The fused output returned last time.
    output: RgbaImage,
    /// The rendering passed in last time (to recognise a repeated call).
    input: RgbaImage,
    gbuf: GBuffer,
    camera: Camera,
}

/// Spatial fusion state over a sequence of views (orbit or free-view perspective). See the module docs.
#[derive(Clone, Debug, Default)]
pub struct SpatialFusion {
    previous: Option<Previous>,
    flowz: FlowZ,
    visible: Vec<bool>,
}

impl SpatialFusion {
    /// A fusion state with no previous frame.
    pub fn new() -> Self {
        Self::default()
    }

    /// Forgets the previous frame (call when the input photo or the subject changes).
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// Whether a previous frame is held.
    pub fn has_previous(&self) -> bool {
        self.previous.is_some()
    }

    /// Fuses `current` (premultiplied linear RGBA rendered for `current_cam`, with its G-buffer) with the
    /// previous output, remembers the result and returns it.
    pub fn fuse(&mut self, current: &RgbaImage, current_gbuf: &GBuffer, current_cam: &Camera) -> RgbaImage {
        let (w, h) = (current.width, current.height);
        let consistent = current_gbuf.width == w && current_gbuf.height == h && current_gbuf.mask.len() == w * h;
        let usable = match &self.previous {
            Some(p) => consistent && p.output.width == w && p.output.height == h,
            None => false,
        };
        if !usable {
            return self.remember(current.clone(), current, current_gbuf, current_cam);
        }
        let prev = self.previous.as_ref().unwrap_or_else(|| unreachable!("checked above"));
        if prev.camera == *current_cam {
            // The view has not moved: nothing to fuse.
            if prev.input == *current {
                return prev.output.clone();
            }
            return self.remember(current.clone(), current, current_gbuf, current_cam);
        }

        flow_and_zmap_into(&mut self.flowz, current_gbuf, current_cam, &prev.camera);
        visibility_into(&mut self.visible, &self.flowz, &prev.gbuf, &prev.camera, VISIBILITY_LAMBDA);
        let wp = previous_weight(current_cam.angle_from_source());
        let mut out = current.clone();
        if wp > 0.0 {
            let (flowz, visible, prev_img) = (&self.flowz, &self.visible, &prev.output);
            out.data.par_chunks_mut(w).enumerate().for_each(|(row, out_row)| {
                for (col, o) in out_row.iter_mut().enumerate() {
                    let i = row * w + col;
                    if !visible[i] || !current_gbuf.mask[i] || o.w <= 0.0 {
                        continue;
                    }
                    let f = flowz.flow.data[i];
                    let p = sample_bilinear(prev_img, f.x, f.y, Vec4::ZERO);
                    if !p.is_finite() || p.w < MIN_PREVIOUS_ALPHA {
                        continue;
                    }
                    let pre = p.truncate() / p.w;
                    let cur = o.truncate() / o.w;
                    let blended = (cur * (1.0 - wp) + pre * wp).clamp(Vec3::ZERO, Vec3::ONE);
                    *o = (blended * o.w).extend(o.w);
                }
            });
        }
        self.remember(out, current, current_gbuf, current_cam)
    }

    fn remember(&mut self, output: RgbaImage, input: &RgbaImage, gbuf: &GBuffer, camera: &Camera) -> RgbaImage {
        match &mut self.previous {
            Some(p) => {
                p.output.clone_from(&output);
                p.input.clone_from(input);
                p.gbuf.clone_from(gbuf);
                p.camera = *camera;
            }
            None => {
                self.previous =
                    Some(Previous { output: output.clone(), input: input.clone(), gbuf: gbuf.clone(), camera: *camera })
            }
        }
        output
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::Image;
    use crate::geometry::raster::rasterize;
    use crate::geometry::TriMesh;
    use std::f32::consts::PI;

    fn solid(g: &GBuffer, c: Vec3) -> RgbaImage {
        Image {
            width: g.width,
            height: g.height,
            data: g.mask.iter().map(|&m| if m { c.extend(1.0) } else { Vec4::ZERO }).collect(),
        }
    }

    #[test]
    fn weight_is_zero_at_the_input_view_and_beta_at_the_back() {
        assert_eq!(previous_weight(0.0), 0.0);
        assert!((previous_weight(PI) - FUSION_BETA).abs() < 1e-6);
        assert!((previous_weight(PI / 3.0) - 0.4).abs() < 1e-6);
        assert_eq!(previous_weight(f32::NAN), 0.0);
    }

    #[test]
    fn orbit_step_blends_where_both_views_see_the_surface() {
        let mesh = TriMesh::uv_sphere(glam::Vec3::ZERO, 0.7, 32, 64);
        let res = 64;
        let (c0, c1) = (Camera::orbit(60.0, 0.0, res, res), Camera::orbit(75.0, 0.0, res, res));
        let (g0, g1) = (rasterize(&mesh, &c0), rasterize(&mesh, &c1));
        let mut f = SpatialFusion::new();
        let red = Vec3::new(1.0, 0.0, 0.0);
        let green = Vec3::new(0.0, 1.0, 0.0);
        let first = f.fuse(&solid(&g0, red), &g0, &c0);
        assert_eq!(first, solid(&g0, red));
        let out = f.fuse(&solid(&g1, green), &g1, &c1);
        let wp = previous_weight(75f32.to_radians());
        let expect = green * (1.0 - wp) + red * wp;
        let (mut blended, mut kept) = (0, 0);
        for row in 0..res {
            for col in 0..res {
                let i = row * res + col;
                if !g1.mask[i] {
                    assert_eq!(out.data[i], Vec4::ZERO);
                    continue;
                }
                let o = out.data[i].truncate();
                // World point of the pixel: its x in the previous view decides whether the previous view saw it.
                let p = c1.unproject(col as f32 + 0.5, row as f32 + 0.5, g1.depth[i]);
                let in_prev = c0.view_from_world.transform_point3(p).z;
                if in_prev > 0.3 {
                    assert!((o - expect).length() < 1e-4, "{o} vs {expect}");
                    blended += 1;
                } else if in_prev < -0.05 {
                    assert!((o - green).length() < 1e-6);
                    kept += 1;
                }
            }
        }
        assert!(blended > 500 && kept > 5, "{blended} {kept}");
    }

    #[test]
    fn unmoved_view_returns_the_cache_or_the_input() {
        let mesh = TriMesh::uv_sphere(glam::Vec3::ZERO, 0.7, 16, 32);
        let (c0, c1) = (Camera::orbit(0.0, 0.0, 32, 32), Camera::orbit(90.0, 0.0, 32, 32));
        let (g0, g1) = (rasterize(&mesh, &c0), rasterize(&mesh, &c1));
        let mut f = SpatialFusion::new();
        f.fuse(&solid(&g0, Vec3::X), &g0, &c0);
        let a = f.fuse(&solid(&g1, Vec3::Y), &g1, &c1);
        assert_ne!(a, solid(&g1, Vec3::Y), "moved: fused");
        let b = f.fuse(&solid(&g1, Vec3::Y), &g1, &c1);
        assert_eq!(a, b, "same camera and input: cached result");
        let c = f.fuse(&solid(&g1, Vec3::Z), &g1, &c1);
        assert_eq!(c, solid(&g1, Vec3::Z), "same camera, new input: passed through");
        f.reset();
        assert!(!f.has_previous());
        assert_eq!(f.fuse(&solid(&g0, Vec3::Y), &g0, &c0), solid(&g0, Vec3::Y));
    }
}
