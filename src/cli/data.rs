//! `dataset` and `synth`: synthetic ground truth.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

use crate::eval::dataset::{self, DatasetOptions};

/// Arguments of `dataset`.
#[derive(Args, Debug)]
pub struct DatasetArgs {
    /// Number of synthetic subjects.
    #[arg(long, default_value_t = 10)]
    pub subjects: usize,
    /// Seed: the same seed writes the same dataset.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Target views per subject.
    #[arg(long, default_value_t = 8)]
    pub views: usize,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Framing of each subject: mixed (full, three-quarter and upper in turn), full, three-quarter or upper.
    #[arg(long, default_value = "mixed", value_parser = parse_framing_choice)]
    pub framing: crate::synth::framing::FramingChoice,
    /// Do not write `body_fof.npy` (the body prior's FOF: pose network + fitter on each rendered source, the FOF
    /// net's `body` input). Without this flag the pose model must be installed (`bash scripts/setup.sh`).
    #[arg(long)]
    pub no_body_fof: bool,
    /// Turning clips instead: each subject (full body) turns once in front of a fixed camera, then faces it again;
    /// one folder of frames per subject (frame_NNNN.png with the true mask as alpha, clip.json), playable with
    /// `view --video DIR/subject_0000 --fps 16`. Uses --subjects, --seed, --size and the turn's flags.
    #[arg(long)]
    pub turn: bool,
    /// The turn's timing and arm swing (with --turn).
    #[command(flatten)]
    pub turn_clip: TurnArgs,
}

/// The turning clips' flags of `dataset --turn` and `eval --turn`.
#[derive(Args, Debug)]
pub struct TurnArgs {
    /// With --turn: what happens halfway through the turn: none, cut (another synthetic subject takes the
    /// person's place) or take-off (the person's top is off).
    #[arg(long, value_enum, default_value_t = crate::eval::turn::EventChoice::None)]
    pub event: crate::eval::turn::EventChoice,
    /// With --turn: frames over which the person turns once.
    #[arg(long, default_value_t = 48)]
    pub turn_frames: usize,
    /// With --turn: frames facing the camera after the turn.
    #[arg(long, default_value_t = 8)]
    pub hold_frames: usize,
    /// With --turn: how far each arm's elevation swings during the turn (degrees, 0 to 45).
    #[arg(long, default_value_t = 15.0)]
    pub arm_swing: f32,
    /// eval --turn: where the person model reads the body's orientation: segmenter (the live segmenter's pose
    /// read of each frame, as a live camera hands it on), own (one pose read of its own a frame) or colour (none:
    /// the yaw from the colours alone), to compare.
    #[arg(long, value_enum, default_value_t = crate::eval::turn::ModelBody::Segmenter)]
    pub model_body: crate::eval::turn::ModelBody,
    /// eval --turn: degrees either side of the body's yaw the person model's colours refine it (0: the body's
    /// yaw alone).
    #[arg(long, default_value_t = crate::pipeline::person_model::COLOUR_REFINE_DEGREES)]
    pub model_colour_refine: i32,
}

impl TurnArgs {
    /// The clip these flags describe.
    pub fn options(&self) -> crate::synth::turn::TurnOptions {
        crate::synth::turn::TurnOptions {
            turn_frames: self.turn_frames,
            hold_frames: self.hold_frames,
            arm_swing: self.arm_swing,
        }
    }
}

/// Arguments of `synth`.
#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Seed of the subject (shape, pose, clothing).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output glTF binary (.glb).
    #[arg(long)]
    pub out: PathBuf,
    /// Framing: full body, three-quarter (cut at the thighs) or upper body (cut at the chest or waist).
    #[arg(long, default_value = "full", value_parser = parse_framing)]
    pub framing: crate::synth::Framing,
    /// Also write a contact sheet of the subject seen at yaw 0, 90 and 180 degrees (shaded, 512 px per view).
    #[arg(long)]
    pub sheet: Option<PathBuf>,
}

/// Parses `mixed`, `full`, `three-quarter` or `upper`.
pub fn parse_framing_choice(s: &str) -> Result<crate::synth::framing::FramingChoice, String> {
    crate::synth::framing::FramingChoice::parse(s)
        .ok_or_else(|| format!("unknown framing {s:?}: use mixed, full, three-quarter or upper"))
}

/// Parses `full`, `three-quarter` or `upper`.
pub fn parse_framing(s: &str) -> Result<crate::synth::Framing, String> {
    crate::synth::Framing::parse(s).ok_or_else(|| format!("unknown framing {s:?}: use full, three-quarter or upper"))
}

/// `r2human dataset`.
pub fn run_dataset(args: &DatasetArgs) -> Result<()> {
    if !(1..=100_000).contains(&args.subjects) {
        bail!("--subjects {} is out of range: use 1 to 100000", args.subjects);
    }
    if !(16..=4096).contains(&args.size) {
        bail!("--size {} is out of range: use 16 to 4096 pixels", args.size);
    }
    if args.views > 360 {
        bail!("--views {} is out of range: use 0 to 360", args.views);
    }
    if args.turn {
        let opts = crate::eval::turn::TurnEvalOptions {
            subjects: args.subjects,
            seed: args.seed,
            out: args.out.clone(),
            size: args.size,
            turn: args.turn_clip.options(),
            event: args.turn_clip.event,
            ..Default::default()
        };
        let crate::eval::turn::TurnClipsWritten { written, failed } = crate::eval::turn::write_turn_clips(&opts)?;
        for (name, why) in &failed {
            tracing::warn!("{name} failed and was skipped: {why}");
        }
        println!("wrote {} turning clip(s) of {} frames to {}", written.len(), opts.turn.frames(), args.out.display());
        if written.is_empty() {
            bail!("no clip could be written");
        }
        return Ok(());
    }
    let opts = DatasetOptions {
        subjects: args.subjects,
        seed: args.seed,
        out: args.out.clone(),
        views: args.views,
        size: args.size,
        framing: args.framing,
        body_fof: !args.no_body_fof,
        ..Default::default()
    };
    let summary = dataset::write_dataset(&opts)?;
    println!("wrote {} subjects to {} in {:.1} s", summary.written.len(), args.out.display(), summary.seconds);
    if !summary.body_fallbacks.is_empty() {
        eprintln!(
            "note: {} subject(s) have the body prior's fall-back (the inflation prior) as body_fof.npy, as the \
             pipeline does at run time (listed in dataset.json, body_fof_fallbacks)",
            summary.body_fallbacks.len()
        );
    }
    for (name, why) in &summary.failed {
        tracing::warn!("{name} failed and was skipped: {why}");
    }
    if summary.written.is_empty() {
        bail!("no subject could be written");
    }
    Ok(())
}

/// `r2human synth`.
pub fn run_synth(args: &SynthArgs) -> Result<()> {
    let subject = crate::synth::write_subject_glb(args.seed, args.framing, &args.out)?;
    println!(
        "wrote {} ({} triangles; {} framing{}; garments: {})",
        args.out.display(),
        subject.mesh.mesh.triangle_count(),
        subject.crop.framing.label(),
        if subject.crop.at == "none" { String::new() } else { format!(", cut at the {}", subject.crop.at) },
        if subject.garments.is_empty() {
            "none".to_string()
        } else {
            subject.garments.iter().map(|g| g.label.as_str()).collect::<Vec<_>>().join(", ")
        }
    );
    if let Some(sheet) = &args.sheet {
        crate::eval::ground_truth::write_contact_sheet(sheet, &[&subject.mesh], &[0.0, 90.0, 180.0], 512)?;
        println!("wrote {}", sheet.display());
    }
    Ok(())
}

/// Arguments of `eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Number of synthetic subjects: 8 by default, none when --scan or --photos is given (add them with
    /// --subjects N).
    #[arg(long)]
    pub subjects: Option<usize>,
    /// Seed of the synthetic subjects.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder for report.md, report.csv and error_vs_time.png.
    #[arg(long)]
    pub out: PathBuf,
    /// A textured scan to evaluate (glTF/GLB or OBJ+MTL); repeatable. Alone, only the scans are evaluated; their
    /// rows are reported per scan.
    #[arg(long)]
    pub scan: Vec<PathBuf>,
    /// The scans' up axis (y or z); detected when not given (the log says what was detected).
    #[arg(long)]
    pub up: Option<crate::synth::scan::UpAxis>,
    /// The direction the scanned person faces once upright (+z, -z, +x or -x); detected when not given.
    #[arg(long, allow_hyphen_values = true)]
    pub facing: Option<crate::synth::scan::Facing>,
    /// A folder of real photos (PNG/JPEG) to check without ground truth: views at yaws 0-180 per method, a
    /// contact sheet per photo, input-view PSNR, detached fragments, doubled surfaces (DIR/photos.md).
    #[arg(long, value_name = "DIR")]
    pub photos: Option<PathBuf>,
    /// Person segmentation of --photos: alpha (the photo's own), onnx (the segmentation model installed by
    /// scripts/setup.sh) or auto (alpha when the photo has a real one, else the model).
    #[arg(long, default_value = "auto")]
    pub segment: String,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Framing of the synthetic subjects: mixed (full, three-quarter and upper in turn; each framing is its own
    /// group in the report), full, three-quarter or upper.
    #[arg(long, default_value = "mixed", value_parser = parse_framing_choice)]
    pub framing: crate::synth::framing::FramingChoice,
    /// Also write every view's ground truth and each method's rendering as PNGs (DIR/views/...), to look at.
    #[arg(long)]
    pub save_views: bool,
    /// Model folder of the neural methods (neural+inflation, neural+gt-fof) and of the FOF net (fof.onnx:
    /// geometric+fofnet, neural+fofnet); default: the project's models/tiny. Without loadable models those rows are
    /// left out with one warning (and a note in report.md).
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Leave the network methods out: the neural renderer, the FOF net and the body prior (its pose network), so
    /// only the billboard, 2.5d, inflation-prior and ground-truth rows remain.
    #[arg(long)]
    pub no_neural: bool,
    /// Execution provider of the neural methods: auto tries TensorRT, then CUDA, then the CPU.
    #[arg(long, value_enum, default_value_t = crate::neural::ExecutionProvider::Auto)]
    pub ep: crate::neural::ExecutionProvider,
    /// Turning clips instead: each synthetic subject (3 by default, full body) and each --scan turns once in
    /// front of a fixed camera, then faces it again; every frame goes through the live frame path and is scored
    /// at close and divergent views (DIR/turn.md, turn.csv, turn_divergent_psnr.png, sheets/).
    #[arg(long)]
    pub turn: bool,
    /// The turn's timing and arm swing (with --turn).
    #[command(flatten)]
    pub turn_clip: TurnArgs,
}

/// `r2human eval`: the synthetic subjects and scans against ground truth, then (with --photos) the checks on real
/// photos.
pub fn run_eval(args: &EvalArgs) -> Result<()> {
    if !(16..=4096).contains(&args.size) {
        bail!("--size {} is out of range: use 16 to 4096 pixels", args.size);
    }
    if args.turn {
        return run_turn_eval(args);
    }
    let subjects = args.subjects.unwrap_or(if args.scan.is_empty() && args.photos.is_none() { 8 } else { 0 });
    let neural =
        crate::eval::runner::NeuralEvalOptions { models: args.models.clone(), skip: args.no_neural, ep: args.ep };
    if subjects > 0 || !args.scan.is_empty() {
        let opts = crate::eval::runner::EvalOptions {
            subjects,
            seed: args.seed,
            out: args.out.clone(),
            scans: args.scan.clone(),
            scan_orientation: crate::synth::scan::ScanOrientation { up: args.up, facing: args.facing },
            size: args.size,
            save_views: args.save_views,
            framing: args.framing,
            ..Default::default()
        };
        let report = crate::eval::runner::run_eval_with(&opts, &neural)?;
        for (name, why) in &report.failed {
            tracing::warn!("{name} was skipped: {why}");
        }
        println!("wrote {}/report.md, report.csv and error_vs_time.png", args.out.display());
    }
    if let Some(dir) = &args.photos {
        let Some(segment) = crate::capture::SegmentMethod::parse(&args.segment) else {
            bail!("--segment {} is not known: use alpha, onnx or auto", args.segment);
        };
        let opts =
            crate::eval::photos::PhotoEvalOptions { dir: dir.clone(), out: args.out.clone(), size: args.size, segment };
        let report = crate::eval::photos::run_photo_eval_with(&opts, &neural)?;
        for (name, why) in &report.failed {
            tracing::warn!("{name} was skipped: {why}");
        }
        let passed = report.rows.iter().filter(|r| r.passes()).count();
        println!(
            "wrote {}/photos.md, photos.csv and {} contact sheet(s): {passed} of {} photo x method rows pass the checks",
            args.out.display(),
            report.sheets.len(),
            report.rows.len()
        );
    }
    Ok(())
}

/// `r2human eval --turn`: turning clips through the live frame path.
fn run_turn_eval(args: &EvalArgs) -> Result<()> {
    if args.photos.is_some() {
        bail!("--turn plays turning clips of synthetic subjects and scans; --photos has no turn to play: run it alone");
    }
    let subjects = args.subjects.unwrap_or(if args.scan.is_empty() { 3 } else { 0 });
    let opts = crate::eval::turn::TurnEvalOptions {
        subjects,
        seed: args.seed,
        scans: args.scan.clone(),
        scan_orientation: crate::synth::scan::ScanOrientation { up: args.up, facing: args.facing },
        out: args.out.clone(),
        size: args.size,
        turn: args.turn_clip.options(),
        event: args.turn_clip.event,
        model_body: args.turn_clip.model_body,
        model_colour_refine: args.turn_clip.model_colour_refine,
        ..Default::default()
    };
    let options = crate::neural::RuntimeOptions { ep: args.ep, ..Default::default() };
    let back_pose = if args.no_neural {
        None
    } else {
        crate::pipeline::load_back_pose(crate::pipeline::warp::OcclusionFill::default(), &options)
    };
    let report = crate::eval::turn::run_turn_eval(&opts, back_pose)?;
    for (name, why) in &report.failed {
        tracing::warn!("{name} was skipped: {why}");
    }
    println!("wrote {}/turn.md, turn.csv, turn_divergent_psnr.png and sheets/", args.out.display());
    Ok(())
}
