//! `r2human xr`: the person from one photo in a headset, per eye through the per-view pipeline, either standing in
//! a 360-degree panorama (VR) or as an alpha layer over the room (AR); and `r2human xr --check`.
//!
//! The OpenXR session, frame pacing and placement live in [`crate::xr`]; this module prepares the input once and
//! plugs the CPU pipeline in as the eye renderer (one [`ViewRenderer`] per eye, so spatial fusion follows each eye's
//! own view sequence).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};

use crate::buffer::RgbaImage;
use crate::compose::{self, Mode};
use crate::io::environment::Environment;
use crate::io::image_io;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{PrepareOptions, PreparedInput, ViewRenderer};
use crate::xr::{EyeImageRenderer, EyeRequest, SessionConfig, SessionReport, XrMode};

/// Options of `r2human xr`.
#[derive(Clone, Debug)]
pub struct XrOptions {
    /// Photo of a person (PNG/JPEG); its alpha channel is the mask unless `mask` is given.
    pub image: PathBuf,
    /// Person mask (white = person), same size as the image.
    pub mask: Option<PathBuf>,
    /// Panorama for VR (equirectangular PNG/JPEG or .hdr); the embedded one when `None`.
    pub env: Option<PathBuf>,
    /// VR or AR.
    pub mode: Mode,
    /// Stop after this many frames showing the person (`None`: until the runtime ends the session).
    pub frames: Option<u64>,
    /// Largest eye image side in pixels (the CPU renderer cannot fill full headset resolution at display rate).
    pub eye_size: u32,
    /// Stop after this long (`None`: no limit).
    pub duration: Option<Duration>,
    /// Show the eye images in a desktop window while the session runs.
    pub mirror: bool,
}

impl Default for XrOptions {
    fn default() -> Self {
        Self {
            image: PathBuf::new(),
            mask: None,
            env: None,
            mode: Mode::Vr,
            frames: None,
            eye_size: 384,
            duration: None,
            mirror: true,
        }
    }
}

/// The per-eye renderer on top of the CPU pipeline: person for the body-cube eye camera, composited over the
/// room-locked panorama (VR, using the reference-space eye camera for the lookup) or left as the alpha layer (AR).
pub struct PipelineEyeRenderer<'a> {
    eyes: Vec<ViewRenderer<'a>>,
    input: &'a PreparedInput,
    environment: Option<&'a Environment>,
}

impl<'a> PipelineEyeRenderer<'a> {
    /// A renderer for `input`; `environment` is the panorama in VR and `None` in AR.
    pub fn new(input: &'a PreparedInput, environment: Option<&'a Environment>) -> Self {
        Self { eyes: Vec::new(), input, environment }
    }
}

impl EyeImageRenderer for PipelineEyeRenderer<'_> {
    fn render_eye(&mut self, eye: &EyeRequest) -> std::result::Result<RgbaImage, String> {
        while self.eyes.len() <= eye.eye {
            self.eyes.push(ViewRenderer::new(self.input, OcclusionFill::default(), true));
        }
        let person = self.eyes[eye.eye].render_person(&eye.body_camera).map_err(|e| e.to_string())?;
        Ok(match self.environment {
            Some(env) => compose::compose_vr(&person, env, &eye.stage_camera).map(|c| c.extend(1.0)),
            None => compose::compose_ar(&person),
        })
    }
}

/// Prepares the input and runs one OpenXR session; returns the session report.
pub fn run_xr_session(opts: &XrOptions) -> Result<SessionReport> {
    if !(16..=4096).contains(&opts.eye_size) {
        bail!("eye size {} is out of range: use 16 to 4096 pixels", opts.eye_size);
    }
    if opts.frames == Some(0) {
        bail!("--frames 0 shows nothing: give at least 1, or leave it out to run until the headset session ends");
    }
    let (photo, mask) = image_io::load_person(&opts.image, opts.mask.as_deref())?;
    let prepared = PreparedInput::prepare(&photo.rgb, &mask, &PrepareOptions::default())
        .with_context(|| format!("preparing {}", opts.image.display()))?;
    let environment = match (opts.mode, &opts.env) {
        (Mode::Ar, _) => None,
        (Mode::Vr, Some(p)) => Some(Environment::load(p)?),
        (Mode::Vr, None) => Some(Environment::default_embedded()),
    };
    let mut renderer = PipelineEyeRenderer::new(&prepared, environment.as_ref());
    let config = SessionConfig {
        mode: match opts.mode {
            Mode::Vr => XrMode::Vr,
            Mode::Ar => XrMode::Ar,
        },
        max_person_frames: opts.frames,
        max_duration: opts.duration,
        eye_max_side: opts.eye_size,
        capture: false,
        mirror: opts.mirror,
    };
    let report = crate::xr::run_session(&config, &mut renderer)?;
    if let crate::xr::EndReason::RenderFailed(e) = &report.end {
        bail!("the person renderer failed during the XR session: {e}");
    }
    Ok(report)
}

/// `r2human xr --image IN [--env FILE] [--mode vr|ar] [--frames N]`: runs the session and prints what happened
/// (frame rate, fresh-render share, motion-to-photon latency of the person layer, how it ended).
pub fn run_xr(opts: XrOptions) -> Result<()> {
    let report = run_xr_session(&opts)?;
    println!("{report}");
    Ok(())
}

/// `r2human xr --check`: prints the runtime, its extensions, blend modes and view configuration, or (as the error)
/// a sentence saying what to install or start when there is no runtime.
pub fn run_check() -> Result<()> {
    let report = crate::xr::check_runtime()?;
    println!("{report}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_options_are_refused_with_a_sentence() {
        let opts = XrOptions { image: "missing.png".into(), eye_size: 8, ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("eye size 8"));
        let opts = XrOptions { image: "missing.png".into(), frames: Some(0), ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("--frames 0"));
        let opts = XrOptions { image: "/nonexistent/person.png".into(), ..Default::default() };
        assert!(run_xr_session(&opts).is_err());
    }
}
