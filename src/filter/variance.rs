//! Variance of the mean (SPEC §1): from a sample-variance buffer or from two
//! half buffers, and the variance prefilter `v' = max(v, box_rho(v))`.

use std::borrow::Cow;

use super::kernels::box_mean;
use crate::geom::Rect;
use crate::image::Plane;

/// Where the variance of the mean of a buffer comes from.
#[derive(Clone, Debug)]
pub enum VarianceSource {
    /// The renderer's per-pixel variance of the mean, one plane per channel.
    Sample(Vec<Plane>),
    /// Two half buffers rendered with independent seeds: `v = (A - B)^2 / 4`.
    Halves {
        /// First half buffer, one plane per channel.
        a: Vec<Plane>,
        /// Second half buffer, one plane per channel.
        b: Vec<Plane>,
    },
}

impl VarianceSource {
    /// The raw variance of channel `c` on `rect` (which the source must cover).
    pub fn raw(&self, c: usize, rect: Rect) -> Plane {
        match self.raw_covering(c, rect) {
            Cow::Borrowed(p) => p.crop(rect),
            Cow::Owned(p) => p,
        }
    }

    /// The raw variance of channel `c` on at least `rect`: a sample variance's
    /// own plane, borrowed whole (no copy), or the half buffers' difference
    /// computed on `rect`.
    fn raw_covering(&self, c: usize, rect: Rect) -> Cow<'_, Plane> {
        match self {
            VarianceSource::Sample(v) => {
                assert!(v[c].rect().contains_rect(&rect), "variance {:?} does not cover {rect:?}", v[c].rect());
                Cow::Borrowed(&v[c])
            }
            VarianceSource::Halves { a, b } => {
                let (a, b) = (&a[c], &b[c]);
                Cow::Owned(Plane::from_fn(rect, |x, y| {
                    let d = a.get(x, y) - b.get(x, y);
                    (d * d) * 0.25
                }))
            }
        }
    }

    /// The planes this source reads (for coverage checks).
    pub fn planes(&self) -> Vec<&Plane> {
        match self {
            VarianceSource::Sample(v) => v.iter().collect(),
            VarianceSource::Halves { a, b } => a.iter().chain(b.iter()).collect(),
        }
    }

    /// Short name for logs and reports.
    pub fn kind(&self) -> &'static str {
        match self {
            VarianceSource::Sample(_) => "sample variance",
            VarianceSource::Halves { .. } => "half-buffer difference",
        }
    }
}

/// The variance prefilter `max(v, box_rho(v))` evaluated on `target`.
///
/// `raw` must cover `(target ⊕ rho) ∩ frame`; the box is clipped to the frame.
/// `rho = 0` returns the raw variance unchanged.
pub fn prefilter(raw: &Plane, frame: Rect, rho: usize, target: Rect) -> Plane {
    if rho == 0 {
        return raw.crop(target);
    }
    let mut out = vec![0.0f32; target.area()];
    let mut scratch = Vec::new();
    box_mean(raw.data(), raw.rect(), frame, rho, target, &mut out, &mut scratch);
    let mut plane = Plane::from_vec(target, out).expect("target-sized buffer");
    for y in target.y0..target.y1 {
        let v = raw.row(y, target.x0, target.x1);
        for (b, &v) in plane.row_mut(y, target.x0, target.x1).iter_mut().zip(v) {
            *b = if v > *b { v } else { *b };
        }
    }
    plane
}

/// Raw variance of every channel on `(target ⊕ rho) ∩ frame`, prefiltered onto `target`.
pub fn prefiltered(src: &VarianceSource, channels: usize, frame: Rect, rho: usize, target: Rect) -> Vec<Plane> {
    let raw_rect = target.expand(rho).intersect(&frame);
    (0..channels).map(|c| prefilter(&src.raw_covering(c, raw_rect), frame, rho, target)).collect()
}
