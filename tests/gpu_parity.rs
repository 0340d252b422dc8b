//! Vulkan (lavapipe in CI) against the CPU reference, stage by stage and end to end, with the Khronos
//! validation layer on: every test fails on any validation error or warning.
//!
//! Sizes are small (lavapipe is a CPU rasteriser on shared cores). When no Vulkan driver is installed at all the
//! tests print why and return (the setup script installs lavapipe, so CI always runs them).

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;

use glam::{Quat, Vec3, Vec4};
use r2human::buffer::{Image, RgbImage, RgbaImage};
use r2human::compose;
use r2human::geometry::raster::rasterize;
use r2human::geometry::zmap::{flow_and_zmap, visibility, VISIBILITY_LAMBDA};
use r2human::geometry::{Camera, Fov, TriMesh};
use r2human::gpu::{Context, ContextOptions, GpuError, Renderer};
use r2human::io::environment::Environment;

/// Counts heap allocations per thread, so a test can check that a frame allocates nothing on the host.
struct CountingAllocator;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: forwards to the system allocator; the counter is a const-initialised thread local without destructor.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

fn context() -> Option<Arc<Context>> {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        let dir = std::env::temp_dir().join("r2human-xdg");
        let _ = std::fs::create_dir_all(&dir);
        std::env::set_var("XDG_RUNTIME_DIR", dir);
    }
    match Context::new(&ContextOptions { validation: Some(true), display: None }) {
        Ok(c) => Some(Arc::new(c)),
        Err(e @ (GpuError::NoVulkan(_) | GpuError::NoDevice(_))) => {
            eprintln!("SKIPPED: {e}");
            None
        }
        Err(e) => panic!("cannot create the Vulkan context: {e}"),
    }
}

fn assert_clean(ctx: &Context) {
    let log = ctx.validation();
    assert!(ctx.validation_enabled());
    assert_eq!(log.errors() + log.warnings(), 0, "validation messages: {:#?}", log.messages());
}

/// A small scene: a sphere (head) over a box (body), with per-vertex colours.
fn scene() -> TriMesh {
    let mut a = TriMesh::uv_sphere(Vec3::new(0.05, 0.45, 0.05), 0.3, 24, 32);
    let b = TriMesh::cuboid(Vec3::new(-0.35, -0.85, -0.2), Vec3::new(0.4, 0.2, 0.25));
    let offset = a.positions.len() as u32;
    a.positions.extend(&b.positions);
    a.triangles.extend(b.triangles.iter().map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]));
    a.compute_normals();
    a.colors = a.positions.iter().map(|p| (*p * 0.5 + Vec3::splat(0.5)).clamp(Vec3::ZERO, Vec3::ONE)).collect();
    a
}

fn cameras(n: usize) -> Vec<Camera> {
    let fov = Fov { angle_left: -0.55, angle_right: 0.5, angle_up: 0.5, angle_down: -0.6 };
    let q = Quat::from_rotation_y(0.4) * Quat::from_rotation_x(-0.15);
    vec![
        Camera::orbit(0.0, 0.0, n, n),
        Camera::orbit(63.0, 20.0, n, n),
        Camera::orbit(180.0, -35.0, n, n),
        Camera::perspective(q * Vec3::new(0.0, 0.0, 2.6), q, fov, 0.05, n, n),
    ]
}

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>() / a.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (1.0 / mse).log10()
    }
}

#[test]
fn raster_matches_cpu() {
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let mut r = Renderer::new(ctx.clone(), 96, 96).unwrap();
    r.set_mesh(&mesh).unwrap();
    for cam in cameras(96) {
        let gpu = r.rasterize(&cam).unwrap();
        let cpu = rasterize(&mesh, &cam);
        let n = cpu.mask.len();
        let mismatched = cpu.mask.iter().zip(&gpu.mask).filter(|(a, b)| a != b).count();
        let covered = cpu.coverage();
        assert!(covered > n / 20, "the scene must be visible: {covered} of {n}");
        // Both sample pixel centres with 8 sub-pixel bits and the top-left rule; only exact ties on silhouette
        // edges (snapping of a vertex to the sub-pixel grid in a different order of operations) may differ.
        assert!(mismatched * 200 <= covered, "{mismatched} mask mismatches of {covered} covered ({cam:?})");
        let mut max_depth = 0.0f32;
        let mut min_dot = 1.0f32;
        let mut max_col = 0.0f32;
        for i in 0..n {
            if cpu.mask[i] && gpu.mask[i] {
                max_depth = max_depth.max((cpu.depth[i] - gpu.depth[i]).abs());
                min_dot = min_dot.min(cpu.normal[i].dot(gpu.normal[i]));
                let (cc, gc) = (cpu.color.as_ref().unwrap()[i], gpu.color.as_ref().unwrap()[i]);
                max_col = max_col.max((cc - gc).abs().max_element());
            } else if !gpu.mask[i] {
                assert_eq!(gpu.normal[i], Vec3::ZERO);
                assert!(gpu.depth[i] < -1e29);
            }
        }
        // Where both cover a pixel, they see the same surface except where two surfaces are within a depth
        // tie; the bounds state float interpolation error (1e-3 of the cube) plus rare ties near edges.
        let bad_depth =
            (0..n).filter(|&i| cpu.mask[i] && gpu.mask[i] && (cpu.depth[i] - gpu.depth[i]).abs() > 1e-3).count();
        assert!(bad_depth * 200 <= covered, "{bad_depth} depth mismatches > 1e-3 (max {max_depth})");
        let bad_normal =
            (0..n).filter(|&i| cpu.mask[i] && gpu.mask[i] && cpu.normal[i].dot(gpu.normal[i]) < 0.999).count();
        assert!(bad_normal * 200 <= covered, "{bad_normal} normal mismatches (min dot {min_dot})");
        eprintln!("raster {:?}: mask mismatches {mismatched}/{covered}, max |dz| {max_depth:.2e}, min n.n {min_dot:.6}, max dcolour {max_col:.2e}", cam.projection);
    }
    assert_clean(&ctx);
}

fn test_person(n: usize) -> RgbaImage {
    // A disc of premultiplied colour with a soft edge, fully transparent outside.
    Image::from_fn(n, n, |c, r| {
        let (x, y) = ((c as f32 + 0.5) / n as f32 - 0.5, (r as f32 + 0.5) / n as f32 - 0.5);
        let a = (1.0 - ((x * x + y * y).sqrt() - 0.25) * 20.0).clamp(0.0, 1.0);
        let rgb = Vec3::new(0.9 * (c as f32 / n as f32), 0.4, 0.7 * (r as f32 / n as f32));
        (rgb * a).extend(a)
    })
}

fn test_env() -> Environment {
    // Smooth and sharp features, non-2:1 size to catch index mistakes.
    let image: RgbImage = Image::from_fn(96, 50, |c, r| {
        let checker = if (c / 8 + r / 8) % 2 == 0 { 0.8 } else { 0.1 };
        Vec3::new(c as f32 / 96.0, r as f32 / 50.0, checker)
    });
    Environment { image, yaw: 0.7 }
}

#[test]
fn panorama_matches_cpu() {
    let Some(ctx) = context() else { return };
    let n = 80;
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    for env in [test_env(), Environment { yaw: -2.0, ..Environment::default_embedded() }] {
        r.set_environment(&env).unwrap();
        let person = test_person(n);
        let mut cams = cameras(n);
        // Looking straight up and down exercises the pole-aware rows.
        cams.push(Camera::orbit(30.0, 89.0, n, n));
        cams.push(Camera::orbit(-120.0, -90.0, n, n));
        for cam in cams {
            let gpu = r.compose_vr(&person, &cam).unwrap();
            let cpu = compose::compose_vr(&person, &env, &cam);
            let a: Vec<f32> = cpu.data.iter().flat_map(|v| v.to_array()).collect();
            let b: Vec<f32> = gpu.data.iter().flat_map(|v| v.to_array()).collect();
            let p = psnr(&a, &b);
            let max = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
            eprintln!("panorama {:?}: PSNR {p:.1} dB, max abs {max:.2e}", cam.projection);
            // Half-float texels (relative 2^-11) and the GPU's atan/acos: far above 40 dB.
            assert!(p >= 40.0, "PSNR {p}");
            // A pixel fully covered by the person shows exactly the person.
            let centre = (n / 2) * n + n / 2;
            assert!((gpu.data[centre] - person.data[centre].truncate()).abs().max_element() < 1e-6);
        }
    }
    assert_clean(&ctx);
}

#[test]
fn ar_layer_matches_cpu_exactly() {
    let Some(ctx) = context() else { return };
    let n = 40;
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    let mut person = test_person(n);
    // Out-of-range values the sanitiser must fix: alpha > 1, colour > alpha, negative colour.
    person.data[0] = Vec4::new(2.0, -1.0, 0.5, 1.5);
    person.data[1] = Vec4::new(0.9, 0.9, 0.9, 0.3);
    let gpu = r.compose_ar(&person).unwrap();
    let cpu = compose::compose_ar(&person);
    let differing = gpu.data.iter().zip(&cpu.data).filter(|(a, b)| a != b).count();
    assert_eq!(differing, 0, "{differing} pixels differ");
    assert_eq!(gpu.data[1], Vec4::new(0.3, 0.3, 0.3, 0.3));
    assert_clean(&ctx);
}

#[test]
fn wrong_sizes_are_errors_not_panics() {
    let Some(ctx) = context() else { return };
    assert!(Renderer::new(ctx.clone(), 0, 10).is_err());
    let mut r = Renderer::new(ctx.clone(), 16, 16).unwrap();
    assert!(r.rasterize(&Camera::orbit(0.0, 0.0, 17, 16)).is_err());
    assert!(r.compose_vr(&test_person(16), &Camera::orbit(0.0, 0.0, 16, 16)).is_err(), "no panorama uploaded");
    // An empty mesh renders an empty G-buffer.
    let g = r.rasterize(&Camera::orbit(0.0, 0.0, 16, 16)).unwrap();
    assert_eq!(g.coverage(), 0);
    assert_clean(&ctx);
}

/// A source view of the scene: the mesh's vertex colours as the "photo", premultiplied by coverage.
fn source_view(mesh: &TriMesh, n: usize) -> (RgbaImage, r2human::geometry::raster::GBuffer, Camera) {
    let cam = Camera::source(n);
    let g = rasterize(mesh, &cam);
    let colors = g.color.clone().unwrap();
    let img = Image::from_fn(n, n, |c, r| {
        let i = r * n + c;
        if g.mask[i] {
            colors[i].extend(1.0)
        } else {
            Vec4::ZERO
        }
    });
    (img, g, cam)
}

#[test]
fn flow_zmap_visibility_match_cpu() {
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 72;
    let (src_img, src_g, src_cam) = source_view(&mesh, 96);
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    for cam in cameras(n) {
        // Same target G-buffer on both sides: this checks the flow stage alone.
        let target = rasterize(&mesh, &cam);
        let (gpu, gvis) = r.flow_and_zmap(&target, &cam).unwrap();
        let cpu = flow_and_zmap(&target, &cam, &src_cam);
        let cvis = visibility(&cpu, &src_g, &src_cam, VISIBILITY_LAMBDA);
        assert_eq!(gpu.mask, cpu.mask);
        let mut max_flow = 0.0f32;
        let mut max_z = 0.0f32;
        for i in 0..n * n {
            max_flow = max_flow.max((gpu.flow.data[i] - cpu.flow.data[i]).abs().max_element());
            max_z = max_z.max((gpu.z.data[i] - cpu.z.data[i]).abs());
        }
        // f32 transforms in a different order: 1e-3 pixel and 1e-5 of the cube.
        assert!(max_flow < 2e-3 && max_z < 2e-5, "flow {max_flow} z {max_z}");
        // Visibility flips only where the flow sits within float error of a pixel border or the depth test is
        // within float error of its threshold.
        let flips = gvis.iter().zip(&cvis).filter(|(a, b)| a != b).count();
        let visible = cvis.iter().filter(|v| **v).count();
        assert!(flips * 500 <= cpu.mask.len().max(1), "{flips} visibility flips ({visible} visible)");
        eprintln!(
            "flow {:?}: max |dflow| {max_flow:.2e} px, max |dz| {max_z:.2e}, {flips} flips of {visible}",
            cam.projection
        );
    }
    assert_clean(&ctx);
}

fn rgb_mask(img: &RgbaImage) -> (RgbImage, r2human::buffer::GrayImage) {
    (img.map(|p| p.truncate()), img.map(|p| p.w))
}

fn psnr_rgba(a: &RgbaImage, b: &RgbaImage) -> f64 {
    let x: Vec<f32> = a.data.iter().flat_map(|v| v.to_array()).collect();
    let y: Vec<f32> = b.data.iter().flat_map(|v| v.to_array()).collect();
    psnr(&x, &y)
}

#[test]
fn warp_and_hole_fill_match_cpu() {
    use r2human::pipeline::warp::{render_from_flow, OcclusionFill, SideImages, SourceColours};
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 64;
    let (src_img, src_g, src_cam) = source_view(&mesh, 80);
    let (src_rgb, src_mask) = rgb_mask(&src_img);
    // A back image unlike the photo (its complement, premultiplied by the same mask), stored after the photo.
    let back_img = src_img.map(|p| ((Vec3::ONE - p.truncate()) * p.w).extend(p.w));
    let back_rgb = back_img.map(|p| p.truncate());
    // With the side images (both blurred) that surfaces seen edge-on take.
    let side = SideImages::of(&src_rgb, Some(&back_rgb), &src_mask);
    let colours = SourceColours { rgb: &src_rgb, back: Some(&back_rgb), side: Some(&side) };
    let sharp = SourceColours { side: None, ..colours };
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_source_parts(colours, &src_mask, &src_g, &src_cam).unwrap();
    let (mut back_differs, mut side_differs) = (0, 0);
    for fill in [OcclusionFill::MirroredFront, OcclusionFill::Propagate, OcclusionFill::Back] {
        r.set_fill(fill);
        for cam in cameras(n) {
            let target = rasterize(&mesh, &cam);
            let flowz = flow_and_zmap(&target, &cam, &src_cam);
            let vis = visibility(&flowz, &src_g, &src_cam, VISIBILITY_LAMBDA);
            let cpu = render_from_flow(colours, &src_mask, &src_cam, &target, &cam, &flowz, &vis, fill);
            let gpu = r.warp_from_flow(&target, &flowz, &vis, &cam).unwrap();
            let without_side = render_from_flow(sharp, &src_mask, &src_cam, &target, &cam, &flowz, &vis, fill);
            side_differs +=
                gpu.data.iter().zip(&without_side.data).filter(|(a, b)| (**a - **b).abs().max_element() > 1e-3).count();
            let p = psnr_rgba(&cpu, &gpu);
            let max = cpu.data.iter().zip(&gpu.data).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
            eprintln!("warp {fill:?} {:?}: PSNR {p:.1} dB, max abs {max:.2e}", cam.projection);
            // Same arithmetic in f32; sums in the pyramid run in another order.
            assert!(p >= 60.0 && max < 1e-3, "PSNR {p}, max {max}");
            assert!(gpu.data.iter().zip(&target.mask).all(|(c, &m)| (c.w == 1.0) == m));
            if fill == OcclusionFill::Back {
                let mirrored = render_from_flow(
                    &src_rgb,
                    &src_mask,
                    &src_cam,
                    &target,
                    &cam,
                    &flowz,
                    &vis,
                    OcclusionFill::MirroredFront,
                );
                back_differs +=
                    gpu.data.iter().zip(&mirrored.data).filter(|(a, b)| (**a - **b).abs().max_element() > 0.1).count();
            }
        }
    }
    // The back image was used where surfaces face away from the source (the back view's pixels), the side images
    // where they turn edge-on.
    assert!(back_differs > 100, "{back_differs}");
    assert!(side_differs > 100, "{side_differs}");
    // Without a back image the back fill is the mirrored-front fill.
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    let cam = Camera::orbit(180.0, -35.0, n, n);
    let target = rasterize(&mesh, &cam);
    let flowz = flow_and_zmap(&target, &cam, &src_cam);
    let vis = visibility(&flowz, &src_g, &src_cam, VISIBILITY_LAMBDA);
    r.set_fill(OcclusionFill::Back);
    let back = r.warp_from_flow(&target, &flowz, &vis, &cam).unwrap();
    r.set_fill(OcclusionFill::MirroredFront);
    let mirrored = r.warp_from_flow(&target, &flowz, &vis, &cam).unwrap();
    assert_eq!(back.data, mirrored.data);
    assert_clean(&ctx);
}

#[test]
fn warp_with_nothing_seen_uses_the_mean_colour() {
    use r2human::pipeline::warp::{render_from_flow, OcclusionFill};
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 32;
    let (src_img, src_g, src_cam) = source_view(&mesh, 48);
    let (src_rgb, src_mask) = rgb_mask(&src_img);
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    r.set_fill(OcclusionFill::Propagate);
    let cam = Camera::orbit(180.0, 0.0, n, n);
    let target = rasterize(&mesh, &cam);
    let flowz = flow_and_zmap(&target, &cam, &src_cam);
    let nothing = vec![false; n * n];
    let cpu =
        render_from_flow(&src_rgb, &src_mask, &src_cam, &target, &cam, &flowz, &nothing, OcclusionFill::Propagate);
    let gpu = r.warp_from_flow(&target, &flowz, &nothing, &cam).unwrap();
    let max = cpu.data.iter().zip(&gpu.data).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
    assert!(max < 1e-5, "{max}");
    assert!(target.coverage() > 0);
    assert_clean(&ctx);
}

#[test]
fn fusion_matches_cpu_over_an_orbit() {
    use r2human::pipeline::fusion::SpatialFusion;
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 64;
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    let mut cpu_fusion = SpatialFusion::new();
    for (k, yaw) in [30.0f32, 45.0, 45.0, 60.0, 60.0].iter().enumerate() {
        let cam = Camera::orbit(*yaw, 5.0, n, n);
        let g = rasterize(&mesh, &cam);
        // A view-dependent rendering so the blend is visible: colour from yaw.
        let shade = Vec3::new(yaw / 90.0, 1.0 - yaw / 90.0, 0.3);
        let mut current = Image::from_fn(n, n, |c, row| {
            let i = row * n + c;
            if g.mask[i] {
                shade.extend(1.0)
            } else {
                Vec4::ZERO
            }
        });
        if k == 4 {
            // The same (unmoved) view with a new input: remembered unfused.
            current.data.iter_mut().filter(|p| p.w > 0.0).for_each(|p| p.x *= 0.5);
        }
        let cpu = cpu_fusion.fuse(&current, &g, &cam);
        let gpu = r.fuse(&current, &g, &cam).unwrap();
        let max = cpu.data.iter().zip(&gpu.data).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
        let changed =
            cpu.data.iter().zip(&current.data).filter(|(a, b)| (**a - **b).abs().max_element() > 1e-3).count();
        eprintln!("fusion step {k} yaw {yaw}: max abs {max:.2e}, {changed} pixels blended");
        if k == 1 {
            assert!(changed > 100, "fusion must blend where both views see the surface");
        }
        // Bilinear sampling of the previous output and the visibility test near its threshold: identical
        // arithmetic, so only float rounding differs.
        let off = cpu.data.iter().zip(&gpu.data).filter(|(a, b)| (**a - **b).abs().max_element() > 1e-4).count();
        assert!(off * 500 <= n * n, "{off} pixels differ (max {max})");
    }
    assert_clean(&ctx);
}

#[test]
fn feature_warp_matches_cpu() {
    use r2human::pipeline::warp::warp_features;
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 48;
    let (src_img, src_g, src_cam) = source_view(&mesh, 64);
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    let (c, fw, fh) = (5usize, 16usize, 16usize);
    let features: Vec<f32> = (0..c * fw * fh).map(|i| ((i * 37) % 101) as f32 / 50.0 - 1.0).collect();
    r.set_features(&features, c, fw, fh).unwrap();
    let cam = Camera::orbit(40.0, -10.0, n, n);
    let flowz = flow_and_zmap(&rasterize(&mesh, &cam), &cam, &src_cam);
    let mut cpu = vec![0.0f32; c * n * n];
    warp_features(&features, c, fw, fh, &flowz, 64, &mut cpu);
    r.warp_features(&flowz).unwrap();
    let gpu = r.warped_features();
    assert_eq!(gpu.len(), cpu.len());
    let max = cpu.iter().zip(gpu).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    assert!(max < 1e-5, "{max}");
    assert!(cpu.iter().filter(|v| **v != 0.0).count() > c * 100, "the flow must hit the features");
    assert_clean(&ctx);
}

#[test]
fn end_to_end_person_and_frames_match_cpu() {
    use r2human::pipeline::fusion::SpatialFusion;
    use r2human::pipeline::warp::{render_geometric, OcclusionFill};
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 64;
    let (src_img, src_g, src_cam) = source_view(&mesh, 96);
    let (src_rgb, src_mask) = rgb_mask(&src_img);
    let env = test_env();
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_mesh(&mesh).unwrap();
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    r.set_environment(&env).unwrap();
    r.set_fusion(true);
    let mut fusion = SpatialFusion::new();
    for (k, cam) in [Camera::orbit(20.0, 0.0, n, n), Camera::orbit(35.0, 10.0, n, n), Camera::orbit(35.0, 10.0, n, n)]
        .iter()
        .enumerate()
    {
        let target = rasterize(&mesh, cam);
        let person =
            render_geometric(&src_rgb, &src_mask, &src_g, &src_cam, &target, cam, OcclusionFill::MirroredFront);
        let cpu_person = fusion.fuse(&person, &target, cam);
        r.render_frame(cam, r2human::compose::Mode::Vr, None).unwrap();
        let gpu_vr = match r.read_output(r2human::compose::Mode::Vr) {
            r2human::compose::RenderedFrame::Vr(img) => img,
            r2human::compose::RenderedFrame::Ar(_) => unreachable!("asked for VR"),
        };
        let cpu_vr = compose::compose_vr(&cpu_person, &env, cam);
        let a: Vec<f32> = cpu_vr.data.iter().flat_map(|v| v.to_array()).collect();
        let b: Vec<f32> = gpu_vr.data.iter().flat_map(|v| v.to_array()).collect();
        let p = psnr(&a, &b);
        eprintln!("end to end view {k}: VR PSNR {p:.1} dB");
        assert!(p >= 40.0, "PSNR {p}");
        let gpu_person = r.render_person(cam).unwrap();
        let pp = psnr_rgba(&cpu_person, &gpu_person);
        assert!(pp >= 40.0, "person PSNR {pp}");
    }
    assert_clean(&ctx);
}

#[test]
fn frames_allocate_nothing_create_nothing_and_upload_nothing() {
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 48;
    let (src_img, src_g, src_cam) = source_view(&mesh, 64);
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_mesh(&mesh).unwrap();
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    r.set_environment(&test_env()).unwrap();
    r.set_fusion(true);
    let cams: Vec<Camera> = (0..12).map(|i| Camera::orbit(13.0 * i as f32, 5.0, n, n)).collect();
    r.render_frame(&cams[0], r2human::compose::Mode::Vr, None).unwrap();
    let before = r.counters();
    assert_eq!((before.mesh_uploads, before.source_uploads, before.frames), (1, 1, 1));
    let allocs = allocations();
    for (i, cam) in cams.iter().enumerate().skip(1) {
        let mode = if i % 2 == 0 { r2human::compose::Mode::Vr } else { r2human::compose::Mode::Ar };
        r.render_frame(cam, mode, None).unwrap();
    }
    let allocs = allocations() - allocs;
    let after = r.counters();
    assert_eq!(allocs, 0, "host allocations during 11 frames");
    assert_eq!(
        after,
        r2human::gpu::RendererCounters { frames: before.frames + 11, ..before },
        "frames must not create resources or pipelines, nor upload the mesh or the source"
    );
    // A new mesh of the same size reuses the buffers: an upload, no new resource.
    r.set_mesh(&mesh).unwrap();
    assert_eq!(r.counters().resources_created, before.resources_created);
    assert_eq!(r.counters().mesh_uploads, 2);
    assert_clean(&ctx);
}

#[test]
fn stage_times_come_from_gpu_timestamps() {
    let Some(ctx) = context() else { return };
    let mesh = scene();
    let n = 48;
    let (src_img, src_g, src_cam) = source_view(&mesh, 64);
    let mut r = Renderer::new(ctx.clone(), n, n).unwrap();
    r.set_mesh(&mesh).unwrap();
    r.set_source(&src_img, &src_g, &src_cam).unwrap();
    r.set_environment(&test_env()).unwrap();
    let t = std::time::Instant::now();
    r.render_frame(&Camera::orbit(30.0, 0.0, n, n), r2human::compose::Mode::Vr, None).unwrap();
    let wall = t.elapsed();
    let times = r.stage_times();
    if times.is_empty() {
        eprintln!("SKIPPED: the device has no timestamp queries");
        return;
    }
    let names: Vec<&str> = times.iter().map(|(n, _)| *n).collect();
    assert_eq!(names, ["raster", "flow + Z-map", "warp", "hole fill", "fusion", "keep previous", "compose VR"]);
    let total: std::time::Duration = times.iter().map(|(_, d)| *d).sum();
    assert!(total > std::time::Duration::ZERO && total <= wall, "GPU {total:?} within wall {wall:?}");
    // An unmoved view with unchanged inputs reuses the last person layer.
    r.render_frame(&Camera::orbit(30.0, 0.0, n, n), r2human::compose::Mode::Ar, None).unwrap();
    let names: Vec<&str> = r.stage_times().iter().map(|(n, _)| *n).collect();
    assert_eq!(names, ["reuse previous", "compose AR"]);
    assert_clean(&ctx);
}

fn r2human_cmd() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_r2human"));
    c.env("R2HUMAN_LOG", "warn");
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        let dir = std::env::temp_dir().join("r2human-xdg");
        let _ = std::fs::create_dir_all(&dir);
        c.env("XDG_RUNTIME_DIR", dir);
    }
    c
}

fn run_render(args: &[&str], image: &Path, out: &Path, extra_env: &[(&str, &str)]) -> String {
    let mut c = r2human_cmd();
    c.arg("render").args(args).arg("--image").arg(image).arg("--out").arg(out);
    for (k, v) in extra_env {
        c.env(k, v);
    }
    let o = c.output().expect("run r2human");
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "r2human render {args:?} failed:\n{text}");
    text
}

fn png_psnr(a: &Path, b: &Path) -> f64 {
    let a = image::open(a).unwrap().to_rgba8();
    let b = image::open(b).unwrap().to_rgba8();
    assert_eq!(a.dimensions(), b.dimensions());
    let x: Vec<f32> = a.as_raw().iter().map(|&v| f32::from(v) / 255.0).collect();
    let y: Vec<f32> = b.as_raw().iter().map(|&v| f32::from(v) / 255.0).collect();
    psnr(&x, &y)
}

#[test]
fn cli_render_backend_vulkan_matches_cpu_and_falls_back_without_a_device() {
    if context().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("person.png");
    common::write_figure(&img, 120, 160);
    // Geometric on both sides: the Vulkan backend has no neural path (the CPU default would pick the neural one).
    let common_args = ["--size", "96", "--yaw", "40", "--pitch", "10", "--renderer", "geometric"];
    let cpu = dir.path().join("cpu.png");
    let gpu = dir.path().join("gpu.png");
    run_render(&[&common_args[..], &["--backend", "cpu"]].concat(), &img, &cpu, &[]);
    let log = run_render(
        &[&common_args[..], &["--backend", "vulkan"]].concat(),
        &img,
        &gpu,
        &[("R2HUMAN_VULKAN_VALIDATION", "1")],
    );
    assert!(!log.contains("Validation") && !log.contains("VUID"), "validation messages:\n{log}");
    let p = png_psnr(&cpu, &gpu);
    eprintln!("render --backend vulkan vs cpu, VR view: PSNR {p:.1} dB");
    assert!(p >= 40.0, "PSNR {p}");
    // The person is really there (not two equal empty panoramas): the striped shirt's blue.
    let shot = image::open(&gpu).unwrap().to_rgb8();
    let blue = shot.pixels().filter(|p| p[2] > 150 && p[0] < 100).count();
    assert!(blue > 96 * 96 / 50, "{blue} shirt pixels");

    // An AR orbit (spatial fusion across the views) on both backends.
    let cpu_dir = dir.path().join("cpu_orbit");
    let gpu_dir = dir.path().join("gpu_orbit");
    let orbit = ["--size", "64", "--mode", "ar", "--orbit", "3", "--yaw", "20", "--renderer", "geometric"];
    run_render(&[&orbit[..], &["--backend", "cpu"]].concat(), &img, &cpu_dir, &[]);
    run_render(&[&orbit[..], &["--backend", "vulkan"]].concat(), &img, &gpu_dir, &[]);
    for i in 0..3 {
        let name = format!("view_{i:03}.png");
        let p = png_psnr(&cpu_dir.join(&name), &gpu_dir.join(&name));
        eprintln!("AR orbit view {i}: PSNR {p:.1} dB");
        assert!(p >= 40.0, "view {i}: PSNR {p}");
    }

    // No Vulkan driver: one clear message, then the CPU path (the very same image).
    let fallback = dir.path().join("fallback.png");
    let log = run_render(
        &[&common_args[..], &["--backend", "vulkan"]].concat(),
        &img,
        &fallback,
        &[("VK_ICD_FILENAMES", "/nonexistent/icd.json"), ("VK_DRIVER_FILES", "/nonexistent/icd.json")],
    );
    assert!(log.contains("rendering on the CPU instead") && log.contains("Vulkan"), "{log}");
    let device_warnings = log.lines().filter(|l| l.contains("WARN") && l.contains("Vulkan")).count();
    assert_eq!(device_warnings, 1, "one warning about the device:\n{log}");
    assert_eq!(image::open(&fallback).unwrap().to_rgb8(), image::open(&cpu).unwrap().to_rgb8());
}
