//! Person segmentation, chosen per source:
//! - [`AlphaSegmenter`]: the input's own alpha (PNG sequences with transparency, videos with an alpha plane);
//! - [`CleanPlateSegmenter`]: background subtraction against a clean plate (the empty scene, captured first) for a
//!   fixed camera;
//! - [`super::onnx::OnnxSegmenter`]: an ONNX person/salient-object model through ONNX Runtime.
//!
//! Every segmenter returns a soft mask in `[0, 1]` at the frame's size.

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::morph::{close, fill_holes, largest_component, open, to_gray, BinaryMask};
use super::{CaptureError, Frame};
use crate::buffer::{GrayImage, Image, RgbImage};

/// A per-frame person segmenter.
pub trait Segmenter: Send {
    /// Short name for messages and statistics ("alpha", "clean-plate", "onnx").
    fn name(&self) -> &'static str;
    /// The person mask of `frame`, values in `[0, 1]`, same size as the frame.
    fn segment(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError>;
    /// The person's world landmarks the last [`Segmenter::segment`] read, when this segmenter runs MediaPipe's pose
    /// model ([`crate::body::pose::PoseLandmarks::world`]'s convention: metres about the hips, y up, z toward the
    /// camera): the body's orientation for the person model ([`crate::pipeline::person_model::body_yaw`]) without
    /// a second run of the network. `None` by default.
    fn body_world(&self) -> Option<&[glam::Vec3]> {
        None
    }
}

/// Which segmentation to use (`--segment alpha|plate|onnx|auto`).
#[derive(Clone, Debug, PartialEq)]
pub enum SegmentMethod {
    /// The frame's alpha channel.
    Alpha,
    /// Clean-plate background subtraction. The plate is the image `plate` when given, otherwise the first
    /// `plate_frames` frames of the source (the empty scene: step out of view when the camera starts).
    CleanPlate {
        /// A picture of the empty scene, if one was taken beforehand.
        plate: Option<PathBuf>,
        /// Frames of the source used as the plate when `plate` is `None` (at least 1).
        plate_frames: usize,
    },
    /// The ONNX model (`model` or the installed default), run at `input_size` x `input_size` pixels.
    Onnx {
        /// Model file; `None` = `R2HUMAN_SEG_MODEL` or the one installed by scripts/setup.d/live.sh.
        model: Option<PathBuf>,
        /// Network input side (a multiple of 32).
        input_size: usize,
    },
    /// Per frame: the frame's alpha when it has a real one ([`has_useful_alpha`]), else the ONNX model (loaded
    /// when first needed).
    Auto,
}

impl SegmentMethod {
    /// Parses `alpha`, `plate`, `onnx`, `auto` (defaults for the parameters).
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "alpha" => Some(Self::Alpha),
            "plate" | "clean-plate" | "cleanplate" => Some(Self::CleanPlate { plate: None, plate_frames: 10 }),
            "onnx" | "model" => Some(Self::Onnx { model: None, input_size: super::onnx::DEFAULT_INPUT_SIZE }),
            "auto" => Some(Self::Auto),
            _ => None,
        }
    }

    /// The names `--segment` accepts, for messages.
    pub const NAMES: &'static str = "auto, alpha, onnx or plate";

    /// Parses `--segment`, or a sentence naming the accepted values.
    pub fn from_arg(s: &str) -> Result<Self, CaptureError> {
        Self::parse(s).ok_or_else(|| CaptureError::Segment {
            method: "--segment",
            reason: format!("`{s}` is not known: use {}", Self::NAMES),
        })
    }

    /// This method with the clean plate taken from `plate` (a picture of the empty scene) when given.
    pub fn with_plate(self, plate: Option<&Path>) -> Self {
        match (self, plate) {
            (Self::CleanPlate { plate_frames, .. }, Some(p)) => {
                Self::CleanPlate { plate: Some(p.into()), plate_frames }
            }
            (m, _) => m,
        }
    }

    /// Builds the segmenter. With [`SegmentMethod::Auto`] a first frame that has a real alpha channel starts
    /// with the alpha path without loading the model; the choice is then made per frame ([`AutoSegmenter`]).
    pub fn build(&self, first: Option<&Frame>) -> Result<Box<dyn Segmenter>, CaptureError> {
        match self {
            Self::Alpha => Ok(Box::new(AlphaSegmenter)),
            Self::CleanPlate { plate: Some(path), .. } => {
                let (rgb, _) = super::load_image_frame(path)
                    .map_err(|e| CaptureError::Image { path: path.clone(), source: Box::new(e) })?;
                Ok(Box::new(CleanPlateSegmenter::with_plate(CleanPlate::from_frames(&[rgb])?)))
            }
            Self::CleanPlate { plate: None, plate_frames } => {
                Ok(Box::new(CleanPlateSegmenter::learning(*plate_frames)))
            }
            Self::Onnx { model, input_size } => {
                Ok(Box::new(super::onnx::OnnxSegmenter::load(model.as_deref(), *input_size)?))
            }
            Self::Auto => {
                let mut auto = AutoSegmenter::default();
                if !first.is_some_and(has_useful_alpha) {
                    auto.model = Some(super::onnx::OnnxSegmenter::load(None, super::onnx::DEFAULT_INPUT_SIZE)?);
                }
                Ok(Box::new(auto))
            }
        }
    }
}

/// `--segment auto` per frame: the frame's alpha when it has a real one, else the ONNX model (loaded on the first
/// frame that needs it). Logs each change of path.
#[derive(Default)]
pub struct AutoSegmenter {
    model: Option<super::onnx::OnnxSegmenter>,
    last: Option<&'static str>,
}

impl Segmenter for AutoSegmenter {
    fn name(&self) -> &'static str {
        self.last.unwrap_or("auto")
    }

    fn segment(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let (name, mask) = if has_useful_alpha(frame) {
            ("alpha", AlphaSegmenter.segment(frame)?)
        } else {
            let model = match &mut self.model {
                Some(m) => m,
                None => self.model.insert(super::onnx::OnnxSegmenter::load(None, super::onnx::DEFAULT_INPUT_SIZE)?),
            };
            ("onnx", model.segment(frame)?)
        };
        if self.last != Some(name) {
            match name {
                "alpha" => {
                    tracing::info!("segmentation: frame {} has an alpha channel; using it as the mask", frame.index)
                }
                _ => tracing::info!(
                    "segmentation: frame {} has no alpha channel; using the segmentation model",
                    frame.index
                ),
            }
            self.last = Some(name);
        }
        Ok(mask)
    }

    fn body_world(&self) -> Option<&[glam::Vec3]> {
        match self.last {
            Some("onnx") => self.model.as_ref().and_then(|m| m.body_world()),
            _ => None,
        }
    }
}

/// Where the person mask of a still photo came from ([`segment_photo`]).
#[derive(Clone, Debug, PartialEq)]
pub enum MaskOrigin {
    /// A mask file (`--mask`), which wins over every `--segment` method.
    File(PathBuf),
    /// The photo's own alpha channel.
    Alpha,
    /// The ONNX segmentation model in this file.
    Model(PathBuf),
    /// Clean-plate subtraction against this picture of the empty scene.
    Plate(PathBuf),
}

impl MaskOrigin {
    /// A short label for tables: `alpha`, `mask`, `plate`, or the model's file stem (`isnet_seg`).
    pub fn short_name(&self) -> String {
        match self {
            Self::File(_) => "mask".into(),
            Self::Alpha => "alpha".into(),
            Self::Model(p) => p.file_stem().unwrap_or_default().to_string_lossy().into_owned(),
            Self::Plate(_) => "plate".into(),
        }
    }
}

impl std::fmt::Display for MaskOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::File(p) => write!(f, "the mask file {}", p.display()),
            Self::Alpha => write!(f, "the photo's alpha channel"),
            Self::Model(p) => write!(f, "the segmentation model {}", p.display()),
            Self::Plate(p) => write!(f, "clean-plate subtraction against {}", p.display()),
        }
    }
}

/// A still photo of a person with its mask.
#[derive(Clone, Debug)]
pub struct SegmentedPhoto {
    /// The decoded photo (linear RGB, alpha when the file has one).
    pub photo: crate::io::image_io::LoadedImage,
    /// The person mask in `[0, 1]`, the photo's size.
    pub mask: GrayImage,
    /// Where the mask came from.
    pub origin: MaskOrigin,
}

/// Errors of [`segment_photo`].
#[derive(Debug, thiserror::Error)]
pub enum PhotoError {
    /// The photo or the mask file cannot be read.
    #[error(transparent)]
    Io(#[from] crate::io::image_io::IoError),
    /// `--segment alpha` on a photo without a real alpha channel.
    #[error(
        "{} has no alpha channel that separates the person (it is missing or fully opaque), so --segment alpha          cannot be used: use --segment auto or onnx (the segmentation model), or give --mask FILE (white = person)",
        .0.display()
    )]
    NoAlpha(PathBuf),
    /// `--segment plate` on a still photo without a picture of the empty scene.
    #[error(
        "--segment plate on the still photo {} needs --plate FILE, a photo of the same scene without the person          taken from the same place",
        .0.display()
    )]
    NoPlate(PathBuf),
    /// The segmentation model cannot be found, loaded or run.
    #[error("{} has no alpha channel that separates the person, so it needs the {source}", path.display())]
    Model {
        /// The photo.
        path: PathBuf,
        /// What went wrong with the model (names the install script when it is missing).
        source: CaptureError,
    },
    /// The segmentation model marked no pixel as a person, or the pose model sees nobody in the photo.
    #[error(
        "found no person in {}: give --mask FILE (white = person), or a photo in which a person stands out from the \
         background",
        .0.display()
    )]
    NoPerson(PathBuf),
    /// Clean-plate segmentation failed (sizes differ, unreadable plate).
    #[error("{0}")]
    Plate(CaptureError),
}

/// Loads a still photo and finds the person in it (`--image` with `--mask` / `--segment`). A `mask` file wins;
/// otherwise `method`: `alpha` = the photo's alpha (an error when it has no real one), `onnx` = the segmentation
/// model ([`super::onnx::OnnxSegmenter::segment_still`]), `plate` = subtraction against the picture in
/// [`SegmentMethod::CleanPlate::plate`], `auto` = the alpha when the photo has a real one (not fully opaque),
/// else the model. The choice is logged.
pub fn segment_photo(image: &Path, mask: Option<&Path>, method: &SegmentMethod) -> Result<SegmentedPhoto, PhotoError> {
    let photo = crate::io::image_io::load_image(image)?;
    let frame =
        Frame { index: 0, timestamp: std::time::Duration::ZERO, rgb: photo.rgb.clone(), alpha: photo.alpha.clone() };
    let done = |mask: GrayImage, origin: MaskOrigin| {
        tracing::info!("person mask of {}: {origin}", image.display());
        Ok(SegmentedPhoto { photo: photo.clone(), mask, origin })
    };
    if let Some(m) = mask {
        let loaded = crate::io::image_io::load_mask(m, photo.rgb.width, photo.rgb.height)?;
        return done(loaded, MaskOrigin::File(m.into()));
    }
    // A still's alpha is real unless it is fully opaque (an all-transparent one says there is no one: the pipeline
    // then reports an empty mask rather than a model guessing at hidden colours).
    let alpha = frame.alpha.as_ref().is_some_and(|a| a.data.iter().any(|&v| v < 0.5));
    match method {
        SegmentMethod::Alpha | SegmentMethod::Auto if alpha => {
            done(AlphaSegmenter.segment(&frame).map_err(PhotoError::Plate)?, MaskOrigin::Alpha)
        }
        SegmentMethod::Alpha => Err(PhotoError::NoAlpha(image.into())),
        SegmentMethod::CleanPlate { plate: None, .. } => Err(PhotoError::NoPlate(image.into())),
        SegmentMethod::CleanPlate { plate: Some(p), .. } => {
            let seg = SegmentMethod::CleanPlate { plate: Some(p.clone()), plate_frames: 1 }
                .build(None)
                .map_err(PhotoError::Plate)?;
            let mut seg = seg;
            done(seg.segment(&frame).map_err(PhotoError::Plate)?, MaskOrigin::Plate(p.clone()))
        }
        SegmentMethod::Onnx { model, .. } => still_model(image, &frame, model.as_deref()).and_then(|(m, o)| done(m, o)),
        SegmentMethod::Auto => still_model(image, &frame, None).and_then(|(m, o)| done(m, o)),
    }
}

/// The segmentation model's mask of a still photo ([`super::onnx::OnnxSegmenter::load_still`]).
fn still_model(image: &Path, frame: &Frame, model: Option<&Path>) -> Result<(GrayImage, MaskOrigin), PhotoError> {
    let err = |source| PhotoError::Model { path: image.into(), source };
    let mut seg = super::onnx::OnnxSegmenter::load_still(model).map_err(err)?;
    let mask = seg.segment_still(frame).map_err(err)?;
    if !mask.data.iter().any(|&v| v >= 0.5) {
        return Err(PhotoError::NoPerson(image.into()));
    }
    // ISNet outlines whatever stands out, a person or not (a blank grey photo gave a ragged grey "person"): the
    // pose model, when installed, says whether anybody is there at all.
    if model.is_none() && seg.kind() == super::onnx::SegmentationModel::Isnet {
        if let Some(presence) = person_presence(frame) {
            if presence < super::onnx::MIN_PERSON_PRESENCE {
                tracing::info!("{}: the pose model sees nobody (presence {presence:.3})", image.display());
                return Err(PhotoError::NoPerson(image.into()));
            }
        }
    }
    Ok((mask, MaskOrigin::Model(seg.path().to_path_buf())))
}

/// The pose model's presence score for the person in `frame` (read letterboxed, then on the square around what
/// it found), or `None` when the pose model is not installed or fails (the photo is then not checked).
fn person_presence(frame: &Frame) -> Option<f32> {
    let path = super::onnx::model_path_from(None, &[super::onnx::MODEL_FILES[0]]).ok()?;
    let mut pose = super::onnx::OnnxSegmenter::load(Some(&path), super::onnx::DEFAULT_INPUT_SIZE).ok()?;
    if pose.kind() != super::onnx::SegmentationModel::MediapipePose {
        return None;
    }
    pose.segment_still(frame).ok()?;
    Some(pose.presence())
}

/// True when the frame has an alpha channel that is neither all opaque nor all transparent.
pub fn has_useful_alpha(frame: &Frame) -> bool {
    frame.alpha.as_ref().is_some_and(|a| {
        let opaque = a.data.iter().filter(|&&v| v > 0.5).count();
        opaque > 0 && opaque < a.data.len()
    })
}

/// Uses the frame's own alpha channel.
pub struct AlphaSegmenter;

impl Segmenter for AlphaSegmenter {
    fn name(&self) -> &'static str {
        "alpha"
    }

    fn segment(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let alpha = frame.alpha.as_ref().ok_or_else(|| CaptureError::Segment {
            method: "alpha",
            reason: "this source has no alpha channel; use --segment plate (fixed camera) or --segment onnx".into(),
        })?;
        Ok(alpha.map(|v| if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 }))
    }
}

/// Tunables of the clean-plate test (defaults suit 8-bit webcam footage).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlateParams {
    /// A pixel differs from the plate when its colour distance exceeds `k_sigma` times the pixel's noise.
    pub k_sigma: f32,
    /// Noise floor (linear RGB distance) so a perfectly still plate does not make every pixel noisy.
    pub min_sigma: f32,
    /// Shadows: a pixel that is a darker copy of the plate (brightness ratio in `[shadow_min, 1]`, chroma distance
    /// below `k_sigma` noise) is background.
    pub shadow_min: f32,
    /// Radius of the opening (removes specks).
    pub open_radius: usize,
    /// Radius of the closing (fills gaps in clothing that matches the background) at 480 pixels of frame height;
    /// scaled with the frame (at least 1), so gaps between limbs and body stay open at every resolution.
    pub close_radius_480: usize,
}

impl Default for PlateParams {
    fn default() -> Self {
        Self { k_sigma: 4.0, min_sigma: 0.02, shadow_min: 0.45, open_radius: 1, close_radius_480: 2 }
    }
}

/// The empty scene: per-pixel median colour and noise level over one or more frames.
#[derive(Clone, Debug)]
pub struct CleanPlate {
    /// Per-pixel median, linear RGB.
    pub median: RgbImage,
    /// Per-pixel noise (1.4826 x median absolute deviation of the colour distance to the median).
    pub sigma: GrayImage,
}

impl CleanPlate {
    /// Builds the plate from frames of the empty scene (all of one size).
    pub fn from_frames(frames: &[RgbImage]) -> Result<Self, CaptureError> {
        let err = |reason: String| CaptureError::Segment { method: "clean-plate", reason };
        let first = frames.first().ok_or_else(|| err("no plate frames".into()))?;
        let (w, h) = (first.width, first.height);
        if frames.iter().any(|f| (f.width, f.height) != (w, h)) {
            return Err(err("the plate frames differ in size; capture the plate with the same camera mode".into()));
        }
        let n = frames.len();
        let mut median = Image::new(w, h, Vec3::ZERO);
        let mut sigma = Image::new(w, h, 0.0);
        let mut chan = vec![0.0f32; n];
        let mut dist = vec![0.0f32; n];
        let med = |v: &mut [f32]| -> f32 {
            v.sort_by(|a, b| a.total_cmp(b));
            let m = v.len() / 2;
            if v.len() % 2 == 1 {
                v[m]
            } else {
                0.5 * (v[m - 1] + v[m])
            }
        };
        for i in 0..w * h {
            let mut m = Vec3::ZERO;
            for c in 0..3 {
                for (k, f) in frames.iter().enumerate() {
                    chan[k] = f.data[i][c];
                }
                m[c] = med(&mut chan);
            }
            for (k, f) in frames.iter().enumerate() {
                dist[k] = (f.data[i] - m).length();
            }
            median.data[i] = m;
            sigma.data[i] = 1.4826 * med(&mut dist);
        }
        Ok(Self { median, sigma })
    }

    /// The raw foreground test (before morphology).
    pub fn raw_foreground(&self, rgb: &RgbImage, p: &PlateParams) -> BinaryMask {
        Image {
            width: rgb.width,
            height: rgb.height,
            data: rgb
                .data
                .iter()
                .zip(&self.median.data)
                .zip(&self.sigma.data)
                .map(|((&i, &e), &s)| {
                    let tol = p.k_sigma * s.max(p.min_sigma);
                    if (i - e).length() <= tol {
                        return false;
                    }
                    // Brightness/chroma split (Horprasert et al.): a = best scale of the plate colour, the rest is
                    // chroma. A shadow is a darker copy of the background with little chroma change.
                    let ee = e.length_squared();
                    if ee > 1e-6 {
                        let a = i.dot(e) / ee;
                        let chroma = (i - a * e).length();
                        if (p.shadow_min..=1.0).contains(&a) && chroma <= tol {
                            return false;
                        }
                    }
                    true
                })
                .collect(),
        }
    }

    /// Segments one frame: raw test, opening, closing, largest component, hole filling.
    pub fn segment(&self, rgb: &RgbImage, p: &PlateParams) -> Result<GrayImage, CaptureError> {
        if (rgb.width, rgb.height) != (self.median.width, self.median.height) {
            return Err(CaptureError::Segment {
                method: "clean-plate",
                reason: format!(
                    "the frame is {}x{} but the plate is {}x{}; recapture the plate",
                    rgb.width, rgb.height, self.median.width, self.median.height
                ),
            });
        }
        let raw = self.raw_foreground(rgb, p);
        let close_radius = ((p.close_radius_480 * rgb.height) as f32 / 480.0).round().max(1.0) as usize;
        let cleaned = close(&open(&raw, p.open_radius), close_radius);
        Ok(to_gray(&fill_holes(&largest_component(&cleaned))))
    }
}

/// Clean-plate segmentation that first learns the plate from the source's first frames (empty masks meanwhile).
pub struct CleanPlateSegmenter {
    plate: Option<CleanPlate>,
    learning: Vec<RgbImage>,
    plate_frames: usize,
    /// The test's tunables.
    pub params: PlateParams,
}

impl CleanPlateSegmenter {
    /// Learns the plate from the next `plate_frames` frames (at least 1).
    pub fn learning(plate_frames: usize) -> Self {
        Self { plate: None, learning: Vec::new(), plate_frames: plate_frames.max(1), params: PlateParams::default() }
    }

    /// Uses a plate captured beforehand.
    pub fn with_plate(plate: CleanPlate) -> Self {
        Self { plate: Some(plate), learning: Vec::new(), plate_frames: 0, params: PlateParams::default() }
    }

    /// True once the plate is known.
    pub fn has_plate(&self) -> bool {
        self.plate.is_some()
    }
}

impl Segmenter for CleanPlateSegmenter {
    fn name(&self) -> &'static str {
        "clean-plate"
    }

    fn segment(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        if let Some(plate) = &self.plate {
            return plate.segment(&frame.rgb, &self.params);
        }
        if self.learning.first().is_some_and(|f| (f.width, f.height) != (frame.width(), frame.height())) {
            self.learning.clear();
        }
        self.learning.push(frame.rgb.clone());
        if self.learning.len() >= self.plate_frames {
            self.plate = Some(CleanPlate::from_frames(&self.learning)?);
            self.learning.clear();
            tracing::info!("clean plate captured from {} frames", self.plate_frames);
        }
        // While learning, the scene is assumed empty.
        Ok(Image::new(frame.width(), frame.height(), 0.0))
    }
}
