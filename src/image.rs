//! Planes of `f32` samples placed in frame coordinates.
//!
//! A [`Plane`] is one channel over one [`Rect`]; reading is always by frame
//! coordinate, so the same code serves a whole frame, a tile with its halo or a
//! strip.

use half::slice::HalfFloatSliceExt;

use crate::geom::Rect;

/// `n` copies of `value`, every page written now.
///
/// `vec![0.0; n]` takes its memory zeroed from the allocator (`calloc`),
/// which leaves fresh pages untouched for the kernel to map on first access.
/// A buffer *read* before it is written (an accumulator, a `+=` sum) then
/// faults twice per page: the read maps the shared zero page, the write
/// replaces it, and the kernel flushes that page's TLB entry on every core
/// running the process, an interrupt to each (docs/performance.md, session
/// 46). Written here, each page faults once, on the write.
pub(crate) fn written<T: Copy>(value: T, n: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(n);
    v.resize(n, value);
    v
}

/// One channel of `f32` samples covering `rect`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    rect: Rect,
    data: Vec<f32>,
}

impl Plane {
    /// A plane filled with `value`.
    pub fn filled(rect: Rect, value: f32) -> Plane {
        Plane { rect, data: written(value, rect.area()) }
    }

    /// A plane from row-major samples; `None` when the length does not match.
    pub fn from_vec(rect: Rect, data: Vec<f32>) -> Option<Plane> {
        (data.len() == rect.area()).then_some(Plane { rect, data })
    }

    /// A plane computed pixel by pixel from frame coordinates.
    pub fn from_fn(rect: Rect, mut f: impl FnMut(i64, i64) -> f32) -> Plane {
        let mut data = Vec::with_capacity(rect.area());
        for y in rect.y0..rect.y1 {
            for x in rect.x0..rect.x1 {
                data.push(f(x, y));
            }
        }
        Plane { rect, data }
    }

    /// The rectangle this plane covers.
    pub fn rect(&self) -> Rect {
        self.rect
    }

    /// All samples, row-major.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// All samples, row-major, mutable.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Consume into the sample vector.
    pub fn into_vec(self) -> Vec<f32> {
        self.data
    }

    #[inline(always)]
    fn index(&self, x: i64, y: i64) -> usize {
        debug_assert!(self.rect.contains(x, y), "({x},{y}) outside {:?}", self.rect);
        (y - self.rect.y0) as usize * self.rect.width() + (x - self.rect.x0) as usize
    }

    /// The sample at frame pixel `(x, y)`, which must lie inside the plane.
    #[inline]
    pub fn get(&self, x: i64, y: i64) -> f32 {
        self.data[self.index(x, y)]
    }

    /// Set the sample at frame pixel `(x, y)`.
    #[inline]
    pub fn set(&mut self, x: i64, y: i64, v: f32) {
        let i = self.index(x, y);
        self.data[i] = v;
    }

    /// Samples of row `y` for columns `[x0, x1)`.
    #[inline(always)]
    pub fn row(&self, y: i64, x0: i64, x1: i64) -> &[f32] {
        let i = self.index(x0, y);
        &self.data[i..i + (x1 - x0) as usize]
    }

    /// Mutable samples of row `y` for columns `[x0, x1)`.
    #[inline(always)]
    pub fn row_mut(&mut self, y: i64, x0: i64, x1: i64) -> &mut [f32] {
        let i = self.index(x0, y);
        &mut self.data[i..i + (x1 - x0) as usize]
    }

    /// A copy of the samples inside `rect` (which must lie inside the plane).
    pub fn crop(&self, rect: Rect) -> Plane {
        assert!(self.rect.contains_rect(&rect), "crop {rect:?} outside {:?}", self.rect);
        let mut data = Vec::with_capacity(rect.area());
        for y in rect.y0..rect.y1 {
            data.extend_from_slice(self.row(y, rect.x0, rect.x1));
        }
        Plane { rect, data }
    }

    /// Copy `src` into this plane where they overlap.
    pub fn paste(&mut self, src: &Plane) {
        let r = self.rect.intersect(&src.rect);
        for y in r.y0..r.y1 {
            let s = src.index(r.x0, y);
            let d = self.index(r.x0, y);
            let w = r.width();
            self.data[d..d + w].copy_from_slice(&src.data[s..s + w]);
        }
    }

    /// Apply `f` to every sample.
    pub fn map(&self, f: impl Fn(f32) -> f32) -> Plane {
        Plane { rect: self.rect, data: self.data.iter().map(|&v| f(v)).collect() }
    }
}

/// One channel of half-float samples covering `rect`, row-major: a
/// [`Plane`] whose every sample is exactly a half float, in half the bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct HalfPlane {
    rect: Rect,
    data: Vec<half::f16>,
}

impl HalfPlane {
    /// The plane's samples as half floats, when every one of them is exactly
    /// a half float (the same bits once widened back); `None` otherwise.
    pub fn exact(plane: &Plane) -> Option<HalfPlane> {
        let mut data = vec![half::f16::ZERO; plane.data.len()];
        let mut back = [0.0f32; 256];
        // Chunk by chunk, so that a plane of other values stops at its first chunk.
        for (h, f) in data.chunks_mut(back.len()).zip(plane.data.chunks(back.len())) {
            h.convert_from_f32_slice(f);
            let back = &mut back[..h.len()];
            h.convert_to_f32_slice(back);
            if back.iter().zip(f).any(|(b, f)| b.to_bits() != f.to_bits()) {
                return None;
            }
        }
        Some(HalfPlane { rect: plane.rect, data })
    }

    /// The rectangle this plane covers.
    pub fn rect(&self) -> Rect {
        self.rect
    }

    /// Samples of row `y` for columns `[x0, x1)`.
    #[inline(always)]
    pub fn row(&self, y: i64, x0: i64, x1: i64) -> &[half::f16] {
        debug_assert!(self.rect.contains(x0, y) && x1 <= self.rect.x1, "row {y} [{x0}, {x1}) outside {:?}", self.rect);
        let i = (y - self.rect.y0) as usize * self.rect.width() + (x0 - self.rect.x0) as usize;
        &self.data[i..i + (x1 - x0) as usize]
    }
}

/// Samples of one channel in their storage type (carried channels keep their
/// exact bits; denoised channels are `F32`, or `F16` when asked).
#[derive(Clone, Debug, PartialEq)]
pub enum Samples {
    /// 16-bit floats.
    F16(Vec<half::f16>),
    /// 32-bit floats.
    F32(Vec<f32>),
    /// 32-bit unsigned integers.
    U32(Vec<u32>),
}

impl Samples {
    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            Samples::F16(v) => v.len(),
            Samples::F32(v) => v.len(),
            Samples::U32(v) => v.len(),
        }
    }

    /// True when there is no sample.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes per sample.
    pub fn bytes_per_sample(&self) -> usize {
        match self {
            Samples::F16(_) => 2,
            _ => 4,
        }
    }

    /// The samples as `f32`.
    pub fn to_f32(&self) -> Vec<f32> {
        match self {
            Samples::F16(v) => {
                let mut out = vec![0.0f32; v.len()];
                v.convert_to_f32_slice(&mut out);
                out
            }
            Samples::F32(v) => v.clone(),
            Samples::U32(v) => v.iter().map(|&x| x as f32).collect(),
        }
    }

    /// `f32` samples rounded to half floats (vectorised where the CPU converts).
    pub fn half_from_f32(samples: &[f32]) -> Samples {
        let mut out = vec![half::f16::ZERO; samples.len()];
        out.convert_from_f32_slice(samples);
        Samples::F16(out)
    }

    /// An empty buffer of the same type with room for `n` samples.
    pub fn empty_like(&self, n: usize) -> Samples {
        match self {
            Samples::F16(_) => Samples::F16(Vec::with_capacity(n)),
            Samples::F32(_) => Samples::F32(Vec::with_capacity(n)),
            Samples::U32(_) => Samples::U32(Vec::with_capacity(n)),
        }
    }

    /// Append `other[range]` (same type).
    pub fn extend_from(&mut self, other: &Samples, range: std::ops::Range<usize>) {
        match (self, other) {
            (Samples::F16(a), Samples::F16(b)) => a.extend_from_slice(&b[range]),
            (Samples::F32(a), Samples::F32(b)) => a.extend_from_slice(&b[range]),
            (Samples::U32(a), Samples::U32(b)) => a.extend_from_slice(&b[range]),
            _ => panic!("extend_from: sample types differ"),
        }
    }
}

/// Consecutive full-width rows of one channel: samples over `rect`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelRows {
    /// The rows (and columns) covered.
    pub rect: Rect,
    /// The samples, `rect.area()` of them.
    pub samples: Samples,
}

impl ChannelRows {
    /// The rows as an `f32` plane; `f32` samples are moved, not copied.
    pub fn into_plane(self) -> Plane {
        let samples = match self.samples {
            Samples::F32(v) => v,
            other => other.to_f32(),
        };
        Plane::from_vec(self.rect, samples).expect("rows hold rect.area() samples")
    }

    /// The sub-range of rows `[y0, y1)` (full width).
    pub fn rows(&self, y0: i64, y1: i64) -> ChannelRows {
        let w = self.rect.width();
        let a = (y0 - self.rect.y0) as usize * w;
        let b = (y1 - self.rect.y0) as usize * w;
        let mut s = self.samples.empty_like(b - a);
        s.extend_from(&self.samples, a..b);
        ChannelRows { rect: Rect { y0, y1, ..self.rect }, samples: s }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane of exact half floats gives its halves, row by row; one
    /// sample that is not a half (anywhere, also past the first 256) gives none.
    #[test]
    fn half_planes_only_of_exact_halves() {
        let rect = Rect::from_origin_size(-2, 3, 31, 17);
        let exact = Plane::from_fn(rect, |x, y| half::f16::from_f32(0.37 * x as f32 - 1.1 * y as f32).to_f32());
        let h = HalfPlane::exact(&exact).expect("every sample is a half");
        assert_eq!(h.rect(), rect);
        for y in rect.y0..rect.y1 {
            let row: Vec<f32> = h.row(y, rect.x0 + 1, rect.x1).iter().map(|v| v.to_f32()).collect();
            assert_eq!(row, exact.row(y, rect.x0 + 1, rect.x1));
        }
        for (x, y) in [(rect.x0, rect.y0), (rect.x1 - 1, rect.y1 - 1)] {
            let mut p = exact.clone();
            p.set(x, y, p.get(x, y) + 1e-4);
            assert!(HalfPlane::exact(&p).is_none(), "({x},{y}) is not a half");
        }
    }
}
