//! `r2human eval --photos DIR` as a user runs it: real photos without ground truth, the checks and the contact
//! sheets, and bad folders.

mod common;

use std::path::Path;

use common::{r2human, run};

/// `r2human eval --photos PHOTOS --size 128 --no-neural --out OUT`: (success, output).
fn eval_photos(photos: &Path, out: &Path) -> (bool, String) {
    run(r2human().args(["eval", "--photos"]).arg(photos).args(["--size", "128", "--no-neural", "--out"]).arg(out))
}

fn project_file(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The CSV rows of `photos.csv` as (photo, method, segmentation, fields by column name).
fn csv_rows(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(str::to_string).collect();
    lines.map(|l| header.iter().cloned().zip(l.split(',').map(str::to_string)).collect()).collect()
}

#[test]
fn photo_folder_gets_checks_and_contact_sheets() {
    let dir = tempfile::tempdir().unwrap();
    let photos = dir.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    // A person with a real alpha (the demo person), a damaged file, and a file that is not an image.
    std::fs::copy(project_file("assets/demo/person.png"), photos.join("demo.png")).unwrap();
    std::fs::write(photos.join("broken.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
    std::fs::write(photos.join("notes.txt"), b"ignored").unwrap();
    let out = dir.path().join("out");
    let (ok, text) = eval_photos(&photos, &out);
    assert!(ok, "{text}");
    assert!(!out.join("report.md").exists(), "--photos alone evaluates no synthetic subject");
    let rows = csv_rows(&out.join("photos.csv"));
    assert_eq!(rows.len(), 1, "one photo x one method (geometric+inflation without networks): {rows:?}");
    let row = &rows[0];
    assert_eq!(row["photo"], "demo.png");
    assert_eq!(row["method"], "geometric+inflation");
    assert_eq!(row["segmentation"], "alpha", "the demo person has a real alpha");
    let psnr: f32 = row["input_psnr"].parse().unwrap();
    assert!(psnr > 20.0 && psnr.is_finite(), "the input view reproduces the photo: {psnr}");
    for yaw in [0, 30, 60, 90, 135, 180] {
        let d: f32 = row[&format!("detached_yaw{yaw}")].parse().unwrap();
        assert!((0.0..=0.005).contains(&d), "one body at yaw {yaw}: {d}");
    }
    assert_eq!(row["doubled"].parse::<f32>().unwrap(), 0.0, "the inflation prior is one shell");
    assert_eq!(row["passes"], "true");
    // The damaged photo is reported, not fatal.
    let md = std::fs::read_to_string(out.join("photos.md")).unwrap();
    assert!(md.contains("broken.png"), "{md}");
    assert!(md.contains("photos/demo.png"), "the report links the contact sheet: {md}");
    // The contact sheet: one row (one method), the input and six yaws; the person is drawn in every cell.
    let sheet = image::open(out.join("photos/demo.png")).unwrap().to_rgb8();
    let (thumb, gap) = (160u32, 4u32);
    assert_eq!((sheet.width(), sheet.height()), (7 * (thumb + gap) + gap, thumb + 2 * gap));
    for cell in 0..7 {
        let x0 = gap + cell * (thumb + gap);
        let grey = image::Rgb([118u8, 118, 118]);
        let differs = (0..thumb)
            .flat_map(|r| (0..thumb).map(move |c| (c, r)))
            .filter(|&(c, r)| {
                let p = sheet.get_pixel(x0 + c, gap + r);
                p.0.iter().zip(grey.0).any(|(a, b)| a.abs_diff(b) > 12)
            })
            .count();
        assert!(differs > 500, "cell {cell} shows the person ({differs} non-grey pixels)");
    }
    for e in std::fs::read_dir(&out).unwrap() {
        assert!(!e.unwrap().file_name().to_string_lossy().ends_with(".part"));
    }
}

#[test]
fn a_folder_without_photos_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let (ok, text) = run(r2human().args(["eval", "--photos"]).arg(dir.path()).arg("--out").arg(&out));
    assert!(!ok);
    assert!(text.contains("holds no photo"), "{text}");
    let (ok, text) = run(r2human().args(["eval", "--photos", "/nonexistent/folder", "--out"]).arg(&out));
    assert!(!ok);
    assert!(text.contains("/nonexistent/folder"), "names the folder: {text}");
}

#[test]
fn a_photo_without_alpha_is_segmented_by_the_model() {
    let model = project_file(".tools/models/pose_landmark_full.onnx");
    if !model.is_file() {
        eprintln!("skipped: the segmentation model is not installed (bash scripts/setup.d/live.sh)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let photos = dir.path().join("photos");
    std::fs::create_dir(&photos).unwrap();
    std::fs::copy(project_file("assets/photos/grace_hopper.jpg"), photos.join("grace_hopper.jpg")).unwrap();
    let out = dir.path().join("out");
    let (ok, text) = eval_photos(&photos, &out);
    assert!(ok, "{text}");
    let rows = csv_rows(&out.join("photos.csv"));
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_ne!(rows[0]["segmentation"], "alpha", "a JPEG has no alpha: the model segments it");
    assert!(out.join("photos/grace_hopper.png").is_file());
}
