//! A procedural walking figure over a still background, with exact ground-truth masks: the camera stand-in for
//! tests and benchmarks of sources, segmentation and the live loop (no camera on CI machines).
//!
//! The figure is a union of capsules (head, torso, arms, legs) with anti-aliased coverage; it walks across the
//! frame and swings its limbs with the walk phase. Colours are linear RGB. The background is a smooth wall with a
//! few darker panels (static, so a clean plate of it is exact up to the added noise).

use std::time::{Duration, Instant};

use glam::{Vec2, Vec3};

use super::{Frame, FrameSource, SourceEvent};
use crate::buffer::{GrayImage, Image, RgbImage};

/// Parameters of the synthetic walker sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct WalkerParams {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Number of frames.
    pub frames: usize,
    /// Frame rate for the timestamps.
    pub fps: f32,
    /// Standard deviation of the per-pixel sensor noise (linear units), deterministic per frame.
    pub noise: f32,
}

impl Default for WalkerParams {
    fn default() -> Self {
        Self { width: 192, height: 144, frames: 12, fps: 30.0, noise: 0.01 }
    }
}

fn capsule_distance(p: Vec2, a: Vec2, b: Vec2, r: f32) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + ab * t)).length() - r
}

/// The background wall (linear RGB) at `width x height`.
pub fn background(width: usize, height: usize) -> RgbImage {
    Image::from_fn(width, height, |c, r| {
        let (u, v) = (c as f32 / width as f32, r as f32 / height as f32);
        let mut col = Vec3::new(0.45, 0.5, 0.55) * (0.8 + 0.2 * u) + Vec3::new(0.05, 0.03, 0.0) * v;
        // Panels: darker rectangles, a floor strip.
        if (0.08..0.22).contains(&u) && (0.15..0.55).contains(&v) {
            col = Vec3::new(0.25, 0.2, 0.15);
        }
        if (0.7..0.9).contains(&u) && (0.1..0.35).contains(&v) {
            col = Vec3::new(0.6, 0.55, 0.35);
        }
        if v > 0.88 {
            col = Vec3::new(0.3, 0.28, 0.26);
        }
        col
    })
}

/// The walker at frame `i` of `params`: straight linear RGB of the figure (black outside) and its coverage in
/// `[0, 1]` (the ground-truth alpha).
pub fn walker(params: &WalkerParams, i: usize) -> (RgbImage, GrayImage) {
    let (w, h) = (params.width as f32, params.height as f32);
    let n = params.frames.max(1) as f32;
    let t = i as f32 / n;
    // Units: fraction of the frame height; the figure is 0.8 of the height tall.
    let s = h;
    let cx = w * (0.3 + 0.4 * t);
    let phase = std::f32::consts::TAU * 2.0 * t;
    let swing = 0.35 * phase.sin();
    let hip = Vec2::new(cx, 0.55 * s);
    let shoulder = Vec2::new(cx, 0.28 * s);
    let leg = 0.32 * s;
    let arm = 0.24 * s;
    let limb = |origin: Vec2, len: f32, angle: f32| origin + Vec2::new(angle.sin(), angle.cos()) * len;
    let skin = Vec3::new(0.8, 0.55, 0.4);
    let shirt = Vec3::new(0.7, 0.08, 0.06);
    let trousers = Vec3::new(0.05, 0.08, 0.3);
    let parts: [(Vec2, Vec2, f32, Vec3); 7] = [
        (Vec2::new(cx, 0.17 * s), Vec2::new(cx, 0.17 * s), 0.065 * s, skin),
        (shoulder, hip, 0.075 * s, shirt),
        (
            hip + Vec2::new(-0.035 * s, 0.0),
            limb(hip + Vec2::new(-0.035 * s, 0.0), leg, swing - 0.08),
            0.04 * s,
            trousers,
        ),
        (
            hip + Vec2::new(0.035 * s, 0.0),
            limb(hip + Vec2::new(0.035 * s, 0.0), leg, -swing + 0.08),
            0.04 * s,
            trousers,
        ),
        (
            shoulder + Vec2::new(-0.07 * s, 0.02 * s),
            limb(shoulder + Vec2::new(-0.07 * s, 0.02 * s), arm, -0.8 * swing - 0.3),
            0.028 * s,
            skin,
        ),
        (
            shoulder + Vec2::new(0.07 * s, 0.02 * s),
            limb(shoulder + Vec2::new(0.07 * s, 0.02 * s), arm, 0.8 * swing + 0.3),
            0.028 * s,
            skin,
        ),
        (Vec2::new(cx, 0.22 * s), Vec2::new(cx, 0.27 * s), 0.03 * s, skin),
    ];
    let mut rgb = Image::new(params.width, params.height, Vec3::ZERO);
    let mut cov = Image::new(params.width, params.height, 0.0f32);
    for r in 0..params.height {
        for c in 0..params.width {
            let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
            // Nearest part gives the colour; coverage from the union's signed distance (1 px ramp).
            let (d, col) = parts
                .iter()
                .map(|&(a, b, rad, col)| (capsule_distance(p, a, b, rad), col))
                .fold((f32::INFINITY, Vec3::ZERO), |acc, x| if x.0 < acc.0 { x } else { acc });
            let a = (0.5 - d).clamp(0.0, 1.0);
            if a > 0.0 {
                // Simple shading: brighter towards the figure's left side.
                let shade = 0.85 + 0.15 * ((cx - p.x) / (0.1 * s)).clamp(-1.0, 1.0);
                rgb.set(c, r, col * shade);
                cov.set(c, r, a);
            }
        }
    }
    (rgb, cov)
}

/// Deterministic pseudo-random noise in `[-1, 1]` for pixel `k` of frame `i` (a hash, no RNG state).
fn noise(i: usize, k: usize) -> f32 {
    let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (k as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    (x >> 40) as f32 / (1u64 << 23) as f32 - 1.0
}

/// Frame `i` composited over the background with sensor noise: `(rgb, ground-truth mask)`.
pub fn composite(params: &WalkerParams, i: usize) -> (RgbImage, GrayImage) {
    let bg = background(params.width, params.height);
    let (fg, cov) = walker(params, i);
    let data = bg
        .data
        .iter()
        .zip(&fg.data)
        .zip(&cov.data)
        .enumerate()
        .map(|(k, ((&b, &f), &a))| {
            (f * a + b * (1.0 - a) + Vec3::splat(params.noise * noise(i, k))).clamp(Vec3::ZERO, Vec3::ONE)
        })
        .collect();
    (Image { width: params.width, height: params.height, data }, cov)
}

/// The background alone with frame-`i` noise (an empty-scene frame for the clean plate).
pub fn empty_scene(params: &WalkerParams, i: usize) -> RgbImage {
    let mut bg = background(params.width, params.height);
    for (k, v) in bg.data.iter_mut().enumerate() {
        *v = (*v + Vec3::splat(params.noise * noise(i + 1_000_000, k))).clamp(Vec3::ZERO, Vec3::ONE);
    }
    bg
}

/// The walker as a frame source: the first `plate_frames` frames show the empty scene (for clean-plate
/// segmentation), then the walker over the background; `with_alpha` adds the ground-truth alpha to each frame.
pub struct WalkerSource {
    params: WalkerParams,
    plate_frames: usize,
    with_alpha: bool,
    next: usize,
}

impl WalkerSource {
    /// A source of `plate_frames` empty frames followed by `params.frames` walker frames.
    pub fn new(params: WalkerParams, plate_frames: usize, with_alpha: bool) -> Self {
        Self { params, plate_frames, with_alpha, next: 0 }
    }
}

impl FrameSource for WalkerSource {
    fn describe(&self) -> String {
        format!("synthetic walker {}x{} ({} frames)", self.params.width, self.params.height, self.params.frames)
    }

    fn next_frame(&mut self) -> Result<SourceEvent, super::CaptureError> {
        let k = self.next;
        if k >= self.plate_frames + self.params.frames {
            return Ok(SourceEvent::End);
        }
        self.next += 1;
        let (rgb, alpha) = if k < self.plate_frames {
            let bg = empty_scene(&self.params, k);
            let a = Image::new(bg.width, bg.height, 0.0);
            (bg, a)
        } else {
            composite(&self.params, k - self.plate_frames)
        };
        let timestamp = Duration::from_secs_f64(k as f64 / self.params.fps.max(0.1) as f64);
        Ok(SourceEvent::Frame(Frame { index: k as u64, timestamp, rgb, alpha: self.with_alpha.then_some(alpha) }))
    }

    fn nominal_fps(&self) -> Option<f32> {
        Some(self.params.fps)
    }
}

/// The prefix of a synthetic live source given to `--video`: `synthetic:[WxH][@FPS][+faults]`.
pub const LIVE_PREFIX: &str = "synthetic:";

/// A parsed `--video synthetic:…` request.
#[derive(Clone, Debug, PartialEq)]
pub struct LiveSpec {
    /// Frame size (default 320x240).
    pub width: usize,
    /// Frame size.
    pub height: usize,
    /// Frames per second delivered in real time (default 30).
    pub fps: f32,
    /// Run the fault script ([`FaultScript`]) over and over.
    pub faults: bool,
}

/// A `synthetic:` source spec that does not parse ([`LiveSpec::parse`]).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{spec:?}: {problem}; expected synthetic:[WxH][@FPS][+faults], e.g. synthetic:320x240@30+faults")]
pub struct BadLiveSpec {
    /// The spec as given.
    pub spec: String,
    /// Which part is wrong and what it must be.
    pub problem: &'static str,
}

impl LiveSpec {
    /// Parses `synthetic:[WxH][@FPS][+faults]` (e.g. `synthetic:`, `synthetic:640x480@30`,
    /// `synthetic:320x240+faults`); `None` when `spec` does not start with [`LIVE_PREFIX`].
    pub fn parse(spec: &str) -> Option<Result<LiveSpec, BadLiveSpec>> {
        let rest = spec.strip_prefix(LIVE_PREFIX)?;
        let bad = |problem: &'static str| Err(BadLiveSpec { spec: spec.to_string(), problem });
        let (rest, faults) = match rest.strip_suffix("+faults") {
            Some(r) => (r, true),
            None => (rest, false),
        };
        let (size, fps) = match rest.split_once('@') {
            Some((s, f)) => (s, Some(f)),
            None => (rest, None),
        };
        let (width, height) = if size.is_empty() {
            (320, 240)
        } else {
            match size.split_once('x').map(|(w, h)| (w.parse::<usize>(), h.parse::<usize>())) {
                Some((Ok(w), Ok(h))) if (16..=4096).contains(&w) && (16..=4096).contains(&h) => (w, h),
                _ => return Some(bad("the size must be WxH with sides of 16 to 4096 pixels")),
            }
        };
        let fps = match fps.map(str::parse::<f32>) {
            None => 30.0,
            Some(Ok(f)) if (0.5..=240.0).contains(&f) => f,
            Some(_) => return Some(bad("the rate must be 0.5 to 240 frames per second")),
        };
        Some(Ok(LiveSpec { width, height, fps, faults }))
    }
}

/// What a faulty synthetic source does at a moment of its cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultPhase {
    /// Frames at the requested size.
    Normal,
    /// No frame at all: `next_frame` blocks until the phase ends (a frozen camera or network stream).
    Stall,
    /// The source is gone: `next_frame` fails (a recoverable error) every 0.25 s until the phase ends.
    Gone,
    /// Frames at half the requested width and height (a camera that switched modes).
    Resized,
}

/// The fault cycle of `synthetic:…+faults`, repeating every [`FaultScript::CYCLE`]: 3 s normal, 2 s stalled,
/// 2 s normal, 2 s gone, 3 s at half resolution, then normal again.
#[derive(Clone, Copy, Debug, Default)]
pub struct FaultScript;

impl FaultScript {
    /// Phases and their lengths, in order.
    pub const PHASES: [(FaultPhase, Duration); 5] = [
        (FaultPhase::Normal, Duration::from_secs(3)),
        (FaultPhase::Stall, Duration::from_secs(2)),
        (FaultPhase::Normal, Duration::from_secs(2)),
        (FaultPhase::Gone, Duration::from_secs(2)),
        (FaultPhase::Resized, Duration::from_secs(3)),
    ];
    /// Length of one cycle.
    pub const CYCLE: Duration = Duration::from_secs(12);

    /// The phase at time `t` since the source opened, and the time left in it.
    pub fn phase_at(t: Duration) -> (FaultPhase, Duration) {
        let mut in_cycle = Duration::from_nanos((t.as_nanos() % Self::CYCLE.as_nanos()) as u64);
        for (phase, len) in Self::PHASES {
            if in_cycle < len {
                return (phase, len - in_cycle);
            }
            in_cycle -= len;
        }
        (FaultPhase::Normal, Duration::ZERO)
    }
}

/// The walker as a live source (a camera stand-in for soak runs, `--video synthetic:…`): frames with their
/// ground-truth alpha delivered in real time at the nominal rate, forever (the walk loops every 4 s), optionally
/// misbehaving on the [`FaultScript`].
pub struct LiveWalkerSource {
    spec: LiveSpec,
    start: Instant,
    next: u64,
    background: (usize, usize, RgbImage),
}

impl LiveWalkerSource {
    /// A source for `spec`; its clock starts now.
    pub fn new(spec: LiveSpec) -> Self {
        let bg = background(spec.width, spec.height);
        Self { background: (spec.width, spec.height, bg), spec, start: Instant::now(), next: 0 }
    }

    fn frame(&mut self, index: u64, width: usize, height: usize) -> Frame {
        let frames = (self.spec.fps * 4.0).round().max(1.0) as usize;
        let params = WalkerParams { width, height, frames, fps: self.spec.fps, noise: 0.01 };
        if (self.background.0, self.background.1) != (width, height) {
            self.background = (width, height, background(width, height));
        }
        let (fg, cov) = walker(&params, index as usize % frames);
        let bg = &self.background.2;
        let data = bg.data.iter().zip(&fg.data).zip(&cov.data).map(|((&b, &f), &a)| f * a + b * (1.0 - a)).collect();
        let rgb = Image { width, height, data };
        let timestamp = Duration::from_secs_f64(index as f64 / self.spec.fps as f64);
        Frame { index, timestamp, rgb, alpha: Some(cov) }
    }
}

impl FrameSource for LiveWalkerSource {
    fn describe(&self) -> String {
        let s = &self.spec;
        let faults = if s.faults { ", fault script: stall, gone, half resolution every 12 s" } else { "" };
        format!("synthetic live walker {}x{} at {} fps{faults}", s.width, s.height, s.fps)
    }

    fn next_frame(&mut self) -> Result<SourceEvent, super::CaptureError> {
        // Real time: frame k is due at k / fps after the start (a late reader gets the next one at once).
        let period = Duration::from_secs_f64(1.0 / self.spec.fps as f64);
        loop {
            let due = period.mul_f64(self.next as f64);
            let now = self.start.elapsed();
            if due > now {
                std::thread::sleep(due - now);
            }
            let phase = if self.spec.faults {
                FaultScript::phase_at(self.start.elapsed())
            } else {
                (FaultPhase::Normal, Duration::ZERO)
            };
            match phase {
                (FaultPhase::Stall, left) => {
                    // Frames that would have come during the stall are lost, as with a frozen stream.
                    std::thread::sleep(left);
                    self.next = (self.start.elapsed().as_secs_f64() * self.spec.fps as f64).ceil() as u64;
                    continue;
                }
                (FaultPhase::Gone, left) => {
                    std::thread::sleep(left.min(Duration::from_millis(250)));
                    self.next = (self.start.elapsed().as_secs_f64() * self.spec.fps as f64).ceil() as u64;
                    return Err(super::CaptureError::StreamLost {
                        path: format!("{LIVE_PREFIX}{}x{}", self.spec.width, self.spec.height).into(),
                        index: self.next.saturating_sub(1),
                        reason: "the synthetic source is gone (fault script); waiting for it to come back".into(),
                    });
                }
                (FaultPhase::Resized, _) => {
                    let index = self.next;
                    self.next += 1;
                    let (w, h) = ((self.spec.width / 2).max(16), (self.spec.height / 2).max(16));
                    return Ok(SourceEvent::Frame(self.frame(index, w, h)));
                }
                (FaultPhase::Normal, _) => {
                    let index = self.next;
                    self.next += 1;
                    let (w, h) = (self.spec.width, self.spec.height);
                    return Ok(SourceEvent::Frame(self.frame(index, w, h)));
                }
            }
        }
    }

    fn nominal_fps(&self) -> Option<f32> {
        Some(self.spec.fps)
    }

    fn is_live(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn live_specs_parse() {
        assert_eq!(LiveSpec::parse("clip.mp4"), None);
        let d = LiveSpec::parse("synthetic:").unwrap().unwrap();
        assert_eq!((d.width, d.height, d.fps, d.faults), (320, 240, 30.0, false));
        let s = LiveSpec::parse("synthetic:160x120@15+faults").unwrap().unwrap();
        assert_eq!((s.width, s.height, s.fps, s.faults), (160, 120, 15.0, true));
        for bad in ["synthetic:0x5", "synthetic:100", "synthetic:64x64@0", "synthetic:64x64@x", "synthetic:+fault"] {
            let e = LiveSpec::parse(bad).unwrap().unwrap_err();
            assert_eq!(e.spec, bad);
            let e = e.to_string();
            assert!(e.contains(bad) && e.contains("synthetic:[WxH]"), "{e}");
        }
    }

    #[test]
    fn fault_script_phases() {
        let at = |s: f64| FaultScript::phase_at(Duration::from_secs_f64(s));
        assert_eq!(at(0.0).0, FaultPhase::Normal);
        assert_eq!(at(3.5), (FaultPhase::Stall, Duration::from_secs_f64(1.5)));
        assert_eq!(at(6.0).0, FaultPhase::Normal);
        assert_eq!(at(7.0).0, FaultPhase::Gone);
        assert_eq!(at(9.0).0, FaultPhase::Resized);
        assert_eq!(at(12.5).0, FaultPhase::Normal, "the cycle repeats");
        let total: Duration = FaultScript::PHASES.iter().map(|p| p.1).sum();
        assert_eq!(total, FaultScript::CYCLE);
    }

    #[test]
    fn live_walker_is_paced() {
        let mut src = LiveWalkerSource::new(LiveSpec { width: 48, height: 32, fps: 300.0, faults: false });
        assert!(src.is_live());
        let t = std::time::Instant::now();
        for k in 0..300u64 {
            let SourceEvent::Frame(f) = src.next_frame().unwrap() else { panic!("a live source never ends") };
            assert_eq!((f.index, f.width(), f.height()), (k, 48, 32));
            assert!(f.alpha.as_ref().is_some_and(|a| a.data.iter().any(|&v| v > 0.5)));
            assert_eq!(f.timestamp, Duration::from_secs_f64(k as f64 / 300.0));
        }
        // 300 frames at 300 fps take about 1 s (real time, not as fast as possible).
        assert!(t.elapsed() >= Duration::from_millis(990), "{:?}", t.elapsed());
    }

    #[test]
    fn walker_is_bounded_and_moves() {
        let p = WalkerParams::default();
        let (_, a0) = walker(&p, 0);
        let (_, a1) = walker(&p, p.frames - 1);
        let area = |a: &GrayImage| a.data.iter().sum::<f32>() / a.data.len() as f32;
        // A figure 0.8 of the frame height covers roughly 5-15% of the frame.
        assert!((0.04..0.2).contains(&area(&a0)), "{}", area(&a0));
        let cx = |a: &GrayImage| {
            let (mut s, mut m) = (0.0, 0.0);
            for (k, v) in a.data.iter().enumerate() {
                s += (k % a.width) as f32 * v;
                m += v;
            }
            s / m
        };
        assert!(cx(&a1) > cx(&a0) + 0.2 * p.width as f32);
        let (rgb, _) = composite(&p, 3);
        assert!(rgb.data.iter().all(|v| v.is_finite() && v.min_element() >= 0.0 && v.max_element() <= 1.0));
        assert!((-1.0..=1.0).contains(&noise(5, 7)));
    }
}
