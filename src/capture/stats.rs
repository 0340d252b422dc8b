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

/// A histogram of durations in fixed memory (50 µs bins up to 2 s, one overflow bin): the frame times of a
/// display loop that runs for hours without its bookkeeping growing.
#[derive(Clone, Debug)]
pub struct DurationHistogram {
    counts: Vec<u32>,
    overflow: u64,
    count: u64,
    sum: Duration,
    max: Duration,
}

impl Default for DurationHistogram {
    fn default() -> Self {
        Self { counts: vec![0; Self::BINS], overflow: 0, count: 0, sum: Duration::ZERO, max: Duration::ZERO }
    }
}

impl DurationHistogram {
    /// Bin width.
    pub const BIN: Duration = Duration::from_micros(50);
    /// Bins below the overflow (2 s).
    pub const BINS: usize = 40_000;

    /// Counts one duration.
    pub fn record(&mut self, d: Duration) {
        let bin = (d.as_nanos() / Self::BIN.as_nanos()) as usize;
        match self.counts.get_mut(bin) {
            Some(c) => *c = c.saturating_add(1),
            None => self.overflow += 1,
        }
        self.count += 1;
        self.sum += d;
        self.max = self.max.max(d);
    }

    /// Durations recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The longest duration recorded.
    pub fn max(&self) -> Duration {
        self.max
    }

    /// The mean (`ZERO` when empty).
    pub fn mean(&self) -> Duration {
        if self.count == 0 {
            Duration::ZERO
        } else {
            Duration::from_secs_f64(self.sum.as_secs_f64() / self.count as f64)
        }
    }

    /// The `q` quantile (`0..=1`) to within one bin: the centre of the bin holding it (the maximum when it lies
    /// in the overflow bin; `ZERO` when empty).
    pub fn quantile(&self, q: f64) -> Duration {
        if self.count == 0 {
            return Duration::ZERO;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c as u64;
            if seen >= rank {
                return Self::BIN * i as u32 + Self::BIN / 2;
            }
        }
        self.max
    }

    /// The median ([`Self::quantile`] 0.5).
    pub fn median(&self) -> Duration {
        self.quantile(0.5)
    }

    /// Counts per range: `edges` in milliseconds, ascending; ranges `[e_i, e_i+1)` and a last one from the last
    /// edge up. Each duration lands in the range holding its 50 µs bin's start.
    pub fn ranges(&self, edges_ms: &[f64]) -> Vec<(f64, Option<f64>, u64)> {
        let mut out: Vec<(f64, Option<f64>, u64)> =
            edges_ms.iter().enumerate().map(|(i, &lo)| (lo, edges_ms.get(i + 1).copied(), 0)).collect();
        let place = |ms: f64, out: &mut Vec<(f64, Option<f64>, u64)>, n: u64| {
            if let Some(r) = out.iter_mut().rev().find(|r| ms >= r.0) {
                r.2 += n;
            }
        };
        for (i, &c) in self.counts.iter().enumerate().filter(|(_, &c)| c > 0) {
            place((Self::BIN * i as u32).as_secs_f64() * 1e3, &mut out, c as u64);
        }
        if self.overflow > 0 {
            place((Self::BIN * Self::BINS as u32).as_secs_f64() * 1e3, &mut out, self.overflow);
        }
        out
    }

    /// Range edges (ms) of [`DurationHistogram::summary`]'s coarse histogram: under 10 ms, to 20, to a 30 Hz
    /// frame (33.3), to 50, 100, 250, 1000 ms, and longer.
    pub const SUMMARY_EDGES_MS: [f64; 8] = [0.0, 10.0, 20.0, 33.3, 50.0, 100.0, 250.0, 1000.0];

    /// One line: median, p99 and maximum in ms, then the coarse histogram (counts per range of
    /// [`DurationHistogram::SUMMARY_EDGES_MS`]), e.g. `median 16.70, p99 33.10, max 40.00; histogram [0,10) 0,
    /// [10,20) 98, …, 1000+ 0`. The window's and the XR session's reports print it; `examples/soak_report` reads
    /// the histogram back from their logs.
    pub fn summary(&self) -> String {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let bars: Vec<String> = self
            .ranges(&Self::SUMMARY_EDGES_MS)
            .iter()
            .map(|(lo, hi, n)| match hi {
                Some(hi) => format!("[{lo},{hi}) {n}"),
                None => format!("{lo}+ {n}"),
            })
            .collect();
        format!(
            "median {:.2}, p99 {:.2}, max {:.2}; histogram {}",
            ms(self.median()),
            ms(self.quantile(0.99)),
            ms(self.max()),
            bars.join(", ")
        )
    }

    /// A CSV of the non-empty bins: `from_ms,to_ms,frames` (the overflow bin's upper end is the maximum).
    pub fn to_csv(&self) -> String {
        let mut s = String::from("from_ms,to_ms,frames\n");
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        for (i, &c) in self.counts.iter().enumerate().filter(|(_, &c)| c > 0) {
            s.push_str(&format!("{:.2},{:.2},{c}\n", ms(Self::BIN * i as u32), ms(Self::BIN * (i as u32 + 1))));
        }
        if self.overflow > 0 {
            s.push_str(&format!("{:.2},{:.2},{}\n", ms(Self::BIN * Self::BINS as u32), ms(self.max), self.overflow));
        }
        s
    }
}

/// Least-squares line through `(x, y)` points: `(slope, intercept)`; `None` with fewer than two distinct `x`
/// (or a non-finite result). Soak runs fit resident memory against time with it.
pub fn linear_fit(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    if points.len() < 2 {
        return None;
    }
    let (mx, my) = points.iter().fold((0.0, 0.0), |(a, b), &(x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) =
        points.iter().fold((0.0, 0.0), |(a, b), &(x, y)| (a + (x - mx) * (y - my), b + (x - mx) * (x - mx)));
    let slope = sxy / sxx;
    (sxx > 0.0 && slope.is_finite()).then_some((slope, my - slope * mx))
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
    fn linear_fit_closed_forms() {
        // Exact line: y = 2x + 1.
        let (m, c) = linear_fit(&[(0.0, 1.0), (1.0, 3.0), (2.0, 5.0)]).unwrap();
        assert!((m - 2.0).abs() < 1e-12 && (c - 1.0).abs() < 1e-12);
        // Symmetric noise around y = 0.5x: (0,0) (1,1) (2,1) (3,2) -> slope 0.6, intercept 0.1.
        let (m, c) = linear_fit(&[(0.0, 0.0), (1.0, 1.0), (2.0, 1.0), (3.0, 2.0)]).unwrap();
        assert!((m - 0.6).abs() < 1e-12 && (c - 0.1).abs() < 1e-12, "{m} {c}");
        assert_eq!(linear_fit(&[(1.0, 2.0)]), None);
        assert_eq!(linear_fit(&[(1.0, 2.0), (1.0, 3.0)]), None, "no spread in x");
        // Large offsets (seconds since the epoch, bytes) stay exact enough: centred sums.
        let pts: Vec<(f64, f64)> = (0..1000).map(|i| (1.7e9 + i as f64, 5e8 + 3.0 * i as f64)).collect();
        assert!((linear_fit(&pts).unwrap().0 - 3.0).abs() < 1e-6);
    }

    #[test]
    fn histogram_quantiles_and_ranges() {
        let mut h = DurationHistogram::default();
        assert_eq!(h.median(), Duration::ZERO);
        for ms in 1..=100u64 {
            h.record(Duration::from_millis(ms));
        }
        h.record(Duration::from_secs(5)); // overflow
        assert_eq!(h.count(), 101);
        assert_eq!(h.max(), Duration::from_secs(5));
        // The 51st of 101 values is 51 ms: the bin [51, 51.05) ms, reported at its centre.
        assert_eq!(h.median(), Duration::from_micros(51_025));
        assert_eq!(h.quantile(1.0), Duration::from_secs(5));
        let r = h.ranges(&[0.0, 10.0, 50.0, 1000.0]);
        assert_eq!(r, vec![(0.0, Some(10.0), 9), (10.0, Some(50.0), 40), (50.0, Some(1000.0), 51), (1000.0, None, 1)]);
        let csv = h.to_csv();
        assert!(csv.starts_with("from_ms,to_ms,frames\n1.00,1.05,1\n"), "{csv}");
        assert!(csv.ends_with("2000.00,5000.00,1\n"), "{csv}");
        assert_eq!(csv.lines().count(), 102);
        // The one-line summary the reports print and soak_report reads back: 1..=9 ms, 10..=19, 20..=33, 34..=49,
        // 50..=99, 100, the 5 s overflow.
        let line = h.summary();
        assert!(line.starts_with("median 51.02, p99 "), "{line}");
        assert!(
            line.ends_with(
                ", max 5000.00; histogram [0,10) 9, [10,20) 10, [20,33.3) 14, [33.3,50) 16, [50,100) 50, [100,250) 1, \
                 [250,1000) 0, 1000+ 1"
            ),
            "{line}"
        );
    }

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
