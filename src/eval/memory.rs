//! Peak resident memory of one phase of the process (one method of `r2human eval`), as the kernel counts it.
//!
//! A counting global allocator would miss what ONNX Runtime allocates (its own arenas, through its own
//! allocator), so the probe reads the process's resident set instead: [`PhaseMemory::start`] hands freed heap
//! back to the OS (`malloc_trim`, glibc), resets the kernel's peak counter (`5` into `/proc/self/clear_refs`,
//! Linux 4.0+) and records the resident set; [`PhaseStart::finish`] reads the peak (`VmHWM`) since then.
//! The phase's memory is that peak minus the resident set at the start: what the phase needed on top of what was
//! already resident (code, loaded models, the subject). Phases must not overlap (the counter is per process).
//! Elsewhere (not Linux, or a kernel that refuses the reset) both readings are `None` and reports say so.

use std::fs;
use std::sync::atomic::{AtomicU64, Ordering};

/// The highest `VmHWM` (KiB) seen before a reset, so [`process_peak_mib`] still covers the whole run.
static PEAK_BEFORE_RESETS_KIB: AtomicU64 = AtomicU64::new(0);

/// Memory readings of one phase, in MiB.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseMemory {
    /// Resident set when the phase started.
    pub start_mib: f32,
    /// Peak resident set during the phase (at least `start_mib`).
    pub peak_mib: f32,
}

impl PhaseMemory {
    /// Memory the phase needed beyond what was resident when it started.
    pub fn extra_mib(&self) -> f32 {
        (self.peak_mib - self.start_mib).max(0.0)
    }

    /// Starts a phase; `None` where the peak cannot be reset or read (then the phase is not measured).
    pub fn start() -> Option<PhaseStart> {
        if let Some((_, hwm)) = read_status() {
            PEAK_BEFORE_RESETS_KIB.fetch_max(hwm, Ordering::Relaxed);
        }
        trim_heap();
        fs::write("/proc/self/clear_refs", "5").ok()?;
        let (rss, hwm) = read_status()?;
        // After a reset the peak equals the current resident set; a larger value means the reset did nothing.
        if hwm > rss + 1024 {
            return None;
        }
        Some(PhaseStart { start_kib: rss })
    }
}

/// A phase in progress (see [`PhaseMemory::start`]).
#[derive(Clone, Copy, Debug)]
pub struct PhaseStart {
    start_kib: u64,
}

impl PhaseStart {
    /// Ends the phase: the peak since [`PhaseMemory::start`].
    pub fn finish(self) -> Option<PhaseMemory> {
        let (_, hwm) = read_status()?;
        let mib = |kib: u64| kib as f32 / 1024.0;
        Some(PhaseMemory { start_mib: mib(self.start_kib), peak_mib: mib(hwm.max(self.start_kib)) })
    }
}

/// Peak resident memory of the whole process so far (MiB), phases included; `None` where unavailable.
pub fn process_peak_mib() -> Option<f32> {
    let (_, hwm) = read_status()?;
    Some(hwm.max(PEAK_BEFORE_RESETS_KIB.load(Ordering::Relaxed)) as f32 / 1024.0)
}

/// `(VmRSS, VmHWM)` in KiB from `/proc/self/status`.
fn read_status() -> Option<(u64, u64)> {
    let status = fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| -> Option<u64> {
        let line = status.lines().find(|l| l.starts_with(name))?;
        line[name.len()..].trim().trim_end_matches("kB").trim().parse().ok()
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

/// Returns free heap pages to the OS so the starting resident set holds only live memory (glibc only; other
/// allocators return large blocks on their own).
fn trim_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn malloc_trim(pad: usize) -> i32;
        }
        // SAFETY: glibc's malloc_trim only releases free memory; it takes no pointers.
        unsafe {
            malloc_trim(0);
        }
    }
}
