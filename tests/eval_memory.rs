//! The per-phase memory probe of `r2human eval` (alone in its own test binary: the kernel's peak counter is per
//! process, and other tests allocating in parallel threads would blur it).

use std::sync::Mutex;

use r2human::eval::memory::{process_peak_mib, PhaseMemory};
use r2human::eval::runner::{run_eval_with, EvalOptions, NeuralEvalOptions};

/// The kernel's peak counter is per process: the tests of this file take turns.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Touches `mib` MiB (every page written) and returns it, so it stays resident until dropped.
fn touch(mib: usize) -> Vec<u8> {
    let mut v = vec![0u8; mib << 20];
    for page in v.chunks_mut(4096) {
        page[0] = 1;
    }
    std::hint::black_box(&mut v);
    v
}

#[test]
fn a_phase_sees_its_own_peak_and_not_an_earlier_one() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let Some(start) = PhaseMemory::start() else {
        // Not Linux, or a kernel without the peak reset: the probe reports None and eval says so.
        assert!(!cfg!(target_os = "linux") || std::fs::write("/proc/self/clear_refs", "5").is_err());
        return;
    };
    let big = touch(256);
    drop(big);
    let first = start.finish().unwrap();
    assert!(first.extra_mib() >= 250.0 && first.extra_mib() < 300.0, "{first:?}");
    assert!(first.peak_mib >= first.start_mib);

    // The earlier 256 MiB peak must not leak into a phase that allocates little.
    let start = PhaseMemory::start().unwrap();
    let small = touch(8);
    drop(small);
    let second = start.finish().unwrap();
    assert!(second.extra_mib() >= 7.0 && second.extra_mib() < 40.0, "{second:?}");
    assert!(process_peak_mib().unwrap() >= first.peak_mib);
}

#[test]
fn eval_reports_what_each_method_needs_on_its_own() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    if PhaseMemory::start().is_none() {
        return; // no peak reset here: the column stays empty (checked in tests/synth.rs)
    }
    let dir = tempfile::tempdir().unwrap();
    let opts = EvalOptions {
        subjects: 1,
        seed: 3,
        out: dir.path().join("eval"),
        size: 256,
        yaws: vec![45.0, 180.0],
        texture_size: 128,
        ..EvalOptions::default()
    };
    let rep = run_eval_with(&opts, &NeuralEvalOptions { skip: true, ..Default::default() }).unwrap();
    let mib = |m: &str| rep.rows.iter().find(|r| r.method == m).and_then(|r| r.peak_mib).unwrap();
    // The billboard keeps nothing per input (its view is 1 MiB of RGBA); the geometric renderer holds at least the
    // source and the target G-buffer (depth, normal and mask: 17 bytes per pixel, 2 x 1.06 MiB at 256^2) besides
    // its FOF, mesh and view.
    let (billboard, geometric) = (mib("billboard"), mib("geometric+inflation"));
    eprintln!("billboard {billboard} MiB, geometric+inflation {geometric} MiB");
    assert!(billboard < 2.0, "billboard {billboard} MiB");
    assert!(geometric > 2.1 && geometric > billboard, "geometric {geometric} vs billboard {billboard} MiB");
    assert!(rep.peak_memory_mib >= geometric);
    let md = std::fs::read_to_string(opts.out.join("report.md")).unwrap();
    assert!(md.contains("| MiB |"), "{md}");
}
