//! Per-view stages at 512x512 on a ~126k-triangle synthetic person: raster, flow + Z-map + visibility,
//! geometric warp, fusion, and the chain raster + warp (which includes flow, Z-map and visibility).
//!
//! `cargo bench --bench per_view`

#[path = "../tests/common/person.rs"]
mod person;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::{Quat, Vec3};
use r2human::buffer::Image;
use r2human::geometry::raster::{rasterize, rasterize_into};
use r2human::geometry::zmap::{flow_and_zmap_into, visibility_into, FlowZ, VISIBILITY_LAMBDA};
use r2human::geometry::{Camera, Fov};
use r2human::pipeline::fusion::SpatialFusion;
use r2human::pipeline::warp::{render_from_flow, render_geometric, OcclusionFill};

const RES: usize = 512;

fn per_view(c: &mut Criterion) {
    let mesh = person::person(3);
    eprintln!("mesh: {} triangles", mesh.triangle_count());
    let src = Camera::source(RES);
    let gs = rasterize(&mesh, &src);
    let src_rgb = Image {
        width: RES,
        height: RES,
        data: gs.color.as_ref().unwrap().iter().zip(&gs.mask).map(|(c, &m)| *c * m as u8 as f32).collect(),
    };
    let src_mask = gs.mask_image();
    let orbit = Camera::orbit(135.0, 20.0, RES, RES);
    let eye = Camera::perspective(
        Vec3::new(0.6, 0.4, 2.2),
        Quat::from_rotation_y(0.3) * Quat::from_rotation_x(-0.15),
        Fov::symmetric(1.2, 1.0),
        0.05,
        RES,
        RES,
    );

    let mut group = c.benchmark_group("per_view_512");
    group.sample_size(20);
    let mut g = rasterize(&mesh, &orbit);
    group.bench_function("raster_orbit", |b| b.iter(|| rasterize_into(&mut g, &mesh, &orbit)));
    let mut ge = rasterize(&mesh, &eye);
    group.bench_function("raster_perspective", |b| b.iter(|| rasterize_into(&mut ge, &mesh, &eye)));

    let mut fz = FlowZ::default();
    let mut vis = Vec::new();
    group.bench_function("flow_zmap_visibility", |b| {
        b.iter(|| {
            flow_and_zmap_into(&mut fz, &g, &orbit, &src);
            visibility_into(&mut vis, &fz, &gs, &src, VISIBILITY_LAMBDA);
        })
    });
    for (name, fill) in [("warp_mirrored", OcclusionFill::MirroredFront), ("warp_propagate", OcclusionFill::Propagate)]
    {
        group.bench_function(name, |b| {
            b.iter(|| render_from_flow(&src_rgb, &src_mask, &src, &g, &orbit, &fz, &vis, fill));
        });
    }

    let out = render_geometric(&src_rgb, &src_mask, &gs, &src, &g, &orbit, OcclusionFill::MirroredFront);
    let orbit2 = Camera::orbit(140.0, 20.0, RES, RES);
    let g2 = rasterize(&mesh, &orbit2);
    let out2 = render_geometric(&src_rgb, &src_mask, &gs, &src, &g2, &orbit2, OcclusionFill::MirroredFront);
    let mut fusion = SpatialFusion::new();
    let mut flip = false;
    group.bench_function("fusion", |b| {
        b.iter(|| {
            // Alternate two views so every call warps and blends.
            flip = !flip;
            if flip {
                fusion.fuse(&out2, &g2, &orbit2)
            } else {
                fusion.fuse(&out, &g, &orbit)
            }
        })
    });

    let mut gt = rasterize(&mesh, &orbit);
    group.bench_function("chain_raster_flow_warp", |b| {
        b.iter(|| {
            rasterize_into(&mut gt, &mesh, &orbit);
            render_geometric(&src_rgb, &src_mask, &gs, &src, &gt, &orbit, OcclusionFill::MirroredFront)
        })
    });
    group.finish();
}

criterion_group!(benches, per_view);
criterion_main!(benches);
