//! The command line as a user meets it: real runs of the binary, good and bad input.

mod common;

use std::path::Path;

use common::{r2human, run};

fn no_partial_files(dir: &Path) {
    for e in std::fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.ends_with(".part"), "temporary file left behind: {name}");
    }
}

#[test]
fn renders_one_view_vr_and_ar() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("person.png");
    common::write_figure(&img, 300, 400);
    let out = dir.path().join("vr.png");
    let (ok, text) = run(r2human()
        .args(["render", "--image"])
        .arg(&img)
        .args(["--yaw", "150", "--pitch", "-20", "--size", "128", "--out"])
        .arg(&out));
    assert!(ok, "{text}");
    let vr = image::open(&out).unwrap();
    assert_eq!((vr.width(), vr.height()), (128, 128));
    assert!(!vr.color().has_alpha());

    let out_ar = dir.path().join("ar.png");
    let (ok, text) = run(r2human()
        .args(["render", "--mode", "ar", "--size", "96", "--image"])
        .arg(&img)
        .args(["--yaw", "180", "--out"])
        .arg(&out_ar));
    assert!(ok, "{text}");
    let ar = image::open(&out_ar).unwrap().into_rgba8();
    let opaque = ar.pixels().filter(|p| p.0[3] == 255).count();
    let clear = ar.pixels().filter(|p| p.0[3] == 0).count();
    assert!(opaque > 500 && clear > 2000, "person and transparent background: {opaque} {clear}");
    no_partial_files(dir.path());
}

#[test]
fn orbit_writes_frames_gif_and_sheet() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("person.png");
    common::write_figure(&img, 200, 260);
    let out = dir.path().join("orbit");
    let (ok, text) =
        run(r2human().args(["render", "--orbit", "4", "--size", "64", "--image"]).arg(&img).arg("--out").arg(&out));
    assert!(ok, "{text}");
    for i in 0..4 {
        assert!(out.join(format!("view_{i:03}.png")).exists());
    }
    assert!(image::open(out.join("orbit.gif")).is_ok());
    assert!(image::open(out.join("contact_sheet.png")).is_ok());
}

#[test]
fn bad_input_gets_a_clear_error_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    let render = |image: &Path, extra: &[&str]| {
        let mut c = r2human();
        c.args(["render", "--size", "64", "--image"]).arg(image).args(extra).arg("--out").arg(&out);
        run(&mut c)
    };

    // Truncated PNG.
    let good = dir.path().join("good.png");
    common::write_figure(&good, 120, 160);
    let bytes = std::fs::read(&good).unwrap();
    let cut = dir.path().join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
    let (ok, text) = render(&cut, &[]);
    assert!(!ok && text.contains("cut.png"), "{text}");

    // Not an image at all.
    let junk = dir.path().join("junk.jpg");
    std::fs::write(&junk, b"hello").unwrap();
    let (ok, text) = render(&junk, &[]);
    assert!(!ok && text.contains("decode"), "{text}");

    // No alpha, no mask and a bad segmentation model (tests/photo_input.rs has the rest of the mask choice).
    let rgb = dir.path().join("rgb.jpg");
    image::DynamicImage::ImageRgba8(common::figure_rgba(120, 160)).into_rgb8().save(&rgb).unwrap();
    let (ok, text) = render(&rgb, &["--segment", "alpha"]);
    assert!(!ok && text.contains("--mask"), "{text}");

    // Empty mask, full mask, tiny person.
    let empty = dir.path().join("empty.png");
    image::RgbaImage::new(100, 100).save(&empty).unwrap();
    let (ok, text) = render(&empty, &[]);
    assert!(!ok && text.contains("mask is empty"), "{text}");
    let full = dir.path().join("full.png");
    image::RgbaImage::from_pixel(100, 100, image::Rgba([9, 9, 9, 255])).save(&full).unwrap();
    let white = dir.path().join("white.png");
    image::GrayImage::from_pixel(100, 100, image::Luma([255])).save(&white).unwrap();
    let (ok, text) = render(&full, &["--mask", white.to_str().unwrap()]);
    assert!(!ok && text.contains("does not separate"), "{text}");
    // An opaque photo with nothing in it goes to the segmentation model (ISNet for stills), which finds no one.
    // (The pose model does not do for this: on a flat dark image it marks a blob as a person.)
    let isnet = Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools/models/isnet_seg.onnx");
    if isnet.is_file() {
        let (ok, text) = render(&full, &[]);
        assert!(!ok && text.contains("found no person in") && text.contains("--mask FILE"), "{text}");
    }
    let tiny = dir.path().join("tiny.png");
    let mut t = image::RgbaImage::new(400, 400);
    for y in 0..10 {
        for x in 0..8 {
            t.put_pixel(200 + x, 200 + y, image::Rgba([200, 100, 50, 255]));
        }
    }
    t.save(&tiny).unwrap();
    let (ok, text) = render(&tiny, &[]);
    assert!(!ok && text.contains("crop"), "{text}");

    // Mask of the wrong size.
    let mask = dir.path().join("mask.png");
    image::GrayImage::new(10, 10).save(&mask).unwrap();
    let (ok, text) = render(&rgb, &["--mask", mask.to_str().unwrap()]);
    assert!(!ok && text.contains("same size"), "{text}");

    // Out-of-range options.
    let (ok, text) = render(&good, &["--yaw", "nan"]);
    assert!(!ok && text.contains("finite"), "{text}");

    assert!(!out.exists(), "a failed render must not leave an output");
    no_partial_files(dir.path());
}

#[test]
fn non_square_and_mask_file_inputs_work() {
    let dir = tempfile::tempdir().unwrap();
    let fig = common::figure_rgba(500, 180); // very wide photo: the figure is short, so it is scaled up
    let rgb = dir.path().join("wide.jpg");
    image::DynamicImage::ImageRgba8(fig.clone()).into_rgb8().save(&rgb).unwrap();
    let mask = dir.path().join("wide_mask.png");
    image::GrayImage::from_fn(500, 180, |x, y| image::Luma([fig.get_pixel(x, y).0[3]])).save(&mask).unwrap();
    let out = dir.path().join("o.png");
    let (ok, text) = run(r2human()
        .args(["render", "--size", "64", "--yaw", "90", "--image"])
        .arg(&rgb)
        .arg("--mask")
        .arg(&mask)
        .arg("--out")
        .arg(&out));
    assert!(ok, "{text}");
    assert!(out.exists());
}

#[test]
fn video_folder_writes_one_png_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for i in 0..3 {
        common::write_figure(&frames.join(format!("f{i}.png")), 150, 200);
    }
    let out = dir.path().join("out");
    let (ok, text) = run(r2human()
        .args(["render", "--segment", "alpha", "--yaw", "45", "--size", "64", "--video"])
        .arg(&frames)
        .arg("--out")
        .arg(&out));
    assert!(ok, "{text}");
    let written = std::fs::read_dir(&out).unwrap().count();
    assert_eq!(written, 3, "{text}");
    // `auto` (the default) draws the inflation prior on frames (pipeline::FRAMES_AUTO_CHOICE) through the frame
    // path: no body is fitted, no FOF and no marching cubes, as the per-frame stage medians show.
    let medians = text.lines().find(|l| l.starts_with("per-frame stage medians")).unwrap_or_else(|| panic!("{text}"));
    assert!(medians.contains("geometry (inflate)") && medians.contains("mesh (depth maps)"), "{medians}");
    assert!(!medians.contains("body fit") && !medians.contains("FOF"), "{medians}");
    let (ok, text) =
        run(r2human().args(["render", "--segment", "nonsense", "--video"]).arg(&frames).arg("--out").arg(&out));
    assert!(!ok && text.contains("--segment"), "{text}");
}
