//! The whole still-photo path per input at 512², as `r2human render --image PHOTO` runs it
//! ([`PreparedInput::prepare`]: normalise -> geometry -> depth centring -> mesh -> source raster), for four
//! geometries: `fofnet` (the shipped FOF net on the body prior, `models/tiny/fof.onnx`, with the inputs it declares:
//! geometry only, body FOF + inflation prior and no image ([`FofNet::takes_image`] false), so pose landmarks, the
//! body fit, the reconciled body FOF, the inflation prior and the network all run), `body` (the body prior alone),
//! `body-placed` (what `--geometry auto` draws on stills: the inflation prior moved by the body's depths) and
//! `inflate` (the silhouette-inflation prior).
//! Inputs: a rendered synthetic subject (seed 3, the `body` bench's) and the shipped photos (`assets/photos`,
//! segmented once up front as `render` does, `--segment auto`).
//!
//! Criterion times the whole `prepare`; every iteration's own stage times ([`PreparedInput::timings`]) and its
//! wall-clock time are kept, and at the end a table of their medians is printed (markdown, the still-photo
//! table of docs/performance.md), with the target: everything from the photo's normalised view to the mesh
//! (inflation prior, pose landmarks, body fit, body FOF, FOF net, guard, depth centring, mesh), measured as the
//! iteration's wall-clock time minus its normalisation and source raster (the median over iterations). Stage times
//! do not add up to it: the inflation prior runs side by side with the pose, the fit and the body FOF. The last
//! column is the process CPU time of the whole `prepare` (every thread's, `getrusage`): on a machine others share,
//! wall-clock times grow with their load, this much less.
//!
//! Run: `cargo bench --bench still` (all; about three minutes) or a subset, e.g. `cargo bench --bench still --
//! fofnet/synthetic`. Needs `.tools` (`bash scripts/setup.sh`: ONNX Runtime, the pose and segmentation models,
//! the MakeHuman data).
//!
//! `STILL_HASHES=1 cargo bench --bench still` benchmarks nothing: it prints, per geometry and input, the mesh's size
//! and a hash of its vertex bits and triangles, and a hash of the FOF's coefficient bits. Speed work that must keep
//! the output bits compares these before and after a change (same toolchain).

#[path = "../tests/common/cpu_time.rs"]
mod cpu_time;

use std::collections::BTreeMap;
use std::hint::black_box;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use r2human::body::prior::BodyEstimator;
use r2human::buffer::Image;
use r2human::capture::segment::{segment_photo, SegmentMethod};
use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::neural::FofNet;
use r2human::pipeline::{GeometryMode, PrepareOptions, PreparedInput};

use cpu_time::process_cpu_time;
use r2human::synth::{self, SubjectParams, SynthAssets};

const RES: usize = 512;
/// Stages that are not part of the target ("pose + fit + FOF net + mesh"): the photo's normalisation
/// before the geometry and the source-view raster after the mesh (both per-input costs, reported separately).
const OUTSIDE_TARGET: [&str; 2] = ["normalise", "source raster"];

/// One input: a name and the photo (linear RGB) with its person mask.
struct Input {
    name: String,
    rgb: r2human::buffer::RgbImage,
    mask: r2human::buffer::GrayImage,
}

/// One iteration: its stage times ([`PreparedInput::timings`]), the wall-clock time of the whole `prepare` and the
/// process CPU time it used (all threads: the work the two cores have to do, whatever else runs on them).
type Run = (Vec<(&'static str, Duration)>, Duration, Duration);
/// Per (geometry, input): every iteration's [`Run`].
type Recorded = BTreeMap<(usize, usize), Vec<Run>>;

fn inputs() -> Vec<Input> {
    let assets = SynthAssets::shared().expect("synthetic-subject data: run bash scripts/setup.sh");
    let subject = synth::generate(assets, &SubjectParams::sample(3), 1024).expect("subject");
    let view = render_ground_truth(&subject.mesh, &Camera::source(RES));
    let mut out = vec![Input {
        name: "synthetic".into(),
        rgb: Image { width: RES, height: RES, data: view.albedo.clone() },
        mask: view.mask_image(),
    }];
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/photos");
    let mut photos: Vec<_> = std::fs::read_dir(&dir)
        .expect("assets/photos")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "jpg"))
        .collect();
    photos.sort();
    for path in photos {
        let person = segment_photo(&path, None, &SegmentMethod::Auto).expect("segmentation: run bash scripts/setup.sh");
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        out.push(Input { name, rgb: person.photo.rgb, mask: person.mask });
    }
    out
}

fn median(mut v: Vec<Duration>) -> f64 {
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

fn benches(c: &mut Criterion) {
    let runtime = Default::default();
    let fof = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny/fof.onnx");
    let net = Arc::new(Mutex::new(FofNet::load(&fof, &runtime).expect("models/tiny/fof.onnx")));
    let body =
        Arc::new(Mutex::new(BodyEstimator::load(None, &runtime).expect("body prior: run bash scripts/setup.sh")));
    let base = PrepareOptions { resolution: RES, depth_samples: RES, ..Default::default() };
    let modes = [
        (
            "fofnet",
            PrepareOptions {
                geometry: GeometryMode::FofNet,
                fof_net: Some(net),
                body: Some(body.clone()),
                ..base.clone()
            },
        ),
        ("body", PrepareOptions { geometry: GeometryMode::Body, body: Some(body.clone()), ..base.clone() }),
        ("body-placed", PrepareOptions { geometry: GeometryMode::BodyPlaced, body: Some(body), ..base.clone() }),
        ("inflate", PrepareOptions { geometry: GeometryMode::Inflate, ..base }),
    ];
    let inputs = inputs();
    if std::env::var_os("STILL_HASHES").is_some() {
        print_hashes(&modes, &inputs);
        return;
    }
    // Per (mode, input): every iteration's stage times.
    let mut recorded = Recorded::new();
    let mut g = c.benchmark_group("still");
    g.sample_size(10);
    g.warm_up_time(Duration::from_secs(1));
    for (m, (mode, opts)) in modes.iter().enumerate() {
        for (i, input) in inputs.iter().enumerate() {
            let runs = recorded.entry((m, i)).or_default();
            g.bench_function(format!("{mode}/{}", input.name), |b| {
                b.iter(|| {
                    let (start, cpu) = (Instant::now(), process_cpu_time());
                    let p = PreparedInput::prepare(black_box(&input.rgb), &input.mask, opts).expect("prepare");
                    runs.push((p.timings.0.clone(), start.elapsed(), process_cpu_time().saturating_sub(cpu)));
                    p
                })
            });
        }
    }
    g.finish();
    print_table(&modes.map(|(m, _)| m), &inputs, &recorded);
}

/// One `prepare` per (mode, input): the mesh's vertex and triangle counts, a hash of its vertex bits and triangles,
/// a hash of the FOF's coefficient bits.
fn print_hashes(modes: &[(&str, PrepareOptions)], inputs: &[Input]) {
    use std::hash::{DefaultHasher, Hash, Hasher};
    for (mode, opts) in modes {
        for input in inputs {
            let p = PreparedInput::prepare(&input.rgb, &input.mask, opts).expect("prepare");
            let mut mesh = DefaultHasher::new();
            p.mesh.positions.iter().for_each(|v| v.to_array().map(f32::to_bits).hash(&mut mesh));
            p.mesh.triangles.hash(&mut mesh);
            let mut fof = DefaultHasher::new();
            p.fof.iter().flat_map(|f| &f.coeffs).for_each(|c| c.to_bits().hash(&mut fof));
            println!(
                "{mode} {}: mesh {} vertices {} triangles {:016x}, FOF {:016x}",
                input.name,
                p.mesh.positions.len(),
                p.mesh.triangles.len(),
                mesh.finish(),
                fof.finish()
            );
        }
    }
}

/// The medians of every stage per (mode, input), in markdown.
fn print_table(modes: &[&str], inputs: &[Input], recorded: &Recorded) {
    // Stage names in the order they first ran.
    let mut stages: Vec<&'static str> = Vec::new();
    for runs in recorded.values() {
        for (run, _, _) in runs {
            for (name, _) in run {
                if !stages.contains(name) {
                    stages.push(name);
                }
            }
        }
    }
    println!("\nstage medians (ms) per input, `cargo bench --bench still`:\n");
    println!(
        "| geometry | input | runs | {} | **target (wall)** | prepare (wall) | prepare (CPU) |",
        stages.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(" | ")
    );
    println!("|---|---|---|{}---|---|---|", "---|".repeat(stages.len()));
    for (&(m, i), runs) in recorded {
        if runs.is_empty() {
            continue;
        }
        let cell = |name: &str| {
            let v: Vec<Duration> =
                runs.iter().filter_map(|(r, _, _)| r.iter().find(|(n, _)| *n == name).map(|p| p.1)).collect();
            if v.is_empty() {
                "–".to_string()
            } else {
                format!("{:.1}", median(v))
            }
        };
        let target = median(
            runs.iter()
                .map(|(r, wall, _)| {
                    let outside: Duration = r.iter().filter(|(n, _)| OUTSIDE_TARGET.contains(n)).map(|p| p.1).sum();
                    wall.saturating_sub(outside)
                })
                .collect(),
        );
        let total = median(runs.iter().map(|(_, wall, _)| *wall).collect());
        let cpu = median(runs.iter().map(|(_, _, cpu)| *cpu).collect());
        println!(
            "| {} | {} | {} | {} | **{target:.1}** | {total:.1} | {cpu:.1} |",
            modes[m],
            inputs[i].name,
            runs.len(),
            stages.iter().map(|s| cell(s)).collect::<Vec<_>>().join(" | ")
        );
    }
}

criterion_group!(still, benches);
criterion_main!(still);
