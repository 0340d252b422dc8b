//! `render`, `export` and `demo`: their arguments, each handed to one function of [`crate::app::offline`].

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::app::offline::{self, ExportJob, GeometryOptions, RenderInput, RenderJob, ViewSetup};
use crate::app::Backend;
use crate::compose::Mode;
use crate::neural::{ExecutionProvider, RuntimeOptions};
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{GeometryMode, RendererChoice};

/// `--fill`: how occluded surfaces are coloured (see [`OcclusionFill`]).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FillArg {
    /// Surfaces facing away from the photo take the back image: the clothing without front-only details (face,
    /// ties, logos), the head in the head top's colour (needs the pose model of scripts/setup.d/live.sh to find the
    /// face; without it, or when no face is found, mirrored-front with a warning).
    Back,
    /// The back shows the front's colours at the same place (what a person expects from one photo).
    MirroredFront,
    /// Colours diffused inward from the nearest visible pixels.
    Propagate,
}

impl From<FillArg> for OcclusionFill {
    fn from(f: FillArg) -> Self {
        match f {
            FillArg::Back => OcclusionFill::Back,
            FillArg::MirroredFront => OcclusionFill::MirroredFront,
            FillArg::Propagate => OcclusionFill::Propagate,
        }
    }
}

/// `--geometry`, `--fill`, `--fof-order`: how the person is reconstructed (render, demo, export).
#[derive(Args, Debug, Clone)]
pub struct GeometryArgs {
    /// Where the geometry comes from: inflate (silhouette-inflation prior), fofnet (the FOF network in the model
    /// folder correcting that prior; an error without fof.onnx), body (the body prior: pose landmarks -> fitted
    /// MakeHuman body -> its FOF reconciled with the silhouette, no FOF network; needs the pose model of
    /// scripts/setup.d/live.sh), body-placed (the silhouette-inflation prior with the face mesh's relief and each
    /// column moved toward the fitted body's depth only where the fit is trusted, or as far as the model folder's
    /// placement.onnx says when it has one: the silhouette's thickness, the body's placement; same pose model) or auto (the default: the geometry that wins
    /// the whole evaluation, docs/geometry.md; on --video frames the inflation prior, which stays
    /// steady between frames).
    #[arg(long, value_enum, default_value_t = GeometryMode::Auto)]
    pub geometry: GeometryMode,
    /// How surfaces the photo does not show are coloured.
    #[arg(long, value_enum, default_value_t = FillArg::Back)]
    pub fill: FillArg,
    /// Number of Fourier occupancy coefficients (FOF-X N).
    #[arg(long, default_value_t = 32)]
    pub fof_order: usize,
    /// `render --video` only: keep a person model across the frames (the shape the silhouettes
    /// showed from each side, the colours of the sides and back the camera saw; its yaw from the pose read of the
    /// body on each frame; docs/live.md "The person model"). Off by default: its update costs more than the 10 ms
    /// a live frame can spare (docs/live.md).
    #[arg(long)]
    pub person_model: bool,
}

impl GeometryArgs {
    /// The options as [`crate::app::offline`] takes them.
    pub fn options(&self) -> GeometryOptions {
        GeometryOptions {
            geometry: self.geometry,
            fill: self.fill.into(),
            fof_order: self.fof_order,
            person_model: self.person_model,
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
    /// How the person is reconstructed.
    #[command(flatten)]
    pub geometry: GeometryArgs,
    /// Camera pitch in degrees (positive looks down on the person).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub pitch: f32,
    /// Which renderer draws the person.
    #[command(flatten)]
    pub neural: NeuralArgs,
}

impl ViewOptions {
    /// The options as [`crate::app::offline`] takes them.
    pub fn setup(&self) -> ViewSetup {
        ViewSetup {
            env: self.env.clone(),
            mode: self.mode,
            size: self.size,
            pitch: self.pitch,
            geometry: self.geometry.options(),
            neural: self.neural.setup(),
        }
    }
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
    /// Model folder of the neural renderer (encoder.onnx, decoder.onnx), the FOF network (fof.onnx, for
    /// --geometry fofnet) and an optional placement network (placement.onnx, for --geometry body-placed|auto);
    /// default: the project's models/tiny.
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

/// `r2human render`.
pub fn run_render(args: &RenderArgs) -> Result<()> {
    let input = match (&args.video, &args.image) {
        (Some(video), _) => RenderInput::Video(video.clone()),
        (None, Some(path)) => RenderInput::Photo { path: path.clone(), mask: args.mask.clone() },
        (None, None) => anyhow::bail!("--image or --video is required"),
    };
    let job = RenderJob {
        input,
        segment: args.segment.method()?,
        yaw: args.yaw,
        orbit: args.orbit,
        out: args.out.clone(),
        backend: args.backend,
        view: args.view.setup(),
    };
    println!("{}", offline::render(&job)?);
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
    /// How the person is reconstructed (as for render).
    #[command(flatten)]
    pub geometry: GeometryArgs,
    /// Model folder of the FOF network (fof.onnx) for --geometry fofnet|auto; default: the project's models/tiny.
    #[arg(long)]
    pub models: Option<PathBuf>,
}

/// `r2human export`.
pub fn run_export(args: &ExportArgs) -> Result<()> {
    let job = ExportJob {
        image: args.image.clone(),
        mask: args.mask.clone(),
        segment: args.segment.method()?,
        out: args.out.clone(),
        geometry: args.geometry.options(),
        models: args.models.clone(),
        options: crate::pipeline::export::ExportOptions {
            height_m: args.height,
            decimate: args.decimate,
            ..Default::default()
        },
    };
    println!("{}", offline::export(&job)?);
    Ok(())
}

/// `r2human demo`.
pub fn run_demo(args: &DemoArgs) -> Result<()> {
    println!("{}", offline::demo(&args.out, args.frames, &args.view.setup())?);
    Ok(())
}
