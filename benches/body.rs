//! The body prior per input at 512² (a rendered synthetic subject, seed 3): pose landmarks (two network runs; live
//! frames are read the same way), the cold fit, a warm-started fit (the next live frame: landmarks moved by a
//! few pixels), the body FOF reconciled with the silhouette (N = 32), the mesh from it (512 depth samples), and
//! the whole still-photo path (pose + fit + body FOF + mesh). The two fits also run with the forward-difference
//! Jacobian for comparison.
//!
//! Run: `cargo bench --bench body` (needs `.tools`: the pose model and the MakeHuman data, `bash scripts/setup.sh`).

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec2;
use r2human::body::fit::{fit_body, FitOptions, FitTarget, JacobianKind};
use r2human::body::model::BodyModel;
use r2human::body::pose::PoseEstimator;
use r2human::body::prior::{body_fof, centre_depth};
use r2human::buffer::Image;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::geometry::inflate::InflateParams;
use r2human::geometry::marching::extract_mesh;
use r2human::synth::{self, SubjectParams, SynthAssets};

const RES: usize = 512;

fn benches(c: &mut Criterion) {
    let assets = SynthAssets::shared().expect("synthetic-subject data: run bash scripts/setup.sh");
    let model = BodyModel::shared().expect("body model data: run bash scripts/setup.sh");
    let subject = synth::generate(assets, &SubjectParams::sample(3), 1024).expect("subject");
    let view = render_ground_truth(&subject.mesh, &Camera::source(RES));
    let rgb = Image { width: RES, height: RES, data: view.albedo.clone() };
    let mask = Image { width: RES, height: RES, data: view.mask.iter().map(|&m| m as u8 as f32).collect() };
    let mut net = PoseEstimator::load(None, &Default::default()).expect("pose model: run bash scripts/setup.sh");
    let landmarks = net.estimate(&rgb, &mask, None).expect("pose network").expect("a pose");
    let options = FitOptions::default();
    let target = FitTarget::new(&landmarks, &mask);
    let cold = fit_body(model, &target, None, &options);
    let mut moved = landmarks.clone();
    moved.landmarks.iter_mut().for_each(|l| l.pixel += Vec2::new(3.0, 2.0));
    let moved_target = FitTarget::new(&moved, &mask);
    let warm = fit_body(model, &moved_target, Some(&cold.pose), &options);
    println!("fit evaluations: cold {}, warm {}", cold.evaluations, warm.evaluations);
    let (_, body_mesh) = centre_depth(model, &cold.pose);
    let params = InflateParams::default();
    let fof = body_fof(&body_mesh, &mask, None, 32, &params).expect("body FOF");

    let mut g = c.benchmark_group("body");
    g.sample_size(10);
    // Each iteration forgets the network's cached runs: a photo is read once (the cache serves one photo's reads).
    g.bench_function("pose_landmarks_still_512", |b| {
        b.iter(|| {
            net.forget_runs();
            net.estimate(black_box(&rgb), &mask, None)
        })
    });
    g.bench_function("fit_cold", |b| b.iter(|| fit_body(model, black_box(&target), None, &options)));
    g.bench_function("fit_warm", |b| b.iter(|| fit_body(model, black_box(&moved_target), Some(&cold.pose), &options)));
    // The same fits with the forward-difference Jacobian (the variant the analytic one replaced).
    let difference = FitOptions { jacobian: JacobianKind::ForwardDifference, ..FitOptions::default() };
    g.bench_function("fit_cold_difference_jacobian", |b| {
        b.iter(|| fit_body(model, black_box(&target), None, &difference))
    });
    g.bench_function("fit_warm_difference_jacobian", |b| {
        b.iter(|| fit_body(model, black_box(&moved_target), Some(&cold.pose), &difference))
    });
    g.bench_function("distance_field_512", |b| b.iter(|| FitTarget::new(black_box(&landmarks), &mask)));
    g.bench_function("body_mesh_and_centre", |b| b.iter(|| centre_depth(model, black_box(&cold.pose))));
    g.bench_function("body_fof_512_n32", |b| b.iter(|| body_fof(black_box(&body_mesh), &mask, None, 32, &params)));
    g.bench_function("mesh_512_d512", |b| b.iter(|| extract_mesh(black_box(&fof), 512)));
    g.bench_function("still_pose_fit_fof_mesh_512", |b| {
        b.iter(|| {
            net.forget_runs();
            let lm = net.estimate(black_box(&rgb), &mask, None).expect("runs").expect("a pose");
            let fit = fit_body(model, &FitTarget::new(&lm, &mask), None, &options);
            let (_, m) = centre_depth(model, &fit.pose);
            let f = body_fof(&m, &mask, None, 32, &params).expect("body FOF");
            extract_mesh(&f, 512)
        })
    });
    g.finish();
}

criterion_group!(body, benches);
criterion_main!(body);
