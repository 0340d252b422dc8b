//! Geometry benchmarks at the reference size (512x512 grid, 512 depth samples, N = 32):
//! - FOF decode + marching cubes of an ellipsoid body, the same field as the reference anchor
//!   (shared/tools/anchors/anchor_fof_mc.py: dense numpy decode + skimage marching cubes);
//! - the dense reference approach in Rust at 256^3 next to the sparse extractor at the same size;
//! - FOF from a mesh (interval automaton), the silhouette inflation, and the whole per-input path
//!   (inflate + FOF + mesh).
//!
//! Run: `cargo bench --bench fof`. Face counts are printed once so they can be compared with the anchor.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use r2human::buffer::{GrayImage, Image};
use r2human::geometry::fof::Fof;
use r2human::geometry::inflate::{inflate, inflate_to_fof, InflateParams};
use r2human::geometry::marching::{extract_mesh, extract_mesh_dense};

/// The anchor's ellipsoid body: x radius 0.35, y radius 0.6 around y = 0.2, half depth 0.25.
fn ellipsoid_fof(res: usize, n: usize) -> Fof {
    let intervals = Image::from_fn(res, res, |col, row| {
        let x = (col as f32 + 0.5) / (res as f32 * 0.5) - 1.0;
        let y = 1.0 - (row as f32 + 0.5) / (res as f32 * 0.5);
        let r2 = (x / 0.35).powi(2) + ((y - 0.2) / 0.6).powi(2);
        if r2 < 1.0 {
            let h = 0.25 * (1.0 - r2).sqrt();
            vec![(-h, h)]
        } else {
            Vec::new()
        }
    });
    Fof::from_intervals(&intervals, n).expect("valid field")
}

/// A person-like silhouette in the body cube (head, torso, arms, legs as capsules), height ~1.8.
pub fn person_mask(res: usize) -> GrayImage {
    let capsule = |p: (f32, f32), a: (f32, f32), b: (f32, f32), r: f32| {
        let (abx, aby) = (b.0 - a.0, b.1 - a.1);
        let t = (((p.0 - a.0) * abx + (p.1 - a.1) * aby) / (abx * abx + aby * aby).max(1e-12)).clamp(0.0, 1.0);
        let (dx, dy) = (p.0 - a.0 - t * abx, p.1 - a.1 - t * aby);
        dx * dx + dy * dy < r * r
    };
    GrayImage::from_fn(res, res, |col, row| {
        let p = ((col as f32 + 0.5) / (res as f32 * 0.5) - 1.0, 1.0 - (row as f32 + 0.5) / (res as f32 * 0.5));
        let inside = capsule(p, (0.0, 0.78), (0.0, 0.76), 0.11)
            || capsule(p, (0.0, 0.66), (0.0, 0.55), 0.05)
            || capsule(p, (0.0, 0.42), (0.0, 0.05), 0.17)
            || capsule(p, (-0.2, 0.5), (-0.42, 0.02), 0.05)
            || capsule(p, (0.2, 0.5), (0.42, 0.02), 0.05)
            || capsule(p, (-0.09, -0.02), (-0.13, -0.86), 0.07)
            || capsule(p, (0.09, -0.02), (0.13, -0.86), 0.07);
        if inside {
            1.0
        } else {
            0.0
        }
    })
}

fn benches(c: &mut Criterion) {
    let fof = ellipsoid_fof(512, 32);
    let mesh = extract_mesh(&fof, 512);
    eprintln!(
        "ellipsoid 512^2 x 512, N=32: {} faces, {} vertices (anchor reports its skimage face count)",
        mesh.triangle_count(),
        mesh.positions.len()
    );
    let small = ellipsoid_fof(256, 32);
    let sparse = extract_mesh(&small, 256);
    let dense = extract_mesh_dense(&small, 256);
    eprintln!(
        "256^3: sparse {} faces / dense reference {} faces (identical vertex sets are checked in the unit tests)",
        sparse.triangle_count(),
        dense.triangle_count()
    );
    let mask = person_mask(512);
    let params = InflateParams::default();
    let person = extract_mesh(&inflate_to_fof(&mask, 32, &params, None).expect("inflates"), 512);
    eprintln!("person inflation mesh: {} faces", person.triangle_count());

    let mut g = c.benchmark_group("geometry");
    g.sample_size(10);
    g.bench_function("fof_decode_mesh_512x512_d512_n32", |b| b.iter(|| extract_mesh(black_box(&fof), 512)));
    g.bench_function("sparse_mesh_256x256_d256_n32", |b| b.iter(|| extract_mesh(black_box(&small), 256)));
    g.bench_function("dense_reference_mesh_256x256_d256_n32", |b| {
        b.iter(|| extract_mesh_dense(black_box(&small), 256))
    });
    g.bench_function("fof_from_mesh_512_n32", |b| b.iter(|| Fof::from_mesh(black_box(&mesh), 512, 32)));
    g.bench_function("inflate_person_512", |b| b.iter(|| inflate(black_box(&mask), &params)));
    g.bench_function("inflate_to_fof_person_512_n32", |b| {
        b.iter(|| inflate_to_fof(black_box(&mask), 32, &params, None))
    });
    g.bench_function("per_input_inflate_fof_mesh_512_d512_n32", |b| {
        b.iter(|| {
            let f = inflate_to_fof(black_box(&mask), 32, &params, None).expect("inflates");
            extract_mesh(&f, 512)
        })
    });
    g.finish();
}

criterion_group!(geometry, benches);
criterion_main!(geometry);
