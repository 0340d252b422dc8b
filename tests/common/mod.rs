//! Test fixtures shared by the integration tests.
#![allow(dead_code)]

use std::path::Path;
use std::process::Command;

/// The r2human binary of this build, logging warnings only.
pub fn r2human() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_r2human"));
    c.env("R2HUMAN_LOG", "warn");
    c
}

/// Runs a command to completion: (exit success, stdout and stderr together).
pub fn run(cmd: &mut Command) -> (bool, String) {
    let out = cmd.output().expect("run r2human");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.success(), text)
}

/// Draws a simple standing figure (head, torso, arms, legs) with a striped shirt into an RGBA PNG of
/// `w x h` pixels: alpha is the exact mask. Deterministic; used where a person photo with a mask is needed.
pub fn figure_rgba(w: u32, h: u32) -> image::RgbaImage {
    let mut img = image::RgbaImage::new(w, h);
    let (fw, fh) = (w as f32, h as f32);
    let s = fh / 100.0; // figure units: 100 tall
    let cx = fw / 2.0;
    for y in 0..h {
        for x in 0..w {
            let px = (x as f32 + 0.5 - cx) / s;
            let py = (y as f32 + 0.5) / s - (fh / s - 90.0) / 2.0; // figure spans y in [0, 90]
            let head = (px / 7.0).powi(2) + ((py - 9.0) / 8.5).powi(2) <= 1.0;
            let torso = px.abs() <= 12.0 && (17.0..=50.0).contains(&py);
            let arm = (12.0..=17.0).contains(&px.abs()) && (19.0..=48.0).contains(&py);
            let leg = (2.0..=10.0).contains(&px.abs()) && (50.0..=90.0).contains(&py);
            let colour = if head {
                [224, 172, 140]
            } else if torso || arm {
                if ((py / 4.0) as i32) % 2 == 0 {
                    [40, 90, 200]
                } else {
                    [230, 230, 230]
                }
            } else if leg {
                [60, 50, 40]
            } else {
                continue;
            };
            img.put_pixel(x, y, image::Rgba([colour[0], colour[1], colour[2], 255]));
        }
    }
    img
}

/// Writes [`figure_rgba`] to `path`.
pub fn write_figure(path: &Path, w: u32, h: u32) {
    figure_rgba(w, h).save(path).expect("write fixture");
}

/// The checkout's path of `path`.
pub fn repo(path: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// Runs the Khronos glTF validator (npm `gltf-validator`, installed into .tools by scripts/setup.d/gltf.sh, which
/// this runs when it is missing) on `path` and returns its JSON report; `None` (with a message) only when npm is
/// not installed.
pub fn khronos_validate(path: &Path) -> Option<serde_json::Value> {
    if Command::new("npm").arg("--version").output().is_err() {
        eprintln!("SKIPPED the glTF validator: npm is not installed (bash scripts/setup.d/gltf.sh installs it)");
        return None;
    }
    if !repo(".tools/gltf-validator/node_modules/gltf-validator/package.json").is_file() {
        let status = Command::new("bash").arg(repo("scripts/setup.d/gltf.sh")).status().unwrap();
        assert!(status.success(), "scripts/setup.d/gltf.sh failed");
    }
    let out = Command::new("node").arg(repo("scripts/gltf-validate.mjs")).arg(path).output().unwrap();
    let report: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("validator output: {e}: {}", String::from_utf8_lossy(&out.stderr)));
    Some(report)
}
