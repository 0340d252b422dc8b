//! Plausibility checks of a decoded FOF that need no ground truth: how many separate shells a column crosses
//! ([`count_intervals`], [`doubled_fraction`]) and how much of the occupied volume floats apart from the body
//! ([`detached_volume_fraction`]). A person is one connected body whose every column crosses as many shells as
//! its silhouette and pose explain; a face drawn twice, one shell behind the other, or a sliver of arm floating
//! beside the body break that, and a viewer notices them at once from the side.
//!
//! Used by the real-photo checks of `r2human eval --photos` and by the guard on predicted FOFs in the pipeline.

use rayon::prelude::*;

use super::fof::{accumulate_interval, CosineTable, Fof};
use super::marching::ISO_LEVEL;
use crate::buffer::GrayImage;

/// Occupancy intervals separated by a gap shorter than this many depth samples are one interval, and runs shorter
/// than this are ignored.
pub const MIN_RUN_SAMPLES: usize = 2;

/// Depth samples per column for [`doubled_fraction`] (at 128 over the cube's depth of 2, [`MIN_RUN_SAMPLES`] is
/// 0.031 body-cube units: under 3 cm at a body height of 1.8 units = 1.75 m).
pub const INTERVAL_SAMPLES: usize = 128;

/// The occupancy intervals of one decoded column: runs at or above `level`, runs separated by fewer than
/// [`MIN_RUN_SAMPLES`] empty samples merged, runs shorter than [`MIN_RUN_SAMPLES`] ignored.
pub fn count_intervals(occupancy: &[f32], level: f32) -> usize {
    intervals(occupancy, level).len()
}

/// Whether `occupancy` rises to `level` at most once (a sample at or above it after one below it, or the first
/// sample at or above it): then [`count_intervals`] is at most 1, since merging and dropping runs never adds one.
/// Each pair of neighbours on its own, without branches (vectorised): the common case of one surface per column
/// is decided without the run-by-run walk of [`intervals`].
fn at_most_one_run(occupancy: &[f32], level: f32) -> bool {
    let at_level = |o: f32| o >= level;
    let first = occupancy.first().is_some_and(|&o| at_level(o));
    let rises = occupancy.windows(2).map(|p| usize::from(at_level(p[1]) && !at_level(p[0]))).sum::<usize>();
    usize::from(first) + rises <= 1
}

/// The occupancy intervals [`count_intervals`] counts, as half-open sample ranges `(first, end)` in depth order.
fn intervals(occupancy: &[f32], level: f32) -> Vec<(usize, usize)> {
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut start = None;
    for (i, &o) in occupancy.iter().chain(std::iter::once(&f32::NEG_INFINITY)).enumerate() {
        match (o >= level, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                match runs.last_mut() {
                    Some(last) if s - last.1 < MIN_RUN_SAMPLES => last.1 = i,
                    _ => runs.push((s, i)),
                }
                start = None;
            }
            _ => {}
        }
    }
    runs.retain(|(s, e)| e - s >= MIN_RUN_SAMPLES);
    runs
}

/// Removes from each of the person's columns (`mask` at least 0.5) of `fof` the shells that `references` do not
/// explain (the rule of [`doubled_fraction_beyond`]: a column is explained up to the largest interval count any
/// reference has there, at least one). Such a column keeps its longest intervals, as many as are explained, and
/// is re-encoded from them ([`accumulate_interval`]; intervals of [`INTERVAL_SAMPLES`] depth samples); every other
/// column keeps its coefficients bit for bit. A network's surface drawn twice (a face behind the face) becomes
/// one, and a column never loses its longest interval. Returns how many columns changed; `fof` is left as it is
/// when a grid differs.
pub fn drop_unexplained_shells(fof: &mut Fof, references: &[&Fof], mask: &GrayImage) -> usize {
    let Some(explanation) = Explanation::of(fof, references, mask) else { return 0 };
    let (w, n) = (fof.width, fof.n);
    let table = CosineTable::new(n, INTERVAL_SAMPLES);
    let depth = |sample: usize| 2.0 * sample as f32 / INTERVAL_SAMPLES as f32 - 1.0;
    fof.coeffs
        .par_chunks_mut(w * n)
        .enumerate()
        .map(|(row, line)| {
            let (mut a, mut b) = (vec![0.0f32; INTERVAL_SAMPLES], vec![0.0f32; INTERVAL_SAMPLES]);
            let mut changed = 0;
            for (col, coeffs) in line.chunks_exact_mut(n).enumerate() {
                if *mask.get(col, row) < 0.5 || Fof::is_empty_coefficients(coeffs) {
                    continue;
                }
                table.decode(coeffs, &mut a);
                if at_most_one_run(&a, ISO_LEVEL) {
                    continue;
                }
                let mut runs = intervals(&a, ISO_LEVEL);
                if runs.len() <= 1 {
                    continue;
                }
                let explained = explanation.intervals(col, row, &mut b);
                if runs.len() <= explained {
                    continue;
                }
                // The longest first (the earlier one on a tie), then back in depth order.
                runs.sort_by_key(|&(s, e)| (std::cmp::Reverse(e - s), s));
                runs.truncate(explained);
                coeffs.fill(0.0);
                for &(s, e) in &runs {
                    accumulate_interval(depth(s), depth(e), coeffs);
                }
                changed += 1;
            }
            changed
        })
        .sum()
}

/// What explains a column's shells: reference FOFs on the same grid (the inflation prior, a fitted body), decoded
/// at [`INTERVAL_SAMPLES`] depths. The one rule of [`doubled_fraction_beyond`] and [`drop_unexplained_shells`].
struct Explanation<'a> {
    references: &'a [&'a Fof],
    tables: Vec<CosineTable>,
}

impl<'a> Explanation<'a> {
    /// `None` when a grid differs from `fof`'s or `mask`'s.
    fn of(fof: &Fof, references: &'a [&'a Fof], mask: &GrayImage) -> Option<Self> {
        let same = |w: usize, h: usize| (w, h) == (fof.width, fof.height);
        if !same(mask.width, mask.height) || references.iter().any(|r| !same(r.width, r.height)) {
            return None;
        }
        let tables = references.iter().map(|r| CosineTable::new(r.n, INTERVAL_SAMPLES)).collect();
        Some(Self { references, tables })
    }

    /// How many intervals column `(col, row)` may have: the most any reference has there, at least one. `buf`
    /// holds [`INTERVAL_SAMPLES`] values (scratch).
    fn intervals(&self, col: usize, row: usize, buf: &mut [f32]) -> usize {
        let mut explained = 1;
        for (r, t) in self.references.iter().zip(&self.tables) {
            r.decode_column_with(t, col, row, buf);
            explained = explained.max(count_intervals(buf, ISO_LEVEL));
        }
        explained
    }
}

/// Fraction of the person's columns (`mask` at least 0.5) where `fof` decodes to more occupancy intervals than
/// `reference` does (at least one is always explained): surfaces the reference (the silhouette-inflation prior,
/// one shell per column, or a fitted body) cannot explain. Every column is tested; [`doubled_fraction_sampled`]
/// tests a sparser grid. NaN when the grids differ; 0 for an empty mask.
pub fn doubled_fraction(fof: &Fof, reference: &Fof, mask: &GrayImage) -> f32 {
    doubled_fraction_beyond(fof, &[reference], mask, 1)
}

/// [`doubled_fraction`] over every `step`-th column and row only (`step` 4: a sixteenth of the work, for checks
/// on the per-input path).
pub fn doubled_fraction_sampled(fof: &Fof, reference: &Fof, mask: &GrayImage, step: usize) -> f32 {
    doubled_fraction_beyond(fof, &[reference], mask, step)
}

/// [`doubled_fraction_sampled`] against several references at once: a column is explained up to the largest
/// interval count any reference has there (e.g. the inflation prior's one shell, or a fitted body's arm in front of
/// its torso). NaN when a grid differs from `fof`'s or `mask`'s; 0 for an empty mask; with no reference, one
/// interval per column is explained.
pub fn doubled_fraction_beyond(fof: &Fof, references: &[&Fof], mask: &GrayImage, step: usize) -> f32 {
    let step = step.max(1);
    let Some(explanation) = Explanation::of(fof, references, mask) else { return f32::NAN };
    let table = CosineTable::new(fof.n, INTERVAL_SAMPLES);
    let (doubled, person) = (0..fof.height)
        .into_par_iter()
        .step_by(step)
        .map(|row| {
            let (mut a, mut b) = (vec![0.0f32; INTERVAL_SAMPLES], vec![0.0f32; INTERVAL_SAMPLES]);
            let (mut doubled, mut person) = (0usize, 0usize);
            for col in (0..fof.width).step_by(step) {
                if *mask.get(col, row) < 0.5 {
                    continue;
                }
                person += 1;
                fof.decode_column_with(&table, col, row, &mut a);
                if at_most_one_run(&a, ISO_LEVEL) {
                    continue;
                }
                let count = count_intervals(&a, ISO_LEVEL);
                if count > 1 && count > explanation.intervals(col, row, &mut b) {
                    doubled += 1;
                }
            }
            (doubled, person)
        })
        .reduce(|| (0, 0), |p, q| (p.0 + q.0, p.1 + q.1));
    if person == 0 {
        0.0
    } else {
        doubled as f32 / person as f32
    }
}

/// A run of occupied voxels in one column of [`Pieces`]: its first and last depth sample.
type Run = (u32, u32);

/// The occupied voxels of a FOF on a coarse grid, labelled by connected piece ([`detached_volume_fraction`],
/// [`keep_largest_piece`]; [`Pieces::of`] once serves both).
pub struct Pieces {
    /// Voxels a side in x and y, and depth samples.
    w: usize,
    h: usize,
    d: usize,
    /// Column and row step from the FOF's grid to this one.
    step: usize,
    /// Piece per voxel at `(y * w + x) * d + z`: 0 empty, else 1-based.
    labels: Vec<u32>,
    /// The largest piece's label (0 when empty).
    largest: u32,
    /// Occupied voxels, and those in the largest piece.
    total: usize,
    largest_size: usize,
}

impl Pieces {
    /// Decodes every `step`-th column and row of `fof` at `width / step` depth samples (cubic voxels), occupancy at
    /// the marching-cubes level, and labels the pieces connected through faces, edges and corners.
    ///
    /// Pieces are found on the columns' runs of occupied voxels, not voxel by voxel: two runs of neighbouring
    /// columns (the eight around a column) touch when their depth ranges overlap or meet within one voxel, and a
    /// union-find joins touching runs. Labels are numbered in the order of each piece's first voxel in
    /// `(y, x, z)` order, as a voxel flood fill scanning in that order numbers them (the same labels, tested);
    /// measured on a 512² portrait's FOF (`astronaut`, step 4): 21 -> 4 ms CPU.
    pub fn of(fof: &Fof, step: usize) -> Self {
        let step = step.max(1);
        let (w, h) = (fof.width.div_ceil(step), fof.height.div_ceil(step));
        let d = (fof.width / step).max(1);
        let table = CosineTable::new(fof.n, d);
        // Per grid row: every column's runs `[first, last]` of occupied voxels in depth order, and where each
        // column's runs end in that list.
        let per_row: Vec<(Vec<Run>, Vec<u32>)> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut col = vec![0.0f32; d];
                let (mut runs, mut ends) = (Vec::new(), Vec::with_capacity(w));
                for x in 0..w {
                    let (c, r) = (x * step, y * step);
                    if !fof.is_empty_column(c, r) {
                        fof.decode_column_with(&table, c, r, &mut col);
                        let mut start = None;
                        for (z, &o) in col.iter().chain(std::iter::once(&f32::NEG_INFINITY)).enumerate() {
                            match (o >= ISO_LEVEL, start) {
                                (true, None) => start = Some(z as u32),
                                (false, Some(first)) => {
                                    runs.push((first, z as u32 - 1));
                                    start = None;
                                }
                                _ => {}
                            }
                        }
                    }
                    ends.push(runs.len() as u32);
                }
                (runs, ends)
            })
            .collect();
        // All runs in (y, x, z) order; column `(x, y)` holds `runs[starts[y * w + x]..starts[y * w + x + 1]]`.
        let mut runs: Vec<Run> = Vec::new();
        let mut starts = Vec::with_capacity(w * h + 1);
        starts.push(0usize);
        for (row_runs, ends) in per_row {
            let base = runs.len();
            starts.extend(ends.iter().map(|&e| base + e as usize));
            runs.extend(row_runs);
        }
        let column = |x: usize, y: usize| starts[y * w + x]..starts[y * w + x + 1];
        let mut parent: Vec<u32> = (0..runs.len() as u32).collect();
        fn find(parent: &mut [u32], mut i: u32) -> u32 {
            while parent[i as usize] != i {
                let up = parent[parent[i as usize] as usize];
                parent[i as usize] = up;
                i = up;
            }
            i
        }
        for y in 0..h {
            for x in 0..w {
                let here = column(x, y);
                if here.is_empty() {
                    continue;
                }
                // The neighbours already visited in scan order: every pair of neighbouring columns once.
                let earlier = [(x.wrapping_sub(1), y), (x.wrapping_sub(1), y.wrapping_sub(1)), (x, y.wrapping_sub(1))]
                    .into_iter()
                    .chain(std::iter::once((x + 1, y.wrapping_sub(1))));
                for (nx, ny) in earlier {
                    if nx >= w || ny >= h {
                        continue;
                    }
                    let there = column(nx, ny);
                    // Both lists are sorted and disjoint within themselves: walk them together.
                    let (mut i, mut j) = (here.start, there.start);
                    while i < here.end && j < there.end {
                        let (a, b) = (runs[i], runs[j]);
                        if a.0 <= b.1 + 1 && b.0 <= a.1 + 1 {
                            let (ra, rb) = (find(&mut parent, i as u32), find(&mut parent, j as u32));
                            if ra != rb {
                                parent[ra.max(rb) as usize] = ra.min(rb);
                            }
                        }
                        if a.1 < b.1 {
                            i += 1;
                        } else {
                            j += 1;
                        }
                    }
                }
            }
        }
        // Labels in the order of each piece's first run (its first voxel in scan order).
        let mut label_of_root = vec![0u32; runs.len()];
        let mut sizes: Vec<usize> = vec![0];
        let mut labels = vec![0u32; w * h * d];
        for y in 0..h {
            for x in 0..w {
                for r in column(x, y) {
                    let root = find(&mut parent, r as u32) as usize;
                    if label_of_root[root] == 0 {
                        label_of_root[root] = sizes.len() as u32;
                        sizes.push(0);
                    }
                    let label = label_of_root[root];
                    let (first, last) = (runs[r].0 as usize, runs[r].1 as usize);
                    sizes[label as usize] += last - first + 1;
                    let base = (y * w + x) * d;
                    labels[base + first..=base + last].fill(label);
                }
            }
        }
        let (mut largest, mut largest_size) = (0u32, 0usize);
        for (label, &size) in sizes.iter().enumerate().skip(1) {
            if size > largest_size {
                (largest, largest_size) = (label as u32, size);
            }
        }
        let total = sizes.iter().sum();
        Self { w, h, d, step, labels, largest, total, largest_size }
    }

    /// Where a run of full-resolution column `(col, row)` over depth samples `[s, e)` of `d * step` belongs:
    /// `Some(true)` when a voxel of the largest piece lies in or next to it, `Some(false)` when only other pieces
    /// do, `None` when the coarse grid saw nothing there (a structure thinner than its voxels).
    fn run_in_largest(&self, col: usize, row: usize, s: usize, e: usize) -> Option<bool> {
        let (x, y) = ((col / self.step).min(self.w - 1), (row / self.step).min(self.h - 1));
        let mut other = false;
        let (z0, z1) = (s / self.step, (e.saturating_sub(1) / self.step).min(self.d - 1));
        for z in z0..=z1 {
            let centre = (y * self.w + x) * self.d + z;
            for j in std::iter::once(centre).chain(neighbours26(x, y, z, self.w, self.h, self.d)) {
                match self.labels[j] {
                    0 => {}
                    l if l == self.largest => return Some(true),
                    _ => other = true,
                }
            }
        }
        other.then_some(false)
    }
}

/// The in-bounds 26-neighbourhood of voxel `(x, y, z)` as indices `(y * w + x) * d + z`, in the order dy, dx, dz
/// (each -1, 0, 1). Filled into a fixed array (the flood fill visits every occupied voxel's neighbours: an
/// iterator of nested closures cost most of the guard's time).
fn neighbours26(x: usize, y: usize, z: usize, w: usize, h: usize, d: usize) -> impl Iterator<Item = usize> {
    let mut out = [0usize; 26];
    let mut len = 0;
    let (xs, xe) = (x.saturating_sub(1), (x + 1).min(w - 1));
    let (ys, ye) = (y.saturating_sub(1), (y + 1).min(h - 1));
    let (zs, ze) = (z.saturating_sub(1), (z + 1).min(d - 1));
    for ny in ys..=ye {
        for nx in xs..=xe {
            let base = (ny * w + nx) * d;
            for nz in zs..=ze {
                if (nx, ny, nz) != (x, y, z) {
                    out[len] = base + nz;
                    len += 1;
                }
            }
        }
    }
    out.into_iter().take(len)
}

/// Fraction of the occupied volume outside the largest connected piece: the FOF decoded on a voxel grid of every
/// `step`-th column and row (`width / step` depth samples, so voxels are cubes), occupancy at the marching-cubes
/// level, voxels connected through faces, edges and corners (26-neighbourhood). 0 for an empty field.
pub fn detached_volume_fraction(fof: &Fof, step: usize) -> f32 {
    Pieces::of(fof, step).detached_fraction()
}

/// The FOF with every piece but the largest removed (pieces found as in [`detached_volume_fraction`]): each
/// column's occupancy runs (at `width` depth samples) that lie only in other pieces are dropped and the column is
/// re-encoded from the runs it keeps ([`crate::geometry::fof::accumulate_interval`]); columns with nothing to drop
/// keep their coefficients exactly. Runs thinner than the coarse grid's voxels stay. Returns the field and the
/// number of columns changed.
pub fn keep_largest_piece(fof: &Fof, step: usize) -> (Fof, usize) {
    Pieces::of(fof, step).keep_largest(fof.clone())
}

impl Pieces {
    /// [`detached_volume_fraction`] of the field these pieces were found in.
    pub fn detached_fraction(&self) -> f32 {
        if self.total == 0 {
            0.0
        } else {
            (self.total - self.largest_size) as f32 / self.total as f32
        }
    }

    /// [`keep_largest_piece`] of `fof`, the field these pieces were found in (with the same `step`), changed in
    /// place.
    pub fn keep_largest(&self, fof: Fof) -> (Fof, usize) {
        let pieces = self;
        if pieces.total == pieces.largest_size {
            return (fof, 0);
        }
        // Columns whose coarse neighbourhood holds a voxel of another piece: only these can change.
        let (w, h, d) = (pieces.w, pieces.h, pieces.d);
        let mut other_near = vec![false; w * h];
        for (i, &l) in pieces.labels.iter().enumerate() {
            if l != 0 && l != pieces.largest {
                let (x, y) = ((i / d) % w, (i / d) / w);
                for ny in y.saturating_sub(1)..(y + 2).min(h) {
                    for nx in x.saturating_sub(1)..(x + 2).min(w) {
                        other_near[ny * w + nx] = true;
                    }
                }
            }
        }
        let samples = pieces.d * pieces.step;
        let table = CosineTable::new(fof.n, samples);
        let mut out = fof;
        let (n, width) = (out.n, out.width);
        let changed: usize = out
            .coeffs
            .par_chunks_mut(n * width)
            .enumerate()
            .map(|(row, coeffs)| {
                let mut occ = vec![0.0f32; samples];
                let mut changed = 0;
                for col in 0..width {
                    let coarse = ((row / pieces.step).min(h - 1)) * w + (col / pieces.step).min(w - 1);
                    let c = &mut coeffs[col * n..(col + 1) * n];
                    if !other_near[coarse] || Fof::is_empty_coefficients(c) {
                        continue;
                    }
                    table.decode(c, &mut occ);
                    let mut kept = Vec::new();
                    let mut dropped = false;
                    let mut start = None;
                    for (i, &o) in occ.iter().chain(std::iter::once(&f32::NEG_INFINITY)).enumerate() {
                        match (o >= ISO_LEVEL, start) {
                            (true, None) => start = Some(i),
                            (false, Some(s)) => {
                                start = None;
                                if pieces.run_in_largest(col, row, s, i) == Some(false) {
                                    dropped = true;
                                } else {
                                    kept.push((s, i));
                                }
                            }
                            _ => {}
                        }
                    }
                    if dropped {
                        c.fill(0.0);
                        let z = |i: usize| 2.0 * i as f32 / samples as f32 - 1.0;
                        for (s, e) in kept {
                            accumulate_interval(z(s), z(e), c);
                        }
                        changed += 1;
                    }
                }
                changed
            })
            .sum();
        (out, changed)
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::buffer::Image;
    use crate::geometry::mesh::TriMesh;

    /// An axis-aligned box mesh (outward faces) from `lo` to `hi`.
    pub(crate) fn cuboid(lo: Vec3, hi: Vec3) -> TriMesh {
        let p = |i: usize| {
            Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
        };
        let positions = (0..8).map(p).collect();
        let faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let triangles = faces.iter().flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]]).collect();
        TriMesh::new(positions, triangles)
    }

    fn merged(a: TriMesh, b: TriMesh) -> TriMesh {
        let offset = a.positions.len() as u32;
        let mut positions = a.positions;
        positions.extend(b.positions);
        let mut triangles = a.triangles;
        triangles.extend(b.triangles.iter().map(|t| t.map(|i| i + offset)));
        TriMesh::new(positions, triangles)
    }

    #[test]
    fn intervals_are_counted_with_small_gaps_merged_and_specks_ignored() {
        let occ = |s: &str| s.chars().map(|c| if c == '#' { 1.0 } else { 0.0 }).collect::<Vec<f32>>();
        assert_eq!(count_intervals(&occ("....####...."), 0.5), 1);
        assert_eq!(count_intervals(&occ("..###...###."), 0.5), 2);
        assert_eq!(count_intervals(&occ("..###.###..."), 0.5), 1, "a one-sample gap is one interval");
        assert_eq!(count_intervals(&occ("..###....#.."), 0.5), 1, "a one-sample speck is ignored");
        assert_eq!(count_intervals(&occ("############"), 0.5), 1);
        assert_eq!(count_intervals(&occ("............"), 0.5), 0);
        assert_eq!(count_intervals(&occ("##........##"), 0.5), 2, "runs touching both ends");
    }

    #[test]
    fn one_rise_at_most_means_one_interval_at_most() {
        let occ = |s: &str| s.chars().map(|c| if c == '#' { 1.0 } else { 0.0 }).collect::<Vec<f32>>();
        for (column, one) in [
            ("............", true),
            ("....####....", true),
            ("#######.....", true),
            (".......#####", true),
            ("..###.###...", false),
            ("##........##", false),
            ("..###....#..", false),
        ] {
            assert_eq!(at_most_one_run(&occ(column), 0.5), one, "{column}");
        }
        // NaN is below every level, as in `intervals`.
        assert!(at_most_one_run(&[1.0, f32::NAN, 1.0, 1.0][..1], 0.5));
        assert!(!at_most_one_run(&[1.0, f32::NAN, 1.0, 1.0], 0.5));
        // Every pattern of 10 samples: one rise at most always means at most one interval.
        for bits in 0u32..1 << 10 {
            let column: Vec<f32> = (0..10).map(|i| if bits >> i & 1 == 1 { 1.0 } else { 0.0 }).collect();
            if at_most_one_run(&column, 0.5) {
                assert!(count_intervals(&column, 0.5) <= 1, "{bits:010b}");
            } else {
                assert!(intervals_raw_runs(&column) >= 2, "{bits:010b}");
            }
        }
    }

    /// Runs of samples at or above 0.5 before any merging (the reference for [`at_most_one_run`]).
    fn intervals_raw_runs(column: &[f32]) -> usize {
        column.iter().enumerate().filter(|&(i, &v)| v >= 0.5 && (i == 0 || column[i - 1] < 0.5)).count()
    }

    #[test]
    fn two_shells_count_as_doubled_and_one_does_not() {
        let res = 32;
        let slab = cuboid(Vec3::new(-0.5, -0.5, -0.1), Vec3::new(0.5, 0.5, 0.1));
        let one = Fof::from_mesh(&slab, res, 32).unwrap();
        // A second shell behind the first, over the left half of the silhouette only.
        let back = cuboid(Vec3::new(-0.5, -0.5, -0.7), Vec3::new(0.0, 0.5, -0.5));
        let two = Fof::from_mesh(&merged(slab.clone(), back), res, 32).unwrap();
        let mask = Image::from_fn(res, res, |c, r| {
            let x = (c as f32 + 0.5) / (res as f32 / 2.0) - 1.0;
            let y = 1.0 - (r as f32 + 0.5) / (res as f32 / 2.0);
            if x.abs() < 0.5 && y.abs() < 0.5 {
                1.0
            } else {
                0.0
            }
        });
        assert_eq!(doubled_fraction(&one, &one, &mask), 0.0);
        let d = doubled_fraction(&two, &one, &mask);
        assert!((d - 0.5).abs() < 0.1, "half the columns have a second shell: {d}");
        // The same second shell is explained when the reference has it too.
        assert_eq!(doubled_fraction(&two, &two, &mask), 0.0);
        // Grids that differ are not comparable.
        assert!(doubled_fraction(&one, &Fof::zeros(32, 16, 16).unwrap(), &mask).is_nan());
        // Several references: a column is explained up to the most intervals any of them has there.
        let right = cuboid(Vec3::new(0.0, -0.5, -0.7), Vec3::new(0.5, 0.5, -0.5));
        let right_two = Fof::from_mesh(&merged(slab.clone(), right), res, 32).unwrap();
        let both = doubled_fraction_beyond(&two, &[&one, &right_two], &mask, 1);
        assert!((both - 0.5).abs() < 0.1, "the right half's second shell does not explain the left's: {both}");
        assert_eq!(doubled_fraction_beyond(&two, &[&one, &two], &mask, 1), 0.0);
        assert_eq!(doubled_fraction_beyond(&one, &[], &mask, 1), 0.0, "one shell is always explained");
        assert!((doubled_fraction_beyond(&two, &[], &mask, 1) - d).abs() < 1e-6, "no reference: one shell explained");
        assert!(doubled_fraction_beyond(&one, &[&one, &Fof::zeros(32, 16, 16).unwrap()], &mask, 1).is_nan());
    }

    /// A 3x1 field whose columns hold the intervals given (z in [-1, 1]).
    fn columns(cols: &[&[(f32, f32)]]) -> Fof {
        let n = 32;
        let mut coeffs = vec![0.0f32; cols.len() * n];
        for (c, intervals) in cols.iter().enumerate() {
            for &(lo, hi) in *intervals {
                accumulate_interval(lo, hi, &mut coeffs[c * n..(c + 1) * n]);
            }
        }
        Fof::new(n, cols.len(), 1, coeffs).unwrap()
    }

    #[test]
    fn unexplained_shells_are_dropped_and_the_longest_kept() {
        let (long, short, other) = ((-0.6, -0.2), (0.3, 0.5), (0.6, 0.8));
        // Column 0: a second, shorter shell no reference explains. Column 1: the same, but the second reference
        // has two shells there. Column 2: outside the mask.
        let mut fof = columns(&[&[long, short], &[long, short], &[long, short]]);
        let before = fof.clone();
        let one = columns(&[&[(-0.5, 0.0)], &[(-0.5, 0.0)], &[(-0.5, 0.0)]]);
        let two = columns(&[&[(-0.5, 0.0)], &[(-0.7, -0.3), other], &[(-0.5, 0.0)]]);
        let mask = GrayImage::from_fn(3, 1, |c, _| if c < 2 { 1.0 } else { 0.0 });
        assert_eq!(drop_unexplained_shells(&mut fof, &[&one, &two], &mask), 1);
        // Column 0 is now the long interval alone, re-encoded from its decoded ends (within a sample of 2/128).
        let mut occ = vec![0.0f32; INTERVAL_SAMPLES];
        fof.decode_column(0, 0, INTERVAL_SAMPLES, &mut occ);
        let runs = intervals(&occ, ISO_LEVEL);
        assert_eq!(runs.len(), 1, "{runs:?}");
        let z = |s: usize| 2.0 * s as f32 / INTERVAL_SAMPLES as f32 - 1.0;
        let sample = 2.0 / INTERVAL_SAMPLES as f32;
        assert!((z(runs[0].0) - long.0).abs() <= 1.5 * sample && (z(runs[0].1) - long.1).abs() <= 1.5 * sample);
        // The explained column and the one outside the mask keep every bit.
        for c in 1..3 {
            let (a, b) = (fof.column(c, 0), before.column(c, 0));
            assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "column {c}");
        }
        // One shell is always explained: a single-shell field is untouched even with no reference.
        let mut single = columns(&[&[long], &[short], &[]]);
        assert_eq!(drop_unexplained_shells(&mut single, &[], &GrayImage::new(3, 1, 1.0)), 0);
        // Grids that differ: nothing changes.
        let wide = Fof::zeros(32, 4, 1).unwrap();
        assert_eq!(drop_unexplained_shells(&mut fof, &[&wide], &mask), 0);
    }

    #[test]
    fn pieces_are_labelled_as_a_voxel_flood_fill_labels_them() {
        // Random intervals per column: many pieces, touching through faces, edges and corners only, with gaps of
        // one voxel in depth. The run-based labels must be those of a 26-connected flood fill scanning voxels in
        // (y, x, z) order, numbering each piece at its first voxel.
        let mut seed = 11u32;
        let mut next = |m: u32| {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) % m
        };
        let res = 40;
        let intervals = Image::from_fn(res, res, |_, _| {
            (0..next(3))
                .map(|_| {
                    let a = next(200) as f32 / 100.0 - 1.0;
                    (a, (a + next(40) as f32 / 100.0).min(1.0))
                })
                .collect::<Vec<_>>()
        });
        let fof = Fof::from_intervals(&intervals, 32).unwrap();
        for step in [1, 2, 3] {
            let pieces = Pieces::of(&fof, step);
            let (w, h, d) = (pieces.w, pieces.h, pieces.d);
            let table = CosineTable::new(fof.n, d);
            let mut col = vec![0.0f32; d];
            let mut occupied = vec![false; w * h * d];
            for y in 0..h {
                for x in 0..w {
                    if fof.is_empty_column(x * step, y * step) {
                        continue;
                    }
                    fof.decode_column_with(&table, x * step, y * step, &mut col);
                    for z in 0..d {
                        occupied[(y * w + x) * d + z] = col[z] >= ISO_LEVEL;
                    }
                }
            }
            let mut labels = vec![0u32; w * h * d];
            let (mut next_label, mut largest, mut largest_size, mut total) = (0u32, 0u32, 0usize, 0usize);
            for start in 0..labels.len() {
                if !occupied[start] || labels[start] != 0 {
                    continue;
                }
                next_label += 1;
                labels[start] = next_label;
                let (mut stack, mut size) = (vec![start], 0usize);
                while let Some(i) = stack.pop() {
                    size += 1;
                    let (z, x, y) = (i % d, (i / d) % w, i / d / w);
                    for j in neighbours26(x, y, z, w, h, d) {
                        if occupied[j] && labels[j] == 0 {
                            labels[j] = next_label;
                            stack.push(j);
                        }
                    }
                }
                total += size;
                if size > largest_size {
                    (largest, largest_size) = (next_label, size);
                }
            }
            assert!(next_label > 5, "step {step}: the field has many pieces ({next_label})");
            assert!(pieces.labels == labels, "step {step}: labels differ");
            assert_eq!(
                (pieces.largest, pieces.largest_size, pieces.total),
                (largest, largest_size, total),
                "step {step}"
            );
        }
    }

    #[test]
    fn a_floating_block_is_its_share_of_the_volume() {
        let res = 64;
        let body = cuboid(Vec3::new(-0.5, -0.5, -0.25), Vec3::new(0.0, 0.5, 0.25));
        let whole = Fof::from_mesh(&body, res, 32).unwrap();
        assert!(detached_volume_fraction(&whole, 2) < 1e-3, "one block is one body");
        // A block of an eighth of the body's volume, well apart from it.
        let fragment = cuboid(Vec3::new(0.5, -0.25, -0.125), Vec3::new(0.75, 0.25, 0.125));
        let two = Fof::from_mesh(&merged(body.clone(), fragment), res, 32).unwrap();
        let f = detached_volume_fraction(&two, 2);
        let expected = 1.0 / 9.0;
        assert!((f - expected).abs() < 0.04, "{f} vs {expected}");
        // A block touching the body is part of it.
        let touching = cuboid(Vec3::new(0.0, -0.25, -0.125), Vec3::new(0.25, 0.25, 0.125));
        let joined = Fof::from_mesh(&merged(body, touching), res, 32).unwrap();
        assert!(detached_volume_fraction(&joined, 2) < 1e-3);
        assert_eq!(detached_volume_fraction(&Fof::zeros(32, 16, 16).unwrap(), 1), 0.0, "empty field");
    }

    #[test]
    fn keeping_the_largest_piece_removes_the_fragment_only() {
        let res = 64;
        let body = cuboid(Vec3::new(-0.5, -0.5, -0.25), Vec3::new(0.0, 0.5, 0.25));
        let whole = Fof::from_mesh(&body, res, 32).unwrap();
        let (same, changed) = keep_largest_piece(&whole, 2);
        assert_eq!(changed, 0);
        assert!(same == whole, "nothing to remove: coefficients unchanged");
        // A fragment beside the body, and one behind it in the same columns (a doubled shell).
        let beside = cuboid(Vec3::new(0.5, -0.25, -0.125), Vec3::new(0.75, 0.25, 0.125));
        let behind = cuboid(Vec3::new(-0.4, 0.1, -0.8), Vec3::new(-0.1, 0.4, -0.6));
        let broken = Fof::from_mesh(&merged(merged(body, beside), behind), res, 32).unwrap();
        assert!(detached_volume_fraction(&broken, 2) > 0.1);
        let (fixed, changed) = keep_largest_piece(&broken, 2);
        assert!(changed > 0);
        assert!(detached_volume_fraction(&fixed, 2) < 1e-3, "{}", detached_volume_fraction(&fixed, 2));
        // The body's own columns keep their volume: the columns with the shell behind now decode like the body.
        let mut a = vec![0.0; 64];
        let mut b = vec![0.0; 64];
        broken.decode_column(20, 20, 64, &mut a);
        assert_eq!(count_intervals(&a, ISO_LEVEL), 2, "the test column crosses the body and the shell");
        let (col, row) = (20, 20); // x = -0.36, y = 0.36: inside the body and the shell behind it
        fixed.decode_column(col, row, 64, &mut a);
        whole.decode_column(col, row, 64, &mut b);
        let diff = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(diff < 0.2, "re-encoded column matches the body's: {diff}");
        assert_eq!(count_intervals(&a, ISO_LEVEL), 1);
        assert!(fixed.coeffs.iter().all(|c| c.is_finite()));
    }
}
