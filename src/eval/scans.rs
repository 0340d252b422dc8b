//! Several scans together (`r2human eval --scan A --scan B …`): per method, the mean over the characters of the
//! volumetric IoU of its geometry, the divergent views' mask IoU and the whole-frame PSNR at close and divergent
//! views, for a **development** half, a **held-out** half and all of them, plus every character's own values.
//! Nothing is measured here: the numbers are the report's own rows ([`super::runner::ReportRow`]) and per-scan
//! geometry IoUs ([`super::runner::EvalReport::set_geometry_iou`]), each character weighted equally.
//!
//! The split is a fixed rule on the scans' names, set before any method's number was looked at (issue 14):
//! sorted alphabetically (case-folded), the 1st, 3rd, 5th … scan is **dev** and the 2nd, 4th, 6th …
//! is **held out** ([`held_out`]). Decisions are taken on dev; held out says whether they carry over.

use std::path::Path;

use super::runner::{fmt_cell as cell, EvalReport, ReportRow, GEOMETRIES, ORACLE_TAG};
use super::EvalError;
use crate::io::npy::write_atomic;

/// The split names, in table order.
pub const SPLITS: [&str; 3] = ["dev", "held-out", "all"];

/// Whether each of `names` is held out: sorted alphabetically (case-folded, then as written), every second one
/// (the 2nd, 4th, …) is held out, the others are dev.
pub fn held_out(names: &[&str]) -> Vec<bool> {
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by(|&a, &b| names[a].to_lowercase().cmp(&names[b].to_lowercase()).then(names[a].cmp(names[b])));
    let mut out = vec![false; names.len()];
    for (rank, &i) in order.iter().enumerate() {
        out[i] = rank % 2 == 1;
    }
    out
}

/// The four numbers the summary keeps of one character and method, or their means (`None`: not measured).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScanMetrics {
    /// Volumetric IoU of the method's geometry against the ground-truth FOF (`None`: billboard, 2.5d, the oracle).
    pub volumetric_iou: Option<f32>,
    /// Mask IoU at divergent views.
    pub mask_iou_divergent: Option<f32>,
    /// Whole-frame PSNR at close views (dB).
    pub psnr_frame_close: Option<f32>,
    /// Whole-frame PSNR at divergent views (dB).
    pub psnr_frame_divergent: Option<f32>,
}

impl ScanMetrics {
    /// The fields' CSV column names, in [`ScanMetrics::values`] order.
    pub const COLUMNS: [&'static str; 4] =
        ["volumetric_iou", "mask_iou_divergent", "psnr_frame_close", "psnr_frame_divergent"];
    /// The fields' table headings, in [`ScanMetrics::values`] order.
    pub const LABELS: [&'static str; 4] =
        ["volumetric IoU", "divergent mask IoU", "PSNR frame close", "PSNR frame divergent"];

    /// The fields in [`ScanMetrics::COLUMNS`] order.
    pub fn values(&self) -> [Option<f32>; 4] {
        [self.volumetric_iou, self.mask_iou_divergent, self.psnr_frame_close, self.psnr_frame_divergent]
    }

    /// Each field's mean over `of`, over the entries that have it (`None` where none has).
    fn mean<'a>(of: impl Iterator<Item = &'a ScanMetrics> + Clone) -> Self {
        let field = |i: usize| mean(of.clone().filter_map(|m| m.values()[i]));
        Self {
            volumetric_iou: field(0),
            mask_iou_divergent: field(1),
            psnr_frame_close: field(2),
            psnr_frame_divergent: field(3),
        }
    }

    /// The fields as CSV cells (4 decimals, empty when `None`), comma-separated.
    fn csv_cells(&self) -> String {
        self.values().map(|v| v.map(|x| format!("{x:.4}")).unwrap_or_default()).join(",")
    }
}

/// One character's numbers for one method.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanValues {
    /// The scan (its report name).
    pub scan: String,
    /// Whether it is held out ([`held_out`]).
    pub held_out: bool,
    /// The method ([`super::runner::METHODS`]).
    pub method: String,
    /// Its numbers.
    pub metrics: ScanMetrics,
}

/// Means over characters of one method in one split.
#[derive(Clone, Debug, PartialEq)]
pub struct SplitMeans {
    /// `dev`, `held-out` or `all`.
    pub split: &'static str,
    /// The method.
    pub method: String,
    /// Characters with a row of this method in the split.
    pub characters: usize,
    /// Means of their [`ScanValues::metrics`] (each over the characters that have it).
    pub metrics: ScanMetrics,
}

/// The table over several scans.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanSummary {
    /// Every character and method.
    pub per_scan: Vec<ScanValues>,
    /// Per split and method (splits in [`SPLITS`] order, methods in report order).
    pub means: Vec<SplitMeans>,
    /// The scans, with whether each is held out, in alphabetical order.
    pub scans: Vec<(String, bool)>,
}

/// The geometry a method draws (`None` for billboard, 2.5d and the oracle).
fn geometry_of(method: &str) -> Option<&'static str> {
    let (_, geometry) = method.split_once('+')?;
    GEOMETRIES.iter().copied().find(|g| *g == geometry)
}

fn mean(v: impl Iterator<Item = f32>) -> Option<f32> {
    let (sum, n) = v.filter(|x| x.is_finite()).fold((0.0f64, 0usize), |(s, n), x| (s + x as f64, n + 1));
    (n > 0).then(|| (sum / n as f64) as f32)
}

impl ScanSummary {
    /// The summary of the scans in `rep` (input sets not named `synthetic/…`); `None` with fewer than two scans.
    pub fn of(rep: &EvalReport) -> Option<Self> {
        let mut names: Vec<&str> = Vec::new();
        let mut methods: Vec<&str> = Vec::new();
        for r in rep.rows.iter().filter(|r| !r.inputs.starts_with("synthetic/")) {
            if !names.contains(&r.inputs.as_str()) {
                names.push(&r.inputs);
            }
            if !methods.contains(&r.method.as_str()) {
                methods.push(&r.method);
            }
        }
        if names.len() < 2 {
            return None;
        }
        let split = held_out(&names);
        let mut scans: Vec<(String, bool)> = names.iter().map(|n| n.to_string()).zip(split).collect();
        scans.sort_by(|a, b| a.0.to_lowercase().cmp(&b.0.to_lowercase()).then(a.0.cmp(&b.0)));
        let row = |scan: &str, method: &str, group: &str| -> Option<&ReportRow> {
            rep.rows.iter().find(|r| r.inputs == scan && r.method == method && r.group == group)
        };
        let mut per_scan = Vec::new();
        for (scan, is_held_out) in &scans {
            for &method in &methods {
                let (close, divergent) = (row(scan, method, "close"), row(scan, method, "divergent"));
                if close.is_none() && divergent.is_none() {
                    continue;
                }
                let volumetric_iou = geometry_of(method).and_then(|g| {
                    rep.set_geometry_iou.iter().find(|(s, geometry, _)| s == scan && geometry == g).map(|x| x.2)
                });
                per_scan.push(ScanValues {
                    scan: scan.clone(),
                    held_out: *is_held_out,
                    method: method.to_string(),
                    metrics: ScanMetrics {
                        volumetric_iou,
                        mask_iou_divergent: divergent.map(|r| r.scores.mask_iou),
                        psnr_frame_close: close.map(|r| r.scores.psnr_frame),
                        psnr_frame_divergent: divergent.map(|r| r.scores.psnr_frame),
                    },
                });
            }
        }
        let mut means = Vec::new();
        for split in SPLITS {
            for &method in &methods {
                let of: Vec<&ScanValues> = per_scan
                    .iter()
                    .filter(|v| v.method == method)
                    .filter(|v| match split {
                        "dev" => !v.held_out,
                        "held-out" => v.held_out,
                        _ => true,
                    })
                    .collect();
                means.push(SplitMeans {
                    split,
                    method: method.to_string(),
                    characters: of.len(),
                    metrics: ScanMetrics::mean(of.iter().map(|v| &v.metrics)),
                });
            }
        }
        Some(Self { per_scan, means, scans })
    }

    /// `scans.csv` (every character and method) and `scans_summary.csv` (means per split and method) into `out`.
    pub fn write_csv(&self, out: &Path) -> Result<(), EvalError> {
        let columns = ScanMetrics::COLUMNS.join(",");
        let mut per = format!("scan,split,method,{columns}\n");
        for v in &self.per_scan {
            per.push_str(&format!(
                "\"{}\",{},{},{}\n",
                v.scan.replace('"', "\"\""),
                if v.held_out { "held-out" } else { "dev" },
                v.method,
                v.metrics.csv_cells()
            ));
        }
        let mut sum = format!("split,method,characters,{columns}\n");
        for m in &self.means {
            sum.push_str(&format!("{},{},{},{}\n", m.split, m.method, m.characters, m.metrics.csv_cells()));
        }
        for (name, text) in [("scans.csv", per), ("scans_summary.csv", sum)] {
            let p = out.join(name);
            write_atomic(&p, text.as_bytes()).map_err(|e| EvalError::io(&p, e))?;
        }
        Ok(())
    }

    /// The report section: the split, then per split a table of the four means per method (best predicted
    /// geometry in bold), then each character's volumetric and divergent mask IoU per geometry.
    pub fn markdown(&self) -> String {
        let count = |h: bool| self.scans.iter().filter(|s| s.1 == h).count();
        let list =
            |h: bool| self.scans.iter().filter(|s| s.1 == h).map(|s| s.0.as_str()).collect::<Vec<_>>().join(", ");
        let mut md = format!(
            "\n## Scans together ({} characters)\n\nEach character weighs the same. Split, fixed before any number was \
             read: sorted by name, every second scan is held out. Dev ({}): {}. Held out ({}): {}. Files: \
             `scans.csv` (every character), `scans_summary.csv` (these means).\n",
            self.scans.len(),
            count(false),
            list(false),
            count(true),
            list(true)
        );
        for split in SPLITS {
            let rows: Vec<&SplitMeans> = self.means.iter().filter(|m| m.split == split).collect();
            md.push_str(&format!(
                "\n### {split}\n\n| method | characters | {} |\n|---|---|{}\n",
                ScanMetrics::LABELS.join(" | "),
                "---|".repeat(ScanMetrics::LABELS.len())
            ));
            let best: Vec<Option<f32>> = (0..ScanMetrics::LABELS.len())
                .map(|i| {
                    rows.iter()
                        .filter(|m| !m.method.contains(ORACLE_TAG))
                        .filter_map(|m| m.metrics.values()[i])
                        .fold(None, |b: Option<f32>, x| Some(b.map_or(x, |b| b.max(x))))
                })
                .collect();
            for m in rows {
                md.push_str(&format!("| {} | {} |", m.method, m.characters));
                for (value, b) in m.metrics.values().into_iter().zip(&best) {
                    md.push_str(&match value {
                        Some(v) if Some(v) == *b && !m.method.contains(ORACLE_TAG) => format!(" **{}** |", cell(v)),
                        Some(v) => format!(" {} |", cell(v)),
                        None => " - |".to_string(),
                    });
                }
                md.push('\n');
            }
        }
        // Per character: each predicted geometry's volumetric IoU and its geometric renderer's divergent mask IoU.
        let geometries: Vec<&str> = GEOMETRIES
            .iter()
            .copied()
            .filter(|g| self.per_scan.iter().any(|v| v.method == format!("geometric+{g}")))
            .collect();
        md.push_str(&format!(
            "\n### Per character (geometric renderer)\n\n| scan | split | {} | {} |\n|---|---|{}\n",
            geometries.iter().map(|g| format!("{g} vol. IoU")).collect::<Vec<_>>().join(" | "),
            geometries.iter().map(|g| format!("{g} div. mask IoU")).collect::<Vec<_>>().join(" | "),
            "---|".repeat(2 * geometries.len())
        ));
        for (scan, is_held_out) in &self.scans {
            let v = |g: &str| self.per_scan.iter().find(|v| v.scan == *scan && v.method == format!("geometric+{g}"));
            let fmt = |x: Option<f32>| x.map(cell).unwrap_or_else(|| "-".into());
            md.push_str(&format!("| {scan} | {} |", if *is_held_out { "held-out" } else { "dev" }));
            for g in &geometries {
                md.push_str(&format!(" {} |", fmt(v(g).and_then(|v| v.metrics.volumetric_iou))));
            }
            for g in &geometries {
                md.push_str(&format!(" {} |", fmt(v(g).and_then(|v| v.metrics.mask_iou_divergent))));
            }
            md.push('\n');
        }
        md
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::eval::runner::test_row as row;

    #[test]
    fn every_second_name_in_alphabetical_order_is_held_out() {
        assert_eq!(held_out(&["tony", "Assassin", "beret", "major"]), vec![true, false, true, false]);
        assert_eq!(held_out(&["b", "a"]), vec![true, false]);
        assert_eq!(held_out(&[]), Vec::<bool>::new());
        // Adding a name that sorts last leaves the others' split unchanged.
        assert_eq!(held_out(&["a", "b", "c"]), vec![false, true, false]);
    }

    #[test]
    fn means_per_split_weigh_characters_equally_and_skip_the_synthetic_sets() {
        // a: dev, b: held out, c: dev. Inflation's divergent mask IoU 0.5, 0.7, 0.9; the FOF net missing on c.
        let mut rows = Vec::new();
        for (scan, iou, psnr) in [("a", 0.5, 20.0), ("b", 0.7, 22.0), ("c", 0.9, 27.0)] {
            rows.push(row(scan, "geometric+inflation", "close", psnr + 1.0, 0.0));
            rows.push(row(scan, "geometric+inflation", "divergent", psnr, iou));
            rows.push(row(scan, "geometric+gt-fof", "divergent", 30.0, 0.99));
            if scan != "c" {
                rows.push(row(scan, "geometric+fofnet", "divergent", psnr - 1.0, iou + 0.05));
            }
        }
        rows.push(row("synthetic/full", "geometric+inflation", "divergent", 10.0, 0.1));
        let set_geometry_iou = vec![
            ("a".to_string(), "inflation".to_string(), 0.4),
            ("b".to_string(), "inflation".to_string(), 0.6),
            ("c".to_string(), "inflation".to_string(), 0.5),
            ("a".to_string(), "fofnet".to_string(), 0.3),
            ("b".to_string(), "fofnet".to_string(), 0.2),
            ("synthetic/full".to_string(), "inflation".to_string(), 0.0),
        ];
        let rep = EvalReport { rows, set_geometry_iou, ..Default::default() };
        let s = ScanSummary::of(&rep).unwrap();
        assert_eq!(s.scans, vec![("a".into(), false), ("b".into(), true), ("c".into(), false)]);
        let m = |split: &str, method: &str| s.means.iter().find(|m| m.split == split && m.method == method).unwrap();
        let of = |split: &str, method: &str| m(split, method).metrics;
        let close = |a: Option<f32>, b: f32| (a.unwrap() - b).abs() < 1e-5;
        assert_eq!(m("dev", "geometric+inflation").characters, 2);
        let inf = of("dev", "geometric+inflation");
        assert!(close(inf.mask_iou_divergent, 0.7) && close(inf.volumetric_iou, 0.45));
        assert!(close(inf.psnr_frame_divergent, 23.5) && close(inf.psnr_frame_close, 24.5));
        let all = of("all", "geometric+inflation");
        assert!(close(all.mask_iou_divergent, 0.7) && close(all.volumetric_iou, 0.5));
        assert_eq!(m("all", "geometric+inflation").characters, 3);
        let held = of("held-out", "geometric+fofnet");
        assert!(close(held.volumetric_iou, 0.2) && close(held.mask_iou_divergent, 0.75));
        assert_eq!(m("held-out", "geometric+fofnet").characters, 1);
        assert_eq!(held.psnr_frame_close, None);
        assert_eq!(m("dev", "geometric+fofnet").characters, 1);
        // The oracle has no volumetric IoU and is never bold.
        assert_eq!(of("all", "geometric+gt-fof").volumetric_iou, None);
        let md = s.markdown();
        assert!(md.contains("Dev (2): a, c. Held out (1): b."), "{md}");
        assert!(md.contains("| geometric+gt-fof | 3 | - | 0.990 | - | 30.00 |"), "{md}");
        assert!(md.contains("| geometric+inflation | 2 | **0.450** | **0.700** | **24.50** | **23.50** |"), "{md}");
        assert!(md.contains("| b | held-out | 0.600 | 0.200 | 0.700 | 0.750 |"), "{md}");
        // One scan: no summary.
        let one = EvalReport { rows: vec![row("a", "billboard", "close", 1.0, 1.0)], ..Default::default() };
        assert!(ScanSummary::of(&one).is_none());
    }
}
