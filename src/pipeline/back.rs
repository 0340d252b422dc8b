//! The back image: what the surfaces the photo does not show are coloured from ([`super::warp::OcclusionFill::Back`]).
//!
//! Computed once per input in the normalised source frame (same size and mask as the photo, premultiplied the
//! same way), so every renderer samples it exactly as it samples the photo, at the same flow:
//! - **Clothing without front-only details**: a mode filter of the photo over a window of [`CLOTHING_RADIUS`] face
//!   units (a face unit `d` is the eye-to-mouth distance, the one size every pose read of a face gives): the
//!   person's colours are reduced to a palette of [`PALETTE_SIZE`] colours (k-means), each place takes the most
//!   common palette colour of its window (the mean of the window's pixels of that colour), computed on a grid
//!   [`WORK_FACTOR`] times coarser than the source and upsampled bilinearly. Like a median it keeps the boundaries
//!   between large regions (jacket and trousers, sleeve and hand) sharp and removes what covers less of the window
//!   than the colour around it: ties, buttons, ribbons, logos, glasses; unlike a per-channel median it never
//!   invents a colour (a median of blue and white stripes mixes channels into pink), and unlike a blur it leaves
//!   flat regions with sharp edges (stripes come out as stripes, not in their phase).
//! - **The head in the head top's colour**: an ellipse around the face (along the eyes-minus-mouth axis, so a
//!   tilted head is covered) gets the dominant colour of the person above the hairline (hair, a hat, a bald head's
//!   skin, whatever the photo shows there), feathered at its border; weighted by how frontal the face is (ear
//!   distance over `d`), because a profile's hidden side is the other profile, which the photo itself already
//!   gives. When nothing of the person lies above the face (the photo cuts the head), the head's sides are used,
//!   then the head region itself.
//!
//! Where the face is comes from the pose network's face landmarks ([`FacePoints::from_pose`]); without them there
//! is no back image and the renderers use the photo ([`super::warp::OcclusionFill::MirroredFront`]'s lookup, one
//! warning; [`super::PreparedInput::prepare`]).

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::body::pose::PoseLandmarks;
use crate::buffer::{GrayImage, Image, RgbImage};

/// Mode-filter window radius for the clothing, in face units (eye-to-mouth distances).
pub const CLOTHING_RADIUS: f32 = 2.0;
/// The mode filter runs on a grid this many times coarser than a 512² source (scaled with the resolution).
pub const WORK_FACTOR: usize = 4;
/// Largest mode-filter window radius on the working grid (cells); caps the cost on face-filling photos.
pub const MAX_WORK_RADIUS: usize = 10;
/// Half-axes of the head ellipse in face units: along the face's up axis and across it.
pub const HEAD_AXES: Vec2 = Vec2::new(1.8, 2.4);
/// Centre of the head ellipse above the eyes, in face units.
pub const HEAD_CENTRE_UP: f32 = 0.3;
/// Fraction of the ellipse's radius over which the head colour fades into the clothing.
pub const HEAD_FEATHER: f32 = 0.2;
/// The band the head top's colour is read in: from this many face units above the eyes (the hairline) ...
pub const TOP_BAND_FROM: f32 = 1.1;
/// ... to this many, and at most [`TOP_BAND_HALF_WIDTH`] face units to either side of the face's axis.
pub const TOP_BAND_TO: f32 = 2.6;
/// Half-width of the head-top band, face units.
pub const TOP_BAND_HALF_WIDTH: f32 = 1.5;
/// Fewest person pixels a colour band needs before its dominant colour is trusted.
pub const MIN_BAND_PIXELS: usize = 12;
/// Ear distance over `d` of a profile (frontality 0) and of a frontal face (frontality 1).
pub const FRONTALITY_RANGE: (f32, f32) = (0.6, 1.4);
/// Smallest face unit (source pixels) accepted: below it the landmarks say nothing usable about the face.
pub const MIN_FACE_UNIT: f32 = 1.5;

/// The face as the back image needs it, in source pixels (continuous coordinates, centres at +0.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FacePoints {
    /// Midpoint of the two eyes.
    pub eyes: Vec2,
    /// Midpoint of the mouth's corners.
    pub mouth: Vec2,
    /// The two ears (left, right).
    pub ears: [Vec2; 2],
}

/// The face's frame derived from [`FacePoints`]: unit axes and the face unit.
#[derive(Clone, Copy, Debug, PartialEq)]
struct FaceFrame {
    eyes: Vec2,
    /// Unit vector from the mouth toward the eyes (image "up" of the face).
    up: Vec2,
    /// Unit vector across the face.
    across: Vec2,
    /// Eye-to-mouth distance (source pixels).
    d: f32,
    /// 0 for a profile, 1 for a frontal face.
    frontality: f32,
}

impl FacePoints {
    /// The face points of pose landmarks already in the source frame (see
    /// [`crate::body::pose::PoseLandmarks::transformed`]); `None` when any of them is not finite.
    pub fn from_pose(p: &PoseLandmarks) -> Option<Self> {
        let at = |i: usize| p.landmarks.get(i).map(|l| l.pixel).filter(|v| v.is_finite());
        // MediaPipe: 2 left eye, 5 right eye, 7/8 ears, 9/10 mouth corners.
        let face = Self { eyes: (at(2)? + at(5)?) * 0.5, mouth: (at(9)? + at(10)?) * 0.5, ears: [at(7)?, at(8)?] };
        Some(face)
    }

    fn frame(&self) -> Option<FaceFrame> {
        let v = self.eyes - self.mouth;
        let d = v.length();
        if !(d.is_finite() && d >= MIN_FACE_UNIT && self.ears.iter().all(|e| e.is_finite())) {
            return None;
        }
        let up = v / d;
        let ear = (self.ears[0] - self.ears[1]).length() / d;
        let (lo, hi) = FRONTALITY_RANGE;
        let frontality = ((ear - lo) / (hi - lo)).clamp(0.0, 1.0);
        Some(FaceFrame { eyes: self.eyes, up, across: Vec2::new(-up.y, up.x), d, frontality })
    }
}

impl FaceFrame {
    /// `p` in face units: (across, up) relative to the eyes.
    fn local(&self, p: Vec2) -> Vec2 {
        let q = p - self.eyes;
        Vec2::new(q.dot(self.across), q.dot(self.up)) / self.d
    }

    /// Weight of the head colour at `p`: 1 inside the head ellipse, fading to 0 over its border.
    fn head_weight(&self, p: Vec2) -> f32 {
        let l = self.local(p) - Vec2::new(0.0, HEAD_CENTRE_UP);
        let r = (l / HEAD_AXES).length();
        let t = ((1.0 - r) / HEAD_FEATHER).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }
}

/// A person's back image and where it drew the head: what [`back_image`] returns and an input keeps
/// ([`super::PreparedInput::back`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BackImage {
    /// The colours: linear, premultiplied by the photo's mask, the photo's size.
    pub rgb: RgbImage,
    /// Per source pixel, how much of the colour is the head top's (the feathered head ellipse times the face's
    /// frontality; 0 everywhere when no head colour was found, and outside the mask): where the back image knows
    /// what the back of the head looks like, which the neural renderer keeps ([`super::lookup_kept`]).
    pub head: GrayImage,
}

/// The back image of a person (see the module docs): `rgb` linear premultiplied by `mask`, `face` where the face
/// is. Same size as `rgb`, premultiplied by the same mask, with its head weights ([`BackImage::head`]). `None` when
/// the face points are unusable (degenerate or not finite) or the sizes disagree; every colour is finite and in
/// `[0, 1]`. [`back_layers`] masked by `mask`.
pub fn back_image(rgb: &RgbImage, mask: &GrayImage, face: &FacePoints) -> Option<BackImage> {
    back_layers(rgb, mask, face)?.masked(mask)
}

/// A back image before a mask multiplies it: its straight colour and head weight at every pixel of the grid, the
/// person's and beyond (the clothing layer carried past the outline from the nearest cells). A live source keeps
/// them between frames and masks them with each frame's own silhouette ([`super::frame`]): the colours of clothing
/// and hair change more slowly than the outline.
#[derive(Clone, Debug, PartialEq)]
pub struct BackLayers {
    /// Straight linear colour, finite and in `[0, 1]`.
    pub colour: RgbImage,
    /// How much of `colour` is the head top's, before the mask ([`BackImage::head`]).
    pub head: GrayImage,
}

impl BackLayers {
    /// The back image of a person with silhouette `mask`: the colour premultiplied by it, the head weight where it
    /// is above 0; `None` for a mask of another size.
    pub fn masked(&self, mask: &GrayImage) -> Option<BackImage> {
        let (w, h) = (self.colour.width, self.colour.height);
        if (mask.width, mask.height) != (w, h) || mask.data.len() != self.colour.data.len() {
            return None;
        }
        let rgb = super::warp::premultiplied(&self.colour, mask);
        // NaN fails the comparison: outside.
        let head = self.head.data.iter().zip(&mask.data).map(|(&hw, &m)| if m > 0.0 { hw } else { 0.0 });
        Some(BackImage { rgb, head: GrayImage { width: w, height: h, data: head.collect() } })
    }
}

/// The layers of [`back_image`] (see there for `None`).
pub fn back_layers(rgb: &RgbImage, mask: &GrayImage, face: &FacePoints) -> Option<BackLayers> {
    let (w, h) = (rgb.width, rgb.height);
    if (mask.width, mask.height) != (w, h) || w == 0 || h == 0 {
        return None;
    }
    let frame = face.frame()?;
    let straight = |i: usize| -> Option<Vec3> {
        let m = mask.data[i];
        (m >= 0.5).then(|| (rgb.data[i] / m).clamp(Vec3::ZERO, Vec3::ONE)).filter(|c| c.is_finite())
    };
    let clothing = clothing(rgb, mask, frame.d);
    let head = head_colour(w, h, &straight, &frame);
    let mut colour = Image::new(w, h, Vec3::ZERO);
    let mut weights = Image::new(w, h, 0.0f32);
    colour.data.par_chunks_mut(w).zip(weights.data.par_chunks_mut(w)).enumerate().for_each(|(row, (line, hws))| {
        for (col, (o, hw_out)) in line.iter_mut().zip(hws.iter_mut()).enumerate() {
            let p = Vec2::new(col as f32 + 0.5, row as f32 + 0.5);
            let hw = match head {
                Some(_) => frame.head_weight(p) * frame.frontality,
                None => 0.0,
            };
            let c = clothing.data[row * w + col] * (1.0 - hw) + head.unwrap_or(Vec3::ZERO) * hw;
            *o = if c.is_finite() { c.clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
            *hw_out = hw;
        }
    });
    Some(BackLayers { colour, head: weights })
}

/// Colours in the clothing's palette (`palette`).
pub const PALETTE_SIZE: usize = 8;
/// k-means iterations of the palette.
pub const PALETTE_ITERATIONS: usize = 8;

/// Index of the palette colour nearest `c` (in the palette's square-root space).
fn nearest(palette: &[Vec3], c: Vec3) -> u8 {
    let q = c.max(Vec3::ZERO).powf(0.5);
    let mut best = (0u8, f32::INFINITY);
    for (i, p) in palette.iter().enumerate() {
        let e = (*p - q).length_squared();
        if e < best.1 {
            best = (i as u8, e);
        }
    }
    best.0
}

/// At most `k` representative colours of `colours` (linear RGB) by k-means in a square-root space (closer to how
/// different colours look than linear RGB), started from farthest points (deterministic). Returned in that space
/// (see [`nearest`]). Empty for no colours.
fn palette(colours: &[Vec3], k: usize, iterations: usize) -> Vec<Vec3> {
    let q: Vec<Vec3> = colours.iter().map(|c| c.max(Vec3::ZERO).powf(0.5)).collect();
    let Some(first) = q.first() else { return Vec::new() };
    let mean = q.iter().copied().sum::<Vec3>() / q.len() as f32;
    let start = q.iter().copied().min_by(|a, b| (*a - mean).length_squared().total_cmp(&(*b - mean).length_squared()));
    let mut centres = vec![start.unwrap_or(*first)];
    let mut dist: Vec<f32> = q.iter().map(|c| (*c - centres[0]).length_squared()).collect();
    while centres.len() < k {
        let Some((i, &far)) = dist.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else { break };
        if far <= 1e-6 {
            break;
        }
        centres.push(q[i]);
        for (d, c) in dist.iter_mut().zip(&q) {
            *d = d.min((*c - q[i]).length_squared());
        }
    }
    for _ in 0..iterations {
        let mut acc = vec![(Vec3::ZERO, 0u32); centres.len()];
        for c in &q {
            let l = centres
                .iter()
                .enumerate()
                .min_by(|a, b| (*a.1 - *c).length_squared().total_cmp(&(*b.1 - *c).length_squared()))
                .map_or(0, |(i, _)| i);
            acc[l].0 += *c;
            acc[l].1 += 1;
        }
        for (centre, (sum, n)) in centres.iter_mut().zip(acc) {
            if n > 0 {
                *centre = sum / n as f32;
            }
        }
    }
    centres
}

/// Colours in the head top's palette (`dominant_colour`).
pub const HEAD_PALETTE_SIZE: usize = 4;

/// The mean of the largest of [`HEAD_PALETTE_SIZE`] colour clusters of `pixels` (straight linear colours): a
/// hat's badge or a hair clip is a smaller cluster than the hat or the hair. `None` below [`MIN_BAND_PIXELS`].
fn dominant_colour(pixels: &[Vec3]) -> Option<Vec3> {
    if pixels.len() < MIN_BAND_PIXELS {
        return None;
    }
    let palette = palette(pixels, HEAD_PALETTE_SIZE, PALETTE_ITERATIONS);
    let mut acc = vec![(Vec3::ZERO, 0usize); palette.len()];
    for &c in pixels {
        let l = nearest(&palette, c) as usize;
        acc[l].0 += c;
        acc[l].1 += 1;
    }
    let (sum, n) = acc.into_iter().max_by_key(|a| a.1)?;
    (n > 0).then(|| sum / n as f32)
}

/// The head top's colour (module docs): the band above the hairline, else the head's sides, else the head.
fn head_colour(w: usize, h: usize, straight: &dyn Fn(usize) -> Option<Vec3>, f: &FaceFrame) -> Option<Vec3> {
    let bands: [&dyn Fn(Vec2) -> bool; 3] = [
        &|l| l.x.abs() <= TOP_BAND_HALF_WIDTH && (TOP_BAND_FROM..=TOP_BAND_TO).contains(&l.y),
        &|l| (1.1..=HEAD_AXES.x).contains(&l.x.abs()) && (-0.5..=TOP_BAND_FROM).contains(&l.y),
        &|l| ((l - Vec2::new(0.0, HEAD_CENTRE_UP)) / HEAD_AXES).length() <= 1.0,
    ];
    // Only the box that can hold the head is scanned.
    let reach = f.d * (HEAD_AXES.max_element() + TOP_BAND_TO + 1.0);
    let (c0, c1) = ((f.eyes.x - reach).max(0.0) as usize, ((f.eyes.x + reach).max(0.0) as usize).min(w));
    let (r0, r1) = ((f.eyes.y - reach).max(0.0) as usize, ((f.eyes.y + reach).max(0.0) as usize).min(h));
    bands.iter().find_map(|inside| {
        let mut px = Vec::new();
        for r in r0..r1 {
            for c in c0..c1 {
                let l = f.local(Vec2::new(c as f32 + 0.5, r as f32 + 0.5));
                if inside(l) {
                    px.extend(straight(r * w + c));
                }
            }
        }
        dominant_colour(&px)
    })
}

/// The clothing layer (module docs): straight colour at every source pixel (past the person's outline, the nearest
/// cells' colours).
fn clothing(rgb: &RgbImage, mask: &GrayImage, d: f32) -> RgbImage {
    let (w, h) = (rgb.width, rgb.height);
    let factor = (WORK_FACTOR * w.max(h)).div_ceil(512).max(1);
    let (gw, gh) = (w.div_ceil(factor), h.div_ceil(factor));
    // Working grid: mean straight colour of each block's person pixels, known where half the block is person.
    let cells: Vec<(Vec3, bool)> = (0..gw * gh)
        .into_par_iter()
        .map(|k| {
            let (gc, gr) = (k % gw, k / gw);
            let (mut sum, mut wsum, mut n) = (Vec3::ZERO, 0.0f32, 0usize);
            for r in gr * factor..((gr + 1) * factor).min(h) {
                for c in gc * factor..((gc + 1) * factor).min(w) {
                    let i = r * w + c;
                    let m = mask.data[i].clamp(0.0, 1.0);
                    sum += rgb.data[i];
                    wsum += m;
                    n += 1;
                }
            }
            let known = n > 0 && wsum >= 0.5 * n as f32;
            let c = if known { (sum / wsum).clamp(Vec3::ZERO, Vec3::ONE) } else { Vec3::ZERO };
            (c, known && c.is_finite())
        })
        .collect();
    let radius = ((CLOTHING_RADIUS * d / factor as f32).round() as usize).clamp(1, MAX_WORK_RADIUS);
    let known_colours: Vec<Vec3> = cells.iter().filter(|c| c.1).map(|c| c.0).collect();
    let palette = palette(&known_colours, PALETTE_SIZE, PALETTE_ITERATIONS);
    let labels: Vec<u8> =
        cells.par_iter().map(|&(c, known)| if known { nearest(&palette, c) } else { u8::MAX }).collect();
    let mut filtered: Vec<Vec3> = (0..gw * gh)
        .into_par_iter()
        .map(|k| {
            let (gc, gr) = (k % gw, k / gw);
            if !cells[k].1 {
                return Vec3::ZERO;
            }
            // The window's most common palette colour wins; the cell takes the mean of the window's cells of it.
            let mut count = [0u32; PALETTE_SIZE];
            let mut sum = [Vec3::ZERO; PALETTE_SIZE];
            for r in gr.saturating_sub(radius)..(gr + radius + 1).min(gh) {
                for c in gc.saturating_sub(radius)..(gc + radius + 1).min(gw) {
                    let j = r * gw + c;
                    if let Some(l) = Some(labels[j] as usize).filter(|&l| l < PALETTE_SIZE) {
                        count[l] += 1;
                        sum[l] += cells[j].0;
                    }
                }
            }
            // Ties go to the cell's own colour, then to the lower index (deterministic).
            let own = labels[k] as usize;
            let best = (0..PALETTE_SIZE).fold(own, |b, l| if count[l] > count[b] { l } else { b });
            sum[best] / count[best].max(1) as f32
        })
        .collect();
    let known: Vec<bool> = cells.iter().map(|c| c.1).collect();
    if known.iter().any(|&k| k) {
        // Cells without enough person (the silhouette's edge) take their neighbours' colours.
        super::warp::push_pull(&mut filtered, &known, None, gw, gh);
    }
    // Bilinear upsampling to the source grid (cell centres at (k + 0.5) * factor).
    let grid =
        |c: isize, r: isize| filtered[r.clamp(0, gh as isize - 1) as usize * gw + c.clamp(0, gw as isize - 1) as usize];
    let mut out = Image::new(w, h, Vec3::ZERO);
    out.data.par_chunks_mut(w).enumerate().for_each(|(row, line)| {
        let y = (row as f32 + 0.5) / factor as f32 - 0.5;
        let (y0, ty) = (y.floor(), y - y.floor());
        for (col, o) in line.iter_mut().enumerate() {
            let x = (col as f32 + 0.5) / factor as f32 - 0.5;
            let (x0, tx) = (x.floor(), x - x.floor());
            let (xi, yi) = (x0 as isize, y0 as isize);
            let top = grid(xi, yi) * (1.0 - tx) + grid(xi + 1, yi) * tx;
            let bottom = grid(xi, yi + 1) * (1.0 - tx) + grid(xi + 1, yi + 1) * tx;
            *o = top * (1.0 - ty) + bottom * ty;
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 128² person: a blue body rectangle, a skin face disc with dark "eyes", a brown hair cap above it, and a
    /// thin white "tie" down the body. Face unit d = 8 px.
    fn person() -> (RgbImage, GrayImage, FacePoints) {
        let n = 128;
        let (blue, skin, hair, white, dark) = (
            Vec3::new(0.05, 0.1, 0.6),
            Vec3::new(0.8, 0.55, 0.45),
            Vec3::new(0.3, 0.15, 0.05),
            Vec3::ONE,
            Vec3::splat(0.02),
        );
        let face_c = Vec2::new(64.0, 34.0);
        let mask = Image::from_fn(n, n, |c, r| {
            let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
            let head = (p - Vec2::new(64.0, 30.0)).length() < 16.0;
            let body = (40..88).contains(&c) && (46..128).contains(&r);
            if head || body {
                1.0
            } else {
                0.0
            }
        });
        let rgb = Image::from_fn(n, n, |c, r| {
            let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
            if mask.get(c, r) <= &0.0 {
                return Vec3::ZERO;
            }
            if r >= 46 {
                return if (62..66).contains(&c) { white } else { blue };
            }
            if (p - face_c).length() < 9.0 {
                let eye = (p - Vec2::new(60.0, 32.0)).length() < 2.0 || (p - Vec2::new(68.0, 32.0)).length() < 2.0;
                return if eye { dark } else { skin };
            }
            hair
        });
        let face = FacePoints {
            eyes: Vec2::new(64.0, 32.0),
            mouth: Vec2::new(64.0, 40.0),
            ears: [Vec2::new(75.0, 33.0), Vec2::new(53.0, 33.0)],
        };
        (rgb, mask, face)
    }

    #[test]
    fn the_face_becomes_the_head_tops_colour_and_the_tie_the_clothing() {
        let (rgb, mask, face) = person();
        let BackImage { rgb: back, head } = back_image(&rgb, &mask, &face).unwrap();
        let at = |c: usize, r: usize| back.data[r * 128 + c];
        let hair = Vec3::new(0.3, 0.15, 0.05);
        // Face centre, an eye and the mouth: hair colour (the head-top band holds only hair).
        for (c, r) in [(64, 34), (60, 32), (64, 40)] {
            assert!((at(c, r) - hair).abs().max_element() < 1e-4, "({c}, {r}): {}", at(c, r));
        }
        // The tie (4 px wide, window radius 12 px at d = 8) is gone: the body is blue on it and around it.
        let blue = Vec3::new(0.05, 0.1, 0.6);
        for (c, r) in [(63, 90), (64, 100), (50, 100), (80, 70)] {
            assert!((at(c, r) - blue).abs().max_element() < 1e-4, "({c}, {r}): {}", at(c, r));
        }
        // Where the head colour went in: the head weights say so (1 inside the ellipse, 0 on the body and outside
        // the mask).
        for (c, r) in [(64, 34), (60, 32), (64, 40)] {
            assert_eq!(head.data[r * 128 + c], 1.0, "({c}, {r})");
        }
        for (c, r) in [(63, 90), (64, 100), (50, 100), (80, 70), (0, 0)] {
            assert_eq!(head.data[r * 128 + c], 0.0, "({c}, {r})");
        }
        // Premultiplied by the same mask: zero outside, finite everywhere.
        for (b, &m) in back.data.iter().zip(&mask.data) {
            assert!(b.is_finite() && b.min_element() >= 0.0 && b.max_element() <= 1.0);
            if m == 0.0 {
                assert_eq!(*b, Vec3::ZERO);
            }
        }
    }

    #[test]
    fn a_profile_keeps_its_face_and_a_bald_head_gets_skin() {
        let (rgb, mask, mut face) = person();
        // Ears 2 px apart over d = 8: a profile, frontality 0, the head keeps the (filtered) photo.
        face.ears = [Vec2::new(65.0, 33.0), Vec2::new(63.0, 33.0)];
        let BackImage { rgb: back, head } = back_image(&rgb, &mask, &face).unwrap();
        let hair = Vec3::new(0.3, 0.15, 0.05);
        assert!((back.data[34 * 128 + 64] - hair).abs().max_element() > 0.2, "{}", back.data[34 * 128 + 64]);
        // No head colour went in anywhere: nothing for the neural renderer to keep.
        assert!(head.data.iter().all(|&w| w == 0.0));
        // A bald head: the head top is skin, so the head is skin.
        let (mut rgb, mask, face) = person();
        let skin = Vec3::new(0.8, 0.55, 0.45);
        for r in 0..46 {
            for c in 0..128 {
                if mask.data[r * 128 + c] > 0.0 {
                    rgb.data[r * 128 + c] = skin;
                }
            }
        }
        let back = back_image(&rgb, &mask, &face).unwrap().rgb;
        assert!((back.data[34 * 128 + 64] - skin).abs().max_element() < 1e-4);
    }

    #[test]
    fn a_head_cut_by_the_frame_uses_its_sides_and_degenerate_faces_give_none() {
        let (rgb, mask, face) = person();
        // Everything above the eyes removed (the photo cuts the head at the eyes): no head-top band; the
        // sides of the head (hair at |across| >= d) decide.
        let cut = Image::from_fn(128, 128, |c, r| if r < 31 { 0.0 } else { *mask.get(c, r) });
        let rgb_cut = Image::from_fn(128, 128, |c, r| if r < 31 { Vec3::ZERO } else { *rgb.get(c, r) });
        let back = back_image(&rgb_cut, &cut, &face).unwrap().rgb;
        assert!(back.data.iter().all(|c| c.is_finite()));
        let hair = Vec3::new(0.3, 0.15, 0.05);
        assert!((back.data[36 * 128 + 64] - hair).abs().max_element() < 1e-4, "{}", back.data[36 * 128 + 64]);
        // A face landmark far outside the frame: still finite, nothing panics.
        let far = FacePoints { eyes: Vec2::new(-500.0, -400.0), mouth: Vec2::new(-500.0, -390.0), ..face };
        let back = back_image(&rgb, &mask, &far).unwrap().rgb;
        assert!(back.data.iter().all(|c| c.is_finite()));
        // Degenerate: eyes on the mouth, NaN, an empty mask, mismatched sizes.
        assert!(back_image(&rgb, &mask, &FacePoints { mouth: face.eyes, ..face }).is_none());
        assert!(back_image(&rgb, &mask, &FacePoints { eyes: Vec2::NAN, ..face }).is_none());
        assert!(back_image(&rgb, &mask, &FacePoints { ears: [Vec2::NAN, Vec2::ZERO], ..face }).is_none());
        let empty = Image::new(128, 128, 0.0f32);
        let out = back_image(&Image::new(128, 128, Vec3::ZERO), &empty, &face).unwrap().rgb;
        assert!(out.data.iter().all(|c| *c == Vec3::ZERO));
        assert!(back_image(&rgb, &Image::new(64, 64, 1.0f32), &face).is_none());
        assert!(back_image(&Image::new(0, 0, Vec3::ZERO), &Image::new(0, 0, 0.0f32), &face).is_none());
    }

    #[test]
    fn frontality_and_head_weight_in_closed_form() {
        let (_, _, face) = person();
        let f = face.frame().unwrap();
        assert_eq!(f.d, 8.0);
        assert_eq!(f.up, Vec2::new(0.0, -1.0));
        // Ears 22 px apart over d = 8 = 2.75: frontal.
        assert_eq!(f.frontality, 1.0);
        // Ears d apart: (1 - 0.6) / 0.8 = 0.5.
        let half = FacePoints { ears: [Vec2::new(68.0, 33.0), Vec2::new(60.0, 33.0)], ..face }.frame().unwrap();
        assert!((half.frontality - 0.5).abs() < 1e-6);
        // Head weight: 1 at the centre, 0 at and past the ellipse, 0.5 halfway through the feather.
        let centre = f.eyes + f.up * HEAD_CENTRE_UP * f.d;
        assert_eq!(f.head_weight(centre), 1.0);
        assert_eq!(f.head_weight(centre + f.across * HEAD_AXES.x * f.d), 0.0);
        let mid = centre + f.up * HEAD_AXES.y * (1.0 - HEAD_FEATHER / 2.0) * f.d;
        assert!((f.head_weight(mid) - 0.5).abs() < 1e-5, "{}", f.head_weight(mid));
    }
}
