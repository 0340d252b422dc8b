//! The on-screen text overlay of the desktop window (frame time, backend, mode, live statistics).
//!
//! Text is laid out on the host into a small coverage mask ([`OverlayMask`]: one byte per pixel, [`PLATE`] for
//! the dark backing plate, [`INK`] for the letters) with a built-in 5x7 pixel font (upper case, digits and
//! punctuation; lower case is shown as upper case). The renderer uploads the mask only when the text changes and
//! blends it into the 8-bit image it presents (`shaders/encode.comp`), so the overlay is in the window but never
//! in the linear output that screenshots and `read_output` return.

/// Mask value: nothing drawn.
pub const CLEAR: u8 = 0;
/// Mask value: the dark plate behind the text (the presented colour is darkened).
pub const PLATE: u8 = 1;
/// Mask value: a letter pixel (drawn white).
pub const INK: u8 = 2;

/// Glyph cell size in font pixels (5x7 glyph, 1 column and 2 rows of spacing).
const CELL_W: usize = 6;
const CELL_H: usize = 9;
/// Margin around the text inside the plate, in font pixels.
const PAD: usize = 2;

/// A text overlay as a coverage mask anchored at the top-left corner of the image.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OverlayMask {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` values, row-major: [`CLEAR`], [`PLATE`] or [`INK`].
    pub data: Vec<u8>,
}

impl OverlayMask {
    /// Lays `lines` out at `scale` (1 = 5x7 pixel letters) within `max_width x max_height` pixels: lines that
    /// are too long are cut, lines that do not fit are dropped. Empty when there is nothing to show or no room.
    pub fn text(lines: &[String], max_width: usize, max_height: usize, scale: usize) -> Self {
        let s = scale.max(1);
        let fit_cols = (max_width / s).saturating_sub(2 * PAD) / CELL_W;
        let fit_rows = (max_height / s).saturating_sub(2 * PAD) / CELL_H;
        let lines: Vec<Vec<char>> = lines
            .iter()
            .take(fit_rows)
            .map(|l| l.chars().take(fit_cols).collect::<Vec<char>>())
            .filter(|l| !l.is_empty())
            .collect();
        let cols = lines.iter().map(Vec::len).max().unwrap_or(0);
        if cols == 0 {
            return Self::default();
        }
        let width = (cols * CELL_W + 2 * PAD) * s;
        let height = (lines.len() * CELL_H + 2 * PAD) * s;
        let mut data = vec![PLATE; width * height];
        for (row, line) in lines.iter().enumerate() {
            for (col, &ch) in line.iter().enumerate() {
                let bits = glyph(ch);
                for (gy, &bits_row) in bits.iter().enumerate() {
                    for gx in 0..5 {
                        if bits_row & (0x10 >> gx) == 0 {
                            continue;
                        }
                        let x0 = (PAD + col * CELL_W + gx) * s;
                        let y0 = (PAD + row * CELL_H + 1 + gy) * s;
                        for y in y0..y0 + s {
                            data[y * width + x0..y * width + x0 + s].fill(INK);
                        }
                    }
                }
            }
        }
        Self { width, height, data }
    }

    /// Is there anything to draw?
    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }
}

/// The 5x7 glyph of `c` (rows top to bottom, bit 4 = leftmost column). Lower case maps to upper case; characters
/// the font lacks show as `?`.
pub fn glyph(c: char) -> [u8; 7] {
    let c = c.to_ascii_uppercase();
    match c {
        ' ' => [0, 0, 0, 0, 0, 0, 0],
        '!' => [0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x04],
        '"' => [0x0A, 0x0A, 0, 0, 0, 0, 0],
        '#' => [0x0A, 0x1F, 0x0A, 0x0A, 0x1F, 0x0A, 0x00],
        '$' => [0x04, 0x0F, 0x14, 0x0E, 0x05, 0x1E, 0x04],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '&' => [0x0C, 0x12, 0x14, 0x08, 0x15, 0x12, 0x0D],
        '\'' | '`' => [0x04, 0x04, 0, 0, 0, 0, 0],
        '(' | '{' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' | '}' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '*' => [0x00, 0x04, 0x15, 0x0E, 0x15, 0x04, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        ',' => [0, 0, 0, 0, 0x06, 0x04, 0x08],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '.' => [0, 0, 0, 0, 0, 0x06, 0x06],
        '/' => [0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10],
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        ':' => [0, 0x06, 0x06, 0, 0x06, 0x06, 0],
        ';' => [0, 0x06, 0x06, 0, 0x06, 0x04, 0x08],
        '<' => [0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02],
        '=' => [0, 0, 0x1F, 0, 0x1F, 0, 0],
        '>' => [0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08],
        '?' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04],
        '@' => [0x0E, 0x11, 0x01, 0x0D, 0x15, 0x15, 0x0E],
        'A' => [0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '[' => [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E],
        '\\' => [0x10, 0x10, 0x08, 0x04, 0x02, 0x01, 0x01],
        ']' => [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E],
        '^' => [0x04, 0x0A, 0x11, 0, 0, 0, 0],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '|' => [0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        '~' => [0, 0, 0x08, 0x15, 0x02, 0, 0],
        '·' | '•' => [0, 0, 0, 0x0C, 0x0C, 0, 0],
        _ => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ink(m: &OverlayMask) -> usize {
        m.data.iter().filter(|&&v| v == INK).count()
    }

    #[test]
    fn layout_size_follows_the_longest_line_and_the_scale() {
        let lines = vec!["AB".to_string(), "1234".to_string()];
        let m = OverlayMask::text(&lines, 1000, 1000, 1);
        assert_eq!((m.width, m.height), (4 * CELL_W + 2 * PAD, 2 * CELL_H + 2 * PAD));
        let m2 = OverlayMask::text(&lines, 1000, 1000, 2);
        assert_eq!((m2.width, m2.height), (2 * m.width, 2 * m.height));
        // Every font pixel becomes a 2x2 block.
        assert_eq!(ink(&m2), 4 * ink(&m));
        assert!(m.data.iter().all(|&v| v == PLATE || v == INK));
    }

    #[test]
    fn ink_count_is_the_sum_of_the_glyph_bits() {
        let text = "12.5 MS";
        let m = OverlayMask::text(&[text.to_string()], 500, 100, 1);
        let bits: usize = text.chars().map(|c| glyph(c).iter().map(|r| r.count_ones() as usize).sum::<usize>()).sum();
        assert_eq!(ink(&m), bits);
        // A space draws nothing; lower case is drawn as upper case.
        assert_eq!(glyph(' '), [0; 7]);
        assert_eq!(glyph('m'), glyph('M'));
        // The letter 'L' occupies the left column and the bottom row of its cell.
        let l = OverlayMask::text(&["L".to_string()], 100, 100, 1);
        let at = |x: usize, y: usize| l.data[(PAD + 1 + y) * l.width + PAD + x];
        assert!((0..7).all(|y| at(0, y) == INK));
        assert!((0..5).all(|x| at(x, 6) == INK));
        assert_eq!(at(4, 0), PLATE);
    }

    #[test]
    fn long_text_is_cut_to_the_room_available() {
        let long = "X".repeat(500);
        let m = OverlayMask::text(&[long.clone(), long.clone(), long], 128, 30, 1);
        assert!(m.width <= 128 && m.height <= 30, "{}x{}", m.width, m.height);
        assert_eq!(m.width, (128 - 2 * PAD) / CELL_W * CELL_W + 2 * PAD);
        assert_eq!(m.height, 2 * CELL_H + 2 * PAD);
        assert!(OverlayMask::text(&["X".to_string()], 5, 5, 1).is_empty());
        assert!(OverlayMask::text(&[], 500, 500, 1).is_empty());
        // Unknown characters are drawn as '?', not skipped.
        let q = OverlayMask::text(&["\u{2603}".to_string()], 100, 100, 1);
        assert_eq!(ink(&q), glyph('?').iter().map(|r| r.count_ones() as usize).sum::<usize>());
    }
}
