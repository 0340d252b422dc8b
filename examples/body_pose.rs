//! Pose landmarks drawn on a photo, to look at what the body prior starts from:
//! `cargo run --example body_pose -- PHOTO OUT.png [MASK]`.
//!
//! The mask is the photo's alpha, the given mask file, or the ONNX segmentation model's (`--segment onnx`).
//! Landmarks are drawn as dots (green = visible, red = not visible; visibility > 0.5), the skeleton as lines, and
//! the network's region as a box; the landmark table (photo pixels, depth, visibility, presence) is printed.

use std::path::PathBuf;

use anyhow::{bail, Context};
use glam::{Vec2, Vec3};
use r2human::body::pose::{PoseEstimator, NAMES, SKELETON};
use r2human::buffer::RgbImage;
use r2human::capture::{Frame, SegmentMethod};
use r2human::io::image_io;
use r2human::neural::RuntimeOptions;

fn dot(img: &mut RgbImage, p: Vec2, radius: f32, colour: Vec3) {
    let r = radius.ceil() as i64;
    for dy in -r..=r {
        for dx in -r..=r {
            let (x, y) = (p.x as i64 + dx, p.y as i64 + dy);
            if (dx * dx + dy * dy) as f32 <= radius * radius
                && x >= 0
                && y >= 0
                && (x as usize) < img.width
                && (y as usize) < img.height
            {
                img.set(x as usize, y as usize, colour);
            }
        }
    }
}

fn line(img: &mut RgbImage, a: Vec2, b: Vec2, width: f32, colour: Vec3) {
    let n = (a.distance(b).ceil() as usize).clamp(1, 4096);
    for i in 0..=n {
        dot(img, a.lerp(b, i as f32 / n as f32), width, colour);
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(photo_path), Some(out)) = (args.first(), args.get(1)) else {
        bail!("usage: body_pose PHOTO OUT.png [MASK]");
    };
    let photo = image_io::load_image(&PathBuf::from(photo_path))?;
    let mask = match (args.get(2), &photo.alpha) {
        (Some(m), _) => image_io::load_mask(&PathBuf::from(m), photo.rgb.width, photo.rgb.height)?,
        (None, Some(a)) => a.clone(),
        (None, None) => {
            let frame = Frame { index: 0, timestamp: Default::default(), rgb: photo.rgb.clone(), alpha: None };
            let mut seg = SegmentMethod::parse("onnx").context("onnx segmentation")?.build(Some(&frame))?;
            seg.segment(&frame)?
        }
    };
    let coverage = mask.data.iter().filter(|&&m| m >= 0.5).count() as f32 / mask.data.len().max(1) as f32;
    println!("mask covers {:.1}% of the photo", coverage * 100.0);
    if let Some(path) = std::env::var_os("BODY_POSE_MASK_OUT") {
        image_io::save_gray_png(&PathBuf::from(path), &mask)?;
    }
    let mut pose = PoseEstimator::load(None, &RuntimeOptions::default())?;
    let start = std::time::Instant::now();
    let found = pose.estimate(&photo.rgb, &mask, None)?;
    println!("pose: {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
    let mut img = photo.rgb.clone();
    for (v, m) in img.data.iter_mut().zip(&mask.data) {
        *v *= 0.35 + 0.65 * m;
    }
    let Some(p) = found else {
        image_io::save_rgb_png(&PathBuf::from(out), &img)?;
        println!("no pose found; wrote {out}");
        return Ok(());
    };
    println!("score {:.3}, region centre {:?} side {:.1}", p.score, p.region.centre, p.region.side);
    let s = (img.width.max(img.height) as f32 / 256.0).max(1.0);
    let (c, h) = (p.region.centre, p.region.side * 0.5);
    for (a, b) in [
        (Vec2::new(-h, -h), Vec2::new(h, -h)),
        (Vec2::new(h, -h), Vec2::new(h, h)),
        (Vec2::new(h, h), Vec2::new(-h, h)),
        (Vec2::new(-h, h), Vec2::new(-h, -h)),
    ] {
        line(&mut img, c + a, c + b, 0.5 * s, Vec3::new(0.2, 0.2, 1.0));
    }
    for &(a, b) in &SKELETON {
        let (la, lb) = (p.landmarks[a], p.landmarks[b]);
        let colour = if la.visibility.min(lb.visibility) > 0.5 { Vec3::ONE } else { Vec3::splat(0.3) };
        line(&mut img, la.pixel, lb.pixel, 0.6 * s, colour);
    }
    println!("{:>3} {:<18} {:>8} {:>8} {:>8} {:>6} {:>6}  world (m)", "i", "name", "x", "y", "depth", "vis", "pres");
    for (i, l) in p.landmarks.iter().enumerate() {
        let colour = if l.visibility > 0.5 { Vec3::new(0.0, 1.0, 0.0) } else { Vec3::new(1.0, 0.0, 0.0) };
        dot(&mut img, l.pixel, 1.6 * s, colour);
        let w = p.world[i];
        println!(
            "{i:>3} {:<18} {:>8.1} {:>8.1} {:>8.1} {:>6.3} {:>6.3}  ({:.2}, {:.2}, {:.2})",
            NAMES[i], l.pixel.x, l.pixel.y, l.depth, l.visibility, l.presence, w.x, w.y, w.z
        );
    }
    image_io::save_rgb_png(&PathBuf::from(out), &img)?;
    println!("wrote {out}");
    Ok(())
}
