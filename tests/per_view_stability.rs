//! Numerical stability of the per-view stages (raster, flow/Z-map, visibility, geometric warp, fusion) over a
//! grid of extreme views and degenerate geometry: no NaN anywhere, colours and alpha bounded in [0, 1].

#[path = "common/person.rs"]
mod person;

use glam::{Quat, Vec2, Vec3, Vec4};
use r2human::buffer::{GrayImage, Image, RgbImage, RgbaImage};
use r2human::geometry::raster::{rasterize, GBuffer, BACKGROUND_DEPTH};
use r2human::geometry::zmap::{flow_and_zmap, visibility, FlowZ, FLOW_OUTSIDE, VISIBILITY_LAMBDA};
use r2human::geometry::{Camera, Fov, TriMesh};
use r2human::pipeline::fusion::SpatialFusion;
use r2human::pipeline::warp::{render_geometric, warp_features, OcclusionFill};

const RES: usize = 64;

fn check_gbuf(g: &GBuffer, what: &str) {
    let n = g.width * g.height;
    assert_eq!((g.depth.len(), g.normal.len(), g.mask.len()), (n, n, n), "{what}: sizes");
    for i in 0..n {
        assert!(g.depth[i].is_finite() && g.normal[i].is_finite(), "{what}: non-finite at {i}");
        if g.mask[i] {
            assert!((g.normal[i].length() - 1.0).abs() < 1e-3, "{what}: normal {} at {i}", g.normal[i]);
            assert!(g.depth[i] > BACKGROUND_DEPTH, "{what}");
        } else {
            assert_eq!(g.depth[i], BACKGROUND_DEPTH, "{what}");
        }
    }
    if let Some(c) = &g.color {
        assert!(c.iter().all(|c| c.is_finite() && c.min_element() >= -1e-5 && c.max_element() <= 1.0 + 1e-5));
    }
}

fn check_flow(f: &FlowZ, g: &GBuffer, what: &str) {
    for i in 0..g.mask.len() {
        assert!(f.flow.data[i].is_finite() && f.z.data[i].is_finite(), "{what}: flow NaN at {i}");
        assert!(!f.mask[i] || g.mask[i], "{what}: flow mask outside the target mask");
        if !f.mask[i] {
            assert_eq!(f.flow.data[i], FLOW_OUTSIDE);
        }
    }
}

fn check_rgba(img: &RgbaImage, mask: &[bool], what: &str) {
    for (i, p) in img.data.iter().enumerate() {
        assert!(p.is_finite(), "{what}: NaN at {i}");
        assert!(p.min_element() >= 0.0 && p.max_element() <= 1.0, "{what}: {p} out of [0, 1]");
        assert!(p.x <= p.w + 1e-6 && p.y <= p.w + 1e-6 && p.z <= p.w + 1e-6, "{what}: not premultiplied");
        assert_eq!(p.w, mask[i] as u8 as f32, "{what}: alpha is not the mask at {i}");
    }
}

struct Source {
    rgb: RgbImage,
    mask: GrayImage,
    gbuf: GBuffer,
    cam: Camera,
}

fn source_of(mesh: &TriMesh) -> Source {
    let cam = Camera::source(RES);
    let gbuf = rasterize(mesh, &cam);
    let colors = gbuf.color.clone().unwrap_or_else(|| vec![Vec3::splat(0.7); RES * RES]);
    let rgb = Image {
        width: RES,
        height: RES,
        data: colors.iter().zip(&gbuf.mask).map(|(c, &m)| *c * m as u8 as f32).collect(),
    };
    Source { rgb, mask: gbuf.mask_image(), gbuf, cam }
}

/// Every per-view stage for one target camera; returns the target G-buffer.
fn run_view(mesh: &TriMesh, src: &Source, cam: &Camera, fusion: &mut SpatialFusion, what: &str) -> GBuffer {
    let g = rasterize(mesh, cam);
    check_gbuf(&g, what);
    let fz = flow_and_zmap(&g, cam, &src.cam);
    check_flow(&fz, &g, what);
    let vis = visibility(&fz, &src.gbuf, &src.cam, VISIBILITY_LAMBDA);
    assert!(vis.iter().zip(&fz.mask).all(|(&v, &m)| !v || m), "{what}: visible outside the flow mask");
    let mut last = None;
    for fill in [OcclusionFill::MirroredFront, OcclusionFill::Propagate] {
        let out = render_geometric(&src.rgb, &src.mask, &src.gbuf, &src.cam, &g, cam, fill);
        check_rgba(&out, &g.mask, what);
        last = Some(out);
    }
    let fused = fusion.fuse(&last.unwrap(), &g, cam);
    check_rgba(&fused, &g.mask, &format!("{what} (fused)"));
    // Features at 1/4 resolution.
    let (fw, c) = (RES / 4, 3);
    let feat: Vec<f32> = (0..c * fw * fw).map(|i| (i % 7) as f32 / 7.0).collect();
    let mut out = vec![0.0; c * g.width * g.height];
    warp_features(&feat, c, fw, fw, &fz, RES, &mut out);
    assert!(out.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)), "{what}: features");
    g
}

#[test]
fn orbit_grid_including_poles_and_the_back() {
    let mesh = person::person(1);
    let src = source_of(&mesh);
    let mut fusion = SpatialFusion::new();
    for &pitch in &[0.0f32, 45.0, -45.0, 89.9, -89.9, 90.0, -90.0] {
        for &yaw in &[0.0f32, 45.0, 90.0, 135.0, 180.0, 270.0, -180.0, 359.99] {
            let cam = Camera::orbit(yaw, pitch, RES, RES);
            let g = run_view(&mesh, &src, &cam, &mut fusion, &format!("yaw {yaw} pitch {pitch}"));
            assert!(g.coverage() > 50, "yaw {yaw} pitch {pitch}: the person must be in view");
        }
    }
}

#[test]
fn grazing_and_edge_on_surfaces() {
    // A paper-thin plate seen almost and exactly edge-on, and a single triangle exactly edge-on.
    let plate = TriMesh::cuboid(Vec3::new(-0.6, -0.6, -1e-5), Vec3::new(0.6, 0.6, 1e-5));
    let edge_on = TriMesh::new(
        vec![Vec3::new(-0.5, -0.5, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)],
        vec![[0, 1, 2]],
    );
    for mesh in [plate, edge_on] {
        let src = source_of(&mesh);
        let mut fusion = SpatialFusion::new();
        for yaw in [89.0f32, 89.99, 90.0, 90.01, 91.0, 270.0] {
            run_view(&mesh, &src, &Camera::orbit(yaw, 0.0, RES, RES), &mut fusion, &format!("grazing yaw {yaw}"));
        }
    }
}

#[test]
fn one_pixel_wide_limb_has_no_gaps() {
    // A vertical cylinder-like limb 1.3 pixels wide: every row along it covers at least one pixel centre.
    let px = 2.0 / RES as f32;
    let limb = person::ellipsoid(Vec3::ZERO, Vec3::new(0.65 * px, 0.8, 0.65 * px), 64, 12);
    let src = source_of(&limb);
    let g = &src.gbuf;
    check_gbuf(g, "limb");
    for row in 0..RES {
        let y = 1.0 - (row as f32 + 0.5) * px;
        let covered = (0..RES).filter(|&c| g.mask[row * RES + c]).count();
        // Half-width 0.65 px * sqrt(1 - (y / 0.8)^2) * cos(15 deg) (12-gon) stays above 0.5 px for |y| < 0.45.
        if y.abs() < 0.45 {
            assert!(covered >= 1, "row {row} (y {y}) has a gap");
        }
        assert!(covered <= 3, "row {row}: {covered} pixels for a 1.3 pixel limb");
    }
    let mut fusion = SpatialFusion::new();
    for yaw in [0.0f32, 33.0, 90.0, 180.0] {
        for pitch in [0.0f32, 60.0, 90.0] {
            run_view(&limb, &src, &Camera::orbit(yaw, pitch, RES, RES), &mut fusion, "limb");
        }
    }
}

#[test]
fn perspective_cameras_inside_the_cube_and_inside_the_mesh() {
    let mesh = person::person(1);
    let src = source_of(&mesh);
    let mut fusion = SpatialFusion::new();
    let fov = Fov::symmetric(1.5, 1.0);
    let poses = [
        (Vec3::new(0.0, 0.25, 0.0), Quat::IDENTITY, "inside the torso"),
        (Vec3::new(0.0, 0.25, 0.0), Quat::from_rotation_y(std::f32::consts::PI), "inside the torso, looking back"),
        (Vec3::new(0.5, 0.2, -0.7), Quat::from_rotation_y(2.5), "inside the cube, outside the mesh"),
        (Vec3::new(0.0, 0.3, 0.15), Quat::from_rotation_x(-0.3), "near plane crossing the torso"),
        (Vec3::new(0.0, 0.0, 2.5), Quat::IDENTITY, "outside, in front"),
        (Vec3::new(0.0, 3.0, 0.0), Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2), "straight down"),
        (Vec3::new(0.0, 0.0, 0.0), Quat::from_rotation_x(std::f32::consts::FRAC_PI_2), "straight up from the centre"),
    ];
    for (pos, rot, what) in poses {
        for near in [0.01f32, 1e-6] {
            let cam = Camera::perspective(pos, rot, fov, near, RES, RES);
            let g = run_view(&mesh, &src, &cam, &mut fusion, what);
            if what.starts_with("inside the torso") {
                assert_eq!(g.coverage(), RES * RES, "{what}: a closed mesh around the eye covers every pixel");
            }
        }
    }
}

#[test]
fn empty_and_degenerate_meshes() {
    let empty = TriMesh::default();
    let degenerate = TriMesh {
        positions: vec![
            Vec3::ZERO,
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::new(1.0, 1.0, 0.0), // collinear with the first two
            Vec3::new(f32::NAN, 0.0, 0.0),
            Vec3::new(f32::INFINITY, 1.0, 0.0),
            Vec3::new(0.1, -0.3, 0.2),
        ],
        triangles: vec![[0, 0, 0], [0, 1, 2], [0, 1, 1], [0, 3, 5], [4, 5, 0], [0, 5, 99], [7, 8, 9]],
        normals: vec![Vec3::ZERO; 6], // zero normals must fall back to face normals
        colors: Vec::new(),
        uvs: Vec::new(),
    };
    for (mesh, what) in [(&empty, "empty"), (&degenerate, "degenerate")] {
        let src = source_of(mesh);
        assert_eq!(src.gbuf.coverage(), 0, "{what}: nothing has area");
        let mut fusion = SpatialFusion::new();
        for (yaw, pitch) in [(0.0, 0.0), (90.0, 0.0), (180.0, 90.0)] {
            let g = run_view(mesh, &src, &Camera::orbit(yaw, pitch, RES, RES), &mut fusion, what);
            assert_eq!(g.coverage(), 0);
        }
    }
    // A valid triangle with zero vertex normals next to the garbage still renders, with its face normal.
    let mut mixed = degenerate.clone();
    mixed.positions.extend([Vec3::new(-0.5, -0.5, 0.0), Vec3::new(0.5, -0.5, 0.0), Vec3::new(0.0, 0.5, 0.0)]);
    mixed.normals.extend([Vec3::ZERO; 3]);
    mixed.triangles.push([6, 7, 8]);
    let g = rasterize(&mixed, &Camera::source(RES));
    check_gbuf(&g, "mixed");
    assert!(g.coverage() > 100);
    assert!(g.normal.iter().zip(&g.mask).all(|(n, &m)| !m || (*n - Vec3::Z).length() < 1e-5));
}

#[test]
fn zero_sized_and_mismatched_inputs_do_not_panic() {
    let mesh = person::person(1);
    let src = source_of(&mesh);
    let cam0 = Camera::orbit(30.0, 0.0, 0, 0);
    let g0 = rasterize(&mesh, &cam0);
    assert_eq!(g0.mask.len(), 0);
    let fz = flow_and_zmap(&g0, &cam0, &src.cam);
    assert!(visibility(&fz, &src.gbuf, &src.cam, VISIBILITY_LAMBDA).is_empty());
    let out = render_geometric(&src.rgb, &src.mask, &src.gbuf, &src.cam, &g0, &cam0, OcclusionFill::Propagate);
    assert!(out.data.is_empty());
    // A source photo of another size than the source camera, and a mask of the wrong size.
    let cam = Camera::orbit(60.0, 20.0, RES, RES);
    let g = rasterize(&mesh, &cam);
    let big_rgb = Image::new(2 * RES, 2 * RES, Vec3::splat(0.5));
    let big_mask = Image::new(2 * RES, 2 * RES, 1.0);
    let out = render_geometric(&big_rgb, &big_mask, &src.gbuf, &src.cam, &g, &cam, OcclusionFill::MirroredFront);
    check_rgba(&out, &g.mask, "bigger photo");
    let bad_mask = Image::new(3, 3, 1.0);
    let out = render_geometric(&src.rgb, &bad_mask, &src.gbuf, &src.cam, &g, &cam, OcclusionFill::MirroredFront);
    check_rgba(&out, &g.mask, "mismatched mask");
    // Fusion across a resolution change just restarts.
    let mut fusion = SpatialFusion::new();
    fusion.fuse(&out, &g, &cam);
    let cam2 = Camera::orbit(70.0, 20.0, RES / 2, RES / 2);
    let g2 = rasterize(&mesh, &cam2);
    let small = Image::new(RES / 2, RES / 2, Vec4::ZERO);
    assert_eq!(fusion.fuse(&small, &g2, &cam2), small);
    let _ = Vec2::ZERO;
}
