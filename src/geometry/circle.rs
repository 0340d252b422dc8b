//! The minimal enclosing circle of 2-D points (Welzl's algorithm): the reference's FOF preprocessing centres a
//! body's x and z on it (`synth::normalize`), and the body prior centres its fitted body the same way.

use glam::{DVec2, Vec2};

/// Minimal enclosing circle `(centre, radius)` of 2-D points (Welzl, iterative move-to-front form with a fixed
/// pseudo-random order, so the result is deterministic). Computed in f64. Empty input gives `(0, 0)`.
pub fn min_enclosing_circle(points: &[Vec2]) -> (Vec2, f32) {
    if points.is_empty() {
        return (Vec2::ZERO, 0.0);
    }
    let mut p: Vec<DVec2> = points.iter().map(|v| v.as_dvec2()).collect();
    // Deterministic shuffle (expected linear time needs a random order).
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    for i in (1..p.len()).rev() {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let j = ((state >> 33) % (i as u64 + 1)) as usize;
        p.swap(i, j);
    }
    let eps = 1e-9;
    let inside = |c: DVec2, r: f64, q: DVec2| c.distance(q) <= r * (1.0 + 1e-12) + eps;
    let (mut c, mut r) = (p[0], 0.0f64);
    for i in 1..p.len() {
        if inside(c, r, p[i]) {
            continue;
        }
        c = p[i];
        r = 0.0;
        for j in 0..i {
            if inside(c, r, p[j]) {
                continue;
            }
            c = (p[i] + p[j]) * 0.5;
            r = p[i].distance(c);
            for k in 0..j {
                if inside(c, r, p[k]) {
                    continue;
                }
                (c, r) = circumcircle(p[i], p[j], p[k]);
            }
        }
    }
    (c.as_vec2(), r as f32)
}

/// Circle through three points; for (nearly) collinear points the circle on the farthest pair.
fn circumcircle(a: DVec2, b: DVec2, c: DVec2) -> (DVec2, f64) {
    let (bx, by) = (b.x - a.x, b.y - a.y);
    let (cx, cy) = (c.x - a.x, c.y - a.y);
    let d = 2.0 * (bx * cy - by * cx);
    let scale = (bx * bx + by * by).max(cx * cx + cy * cy);
    if d.abs() <= 1e-12 * scale.max(1e-300) {
        let pairs = [(a, b), (a, c), (b, c)];
        let (p, q) = pairs.into_iter().max_by(|x, y| x.0.distance(x.1).total_cmp(&y.0.distance(y.1))).unwrap_or((a, b));
        let m = (p + q) * 0.5;
        return (m, p.distance(m));
    }
    let b2 = bx * bx + by * by;
    let c2 = cx * cx + cy * cy;
    let ux = (cy * b2 - by * c2) / d;
    let uy = (bx * c2 - cx * b2) / d;
    let center = DVec2::new(a.x + ux, a.y + uy);
    (center, center.distance(a))
}
