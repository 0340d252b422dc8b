//! Video files, decoded by Debian's `ffmpeg` command-line tool in a subprocess that writes raw 8-bit sRGB(A) frames
//! to a pipe (`-f rawvideo`). `ffprobe` reads the stream's size, rate and pixel format first.
//!
//! Why a subprocess: it needs no native FFmpeg bindings at build time, decodes every format ffmpeg knows, and a
//! crashing decoder cannot take the application down (it shows up as [`CaptureError::StreamLost`]).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::{frame_from_srgb8, CaptureError, Frame, FrameSource, SourceEvent};
use crate::io::image_io::MAX_INPUT_SIDE;

/// What ffprobe says about the first video stream.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoInfo {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Frames per second (average rate; 30 when the container does not say).
    pub fps: f32,
    /// ffmpeg's pixel format name, e.g. `yuv420p`, `rgba`.
    pub pix_fmt: String,
}

impl VideoInfo {
    /// Channels the reader requests from ffmpeg: 4 (RGBA) with an alpha plane, else 3 (RGB).
    pub fn channels(&self) -> usize {
        if self.has_alpha() {
            4
        } else {
            3
        }
    }

    /// Bytes of one decoded frame as the reader requests it from ffmpeg.
    pub fn frame_bytes(&self) -> usize {
        self.width * self.height * self.channels()
    }

    /// True for pixel formats with an alpha plane (`rgba`, `yuva420p`, `gbrap`, `ya8`, …).
    pub fn has_alpha(&self) -> bool {
        let f = self.pix_fmt.as_str();
        f.starts_with("yuva")
            || f.starts_with("gbrap")
            || f.starts_with("ya")
            || ["rgba", "bgra", "argb", "abgr", "rgba64", "bgra64", "pal8"].iter().any(|p| f.starts_with(p))
    }
}

/// Parses an ffmpeg rational like `30000/1001` (or a plain number); `None` for `0/0` and garbage.
pub fn parse_rate(s: &str) -> Option<f32> {
    let v = match s.split_once('/') {
        Some((n, d)) => n.trim().parse::<f64>().ok()? / d.trim().parse::<f64>().ok()?,
        None => s.trim().parse::<f64>().ok()?,
    };
    (v.is_finite() && v > 0.0).then_some(v as f32)
}

/// Why ffprobe's description of a file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProbeError {
    /// Not JSON.
    #[error("unreadable ffprobe output: {0}")]
    Unreadable(#[from] serde_json::Error),
    /// No stream listed.
    #[error("no video stream")]
    NoStream,
    /// Width or height missing or zero.
    #[error("the video stream has no valid size")]
    NoSize,
    /// Larger than the input limit.
    #[error("the video is {width}x{height} pixels; the limit is {max}x{max}: downscale it first")]
    TooLarge {
        /// Declared width.
        width: u64,
        /// Declared height.
        height: u64,
        /// The limit per side ([`MAX_INPUT_SIDE`]).
        max: u64,
    },
}

/// Parses `ffprobe -of json -show_entries stream=width,height,avg_frame_rate,r_frame_rate,pix_fmt` output.
pub fn parse_ffprobe_json(json: &str) -> Result<VideoInfo, ProbeError> {
    let v: serde_json::Value = serde_json::from_str(json)?;
    let s = v.get("streams").and_then(|s| s.get(0)).ok_or(ProbeError::NoStream)?;
    let dim = |k: &str| s.get(k).and_then(|x| x.as_u64()).filter(|&x| x > 0);
    let (width, height) = match (dim("width"), dim("height")) {
        (Some(w), Some(h)) => (w, h),
        _ => return Err(ProbeError::NoSize),
    };
    // The same limit as photos: a frame buffer is allocated from this size before any frame is decoded.
    let max = MAX_INPUT_SIDE as u64;
    if width > max || height > max {
        return Err(ProbeError::TooLarge { width, height, max });
    }
    let (width, height) = (width as usize, height as usize);
    let rate = |k: &str| s.get(k).and_then(|x| x.as_str()).and_then(parse_rate);
    let fps = rate("avg_frame_rate").or_else(|| rate("r_frame_rate")).unwrap_or(30.0).clamp(0.1, 1000.0);
    let pix_fmt = s.get("pix_fmt").and_then(|x| x.as_str()).unwrap_or("unknown").to_string();
    Ok(VideoInfo { width, height, fps, pix_fmt })
}

/// The stream description of `path` from ffprobe's JSON output (`stdout`); errors name the file.
pub fn info_from_ffprobe(path: &Path, stdout: &[u8]) -> Result<VideoInfo, CaptureError> {
    parse_ffprobe_json(&String::from_utf8_lossy(stdout))
        .map_err(|e| CaptureError::Probe { path: path.into(), source: Box::new(e) })
}

/// Runs ffprobe on `path`.
pub fn probe(path: &Path) -> Result<VideoInfo, CaptureError> {
    let out = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .arg("stream=width,height,avg_frame_rate,r_frame_rate,pix_fmt")
        .args(["-of", "json"])
        .arg(path)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => CaptureError::FfmpegMissing("ffprobe"),
            _ => CaptureError::Open { path: path.into(), reason: e.to_string() },
        })?;
    if !out.status.success() {
        let reason = String::from_utf8_lossy(&out.stderr).trim().to_string();
        return Err(CaptureError::NoVideoStream { path: path.into(), reason });
    }
    info_from_ffprobe(path, &out.stdout)
}

/// A video file decoded by an `ffmpeg` subprocess.
pub struct VideoFileSource {
    path: PathBuf,
    info: VideoInfo,
    channels: usize,
    child: Child,
    stdout: Option<ChildStdout>,
    stderr: Arc<Mutex<String>>,
    /// The thread draining ffmpeg's stderr; joined once ffmpeg has exited, so its messages are complete.
    stderr_reader: Option<std::thread::JoinHandle<()>>,
    buf: Vec<u8>,
    next: u64,
}

impl VideoFileSource {
    /// Probes the file and starts the decoder.
    pub fn open(path: &Path) -> Result<Self, CaptureError> {
        if !path.is_file() {
            return Err(CaptureError::Open { path: path.into(), reason: "not a file".into() });
        }
        let info = probe(path)?;
        let channels = info.channels();
        let mut child = Command::new("ffmpeg")
            // -noautorotate keeps the frame size equal to what ffprobe reported.
            .args(["-nostdin", "-v", "error", "-noautorotate", "-i"])
            .arg(path)
            .args(["-map", "0:v:0", "-f", "rawvideo", "-pix_fmt", if channels == 4 { "rgba" } else { "rgb24" }, "-"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::NotFound => CaptureError::FfmpegMissing("ffmpeg"),
                _ => CaptureError::Open { path: path.into(), reason: e.to_string() },
            })?;
        let stderr = Arc::new(Mutex::new(String::new()));
        let stderr_reader = child.stderr.take().map(|mut err| {
            let sink = Arc::clone(&stderr);
            // Drains ffmpeg's messages so the pipe never fills up; read when the stream fails.
            std::thread::spawn(move || {
                let mut s = String::new();
                let _ = err.read_to_string(&mut s);
                if let Ok(mut g) = sink.lock() {
                    g.push_str(&s);
                }
            })
        });
        let stdout = child.stdout.take();
        let buf = vec![0u8; info.frame_bytes()];
        Ok(Self { path: path.into(), info, channels, child, stdout, stderr, stderr_reader, buf, next: 0 })
    }

    /// The probed stream description.
    pub fn info(&self) -> &VideoInfo {
        &self.info
    }

    /// Waits for ffmpeg to exit and for its stderr to be read to the end (the pipe closes when it exits), so
    /// what it printed is known before deciding whether the stream ended cleanly.
    fn wait_for_decoder(&mut self) -> Option<std::process::ExitStatus> {
        let status = self.child.wait().ok();
        if let Some(reader) = self.stderr_reader.take() {
            let _ = reader.join();
        }
        status
    }

    fn decoder_message(&mut self) -> String {
        let status = self.wait_for_decoder();
        let msg = self.stderr.lock().map(|s| s.trim().to_string()).unwrap_or_default();
        match (msg.is_empty(), status) {
            (false, _) => msg,
            (true, Some(s)) => format!("ffmpeg exited with {s}"),
            (true, None) => "ffmpeg vanished".into(),
        }
    }
}

impl FrameSource for VideoFileSource {
    fn describe(&self) -> String {
        let i = &self.info;
        format!("video `{}` ({}x{}, {:.2} fps, {})", self.path.display(), i.width, i.height, i.fps, i.pix_fmt)
    }

    fn next_frame(&mut self) -> Result<SourceEvent, CaptureError> {
        let Some(out) = self.stdout.as_mut() else {
            return Ok(SourceEvent::End);
        };
        let mut filled = 0;
        while filled < self.buf.len() {
            match out.read(&mut self.buf[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    self.stdout = None;
                    let index = self.next.saturating_sub(1);
                    return Err(CaptureError::StreamLost { path: self.path.clone(), index, reason: e.to_string() });
                }
            }
        }
        if filled < self.buf.len() {
            self.stdout = None;
            let clean_exit = self.wait_for_decoder().is_some_and(|s| s.success());
            let printed = self.stderr.lock().map(|s| !s.trim().is_empty()).unwrap_or(false);
            // A clean end: ffmpeg exited successfully, said nothing, and no partial frame is pending.
            if filled == 0 && clean_exit && !printed && self.next > 0 {
                return Ok(SourceEvent::End);
            }
            let message = self.decoder_message();
            let index = self.next.saturating_sub(1);
            let reason = if filled > 0 { format!("a truncated frame ({message})") } else { message };
            return Err(CaptureError::StreamLost { path: self.path.clone(), index, reason });
        }
        let index = self.next;
        self.next += 1;
        let (w, h) = (self.info.width, self.info.height);
        let (rgb, alpha) = frame_from_srgb8(&self.buf, w, h, self.channels, true).ok_or_else(|| {
            CaptureError::CorruptFrame { index, path: self.path.clone(), reason: "short frame buffer".into() }
        })?;
        let timestamp = Duration::from_secs_f64(index as f64 / self.info.fps as f64);
        Ok(SourceEvent::Frame(Frame { index, timestamp, rgb, alpha }))
    }

    fn nominal_fps(&self) -> Option<f32> {
        Some(self.info.fps)
    }
}

impl Drop for VideoFileSource {
    fn drop(&mut self) {
        self.stdout = None;
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates() {
        assert!((parse_rate("30000/1001").unwrap() - 29.97).abs() < 0.01);
        assert_eq!(parse_rate("25"), Some(25.0));
        assert_eq!(parse_rate("0/0"), None);
        assert_eq!(parse_rate("x"), None);
    }

    #[test]
    fn ffprobe_json() {
        let j = r#"{"programs":[],"streams":[{"width":640,"height":480,"pix_fmt":"yuva420p","r_frame_rate":"25/1","avg_frame_rate":"0/0"}]}"#;
        let i = parse_ffprobe_json(j).unwrap();
        assert_eq!((i.width, i.height), (640, 480));
        assert_eq!(i.fps, 25.0);
        assert!(i.has_alpha());
        assert!(parse_ffprobe_json(r#"{"streams":[]}"#).is_err());
        assert!(parse_ffprobe_json(r#"{"streams":[{"width":0,"height":4}]}"#).is_err());
        // A declared size past the photo limit is refused before any frame buffer exists.
        let huge = parse_ffprobe_json(r#"{"streams":[{"width":8193,"height":4}]}"#).unwrap_err().to_string();
        assert!(huge.contains("8193x4"), "{huge}");
        let named = info_from_ffprobe(Path::new("dir/clip.mp4"), b"{").unwrap_err().to_string();
        assert!(named.contains("dir/clip.mp4"), "{named}");
        assert_eq!(parse_ffprobe_json(j).unwrap().frame_bytes(), 640 * 480 * 4);
        let yuv = VideoInfo { width: 1, height: 1, fps: 1.0, pix_fmt: "yuv420p".into() };
        assert!(!yuv.has_alpha());
    }
}
