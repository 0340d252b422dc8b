//! What one input frame becomes before any view is drawn ([`PreparedInput`]), the settings it is prepared with
//! ([`PrepareOptions`]) and the stage clock ([`StageTimings`]). The still path (`still`) and the frame path
//! (`frame`) fill it.

use glam::Vec3;
use std::time::{Duration, Instant};

use crate::geometry::fof::Fof;
use crate::geometry::inflate::{self, InflateParams};
use crate::geometry::raster::GBuffer;
use crate::geometry::{Camera, TriMesh, SOURCE_RESOLUTION};

use super::input::NormalisedInput;
use super::{back, warp, GeometryMode, SharedBody, SharedFofNet, SharedPlacementNet, SharedPose};

/// Settings for [`PreparedInput::prepare`].
#[derive(Clone, Debug)]
pub struct PrepareOptions {
    /// Source (FOF grid) resolution; 512 like the reference.
    pub resolution: usize,
    /// Number of FOF-X coefficients N.
    pub fof_order: usize,
    /// Depth samples for mesh extraction (512 like the reference).
    pub depth_samples: usize,
    /// Geometry source.
    pub geometry: GeometryMode,
    /// Parameters of the inflation prior.
    pub inflate: InflateParams,
    /// The FOF network for [`GeometryMode::FofNet`] (and [`GeometryMode::Auto`] when [`super::AUTO_CHOICE`] is the FOF
    /// net; [`super::load_fof_net`]); `None` with `FofNet` is an error, with `Auto` the inflation prior.
    pub fof_net: Option<SharedFofNet>,
    /// The body prior for [`GeometryMode::Body`] ([`super::load_body`]) and for a FOF net that takes the body FOF
    /// ([`super::load_body_for`]); `None` with `Body` is an error.
    pub body: Option<SharedBody>,
    /// The placement network of [`GeometryMode::BodyPlaced`] ([`super::load_placement_net`]); `None`: each column
    /// moves toward the fitted body's depth as far as the fit is trusted there ([`crate::body::placed`]).
    pub placement: Option<SharedPlacementNet>,
    /// Live input: warm-start the body prior from the previous frame (its tracking region and fitted pose).
    pub warm_start: bool,
    /// The pose network that finds the face for the back image ([`super::load_back_pose`]; [`back::back_image`]); `None`:
    /// no back image (the renderers then colour what the photo does not show from the photo itself).
    pub back_pose: Option<SharedPose>,
    /// Also build [`PreparedInput::coarse`], a mesh with half the samples across for views whose pixels are larger
    /// than two source pixels (the XR eyes, the window): interactive views ask for it, offline renders and the
    /// evaluation (512 px over the body cube, one source pixel a pixel) never use it and leave it out.
    pub coarse_views: bool,
    /// Live sources: keep the person model across frames ([`super::person_model`]; `--person-model`, off by
    /// default). Stills ignore it.
    pub person_model: bool,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        Self {
            resolution: SOURCE_RESOLUTION,
            fof_order: 32,
            depth_samples: SOURCE_RESOLUTION,
            geometry: GeometryMode::Inflate,
            inflate: InflateParams::default(),
            fof_net: None,
            body: None,
            placement: None,
            warm_start: false,
            back_pose: None,
            coarse_views: false,
            person_model: false,
        }
    }
}

/// Wall-clock time of named stages, in the order they ran.
#[derive(Clone, Debug, Default)]
pub struct StageTimings(pub Vec<(&'static str, Duration)>);

impl StageTimings {
    /// Runs `f`, recording its duration under `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let out = f();
        self.0.push((name, start.elapsed()));
        out
    }

    /// Total of all recorded stages.
    pub fn total(&self) -> Duration {
        self.0.iter().map(|(_, d)| *d).sum()
    }

    /// One line: "name 12.3 ms, name 4.5 ms, …" in the order the stages ran.
    pub fn summary(&self) -> String {
        let parts: Vec<String> =
            self.0.iter().map(|(name, d)| format!("{name} {:.1} ms", d.as_secs_f64() * 1e3)).collect();
        parts.join(", ")
    }
}

/// Everything computed once per input frame.
#[derive(Clone, Debug)]
pub struct PreparedInput {
    /// The orthographic source camera (`resolution^2`).
    pub source_camera: Camera,
    /// The person normalised into the body cube (premultiplied RGB and mask).
    pub normalised: NormalisedInput,
    /// The Fourier occupancy field the still path decoded the mesh from; `None` on the frame path, whose geometry
    /// is `surfaces`.
    pub fof: Option<Fof>,
    /// The one-shell front and back depth maps the frame path meshed directly ([`super::frame`]); `None` on the
    /// still path.
    pub surfaces: Option<inflate::InflatedSurfaces>,
    /// The mesh: extracted from the FOF (still path) or joined from the two depth maps (frame path).
    pub mesh: TriMesh,
    /// Whether `mesh` is known to be closed and consistently wound (the frame path's, by construction): views from
    /// outside may skip its back faces. False where it was not checked (the still path's marching cubes).
    pub mesh_closed: bool,
    /// The same geometry sampled half as finely across, when [`PrepareOptions::coarse_views`] asked for it: the
    /// CPU renderers draw a view with it when one of the view's pixels spans at least its sample spacing there
    /// ([`mesh_for_view`]).
    pub coarse: Option<CoarseMesh>,
    /// Source-view depth and normals of the geometry (the mesh's raster on the still path, the front map on the
    /// frame path).
    pub source_gbuffer: GBuffer,
    /// The back image and where it drew the head ([`back::back_image`]) when `back_pose` was given and found a
    /// face.
    pub back: Option<back::BackImage>,
    /// The photo and the back image blurred for the surfaces the photo sees edge-on ([`warp::SideImages`]).
    pub side: warp::SideImages,
    /// How long each per-input stage took.
    pub timings: StageTimings,
}

impl PreparedInput {
    /// The FOF of this input with `n` coefficients, for the encoder: the still path's own, or on the frame path
    /// the depth maps encoded now ([`Fof::from_depth_maps`]); `None` when neither has `n` coefficients.
    pub fn fof_with(&self, n: usize) -> Option<std::borrow::Cow<'_, Fof>> {
        match (&self.fof, &self.surfaces) {
            (Some(f), _) if f.n == n => Some(std::borrow::Cow::Borrowed(f)),
            (_, Some(s)) => Fof::from_depth_maps(&s.front, &s.back, &s.mask, n).ok().map(std::borrow::Cow::Owned),
            _ => None,
        }
    }
}

/// A coarser copy of a person's mesh for views that cannot show its finest triangles.
#[derive(Clone, Debug)]
pub struct CoarseMesh {
    /// The mesh (body-cube coordinates, like the full one).
    pub mesh: TriMesh,
    /// Distance between its samples across the source view (body-cube units).
    pub spacing: f32,
    /// Whether it is closed and consistently wound ([`TriMesh::is_closed`]): a view from outside may then skip
    /// the triangles facing away ([`crate::geometry::raster::rasterize_front_into`]).
    pub closed: bool,
    /// Its bounding box (`None` when empty), computed once: every view asks for it.
    pub bounds: Option<(Vec3, Vec3)>,
}

impl CoarseMesh {
    /// `mesh` with its sample `spacing`, its closedness and bounds computed once.
    pub fn new(mesh: TriMesh, spacing: f32) -> Self {
        let closed = mesh.is_closed();
        let bounds = mesh.bounds();
        Self { mesh, spacing, closed, bounds }
    }
}

/// The mesh a view draws ([`mesh_for_view`]) and whether its back faces may be skipped.
#[derive(Clone, Copy, Debug)]
pub struct ViewMesh<'m> {
    /// The mesh.
    pub mesh: &'m TriMesh,
    /// Closed and consistently wound, and the camera outside its bounds: back faces are hidden.
    pub front_only: bool,
}

/// The mesh a view is drawn with: `full`, or `coarse` when a pixel of `camera` spans at least the coarse mesh's
/// sample spacing at the centre of the person's bounds, so the full mesh's extra triangles would fall inside
/// pixels. (For a person a few body heights away the footprint varies by the person's depth over the distance,
/// a few tens of per cent at most.) The drawn mesh's back faces are skipped when it is closed (`full_closed`,
/// [`CoarseMesh::closed`]) and the camera is outside the drawn mesh's bounds. The coarse mesh's bounds are kept
/// with it ([`CoarseMesh::bounds`]); the full mesh's are computed only when it is drawn closed.
pub fn mesh_for_view<'m>(
    full: &'m TriMesh,
    full_closed: bool,
    coarse: Option<&'m CoarseMesh>,
    camera: &Camera,
) -> ViewMesh<'m> {
    let outside = |bounds: Option<(Vec3, Vec3)>| {
        bounds.is_some_and(|(lo, hi)| {
            let eye = camera.position();
            camera.is_orthographic() || eye.cmplt(lo).any() || eye.cmpgt(hi).any()
        })
    };
    // The footprint is never NaN (0 for points it cannot see), so `>=` refuses every unsure case.
    let coarse_enough = |c: &CoarseMesh| {
        !c.mesh.is_empty() && c.bounds.is_some_and(|(lo, hi)| camera.pixel_footprint((lo + hi) * 0.5) >= c.spacing)
    };
    match coarse {
        Some(c) if coarse_enough(c) => ViewMesh { mesh: &c.mesh, front_only: c.closed && outside(c.bounds) },
        _ => ViewMesh { mesh: full, front_only: full_closed && outside(full.bounds()) },
    }
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, Quat, Vec3};

    use super::*;
    use crate::geometry::Fov;

    #[test]
    fn a_view_draws_the_coarse_mesh_only_when_its_pixels_are_as_large_as_the_coarse_samples() {
        let full = TriMesh::uv_sphere(Vec3::ZERO, 0.5, 64, 64);
        let coarse = CoarseMesh::new(TriMesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)), 0.01);
        assert!(coarse.closed);
        let is_coarse = |camera: &Camera| {
            let chosen = mesh_for_view(&full, false, Some(&coarse), camera);
            assert_eq!(
                chosen.front_only,
                std::ptr::eq(chosen.mesh, &coarse.mesh),
                "back faces skipped on the coarse mesh only"
            );
            std::ptr::eq(chosen.mesh, &coarse.mesh)
        };
        // Orthographic over the body cube: 2 / 512 = 0.0039 per pixel (full), 2 / 128 = 0.0156 (coarse), and
        // exactly the spacing at 200 pixels.
        assert!(!is_coarse(&Camera::orthographic(Affine3A::IDENTITY, 1.0, 512, 512)));
        assert!(is_coarse(&Camera::orthographic(Affine3A::IDENTITY, 1.0, 128, 128)));
        assert!(is_coarse(&Camera::orthographic(Affine3A::IDENTITY, 1.0, 200, 200)));
        // Perspective, 90 degrees over 200 pixels: 0.01 per pixel one unit away. From 3 units: 0.03 (coarse);
        // from 0.8 units: 0.008 (full).
        let q = std::f32::consts::FRAC_PI_4;
        let fov = Fov { angle_left: -q, angle_right: q, angle_up: q, angle_down: -q };
        let at = |z: f32| Camera::perspective(Vec3::new(0.0, 0.0, z), Quat::IDENTITY, fov, 0.01, 200, 200);
        assert!(is_coarse(&at(3.0)));
        assert!(!is_coarse(&at(0.8)));
        // Inside the person, no coarse mesh, or an empty one: the full mesh.
        assert!(!is_coarse(&at(0.0)));
        assert!(std::ptr::eq(mesh_for_view(&full, false, None, &at(3.0)).mesh, &full));
        // A full mesh known to be closed skips its back faces from outside, not from inside.
        assert!(mesh_for_view(&full, true, None, &at(3.0)).front_only);
        assert!(!mesh_for_view(&full, true, None, &at(0.0)).front_only);
        let empty = CoarseMesh::new(TriMesh::default(), 0.01);
        assert!(std::ptr::eq(mesh_for_view(&full, false, Some(&empty), &at(3.0)).mesh, &full));
        // A coarse mesh with a hole draws all its faces.
        let mut holed = coarse.clone();
        holed.mesh.triangles.pop();
        let holed = CoarseMesh::new(holed.mesh, 0.01);
        assert!(!mesh_for_view(&full, false, Some(&holed), &at(3.0)).front_only);
    }
}
