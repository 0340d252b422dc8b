//! Summarises a soak run of `scripts/soak.sh`: resident memory against time (least-squares slope in MiB/hour,
//! ignoring the first 10 % of the run, at least a minute of a long run, as warm-up) and the display loop's frame times (histogram CSV and PNG).
//!
//! `cargo run --example soak_report -- DIR NAME` reads `DIR/NAME_rss.csv` (`seconds,rss_kib` per sample) and, when
//! present, `DIR/NAME_frames.csv` (the window's `--frame-log`), and writes `DIR/NAME_summary.txt`,
//! `DIR/NAME_histogram.csv` and `DIR/NAME_frame_times.png`. The summary is also printed.

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
    let end = points.last().map_or(0.0, |p| p.0);
    // Warm-up (models loading, first frames, allocator pools): the first 10 % of the run, at least 60 s of a
    // run over 10 minutes.
    let warmup = if end > 600.0 { (0.1 * end).max(60.0) } else { 0.1 * end };
    let steady: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 >= warmup).collect();
    let (slope, _) = linear_fit(&steady).context("memory samples without spread in time")?;
    let max = points.iter().map(|p| p.1).fold(0.0, f64::max);
    out.push_str(&format!(
        "{name}: {} memory samples over {:.0} s; resident {:.1} MiB at the start, {:.1} MiB at the end, {:.1} MiB \
         at most; slope after warm-up {:+.2} MiB/hour\n",
        points.len(),
        end,
        points[0].1,
        points.last().map_or(0.0, |p| p.1),
        max,
        slope * 3600.0
    ));
    let frames_path = dir.join(format!("{name}_frames.csv"));
    if frames_path.is_file() {
        let rows = read_csv(&frames_path)?;
        let mut h = DurationHistogram::default();
        for r in rows.iter().filter(|r| r.len() >= 2) {
            h.record(Duration::from_secs_f64(r[1].max(0.0) / 1e3));
        }
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        out.push_str(&format!(
            "{name}: {} frames; frame time median {:.2} ms, p99 {:.2} ms, max {:.2} ms\n",
            h.count(),
            ms(h.median()),
            ms(h.quantile(0.99)),
            ms(h.max())
        ));
        let edges = [0.0, 5.0, 10.0, 20.0, 33.3, 50.0, 100.0, 250.0, 1000.0];
        for (lo, hi, n) in h.ranges(&edges) {
            let range = hi.map_or(format!("{lo} ms and more"), |hi| format!("[{lo}, {hi}) ms"));
            out.push_str(&format!("  {range:>18}: {n}\n"));
        }
        std::fs::write(dir.join(format!("{name}_histogram.csv")), h.to_csv())?;
        plot(&dir.join(format!("{name}_frame_times.png")), &h.ranges(&edges), name)?;
    }
    print!("{out}");
    std::fs::write(dir.join(format!("{name}_summary.txt")), out)?;
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
            .build_cartesian_2d(0f64..ranges.len() as f64, 0f64..top)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_labels(ranges.len())
            .x_label_formatter(&|x| labels.get(*x as usize).cloned().unwrap_or_default())
            .y_desc("frames")
            .disable_x_mesh()
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(ranges.iter().enumerate().map(|(i, r)| {
                Rectangle::new([(i as f64 + 0.1, 0.0), (i as f64 + 0.9, r.2 as f64)], BLUE.mix(0.6).filled())
            }))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("plot buffer")?;
    img.save(path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
