//! Offline rendering, the use cases of `render` (one view, `--orbit`, `--video`), `demo` and `export`: load the
//! photo, prepare the person, render the views on the chosen backend — the Vulkan passes
//! ([`crate::gpu::offline`]) or the CPU reference — through the one person-renderer policy, and write the files.
//! Each command is one function ([`render`], [`demo`], [`export`]) that returns what it wrote; the CLI prints it.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _, Result};
use indicatif::{ProgressBar, ProgressStyle};

use super::live::{render_video_views, LiveOptions, RenderReport};
use super::neural::NeuralSetup;
use super::{log_software_device, Backend};
use crate::buffer::{GrayImage, Image, RgbImage};
use crate::capture::segment::segment_photo;
use crate::capture::{open_video_path, SegmentMethod};
use crate::compose::{Mode, RenderedFrame};
use crate::geometry::Camera;
use crate::gpu::{offline, Context, GpuError};
use crate::io::environment::Environment;
use crate::io::image_io::{self, LoadedImage};
use crate::io::sequence;
use crate::pipeline::export::{ExportOptions, ExportReport};
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{
    load_body_for, load_fof_net, load_renderer, GeometryMode, NeuralRequest, PrepareOptions, PreparedInput,
    SharedNeural, SourceView, StageTimings, ViewRenderer,
};

/// The person image embedded in the binary for `demo` (a synthetic CC0 subject with alpha; see assets/CREDITS.md).
pub const DEFAULT_PERSON_PNG: &[u8] = include_bytes!("../../assets/demo/person.png");

/// The most views of an orbit (`render --orbit`, `demo --frames`).
pub const MAX_ORBIT_VIEWS: usize = 720;

/// How the person is reconstructed: `--geometry`, `--fill`, `--fof-order` (shared by rendering and export).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeometryOptions {
    /// Where the geometry comes from (inflation prior, FOF network, body prior).
    pub geometry: GeometryMode,
    /// How surfaces the photo does not show are coloured.
    pub fill: OcclusionFill,
    /// Number of Fourier occupancy coefficients (FOF-X N), 2 to 256.
    pub fof_order: usize,
    /// Whether a video's frames keep the person model across them ([`crate::pipeline::person_model`]).
    pub person_model: bool,
}

impl GeometryOptions {
    /// Checks the FOF order.
    pub fn check(&self) -> Result<()> {
        if !(2..=256).contains(&self.fof_order) {
            bail!("--fof-order {} is out of range: use 2 to 256 (32 is the reference's choice)", self.fof_order);
        }
        Ok(())
    }

    /// The per-input options (loads the FOF network or the body prior when the geometry mode asks for it, from
    /// `models` or the project's models/tiny).
    fn prepare_options(
        &self,
        models: Option<&Path>,
        runtime: &crate::neural::RuntimeOptions,
    ) -> Result<PrepareOptions> {
        let fof_net = load_fof_net(self.geometry, models, self.fof_order, runtime)?;
        let body = load_body_for(self.geometry, fof_net.as_ref(), runtime)?;
        let placement = crate::pipeline::load_placement_net(self.geometry, models, self.fof_order, runtime)?;
        let back_pose = crate::pipeline::load_back_pose(self.fill, runtime);
        Ok(PrepareOptions {
            fof_order: self.fof_order,
            geometry: self.geometry,
            fof_net,
            body,
            placement,
            back_pose,
            person_model: self.person_model,
            ..Default::default()
        })
    }
}

/// Everything that shapes a rendered view (the CLI's rendering options).
#[derive(Clone, Debug)]
pub struct ViewSetup {
    /// Panorama behind the person in VR (`None`: the embedded one; not read in AR).
    pub env: Option<PathBuf>,
    /// VR composite or AR layer.
    pub mode: Mode,
    /// Output width and height in pixels, 16 to 4096.
    pub size: usize,
    /// Camera pitch in degrees.
    pub pitch: f32,
    /// How the person is reconstructed.
    pub geometry: GeometryOptions,
    /// Which renderer draws the person (and the model folder of the FOF network).
    pub neural: NeuralSetup,
}

impl ViewSetup {
    /// Checks size, pitch and FOF order before any work is done.
    pub fn check(&self) -> Result<()> {
        if !(16..=4096).contains(&self.size) {
            bail!("--size {} is out of range: use 16 to 4096 pixels", self.size);
        }
        if !self.pitch.is_finite() {
            bail!("--pitch must be a finite number of degrees");
        }
        self.geometry.check()
    }

    /// The panorama (a blank one in AR, which never reads it).
    fn environment(&self) -> Result<Environment> {
        match (&self.env, self.mode) {
            // AR needs no panorama: do not even read it.
            (_, Mode::Ar) => Ok(Environment { image: Image::new(2, 1, glam::Vec3::ZERO), yaw: 0.0 }),
            (Some(p), Mode::Vr) => Ok(Environment::load(p)?),
            (None, Mode::Vr) => Ok(Environment::default_embedded()),
        }
    }

    /// The neural renderer asked for (`None`: geometric).
    fn neural(&self) -> Result<Option<SharedNeural>> {
        Ok(load_renderer(self.neural.choice, self.neural.models.as_deref(), &self.neural.options)?)
    }

    /// The per-input options of the geometry (the FOF network from `--models`, with `--ep`).
    fn prepare_options(&self) -> Result<PrepareOptions> {
        self.geometry.prepare_options(self.neural.models.as_deref(), &self.neural.options)
    }

    /// Prepares one photo (the stage timings go to the log).
    fn prepare(&self, photo: &LoadedImage, mask: &GrayImage) -> Result<PreparedInput> {
        let prepared = PreparedInput::prepare(&photo.rgb, mask, &self.prepare_options()?)?;
        for (name, d) in &prepared.timings.0 {
            tracing::info!("{name}: {:.1} ms", d.as_secs_f64() * 1e3);
        }
        Ok(prepared)
    }

    /// The camera at `yaw` degrees.
    fn camera(&self, yaw: f32) -> Camera {
        Camera::orbit(yaw, self.pitch, self.size, self.size)
    }
}

/// What `render` reads.
#[derive(Clone, Debug)]
pub enum RenderInput {
    /// One photo, the person found by `mask` (white = person) or the segmentation method.
    Photo {
        /// The photo.
        path: PathBuf,
        /// A person mask of the photo's size; wins over the segmentation method.
        mask: Option<PathBuf>,
    },
    /// A video file or a folder of frames: one view per input frame.
    Video(PathBuf),
}

/// `r2human render`: what to render, how, and where to.
#[derive(Clone, Debug)]
pub struct RenderJob {
    /// The photo or the video.
    pub input: RenderInput,
    /// How the person is told from the background.
    pub segment: SegmentMethod,
    /// Camera yaw in degrees (the first view of an orbit).
    pub yaw: f32,
    /// `Some(n)`: an orbit of `n` views into the folder `out`; `None`: one view into the PNG `out`.
    pub orbit: Option<usize>,
    /// Output PNG (one view) or folder (orbit, video).
    pub out: PathBuf,
    /// Engine for photo views.
    pub backend: Backend,
    /// The view's options.
    pub view: ViewSetup,
}

/// What a command wrote (its `Display` is the summary the CLI prints).
#[derive(Debug)]
pub enum Written {
    /// One view.
    View(PathBuf),
    /// An orbit: `views` PNGs, orbit.gif and contact_sheet.png in the folder.
    Orbit {
        /// The folder.
        dir: PathBuf,
        /// Number of views.
        views: usize,
    },
    /// `render --video`: one PNG per usable input frame.
    Video {
        /// The output folder.
        dir: PathBuf,
        /// What happened to each frame.
        report: RenderReport,
        /// `neural` or `geometric`.
        renderer: &'static str,
    },
    /// `demo`: an orbit, and what the input cost.
    Demo {
        /// The orbit written.
        orbit: Box<Written>,
        /// Time of the per-input stages.
        prepare_ms: f64,
        /// Triangles of the person's mesh.
        triangles: usize,
    },
    /// `export`: the glTF file.
    Export {
        /// The .glb file.
        path: PathBuf,
        /// What went into it.
        report: ExportReport,
        /// Time of every stage: loading and segmenting the photo, reconstruction, the export's own stages.
        stages: StageTimings,
    },
}

impl fmt::Display for Written {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Written::View(path) => write!(f, "wrote {}", path.display()),
            Written::Orbit { dir, views } => {
                write!(f, "wrote {views} views, orbit.gif and contact_sheet.png to {}", dir.display())
            }
            Written::Video { dir, report, renderer } => {
                for frame in &report.frames {
                    writeln!(f, "{frame}")?;
                }
                let medians: Vec<String> =
                    report.stages.iter().map(|s| format!("{} {:.1}", s.name, s.median_ms())).collect();
                write!(
                    f,
                    "wrote {} frames to {} with the {renderer} renderer ({} skipped)\nper-frame stage medians (ms): {}",
                    report.written.len(),
                    dir.display(),
                    report.skipped.len(),
                    medians.join(", ")
                )
            }
            Written::Demo { orbit, prepare_ms, triangles } => {
                write!(f, "{orbit}\nper-input stages: {prepare_ms:.0} ms; mesh: {triangles} triangles")
            }
            Written::Export { path, report, stages } => write!(
                f,
                "wrote {}: {report}\nstages: {}; export {:.1} ms",
                path.display(),
                stages.summary(),
                report.timings.total().as_secs_f64() * 1e3
            ),
        }
    }
}

/// `r2human render`: one view, an orbit or one view per video frame, written to `job.out`.
pub fn render(job: &RenderJob) -> Result<Written> {
    job.view.check()?;
    if !job.yaw.is_finite() {
        bail!("--yaw must be a finite number of degrees");
    }
    if let Some(n) = job.orbit {
        if !(1..=MAX_ORBIT_VIEWS).contains(&n) {
            bail!("--orbit {n} is out of range: use 1 to {MAX_ORBIT_VIEWS} views");
        }
    }
    let (photo, mask) = match &job.input {
        RenderInput::Video(video) => return render_video(job, video),
        RenderInput::Photo { path, mask } => (path, mask),
    };
    let person = segment_photo(photo, mask.as_deref(), &job.segment)?;
    let env = job.view.environment()?;
    let neural = job.view.neural()?;
    let prepared = job.view.prepare(&person.photo, &person.mask)?;
    let n = job.orbit.unwrap_or(1);
    let cams = orbit_cameras(n, job.yaw, job.view.pitch, job.view.size);
    let (mode, fill) = (job.view.mode, job.view.geometry.fill);
    let frames = match render_on_backend(job.backend, &prepared, &env, &cams, mode, fill, n > 1, neural.as_ref())? {
        Some(frames) => frames,
        None => render_cpu(&prepared, &env, &cams, mode, fill, job.orbit.is_some(), neural.as_ref())?,
    };
    match job.orbit {
        None => {
            frames[0].save_png(&job.out).with_context(|| format!("writing {}", job.out.display()))?;
            Ok(Written::View(job.out.clone()))
        }
        Some(_) => write_orbit(&job.out, &frames),
    }
}

/// `render --video`: one PNG per input frame (frames that cannot be used are skipped, with a warning each).
fn render_video(job: &RenderJob, video: &Path) -> Result<Written> {
    let mut source = open_video_path(video, 25.0)?;
    let neural = job.view.neural()?;
    let live = LiveOptions { segment: job.segment.clone(), ..Default::default() };
    // Frames draw what `--geometry` names; `auto` means the steady inflation prior on frames (FRAMES_AUTO_CHOICE).
    let geometry = GeometryOptions { geometry: job.view.geometry.geometry.for_frames(), ..job.view.geometry };
    if job.view.geometry.geometry == GeometryMode::Auto {
        tracing::info!("video frames: auto draws `{}` (steady between frames)", geometry.geometry.name());
    }
    let prepare = geometry.prepare_options(job.view.neural.models.as_deref(), &job.view.neural.options)?;
    let cam = job.view.camera(job.yaw);
    let fill = job.view.geometry.fill;
    let (report, fallbacks) = render_video_views(
        source.as_mut(),
        &job.segment,
        &live,
        &prepare,
        &cam,
        fill,
        neural.as_ref(),
        &job.out,
        |m| tracing::warn!("{m}"),
    )?;
    if fallbacks > 0 {
        tracing::warn!("the neural decoder failed on {fallbacks} frame(s); the geometric renderer drew them");
    }
    if report.written.is_empty() {
        bail!("no frame could be rendered");
    }
    let renderer = if neural.is_some() { "neural" } else { "geometric" };
    Ok(Written::Video { dir: job.out.clone(), report, renderer })
}

/// `r2human demo`: an orbit of `frames` views of the embedded person into `out`.
pub fn demo(out: &Path, frames: usize, view: &ViewSetup) -> Result<Written> {
    view.check()?;
    if !(1..=MAX_ORBIT_VIEWS).contains(&frames) {
        bail!("--frames {frames} is out of range: use 1 to {MAX_ORBIT_VIEWS}");
    }
    let photo = image_io::load_image_bytes(DEFAULT_PERSON_PNG, "embedded person.png")?;
    let mask = photo.alpha.clone().context("the embedded person image has an alpha channel")?;
    let env = view.environment()?;
    let neural = view.neural()?;
    let prepared = view.prepare(&photo, &mask)?;
    let cams = orbit_cameras(frames, 0.0, view.pitch, view.size);
    let rendered = render_cpu(&prepared, &env, &cams, view.mode, view.geometry.fill, true, neural.as_ref())?;
    let orbit = write_orbit(out, &rendered)?;
    Ok(Written::Demo {
        orbit: Box::new(orbit),
        prepare_ms: prepared.timings.total().as_secs_f64() * 1e3,
        triangles: prepared.mesh.triangle_count(),
    })
}

/// `r2human export`: what to export and where.
#[derive(Clone, Debug)]
pub struct ExportJob {
    /// The photo.
    pub image: PathBuf,
    /// A person mask of the photo's size; wins over the segmentation method.
    pub mask: Option<PathBuf>,
    /// How the person is told from the background.
    pub segment: SegmentMethod,
    /// The .glb file to write.
    pub out: PathBuf,
    /// How the person is reconstructed (the fill colours the texture's hidden side).
    pub geometry: GeometryOptions,
    /// Model folder of the FOF network; default: the project's models/tiny.
    pub models: Option<PathBuf>,
    /// Height and triangle budget (the texture's fill is `geometry.fill`).
    pub options: ExportOptions,
}

/// `r2human export`: the person in a photo as a textured glTF binary.
pub fn export(job: &ExportJob) -> Result<Written> {
    job.geometry.check()?;
    let opts = ExportOptions { fill: job.geometry.fill, ..job.options.clone() };
    opts.validate()?;
    let mut stages = StageTimings::default();
    let person = stages.time("load + segment", || segment_photo(&job.image, job.mask.as_deref(), &job.segment))?;
    let prepare = job.geometry.prepare_options(job.models.as_deref(), &Default::default())?;
    let prepared = PreparedInput::prepare(&person.photo.rgb, &person.mask, &prepare)
        .with_context(|| format!("reconstructing the person in {}", job.image.display()))?;
    let report = crate::pipeline::export::person_glb(&job.out, &prepared, &person.mask, &opts)?;
    stages.0.extend(prepared.timings.0.iter().chain(&report.timings.0).cloned());
    Ok(Written::Export { path: job.out.clone(), report, stages })
}

/// Renders one frame per camera with the CPU reference ([`ViewRenderer`], spatial fusion across the cameras when
/// `fusion`), with a progress bar for more than one view and one warning when the neural decoder failed on some.
fn render_cpu(
    prepared: &PreparedInput,
    env: &Environment,
    cameras: &[Camera],
    mode: Mode,
    fill: OcclusionFill,
    fusion: bool,
    neural: Option<&SharedNeural>,
) -> Result<Vec<RenderedFrame>> {
    let mut renderer = ViewRenderer::for_renderer(prepared, fill, fusion, neural);
    let bar = (cameras.len() > 1).then(|| {
        ProgressBar::new(cameras.len() as u64)
            .with_style(
                ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} views ({elapsed})").expect("valid template"),
            )
            .with_message("rendering")
    });
    let mut frames = Vec::with_capacity(cameras.len());
    for cam in cameras {
        frames.push(renderer.render_frame(cam, mode, env)?);
        if let Some(bar) = &bar {
            bar.inc(1);
        }
    }
    if let Some(bar) = bar {
        bar.finish();
    }
    if renderer.neural_fallbacks() > 0 {
        tracing::warn!(
            "the neural decoder failed on {} view(s); the geometric renderer drew them",
            renderer.neural_fallbacks()
        );
    }
    Ok(frames)
}

/// Writes `DIR/view_000.png` ..., `DIR/orbit.gif` and `DIR/contact_sheet.png`.
pub fn write_orbit(dir: &Path, frames: &[RenderedFrame]) -> Result<Written> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating output folder {}", dir.display()))?;
    for (i, f) in frames.iter().enumerate() {
        f.save_png(&dir.join(format!("view_{i:03}.png")))?;
    }
    let previews: Vec<RgbImage> = frames.iter().map(RenderedFrame::preview).collect();
    sequence::write_gif(&dir.join("orbit.gif"), &previews, 80)?;
    let columns = (frames.len() as f64).sqrt().ceil() as usize;
    sequence::write_contact_sheet(&dir.join("contact_sheet.png"), &previews, columns, 160)?;
    Ok(Written::Orbit { dir: dir.to_path_buf(), views: frames.len() })
}

/// `render --backend`: renders one frame per camera on the chosen backend, with the neural renderer when `neural`
/// is given (through the host-memory seam; views the decoder fails on are drawn geometrically, with a warning).
/// `Ok(None)` means "use the CPU path": the CPU was asked for, `auto` found a software rasteriser or no device
/// (logged), or Vulkan was asked for but no device is usable (the reason is printed once on stderr, with the
/// fallback). Other GPU failures are errors.
#[allow(clippy::too_many_arguments)]
pub fn render_on_backend(
    backend: Backend,
    input: &PreparedInput,
    env: &Environment,
    cameras: &[Camera],
    mode: Mode,
    fill: OcclusionFill,
    fusion: bool,
    neural: Option<&SharedNeural>,
) -> Result<Option<Vec<RenderedFrame>>> {
    if backend == Backend::Cpu {
        return Ok(None);
    }
    // One headless device for the probe of `auto` and for the views.
    let ctx = match Context::headless() {
        Ok(ctx) => ctx,
        Err(e) if backend == Backend::Auto => {
            tracing::info!("no usable Vulkan device ({e}): rendering on the CPU reference");
            return Ok(None);
        }
        Err(e) => return cpu_without_device(e),
    };
    if backend.resolve(ctx.is_software()) == Backend::Cpu {
        log_software_device(ctx.device_name());
        return Ok(None);
    }
    let ctx = Arc::new(ctx);
    let encoded = match neural {
        Some(shared) => match shared.lock().unwrap_or_else(|p| p.into_inner()).encode(input) {
            Ok(e) => Some(e),
            Err(e) => {
                tracing::warn!("the neural encoder failed on this input ({e}); rendering geometrically");
                None
            }
        },
        None => None,
    };
    // An input the encoder failed on is drawn geometrically (said above), not counted per view.
    let request = match encoded.as_ref() {
        Some(e) => NeuralRequest::from_parts(neural, Some(e)),
        None => NeuralRequest::Off,
    };
    let settings = offline::ViewSettings { mode, fill, fusion };
    match offline::render_views(ctx, SourceView::of(input), request, env, cameras, settings) {
        Ok((frames, counters)) => {
            if counters.fallbacks > 0 {
                tracing::warn!(
                    "the neural decoder failed on {} view(s); the geometric renderer drew them",
                    counters.fallbacks
                );
            }
            Ok(Some(frames))
        }
        Err(e) => cpu_without_device(e),
    }
}

/// `render --backend vulkan` without a usable device: one warning (the reason and the CPU fallback), `Ok(None)`
/// (the CPU path); any other GPU failure is an error.
fn cpu_without_device(e: GpuError) -> Result<Option<Vec<RenderedFrame>>> {
    match e {
        GpuError::NoVulkan(_) | GpuError::NoDevice(_) => {
            tracing::warn!("{e}; rendering on the CPU instead (--backend cpu)");
            Ok(None)
        }
        e => Err(anyhow::Error::new(e).context("the Vulkan backend failed")),
    }
}

/// The cameras of an orbit: `n` views evenly spaced in yaw from `start_yaw`, at `pitch`, `size x size` (the
/// same views as `r2human render --orbit`).
pub fn orbit_cameras(n: usize, start_yaw: f32, pitch: f32, size: usize) -> Vec<Camera> {
    (0..n).map(|i| Camera::orbit(start_yaw + 360.0 * i as f32 / n.max(1) as f32, pitch, size, size)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_cameras_match_the_render_orbit_spacing() {
        let cams = orbit_cameras(4, 10.0, -5.0, 32);
        assert_eq!(cams.len(), 4);
        for (i, cam) in cams.iter().enumerate() {
            assert_eq!(*cam, Camera::orbit(10.0 + 90.0 * i as f32, -5.0, 32, 32));
        }
        assert!(orbit_cameras(0, 0.0, 0.0, 32).is_empty());
    }
}
