//! `view`, `xr`, `devices` and `bench-live`: the interactive and live commands.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::app::window;
use crate::app::xr_session::{self, XrInput, XrOptions};
use crate::app::Backend;
use crate::cli::render::{NeuralArgs, SegmentArgs};
use crate::compose::Mode;

/// Arguments of `view`.
#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Photo of a person (PNG/JPEG); the person is found by --mask or --segment.
    #[arg(long, required_unless_present_any = ["video", "camera"], conflicts_with_all = ["video", "camera"])]
    pub image: Option<PathBuf>,
    /// Person mask (white = person), same size as the image; wins over --segment.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Live input from a video file or a folder of frames (played at --fps); the window shows the latest
    /// processed frame.
    #[arg(long, conflicts_with = "camera")]
    pub video: Option<PathBuf>,
    /// Live input from camera N (`r2human devices` lists them).
    #[arg(long)]
    pub camera: Option<u32>,
    /// How the person is found.
    #[command(flatten)]
    pub segment: SegmentArgs,
    /// Frame rate of an image folder given to --video.
    #[arg(long, default_value_t = 25.0)]
    pub fps: f32,
    /// Do not draw the text overlay (frame time, backend, live statistics) into the window.
    #[arg(long)]
    pub no_overlay: bool,
    /// Panorama behind the person in VR.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// Start in VR (panorama) or AR (person alone); V and A switch while running.
    #[arg(long, value_enum, default_value_t = Mode::Vr)]
    pub mode: Mode,
    /// Engine for the person: the Vulkan passes, the CPU reference, or auto (Vulkan on a GPU, the CPU reference on
    /// a software rasteriser such as lavapipe, where it is faster); falls back to the CPU when the passes cannot run.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Render this many frames and exit (for tests and benchmarks).
    #[arg(long)]
    pub frames: Option<u64>,
    /// Window size in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Folder for screenshots (S key).
    #[arg(long, default_value = ".")]
    pub screenshot_dir: PathBuf,
    /// How the E key exports the person as glTF.
    #[command(flatten)]
    pub export: ExportFlags,
    /// Write the last frame to this PNG when the window closes.
    #[arg(long)]
    pub screenshot_on_exit: Option<PathBuf>,
    /// Turntable: turn the orbit by this many degrees every frame (demos; benchmarks with --frames, where an
    /// unmoved view would reuse the last person layer).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub spin: f32,
    /// Write one CSV line per presented frame to this file (start and frame time in ms, the live frame shown and
    /// its size): the timeline of a soak run (`scripts/soak.sh`).
    #[arg(long)]
    pub frame_log: Option<PathBuf>,
    /// Close the window after this many seconds (soak runs; with or without --frames).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Which renderer draws the person (G/N switch while running).
    #[command(flatten)]
    pub neural: NeuralArgs,
    /// Live sources (--video, --camera): keep a person model across the frames (the shape the silhouettes showed
    /// from each side and the colours of the sides and back the camera saw; docs/live.md "The person model").
    #[arg(long)]
    pub person_model: bool,
}

/// Arguments of `xr`.
#[derive(Args, Debug)]
pub struct XrArgs {
    /// Print the OpenXR runtime, its extensions, blend modes and view configuration, then exit.
    #[arg(long)]
    pub check: bool,
    /// Photo of a person (PNG/JPEG); the person is found by --mask or --segment.
    #[arg(long, required_unless_present_any = ["check", "video", "camera"], conflicts_with_all = ["video", "camera"])]
    pub image: Option<PathBuf>,
    /// Person mask (white = person), same size as the image; wins over --segment.
    #[arg(long, requires = "image")]
    pub mask: Option<PathBuf>,
    /// A video file or a folder of frames instead of --image: the person follows the frames (the session keeps
    /// the last person when the source ends or a frame is unusable).
    #[arg(long, conflicts_with = "camera")]
    pub video: Option<PathBuf>,
    /// A camera (index from `r2human devices`) instead of --image.
    #[arg(long)]
    pub camera: Option<u32>,
    /// Frame rate of a --video folder of frames.
    #[arg(long, default_value_t = 25.0)]
    pub fps: f32,
    /// How the person is found.
    #[command(flatten)]
    pub segment: SegmentArgs,
    /// Panorama around the viewer in VR.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// VR (panorama) or AR (passthrough where the runtime offers it).
    #[arg(long, value_enum, default_value_t = Mode::Vr)]
    pub mode: Mode,
    /// Stop after this many frames showing the person.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Largest eye image side in pixels.
    #[arg(long, default_value_t = 384)]
    pub eye_size: u32,
    /// Do not show the eye images in a desktop window.
    #[arg(long)]
    pub no_mirror: bool,
    /// How the export action (right B on Touch/Index, left select on the simple controller, E in the mirror
    /// window) writes the person as glTF.
    #[command(flatten)]
    pub export: ExportFlags,
    /// Also export the person when this many frames have shown it (repeatable; scripted captures).
    #[arg(long, value_name = "N")]
    pub export_at_frame: Vec<u64>,
    /// Engine for the eyes: the Vulkan passes, the CPU reference, or auto (the CPU reference when the runtime's
    /// Vulkan device is a software rasteriser such as lavapipe, the Vulkan passes on a GPU).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Which renderer draws the person.
    #[command(flatten)]
    pub neural: NeuralArgs,
    /// Live sources (--video, --camera): keep a person model across the frames (the shape the silhouettes showed
    /// from each side and the colours of the sides and back the camera saw; docs/live.md "The person model").
    #[arg(long)]
    pub person_model: bool,
    /// Live sources: the resolution frames are prepared at (64 to 512; default: the least that holds what the
    /// eyes show of the person at the default distance, 256 for eyes of 384 pixels; docs/xr.md).
    #[arg(long, value_name = "PIXELS")]
    pub live_resolution: Option<usize>,
}

/// Arguments of `bench-live`.
#[derive(Args, Debug)]
pub struct BenchLiveArgs {
    /// A video file or a folder of frames, played at its frame rate as `view --video` plays it.
    #[arg(long)]
    pub video: PathBuf,
    /// Frame rate of a folder of frames.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f32,
    /// How the person is found.
    #[command(flatten)]
    pub segment: SegmentArgs,
    /// Stop after this many seconds (default: the whole clip).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Side of the view drawn from each completed frame, in pixels.
    #[arg(long, default_value_t = 512)]
    pub view_size: usize,
    /// Yaw of that view in degrees.
    #[arg(long, default_value_t = 30.0, allow_negative_numbers = true)]
    pub yaw: f32,
    /// Also draw one view (--view-size, --yaw) of every completed frame on the calling thread, as a display would,
    /// and report its median time.
    #[arg(long)]
    pub views: bool,
    /// Source resolution frames are prepared at (the person's cube, 512 like the reference).
    #[arg(long, default_value_t = crate::geometry::SOURCE_RESOLUTION)]
    pub resolution: usize,
    /// Which renderer draws the views (neural: the worker also runs the encoder on every frame).
    #[command(flatten)]
    pub neural: NeuralArgs,
    /// Keep the person model across the frames, as `view --person-model` does (its cost is the stage "person
    /// model").
    #[arg(long)]
    pub person_model: bool,
}

/// `r2human bench-live`.
pub fn run_bench_live(args: &BenchLiveArgs) -> Result<()> {
    let report = crate::app::live_bench::bench_live(&crate::app::live_bench::LiveBenchOptions {
        video: args.video.clone(),
        fps: args.fps,
        segment: args.segment.method()?,
        neural: args.neural.setup(),
        seconds: args.seconds,
        view_size: args.view_size,
        yaw: args.yaw,
        views: args.views,
        resolution: args.resolution,
        person_model: args.person_model,
    })?;
    println!("{report}");
    Ok(())
}

/// `--export-dir`, `--export-height`, `--export-decimate`: how `view` (E key) and `xr` (the export action) write
/// the person as glTF.
#[derive(Args, Debug, Clone)]
pub struct ExportFlags {
    /// Folder for glTF exports of the person (E key, xr's export action): r2human-person-NNNNN.glb.
    #[arg(long, default_value = ".")]
    pub export_dir: PathBuf,
    /// The person's standing height in metres for exports (see `r2human export --height`).
    #[arg(long, default_value_t = crate::pipeline::export::DEFAULT_HEIGHT_M)]
    pub export_height: f32,
    /// Simplify exported meshes to about this many triangles.
    #[arg(long)]
    pub export_decimate: Option<usize>,
}

impl ExportFlags {
    /// The export options (checked now, so a bad value fails before the window opens).
    pub fn options(&self) -> Result<crate::pipeline::export::ExportOptions> {
        let o = crate::pipeline::export::ExportOptions {
            height_m: self.export_height,
            decimate: self.export_decimate,
            ..Default::default()
        };
        o.validate()?;
        Ok(o)
    }
}

/// `r2human view`.
pub fn run_view(args: &ViewArgs) -> Result<()> {
    let segment = args.segment.method()?;
    let frames = args.frames;
    let stats = window::run_view_with_stats(window::WindowOptions {
        image: args.image.clone().unwrap_or_default(),
        mask: args.mask.clone(),
        video: args.video.clone(),
        camera: args.camera.map(|index| crate::capture::CameraRequest { index, ..Default::default() }),
        segment,
        fps: args.fps,
        overlay: !args.no_overlay,
        env: args.env.clone(),
        mode: args.mode,
        backend: args.backend,
        frames: args.frames,
        size: args.size,
        screenshot_dir: args.screenshot_dir.clone(),
        export_dir: args.export.export_dir.clone(),
        export: args.export.options()?,
        screenshot_on_exit: args.screenshot_on_exit.clone(),
        neural: args.neural.setup(),
        person_model: args.person_model,
        spin: args.spin,
        frame_log: args.frame_log.clone(),
        duration: match args.seconds.map(std::time::Duration::try_from_secs_f64) {
            Some(Ok(d)) if !d.is_zero() => Some(d),
            Some(_) => anyhow::bail!("--seconds: give a positive number of seconds"),
            None => None,
        },
        ..Default::default()
    })?;
    if frames.is_some() || args.seconds.is_some() {
        // A scripted run (tests, benchmarks) says what it measured.
        let n = stats.neural;
        println!(
            "view: {} frames on {} ({:?}), median {:.2} ms/frame, last frame drawn by {}; neural frames {}, decoder \
             runs {}, encoder runs {}, fallbacks {}",
            stats.frames,
            stats.device,
            stats.backend,
            stats.median_frame.as_secs_f64() * 1e3,
            stats.renderer.label(),
            n.views,
            n.decoder_runs,
            stats.encodes,
            n.fallbacks
        );
        println!("frame times (ms): {}", stats.frame_histogram.summary());
        if let Some(live) = &stats.live {
            println!(
                "{}; {} uploaded; validation messages {}",
                live.report_line(),
                stats.live_uploads,
                stats.validation_messages
            );
        }
    }
    Ok(())
}

/// `r2human xr`.
pub fn run_xr(args: &XrArgs) -> Result<()> {
    if args.check {
        // The runtime, its extensions, blend modes and view configuration, or (as the error) a sentence saying what
        // to install or start when there is no runtime.
        println!("{}", crate::xr::check_runtime()?);
        return Ok(());
    }
    let segment = args.segment.method()?;
    let input = match (&args.image, &args.video, args.camera) {
        (_, Some(path), _) => XrInput::Video { path: path.clone(), fps: args.fps, segment },
        (_, None, Some(index)) => {
            XrInput::Camera { request: crate::capture::CameraRequest { index, ..Default::default() }, segment }
        }
        (Some(path), None, None) => XrInput::Image { path: path.clone(), mask: args.mask.clone(), segment },
        (None, None, None) => anyhow::bail!("give --image, --video or --camera (or --check)"),
    };
    // What happened: frame rate, fresh-render share, motion-to-photon latency of the person layer, how it ended.
    let report = xr_session::run_xr_session(&XrOptions {
        input,
        env: args.env.clone(),
        mode: args.mode,
        frames: args.frames,
        eye_size: args.eye_size,
        mirror: !args.no_mirror,
        neural: args.neural.setup(),
        export_dir: args.export.export_dir.clone(),
        export: args.export.options()?,
        export_at_frames: args.export_at_frame.clone(),
        backend: args.backend,
        person_model: args.person_model,
        live_resolution: args.live_resolution,
        ..Default::default()
    })?;
    println!("{report}");
    Ok(())
}

/// `r2human devices`.
pub fn run_devices() -> Result<()> {
    print!("{}", crate::capture::camera::devices_report());
    Ok(())
}
