//! Clothes, hair, hats, shoes and bags as **surfaces** over the synthetic body, skinned with it.
//!
//! Every piece is built in the shaped rest pose (MakeHuman decimetres, +Y up, +Z forward, +X the model's left)
//! around the body it covers, then posed by the same linear blend skinning as the body:
//! - **tubes** (tops, sleeves, skirts, dresses, trouser legs, boot shafts, backpack straps): rings of stations
//!   along an axis (vertical for the torso and skirts, the bone chain for limbs). Each ring's radius is the convex
//!   hull of the body's cross-section there (cloth bridges concavities and the gap between the legs) plus a seeded
//!   looseness; the ring's skin weights are those of the body vertices that gave its radius (weights transferred
//!   from the nearest body vertices along the ring's rays), averaged over neighbouring rays. Open edges (hems,
//!   cuffs, a jacket's front opening) fold inward by the cloth thickness, so the cloth shows a rim, and the tube
//!   stays an open (not watertight) single sheet, as scans of clothes are.
//! - **closed volumes** (hair, hats, hoods, shoes, bags): star-shaped surfaces around a centre, watertight.
//!
//! Skirts and dresses do not follow the legs rigidly: below the waist their weights blend the waist's weights with
//! an even mix of both thighs (half strength at the hem), so the skirt hangs between the legs, and after posing any
//! ring a leg would pierce is pushed out radially ([`pose_garments`]).
//!
//! The body under the clothes keeps its painted layer (texture module): tight clothes are paint, loose ones are
//! geometry. The ground-truth FOF and views see the union of body and garments (the FOF interval automaton turns
//! an outward-facing sheet around the body into the solid it encloses).

use std::f32::consts::{PI, TAU};

use glam::{Affine3A, Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::rig::Rig;
use super::texture::{random_fabric, Fabric};
use super::Rng;

/// Body-part indices of [`super::texture::PARTS`].
const HEAD: usize = 0;
const NECK: usize = 1;
const TORSO: usize = 2;
const PELVIS: usize = 3;
const UPPERARM: usize = 4;
const LOWERARM: usize = 5;
const THIGH: usize = 7;
const SHIN: usize = 8;
const FOOT: usize = 9;

/// What covers the torso.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum UpperKind {
    /// Nothing loose: the painted top only.
    None,
    /// A loose T-shirt (short sleeves).
    Tee,
    /// A loose long-sleeved top.
    LongSleeve,
    /// A hoodie: long sleeves and a hood (up over the head or down on the back).
    Hoodie,
    /// An open jacket: long sleeves, front open (the painted top shows between the panels).
    OpenJacket,
    /// A dress: one piece from the shoulders to a flared hem (no separate lower garment).
    Dress,
}

/// What covers the legs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum LowerKind {
    /// Nothing loose: the painted bottom only.
    None,
    /// Wide trousers to the ankle.
    WideTrousers,
    /// Shorts above the knee.
    Shorts,
    /// A skirt that flares and hangs from the hips.
    Skirt,
}

/// Hair volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HairKind {
    /// A thin cap over the cranium.
    Short,
    /// A bob: the cap hanging to the chin at the sides and back.
    Bob,
    /// Long hair falling on the shoulders and back.
    Long,
    /// A cap and a ponytail.
    Ponytail,
    /// A cap and a bun.
    Bun,
}

/// Headwear.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HatKind {
    /// None.
    None,
    /// A knitted cap.
    Beanie,
    /// A baseball cap (crown and a front brim).
    Cap,
    /// A hat with a wide round brim.
    WideBrim,
}

/// Footwear.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShoeKind {
    /// Painted shoes only.
    None,
    /// Shoes around the feet.
    Shoes,
    /// Boots: shoes and a shaft up the shin.
    Boots,
}

/// Bags.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum BagKind {
    /// None.
    None,
    /// A backpack with two shoulder straps.
    Backpack,
}

/// The garments of a subject and their seeded looseness, thickness and fabrics. Lengths are decimetres in the
/// rest pose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outfit {
    /// Torso garment.
    pub upper: UpperKind,
    /// Its fabric.
    pub upper_fabric: Fabric,
    /// Extra radius of the torso garment at its hem (dm).
    pub upper_loose: f32,
    /// Height of the top's hem relative to the hip joints (dm, negative = below).
    pub upper_hem: f32,
    /// Width of a jacket's front opening (radians around the body axis).
    pub opening: f32,
    /// Whether a hoodie's hood is up.
    pub hood_up: bool,
    /// Leg garment.
    pub lower: LowerKind,
    /// Its fabric.
    pub lower_fabric: Fabric,
    /// Extra radius of the leg garment at its hem (dm).
    pub lower_loose: f32,
    /// Extra flare of a skirt's or dress's hem (dm).
    pub flare: f32,
    /// Rest height of a skirt's, dress's or shorts' hem (dm).
    pub lower_hem: f32,
    /// Cloth thickness shown at hems and openings (dm).
    pub thickness: f32,
    /// Hair style.
    pub hair: HairKind,
    /// Hair thickness over the scalp (dm).
    pub hair_volume: f32,
    /// How far below the cranium centre long hair, a bob or a ponytail reaches (dm).
    pub hair_length: f32,
    /// Headwear.
    pub hat: HatKind,
    /// Its fabric.
    pub hat_fabric: Fabric,
    /// Footwear.
    pub shoes: ShoeKind,
    /// Bag.
    pub bag: BagKind,
    /// Its fabric.
    pub bag_fabric: Fabric,
}

fn pick<T: Copy>(rng: &mut Rng, choices: &[(T, f32)]) -> T {
    let total: f32 = choices.iter().map(|c| c.1).sum();
    let mut x = rng.uniform() * total;
    for &(c, w) in choices {
        if x < w {
            return c;
        }
        x -= w;
    }
    choices[choices.len() - 1].0
}

impl Outfit {
    /// Nothing loose: the painted body alone (the subjects before garments existed).
    pub fn none(fabric: Fabric) -> Self {
        Self {
            upper: UpperKind::None,
            upper_fabric: fabric,
            upper_loose: 0.0,
            upper_hem: 0.0,
            opening: 0.0,
            hood_up: false,
            lower: LowerKind::None,
            lower_fabric: fabric,
            lower_loose: 0.0,
            flare: 0.0,
            lower_hem: 0.0,
            thickness: 0.05,
            hair: HairKind::Short,
            hair_volume: 0.0,
            hair_length: 0.0,
            hat: HatKind::None,
            hat_fabric: fabric,
            shoes: ShoeKind::None,
            bag: BagKind::None,
            bag_fabric: fabric,
        }
    }

    /// A random outfit. `top`/`bottom` are the painted layer's fabrics: a loose top reuses the painted top's
    /// fabric half of the time (a loose version of the same shirt), a skirt or trousers the painted bottom's.
    pub fn sample(rng: &mut Rng, top: &Fabric, bottom: &Fabric) -> Self {
        use UpperKind as U;
        let upper = pick(
            rng,
            &[
                (U::None, 0.12),
                (U::Tee, 0.2),
                (U::LongSleeve, 0.14),
                (U::Hoodie, 0.16),
                (U::OpenJacket, 0.2),
                (U::Dress, 0.18),
            ],
        );
        let lower = if upper == U::Dress {
            LowerKind::None
        } else {
            pick(
                rng,
                &[
                    (LowerKind::None, 0.2),
                    (LowerKind::WideTrousers, 0.27),
                    (LowerKind::Shorts, 0.18),
                    (LowerKind::Skirt, 0.35),
                ],
            )
        };
        let upper_fabric = if rng.uniform() < 0.5 { *top } else { random_fabric(rng, false) };
        let lower_fabric = if rng.uniform() < 0.5 { *bottom } else { random_fabric(rng, true) };
        let hair = pick(
            rng,
            &[
                (HairKind::Short, 0.26),
                (HairKind::Bob, 0.2),
                (HairKind::Long, 0.22),
                (HairKind::Ponytail, 0.16),
                (HairKind::Bun, 0.16),
            ],
        );
        let hood_up = upper == U::Hoodie && rng.uniform() < 0.45;
        let hat = if hood_up {
            HatKind::None
        } else {
            pick(rng, &[(HatKind::None, 0.6), (HatKind::Beanie, 0.13), (HatKind::Cap, 0.14), (HatKind::WideBrim, 0.13)])
        };
        let lower_hem = match (upper, lower) {
            (U::Dress, _) => rng.range(-5.5, -1.5),
            (_, LowerKind::Skirt) => rng.range(-5.8, -1.2),
            (_, LowerKind::Shorts) => rng.range(-2.6, -1.0),
            _ => 0.0,
        };
        Self {
            upper,
            upper_fabric,
            upper_loose: rng.range(0.15, 0.9),
            upper_hem: rng.range(-1.4, -0.2),
            opening: rng.range(0.35, 1.0),
            hood_up,
            lower,
            lower_fabric,
            lower_loose: rng.range(0.1, 0.8),
            flare: rng.range(0.3, 2.2),
            lower_hem,
            thickness: rng.range(0.04, 0.14),
            hair,
            hair_volume: rng.range(0.12, 0.4),
            hair_length: rng.range(1.2, 3.8),
            hat,
            hat_fabric: random_fabric(rng, false),
            shoes: pick(rng, &[(ShoeKind::None, 0.2), (ShoeKind::Shoes, 0.5), (ShoeKind::Boots, 0.3)]),
            bag: pick(rng, &[(BagKind::None, 0.72), (BagKind::Backpack, 0.28)]),
            bag_fabric: random_fabric(rng, false),
        }
    }
}

/// How a garment's texels are coloured (evaluated at the rest-pose position, so patterns are seamless).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Look {
    /// A fabric pattern.
    Fabric(Fabric),
    /// Hair of this linear colour, strands along y.
    Hair([f32; 3]),
    /// Shoes: upper colour, sole colour below `sole_y` (rest dm).
    Shoe {
        /// Upper colour, linear RGB.
        upper: [f32; 3],
        /// Sole colour, linear RGB.
        sole: [f32; 3],
        /// Sole top height.
        sole_y: f32,
    },
}

/// One garment piece: rest geometry, local UVs, skin weights and look.
#[derive(Clone, Debug)]
pub struct Garment {
    /// Name (`skirt`, `sleeve.L`, `hair`...).
    pub label: String,
    /// Rest-pose positions (dm).
    pub rest: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex UV in the piece's own `[0, 1]^2` (placed in the texture atlas later).
    pub uv: Vec<Vec2>,
    /// Physical size of the UV square's sides (dm), for an even texel density in the atlas.
    pub extent: Vec2,
    /// Per-vertex skin weights `(bone, weight)`, summing to one.
    pub weights: Vec<Vec<(u16, f32)>>,
    /// Per-vertex brightness factor (folds and rims are darker).
    pub tint: Vec<f32>,
    /// How its texels are coloured.
    pub look: Look,
    /// Whether the piece is a watertight closed surface (volumes) or an open sheet (tubes).
    pub closed: bool,
    /// For skirt-like pieces: the grid `(rows, columns)` and which rows are stations, to push out of posed legs.
    pub hang: Option<HangGrid>,
}

/// The grid layout of a hanging piece (row-major vertices, `cols` per row).
#[derive(Clone, Debug, PartialEq)]
pub struct HangGrid {
    /// Rows.
    pub rows: usize,
    /// Vertices per row.
    pub cols: usize,
}

/// The shaped rest body the garments are built around.
#[derive(Clone, Copy)]
pub struct BodyRest<'a> {
    /// Base-mesh body vertices in the shaped rest pose (dm), `BODY_VERTEX_COUNT` of them.
    pub positions: &'a [Vec3],
    /// Per body vertex part weights ([`super::texture::part_weights`]).
    pub parts: &'a [[f32; 10]],
    /// The rig (bones and the body's skin weights).
    pub rig: &'a Rig,
    /// Shaped rest bone heads.
    pub heads: &'a [Vec3],
}

impl BodyRest<'_> {
    fn head(&self, bone: &str) -> Vec3 {
        self.rig.bone(bone).map(|b| self.heads[b]).unwrap_or(Vec3::ZERO)
    }

    fn bone_weight(&self, bone: &str) -> Vec<(u16, f32)> {
        self.rig.bone(bone).map(|b| vec![(b as u16, 1.0)]).unwrap_or_default()
    }

    /// Body vertices whose summed weight over `parts` exceeds one half and that pass `keep`.
    fn select(&self, parts: &[usize], keep: impl Fn(Vec3) -> bool) -> Vec<u32> {
        (0..self.positions.len())
            .filter(|&v| parts.iter().map(|&p| self.parts[v][p]).sum::<f32>() > 0.5 && keep(self.positions[v]))
            .map(|v| v as u32)
            .collect()
    }
}

/// A cross-section plane of a tube: centre, axis and the in-plane frame (`e1 x e2 = axis`).
#[derive(Clone, Copy, Debug)]
struct Station {
    c: Vec3,
    a: Vec3,
    e1: Vec3,
    e2: Vec3,
}

impl Station {
    fn dir(&self, theta: f32) -> Vec3 {
        self.e1 * theta.cos() + self.e2 * theta.sin()
    }
}

/// Per station and angular bin: the radius of the body's cross-section (convex hull) and the body vertex that
/// gave it (for the skin weights).
struct Profile {
    bins: usize,
    r: Vec<Vec<f32>>,
    src: Vec<Vec<u32>>,
}

impl Profile {
    fn radius(&self, i: usize, theta: f32) -> f32 {
        let x = theta.rem_euclid(TAU) / TAU * self.bins as f32 - 0.5;
        let b0 = x.floor();
        let f = x - b0;
        let b0 = (b0 as i64).rem_euclid(self.bins as i64) as usize;
        let b1 = (b0 + 1) % self.bins;
        self.r[i][b0] * (1.0 - f) + self.r[i][b1] * f
    }

    fn bin(&self, theta: f32) -> usize {
        ((theta.rem_euclid(TAU) / TAU * self.bins as f32) as usize).min(self.bins - 1)
    }
}

/// Convex hull (counter-clockwise, Andrew's monotone chain) of 2-D points.
fn convex_hull(mut p: Vec<Vec2>) -> Vec<Vec2> {
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let mut hull: Vec<Vec2> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Vec2>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for &q in iter {
            while hull.len() >= start + 2
                && (hull[hull.len() - 1] - hull[hull.len() - 2]).perp_dot(q - hull[hull.len() - 2]) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    hull
}

/// Distance from the origin to a convex polygon containing it, along unit direction `d`; `None` when the origin
/// is not inside.
fn ray_to_hull(hull: &[Vec2], d: Vec2) -> Option<f32> {
    if hull.len() < 3 {
        return None;
    }
    let mut best: Option<f32> = None;
    for k in 0..hull.len() {
        let (p, q) = (hull[k], hull[(k + 1) % hull.len()]);
        if p.perp_dot(q) <= 0.0 {
            return None; // the origin is on or outside this edge
        }
        let e = q - p;
        let den = d.perp_dot(e);
        if den.abs() < 1e-12 {
            continue;
        }
        let t = p.perp_dot(e) / den;
        let s = p.perp_dot(d) / den;
        if t > 0.0 && (-1e-4..=1.0 + 1e-4).contains(&s) {
            best = Some(best.map_or(t, |b: f32| b.max(t)));
        }
    }
    best
}

/// The cross-section profile of `cand` body vertices at each station (within `band` along the axis).
fn fit_profile(body: &BodyRest<'_>, cand: &[u32], stations: &[Station], band: f32, bins: usize) -> Profile {
    let n = stations.len();
    let mut r = vec![vec![0.0f32; bins]; n];
    let mut src = vec![vec![u32::MAX; bins]; n];
    let mut pts: Vec<Vec<Vec2>> = vec![vec![Vec2::ZERO; bins]; n];
    for (i, s) in stations.iter().enumerate() {
        for &v in cand {
            let d = body.positions[v as usize] - s.c;
            let ax = d.dot(s.a);
            if ax.abs() > band {
                continue;
            }
            let q = Vec2::new(d.dot(s.e1), d.dot(s.e2));
            let rad = q.length();
            let b = ((q.y.atan2(q.x).rem_euclid(TAU) / TAU * bins as f32) as usize).min(bins - 1);
            if rad > r[i][b] {
                r[i][b] = rad;
                src[i][b] = v;
                pts[i][b] = q;
            }
        }
    }
    for i in 0..n {
        let filled: Vec<usize> = (0..bins).filter(|&b| src[i][b] != u32::MAX).collect();
        if filled.is_empty() {
            continue;
        }
        let hull = convex_hull(filled.iter().map(|&b| pts[i][b]).collect());
        for (b, rb) in r[i].iter_mut().enumerate() {
            let th = (b as f32 + 0.5) / bins as f32 * TAU;
            if let Some(t) = ray_to_hull(&hull, Vec2::new(th.cos(), th.sin())) {
                *rb = rb.max(t);
            }
        }
        // Bins no vertex fell in: nearest filled bin's source, radius interpolated around the ring.
        for b in 0..bins {
            if src[i][b] != u32::MAX {
                continue;
            }
            let dist = |f: usize| {
                let d = (f as i64 - b as i64).rem_euclid(bins as i64) as usize;
                d.min(bins - d)
            };
            let near = *filled.iter().min_by_key(|&&f| dist(f)).unwrap_or(&filled[0]);
            src[i][b] = src[i][near];
            if r[i][b] == 0.0 {
                r[i][b] = r[i][near];
            }
        }
    }
    // Rings with no vertex at all: copy the nearest ring that has some.
    let good: Vec<usize> = (0..n).filter(|&i| src[i][0] != u32::MAX).collect();
    for i in 0..n {
        if src[i][0] == u32::MAX {
            if let Some(&g) = good.iter().min_by_key(|&&g| g.abs_diff(i)) {
                r[i] = r[g].clone();
                src[i] = src[g].clone();
            } else {
                r[i] = vec![0.5; bins];
                src[i] = vec![cand.first().copied().unwrap_or(0); bins];
            }
        }
    }
    // Smooth along the axis and around the ring, never inside the unsmoothed section (the cloth stays off the body).
    let unsmoothed = r.clone();
    for _ in 0..2 {
        let old = r.clone();
        for i in 0..n {
            for b in 0..bins {
                let (ip, inx) = (i.saturating_sub(1), (i + 1).min(n - 1));
                let (bp, bn) = ((b + bins - 1) % bins, (b + 1) % bins);
                r[i][b] = 0.5 * old[i][b] + 0.125 * (old[ip][b] + old[inx][b] + old[i][bp] + old[i][bn]);
            }
        }
    }
    for (ri, ui) in r.iter_mut().zip(&unsmoothed) {
        for (x, u) in ri.iter_mut().zip(ui) {
            *x = x.max(*u);
        }
    }
    Profile { bins, r, src }
}

/// Merges weight lists (each summing to one) with the given factors, keeps the four largest, renormalises.
fn blend_weights(parts: &[(&[(u16, f32)], f32)]) -> Vec<(u16, f32)> {
    let mut all: Vec<(u16, f32)> = Vec::with_capacity(16);
    for (list, f) in parts {
        for &(b, w) in *list {
            match all.iter_mut().find(|x| x.0 == b) {
                Some(x) => x.1 += w * f,
                None => all.push((b, w * f)),
            }
        }
    }
    all.retain(|x| x.1 > 0.0);
    all.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    all.truncate(4);
    let s: f32 = all.iter().map(|x| x.1).sum();
    if s > 0.0 {
        all.iter_mut().for_each(|x| x.1 /= s);
    }
    all.sort_by_key(|x| x.0);
    all
}

/// Stations along a vertical axis from `y0` to `y1`, centred on the xz bounding box of `cand` at each height.
fn vertical_stations(body: &BodyRest<'_>, cand: &[u32], y0: f32, y1: f32, n: usize, band: f32) -> Vec<Station> {
    let mut centres: Vec<Option<Vec2>> = (0..n)
        .map(|i| {
            let y = y0 + (y1 - y0) * i as f32 / (n - 1).max(1) as f32;
            let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
            for &v in cand {
                let p = body.positions[v as usize];
                if (p.y - y).abs() <= band {
                    lo = lo.min(Vec2::new(p.x, p.z));
                    hi = hi.max(Vec2::new(p.x, p.z));
                }
            }
            (lo.x <= hi.x).then(|| 0.5 * (lo + hi))
        })
        .collect();
    let known: Vec<(usize, Vec2)> = centres.iter().enumerate().filter_map(|(i, c)| c.map(|c| (i, c))).collect();
    for (i, c) in centres.iter_mut().enumerate() {
        if c.is_none() {
            *c = known.iter().min_by_key(|k| k.0.abs_diff(i)).map(|k| k.1).or(Some(Vec2::ZERO));
        }
    }
    let mut xz: Vec<Vec2> = centres.into_iter().map(|c| c.unwrap_or(Vec2::ZERO)).collect();
    for _ in 0..3 {
        let old = xz.clone();
        for i in 0..n {
            xz[i] = 0.5 * old[i] + 0.25 * (old[i.saturating_sub(1)] + old[(i + 1).min(n - 1)]);
        }
    }
    (0..n)
        .map(|i| {
            let y = y0 + (y1 - y0) * i as f32 / (n - 1).max(1) as f32;
            // theta = 0 at the back (-z), pi at the front (+z).
            let a = if y1 >= y0 { Vec3::Y } else { -Vec3::Y };
            let e1 = -Vec3::Z;
            Station { c: Vec3::new(xz[i].x, y, xz[i].y), a, e1, e2: a.cross(e1) }
        })
        .collect()
}

/// The point at arc length `s` along a polyline (extrapolated along the end segments outside `[0, length]`).
fn polyline_at(points: &[Vec3], s: f32) -> Vec3 {
    let dir = |k: usize| (points[k + 1] - points[k]).normalize_or(Vec3::Y);
    if s <= 0.0 || points.len() < 2 {
        return points[0] + if points.len() < 2 { Vec3::ZERO } else { dir(0) * s };
    }
    let mut acc = 0.0;
    for k in 0..points.len() - 1 {
        let l = points[k].distance(points[k + 1]);
        if s <= acc + l || k == points.len() - 2 {
            return points[k] + dir(k) * (s - acc);
        }
        acc += l;
    }
    points[points.len() - 1]
}

/// Stations along a polyline (bone heads) from arc length `s0` to `s1` (negative or past the end extrapolates),
/// frames parallel-transported from `hint`.
fn polyline_stations(points: &[Vec3], s0: f32, s1: f32, n: usize, hint: Vec3) -> Vec<Station> {
    let at = |s: f32| polyline_at(points, s);
    let mut out: Vec<Station> = Vec::with_capacity(n);
    let mut e1 = hint;
    for i in 0..n {
        let s = s0 + (s1 - s0) * i as f32 / (n - 1).max(1) as f32;
        let c = at(s);
        let a = (at(s + 0.6) - at(s - 0.6)).normalize_or(Vec3::Y) * (s1 - s0).signum();
        e1 = (e1 - a * e1.dot(a)).normalize_or(a.any_orthonormal_vector());
        out.push(Station { c, a, e1, e2: a.cross(e1) });
    }
    out
}

/// Replaces a tube vertex's transferred weights: `(station fraction, transferred weights, body vertex of the top
/// station's ray) -> weights`.
type WeightsOverride<'f> = dyn Fn(f32, &[(u16, f32)], usize) -> Vec<(u16, f32)> + 'f;

/// How a tube is cut and dressed.
struct TubeSpec<'f> {
    label: String,
    stations: Vec<Station>,
    cand: Vec<u32>,
    band: f32,
    bins: usize,
    segs: usize,
    /// Extra radius (dm) at station fraction `t` (0 = first station) and angle.
    extra: &'f dyn Fn(f32, f32) -> f32,
    /// Front opening (radians, centred at theta = pi), or a closed ring.
    gap: Option<f32>,
    thickness: f32,
    fold_start: bool,
    fold_end: bool,
    /// Replaces the transferred weights at (station fraction, transferred weights).
    weights: Option<&'f WeightsOverride<'f>>,
    look: Look,
    hang: bool,
}

/// Builds a tube garment (see the module docs).
fn tube(body: &BodyRest<'_>, spec: &TubeSpec<'_>) -> Garment {
    let prof = fit_profile(body, &spec.cand, &spec.stations, spec.band, spec.bins);
    let ns = spec.stations.len();
    let hem_depth = 0.35f32;
    // Rows: (station index, axial shift, radial offset, tint).
    let mut rows: Vec<(usize, f32, f32, f32)> = Vec::new();
    if spec.fold_start {
        rows.push((0, hem_depth, -spec.thickness, 0.7));
        rows.push((0, 0.0, -spec.thickness, 0.75));
    }
    rows.extend((0..ns).map(|i| (i, 0.0, 0.0, 1.0)));
    if spec.fold_end {
        rows.push((ns - 1, 0.0, -spec.thickness, 0.75));
        rows.push((ns - 1, -hem_depth, -spec.thickness, 0.7));
    }
    // Columns: (theta, radial offset, tint); closed rings repeat the first column at 2 pi (UV seam).
    let mut cols: Vec<(f32, f32, f32)> = Vec::new();
    match spec.gap {
        Some(g) => {
            let (t0, t1) = (PI + 0.5 * g, PI + TAU - 0.5 * g);
            cols.push((t0, -spec.thickness, 0.75));
            cols.extend((0..=spec.segs).map(|j| (t0 + (t1 - t0) * j as f32 / spec.segs as f32, 0.0, 1.0)));
            cols.push((t1, -spec.thickness, 0.75));
        }
        None => cols.extend((0..=spec.segs).map(|j| (TAU * j as f32 / spec.segs as f32, 0.0, 1.0))),
    }
    let nc = cols.len();
    let mut rest = Vec::with_capacity(rows.len() * nc);
    let mut tint = Vec::with_capacity(rows.len() * nc);
    let mut weights = Vec::with_capacity(rows.len() * nc);
    let mut uv = Vec::with_capacity(rows.len() * nc);
    let row_len: Vec<f32> = {
        let mut acc = vec![0.0f32; rows.len()];
        for k in 1..rows.len() {
            let (a, b) = (&spec.stations[rows[k - 1].0], &spec.stations[rows[k].0]);
            acc[k] = acc[k - 1] + (b.c + b.a * rows[k].1).distance(a.c + a.a * rows[k - 1].1).max(0.02);
        }
        acc
    };
    let length = row_len.last().copied().unwrap_or(1.0).max(1e-3);
    let mut circumference = 0.0f32;
    for (k, &(i, shift, dr_row, tint_row)) in rows.iter().enumerate() {
        let s = &spec.stations[i];
        let t = i as f32 / (ns - 1).max(1) as f32;
        for (j, &(th, dr_col, tint_col)) in cols.iter().enumerate() {
            let r = (prof.radius(i, th) + (spec.extra)(t, th) + dr_row + dr_col).max(0.05);
            rest.push(s.c + s.a * shift + s.dir(th) * r);
            tint.push(tint_row.min(tint_col));
            uv.push(Vec2::new(j as f32 / (nc - 1) as f32, row_len[k] / length));
            // Transferred weights: the body vertices behind this ray and its neighbours (3 stations x 3 bins).
            let b = prof.bin(th);
            let mut lists: Vec<(&[(u16, f32)], f32)> = Vec::with_capacity(9);
            for di in [i.saturating_sub(1), i, (i + 1).min(ns - 1)] {
                for db in [prof.bins - 1, 0, 1] {
                    let v = prof.src[di][(b + db) % prof.bins] as usize;
                    lists.push((&body.rig.weights[v], 1.0));
                }
            }
            let w = blend_weights(&lists);
            weights.push(match spec.weights {
                Some(f) => f(t, &w, prof.src[ns - 1][b] as usize),
                None => w,
            });
        }
        if k == rows.len() / 2 {
            circumference = (1..nc).map(|j| rest[k * nc + j].distance(rest[k * nc + j - 1])).sum();
        }
    }
    let mut triangles = Vec::with_capacity(2 * (rows.len() - 1) * (nc - 1));
    for k in 0..rows.len() - 1 {
        for j in 0..nc - 1 {
            let (a, b, c, d) = (
                (k * nc + j) as u32,
                (k * nc + j + 1) as u32,
                ((k + 1) * nc + j + 1) as u32,
                ((k + 1) * nc + j) as u32,
            );
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    orient_outward(
        &rest,
        &mut triangles,
        |p| {
            let s = &spec.stations[ns / 2];
            let d = p - s.c;
            d - s.a * d.dot(s.a)
        },
        (rows.len() / 2) * nc + nc / 2,
    );
    Garment {
        label: spec.label.clone(),
        rest,
        triangles,
        uv,
        extent: Vec2::new(circumference.max(0.5), length),
        weights,
        tint,
        look: spec.look,
        closed: false,
        hang: spec.hang.then_some(HangGrid { rows: rows.len(), cols: nc }),
    }
}

/// Flips every triangle when the ones around vertex `probe` face against `outward(p)`.
fn orient_outward(p: &[Vec3], tris: &mut [[u32; 3]], outward: impl Fn(Vec3) -> Vec3, probe: usize) {
    let mut score = 0.0;
    for t in tris.iter().filter(|t| t.contains(&(probe as u32))) {
        let [a, b, c] = t.map(|i| p[i as usize]);
        score += (b - a).cross(c - a).dot(outward((a + b + c) / 3.0));
    }
    if score < 0.0 {
        tris.iter_mut().for_each(|t| t.swap(1, 2));
    }
}

/// A closed star-shaped volume: `point(dir)` for unit directions `dir` in the local frame `axes` (x, y, z
/// columns) around `centre`, on a `stacks x slices` latitude-longitude grid (poles single points).
#[allow(clippy::too_many_arguments)]
fn volume(
    label: &str,
    centre: Vec3,
    axes: [Vec3; 3],
    stacks: usize,
    slices: usize,
    point: impl Fn(Vec3) -> Vec3,
    weights: impl Fn(Vec3) -> Vec<(u16, f32)>,
    look: Look,
) -> Garment {
    let mut rest = Vec::new();
    let mut uv = Vec::new();
    let mut local = Vec::new();
    for i in 0..=stacks {
        let phi = PI * i as f32 / stacks as f32;
        for j in 0..=slices {
            let th = TAU * j as f32 / slices as f32;
            // Exact poles, so each is one point whatever `point` does with the longitude.
            let d = match i {
                0 => Vec3::Y,
                i if i == stacks => -Vec3::Y,
                _ => Vec3::new(phi.sin() * th.cos(), phi.cos(), phi.sin() * th.sin()),
            };
            let q = point(d);
            local.push(q);
            rest.push(centre + axes[0] * q.x + axes[1] * q.y + axes[2] * q.z);
            uv.push(Vec2::new(j as f32 / slices as f32, i as f32 / stacks as f32));
        }
    }
    let nc = slices + 1;
    let mut triangles = Vec::new();
    for i in 0..stacks {
        for j in 0..slices {
            let (a, b, c, d) = (
                (i * nc + j) as u32,
                (i * nc + j + 1) as u32,
                ((i + 1) * nc + j + 1) as u32,
                ((i + 1) * nc + j) as u32,
            );
            if i != 0 {
                triangles.push([a, b, c]);
            }
            if i != stacks - 1 {
                triangles.push([a, c, d]);
            }
        }
    }
    // Outward: positive signed volume.
    let vol: f32 = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| rest[i as usize] - centre);
            a.dot(b.cross(c))
        })
        .sum();
    if vol < 0.0 {
        triangles.iter_mut().for_each(|t| t.swap(1, 2));
    }
    let (lo, hi) = rest.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(l, h), p| (l.min(*p), h.max(*p)));
    let size = hi - lo;
    let w = rest.iter().map(|&p| weights(p)).collect();
    let n = rest.len();
    Garment {
        label: label.to_string(),
        rest,
        triangles,
        uv,
        extent: Vec2::new(PI * 0.5 * (size.x + size.z).max(0.2), size.y.max(0.2) * 1.3),
        weights: w,
        tint: vec![1.0; n],
        look,
        closed: true,
        hang: None,
    }
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The head: centre of the cranium and the radius of the head surface per direction (a profile around the
/// vertical axis through the centre, bins over latitude and longitude).
struct HeadShape {
    centre: Vec3,
    stacks: usize,
    slices: usize,
    r: Vec<f32>,
}

impl HeadShape {
    fn new(body: &BodyRest<'_>) -> Self {
        let head = body.select(&[HEAD], |_| true);
        let top = head.iter().map(|&v| body.positions[v as usize].y).fold(f32::MIN, f32::max);
        let chin = body.head("head").y;
        let upper: Vec<Vec3> =
            head.iter().map(|&v| body.positions[v as usize]).filter(|p| p.y > chin + 0.5 * (top - chin)).collect();
        let mut centre = upper.iter().sum::<Vec3>() / upper.len().max(1) as f32;
        centre.y = chin + 0.55 * (top - chin);
        let (stacks, slices) = (16usize, 24usize);
        let mut r = vec![0.0f32; stacks * slices];
        for &v in head.iter().chain(body.select(&[NECK], |_| true).iter()) {
            let d = body.positions[v as usize] - centre;
            let len = d.length();
            if len < 1e-4 {
                continue;
            }
            let (i, j) = Self::bin(stacks, slices, d / len);
            r[i * slices + j] = r[i * slices + j].max(len);
        }
        // Fill empty bins from their ring (then from neighbouring rings), smooth.
        let mean = r.iter().filter(|&&x| x > 0.0).sum::<f32>() / r.iter().filter(|&&x| x > 0.0).count().max(1) as f32;
        for _ in 0..stacks {
            let old = r.clone();
            for i in 0..stacks {
                for j in 0..slices {
                    if old[i * slices + j] > 0.0 {
                        continue;
                    }
                    let nb = [
                        old[i * slices + (j + 1) % slices],
                        old[i * slices + (j + slices - 1) % slices],
                        old[i.saturating_sub(1) * slices + j],
                        old[(i + 1).min(stacks - 1) * slices + j],
                    ];
                    let (s, n) = nb.iter().filter(|&&x| x > 0.0).fold((0.0, 0), |(s, n), x| (s + x, n + 1));
                    if n > 0 {
                        r[i * slices + j] = s / n as f32;
                    }
                }
            }
        }
        r.iter_mut().filter(|x| **x == 0.0).for_each(|x| *x = mean);
        let old = r.clone();
        for i in 0..stacks {
            for j in 0..slices {
                let nb = old[i * slices + (j + 1) % slices]
                    + old[i * slices + (j + slices - 1) % slices]
                    + old[i.saturating_sub(1) * slices + j]
                    + old[(i + 1).min(stacks - 1) * slices + j];
                r[i * slices + j] = 0.5 * old[i * slices + j] + 0.125 * nb;
            }
        }
        Self { centre, stacks, slices, r }
    }

    fn bin(stacks: usize, slices: usize, d: Vec3) -> (usize, usize) {
        let phi = d.y.clamp(-1.0, 1.0).acos();
        let th = d.z.atan2(d.x).rem_euclid(TAU);
        let i = ((phi / PI * stacks as f32) as usize).min(stacks - 1);
        (i, ((th / TAU * slices as f32) as usize).min(slices - 1))
    }

    /// Head surface radius along unit direction `d` (from the centre).
    fn radius(&self, d: Vec3) -> f32 {
        let (i, j) = Self::bin(self.stacks, self.slices, d);
        self.r[i * self.slices + j]
    }
}

/// A cap over the cranium: the head surface pushed out by `volume` above a hairline and pulled inside the head
/// below it. `front`, `side` and `back` are the hairline heights as the `y` of the unit direction.
fn cap_point(head: &HeadShape, d: Vec3, volume: f32, front: f32, side: f32, back: f32) -> Vec3 {
    let line = if d.z >= 0.0 { side + (front - side) * d.z } else { side + (back - side) * (-d.z) };
    let s = smoothstep(line - 0.12, line + 0.05, d.y);
    let r = head.radius(d);
    d * (0.6 * r + s * (0.4 * r + volume))
}

/// The garments of an outfit around a rest body. `skin`, `hair`, `shoes`, `soles` are the painted layer's
/// colours (linear RGB).
pub fn build(body: &BodyRest<'_>, o: &Outfit, hair_color: [f32; 3], shoes: [f32; 3], soles: [f32; 3]) -> Vec<Garment> {
    let mut out = Vec::new();
    let hip_y = 0.5 * (body.head("upperleg01.L").y + body.head("upperleg01.R").y);
    let neck_y = body.head("neck01").y;
    let shoulder_y = 0.5 * (body.head("upperarm01.L").y + body.head("upperarm01.R").y);
    let th = o.thickness;
    let not_arm = |v: u32| body.parts[v as usize][UPPERARM] + body.parts[v as usize][LOWERARM] < 0.3;

    // Torso garments (tops, hoodies, jackets, dresses).
    if o.upper != UpperKind::None {
        let dress = o.upper == UpperKind::Dress;
        let hem = if dress { o.lower_hem.min(hip_y - 1.0) } else { hip_y + o.upper_hem };
        let parts: &[usize] = if dress { &[TORSO, PELVIS, NECK, THIGH, SHIN] } else { &[TORSO, PELVIS, NECK] };
        let cand: Vec<u32> = body.select(parts, |p| p.y < neck_y + 0.3).into_iter().filter(|&v| not_arm(v)).collect();
        let n = (((neck_y - hem) / 0.25).ceil() as usize).clamp(12, 60);
        let stations = vertical_stations(body, &cand, hem, neck_y - 0.05, n, 0.2);
        let (loose, flare, height) = (o.upper_loose, o.flare, neck_y - hem);
        let extra = move |t: f32, _th: f32| {
            let y = hem + t * height;
            let body_part = 0.08 + loose * (1.0 - smoothstep(hem, shoulder_y, y)).powf(1.2);
            let skirt =
                if dress { flare * ((hip_y - y) / (hip_y - hem).max(0.1)).clamp(0.0, 1.0).powi(2) } else { 0.0 };
            body_part + skirt
        };
        let legs = blend_weights(&[(&body.bone_weight("upperleg01.L"), 0.5), (&body.bone_weight("upperleg01.R"), 0.5)]);
        let pelvis = body.bone_weight("spine05");
        let dress_weights = |t: f32, w: &[(u16, f32)], _top: usize| {
            let y = hem + t * height;
            if y >= hip_y {
                return w.to_vec();
            }
            let down = ((hip_y - y) / (hip_y - hem).max(0.1)).clamp(0.0, 1.0);
            blend_weights(&[(&pelvis, 1.0 - 0.5 * down), (&legs, 0.5 * down)])
        };
        let gap = (o.upper == UpperKind::OpenJacket).then_some(o.opening);
        out.push(tube(
            body,
            &TubeSpec {
                label: if dress { "dress".into() } else { "top".into() },
                stations,
                cand,
                band: 0.3,
                bins: 48,
                segs: 48,
                extra: &extra,
                gap,
                thickness: th,
                fold_start: true,
                fold_end: true,
                weights: if dress { Some(&dress_weights) } else { None },
                look: Look::Fabric(o.upper_fabric),
                hang: dress,
            },
        ));
        // Sleeves.
        let sleeve_end = match o.upper {
            UpperKind::Tee | UpperKind::Dress => Some(0.5),
            UpperKind::LongSleeve | UpperKind::Hoodie | UpperKind::OpenJacket => Some(1.95),
            UpperKind::None => None,
        };
        if let Some(end) = sleeve_end {
            for side in ["L", "R"] {
                let sign = if side == "L" { 1.0 } else { -1.0 };
                let chain = [
                    body.head(&format!("upperarm01.{side}")),
                    body.head(&format!("lowerarm01.{side}")),
                    body.head(&format!("wrist.{side}")),
                ];
                let upper_len = chain[0].distance(chain[1]);
                let s1 =
                    if end <= 1.0 { end * upper_len } else { upper_len + (end - 1.0) * chain[1].distance(chain[2]) };
                let n = ((s1 + 0.5) / 0.3).ceil().clamp(6.0, 30.0) as usize;
                let s0 = -1.0;
                let stations = polyline_stations(&chain, s0, s1, n, Vec3::Y);
                let cand = body.select(&[UPPERARM, LOWERARM], |p| p.x * sign > 0.0);
                let loose = o.upper_loose;
                // A wide armhole (the first decimetre), then the sleeve widening a little toward the cuff.
                let armhole = 1.0 / (s1 - s0).max(1.0);
                let extra = move |t: f32, _th: f32| 0.1 + 0.35 * loose * t + 0.2 * (1.0 - t / armhole).max(0.0);
                out.push(tube(
                    body,
                    &TubeSpec {
                        label: format!("sleeve.{side}"),
                        stations,
                        cand,
                        band: 0.25,
                        bins: 24,
                        segs: 24,
                        extra: &extra,
                        gap: None,
                        thickness: th,
                        fold_start: false,
                        fold_end: true,
                        weights: None,
                        look: Look::Fabric(o.upper_fabric),
                        hang: false,
                    },
                ));
            }
        }
    }

    // Leg garments.
    let waist_y = body.head("spine04").y;
    match o.lower {
        LowerKind::Skirt => {
            let cand = body.select(&[PELVIS, THIGH, SHIN, TORSO], |p| p.y < waist_y + 0.4);
            let hem = o.lower_hem.min(hip_y - 0.8);
            let n = (((waist_y - hem) / 0.25).ceil() as usize).clamp(10, 40);
            let stations = vertical_stations(body, &cand, hem, waist_y, n, 0.2);
            let (loose, flare) = (o.lower_loose, o.flare);
            let extra = move |t: f32, _th: f32| {
                let down = 1.0 - t;
                0.08 + loose * down.powf(0.8) + flare * down * down
            };
            let legs =
                blend_weights(&[(&body.bone_weight("upperleg01.L"), 0.5), (&body.bone_weight("upperleg01.R"), 0.5)]);
            let pelvis = body.bone_weight("spine05");
            let weights = move |t: f32, _w: &[(u16, f32)], _top: usize| {
                let down = 1.0 - t;
                blend_weights(&[(&pelvis, 1.0 - 0.5 * down), (&legs, 0.5 * down)])
            };
            out.push(tube(
                body,
                &TubeSpec {
                    label: "skirt".into(),
                    stations,
                    cand,
                    band: 0.3,
                    bins: 48,
                    segs: 56,
                    extra: &extra,
                    gap: None,
                    thickness: th,
                    fold_start: true,
                    fold_end: true,
                    weights: Some(&weights),
                    look: Look::Fabric(o.lower_fabric),
                    hang: true,
                },
            ));
        }
        LowerKind::WideTrousers | LowerKind::Shorts => {
            // Hips to the crotch, then one tube per leg.
            let crotch = hip_y - 0.9;
            let cand = body.select(&[PELVIS, THIGH, TORSO], |p| p.y < waist_y + 0.4 && p.y > crotch - 0.6);
            let stations = vertical_stations(body, &cand, crotch, waist_y, 10, 0.2);
            let loose = o.lower_loose;
            let extra = move |t: f32, _th: f32| 0.08 + 0.3 * loose * (1.0 - t);
            out.push(tube(
                body,
                &TubeSpec {
                    label: "hips".into(),
                    stations,
                    cand,
                    band: 0.25,
                    bins: 48,
                    segs: 48,
                    extra: &extra,
                    gap: None,
                    thickness: th,
                    fold_start: false,
                    fold_end: true,
                    weights: None,
                    look: Look::Fabric(o.lower_fabric),
                    hang: false,
                },
            ));
            for side in ["L", "R"] {
                let sign = if side == "L" { 1.0 } else { -1.0 };
                let chain = [
                    body.head(&format!("upperleg01.{side}")),
                    body.head(&format!("lowerleg01.{side}")),
                    body.head(&format!("foot.{side}")),
                ];
                let total = chain[0].distance(chain[1]) + chain[1].distance(chain[2]);
                // Arc length where the leg reaches the hem height.
                let hem_y = if o.lower == LowerKind::Shorts { o.lower_hem } else { chain[2].y + 0.45 };
                let mut s1 = total;
                for k in 0..200 {
                    let s = total * k as f32 / 199.0;
                    if polyline_at(&chain, s).y <= hem_y {
                        s1 = s;
                        break;
                    }
                }
                let n = ((s1 + 0.5) / 0.3).ceil().clamp(6.0, 40.0) as usize;
                let stations = polyline_stations(&chain, 0.2, s1, n, Vec3::Z);
                let cand = body.select(&[THIGH, SHIN], |p| p.x * sign > 0.0);
                let wide = o.lower == LowerKind::WideTrousers;
                let extra = move |t: f32, _th: f32| 0.1 + loose * if wide { 0.3 + 0.9 * t } else { 0.3 + 0.4 * t };
                out.push(tube(
                    body,
                    &TubeSpec {
                        label: format!("leg.{side}"),
                        stations,
                        cand,
                        band: 0.25,
                        bins: 32,
                        segs: 32,
                        extra: &extra,
                        gap: None,
                        thickness: th,
                        fold_start: false,
                        fold_end: true,
                        weights: None,
                        look: Look::Fabric(o.lower_fabric),
                        hang: false,
                    },
                ));
            }
        }
        LowerKind::None => {}
    }

    // Hair, hats and hoods.
    let head = HeadShape::new(body);
    let hc = head.centre;
    let axes = [Vec3::X, Vec3::Y, Vec3::Z];
    let head_w = body.bone_weight("head");
    let hair_look = Look::Hair(hair_color);
    let hood_up = o.upper == UpperKind::Hoodie && o.hood_up;
    if !hood_up {
        let vol = o.hair_volume;
        let hw = head_w.clone();
        out.push(volume(
            "hair",
            hc,
            axes,
            20,
            32,
            |d| cap_point(&head, d, vol, 0.42, 0.05, -0.45),
            |_| hw.clone(),
            hair_look,
        ));
        let len = o.hair_length;
        match o.hair {
            HairKind::Bob | HairKind::Long => {
                // A bell from the ear line down to `len` below the centre, behind the face.
                let long = o.hair == HairKind::Long;
                let depth = if long { len + 1.8 } else { len.min(2.2) };
                let neck_w = body.bone_weight("neck01");
                let spine_w = body.bone_weight("spine01");
                let (spread, lean) = if long { (0.35, 0.6) } else { (0.12, 0.1) };
                let point = |d: Vec3| {
                    if d.z > 0.3 {
                        return d * head.radius(d) * 0.8; // the face side stays inside the head
                    }
                    if d.y > 0.25 {
                        return d * head.radius(d) * 0.9; // under the cap
                    }
                    let horiz = Vec3::new(d.x, 0.0, d.z).normalize_or(-Vec3::Z);
                    let r_h = head.radius(horiz);
                    let top = 0.25 * r_h;
                    // Down the bell from the cap to `depth` below the centre, then a bottom closing to the axis.
                    let (f, close) = if d.y >= -0.7 { ((0.25 - d.y) / 0.95, 1.0) } else { (1.0, (d.y + 1.0) / 0.3) };
                    let radius = (r_h + vol) * (1.0 + spread * f) * close;
                    horiz * radius + Vec3::new(0.0, top + (-depth - top) * f, -lean * f)
                };
                let hw2 = head_w.clone();
                let weights = move |p: Vec3| {
                    let down = ((hc.y - p.y) / depth.max(0.1)).clamp(0.0, 1.0);
                    if long {
                        blend_weights(&[(&hw2, 1.0 - down), (&neck_w, 0.5 * down), (&spine_w, 0.5 * down)])
                    } else {
                        blend_weights(&[(&hw2, 1.0 - 0.5 * down), (&neck_w, 0.5 * down)])
                    }
                };
                out.push(volume(
                    if long { "hair.long" } else { "hair.bob" },
                    hc,
                    axes,
                    24,
                    36,
                    point,
                    weights,
                    hair_look,
                ));
            }
            HairKind::Ponytail => {
                let back = head.radius(-Vec3::Z);
                let root = hc + Vec3::new(0.0, 0.3, -back);
                let dir = Vec3::new(0.0, -1.0, -0.25).normalize();
                let l = len.clamp(1.5, 3.5);
                let centre = root + dir * (0.5 * l);
                let ax = [Vec3::X, -dir, Vec3::X.cross(-dir)];
                let w = head_w.clone();
                let r0 = 0.35 + 0.4 * o.hair_volume;
                out.push(volume(
                    "hair.ponytail",
                    centre,
                    ax,
                    16,
                    16,
                    |d| {
                        let taper = 1.0 - 0.5 * (0.5 - 0.5 * d.y);
                        Vec3::new(d.x * r0 * taper, d.y * 0.5 * l, d.z * r0 * taper)
                    },
                    |_| w.clone(),
                    hair_look,
                ));
            }
            HairKind::Bun => {
                let up = Vec3::new(0.0, 0.75, -0.66).normalize();
                let centre = hc + up * (head.radius(up) + 0.2);
                let rb = 0.5 + 0.6 * o.hair_volume;
                let w = head_w.clone();
                out.push(volume("hair.bun", centre, axes, 12, 16, |d| d * rb, |_| w.clone(), hair_look));
            }
            HairKind::Short => {}
        }
    }
    match o.hat {
        HatKind::None => {}
        kind => {
            let w = head_w.clone();
            let look = Look::Fabric(o.hat_fabric);
            let vol = 0.15 + o.hair_volume;
            let (front, side, back) = match kind {
                HatKind::Beanie => (0.45, 0.1, -0.1),
                _ => (0.5, 0.25, 0.1),
            };
            out.push(volume(
                "hat",
                hc,
                axes,
                20,
                32,
                |d| cap_point(&head, d, vol, front, side, back),
                |_| w.clone(),
                look,
            ));
            let r_front = head.radius(Vec3::Z);
            let brim_y = {
                let d = Vec3::new(0.0, 0.5, 0.87);
                (d * (head.radius(d) + vol)).y - 0.05
            };
            match kind {
                HatKind::Cap => {
                    let c = hc + Vec3::new(0.0, brim_y, r_front * 0.85 + 0.55);
                    let w = head_w.clone();
                    out.push(volume(
                        "hat.brim",
                        c,
                        axes,
                        8,
                        24,
                        |d| Vec3::new(d.x * 1.05, d.y * 0.06, d.z * 0.85),
                        |_| w.clone(),
                        look,
                    ));
                }
                HatKind::WideBrim => {
                    let rr = head.radius(Vec3::X).max(r_front) + 1.1 + o.hair_volume;
                    let c = hc + Vec3::new(0.0, brim_y - 0.1, 0.0);
                    let w = head_w.clone();
                    out.push(volume(
                        "hat.brim",
                        c,
                        axes,
                        8,
                        40,
                        |d| Vec3::new(d.x * rr, d.y * 0.06, d.z * rr),
                        |_| w.clone(),
                        look,
                    ));
                }
                _ => {}
            }
        }
    }
    if o.upper == UpperKind::Hoodie {
        let look = Look::Fabric(o.upper_fabric);
        let neck_w = body.bone_weight("neck01");
        let spine_w = body.bone_weight("spine01");
        if hood_up {
            let w = head_w.clone();
            let vol = 0.35 + o.upper_loose * 0.3;
            out.push(volume(
                "hood",
                hc,
                axes,
                20,
                32,
                |d| {
                    // Around the head and down to the neck, open at the face.
                    let p = cap_point(&head, d, vol, 0.55, -0.55, -0.95);
                    if d.y < -0.5 && d.z < 0.3 {
                        p * (1.0 + 0.4 * (-d.y - 0.5))
                    } else {
                        p
                    }
                },
                move |p| {
                    let down = ((hc.y - p.y) / 2.0).clamp(0.0, 1.0);
                    blend_weights(&[(&w, 1.0 - down), (&neck_w, down)])
                },
                look,
            ));
        } else {
            let back_z = body
                .select(&[TORSO, NECK], |p| (p.y - neck_y).abs() < 0.5)
                .iter()
                .map(|&v| body.positions[v as usize].z)
                .fold(f32::MAX, f32::min);
            let c = Vec3::new(0.0, neck_y - 0.3, back_z - 0.25);
            let w = spine_w.clone();
            out.push(volume(
                "hood",
                c,
                axes,
                12,
                24,
                |d| Vec3::new(d.x * 1.5, d.y * 0.9, d.z * 0.55),
                |_| w.clone(),
                look,
            ));
        }
    }

    // Shoes and boots.
    if o.shoes != ShoeKind::None {
        for side in ["L", "R"] {
            let sign = if side == "L" { 1.0 } else { -1.0 };
            let foot = body.select(&[FOOT], |p| p.x * sign > 0.0);
            let (lo, hi) = foot.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(l, h), &v| {
                let p = body.positions[v as usize];
                (l.min(p), h.max(p))
            });
            if lo.x > hi.x {
                continue;
            }
            let sole = 0.14;
            let c = 0.5 * (lo + hi) - Vec3::Y * 0.5 * sole;
            let half = 0.5 * (hi - lo) + Vec3::new(0.15, 0.5 * sole + 0.1, 0.18);
            let w = body.bone_weight(&format!("foot.{side}"));
            let look = Look::Shoe { upper: shoes, sole: soles, sole_y: lo.y + 0.05 };
            out.push(volume(
                &format!("shoe.{side}"),
                c,
                axes,
                12,
                24,
                |d| {
                    // A rounded box (superellipsoid, exponent 4).
                    let k = (d.x.powi(4) + d.y.powi(4) + d.z.powi(4)).powf(0.25).max(1e-3);
                    (d / k) * half
                },
                |_| w.clone(),
                look,
            ));
            if o.shoes == ShoeKind::Boots {
                let chain = [body.head(&format!("lowerleg01.{side}")), body.head(&format!("foot.{side}"))];
                let len = chain[0].distance(chain[1]);
                let stations = polyline_stations(&chain, len + 0.2, len * 0.4, 8, Vec3::Z);
                let cand = body.select(&[SHIN, FOOT], |p| p.x * sign > 0.0);
                let extra = |_t: f32, _th: f32| 0.24;
                out.push(tube(
                    body,
                    &TubeSpec {
                        label: format!("boot.{side}"),
                        stations,
                        cand,
                        band: 0.25,
                        bins: 24,
                        segs: 24,
                        extra: &extra,
                        gap: None,
                        thickness: 0.06,
                        fold_start: false,
                        fold_end: true,
                        weights: None,
                        look: Look::Shoe { upper: shoes, sole: soles, sole_y: f32::MIN },
                        hang: false,
                    },
                ));
            }
        }
    }

    // A backpack with two straps over the shoulders.
    if o.bag == BagKind::Backpack {
        let back: Vec<u32> = body.select(&[TORSO], |p| (p.y - shoulder_y + 1.8).abs() < 1.2);
        // Over the top's cloth: its looseness at mid-back plus the cloth thickness.
        let over = if o.upper == UpperKind::None { 0.05 } else { 0.12 + 0.6 * o.upper_loose + o.thickness };
        let back_z = back.iter().map(|&v| body.positions[v as usize].z).fold(f32::MAX, f32::min) - over;
        let depth = 0.5 + 0.4 * o.upper_loose;
        let c = Vec3::new(0.0, shoulder_y - 2.0, back_z - depth - 0.05);
        let half = Vec3::new(1.3, 1.8, depth);
        let w = body.bone_weight("spine02");
        let look = Look::Fabric(o.bag_fabric);
        out.push(volume(
            "backpack",
            c,
            axes,
            12,
            24,
            |d| {
                let k = (d.x.powi(4) + d.y.powi(4) + d.z.powi(4)).powf(0.25).max(1e-3);
                (d / k) * half
            },
            |_| w.clone(),
            look,
        ));
        for side in [1.0f32, -1.0] {
            let x = side * 0.95;
            let cand = body.select(&[TORSO, NECK, PELVIS], |p| p.y > c.y - 0.5 && (p.x - x).abs() < 0.5);
            let a = Vec3::X * side;
            let e1 = Vec3::Y;
            let centre = Vec3::new(x, shoulder_y - 0.9, 0.5 * (back_z + over + 0.8));
            let stations: Vec<Station> =
                (0..4).map(|k| Station { c: centre + a * (-0.3 + 0.2 * k as f32), a, e1, e2: a.cross(e1) }).collect();
            let extra = move |_t: f32, _th: f32| 0.08 + over;
            out.push(tube(
                body,
                &TubeSpec {
                    label: format!("strap.{}", if side > 0.0 { "L" } else { "R" }),
                    stations,
                    cand,
                    band: 0.3,
                    bins: 40,
                    segs: 40,
                    extra: &extra,
                    gap: None,
                    thickness: 0.06,
                    fold_start: true,
                    fold_end: true,
                    weights: None,
                    look,
                    hang: false,
                },
            ));
        }
    }
    out
}

/// Linear blend skinning of points with their own weights (the body's formula, [`Rig::skin`]).
pub fn skin_points(points: &[Vec3], weights: &[Vec<(u16, f32)>], transforms: &[Affine3A]) -> Vec<Vec3> {
    points
        .iter()
        .zip(weights)
        .map(|(&p, list)| {
            if list.is_empty() {
                p
            } else {
                list.iter().map(|&(b, w)| w * transforms[b as usize].transform_point3(p)).sum()
            }
        })
        .collect()
}

/// Poses every garment with the body's skinning transforms, then pushes the rings of hanging pieces (skirts,
/// dresses) radially out of the posed legs (`posed_body`: base-mesh body vertices, `parts` their part weights).
pub fn pose_garments(
    garments: &[Garment],
    transforms: &[Affine3A],
    posed_body: &[Vec3],
    parts: &[[f32; 10]],
) -> Vec<Vec<Vec3>> {
    let legs: Vec<Vec3> =
        posed_body.iter().zip(parts).filter(|(_, w)| w[THIGH] + w[SHIN] > 0.5).map(|(p, _)| *p).collect();
    garments
        .iter()
        .map(|g| {
            let mut posed = skin_points(&g.rest, &g.weights, transforms);
            if let Some(grid) = &g.hang {
                push_out_of(&mut posed, grid, &legs, 0.12);
            }
            posed
        })
        .collect()
}

/// Pushes each ring of a hanging grid out of `obstacles` (radially from the ring's centre, in the horizontal
/// plane, with `margin`), then lets no ring be narrower in a direction than the ring above it minus its drop, so
/// the cloth hangs over what it was pushed by.
fn push_out_of(posed: &mut [Vec3], grid: &HangGrid, obstacles: &[Vec3], margin: f32) {
    const BINS: usize = 64;
    let (rows, cols) = (grid.rows, grid.cols);
    // Rows run from the hem (0) up; process from the top down.
    let mut prev: Option<Vec<f32>> = None;
    for k in (0..rows).rev() {
        let ring = &posed[k * cols..(k + 1) * cols];
        let centre = ring.iter().sum::<Vec3>() / cols as f32;
        let mut need = [0.0f32; BINS];
        let y_band = 0.3;
        for p in obstacles {
            if (p.y - centre.y).abs() > y_band {
                continue;
            }
            let d = Vec2::new(p.x - centre.x, p.z - centre.z);
            let b = ((d.y.atan2(d.x).rem_euclid(TAU) / TAU * BINS as f32) as usize).min(BINS - 1);
            need[b] = need[b].max(d.length() + margin);
        }
        let mut radii = vec![0.0f32; cols];
        for j in 0..cols {
            let p = posed[k * cols + j];
            let d = Vec2::new(p.x - centre.x, p.z - centre.z);
            let len = d.length();
            let b = ((d.y.atan2(d.x).rem_euclid(TAU) / TAU * BINS as f32) as usize).min(BINS - 1);
            let mut req = need[(b + BINS - 1) % BINS].max(need[b]).max(need[(b + 1) % BINS]);
            if let Some(pr) = &prev {
                req = req.max(pr[j] - 0.15);
            }
            let r = len.max(req);
            radii[j] = r;
            if len > 1e-5 && r > len {
                let q = d * (r / len);
                posed[k * cols + j] = Vec3::new(centre.x + q.x, p.y, centre.z + q.y);
            }
        }
        prev = Some(radii);
    }
}

/// Linear RGB of a garment texel at rest position `p` (dm) with brightness `tint`.
pub fn look_color(look: &Look, p: Vec3, tint: f32) -> Vec3 {
    let c = match look {
        Look::Fabric(f) => super::texture::fabric_color(f, p),
        Look::Hair(h) => {
            let strands = Vec3::new(p.x * 30.0, p.y * 3.0, p.z * 30.0);
            Vec3::from(*h) * (0.8 + 0.35 * super::texture::value_noise(0x4a17, strands))
        }
        Look::Shoe { upper, sole, sole_y } => {
            if p.y < *sole_y {
                Vec3::from(*sole)
            } else {
                Vec3::from(*upper) * (0.95 + 0.1 * super::texture::value_noise(0x5e0, p * 10.0))
            }
        }
    };
    c * tint.clamp(0.0, 1.5)
}

/// Places rectangles of physical size `extents` (any unit) into the unit square at one common scale, on shelves,
/// with `gutter` (unit-square units) around each. Returns `(origin, size)` per rectangle, in input order.
pub fn pack_atlas(extents: &[Vec2], gutter: f32) -> Vec<(Vec2, Vec2)> {
    let mut order: Vec<usize> = (0..extents.len()).collect();
    order.sort_by(|&a, &b| extents[b].y.total_cmp(&extents[a].y).then(a.cmp(&b)));
    let place = |s: f32| -> Option<Vec<(Vec2, Vec2)>> {
        let mut out = vec![(Vec2::ZERO, Vec2::ZERO); extents.len()];
        let (mut x, mut y, mut shelf) = (gutter, gutter, 0.0f32);
        for &i in &order {
            let size = extents[i].max(Vec2::splat(1e-3)) * s;
            if size.x + 2.0 * gutter > 1.0 {
                return None;
            }
            if x + size.x + gutter > 1.0 {
                x = gutter;
                y += shelf + gutter;
                shelf = 0.0;
            }
            if y + size.y + gutter > 1.0 {
                return None;
            }
            out[i] = (Vec2::new(x, y), size);
            x += size.x + gutter;
            shelf = shelf.max(size.y);
        }
        Some(out)
    };
    let (mut lo, mut hi) = (0.0f32, 1.0f32);
    while place(hi).is_some() && hi < 1e6 {
        hi *= 2.0;
    }
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if place(mid).is_some() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    place(lo).unwrap_or_else(|| vec![(Vec2::ZERO, Vec2::ZERO); extents.len()])
}
