//! Feature guides for joint NL-means (SPEC §3): feature prefiltering with the
//! colour NL-means applied to the feature itself, the squared gradient
//! `G(p)`, and the per-pixel denominators of the feature distance.

use super::kernels::log2_distance_scale;
use super::nlmeans::{GuideFeature, Job, NlmSettings, nlmeans};
use super::variance;
use crate::geom::Rect;
use crate::image::Plane;

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
pub fn squared_gradient(values: &[Plane], frame: Rect, target: Rect) -> Plane {
    let mut g = Plane::filled(target, 0.0);
    for fv in values {
        for y in target.y0..target.y1 {
            for x in target.x0..target.x1 {
                let c = fv.get(x, y);
                let side = |xx: i64, yy: i64| -> Option<f32> {
                    frame.contains(xx, yy).then(|| {
                        let d = (c - fv.get(xx, yy)) * 0.5;
                        d * d
                    })
                };
                let pair = |a: Option<f32>, b: Option<f32>| match (a, b) {
                    (Some(a), Some(b)) => {
                        if b < a {
                            b
                        } else {
                            a
                        }
                    }
                    (Some(a), None) | (None, Some(a)) => a,
                    (None, None) => 0.0,
                };
                let h = pair(side(x - 1, y), side(x + 1, y));
                let v = pair(side(x, y - 1), side(x, y + 1));
                let sum = g.get(x, y) + (h + v);
                g.set(x, y, sum);
            }
        }
    }
    g
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
    let values: Vec<Plane> = match (&var_src, s.prefilter) {
        (Some(src), Some(ps)) => {
            let pre_rect = guide_rect.expand(ps.radius()).intersect(&frame);
            let var_pre = variance::prefiltered(src, n, frame, s.variance_prefilter_radius, pre_rect);
            let job = Job { values: feature.values.iter().collect(), variance: var_pre.iter().collect() };
            nlmeans(&[job], &[], frame, guide_rect, &ps).pop().expect("one job")
        }
        _ => feature.values.iter().map(|p| p.crop(guide_rect)).collect(),
    };
    let variance = match (&var_src, s.use_variance && has_var) {
        (Some(src), true) => Some(variance::prefiltered(src, n, frame, s.variance_prefilter_radius, guide_rect)),
        _ => None,
    };
    let grad = squared_gradient(&values, frame, den_rect);
    let kf2 = s.feature_strength * s.feature_strength;
    // The channel mean and `-log2(e)` of the weight's argument (see `nlmeans`).
    let scale = log2_distance_scale(n);
    // Without a variance the denominator is the same for every channel: one plane.
    let planes = if variance.is_some() { n } else { 1 };
    let inv_den = (0..planes)
        .map(|c| {
            Plane::from_fn(den_rect, |x, y| {
                let mut m = s.tau;
                let g = grad.get(x, y);
                if g > m {
                    m = g;
                }
                if let Some(v) = &variance {
                    let v = v[c].get(x, y);
                    if v > m {
                        m = v;
                    }
                }
                scale / (kf2 * m)
            })
        })
        .collect();
    GuideFeature { values, variance, inv_den }
}
