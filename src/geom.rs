//! Pure geometry in frame coordinates: rectangles, clipping and expansion.
//!
//! Every coordinate in the crate is a *frame* coordinate (the EXR data window's
//! coordinate system, origin possibly non-zero or negative). A tile or a strip is
//! just a [`Rect`] inside the frame; nothing in the filter ever sees tile-local
//! coordinates, which is what makes tiled and whole-frame filtering identical.

/// A half-open rectangle `[x0, x1) × [y0, y1)` in frame coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Rect {
    /// Left column (inclusive).
    pub x0: i64,
    /// Top row (inclusive).
    pub y0: i64,
    /// Right column (exclusive).
    pub x1: i64,
    /// Bottom row (exclusive).
    pub y1: i64,
}

impl Rect {
    /// The empty rectangle at the origin.
    pub const EMPTY: Rect = Rect { x0: 0, y0: 0, x1: 0, y1: 0 };

    /// A rectangle from its origin and size.
    pub fn from_origin_size(x: i64, y: i64, width: usize, height: usize) -> Rect {
        Rect { x0: x, y0: y, x1: x + width as i64, y1: y + height as i64 }
    }

    /// Width in pixels (0 when empty).
    pub fn width(&self) -> usize {
        (self.x1 - self.x0).max(0) as usize
    }

    /// Height in pixels (0 when empty).
    pub fn height(&self) -> usize {
        (self.y1 - self.y0).max(0) as usize
    }

    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width() * self.height()
    }

    /// True when the rectangle holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.x1 <= self.x0 || self.y1 <= self.y0
    }

    /// The rectangle grown by `radius` pixels on every side.
    pub fn expand(&self, radius: usize) -> Rect {
        let r = radius as i64;
        Rect { x0: self.x0 - r, y0: self.y0 - r, x1: self.x1 + r, y1: self.y1 + r }
    }

    /// The rectangle moved by `(dx, dy)`.
    pub fn translate(&self, dx: i64, dy: i64) -> Rect {
        Rect { x0: self.x0 + dx, y0: self.y0 + dy, x1: self.x1 + dx, y1: self.y1 + dy }
    }

    /// Intersection (possibly empty).
    pub fn intersect(&self, other: &Rect) -> Rect {
        Rect {
            x0: self.x0.max(other.x0),
            y0: self.y0.max(other.y0),
            x1: self.x1.min(other.x1),
            y1: self.y1.min(other.y1),
        }
    }

    /// True when `other` lies inside `self` (an empty `other` always does).
    pub fn contains_rect(&self, other: &Rect) -> bool {
        other.is_empty() || (other.x0 >= self.x0 && other.y0 >= self.y0 && other.x1 <= self.x1 && other.y1 <= self.y1)
    }

    /// True when pixel `(x, y)` lies inside.
    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }

    /// The pixels `s` with `s` and `s + (dx, dy)` both inside `self`:
    /// `self ∩ (self − n)`. This is the set on which a search offset is defined.
    pub fn valid_for_offset(&self, dx: i64, dy: i64) -> Rect {
        self.intersect(&self.translate(-dx, -dy))
    }

    /// Cut the rectangle into row bands of at most `rows` rows (top to bottom).
    pub fn row_bands(&self, rows: usize) -> Vec<Rect> {
        let rows = rows.max(1) as i64;
        let mut out = Vec::new();
        let mut y = self.y0;
        while y < self.y1 {
            let y1 = (y + rows).min(self.y1);
            out.push(Rect { x0: self.x0, y0: y, x1: self.x1, y1 });
            y = y1;
        }
        out
    }

    /// Cut the rectangle into tiles of at most `w × h` (row-major order).
    pub fn tiles(&self, w: usize, h: usize) -> Vec<Rect> {
        let (w, h) = (w.max(1) as i64, h.max(1) as i64);
        let mut out = Vec::new();
        let mut y = self.y0;
        while y < self.y1 {
            let y1 = (y + h).min(self.y1);
            let mut x = self.x0;
            while x < self.x1 {
                let x1 = (x + w).min(self.x1);
                out.push(Rect { x0: x, y0: y, x1, y1 });
                x = x1;
            }
            y = y1;
        }
        out
    }
}

/// The size cutting `total` into as few parts of at most `size` as possible,
/// all of (nearly) equal size: `ceil(total / ceil(total / size))`.
pub fn even(total: usize, size: usize) -> usize {
    let (total, size) = (total.max(1), size.max(1));
    total.div_ceil(total.div_ceil(size))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn valid_for_offset_is_frame_minus_shift() {
        let f = Rect::from_origin_size(-3, 2, 10, 5);
        let v = f.valid_for_offset(2, -1);
        assert_eq!(v, Rect { x0: -3, y0: 3, x1: 5, y1: 7 });
        for y in f.y0..f.y1 {
            for x in f.x0..f.x1 {
                assert_eq!(v.contains(x, y), f.contains(x + 2, y - 1));
            }
        }
    }

    #[test]
    fn tiles_cover_exactly_once() {
        let f = Rect::from_origin_size(5, -7, 13, 9);
        let tiles = f.tiles(4, 3);
        let mut count = vec![0u8; f.area()];
        for t in &tiles {
            assert!(f.contains_rect(t));
            for y in t.y0..t.y1 {
                for x in t.x0..t.x1 {
                    count[((y - f.y0) as usize) * f.width() + (x - f.x0) as usize] += 1;
                }
            }
        }
        assert!(count.iter().all(|&c| c == 1));
        assert_eq!(f.row_bands(4).len(), 3);
    }
}
