//! The still path: a photo's geometry as a Fourier occupancy field, decoded by marching cubes into the mesh,
//! whose source view is rasterised; the back image and the side images beside it.

use std::sync::atomic::AtomicBool;

use crate::body::pose::PoseRegion;
use crate::buffer::{GrayImage, RgbImage};
use crate::geometry::fof::Fof;
use crate::geometry::marching;
use crate::geometry::raster::{self, GBuffer};
use crate::geometry::{Camera, TriMesh};

use super::input::NormalisedInput;
use super::prepared::CoarseMesh;
use super::{
    back, compute_geometry, input, warn_once, warp, PipelineError, PrepareOptions, PreparedInput, SharedPose,
    StageTimings,
};

impl PreparedInput {
    /// Runs the per-input stages on a photo (linear RGB, straight colour) and its person mask (`[0, 1]`).
    pub fn prepare(rgb: &RgbImage, mask: &GrayImage, opts: &PrepareOptions) -> Result<Self, PipelineError> {
        let mut timings = StageTimings::default();
        let normalised = timings.time("normalise", || input::normalise(rgb, mask, opts.resolution))?;
        let fof = compute_geometry(&normalised, opts, &mut timings)?;
        Self::from_fof(normalised, fof, opts, timings)
    }

    /// Finishes preparation from an already computed FOF (e.g. a network's, or ground truth). The back image
    /// (with `opts.back_pose`) depends on the photo alone, whatever the geometry: its face is the pose network's own
    /// read of the normalised photo ([`back_image_with`]), computed beside the mesh and the source raster, and its
    /// stage times are recorded after theirs.
    pub fn from_fof(
        normalised: NormalisedInput,
        fof: Fof,
        opts: &PrepareOptions,
        mut timings: StageTimings,
    ) -> Result<Self, PipelineError> {
        let source_camera = Camera::source(opts.resolution);
        let mut back_timings = StageTimings::default();
        // The colours are only read by the back image and the renderers, so their rim is cleaned beside the mesh.
        let rim = input::RIM_FRACTION * opts.resolution as f32;
        let (geometry, (normalised, back, side)) = rayon::join(
            || -> Result<(TriMesh, GBuffer, Option<CoarseMesh>), PipelineError> {
                let mesh =
                    timings.time("mesh (FOF -> marching cubes)", || marching::extract_mesh(&fof, opts.depth_samples));
                if mesh.is_empty() {
                    return Err(PipelineError::EmptyGeometry);
                }
                if mesh.validate().is_err() {
                    return Err(PipelineError::NonFinite("mesh"));
                }
                let source_gbuffer = timings.time("source raster", || raster::rasterize(&mesh, &source_camera));
                let coarse = opts.coarse_views.then(|| {
                    timings.time("coarse mesh (halved FOF -> marching cubes)", || coarse_still_mesh(&fof, opts))
                });
                Ok((mesh, source_gbuffer, coarse))
            },
            || {
                let normalised =
                    back_timings.time("rim colours", || input::interior_colours_at_the_rim(normalised, rim));
                let back = opts.back_pose.as_ref().and_then(|net| back_image_with(&normalised, net, &mut back_timings));
                let side = back_timings.time("side images", || {
                    warp::SideImages::of(&normalised.rgb, back.as_ref().map(|b| &b.rgb), &normalised.mask)
                });
                (normalised, back, side)
            },
        );
        let (mesh, source_gbuffer, coarse) = geometry?;
        timings.0.extend(back_timings.0);
        Ok(Self {
            source_camera,
            normalised,
            fof: Some(fof),
            surfaces: None,
            mesh,
            mesh_closed: false,
            coarse,
            source_gbuffer,
            back,
            side,
            timings,
        })
    }
}

/// The mesh of the FOF on a grid of half the resolution ([`Fof::halved`], half the depth samples): a quarter of
/// the triangles, sample spacing two source pixels ([`PreparedInput::coarse`]).
fn coarse_still_mesh(fof: &Fof, opts: &PrepareOptions) -> CoarseMesh {
    let mesh = marching::extract_mesh(&fof.halved(), opts.depth_samples.div_ceil(2));
    CoarseMesh::new(mesh, 2.0 * 2.0 / opts.resolution.max(1) as f32)
}

/// The back image of a normalised input ([`back::back_image`]) with the face found by `pose`; `None` (one warning
/// per process, then debug messages) when the pose network finds no person or no usable face, or fails.
pub fn back_image_of(normalised: &NormalisedInput, pose: &SharedPose, timings: &mut StageTimings) -> Option<RgbImage> {
    back_image_with(normalised, pose, timings).map(|back| back.rgb)
}

/// [`back_image_of`] with its head weights. The face is always the pose network's own read of the normalised photo
/// in its own frame ([`read_face`]), never a geometry's read: the body prior reads in the frame
/// [`crate::body::prior::effective_frame`] gives (a straight bottom edge counted as a cut), where the network can
/// place the face elsewhere, so a geometry's read would change the back image with the geometry.
pub fn back_image_with(
    normalised: &NormalisedInput,
    pose: &SharedPose,
    timings: &mut StageTimings,
) -> Option<back::BackImage> {
    let face = read_face(normalised, pose, timings);
    back_image_from_face(normalised, face.as_ref(), timings)
}

/// The face of a normalised input as the pose network reads it (stage "back image (face landmarks)"); `None` when
/// it finds no person or no usable face, or fails (said at debug level).
pub fn read_face(
    normalised: &NormalisedInput,
    pose: &SharedPose,
    timings: &mut StageTimings,
) -> Option<back::FacePoints> {
    read_face_near(normalised, pose, None, timings).0
}

/// [`read_face`] warm-started: with `region` (the region the last read of the same person came from, in the same
/// normalised frame, which follows the person) one run of the pose network there
/// ([`crate::body::pose::PoseEstimator::read_in`]) instead of the full read's two to six; the full read when there is
/// no region, or the tracked run finds no usable face. Also returns the region the answer came from, for the next
/// read (stage "back image (face landmarks)").
pub fn read_face_near(
    normalised: &NormalisedInput,
    pose: &SharedPose,
    region: Option<PoseRegion>,
    timings: &mut StageTimings,
) -> (Option<back::FacePoints>, Option<PoseRegion>) {
    let found = timings.time("back image (face landmarks)", || {
        let mut p = pose.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let tracked = match region {
            Some(r) => p.read_in(&normalised.rgb, r, Some(normalised.frame)),
            None => Ok(None),
        };
        match tracked {
            Ok(Some(l)) if back::FacePoints::from_pose(&l).is_some() => Ok(Some(l)),
            _ => p.estimate(&normalised.rgb, &normalised.mask, Some(normalised.frame)),
        }
    });
    match found {
        Ok(Some(l)) => (back::FacePoints::from_pose(&l), Some(l.region)),
        Ok(None) => (None, None),
        Err(e) => {
            tracing::debug!("back image: the pose network failed: {e}");
            (None, None)
        }
    }
}

/// The back image of a normalised input around `face` (stage "back image (filter)"); `None`, with one warning
/// per process, without a face or when the filter finds no person.
pub fn back_image_from_face(
    normalised: &NormalisedInput,
    face: Option<&back::FacePoints>,
    timings: &mut StageTimings,
) -> Option<back::BackImage> {
    let back = face
        .and_then(|f| timings.time("back image (filter)", || back::back_image(&normalised.rgb, &normalised.mask, f)));
    if back.is_none() {
        static WARNED: AtomicBool = AtomicBool::new(false);
        warn_once(
            &WARNED,
            "back image: no face found in this input; surfaces the photo does not show take the photo's colours",
        );
    }
    back
}
