//! Per-stage wall-clock and CPU time of the still-photo FOF-net path on the shipped photos: each stage function
//! called on its own, one after another (no stage overlaps another), so its CPU time is its own work whatever the
//! machine's load. `cargo bench --bench still` times the whole `prepare` as the app runs it (stages side by side);
//! this example says where the CPU time goes inside it.
//!
//! Run: `cargo run --release --example still_stages -- [REPEATS [PHOTO_PREFIX]]` (default 5 repeats, every photo
//! in `assets/photos`). Prints, per photo, the median wall and process CPU time (every thread's, `getrusage`) of:
//! pose landmarks alone ([`PoseEstimator::estimate`]), pose + fit ([`BodyEstimator::estimate`]), the body FOF's
//! parts (depth placement, the body's intervals, the reconciliation, the encoding), the inflation prior, the FOF
//! net (the shipped `models/tiny/fof.onnx`), the one-shell stage, the guard, the depth centring and the mesh.

#[path = "../tests/common/cpu_time.rs"]
mod cpu_time;

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use r2human::body::pose::PoseEstimator;
use r2human::body::prior::{effective_frame, BodyEstimator};
use r2human::body::reconcile::{reconcile, ReconcileParams};
use r2human::capture::segment::{segment_photo, SegmentMethod};
use r2human::geometry::fof::{intervals_from_mesh, sheet_thickness, Fof};
use r2human::geometry::inflate::{inflate_to_fof, InflateParams};
use r2human::geometry::shells::drop_unexplained_shells;
use r2human::neural::{FofInput, FofNet};
use r2human::pipeline::input::normalise;

use cpu_time::process_cpu_time;

/// FOF coefficients and resolution of the still bench.
const N: usize = 32;
const RES: usize = 512;

/// Every stage's (wall, CPU) times in milliseconds, stages in the order they first ran.
#[derive(Default)]
struct Stages(Vec<(&'static str, Vec<(f64, f64)>)>);

impl Stages {
    fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let (wall, cpu) = (Instant::now(), process_cpu_time());
        let out = f();
        let sample = (wall.elapsed().as_secs_f64() * 1e3, (process_cpu_time() - cpu).as_secs_f64() * 1e3);
        match self.0.iter_mut().find(|(n, _)| *n == name) {
            Some((_, samples)) => samples.push(sample),
            None => self.0.push((name, vec![sample])),
        }
        out
    }

    fn print(&self) {
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        println!("| stage | wall (ms) | CPU (ms) |\n|---|---|---|");
        for (name, samples) in &self.0 {
            let wall = median(samples.iter().map(|s| s.0).collect());
            let cpu = median(samples.iter().map(|s| s.1).collect());
            println!("| {name} | {wall:.1} | {cpu:.1} |");
        }
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let repeats: usize = args.first().map(|s| s.parse()).transpose().context("REPEATS must be a number")?.unwrap_or(5);
    let prefix = args.get(1).cloned().unwrap_or_default();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let runtime = Default::default();
    // The shipped FOF net (geometry only: body FOF + inflation prior), as `cargo bench --bench still` runs it.
    let fof_net = root.join("models/tiny/fof.onnx");
    let mut net = FofNet::load(&fof_net, &runtime).with_context(|| format!("loading {}", fof_net.display()))?;
    let mut body = BodyEstimator::load(None, &runtime).context("body prior: run bash scripts/setup.sh")?;
    let mut pose = PoseEstimator::load(None, &runtime).context("pose model: run bash scripts/setup.sh")?;
    let inflate = InflateParams::default();
    let reconcile_params = ReconcileParams {
        thickness: inflate.thickness,
        min_half_thickness: inflate.min_half_thickness,
        min_half_depth: 0.5 * sheet_thickness(N),
        ..Default::default()
    };
    let dir = root.join("assets/photos");
    let mut photos: Vec<_> = std::fs::read_dir(&dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "jpg"))
        .filter(|p| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with(&prefix)))
        .collect();
    photos.sort();
    for path in photos {
        let person = segment_photo(&path, None, &SegmentMethod::Auto)
            .with_context(|| format!("segmenting {}", path.display()))?;
        let input = normalise(&person.photo.rgb, &person.mask, RES)?;
        let (mask, frame) = (&input.mask, Some(input.frame));
        let mut stages = Stages::default();
        for _ in 0..repeats {
            pose.forget_runs();
            stages
                .time("pose landmarks alone", || pose.estimate(&input.rgb, mask, Some(effective_frame(mask, frame))))?;
            let Some(prior) = stages
                .time("pose landmarks + fit", || body.estimate(&input.rgb, mask, frame, false, &mut |_, _| {}))?
            else {
                println!("{}: no pose found", path.display());
                break;
            };
            let mesh =
                stages.time("body depth placement", || r2human::pipeline::centre_visible_depth(prior.mesh, mask));
            let intervals = stages.time("body intervals", || intervals_from_mesh(&mesh, RES, RES, sheet_thickness(N)));
            let cut = Some(effective_frame(mask, frame));
            let reconciled = stages.time("reconciliation", || reconcile(&intervals, mask, cut, &reconcile_params));
            let body_fof = stages.time("body FOF encoding", || Fof::from_intervals(&reconciled, N))?;
            // Closed along the whole outline: the prior the FOF net refines (as `pipeline` feeds it).
            let prior_fof = stages.time("inflation prior", || inflate_to_fof(mask, N, &inflate, None))?;
            let mut refined =
                stages.time("FOF net", || net.refine_with(&input.rgb, mask, &prior_fof, Some(&body_fof)))?;
            stages.time("one shell per explained surface", || {
                drop_unexplained_shells(&mut refined, &[&prior_fof, &body_fof], mask)
            });
            // What the network refined: the guard measures against it (as `pipeline::compute_geometry` does).
            let base = match net.base() {
                FofInput::Body => body_fof,
                FofInput::Prior => prior_fof,
            };
            let (guarded, _) =
                stages.time("guard", || r2human::pipeline::guard::guarded(refined, base, mask, &Default::default()));
            let (centred, _) = stages.time("depth centring", || r2human::geometry::depth_centre::centre_fof(guarded));
            stages.time("mesh", || r2human::geometry::marching::extract_mesh(&centred, RES));
        }
        println!("\n{} ({repeats} repeats, medians):\n", path.display());
        stages.print();
    }
    Ok(())
}
