//! Cameras through `nokhwa` 0.10 (V4L2 on Linux): listing, format choice and a [`FrameSource`] that survives
//! a camera that disappears mid-stream (it reports [`CaptureError::CameraLost`] and reopens the device).
//!
//! The device itself sits behind [`CameraBackend`], so format choice, loss and reconnection are testable without
//! hardware; [`NokhwaBackend`] is the real one.

use std::time::{Duration, Instant};

use nokhwa::pixel_format::RgbFormat;
use nokhwa::utils::{ApiBackend, CameraFormat, CameraIndex, FrameFormat, RequestedFormat, RequestedFormatType};

use super::{frame_from_srgb8, CaptureError, Frame, FrameSource, SourceEvent};

/// Smallest accepted frame side: below this the segmentation and geometry have nothing to work with.
pub const MIN_SIDE: u32 = 64;

/// A camera device's own error: nokhwa's (V4L2 on Linux), or another backend's ([`CameraBackend`] test doubles).
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// nokhwa's error (opening, querying, streaming, decoding a frame).
    #[error("{0}")]
    Driver(#[source] nokhwa::NokhwaError),
    /// Another backend's error.
    #[error("{0}")]
    Other(#[source] Box<dyn std::error::Error + Send + Sync>),
}

impl From<nokhwa::NokhwaError> for DeviceError {
    fn from(e: nokhwa::NokhwaError) -> Self {
        DeviceError::Driver(e)
    }
}

impl From<&str> for DeviceError {
    fn from(message: &str) -> Self {
        DeviceError::Other(message.into())
    }
}

impl From<String> for DeviceError {
    fn from(message: String) -> Self {
        DeviceError::Other(message.into())
    }
}

/// Why a camera stopped delivering frames ([`CaptureError::CameraLost`]).
#[derive(Debug, thiserror::Error)]
pub enum CameraLoss {
    /// Reading a frame failed (the device was unplugged, the driver gave up).
    #[error("{0}")]
    Read(#[source] DeviceError),
    /// Reopening the device failed (still unplugged).
    #[error("reopening failed: {0}")]
    Reopen(#[source] DeviceError),
    /// The device came back but could not be started again (no usable format any more, refused stream).
    #[error("{0}")]
    Restart(#[source] Box<CaptureError>),
    /// No device is open.
    #[error("no device")]
    NoDevice,
}

/// A camera offers no usable format ([`choose_format`]): what it offers, for the message.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}", describe_offered(.0))]
pub struct NoUsableFormat(pub Vec<CameraFormat>);

/// "none offered", or every offered format as `WxH FORMAT R fps`, comma-separated.
fn describe_offered(offered: &[CameraFormat]) -> String {
    if offered.is_empty() {
        return "none offered".into();
    }
    let list: Vec<String> =
        offered.iter().map(|f| format!("{}x{} {} {} fps", f.width(), f.height(), f.format(), f.frame_rate())).collect();
    list.join(", ")
}

/// One camera as listed by the operating system.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceInfo {
    /// Index to pass to `--camera`.
    pub index: u32,
    /// Human-readable name.
    pub name: String,
    /// Driver description (bus, path).
    pub description: String,
}

/// Lists the cameras (V4L2 on Linux). An empty list means no camera; an error means the query itself failed.
pub fn list_devices() -> Result<Vec<DeviceInfo>, CaptureError> {
    let backend = nokhwa::native_api_backend().unwrap_or(ApiBackend::Auto);
    let infos = match nokhwa::query(backend) {
        Ok(v) => v,
        // V4L2 reports a missing /dev/video* as an error: that is simply "no camera".
        Err(e) if no_video_nodes() => {
            tracing::debug!("camera query failed without /dev/video*: {e}");
            Vec::new()
        }
        Err(e) => return Err(CaptureError::CameraList { source: e.into() }),
    };
    Ok(infos
        .iter()
        .enumerate()
        .map(|(i, info)| DeviceInfo {
            index: info.index().as_index().unwrap_or(i as u32),
            name: info.human_name(),
            description: info.description().to_string(),
        })
        .collect())
}

fn no_video_nodes() -> bool {
    std::fs::read_dir("/dev")
        .map(|d| !d.filter_map(|e| e.ok()).any(|e| e.file_name().to_string_lossy().starts_with("video")))
        .unwrap_or(true)
}

/// Text for `r2human devices`: every camera with the formats it offers, or one sentence when there is none.
pub fn devices_report() -> String {
    let devices = match list_devices() {
        Ok(d) => d,
        Err(e) => return format!("{e}\n"),
    };
    if devices.is_empty() {
        return format!("{}\n", CaptureError::NoCamera);
    }
    let mut out = String::new();
    for d in &devices {
        out.push_str(&format!("camera {}: {} ({})\n", d.index, d.name, d.description));
        match NokhwaBackend::open(d.index).and_then(|mut b| b.formats()) {
            Ok(formats) => {
                let mut formats = formats;
                formats.sort_by_key(|f| (std::cmp::Reverse(f.width() * f.height()), f.format().to_string()));
                for f in formats.iter().filter(|f| is_supported(f)) {
                    out.push_str(&format!("    {}x{} {} {} fps\n", f.width(), f.height(), f.format(), f.frame_rate()));
                }
                if !formats.iter().any(is_supported) {
                    out.push_str("    (no supported format)\n");
                }
            }
            Err(e) => out.push_str(&format!("    formats unavailable: {e}\n")),
        }
    }
    out
}

/// What the user asks of a camera (`--camera N` plus optional size, rate and pixel format).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraRequest {
    /// Camera index (see `r2human devices`).
    pub index: u32,
    /// Wanted frame size; the closest offered size is used. `None`: the largest up to 1280x720.
    pub resolution: Option<(u32, u32)>,
    /// Wanted frame rate; the closest offered rate is used. `None`: the highest.
    pub fps: Option<u32>,
    /// Wanted pixel format; `None`: MJPEG, then YUYV, NV12, RGB, GRAY.
    pub format: Option<FrameFormat>,
}

/// Parses a pixel-format name given on the command line (`mjpeg`, `yuyv`, `nv12`, `rgb`, `bgr`, `gray`).
pub fn parse_frame_format(s: &str) -> Option<FrameFormat> {
    match s.to_ascii_lowercase().as_str() {
        "mjpeg" | "mjpg" => Some(FrameFormat::MJPEG),
        "yuyv" | "yuy2" => Some(FrameFormat::YUYV),
        "nv12" => Some(FrameFormat::NV12),
        "rgb" | "rgb24" | "rawrgb" => Some(FrameFormat::RAWRGB),
        "bgr" | "bgr24" | "rawbgr" => Some(FrameFormat::RAWBGR),
        "gray" | "grey" | "y8" => Some(FrameFormat::GRAY),
        _ => None,
    }
}

/// Whether a camera format can be used: decodable by nokhwa, at least [`MIN_SIDE`] pixels a side, a real rate.
pub fn is_supported(f: &CameraFormat) -> bool {
    f.width() >= MIN_SIDE && f.height() >= MIN_SIDE && f.frame_rate() > 0
}

fn format_rank(f: FrameFormat) -> u32 {
    match f {
        FrameFormat::MJPEG => 0,
        FrameFormat::YUYV => 1,
        FrameFormat::NV12 => 2,
        FrameFormat::RAWRGB => 3,
        FrameFormat::RAWBGR => 4,
        FrameFormat::GRAY => 5,
    }
}

/// Picks the offered format closest to the request: size first (sum of side differences; without a request the
/// largest not above 1280x720, else the smallest), then rate, then pixel format. `Err` holds what was offered.
pub fn choose_format(offered: &[CameraFormat], request: &CameraRequest) -> Result<CameraFormat, NoUsableFormat> {
    let usable: Vec<&CameraFormat> = offered.iter().filter(|f| is_supported(f)).collect();
    let size_cost = |f: &CameraFormat| -> i64 {
        match request.resolution {
            Some((w, h)) => (f.width() as i64 - w as i64).abs() + (f.height() as i64 - h as i64).abs(),
            None => {
                let px = f.width() as i64 * f.height() as i64;
                if px <= 1280 * 720 {
                    -px
                } else {
                    px
                }
            }
        }
    };
    let fps_cost = |f: &CameraFormat| -> i64 {
        match request.fps {
            Some(r) => (f.frame_rate() as i64 - r as i64).abs(),
            None => -(f.frame_rate() as i64),
        }
    };
    let fmt_cost = |f: &CameraFormat| -> u32 {
        match request.format {
            Some(want) if want == f.format() => 0,
            Some(_) => 10 + format_rank(f.format()),
            None => format_rank(f.format()),
        }
    };
    let best = usable.into_iter().min_by_key(|f| (size_cost(f), fps_cost(f), fmt_cost(f))).copied();
    best.ok_or_else(|| NoUsableFormat(offered.to_vec()))
}

/// One camera device: what [`CameraSource`] needs from it. Not `Send`: V4L2 handles stay on the thread that
/// opened them (the live loop opens sources on its capture thread).
pub trait CameraBackend {
    /// Human-readable name.
    fn name(&self) -> String;
    /// All formats the device offers.
    fn formats(&mut self) -> Result<Vec<CameraFormat>, DeviceError>;
    /// Starts streaming in `format`.
    fn start(&mut self, format: CameraFormat) -> Result<(), DeviceError>;
    /// Blocks for the next frame: 8-bit sRGB, 3 channels, row-major, with its size.
    fn frame(&mut self) -> Result<(Vec<u8>, usize, usize), DeviceError>;
}

/// The real device, through nokhwa.
pub struct NokhwaBackend {
    camera: nokhwa::Camera,
}

impl NokhwaBackend {
    /// Opens camera `index` (no stream yet).
    pub fn open(index: u32) -> Result<Self, DeviceError> {
        let request = RequestedFormat::new::<RgbFormat>(RequestedFormatType::AbsoluteHighestFrameRate);
        let camera = nokhwa::Camera::new(CameraIndex::Index(index), request)?;
        Ok(Self { camera })
    }
}

impl CameraBackend for NokhwaBackend {
    fn name(&self) -> String {
        self.camera.info().human_name()
    }

    fn formats(&mut self) -> Result<Vec<CameraFormat>, DeviceError> {
        Ok(self.camera.compatible_camera_formats()?)
    }

    fn start(&mut self, format: CameraFormat) -> Result<(), DeviceError> {
        let request = RequestedFormat::new::<RgbFormat>(RequestedFormatType::Exact(format));
        self.camera.set_camera_requset(request)?;
        Ok(self.camera.open_stream()?)
    }

    fn frame(&mut self) -> Result<(Vec<u8>, usize, usize), DeviceError> {
        let buffer = self.camera.frame()?;
        let img = buffer.decode_image::<RgbFormat>()?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        Ok((img.into_raw(), w, h))
    }
}

impl Drop for NokhwaBackend {
    fn drop(&mut self) {
        let _ = self.camera.stop_stream();
    }
}

/// Opens a backend for a camera index; called again to reconnect after a loss.
pub type BackendOpener = Box<dyn FnMut(u32) -> Result<Box<dyn CameraBackend>, DeviceError> + Send>;

/// A camera as a frame source. A failing frame read drops the device and returns [`CaptureError::CameraLost`];
/// the next calls try to reopen it (at most every `retry_interval`), so the session never ends because of it.
pub struct CameraSource {
    request: CameraRequest,
    opener: BackendOpener,
    backend: Option<Box<dyn CameraBackend>>,
    name: String,
    format: CameraFormat,
    started: Instant,
    next: u64,
    last_attempt: Option<Instant>,
    /// Minimum time between two reconnection attempts.
    pub retry_interval: Duration,
}

impl CameraSource {
    /// Opens the requested camera through nokhwa and starts it in the closest supported format.
    pub fn open(request: &CameraRequest) -> Result<Self, CaptureError> {
        let devices = list_devices()?;
        if devices.is_empty() {
            return Err(CaptureError::NoCamera);
        }
        if !devices.iter().any(|d| d.index == request.index) {
            return Err(CaptureError::CameraIndex { index: request.index, count: devices.len() });
        }
        let opener: BackendOpener = Box::new(|i| NokhwaBackend::open(i).map(|b| Box::new(b) as Box<dyn CameraBackend>));
        Self::with_backend(request, opener)
    }

    /// Opens a camera through any backend (tests use fake devices).
    pub fn with_backend(request: &CameraRequest, mut opener: BackendOpener) -> Result<Self, CaptureError> {
        let index = request.index;
        let mut backend = opener(index).map_err(|source| CaptureError::Camera { index, source })?;
        let format = start_backend(backend.as_mut(), request)?;
        Ok(Self {
            request: request.clone(),
            opener,
            name: backend.name(),
            backend: Some(backend),
            format,
            started: Instant::now(),
            next: 0,
            last_attempt: None,
            retry_interval: Duration::from_millis(500),
        })
    }

    /// The format the camera streams in.
    pub fn format(&self) -> CameraFormat {
        self.format
    }

    fn reconnect(&mut self) -> Result<(), CaptureError> {
        let index = self.request.index;
        if let Some(t) = self.last_attempt {
            let wait = self.retry_interval.saturating_sub(t.elapsed());
            std::thread::sleep(wait);
        }
        self.last_attempt = Some(Instant::now());
        let lost = |source: CameraLoss| CaptureError::CameraLost { index, source };
        let mut backend = (self.opener)(index).map_err(|e| lost(CameraLoss::Reopen(e)))?;
        self.format =
            start_backend(backend.as_mut(), &self.request).map_err(|e| lost(CameraLoss::Restart(Box::new(e))))?;
        tracing::info!("camera {index} reconnected");
        self.backend = Some(backend);
        Ok(())
    }
}

fn start_backend(backend: &mut dyn CameraBackend, request: &CameraRequest) -> Result<CameraFormat, CaptureError> {
    let index = request.index;
    let offered = backend.formats().map_err(|source| CaptureError::Camera { index, source })?;
    let format = choose_format(&offered, request).map_err(|offered| CaptureError::NoSupportedFormat {
        index,
        name: backend.name(),
        offered,
        min: MIN_SIDE,
    })?;
    backend.start(format).map_err(|source| CaptureError::CameraStart {
        index,
        width: format.width(),
        height: format.height(),
        format: format.format(),
        source,
    })?;
    Ok(format)
}

impl FrameSource for CameraSource {
    fn describe(&self) -> String {
        let f = self.format;
        format!(
            "camera {} ({}) {}x{} {} {} fps",
            self.request.index,
            self.name,
            f.width(),
            f.height(),
            f.format(),
            f.frame_rate()
        )
    }

    fn next_frame(&mut self) -> Result<SourceEvent, CaptureError> {
        let index = self.request.index;
        if self.backend.is_none() {
            self.reconnect()?;
        }
        let Some(backend) = self.backend.as_mut() else {
            return Err(CaptureError::CameraLost { index, source: CameraLoss::NoDevice });
        };
        let (bytes, w, h) = match backend.frame() {
            Ok(f) => f,
            Err(e) => {
                self.backend = None;
                return Err(CaptureError::CameraLost { index, source: CameraLoss::Read(e) });
            }
        };
        let frame_index = self.next;
        self.next += 1;
        let (rgb, _) = frame_from_srgb8(&bytes, w, h, 3, false).ok_or_else(|| CaptureError::CorruptFrame {
            index: frame_index,
            path: format!("camera {index}").into(),
            reason: format!("{} bytes for a {w}x{h} RGB frame", bytes.len()),
        })?;
        Ok(SourceEvent::Frame(Frame { index: frame_index, timestamp: self.started.elapsed(), rgb, alpha: None }))
    }

    fn nominal_fps(&self) -> Option<f32> {
        Some(self.format.frame_rate() as f32)
    }

    fn is_live(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(w: u32, h: u32, fmt: FrameFormat, fps: u32) -> CameraFormat {
        CameraFormat::new_from(w, h, fmt, fps)
    }

    #[test]
    fn format_choice() {
        let offered = [
            f(1920, 1080, FrameFormat::MJPEG, 30),
            f(1280, 720, FrameFormat::MJPEG, 30),
            f(1280, 720, FrameFormat::YUYV, 10),
            f(640, 480, FrameFormat::YUYV, 30),
            f(640, 480, FrameFormat::MJPEG, 30),
            f(32, 32, FrameFormat::MJPEG, 30),
        ];
        // Default: largest up to 720p, highest rate, MJPEG first.
        assert_eq!(choose_format(&offered, &CameraRequest::default()).unwrap(), offered[1]);
        let req = CameraRequest { resolution: Some((600, 500)), format: Some(FrameFormat::YUYV), ..Default::default() };
        assert_eq!(choose_format(&offered, &req).unwrap(), offered[3]);
        let req = CameraRequest { resolution: Some((1280, 720)), fps: Some(10), ..Default::default() };
        assert_eq!(choose_format(&offered, &req).unwrap(), offered[2]);
        assert_eq!(choose_format(&[], &req).unwrap_err().to_string(), "none offered");
        let err = choose_format(&offered[5..], &req).unwrap_err();
        assert_eq!(err, NoUsableFormat(offered[5..].to_vec()));
        assert_eq!(err.to_string(), "32x32 MJPEG 30 fps");
        let two = NoUsableFormat(vec![offered[5], f(16, 8, FrameFormat::GRAY, 0)]).to_string();
        assert_eq!(two, "32x32 MJPEG 30 fps, 16x8 GRAY 0 fps");
    }

    #[test]
    fn frame_format_names() {
        assert_eq!(parse_frame_format("MJPG"), Some(FrameFormat::MJPEG));
        assert_eq!(parse_frame_format("yuyv"), Some(FrameFormat::YUYV));
        assert_eq!(parse_frame_format("h264"), None);
    }
}
