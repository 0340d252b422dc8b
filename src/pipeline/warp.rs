//! The geometric novel-view renderer (used until the neural decoder exists) and the feature warp the decoder
//! will consume.
//!
//! [`render_geometric`] follows the data path of the paper with the decoder replaced by a colour lookup: target
//! depth -> flow and Z-map (Eq. 4) -> visibility (Eq. 9) -> visible pixels take the source colour at the flow
//! (bilinear, mask-aware; surfaces the photo sees edge-on blend in its blurred [`SideImages`]) -> occluded pixels
//! get an [`OcclusionFill`].
//!
//! # Colour conventions
//! - `source_rgb` is linear RGB **premultiplied by `source_mask`** (the reference feeds `img * mask`), so the
//!   background is black. A sample is `sum(w_i * c_i) / sum(w_i * m_i)` over the four bilinear taps: dividing by
//!   the bilinear mask weight un-premultiplies, so the background never darkens or bleeds into edge pixels.
//! - The output is linear, premultiplied RGBA: alpha is the target coverage mask (0 or 1 per pixel centre),
//!   colours are clamped to `[0, 1]`.
//!
//! # Which fill
//! Measured with `cargo run --release --example warp_gallery` (synthetic person of `tests/common/person.rs`:
//! horizontally striped shirt, a logo and a face on the front only, hair on the back; 512^2; PSNR in dB over the
//! target mask against a ground-truth render of the coloured mesh; visible = share of the target mask that passes
//! Eq. 9; the back fill's back image from the person's known face points):
//!
//! | view (yaw, pitch) | visible | MirroredFront | Propagate | Back |
//! |-------------------|---------|---------------|-----------|------|
//! | 45, 0             | 88 %    | 27.3          | **31.8**  | 28.8 |
//! | 90, 0             | 49 %    | 19.2          | **20.4**  | 18.9 |
//! | 180, 0            | 1 %     | 17.4          | **18.3**  | 15.0 |
//! | 30, +90 (above)   | 49 %    | **19.2**      | 17.9      | 18.0 |
//! | 0, -90 (below)    | 53 %    | **45.1**      | 17.3      | 17.3 |
//! | 135, +30          | 12 %    | **18.2**      | 16.5      | 16.0 |
//!
//! On this person every fill has a flaw a viewer sees: [`OcclusionFill::MirroredFront`] puts the face and the logo
//! on the back; [`OcclusionFill::Propagate`] is a blur; [`OcclusionFill::Back`] draws the back of the head in the
//! hair's colour and the shirt without the logo, but its mode filter moves the stripes (a pattern that happens to
//! be the same at the front and the back, which PSNR rewards the mirrored fill for, and which a viewer cannot tell
//! from any other stripes). On the evaluation's clothed synthetic subjects with ground-truth geometry (docs/rendering.md,
//! "What the photo does not show") the back fill gains on every divergent framing for the geometric renderer
//! (whole-frame PSNR +0.1 to +0.7 dB, SSIM up) and its SSIM gains for the neural one, and on real photos it is the
//! only fill that shows a plausible person from behind. [`OcclusionFill::Back`] is the default.

use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;

use crate::buffer::{floor_fast, GrayImage, Image, RgbImage, RgbaImage};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::{flow_and_zmap, visibility, FlowZ, VISIBILITY_LAMBDA};
use crate::geometry::Camera;

/// Smallest bilinear mask weight accepted as "the source sees colour here"; below it the sample is mostly
/// background and the pixel is treated as unseen.
const MIN_MASK_WEIGHT: f32 = 0.05;

/// How target pixels that the source does not see (occluded by Eq. 9) get a colour. The module docs have the
/// measured comparison.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OcclusionFill {
    /// Like [`OcclusionFill::MirroredFront`], but surfaces that face away from the source camera take the input's
    /// back image ([`super::back`]: the clothing without front-only details, the head in the head top's colour)
    /// instead of the photo, blended in by [`back_weight`]. Without a back image (no pose model, or no face found
    /// in the input) it is [`OcclusionFill::MirroredFront`].
    #[default]
    Back,
    /// The occluded point takes the source colour at its own flow, ignoring depth: the back of the body shows the
    /// front texture at the same `(x, y)` (mirrored, as seen from behind). Pixels whose flow lands outside the
    /// source silhouette fall back to [`OcclusionFill::Propagate`].
    MirroredFront,
    /// Colour diffused from the nearest visible target pixels in image space by a multi-scale push-pull
    /// (coverage-weighted downsampling, then bilinear upsampling into the holes).
    Propagate,
}

/// The colours the renderers sample at the flow: the photo (linear RGB premultiplied by the source mask), for
/// [`OcclusionFill::Back`] the input's back image (the same size, premultiplied by the same mask), and the side
/// images ([`SideImages`]) that surfaces the photo sees edge-on take.
#[derive(Clone, Copy, Debug)]
pub struct SourceColours<'a> {
    /// The photo.
    pub rgb: &'a RgbImage,
    /// The back image, when the input has one.
    pub back: Option<&'a RgbImage>,
    /// The photo and the back image blurred for surfaces seen edge-on; without them those surfaces take the
    /// sharp images' colours (the photo's pixels stretched along the surface).
    pub side: Option<&'a SideImages>,
}

impl<'a> From<&'a RgbImage> for SourceColours<'a> {
    fn from(rgb: &'a RgbImage) -> Self {
        Self { rgb, back: None, side: None }
    }
}

/// How much a surface takes the side images: where the photo sees it edge-on, one photo pixel's colour is stretched
/// along its whole depth, so the vertical run of pixels along the outline (an ear, a collar, spectacles, the hem)
/// became horizontal stripes in every view from the side (docs/rendering.md). A blur of the photo
/// along and across the outline turns them into the mean colour of that stretch of outline.
/// The blur is a standard deviation of [`SIDE_BLUR`] of the source image's width; the weight is
/// [`side_weight`].
#[derive(Clone, Debug, PartialEq)]
pub struct SideImages {
    /// The photo blurred (mask-aware), premultiplied by the sharp mask.
    pub rgb: RgbImage,
    /// The back image blurred the same way, when the input has one.
    pub back: Option<RgbImage>,
}

/// Standard deviation of the side images' blur as a fraction of the source image's width (4 px at 512²).
pub const SIDE_BLUR: f32 = 4.0 / 512.0;

/// Up to which ratio of a surface's unit normal's `|source-view z|` to its `|target-view z|` the side images blend
/// in: 1 where the photo sees the surface edge-on and the view does not, 0 from this ratio on
/// (`1 - smoothstep(0, SIDE_RAMP, ratio)`). A view from the photo's own direction has ratio 1 everywhere.
pub const SIDE_RAMP: f32 = 0.5;

impl SideImages {
    /// The side images of a photo and its back image (both premultiplied by `mask`, of its size; a back image of
    /// another size is left out): each blurred mask-aware, `blur(c m) / blur(m)` (the background never bleeds in),
    /// premultiplied again by the sharp mask so that [`sample_masked`] reads them like the sharp images.
    pub fn of(rgb: &RgbImage, back: Option<&RgbImage>, mask: &GrayImage) -> Self {
        let sigma = SIDE_BLUR * rgb.width as f32;
        let back = back.filter(|b| (b.width, b.height) == (rgb.width, rgb.height));
        Self { rgb: blur_masked(rgb, mask, sigma), back: back.map(|b| blur_masked(b, mask, sigma)) }
    }

    /// [`SideImages::of`] with the back image's side image already made (a back image kept from an earlier frame,
    /// [`super::frame`]), the photo blurred on a grid `factor` times coarser ([`blur_masked_coarse`]; 1: as
    /// [`SideImages::of`]).
    pub fn with_back_side(rgb: &RgbImage, back_side: Option<RgbImage>, mask: &GrayImage, factor: usize) -> Self {
        let sigma = SIDE_BLUR * rgb.width as f32;
        let back = back_side.filter(|b| (b.width, b.height) == (rgb.width, rgb.height));
        Self { rgb: blur_masked_coarse(rgb, mask, sigma, factor), back }
    }

    /// The side image of a straight colour image defined at every pixel (a back image's layers,
    /// [`super::back::BackLayers`], kept between frames): blurred as the side images are, not premultiplied;
    /// [`premultiplied`] by a frame's mask it is that frame's side image of the back.
    pub fn of_straight(colour: &RgbImage) -> RgbImage {
        let everywhere = GrayImage::new(colour.width, colour.height, 1.0);
        blur_masked(colour, &everywhere, SIDE_BLUR * colour.width as f32)
    }

    /// The blurred colours as [`SourceColours`] without side images of their own.
    fn colours(&self) -> SourceColours<'_> {
        SourceColours { rgb: &self.rgb, back: self.back.as_ref(), side: None }
    }
}

/// `straight` premultiplied by `mask` (0 where the mask is not above 0; `straight` unchanged for a mask of another
/// size).
pub fn premultiplied(straight: &RgbImage, mask: &GrayImage) -> RgbImage {
    if mask.data.len() != straight.data.len() || (mask.width, mask.height) != (straight.width, straight.height) {
        return straight.clone();
    }
    let data = straight.data.iter().zip(&mask.data).map(|(c, &m)| if m > 0.0 { *c * m.min(1.0) } else { Vec3::ZERO });
    RgbImage { width: straight.width, height: straight.height, data: data.collect() }
}

/// [`blur_masked`] computed on a grid `factor` times coarser: the premultiplied colour and the mask box-averaged,
/// blurred by `sigma / factor`, read back bilinearly at each pixel and divided, premultiplied by the sharp mask. A
/// blur of several pixels loses nothing a coarser grid cannot hold, at a `factor²`-th of the pixels (what a video
/// frame can afford). `factor` 1, or an image smaller than `4 factor` a side, is [`blur_masked`].
fn blur_masked_coarse(rgb: &RgbImage, mask: &GrayImage, sigma: f32, factor: usize) -> RgbImage {
    let (w, h) = (rgb.width, rgb.height);
    if factor <= 1 || w < 4 * factor || h < 4 * factor || mask.data.len() != w * h {
        return blur_masked(rgb, mask, sigma);
    }
    let (cw, ch) = (w.div_ceil(factor), h.div_ceil(factor));
    // Means of each cell's premultiplied colour and coverage: means, not sums, as `fast_blur` clamps to [0, 1].
    let mut flat = vec![0.0f32; cw * ch * 4];
    for (r, (line, mask_line)) in rgb.data.chunks_exact(w).zip(mask.data.chunks_exact(w)).enumerate() {
        let cells = &mut flat[(r / factor) * cw * 4..][..cw * 4];
        for ((cell, colours), masks) in cells.chunks_exact_mut(4).zip(line.chunks(factor)).zip(mask_line.chunks(factor))
        {
            for (v, &m) in colours.iter().zip(masks) {
                let m = if m.is_finite() { m.clamp(0.0, 1.0) } else { 0.0 };
                cell[0] += v.x;
                cell[1] += v.y;
                cell[2] += v.z;
                cell[3] += m;
            }
        }
    }
    for (j, cells) in flat.chunks_exact_mut(cw * 4).enumerate() {
        let rows = (h - j * factor).min(factor);
        for (i, cell) in cells.chunks_exact_mut(4).enumerate() {
            let pixels = (rows * (w - i * factor).min(factor)) as f32;
            cell.iter_mut().for_each(|v| *v /= pixels);
        }
    }
    let Some(buffer) = image::ImageBuffer::<image::Rgba<f32>, Vec<f32>>::from_raw(cw as u32, ch as u32, flat) else {
        return blur_masked(rgb, mask, sigma);
    };
    let blurred: Vec<Vec4> = image::imageops::fast_blur(&buffer, sigma / factor as f32)
        .into_raw()
        .chunks_exact(4)
        .map(|p| Vec4::new(p[0], p[1], p[2], p[3]))
        .collect();
    // Bilinear at every pixel (cell centres at (k + 0.5) factor, edges clamped): each output row lerps its two
    // cell rows once, then each pixel its two cells.
    let f = factor as f32;
    let columns: Vec<(usize, usize, f32)> = (0..w)
        .map(|c| {
            let x = ((c as f32 + 0.5) / f - 0.5).max(0.0);
            let x0 = (x as usize).min(cw - 1);
            (x0, (x0 + 1).min(cw - 1), x - x0 as f32)
        })
        .collect();
    let mut out = Image::new(w, h, Vec3::ZERO);
    let mut row_cells = vec![Vec4::ZERO; cw];
    for (r, (line, mask_line)) in out.data.chunks_exact_mut(w).zip(mask.data.chunks_exact(w)).enumerate() {
        if mask_line.iter().all(|&m| m.is_nan() || m <= 0.0) {
            continue;
        }
        let y = ((r as f32 + 0.5) / f - 0.5).max(0.0);
        let y0 = (y as usize).min(ch - 1);
        let (y1, ty) = ((y0 + 1).min(ch - 1), y - y0 as f32);
        let (top, bottom) = (&blurred[y0 * cw..][..cw], &blurred[y1 * cw..][..cw]);
        for (cell, (t, b)) in row_cells.iter_mut().zip(top.iter().zip(bottom)) {
            *cell = *t * (1.0 - ty) + *b * ty;
        }
        for ((o, &m), &(x0, x1, tx)) in line.iter_mut().zip(mask_line).zip(&columns) {
            if m.is_nan() || m <= 0.0 {
                continue;
            }
            let v = row_cells[x0] * (1.0 - tx) + row_cells[x1] * tx;
            if v.w > 1e-6 {
                let colour = v.truncate() / v.w * m.min(1.0);
                if colour.is_finite() {
                    *o = colour;
                }
            }
        }
    }
    out
}

/// `blur(c m) / blur(m)` with a Gaussian-like blur of standard deviation `sigma` pixels (`image`'s
/// `fast_blur`: three box passes), premultiplied by `mask`; an image and a mask of other sizes give the image
/// unchanged.
fn blur_masked(rgb: &RgbImage, mask: &GrayImage, sigma: f32) -> RgbImage {
    let (w, h) = (rgb.width, rgb.height);
    if mask.data.len() != w * h || w == 0 || h == 0 || sigma.is_nan() || sigma <= 0.0 {
        return rgb.clone();
    }
    // Premultiplied colour in the first three channels, coverage in the fourth.
    let flat: Vec<f32> = rgb
        .data
        .iter()
        .zip(&mask.data)
        .flat_map(|(c, &m)| {
            let m = if m.is_finite() { m.clamp(0.0, 1.0) } else { 0.0 };
            [c.x, c.y, c.z, m]
        })
        .collect();
    let Some(buffer) = image::ImageBuffer::<image::Rgba<f32>, Vec<f32>>::from_raw(w as u32, h as u32, flat) else {
        return rgb.clone();
    };
    let blurred = image::imageops::fast_blur(&buffer, sigma);
    let mut out = Image::new(w, h, Vec3::ZERO);
    for ((o, px), &m) in out.data.iter_mut().zip(blurred.pixels()).zip(&mask.data) {
        let [r, g, b, cover] = px.0;
        if cover > 1e-6 && m > 0.0 {
            let c = Vec3::new(r, g, b) / cover * m.min(1.0);
            if c.is_finite() {
                *o = c;
            }
        }
    }
    out
}

impl<'a> SourceColours<'a> {
    /// The back image when `fill` uses it and it matches the photo's size.
    fn back_for(&self, fill: OcclusionFill) -> Option<&'a RgbImage> {
        self.back.filter(|b| fill == OcclusionFill::Back && (b.width, b.height) == (self.rgb.width, self.rgb.height))
    }

    /// The source colour at `p` (continuous source pixels): the photo blended with the back image by `back`
    /// (0: the photo, 1: the back image; the back image is ignored when absent), both by [`sample_masked`], and
    /// that blended with the same lookup in the side images by `side` (0: sharp, 1: the side images; ignored when
    /// absent). The one lookup every renderer of the fill follows (`render_from_flow`,
    /// [`crate::pipeline::photo_lookup`], `shaders/warp.comp`; the glTF export's texture is the sharp images').
    pub fn sample(&self, mask: &GrayImage, p: Vec2, back: f32, side: f32, fill: OcclusionFill) -> Option<Vec3> {
        let sharp = self.sample_sharp(mask, p, back, fill)?;
        match self.side.filter(|_| side > 0.0) {
            Some(images) => {
                let blurred = images.colours().sample_sharp(mask, p, back, fill).unwrap_or(sharp);
                Some(if side >= 1.0 { blurred } else { sharp * (1.0 - side) + blurred * side })
            }
            None => Some(sharp),
        }
    }

    /// [`SourceColours::sample`] without the side images.
    fn sample_sharp(&self, mask: &GrayImage, p: Vec2, back: f32, fill: OcclusionFill) -> Option<Vec3> {
        let Some(image) = self.back_for(fill).filter(|_| back > 0.0) else { return sample_masked(self.rgb, mask, p) };
        // Both images are premultiplied by the same mask: they have a colour at the same points.
        let behind = sample_masked(image, mask, p)?;
        if back >= 1.0 {
            return Some(behind);
        }
        Some(sample_masked(self.rgb, mask, p)? * (1.0 - back) + behind * back)
    }
}

/// How far (the source-view z of a surface's unit normal, negated) a surface must turn away from the source camera
/// before it takes the back image alone; between 0 (seen edge-on) and this, the photo and the back image blend.
pub const BACK_FACING_RAMP: f32 = 0.3;

/// The direction, in the target camera's view space, of the source camera's view +z axis (toward the source
/// camera): a target-view normal `n` faces the source when `n . axis > 0`. Once per view.
pub fn source_axis(target: &Camera, source: &Camera) -> Vec3 {
    let world = source.view_from_world.inverse().transform_vector3(Vec3::Z);
    target.view_from_world.transform_vector3(world).normalize_or_zero()
}

/// How much the surface with unit target-view normal `normal` takes the back image: `smoothstep(0,
/// BACK_FACING_RAMP, -normal . axis)` with `axis` = [`source_axis`]: 0 for surfaces facing the source camera
/// (self-occluded front surfaces keep the photo), 1 for those turned away from it. 0 for a non-finite normal.
pub fn back_weight(normal: Vec3, axis: Vec3) -> f32 {
    let t = (-normal.dot(axis) / BACK_FACING_RAMP).clamp(0.0, 1.0);
    if t.is_finite() {
        t * t * (3.0 - 2.0 * t)
    } else {
        0.0
    }
}

/// How much the surface with unit target-view normal `normal` takes the side images ([`SideImages`]):
/// `1 - smoothstep(0, SIDE_RAMP, |normal . axis| / |normal . z|)` with `axis` = [`source_axis`] and `z` the target
/// camera's own axis. The ratio is how much the photo shrinks the surface against this view (one photo pixel
/// covers `1 / ratio` pixels here): 1 for a surface the source camera sees edge-on and this view face-on, 0 where
/// the photo sees the surface at least [`SIDE_RAMP`] as well as this view does, so the photo's own view (ratio 1)
/// and surfaces this view sees edge-on keep the sharp photo. 0 for a non-finite normal.
pub fn side_weight(normal: Vec3, axis: Vec3) -> f32 {
    let t = (normal.dot(axis).abs() / (SIDE_RAMP * normal.z.abs())).clamp(0.0, 1.0);
    if t.is_finite() {
        1.0 - t * t * (3.0 - 2.0 * t)
    } else {
        0.0
    }
}

/// Renders the person from `target_cam` by warping the source photo through the geometry (see the module docs).
///
/// `source_gbuf` is the source camera's G-buffer of the same mesh (its depth decides visibility), `target_gbuf`
/// the target camera's. Returns linear premultiplied RGBA of the target G-buffer's size, alpha = target mask.
pub fn render_geometric<'a>(
    source_rgb: impl Into<SourceColours<'a>>,
    source_mask: &GrayImage,
    source_gbuf: &GBuffer,
    source_cam: &Camera,
    target_gbuf: &GBuffer,
    target_cam: &Camera,
    fill: OcclusionFill,
) -> RgbaImage {
    let flowz = flow_and_zmap(target_gbuf, target_cam, source_cam);
    let vis = visibility(&flowz, source_gbuf, source_cam, VISIBILITY_LAMBDA);
    render_from_flow(source_rgb, source_mask, source_cam, target_gbuf, target_cam, &flowz, &vis, fill)
}

/// The second half of [`render_geometric`], for callers that already have the flow and visibility.
#[allow(clippy::too_many_arguments)]
pub fn render_from_flow<'a>(
    source_rgb: impl Into<SourceColours<'a>>,
    source_mask: &GrayImage,
    source_cam: &Camera,
    target_gbuf: &GBuffer,
    target_cam: &Camera,
    flowz: &FlowZ,
    vis: &[bool],
    fill: OcclusionFill,
) -> RgbaImage {
    let colours: SourceColours = source_rgb.into();
    let source_rgb = colours.rgb;
    let (w, h) = (target_gbuf.width, target_gbuf.height);
    let n = w * h;
    let mut out = Image::new(w, h, Vec4::ZERO);
    if n == 0 || flowz.mask.len() != n || vis.len() != n || target_gbuf.mask.len() != n {
        return out;
    }
    // Flow is in the source camera's pixels; the photo may have another size.
    let scale = Vec2::new(
        source_rgb.width as f32 / source_cam.width.max(1) as f32,
        source_rgb.height as f32 / source_cam.height.max(1) as f32,
    );
    let same_size = source_mask.width == source_rgb.width && source_mask.height == source_rgb.height;
    let back = colours.back_for(fill).is_some();
    let axis = source_axis(target_cam, source_cam);

    // Colour per target pixel and whether it is known (weight 1) or still a hole (weight 0).
    let mut color = vec![Vec3::ZERO; n];
    let mut known = vec![false; n];
    color.par_chunks_mut(w).zip(known.par_chunks_mut(w)).enumerate().for_each(|(row, (cr, kr))| {
        for col in 0..w {
            let i = row * w + col;
            if !target_gbuf.mask[i] || !flowz.mask[i] {
                continue;
            }
            let take = vis[i] || fill != OcclusionFill::Propagate;
            if take && same_size {
                let normal = target_gbuf.normal[i];
                let b = if back && !vis[i] { back_weight(normal, axis) } else { 0.0 };
                let s = side_weight(normal, axis);
                if let Some(c) = colours.sample(source_mask, flowz.flow.data[i] * scale, b, s, fill) {
                    cr[col] = c;
                    kr[col] = true;
                }
            }
        }
    });

    let holes = (0..n).any(|i| target_gbuf.mask[i] && !known[i]);
    if holes {
        if known.iter().any(|&k| k) {
            push_pull(&mut color, &known, Some(&target_gbuf.mask), w, h);
        } else {
            // Nothing seen at all: the mean colour of the person in the photo (grey without a person).
            let mean = mean_masked(source_rgb, source_mask).unwrap_or(Vec3::splat(0.5));
            for (c, &m) in color.iter_mut().zip(&target_gbuf.mask) {
                if m {
                    *c = mean;
                }
            }
        }
    }
    out.data.par_iter_mut().zip(color.par_iter()).zip(target_gbuf.mask.par_iter()).for_each(|((o, c), &m)| {
        if m {
            *o = c.clamp(Vec3::ZERO, Vec3::ONE).extend(1.0);
        }
    });
    out
}

/// Mask-aware bilinear sample of a premultiplied image at continuous pixel coordinates `p` (centres at +0.5):
/// `sum(w c) / sum(w m)` over the four taps; `None` where the mask weight is too small (the point is essentially
/// outside the person). Public so the neural decoder's colour lookup is this exact function.
pub fn sample_masked(rgb: &RgbImage, mask: &GrayImage, p: Vec2) -> Option<Vec3> {
    if !p.is_finite() {
        return None;
    }
    let fx = p.x - 0.5;
    let fy = p.y - 0.5;
    let x0 = floor_fast(fx);
    let y0 = floor_fast(fy);
    let (tx, ty) = (fx - x0, fy - y0);
    let (c0, r0) = (x0 as i64, y0 as i64);
    let (w, h) = (rgb.width as i64, rgb.height as i64);
    let mut acc = Vec3::ZERO;
    let mut wm = 0.0;
    for (dc, dr, wt) in
        [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
    {
        let (c, r) = (c0 + dc, r0 + dr);
        if c < 0 || r < 0 || c >= w || r >= h || wt <= 0.0 {
            continue;
        }
        let j = (r * w + c) as usize;
        let m = mask.data[j].clamp(0.0, 1.0);
        if m > 0.0 {
            acc += rgb.data[j] * wt;
            wm += m * wt;
        }
    }
    (wm >= MIN_MASK_WEIGHT).then(|| acc / wm).filter(|c| c.is_finite())
}

/// Mean un-premultiplied colour under the mask.
fn mean_masked(rgb: &RgbImage, mask: &GrayImage) -> Option<Vec3> {
    if rgb.data.len() != mask.data.len() {
        return None;
    }
    let (sum, wsum) = rgb.data.iter().zip(&mask.data).fold((Vec3::ZERO, 0.0f32), |(s, ws), (c, &m)| {
        if m > 0.0 {
            (s + *c, ws + m.min(1.0))
        } else {
            (s, ws)
        }
    });
    (wsum > 0.0).then(|| (sum / wsum).clamp(Vec3::ZERO, Vec3::ONE))
}

/// Multi-scale push-pull hole filling: known pixels keep their colour, holes get the coverage-weighted average of
/// progressively coarser levels, upsampled bilinearly (smooth, no block artefacts). Every pixel ends with a
/// colour as soon as one pixel is known.
/// `needed` limits the finest level to the pixels whose colour is used (the target mask).
///
/// Only the work that can change a needed pixel is done, with results identical to the whole-frame pyramid: a pull
/// outside the box of known pixels is exactly zero (zero weights add nothing), so each level is pulled only over
/// that box; and a push only touches the box that the next finer level's needed box reads (its footprint halved
/// and grown by one bilinear tap). The finest level is never materialised: it is read from `color`/`known`.
pub fn push_pull(color: &mut [Vec3], known: &[bool], needed: Option<&[bool]>, w: usize, h: usize) {
    let Some(known_box) = PixelBox::of(known, w, h) else { return };
    let needed_box = match needed {
        Some(m) => match PixelBox::of(m, w, h) {
            Some(b) => b,
            None => return,
        },
        None => PixelBox { c0: 0, r0: 0, c1: w - 1, r1: h - 1 },
    };
    // Coarse levels 1.. as (width, height, premultiplied colour + weight, box that holds every non-zero weight,
    // box the next finer level reads). Pixels outside the pulled box stay zero, as in the whole-frame pyramid.
    let mut levels: Vec<(usize, usize, Vec<Vec4>, PixelBox, PixelBox)> = Vec::new();
    let (mut lw, mut lh, mut pulled, mut read) = (w, h, known_box, needed_box);
    while lw > 1 || lh > 1 {
        let (nw, nh) = (lw.div_ceil(2), lh.div_ceil(2));
        let next_pulled = pulled.halved();
        let next_read = read.halved().grown(1, nw, nh);
        let mut next = vec![Vec4::ZERO; nw * nh];
        {
            let fetch = |i: usize, prev: Option<&[Vec4]>| match prev {
                Some(p) => p[i],
                None if known[i] => color[i].extend(1.0),
                None => Vec4::ZERO,
            };
            let prev = levels.last().map(|l| l.2.as_slice());
            let rows = &mut next[next_pulled.r0 * nw..(next_pulled.r1 + 1) * nw];
            rows.par_chunks_mut(nw).enumerate().for_each(|(dr, row)| {
                let r = next_pulled.r0 + dr;
                for (c, px) in row.iter_mut().enumerate().take(next_pulled.c1 + 1).skip(next_pulled.c0) {
                    let mut s = Vec4::ZERO;
                    for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (cc, rr) = (2 * c + dc, 2 * r + dr);
                        if cc < lw && rr < lh {
                            s += fetch(rr * lw + cc, prev);
                        }
                    }
                    *px = if s.w > 0.0 { (s.truncate() / s.w * s.w.min(1.0)).extend(s.w.min(1.0)) } else { Vec4::ZERO };
                }
            });
        }
        levels.push((nw, nh, next, next_pulled, next_read));
        (lw, lh, pulled, read) = (nw, nh, next_pulled, next_read);
    }
    // Push: from coarse to fine, holes (weight < 1) are completed by the upsampled coarser level.
    for k in (0..levels.len()).rev() {
        let (finer, coarser) = levels.split_at_mut(k);
        let (cw, ch, coarse) = (coarser[0].0, coarser[0].1, &coarser[0].2);
        if k == 0 {
            // The finest level: only needed holes, written straight into `color`.
            let rows = &mut color[needed_box.r0 * w..(needed_box.r1 + 1) * w];
            rows.par_chunks_mut(w).enumerate().for_each(|(dr, row)| {
                let r = needed_box.r0 + dr;
                for (c, px) in row.iter_mut().enumerate().take(needed_box.c1 + 1).skip(needed_box.c0) {
                    let i = r * w + c;
                    if known[i] || needed.is_some_and(|m| !m[i]) {
                        continue;
                    }
                    let up = bilinear4(coarse, cw, ch, (c as f32 + 0.5) * 0.5, (r as f32 + 0.5) * 0.5);
                    *px = if up.w > 0.0 { up.truncate() / up.w } else { Vec3::ZERO };
                }
            });
            continue;
        }
        let (fw, fine, fine_read) = (finer[k - 1].0, &mut finer[k - 1].2, finer[k - 1].4);
        let rows = &mut fine[fine_read.r0 * fw..(fine_read.r1 + 1) * fw];
        rows.par_chunks_mut(fw).enumerate().for_each(|(dr, row)| {
            let r = fine_read.r0 + dr;
            for (c, px) in row.iter_mut().enumerate().take(fine_read.c1 + 1).skip(fine_read.c0) {
                if px.w >= 1.0 {
                    continue;
                }
                // Fine pixel centre in coarse pixel coordinates.
                let up = bilinear4(coarse, cw, ch, (c as f32 + 0.5) * 0.5, (r as f32 + 0.5) * 0.5);
                let up_rgb = if up.w > 0.0 { up.truncate() / up.w } else { Vec3::ZERO };
                let own = px.truncate(); // premultiplied by px.w
                *px = (own + up_rgb * (1.0 - px.w)).extend(1.0);
            }
        });
    }
}

/// An inclusive pixel rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PixelBox {
    c0: usize,
    r0: usize,
    c1: usize,
    r1: usize,
}

impl PixelBox {
    /// The bounding box of the set pixels of a `w x h` mask; `None` when none is set.
    fn of(mask: &[bool], w: usize, h: usize) -> Option<Self> {
        let rows: Vec<Option<(usize, usize)>> = mask[..w * h]
            .par_chunks(w)
            .map(|row| Some((row.iter().position(|&m| m)?, row.iter().rposition(|&m| m)?)))
            .collect();
        let r0 = rows.iter().position(Option::is_some)?;
        let r1 = rows.iter().rposition(Option::is_some)?;
        let (c0, c1) = rows.iter().flatten().fold((usize::MAX, 0), |(a, b), &(lo, hi)| (a.min(lo), b.max(hi)));
        Some(Self { c0, r0, c1, r1 })
    }

    /// The box of the next coarser level's pixels that contain this box's pixels.
    fn halved(self) -> Self {
        Self { c0: self.c0 / 2, r0: self.r0 / 2, c1: self.c1 / 2, r1: self.r1 / 2 }
    }

    /// Grown by `n` pixels on every side, clamped to a `w x h` image.
    fn grown(self, n: usize, w: usize, h: usize) -> Self {
        Self {
            c0: self.c0.saturating_sub(n),
            r0: self.r0.saturating_sub(n),
            c1: (self.c1 + n).min(w - 1),
            r1: (self.r1 + n).min(h - 1),
        }
    }
}

/// Bilinear sample of a Vec4 grid with clamp-to-edge (pixel centres at +0.5).
fn bilinear4(img: &[Vec4], w: usize, h: usize, x: f32, y: f32) -> Vec4 {
    let fx = (x - 0.5).clamp(0.0, (w - 1) as f32);
    let fy = (y - 0.5).clamp(0.0, (h - 1) as f32);
    // Clamped to be non-negative, so truncation is the floor.
    let (x0, y0) = (fx as usize, fy as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    let top = img[y0 * w + x0] * (1.0 - tx) + img[y0 * w + x1] * tx;
    let bottom = img[y1 * w + x0] * (1.0 - tx) + img[y1 * w + x1] * tx;
    top * (1.0 - ty) + bottom * ty
}

/// Bilinearly samples a `channels x fh x fw` feature map (row-major planes, e.g. the encoder's 128^2 output at
/// 1/4 of the source resolution) at the flow of every target pixel, writing `channels x th x tw` into `out`
/// (`th x tw` = the flow's size). `source_res` is the source image size the flow is expressed in (512): the
/// flow is scaled by `fw / source_res` (pixel edges aligned, like `grid_sample(align_corners=False)`). Taps
/// outside the feature map read zero, and pixels outside `flowz.mask` are zero — the decoder's input.
///
/// # Panics
/// When `features` or `out` is shorter than the sizes say (a programming error).
pub fn warp_features(
    features: &[f32],
    channels: usize,
    fw: usize,
    fh: usize,
    flowz: &FlowZ,
    source_res: usize,
    out: &mut [f32],
) {
    let (tw, th) = (flowz.flow.width, flowz.flow.height);
    let plane = tw * th;
    assert!(features.len() >= channels * fw * fh, "feature map shorter than {channels}x{fh}x{fw}");
    assert!(out.len() >= channels * plane, "output shorter than {channels}x{th}x{tw}");
    let out = &mut out[..channels * plane];
    out.fill(0.0);
    if plane == 0 || channels == 0 || fw == 0 || fh == 0 || source_res == 0 || flowz.mask.len() != plane {
        return;
    }
    let sx = fw as f32 / source_res as f32;
    let sy = fh as f32 / source_res as f32;
    let fplane = fw * fh;
    // Channels in groups so each group computes its taps once per pixel and writes a contiguous block.
    const GROUP: usize = 8;
    out.par_chunks_mut(GROUP * plane).enumerate().for_each(|(g, block)| {
        let c0 = g * GROUP;
        let nc = block.len() / plane;
        for i in 0..plane {
            if !flowz.mask[i] {
                continue;
            }
            let f = flowz.flow.data[i];
            let (x, y) = (f.x * sx - 0.5, f.y * sy - 0.5);
            if !(x.is_finite() && y.is_finite()) || x <= -1.0 || y <= -1.0 || x >= fw as f32 || y >= fh as f32 {
                continue;
            }
            let (x0, y0) = (floor_fast(x), floor_fast(y));
            let (tx, ty) = (x - x0, y - y0);
            let (xi, yi) = (x0 as i64, y0 as i64);
            let mut taps = [(0usize, 0.0f32); 4];
            let mut nt = 0;
            for (dx, dy, wt) in
                [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
            {
                let (c, r) = (xi + dx, yi + dy);
                if c >= 0 && r >= 0 && c < fw as i64 && r < fh as i64 {
                    taps[nt] = (r as usize * fw + c as usize, wt);
                    nt += 1;
                }
            }
            for k in 0..nc {
                let src = &features[(c0 + k) * fplane..(c0 + k + 1) * fplane];
                let mut v = 0.0;
                for &(j, wt) in &taps[..nt] {
                    v += src[j] * wt;
                }
                block[k * plane + i] = v;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raster::rasterize;
    use crate::geometry::TriMesh;

    fn gradient_source(res: usize) -> (RgbImage, GrayImage, GBuffer, Camera, TriMesh) {
        let mesh = TriMesh::uv_sphere(Vec3::ZERO, 0.7, 32, 64);
        let cam = Camera::source(res);
        let g = rasterize(&mesh, &cam);
        let rgb = Image::from_fn(res, res, |c, r| {
            if g.mask[r * res + c] {
                Vec3::new(c as f32 / res as f32, r as f32 / res as f32, 0.5)
            } else {
                Vec3::ZERO
            }
        });
        (rgb, g.mask_image(), g, cam, mesh)
    }

    #[test]
    fn identity_view_reproduces_the_photo() {
        let (rgb, mask, g, cam, _) = gradient_source(64);
        for fill in [OcclusionFill::MirroredFront, OcclusionFill::Propagate] {
            let out = render_geometric(&rgb, &mask, &g, &cam, &g, &cam, fill);
            for i in 0..64 * 64 {
                let expect = rgb.data[i].extend(mask.data[i]);
                assert!((out.data[i] - expect).abs().max_element() < 1e-5, "{i}");
            }
        }
    }

    #[test]
    fn background_never_bleeds_into_the_edge() {
        // A white disc on black: every output pixel of the person is white, even on the silhouette.
        let (_, mask, g, cam, mesh) = gradient_source(64);
        let rgb = mask.map(|&m| Vec3::splat(m));
        let tgt = Camera::orbit(20.0, 10.0, 64, 64);
        let gt = rasterize(&mesh, &tgt);
        let out = render_geometric(&rgb, &mask, &g, &cam, &gt, &tgt, OcclusionFill::Propagate);
        for (o, &m) in out.data.iter().zip(&gt.mask) {
            if m {
                assert!((*o - Vec4::ONE).abs().max_element() < 1e-5, "{o}");
            } else {
                assert_eq!(*o, Vec4::ZERO);
            }
        }
    }

    #[test]
    fn back_view_fills_every_pixel_of_the_mask() {
        let (rgb, mask, g, cam, mesh) = gradient_source(64);
        let tgt = Camera::orbit(180.0, 0.0, 64, 64);
        let gt = rasterize(&mesh, &tgt);
        for fill in [OcclusionFill::MirroredFront, OcclusionFill::Propagate] {
            let out = render_geometric(&rgb, &mask, &g, &cam, &gt, &tgt, fill);
            for (o, &m) in out.data.iter().zip(&gt.mask) {
                assert_eq!(o.w, m as u8 as f32);
                assert!(o.is_finite() && o.min_element() >= 0.0 && o.max_element() <= 1.0);
            }
            if fill == OcclusionFill::MirroredFront {
                // Mirrored: the target pixel (col, row) at yaw 180 sees world x = -x_t, so it shows the source
                // colour of column 63 - col.
                for row in 20..44 {
                    for col in 20..44 {
                        let o = out.data[row * 64 + col];
                        let expect = (63 - col) as f32 / 64.0;
                        assert!((o.x - expect).abs() < 0.02, "{col},{row}: {o}");
                    }
                }
            }
        }
    }

    #[test]
    fn back_weight_and_source_axis_in_closed_form() {
        let src = Camera::source(8);
        // From the source itself the axis is view +z: a normal toward the camera weighs 0, away 1.
        let axis = source_axis(&src, &src);
        assert!((axis - Vec3::Z).length() < 1e-6);
        assert_eq!(back_weight(Vec3::Z, axis), 0.0);
        assert_eq!(back_weight(-Vec3::Z, axis), 1.0);
        assert_eq!(back_weight(Vec3::X, axis), 0.0);
        // Halfway through the ramp: smoothstep(0.5) = 0.5.
        let n = Vec3::new((1.0 - 0.0225f32).sqrt(), 0.0, -0.15);
        assert!((back_weight(n, axis) - 0.5).abs() < 1e-6);
        // From behind (yaw 180) the source's +z is the target's -z.
        let back = Camera::orbit(180.0, 0.0, 8, 8);
        assert!((source_axis(&back, &src) + Vec3::Z).length() < 1e-5);
        assert_eq!(back_weight(Vec3::Z, source_axis(&back, &src)), 1.0);
        assert_eq!(back_weight(Vec3::NAN, axis), 0.0);
    }

    #[test]
    fn side_weight_in_closed_form() {
        let src = Camera::source(8);
        // From the photo's own direction the ratio is 1 for every surface: the sharp photo everywhere.
        let own = source_axis(&src, &src);
        for n in [Vec3::Z, Vec3::new(0.0, 0.8, 0.6), Vec3::new(0.99, 0.0, 0.141), Vec3::X] {
            assert_eq!(side_weight(n.normalize(), own), 0.0, "{n}");
        }
        // Seen from the side (the photo's axis is the view's x): edge-on in the photo and face-on here, the side
        // images alone; the photo sees it at least half as well as this view: none; seen edge-on here: none.
        let tgt = Camera::orbit(90.0, 0.0, 8, 8);
        let axis = source_axis(&tgt, &src);
        assert!((axis.abs() - Vec3::X).length() < 1e-5, "{axis}");
        assert_eq!(side_weight(Vec3::Z, axis), 1.0);
        assert_eq!(side_weight(-Vec3::Z, axis), 1.0);
        assert_eq!(side_weight(Vec3::new(0.6, 0.0, 0.8), axis), 0.0);
        assert_eq!(side_weight(Vec3::X, axis), 0.0);
        assert_eq!(side_weight(Vec3::Y, axis), 0.0);
        // Halfway through the ramp (ratio 0.25), facing the photo or away: 1 - smoothstep(0.5) = 0.5.
        for x in [0.25f32, -0.25] {
            let n = Vec3::new(x, 0.0, 1.0).normalize();
            assert!((side_weight(n, axis) - 0.5).abs() < 1e-6, "{x}");
        }
        // A tenth of the ramp (ratio 0.05): 1 - (3 t^2 - 2 t^3) with t = 0.1.
        let n = Vec3::new(0.05, 0.0, 1.0).normalize();
        assert!((side_weight(n, axis) - 0.972).abs() < 1e-5);
        assert_eq!(side_weight(Vec3::NAN, axis), 0.0);
        assert_eq!(side_weight(Vec3::ZERO, axis), 0.0);
    }

    #[test]
    fn side_images_blur_inside_the_mask_only() {
        // A disc of horizontal stripes (red and green rows, 2 px each) on black, its back image all blue.
        let res = 256;
        let mask = Image::from_fn(res, res, |c, r| {
            let (x, y) = (c as f32 + 0.5 - 128.0, r as f32 + 0.5 - 128.0);
            if x * x + y * y < 80.0 * 80.0 {
                1.0
            } else {
                0.0
            }
        });
        let stripes = Image::from_fn(res, res, |c, r| {
            let colour = if (r / 2) % 2 == 0 { Vec3::X } else { Vec3::Y };
            colour * mask.data[r * res + c]
        });
        let back = mask.map(|&m| Vec3::Z * m);
        let side = SideImages::of(&stripes, Some(&back), &mask);
        // sigma = 2 px at 256 (SIDE_BLUR of the width).
        assert!((SIDE_BLUR * res as f32 - 2.0).abs() < 1e-6);
        for (i, &m) in mask.data.iter().enumerate() {
            let (c, b) = (side.rgb.data[i], side.back.as_ref().unwrap().data[i]);
            if m == 0.0 {
                // Outside the person nothing, as in the sharp images.
                assert_eq!((c, b), (Vec3::ZERO, Vec3::ZERO));
                continue;
            }
            // Inside: a mix of the stripes only (no black from the background, even on the outline) and the back
            // image's blue unchanged.
            assert!((c.x + c.y - 1.0).abs() < 1e-4 && c.z.abs() < 1e-6, "{i}: {c}");
            assert!((b - Vec3::Z).abs().max_element() < 1e-4, "{i}: {b}");
        }
        // The stripes are flattened: row to row the blurred colour changes far less than the sharp one.
        let step = |img: &RgbImage| {
            (60..196).map(|r| (img.data[r * res + 128] - img.data[(r + 1) * res + 128]).x.abs()).sum::<f32>()
        };
        assert!(step(&side.rgb) < 0.1 * step(&stripes), "{} {}", step(&side.rgb), step(&stripes));
        // A back image of another size is left out; an image without a person stays black.
        let small = Image::new(8, 8, Vec3::Z);
        assert!(SideImages::of(&stripes, Some(&small), &mask).back.is_none());
        let none = SideImages::of(&Image::new(16, 16, Vec3::ZERO), None, &Image::new(16, 16, 0.0));
        assert!(none.rgb.data.iter().all(|c| *c == Vec3::ZERO));
    }

    #[test]
    fn side_images_on_a_coarser_grid_match_the_full_ones() {
        // A disc of red and green stripes 2 px high on black, the disc's mask soft at its edge: a blur of 4 px
        // computed on a grid twice as coarse. Red and green average to (0.5, 0.5, 0) away from the outline.
        let res = 256;
        let mask = Image::from_fn(res, res, |c, r| {
            let d = (Vec2::new(c as f32 + 0.5, r as f32 + 0.5) - Vec2::splat(128.0)).length();
            (80.0 - d).clamp(0.0, 1.0)
        });
        let rgb = Image::from_fn(res, res, |c, r| {
            let m = mask.data[r * res + c];
            let colour = if (r / 2) % 2 == 0 { Vec3::X } else { Vec3::Y };
            colour * m
        });
        let full = SideImages::with_back_side(&rgb, None, &mask, 1);
        assert_eq!(full, SideImages::of(&rgb, None, &mask));
        let coarse = SideImages::with_back_side(&rgb, None, &mask, 2);
        let (mut sum, mut n, mut worst) = (0.0f32, 0, 0.0f32);
        for i in 0..res * res {
            let m = mask.data[i];
            if m <= 0.0 {
                // Nothing outside the person.
                assert_eq!(coarse.rgb.data[i], Vec3::ZERO, "{i}");
                continue;
            }
            // Straight colours: no black from the background pulled in at the outline.
            let (a, b) = (coarse.rgb.data[i] / m, full.rgb.data[i] / m);
            assert!(a.is_finite() && (a.x + a.y) > 0.9, "{i}: {a}");
            let e = (a - b).abs().max_element();
            // The worst is taken where the person covers the pixel at least half: a pixel of the soft outline
            // mixes a coarse cell's two rows of opposite stripes into a different share of its tiny coverage.
            (sum, n) = (sum + e, n + 1);
            if m >= 0.5 {
                worst = worst.max(e);
            }
        }
        assert!(sum / (n as f32) < 0.01, "mean {}", sum / n as f32);
        // Stripes of 2 px are at the coarse grid's Nyquist limit (each cell row one stripe): near the outline, where
        // the blur sees stripes on one side only, the two grids read them at different phases (0.107 here).
        assert!(worst < 0.15, "worst {worst}");
        // Well inside: the stripes' mean.
        let centre = coarse.rgb.data[128 * res + 128];
        assert!((centre - Vec3::new(0.5, 0.5, 0.0)).abs().max_element() < 0.02, "{centre}");
        // Too small for the grid: the full blur.
        let tiny = Image::new(6, 6, Vec3::X);
        let ones = Image::new(6, 6, 1.0);
        assert_eq!(SideImages::with_back_side(&tiny, None, &ones, 2), SideImages::of(&tiny, None, &ones));
    }

    #[test]
    fn a_coarser_grid_keeps_a_flat_colour() {
        // A flat mid colour over a whole frame whose sides are not multiples of the cell (partial cells at the right
        // and bottom edges): every coarser grid gives the colour back, as the full blur does.
        let colour = Vec3::new(0.8, 0.45, 0.2);
        let (w, h) = (67, 50);
        let rgb = Image::new(w, h, colour);
        let mask = Image::new(w, h, 1.0);
        for factor in [1, 2, 3, 4] {
            let side = SideImages::with_back_side(&rgb, None, &mask, factor);
            for (i, c) in side.rgb.data.iter().enumerate() {
                assert!((*c - colour).abs().max_element() < 1e-4, "factor {factor}, pixel {i}: {c}");
            }
        }
    }

    #[test]
    fn a_straight_layer_masked_is_its_premultiplied_side_image() {
        // A uniform straight colour everywhere: its side image is the colour; masked, the colour times the mask.
        let colour = Image::new(32, 32, Vec3::new(0.2, 0.4, 0.6));
        let side = SideImages::of_straight(&colour);
        assert!(side.data.iter().all(|c| (*c - Vec3::new(0.2, 0.4, 0.6)).abs().max_element() < 1e-5));
        let mask = Image::from_fn(32, 32, |c, _| match c {
            0..=9 => 0.0,
            10 => 0.25,
            11 => f32::NAN,
            _ => 1.0,
        });
        let masked = premultiplied(&side, &mask);
        assert_eq!(masked.data[5], Vec3::ZERO);
        assert!((masked.data[10] - Vec3::new(0.05, 0.1, 0.15)).abs().max_element() < 1e-5);
        assert_eq!(masked.data[11], Vec3::ZERO);
        assert!((masked.data[20] - Vec3::new(0.2, 0.4, 0.6)).abs().max_element() < 1e-5);
        // A mask of another size leaves it as it is.
        assert_eq!(premultiplied(&side, &Image::new(4, 4, 1.0)), side);
    }

    #[test]
    fn side_images_are_three_box_passes() {
        // A step from white to black at column 64 of a 128-wide image (sigma 1 px: `image`'s fast_blur makes three
        // boxes of 3): the kernel [1, 3, 6, 7, 6, 3, 1] / 27, so columns 60..67 are 27, 26, 23, 17, 10, 4, 1, 0 / 27.
        // train/tests/test_train.py test_side_image_is_three_box_passes_inside_the_mask checks the training
        // code's copy against the same numbers.
        let (w, h) = (128, 8);
        let rgb = Image::from_fn(w, h, |c, _| if c < 64 { Vec3::ONE } else { Vec3::ZERO });
        let side = SideImages::of(&rgb, None, &Image::new(w, h, 1.0));
        for (k, want) in [27.0f32, 26.0, 23.0, 17.0, 10.0, 4.0, 1.0, 0.0].iter().enumerate() {
            for r in 0..h {
                let got = side.rgb.data[r * w + 60 + k];
                assert!((got - Vec3::splat(want / 27.0)).abs().max_element() < 1e-5, "{k} {r}: {got}");
            }
        }
    }

    #[test]
    fn surfaces_seen_edge_on_take_the_side_images() {
        // A sphere whose photo has horizontal stripes, seen from the side (yaw 90): the pixels near the sphere's
        // outline in the photo (the surface the photo sees edge-on) are striped without the side images and take
        // the blurred stripes with them; the surface facing the target camera head-on keeps the photo's.
        let res = 256;
        let mesh = TriMesh::uv_sphere(Vec3::ZERO, 0.7, 48, 96);
        let cam = Camera::source(res);
        let g = rasterize(&mesh, &cam);
        let mask = g.mask_image();
        let stripes = Image::from_fn(res, res, |c, r| {
            let colour = if (r / 3) % 2 == 0 { Vec3::new(0.9, 0.2, 0.2) } else { Vec3::new(0.2, 0.2, 0.9) };
            colour * mask.data[r * res + c]
        });
        let side = SideImages::of(&stripes, None, &mask);
        let with = SourceColours { rgb: &stripes, back: None, side: Some(&side) };
        let tgt = Camera::orbit(90.0, 0.0, res, res);
        let gt = rasterize(&mesh, &tgt);
        let sharp = render_geometric(&stripes, &mask, &g, &cam, &gt, &tgt, OcclusionFill::MirroredFront);
        let soft = render_geometric(with, &mask, &g, &cam, &gt, &tgt, OcclusionFill::MirroredFront);
        let axis = source_axis(&tgt, &cam);
        let (mut edge_on, mut sharp_step, mut soft_step) = (0, 0.0f32, 0.0f32);
        for r in 40..res - 41 {
            for c in 0..res {
                let (i, j) = (r * res + c, (r + 1) * res + c);
                if !(gt.mask[i] && gt.mask[j]) {
                    continue;
                }
                let w = side_weight(gt.normal[i], axis);
                if w >= 0.99 {
                    edge_on += 1;
                    sharp_step += (sharp.data[i] - sharp.data[j]).truncate().abs().max_element();
                    soft_step += (soft.data[i] - soft.data[j]).truncate().abs().max_element();
                } else if w == 0.0 {
                    assert_eq!(sharp.data[i], soft.data[i], "{c},{r}");
                }
            }
        }
        assert!(edge_on > 200, "{edge_on}");
        assert!(soft_step < 0.5 * sharp_step, "{soft_step} {sharp_step}");
        // The photo's own view keeps the sharp photo everywhere, the sphere's rim included.
        let own = render_geometric(with, &mask, &g, &cam, &g, &cam, OcclusionFill::MirroredFront);
        assert_eq!(own, render_geometric(&stripes, &mask, &g, &cam, &g, &cam, OcclusionFill::MirroredFront));
    }

    #[test]
    fn the_back_fill_samples_the_back_image_behind_and_the_photo_in_front() {
        let (rgb, mask, g, cam, mesh) = gradient_source(64);
        let back_rgb = mask.map(|&m| Vec3::new(0.0, 0.0, 1.0) * m);
        let colours = SourceColours { rgb: &rgb, back: Some(&back_rgb), side: None };
        // The identity view is all visible: the photo.
        let out = render_geometric(colours, &mask, &g, &cam, &g, &cam, OcclusionFill::Back);
        for i in 0..64 * 64 {
            assert!((out.data[i] - rgb.data[i].extend(mask.data[i])).abs().max_element() < 1e-5);
        }
        // From behind: the back image (pure blue) where the sphere faces away from the source, blends only on the
        // rim.
        let tgt = Camera::orbit(180.0, 0.0, 64, 64);
        let gt = rasterize(&mesh, &tgt);
        let out = render_geometric(colours, &mask, &g, &cam, &gt, &tgt, OcclusionFill::Back);
        for row in 20..44 {
            for col in 20..44 {
                let o = out.data[row * 64 + col];
                assert!((o - Vec4::new(0.0, 0.0, 1.0, 1.0)).abs().max_element() < 1e-5, "{col},{row}: {o}");
            }
        }
        // Without a back image, or with another fill, the back image is not used.
        let mirrored = render_geometric(&rgb, &mask, &g, &cam, &gt, &tgt, OcclusionFill::MirroredFront);
        assert_eq!(render_geometric(&rgb, &mask, &g, &cam, &gt, &tgt, OcclusionFill::Back).data, mirrored.data);
        assert_eq!(
            render_geometric(colours, &mask, &g, &cam, &gt, &tgt, OcclusionFill::MirroredFront).data,
            mirrored.data
        );
        // A back image of another size is ignored.
        let small = Image::new(8, 8, Vec3::ONE);
        let odd = SourceColours { rgb: &rgb, back: Some(&small), side: None };
        assert_eq!(render_geometric(odd, &mask, &g, &cam, &gt, &tgt, OcclusionFill::Back).data, mirrored.data);
    }

    /// The whole-frame push-pull the cropped [`push_pull`] must match exactly.
    /// Multi-scale push-pull hole filling: known pixels keep their colour, holes get the coverage-weighted average of
    /// progressively coarser levels, upsampled bilinearly (smooth, no block artefacts). Every pixel ends with a
    /// colour as soon as one pixel is known.
    /// `needed` limits the finest level to the pixels whose colour is used (the target mask).
    fn push_pull_reference(color: &mut [Vec3], known: &[bool], needed: Option<&[bool]>, w: usize, h: usize) {
        // Level 0: premultiplied colour and weight.
        let mut levels: Vec<(usize, usize, Vec<Vec4>)> = Vec::new();
        let base: Vec<Vec4> =
            color.iter().zip(known).map(|(c, &k)| if k { c.extend(1.0) } else { Vec4::ZERO }).collect();
        levels.push((w, h, base));
        // Pull: halve until 1x1, weights capped at 1 (a fully covered coarse pixel is as certain as a known one).
        loop {
            let (lw, lh, prev) = &levels[levels.len() - 1];
            let (lw, lh) = (*lw, *lh);
            if lw <= 1 && lh <= 1 {
                break;
            }
            let (nw, nh) = (lw.div_ceil(2), lh.div_ceil(2));
            let mut next = vec![Vec4::ZERO; nw * nh];
            next.par_chunks_mut(nw).enumerate().for_each(|(r, row)| {
                for (c, px) in row.iter_mut().enumerate() {
                    let mut s = Vec4::ZERO;
                    for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (cc, rr) = (2 * c + dc, 2 * r + dr);
                        if cc < lw && rr < lh {
                            s += prev[rr * lw + cc];
                        }
                    }
                    *px = if s.w > 0.0 { (s.truncate() / s.w * s.w.min(1.0)).extend(s.w.min(1.0)) } else { Vec4::ZERO };
                }
            });
            levels.push((nw, nh, next));
        }
        // Push: from coarse to fine, holes (weight < 1) are completed by the upsampled coarser level.
        for k in (0..levels.len() - 1).rev() {
            let (finer, coarser) = levels.split_at_mut(k + 1);
            let (cw, ch, coarse) = (&coarser[0].0, &coarser[0].1, &coarser[0].2);
            let (cw, ch) = (*cw, *ch);
            let (fw, fine) = (finer[k].0, &mut finer[k].2);
            let finest = k == 0;
            fine.par_chunks_mut(fw).enumerate().for_each(|(r, row)| {
                for (c, px) in row.iter_mut().enumerate() {
                    if px.w >= 1.0 || (finest && needed.is_some_and(|m| !m[r * fw + c])) {
                        continue;
                    }
                    // Fine pixel centre in coarse pixel coordinates.
                    let up = bilinear4(coarse, cw, ch, (c as f32 + 0.5) * 0.5, (r as f32 + 0.5) * 0.5);
                    let up_rgb = if up.w > 0.0 { up.truncate() / up.w } else { Vec3::ZERO };
                    let own = px.truncate(); // premultiplied by px.w
                    *px = (own + up_rgb * (1.0 - px.w)).extend(1.0);
                }
            });
        }
        for ((c, &k), l) in color.iter_mut().zip(known).zip(&levels[0].2) {
            if !k {
                *c = l.truncate();
            }
        }
    }

    #[test]
    fn cropped_push_pull_equals_the_whole_frame_pyramid() {
        // Irregular blobs of known pixels inside a mask that is not the whole frame, odd sizes, and the mask
        // touching the border: every needed pixel must be bit-identical to the whole-frame pyramid.
        for (w, h, seed) in [(37usize, 23usize, 1u32), (64, 64, 2), (101, 57, 3), (5, 1, 4), (1, 9, 5)] {
            let mut rng = seed.wrapping_mul(2654435761);
            let mut next = || {
                rng ^= rng << 13;
                rng ^= rng >> 17;
                rng ^= rng << 5;
                rng
            };
            let (mut color, mut known, mut mask) = (vec![Vec3::ZERO; w * h], vec![false; w * h], vec![false; w * h]);
            let (cx, cy) = (w as f32 * 0.6, h as f32 * 0.4);
            for r in 0..h {
                for c in 0..w {
                    let i = r * w + c;
                    let d = ((c as f32 - cx) / w as f32).hypot((r as f32 - cy) / h as f32);
                    mask[i] = d < 0.35 || c == w - 1;
                    if mask[i] && next() % 3 == 0 {
                        known[i] = true;
                        color[i] =
                            Vec3::new((next() % 256) as f32, (next() % 256) as f32, (next() % 256) as f32) / 255.0;
                    }
                }
            }
            if !known.iter().any(|&k| k) {
                known[w * h - 1] = true;
                color[w * h - 1] = Vec3::ONE;
            }
            let mut a = color.clone();
            push_pull(&mut a, &known, Some(&mask), w, h);
            let mut b = color.clone();
            push_pull_reference(&mut b, &known, Some(&mask), w, h);
            for i in 0..w * h {
                if mask[i] {
                    assert_eq!(a[i], b[i], "{w}x{h} pixel {i}");
                }
            }
            let mut a = color.clone();
            push_pull(&mut a, &known, None, w, h);
            let mut b = color;
            push_pull_reference(&mut b, &known, None, w, h);
            assert_eq!(a, b, "{w}x{h} without a mask");
        }
    }

    #[test]
    fn push_pull_keeps_known_pixels_and_fills_holes_smoothly() {
        let (w, h) = (33, 17);
        let mut color = vec![Vec3::ZERO; w * h];
        let mut known = vec![false; w * h];
        // Left column red, right column blue.
        for r in 0..h {
            color[r * w] = Vec3::X;
            known[r * w] = true;
            color[r * w + w - 1] = Vec3::Z;
            known[r * w + w - 1] = true;
        }
        push_pull(&mut color, &known, None, w, h);
        assert_eq!(color[0], Vec3::X);
        assert_eq!(color[w - 1], Vec3::Z);
        let mid = color[8 * w + 16];
        assert!(mid.is_finite() && (mid.x + mid.z - 1.0).abs() < 0.05, "{mid}");
        // Closer to the red side is redder.
        assert!(color[8 * w + 3].x > color[8 * w + 29].x);
    }

    #[test]
    fn warp_features_samples_bilinearly_with_zero_outside() {
        // A 2-channel 4x4 map at 1/4 of a 16-pixel source; flow at chosen points.
        let (fw, fh) = (4, 4);
        let mut feat = vec![0.0f32; 2 * 16];
        for r in 0..4 {
            for c in 0..4 {
                feat[r * 4 + c] = c as f32; // channel 0: column index
                feat[16 + r * 4 + c] = 10.0 * r as f32; // channel 1: 10 * row
            }
        }
        let mut fz =
            FlowZ { flow: Image::new(3, 1, Vec2::ZERO), z: Image::new(3, 1, 0.0), mask: vec![true, true, false] };
        // Source pixel (6, 10) -> feature (1.5, 2.5): exactly the centre of feature pixel (1, 2).
        fz.flow.data[0] = Vec2::new(6.0, 10.0);
        // Source (8, 8) -> feature (2, 2): halfway between columns 1 and 2, rows 1 and 2.
        fz.flow.data[1] = Vec2::new(8.0, 8.0);
        fz.flow.data[2] = Vec2::new(6.0, 10.0); // masked out
        let mut out = vec![9.0f32; 2 * 3];
        warp_features(&feat, 2, fw, fh, &fz, 16, &mut out);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[3] - 20.0).abs() < 1e-6);
        assert!((out[1] - 1.5).abs() < 1e-6 && (out[4] - 15.0).abs() < 1e-6);
        assert_eq!((out[2], out[5]), (0.0, 0.0));
        // Outside the map: the edge tap is weighted by its bilinear weight, the outside one reads zero.
        fz.flow.data[0] = Vec2::new(0.0, 2.0); // feature (0, 0.5): half of column 0 (value 0) ...
        fz.flow.data[1] = Vec2::new(16.0, 2.0); // feature (4, 0.5): half of column 3 (value 3) -> 1.5
        warp_features(&feat, 2, fw, fh, &fz, 16, &mut out);
        assert!((out[1] - 1.5).abs() < 1e-6, "{}", out[1]);
        fz.flow.data[0] = Vec2::new(-100.0, 2.0);
        warp_features(&feat, 2, fw, fh, &fz, 16, &mut out);
        assert_eq!(out[0], 0.0);
    }
}
