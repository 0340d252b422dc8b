//! `render` and `demo`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use crate::app::offline::{orbit_cameras, render_on_backend};
use crate::app::Backend;
use crate::buffer::GrayImage;
use crate::capture::segment::segment_photo;
use crate::compose::Mode;
use crate::geometry::Camera;
use crate::io::environment::Environment;
use crate::io::image_io::{self, LoadedImage};
use crate::io::sequence::{self, RenderedFrame};
use crate::neural::{ExecutionProvider, RuntimeOptions};
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{
    load_body_for, load_fof_net, load_renderer, GeometryMode, PrepareOptions, PreparedInput, RendererChoice,
    SharedNeural, ViewRenderer,
};

/// The person image embedded in the binary for `demo` (a synthetic CC0 subject with alpha; see assets/CREDITS.md).
pub const DEFAULT_PERSON_PNG: &[u8] = include_bytes!("../../assets/demo/person.png");

/// `--fill`: how occluded surfaces are coloured (see [`OcclusionFill`]).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FillArg {
    /// The back shows the front's colours at the same place (what a person expects from one photo).
    MirroredFront,
    /// Colours diffused inward from the nearest visible pixels.
    Propagate,
}

impl From<FillArg> for OcclusionFill {
    fn from(f: FillArg) -> Self {
        match f {
            FillArg::MirroredFront => OcclusionFill::MirroredFront,
            FillArg::Propagate => OcclusionFill::Propagate,
        }
    }
}

/// Options shared by everything that renders.
#[derive(Args, Debug, Clone)]
pub struct ViewOptions {
    /// 360-degree panorama behind the person in VR mode (equirectangular PNG/JPEG or Radiance .hdr).
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// vr: the person over the panorama; ar: the person alone with alpha, for passthrough.
    #[arg(long, value_enum, default_value_t = Mode::Vr)]
    pub mode: Mode,
    /// Output width and height in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Where the geometry comes from: inflate (silhouette-inflation prior), fofnet (the FOF network in the model
    /// folder correcting that prior; an error without fof.onnx) or auto (fofnet when fof.onnx loads, else inflate
    /// with one warning), or body (the body prior: pose landmarks -> fitted MakeHuman body -> its FOF reconciled with
    /// the silhouette, no FOF network; needs the pose model of scripts/setup.d/live.sh). Default auto: the shipped
    /// FOF net beats the prior in `r2human eval` on geometry and image error (models/tiny/README.md); inflate is
    /// about 0.3 s per input faster on this CPU.
    #[arg(long, value_enum, default_value_t = GeometryMode::Auto)]
    pub geometry: GeometryMode,
    /// How surfaces the photo does not show are coloured.
    #[arg(long, value_enum, default_value_t = FillArg::MirroredFront)]
    pub fill: FillArg,
    /// Number of Fourier occupancy coefficients (FOF-X N).
    #[arg(long, default_value_t = 32)]
    pub fof_order: usize,
    /// Camera pitch in degrees (positive looks down on the person).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub pitch: f32,
    /// Which renderer draws the person.
    #[command(flatten)]
    pub neural: NeuralArgs,
}

/// `--renderer`, `--ep`, `--models`: shared by everything that renders (render, demo, view, xr).
#[derive(Args, Debug, Clone)]
pub struct NeuralArgs {
    /// Which renderer draws the person: geometric (the photo warped through the geometry), neural (encoder +
    /// residual decoder through ONNX Runtime; an error without models) or auto (neural when its models load, else
    /// geometric with one warning).
    #[arg(long, value_enum, default_value_t = RendererChoice::Auto)]
    pub renderer: RendererChoice,
    /// Execution provider of the neural renderer: auto tries TensorRT, then CUDA, then the CPU.
    #[arg(long, value_enum, default_value_t = ExecutionProvider::Auto)]
    pub ep: ExecutionProvider,
    /// Model folder of the neural renderer (encoder.onnx, decoder.onnx) and the FOF network (fof.onnx, for
    /// --geometry fofnet|auto); default: the project's models/tiny.
    #[arg(long)]
    pub models: Option<PathBuf>,
}

impl NeuralArgs {
    /// The options as the interactive paths take them.
    pub fn setup(&self) -> crate::app::neural::NeuralSetup {
        crate::app::neural::NeuralSetup {
            choice: self.renderer,
            models: self.models.clone(),
            options: RuntimeOptions { ep: self.ep, ..Default::default() },
        }
    }
}

/// `--segment` and `--plate`: how the person is told from the background in photos and frames (`--mask` wins).
#[derive(Args, Debug, Clone)]
pub struct SegmentArgs {
    /// Person segmentation: auto (the photo's or frame's alpha when it has a real one, else the segmentation
    /// model), alpha, onnx (the model installed by scripts/setup.d/live.sh) or plate (clean plate: --plate FILE,
    /// or the first frames of a video showing the empty scene). --mask FILE wins over all of them.
    #[arg(long, default_value = "auto")]
    pub segment: String,
    /// A picture of the empty scene (same camera, same place) for --segment plate.
    #[arg(long)]
    pub plate: Option<PathBuf>,
}

impl SegmentArgs {
    /// The segmentation method the options name.
    pub fn method(&self) -> Result<crate::capture::SegmentMethod> {
        Ok(crate::capture::SegmentMethod::from_arg(&self.segment)?.with_plate(self.plate.as_deref()))
    }
}

/// Loads the neural renderer the options ask for (`None`: geometric).
fn neural_for(view: &ViewOptions) -> Result<Option<SharedNeural>> {
    let setup = view.neural.setup();
    Ok(load_renderer(setup.choice, setup.models.as_deref(), &setup.options)?)
}

fn report_fallbacks(renderer: &ViewRenderer<'_>) {
    if renderer.neural_fallbacks() > 0 {
        eprintln!(
            "warning: the neural decoder failed on {} view(s); the geometric renderer drew them",
            renderer.neural_fallbacks()
        );
    }
}

/// Arguments of `render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Photo of a person (PNG/JPEG); the person is found by --mask or --segment.
    #[arg(long, required_unless_present = "video")]
    pub image: Option<PathBuf>,
    /// A video file or a folder of frames (photos of any sizes) instead of --image: writes one PNG per input
    /// frame into --out.
    #[arg(long, conflicts_with_all = ["image", "orbit"])]
    pub video: Option<PathBuf>,
    /// How the person is found.
    #[command(flatten)]
    pub segment: SegmentArgs,
    /// Person mask (white = person), same size as the image; wins over --segment.
    #[arg(long, conflicts_with = "video")]
    pub mask: Option<PathBuf>,
    /// Camera yaw in degrees around the person (0 = the photo's viewpoint, 180 = from behind).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub yaw: f32,
    /// Render an orbit of N views around the person into the --out folder instead of one view.
    #[arg(long)]
    pub orbit: Option<usize>,
    /// Output PNG file (one view) or folder (--orbit).
    #[arg(long)]
    pub out: PathBuf,
    /// Engine for --image views: the CPU reference, the Vulkan passes (no Vulkan device: a message and the CPU), or
    /// auto (Vulkan on a GPU, the CPU on a software rasteriser); the neural renderer on Vulkan runs its decoder
    /// through host memory.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    pub backend: Backend,
    /// Rendering options.
    #[command(flatten)]
    pub view: ViewOptions,
}

/// Arguments of `demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Number of views in the orbit.
    #[arg(long, default_value_t = 24)]
    pub frames: usize,
    /// Rendering options.
    #[command(flatten)]
    pub view: ViewOptions,
}

fn check_view_options(v: &ViewOptions) -> Result<()> {
    if !(16..=4096).contains(&v.size) {
        bail!("--size {} is out of range: use 16 to 4096 pixels", v.size);
    }
    if !v.pitch.is_finite() {
        bail!("--pitch must be a finite number of degrees");
    }
    if !(2..=256).contains(&v.fof_order) {
        bail!("--fof-order {} is out of range: use 2 to 256 (32 is the reference's choice)", v.fof_order);
    }
    Ok(())
}

fn load_environment(view: &ViewOptions) -> Result<Environment> {
    match (&view.env, view.mode) {
        // AR needs no panorama: do not even read it.
        (_, Mode::Ar) => Ok(Environment { image: crate::buffer::Image::new(2, 1, glam::Vec3::ZERO), yaw: 0.0 }),
        (Some(p), Mode::Vr) => Ok(Environment::load(p)?),
        (None, Mode::Vr) => Ok(Environment::default_embedded()),
    }
}

/// The per-input options of `--geometry`, `--fof-order`, `--models` and `--ep` (loads the FOF network when the
/// geometry mode asks for it).
fn prepare_options(view: &ViewOptions) -> Result<PrepareOptions> {
    let options = RuntimeOptions { ep: view.neural.ep, ..Default::default() };
    let fof_net = load_fof_net(view.geometry, view.neural.models.as_deref(), view.fof_order, &options)?;
    let body = load_body_for(view.geometry, fof_net.as_ref(), &options)?;
    Ok(PrepareOptions { fof_order: view.fof_order, geometry: view.geometry, fof_net, body, ..Default::default() })
}

fn prepare(photo: &LoadedImage, mask: &GrayImage, view: &ViewOptions) -> Result<PreparedInput> {
    let opts = prepare_options(view)?;
    let prepared = PreparedInput::prepare(&photo.rgb, mask, &opts)?;
    for (name, d) in &prepared.timings.0 {
        tracing::info!("{name}: {:.1} ms", d.as_secs_f64() * 1e3);
    }
    Ok(prepared)
}

/// `r2human render`.
pub fn run_render(args: &RenderArgs) -> Result<()> {
    check_view_options(&args.view)?;
    if !args.yaw.is_finite() {
        bail!("--yaw must be a finite number of degrees");
    }
    if let Some(video) = &args.video {
        return run_render_video(args, video);
    }
    let image = args.image.as_deref().context("--image or --video is required")?;
    let person = segment_photo(image, args.mask.as_deref(), &args.segment.method()?)?;
    let env = load_environment(&args.view)?;
    let neural = neural_for(&args.view)?;
    let prepared = prepare(&person.photo, &person.mask, &args.view)?;
    let (n, fill) = (args.orbit.unwrap_or(1), args.view.fill.into());
    let cams = orbit_cameras(n, args.yaw, args.view.pitch, args.view.size);
    if (1..=720).contains(&n) {
        let mode = args.view.mode;
        if let Some(frames) =
            render_on_backend(args.backend, &prepared, &env, &cams, mode, fill, n > 1, neural.as_ref())?
        {
            return match args.orbit {
                None => {
                    frames[0].save_png(&args.out).map(|_| println!("wrote {}", args.out.display())).map_err(Into::into)
                }
                Some(_) => write_orbit(&args.out, &frames),
            }
            .with_context(|| format!("writing {}", args.out.display()));
        }
    }
    match args.orbit {
        None => {
            let mut renderer = ViewRenderer::for_renderer(&prepared, args.view.fill.into(), false, neural.as_ref());
            let cam = Camera::orbit(args.yaw, args.view.pitch, args.view.size, args.view.size);
            let frame = renderer.render_frame(&cam, args.view.mode, &env)?;
            report_fallbacks(&renderer);
            frame.save_png(&args.out).with_context(|| format!("writing {}", args.out.display()))?;
            println!("wrote {}", args.out.display());
        }
        Some(n) => {
            if !(1..=720).contains(&n) {
                bail!("--orbit {n} is out of range: use 1 to 720 views");
            }
            let frames = render_orbit(&prepared, &args.view, &env, n, args.yaw, neural.as_ref())?;
            write_orbit(&args.out, &frames)?;
        }
    }
    Ok(())
}

/// `render --video`: one PNG per input frame (frames that cannot be used are skipped with a message).
fn run_render_video(args: &RenderArgs, video: &Path) -> Result<()> {
    use crate::app::live::{render_video_views, LiveOptions};
    use crate::capture::open_video_path;
    let segment = args.segment.method()?;
    let mut source = open_video_path(video, 25.0)?;
    let neural = neural_for(&args.view)?;
    let live = LiveOptions { segment: segment.clone(), ..Default::default() };
    let prepare = prepare_options(&args.view)?;
    let cam = Camera::orbit(args.yaw, args.view.pitch, args.view.size, args.view.size);
    let fill = args.view.fill.into();
    let (report, fallbacks) =
        render_video_views(source.as_mut(), &segment, &live, &prepare, &cam, fill, neural.as_ref(), &args.out, |m| {
            eprintln!("warning: {m}")
        })?;
    let renderer = if neural.is_some() { "neural" } else { "geometric" };
    for frame in &report.frames {
        println!("{frame}");
    }
    println!(
        "wrote {} frames to {} with the {renderer} renderer ({} skipped)",
        report.written.len(),
        args.out.display(),
        report.skipped.len()
    );
    if fallbacks > 0 {
        eprintln!("warning: the neural decoder failed on {fallbacks} frame(s); the geometric renderer drew them");
    }
    if report.written.is_empty() {
        bail!("no frame could be rendered");
    }
    Ok(())
}

/// Renders `n` views evenly spaced in yaw starting at `start_yaw`, with spatial fusion across the sequence, with
/// the neural renderer when `neural` is given (else the geometric one).
pub fn render_orbit(
    prepared: &PreparedInput,
    view: &ViewOptions,
    env: &Environment,
    n: usize,
    start_yaw: f32,
    neural: Option<&SharedNeural>,
) -> Result<Vec<RenderedFrame>> {
    let mut renderer = ViewRenderer::for_renderer(prepared, view.fill.into(), true, neural);
    let bar = ProgressBar::new(n as u64).with_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} views ({elapsed})").expect("valid template"),
    );
    bar.set_message("rendering");
    let mut frames = Vec::with_capacity(n);
    for i in 0..n {
        let yaw = start_yaw + 360.0 * i as f32 / n as f32;
        let cam = Camera::orbit(yaw, view.pitch, view.size, view.size);
        frames.push(renderer.render_frame(&cam, view.mode, env)?);
        bar.inc(1);
    }
    bar.finish();
    report_fallbacks(&renderer);
    Ok(frames)
}

/// Writes `DIR/view_000.png` ..., `DIR/orbit.gif` and `DIR/contact_sheet.png`.
pub fn write_orbit(dir: &Path, frames: &[RenderedFrame]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating output folder {}", dir.display()))?;
    for (i, f) in frames.iter().enumerate() {
        f.save_png(&dir.join(format!("view_{i:03}.png")))?;
    }
    sequence::write_gif(&dir.join("orbit.gif"), frames, 80)?;
    let columns = (frames.len() as f64).sqrt().ceil() as usize;
    sequence::write_contact_sheet(&dir.join("contact_sheet.png"), frames, columns, 160)?;
    println!("wrote {} views, orbit.gif and contact_sheet.png to {}", frames.len(), dir.display());
    Ok(())
}

/// Arguments of `export`.
#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Photo of a person (PNG/JPEG); the person is found by --mask or --segment.
    #[arg(long)]
    pub image: PathBuf,
    /// Person mask (white = person), same size as the image; wins over --segment.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// How the person is found.
    #[command(flatten)]
    pub segment: SegmentArgs,
    /// Output file (glTF 2.0 binary, .glb).
    #[arg(long)]
    pub out: PathBuf,
    /// Simplify the mesh to about this many triangles (meshoptimizer), e.g. 20000 for a web viewer.
    #[arg(long)]
    pub decimate: Option<usize>,
    /// The person's standing height in metres; a photo showing only the top of the person is scaled by its neck.
    #[arg(long, default_value_t = crate::pipeline::export::DEFAULT_HEIGHT_M)]
    pub height: f32,
    /// Where the geometry comes from (as for render).
    #[arg(long, value_enum, default_value_t = GeometryMode::Auto)]
    pub geometry: GeometryMode,
    /// How surfaces the photo does not show are coloured (as for render).
    #[arg(long, value_enum, default_value_t = FillArg::MirroredFront)]
    pub fill: FillArg,
    /// Number of Fourier occupancy coefficients (FOF-X N).
    #[arg(long, default_value_t = 32)]
    pub fof_order: usize,
    /// Model folder of the FOF network (fof.onnx) for --geometry fofnet|auto; default: the project's models/tiny.
    #[arg(long)]
    pub models: Option<PathBuf>,
}

/// `r2human export`.
pub fn run_export(args: &ExportArgs) -> Result<()> {
    if !(2..=256).contains(&args.fof_order) {
        bail!("--fof-order {} is out of range: use 2 to 256 (32 is the reference's choice)", args.fof_order);
    }
    let opts = crate::pipeline::export::ExportOptions {
        height_m: args.height,
        fill: args.fill.into(),
        decimate: args.decimate,
    };
    opts.validate()?;
    let person = segment_photo(&args.image, args.mask.as_deref(), &args.segment.method()?)?;
    let runtime = RuntimeOptions::default();
    let fof_net = load_fof_net(args.geometry, args.models.as_deref(), args.fof_order, &runtime)?;
    let body = load_body_for(args.geometry, fof_net.as_ref(), &runtime)?;
    let prepare =
        PrepareOptions { fof_order: args.fof_order, geometry: args.geometry, fof_net, body, ..Default::default() };
    let prepared = PreparedInput::prepare(&person.photo.rgb, &person.mask, &prepare)
        .with_context(|| format!("reconstructing the person in {}", args.image.display()))?;
    let report = crate::pipeline::export::person_glb(&args.out, &prepared, &person.mask, &opts)?;
    println!("wrote {}: {report}", args.out.display());
    Ok(())
}

/// `r2human demo`.
pub fn run_demo(args: &DemoArgs) -> Result<()> {
    check_view_options(&args.view)?;
    if !(1..=720).contains(&args.frames) {
        bail!("--frames {} is out of range: use 1 to 720", args.frames);
    }
    let photo = image_io::load_image_bytes(DEFAULT_PERSON_PNG, "embedded person.png")?;
    let mask = photo.alpha.clone().context("the embedded person image has an alpha channel")?;
    let env = load_environment(&args.view)?;
    let neural = neural_for(&args.view)?;
    let prepared = prepare(&photo, &mask, &args.view)?;
    let frames = render_orbit(&prepared, &args.view, &env, args.frames, 0.0, neural.as_ref())?;
    write_orbit(&args.out, &frames)?;
    println!(
        "per-input stages: {:.0} ms; mesh: {} triangles",
        prepared.timings.total().as_secs_f64() * 1e3,
        prepared.mesh.triangle_count()
    );
    Ok(())
}
