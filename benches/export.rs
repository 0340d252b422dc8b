//! `r2human export` stage by stage at 512x512 (the default reconstruction resolution) on the demo person
//! (assets/demo/person.png, a full body with an exact alpha mask): reconstruction (normalise, FOF, marching
//! cubes, source raster), then the export itself with and without `--decimate 20000` — decimation (meshoptimizer),
//! UVs + metres, texture bake, glTF encode + write — and the whole export after reconstruction.
//! `cargo bench --bench export`; docs/performance.md quotes the medians.

use criterion::{criterion_group, criterion_main, Criterion};
use r2human::capture::segment::segment_photo;
use r2human::capture::SegmentMethod;
use r2human::io::mesh_io::write_glb;
use r2human::pipeline::export::{person_glb, person_mesh, ExportOptions};
use r2human::pipeline::{PrepareOptions, PreparedInput};

fn bench(c: &mut Criterion) {
    let photo = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/demo/person.png");
    let person = segment_photo(photo.as_ref(), None, &SegmentMethod::Alpha).expect("the demo person loads");
    let prepare = PrepareOptions::default();
    let input = PreparedInput::prepare(&person.photo.rgb, &person.mask, &prepare).expect("reconstruction");
    let full = ExportOptions::default();
    let decimated = ExportOptions { decimate: Some(20_000), ..Default::default() };
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("person.glb");
    let (full_mesh, report) = person_mesh(&input, &person.mask, &full).expect("export");
    let (small_mesh, small) = person_mesh(&input, &person.mask, &decimated).expect("export");
    println!("full: {report}\ndecimated: {small}");

    let mut g = c.benchmark_group("export_512");
    g.sample_size(10);
    g.bench_function("reconstruct (normalise, FOF, marching cubes, source raster)", |b| {
        b.iter(|| PreparedInput::prepare(&person.photo.rgb, &person.mask, &prepare).unwrap())
    });
    g.bench_function("decimate to 20k triangles", |b| b.iter(|| input.mesh.simplified(20_000)));
    g.bench_function("UVs + texture bake, full mesh", |b| b.iter(|| person_mesh(&input, &person.mask, &full).unwrap()));
    g.bench_function("decimate + UVs + texture bake, 20k", |b| {
        b.iter(|| person_mesh(&input, &person.mask, &decimated).unwrap())
    });
    g.bench_function("encode + write, full mesh", |b| b.iter(|| write_glb(&path, &full_mesh).unwrap()));
    g.bench_function("encode + write, 20k", |b| b.iter(|| write_glb(&path, &small_mesh).unwrap()));
    g.bench_function("export after reconstruction, full mesh", |b| {
        b.iter(|| person_glb(&path, &input, &person.mask, &full).unwrap())
    });
    g.bench_function("export after reconstruction, 20k", |b| {
        b.iter(|| person_glb(&path, &input, &person.mask, &decimated).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
