//! Binary-mask cleanup: square erosion/dilation (separable min/max), opening/closing, the largest 4-connected
//! component, hole filling, and the IoU used to compare masks.

use std::collections::VecDeque;

use crate::buffer::{neighbours4, GrayImage, Image};

/// A binary mask (`true` = person).
pub type BinaryMask = Image<bool>;

/// Thresholds a soft mask: `m > t`.
pub fn threshold(mask: &GrayImage, t: f32) -> BinaryMask {
    mask.map(|&v| v > t)
}

/// A binary mask as 0/1 floats.
pub fn to_gray(mask: &BinaryMask) -> GrayImage {
    mask.map(|&b| if b { 1.0 } else { 0.0 })
}

/// One separable pass: each output is the OR (`dilate`) or AND (erode) over a `2r+1` window along rows then
/// columns. Pixels outside count as background for dilation and as foreground for erosion (so borders do not eat
/// a person who touches the frame edge).
fn square_filter(mask: &BinaryMask, r: usize, dilate: bool) -> BinaryMask {
    if r == 0 || mask.data.is_empty() {
        return mask.clone();
    }
    let (w, h) = (mask.width, mask.height);
    let pass = |src: &BinaryMask, horizontal: bool| -> BinaryMask {
        let mut out = src.clone();
        let (n, lines) = if horizontal { (w, h) } else { (h, w) };
        let idx = |line: usize, i: usize| if horizontal { line * w + i } else { i * w + line };
        let mut prefix = vec![0usize; n + 1];
        for line in 0..lines {
            // Prefix counts of "set" pixels along the line: a window is all-set / any-set in O(1).
            for i in 0..n {
                prefix[i + 1] = prefix[i] + src.data[idx(line, i)] as usize;
            }
            for i in 0..n {
                let lo = i.saturating_sub(r);
                let hi = (i + r + 1).min(n);
                let count = prefix[hi] - prefix[lo];
                out.data[idx(line, i)] = if dilate { count > 0 } else { count == hi - lo };
            }
        }
        out
    };
    pass(&pass(mask, true), false)
}

/// Dilation by a `(2r+1)^2` square.
pub fn dilate(mask: &BinaryMask, r: usize) -> BinaryMask {
    square_filter(mask, r, true)
}

/// Erosion by a `(2r+1)^2` square.
pub fn erode(mask: &BinaryMask, r: usize) -> BinaryMask {
    square_filter(mask, r, false)
}

/// Opening (erode then dilate): removes specks narrower than `2r+1`.
pub fn open(mask: &BinaryMask, r: usize) -> BinaryMask {
    dilate(&erode(mask, r), r)
}

/// Closing (dilate then erode): fills gaps narrower than `2r+1`.
pub fn close(mask: &BinaryMask, r: usize) -> BinaryMask {
    erode(&dilate(mask, r), r)
}

/// Keeps only the largest 4-connected foreground component (empty stays empty).
pub fn largest_component(mask: &BinaryMask) -> BinaryMask {
    let (w, h) = (mask.width, mask.height);
    let mut label = vec![0u32; w * h];
    let mut best = (0u32, 0usize);
    let mut next = 0u32;
    let mut queue = VecDeque::new();
    for start in 0..w * h {
        if !mask.data[start] || label[start] != 0 {
            continue;
        }
        next += 1;
        label[start] = next;
        queue.push_back(start);
        let mut size = 0;
        while let Some(p) = queue.pop_front() {
            size += 1;
            for q in neighbours4(p, w, h) {
                if mask.data[q] && label[q] == 0 {
                    label[q] = next;
                    queue.push_back(q);
                }
            }
        }
        if size > best.1 {
            best = (next, size);
        }
    }
    Image { width: w, height: h, data: label.iter().map(|&l| l != 0 && l == best.0).collect() }
}

/// Fills holes: background pixels not 4-connected to the image border become foreground.
pub fn fill_holes(mask: &BinaryMask) -> BinaryMask {
    let (w, h) = (mask.width, mask.height);
    let mut outside = vec![false; w * h];
    let mut queue = VecDeque::new();
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            if (x == 0 || y == 0 || x + 1 == w || y + 1 == h) && !mask.data[p] {
                outside[p] = true;
                queue.push_back(p);
            }
        }
    }
    while let Some(p) = queue.pop_front() {
        for q in neighbours4(p, w, h) {
            if !mask.data[q] && !outside[q] {
                outside[q] = true;
                queue.push_back(q);
            }
        }
    }
    Image { width: w, height: h, data: outside.iter().map(|&o| !o).collect() }
}

/// Intersection over union of two binary masks of the same size; two empty masks give 1 (they agree).
pub fn iou(a: &BinaryMask, b: &BinaryMask) -> f32 {
    assert_eq!((a.width, a.height), (b.width, b.height), "iou of masks of different sizes");
    let (mut inter, mut uni) = (0usize, 0usize);
    for (&x, &y) in a.data.iter().zip(&b.data) {
        inter += (x && y) as usize;
        uni += (x || y) as usize;
    }
    if uni == 0 {
        1.0
    } else {
        inter as f32 / uni as f32
    }
}

/// IoU of two soft masks thresholded at 0.5.
pub fn iou_soft(a: &GrayImage, b: &GrayImage) -> f32 {
    iou(&threshold(a, 0.5), &threshold(b, 0.5))
}

/// Bilinear resize of a soft mask to `w x h` (pixel centres aligned).
pub fn resize_gray(src: &GrayImage, w: usize, h: usize) -> GrayImage {
    if (src.width, src.height) == (w, h) {
        return src.clone();
    }
    let (sx, sy) = (src.width as f32 / w as f32, src.height as f32 / h as f32);
    Image::from_fn(w, h, |c, r| {
        let x = ((c as f32 + 0.5) * sx).clamp(0.5, src.width as f32 - 0.5);
        let y = ((r as f32 + 0.5) * sy).clamp(0.5, src.height as f32 - 0.5);
        crate::buffer::sample_bilinear(src, x, y, 0.0)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(w: usize, h: usize, x0: usize, y0: usize, x1: usize, y1: usize) -> BinaryMask {
        Image::from_fn(w, h, |x, y| x >= x0 && x < x1 && y >= y0 && y < y1)
    }

    fn count(m: &BinaryMask) -> usize {
        m.data.iter().filter(|&&b| b).count()
    }

    #[test]
    fn dilate_erode_squares() {
        let m = rect(20, 20, 8, 8, 12, 12); // 4x4
        assert_eq!(count(&dilate(&m, 2)), 8 * 8);
        assert_eq!(count(&erode(&m, 1)), 2 * 2);
        assert_eq!(count(&erode(&m, 2)), 0);
        // Opening removes a single speck, keeps the square.
        let mut s = m.clone();
        s.set(1, 1, true);
        assert_eq!(open(&s, 1), m);
        // Closing fills a one-pixel gap.
        let mut g = rect(20, 20, 4, 4, 16, 16);
        g.set(10, 10, false);
        assert_eq!(count(&close(&g, 1)), 144);
        // A mask touching the border is not eroded from the border side.
        let full = rect(10, 10, 0, 0, 10, 10);
        assert_eq!(erode(&full, 2), full);
    }

    #[test]
    fn components_and_holes() {
        let mut m = rect(30, 30, 2, 2, 12, 12); // 100 px
        for x in 20..25 {
            m.set(x, 20, true); // 5 px
        }
        let l = largest_component(&m);
        assert_eq!(count(&l), 100);
        assert!(!*l.get(22, 20));
        let mut ring = rect(30, 30, 5, 5, 25, 25);
        for y in 10..15 {
            for x in 10..15 {
                ring.set(x, y, false);
            }
        }
        assert_eq!(count(&fill_holes(&ring)), 400);
        // A notch open to the border is not a hole.
        let notch = rect(10, 10, 0, 0, 10, 5);
        assert_eq!(fill_holes(&notch), notch);
        let empty = rect(5, 5, 0, 0, 0, 0);
        assert_eq!(count(&largest_component(&empty)), 0);
    }

    #[test]
    fn iou_closed_form() {
        let a = rect(10, 10, 0, 0, 4, 10); // 40
        let b = rect(10, 10, 2, 0, 6, 10); // 40, overlap 20
        assert!((iou(&a, &b) - 20.0 / 60.0).abs() < 1e-6);
        assert_eq!(iou(&a, &a), 1.0);
        let e = rect(10, 10, 0, 0, 0, 0);
        assert_eq!(iou(&e, &e), 1.0);
        assert_eq!(iou(&a, &e), 0.0);
    }

    #[test]
    fn resize_keeps_constant_and_edges() {
        let m = Image::from_fn(8, 8, |x, _| if x < 4 { 1.0 } else { 0.0 });
        let r = resize_gray(&m, 16, 16);
        assert_eq!(*r.get(0, 0), 1.0);
        assert_eq!(*r.get(15, 15), 0.0);
        assert!((r.get(7, 3) - 0.75).abs() < 1e-6);
        assert!(r.data.iter().all(|v| (0.0..=1.0).contains(v)));
    }
}
