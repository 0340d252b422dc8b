//! The body cube's depth convention: **the person's occupied volume has its centroid at z = 0**.
//!
//! One photo says nothing about how far away the person is: under the orthographic source camera every depth
//! offset gives the same image. Ground truth and every predicted geometry therefore need one rule that places
//! them in depth, computable from the geometry alone, so that novel views rotate the person about the same
//! vertical axis and the evaluation compares shapes, not an unobservable offset. The rule is the centroid of the
//! occupied volume: a hand reaching toward the camera or a flared skirt moves it a little, where the reference's
//! minimal enclosing circle of the xz projection (still used for x and the scale of full bodies, see
//! `synth::normalize`) jumps to wherever the extremities are — on a chest-up crop by up to a quarter of the cube.
//! When the centroid rule would push part of the person out of the cube, the smallest shift that keeps it inside
//! is used instead ([`centring_shift`]).
//!
//! Ground truth is centred by [`mesh_centring_shift`] (synthetic subjects, crops and scans); predicted fields by
//! [`centre_fof`] (the end of `pipeline::compute_geometry`). Both measure the same quantity: the centroid of the
//! per-pixel occupancy intervals, from the mesh's intervals exactly, from a FOF's coefficients in closed form
//! ([`fof_centroid_z`]).

use rayon::prelude::*;

use super::fof::{intervals_from_mesh, sheet_thickness, CosineTable, Fof};
use super::marching::ISO_LEVEL;
use super::mesh::TriMesh;

/// Grid side on which [`mesh_centring_shift`] measures a mesh's volume (body-cube pixels; the centroid of a
/// 1.8-unit person moves by well under a 1/1000 of the cube between 128 and 512).
pub const MESH_GRID: usize = 128;

/// The FOF order whose sheet thickness [`mesh_centring_shift`] gives open surfaces: R²Human's N = 32.
pub const SHEET_ORDER: usize = 32;

/// Shifts smaller than this (body-cube z units, a quarter of a depth sample at 512 samples) are not applied to a
/// FOF: re-encoding costs more than the offset is worth.
pub const MIN_SHIFT: f32 = 1e-3;

/// The z shift that puts `centroid` at 0, limited so that the occupied depth range `[z_min, z_max]` stays inside
/// the cube `[-1, 1]`; a range wider than the cube is centred on its middle instead. Non-finite input gives 0.
pub fn centring_shift(centroid: f32, z_min: f32, z_max: f32) -> f32 {
    if !(centroid.is_finite() && z_min.is_finite() && z_max.is_finite()) || z_min > z_max {
        return 0.0;
    }
    let (lowest, highest) = (-1.0 - z_min, 1.0 - z_max);
    if lowest > highest {
        return -0.5 * (z_min + z_max);
    }
    (-centroid).clamp(lowest, highest)
}

/// Centroid z of the occupied volume of per-pixel intervals `(z_lo, z_hi)` (each pixel's intervals weighted by
/// their length, the pixel area being the same everywhere), with the range they span; `None` when there is no
/// volume. Reversed and non-finite intervals are ignored.
pub fn intervals_centroid_z<'a>(intervals: impl IntoIterator<Item = &'a [(f32, f32)]>) -> Option<(f32, f32, f32)> {
    let (mut moment, mut volume) = (0f64, 0f64);
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for list in intervals {
        for &(a, b) in list {
            if !(a.is_finite() && b.is_finite()) || b <= a {
                continue;
            }
            moment += 0.5 * (b as f64 * b as f64 - a as f64 * a as f64);
            volume += (b - a) as f64;
            lo = lo.min(a);
            hi = hi.max(b);
        }
    }
    (volume > 0.0).then(|| ((moment / volume) as f32, lo, hi))
}

/// The z shift that centres a mesh (body-cube coordinates) by the convention of this module, measured on its
/// intervals over a [`MESH_GRID`]² source grid with the FOF encoder's sheet thickness at [`SHEET_ORDER`] for open
/// surfaces (so garments and hair count as they do in the ground-truth FOF). `None` when the mesh covers no
/// pixel.
pub fn mesh_centring_shift(mesh: &TriMesh) -> Option<f32> {
    let (centroid, lo, hi) = mesh_depth_extent(mesh)?;
    Some(centring_shift(centroid, lo, hi))
}

/// A mesh's occupied-volume centroid z (measured as [`mesh_centring_shift`] does) and the z range of its finite
/// vertices (exact: the intervals are clamped to the cube); `None` when it covers no pixel.
pub fn mesh_depth_extent(mesh: &TriMesh) -> Option<(f32, f32, f32)> {
    let intervals = intervals_from_mesh(mesh, MESH_GRID, MESH_GRID, sheet_thickness(SHEET_ORDER));
    let (centroid, _, _) = intervals_centroid_z(intervals.data.iter().map(|v| v.as_slice()))?;
    let (lo, hi) = mesh
        .positions
        .iter()
        .filter(|p| p.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| (lo.min(p.z), hi.max(p.z)));
    Some((centroid, lo, hi))
}

/// Centroid z of a FOF's occupied volume in closed form, `None` when it is empty.
///
/// With `s = (z + 1) / 2` and `occ(s) = c_0 / 2 + sum_k c_k cos(k pi s)`, a column holds the volume
/// `int_0^1 occ ds = c_0 / 2` and the first moment `int_0^1 s occ ds = c_0 / 4 + sum_k c_k ((-1)^k - 1) / (k pi)^2`
/// (exact for the truncated series the field stores). Columns [`Fof::is_empty_column`] proves empty are left out
/// (a network's near-zero noise there is no volume).
pub fn fof_centroid_z(fof: &Fof) -> Option<f32> {
    let n = fof.n;
    let weights: Vec<f64> = (0..n)
        .map(|k| match k {
            0 => 0.25,
            k if k % 2 == 1 => -2.0 / (k as f64 * std::f64::consts::PI).powi(2),
            _ => 0.0,
        })
        .collect();
    let (moment, volume) = (0..fof.height)
        .into_par_iter()
        .map(|row| {
            let (mut m, mut v) = (0f64, 0f64);
            for col in 0..fof.width {
                if fof.is_empty_column(col, row) {
                    continue;
                }
                let c = fof.column(col, row);
                v += 0.5 * c[0] as f64;
                m += c.iter().zip(&weights).map(|(&ck, &w)| ck as f64 * w).sum::<f64>();
            }
            (m, v)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if volume.is_nan() || volume <= 1e-9 || !moment.is_finite() {
        return None;
    }
    let s = moment / volume;
    Some((2.0 * s - 1.0) as f32)
}

/// The depth range `[z_min, z_max]` a FOF occupies (decoded at the surface level on every `step`-th column and
/// row, `samples` depths per column); `None` when nothing is occupied.
pub fn fof_depth_range(fof: &Fof, step: usize, samples: usize) -> Option<(f32, f32)> {
    let step = step.max(1);
    let table = CosineTable::new(fof.n, samples.max(2));
    // Rows in parallel (the result is a min and a max: the same whatever the order).
    let (lo, hi) = (0..fof.height)
        .into_par_iter()
        .step_by(step)
        .map_init(
            || vec![0.0f32; table.samples],
            |buf, row| {
                let (mut lo, mut hi) = (usize::MAX, 0usize);
                for col in (0..fof.width).step_by(step) {
                    if fof.is_empty_column(col, row) {
                        continue;
                    }
                    fof.decode_column_with(&table, col, row, buf);
                    if let Some(first) = buf.iter().position(|&v| v >= ISO_LEVEL) {
                        let last = buf.iter().rposition(|&v| v >= ISO_LEVEL).unwrap_or(first);
                        lo = lo.min(first);
                        hi = hi.max(last);
                    }
                }
                (lo, hi)
            },
        )
        .reduce(|| (usize::MAX, 0), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    let z = |d: usize| 2.0 * (d as f32 + 0.5) / table.samples as f32 - 1.0;
    (lo <= hi).then(|| (z(lo), z(hi)))
}

/// The linear map of a FOF column's coefficients under a depth shift `dz` (body-cube z units), as an `n x n`
/// row-major matrix: `c'_k = cos(k pi d) c_k - sin(k pi d) S_k` with `d = dz / 2` and `S_k = 2 int_0^1 occ(u)
/// sin(k pi u) du = sum_j w_j c_j 2 k (1 - (-1)^(j+k)) / (pi (k^2 - j^2))` (`w_0 = 1/2`, else 1; `j = k` adds 0);
/// `c'_0 = c_0` (the volume is kept).
///
/// Exact for the stored (truncated) occupancy as long as nothing occupied lies within `|d|` of the cube's near
/// or far face; what would leave the cube is reflected back at the face instead (the even extension of the
/// cosine series) — [`centring_shift`] never asks for that.
pub fn shift_matrix(n: usize, dz: f32) -> Vec<f64> {
    use std::f64::consts::PI;
    let d = 0.5 * dz as f64;
    let mut m = vec![0.0f64; n * n];
    if n == 0 {
        return m;
    }
    m[0] = 1.0;
    for k in 1..n {
        let (sin, cos) = (k as f64 * PI * d).sin_cos();
        m[k * n + k] += cos;
        for j in 0..n {
            if j == k || (j + k) % 2 == 0 {
                continue;
            }
            let w = if j == 0 { 0.5 } else { 1.0 };
            let s_kj = w * 4.0 * k as f64 / (PI * ((k * k) as f64 - (j * j) as f64));
            m[k * n + j] -= sin * s_kj;
        }
    }
    m
}

/// `fof` moved by `dz` along z (see [`shift_matrix`] for what is exact); empty columns stay empty.
pub fn shift_fof(fof: &Fof, dz: f32) -> Fof {
    let mut out = fof.clone();
    shift_fof_in_place(&mut out, dz);
    out
}

/// [`shift_fof`] on the field itself (no second field allocated: a 512² field of 32 coefficients is 32 MB, and
/// allocating it cost more than the shift). Every output coefficient is the same f64 sum, over the same non-zero
/// terms in the same order, as the row-by-column product of [`shift_matrix`], so for finite coefficients the result
/// is bit-identical to it.
///
/// The matrix's entry `(k, j)` is zero unless `j = k` or `j + k` is odd (row 0 holds only `(0, 0)`): an input
/// coefficient updates its own output and those of the other parity. Only those products are formed, half of the
/// dense product's: a sum that starts at +0 never becomes -0, so the zero products the dense sum adds never change
/// a bit of it.
pub fn shift_fof_in_place(fof: &mut Fof, dz: f32) {
    let n = fof.n;
    if n == 0 || fof.width == 0 {
        return;
    }
    let m = shift_matrix(n, dz);
    // Per input coefficient j: its weight on its own output, and on the outputs of the other parity in k order.
    let diagonal: Vec<f64> = (0..n).map(|j| m[j * n + j]).collect();
    let cross: Vec<Vec<f64>> =
        (0..n).map(|j| (0..n).filter(|k| (j + k) % 2 == 1).map(|k| m[k * n + j]).collect()).collect();
    let width = fof.width;
    fof.coeffs.par_chunks_mut(n * width).for_each_init(
        // Outputs k = 0, 2, 4, ... and k = 1, 3, 5, ...
        || (vec![0.0f64; n.div_ceil(2)], vec![0.0f64; n / 2]),
        |(even, odd), row| {
            for c in row.chunks_exact_mut(n) {
                if Fof::is_empty_coefficients(c) {
                    continue;
                }
                even.fill(0.0);
                odd.fill(0.0);
                for (j, (&cj, (&own, other))) in c.iter().zip(diagonal.iter().zip(&cross)).enumerate() {
                    let cj = cj as f64;
                    let (same, opposite) = if j % 2 == 0 { (&mut *even, &mut *odd) } else { (&mut *odd, &mut *even) };
                    same[j / 2] += own * cj;
                    for (a, &w) in opposite.iter_mut().zip(other) {
                        *a += w * cj;
                    }
                }
                for (k, o) in c.iter_mut().enumerate() {
                    *o = if k % 2 == 0 { even[k / 2] } else { odd[k / 2] } as f32;
                }
            }
        },
    );
}

/// A predicted field centred by this module's convention, with the shift applied (0 when the field is empty or
/// already centred to within [`MIN_SHIFT`]).
pub fn centre_fof(fof: Fof) -> (Fof, f32) {
    let Some(centroid) = fof_centroid_z(&fof) else { return (fof, 0.0) };
    // A decoded range lies inside the cube, so the limited shift is never larger than the centroid: a field that is
    // centred already needs no range (decoding it is most of this function's time).
    if centroid.abs() < MIN_SHIFT {
        return (fof, 0.0);
    }
    let Some((lo, hi)) = fof_depth_range(&fof, 4, 256) else { return (fof, 0.0) };
    let dz = centring_shift(centroid, lo, hi);
    if dz.abs() < MIN_SHIFT {
        return (fof, 0.0);
    }
    let mut fof = fof;
    shift_fof_in_place(&mut fof, dz);
    (fof, dz)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::Image;
    use glam::Vec3;

    /// A FOF whose every pixel of a `w x w` grid holds `intervals` (z units).
    fn field(w: usize, n: usize, intervals: &[(f32, f32)]) -> Fof {
        Fof::from_intervals(&Image::new(w, w, intervals.to_vec()), n).unwrap()
    }

    /// The 0.5-crossings of a decoded column (z units, linear interpolation between samples).
    fn crossings(fof: &Fof, samples: usize) -> Vec<f32> {
        let mut buf = vec![0.0; samples];
        fof.decode_column(0, 0, samples, &mut buf);
        let z = |d: f32| 2.0 * (d + 0.5) / samples as f32 - 1.0;
        (1..samples)
            .filter(|&d| (buf[d - 1] >= ISO_LEVEL) != (buf[d] >= ISO_LEVEL))
            .map(|d| z(d as f32 - 1.0 + (ISO_LEVEL - buf[d - 1]) / (buf[d] - buf[d - 1])))
            .collect()
    }

    #[test]
    fn shift_rule_centres_and_keeps_the_person_in_the_cube() {
        assert_eq!(centring_shift(0.3, 0.0, 0.5), -0.3);
        assert_eq!(centring_shift(-0.2, -0.6, 0.1), 0.2);
        // Centring would push the front past z = 1: only as far as the face.
        assert!((centring_shift(-0.5, -0.6, 0.8) - 0.2).abs() < 1e-6);
        assert!((centring_shift(0.5, -0.9, 0.7) + 0.1).abs() < 1e-6);
        // Wider than the cube: centred on the range's middle.
        assert!((centring_shift(0.0, -1.5, 0.9) - 0.3).abs() < 1e-6);
        for bad in [f32::NAN, f32::INFINITY] {
            assert_eq!(centring_shift(bad, 0.0, 0.1), 0.0);
            assert_eq!(centring_shift(0.0, bad, 0.1), 0.0);
        }
        assert_eq!(centring_shift(0.0, 0.5, 0.1), 0.0, "reversed range");
    }

    #[test]
    fn interval_centroid_is_the_volume_weighted_mean() {
        // [0, 1] (centre 0.5, length 1) and [-0.6, -0.4] (centre -0.5, length 0.2): (0.5 - 0.1) / 1.2.
        let a = [(0.0, 1.0)];
        let b = [(-0.6, -0.4), (0.3, 0.2), (f32::NAN, 0.0)];
        let (c, lo, hi) = intervals_centroid_z([&a[..], &b[..]]).unwrap();
        assert!((c - 0.4 / 1.2).abs() < 1e-6, "{c}");
        assert_eq!((lo, hi), (-0.6, 1.0));
        assert!(intervals_centroid_z([&[][..], &[(0.2f32, 0.1f32)][..]]).is_none());
    }

    #[test]
    fn fof_centroid_matches_the_intervals_in_closed_form() {
        for n in [8, 16, 32, 64] {
            for iv in [vec![(-0.3, 0.1)], vec![(-0.7, -0.5), (0.2, 0.6)], vec![(0.1, 0.9)]] {
                let (want, _, _) = intervals_centroid_z([iv.as_slice()]).unwrap();
                let got = fof_centroid_z(&field(3, n, &iv)).unwrap();
                // The truncated series drops odd terms k >= n whose weight falls as 1/k^3.
                assert!((got - want).abs() < 2.0 / (n * n) as f32, "n {n} {iv:?}: {got} vs {want}");
            }
        }
        assert!(fof_centroid_z(&Fof::zeros(32, 4, 4).unwrap()).is_none());
    }

    #[test]
    fn shifted_field_equals_the_field_of_shifted_intervals() {
        let n = 32;
        for iv in [vec![(-0.4f32, 0.0f32)], vec![(-0.5, -0.3), (0.0, 0.3)], vec![(-0.1, -0.0625 + 0.0)]] {
            for dz in [0.35f32, -0.27, 0.05, -0.45] {
                let shifted = shift_fof(&field(1, n, &iv), dz);
                let direct = field(1, n, &iv.iter().map(|&(a, b)| (a + dz, b + dz)).collect::<Vec<_>>());
                let (a, b) = (crossings(&shifted, 512), crossings(&direct, 512));
                assert_eq!(a.len(), b.len(), "{iv:?} by {dz}: {a:?} vs {b:?}");
                for (x, y) in a.iter().zip(&b) {
                    assert!((x - y).abs() < 0.02, "{iv:?} by {dz}: surface at {x} vs {y}");
                }
                let (ca, cb) = (fof_centroid_z(&shifted).unwrap(), fof_centroid_z(&direct).unwrap());
                assert!((ca - cb).abs() < 0.01, "centroid {ca} vs {cb}");
                assert!(shifted.coeffs.iter().all(|c| c.is_finite()));
            }
        }
        // No shift is the identity; an empty column stays empty.
        let f = field(2, n, &[(-0.2, 0.3)]);
        let same = shift_fof(&f, 0.0);
        assert!(f.coeffs.iter().zip(&same.coeffs).all(|(a, b)| (a - b).abs() < 1e-6));
        let empty = Fof::zeros(n, 2, 2).unwrap();
        assert!(shift_fof(&empty, 0.4).coeffs.iter().all(|&c| c == 0.0));
    }

    #[test]
    fn the_shift_is_the_matrix_times_each_column_exactly() {
        // Every output coefficient is the f64 row-by-column product of `shift_matrix`, summed in ascending order
        // (what the in-place, column-major loop must reproduce bit for bit); empty columns are left as they are.
        let n = 32;
        let f = field(3, n, &[(-0.55, -0.2), (0.1, 0.45)]);
        let mut speck = f.clone();
        speck.coeffs[n..2 * n].iter_mut().enumerate().for_each(|(k, c)| *c = 1e-3 / (k + 1) as f32);
        for dz in [0.3f32, -0.17] {
            let m = shift_matrix(n, dz);
            let shifted = shift_fof(&speck, dz);
            for col in 0..3 {
                let c = speck.column(col, 0);
                for k in 0..n {
                    let want = if Fof::is_empty_coefficients(c) {
                        c[k]
                    } else {
                        m[k * n..(k + 1) * n].iter().zip(c).map(|(&a, &b)| a * b as f64).sum::<f64>() as f32
                    };
                    assert_eq!(shifted.column(col, 0)[k].to_bits(), want.to_bits(), "column {col}, k {k}, dz {dz}");
                }
            }
        }
    }

    #[test]
    fn centring_a_field_moves_its_centroid_to_zero() {
        let f = field(4, 32, &[(0.1, 0.5)]);
        let (centred, dz) = centre_fof(f);
        assert!((dz + 0.3).abs() < 0.01, "shift {dz}");
        assert!(fof_centroid_z(&centred).unwrap().abs() < 0.01);
        let (lo, hi) = fof_depth_range(&centred, 1, 512).unwrap();
        assert!((lo + 0.2).abs() < 0.03 && (hi - 0.2).abs() < 0.03, "{lo} {hi}");
        // Already centred and empty fields are returned as they are.
        let (_, dz) = centre_fof(field(4, 32, &[(-0.25, 0.25)]));
        assert_eq!(dz, 0.0);
        let (_, dz) = centre_fof(Fof::zeros(32, 4, 4).unwrap());
        assert_eq!(dz, 0.0);
    }

    #[test]
    fn a_mesh_is_centred_on_its_volume_not_its_extremities() {
        // A 0.4-deep box (the torso) at z in [0.2, 0.6] with a thin rod (an arm) reaching to z = -0.6.
        let torso = TriMesh::cuboid(Vec3::new(-0.3, -0.5, 0.2), Vec3::new(0.3, 0.5, 0.6));
        let rod = TriMesh::cuboid(Vec3::new(0.3, 0.0, -0.6), Vec3::new(0.34, 0.04, 0.2));
        let offset = torso.positions.len() as u32;
        let positions = [torso.positions.clone(), rod.positions.clone()].concat();
        let triangles = torso.triangles.iter().copied().chain(rod.triangles.iter().map(|t| t.map(|i| i + offset)));
        let mesh = TriMesh::new(positions, triangles.collect());
        let dz = mesh_centring_shift(&mesh).unwrap();
        // Volume: box 0.6*1.0*0.4 = 0.24 at 0.4, rod 0.04*0.04*0.8 = 0.00128 at -0.2 -> centroid ~0.3968.
        assert!((dz + 0.3968).abs() < 0.01, "shift {dz}");
        // The minimal enclosing circle of xz would have centred it near z = 0: far from the torso.
        assert!(mesh_centring_shift(&TriMesh::new(vec![], vec![])).is_none());
    }
}
