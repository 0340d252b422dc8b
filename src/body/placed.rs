//! The silhouette-inflation prior placed in depth by the fitted body (`--geometry body-placed`): what the
//! pipeline draws is the inflation prior with the face relief ([`super::face`]) and, when the model folder has a
//! placement network (`placement.onnx`), every column moved by that network's shift ([`place`]). Without one, no
//! column moves: the fixed rule this module measured does not hold on people the fit was not made on.
//!
//! Why columns are no longer moved toward the fitted body's depth. Reduce every column of a person to one interval
//! (its occupied length about its occupied centroid) and the ground truth loses little, so a geometry is mostly a
//! thickness and a depth per column, and the inflation prior's thickness at the true depths would gain a lot
//! (`cargo run --release --example geometry_oracle`). The fitted body's depths carry that on the synthetic
//! (MakeHuman) people the fit is made of: the least-squares scale of the body's per-column depths that best fits the
//! truth is 0.32–1.00 on `geometry_oracle 9 0 256`. On the dev half of the UFO: Alien Invasion characters
//! (`scripts/scan-ufoai.sh`) it is −0.60 to −0.22 on all six civilians and 0.01–0.22 on the four soldiers: the
//! body's depths point the wrong way as often as not, although the pose network sees every one of them facing the
//! camera (facing 0.88–0.98), its key landmarks' mean visibility is 0.79–0.99 and the posed body covers as much of
//! the silhouette as on the synthetic people (IoU 0.63–0.81 against 0.43–0.82). None of these signals tells a fit
//! whose depths can be trusted from one whose cannot. A confidence map per column (the weight of the nearest
//! landmark segment's body part times its visibility, zero where the posed body does not cover the column,
//! averaged over 1/64 of the grid) lost on that dev half with every part weight tried (whole-frame PSNR at close /
//! divergent views against the inflation prior, mean over the ten): head, torso and arms 0.5, legs 0: −0.17 /
//! −0.26 dB; head and torso 0.5: −0.19 / −0.26; head 0.5: −0.15 / −0.13; torso 0.5: +0.03 / −0.14; arms 0.5: +0.07
//! / +0.01 (worst character −0.15 dB); arms 1: +0.02 / −0.01; nothing moved, the face relief alone: +0.07 / +0.01
//! (worst −0.08). The earlier rule, every column moved halfway ([`PLACEMENT_WEIGHT`]): −0.57 / −0.36 dB. So where
//! the fit is unsure, which on people it was not made on is everywhere, each column stays at the prior's depth.
//!
//! [`depth_shifts`] and [`PLACEMENT_WEIGHT`] remain for the diagnostics that compare against that rule
//! (`examples/fit_ambiguity.rs`). Depths are measured about the body's own volume centroid, so a placement moves
//! columns against each other and not the person as a whole (the pipeline centres the result by the depth
//! convention afterwards, [`centred`]).

use crate::buffer::{GrayImage, Image};
use crate::geometry::depth_centre::{centring_shift, intervals_centroid_z, MIN_SHIFT};
use crate::geometry::inflate::InflatedSurfaces;

/// The fraction of the way from the inflation prior's centre plane to the body's depth that the earlier fixed rule
/// moved each column (chosen on the synthetic people and the five dev characters of `scripts/scan-check.sh`; the
/// pipeline no longer applies it, module docs).
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
