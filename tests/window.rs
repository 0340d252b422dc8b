//! The mirror window under a virtual X server (Xvfb): open it, render frames through the Vulkan swapchain on
//! lavapipe with validation on, write a screenshot and check the person is in it. The test starts its own Xvfb
//! and skips (with the reason printed) only when no Xvfb binary exists.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use r2human::app::mirror::{run_view_with_stats, Backend, ViewOptions};
use r2human::compose::Mode;

struct Xvfb(Child);

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn find_xvfb() -> Option<PathBuf> {
    std::env::var_os("PATH")?.to_str()?.split(':').map(|d| Path::new(d).join("Xvfb")).find(|p| p.is_file())
}

fn start_xvfb() -> Option<(Xvfb, String)> {
    let bin = find_xvfb()?;
    // A display number unlikely to collide with other test runs on the machine.
    for n in 0..20 {
        let display = 140 + (std::process::id() as usize + n * 7) % 300;
        if Path::new(&format!("/tmp/.X11-unix/X{display}")).exists() {
            continue;
        }
        let child = Command::new(&bin)
            .arg(format!(":{display}"))
            .args(["-screen", "0", "640x480x24", "-nolisten", "tcp"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .ok()?;
        let guard = Xvfb(child);
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            if Path::new(&format!("/tmp/.X11-unix/X{display}")).exists() {
                return Some((guard, format!(":{display}")));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    None
}

/// A person-shaped magenta silhouette with alpha (head, torso, legs) on a transparent background.
fn write_person(path: &Path) {
    let (w, h) = (200u32, 200u32);
    let img = image::RgbaImage::from_fn(w, h, |x, y| {
        let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
        let head = ((fx - 100.0) / 18.0).powi(2) + ((fy - 38.0) / 22.0).powi(2) <= 1.0;
        let torso = (70.0..130.0).contains(&fx) && (60.0..125.0).contains(&fy);
        let legs = ((76.0..96.0).contains(&fx) || (104.0..124.0).contains(&fx)) && (120.0..185.0).contains(&fy);
        if head || torso || legs {
            image::Rgba([235, 30, 210, 255])
        } else {
            image::Rgba([0, 0, 0, 0])
        }
    });
    img.save(path).unwrap();
}

#[test]
fn mirror_window_renders_frames_and_screenshots_the_person() {
    let Some((_xvfb, display)) = start_xvfb() else {
        eprintln!("SKIPPED: no Xvfb binary on PATH (install xvfb)");
        return;
    };
    std::env::set_var("DISPLAY", &display);
    std::env::remove_var("WAYLAND_DISPLAY");
    std::env::set_var("R2HUMAN_VULKAN_VALIDATION", "1");
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        let dir = std::env::temp_dir().join("r2human-xdg");
        std::fs::create_dir_all(&dir).unwrap();
        std::env::set_var("XDG_RUNTIME_DIR", dir);
    }
    let dir = tempfile::tempdir().unwrap();
    let person = dir.path().join("person.png");
    write_person(&person);
    let shot = dir.path().join("shot.png");
    let opts = ViewOptions {
        image: person,
        mode: Mode::Vr,
        backend: Backend::Vulkan,
        frames: Some(6),
        size: 128,
        screenshot_dir: dir.path().to_path_buf(),
        screenshot_on_exit: Some(shot.clone()),
        resolution: 128,
        ..ViewOptions::default()
    };
    let stats = match run_view_with_stats(opts) {
        Ok(s) => s,
        Err(e) => panic!("the mirror failed: {e:#}"),
    };
    eprintln!("window: {} frames on {}, median {:?}", stats.frames, stats.device, stats.median_frame);
    assert_eq!(stats.frames, 6);
    assert_eq!(stats.validation_messages, 0, "validation messages (see the log)");
    assert_eq!(stats.screenshots, vec![shot.clone()]);
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (128, 128));
    // The person is magenta (strong red and blue, little green); the panorama has nothing like it.
    let magenta = |p: &image::Rgb<u8>| p[0] > 150 && p[2] > 130 && p[1] < 90;
    let mut count = 0usize;
    let (mut cx, mut cy) = (0.0f64, 0.0f64);
    for (x, y, p) in img.enumerate_pixels() {
        if magenta(p) {
            count += 1;
            cx += f64::from(x);
            cy += f64::from(y);
        }
    }
    assert!(count > 128 * 128 / 20, "only {count} person pixels in the screenshot");
    let (cx, cy) = (cx / count as f64, cy / count as f64);
    assert!((cx - 64.0).abs() < 16.0 && (cy - 64.0).abs() < 24.0, "the person is off centre: ({cx}, {cy})");
    // The corners show the panorama, not the person.
    for (x, y) in [(2, 2), (125, 2)] {
        assert!(!magenta(img.get_pixel(x, y)));
    }
}
