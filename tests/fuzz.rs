//! Mutation fuzzing of every file loader on stable Rust (`r2human::fuzzing` holds the targets, seeds and the
//! mutator, shared with the `cargo fuzz` crate in `fuzz/`).
//!
//! Per target: the committed corpus (`tests/corpus/<target>/`, crashes found earlier, kept as regressions) and
//! the generated seeds run unchanged, then `R2HUMAN_FUZZ_CASES` (default 1000) mutated inputs, reproducible from
//! `R2HUMAN_FUZZ_SEED` (default 0). Every input must end in `Ok` or an error naming its file (checked by
//! `fuzzing::run`), and here additionally:
//! - no panic (`catch_unwind` on a worker thread),
//! - no hang: each case has `R2HUMAN_FUZZ_TIMEOUT_MS` (default 20 s, dev profile on a loaded machine),
//! - no allocation beyond a budget derived from the input: a fixed 24 MiB, plus 64 bytes per pixel the image
//!   headers declare, where a header is believed for at most 16384 pixels per byte of its file (twice the densest
//!   format, 1-bit PNG at deflate's best ratio), plus 256 bytes per input byte for meshes and 64 for the rest.
//!   A counting global allocator measures the peak; it refuses (aborting the process, with the input left in the
//!   work folder) anything past 4 GiB live, so a runaway case cannot take the machine down.
//! - nothing written: the input folder is unchanged (in `fuzzing::run`), and `r2human render` on rejected inputs
//!   leaves no output file (`rejected_inputs_leave_no_output`).
//!
//! Failing inputs are written to `target/tmp/fuzz-failures/<target>/` with the reason; the fix goes into the
//! loader and the input into `tests/corpus/<target>/`. A summary (cases per target and outcome, slowest case,
//! largest allocation) is printed and written to `target/tmp/fuzz-report.json` (`R2HUMAN_FUZZ_REPORT` overrides)
//! and, as a Markdown table, beside it with the extension `.md`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use r2human::fuzzing::{self, Case, Outcome, Rng, Target};

// ------------------------------------------------------------------------------------------------------------
// Counting allocator
// ------------------------------------------------------------------------------------------------------------

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
const HARD_CAP: usize = 4 << 30;

fn reserve(n: usize) -> bool {
    let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
    if now > HARD_CAP {
        LIVE.fetch_sub(n, Ordering::Relaxed);
        // No allocation here: a static message, then the standard library aborts on the null pointer.
        use std::io::Write;
        let _ = std::io::stderr().write_all(
            b"\nfuzz: a case exceeded the 4 GiB allocation cap; its input is in target/tmp/fuzz-work/<target>/\n",
        );
        return false;
    }
    PEAK.fetch_max(now, Ordering::Relaxed);
    true
}

// SAFETY: every method forwards to the system allocator with the caller's layout and pointer unchanged; the
// counters only observe sizes, and a refused request returns null as the GlobalAlloc contract allows.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !reserve(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded with the caller's (valid, non-zero-size) layout.
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !reserve(layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: as in `alloc`.
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by `System` with this layout (through this allocator).
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > layout.size() && !reserve(new_size - layout.size()) {
            return std::ptr::null_mut();
        }
        // SAFETY: `ptr`/`layout` come from this allocator; `new_size` is the caller's.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            if new_size > layout.size() {
                LIVE.fetch_sub(new_size - layout.size(), Ordering::Relaxed);
            }
        } else if new_size < layout.size() {
            LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The tests of this file measure process-wide allocation: they run one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

// ------------------------------------------------------------------------------------------------------------
// Budget
// ------------------------------------------------------------------------------------------------------------

const BASE_BUDGET: u64 = 24 << 20;

/// Pixels an image header declares (format from the content, else from `name`: TGA has no signature), believed
/// up to 16384 per byte of the data that holds it (twice the densest format, 1-bit PNG at deflate's best
/// ratio), 131072 for WebP (twice the loader's bound: lossless WebP codes uniform images at almost 0 bits).
fn believable_pixels(bytes: &[u8], name: &str) -> u64 {
    let Ok(mut reader) = image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format() else { return 0 };
    if reader.format().is_none() {
        if let Ok(format) = image::ImageFormat::from_path(name) {
            reader.set_format(format);
        }
    }
    let per_byte = if reader.format() == Some(image::ImageFormat::WebP) { 131072 } else { 16384 };
    let declared = reader.into_dimensions().map(|(w, h)| w as u64 * h as u64).unwrap_or(0);
    declared.min(per_byte * bytes.len() as u64 + 65536)
}

/// The most bytes one case may have allocated at once beyond what was live before it.
fn budget(target: Target, case: &Case) -> u64 {
    let total: u64 = case.files.iter().map(|(_, b)| b.len() as u64).sum();
    let images: u64 = match target {
        Target::Image | Target::Mask | Target::Panorama | Target::ScanImage => {
            believable_pixels(&case.files[0].1, &case.files[0].0)
        }
        Target::Gltf | Target::Obj | Target::ObjTextures | Target::GltfTextures | Target::Ply => {
            case.texture().map(|(name, bytes)| believable_pixels(bytes, name)).unwrap_or(0)
        }
        // The texture is embedded: whatever image starts at a PNG or JPEG signature inside the file.
        Target::Glb => {
            let data = &case.files[0].1;
            (0..data.len().saturating_sub(4))
                .filter(|&i| data[i..].starts_with(b"\x89PNG") || data[i..].starts_with(&[0xFF, 0xD8, 0xFF]))
                .map(|i| believable_pixels(&data[i..], "embedded"))
                .max()
                .unwrap_or(0)
        }
        _ => 0,
    };
    let per_byte = match target {
        Target::Gltf | Target::Glb | Target::Obj | Target::ObjTextures | Target::GltfTextures | Target::Ply => 256,
        _ => 64,
    };
    BASE_BUDGET + 64 * images + per_byte * total
}

// ------------------------------------------------------------------------------------------------------------
// Running cases
// ------------------------------------------------------------------------------------------------------------

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn project_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn tmp_root() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
}

/// What one case did.
struct CaseResult {
    outcome: Result<Outcome, String>,
    time: Duration,
    peak: u64,
}

/// Runs one case on a worker thread with a time bound, measuring the peak allocation. `None` = it hung.
fn run_one(target: Target, data: &[u8], dir: &Path, timeout: Duration) -> Option<CaseResult> {
    let (tx, rx) = std::sync::mpsc::channel();
    let data = data.to_vec();
    let dir = dir.to_path_buf();
    // Wait for frees of the previous case's thread to settle, then measure from here.
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let start = Instant::now();
    std::thread::Builder::new()
        .name(format!("fuzz-{}", target.name()))
        .spawn(move || {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| fuzzing::run(target, &data, &dir)));
            let outcome = match r {
                Ok(Ok(o)) => Ok(o),
                Ok(Err(v)) => Err(v.to_string()),
                Err(p) => Err(format!("panic: {}", panic_message(&p))),
            };
            let _ = tx.send(outcome);
        })
        .expect("spawning a fuzz worker");
    let outcome = rx.recv_timeout(timeout).ok()?;
    let time = start.elapsed();
    let peak = PEAK.load(Ordering::Relaxed).saturating_sub(base) as u64;
    Some(CaseResult { outcome, time, peak })
}

fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(non-text panic)".into())
}

/// Counters of one target's run.
#[derive(Default, serde::Serialize)]
struct TargetReport {
    target: String,
    cases: u64,
    accepted: u64,
    rejected: u64,
    skipped: u64,
    failures: u64,
    slowest_ms: f64,
    largest_alloc_mib: f64,
    skip_reason: Option<String>,
    failure_files: Vec<String>,
}

/// Files of `tests/corpus/<target>/`, sorted.
fn committed_corpus(target: Target) -> Vec<(String, Vec<u8>)> {
    let dir = project_root().join("tests/corpus").join(target.name());
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&dir).map(|e| e.filter_map(|e| e.ok()).map(|e| e.path()).collect()).unwrap_or_default();
    files.retain(|p| p.is_file() && !p.extension().is_some_and(|e| e == "txt" || e == "md"));
    files.sort();
    files.into_iter().filter_map(|p| Some((p.display().to_string(), std::fs::read(&p).ok()?))).collect()
}

fn fuzz_target(target: Target, cases: u64, seed: u64, timeout: Duration) -> TargetReport {
    let mut report = TargetReport { target: target.name().into(), ..Default::default() };
    let dir = tmp_root().join(format!("fuzz-work-{}", std::process::id())).join(target.name());
    let failures_dir = tmp_root().join("fuzz-failures").join(target.name());
    let root = project_root();
    let seeds = fuzzing::seeds(target, &root);
    let committed = committed_corpus(target);
    // Parents for mutation: seeds, the committed corpus, then inputs the loader accepted (they reach deeper).
    let mut pool: Vec<Vec<u8>> = seeds.clone();
    pool.extend(committed.iter().map(|(_, b)| b.clone()));
    let fixed: Vec<(String, Vec<u8>)> =
        committed.into_iter().chain(seeds.into_iter().enumerate().map(|(i, b)| (format!("seed {i}"), b))).collect();
    let mut rng = Rng::new(seed ^ (target as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let total = fixed.len() as u64 + cases;
    for i in 0..total {
        let (label, data) = if (i as usize) < fixed.len() {
            fixed[i as usize].clone()
        } else {
            let mut data = pool[rng.below(pool.len())].clone();
            fuzzing::mutate(target, &mut data, &pool, &mut rng);
            (format!("seed {seed} case {i}"), data)
        };
        let Some(result) = run_one(target, &data, &dir, timeout) else {
            let file = save_failure(&failures_dir, &label, &data, &format!("no result within {timeout:?} (hang)"));
            report.failures += 1;
            report.failure_files.push(file);
            // The hung thread cannot be stopped: end this target here.
            break;
        };
        report.cases += 1;
        report.slowest_ms = report.slowest_ms.max(result.time.as_secs_f64() * 1e3);
        report.largest_alloc_mib = report.largest_alloc_mib.max(result.peak as f64 / (1 << 20) as f64);
        let case = Case::from_bytes(target, &data);
        let allowed = budget(target, &case);
        let problem = match &result.outcome {
            Err(e) => Some(e.clone()),
            Ok(_) if result.peak > allowed => Some(format!(
                "allocated {:.1} MiB at once; the budget for this {}-byte input is {:.1} MiB",
                result.peak as f64 / (1 << 20) as f64,
                data.len(),
                allowed as f64 / (1 << 20) as f64
            )),
            Ok(Outcome::Accepted) => {
                report.accepted += 1;
                if pool.len() < 256 && (i as usize) >= fixed.len() && data.len() < 256 << 10 {
                    pool.push(data.clone());
                }
                None
            }
            Ok(Outcome::Rejected(_)) => {
                report.rejected += 1;
                None
            }
            Ok(Outcome::Skipped(why)) => {
                report.skipped += 1;
                report.skip_reason = Some(why.clone());
                None
            }
        };
        if let Some(problem) = problem {
            report.failures += 1;
            if report.failure_files.len() < 20 {
                report.failure_files.push(save_failure(&failures_dir, &label, &data, &problem));
            }
        }
        if report.skipped > 0 {
            break; // the target cannot run here (said in the report)
        }
    }
    report
}

fn save_failure(dir: &Path, label: &str, data: &[u8], problem: &str) -> String {
    let _ = std::fs::create_dir_all(dir);
    let name: String = label.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '-' }).collect();
    let path = dir.join(format!("{name}.bin"));
    let _ = std::fs::write(&path, data);
    let _ = std::fs::write(path.with_extension("txt"), format!("{label}\n{problem}\n"));
    eprintln!("fuzz failure ({label}): {problem}\n  input: {}", path.display());
    path.display().to_string()
}

#[test]
fn every_loader_survives_mutated_inputs() {
    let _serial = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    let cases = env_u64("R2HUMAN_FUZZ_CASES", 1000);
    let seed = env_u64("R2HUMAN_FUZZ_SEED", 0);
    let timeout = Duration::from_millis(env_u64("R2HUMAN_FUZZ_TIMEOUT_MS", 20_000));
    let only = std::env::var("R2HUMAN_FUZZ_TARGETS").ok();
    let started = Instant::now();
    let mut reports = Vec::new();
    for target in Target::ALL {
        if only.as_deref().is_some_and(|o| !o.split(',').any(|t| t == target.name())) {
            continue;
        }
        let t0 = Instant::now();
        let r = fuzz_target(target, cases, seed, timeout);
        println!(
            "{:<13} {:>7} cases: {:>7} accepted, {:>7} rejected, {} skipped, {} failures; slowest {:.0} ms, largest \
             allocation {:.1} MiB; {:.1} s{}",
            r.target,
            r.cases,
            r.accepted,
            r.rejected,
            r.skipped,
            r.failures,
            r.slowest_ms,
            r.largest_alloc_mib,
            t0.elapsed().as_secs_f64(),
            r.skip_reason.as_deref().map(|s| format!(" ({s})")).unwrap_or_default()
        );
        reports.push(r);
    }
    let report_path =
        std::env::var("R2HUMAN_FUZZ_REPORT").map(PathBuf::from).unwrap_or_else(|_| tmp_root().join("fuzz-report.json"));
    let json = serde_json::json!({
        "seed": seed,
        "cases_per_target": cases,
        "seconds": started.elapsed().as_secs_f64(),
        "targets": reports,
    });
    std::fs::write(&report_path, serde_json::to_vec_pretty(&json).unwrap()).unwrap();
    // The same as a Markdown table (docs/reliability.md's table is made from a long run's).
    let mut md = format!(
        "| loader (target) | cases (seed {seed}) | accepted | rejected | failures | slowest case | largest allocation |\n\
         |---|---:|---:|---:|---:|---:|---:|\n"
    );
    for r in &reports {
        md.push_str(&format!(
            "| `{}` | {} | {} | {} | {} | {:.0} ms | {:.1} MiB |\n",
            r.target, r.cases, r.accepted, r.rejected, r.failures, r.slowest_ms, r.largest_alloc_mib
        ));
    }
    std::fs::write(report_path.with_extension("md"), md).unwrap();
    let failed: Vec<String> = reports.iter().flat_map(|r| r.failure_files.iter().cloned()).collect();
    let total_failures: u64 = reports.iter().map(|r| r.failures).sum();
    assert_eq!(total_failures, 0, "{total_failures} failing inputs, saved as {failed:#?}");
    // The harness must really exercise the loaders: mutated inputs reach both outcomes.
    for r in &reports {
        if r.skipped == 0 {
            assert!(r.accepted > 0 && r.rejected > 0, "{}: {} accepted, {} rejected", r.target, r.accepted, r.rejected);
        }
    }
}

/// The budget catches what it is meant to catch: a loader that believes a forged header.
#[test]
fn budget_refuses_a_forged_header() {
    let _serial = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    // A 40-odd byte PNG claiming 8000x8000 RGBA pixels (256 MB decoded as 8-bit).
    let mut png = fuzzing::seeds(Target::Image, &project_root()).remove(0);
    png[16..20].copy_from_slice(&8000u32.to_be_bytes());
    png[20..24].copy_from_slice(&8000u32.to_be_bytes());
    png.truncate(33 + 12);
    fuzzing::fix_png_crcs(&mut png);
    let case = Case::from_bytes(Target::Image, &png);
    let allowed = budget(Target::Image, &case);
    assert!(allowed < 100 << 20, "budget {allowed}");
    // Decoding it without the size check would allocate past the budget: the image crate alone asks for the
    // full pixel buffer.
    let dir = tmp_root().join("fuzz-budget");
    let r = run_one(Target::Image, &png, &dir, Duration::from_secs(60)).expect("no hang");
    match r.outcome {
        Ok(Outcome::Rejected(msg)) => assert!(msg.contains("photo.png") && msg.contains("8000x8000"), "{msg}"),
        other => panic!("expected a refusal, got {other:?}"),
    }
    assert!(r.peak < allowed, "{} > {allowed}", r.peak);
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let unchecked = image::load_from_memory_with_format(&png, image::ImageFormat::Png);
    let peak = PEAK.load(Ordering::Relaxed) - base;
    assert!(unchecked.is_err());
    assert!(peak as u64 > allowed, "the unchecked decoder allocated only {peak} bytes");
}

/// Forged headers of the scan texture formats (BMP, TGA, WebP, and a WebP frame larger than its canvas) are
/// refused before their pixel buffers exist, where the decoders alone allocate past the budget.
#[test]
fn forged_scan_texture_headers_are_refused_within_budget() {
    let _serial = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    let root = project_root();
    let seeds = fuzzing::seeds(Target::ScanImage, &root);
    let find = |magic: &[u8], nth: usize| seeds.iter().filter(|s| s.starts_with(magic)).nth(nth).unwrap().clone();
    // BMP: width and height (i32) at 18 and 22; the pixel data cut off.
    let mut bmp = find(b"BM", 0);
    bmp[18..22].copy_from_slice(&8000i32.to_le_bytes());
    bmp[22..26].copy_from_slice(&8000i32.to_le_bytes());
    bmp.truncate(70);
    // TGA (RLE, no signature): width and height (u16) at 12 and 14.
    let mut tga = seeds.iter().find(|s| !s.starts_with(b"BM") && !s.starts_with(b"RIFF")).unwrap().clone();
    tga[12..14].copy_from_slice(&8000u16.to_le_bytes());
    tga[14..16].copy_from_slice(&8000u16.to_le_bytes());
    tga.truncate(60);
    // Lossy WebP: the VP8 frame header's 14-bit width and height at 26 and 28.
    let mut webp = std::fs::read(root.join("tests/corpus/scan_image/lossy.webp")).unwrap();
    assert_eq!(&webp[12..16], b"VP8 ");
    webp[26..28].copy_from_slice(&8000u16.to_le_bytes());
    webp[28..30].copy_from_slice(&8000u16.to_le_bytes());
    // A 24x16 canvas whose VP8 frame claims 16383x16255 (found by the harness).
    let frame = std::fs::read(root.join("tests/corpus/scan_image/webp-frame-larger-than-canvas.webp")).unwrap();
    let cases = [
        ("photo.bmp", bmp, "8000x8000"),
        ("photo.tga", tga, "8000x8000"),
        ("photo.webp", webp, "8000x8000"),
        ("photo.webp", frame, "larger than its 24x16 canvas"),
    ];
    for (name, data, says) in cases {
        let case = Case::from_bytes(Target::ScanImage, &data);
        assert_eq!(case.files[0].0, name);
        let allowed = budget(Target::ScanImage, &case);
        let r = run_one(Target::ScanImage, &data, &tmp_root().join("fuzz-forged"), Duration::from_secs(60)).unwrap();
        match r.outcome {
            Ok(Outcome::Rejected(msg)) => assert!(msg.contains(name) && msg.contains(says), "{name}: {msg}"),
            other => panic!("{name}: expected a refusal, got {other:?}"),
        }
        assert!(r.peak < allowed, "{name}: {} > {allowed}", r.peak);
        // The decoder alone asks for the claimed pixel buffer (for the 250-byte WebP the budget itself believes
        // 131072 pixels per byte, so the comparison is with the checked load).
        let format = image::ImageFormat::from_path(name).unwrap();
        let base = LIVE.load(Ordering::Relaxed);
        PEAK.store(base, Ordering::Relaxed);
        let unchecked = image::load_from_memory_with_format(&data, format);
        let peak = PEAK.load(Ordering::Relaxed) - base;
        assert!(unchecked.is_err(), "{name}");
        assert!(
            peak > 100 << 20 && peak > 10 * r.peak as usize,
            "{name}: the unchecked decoder allocated only {peak} bytes (checked: {})",
            r.peak
        );
    }
}

/// `r2human render` on inputs the loaders reject fails with a message naming the file and writes nothing.
#[test]
fn rejected_inputs_leave_no_output() {
    let _serial = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    let root = project_root();
    let work = tmp_root().join("fuzz-cli");
    let mut rng = Rng::new(99);
    let mut tried = 0;
    for (target, flag) in [(Target::Image, "--image"), (Target::Panorama, "--env")] {
        let seeds = fuzzing::seeds(target, &root);
        let mut found = 0;
        for _ in 0..200 {
            if found == 2 {
                break;
            }
            let mut data = seeds[rng.below(seeds.len())].clone();
            fuzzing::mutate(target, &mut data, &seeds, &mut rng);
            let dir = work.join(format!("{}-{found}", target.name()));
            let Ok(Outcome::Rejected(_)) = fuzzing::run(target, &data, &dir.join("probe")) else { continue };
            let case = Case::from_bytes(target, &data);
            std::fs::create_dir_all(&dir).unwrap();
            let input = dir.join(&case.files[0].0);
            std::fs::write(&input, &case.files[0].1).unwrap();
            let out_dir = dir.join("out");
            std::fs::create_dir_all(&out_dir).unwrap();
            let person = root.join("assets/demo/person.png");
            let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_r2human"));
            cmd.arg("render").args(["--yaw", "30", "--size", "64", "--out"]).arg(out_dir.join("view.png"));
            if target == Target::Image {
                cmd.arg("--image").arg(&input);
            } else {
                cmd.arg("--image").arg(&person).arg(flag).arg(&input);
            }
            let out = cmd.env("R2HUMAN_LOG", "error").output().unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success(), "{} accepted a rejected input", target.name());
            assert!(stderr.contains(&case.files[0].0), "error does not name the file: {stderr}");
            let left: Vec<_> = std::fs::read_dir(&out_dir).unwrap().collect();
            assert!(left.is_empty(), "{}: files left in the output folder: {left:?}", target.name());
            found += 1;
            tried += 1;
        }
    }
    assert_eq!(tried, 4);
}

/// Prints what each committed corpus file now gives (`cargo test --test fuzz explain_corpus -- --ignored
/// --nocapture`): the regressions' messages, for naming and reviewing them.
#[test]
#[ignore]
fn explain_corpus() {
    let _serial = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    for target in Target::ALL {
        for (name, data) in committed_corpus(target) {
            let r = fuzzing::run(target, &data, &tmp_root().join("fuzz-explain"));
            println!("{name}: {r:?}");
        }
    }
}

/// The `cargo fuzz` crate (`fuzz/`, built with nightly only) has one target per loader, each calling the shared
/// entry point of its `Target`, so it cannot fall behind the stable harness unseen.
#[test]
fn cargo_fuzz_crate_has_a_target_per_loader() {
    let fuzz = project_root().join("fuzz");
    let manifest = std::fs::read_to_string(fuzz.join("Cargo.toml")).unwrap();
    let mut names = Vec::new();
    for target in Target::ALL {
        let name = target.name();
        names.push(name);
        let path = format!("fuzz_targets/{name}.rs");
        assert!(manifest.contains(&format!("name = \"{name}\"\npath = \"{path}\"")), "fuzz/Cargo.toml lacks {name}");
        let source = std::fs::read_to_string(fuzz.join(&path)).unwrap();
        assert!(source.contains(&format!("target!(r2human::fuzzing::Target::{target:?});")), "{path}: {source}");
    }
    let bins = manifest.matches("[[bin]]").count();
    assert_eq!(bins, names.len(), "fuzz/Cargo.toml has {bins} targets for {names:?}");
}

/// Writes the starting corpus of the `cargo fuzz` targets: `fuzz/corpus/<target>/` gets the generated seeds and
/// the committed corpus (`cargo test --test fuzz export_cargo_fuzz_corpus -- --ignored`).
#[test]
#[ignore]
fn export_cargo_fuzz_corpus() {
    let root = project_root();
    for target in Target::ALL {
        let dir = root.join("fuzz/corpus").join(target.name());
        std::fs::create_dir_all(&dir).unwrap();
        let seeds = fuzzing::seeds(target, &root).into_iter().enumerate().map(|(i, b)| (format!("seed-{i}"), b));
        let committed = committed_corpus(target)
            .into_iter()
            .map(|(path, b)| (Path::new(&path).file_name().unwrap().to_string_lossy().into_owned(), b));
        let mut n = 0;
        for (name, bytes) in seeds.chain(committed) {
            std::fs::write(dir.join(name), bytes).unwrap();
            n += 1;
        }
        println!("{}: {n} files", dir.display());
    }
}
