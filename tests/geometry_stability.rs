//! Stiff and extreme cases for the FOF, marching cubes and inflation stages: Gibbs ringing at N = 128, empty
//! and noise-only columns, huge coefficients, non-watertight meshes, degenerate masks. Everything must stay
//! finite and bounded in the body cube; analytic shapes must keep their radius and volume.

use std::collections::HashMap;

use glam::Vec3;
use r2human::buffer::{GrayImage, Image};
use r2human::geometry::fof::{intervals_from_mesh, sheet_thickness, Fof};
use r2human::geometry::inflate::{inflate, inflate_to_fof, InflateError, InflateParams};
use r2human::geometry::marching::extract_mesh;
use r2human::geometry::TriMesh;

fn assert_sane(mesh: &TriMesh) {
    mesh.validate().expect("finite vertices, valid indices");
    assert!(mesh.normals.iter().all(|n| n.is_finite() && (n.length() - 1.0).abs() < 1e-3));
    if let Some((lo, hi)) = mesh.bounds() {
        assert!(lo.cmpge(Vec3::splat(-1.0)).all() && hi.cmple(Vec3::splat(1.0)).all(), "{lo:?} {hi:?}");
    }
}

/// Every undirected edge is used exactly once in each direction (closed, consistently oriented), ignoring
/// edges on the grid border where the surface may be cut open.
fn assert_closed(mesh: &TriMesh) {
    let mut uses: HashMap<(u32, u32), i32> = HashMap::new();
    for t in &mesh.triangles {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
        }
    }
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &mesh.triangles {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    for (e, n) in count {
        assert_eq!(n, 2, "edge {e:?} used {n} times");
        assert_eq!(uses[&e], 0, "edge {e:?} not oppositely oriented");
    }
}

/// A capsule: segment end points and radius, in body-cube x, y.
type Capsule = ((f32, f32), (f32, f32), f32);

fn capsule_mask(res: usize, caps: &[Capsule]) -> GrayImage {
    GrayImage::from_fn(res, res, |col, row| {
        let p = ((col as f32 + 0.5) / (res as f32 * 0.5) - 1.0, 1.0 - (row as f32 + 0.5) / (res as f32 * 0.5));
        let inside = caps.iter().any(|&(a, b, r)| {
            let (abx, aby) = (b.0 - a.0, b.1 - a.1);
            let t = (((p.0 - a.0) * abx + (p.1 - a.1) * aby) / (abx * abx + aby * aby).max(1e-12)).clamp(0.0, 1.0);
            let (dx, dy) = (p.0 - a.0 - t * abx, p.1 - a.1 - t * aby);
            dx * dx + dy * dy < r * r
        });
        if inside {
            1.0
        } else {
            0.0
        }
    })
}

fn person(res: usize) -> GrayImage {
    capsule_mask(
        res,
        &[
            ((0.0, 0.78), (0.0, 0.76), 0.11),
            ((0.0, 0.66), (0.0, 0.55), 0.05),
            ((0.0, 0.42), (0.0, 0.05), 0.17),
            ((-0.2, 0.5), (-0.42, 0.02), 0.05),
            ((0.2, 0.5), (0.42, 0.02), 0.05),
            ((-0.09, -0.02), (-0.13, -0.86), 0.07),
            ((0.09, -0.02), (0.13, -0.86), 0.07),
        ],
    )
}

#[test]
fn n128_thin_intervals_ring_but_stay_finite_and_bounded() {
    let res = 48;
    let intervals = Image::from_fn(res, res, |col, row| {
        if (6..42).contains(&col) && (6..42).contains(&row) {
            let t = 0.002 * ((col + row) % 7) as f32;
            vec![(-0.95, -0.95 + t), (-0.1, -0.1 + t + 1e-6), (0.99, 1.0)]
        } else {
            Vec::new()
        }
    });
    let fof = Fof::from_intervals(&intervals, 128).unwrap();
    assert!(fof.coeffs.iter().all(|c| c.is_finite()));
    for depth in [64, 256, 512] {
        let mesh = extract_mesh(&fof, depth);
        assert_sane(&mesh);
    }
    let mut col = vec![0.0; 512];
    fof.decode_column(20, 20, 512, &mut col);
    assert!(col.iter().all(|v| v.is_finite() && v.abs() < 1.5));
}

#[test]
fn empty_noise_and_huge_columns() {
    let (res, n) = (32, 32);
    // Network-like noise everywhere (provably below the level) plus a sphere in the middle.
    let mut coeffs = vec![0.0f32; res * res * n];
    for (i, c) in coeffs.iter_mut().enumerate() {
        *c = 0.004 * (((i * 7919) % 97) as f32 / 97.0 - 0.5);
    }
    let sphere = TriMesh::uv_sphere(Vec3::ZERO, 0.5, 32, 64);
    let exact = Fof::from_mesh(&sphere, res, n).unwrap();
    for (c, e) in coeffs.iter_mut().zip(&exact.coeffs) {
        *c += e;
    }
    let fof = Fof::new(n, res, res, coeffs).unwrap();
    let corner_empty = fof.is_empty_column(0, 0);
    assert!(corner_empty, "noise-only columns are provably empty");
    let mesh = extract_mesh(&fof, 64);
    assert_sane(&mesh);
    assert!(!mesh.is_empty());

    // Negative DC and huge finite coefficients (overflow to inf/NaN while decoding) never reach the mesh.
    let mut wild = fof.clone();
    for (i, c) in wild.coeffs.iter_mut().enumerate() {
        if i % 5 == 0 {
            *c = if i % 2 == 0 { 3.0e38 } else { -3.0e38 };
        }
    }
    wild.coeffs[0] = -7.0;
    let mesh = extract_mesh(&wild, 64);
    assert_sane(&mesh);
    assert!(Fof::zeros(32, res, res).map(|f| extract_mesh(&f, 512).is_empty()).unwrap());
}

#[test]
fn sphere_round_trip_through_mesh_fof_mesh() {
    let (res, r) = (96, 0.55f32);
    let c = Vec3::new(0.1, -0.05, 0.2);
    let sphere = TriMesh::uv_sphere(c, r, 64, 128);
    let fof = Fof::from_mesh(&sphere, res, 32).unwrap();
    let mesh = extract_mesh(&fof, 96);
    assert_sane(&mesh);
    assert_closed(&mesh);
    let vol = mesh.signed_volume();
    let exact = 4.0 / 3.0 * std::f32::consts::PI * r.powi(3);
    assert!((vol - exact).abs() / exact < 0.03, "volume {vol} vs {exact}");
    let mean_r = mesh.positions.iter().map(|p| (*p - c).length()).sum::<f32>() / mesh.positions.len() as f32;
    assert!((mean_r - r).abs() < 0.01, "mean radius {mean_r}");
}

#[test]
fn non_watertight_scan_still_meshes() {
    let res = 48;
    let mut scan = TriMesh::uv_sphere(Vec3::ZERO, 0.6, 32, 64);
    // A hole at the side and a duplicated patch of faces.
    scan.triangles.retain(|t| {
        let m = t.iter().map(|&i| scan.positions[i as usize]).sum::<Vec3>() / 3.0;
        !(m.x > 0.5 && m.y.abs() < 0.15)
    });
    let extra: Vec<[u32; 3]> = scan.triangles.iter().take(200).copied().collect();
    scan.triangles.extend(extra);
    let intervals = intervals_from_mesh(&scan, res, res, sheet_thickness(32));
    assert!(intervals.data.iter().all(|v| v.iter().all(|&(a, b)| a < b && a >= -1.0 && b <= 1.0)));
    let fof = Fof::from_intervals(&intervals, 32).unwrap();
    let mesh = extract_mesh(&fof, 64);
    assert_sane(&mesh);
    let exact = 4.0 / 3.0 * std::f32::consts::PI * 0.216;
    assert!((mesh.signed_volume() - exact).abs() / exact < 0.05, "side hole loses almost nothing seen from the front");
}

#[test]
fn disc_inflation_meshes_to_a_ball() {
    let res = 128;
    let r = 0.6f32;
    let mask = capsule_mask(res, &[((0.0, 0.0), (0.0, 0.0), r)]);
    let params = InflateParams { thickness: 1.0, ..Default::default() };
    let fof = inflate_to_fof(&mask, 32, &params, None).unwrap();
    let mesh = extract_mesh(&fof, 128);
    assert_sane(&mesh);
    assert_closed(&mesh);
    let exact = 4.0 / 3.0 * std::f32::consts::PI * r.powi(3);
    let vol = mesh.signed_volume();
    assert!((vol - exact).abs() / exact < 0.05, "volume {vol} vs ball {exact}");
    let (lo, hi) = mesh.bounds().unwrap();
    assert!((hi.z - r).abs() < 0.04 && (lo.z + r).abs() < 0.04, "depth extent {lo:?} {hi:?}");
}

#[test]
fn person_inflation_is_closed_and_bounded() {
    let res = 128;
    let fof = inflate_to_fof(&person(res), 32, &InflateParams::default(), None).unwrap();
    let mesh = extract_mesh(&fof, 128);
    assert_sane(&mesh);
    assert_closed(&mesh);
    assert!(mesh.signed_volume() > 0.0);
    let (lo, hi) = mesh.bounds().unwrap();
    assert!(hi.y > 0.8 && lo.y < -0.85, "head to feet survive: {lo:?} {hi:?}");
}

#[test]
fn degenerate_masks_error_or_stay_thin_and_valid() {
    let p = InflateParams::default();
    let res = 64;
    assert_eq!(inflate(&GrayImage::new(res, res, 0.0), &p), Err(InflateError::EmptyMask));
    assert_eq!(inflate(&GrayImage::new(res, res, 1.0), &p), Err(InflateError::FullMask));
    // Tiny specks only.
    let specks = GrayImage::from_fn(res, res, |c, r| if c % 9 == 0 && r % 11 == 0 { 1.0 } else { 0.0 });
    assert!(matches!(inflate(&specks, &p), Err(InflateError::OnlySpecks { .. })));
    // Only one-pixel-wide limbs (a cross and a diagonal staircase): valid, thin, finite.
    let limbs = GrayImage::from_fn(res, res, |c, r| if c == 20 || r == 40 || (c == r && c > 45) { 1.0 } else { 0.0 });
    let s = inflate(&limbs, &p).unwrap();
    for i in 0..res * res {
        assert!(s.front.data[i] >= s.back.data[i]);
        if s.mask.data[i] > 0.5 {
            assert!(s.front.data[i] - s.back.data[i] < 0.1, "one-pixel limbs stay thin");
        }
    }
    let mesh = extract_mesh(&inflate_to_fof(&limbs, 32, &p, None).unwrap(), 64);
    assert_sane(&mesh);
    // Many components (a grid of small blobs), touching the image border too.
    let many = GrayImage::from_fn(res, res, |c, r| if c % 6 < 4 && r % 6 < 4 { 1.0 } else { 0.0 });
    let fof = inflate_to_fof(&many, 32, &p, None).unwrap();
    assert_sane(&extract_mesh(&fof, 64));
    // A person on a non-square grid.
    let wide = GrayImage::from_fn(96, 64, |c, r| {
        let (x, y) = (c as f32 - 48.0, r as f32 - 32.0);
        if (x / 30.0).powi(2) + (y / 20.0).powi(2) < 1.0 {
            1.0
        } else {
            0.0
        }
    });
    let fof = inflate_to_fof(&wide, 16, &p, None).unwrap();
    assert_eq!((fof.width, fof.height), (96, 64));
    assert_sane(&extract_mesh(&fof, 64));
}

/// A bust cut by the photo's bottom edge, through the pipeline's inflation geometry: the chest keeps its thickness
/// down to the cut (an open surface, not an egg closing at the photo's edge) and is never thicker than the closed
/// silhouette's thickest column; a body that ends inside the photo (rounded, no straight edge) still closes.
#[test]
fn the_inflation_geometry_stays_open_where_the_photo_cuts_the_person() {
    use r2human::pipeline::input::normalise;
    use r2human::pipeline::{compute_geometry, GeometryMode, PrepareOptions, StageTimings};
    let (w, h) = (160usize, 200usize);
    // Head and a wide chest running off the photo's bottom edge.
    let bust = GrayImage::from_fn(w, h, |c, r| {
        let (x, y) = (c as f32 + 0.5, r as f32 + 0.5);
        let head = (x - 80.0).powi(2) + (y - 60.0).powi(2) < 30.0f32.powi(2);
        let chest = y > 95.0 && (x - 80.0).abs() < 60.0 - (115.0 - y).max(0.0);
        f32::from(head || chest)
    });
    let opts = PrepareOptions { geometry: GeometryMode::Inflate, resolution: 128, ..Default::default() };
    let rgb = Image::new(w, h, Vec3::splat(0.5));
    let input = normalise(&rgb, &bust, opts.resolution).unwrap();
    let fof = compute_geometry(&input, &opts, &mut StageTimings::default()).unwrap();
    // c_0 of a column is its occupied depth (body-cube units).
    let rows: Vec<usize> = (0..128).filter(|&r| input.mask.get(64, r) > &0.5).collect();
    let last = *rows.last().unwrap();
    let thickness = |r: usize| fof.column(64, r)[0];
    let chest_mid = last - (last - rows[0]) / 5;
    assert!(thickness(last) > 0.8 * thickness(chest_mid), "{} vs {}", thickness(last), thickness(chest_mid));
    let closed = inflate_to_fof(&input.mask, fof.n, &InflateParams::default(), None).unwrap();
    let thickest = (0..128 * 128).map(|i| closed.coeffs[i * fof.n]).fold(0.0f32, f32::max);
    assert!(closed.column(64, last)[0] < 0.6 * thickness(last), "the closed prior thins at the cut");
    assert!((0..128 * 128).all(|i| fof.coeffs[i * fof.n] <= thickest + 0.02), "thicker than the closed prior");
    // The same person with a rounded bottom inside the photo: nothing is cut, the bottom closes.
    let whole = GrayImage::from_fn(w, h, |c, r| {
        let (x, y) = (c as f32 + 0.5, r as f32 + 0.5);
        f32::from((x - 80.0).powi(2) / 55.0f32.powi(2) + (y - 130.0).powi(2) / 60.0f32.powi(2) < 1.0)
    });
    let input = normalise(&rgb, &whole, opts.resolution).unwrap();
    let fof = compute_geometry(&input, &opts, &mut StageTimings::default()).unwrap();
    let rows: Vec<usize> = (0..128).filter(|&r| input.mask.get(64, r) > &0.5).collect();
    let (first, last) = (rows[0], *rows.last().unwrap());
    assert!(fof.column(64, last)[0] < 0.5 * fof.column(64, (first + last) / 2)[0]);
}
