//! Procedural clothing baked into a texture over the MakeHuman UV layout: top (tank, T-shirt or long sleeves),
//! trousers, shorts or skirt, shoes, skin, hair cap and simple face marks, with colours and patterns (stripes,
//! checks, dots, blobs, text-like marks, fabric noise). Everything is albedo: no lighting is baked in, so every
//! view of a subject agrees.
//!
//! Regions come from the rest pose: each body vertex's skin weights give body-part weights (head, torso, upper
//! arm...), interpolated per texel; garment borders (hems, waist, neckline, hairline) are cut at rest-pose
//! positions (decimetres, MakeHuman axes). Patterns are functions of the rest position, so they continue across
//! UV seams.

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::base::BaseMesh;
use super::rig::Rig;
use super::Rng;
use crate::buffer::{neighbours4, srgb_to_linear};
use crate::io::mesh_io::linear_to_srgb8;

/// Body parts used for clothing regions.
pub const PARTS: [&str; 10] =
    ["head", "neck", "torso", "pelvis", "upperarm", "lowerarm", "hand", "thigh", "shin", "foot"];

/// Body part of a rig bone (index into [`PARTS`]).
pub fn bone_part(name: &str) -> usize {
    let n = name.trim_end_matches(".L").trim_end_matches(".R");
    if n.starts_with("neck") {
        1
    } else if n.starts_with("spine05") || n.starts_with("pelvis") || n == "root" {
        3
    } else if n.starts_with("spine")
        || n.starts_with("clavicle")
        || n.starts_with("breast")
        || n.starts_with("shoulder")
    {
        2
    } else if n.starts_with("upperarm") {
        4
    } else if n.starts_with("lowerarm") {
        5
    } else if n.starts_with("wrist") || n.starts_with("finger") || n.starts_with("metacarpal") {
        6
    } else if n.starts_with("upperleg") {
        7
    } else if n.starts_with("lowerleg") {
        8
    } else if n.starts_with("foot") || n.starts_with("toe") {
        9
    } else {
        0 // head, jaw and all face bones
    }
}

/// Surface pattern of a garment.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Pattern {
    /// One colour.
    Solid,
    /// Horizontal stripes.
    HorizontalStripes,
    /// Vertical stripes.
    VerticalStripes,
    /// Gingham checks.
    Checks,
    /// A dot print.
    Dots,
    /// Organic blobs (camouflage-like print).
    Blobs,
    /// Heathered noise.
    Noise,
}

/// A garment's look.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Fabric {
    /// Base colour, linear RGB.
    pub base: [f32; 3],
    /// Pattern colour, linear RGB.
    pub accent: [f32; 3],
    /// Pattern.
    pub pattern: Pattern,
    /// Pattern period in decimetres.
    pub period: f32,
    /// Seed of the pattern's random parts.
    pub seed: u64,
}

/// Kinds of top.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum TopKind {
    /// Sleeveless.
    Tank,
    /// Short sleeves.
    TShirt,
    /// Long sleeves.
    LongSleeve,
}

/// Kinds of bottom.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum BottomKind {
    /// Long trousers.
    Trousers,
    /// Shorts above the knee.
    Shorts,
    /// A skirt (painted on the legs: the body mesh has no skirt geometry).
    Skirt,
}

/// Everything that decides a subject's look.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Appearance {
    /// Skin colour, linear RGB.
    pub skin: [f32; 3],
    /// Hair colour, linear RGB.
    pub hair: [f32; 3],
    /// Hairline height at the forehead (decimetres, rest pose).
    pub hairline: f32,
    /// The top.
    pub top: TopKind,
    /// Its fabric.
    pub top_fabric: Fabric,
    /// Text-like marks printed on the chest.
    pub chest_text: bool,
    /// The bottom.
    pub bottom: BottomKind,
    /// Its fabric.
    pub bottom_fabric: Fabric,
    /// Waistline height (decimetres, rest pose).
    pub waist: f32,
    /// Lowest point of a skirt or shorts (decimetres, rest pose).
    pub hem: f32,
    /// Shoe colour, linear RGB.
    pub shoes: [f32; 3],
    /// Sole colour, linear RGB.
    pub soles: [f32; 3],
    /// Seed for noise and text marks.
    pub seed: u64,
}

fn lin(srgb: [f32; 3]) -> [f32; 3] {
    srgb.map(srgb_to_linear)
}

fn hsv(h: f32, s: f32, v: f32) -> [f32; 3] {
    let h = h.rem_euclid(1.0) * 6.0;
    let c = v * s;
    let x = c * (1.0 - ((h % 2.0) - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    lin([r + m, g + m, b + m])
}

/// A random garment fabric (`denim_like`: blue denim tones are likelier).
pub(crate) fn random_fabric(rng: &mut Rng, denim_like: bool) -> Fabric {
    let base = if denim_like && rng.uniform() < 0.4 {
        hsv(rng.range(0.58, 0.64), rng.range(0.4, 0.7), rng.range(0.25, 0.6))
    } else {
        hsv(rng.uniform(), rng.range(0.1, 0.85), rng.range(0.15, 0.95))
    };
    let accent = if rng.uniform() < 0.5 {
        hsv(rng.uniform(), rng.range(0.0, 0.9), rng.range(0.6, 1.0))
    } else {
        hsv(rng.uniform(), rng.range(0.2, 0.9), rng.range(0.05, 0.4))
    };
    let pattern = match rng.below(10) {
        0..=2 => Pattern::Solid,
        3 => Pattern::HorizontalStripes,
        4 => Pattern::VerticalStripes,
        5 => Pattern::Checks,
        6 => Pattern::Dots,
        7 => Pattern::Blobs,
        _ => Pattern::Noise,
    };
    Fabric { base, accent, pattern, period: rng.range(0.25, 1.0), seed: rng.next_u64() }
}

impl Appearance {
    /// A random appearance.
    pub fn sample(rng: &mut Rng) -> Self {
        const SKIN: [[f32; 3]; 8] = [
            [0.98, 0.87, 0.78],
            [0.94, 0.78, 0.66],
            [0.87, 0.69, 0.55],
            [0.78, 0.58, 0.44],
            [0.65, 0.46, 0.33],
            [0.52, 0.36, 0.25],
            [0.40, 0.27, 0.19],
            [0.30, 0.20, 0.14],
        ];
        const HAIR: [[f32; 3]; 6] = [
            [0.06, 0.05, 0.05],
            [0.22, 0.14, 0.08],
            [0.40, 0.26, 0.14],
            [0.80, 0.66, 0.42],
            [0.55, 0.25, 0.10],
            [0.70, 0.70, 0.68],
        ];
        let s = SKIN[rng.below(SKIN.len())];
        let k = rng.range(0.95, 1.05);
        let skin = lin(s.map(|c| (c * k).min(1.0)));
        let hair = lin(HAIR[rng.below(HAIR.len())]);
        let top = [TopKind::Tank, TopKind::TShirt, TopKind::TShirt, TopKind::LongSleeve][rng.below(4)];
        let bottom = [BottomKind::Trousers, BottomKind::Trousers, BottomKind::Shorts, BottomKind::Skirt][rng.below(4)];
        let hem = match bottom {
            BottomKind::Trousers => -9.0,
            BottomKind::Shorts => rng.range(-2.6, -1.2),
            BottomKind::Skirt => rng.range(-4.8, -2.0),
        };
        Self {
            skin,
            hair,
            hairline: rng.range(7.45, 7.75),
            top,
            top_fabric: random_fabric(rng, false),
            chest_text: rng.uniform() < 0.4,
            bottom,
            bottom_fabric: random_fabric(rng, true),
            waist: rng.range(0.9, 1.6),
            hem,
            shoes: hsv(rng.uniform(), rng.range(0.0, 0.7), rng.range(0.05, 0.9)),
            soles: if rng.uniform() < 0.5 { lin([0.92, 0.92, 0.9]) } else { lin([0.1, 0.1, 0.1]) },
            seed: rng.next_u64(),
        }
    }
}

/// Landmarks of the rest-pose base mesh that garments and face marks are placed against (decimetres).
#[derive(Clone, Copy, Debug)]
pub struct Landmarks {
    /// Left eye centre (the right eye mirrors x).
    pub eye: Vec3,
    /// Left shoulder and elbow joints.
    pub shoulder: Vec3,
    /// Left elbow joint.
    pub elbow: Vec3,
    /// Left wrist (hand joint).
    pub wrist: Vec3,
    /// Left ankle joint.
    pub ankle: Vec3,
    /// Front-most z of the face at eye height (used to keep face marks on the front).
    pub face_front: f32,
}

impl Landmarks {
    /// Landmarks of the unmorphed base mesh.
    pub fn from_base(base: &BaseMesh) -> Self {
        let p = &base.full_positions;
        let c = |n: &str, fallback: Vec3| base.group_centroid(n, p).unwrap_or(fallback);
        let eye = c("helper-l-eye", Vec3::new(0.31, 7.3, 1.2));
        let face_front = base.full_positions[..super::base::BODY_VERTEX_COUNT]
            .iter()
            .filter(|q| (q.y - eye.y).abs() < 0.3 && q.x.abs() < 0.3)
            .map(|q| q.z)
            .fold(eye.z, f32::max);
        Self {
            eye,
            shoulder: c("joint-l-shoulder", Vec3::new(1.68, 5.25, 0.15)),
            elbow: c("joint-l-elbow", Vec3::new(3.13, 3.49, 0.13)),
            wrist: c("joint-l-hand", Vec3::new(4.31, 2.45, 1.76)),
            ankle: c("joint-l-ankle", Vec3::new(2.2, -7.45, 0.0)),
            face_front,
        }
    }
}

/// Per base-mesh body vertex body-part weights from the skin weights.
pub fn part_weights(rig: &Rig) -> Vec<[f32; 10]> {
    let parts: Vec<usize> = rig.bones.iter().map(|b| bone_part(&b.name)).collect();
    rig.weights
        .iter()
        .map(|list| {
            let mut w = [0.0f32; 10];
            for &(b, x) in list {
                w[parts[b as usize]] += x;
            }
            w
        })
        .collect()
}

fn hash(mut x: u64) -> u64 {
    x ^= x >> 30;
    x = x.wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x ^= x >> 27;
    x = x.wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

fn hash3(seed: u64, i: i32, j: i32, k: i32) -> f32 {
    let key = (i as u32 as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u32 as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (k as u32 as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    (hash(seed ^ key) >> 40) as f32 / (1u64 << 24) as f32
}

/// Smooth 3-D value noise in `[0, 1]`.
pub(crate) fn value_noise(seed: u64, p: Vec3) -> f32 {
    let f = p.floor();
    let t = p - f;
    let s = t * t * (Vec3::splat(3.0) - 2.0 * t);
    let (i, j, k) = (f.x as i32, f.y as i32, f.z as i32);
    let mut acc = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let w = (if dx == 1 { s.x } else { 1.0 - s.x })
                    * (if dy == 1 { s.y } else { 1.0 - s.y })
                    * (if dz == 1 { s.z } else { 1.0 - s.z });
                acc += w * hash3(seed, i + dx, j + dy, k + dz);
            }
        }
    }
    acc
}

fn fbm(seed: u64, p: Vec3) -> f32 {
    0.5 * value_noise(seed, p) + 0.3 * value_noise(seed ^ 1, p * 2.03) + 0.2 * value_noise(seed ^ 2, p * 4.1)
}

/// Evaluates a fabric at a rest-pose position.
pub(crate) fn fabric_color(f: &Fabric, p: Vec3) -> Vec3 {
    let base = Vec3::from(f.base);
    let accent = Vec3::from(f.accent);
    // Arc length around the body axis (decimetres); the one seam is the back's centre line.
    let around = p.x.atan2(p.z + 0.3) * 1.6;
    let per = f.period.max(0.05);
    let c = match f.pattern {
        Pattern::Solid => base,
        Pattern::HorizontalStripes => {
            if (p.y / per).rem_euclid(1.0) < 0.45 {
                accent
            } else {
                base
            }
        }
        Pattern::VerticalStripes => {
            if (around / per).rem_euclid(1.0) < 0.4 {
                accent
            } else {
                base
            }
        }
        Pattern::Checks => {
            let a = (p.y / per).rem_euclid(1.0) < 0.5;
            let b = (around / per).rem_euclid(1.0) < 0.5;
            match (a, b) {
                (true, true) => accent,
                (false, false) => base,
                _ => base.lerp(accent, 0.5),
            }
        }
        Pattern::Dots => {
            let q = Vec2::new(around, p.y) / per;
            let cell = q.floor();
            let centre = cell
                + Vec2::new(
                    0.25 + 0.5 * hash3(f.seed, cell.x as i32, cell.y as i32, 1),
                    0.25 + 0.5 * hash3(f.seed, cell.x as i32, cell.y as i32, 2),
                );
            let r = 0.12 + 0.15 * hash3(f.seed, cell.x as i32, cell.y as i32, 3);
            if q.distance(centre) < r {
                accent
            } else {
                base
            }
        }
        Pattern::Blobs => {
            let n = fbm(f.seed, p / (per * 1.5));
            if n > 0.55 {
                accent
            } else if n > 0.45 {
                base.lerp(accent, 0.35)
            } else {
                base
            }
        }
        Pattern::Noise => base.lerp(accent, 0.6 * fbm(f.seed, p * (4.0 / per))),
    };
    // Fine fabric grain, identical in every view.
    c * (0.94 + 0.12 * value_noise(f.seed ^ 0xfab, p * 18.0))
}

/// Text-like marks: rows of random 3x5 glyphs on the chest. Returns whether `p` is on ink.
fn chest_text(seed: u64, p: Vec3, front: bool) -> bool {
    if !front || p.x.abs() > 1.1 || !(3.2..4.15).contains(&p.y) {
        return false;
    }
    let (gw, gh) = (0.2f32, 0.4f32); // glyph cell (with spacing)
    let col = ((p.x + 1.1) / gw).floor() as i32;
    let row = ((4.15 - p.y) / gh).floor() as i32;
    let fx = ((p.x + 1.1) / gw).rem_euclid(1.0);
    let fy = ((4.15 - p.y) / gh).rem_euclid(1.0);
    if hash3(seed, col, row, 99) < 0.15 {
        return false; // word gap
    }
    // 3x5 bitmap inside the cell, with margins.
    let gx = ((fx - 0.15) / 0.7 * 3.0).floor() as i32;
    let gy = ((fy - 0.12) / 0.76 * 5.0).floor() as i32;
    if !(0..3).contains(&gx) || !(0..5).contains(&gy) {
        return false;
    }
    hash3(seed, col * 16 + gx, row * 16 + gy, 7) < 0.55
}

/// Colour of a texel given its rest position `p` (decimetres) and interpolated body-part weights.
pub fn texel_color(a: &Appearance, lm: &Landmarks, p: Vec3, part: usize) -> Vec3 {
    // Evaluated lazily: noise is the expensive part of baking.
    let skin = || Vec3::from(a.skin) * (0.97 + 0.06 * value_noise(a.seed ^ 0x5c1, p * 6.0));
    let hair = || {
        Vec3::from(a.hair) * (0.85 + 0.3 * value_noise(a.seed ^ 0x4a1, Vec3::new(p.x * 30.0, p.y * 4.0, p.z * 30.0)))
    };
    let ax = p.x.abs();
    let top = |p: Vec3| {
        if a.chest_text && chest_text(a.seed, p, p.z > 0.6) {
            Vec3::from(a.top_fabric.accent)
                .lerp(Vec3::ONE - Vec3::from(a.top_fabric.base), 0.5)
                .clamp(Vec3::ZERO, Vec3::ONE)
        } else {
            fabric_color(&a.top_fabric, p)
        }
    };
    let bottom = |p: Vec3| fabric_color(&a.bottom_fabric, p);
    // Position along the (left, mirrored) arm: 0 at the shoulder, 1 at the elbow, 2 at the wrist.
    let arm_t = || {
        let q = Vec3::new(ax, p.y, p.z);
        let up = lm.elbow - lm.shoulder;
        let t = (q - lm.shoulder).dot(up) / up.length_squared();
        if t <= 1.0 {
            t
        } else {
            let fore = lm.wrist - lm.elbow;
            1.0 + (q - lm.elbow).dot(fore) / fore.length_squared()
        }
    };
    match PARTS[part] {
        "head" => {
            // Hairline: high on the forehead, dropping toward the nape.
            let line = if p.z > 0.6 { a.hairline } else { a.hairline + (p.z - 0.6) * 1.3 };
            let on_face = p.z > lm.eye.z - 0.6 && ax < 1.0;
            if p.y > line.max(6.2) && !(on_face && p.y < a.hairline) {
                return hair();
            }
            if on_face {
                let d = Vec2::new(ax - lm.eye.x, p.y - lm.eye.y);
                // Eyebrow, eye white and iris.
                if (d.x / 0.3).powi(2) + ((d.y - 0.32) / 0.06).powi(2) < 1.0 {
                    return hair() * 0.9;
                }
                if (d.x / 0.2).powi(2) + (d.y / 0.09).powi(2) < 1.0 {
                    return if d.length() < 0.075 { Vec3::new(0.03, 0.025, 0.02) } else { Vec3::splat(0.8) };
                }
                // Lips.
                let m = Vec2::new(p.x / 0.3, (p.y - (lm.eye.y - 0.95)) / 0.07);
                if m.length_squared() < 1.0 && p.z > lm.face_front - 0.6 {
                    return Vec3::from(a.skin) * Vec3::new(0.85, 0.45, 0.45);
                }
            }
            skin()
        }
        "neck" => skin(),
        "torso" | "pelvis" => {
            if p.y < a.waist {
                return bottom(p);
            }
            // Neckline (crew, a little lower at the front) and, for tanks, bare shoulders.
            let neck = if p.z > 0.3 { 5.45 } else { 5.75 };
            if p.y > neck && ax < 1.6 {
                return skin();
            }
            if a.top == TopKind::Tank && ax > 1.0 && p.y > 4.4 {
                return skin();
            }
            top(p)
        }
        "upperarm" | "lowerarm" => {
            let t = arm_t();
            let sleeve = match a.top {
                TopKind::Tank => -1.0,
                TopKind::TShirt => 0.45,
                TopKind::LongSleeve => 1.93,
            };
            if t < sleeve {
                top(p)
            } else {
                skin()
            }
        }
        "hand" => skin(),
        "thigh" | "shin" => {
            if p.y < lm.ankle.y + 0.35 {
                return if p.y < lm.ankle.y - 0.55 { Vec3::from(a.soles) } else { Vec3::from(a.shoes) };
            }
            if p.y >= a.hem {
                bottom(p)
            } else {
                skin()
            }
        }
        _ => {
            // Feet: shoe upper, white or black sole near the ground.
            if p.y < lm.ankle.y - 0.55 {
                Vec3::from(a.soles)
            } else {
                Vec3::from(a.shoes) * (0.95 + 0.1 * value_noise(a.seed ^ 0x5e0, p * 10.0))
            }
        }
    }
}

/// A texture being painted: triangles are rasterised in UV space (glTF UVs as fractions of the whole canvas) and
/// each covered texel is coloured by a callback; [`Canvas::finish`] dilates the colours into the empty gutters (so
/// bilinear lookups at UV seams never see the background) and encodes sRGB.
pub struct Canvas {
    width: usize,
    height: usize,
    colors: Vec<Option<Vec3>>,
}

impl Canvas {
    /// An empty `width x height` canvas.
    pub fn new(width: usize, height: usize) -> Self {
        let (width, height) = (width.max(4), height.max(4));
        Self { width, height, colors: vec![None; width * height] }
    }

    /// Paints `triangles` (indices into `uvs`): every texel whose centre a triangle covers gets
    /// `color(triangle, barycentrics)` (linear RGB).
    pub fn paint(&mut self, triangles: &[[u32; 3]], uvs: &[Vec2], color: impl Fn(usize, [f32; 3]) -> Vec3 + Sync) {
        let (w, h) = (self.width, self.height);
        let scale = Vec2::new(w as f32, h as f32);
        // Which triangle covers each texel (+ barycentrics): rasterise the UV layout.
        let mut owner: Vec<(u32, u32, [f32; 3])> = Vec::new();
        for (t, tri) in triangles.iter().enumerate() {
            let uv = tri.map(|i| uvs[i as usize] * scale);
            let area = (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]);
            if area.abs() < 1e-12 || !area.is_finite() {
                continue;
            }
            let lo = uv[0].min(uv[1]).min(uv[2]).floor().max(Vec2::ZERO);
            let hi = uv[0].max(uv[1]).max(uv[2]).ceil().min(scale);
            for y in lo.y as usize..hi.y as usize {
                for x in lo.x as usize..hi.x as usize {
                    let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    let w0 = (uv[2] - uv[1]).perp_dot(c - uv[1]) / area;
                    let w1 = (uv[0] - uv[2]).perp_dot(c - uv[2]) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 >= -1e-4 && w1 >= -1e-4 && w2 >= -1e-4 {
                        owner.push(((y * w + x) as u32, t as u32, [w0, w1, w2]));
                    }
                }
            }
        }
        // A later triangle wins a shared texel, as before.
        let painted: Vec<(u32, Vec3)> = owner.par_iter().map(|&(i, t, b)| (i, color(t as usize, b))).collect();
        for (i, c) in painted {
            self.colors[i as usize] = Some(c);
        }
    }

    /// Dilates into the gutters (4 texels), fills what is left with `fill` and encodes 8-bit sRGB.
    pub fn finish(mut self, fill: Vec3) -> image::RgbImage {
        let (w, h) = (self.width, self.height);
        let colors = &mut self.colors;
        let mut empty: Vec<usize> = (0..colors.len()).filter(|&i| colors[i].is_none()).collect();
        for _ in 0..4 {
            let fills: Vec<Option<Vec3>> = empty
                .iter()
                .map(|&i| {
                    let (sum, n) = neighbours4(i, w, h)
                        .filter_map(|j| colors[j])
                        .fold((Vec3::ZERO, 0), |(sum, n), c| (sum + c, n + 1));
                    (n > 0).then(|| sum / n as f32)
                })
                .collect();
            for (&i, f) in empty.iter().zip(&fills) {
                colors[i] = *f;
            }
            empty.retain(|&i| colors[i].is_none());
        }
        let raw: Vec<u8> = colors.iter().flat_map(|c| linear_to_srgb8(c.unwrap_or(fill))).collect();
        image::RgbImage::from_raw(w as u32, h as u32, raw).unwrap_or_else(|| image::RgbImage::new(w as u32, h as u32))
    }
}

/// Paints the body's appearance over the base mesh triangles with the given UVs (the base UVs, or the base UVs
/// mapped into part of an atlas). `parts` is [`part_weights`]; positions are the unmorphed rest pose, so the
/// pattern does not depend on shape or pose.
pub fn paint_body(
    canvas: &mut Canvas,
    base: &BaseMesh,
    uvs: &[Vec2],
    parts: &[[f32; 10]],
    lm: &Landmarks,
    a: &Appearance,
) {
    canvas.paint(&base.triangles, uvs, |t, w| {
        let tri = base.triangles[t];
        let src = tri.map(|i| base.source_vertex[i as usize] as usize);
        let p = w[0] * base.full_positions[src[0]]
            + w[1] * base.full_positions[src[1]]
            + w[2] * base.full_positions[src[2]];
        let mut pw = [0.0f32; 10];
        for k in 0..3 {
            for (acc, x) in pw.iter_mut().zip(&parts[src[k]]) {
                *acc += w[k] * x;
            }
        }
        let part = pw.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).map(|x| x.0).unwrap_or(0);
        texel_color(a, lm, p, part)
    });
}

/// Bakes the appearance into a `size x size` sRGB texture over the base mesh UVs (the unclothed body alone).
pub fn bake(base: &BaseMesh, parts: &[[f32; 10]], lm: &Landmarks, a: &Appearance, size: usize) -> image::RgbImage {
    let mut canvas = Canvas::new(size, size);
    paint_body(&mut canvas, base, &base.uvs, parts, lm, a);
    canvas.finish(Vec3::from(a.skin))
}
