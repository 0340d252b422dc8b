//! Error against run time of the resolution live frames are prepared at, for an XR eye: each photo is prepared as
//! one live frame (the frame path with the options `xr --video` uses) at 512², 384² and 256², the three alternated
//! so they see the same machine load, and drawn as an eye draws it (342x384 pixels, 90 degrees vertical field of
//! view, the coarse mesh where an eye pixel is that large) with the viewer at 1.75 m (the XR default), 1.2 m and
//! 0.9 m, turned about the person to yaw 0, 30 and 90. Per photo and resolution: the frame's median preparation
//! time and how far its renders are from the 512² frame's (whole-frame PSNR, mask IoU of alpha > 0.5).
//!
//! Run: `cargo run --release --example live_resolution -- [PHOTO...]` (default: every photo in assets/photos). With
//! `LIVE_RESOLUTION_OUT=DIR` it also writes each view as `DIR/<photo>_<resolution>_<distance>m_yaw<yaw>.png`.

#[path = "common/photos.rs"]
mod photos;
#[path = "common/xr_eye.rs"]
mod xr_eye;

use std::path::PathBuf;
use std::time::Instant;

use r2human::buffer::RgbaImage;
use r2human::capture::segment::{segment_photo, SegmentMethod};
use r2human::capture::stats::median;
use r2human::eval::metrics::{mask_iou, psnr_frame, SrgbImage};
use r2human::neural::RuntimeOptions;
use r2human::pipeline::frame::FramePath;
use r2human::pipeline::view::CpuView;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{auto_frame_options, Neural, PrepareOptions, PreparedInput, SourceView};

const RESOLUTIONS: [usize; 3] = [512, 384, 256];
const DISTANCES: [f32; 3] = [1.75, 1.2, 0.9];
const YAWS: [f32; 3] = [0.0, 30.0, 90.0];

/// The eye views of one prepared frame: distances outer, yaws inner.
fn eye_views(input: &PreparedInput) -> anyhow::Result<Vec<RgbaImage>> {
    let mut out = Vec::new();
    for distance in DISTANCES {
        for yaw in YAWS {
            let camera = xr_eye::around_the_person(distance, yaw, (342, 384));
            out.push(
                CpuView::new(OcclusionFill::default(), true).draw(SourceView::of(input), Neural::Off, 0, &camera)?.0,
            );
        }
    }
    Ok(out)
}

fn main() -> anyhow::Result<()> {
    let photos = photos::from_args_or_bundled()?;
    let runtime = RuntimeOptions::default();
    let options: Vec<PrepareOptions> = RESOLUTIONS
        .iter()
        .map(|&r| Ok(PrepareOptions { coarse_views: true, ..auto_frame_options(None, r, &runtime)? }))
        .collect::<anyhow::Result<_>>()?;
    let distances = DISTANCES.map(|d| format!("{d} m")).join(" / ");
    println!(
        "| photo | frame | prepare (ms, median) | PSNR vs 512², yaw 0 / 30 / 90 at {distances} (dB) | mask IoU, same views |"
    );
    println!("|---|---|---|---|---|");
    for photo in &photos {
        let person = segment_photo(photo, None, &SegmentMethod::Auto)?;
        let mut times = vec![Vec::new(); RESOLUTIONS.len()];
        let mut prepared: Vec<Option<PreparedInput>> = vec![None; RESOLUTIONS.len()];
        for _ in 0..5 {
            for (k, opts) in options.iter().enumerate() {
                // A new frame path each time: one frame, nothing carried from the last.
                let mut path = FramePath::new(opts.clone());
                let t = Instant::now();
                let input = path.prepare(&person.photo.rgb, &person.mask)?;
                times[k].push(t.elapsed());
                prepared[k] = Some(input);
            }
        }
        let views: Vec<Vec<RgbaImage>> = prepared.iter().flatten().map(eye_views).collect::<anyhow::Result<_>>()?;
        let name = photo.file_name().map_or_else(|| photo.display().to_string(), |n| n.to_string_lossy().into_owned());
        if let Some(dir) = std::env::var_os("LIVE_RESOLUTION_OUT").map(PathBuf::from) {
            std::fs::create_dir_all(&dir)?;
            let stem = photo.file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned());
            for (r, frame_views) in RESOLUTIONS.iter().zip(&views) {
                let names = DISTANCES.iter().flat_map(|d| YAWS.iter().map(move |y| (d, y)));
                for ((d, y), view) in names.zip(frame_views) {
                    let file = dir.join(format!("{stem}_{r}_{d}m_yaw{y}.png"));
                    r2human::io::image_io::save_rgba_png(&file, view)?;
                }
            }
        }
        for (k, r) in RESOLUTIONS.iter().enumerate() {
            let alpha = |img: &RgbaImage| img.data.iter().map(|p| p.w > 0.5).collect::<Vec<bool>>();
            let (mut psnrs, mut ious) = (Vec::new(), Vec::new());
            for (a, b) in views[0].iter().zip(&views[k]) {
                psnrs.push(psnr_frame(
                    &SrgbImage::from_linear_premultiplied(a),
                    &SrgbImage::from_linear_premultiplied(b),
                ));
                ious.push(mask_iou(&alpha(a), &alpha(b)));
            }
            let groups = |v: &[f32], digits: usize| {
                v.chunks(YAWS.len())
                    .map(|c| c.iter().map(|x| format!("{x:.digits$}")).collect::<Vec<_>>().join(" / "))
                    .collect::<Vec<_>>()
                    .join(" · ")
            };
            let (psnr, iou) = if k == 0 { ("-".into(), "-".into()) } else { (groups(&psnrs, 1), groups(&ious, 3)) };
            println!("| {name} | {r}² | {:.1} | {psnr} | {iou} |", median(&times[k]).as_secs_f64() * 1e3);
        }
    }
    Ok(())
}
