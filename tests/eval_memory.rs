//! The per-phase memory probe of `r2human eval` (alone in its own test binary: the kernel's peak counter is per
//! process, and other tests allocating in parallel threads would blur it).

use r2human::eval::memory::{process_peak_mib, PhaseMemory};

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
