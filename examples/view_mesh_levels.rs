//! Error against run time of the coarse view mesh ([`r2human::pipeline::CoarseMesh`]) on photos, for an XR eye:
//! 342x384 pixels, 90 degrees vertical field of view, the person 1.75 m ahead (the XR default), looked at from
//! several yaws around them. Per photo: the full and the coarse mesh's triangles, the target raster's median time
//! with the full mesh, the coarse one, and the coarse one without its back faces when it is closed (the three
//! alternated, so all see the same machine load), and how far the coarse mesh's render (as the eyes draw it) is
//! from the full mesh's (whole-frame PSNR, mask IoU of alpha > 0.5).
//!
//! Run: `cargo run --release --example view_mesh_levels -- [PHOTO...]` (default: every photo in assets/photos).

#[path = "common/photos.rs"]
mod photos;
#[path = "common/xr_eye.rs"]
mod xr_eye;

use std::time::{Duration, Instant};

use r2human::capture::segment::{segment_photo, SegmentMethod};
use r2human::eval::metrics::{mask_iou, psnr_frame, SrgbImage};
use r2human::geometry::raster::{rasterize_front_into, rasterize_into, GBuffer};
use r2human::pipeline::view::CpuView;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{Neural, PrepareOptions, PreparedInput, SourceView};
use r2human::xr::placement::DEFAULT_DISTANCE;

fn median_ms(mut v: Vec<Duration>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

fn main() -> anyhow::Result<()> {
    let photos = photos::from_args_or_bundled()?;
    let (w, h) = (342, 384);
    println!("| photo | triangles full / coarse | coarse closed | raster full / coarse / coarse front faces (ms) | PSNR coarse vs full, yaw 0 / 30 / 90 / 180 (dB) | mask IoU, same yaws |");
    println!("|---|---|---|---|---|---|");
    for photo in &photos {
        let person = segment_photo(photo, None, &SegmentMethod::Auto)?;
        let opts = PrepareOptions { coarse_views: true, ..PrepareOptions::default() };
        let input = PreparedInput::prepare(&person.photo.rgb, &person.mask, &opts)?;
        let Some(coarse) = input.coarse.as_ref() else { anyhow::bail!("{}: no coarse mesh", photo.display()) };
        let (mut psnrs, mut ious) = (Vec::new(), Vec::new());
        let (mut full_t, mut coarse_t, mut front_t) = (Vec::new(), Vec::new(), Vec::new());
        let (mut ga, mut gb) = (GBuffer::new(0, 0), GBuffer::new(0, 0));
        for yaw in [0.0f32, 30.0, 90.0, 180.0] {
            let camera = xr_eye::around_the_person(DEFAULT_DISTANCE, yaw, (w, h));
            for _ in 0..9 {
                let t = Instant::now();
                rasterize_into(&mut ga, &input.mesh, &camera);
                full_t.push(t.elapsed());
                let t = Instant::now();
                rasterize_into(&mut gb, &coarse.mesh, &camera);
                coarse_t.push(t.elapsed());
                if coarse.closed {
                    let t = Instant::now();
                    rasterize_front_into(&mut gb, &coarse.mesh, &camera);
                    front_t.push(t.elapsed());
                }
            }
            let draw = |coarse: bool| -> anyhow::Result<r2human::buffer::RgbaImage> {
                let mut source = SourceView::of(&input);
                if !coarse {
                    source.coarse = None;
                }
                Ok(CpuView::new(OcclusionFill::default(), false).draw(source, Neural::Off, 0, &camera)?.0)
            };
            let (a, b) = (draw(false)?, draw(true)?);
            let alpha = |img: &r2human::buffer::RgbaImage| img.data.iter().map(|p| p.w > 0.5).collect::<Vec<bool>>();
            psnrs
                .push(psnr_frame(&SrgbImage::from_linear_premultiplied(&a), &SrgbImage::from_linear_premultiplied(&b)));
            ious.push(mask_iou(&alpha(&a), &alpha(&b)));
        }
        let list = |v: &[f32], digits: usize| v.iter().map(|x| format!("{x:.digits$}")).collect::<Vec<_>>().join(" / ");
        println!(
            "| {} | {} / {} | {} | {:.1} / {:.1} / {} | {} | {} |",
            photo.file_name().map_or_else(|| photo.display().to_string(), |n| n.to_string_lossy().into_owned()),
            input.mesh.triangle_count(),
            coarse.mesh.triangle_count(),
            if coarse.closed { "yes" } else { "no" },
            median_ms(full_t),
            median_ms(coarse_t),
            if front_t.is_empty() { "-".to_string() } else { format!("{:.1}", median_ms(front_t)) },
            list(&psnrs, 1),
            list(&ious, 3)
        );
    }
    Ok(())
}
