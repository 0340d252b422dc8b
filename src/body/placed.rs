//! The silhouette-inflation prior placed in depth by the fitted body (`--geometry body-placed`): what the
//! pipeline draws is the inflation prior with the face relief ([`super::face`]) and each column moved toward the
//! fitted body's depth only as far as the fit can be trusted there ([`placement_confidence`], [`confident_shifts`]);
//! with a placement network in the model folder (`placement.onnx`), every column moved by that network's shift
//! instead ([`place`]).
//!
//! Why a confidence. Reduce every column of a person to one interval (its occupied length about its occupied
//! centroid) and the ground truth loses little, so a geometry is mostly a thickness and a depth per column, and the
//! inflation prior's thickness at the true depths would gain a lot (`cargo run --release --example
//! geometry_oracle`). The fitted body's depths carry that on the synthetic (MakeHuman) people the fit is made of;
//! on people it was not made on (the UFO: Alien Invasion civilians of `scripts/scan-ufoai.sh`) the least-squares
//! scale of the body's per-column depths that best fits the truth was negative, and moving every column halfway
//! toward the body's depth ([`PLACEMENT_WEIGHT`], the earlier fixed rule) lost 0.57 / 0.36 dB of whole-frame PSNR
//! at close / divergent views on that dev half. So a column moves only where four things hold at once: the posed
//! body agrees with the silhouette as a whole, covers the column, explains its thickness (no coat, skirt, armour or
//! prop the body does not fill), and the pose network sees the limb nearest the column. And it moves only relative
//! to the rest of its image row ([`Reference::Row`]): what one frontal view says least, the body's lean, moves
//! nothing; an arm ahead of the chest or one leg ahead of the other does. No column moves more than
//! [`MAX_SHIFT_OF_THICKNESS`] of its own thickness, so a wrong placement still overlaps the prior's column. Where
//! the fit is unsure every column stays at the prior's depth; on the Nexuiz dev players the confidence is zero on
//! three of five (the posed body covers their silhouettes too poorly).
//!
//! [`depth_shifts`] is the earlier rule, kept for the diagnostics that compare against it
//! (`examples/fit_ambiguity.rs`). Depths are measured about the body's own volume, so a placement moves columns
//! against each other and not the person as a whole (the pipeline centres the result by the depth convention
//! afterwards, [`centred`]).

use crate::buffer::{GrayImage, Image};
use crate::geometry::depth_centre::{centring_shift, intervals_centroid_z, MIN_SHIFT};
use crate::geometry::inflate::InflatedSurfaces;
use glam::Vec2;

/// The fraction of the way from the inflation prior's depth to the body's that a fully trusted column moves
/// ([`confident_shifts`]; the earlier fixed rule moved every column this far, module docs).
pub const PLACEMENT_WEIGHT: f32 = 0.5;

/// The depth (body-cube z) each column moves by: `weight` times its centroid in `body` (the reconciled body
/// intervals, [`super::prior::body_intervals_with`]) less the centroid of all of `body`'s volume, both over the
/// columns inside `mask` (above 0.5). A column of the mask `body` leaves empty (the inflation prior's mask differs
/// from the body's by cleaned-away specks) takes the mean shift of its 8 neighbours that have one, otherwise 0;
/// outside `mask` the shift is 0. `None` when `body` holds no volume or its grid differs from `mask`'s.
pub fn depth_shifts(body: &Image<Vec<(f32, f32)>>, mask: &GrayImage, weight: f32) -> Option<GrayImage> {
    let (w, h) = (mask.width, mask.height);
    if (body.width, body.height) != (w, h) || body.data.len() != w * h || !weight.is_finite() {
        return None;
    }
    let inside = |i: usize| mask.data[i] > 0.5;
    let (mean, _, _) = intervals_centroid_z((0..w * h).filter(|&i| inside(i)).map(|i| body.data[i].as_slice()))?;
    let own: Vec<Option<f32>> = (0..w * h)
        .map(|i| {
            let column = intervals_centroid_z(std::iter::once(body.data[i].as_slice()));
            column.filter(|_| inside(i)).map(|(c, _, _)| weight * (c - mean))
        })
        .collect();
    Some(Image::from_fn(w, h, |c, r| {
        if !inside(r * w + c) {
            return 0.0;
        }
        if let Some(s) = own[r * w + c] {
            return s;
        }
        let (mut sum, mut count) = (0.0f32, 0u32);
        for (dc, dr) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
            let (cc, rr) = (c as i64 + dc, r as i64 + dr);
            if (0..w as i64).contains(&cc) && (0..h as i64).contains(&rr) {
                if let Some(s) = own[rr as usize * w + cc as usize] {
                    sum += s;
                    count += 1;
                }
            }
        }
        if count > 0 {
            sum / count as f32
        } else {
            0.0
        }
    }))
}

/// Below this share of the posed body's own columns agreeing with the person's mask (intersection over union) no
/// column is trusted; [`TRUSTED_AGREEMENT`] and above, fully ([`placement_confidence`]).
pub const UNTRUSTED_AGREEMENT: f32 = 0.6;
/// The agreement of the posed body with the mask at which the fit is fully trusted.
pub const TRUSTED_AGREEMENT: f32 = 0.8;
/// A column whose body thickness is this fraction of the inflation prior's or less is not explained by the body (a
/// coat, a skirt, armour, a prop): no trust there.
pub const UNEXPLAINED_THICKNESS: f32 = 0.4;
/// A column whose body thickness is this fraction of the inflation prior's or more is explained by the body.
pub const EXPLAINED_THICKNESS: f32 = 0.7;
/// Visibility of the nearest skeleton segment's less visible end at or below which its columns are not trusted.
pub const UNSEEN_VISIBILITY: f32 = 0.5;
/// Visibility at or above which the nearest segment is fully trusted.
pub const SEEN_VISIBILITY: f32 = 0.9;
/// The farthest a column moves, as a fraction of its own thickness in the inflation prior: a wrong placement still
/// overlaps the prior's column by at least half.
pub const MAX_SHIFT_OF_THICKNESS: f32 = 0.5;

/// 0 at or below `lo`, 1 at or above `hi`, linear between; 0 for NaN.
pub fn ramp(x: f32, lo: f32, hi: f32) -> f32 {
    if x.is_nan() {
        return 0.0;
    }
    if hi <= lo {
        return if x >= hi { 1.0 } else { 0.0 };
    }
    ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
}

/// Total occupied length of one column's intervals (empty, reversed and non-finite intervals count nothing).
fn length(intervals: &[(f32, f32)]) -> f32 {
    intervals.iter().filter(|(a, b)| a.is_finite() && b.is_finite() && b > a).map(|(a, b)| b - a).sum()
}

/// Distance from `p` to the segment `a`–`b`.
fn segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f32 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + t * ab)
}

/// How far the fitted body's depth can be trusted at each column of the inflation prior `surfaces`, in `[0, 1]`
/// (0 outside the mask): the product of
/// - the fit's agreement with the silhouette: the intersection over union of the columns `own` covers (the posed
///   body's own intervals, [`crate::geometry::fof::intervals_from_mesh`], not reconciled) and the mask, ramped
///   from [`UNTRUSTED_AGREEMENT`] to [`TRUSTED_AGREEMENT`] ([`ramp`]);
/// - whether the body covers the column at all (0 where only the silhouette says there is something);
/// - whether the body explains the column's thickness: its own length over the prior's, ramped from
///   [`UNEXPLAINED_THICKNESS`] to [`EXPLAINED_THICKNESS`] (a garment or prop the body does not fill gets none);
/// - how well the pose network sees the part: the lower visibility of the two ends of the [`SKELETON`] segment
///   nearest the column's centre (image distance), ramped from [`UNSEEN_VISIBILITY`] to [`SEEN_VISIBILITY`].
///
/// `None` when the grids differ or the landmarks lack the skeleton's points.
///
/// [`SKELETON`]: super::pose::SKELETON
pub fn placement_confidence(
    own: &Image<Vec<(f32, f32)>>,
    surfaces: &InflatedSurfaces,
    landmarks: &super::pose::PoseLandmarks,
) -> Option<GrayImage> {
    let (w, h) = (surfaces.mask.width, surfaces.mask.height);
    let grids = [
        (own.width, own.height),
        (surfaces.front.width, surfaces.front.height),
        (surfaces.back.width, surfaces.back.height),
    ];
    if grids.iter().any(|&g| g != (w, h)) || own.data.len() != w * h {
        return None;
    }
    let points = &landmarks.landmarks;
    let segments: Vec<(Vec2, Vec2, f32)> = super::pose::SKELETON
        .iter()
        .map(|&(a, b)| {
            let (a, b) = (points.get(a)?, points.get(b)?);
            Some((a.pixel, b.pixel, a.visibility.min(b.visibility)))
        })
        .collect::<Option<_>>()?;
    let inside = |i: usize| surfaces.mask.data[i] > 0.5;
    let covered = |i: usize| length(&own.data[i]) > 0.0;
    let (mut both, mut either) = (0usize, 0usize);
    for i in 0..w * h {
        both += (inside(i) && covered(i)) as usize;
        either += (inside(i) || covered(i)) as usize;
    }
    let agreement = if either > 0 { both as f32 / either as f32 } else { 0.0 };
    let trust = ramp(agreement, UNTRUSTED_AGREEMENT, TRUSTED_AGREEMENT);
    Some(Image::from_fn(w, h, |c, r| {
        let i = r * w + c;
        if trust == 0.0 || !inside(i) || !covered(i) {
            return 0.0;
        }
        let prior = surfaces.front.data[i] - surfaces.back.data[i];
        let explained = if prior > 0.0 {
            ramp(length(&own.data[i]) / prior, UNEXPLAINED_THICKNESS, EXPLAINED_THICKNESS)
        } else {
            1.0
        };
        let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
        let nearest = segments
            .iter()
            .map(|&(a, b, v)| (segment_distance(p, a, b), v))
            .filter(|(d, _)| d.is_finite())
            .min_by(|x, y| x.0.total_cmp(&y.0));
        let seen = nearest.map_or(0.0, |(_, v)| ramp(v, UNSEEN_VISIBILITY, SEEN_VISIBILITY));
        trust * explained * seen
    }))
}

/// How columns are moved from the prior's depth toward the body's ([`confident_shifts`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reference {
    /// About the centroid of all of the body's trusted volume: the body's lean and the head ahead of the feet move
    /// columns too.
    Whole,
    /// About the centroid of the body's trusted volume in the column's own image row: only what lies ahead of or
    /// behind the rest at the same height moves (an arm before the chest, one leg ahead of the other); the body's
    /// lean, which one frontal view hardly says, moves nothing.
    Row,
}

/// The depth (body-cube z) each column moves by under a confidence map: `weight × confidence × (c − c̄)`, `c` the
/// column's centroid in `own` (the posed body's own intervals), `c̄` the confidence-weighted centroid of the body's
/// volume (the whole of it or the column's row, `reference`), limited to [`MAX_SHIFT_OF_THICKNESS`] of the
/// column's thickness in `surfaces` (the inflation prior). 0 where the confidence is 0 or the body holds nothing.
/// `None` when the grids differ or `weight` is not finite.
pub fn confident_shifts(
    own: &Image<Vec<(f32, f32)>>,
    surfaces: &InflatedSurfaces,
    confidence: &GrayImage,
    weight: f32,
    reference: Reference,
) -> Option<GrayImage> {
    let (w, h) = (confidence.width, confidence.height);
    let grids = [
        (own.width, own.height),
        (surfaces.front.width, surfaces.front.height),
        (surfaces.back.width, surfaces.back.height),
    ];
    if grids.iter().any(|&g| g != (w, h))
        || own.data.len() != w * h
        || confidence.data.len() != w * h
        || !weight.is_finite()
    {
        return None;
    }
    // Each column's centroid and trusted volume (confidence × length).
    let columns: Vec<Option<(f32, f32)>> = (0..w * h)
        .map(|i| {
            let k = confidence.data[i];
            let (c, _, _) = intervals_centroid_z(std::iter::once(own.data[i].as_slice()))?;
            (k > 0.0 && k.is_finite()).then(|| (c, k * length(&own.data[i])))
        })
        .collect();
    let mean = |range: std::ops::Range<usize>| {
        let (mut moment, mut volume) = (0f64, 0f64);
        for (c, v) in columns[range].iter().flatten() {
            moment += (*c as f64) * (*v as f64);
            volume += *v as f64;
        }
        (volume > 0.0).then(|| (moment / volume) as f32)
    };
    let whole = mean(0..w * h);
    let rows: Vec<Option<f32>> = (0..h)
        .map(|r| match reference {
            Reference::Whole => whole,
            Reference::Row => mean(r * w..(r + 1) * w),
        })
        .collect();
    Some(Image::from_fn(w, h, |c, r| {
        let i = r * w + c;
        let (Some((centroid, _)), Some(reference)) = (columns[i], rows[r]) else { return 0.0 };
        let thickness = (surfaces.front.data[i] - surfaces.back.data[i]).max(0.0);
        let limit = MAX_SHIFT_OF_THICKNESS * thickness;
        (weight * confidence.data[i] * (centroid - reference)).clamp(-limit, limit)
    }))
}

/// `surfaces` (the inflation prior's front and back depth maps) with every column moved by `shifts`
/// ([`depth_shifts`], same grid; another grid leaves them as they are): the thickness of each column stays, its
/// depth changes.
pub fn place(mut surfaces: InflatedSurfaces, shifts: &GrayImage) -> InflatedSurfaces {
    let grid = (shifts.width, shifts.height);
    if (surfaces.front.width, surfaces.front.height) != grid || (surfaces.back.width, surfaces.back.height) != grid {
        return surfaces;
    }
    for map in [&mut surfaces.front, &mut surfaces.back] {
        map.data.iter_mut().zip(&shifts.data).for_each(|(z, s)| *z += s);
    }
    surfaces
}

/// `surfaces` placed by the body cube's depth convention ([`crate::geometry::depth_centre`]), measured exactly on
/// the surfaces' intervals `[back, front]` inside their mask: the occupied volume's centroid moves to z = 0 unless
/// that would push the range out of the cube ([`centring_shift`]). The FOF encoded from the result is centred
/// already (to the encoding's truncation), so [`crate::geometry::depth_centre::centre_fof`] leaves it as it is
/// instead of decoding its range and shifting every column in coefficient space.
pub fn centred(mut surfaces: InflatedSurfaces) -> InflatedSurfaces {
    let columns = surfaces.mask.data.iter().zip(surfaces.front.data.iter().zip(&surfaces.back.data));
    let intervals: Vec<[(f32, f32); 1]> =
        columns.filter(|(m, _)| **m > 0.5).map(|(_, (&front, &back))| [(back, front)]).collect();
    let Some((centroid, lo, hi)) = intervals_centroid_z(intervals.iter().map(|i| i.as_slice())) else {
        return surfaces;
    };
    let dz = centring_shift(centroid, lo, hi);
    if dz.abs() >= MIN_SHIFT {
        let mask = &surfaces.mask.data;
        for map in [&mut surfaces.front, &mut surfaces.back] {
            map.data.iter_mut().zip(mask).filter(|(_, m)| **m > 0.5).for_each(|(z, _)| *z += dz);
        }
    }
    surfaces
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intervals(w: usize, h: usize, f: impl Fn(usize, usize) -> Vec<(f32, f32)>) -> Image<Vec<(f32, f32)>> {
        Image::from_fn(w, h, f)
    }

    #[test]
    fn centred_puts_the_volume_centroid_at_zero_inside_the_cube() {
        // Two columns, [0.1, 0.5] and [0.3, 0.9] (volumes 0.4 and 0.6; centroid (0.4 * 0.3 + 0.6 * 0.6) / 1.0 =
        // 0.48), a third outside the mask that does not count.
        let surfaces = |front: [f32; 3], back: [f32; 3]| InflatedSurfaces {
            front: Image { width: 3, height: 1, data: front.to_vec() },
            back: Image { width: 3, height: 1, data: back.to_vec() },
            mask: Image { width: 3, height: 1, data: vec![1.0, 1.0, 0.0] },
        };
        let s = centred(surfaces([0.5, 0.9, 5.0], [0.1, 0.3, 4.0]));
        for (got, want) in s.front.data.iter().zip([0.02, 0.42, 5.0]).chain(s.back.data.iter().zip([-0.38, -0.18, 4.0]))
        {
            assert!((got - want).abs() < 1e-6, "{got} vs {want}");
        }
        // Centring would push the back past z = -1: only as far as the face.
        let s = centred(surfaces([0.9, 0.95, 0.0], [-0.9, 0.5, 0.0]));
        assert!((s.back.data[0] + 1.0).abs() < 1e-6, "{:?}", s.back.data);
        // No volume: unchanged.
        let empty = surfaces([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]);
        assert_eq!(centred(empty.clone()).front.data, empty.front.data);
    }

    #[test]
    fn columns_move_by_the_weight_times_their_depth_about_the_bodys_centroid() {
        // Body columns of length 0.2 at depths 0.4 and -0.2, and a third holding two intervals, [-0.3, -0.1] and
        // [0.5, 0.9] (centroid (0.2 * -0.2 + 0.4 * 0.7) / 0.6 = 0.4); the body's centroid is
        // (0.2 * 0.4 + 0.2 * -0.2 + 0.6 * 0.4) / 1.0 = 0.28.
        let body = intervals(3, 1, |c, _| match c {
            0 => vec![(0.3, 0.5)],
            1 => vec![(-0.3, -0.1)],
            _ => vec![(-0.3, -0.1), (0.5, 0.9)],
        });
        let mask = Image::new(3, 1, 1.0f32);
        let s = depth_shifts(&body, &mask, 0.5).unwrap();
        for (got, want) in s.data.iter().zip([0.5 * (0.4 - 0.28), 0.5 * (-0.2 - 0.28), 0.5 * (0.4 - 0.28)]) {
            assert!((got - want).abs() < 1e-6, "{got} vs {want}");
        }
        // Weight 0: nothing moves; weight 1: the full depth.
        assert!(depth_shifts(&body, &mask, 0.0).unwrap().data.iter().all(|&v| v == 0.0));
        assert!((depth_shifts(&body, &mask, 1.0).unwrap().data[0] - 0.12).abs() < 1e-6);
    }

    #[test]
    fn mask_columns_the_body_misses_take_their_neighbours_shift_and_the_outside_none() {
        // Body columns at depth 0.6 (left) and 0.0 (centre); the third is in the mask but empty; a fourth, outside the
        // mask, has a body interval that counts nowhere: not in the body's centroid (0.3), not as a neighbour.
        let body = intervals(4, 1, |c, _| match c {
            0 => vec![(0.5, 0.7)],
            1 => vec![(-0.1, 0.1)],
            3 => vec![(0.8, 1.0)],
            _ => vec![],
        });
        let mask = Image::from_fn(4, 1, |c, _| if c < 3 { 1.0f32 } else { 0.0 });
        let s = depth_shifts(&body, &mask, 1.0).unwrap();
        assert!((s.data[0] - 0.3).abs() < 1e-6 && (s.data[1] + 0.3).abs() < 1e-6);
        assert!((s.data[2] + 0.3).abs() < 1e-6, "the missing column copies its one neighbour in the mask");
        assert_eq!(s.data[3], 0.0);
    }

    #[test]
    fn ramp_is_zero_below_one_above_and_linear_between() {
        assert_eq!(ramp(0.2, 0.4, 0.7), 0.0);
        assert_eq!(ramp(0.9, 0.4, 0.7), 1.0);
        assert!((ramp(0.55, 0.4, 0.7) - 0.5).abs() < 1e-6);
        assert_eq!(ramp(f32::NAN, 0.4, 0.7), 0.0);
        // A step when the ends meet.
        assert_eq!((ramp(0.5, 0.5, 0.5), ramp(0.49, 0.5, 0.5)), (1.0, 0.0));
    }

    /// Landmarks all far outside a `w`×1 grid (visibility 1) but the skeleton segment 11–13 along its row, its ends
    /// seen with visibility `v11` and 1.
    fn along_the_row(w: usize, v11: f32) -> crate::body::pose::PoseLandmarks {
        let mut l = crate::body::pose::tests::torso(0.0);
        for p in l.landmarks.iter_mut() {
            p.pixel = Vec2::splat(1000.0);
            p.visibility = 1.0;
        }
        l.landmarks[11].pixel = Vec2::new(0.5, 0.5);
        l.landmarks[11].visibility = v11;
        l.landmarks[13].pixel = Vec2::new(w as f32 - 0.5, 0.5);
        l
    }

    #[test]
    fn confidence_is_agreement_times_cover_times_explained_thickness_times_visibility() {
        // Ten columns, the mask the first nine; the body covers columns 0-6 and 9 (outside the mask): IoU 7 / 10 =
        // 0.7, trust ramp(0.7, 0.6, 0.8) = 0.5. The prior is 0.5 thick everywhere; body lengths 0.4 (explained:
        // 0.8 >= 0.7), 0.1 in column 1 (0.2 <= 0.4: a garment, 0) and 0.275 in column 2 (0.55: half explained).
        // The segment's less visible end has 0.7: ramp(0.7, 0.5, 0.9) = 0.5.
        let own = intervals(10, 1, |c, _| match c {
            1 => vec![(0.0, 0.1)],
            2 => vec![(0.0, 0.275)],
            0..=6 | 9 => vec![(0.0, 0.4)],
            _ => vec![],
        });
        let mask = Image::from_fn(10, 1, |c, _| if c < 9 { 1.0f32 } else { 0.0 });
        let surfaces = InflatedSurfaces { front: Image::new(10, 1, 0.25f32), back: Image::new(10, 1, -0.25f32), mask };
        let k = placement_confidence(&own, &surfaces, &along_the_row(10, 0.7)).unwrap();
        let want = [0.25, 0.0, 0.125, 0.25, 0.25, 0.25, 0.25, 0.0, 0.0, 0.0];
        for (c, (got, want)) in k.data.iter().zip(want).enumerate() {
            assert!((got - want).abs() < 1e-5, "column {c}: {got} vs {want}");
        }
        // The fit agreeing less with the silhouette (body on the mask's first five columns: IoU 5 / 10): no trust.
        let own = intervals(10, 1, |c, _| if c < 5 || c == 9 { vec![(0.0, 0.4)] } else { vec![] });
        assert!(placement_confidence(&own, &surfaces, &along_the_row(10, 1.0)).unwrap().data.iter().all(|&v| v == 0.0));
        // Another grid: none.
        assert!(placement_confidence(&intervals(3, 1, |_, _| vec![]), &surfaces, &along_the_row(10, 1.0)).is_none());
    }

    #[test]
    fn confident_shifts_move_by_weight_confidence_and_depth_about_the_trusted_centroid_limited_by_thickness() {
        // Row 0: centroids 0.3 and -0.1 (length 0.2, confidence 1), 0.9 untrusted; row 1: 0.5 and 0.5 (length 0.2,
        // confidence 0.5), the third empty. Prior thickness 0.5 (limit 0.25).
        let own = intervals(3, 2, |c, r| match (c, r) {
            (0, 0) => vec![(0.2, 0.4)],
            (1, 0) => vec![(-0.2, 0.0)],
            (2, 0) => vec![(0.8, 1.0)],
            (2, 1) => vec![],
            _ => vec![(0.4, 0.6)],
        });
        let confidence = Image::from_fn(3, 2, |c, r| match (c, r) {
            (2, _) => 0.0f32,
            (_, 0) => 1.0,
            _ => 0.5,
        });
        let surfaces = InflatedSurfaces {
            front: Image::new(3, 2, 0.25f32),
            back: Image::new(3, 2, -0.25f32),
            mask: Image::new(3, 2, 1.0),
        };
        // Per row: row 0 about (0.3 * 0.2 - 0.1 * 0.2) / 0.4 = 0.1, row 1 about 0.5.
        let s = confident_shifts(&own, &surfaces, &confidence, 0.5, Reference::Row).unwrap();
        for (got, want) in s.data.iter().zip([0.1, -0.1, 0.0, 0.0, 0.0, 0.0]) {
            assert!((got - want).abs() < 1e-6, "{got} vs {want}");
        }
        // About the whole: (0.06 - 0.02 + 0.5 * 0.1 + 0.5 * 0.1) / 0.6 = 0.14 / 0.6.
        let c = 0.14 / 0.6;
        let s = confident_shifts(&own, &surfaces, &confidence, 0.5, Reference::Whole).unwrap();
        let want = [0.5 * (0.3 - c), 0.5 * (-0.1 - c), 0.0, 0.25 * (0.5 - c), 0.25 * (0.5 - c), 0.0];
        for (got, want) in s.data.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{got} vs {want}");
        }
        // Weight 10: 2.0 and -2.0 limited to half the prior's thickness.
        let s = confident_shifts(&own, &surfaces, &confidence, 10.0, Reference::Row).unwrap();
        assert_eq!((s.data[0], s.data[1]), (0.25, -0.25));
        assert!(confident_shifts(&own, &surfaces, &confidence, f32::NAN, Reference::Row).is_none());
    }

    #[test]
    fn no_volume_no_shifts_and_placing_keeps_each_columns_thickness() {
        let empty = intervals(2, 2, |_, _| vec![]);
        let mask = Image::new(2, 2, 1.0f32);
        assert!(depth_shifts(&empty, &mask, 0.5).is_none());
        assert!(depth_shifts(&intervals(3, 2, |_, _| vec![(0.0, 0.1)]), &mask, 0.5).is_none(), "grid mismatch");
        assert!(depth_shifts(&intervals(2, 2, |_, _| vec![(0.0, 0.1)]), &mask, f32::NAN).is_none());
        let surfaces =
            InflatedSurfaces { front: Image::new(2, 2, 0.2f32), back: Image::new(2, 2, -0.2f32), mask: mask.clone() };
        let shifts = Image::from_fn(2, 2, |c, r| 0.1 * (c + 2 * r) as f32);
        let placed = place(surfaces, &shifts);
        for i in 0..4 {
            assert!((placed.front.data[i] - placed.back.data[i] - 0.4).abs() < 1e-6);
            assert!((placed.front.data[i] + placed.back.data[i] - 2.0 * shifts.data[i]).abs() < 1e-6);
        }
    }
}
