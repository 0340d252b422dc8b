//! What the body prior makes of a photo, as pictures: `cargo run --example body_fields -- PHOTO OUT.png`.
//!
//! Four panels of the normalised 512² source view: the person with the columns the fitted body covers (green),
//! the free columns the reconciliation fills (orange) and the landmarks; the front depth and the back depth of the
//! reconciled intervals (near = bright); and the side view (seen from the person's left, +x: depth across, height
//! down) of the occupied intervals (the body's columns green, the free columns orange). The mask is what `eval --photos` uses: the photo's alpha, else the still-photo segmentation.

use std::path::PathBuf;

use anyhow::{bail, Context};
use glam::Vec3;
use r2human::body::prior::BodyEstimator;
use r2human::body::reconcile::{classify, reconcile, Cell, ReconcileParams};
use r2human::buffer::{Image, RgbImage};
use r2human::capture::SegmentMethod;
use r2human::eval::photos::segment_photo;
use r2human::geometry::fof::{intervals_from_mesh, sheet_thickness};
use r2human::io::image_io;
use r2human::neural::RuntimeOptions;
use r2human::pipeline::input::normalise;

const RES: usize = 512;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(photo_path), Some(out)) = (args.first(), args.get(1)) else {
        bail!("usage: body_fields PHOTO OUT.png");
    };
    let method = SegmentMethod::parse("auto").context("segmentation")?;
    let (rgb, mask, how) = segment_photo(&PathBuf::from(photo_path), &method)?;
    println!("mask: {how}");
    let input = normalise(&rgb, &mask, RES)?;
    let mut body = BodyEstimator::load(None, &RuntimeOptions::default())?;
    let found = body.estimate(&input.rgb, &input.mask, Some(input.frame), false, &mut |name, d| {
        println!("{name}: {:.1} ms", d.as_secs_f64() * 1e3)
    })?;
    let Some(prior) = found else { bail!("no pose found in {photo_path}") };
    println!(
        "fit: {} evaluations, cost {:.1}, shape {:?}",
        prior.fit.evaluations, prior.fit.cost, prior.fit.pose.shape
    );
    for (i, l) in prior.landmarks.landmarks.iter().enumerate() {
        println!(
            "{i:2} {:18} {:7.1} {:7.1} vis {:.2} pres {:.2} world {:?}",
            r2human::body::pose::NAMES[i],
            l.pixel.x,
            l.pixel.y,
            l.visibility,
            l.presence,
            prior.landmarks.world[i]
        );
    }
    // The fitted body's point of each body joint against the network's world landmark, both about their hip
    // centre (fitted: cube units; network: metres; their 2-D extents give the scale between them).
    let model = body.model();
    let heads = model.rest_heads(&prior.fit.pose.shape);
    let g = model.skinning(&prior.fit.pose, &heads);
    let fitted =
        |i: usize| model.landmark_points[i].map(|p| model.point(p, &prior.fit.pose.shape, &heads, &g).as_vec3());
    let w = &prior.landmarks.world;
    if let (Some(l), Some(r)) = (fitted(23), fitted(24)) {
        let (fh, wh) = ((l + r) * 0.5, (w[23] + w[24]) * 0.5);
        println!("joint depth about the hip centre: fitted (cube units) / network (m)");
        for i in [0usize, 11, 12, 13, 14, 15, 16, 25, 26, 27, 28] {
            if let Some(f) = fitted(i) {
                println!("{i:2} {:18} {:+.3} / {:+.3}", r2human::body::pose::NAMES[i], f.z - fh.z, w[i].z - wh.z);
            }
        }
    }
    println!("frame {:?}, region {:?}", (prior.landmarks.frame_min, prior.landmarks.frame_max), prior.landmarks.region);
    let intervals = intervals_from_mesh(&prior.mesh, RES, RES, sheet_thickness(32));
    let cells = classify(&intervals, &input.mask, Some(input.frame));
    let t = std::time::Instant::now();
    let rec = reconcile(&intervals, &input.mask, Some(input.frame), &ReconcileParams::default());
    println!("reconcile: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    if let Some(dump) = std::env::var_os("BODY_FIELDS_DUMP") {
        let flat: Vec<String> =
            rec.data.iter().map(|l| format!("{:?}", l.first().copied().unwrap_or((0.0, 0.0)))).collect();
        std::fs::write(dump, flat.join("\n"))?;
    }

    let depth_colour = |z: f32| Vec3::splat(0.5 + 0.5 * z.clamp(-1.0, 1.0));
    let mut classes = input.rgb.clone();
    for (i, v) in classes.data.iter_mut().enumerate() {
        let tint = match cells[i] {
            Cell::Body => Vec3::new(0.2, 0.9, 0.2),
            Cell::Free => Vec3::new(1.0, 0.5, 0.0),
            Cell::Outside => Vec3::ZERO,
            Cell::Cut => Vec3::new(0.0, 0.0, 0.4),
        };
        *v = 0.5 * *v + 0.5 * tint;
    }
    for l in &prior.landmarks.landmarks {
        if l.visibility > 0.5 {
            let (c, r) = (l.pixel.x as i64, l.pixel.y as i64);
            for dr in -2..=2 {
                for dc in -2..=2 {
                    let (x, y) = (c + dc, r + dr);
                    if x >= 0 && y >= 0 && (x as usize) < RES && (y as usize) < RES {
                        classes.set(x as usize, y as usize, Vec3::new(1.0, 0.0, 1.0));
                    }
                }
            }
        }
    }
    let front = Image::from_fn(RES, RES, |c, r| {
        rec.get(c, r).last().map(|&(_, f)| depth_colour(f)).unwrap_or(Vec3::new(0.0, 0.0, 0.3))
    });
    let back = Image::from_fn(RES, RES, |c, r| {
        rec.get(c, r).first().map(|&(b, _)| depth_colour(-b)).unwrap_or(Vec3::new(0.0, 0.0, 0.3))
    });
    // Side view from +x: column = depth (near the camera on the right), row = row; brightness = how many columns
    // of that row are occupied at that depth, the body's columns in green, the free columns in orange (both: their
    // sum).
    let mut count = vec![[0u32; 2]; RES * RES];
    for r in 0..RES {
        for c in 0..RES {
            let class = usize::from(cells[r * RES + c] == Cell::Free);
            for &(a, b) in rec.get(c, r) {
                let (lo, hi) = (((a + 1.0) * 0.5 * RES as f32) as usize, ((b + 1.0) * 0.5 * RES as f32) as usize);
                for z in lo.min(RES - 1)..=hi.min(RES - 1) {
                    count[r * RES + z][class] += 1;
                }
            }
        }
    }
    let side = Image::from_fn(RES, RES, |z, r| {
        let [b, f] = count[r * RES + z].map(|n| (n as f32 / 40.0).min(1.0));
        Vec3::new(0.2, 0.9, 0.2) * b + Vec3::new(1.0, 0.5, 0.0) * f
    });
    let mut sheet: RgbImage = Image::new(4 * RES, RES, Vec3::ZERO);
    for (k, panel) in [&classes, &front, &back, &side].into_iter().enumerate() {
        for r in 0..RES {
            for c in 0..RES {
                sheet.set(k * RES + c, r, *panel.get(c, r));
            }
        }
    }
    image_io::save_rgb_png(&PathBuf::from(out), &sheet)?;
    println!("wrote {out}");
    Ok(())
}
