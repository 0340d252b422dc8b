//! Temporal smoothing against flicker: an exponential moving average on masks ([`MaskSmoother`]) and on any
//! vector of coefficients such as FOF ([`VecSmoother`]), each reset when the input changes a lot (a cut, the
//! person entering or leaving) so the output never lags behind a real change.

use rayon::prelude::*;

use super::morph::iou_soft;
use crate::buffer::GrayImage;

/// Entries per parallel chunk of [`VecSmoother`]'s passes (small vectors stay on one thread).
const PAR_CHUNK: usize = 1 << 16;

/// A smoothed mask value below which a pixel is not the person at all (0): under the average a pixel the person
/// left decays by `1 - alpha` a frame and never reaches 0, so a moving person trailed a wide band of ever smaller
/// values (denormal floats after about a hundred frames), each one a partly covered pixel for the stages after. An
/// 8-bit alpha shows nothing below 1/255.
pub const MASK_FLOOR: f32 = 1.0 / 256.0;

/// EMA of soft masks: `s = a*m + (1-a)*s`, reset to `m` when the IoU of `s` and `m` (at 0.5) drops below
/// `reset_iou` or the size changes; values below [`MASK_FLOOR`] are 0.
#[derive(Clone, Debug)]
pub struct MaskSmoother {
    /// Weight of the new mask, in `(0, 1]` (1 = no smoothing).
    pub alpha: f32,
    /// IoU below which the state is reset.
    pub reset_iou: f32,
    state: Option<GrayImage>,
    resets: u64,
}

impl MaskSmoother {
    /// A smoother with weight `alpha` (clamped to `[0.01, 1]`) and reset threshold `reset_iou`.
    pub fn new(alpha: f32, reset_iou: f32) -> Self {
        let alpha = if alpha.is_finite() { alpha.clamp(0.01, 1.0) } else { 1.0 };
        Self { alpha, reset_iou, state: None, resets: 0 }
    }

    /// Feeds the next mask, returns the smoothed one (same size, values in `[0, 1]`).
    pub fn update(&mut self, mask: &GrayImage) -> GrayImage {
        let reset = match &self.state {
            None => true,
            Some(s) => (s.width, s.height) != (mask.width, mask.height) || iou_soft(s, mask) < self.reset_iou,
        };
        let floor = |v: f32| if v >= MASK_FLOOR { v.min(1.0) } else { 0.0 };
        if reset {
            self.resets += 1;
            // NaN fails the comparison: 0.
            self.state = Some(GrayImage { data: mask.data.iter().map(|&v| floor(v)).collect(), ..mask.clone() });
        } else if let Some(s) = &mut self.state {
            let a = self.alpha;
            for (sv, &mv) in s.data.iter_mut().zip(&mask.data) {
                let m = if mv.is_finite() { mv } else { 0.0 };
                *sv = floor(a * m + (1.0 - a) * *sv);
            }
        }
        self.state.clone().unwrap_or_else(|| mask.clone())
    }

    /// How many times the state was (re)initialised.
    pub fn resets(&self) -> u64 {
        self.resets
    }

    /// Forgets the state (next mask passes through).
    pub fn reset(&mut self) {
        self.state = None;
    }
}

/// EMA of a coefficient vector, reset when the relative change `|v - s| / max(|s|, eps)` exceeds `reset_change`
/// or the length changes.
#[derive(Clone, Debug)]
pub struct VecSmoother {
    /// Weight of the new vector, in `(0, 1]`.
    pub alpha: f32,
    /// Relative L2 change above which the state is reset.
    pub reset_change: f32,
    state: Option<Vec<f32>>,
    resets: u64,
}

impl VecSmoother {
    /// A smoother with weight `alpha` (clamped to `[0.01, 1]`) and reset threshold `reset_change`.
    pub fn new(alpha: f32, reset_change: f32) -> Self {
        let alpha = if alpha.is_finite() { alpha.clamp(0.01, 1.0) } else { 1.0 };
        Self { alpha, reset_change, state: None, resets: 0 }
    }

    /// Forgets the state (the next vector passes through), e.g. at a cut.
    pub fn reset(&mut self) {
        self.state = None;
    }

    /// Smooths `v` in place (non-finite entries count as 0).
    pub fn update(&mut self, v: &mut [f32]) {
        // FOF vectors have millions of entries (8M at 512² with N = 32): every pass runs in parallel chunks.
        v.par_iter_mut().with_min_len(PAR_CHUNK).for_each(|x| {
            if !x.is_finite() {
                *x = 0.0;
            }
        });
        let reset = match &self.state {
            None => true,
            Some(s) if s.len() != v.len() => true,
            Some(s) => {
                // One pass for both sums, f64 partial sums per chunk so the totals stay exact enough.
                let (diff2, norm2) = s
                    .par_chunks(PAR_CHUNK)
                    .zip(v.par_chunks(PAR_CHUNK))
                    .map(|(sc, vc)| {
                        sc.iter().zip(vc).fold((0.0f64, 0.0f64), |(d, n), (&a, &b)| {
                            let (a, b) = (a as f64, b as f64);
                            (d + (a - b) * (a - b), n + a * a)
                        })
                    })
                    .reduce(|| (0.0, 0.0), |x, y| (x.0 + y.0, x.1 + y.1));
                diff2.sqrt() > self.reset_change as f64 * norm2.sqrt().max(1e-6)
            }
        };
        if reset {
            self.resets += 1;
            self.state = Some(v.to_vec());
            return;
        }
        if let Some(s) = &mut self.state {
            let a = self.alpha;
            s.par_iter_mut().zip(v.par_iter_mut()).with_min_len(PAR_CHUNK).for_each(|(sv, x)| {
                *sv = a * *x + (1.0 - a) * *sv;
                *x = *sv;
            });
        }
    }

    /// How many times the state was (re)initialised.
    pub fn resets(&self) -> u64 {
        self.resets
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::Image;

    #[test]
    fn mask_ema_converges_geometrically_and_resets() {
        let a = Image::from_fn(10, 10, |x, _| if x < 5 { 1.0 } else { 0.0 });
        // Same silhouette with one column flickering off.
        let b = Image::from_fn(10, 10, |x, _| if x < 4 { 1.0 } else { 0.0 });
        let mut s = MaskSmoother::new(0.25, 0.5);
        assert_eq!(s.update(&a), a);
        let out = s.update(&b);
        // Flickering column: 0.75 after one step (1 - alpha), not 0.
        assert!((out.get(4, 0) - 0.75).abs() < 1e-6);
        let out = s.update(&b);
        assert!((out.get(4, 0) - 0.5625).abs() < 1e-6);
        assert_eq!(s.resets(), 1);
        // A completely different mask resets at once.
        let c = Image::from_fn(10, 10, |x, _| if x >= 7 { 1.0 } else { 0.0 });
        assert_eq!(s.update(&c), c);
        assert_eq!(s.resets(), 2);
        // Size change resets.
        let d = Image::new(4, 4, 1.0);
        assert_eq!(s.update(&d), d);
    }

    #[test]
    fn a_pixel_the_person_left_reaches_zero() {
        let person = Image::from_fn(8, 8, |x, _| if x < 6 { 1.0 } else { 0.0 });
        let left = Image::from_fn(8, 8, |x, _| if x < 5 { 1.0 } else { 0.0 });
        let mut s = MaskSmoother::new(0.6, 0.5);
        s.update(&person);
        // Column 5 decays by 0.4 a frame: 0.4, 0.16, 0.064, 0.0256, 0.01024, 0.0041, then 0.0016 < 1/256.
        let mut value = 1.0f32;
        for frame in 1..=7 {
            let out = s.update(&left);
            value *= 0.4;
            let want = if value >= MASK_FLOOR { value } else { 0.0 };
            assert!((out.get(5, 3) - want).abs() < 1e-6, "frame {frame}: {} vs {want}", out.get(5, 3));
        }
        assert_eq!(*s.update(&left).get(5, 3), 0.0);
        // Tiny and non-finite inputs are 0 on a reset too.
        let mut fresh = MaskSmoother::new(0.6, 0.5);
        let noisy = Image::from_fn(4, 4, |x, y| match (x, y) {
            (0, 0) => 1e-30,
            (1, 0) => f32::NAN,
            _ => 1.0,
        });
        let out = fresh.update(&noisy);
        assert_eq!((*out.get(0, 0), *out.get(1, 0), *out.get(2, 0)), (0.0, 0.0, 1.0));
    }

    #[test]
    fn vec_ema_and_reset() {
        let mut s = VecSmoother::new(0.5, 0.5);
        let mut v = vec![1.0, 2.0];
        s.update(&mut v);
        assert_eq!(v, vec![1.0, 2.0]);
        let mut v = vec![1.2, 2.0];
        s.update(&mut v);
        assert!((v[0] - 1.1).abs() < 1e-6 && v[1] == 2.0);
        let mut v = vec![10.0, -3.0];
        s.update(&mut v);
        assert_eq!(v, vec![10.0, -3.0]);
        let mut v = vec![f32::NAN, -3.0];
        s.update(&mut v);
        assert!(v.iter().all(|x| x.is_finite()));
        assert_eq!(s.resets(), 3);
    }
}
