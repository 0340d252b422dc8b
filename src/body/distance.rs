//! Exact Euclidean distance transform (Felzenszwalb & Huttenlocher's separable lower-envelope algorithm) that also
//! returns the nearest site of every pixel. Hand-written because it is 60 lines and the image crates that have
//! one (imageproc) would pull a large dependency tree for it; it is tested against brute force.

/// Squared distance (pixels²) to the nearest site and that site's index, per pixel (row-major). Pixels with no site
/// anywhere get `f32::INFINITY` and index `usize::MAX`.
#[derive(Clone, Debug, PartialEq)]
pub struct DistanceField {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Squared Euclidean distance to the nearest site.
    pub dist2: Vec<f32>,
    /// Row-major index of the nearest site.
    pub nearest: Vec<usize>,
}

/// Value of a non-site in the 1-D transforms: far above any real squared distance (at most 2 x 8192²), low
/// enough that f64 keeps integer precision when squared distances are added to it.
const FAR: f64 = 1e12;

/// 1-D squared distance transform of `f` (a site has value 0, others [`FAR`]) with argmins, into `d`/`arg`.
fn transform_1d(f: &[f64], d: &mut [f64], arg: &mut [usize], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in 1..n {
        let qf = q as f64;
        // z[0] is -inf, so the loop always stops at k = 0 at the latest.
        let s = loop {
            let p = v[k] as f64;
            let s = ((f[q] + qf * qf) - (f[v[k]] + p * p)) / (2.0 * qf - 2.0 * p);
            if s <= z[k] && k > 0 {
                k -= 1;
            } else {
                break s;
            }
        };
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, (dq, aq)) in d.iter_mut().zip(arg.iter_mut()).enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        let dx = q as f64 - p as f64;
        *dq = dx * dx + f[p];
        *aq = p;
    }
}

impl DistanceField {
    /// The distance transform of the sites `site(i)` over a `width x height` grid.
    pub fn new(width: usize, height: usize, site: impl Fn(usize) -> bool) -> Self {
        let n = width * height;
        let mut dist2 = vec![f32::INFINITY; n];
        let mut nearest = vec![usize::MAX; n];
        if n == 0 {
            return Self { width, height, dist2, nearest };
        }
        // Columns first: per column, distance along y to the nearest site row.
        let mut col_d = vec![FAR; n];
        let mut col_row = vec![usize::MAX; n];
        let m = width.max(height);
        let (mut f, mut d, mut arg) = (vec![0.0f64; m], vec![0.0f64; m], vec![0usize; m]);
        let (mut v, mut z) = (vec![0usize; m], vec![0.0f64; m + 1]);
        for c in 0..width {
            for (r, fr) in f[..height].iter_mut().enumerate() {
                *fr = if site(r * width + c) { 0.0 } else { FAR };
            }
            transform_1d(&f[..height], &mut d[..height], &mut arg[..height], &mut v, &mut z);
            for r in 0..height {
                col_d[r * width + c] = d[r];
                col_row[r * width + c] = arg[r];
            }
        }
        for r in 0..height {
            f[..width].copy_from_slice(&col_d[r * width..(r + 1) * width]);
            transform_1d(&f[..width], &mut d[..width], &mut arg[..width], &mut v, &mut z);
            for c in 0..width {
                let i = r * width + c;
                if d[c] < FAR * 0.5 {
                    let src_col = arg[c];
                    dist2[i] = d[c] as f32;
                    nearest[i] = col_row[r * width + src_col] * width + src_col;
                }
            }
        }
        Self { width, height, dist2, nearest }
    }

    /// Distance (pixels) at continuous pixel coordinates `(x, y)` (centres at `+0.5`), bilinear between pixel
    /// centres and clamped at the edges; infinity when there is no site.
    pub fn distance_at(&self, x: f32, y: f32) -> f32 {
        self.distance_and_gradient_at(x, y).0
    }

    /// [`DistanceField::distance_at`] and its gradient `(d/dx, d/dy)` (the bilinear interpolation's, zero across
    /// the clamped border). Infinite distance and a zero gradient for an empty field or a non-finite point.
    pub fn distance_and_gradient_at(&self, x: f32, y: f32) -> (f32, (f32, f32)) {
        if self.width == 0 || self.height == 0 || !(x.is_finite() && y.is_finite()) {
            return (f32::INFINITY, (0.0, 0.0));
        }
        let (x, y) = (x - 0.5, y - 0.5);
        let fx = x.clamp(0.0, (self.width - 1) as f32);
        let fy = y.clamp(0.0, (self.height - 1) as f32);
        let (c0, r0) = (fx as usize, fy as usize);
        let (c1, r1) = ((c0 + 1).min(self.width - 1), (r0 + 1).min(self.height - 1));
        let (tx, ty) = (fx - c0 as f32, fy - r0 as f32);
        let d = |c: usize, r: usize| self.dist2[r * self.width + c].sqrt();
        let (d00, d10, d01, d11) = (d(c0, r0), d(c1, r0), d(c0, r1), d(c1, r1));
        let top = d00 * (1.0 - tx) + d10 * tx;
        let bottom = d01 * (1.0 - tx) + d11 * tx;
        let inside_x = x > 0.0 && x < (self.width - 1) as f32;
        let inside_y = y > 0.0 && y < (self.height - 1) as f32;
        let gx = if inside_x { (d10 - d00) * (1.0 - ty) + (d11 - d01) * ty } else { 0.0 };
        let gy = if inside_y { bottom - top } else { 0.0 };
        (top * (1.0 - ty) + bottom * ty, (gx, gy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gradient_is_the_interpolations() {
        let f = DistanceField::new(20, 15, |i| i == 7 * 20 + 9 || i == 3 * 20 + 2);
        let h = 1e-3f32;
        for (x, y) in [(4.3f32, 6.7f32), (12.2, 3.9), (15.61, 11.17), (9.8, 7.2)] {
            let (d, (gx, gy)) = f.distance_and_gradient_at(x, y);
            assert_eq!(d, f.distance_at(x, y));
            let nx = (f.distance_at(x + h, y) - f.distance_at(x - h, y)) / (2.0 * h);
            let ny = (f.distance_at(x, y + h) - f.distance_at(x, y - h)) / (2.0 * h);
            assert!((gx - nx).abs() < 1e-2 && (gy - ny).abs() < 1e-2, "({x},{y}): {gx},{gy} vs {nx},{ny}");
        }
        assert_eq!(f.distance_and_gradient_at(f32::NAN, 1.0).1, (0.0, 0.0));
    }

    #[test]
    fn matches_brute_force_with_nearest_sites() {
        let (w, h) = (23, 17);
        let sites: Vec<bool> = (0..w * h).map(|i| (i * 7919 + 13) % 41 == 0 || i == 100).collect();
        let f = DistanceField::new(w, h, |i| sites[i]);
        for i in 0..w * h {
            let (c, r) = ((i % w) as i64, (i / w) as i64);
            let best = (0..w * h)
                .filter(|&j| sites[j])
                .map(|j| {
                    let (cj, rj) = ((j % w) as i64, (j / w) as i64);
                    ((cj - c).pow(2) + (rj - r).pow(2)) as f32
                })
                .fold(f32::INFINITY, f32::min);
            assert_eq!(f.dist2[i], best, "pixel {i}");
            let j = f.nearest[i];
            assert!(sites[j]);
            let (cj, rj) = ((j % w) as i64, (j / w) as i64);
            assert_eq!(((cj - c).pow(2) + (rj - r).pow(2)) as f32, best);
        }
    }

    #[test]
    fn one_site_gives_euclidean_distance_and_no_site_infinity() {
        let f = DistanceField::new(10, 10, |i| i == 0);
        assert_eq!(f.dist2[9 * 10 + 9], 162.0);
        assert!((f.distance_at(3.5, 4.5) - 5.0).abs() < 1e-6);
        assert!((f.distance_at(3.0, 4.5) - 0.5 * (5.0 + 4f32.hypot(2.0))).abs() < 1e-5);
        let empty = DistanceField::new(4, 3, |_| false);
        assert!(empty.dist2.iter().all(|d| d.is_infinite()) && empty.nearest.iter().all(|&n| n == usize::MAX));
        assert!(empty.distance_at(1.0, 1.0).is_infinite());
        assert!(f.distance_at(f32::NAN, 1.0).is_infinite());
        let all = DistanceField::new(5, 5, |_| true);
        assert!(all.dist2.iter().all(|&d| d == 0.0));
        assert_eq!(DistanceField::new(0, 0, |_| true).dist2.len(), 0);
    }
}
