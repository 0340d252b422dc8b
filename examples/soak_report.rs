//! Summarises a soak run of `scripts/soak.sh`: resident memory against time (least-squares slope after warm-up,
//! in MiB per hour and per 1000 frames), the validation messages, whether the run ended as asked (not dropped),
//! and the display loop's frame times (histogram CSV and PNG).
//!
//! `cargo run --example soak_report -- DIR NAME` reads
//! - `DIR/NAME_rss.csv` (`seconds,rss_kib[,anon_kib,file_kib,shmem_kib]` per sample, from the script),
//! - `DIR/NAME.log`: the run's output (`view`'s or `xr`'s report: frame count, validation messages, the frame-time
//!   line of `DurationHistogram::summary`, how the session ended) and the script's `exit status: N` line,
//! - `DIR/NAME_heap.csv` when present (`seconds,in_use_kib,held_kib`: the C heap, `R2HUMAN_HEAP_LOG`),
//! - `DIR/NAME_frames.csv` when present (the window's `--frame-log`: per-frame times, a fine histogram),
//!
//! and writes `DIR/NAME_summary.txt` (also printed), `DIR/NAME_summary.json`, `DIR/NAME_histogram.csv`,
//! `DIR/NAME_frame_times.png` and `DIR/NAME_memory.png` (resident memory and the C heap against time, with the
//! warm-up and the fitted line). It exits with an error when the run was dropped or validation reported anything.

use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use r2human::capture::stats::{linear_fit, DurationHistogram};

fn read_csv(path: &Path) -> Result<Vec<Vec<f64>>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(text
        .lines()
        .filter(|l| l.chars().next().is_some_and(|c| c.is_ascii_digit()))
        .map(|l| l.split(',').filter_map(|v| v.trim().parse().ok()).collect())
        .collect())
}

/// The number right after `key` in `line` (`"frames submitted: 303 (18.8 per second)"`, `"frames submitted: "`).
fn number_after(line: &str, key: &str) -> Option<f64> {
    let rest = &line[line.find(key)? + key.len()..];
    let end = rest.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(rest.len());
    rest[..end].parse().ok()
}

/// What the run's log says.
#[derive(Debug, Default)]
struct LogFacts {
    frames: Option<u64>,
    /// Frames per second the report states (XR).
    fps: Option<f64>,
    validation: Option<u64>,
    /// How the run ended ("time budget reached", "exit status 0").
    ended: Vec<String>,
    /// The run ended as asked: exit status 0 and, for XR, on its frame or time budget.
    clean_end: bool,
    /// `(from ms, to ms, frames)` of the report's coarse histogram.
    coarse: Vec<(f64, Option<f64>, u64)>,
    frame_time_line: Option<String>,
}

fn read_log(path: &Path) -> Result<LogFacts> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut facts = LogFacts::default();
    let mut status_ok = false;
    let mut session_ok = true;
    for line in text.lines() {
        if line.starts_with("view: ") {
            facts.frames = number_after(line, "view: ").map(|n| n as u64);
        } else if line.starts_with("frames submitted: ") {
            facts.frames = number_after(line, "frames submitted: ").map(|n| n as u64);
            facts.fps = number_after(line, "(");
        } else if let Some(i) = line.find("validation messages") {
            // view: "... validation messages 0"; xr: "validation messages: OpenXR 0, Vulkan 0".
            let rest = &line[i..];
            let sum = if rest.contains("OpenXR") {
                number_after(rest, "OpenXR ").unwrap_or(f64::NAN) + number_after(rest, "Vulkan ").unwrap_or(f64::NAN)
            } else {
                number_after(rest, "validation messages ").unwrap_or(f64::NAN)
            };
            facts.validation = sum.is_finite().then_some(sum as u64);
        } else if let Some(how) = line.strip_prefix("session ended: ") {
            session_ok = how.contains("budget reached");
            facts.ended.push(format!("session ended: {how}"));
        } else if let Some(code) = line.strip_prefix("exit status: ") {
            status_ok = code.trim() == "0";
            facts.ended.push(format!("exit status {}", code.trim()));
        }
        if let Some(i) = line.find("histogram ") {
            if line.starts_with("frame times (ms)") || line.starts_with("frame interval (ms)") {
                facts.frame_time_line = Some(line.to_string());
                facts.coarse = line[i + "histogram ".len()..]
                    .split(", ")
                    .filter_map(|bar| {
                        let (range, n) = bar.rsplit_once(' ')?;
                        let n: u64 = n.parse().ok()?;
                        match range.strip_suffix('+') {
                            Some(lo) => Some((lo.parse().ok()?, None, n)),
                            None => {
                                let (lo, hi) = range.trim_start_matches('[').trim_end_matches(')').split_once(',')?;
                                Some((lo.parse().ok()?, Some(hi.parse().ok()?), n))
                            }
                        }
                    })
                    .collect();
            }
        }
    }
    facts.clean_end = status_ok && session_ok;
    Ok(facts)
}

/// Quarter `q` (0-3) of the time window `(start, end)`, as `(from, to)` seconds.
fn quarter(window: (f64, f64), q: usize) -> (f64, f64) {
    let step = (window.1 - window.0) / 4.0;
    (window.0 + step * q as f64, window.0 + step * (q + 1) as f64)
}

/// Mean of the values (NaN when there are none).
fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    sum / n as f64
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir, name] = args.as_slice() else { bail!("usage: soak_report DIR NAME") };
    let dir = Path::new(dir);
    let mut out = String::new();
    let rss = read_csv(&dir.join(format!("{name}_rss.csv")))?;
    let points: Vec<(f64, f64)> = rss.iter().filter(|r| r.len() >= 2).map(|r| (r[0], r[1] / 1024.0)).collect();
    if points.len() < 3 {
        bail!("{name}: only {} memory samples", points.len());
    }
    let log = read_log(&dir.join(format!("{name}.log")))?;
    let end = points.last().map_or(0.0, |p| p.0);
    // Warm-up (models loading, first frames, allocator pools): the first 10 % of the run, at least 60 s of a
    // run over 10 minutes.
    let warmup = if end > 600.0 { (0.1 * end).max(60.0) } else { 0.1 * end };
    let steady: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 >= warmup).collect();
    let (slope, intercept) = linear_fit(&steady).context("memory samples without spread in time")?;
    let max = points.iter().map(|p| p.1).fold(0.0, f64::max);
    // The fit window split in quarters (mean resident memory of each) and the slope of its second half alone: a
    // leak keeps its slope to the end, allocator and driver pools level off.
    let window = (steady.first().map_or(warmup, |p| p.0), end);
    let quarter_means: Vec<f64> = (0..4)
        .map(|q| {
            let (lo, hi) = quarter(window, q);
            mean(steady.iter().filter(|p| p.0 >= lo && (p.0 < hi || q == 3)).map(|p| p.1))
        })
        .collect();
    let late: Vec<(f64, f64)> = steady.iter().copied().filter(|p| p.0 >= quarter(window, 2).0).collect();
    let late_slope = linear_fit(&late).map(|f| f.0);
    // Memory by kind (the script's extra columns: anonymous, file-backed, shared), each fitted over the window.
    let kinds: Vec<(&str, f64)> = ["anonymous", "file", "shared"]
        .iter()
        .enumerate()
        .filter_map(|(k, name)| {
            let pts: Vec<(f64, f64)> =
                rss.iter().filter(|r| r.len() >= 5 && r[0] >= window.0).map(|r| (r[0], r[2 + k] / 1024.0)).collect();
            linear_fit(&pts).map(|f| (*name, f.0 * 3600.0))
        })
        .collect();

    // Frame times: the window's per-frame log when there is one, else the report's coarse histogram.
    let frames_path = dir.join(format!("{name}_frames.csv"));
    let edges = [0.0, 5.0, 10.0, 20.0, 33.3, 50.0, 100.0, 250.0, 1000.0];
    let (ranges, fps, detail) = if frames_path.is_file() {
        let rows = read_csv(&frames_path)?;
        let mut h = DurationHistogram::default();
        for r in rows.iter().filter(|r| r.len() >= 2) {
            h.record(Duration::from_secs_f64(r[1].max(0.0) / 1e3));
        }
        std::fs::write(dir.join(format!("{name}_histogram.csv")), h.to_csv())?;
        // Frames per second of the display loop: frame starts (ms, first column) over the run.
        let starts: Vec<f64> = rows.iter().filter_map(|r| r.first().copied()).collect();
        let span = starts.last().zip(starts.first()).map_or(0.0, |(b, a)| (b - a) / 1e3);
        let fps = (span > 0.0).then(|| (starts.len() - 1) as f64 / span);
        (h.ranges(&edges), fps, format!("frame times (ms): {}", h.summary()))
    } else {
        let csv: String = std::iter::once("from_ms,to_ms,frames\n".to_string())
            .chain(
                log.coarse
                    .iter()
                    .map(|(lo, hi, n)| format!("{lo},{},{n}\n", hi.map_or(String::new(), |h| h.to_string()))),
            )
            .collect();
        std::fs::write(dir.join(format!("{name}_histogram.csv")), csv)?;
        (log.coarse.clone(), log.fps, log.frame_time_line.clone().unwrap_or_else(|| "no frame-time line".into()))
    };
    let frames = log.frames.unwrap_or(0);
    let fps = fps.or_else(|| (end > 0.0 && frames > 0).then(|| frames as f64 / end));
    let per_1000 = fps.map(|fps| slope / fps * 1000.0);
    let late_per_1000 = fps.zip(late_slope).map(|(fps, s)| s / fps * 1000.0);
    // The C heap (`R2HUMAN_HEAP_LOG`: bytes malloc handed out and holds), over the same window: flat bytes in use
    // under growing resident memory is the allocator keeping freed memory, growing bytes in use is a leak.
    let heap_path = dir.join(format!("{name}_heap.csv"));
    let heap_rows = if heap_path.is_file() { Some(read_csv(&heap_path)?) } else { None };
    let heap = if let Some(rows) = &heap_rows {
        let column = |c: usize| -> Vec<(f64, f64)> {
            rows.iter().filter(|r| r.len() >= 3 && r[0] >= window.0).map(|r| (r[0], r[c] / 1024.0)).collect()
        };
        let fit = |pts: &[(f64, f64)]| {
            let quarters: Vec<f64> = (0..4)
                .map(|q| {
                    let (lo, hi) = quarter(window, q);
                    mean(pts.iter().filter(|p| p.0 >= lo && (p.0 < hi || q == 3)).map(|p| p.1))
                })
                .collect();
            (linear_fit(pts).map(|f| f.0 * 3600.0), quarters)
        };
        Some((fit(&column(1)), fit(&column(2))))
    } else {
        None
    };
    let quarters = |q: &[f64]| q.iter().map(|m| format!("{m:.1}")).collect::<Vec<_>>().join(" -> ");
    let per_hour = |s: Option<f64>| s.map_or("?".into(), |s| format!("{s:+.2}"));
    out.push_str(&format!(
        "{name}: {frames} frames in {end:.0} s ({}); {} memory samples; resident {:.1} MiB at the start, {:.1} MiB \
         at the end, {:.1} MiB at most; slope after {warmup:.0} s of warm-up {:+.2} MiB/hour = {} MiB per 1000 \
         frames\n",
        fps.map_or("frame rate unknown".into(), |f| format!("{f:.1} frames/s")),
        points.len(),
        points[0].1,
        points.last().map_or(0.0, |p| p.1),
        max,
        slope * 3600.0,
        per_1000.map_or("?".into(), |s| format!("{s:+.3}")),
    ));
    out.push_str(&format!(
        "{name}: fit window {:.0}-{:.0} s; its quarters' mean resident memory {} MiB; second half alone {} MiB/hour \
         = {} MiB per 1000 frames{}\n",
        window.0,
        window.1,
        quarters(&quarter_means),
        per_hour(late_slope.map(|s| s * 3600.0)),
        late_per_1000.map_or("?".into(), |s| format!("{s:+.3}")),
        if kinds.is_empty() {
            String::new()
        } else {
            let parts: Vec<String> = kinds.iter().map(|(k, s)| format!("{k} {s:+.1}")).collect();
            format!("; slope by kind (MiB/hour): {}", parts.join(", "))
        }
    ));
    if let Some(((in_use, in_use_q), (held, held_q))) = &heap {
        out.push_str(&format!(
            "{name}: C heap over the fit window: in use {} MiB (quarters' means), {} MiB/hour = {} MiB per 1000 \
             frames; held from the system {} MiB, {} MiB/hour\n",
            quarters(in_use_q),
            per_hour(*in_use),
            fps.zip(*in_use).map_or("?".into(), |(fps, s)| format!("{:+.3}", s / 3600.0 / fps * 1000.0)),
            quarters(held_q),
            per_hour(*held),
        ));
    }
    out.push_str(&format!(
        "{name}: validation messages {}; ended: {} ({})\n",
        log.validation.map_or("not reported".into(), |n| n.to_string()),
        if log.clean_end { "as asked" } else { "DROPPED or failed" },
        log.ended.join(", ")
    ));
    out.push_str(&format!("{name}: {detail}\n"));
    for (lo, hi, n) in &ranges {
        let range = hi.map_or(format!("{lo} ms and more"), |hi| format!("[{lo}, {hi}) ms"));
        out.push_str(&format!("  {range:>18}: {n}\n"));
    }
    plot(&dir.join(format!("{name}_frame_times.png")), &ranges, name)?;
    let heap_series = match &heap_rows {
        Some(rows) => {
            let column = |c: usize| -> Vec<(f64, f64)> {
                rows.iter().filter(|r| r.len() >= 3).map(|r| (r[0], r[c] / 1024.0)).collect()
            };
            vec![("C heap held from the system", column(2)), ("C heap in use", column(1))]
        }
        None => Vec::new(),
    };
    let anonymous: Vec<(f64, f64)> = rss.iter().filter(|r| r.len() >= 5).map(|r| (r[0], r[2] / 1024.0)).collect();
    let mut series = vec![("resident (VmRSS)", points.clone()), ("resident, anonymous", anonymous)];
    series.extend(heap_series);
    let fit_line = [(window.0, slope * window.0 + intercept), (window.1, slope * window.1 + intercept)];
    plot_memory(&dir.join(format!("{name}_memory.png")), name, &series, warmup, Some(fit_line))?;
    let json = serde_json::json!({
        "name": name,
        "frames": frames,
        "seconds": end,
        "frames_per_second": fps,
        "rss_mib": {"start": points[0].1, "end": points.last().map(|p| p.1), "max": max},
        "warmup_seconds": warmup,
        "fit_window_seconds": [window.0, window.1],
        "slope_mib_per_hour": slope * 3600.0,
        "slope_mib_per_1000_frames": per_1000,
        "quarter_mean_rss_mib": quarter_means,
        "second_half_slope_mib_per_hour": late_slope.map(|s| s * 3600.0),
        "second_half_slope_mib_per_1000_frames": late_per_1000,
        "slope_by_kind_mib_per_hour": kinds.iter().map(|(k, s)| ((*k).to_string(), serde_json::json!(s))).collect::<serde_json::Map<_, _>>(),
        "heap_mib": heap.as_ref().map(|((in_use, in_use_q), (held, held_q))| serde_json::json!({
            "in_use_quarter_means": in_use_q,
            "in_use_slope_per_hour": in_use,
            "held_quarter_means": held_q,
            "held_slope_per_hour": held,
        })),
        "validation_messages": log.validation,
        "ended": log.ended,
        "clean_end": log.clean_end,
        "frame_times": detail,
        "histogram": ranges.iter().map(|(lo, hi, n)| serde_json::json!([lo, hi, n])).collect::<Vec<_>>(),
    });
    std::fs::write(dir.join(format!("{name}_summary.json")), serde_json::to_vec_pretty(&json)?)?;
    print!("{out}");
    std::fs::write(dir.join(format!("{name}_summary.txt")), out)?;
    if !log.clean_end {
        bail!("{name}: the run did not end as asked ({})", log.ended.join(", "));
    }
    if log.validation != Some(0) {
        bail!("{name}: validation messages: {:?}", log.validation);
    }
    Ok(())
}

/// A bar chart of frames per frame-time range.
fn plot(path: &Path, ranges: &[(f64, Option<f64>, u64)], name: &str) -> Result<()> {
    use plotters::prelude::*;
    let (w, h) = (800u32, 400u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
        let top = ranges.iter().map(|r| r.2).max().unwrap_or(1).max(1) as f64 * 1.1;
        let labels: Vec<String> =
            ranges.iter().map(|(lo, hi, _)| hi.map_or(format!("{lo}+"), |hi| format!("{lo}-{hi}"))).collect();
        let mut chart = ChartBuilder::on(&root)
            .caption(format!("{name}: frames per frame time (ms)"), ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5f64..ranges.len().max(1) as f64 - 0.5, 0f64..top)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_labels(ranges.len() + 1)
            .x_label_formatter(&|x| {
                // One label under each bar (bars are centred on whole numbers).
                let i = x.round();
                if (x - i).abs() > 1e-6 || i < 0.0 {
                    return String::new();
                }
                labels.get(i as usize).cloned().unwrap_or_default()
            })
            .y_desc("frames")
            .disable_x_mesh()
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(ranges.iter().enumerate().map(|(i, r)| {
                Rectangle::new([(i as f64 - 0.4, 0.0), (i as f64 + 0.4, r.2 as f64)], BLUE.mix(0.6).filled())
            }))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("plot buffer")?;
    img.save(path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Memory against time: each `(label, points in (seconds, MiB))` series as a line (empty series are left out),
/// the end of the warm-up as a vertical line and the fitted resident-memory line over the fit window.
fn plot_memory(
    path: &Path,
    name: &str,
    series: &[(&str, Vec<(f64, f64)>)],
    warmup: f64,
    fit: Option<[(f64, f64); 2]>,
) -> Result<()> {
    use plotters::prelude::*;
    let (w, h) = (900u32, 450u32);
    let all = || series.iter().flat_map(|(_, pts)| pts.iter());
    let end_min = all().map(|p| p.0).fold(0.0, f64::max) / 60.0;
    let top = all().map(|p| p.1).fold(0.0, f64::max) * 1.15;
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(format!("{name}: memory against time"), ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..end_min.max(1.0 / 60.0), 0f64..top.max(1.0))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc("minutes")
            .y_desc("MiB")
            .light_line_style(BLACK.mix(0.04))
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let colours = [BLUE, CYAN, RED, MAGENTA];
        for ((label, pts), colour) in series.iter().filter(|(_, pts)| !pts.is_empty()).zip(colours.iter().cycle()) {
            let colour = *colour;
            chart
                .draw_series(LineSeries::new(pts.iter().map(|&(t, m)| (t / 60.0, m)), colour.stroke_width(1)))
                .map_err(|e| anyhow::anyhow!("{e}"))?
                .label(*label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        }
        chart
            .draw_series(LineSeries::new([(warmup / 60.0, 0.0), (warmup / 60.0, top)], BLACK.mix(0.5).stroke_width(2)))
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .label("end of warm-up")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5).stroke_width(2)));
        if let Some(line) = fit {
            chart
                .draw_series(LineSeries::new(line.iter().map(|&(t, m)| (t / 60.0, m)), BLACK.stroke_width(2)))
                .map_err(|e| anyhow::anyhow!("{e}"))?
                .label("resident: least-squares fit")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("plot buffer")?;
    img.save(path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
