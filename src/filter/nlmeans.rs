//! The patchwise NL-means offset loop (SPEC §4): for every search offset, the
//! per-pixel distance, its patch box mean, the weight, the box mean of the
//! weights, and the weighted accumulation.
//!
//! The region to produce is cut into blocks that are filtered independently
//! (in parallel with rayon); every value is a function of frame coordinates
//! only, so the block grid never changes a bit of the result.

use rayon::prelude::*;

use super::kernels::{accumulate_colour_distance, accumulate_feature_distance, box_mean, exp_neg_clamped};
use super::simd::{self, Tier};
use crate::geom::Rect;
use crate::image::Plane;

/// Block size of the internal schedule (does not change values).
const BLOCK_W: usize = 128;
const BLOCK_H: usize = 32;

/// Parameters of one NL-means pass.
#[derive(Clone, Copy, Debug)]
pub struct NlmSettings {
    /// Search radius `r`.
    pub search_radius: usize,
    /// Patch radius `f`.
    pub patch_radius: usize,
    /// Strength `k`.
    pub strength: f32,
    /// Variance cancellation `alpha`.
    pub alpha: f32,
    /// Denominator guard `eps`.
    pub eps: f32,
}

impl NlmSettings {
    /// How far around an output pixel this pass reads its inputs: `r + 2f`.
    pub fn radius(&self) -> usize {
        self.search_radius + 2 * self.patch_radius
    }
}

/// One set of channels to filter; its own values and variance give its colour weights.
pub struct Job<'a> {
    /// Channel values, covering `(out ⊕ (r + 2f)) ∩ frame`.
    pub values: Vec<&'a Plane>,
    /// Variance of the mean of each channel, same coverage.
    pub variance: Vec<&'a Plane>,
}

/// A guide feature, ready for the joint weight (SPEC §3).
pub struct GuideFeature {
    /// Feature channels (prefiltered if configured), covering `(out ⊕ max(r + f, f + 1)) ∩ frame`.
    pub values: Vec<Plane>,
    /// Variance of each channel, same coverage, when the feature has one.
    pub variance: Option<Vec<Plane>>,
    /// `1 / (kf^2 max(tau, V_c(p), G(p)))` per channel, covering `(out ⊕ f) ∩ frame`.
    pub inv_den: Vec<Plane>,
}

/// Filter every job on `out`; returns, per job, one plane per channel.
///
/// With `features`, each job's weight is `min(w_colour, w_feature)` where the
/// feature weight is shared by all jobs (layers share the feature weights).
pub fn nlmeans(
    jobs: &[Job<'_>],
    features: &[GuideFeature],
    frame: Rect,
    out: Rect,
    s: &NlmSettings,
) -> Vec<Vec<Plane>> {
    let blocks = out.tiles(BLOCK_W, BLOCK_H);
    let results: Vec<Vec<Vec<Plane>>> = blocks.par_iter().map(|b| filter_block(jobs, features, frame, *b, s)).collect();
    let mut outputs: Vec<Vec<Plane>> =
        jobs.iter().map(|j| j.values.iter().map(|_| Plane::filled(out, 0.0)).collect()).collect();
    for block in results {
        for (job_out, block_job) in outputs.iter_mut().zip(block) {
            for (plane, part) in job_out.iter_mut().zip(block_job) {
                plane.paste(&part);
            }
        }
    }
    outputs
}

/// Filter one block with the kernel compiled for the current [`simd::Tier`].
fn filter_block(
    jobs: &[Job<'_>],
    features: &[GuideFeature],
    frame: Rect,
    block: Rect,
    s: &NlmSettings,
) -> Vec<Vec<Plane>> {
    match simd::current() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `simd::current` returns AVX-512 only when the CPU has avx512f.
        Tier::Avx512 => unsafe { filter_block_avx512(jobs, features, frame, block, s) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `simd::current` returns AVX2 only when the CPU has avx2.
        Tier::Avx2 => unsafe { filter_block_avx2(jobs, features, frame, block, s) },
        _ => filter_block_body(jobs, features, frame, block, s),
    }
}

/// One wrapper per tier: the same body compiled with the tier's target feature.
macro_rules! tier_wrapper {
    ($name:ident, $feature:literal) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $feature)]
        fn $name(
            jobs: &[Job<'_>],
            features: &[GuideFeature],
            frame: Rect,
            block: Rect,
            s: &NlmSettings,
        ) -> Vec<Vec<Plane>> {
            filter_block_body(jobs, features, frame, block, s)
        }
    };
}

tier_wrapper!(filter_block_avx2, "avx2");
tier_wrapper!(filter_block_avx512, "avx512f");

/// The block kernel; inlined into each tier's wrapper so that it (and every
/// kernel it inlines) is compiled for that tier's instruction set.
#[inline(always)]
fn filter_block_body(
    jobs: &[Job<'_>],
    features: &[GuideFeature],
    frame: Rect,
    block: Rect,
    s: &NlmSettings,
) -> Vec<Vec<Plane>> {
    let r = s.search_radius as i64;
    let f = s.patch_radius;
    let k2 = s.strength * s.strength;
    let area = block.area();
    let mut num: Vec<Vec<Vec<f32>>> = jobs.iter().map(|j| vec![vec![0.0f32; area]; j.values.len()]).collect();
    let mut den: Vec<Vec<f32>> = jobs.iter().map(|_| vec![0.0f32; area]).collect();

    let cap_d = block.expand(2 * f).area();
    let cap_w = block.expand(f).area();
    let mut d2 = vec![0.0f32; cap_d];
    let mut dpatch = vec![0.0f32; cap_w];
    let mut wfeat = vec![0.0f32; cap_w];
    let mut wsum = vec![0.0f32; area];
    let mut scratch = Vec::with_capacity(cap_d);
    let mut phi = Vec::with_capacity(block.expand(f).width());

    for dy in -r..=r {
        for dx in -r..=r {
            let valid = frame.valid_for_offset(dx, dy);
            let acc_rect = block.intersect(&valid);
            if acc_rect.is_empty() {
                continue;
            }
            let w_rect = block.expand(f).intersect(&valid);
            let d_rect = block.expand(2 * f).intersect(&valid);

            if !features.is_empty() {
                feature_weights(features, w_rect, dx, dy, &mut wfeat[..w_rect.area()], &mut phi);
            }

            for (j, job) in jobs.iter().enumerate() {
                // Per-pixel distance on d_rect.
                let dw = d_rect.width();
                let d2 = &mut d2[..d_rect.area()];
                let inv_c = 1.0 / job.values.len() as f32;
                for (ri, y) in (d_rect.y0..d_rect.y1).enumerate() {
                    let acc = &mut d2[ri * dw..(ri + 1) * dw];
                    acc.fill(0.0);
                    for (u, v) in job.values.iter().zip(&job.variance) {
                        accumulate_colour_distance(
                            acc,
                            u.row(y, d_rect.x0, d_rect.x1),
                            u.row(y + dy, d_rect.x0 + dx, d_rect.x1 + dx),
                            v.row(y, d_rect.x0, d_rect.x1),
                            v.row(y + dy, d_rect.x0 + dx, d_rect.x1 + dx),
                            s.alpha,
                            s.eps,
                            k2,
                        );
                    }
                    for a in acc.iter_mut() {
                        *a *= inv_c;
                    }
                }
                // Patch distance and weight on w_rect.
                let dp = &mut dpatch[..w_rect.area()];
                box_mean(d2, d_rect, valid, f, w_rect, dp, &mut scratch);
                if features.is_empty() {
                    for v in dp.iter_mut() {
                        *v = exp_neg_clamped(*v);
                    }
                } else {
                    for (v, wf) in dp.iter_mut().zip(&wfeat[..w_rect.area()]) {
                        let wc = exp_neg_clamped(*v);
                        *v = if *wf < wc { *wf } else { wc };
                    }
                }
                // Mean weight of the patches covering each pixel, on acc_rect.
                let ws = &mut wsum[..acc_rect.area()];
                box_mean(dp, w_rect, valid, f, acc_rect, ws, &mut scratch);
                // Accumulate.
                let aw = acc_rect.width();
                let bw = block.width();
                for (ri, y) in (acc_rect.y0..acc_rect.y1).enumerate() {
                    let wrow = &ws[ri * aw..(ri + 1) * aw];
                    let off = (y - block.y0) as usize * bw + (acc_rect.x0 - block.x0) as usize;
                    let drow = &mut den[j][off..off + aw];
                    for (d, w) in drow.iter_mut().zip(wrow) {
                        *d += *w;
                    }
                    for (c, u) in job.values.iter().enumerate() {
                        let q = u.row(y + dy, acc_rect.x0 + dx, acc_rect.x1 + dx);
                        let nrow = &mut num[j][c][off..off + aw];
                        for ((n, w), v) in nrow.iter_mut().zip(wrow).zip(q) {
                            *n += *w * *v;
                        }
                    }
                }
            }
        }
    }

    num.into_iter()
        .zip(den)
        .map(|(chans, den)| {
            chans
                .into_iter()
                .map(|mut n| {
                    for (v, d) in n.iter_mut().zip(&den) {
                        *v /= *d;
                    }
                    Plane::from_vec(block, n).expect("block-sized buffer")
                })
                .collect()
        })
        .collect()
}

/// `w_f = exp(-max(0, max_j Phi_j^2))` on `rect` for offset `(dx, dy)`.
#[inline(always)]
fn feature_weights(features: &[GuideFeature], rect: Rect, dx: i64, dy: i64, out: &mut [f32], phi: &mut Vec<f32>) {
    let w = rect.width();
    phi.clear();
    phi.resize(w, 0.0);
    for (ri, y) in (rect.y0..rect.y1).enumerate() {
        let row = &mut out[ri * w..(ri + 1) * w];
        row.fill(0.0);
        for feat in features {
            phi.fill(0.0);
            for (c, fv) in feat.values.iter().enumerate() {
                let fp = fv.row(y, rect.x0, rect.x1);
                let fq = fv.row(y + dy, rect.x0 + dx, rect.x1 + dx);
                let var = feat
                    .variance
                    .as_ref()
                    .map(|v| (v[c].row(y, rect.x0, rect.x1), v[c].row(y + dy, rect.x0 + dx, rect.x1 + dx)));
                accumulate_feature_distance(phi, fp, fq, var, feat.inv_den[c].row(y, rect.x0, rect.x1));
            }
            let inv_c = 1.0 / feat.values.len() as f32;
            for (o, p) in row.iter_mut().zip(phi.iter()) {
                let v = *p * inv_c;
                // NaN-safe max: a NaN distance must not win over a finite one.
                if v > *o {
                    *o = v;
                }
            }
        }
        for o in row.iter_mut() {
            *o = exp_neg_clamped(*o);
        }
    }
}
