//! Per-stage latency and throughput: a sliding window of durations per named stage, summarised by medians.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Median of a slice of durations (`ZERO` when empty); even lengths average the middle two.
pub fn median(values: &[Duration]) -> Duration {
    if values.is_empty() {
        return Duration::ZERO;
    }
    let mut v = values.to_vec();
    v.sort();
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        (v[m - 1] + v[m]) / 2
    }
}

/// The summary of one stage.
#[derive(Clone, Debug, PartialEq)]
pub struct StageSummary {
    /// Stage name ("segment", "geometry", "encoder", "frame", "view"…).
    pub name: String,
    /// Median latency over the window.
    pub median: Duration,
    /// Samples in the window.
    pub samples: usize,
    /// Samples recorded since the start.
    pub total: u64,
}

impl StageSummary {
    /// Median in milliseconds.
    pub fn median_ms(&self) -> f64 {
        self.median.as_secs_f64() * 1e3
    }
}

/// Sliding-window timings of named stages plus event counters (frames read, dropped, completed).
#[derive(Clone, Debug)]
pub struct StageStats {
    window: usize,
    stages: Vec<(String, VecDeque<Duration>, u64)>,
    completions: VecDeque<Instant>,
}

impl StageStats {
    /// Keeps the last `window` samples per stage (at least 1).
    pub fn new(window: usize) -> Self {
        Self { window: window.max(1), stages: Vec::new(), completions: VecDeque::new() }
    }

    /// Records one duration of `stage`.
    pub fn record(&mut self, stage: &str, d: Duration) {
        let window = self.window;
        let entry = match self.stages.iter().position(|(n, _, _)| n == stage) {
            Some(i) => &mut self.stages[i],
            None => {
                self.stages.push((stage.to_string(), VecDeque::new(), 0));
                self.stages.last_mut().expect("just pushed")
            }
        };
        if entry.1.len() == window {
            entry.1.pop_front();
        }
        entry.1.push_back(d);
        entry.2 += 1;
    }

    /// Times `f` as `stage`.
    pub fn time<R>(&mut self, stage: &str, f: impl FnOnce() -> R) -> R {
        let t = Instant::now();
        let r = f();
        self.record(stage, t.elapsed());
        r
    }

    /// Marks one completed frame at `at` (throughput = completions per second over the window).
    pub fn complete_frame(&mut self, at: Instant) {
        if self.completions.len() == self.window {
            self.completions.pop_front();
        }
        self.completions.push_back(at);
    }

    /// Completed frames per second over the window (0 with fewer than 2 completions).
    pub fn throughput_fps(&self) -> f64 {
        match (self.completions.front(), self.completions.back()) {
            (Some(a), Some(b)) if self.completions.len() >= 2 && *b > *a => {
                (self.completions.len() - 1) as f64 / (*b - *a).as_secs_f64()
            }
            _ => 0.0,
        }
    }

    /// Summaries in first-recorded order.
    pub fn summary(&self) -> Vec<StageSummary> {
        self.stages
            .iter()
            .map(|(name, v, total)| {
                let v: Vec<Duration> = v.iter().copied().collect();
                StageSummary { name: name.clone(), median: median(&v), samples: v.len(), total: *total }
            })
            .collect()
    }

    /// One line for a window title or a log: `segment 12.3 ms · geometry 40.1 ms · 8.2 fps`.
    pub fn overlay_line(&self) -> String {
        let mut parts: Vec<String> =
            self.summary().iter().map(|s| format!("{} {:.1} ms", s.name, s.median_ms())).collect();
        parts.push(format!("{:.1} fps", self.throughput_fps()));
        parts.join(" · ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_and_window() {
        let ms = Duration::from_millis;
        assert_eq!(median(&[]), Duration::ZERO);
        assert_eq!(median(&[ms(3), ms(1), ms(2)]), ms(2));
        assert_eq!(median(&[ms(4), ms(1), ms(2), ms(3)]), Duration::from_micros(2500));
        let mut s = StageStats::new(3);
        for d in [100, 1, 2, 3] {
            s.record("seg", ms(d));
        }
        s.record("geo", ms(7));
        let sum = s.summary();
        assert_eq!(sum[0].name, "seg");
        assert_eq!(sum[0].median, ms(2)); // 100 fell out of the window
        assert_eq!((sum[0].samples, sum[0].total), (3, 4));
        assert_eq!(sum[1].median, ms(7));
        let t0 = Instant::now();
        for i in 0..3 {
            s.complete_frame(t0 + ms(100 * i));
        }
        assert!((s.throughput_fps() - 10.0).abs() < 1e-6);
        assert!(s.overlay_line().contains("seg 2.0 ms"));
    }
}
