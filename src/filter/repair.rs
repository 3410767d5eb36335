//! Repair of unusable input samples before filtering (docs/robustness.md).
//!
//! Renderers emit NaN and infinite samples (a buggy shader, a division by
//! zero), negative variances and absurd fireflies. Left alone, one such sample
//! turns every patch distance that touches it into NaN or infinity and can
//! blank or poison a whole neighbourhood of the output. The rule:
//!
//! * a value sample (colour, half buffer, layer, feature) is *usable* when it
//!   is finite and `|v| <= MAX_VALUE`; a variance sample when
//!   `0 <= v <= MAX_VARIANCE` (NaN fails both tests);
//! * an unusable sample is replaced, before any stage reads it, by the mean of
//!   the usable samples of the same plane in its 3×3 neighbourhood (clipped to
//!   the frame), or by `0` when there are none; the repaired frame is then
//!   filtered as any other, so the pixel's output is its filtered estimate;
//! * the bounds keep every intermediate finite: squared differences stay below
//!   `4e36`, and a distance that still overflows only makes a weight zero.
//!
//! The repair reads a 3×3 neighbourhood, so it adds [`REPAIR_RADIUS`] to the
//! halo; it reads only original samples, in a fixed order, so tiles and the
//! whole frame repair identically (SPEC §6).

use std::borrow::Cow;

use super::{Buffer, FrameInputs, VarianceSource};
use crate::geom::Rect;
use crate::image::Plane;

/// How far the repair of a sample reads.
pub const REPAIR_RADIUS: usize = 1;

/// Largest usable magnitude of a value sample.
pub const MAX_VALUE: f32 = 1e18;

/// Largest usable variance.
pub const MAX_VARIANCE: f32 = 1e30;

/// What a plane holds, which decides what is usable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleRole {
    /// Colour, half buffer, layer or feature values.
    Value,
    /// A variance (must be non-negative).
    Variance,
}

/// Whether the filter can use sample `v` as it is.
#[inline(always)]
pub fn usable(role: SampleRole, v: f32) -> bool {
    match role {
        SampleRole::Value => v.abs() <= MAX_VALUE,
        SampleRole::Variance => (0.0..=MAX_VARIANCE).contains(&v),
    }
}

/// Marks pixels of `rect` that had at least one sample repaired.
struct Mask {
    rect: Rect,
    hit: Vec<bool>,
}

impl Mask {
    fn mark(&mut self, x: i64, y: i64) {
        if self.rect.contains(x, y) {
            let i = (y - self.rect.y0) as usize * self.rect.width() + (x - self.rect.x0) as usize;
            self.hit[i] = true;
        }
    }
}

/// The plane with its unusable samples repaired, or `None` when all are usable.
fn repair_plane(p: &Plane, role: SampleRole, frame: Rect, mask: &mut Mask) -> Option<Plane> {
    if p.data().iter().all(|&v| usable(role, v)) {
        return None;
    }
    let r = p.rect();
    let clip = r.intersect(&frame);
    let mut out = p.clone();
    let w = r.width();
    for (i, &v) in p.data().iter().enumerate() {
        if usable(role, v) {
            continue;
        }
        let (x, y) = (r.x0 + (i % w) as i64, r.y0 + (i / w) as i64);
        let (mut sum, mut n) = (0.0f32, 0u32);
        for yy in (y - 1).max(clip.y0)..(y + 2).min(clip.y1) {
            for xx in (x - 1).max(clip.x0)..(x + 2).min(clip.x1) {
                let s = p.get(xx, yy);
                if usable(role, s) {
                    sum += s;
                    n += 1;
                }
            }
        }
        out.set(x, y, if n > 0 { sum / n as f32 } else { 0.0 });
        mask.mark(x, y);
    }
    Some(out)
}

/// Whether every sample of `inputs` inside `window` is usable.
fn all_usable(inputs: &FrameInputs, window: Rect) -> bool {
    // Each chunk's test without a branch per sample (`&`, not `&&`), so
    // that it compiles to vector compares.
    let chunk_ok = |c: &[f32], role| c.iter().fold(true, |ok, &v| ok & usable(role, v));
    let ok = |planes: &[Plane], role| {
        planes.iter().all(|p| {
            let r = window.intersect(&p.rect());
            (r.y0..r.y1).all(|y| p.row(y, r.x0, r.x1).chunks(256).all(|c| chunk_ok(c, role)))
        })
    };
    let buffer_ok = |b: &Buffer| {
        ok(&b.values, SampleRole::Value)
            && match &b.variance {
                VarianceSource::Sample(v) => ok(v, SampleRole::Variance),
                VarianceSource::Halves { a, b } => ok(a, SampleRole::Value) && ok(b, SampleRole::Value),
            }
    };
    buffer_ok(&inputs.colour)
        && inputs.layers.iter().all(buffer_ok)
        && inputs.features.iter().all(|f| {
            ok(&f.values, SampleRole::Value) && f.variance.as_deref().is_none_or(|v| ok(v, SampleRole::Variance))
        })
}

/// `inputs` inside `window` (the samples the stages read, and the repair's
/// own reach) with every unusable sample repaired: borrowed unchanged, whole,
/// when there are none there, else cropped to `window` and repaired; and the
/// number of pixels of `count_rect` that had a sample repaired. Samples
/// outside `window` are never read by the stages, so neither their
/// usability nor the crop changes a bit of the output.
pub fn repair_inputs(
    inputs: &FrameInputs,
    frame: Rect,
    window: Rect,
    count_rect: Rect,
) -> (Cow<'_, FrameInputs>, usize) {
    if all_usable(inputs, window) {
        return (Cow::Borrowed(inputs), 0);
    }
    // The window's samples, copied once; a plane with an unusable sample is
    // replaced by its repaired copy (the repair reads the original samples).
    let mut fixed = inputs.crop(window);
    let mut mask = Mask { rect: count_rect, hit: vec![false; count_rect.area()] };
    let mut repair = |v: &mut [Plane], role: SampleRole| {
        for p in v {
            if let Some(r) = repair_plane(p, role, frame, &mut mask) {
                *p = r;
            }
        }
    };
    for b in std::iter::once(&mut fixed.colour).chain(fixed.layers.iter_mut()) {
        repair(&mut b.values, SampleRole::Value);
        match &mut b.variance {
            VarianceSource::Sample(v) => repair(v, SampleRole::Variance),
            VarianceSource::Halves { a, b } => {
                repair(a, SampleRole::Value);
                repair(b, SampleRole::Value);
            }
        }
    }
    for f in &mut fixed.features {
        repair(&mut f.values, SampleRole::Value);
        if let Some(v) = f.variance.as_deref_mut() {
            repair(v, SampleRole::Variance);
        }
    }
    let repaired = mask.hit.iter().filter(|&&h| h).count();
    (Cow::Owned(fixed), repaired)
}

#[cfg(test)]
mod tests {
    use super::super::Feature;
    use super::*;

    /// Inputs over `rect`: one colour channel with its sample variance and
    /// a one-channel feature, each sample from `f(plane, x, y)`.
    fn inputs(rect: Rect, f: impl Fn(usize, i64, i64) -> f32) -> FrameInputs {
        let plane = |i: usize| Plane::from_fn(rect, |x, y| f(i, x, y));
        FrameInputs {
            colour: Buffer {
                name: "beauty".into(),
                values: vec![plane(0)],
                variance: VarianceSource::Sample(vec![plane(1)]),
            },
            features: vec![Feature { name: "Z".into(), values: vec![plane(2)], variance: None }],
            layers: Vec::new(),
        }
    }

    /// Only the window's samples decide: an unusable sample outside it
    /// leaves the inputs borrowed whole; one inside gives the window's
    /// samples, cropped, with that sample repaired from its neighbours and
    /// its pixel counted.
    #[test]
    fn only_the_window_is_scanned_and_repaired() {
        let frame = Rect::from_origin_size(0, 0, 40, 30);
        let window = Rect::from_origin_size(10, 5, 12, 8);
        let bad = |at: (i64, i64)| {
            inputs(frame, move |i, x, y| match (i, (x, y) == at) {
                (1, true) => -1.0,
                (1, false) => 0.5,
                _ => (x + 2 * y) as f32,
            })
        };
        let outside = bad((9, 5));
        let (got, n) = repair_inputs(&outside, frame, window, window);
        assert!(matches!(got, Cow::Borrowed(_)) && n == 0, "a bad sample outside the window");
        let inside = bad((10, 5));
        let (got, n) = repair_inputs(&inside, frame, window, window);
        let Cow::Owned(fixed) = got else { panic!("a bad sample inside the window was not repaired") };
        assert_eq!(n, 1);
        let var = &fixed.colour.variance.planes()[0];
        assert_eq!(var.rect(), window, "the repaired inputs are the window's");
        // The mean of its usable neighbours inside the window (the 3x3
        // neighbourhood clipped to the crop; never read by a stage there).
        assert_eq!(var.get(10, 5), 0.5);
        assert_eq!(fixed.colour.values[0].get(11, 6), inside.colour.values[0].get(11, 6));
    }
}
