//! The three networks: [`FofNet`], [`Encoder`] (once per input frame) and [`Decoder`] (once per view, over the
//! target mask's bounding box only).

use std::path::{Path, PathBuf};

use glam::{Vec3, Vec4};
use ort::session::{Session, SessionInputValue};
use ort::value::TensorRef;
use rayon::prelude::*;

use super::model::{check_no_extra_inputs, check_tensor, metadata_problem, optional_key, Dim, ModelInfo, ModelKind};
use super::provider::{create_session, ActiveProvider, RuntimeOptions};
use super::tensor::{
    coefficients_tensor, image_tensor, normals_tensor, resample_plane, Coefficients, FeatureMap, PixelBox,
};
use super::NeuralError;
use crate::buffer::{linear_to_srgb, srgb_to_linear, GrayImage, Image, RgbImage, RgbaImage};
use crate::geometry::fof::{CosineTable, Fof};
use crate::geometry::marching::ISO_LEVEL;
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::FlowZ;

/// A loaded session with its checked metadata.
struct Net {
    session: Session,
    info: ModelInfo,
    path: PathBuf,
    provider: ActiveProvider,
    name: &'static str,
}

impl Net {
    fn load(path: &Path, kind: ModelKind, name: &'static str, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        let (session, provider) = create_session(path, name, options)?;
        let info = ModelInfo::read(&session, path, kind)?;
        Ok(Self { session, info, path: path.to_path_buf(), provider, name })
    }

    /// Runs the session on named planar tensors and returns the named output's shape and values, failing on
    /// non-finite values.
    fn run(
        &mut self,
        inputs: &[(&str, [usize; 4], &[f32])],
        output: &str,
    ) -> Result<(Vec<i64>, Vec<f32>), NeuralError> {
        let name = self.name;
        let run_err = |e: ort::Error| NeuralError::Run { model: name, reason: e.to_string() };
        let mut values: Vec<(std::borrow::Cow<'_, str>, SessionInputValue<'_>)> = Vec::with_capacity(inputs.len());
        for (input, shape, data) in inputs {
            let tensor = TensorRef::from_array_view((*shape, *data)).map_err(run_err)?;
            values.push(((*input).into(), tensor.into()));
        }
        let outputs = self.session.run(values).map_err(run_err)?;
        let value = outputs
            .get(output)
            .ok_or_else(|| NeuralError::Run { model: name, reason: format!("no output named `{output}`") })?;
        let (shape, data) = value.try_extract_tensor::<f32>().map_err(run_err)?;
        let bad = data.iter().filter(|v| !v.is_finite()).count();
        if bad > 0 {
            return Err(NeuralError::NonFinite { model: name, count: bad, total: data.len() });
        }
        Ok((shape.to_vec(), data.to_vec()))
    }

    fn expect_output_shape(&self, shape: &[i64], want: [usize; 4]) -> Result<(), NeuralError> {
        if shape.len() != 4 || shape.iter().zip(want).any(|(&s, w)| s != w as i64) {
            return Err(NeuralError::Run {
                model: self.name,
                reason: format!("output shape {shape:?}, expected {want:?}"),
            });
        }
        Ok(())
    }
}

fn check_sizes(model: &'static str, what: &str, w: usize, h: usize, ew: usize, eh: usize) -> Result<(), NeuralError> {
    if (w, h) != (ew, eh) {
        return Err(NeuralError::BadInput { model, problem: format!("{what} is {w}x{h} but must be {ew}x{eh}") });
    }
    Ok(())
}

/// A FOF input of the FOF network besides the photo (its ONNX input name; listed in `r2human.fof_inputs`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FofInput {
    /// `prior`: the silhouette-inflation prior ([`crate::geometry::inflate::inflate_to_fof`]).
    Prior,
    /// `body`: the fitted body's FOF (the body prior, computed as `--geometry body` does), the reference FOF net's
    /// second input.
    Body,
}

impl FofInput {
    /// The ONNX input name (and the name in `r2human.fof_inputs` / `r2human.residual`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Prior => "prior",
            Self::Body => "body",
        }
    }

    fn parse(s: &str) -> Option<Self> {
        match s {
            "prior" => Some(Self::Prior),
            "body" => Some(Self::Body),
            _ => None,
        }
    }
}

/// The FOF network: source photo and/or the FOF inputs its metadata names (the inflation prior and/or the body
/// FOF) to `N` FOF-X coefficients per pixel.
pub struct FofNet {
    net: Net,
    /// Whether the model takes the masked photo (`image`); a model without it sees geometry only.
    takes_image: bool,
    /// The FOF inputs after `image`, in the model's order.
    inputs: Vec<FofInput>,
    /// The input the network is residual on (`r2human.residual`), if any.
    residual: Option<FofInput>,
}

/// FOF coefficients predicted at the model's resolution, pixel-major (`HWN`), zero outside the mask.
#[derive(Clone, Debug, PartialEq)]
pub struct FofPrediction {
    /// Width in pixels (the model's resolution).
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Coefficients per pixel.
    pub n: usize,
    /// `width*height*n` values.
    pub data: Vec<f32>,
}

impl FofPrediction {
    /// A borrowed view for [`EncoderInput::fof`].
    pub fn view(&self) -> Coefficients<'_> {
        Coefficients { width: self.width, height: self.height, n: self.n, data: &self.data }
    }
}

impl FofNet {
    /// Loads and checks a FOF network (`r2human.kind = fof`; the inputs `r2human.fof_inputs` names: `image`
    /// `[1,3,R,R]` when the model takes the photo, then the FOF inputs (`body`, `prior`), each `[1,N,R,R]`, e.g.
    /// `image,body,prior` or, for a net that sees geometry only, `body,prior`; output `fof` `[1,N,R,R]`). Files
    /// without `r2human.fof_inputs` (written before it existed) take `image` and, when they have it, `prior`.
    /// `r2human.residual`, when present, must name one of the FOF inputs.
    pub fn load(path: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        let net = Net::load(path, ModelKind::Fof, "FOF net", options)?;
        let (r, n) = (net.info.resolution as i64, net.info.fof_n as i64);
        let (takes_image, inputs) = match optional_key(&net.session, path, "r2human.fof_inputs")? {
            Some(text) => {
                parse_fof_inputs(&text).map_err(|p| metadata_problem(path, "r2human.fof_inputs", p.to_string()))?
            }
            None if net.session.inputs().iter().any(|i| i.name() == "prior") => (true, vec![FofInput::Prior]),
            None => (true, Vec::new()),
        };
        if takes_image {
            check_tensor(&net.session, path, false, "image", [Dim::Is(3), Dim::Is(r), Dim::Is(r)])?;
        }
        for input in &inputs {
            check_tensor(&net.session, path, false, input.name(), [Dim::Is(n), Dim::Is(r), Dim::Is(r)])?;
        }
        let names: Vec<&str> =
            takes_image.then_some("image").into_iter().chain(inputs.iter().map(|i| i.name())).collect();
        check_no_extra_inputs(&net.session, path, &names)?;
        let residual = match optional_key(&net.session, path, "r2human.residual")? {
            None => None,
            Some(text) => match FofInput::parse(text.trim()) {
                Some(base) if inputs.contains(&base) => Some(base),
                _ => {
                    return Err(metadata_problem(
                        path,
                        "r2human.residual",
                        format!("is `{text}`, not one of the model's FOF inputs {names:?}"),
                    ))
                }
            },
        };
        check_tensor(&net.session, path, true, "fof", [Dim::Is(n), Dim::Is(r), Dim::Is(r)])?;
        Ok(Self { net, takes_image, inputs, residual })
    }

    /// Whether the model takes the masked photo (`image` in `r2human.fof_inputs`); without it the network sees
    /// geometry only, so what it learned does not depend on how its training images looked.
    pub fn takes_image(&self) -> bool {
        self.takes_image
    }

    /// The FOF inputs the model takes after `image`, in its order.
    pub fn inputs(&self) -> &[FofInput] {
        &self.inputs
    }

    /// Whether the model takes the body FOF (`body` in `r2human.fof_inputs`): the caller must compute the body
    /// prior for it ([`FofNet::refine_with`]).
    pub fn takes_body(&self) -> bool {
        self.inputs.contains(&FofInput::Body)
    }

    /// The FOF input the network's output is a correction of: `r2human.residual`, else the body FOF when the model
    /// takes one, else the inflation prior.
    pub fn base(&self) -> FofInput {
        self.residual.unwrap_or(if self.takes_body() { FofInput::Body } else { FofInput::Prior })
    }

    /// The model's metadata.
    pub fn info(&self) -> &ModelInfo {
        &self.net.info
    }

    /// The execution provider the model runs on.
    pub fn provider(&self) -> ActiveProvider {
        self.net.provider
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.net.path
    }

    /// Predicts FOF coefficients for a square source photo (`rgb` linear and premultiplied, `mask` in `[0,1]`,
    /// any size; resampled to the model's resolution). `prior` feeds the model's `prior` input when it has one
    /// (zeros when `None`) and is ignored otherwise. The result is zero where the resampled mask is below 0.5.
    /// A model that takes the body FOF gets zeros for it here; see [`FofNet::run_with`].
    pub fn run(
        &mut self,
        rgb: &RgbImage,
        mask: &GrayImage,
        prior: Option<Coefficients<'_>>,
    ) -> Result<FofPrediction, NeuralError> {
        self.run_with(rgb, mask, prior, None)
    }

    /// [`FofNet::run`] with the body FOF too: each FOF input the model takes is fed from `prior` / `body` (same
    /// size as the photo, the model's `N`), zeros when `None`.
    pub fn run_with(
        &mut self,
        rgb: &RgbImage,
        mask: &GrayImage,
        prior: Option<Coefficients<'_>>,
        body: Option<Coefficients<'_>>,
    ) -> Result<FofPrediction, NeuralError> {
        let (r, n) = (self.net.info.resolution, self.net.info.fof_n);
        self.check_photo(rgb, mask)?;
        let mut tensors = Vec::with_capacity(self.inputs.len());
        for input in self.inputs.clone() {
            let given = match input {
                FofInput::Prior => &prior,
                FofInput::Body => &body,
            };
            tensors.push(match given {
                Some(c) => {
                    check_coefficients(input, c.width, c.height, c.n, c.data.len(), rgb, n)?;
                    coefficients_tensor(c, r)
                }
                None => vec![0.0; n * r * r],
            });
        }
        self.predict(rgb, mask, &tensors)
    }

    /// Fails unless `rgb` is square and non-empty and `mask` has its size.
    fn check_photo(&self, rgb: &RgbImage, mask: &GrayImage) -> Result<(), NeuralError> {
        if rgb.width != rgb.height || rgb.width == 0 {
            return Err(NeuralError::BadInput {
                model: "FOF net",
                problem: format!("photo is {}x{}, not square", rgb.width, rgb.height),
            });
        }
        check_sizes("FOF net", "mask", mask.width, mask.height, rgb.width, rgb.height)
    }

    /// The network on a checked square photo and its FOF input tensors (planar, at the model's resolution, in
    /// [`FofNet::inputs`] order); zero where the resampled mask is below 0.5.
    fn predict(&mut self, rgb: &RgbImage, mask: &GrayImage, fofs: &[Vec<f32>]) -> Result<FofPrediction, NeuralError> {
        let (r, n) = (self.net.info.resolution, self.net.info.fof_n);
        let image = self.takes_image.then(|| image_tensor(rgb, mask, r));
        let mut inputs: Vec<(&str, [usize; 4], &[f32])> =
            image.iter().map(|image| ("image", [1, 3, r, r], image.as_slice())).collect();
        for (input, tensor) in self.inputs.iter().zip(fofs) {
            inputs.push((input.name(), [1, n, r, r], tensor));
        }
        let start = std::time::Instant::now();
        let (shape, planes) = self.net.run(&inputs, "fof")?;
        tracing::debug!("FOF net: session run {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
        self.net.expect_output_shape(&shape, [1, n, r, r])?;
        let small_mask = resample_plane(&mask.data, mask.width, mask.height, r, r);
        let mut data = vec![0.0; r * r * n];
        for (i, m) in small_mask.iter().enumerate() {
            if *m >= 0.5 {
                for k in 0..n {
                    data[i * n + k] = planes[k * r * r + i];
                }
            }
        }
        Ok(FofPrediction { width: r, height: r, n, data })
    }
}

/// Fails unless a FOF input of `w x h` pixels with `cn` coefficients (`len` values) fits a photo of `rgb`'s size
/// and a model with `n` coefficients.
fn check_coefficients(
    input: FofInput,
    w: usize,
    h: usize,
    cn: usize,
    len: usize,
    rgb: &RgbImage,
    n: usize,
) -> Result<(), NeuralError> {
    let model = "FOF net";
    check_sizes(model, input.name(), w, h, rgb.width, rgb.height)?;
    if cn != n || len != w * h * cn {
        return Err(NeuralError::BadInput {
            model,
            problem: format!("{} has {cn} coefficients per pixel, the model takes {n}", input.name()),
        });
    }
    Ok(())
}

/// A `r2human.fof_inputs` value that is not an optional `image` followed by `body` and/or `prior` once each.
#[derive(Debug, PartialEq, thiserror::Error)]
#[error(
    "is `{0}`; expected `image` (optional) followed by `body` and/or `prior` once each (e.g. `image,body,prior` or \
     `body,prior`)"
)]
struct BadFofInputs(String);

/// Parses `r2human.fof_inputs`: an optional `image` (first), then `body` and/or `prior` once each; at least one
/// input. Returns whether the model takes the image, and its FOF inputs in order.
fn parse_fof_inputs(text: &str) -> Result<(bool, Vec<FofInput>), BadFofInputs> {
    let names: Vec<&str> = text.split(',').map(str::trim).filter(|s| !s.is_empty()).collect();
    let bad = || BadFofInputs(text.to_string());
    let takes_image = names.first() == Some(&"image");
    let mut inputs = Vec::new();
    for name in &names[usize::from(takes_image)..] {
        match FofInput::parse(name) {
            Some(input) if !inputs.contains(&input) => inputs.push(input),
            _ => return Err(bad()),
        }
    }
    if !takes_image && inputs.is_empty() {
        return Err(bad());
    }
    Ok((takes_image, inputs))
}

impl std::fmt::Debug for FofNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FofNet")
            .field("path", &self.net.path)
            .field("info", &self.net.info)
            .field("takes_image", &self.takes_image)
            .field("inputs", &self.inputs)
            .field("residual", &self.residual)
            .field("provider", &self.net.provider)
            .finish()
    }
}

impl FofNet {
    /// Whether the model takes the inflation prior as its `prior` input (the residual FOF net of
    /// `train/nets.py`: `fof = prior + UNet(image, prior)`).
    pub fn has_prior(&self) -> bool {
        self.inputs.contains(&FofInput::Prior)
    }

    /// [`FofNet::refine_with`] without a body FOF (for models that do not take one; those that do fail with a
    /// clear error).
    pub fn refine(&mut self, rgb: &RgbImage, mask: &GrayImage, prior: &Fof) -> Result<Fof, NeuralError> {
        self.refine_with(rgb, mask, prior, None)
    }

    /// The FOF at the prior's full resolution: runs the network at its resolution `R` on the photo and its FOF
    /// inputs (the inflation `prior` and/or the `body` FOF, box-averaged to `R`), then applies its correction
    /// `delta = prediction - base_R` to the full-resolution base FOF ([`FofNet::base`]: what the network is
    /// residual on): `fof(p) = base(p) + delta_up(p)`, where `delta_up` is the bilinear upsampling of `delta` that
    /// only reads model pixels inside the (resampled) mask, renormalising the weights (so the silhouette edge is
    /// not pulled towards zero by background taps). Pixels whose four taps are all outside keep the base, and
    /// pixels where the base is empty (outside the cleaned mask) stay empty. A column inside the silhouette holds
    /// body by definition, so a column the network leaves empty (its occupancy, decoded at 64 depths, never
    /// reaches the mesh's 0.5 level) is treated as outside (no correction from it), and a corrected
    /// full-resolution column that ends up empty keeps the base: the FOF net can reshape the body in depth but
    /// never erases the silhouette.
    ///
    /// A network trained as a residual on its base returns the base unchanged while untrained; a network without a
    /// residual predicts absolute coefficients, which this applies the same way (its prediction minus the base).
    /// `rgb` (linear, premultiplied), `mask`, `prior` and `body` must have the same square size and the model's
    /// `N`; `body` is required when the model takes it ([`FofNet::takes_body`]).
    pub fn refine_with(
        &mut self,
        rgb: &RgbImage,
        mask: &GrayImage,
        prior: &Fof,
        body: Option<&Fof>,
    ) -> Result<Fof, NeuralError> {
        let (r, n) = (self.net.info.resolution, self.net.info.fof_n);
        let model = "FOF net";
        let (w, h) = (prior.width, prior.height);
        self.check_photo(rgb, mask)?;
        check_coefficients(FofInput::Prior, w, h, prior.n, prior.coeffs.len(), rgb, n)?;
        if let Some(b) = body {
            check_coefficients(FofInput::Body, b.width, b.height, b.n, b.coeffs.len(), rgb, n)?;
        }
        let fof_of = |input: FofInput| -> Result<&Fof, NeuralError> {
            match input {
                FofInput::Prior => Ok(prior),
                FofInput::Body => body.ok_or_else(|| NeuralError::BadInput {
                    model,
                    problem: format!(
                        "`{}` takes the body FOF (r2human.fof_inputs) but none was given: compute the body prior \
                         for it (pipeline::load_body, as --geometry body does)",
                        self.net.path.display()
                    ),
                }),
            }
        };
        let base = fof_of(self.base())?;
        let start = std::time::Instant::now();
        let small = |f: &Fof| coefficients_tensor(&Coefficients { width: w, height: h, n, data: &f.coeffs }, r);
        let fofs = self.inputs.iter().map(|&input| fof_of(input)).collect::<Result<Vec<_>, _>>()?;
        let tensors: Vec<Vec<f32>> = fofs.into_par_iter().map(small).collect();
        let base_small = match self.inputs.iter().position(|&i| i == self.base()) {
            Some(k) => tensors[k].clone(),
            None => small(base),
        };
        let predicted = self.predict(rgb, mask, &tensors)?;
        let ran = start.elapsed();
        let small_mask = resample_plane(&mask.data, mask.width, mask.height, r, r);
        let plane = r * r;
        // Correction per model pixel (pixel-major), and which model pixels carry one.
        let mut delta = vec![0.0f32; plane * n];
        // A column inside the silhouette holds some body by definition: a prediction that leaves it empty (no
        // depth reaches the 0.5 level) is wrong there and carries no correction.
        let table = CosineTable::new(n, SILHOUETTE_SAMPLES);
        let valid: Vec<bool> = (0..plane)
            .map(|i| small_mask[i] >= 0.5 && column_holds_body(&table, &predicted.data[i * n..(i + 1) * n], ISO_LEVEL))
            .collect();
        for i in (0..plane).filter(|&i| valid[i]) {
            for k in 0..n {
                delta[i * n + k] = predicted.data[i * n + k] - base_small[k * plane + i];
            }
        }
        // The base's coefficients, copied row by row inside the parallel loop (a 512² field is 32 MB: one thread
        // copying it, and faulting its pages in, cost as much as the correction).
        let mut coeffs = crate::buffer::zeroed_f32(base.coeffs.len());
        let (sx, sy) = (r as f32 / w as f32, r as f32 / h as f32);
        coeffs.par_chunks_mut(w * n).enumerate().for_each(|(row, line)| {
            line.copy_from_slice(&base.coeffs[row * w * n..(row + 1) * w * n]);
            let y = (row as f32 + 0.5) * sy - 0.5;
            let (mut acc, mut before) = (vec![0.0f32; n], vec![0.0f32; n]);
            for (col, out) in line.chunks_exact_mut(n).enumerate() {
                if out.iter().all(|v| *v == 0.0) {
                    continue;
                }
                let x = (col as f32 + 0.5) * sx - 0.5;
                acc.fill(0.0);
                let (taps, count, wsum) = masked_taps(x, y, r, &valid);
                for &(i, wt) in &taps[..count] {
                    for (a, d) in acc.iter_mut().zip(&delta[i * n..(i + 1) * n]) {
                        *a += wt * d;
                    }
                }
                if wsum > 1e-6 {
                    before.copy_from_slice(out);
                    for (o, a) in out.iter_mut().zip(&acc) {
                        *o += a / wsum;
                    }
                    // The same rule at full resolution: a corrected column must still hold body, else the prior's.
                    if !column_holds_body(&table, out, ISO_LEVEL) {
                        out.copy_from_slice(&before);
                    }
                }
            }
        });
        tracing::debug!(
            "FOF net: inputs + network + outputs {:.1} ms, correction to {w}x{h} {:.1} ms",
            ran.as_secs_f64() * 1e3,
            (start.elapsed() - ran).as_secs_f64() * 1e3
        );
        Fof::new(n, w, h, coeffs).map_err(|source| NeuralError::BadFof { model, source })
    }
}

/// The placement network (`placement.onnx`, `train/placement.py`): from the fitted body's FOF and the inflation
/// prior, each box-averaged to its resolution `R`, the depth (body-cube z) by which each column of the inflation
/// prior moves (`--geometry body-placed`, [`crate::body::placed`]). Inputs `body`, `prior` `[1,N,R,R]`; output
/// `shift` `[1,1,R,R]`, zero outside the prior's columns. It keeps the prior's thickness by construction: it has one
/// number per column to get wrong, not a whole FOF.
pub struct PlacementNet {
    net: Net,
}

impl PlacementNet {
    /// Loads and checks a placement network (`r2human.kind = placement`, the inputs and output above).
    pub fn load(path: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        let net = Net::load(path, ModelKind::Placement, "placement net", options)?;
        let (r, n) = (net.info.resolution as i64, net.info.fof_n as i64);
        for input in PLACEMENT_INPUTS {
            check_tensor(&net.session, path, false, input, [Dim::Is(n), Dim::Is(r), Dim::Is(r)])?;
        }
        check_no_extra_inputs(&net.session, path, &PLACEMENT_INPUTS)?;
        check_tensor(&net.session, path, true, "shift", [Dim::Is(1), Dim::Is(r), Dim::Is(r)])?;
        Ok(Self { net })
    }

    /// The model's metadata.
    pub fn info(&self) -> &ModelInfo {
        &self.net.info
    }

    /// The execution provider the model runs on.
    pub fn provider(&self) -> ActiveProvider {
        self.net.provider
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.net.path
    }

    /// The depth shift of every column of `mask`'s grid: the network at its resolution `R` on `body` and `prior`
    /// (both on `mask`'s grid with the model's `N`), upsampled bilinearly from the model pixels inside the
    /// resampled mask (weights renormalised, so the silhouette edge is not pulled toward zero); a pixel of `mask`
    /// whose four taps all lie outside takes the nearest model pixel inside within two pixels, else 0; 0 outside
    /// `mask` (below 0.5).
    pub fn shifts(&mut self, mask: &GrayImage, prior: &Fof, body: &Fof) -> Result<GrayImage, NeuralError> {
        let model = "placement net";
        let (r, n) = (self.net.info.resolution, self.net.info.fof_n);
        let (w, h) = (mask.width, mask.height);
        for (name, f) in [("prior", prior), ("body", body)] {
            if (f.width, f.height) != (w, h) || f.n != n {
                return Err(NeuralError::BadInput {
                    model,
                    problem: format!(
                        "`{name}` is {}x{} with {} coefficients, expected the mask's {w}x{h} and the model's {n}",
                        f.width, f.height, f.n
                    ),
                });
            }
        }
        let small = |f: &Fof| coefficients_tensor(&Coefficients { width: w, height: h, n, data: &f.coeffs }, r);
        let (body_small, prior_small) = rayon::join(|| small(body), || small(prior));
        let start = std::time::Instant::now();
        let (shape, shift) =
            self.net.run(&[("body", [1, n, r, r], &body_small), ("prior", [1, n, r, r], &prior_small)], "shift")?;
        tracing::debug!("placement net: session run {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
        self.net.expect_output_shape(&shape, [1, 1, r, r])?;
        let inside: Vec<bool> = resample_plane(&mask.data, w, h, r, r).iter().map(|m| *m >= 0.5).collect();
        let valid = |c: i64, rr: i64| {
            (0..r as i64).contains(&c) && (0..r as i64).contains(&rr) && inside[rr as usize * r + c as usize]
        };
        let (sx, sy) = (r as f32 / w as f32, r as f32 / h as f32);
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(row, line)| {
            let y = (row as f32 + 0.5) * sy - 0.5;
            for (col, o) in line.iter_mut().enumerate() {
                if mask.data[row * w + col] <= 0.5 {
                    continue;
                }
                let x = (col as f32 + 0.5) * sx - 0.5;
                let (taps, count, wsum) = masked_taps(x, y, r, &inside);
                let acc = taps[..count].iter().fold(0.0f32, |acc, &(i, wt)| acc + wt * shift[i]);
                if wsum > 1e-6 {
                    *o = acc / wsum;
                    continue;
                }
                let (cx, cy) = (x.round() as i64, y.round() as i64);
                let nearest = (1..=2i64).find_map(|radius| {
                    let ring = (-radius..=radius).flat_map(|dy| (-radius..=radius).map(move |dx| (dx, dy)));
                    ring.filter(|&(dx, dy)| valid(cx + dx, cy + dy))
                        .min_by_key(|&(dx, dy)| dx * dx + dy * dy)
                        .map(|(dx, dy)| shift[(cy + dy) as usize * r + (cx + dx) as usize])
                });
                *o = nearest.unwrap_or(0.0);
            }
        });
        Ok(Image { width: w, height: h, data: out })
    }
}

impl std::fmt::Debug for PlacementNet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlacementNet").field("path", &self.net.path).field("info", &self.net.info).finish()
    }
}

/// The placement network's inputs, in order.
const PLACEMENT_INPUTS: [&str; 2] = ["body", "prior"];

/// The bilinear taps at model coordinates (`x`, `y`) (pixel centres at integers) of an `r x r` model grid that land
/// inside it on a pixel `valid` holds true, with positive weight: `(model pixel, weight)` in the order (0,0), (1,0),
/// (0,1), (1,1), how many there are, and their weights' sum. The mask-aware upsampling of [`FofNet::refine_with`]
/// and [`PlacementNet::shifts`] divides by that sum, so pixels outside the mask do not pull the edge toward zero.
fn masked_taps(x: f32, y: f32, r: usize, valid: &[bool]) -> ([(usize, f32); 4], usize, f32) {
    let (x0, tx, y0, ty) = (x.floor(), x - x.floor(), y.floor(), y - y.floor());
    let (mut taps, mut count, mut wsum) = ([(0usize, 0.0f32); 4], 0, 0.0f32);
    for (dx, dy, wt) in
        [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
    {
        let (c, rr) = (x0 as i64 + dx, y0 as i64 + dy);
        if wt <= 0.0 || c < 0 || rr < 0 || c >= r as i64 || rr >= r as i64 {
            continue;
        }
        let i = rr as usize * r + c as usize;
        if valid[i] {
            taps[count] = (i, wt);
            count += 1;
            wsum += wt;
        }
    }
    (taps, count, wsum)
}

/// Depth samples of the "does this column hold body" test of [`FofNet::refine`].
const SILHOUETTE_SAMPLES: usize = 64;

/// Whether one column of coefficients reaches the occupancy `level` at one of the table's depth samples (the
/// samples are visited from the middle of the ray outwards, where the body usually is, and the scan stops at the
/// first hit).
fn column_holds_body(table: &CosineTable, coeffs: &[f32], level: f32) -> bool {
    let m = table.samples;
    (0..m).map(|i| if i % 2 == 0 { m / 2 + i / 2 } else { m / 2 - 1 - i / 2 }).any(|d| {
        let v: f32 = coeffs.iter().take(table.n).enumerate().map(|(k, c)| c * table.values[k * m + d]).sum();
        v >= level
    })
}

/// What the encoder reads: the source photo, its FOF and its normals, all at the same square size.
#[derive(Clone, Copy, Debug)]
pub struct EncoderInput<'a> {
    /// Source colour, linear, premultiplied by `mask`.
    pub rgb: &'a RgbImage,
    /// Source mask in `[0, 1]`.
    pub mask: &'a GrayImage,
    /// FOF-X coefficients (`N` = the model's `fof_n`); `None` feeds zeros, like the reference's test script.
    pub fof: Option<Coefficients<'a>>,
    /// Source view-space unit normals, zero in the background.
    pub normals: &'a Image<Vec3>,
}

/// The feature encoder (runs once per input frame).
pub struct Encoder {
    net: Net,
}

impl Encoder {
    /// Loads and checks an encoder (`r2human.kind = encoder`; inputs `image` `[1,3,R,R]`, `fof` `[1,N,R,R]`,
    /// `normals` `[1,3,R,R]`; output `features` `[1,C,R/4,R/4]`).
    pub fn load(path: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        let net = Net::load(path, ModelKind::Encoder, "encoder", options)?;
        let (r, n, c) = (net.info.resolution as i64, net.info.fof_n as i64, net.info.feature_channels as i64);
        let s = &net.session;
        check_tensor(s, path, false, "image", [Dim::Is(3), Dim::Is(r), Dim::Is(r)])?;
        check_tensor(s, path, false, "fof", [Dim::Is(n), Dim::Is(r), Dim::Is(r)])?;
        check_tensor(s, path, false, "normals", [Dim::Is(3), Dim::Is(r), Dim::Is(r)])?;
        check_no_extra_inputs(s, path, &["image", "fof", "normals"])?;
        check_tensor(s, path, true, "features", [Dim::Is(c), Dim::Is(r / 4), Dim::Is(r / 4)])?;
        Ok(Self { net })
    }

    /// The model's metadata.
    pub fn info(&self) -> &ModelInfo {
        &self.net.info
    }

    /// The execution provider the model runs on.
    pub fn provider(&self) -> ActiveProvider {
        self.net.provider
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.net.path
    }

    /// Encodes a square source frame (any size; resampled to the model's resolution `R`) into features at `R/4`.
    pub fn run(&mut self, input: &EncoderInput<'_>) -> Result<FeatureMap, NeuralError> {
        let (r, n, c) = (self.net.info.resolution, self.net.info.fof_n, self.net.info.feature_channels);
        let model = "encoder";
        let (w, h) = (input.rgb.width, input.rgb.height);
        if w != h || w == 0 {
            return Err(NeuralError::BadInput { model, problem: format!("photo is {w}x{h}, not square") });
        }
        check_sizes(model, "mask", input.mask.width, input.mask.height, w, h)?;
        check_sizes(model, "normal map", input.normals.width, input.normals.height, w, h)?;
        let image = image_tensor(input.rgb, input.mask, r);
        let normals = normals_tensor(input.normals, r);
        let fof = match &input.fof {
            Some(f) => {
                check_sizes(model, "FOF", f.width, f.height, w, h)?;
                if f.n != n || f.data.len() != f.width * f.height * f.n {
                    return Err(NeuralError::BadInput {
                        model,
                        problem: format!("FOF has {} coefficients per pixel, the model takes {n}", f.n),
                    });
                }
                coefficients_tensor(f, r)
            }
            None => vec![0.0; n * r * r],
        };
        let inputs: [(&str, [usize; 4], &[f32]); 3] =
            [("image", [1, 3, r, r], &image), ("fof", [1, n, r, r], &fof), ("normals", [1, 3, r, r], &normals)];
        let (shape, data) = self.net.run(&inputs, "features")?;
        self.net.expect_output_shape(&shape, [1, c, r / 4, r / 4])?;
        Ok(FeatureMap { channels: c, width: r / 4, height: r / 4, data })
    }
}

/// The decoder's inputs, in the order the exporter writes them. `warped_rgb` is the residual decoder's colour lookup
/// (see [`Decoder`]); it is not called `rgb` because ONNX value names are unique and `rgb` is the output.
pub const DECODER_INPUTS: [&str; 4] = ["features", "zmap", "normals", "warped_rgb"];

/// The residual Z-map decoder (runs once per view).
///
/// Its graph computes `rgb = warped_rgb + UNet(features, zmap encoding, normals, warped_rgb)`: `warped_rgb` is the
/// geometric renderer's colour lookup (the source photo at the flow, mask-aware, without the visibility test; see
/// [`crate::pipeline::photo_lookup`]), and training starts from a zero-initialised last convolution, so an
/// untrained decoder reproduces the geometric renderer and training adds what the Z-map, normals and features
/// say (occlusion, the back, shading). This deviates from the paper on purpose: the `tiny` tier sees encoder
/// features at 1/4 resolution only, and the skip keeps the photo's full-resolution texture.
pub struct Decoder {
    net: Net,
    /// Fixed spatial input size `(width, height)` when the model declares one.
    fixed: Option<(usize, usize)>,
}

impl Decoder {
    /// Loads and checks a decoder (`r2human.kind = decoder`; inputs `features` `[1,C,h,w]`, `zmap` `[1,1,h,w]`,
    /// `normals` `[1,3,h,w]`, `warped_rgb` `[1,3,h,w]`; output `rgb` `[1,3,h,w]`; `h`, `w` dynamic or fixed). A
    /// decoder of the earlier three-input contract is rejected with an error that names the missing `warped_rgb`.
    pub fn load(path: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        let net = Net::load(path, ModelKind::Decoder, "decoder", options)?;
        let c = net.info.feature_channels as i64;
        let s = &net.session;
        let shape = check_tensor(s, path, false, "features", [Dim::Is(c), Dim::Any, Dim::Any])?;
        let (h, w) = (shape[2], shape[3]);
        let hw = |v: i64| if v < 0 { Dim::Any } else { Dim::Is(v) };
        check_tensor(s, path, false, "zmap", [Dim::Is(1), hw(h), hw(w)])?;
        check_tensor(s, path, false, "normals", [Dim::Is(3), hw(h), hw(w)])?;
        if !s.inputs().iter().any(|i| i.name() == "warped_rgb") {
            return Err(NeuralError::Signature {
                path: path.to_path_buf(),
                problem: "has no input named `warped_rgb` [1, 3, h, w]: it is a decoder of the earlier \
                          three-input contract (features, zmap, normals), while this build runs the residual \
                          decoder that adds the geometric colour lookup. Retrain and re-export it with this \
                          version's `python -m train fit` and `python -m train export`"
                    .into(),
            });
        }
        check_tensor(s, path, false, "warped_rgb", [Dim::Is(3), hw(h), hw(w)])?;
        check_no_extra_inputs(s, path, &DECODER_INPUTS)?;
        check_tensor(s, path, true, "rgb", [Dim::Is(3), hw(h), hw(w)])?;
        let fixed = (h > 0 && w > 0).then_some((w as usize, h as usize));
        if let Some((fw, fh)) = fixed {
            if fw % net.info.stride != 0 || fh % net.info.stride != 0 {
                return Err(NeuralError::Signature {
                    path: path.to_path_buf(),
                    problem: format!("fixed input size {fw}x{fh} is not a multiple of its stride {}", net.info.stride),
                });
            }
        }
        Ok(Self { net, fixed })
    }

    /// The model's metadata.
    pub fn info(&self) -> &ModelInfo {
        &self.net.info
    }

    /// The execution provider the model runs on.
    pub fn provider(&self) -> ActiveProvider {
        self.net.provider
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.net.path
    }

    /// The region the decoder runs over for a target mask: the mask's bounding box grown by a margin (so the
    /// network sees background context, as on a full frame), aligned and padded to the network's stride (or to its
    /// fixed input size). `None` for an empty mask.
    pub fn region(&self, mask: &GrayImage) -> Result<Option<PixelBox>, NeuralError> {
        self.region_of(PixelBox::of_mask(mask), mask.width, mask.height)
    }

    fn region_of(&self, b: Option<PixelBox>, width: usize, height: usize) -> Result<Option<PixelBox>, NeuralError> {
        let Some(b) = b else { return Ok(None) };
        let stride = self.net.info.stride;
        let mut p = b.padded(stride.max(8), stride, width, height);
        if let Some((fw, fh)) = self.fixed {
            // Centre the fixed window on the mask box with its origin on the stride grid, shifted by whole strides
            // until it covers the box.
            let s = stride as i64;
            let place = |lo: i64, hi: i64, size: i64| -> Option<i64> {
                let mut o = ((lo + hi - size) / 2).max(0) / s * s;
                while o + size < hi {
                    o += s;
                }
                (o <= lo).then_some(o)
            };
            match (place(b.x0, b.x1, fw as i64), place(b.y0, b.y1, fh as i64)) {
                (Some(x0), Some(y0)) => p = PixelBox { x0, y0, x1: x0 + fw as i64, y1: y0 + fh as i64 },
                _ => {
                    return Err(NeuralError::BadInput {
                        model: "decoder",
                        problem: format!(
                            "the target mask spans {}x{} px at ({}, {}) but this decoder has a fixed {fw}x{fh} input",
                            b.width(),
                            b.height(),
                            b.x0,
                            b.y0
                        ),
                    })
                }
            }
        }
        Ok(Some(p))
    }

    /// Renders a view from the pipeline's own buffers: warps the encoder's `features` by `flowz.flow` (continuous
    /// pixel coordinates of the `source_res x source_res` source image, as [`crate::geometry::zmap::flow_and_zmap`]
    /// gives them), decodes with `flowz.z`, the target normals and `lookup` (the geometric colour lookup at the
    /// target size, from [`crate::pipeline::photo_lookup`]: linear premultiplied RGBA whose alpha is 1 where the
    /// photo has a colour for the pixel and 0 where it has none), only over the padded bounding box of
    /// `flowz.mask && target.mask`. Returns linear premultiplied RGBA at the target size (alpha 1 on covered
    /// pixels, transparent elsewhere).
    pub fn render_view(
        &mut self,
        features: &FeatureMap,
        flowz: &FlowZ,
        source_res: usize,
        target: &GBuffer,
        lookup: &RgbaImage,
    ) -> Result<RgbaImage, NeuralError> {
        self.check_feature_channels(features.channels)?;
        let (w, h) = (target.width, target.height);
        let n = w * h;
        if flowz.flow.width != w || flowz.flow.height != h || flowz.mask.len() != n || flowz.z.data.len() != n {
            return Err(NeuralError::BadInput {
                model: "decoder",
                problem: format!("flow/Z-map is {}x{} but the target is {w}x{h}", flowz.flow.width, flowz.flow.height),
            });
        }
        if target.mask.len() != n || target.normal.len() != n {
            return Err(NeuralError::BadInput {
                model: "decoder",
                problem: "target G-buffer arrays do not match its size".into(),
            });
        }
        check_sizes("decoder", "colour lookup", lookup.width, lookup.height, w, h)?;
        if source_res == 0 {
            return Err(NeuralError::BadInput { model: "decoder", problem: "source resolution is 0".into() });
        }
        let half = source_res as f32 * 0.5;
        self.decode(
            w,
            h,
            |i| if flowz.mask[i] && target.mask[i] { 1.0 } else { 0.0 },
            |i| flowz.z.data[i],
            |i| target.normal[i],
            |i| lookup_tensor_value(lookup.data[i]),
            |col, row, out| {
                // Pixel coordinates (centres at +0.5) to body-cube coordinates of the source camera.
                let f = flowz.flow.get(col, row);
                features.sample_cube(f.x / half - 1.0, 1.0 - f.y / half, out);
            },
        )
    }

    /// Decodes already-warped features (`warped`: `C` channels at the target size) with the Z-map, the target
    /// normals and the colour `lookup` (as in [`Decoder::render_view`]), only over [`Decoder::region`] of `mask`.
    /// Returns linear premultiplied RGBA at the target size with the mask as alpha; transparent outside the mask.
    pub fn run(
        &mut self,
        warped: &FeatureMap,
        lookup: &RgbaImage,
        zmap: &GrayImage,
        normals: &Image<Vec3>,
        mask: &GrayImage,
    ) -> Result<RgbaImage, NeuralError> {
        self.check_feature_channels(warped.channels)?;
        check_sizes("decoder", "warped features", warped.width, warped.height, mask.width, mask.height)?;
        check_sizes("decoder", "colour lookup", lookup.width, lookup.height, mask.width, mask.height)?;
        let plane = warped.width * warped.height;
        self.decode_images(zmap, normals, mask, lookup, |col, row, out| {
            let i = row * warped.width + col;
            for (c, o) in out.iter_mut().enumerate() {
                *o = warped.data[c * plane + i];
            }
        })
    }

    fn decode_images(
        &mut self,
        zmap: &GrayImage,
        normals: &Image<Vec3>,
        mask: &GrayImage,
        lookup: &RgbaImage,
        features_at: impl Fn(usize, usize, &mut [f32]) + Sync,
    ) -> Result<RgbaImage, NeuralError> {
        let (w, h) = (mask.width, mask.height);
        check_sizes("decoder", "Z-map", zmap.width, zmap.height, w, h)?;
        check_sizes("decoder", "normal map", normals.width, normals.height, w, h)?;
        self.decode(
            w,
            h,
            |i| mask.data[i],
            |i| zmap.data[i],
            |i| normals.data[i],
            |i| lookup_tensor_value(lookup.data[i]),
            features_at,
        )
    }

    fn check_feature_channels(&self, c: usize) -> Result<(), NeuralError> {
        if c != self.net.info.feature_channels {
            return Err(NeuralError::BadInput {
                model: "decoder",
                problem: format!("features have {c} channels, the model takes {}", self.net.info.feature_channels),
            });
        }
        Ok(())
    }

    /// The shared decoder path over per-pixel accessors (`alpha`, `z`, `normal`, `rgb` (network space) by pixel
    /// index; `features_at` by column and row): crop, pad, run, write back. Packing and unpacking run in
    /// parallel over the box's rows (they are a sizeable share of a small view next to ONNX Runtime's run).
    #[allow(clippy::too_many_arguments)]
    fn decode(
        &mut self,
        w: usize,
        h: usize,
        alpha: impl Fn(usize) -> f32 + Sync,
        zmap: impl Fn(usize) -> f32 + Sync,
        normal: impl Fn(usize) -> Vec3 + Sync,
        rgb_in: impl Fn(usize) -> Vec3 + Sync,
        features_at: impl Fn(usize, usize, &mut [f32]) + Sync,
    ) -> Result<RgbaImage, NeuralError> {
        let mut out = RgbaImage::new(w, h, Vec4::ZERO);
        let Some(p) = self.region_of(PixelBox::of_alpha(w, h, &alpha), w, h)? else { return Ok(out) };
        let c = self.net.info.feature_channels;
        let (pw, ph) = (p.width(), p.height());
        let plane = pw * ph;
        let mut feat = vec![0.0f32; c * plane];
        let mut z = vec![0.0f32; plane];
        let mut nrm = vec![0.0f32; 3 * plane];
        let mut photo = vec![0.0f32; 3 * plane];
        // The image pixel of a box pixel, `None` outside the image or where the alpha says the pixel is unused
        // (background and unusable pixels stay zero in every input, as in training).
        let pixel = |col: usize, row: usize| -> Option<(usize, usize, f32)> {
            let (x, y) = (p.x0 + col as i64, p.y0 + row as i64);
            if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                return None;
            }
            let (x, y) = (x as usize, y as usize);
            let a = alpha(y * w + x);
            (a > 0.0).then_some((x, y, a)) // false for NaN too
        };
        // One entry per box row: that row's slice of every input plane (planes are row-major, so each plane's
        // row is contiguous), in the order features 0..C, Z, normals xyz, colour rgb.
        let mut rows: Vec<Vec<&mut [f32]>> = (0..ph).map(|_| Vec::with_capacity(c + 7)).collect();
        for buffer in [&mut feat, &mut z, &mut nrm, &mut photo] {
            for (j, chunk) in buffer.chunks_mut(pw).enumerate() {
                rows[j % ph].push(chunk);
            }
        }
        rows.par_iter_mut().enumerate().for_each_init(
            || vec![0.0f32; c],
            |px, (row, planes)| {
                // `col` indexes every plane's row slice, not `planes` itself.
                #[allow(clippy::needless_range_loop)]
                for col in 0..pw {
                    let Some((x, y, _)) = pixel(col, row) else { continue };
                    let i = y * w + x;
                    features_at(x, y, px);
                    for (k, v) in px.iter().enumerate() {
                        planes[k][col] = if v.is_finite() { *v } else { 0.0 };
                    }
                    let zz = zmap(i);
                    planes[c][col] = if zz.is_finite() { zz } else { 0.0 };
                    for (k, v) in [(c + 1, normal(i)), (c + 4, rgb_in(i))] {
                        if v.is_finite() {
                            planes[k][col] = v.x;
                            planes[k + 1][col] = v.y;
                            planes[k + 2][col] = v.z;
                        }
                    }
                }
            },
        );
        drop(rows);
        let inputs: [(&str, [usize; 4], &[f32]); 4] = [
            ("features", [1, c, ph, pw], &feat),
            ("zmap", [1, 1, ph, pw], &z),
            ("normals", [1, 3, ph, pw], &nrm),
            ("warped_rgb", [1, 3, ph, pw], &photo),
        ];
        let (shape, rgb) = self.net.run(&inputs, "rgb")?;
        self.net.expect_output_shape(&shape, [1, 3, ph, pw])?;
        out.data.par_chunks_mut(w).enumerate().for_each(|(y, out_row)| {
            let row = y as i64 - p.y0;
            if row < 0 || row >= ph as i64 {
                return;
            }
            let row = row as usize;
            for col in 0..pw {
                let Some((x, _, a)) = pixel(col, row) else { continue };
                let a = a.min(1.0);
                let i = row * pw + col;
                let lin = |v: f32| srgb_to_linear((v + 1.0) * 0.5) * a;
                out_row[x] = Vec4::new(lin(rgb[i]), lin(rgb[plane + i]), lin(rgb[2 * plane + i]), a);
            }
        });
        Ok(out)
    }
}

/// One pixel of the colour lookup (linear premultiplied RGBA, alpha > 0 where the photo has a colour) in the
/// decoder's `warped_rgb` space: straight colour clamped to `[0, 1]`, sRGB-encoded, `*2-1`; `0` where unknown
/// (exactly `train/geometry.py`'s `warp_rgb`).
fn lookup_tensor_value(p: Vec4) -> Vec3 {
    if !(p.w > 0.0 && p.is_finite()) {
        return Vec3::ZERO;
    }
    let c = p.truncate() / p.w;
    Vec3::new(linear_to_srgb(c.x), linear_to_srgb(c.y), linear_to_srgb(c.z)) * 2.0 - 1.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fof_inputs_are_an_optional_image_then_body_and_or_prior_once_each() {
        assert_eq!(parse_fof_inputs("image"), Ok((true, vec![])));
        assert_eq!(parse_fof_inputs(" image , body,prior "), Ok((true, vec![FofInput::Body, FofInput::Prior])));
        assert_eq!(parse_fof_inputs("image,prior"), Ok((true, vec![FofInput::Prior])));
        assert_eq!(parse_fof_inputs("body, prior"), Ok((false, vec![FofInput::Body, FofInput::Prior])));
        assert_eq!(parse_fof_inputs("prior"), Ok((false, vec![FofInput::Prior])));
        for bad in ["", " , ", "body,image", "image,prior,prior", "image,depth", "prior,body,prior", "image,image"] {
            let e = parse_fof_inputs(bad).unwrap_err();
            assert_eq!(e, BadFofInputs(bad.to_string()));
            assert!(e.to_string().starts_with(&format!("is `{bad}`; expected `image` (optional) followed by")), "{e}");
        }
    }
}
