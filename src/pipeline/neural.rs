//! The neural renderer on the CPU: loading it ([`load_renderer`]), the encoder once per input, the residual
//! decoder per view and the colour lookup it keeps where the photo (or the back image) knows the surface.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::{Vec2, Vec4};
use rayon::prelude::*;

use crate::buffer::{GrayImage, Image, RgbaImage};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::{flow_and_zmap_into, FlowZ};
use crate::geometry::Camera;
use crate::neural::{Coefficients, EncoderInput, FeatureMap, NeuralError, NeuralRuntime, RuntimeOptions};

use super::person::SourceView;
use super::warp::OcclusionFill;
use super::{model_folder, warp, PipelineError, PreparedInput};

/// Which renderer draws the person (`--renderer`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum RendererChoice {
    /// The geometric warp of the photo (no network).
    #[default]
    Geometric,
    /// The neural renderer (encoder + residual Z-map decoder through ONNX Runtime); an error when its models or
    /// the ONNX Runtime library cannot be loaded.
    Neural,
    /// The neural renderer when its models and ONNX Runtime load, else the geometric one with one warning.
    Auto,
}

/// The model tier the product ships and looks for by default (`models/tiny`).
pub const DEFAULT_MODEL_TIER: &str = "tiny";

/// A neural renderer shared by every [`super::ViewRenderer`] that uses it (the two eyes of an XR session, say): the
/// decoder runs under the lock, one view at a time.
pub type SharedNeural = Arc<Mutex<NeuralRenderer>>;

/// Resolves `--renderer`, `--models` and `--ep`: `Ok(None)` for the geometric renderer, `Ok(Some(..))` with loaded
/// models for the neural one. [`RendererChoice::Neural`] fails when the models cannot be loaded;
/// [`RendererChoice::Auto`] then logs one warning (saying how to enable the neural renderer) and returns `None`.
/// `models` defaults to [`crate::neural::default_model_dir`] of [`DEFAULT_MODEL_TIER`].
pub fn load_renderer(
    choice: RendererChoice,
    models: Option<&Path>,
    options: &RuntimeOptions,
) -> Result<Option<SharedNeural>, PipelineError> {
    if choice == RendererChoice::Geometric {
        return Ok(None);
    }
    let dir = model_folder(models);
    let loaded = match dir {
        Some(dir) => NeuralRenderer::load(&dir, options).map_err(PipelineError::from),
        None => Err(PipelineError::NoModels(DEFAULT_MODEL_TIER.to_string())),
    };
    match (loaded, choice) {
        (Ok(n), _) => {
            tracing::info!(
                "neural renderer: {} models from `{}` on {}",
                n.runtime.encoder.info().tier,
                n.runtime.dir.display(),
                n.runtime.decoder.provider()
            );
            Ok(Some(Arc::new(Mutex::new(n))))
        }
        (Err(e), RendererChoice::Auto) => {
            tracing::warn!(
                "using the geometric renderer: {e}. To enable the neural one, install ONNX Runtime with \
                 `bash scripts/setup.d/neural.sh` and pass --models DIR (see train/README.md)"
            );
            Ok(None)
        }
        (Err(e), _) => Err(e),
    }
}

/// The neural renderer: the encoder, residual decoder (and optional FOF net) of one model folder.
pub struct NeuralRenderer {
    /// The loaded, mutually checked models.
    pub runtime: NeuralRuntime,
}

/// The encoder's output for one [`PreparedInput`] (computed once per input frame, shared by every view).
#[derive(Clone, Debug)]
pub struct NeuralInput {
    /// Features at 1/4 of the model's resolution.
    pub features: Arc<FeatureMap>,
    /// How long the encoder took (per-input time, on top of [`PreparedInput::timings`]).
    pub encode_time: Duration,
}

impl NeuralRenderer {
    /// Loads the models of `dir` (see [`NeuralRuntime::load`]).
    pub fn load(dir: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        Ok(Self { runtime: NeuralRuntime::load(dir, options)? })
    }

    /// Runs the encoder on a prepared input: its normalised photo and mask, the source normals of its geometry,
    /// and its FOF when the model takes the same number of coefficients (zeros otherwise, as the reference's test
    /// script feeds).
    pub fn encode(&mut self, input: &PreparedInput) -> Result<NeuralInput, NeuralError> {
        let start = Instant::now();
        let g = &input.source_gbuffer;
        let normals = Image { width: g.width, height: g.height, data: g.normal.clone() };
        let owned = input.fof_with(self.runtime.encoder.info().fof_n);
        let fof = owned
            .as_deref()
            .filter(|f| f.width == input.normalised.rgb.width && f.height == input.normalised.rgb.height)
            .map(|f| Coefficients { width: f.width, height: f.height, n: f.n, data: &f.coeffs });
        let features = self.runtime.encoder.run(&EncoderInput {
            rgb: &input.normalised.rgb,
            mask: &input.normalised.mask,
            fof,
            normals: &normals,
        })?;
        Ok(NeuralInput { features: Arc::new(features), encode_time: start.elapsed() })
    }

    /// Renders one view with the decoder: flow and Z-map of `target` (already rasterised for `camera`), the
    /// colour lookup ([`photo_lookup`]), then the decoder over the target mask's bounding box. `flowz` is scratch
    /// memory reused between views.
    pub fn render_view(
        &mut self,
        source: &SourceView<'_>,
        encoded: &NeuralInput,
        target: &GBuffer,
        camera: &Camera,
        flowz: &mut FlowZ,
        fill: OcclusionFill,
    ) -> Result<RgbaImage, NeuralError> {
        flow_and_zmap_into(flowz, target, camera, source.camera);
        decode_person_view(&mut self.runtime.decoder, &encoded.features, flowz, source, target, camera, fill)
    }
}

/// One view of the person by the neural decoder, from the flow and Z-map of `target` (rasterised for `camera`):
/// the colour lookup ([`photo_lookup`], with the back image when [`neural_back_lookup`] says so), the decoder, and
/// then the lookup's colour wherever the source camera sees the surface point or the back image knows the back of the
/// head ([`lookup_kept`], [`keep_lookup_where`]). The
/// CPU pipeline and the Vulkan renderer's host-memory seam both draw through it.
pub fn decode_person_view(
    decoder: &mut crate::neural::Decoder,
    features: &FeatureMap,
    flowz: &FlowZ,
    source: &SourceView<'_>,
    target: &GBuffer,
    camera: &Camera,
    fill: OcclusionFill,
) -> Result<RgbaImage, NeuralError> {
    let mut colours = source.colours();
    if !neural_back_lookup(fill) {
        colours.back = None;
    }
    let lookup = photo_lookup(colours, source.mask, source.camera, flowz, Some((target, camera)));
    let mut person = decoder.render_view(features, flowz, source.camera.width, target, &lookup)?;
    let seen = crate::geometry::zmap::visibility(
        flowz,
        source.gbuffer,
        source.camera,
        crate::geometry::zmap::VISIBILITY_LAMBDA,
    );
    let head = source.back.map(|b| &b.head).filter(|_| colours.back.is_some());
    let axis = warp::source_axis(camera, source.camera);
    let kept = lookup_kept(&seen, flowz, target, axis, head, source.camera.width);
    keep_lookup_where(&mut person, &lookup, &kept);
    Ok(person)
}

/// How much of the back image's colour must be the head top's ([`super::back::BackImage::head`]) for the neural
/// renderer to keep it on the back of the head ([`lookup_kept`]).
pub const HEAD_KEPT: f32 = 0.5;

/// Which pixels of a neural view take the colour lookup ([`photo_lookup`]) instead of the decoder's output: those
/// whose surface point the source camera sees (`seen`, paper Eq. 9), and, with the back image's `head` weights
/// (source pixels of a camera `source_width` wide, or another size scaled to it), the surfaces that face away from
/// the source camera ([`warp::back_weight`] 1 against `axis`, [`warp::source_axis`]) and whose flow lands where the
/// back image drew the head in the head top's colour (weight at least [`HEAD_KEPT`], nearest pixel). The decoder,
/// trained on synthetic people, painted a pale oval where a face would be on the back of real people's dark heads
/// (docs/rendering.md "The neural renderer"); the back image's head colour is what the photo says.
pub fn lookup_kept(
    seen: &[bool],
    flowz: &FlowZ,
    target: &GBuffer,
    axis: glam::Vec3,
    head: Option<&GrayImage>,
    source_width: usize,
) -> Vec<bool> {
    let n = seen.len();
    let Some(head) = head.filter(|_| flowz.mask.len() == n && target.normal.len() == n && flowz.flow.data.len() == n)
    else {
        return seen.to_vec();
    };
    let scale = head.width as f32 / source_width.max(1) as f32;
    let on_head = |i: usize| {
        let p = flowz.flow.data[i] * scale;
        if !p.is_finite() || p.x < 0.0 || p.y < 0.0 {
            return false;
        }
        let (c, r) = (p.x as usize, p.y as usize);
        c < head.width && r < head.height && head.data[r * head.width + c] >= HEAD_KEPT
    };
    (0..n)
        .into_par_iter()
        .map(|i| seen[i] || (flowz.mask[i] && warp::back_weight(target.normal[i], axis) >= 1.0 && on_head(i)))
        .collect()
}

/// Puts the colour lookup (`lookup`, [`photo_lookup`]) back on every covered pixel of the decoder's `person` that
/// `kept` marks ([`lookup_kept`]: the photo sees its surface point, or it is the back of the head the back image
/// knows) and the lookup has a colour for. The decoder is residual on that colour and was trained on synthetic
/// people, where keeping the photo here moves its views by at most 0.15 dB; on real photos it shifted their colours
/// (a blue cast on the astronaut's helmet and gloves, up to 7.5 dB below the geometric renderer at the input view,
/// docs/rendering.md "The neural renderer"), so what the photo shows is taken from the photo and the decoder draws only what it
/// does not show. Arrays of another size leave `person` as it is.
pub fn keep_lookup_where(person: &mut RgbaImage, lookup: &RgbaImage, kept: &[bool]) {
    let n = person.data.len();
    if lookup.data.len() != n || kept.len() != n || (lookup.width, lookup.height) != (person.width, person.height) {
        return;
    }
    for ((p, l), &s) in person.data.iter_mut().zip(&lookup.data).zip(kept) {
        if s && l.w >= 1.0 && p.w > 0.0 {
            *p = *l;
        }
    }
}

/// The residual decoder's colour lookup (its `warped_rgb` input): for every target pixel with a flow, the source
/// colour at the flow by the geometric renderer's lookup ([`warp::SourceColours::sample`]: the photo, `rgb` linear
/// premultiplied by `source_mask`, sampled mask-aware and bilinearly), clamped to `[0, 1]`. With `target` (the
/// view's G-buffer, of the flow's size, and camera) its normals blend in the colours' back image on surfaces facing
/// away from the source camera ([`warp::back_weight`]) and their side images on surfaces it sees edge-on
/// ([`warp::side_weight`]), each when the colours have them. Without `target` this is the geometric renderer's
/// `MirroredFront` lookup of the sharp photo without the visibility test and without filling holes: alpha is 1
/// where the photo has a colour and 0 where the flow lands outside the source silhouette (or there is no flow).
pub fn photo_lookup<'a>(
    source_rgb: impl Into<warp::SourceColours<'a>>,
    source_mask: &GrayImage,
    source_cam: &Camera,
    flowz: &FlowZ,
    target: Option<(&GBuffer, &Camera)>,
) -> RgbaImage {
    let colours: warp::SourceColours = source_rgb.into();
    let source_rgb = colours.rgb;
    let (w, h) = (flowz.flow.width, flowz.flow.height);
    let mut out = RgbaImage::new(w, h, Vec4::ZERO);
    if w * h == 0
        || flowz.mask.len() != w * h
        || source_mask.width != source_rgb.width
        || source_mask.height != source_rgb.height
    {
        return out;
    }
    // The normals only from a target G-buffer of the flow's size.
    let target = target.filter(|(g, _)| (g.width, g.height) == (w, h));
    let fill =
        if target.is_some() && colours.back.is_some() { OcclusionFill::Back } else { OcclusionFill::MirroredFront };
    let axis = target.map_or(glam::Vec3::ZERO, |(_, cam)| warp::source_axis(cam, source_cam));
    // Flow is in the source camera's pixels; the photo may have another size.
    let scale = Vec2::new(
        source_rgb.width as f32 / source_cam.width.max(1) as f32,
        source_rgb.height as f32 / source_cam.height.max(1) as f32,
    );
    out.data.par_chunks_mut(w).enumerate().for_each(|(row, line)| {
        for (col, o) in line.iter_mut().enumerate() {
            let i = row * w + col;
            if flowz.mask[i] {
                let (b, s) = target.map_or((0.0, 0.0), |(g, _)| {
                    (warp::back_weight(g.normal[i], axis), warp::side_weight(g.normal[i], axis))
                });
                if let Some(c) = colours.sample(source_mask, flowz.flow.data[i] * scale, b, s, fill) {
                    *o = c.clamp(glam::Vec3::ZERO, glam::Vec3::ONE).extend(1.0);
                }
            }
        }
    });
    out
}

/// Whether the neural decoder's colour lookup ([`photo_lookup`]) uses the back image under `fill` (the decoder is
/// residual on its lookup; docs/rendering.md, "What the photo does not show", has the measurement that decided this).
pub fn neural_back_lookup(fill: OcclusionFill) -> bool {
    fill == OcclusionFill::Back
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn the_lookup_is_kept_on_the_back_of_the_head_the_back_image_knows() {
        // Six target pixels, seen from behind the source camera's axis (+z): the flows land on a 4x1 source whose
        // left half is head (weight 1, 0.6) and right half not (0.4, 0).
        let head = GrayImage { width: 4, height: 1, data: vec![1.0, 0.6, 0.4, 0.0] };
        let mut flowz = FlowZ {
            flow: Image::new(6, 1, Vec2::ZERO),
            z: GrayImage::new(6, 1, 0.0),
            mask: vec![true, true, true, true, false, true],
        };
        // Pixel 0 on the head facing away, 1 on the 0.6 head facing away, 2 on 0.4 facing away, 3 on the head but
        // edge-on (back weight below 1), 4 no flow, 5 flowing outside the source.
        for (i, x) in [0.5f32, 1.5, 2.5, 0.5, 0.5, 7.5].into_iter().enumerate() {
            flowz.flow.data[i] = Vec2::new(x, 0.5);
        }
        let mut target = GBuffer::new(6, 1);
        target.normal = vec![-Vec3::Z, -Vec3::Z, -Vec3::Z, Vec3::new(0.99, 0.0, -0.141), -Vec3::Z, -Vec3::Z];
        let axis = Vec3::Z;
        let seen = [false, false, false, false, false, false];
        let kept = lookup_kept(&seen, &flowz, &target, axis, Some(&head), 4);
        assert_eq!(kept, vec![true, true, false, false, false, false]);
        // What the photo sees is kept anyway; without head weights only that.
        let seen = [false, false, true, false, false, false];
        assert_eq!(
            lookup_kept(&seen, &flowz, &target, axis, Some(&head), 4),
            vec![true, true, true, false, false, false]
        );
        assert_eq!(lookup_kept(&seen, &flowz, &target, axis, None, 4), seen.to_vec());
        // Head weights of another size are scaled to the source camera: a 2x wider map read at twice the flow.
        let wide = GrayImage { width: 8, height: 2, data: [[1.0, 1.0, 0.6, 0.6, 0.4, 0.4, 0.0, 0.0]; 2].concat() };
        assert_eq!(
            lookup_kept(&seen, &flowz, &target, axis, Some(&wide), 4),
            vec![true, true, true, false, false, false]
        );
        // Mismatched arrays: only what is seen.
        let short = FlowZ::default();
        assert_eq!(lookup_kept(&seen, &short, &target, axis, Some(&head), 4), seen.to_vec());
    }

    #[test]
    fn the_photo_is_kept_only_where_it_sees_the_surface_and_has_a_colour() {
        let decoded = Vec4::new(0.1, 0.2, 0.3, 1.0);
        let photo = Vec4::new(0.7, 0.6, 0.5, 1.0);
        let mut person = RgbaImage::new(4, 1, decoded);
        person.data[3] = Vec4::ZERO; // not covered
        let mut lookup = RgbaImage::new(4, 1, photo);
        lookup.data[1] = Vec4::ZERO; // the photo has no colour there
        keep_lookup_where(&mut person, &lookup, &[true, true, false, true]);
        assert_eq!(person.data, vec![photo, decoded, decoded, Vec4::ZERO]);
        // Arrays of another size change nothing.
        let before = person.clone();
        keep_lookup_where(&mut person, &RgbaImage::new(2, 1, photo), &[true; 4]);
        keep_lookup_where(&mut person, &lookup, &[true; 3]);
        assert_eq!(person, before);
    }
}
