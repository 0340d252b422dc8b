//! The frame path: what a frame of a video or camera needs, and nothing a still needs.
//!
//! A still photo's geometry is encoded as a Fourier occupancy field and decoded by marching cubes (the still path,
//! [`super::still`]): the only route for geometry with more than one shell per column (the FOF net's, the body
//! prior's). The geometries frames draw — the silhouette-inflation prior and the body-placed inflation — have one
//! shell per column, given as a front and a back depth map; for them the FOF round trip only blurs what is known
//! and costs most of a frame (encode, a ~300k-triangle marching-cubes mesh, a raster of the depths back). Here:
//!
//! - **Mesh from the maps** ([`crate::geometry::surface_mesh::mesh_from_surfaces`]): the two height fields sampled
//!   every [`FRAME_MESH_STEP`] pixels and joined at the outline (about a tenth of the marching-cubes triangles).
//! - **Source view from the maps** ([`crate::geometry::surface_mesh::source_gbuffer`]): the front's depth and
//!   slopes at every pixel, no raster.
//! - **Smoothing over time on the maps** ([`SurfaceSmoother`]): an exponential average of the depths where the
//!   person was in both frames, restarted when the silhouette changes a lot (a cut, a person entering).
//! - **The back image at its own rate**: it holds the colours of clothing and hair, which change slowly; its layers
//!   before the mask ([`BackLayers`]) and their side image are kept for up to [`BACK_IMAGE_EVERY`] frames while the
//!   silhouette stays near the one they were made on ([`BACK_KEEP_IOU`]), each frame masking them with its own
//!   silhouette. Its face comes from the back image's own pose network (whatever the geometry, as on stills) every
//!   [`BACK_FACE_EVERY`] frames (the face sits still in the normalised frame, which follows the
//!   person), read in one run on the region the last read came from, with a full read every
//!   [`FULL_FACE_READ_EVERY`]th.
//! - **Side images on a coarser grid** ([`FRAME_SIDE_FACTOR`]): the photo's blur for the surfaces it sees
//!   edge-on.
//! - **The encoder's FOF on demand**: only the neural renderer reads a FOF; it is encoded from the maps when it
//!   asks ([`PreparedInput::fof_with`]).
//!
//! Geometry modes with more than one shell per column (`fofnet`, `body`) are prepared by the still path, frame by
//! frame, and said so once.

use std::sync::atomic::AtomicBool;

use super::back::{BackLayers, FacePoints};
use super::input::{self, NormalisedInput};
use super::prepared::CoarseMesh;
use super::{
    back_layers_from_face, body_placed_surfaces, compute_geometry, inflation_surfaces_coarse, read_face_near,
    warn_once, warp, GeometryMode, PipelineError, PrepareOptions, PreparedInput, StageTimings,
};
use crate::body::pose::PoseRegion;
use crate::buffer::{GrayImage, RgbImage};
use crate::geometry::inflate::InflatedSurfaces;
use crate::geometry::raster::GBuffer;
use crate::geometry::surface_mesh::{mesh_from_surfaces, source_gbuffer, SurfaceMeshError};
use crate::geometry::{Camera, TriMesh};

/// The frame mesh's sampling step in source pixels: at 512² a step of 2 keeps every facet near a pixel of a
/// 512² view of the whole body cube (the largest view the evaluation and the XR eyes draw the person at); a step
/// of 1 quadruples the triangles for no visible change.
pub const FRAME_MESH_STEP: usize = 2;

/// The frame mesh at twice [`FRAME_MESH_STEP`] ([`PreparedInput::coarse`]); `None` when the mask holds no triangle
/// at that step (small people: views then draw the full mesh).
fn coarse_frame_mesh(surfaces: &InflatedSurfaces, resolution: usize) -> Option<CoarseMesh> {
    let step = 2 * FRAME_MESH_STEP;
    let mesh = mesh_from_surfaces(surfaces, step).ok()?;
    Some(CoarseMesh::new(mesh, step as f32 * 2.0 / resolution.max(1) as f32))
}

/// A frame's mesh (every [`FRAME_MESH_STEP`] pixels), its source view and, with `opts.coarse_views`, its coarse
/// mesh, all straight from the one-shell `surfaces`, timed into `t`.
fn meshes_of(
    surfaces: &InflatedSurfaces,
    opts: &PrepareOptions,
    t: &mut StageTimings,
) -> Result<(TriMesh, GBuffer, Option<CoarseMesh>), PipelineError> {
    let mesh = t.time("mesh (depth maps)", || mesh_from_surfaces(surfaces, FRAME_MESH_STEP));
    let mesh = mesh.map_err(|e| match e {
        SurfaceMeshError::Empty { .. } => PipelineError::EmptyGeometry,
        _ => PipelineError::NonFinite("frame geometry"),
    })?;
    let source = t.time("source view (depth maps)", || source_gbuffer(surfaces));
    let coarse = opts
        .coarse_views
        .then(|| t.time("coarse mesh (depth maps)", || coarse_frame_mesh(surfaces, opts.resolution)))
        .flatten();
    Ok((mesh, source, coarse))
}

/// Makes what a frame of a [`FramePath::without_meshes`] path (or a frame whose surfaces changed after it was
/// meshed, which then holds no coarse mesh) lacks, from its surfaces: the mesh and source view when its mesh is
/// empty, the coarse mesh when `opts.coarse_views` asks for one. Timed into the frame's timings under the frame
/// path's names. A frame without surfaces (the still path's) is left as it is.
pub fn finish_meshes(prepared: &mut PreparedInput, opts: &PrepareOptions) -> Result<(), PipelineError> {
    let Some(surfaces) = prepared.surfaces.as_ref() else { return Ok(()) };
    let mut t = StageTimings::default();
    if prepared.mesh.is_empty() {
        let (mesh, source, coarse) = meshes_of(surfaces, opts, &mut t)?;
        prepared.mesh = mesh;
        prepared.source_gbuffer = source;
        prepared.mesh_closed = true;
        prepared.coarse = coarse;
    } else if opts.coarse_views && prepared.coarse.is_none() {
        prepared.coarse = t.time("coarse mesh (depth maps)", || coarse_frame_mesh(surfaces, opts.resolution));
    }
    prepared.timings.0.extend(t.0);
    Ok(())
}

/// How much coarser than the source grid a frame's silhouette is inflated
/// ([`crate::geometry::inflate::inflate_resolvable_coarse`]): the inflated height is smooth, the outline stays the
/// frame's own.
pub const FRAME_INFLATION_FACTOR: usize = 2;

/// Frames between two reads of the face by the pose network for the back image.
pub const BACK_FACE_EVERY: u64 = 8;

/// Every this many face reads one is a full read ([`crate::body::pose::PoseEstimator::estimate`]); the others are
/// one tracked run on the region the read before came from ([`super::still::read_face_near`]).
pub const FULL_FACE_READ_EVERY: u64 = 4;

/// Frames a back image is kept for at most ([`FramePath`]): it holds the colours of clothing and hair, which change
/// slowly; each frame masks its layers with its own silhouette. A silhouette that changes more ([`BACK_KEEP_IOU`])
/// makes a new one sooner.
pub const BACK_IMAGE_EVERY: u64 = 8;

/// Mask IoU with the frame a kept back image was made on below which a new one is made: the person moved enough
/// that the kept colours may sit at the wrong places (an arm raised across the body). At 0.98 a person panned
/// across a webcam's view made a new one on 9 frames in 10.
pub const BACK_KEEP_IOU: f32 = 0.9;

/// How much coarser than the source grid a frame's side images are blurred
/// ([`warp::SideImages::with_back_side`]): a blur of [`warp::SIDE_BLUR`] (4 px at 512²) loses nothing on a grid
/// twice as coarse.
pub const FRAME_SIDE_FACTOR: usize = 2;

/// Frames a body placement ([`GeometryMode::BodyPlaced`]: the fitted body's depths and the face relief, as offsets
/// from the inflation prior) serves at most before a new one is made: the pose network, the body fit and the face
/// mesh cost about as much as the rest of a frame, and the body moves less between frames than the silhouette.
pub const PLACEMENT_EVERY: u64 = 8;

/// Mask IoU with the frame a body placement was made on below which it is not carried (the person moved too much
/// for its offsets to land where they belong) and a new one is due at once.
pub const PLACEMENT_KEEP_IOU: f32 = 0.85;

/// The new frame's weight in the average of the depth maps over time ([`SurfaceSmoother`]).
pub const SURFACE_SMOOTHING: f32 = 0.45;

/// Silhouette IoU between consecutive frames below which the average over time restarts.
pub const SURFACE_RESET_IOU: f32 = 0.6;

/// An exponential average over frames of one-shell depth maps: where a pixel is the person's in this frame and
/// the last, its front and back move `weight` of the way to the new depths; elsewhere the new depths stand. A new
/// size, or a silhouette whose IoU with the last is below `reset_iou`, restarts it.
#[derive(Clone, Debug)]
pub struct SurfaceSmoother {
    weight: f32,
    reset_iou: f32,
    last: Option<InflatedSurfaces>,
}

impl SurfaceSmoother {
    /// A smoother with the new frame's `weight` (1 = none) and the restart threshold `reset_iou`.
    pub fn new(weight: f32, reset_iou: f32) -> Self {
        Self { weight: weight.clamp(0.0, 1.0), reset_iou, last: None }
    }

    /// The averaged surfaces for this frame (kept for the next).
    pub fn update(&mut self, mut surfaces: InflatedSurfaces) -> InflatedSurfaces {
        let same_grid = |a: &InflatedSurfaces| {
            (a.mask.width, a.mask.height) == (surfaces.mask.width, surfaces.mask.height)
                && a.mask.data.len() == surfaces.mask.data.len()
        };
        if let Some(last) = self.last.as_ref().filter(|l| same_grid(l)) {
            if mask_iou(&last.mask, &surfaces.mask) >= self.reset_iou {
                let w = self.weight;
                for i in 0..surfaces.mask.data.len() {
                    if surfaces.mask.data[i] > 0.5 && last.mask.data[i] > 0.5 {
                        let front = w * surfaces.front.data[i] + (1.0 - w) * last.front.data[i];
                        let back = w * surfaces.back.data[i] + (1.0 - w) * last.back.data[i];
                        // Both averages keep back <= front (each input interval is ordered).
                        surfaces.front.data[i] = front;
                        surfaces.back.data[i] = back.min(front);
                    }
                }
            }
        }
        self.last = Some(surfaces.clone());
        surfaces
    }

    /// Forgets the last frame.
    pub fn reset(&mut self) {
        self.last = None;
    }
}

/// The frame path's state across the frames of one source: the options, the average of the depth maps over time,
/// the last face read for the back image, and the body placement carried between its refreshes.
pub struct FramePath {
    options: PrepareOptions,
    smoother: SurfaceSmoother,
    frames: u64,
    face: Option<(u64, FacePoints)>,
    /// The region the last face read came from and how many tracked reads in a row it has served
    /// ([`FULL_FACE_READ_EVERY`]).
    face_region: Option<(PoseRegion, u64)>,
    back: Option<KeptBack>,
    placement: Option<Placement>,
    pending: Option<std::thread::JoinHandle<PlacementResult>>,
    refresh: PlacementRefresh,
    /// Whether frames come with their mesh, source view and coarse mesh ([`FramePath::without_meshes`]).
    meshes: bool,
}

/// Where a frame path makes a new body placement once the first frame has one ([`FramePath::set_refresh`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlacementRefresh {
    /// On a thread of its own; frames carry the last placement until the new one is ready (live sources: no frame
    /// waits for the fit).
    Background,
    /// On the frame it is due on (`render --video`, which draws every frame: the same frames give the same output).
    Inline,
}

/// A body placement made in the background, with how long it took; or why none was made.
type PlacementResult = Result<(Placement, std::time::Duration), PipelineError>;

/// What the body placement changed on one frame's inflation prior, carried to the frames after it: per pixel of the
/// normalised frame, the placed front and back depths ([`body_placed_surfaces`]: the fitted body's depths and the
/// face relief) minus that frame's own inflation prior, filled outside its silhouette from the nearest pixel inside
/// (a pixel the person gains is placed like its neighbour).
#[derive(Clone, Debug)]
struct Placement {
    frame: u64,
    mask: GrayImage,
    front: GrayImage,
    back: GrayImage,
}

impl Placement {
    /// The offsets of `placed` from `inflated` (both one frame's depth-centred surfaces on the same grid).
    fn of(frame: u64, inflated: &InflatedSurfaces, placed: &InflatedSurfaces) -> Self {
        let n = inflated.mask.data.len();
        let inside = |i: usize| {
            inflated.mask.data[i] > 0.5
                && placed.mask.data.get(i).is_some_and(|&m| m > 0.5)
                && placed.front.data[i].is_finite()
                && placed.back.data[i].is_finite()
        };
        let (w, h) = (inflated.mask.width, inflated.mask.height);
        let same_grid = (placed.mask.width, placed.mask.height) == (w, h) && placed.front.data.len() == n;
        let seeds: Vec<usize> = if same_grid { (0..n).filter(|&i| inside(i)).collect() } else { Vec::new() };
        let source = nearest_seed(w, h, &seeds);
        let offset = |placed: &GrayImage, inflated: &GrayImage| GrayImage {
            width: w,
            height: h,
            data: source.iter().map(|s| s.map_or(0.0, |k| placed.data[k] - inflated.data[k])).collect(),
        };
        Self {
            frame,
            mask: inflated.mask.clone(),
            front: offset(&placed.front, &inflated.front),
            back: offset(&placed.back, &inflated.back),
        }
    }

    /// Whether it may be carried to frame `frame` with person mask `mask`, and whether a new one is due.
    fn serves(&self, frame: u64, mask: &GrayImage) -> (bool, bool) {
        let iou = mask_iou(&self.mask, mask);
        let carried = iou >= PLACEMENT_KEEP_IOU;
        (carried, !carried || frame - self.frame >= PLACEMENT_EVERY)
    }

    /// `surfaces` (a frame's inflation prior on the same grid) moved by the offsets; the back never in front of the
    /// front.
    fn apply(&self, mut surfaces: InflatedSurfaces) -> InflatedSurfaces {
        if surfaces.front.data.len() != self.front.data.len() {
            return surfaces;
        }
        for i in 0..surfaces.mask.data.len() {
            if surfaces.mask.data[i] > 0.5 {
                let front = surfaces.front.data[i] + self.front.data[i];
                let back = surfaces.back.data[i] + self.back.data[i];
                surfaces.front.data[i] = front;
                surfaces.back.data[i] = back.min(front);
            }
        }
        surfaces
    }
}

/// For every pixel of a `w` x `h` grid, the seed pixel (an index into the grid) nearest to it in steps along rows
/// and columns (a breadth-first search from all seeds at once); `None` everywhere when there are no seeds.
fn nearest_seed(w: usize, h: usize, seeds: &[usize]) -> Vec<Option<usize>> {
    let mut source: Vec<Option<usize>> = vec![None; w * h];
    let mut queue = std::collections::VecDeque::with_capacity(w * h);
    for &k in seeds {
        source[k] = Some(k);
        queue.push_back(k);
    }
    while let Some(k) = queue.pop_front() {
        let (c, r) = (k % w, k / w);
        let neighbours =
            [(c > 0).then(|| k - 1), (c + 1 < w).then(|| k + 1), (r > 0).then(|| k - w), (r + 1 < h).then(|| k + w)];
        for n in neighbours.into_iter().flatten() {
            if source[n].is_none() {
                source[n] = source[k];
                queue.push_back(n);
            }
        }
    }
    source
}

/// A back image kept from an earlier frame: its layers before the mask ([`BackLayers`]) and their side image
/// (straight, [`warp::SideImages::of_straight`]), each frame masked by its own silhouette; with the mask it was made
/// on.
struct KeptBack {
    frame: u64,
    mask: GrayImage,
    layers: BackLayers,
    side: RgbImage,
}

impl KeptBack {
    /// Whether it still serves frame `frame` with person mask `mask`.
    fn serves(&self, frame: u64, mask: &GrayImage) -> bool {
        frame - self.frame < BACK_IMAGE_EVERY && mask_iou(&self.mask, mask) >= BACK_KEEP_IOU
    }
}

/// IoU of two masks' pixels above 0.5 (0 for masks of different sizes, 1 for two empty ones): how much a person's
/// silhouette changed between two frames, which decides whether what was made on the older one still serves.
pub fn mask_iou(a: &GrayImage, b: &GrayImage) -> f32 {
    if a.data.len() != b.data.len() || (a.width, a.height) != (b.width, b.height) {
        return 0.0;
    }
    crate::capture::morph::iou_soft(a, b)
}

impl FramePath {
    /// A frame path preparing with `options` (geometry [`GeometryMode::for_frames`]; the body fit warm-started from
    /// the frame before).
    pub fn new(options: PrepareOptions) -> Self {
        let options = PrepareOptions { warm_start: true, geometry: options.geometry.for_frames(), ..options };
        Self {
            options,
            smoother: SurfaceSmoother::new(SURFACE_SMOOTHING, SURFACE_RESET_IOU),
            frames: 0,
            face: None,
            face_region: None,
            back: None,
            placement: None,
            pending: None,
            refresh: PlacementRefresh::Background,
            meshes: true,
        }
    }

    /// This path preparing frames without their mesh, source view and coarse mesh (an empty mesh and source view,
    /// no coarse mesh), for a caller that changes the surfaces first (the person model,
    /// [`super::person_model::PersonModel::update`]) and then makes them once with [`finish_meshes`]: a frame's
    /// meshing costs about as much as the person model's own.
    pub fn without_meshes(mut self) -> Self {
        self.meshes = false;
        self
    }

    /// Where this path makes a new body placement once the first frame has one (default
    /// [`PlacementRefresh::Background`]).
    pub fn set_refresh(&mut self, refresh: PlacementRefresh) {
        self.refresh = refresh;
    }

    /// The options frames are prepared with.
    pub fn options(&self) -> &PrepareOptions {
        &self.options
    }

    /// Whether this path's geometry has one shell per column, so frames skip the FOF ([`GeometryMode::Inflate`],
    /// [`GeometryMode::BodyPlaced`], and a body-placed mode without its body prior).
    pub fn meshes_directly(&self) -> bool {
        one_shell(&self.options)
    }

    /// Prepares one frame (linear RGB, its person mask in `[0, 1]`).
    pub fn prepare(&mut self, rgb: &RgbImage, mask: &GrayImage) -> Result<PreparedInput, PipelineError> {
        let mut timings = StageTimings::default();
        let normalised = timings.time("normalise", || input::normalise(rgb, mask, self.options.resolution))?;
        self.prepare_normalised(normalised, timings)
    }

    /// [`FramePath::prepare`] of an input already normalised, adding to `timings`.
    pub fn prepare_normalised(
        &mut self,
        normalised: NormalisedInput,
        mut timings: StageTimings,
    ) -> Result<PreparedInput, PipelineError> {
        self.frames += 1;
        let opts = &self.options;
        if !one_shell(opts) {
            static SAID: AtomicBool = AtomicBool::new(false);
            warn_once(
                &SAID,
                &format!(
                    "frames: --geometry {} can give a column more than one shell; its frames take the still path \
                     (FOF and marching cubes), which is slower",
                    opts.geometry.name()
                ),
            );
            let fof = compute_geometry(&normalised, opts, &mut timings)?;
            return PreparedInput::from_fof(normalised, fof, opts, timings);
        }
        // The rim's colours are only read by the colour stages: they are cleaned beside the geometry, which reads
        // the mask (and, fitting a body, the photo as it came).
        let rim = input::RIM_FRACTION * opts.resolution as f32;
        let (mut geometry_timings, mut rim_timings) = (StageTimings::default(), StageTimings::default());
        let copy = normalised.clone();
        let (geometry, cleaned) = rayon::join(
            || inflation_surfaces_coarse(&normalised, opts, FRAME_INFLATION_FACTOR, &mut geometry_timings),
            || rim_timings.time("rim colours", || input::interior_colours_at_the_rim(copy, rim)),
        );
        timings.0.extend(geometry_timings.0.into_iter().chain(rim_timings.0));
        let surfaces = self.placed(&normalised, geometry?, &mut timings)?;
        let surfaces = timings.time("smooth geometry", || self.smoother.update(surfaces));
        let frame = self.frames;
        // A back image made on a frame like this one serves it; the face is read only for a new one.
        let kept = self.back.take().filter(|k| k.serves(frame, &normalised.mask));
        let face = match kept {
            Some(_) => None,
            None => self.face_for_back(&normalised, &mut timings),
        };
        drop(normalised);
        let normalised = cleaned;
        let opts = &self.options;
        let source_camera = Camera::source(opts.resolution);
        let mut colour_timings = StageTimings::default();
        let meshes = self.meshes;
        let (geometry, (normalised, kept, side)) = rayon::join(
            || -> Result<_, PipelineError> {
                let mut t = StageTimings::default();
                if !meshes {
                    return Ok((TriMesh::default(), GBuffer::default(), None, t));
                }
                let (mesh, source, coarse) = meshes_of(&surfaces, opts, &mut t)?;
                Ok((mesh, source, coarse, t))
            },
            || {
                let kept = match kept {
                    Some(k) => Some(k),
                    None if opts.back_pose.is_some() => {
                        back_layers_from_face(&normalised, face.as_ref(), &mut colour_timings).map(|layers| {
                            let side = colour_timings
                                .time("side images (back)", || warp::SideImages::of_straight(&layers.colour));
                            KeptBack { frame, mask: normalised.mask.clone(), layers, side }
                        })
                    }
                    None => None,
                };
                let (back, side) = colour_timings.time("side images", || {
                    let mask = &normalised.mask;
                    let back = kept.as_ref().and_then(|k| k.layers.masked(mask));
                    let back_side = kept.as_ref().map(|k| warp::premultiplied(&k.side, mask));
                    (back, warp::SideImages::with_back_side(&normalised.rgb, back_side, mask, FRAME_SIDE_FACTOR))
                });
                (normalised, kept, (back, side))
            },
        );
        let (back, side) = side;
        let (mesh, source_gbuffer, coarse, geometry_timings) = geometry?;
        timings.0.extend(geometry_timings.0.into_iter().chain(colour_timings.0));
        self.back = kept;
        Ok(PreparedInput {
            source_camera,
            normalised,
            fof: None,
            surfaces: Some(surfaces),
            mesh,
            // Two height fields joined by a wall along every outline edge (`mesh_from_surfaces`).
            mesh_closed: true,
            coarse,
            source_gbuffer,
            back,
            side,
            timings,
        })
    }

    /// A frame's one-shell surfaces from its inflation prior `inflated`: under [`GeometryMode::BodyPlaced`] with its
    /// body prior loaded, moved by the body placement — made on this frame when there is none to carry (the first
    /// frame, or the person moved too much: [`PLACEMENT_KEEP_IOU`]), else the last one carried while a new one is
    /// made every [`PLACEMENT_EVERY`] frames (in the background unless [`FramePath::set_refresh`] says inline).
    fn placed(
        &mut self,
        normalised: &NormalisedInput,
        inflated: InflatedSurfaces,
        timings: &mut StageTimings,
    ) -> Result<InflatedSurfaces, PipelineError> {
        let Some(body) =
            self.options.body.clone().filter(|_| self.options.geometry.resolved() == GeometryMode::BodyPlaced)
        else {
            return Ok(inflated);
        };
        let frame = self.frames;
        if self.pending.as_ref().is_some_and(|p| p.is_finished()) {
            self.take_pending(timings);
        }
        let (carried, due) = match &self.placement {
            Some(p) => p.serves(frame, &normalised.mask),
            None => (false, true),
        };
        let inline = !carried || self.refresh == PlacementRefresh::Inline;
        if due && inline {
            if let Some(pending) = self.pending.take() {
                // Made on an older frame: this frame makes its own.
                drop(pending);
            }
            let placed = body_placed_surfaces(normalised, &self.options, &body, timings)?;
            let placement = timings.time("body placement (offsets)", || Placement::of(frame, &inflated, &placed));
            self.placement = Some(placement);
            return Ok(placed);
        }
        if due && self.pending.is_none() {
            let (normalised, options, inflated) = (normalised.clone(), self.options.clone(), inflated.clone());
            self.pending = Some(std::thread::spawn(move || {
                let started = std::time::Instant::now();
                let mut ignored = StageTimings::default();
                let placed = body_placed_surfaces(&normalised, &options, &body, &mut ignored)?;
                Ok((Placement::of(frame, &inflated, &placed), started.elapsed()))
            }));
        }
        let placement = self.placement.as_ref().filter(|_| carried);
        Ok(match placement {
            Some(p) => timings.time("body placement (carried)", || p.apply(inflated)),
            None => inflated,
        })
    }

    /// Takes the body placement made in the background, said as the stage "body placement (background)"; one made
    /// on a frame older than the one carried is dropped, a failed one said once.
    fn take_pending(&mut self, timings: &mut StageTimings) {
        let Some(pending) = self.pending.take() else { return };
        match pending.join() {
            Ok(Ok((placement, took))) => {
                timings.0.push(("body placement (background)", took));
                if self.placement.as_ref().is_none_or(|p| p.frame < placement.frame) {
                    self.placement = Some(placement);
                }
            }
            Ok(Err(e)) => {
                static SAID: AtomicBool = AtomicBool::new(false);
                warn_once(&SAID, &format!("frames: a body placement failed ({e}); the last one is carried"));
            }
            Err(_) => {
                static SAID: AtomicBool = AtomicBool::new(false);
                warn_once(&SAID, "frames: a body placement stopped unexpectedly; the last one is carried");
            }
        }
    }

    /// The face the back image is drawn around, whatever the geometry (a body fit's read is in another frame and
    /// would change the back image with the geometry, as on stills: [`super::still::back_image_with`]): the last
    /// read while it is younger than [`BACK_FACE_EVERY`] frames, else a new read by the back image's pose network.
    fn face_for_back(&mut self, normalised: &NormalisedInput, timings: &mut StageTimings) -> Option<FacePoints> {
        let net = self.options.back_pose.as_ref()?;
        match self.face {
            Some((at, face)) if self.frames - at < BACK_FACE_EVERY => Some(face),
            _ => {
                // Warm-started on the last read's region (one network run), with a full read every
                // FULL_FACE_READ_EVERY reads so a drifting track cannot persist.
                let (region, tracked) = match self.face_region {
                    Some((r, n)) if n + 1 < FULL_FACE_READ_EVERY => (Some(r), n + 1),
                    _ => (None, 0),
                };
                let (face, read_on) = read_face_near(normalised, net, region, timings);
                self.face_region = read_on.map(|r| (r, tracked));
                // No face found is remembered as well: the next read is due in BACK_FACE_EVERY frames either way.
                self.face = face.map(|f| (self.frames, f));
                face
            }
        }
    }

    /// Forgets what earlier frames left (a new shot): the average over time, the face and the back image.
    pub fn reset(&mut self) {
        self.smoother.reset();
        self.face = None;
        self.face_region = None;
        self.back = None;
        self.placement = None;
        self.pending = None;
    }
}

/// Whether the geometry `opts` draws has one shell per column.
fn one_shell(opts: &PrepareOptions) -> bool {
    match opts.geometry.resolved() {
        GeometryMode::Body | GeometryMode::FofNet => false,
        // `resolved` never gives Auto; the one-shell modes mesh directly.
        GeometryMode::Inflate | GeometryMode::BodyPlaced | GeometryMode::Auto => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn surfaces(mask: &[f32], front: &[f32], back: &[f32]) -> InflatedSurfaces {
        let n = mask.len();
        InflatedSurfaces {
            front: GrayImage { width: n, height: 1, data: front.to_vec() },
            back: GrayImage { width: n, height: 1, data: back.to_vec() },
            mask: GrayImage { width: n, height: 1, data: mask.to_vec() },
        }
    }

    #[test]
    fn the_smoother_averages_where_the_person_stays_and_restarts_on_a_cut() {
        let mut s = SurfaceSmoother::new(0.6, 0.5);
        let first = surfaces(&[1.0, 1.0, 1.0, 0.0], &[0.5, 0.5, 0.5, -1.0], &[-0.5, -0.5, -0.5, -1.0]);
        assert_eq!(s.update(first.clone()), first);
        // Pixel 2 leaves, pixel 3 joins: IoU 2/4 = 0.5, not below the threshold.
        let second = surfaces(&[1.0, 1.0, 0.0, 1.0], &[0.0, 0.3, -1.0, 0.2], &[-0.2, -0.3, -1.0, -0.2]);
        let out = s.update(second);
        // 0.6 new + 0.4 old where both hold the person; the new depths elsewhere.
        let want_front = [0.6 * 0.0 + 0.4 * 0.5, 0.6 * 0.3 + 0.4 * 0.5, -1.0, 0.2];
        let want_back = [0.6 * -0.2 + 0.4 * -0.5, 0.6 * -0.3 + 0.4 * -0.5, -1.0, -0.2];
        for i in 0..4 {
            assert!((out.front.data[i] - want_front[i]).abs() < 1e-6, "{i}");
            assert!((out.back.data[i] - want_back[i]).abs() < 1e-6, "{i}");
        }
        // A cut (IoU 0 with the last): the new frame as it is.
        let cut = surfaces(&[0.0, 0.0, 1.0, 0.0], &[-1.0, -1.0, 0.9, -1.0], &[-1.0, -1.0, 0.1, -1.0]);
        assert_eq!(s.update(cut.clone()), cut);
        // Another size: as it is too.
        let wide = surfaces(&[1.0; 6], &[0.1; 6], &[-0.1; 6]);
        assert_eq!(s.update(wide.clone()), wide);
    }

    #[test]
    fn nearest_seed_fills_from_the_closest_seed() {
        // 5 x 1 with seeds at 0 and 4: 1 takes 0, 3 takes 4, 2 is as far from both and takes the first reached.
        let s = nearest_seed(5, 1, &[0, 4]);
        assert_eq!(&s[..2], &[Some(0), Some(0)]);
        assert_eq!(&s[3..], &[Some(4), Some(4)]);
        assert!(s[2] == Some(0) || s[2] == Some(4));
        // 3 x 3 with one seed in the middle: every pixel takes it.
        assert!(nearest_seed(3, 3, &[4]).iter().all(|&k| k == Some(4)));
        // No seeds: none anywhere; an empty grid: nothing.
        assert!(nearest_seed(4, 2, &[]).iter().all(Option::is_none));
        assert!(nearest_seed(0, 0, &[]).is_empty());
    }

    #[test]
    fn a_placement_carries_its_offsets_to_a_frame_that_grew() {
        // Made on pixels 0..3 (pixel 3 outside): the placed surfaces are the inflated ones moved by +0.1 / -0.2 at
        // the front, +0.1 / 0.0 at the back.
        let inflated = surfaces(&[1.0, 1.0, 1.0, 0.0], &[0.3, 0.4, 0.3, -1.0], &[-0.3, -0.4, -0.3, -1.0]);
        let placed = surfaces(&[1.0, 1.0, 1.0, 0.0], &[0.4, 0.2, 0.4, -1.0], &[-0.2, -0.4, -0.2, -1.0]);
        let p = Placement::of(7, &inflated, &placed);
        // Pixel 3 takes pixel 2's offsets.
        let want_front = [0.1, -0.2, 0.1, 0.1];
        let want_back = [0.1, 0.0, 0.1, 0.1];
        for i in 0..4 {
            assert!((p.front.data[i] - want_front[i]).abs() < 1e-6, "front {i}");
            assert!((p.back.data[i] - want_back[i]).abs() < 1e-6, "back {i}");
        }
        // The next frame: the person grew into pixel 3 and left pixel 0.
        let next = surfaces(&[0.0, 1.0, 1.0, 1.0], &[-1.0, 0.5, 0.5, 0.05], &[-1.0, -0.5, -0.5, 0.0]);
        let out = p.apply(next);
        let want_front = [-1.0, 0.3, 0.6, 0.15];
        // Pixel 3: front 0.05 + 0.1, back 0.0 + 0.1 (still behind it).
        let want_back = [-1.0, -0.5, -0.4, 0.1];
        for i in 0..4 {
            assert!((out.front.data[i] - want_front[i]).abs() < 1e-6, "front {i}: {}", out.front.data[i]);
            assert!((out.back.data[i] - want_back[i]).abs() < 1e-6, "back {i}: {}", out.back.data[i]);
        }
        // A back pushed in front of the front is held at the front.
        let thin = surfaces(&[1.0, 1.0, 1.0, 1.0], &[0.0; 4], &[-0.05; 4]);
        let pushed = Placement { back: GrayImage { width: 4, height: 1, data: vec![0.3; 4] }, ..p.clone() };
        let out = pushed.apply(thin);
        assert!(out.back.data.iter().zip(&out.front.data).all(|(b, f)| b <= f));
        // Whether it is carried, and whether a new one is due.
        let mask = |m: &[f32]| GrayImage { width: m.len(), height: 1, data: m.to_vec() };
        assert_eq!(p.serves(8, &mask(&[1.0, 1.0, 1.0, 0.0])), (true, false));
        assert_eq!(p.serves(7 + PLACEMENT_EVERY, &mask(&[1.0, 1.0, 1.0, 0.0])), (true, true));
        // IoU 2/4 = 0.5 < PLACEMENT_KEEP_IOU: not carried, due at once.
        assert_eq!(p.serves(8, &mask(&[0.0, 1.0, 1.0, 1.0])), (false, true));
        // Another grid: offsets of nothing, and a frame of another size passes unchanged.
        let other = surfaces(&[1.0; 6], &[0.1; 6], &[-0.1; 6]);
        assert_eq!(p.apply(other.clone()), other);
    }

    #[test]
    fn multi_shell_modes_take_the_still_path() {
        for (mode, direct) in [
            (GeometryMode::Inflate, true),
            (GeometryMode::BodyPlaced, true),
            (GeometryMode::Body, false),
            (GeometryMode::FofNet, false),
        ] {
            let path = FramePath::new(PrepareOptions { geometry: mode, ..Default::default() });
            assert_eq!(path.meshes_directly(), direct, "{mode:?}");
        }
        // Auto on frames draws what FRAMES_AUTO_CHOICE says, which meshes directly.
        let auto = FramePath::new(PrepareOptions { geometry: GeometryMode::Auto, ..Default::default() });
        assert_eq!(auto.options().geometry, super::super::FRAMES_AUTO_CHOICE);
        assert!(auto.meshes_directly());
    }
}
