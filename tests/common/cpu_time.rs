//! Process CPU time for the still bench and `examples/still_stages` (both report wall and CPU time: on a machine
//! others share, CPU time is the figure the load changes least).

use std::time::Duration;

/// User + system CPU time of this process so far, every thread's (`getrusage(RUSAGE_SELF)`); zero if the call fails.
pub fn process_cpu_time() -> Duration {
    // SAFETY: `rusage` is plain old data, valid all zeros; `getrusage` only writes into the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: a valid pointer to a live `rusage`, as `getrusage` requires.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return Duration::ZERO;
    }
    let time = |t: libc::timeval| Duration::from_secs(t.tv_sec as u64) + Duration::from_micros(t.tv_usec as u64);
    time(usage.ru_utime) + time(usage.ru_stime)
}
