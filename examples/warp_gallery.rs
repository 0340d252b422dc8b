//! Renders a synthetic coloured person (and a sphere and a box) at yaw 0/90/180 and pitch +-90 with the
//! geometric warp, writes PNGs to /tmp/r2human_gallery/ and prints the PSNR of each occlusion fill against a
//! ground-truth render of the coloured mesh. The back fill's back image of the person is built from its known face
//! points (eyes, mouth line and ears of `tests/common/person.rs`, projected into the source view), which isolates
//! the fill from the pose network (that finds no face on this ellipsoid person); the sphere and the box have no
//! face, so their back fill is the mirrored-front one.
//!
//! `cargo run --release --example warp_gallery`

#[path = "../tests/common/person.rs"]
mod person;

use std::path::Path;

use glam::Vec2;
use glam::{Vec3, Vec4};
use r2human::buffer::{linear_to_srgb, Image, RgbaImage};
use r2human::geometry::raster::{rasterize, GBuffer};
use r2human::geometry::zmap::{flow_and_zmap, visibility, VISIBILITY_LAMBDA};
use r2human::geometry::{Camera, TriMesh};
use r2human::pipeline::back::{back_image, FacePoints};
use r2human::pipeline::warp::{render_geometric, OcclusionFill, SourceColours};

const RES: usize = 512;

/// Over a mid-grey background, sRGB 8-bit.
fn save_rgba(img: &RgbaImage, path: &Path) {
    let mut out = image::RgbImage::new(img.width as u32, img.height as u32);
    for (i, p) in img.data.iter().enumerate() {
        let c = p.truncate() + Vec3::splat(0.2) * (1.0 - p.w);
        let px = [c.x, c.y, c.z].map(|v| (linear_to_srgb(v) * 255.0).round() as u8);
        out.put_pixel((i % img.width) as u32, (i / img.width) as u32, image::Rgb(px));
    }
    out.save(path).expect("write PNG");
}

fn normals_rgba(g: &GBuffer) -> RgbaImage {
    Image {
        width: g.width,
        height: g.height,
        data: g
            .normal
            .iter()
            .zip(&g.mask)
            .map(|(n, &m)| if m { (*n * 0.5 + Vec3::splat(0.5)).extend(1.0) } else { Vec4::ZERO })
            .collect(),
    }
}

fn gt_rgba(g: &GBuffer) -> RgbaImage {
    let c = g.color.as_ref().expect("coloured mesh");
    Image {
        width: g.width,
        height: g.height,
        data: c.iter().zip(&g.mask).map(|(c, &m)| if m { c.extend(1.0) } else { Vec4::ZERO }).collect(),
    }
}

/// PSNR (dB) over the target mask, in sRGB-encoded values like image metrics usually are.
fn psnr(a: &RgbaImage, b: &RgbaImage, mask: &[bool], only: Option<&[bool]>) -> f32 {
    let (mut se, mut n) = (0.0f64, 0usize);
    for i in 0..mask.len() {
        if !mask[i] || only.is_some_and(|o| !o[i]) {
            continue;
        }
        for k in 0..3 {
            let d = linear_to_srgb(a.data[i][k]) - linear_to_srgb(b.data[i][k]);
            se += (d * d) as f64;
        }
        n += 3;
    }
    if n == 0 {
        return f32::NAN;
    }
    (10.0 * (1.0 / (se / n as f64)).log10()) as f32
}

fn main() {
    let dir = Path::new("/tmp/r2human_gallery");
    std::fs::create_dir_all(dir).expect("create /tmp/r2human_gallery");
    let mut sphere = TriMesh::uv_sphere(Vec3::ZERO, 0.7, 64, 128);
    sphere.colors =
        sphere.positions.iter().map(|p| (*p / 1.4 + Vec3::splat(0.5)).clamp(Vec3::ZERO, Vec3::ONE)).collect();
    let mut cube = TriMesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5));
    cube.colors = cube.positions.iter().map(|p| *p + Vec3::splat(0.5)).collect();
    let shapes = [("person", person::person(2)), ("sphere", sphere), ("box", cube)];
    let views = [(0.0, 0.0), (45.0, 0.0), (90.0, 0.0), (180.0, 0.0), (30.0, 90.0), (0.0, -90.0), (135.0, 30.0)];
    let src = Camera::source(RES);
    for (name, mesh) in &shapes {
        let gs = rasterize(mesh, &src);
        let src_rgba = gt_rgba(&gs);
        let src_rgb = src_rgba.map(|p| p.truncate());
        let src_mask = gs.mask_image();
        save_rgba(&src_rgba, &dir.join(format!("{name}_source.png")));
        // Source pixel of a body-cube point (orthographic source camera).
        let px = |x: f32, y: f32| Vec2::new((x + 1.0) * 0.5 * RES as f32, (1.0 - y) * 0.5 * RES as f32);
        let face = FacePoints { eyes: px(0.0, 0.74), mouth: px(0.0, 0.66), ears: [px(0.12, 0.73), px(-0.12, 0.73)] };
        let back = (*name == "person").then(|| back_image(&src_rgb, &src_mask, &face)).flatten().map(|b| b.rgb);
        if let Some(b) = &back {
            let m = &src_mask.data;
            let img =
                Image { width: RES, height: RES, data: b.data.iter().zip(m).map(|(c, &w)| c.extend(w)).collect() };
            save_rgba(&img, &dir.join(format!("{name}_back_image.png")));
        }
        let colours = SourceColours { rgb: &src_rgb, back: back.as_ref(), side: None };
        println!("{name}: {} triangles", mesh.triangle_count());
        for &(yaw, pitch) in &views {
            let cam = Camera::orbit(yaw, pitch, RES, RES);
            let gt = rasterize(mesh, &cam);
            let truth = gt_rgba(&gt);
            let fz = flow_and_zmap(&gt, &cam, &src);
            let vis = visibility(&fz, &gs, &src, VISIBILITY_LAMBDA);
            let occluded: Vec<bool> = gt.mask.iter().zip(&vis).map(|(&m, &v)| m && !v).collect();
            let tag = format!("{name}_y{yaw:03}_p{pitch:+03}");
            save_rgba(&truth, &dir.join(format!("{tag}_truth.png")));
            save_rgba(&normals_rgba(&gt), &dir.join(format!("{tag}_normals.png")));
            let mut line = format!(
                "  yaw {yaw:5.1} pitch {pitch:+5.1}: visible {:5.1}%",
                100.0 * vis.iter().filter(|&&v| v).count() as f32 / gt.coverage().max(1) as f32
            );
            for (fname, fill) in [
                ("mirrored", OcclusionFill::MirroredFront),
                ("propagate", OcclusionFill::Propagate),
                ("back", OcclusionFill::Back),
            ] {
                let out = render_geometric(colours, &src_mask, &gs, &src, &gt, &cam, fill);
                save_rgba(&out, &dir.join(format!("{tag}_{fname}.png")));
                line += &format!(
                    " | {fname}: PSNR {:5.2} dB (occluded only {:5.2})",
                    psnr(&out, &truth, &gt.mask, None),
                    psnr(&out, &truth, &gt.mask, Some(&occluded))
                );
            }
            println!("{line}");
        }
    }
    println!("PNGs in {}", dir.display());
}
