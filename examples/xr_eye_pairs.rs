//! The XR eye pair on the CPU reference without a headset: the eyes of [`r2human::xr::eyes::CpuEyeViews`] (what
//! `xr` draws on a software Vulkan device) drawn one after the other against both at once, alternated pair by
//! pair so both see the same machine load. A photo prepared as `xr --image` prepares it (the still default with the
//! coarse view mesh), eyes of 342x384 with a 90 degree vertical field of view, the person 1.75 m ahead, the head
//! turning a little every pair (so spatial fusion runs), VR over the embedded panorama and AR.
//!
//! Run: `cargo run --release --example xr_eye_pairs -- [PHOTO] [PAIRS]` (default: assets/photos/astronaut.png,
//! 40 pairs of each way). `THREADS=N` sizes the eyes' thread pool (as the session's own pool: default one per
//! core); `THREADS=1` shows what is left without a second core.
//!
//! Prints, per mode: the median wall time of a pair drawn each way and the eyes' stage medians of each way.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use glam::{Quat, Vec3};
use r2human::capture::segment::{segment_photo, SegmentMethod};
use r2human::compose::Mode;
use r2human::geometry::{Camera, Fov};
use r2human::io::environment::Environment;
use r2human::neural::RuntimeOptions;
use r2human::pipeline::{auto_still_options, PrepareOptions, PreparedInput, Scene};
use r2human::xr::eyes::CpuEyeViews;
use r2human::xr::placement::Placement;

fn median_ms(mut v: Vec<Duration>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

fn stage_line(views: &CpuEyeViews) -> String {
    views.stages.summary().iter().map(|s| format!("{} {:.1}", s.name, s.median_ms())).collect::<Vec<_>>().join(", ")
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args_os().skip(1);
    let photo = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/photos/astronaut.png"));
    let pairs: usize = match args.next() {
        Some(n) => n.to_string_lossy().parse()?,
        None => 40,
    };
    let threads = match std::env::var("THREADS") {
        Ok(t) => t.parse()?,
        Err(_) => std::thread::available_parallelism().map_or(2, |n| n.get()),
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;

    let person = segment_photo(&photo, None, &SegmentMethod::Auto)?;
    let auto = auto_still_options(None, &RuntimeOptions::default())?;
    let input =
        PreparedInput::prepare(&person.photo.rgb, &person.mask, &PrepareOptions { coarse_views: true, ..auto })?;
    let scene = Scene::from_prepared(&input, None);

    let (w, h) = (342, 384);
    let fov = Fov::symmetric(std::f32::consts::FRAC_PI_2, w as f32 / h as f32);
    let head = Vec3::new(0.0, 1.6, 0.0);
    let placement = Placement::in_front_of(head, Quat::IDENTITY, 0.0, 1.75);
    // The eyes 64 mm apart, the head turning by a fifth of a degree each pair.
    let cameras = |pair: usize| -> Vec<Camera> {
        let look = Quat::from_rotation_y((0.2 * pair as f32).to_radians());
        [-0.032f32, 0.032]
            .iter()
            .map(|&x| placement.eye_camera(head + look * Vec3::new(x, 0.0, 0.0), look, fov, w, h))
            .collect()
    };
    println!(
        "{} ({} triangles, coarse {}), eyes {w}x{h}, {pairs} pairs each way, {threads} thread(s)",
        photo.display(),
        input.mesh.triangle_count(),
        input.coarse.as_ref().map_or(0, |c| c.mesh.triangle_count())
    );
    for mode in [Mode::Vr, Mode::Ar] {
        let env = (mode == Mode::Vr).then(Environment::default_embedded);
        let mut one_by_one = CpuEyeViews::new(&[(w, h); 2], mode, env.clone())?;
        let mut at_once = CpuEyeViews::new(&[(w, h); 2], mode, env)?;
        let (mut t_one, mut t_once) = (Vec::new(), Vec::new());
        pool.install(|| -> anyhow::Result<()> {
            for pair in 0..pairs + 2 {
                let cams = cameras(pair);
                let start = Instant::now();
                for (eye, camera) in cams.iter().enumerate() {
                    one_by_one.draw_eye(Some((&scene, 1)), eye, camera)?;
                }
                let one = start.elapsed();
                let start = Instant::now();
                at_once.draw_eyes(Some((&scene, 1)), &cams)?;
                let once = start.elapsed();
                // The first two pairs warm the buffers up.
                if pair >= 2 {
                    t_one.push(one);
                    t_once.push(once);
                }
            }
            Ok(())
        })?;
        let (a, b) = (median_ms(t_one), median_ms(t_once));
        println!(
            "{mode:?}: pair one after the other {a:.1} ms, both at once {b:.1} ms ({:+.0} %)",
            100.0 * (b / a - 1.0)
        );
        println!("  stages one after the other (median ms per eye): {}", stage_line(&one_by_one));
        println!("  stages both at once (median ms per eye, wall while the other eye runs): {}", stage_line(&at_once));
    }
    Ok(())
}
