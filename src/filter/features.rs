//! Feature guides for joint NL-means (SPEC §3): feature prefiltering with the
//! colour NL-means applied to the feature itself, the squared gradient
//! `G(p)`, and the per-pixel denominators of the feature distance.

use super::kernels::log2_distance_scale;
use super::nlmeans::{GuideFeature, Job, NlmSettings, nlmeans};
use super::{simd, variance};
use crate::geom::Rect;
use crate::image::{HalfPlane, Plane};

/// One feature buffer (normal, albedo, depth, ...).
#[derive(Clone, Debug)]
pub struct Feature {
    /// Name shown in logs (`albedo`, `N`, `Z`, ...).
    pub name: String,
    /// One plane per channel.
    pub values: Vec<Plane>,
    /// Variance of the mean of each channel, when the renderer wrote it.
    pub variance: Option<Vec<Plane>>,
}

/// The squared gradient `G(p) = sum_c min(gL^2, gR^2) + min(gU^2, gD^2)` on
/// `target`, with `gL = (F(p) - F(p - x)) / 2` and likewise for R, U, D.
///
/// Border rule: a one-sided difference whose neighbour lies outside the frame
/// is missing and the other side is used alone; with both missing (a frame one
/// pixel wide or tall) that axis contributes 0. `values` must cover
/// `(target ⊕ 1) ∩ frame`.
///
/// Row by row: the columns with both horizontal neighbours in the frame in
/// one loop over slices (vectorised), the frame's first and last columns by
/// `gradient_at`. Every pixel gets the same expression either way.
pub fn squared_gradient(values: &[Plane], frame: Rect, target: Rect) -> Plane {
    let mut g = Plane::filled(target, 0.0);
    // Columns whose left and right neighbours both lie in the frame.
    let ix0 = (frame.x0 + 1).max(target.x0);
    let ix1 = (frame.x1 - 1).min(target.x1).max(ix0);
    for fv in values {
        for y in target.y0..target.y1 {
            for x in (target.x0..ix0).chain(ix1..target.x1) {
                let sum = g.get(x, y) + gradient_at(fv, frame, x, y);
                g.set(x, y, sum);
            }
            if ix0 == ix1 {
                continue;
            }
            let (c, l, r) = (fv.row(y, ix0, ix1), fv.row(y, ix0 - 1, ix1 - 1), fv.row(y, ix0 + 1, ix1 + 1));
            let up = (y > frame.y0).then(|| fv.row(y - 1, ix0, ix1));
            let down = (y + 1 < frame.y1).then(|| fv.row(y + 1, ix0, ix1));
            let out = g.row_mut(y, ix0, ix1);
            let n = out.len();
            let (c, l, r) = (&c[..n], &l[..n], &r[..n]);
            let h = |i: usize| side_min(half_square(c[i], l[i]), half_square(c[i], r[i]));
            // One loop per case of vertical neighbours, so that each is branch-free.
            match (up, down) {
                (Some(u), Some(d)) => {
                    let (u, d) = (&u[..n], &d[..n]);
                    add_rows(out, |i| h(i) + side_min(half_square(c[i], u[i]), half_square(c[i], d[i])));
                }
                (Some(a), None) | (None, Some(a)) => {
                    let a = &a[..n];
                    add_rows(out, |i| h(i) + half_square(c[i], a[i]));
                }
                (None, None) => add_rows(out, |i| h(i) + 0.0),
            }
        }
    }
    g
}

/// `out[i] = out[i] + term(i)` for every sample of the row.
#[inline(always)]
fn add_rows(out: &mut [f32], term: impl Fn(usize) -> f32) {
    for (i, o) in out.iter_mut().enumerate() {
        *o += term(i);
    }
}

/// `((c - n) / 2)^2`, one side's squared difference.
#[inline(always)]
fn half_square(c: f32, n: f32) -> f32 {
    let d = (c - n) * 0.5;
    d * d
}

/// The smaller of a pixel's two sides on one axis (`a` unless `b < a`).
#[inline(always)]
fn side_min(a: f32, b: f32) -> f32 {
    if b < a { b } else { a }
}

/// One channel's `min(gL^2, gR^2) + min(gU^2, gD^2)` at `(x, y)`, with the
/// border rule of [`squared_gradient`].
fn gradient_at(fv: &Plane, frame: Rect, x: i64, y: i64) -> f32 {
    let c = fv.get(x, y);
    let side = |xx: i64, yy: i64| frame.contains(xx, yy).then(|| half_square(c, fv.get(xx, yy)));
    let pair = |a: Option<f32>, b: Option<f32>| match (a, b) {
        (Some(a), Some(b)) => side_min(a, b),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => 0.0,
    };
    pair(side(x - 1, y), side(x + 1, y)) + pair(side(x, y - 1), side(x, y + 1))
}

/// How a feature is turned into a guide.
#[derive(Clone, Copy, Debug)]
pub struct GuideSettings {
    /// Feature strength `kf`.
    pub feature_strength: f32,
    /// Gradient floor `tau`.
    pub tau: f32,
    /// Use the feature's variance in the distance when it has one.
    pub use_variance: bool,
    /// Variance prefilter radius applied to the feature variance.
    pub variance_prefilter_radius: usize,
    /// NL-means prefilter of the feature (applies when it has a variance); `None` = off.
    pub prefilter: Option<NlmSettings>,
}

impl GuideSettings {
    /// Whether the prefilter runs for a feature with (`true`) or without variance.
    pub fn prefilters(&self, has_variance: bool) -> bool {
        has_variance && self.prefilter.is_some()
    }

    /// Whether the feature variance is read at all.
    pub fn reads_variance(&self, has_variance: bool) -> bool {
        has_variance && (self.use_variance || self.prefilters(true))
    }

    /// Radius read around the guide rectangle for the feature values.
    pub fn values_radius(&self, has_variance: bool) -> usize {
        if self.prefilters(has_variance) { self.prefilter.map_or(0, |p| p.radius()) } else { 0 }
    }

    /// Radius read around the guide rectangle for the raw feature variance.
    pub fn variance_radius(&self, has_variance: bool) -> usize {
        self.values_radius(has_variance) + self.variance_prefilter_radius
    }
}

/// Build the guide for one feature.
///
/// `guide_rect = (out ⊕ max(r + f, f + 1)) ∩ frame` is where prefiltered values
/// (and variance) are needed, `den_rect = (out ⊕ f) ∩ frame` where the
/// denominators are needed.
pub fn prepare(feature: &Feature, s: &GuideSettings, frame: Rect, guide_rect: Rect, den_rect: Rect) -> GuideFeature {
    let has_var = feature.variance.is_some();
    let n = feature.values.len();
    let var_src = feature.variance.clone().map(variance::VarianceSource::Sample);
    let use_variance = s.use_variance && has_var;
    let (values, variance): (Vec<Plane>, Option<Vec<Plane>>) = match (&var_src, s.prefilter) {
        (Some(src), Some(ps)) => {
            let pre_rect = guide_rect.expand(ps.radius()).intersect(&frame);
            let var_pre = variance::prefiltered(src, n, frame, s.variance_prefilter_radius, pre_rect);
            let job = Job { values: feature.values.iter().collect(), variance: var_pre.iter().collect() };
            let values = nlmeans(&[job], &[], frame, guide_rect, &ps).pop().expect("one job");
            // The prefiltered variance on `guide_rect` is this one's crop: a
            // pixel's box does not depend on the rectangle it is evaluated on.
            (values, use_variance.then(|| var_pre.iter().map(|p| p.crop(guide_rect)).collect()))
        }
        (src, _) => (
            feature.values.iter().map(|p| p.crop(guide_rect)).collect(),
            src.as_ref()
                .filter(|_| use_variance)
                .map(|src| variance::prefiltered(src, n, frame, s.variance_prefilter_radius, guide_rect)),
        ),
    };
    let grad = squared_gradient(&values, frame, den_rect);
    let kf2 = s.feature_strength * s.feature_strength;
    // The channel mean and `-log2(e)` of the weight's argument (see `nlmeans`).
    let scale = log2_distance_scale(n);
    // Without a variance the denominator is the same for every channel: one plane.
    let planes = if variance.is_some() { n } else { 1 };
    let inv_den = (0..planes)
        .map(|c| {
            let mut inv = Plane::filled(den_rect, 0.0);
            let (x0, x1) = (den_rect.x0, den_rect.x1);
            // `scale / (kf^2 max(tau, G, V))`, the maximum taken in this order.
            let floor = |g: f32| if g > s.tau { g } else { s.tau };
            for y in den_rect.y0..den_rect.y1 {
                let (g, out) = (grad.row(y, x0, x1), inv.row_mut(y, x0, x1));
                match &variance {
                    Some(v) => {
                        let v = &v[c].row(y, x0, x1)[..out.len()];
                        for ((o, &g), &v) in out.iter_mut().zip(g).zip(v) {
                            let m = floor(g);
                            *o = scale / (kf2 * if v > m { v } else { m });
                        }
                    }
                    None => {
                        for (o, &g) in out.iter_mut().zip(g) {
                            *o = scale / (kf2 * floor(g));
                        }
                    }
                }
            }
            inv
        })
        .collect();
    // Half floats for the square sums, where they are exact and the tier
    // reads them (features of 1 to 4 channels without variance, see
    // `nlmeans::pair_feature_row`).
    let wide = matches!(simd::current(), simd::Tier::Avx2 | simd::Tier::Avx512);
    let half = (variance.is_none() && n <= 4 && wide)
        .then(|| values.iter().map(HalfPlane::exact).collect::<Option<Vec<_>>>())
        .flatten();
    GuideFeature { values, variance, inv_den, half }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples with every kind of neighbour order, ties, a NaN and an infinity.
    fn plane(frame: Rect, seed: u32) -> Plane {
        Plane::from_fn(frame, |x, y| {
            let h = (x as u32).wrapping_mul(2_654_435_761) ^ (y as u32).wrapping_mul(40_503) ^ seed;
            match h % 23 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => 0.25,
                _ => (h % 1000) as f32 * 0.013 - 4.0,
            }
        })
    }

    /// The row loops give the bits of the per-pixel expression on every
    /// pixel, at the frame's borders and inside, for frames one pixel wide
    /// or tall and for targets that do not reach the frame's edges.
    #[test]
    fn squared_gradient_rows_match_the_per_pixel_expression() {
        let frames = [
            Rect::from_origin_size(-3, 5, 17, 9),
            Rect::from_origin_size(0, 0, 1, 6),
            Rect::from_origin_size(0, 0, 6, 1),
            Rect::from_origin_size(2, 2, 2, 2),
            Rect::from_origin_size(0, 0, 40, 3),
        ];
        for frame in frames {
            let values = [plane(frame, 1), plane(frame, 7)];
            let targets = [frame, Rect { x0: frame.x0 + 1, y0: frame.y0, x1: frame.x1 - 1, y1: frame.y1 }];
            for target in targets.into_iter().filter(|t| !t.is_empty()) {
                let g = squared_gradient(&values, frame, target);
                for y in target.y0..target.y1 {
                    for x in target.x0..target.x1 {
                        let want = values.iter().fold(0.0f32, |s, fv| s + gradient_at(fv, frame, x, y));
                        assert_eq!(g.get(x, y).to_bits(), want.to_bits(), "({x},{y}) in {frame:?}, target {target:?}");
                    }
                }
            }
        }
    }

    /// The guide's variance is the variance prefilter evaluated on the guide
    /// rectangle, bit for bit, whether or not the NL-means prefilter runs
    /// (which computes it on a larger rectangle and crops it), at the
    /// frame's edges and inside.
    #[test]
    fn the_guides_variance_is_the_prefilter_on_the_guide_rectangle() {
        let frame = Rect::from_origin_size(-4, 3, 40, 30);
        // Finite values and non-negative variances, as after the repair.
        let finite = |seed| {
            let p = plane(frame, seed);
            Plane::from_fn(frame, |x, y| {
                let v = p.get(x, y);
                if v.is_finite() { v.abs() } else { 0.5 }
            })
        };
        let feature = Feature {
            name: "N".into(),
            values: vec![finite(1), finite(2)],
            variance: Some(vec![finite(3), finite(4)]),
        };
        let src = variance::VarianceSource::Sample(feature.variance.clone().expect("a variance"));
        let prefilter = NlmSettings { search_radius: 2, patch_radius: 1, strength: 0.45, alpha: 1.0, eps: 1e-10 };
        for rho in [0, 1, 2] {
            for pre in [None, Some(prefilter)] {
                let s = GuideSettings {
                    feature_strength: 0.6,
                    tau: 1e-3,
                    use_variance: true,
                    variance_prefilter_radius: rho,
                    prefilter: pre,
                };
                for guide_rect in [frame, Rect::from_origin_size(0, 8, 20, 12), Rect::from_origin_size(-4, 20, 9, 13)] {
                    // The gradients read one pixel around the denominators.
                    let r = guide_rect;
                    let den_rect = Rect { x0: r.x0 + 1, y0: r.y0 + 1, x1: r.x1 - 1, y1: r.y1 - 1 };
                    let g = prepare(&feature, &s, frame, guide_rect, den_rect);
                    let want = variance::prefiltered(&src, 2, frame, rho, guide_rect);
                    let got = g.variance.expect("the guide reads its variance");
                    assert_eq!(got.len(), 2);
                    for (c, (a, b)) in got.iter().zip(&want).enumerate() {
                        assert_eq!(a.rect(), guide_rect, "rho {rho}, prefilter {pre:?}");
                        let bits = |p: &Plane| p.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                        assert_eq!(bits(a), bits(b), "channel {c}, rho {rho}, prefilter {pre:?}, {guide_rect:?}");
                    }
                }
            }
        }
    }
}
