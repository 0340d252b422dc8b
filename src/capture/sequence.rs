//! Frame sources from image files: a folder of frames (sorted by name, digits compared as numbers) and a still image.

use std::cmp::Ordering;
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::{is_image_path, load_image_frame, CaptureError, Frame, FrameSource, SourceEvent};

/// Compares file names "naturally": runs of digits compare as numbers, so `frame2` sorts before `frame10`.
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (mut ai, mut bi) = (a.chars().peekable(), b.chars().peekable());
    loop {
        match (ai.peek().copied(), bi.peek().copied()) {
            (None, None) => return Ordering::Equal,
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(x), Some(y)) if x.is_ascii_digit() && y.is_ascii_digit() => {
                let take = |it: &mut std::iter::Peekable<std::str::Chars>| {
                    let mut s = String::new();
                    while let Some(c) = it.peek().copied().filter(char::is_ascii_digit) {
                        s.push(c);
                        it.next();
                    }
                    s
                };
                let (na, nb) = (take(&mut ai), take(&mut bi));
                let (ta, tb) = (na.trim_start_matches('0'), nb.trim_start_matches('0'));
                let ord = ta.len().cmp(&tb.len()).then_with(|| ta.cmp(tb)).then_with(|| na.len().cmp(&nb.len()));
                if ord != Ordering::Equal {
                    return ord;
                }
            }
            (Some(x), Some(y)) => {
                if x != y {
                    return x.cmp(&y);
                }
                ai.next();
                bi.next();
            }
        }
    }
}

/// The image files of a folder in natural name order (hidden files skipped).
pub fn list_frames(dir: &Path) -> Result<Vec<PathBuf>, CaptureError> {
    let entries = std::fs::read_dir(dir).map_err(|e| CaptureError::Open { path: dir.into(), reason: e.to_string() })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && is_image_path(p))
        .filter(|p| !p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with('.')))
        .collect();
    files.sort_by(|a, b| {
        natural_cmp(
            &a.file_name().unwrap_or_default().to_string_lossy(),
            &b.file_name().unwrap_or_default().to_string_lossy(),
        )
    });
    if files.is_empty() {
        return Err(CaptureError::EmptySequence(dir.into()));
    }
    Ok(files)
}

/// A folder of frames, read one file per `next_frame`, at a nominal rate for timestamps.
///
/// Each frame keeps its own size: a folder of photos need not share one (the consumers treat a change of size as
/// a cut and process that frame on its own, see `app::live`). A file that cannot be decoded (or has vanished
/// since the folder was listed) is a recoverable error and is skipped.
pub struct ImageSequenceSource {
    dir: PathBuf,
    files: Vec<PathBuf>,
    next: usize,
    fps: f32,
}

impl ImageSequenceSource {
    /// Lists the folder; `fps` (clamped to `[0.1, 1000]`) gives the frame timestamps.
    pub fn open(dir: &Path, fps: f32) -> Result<Self, CaptureError> {
        let files = list_frames(dir)?;
        let fps = if fps.is_finite() { fps.clamp(0.1, 1000.0) } else { 30.0 };
        Ok(Self { dir: dir.into(), files, next: 0, fps })
    }

    /// Number of files in the sequence.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// True when the sequence has no files (never after a successful `open`).
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    /// The files, in playback order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }
}

impl FrameSource for ImageSequenceSource {
    fn describe(&self) -> String {
        format!("image sequence `{}` ({} frames at {} fps)", self.dir.display(), self.files.len(), self.fps)
    }

    fn next_frame(&mut self) -> Result<SourceEvent, CaptureError> {
        let Some(path) = self.files.get(self.next).cloned() else {
            return Ok(SourceEvent::End);
        };
        let index = self.next as u64;
        self.next += 1;
        let (rgb, alpha) = load_image_frame(&path).map_err(|e| CaptureError::CorruptImage {
            index,
            path: path.clone(),
            source: Box::new(e),
        })?;
        let timestamp = Duration::from_secs_f64(index as f64 / self.fps as f64);
        Ok(SourceEvent::Frame(Frame { index, timestamp, rgb, alpha }))
    }

    fn nominal_fps(&self) -> Option<f32> {
        Some(self.fps)
    }

    fn frame_name(&self, index: u64) -> Option<String> {
        let file = self.files.get(usize::try_from(index).ok()?)?;
        Some(file.file_name().unwrap_or_default().to_string_lossy().into_owned())
    }
}

/// A single image: one frame, then the end.
pub struct StillImageSource {
    path: PathBuf,
    frame: Option<Frame>,
}

impl StillImageSource {
    /// Decodes the image now, so a bad file is reported when the source is opened.
    pub fn open(path: &Path) -> Result<Self, CaptureError> {
        let (rgb, alpha) =
            load_image_frame(path).map_err(|e| CaptureError::Image { path: path.into(), source: Box::new(e) })?;
        Ok(Self { path: path.into(), frame: Some(Frame { index: 0, timestamp: Duration::ZERO, rgb, alpha }) })
    }
}

impl FrameSource for StillImageSource {
    fn describe(&self) -> String {
        format!("still image `{}`", self.path.display())
    }

    fn next_frame(&mut self) -> Result<SourceEvent, CaptureError> {
        Ok(self.frame.take().map(SourceEvent::Frame).unwrap_or(SourceEvent::End))
    }

    fn nominal_fps(&self) -> Option<f32> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order() {
        let mut v = vec!["f10.png", "f2.png", "f1.png", "f02.png", "a.png", "f1b.png"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(v, vec!["a.png", "f1.png", "f1b.png", "f2.png", "f02.png", "f10.png"]);
        assert_eq!(natural_cmp("x", "x"), Ordering::Equal);
        assert_eq!(natural_cmp("x", "xy"), Ordering::Less);
    }
}
