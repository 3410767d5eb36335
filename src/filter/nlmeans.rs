//! The patchwise NL-means offset loop (SPEC §4): for every search offset, the
//! per-pixel distance, its patch box mean, the weight, the box mean of the
//! weights, and the weighted accumulation.
//!
//! The region to produce is cut into blocks that are filtered independently
//! (in parallel with rayon); every value is a function of frame coordinates
//! only, so the block grid never changes a bit of the result.

use rayon::prelude::*;

use super::kernels::{accumulate_colour_distance, accumulate_feature_distance, exp_neg_clamped};
use super::simd::{self, Tier};
use crate::geom::Rect;
use crate::image::Plane;

/// Block size of the internal schedule (does not change values).
const BLOCK_W: usize = 256;
const BLOCK_H: usize = 64;

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
///
/// For each offset, three passes over the block, interleaved row by row so
/// that no block-sized intermediate exists:
///
/// 1. per row of `d_rect`: the per-pixel distance into a row buffer, then its
///    horizontal window sums into the ring `h1` (columns of `w_rect`);
/// 2. per row of `w_rect`, as soon as its window of `h1` rows is complete: the
///    vertical sum, scaled by the window's `1 / count` (the patch distance),
///    the weight, then its horizontal window sums into the ring `h2`
///    (columns of `acc_rect`);
/// 3. per row of `acc_rect`, as soon as its window of `h2` rows is complete:
///    the vertical sum, scaled (the mean weight), accumulated into the
///    numerators and the denominator.
///
/// A vertical window never reaches more than `2f` rows back, so each ring
/// holds `2f + 1` rows and stays in L1.
///
/// Every window sum starts from its first sample and adds the others in
/// increasing frame coordinate, over the window clipped to the offset's valid
/// rectangle (a function of the frame): the same operations for a pixel
/// whichever block, tile or lane computes it.
#[inline(always)]
fn filter_block_body(
    jobs: &[Job<'_>],
    features: &[GuideFeature],
    frame: Rect,
    block: Rect,
    s: &NlmSettings,
) -> Vec<Vec<Plane>> {
    let r = s.search_radius as i64;
    let f = s.patch_radius as i64;
    let k2 = s.strength * s.strength;
    let area = block.area();
    let bw = block.width();
    let mut num: Vec<Vec<Vec<f32>>> = jobs.iter().map(|j| vec![vec![0.0f32; area]; j.values.len()]).collect();
    let mut den: Vec<Vec<f32>> = jobs.iter().map(|_| vec![0.0f32; area]).collect();

    let outer = block.expand(2 * s.patch_radius);
    let mid = block.expand(s.patch_radius);
    // Ring buffers of the last 2f + 1 rows of horizontal sums: a vertical
    // window never reaches further back, and the rings stay in L1.
    let cap = 2 * s.patch_radius + 1;
    let mut h1 = vec![0.0f32; mid.width() * cap];
    let mut h2 = vec![0.0f32; bw * cap];
    let mut drow = vec![0.0f32; outer.width()];
    let mut wrow = vec![0.0f32; mid.width()];
    let mut wfeat = vec![0.0f32; mid.area()];
    let mut phi = Vec::with_capacity(mid.width());

    for dy in -r..=r {
        for dx in -r..=r {
            let valid = frame.valid_for_offset(dx, dy);
            let acc_rect = block.intersect(&valid);
            if acc_rect.is_empty() {
                continue;
            }
            let w_rect = mid.intersect(&valid);
            let d_rect = outer.intersect(&valid);
            let (dw, ww, aw) = (d_rect.width(), w_rect.width(), acc_rect.width());

            if !features.is_empty() {
                feature_weights(features, w_rect, dx, dy, &mut wfeat[..w_rect.area()], &mut phi);
            }

            for (j, job) in jobs.iter().enumerate() {
                // The three passes run interleaved, row by row: each weight row
                // as soon as its window of distance rows is complete, each
                // accumulated row as soon as its window of weight rows is.
                let inv_c = 1.0 / job.values.len() as f32;
                let (mut next_w, mut next_a) = (w_rect.y0, acc_rect.y0);
                let last_row = |y: i64| (y + f).min(valid.y1 - 1);
                for yd in d_rect.y0..d_rect.y1 {
                    // 1. A distance row and its horizontal sums.
                    let d = &mut drow[..dw];
                    d.fill(0.0);
                    for (u, v) in job.values.iter().zip(&job.variance) {
                        accumulate_colour_distance(
                            d,
                            u.row(yd, d_rect.x0, d_rect.x1),
                            u.row(yd + dy, d_rect.x0 + dx, d_rect.x1 + dx),
                            v.row(yd, d_rect.x0, d_rect.x1),
                            v.row(yd + dy, d_rect.x0 + dx, d_rect.x1 + dx),
                            s.alpha,
                            s.eps,
                            k2,
                        );
                    }
                    for a in d.iter_mut() {
                        *a *= inv_c;
                    }
                    let slot = (yd - d_rect.y0) as usize % cap;
                    window_sums_row(d, d_rect.x0, valid, f, w_rect.x0, &mut h1[slot * ww..(slot + 1) * ww]);
                    // 2. Patch distances, weights, and their horizontal sums.
                    while next_w < w_rect.y1 && last_row(next_w) <= yd {
                        let y = next_w;
                        next_w += 1;
                        let wr = &mut wrow[..ww];
                        vertical_means(&h1, cap, d_rect.y0, y, valid, f, w_rect.x0, wr);
                        if features.is_empty() {
                            for v in wr.iter_mut() {
                                *v = exp_neg_clamped(*v);
                            }
                        } else {
                            let ri = (y - w_rect.y0) as usize;
                            for (v, wf) in wr.iter_mut().zip(&wfeat[ri * ww..(ri + 1) * ww]) {
                                let wc = exp_neg_clamped(*v);
                                *v = if *wf < wc { *wf } else { wc };
                            }
                        }
                        let slot = (y - w_rect.y0) as usize % cap;
                        window_sums_row(wr, w_rect.x0, valid, f, acc_rect.x0, &mut h2[slot * aw..(slot + 1) * aw]);
                        // 3. Mean weights, accumulated.
                        while next_a < acc_rect.y1 && last_row(next_a) <= y {
                            let ya = next_a;
                            next_a += 1;
                            let wr = &mut wrow[..aw];
                            vertical_means(&h2, cap, w_rect.y0, ya, valid, f, acc_rect.x0, wr);
                            accumulate(&mut num[j], &mut den[j], &job.values, wr, (ya, dx, dy), acc_rect, block);
                        }
                    }
                }
                debug_assert!(next_w == w_rect.y1 && next_a == acc_rect.y1);
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

/// Horizontal window sums of one row: `dst[x] = sum of src over
/// [x - f, x + f] ∩ clip` for `x` from `dst_x0`, starting from the window's
/// first sample and adding the others in increasing x. `src` starts at
/// column `src_x0` and covers every window.
#[inline(always)]
fn window_sums_row(src: &[f32], src_x0: i64, clip: Rect, f: i64, dst_x0: i64, dst: &mut [f32]) {
    let dst_x1 = dst_x0 + dst.len() as i64;
    let inner_x0 = (clip.x0 + f).clamp(dst_x0, dst_x1);
    let inner_x1 = (clip.x1 - f).clamp(inner_x0, dst_x1);
    for x in (dst_x0..inner_x0).chain(inner_x1..dst_x1) {
        let a = ((x - f).max(clip.x0) - src_x0) as usize;
        let b = ((x + f).min(clip.x1 - 1) - src_x0) as usize;
        let mut acc = src[a];
        for v in &src[a + 1..=b] {
            acc += *v;
        }
        dst[(x - dst_x0) as usize] = acc;
    }
    let n = (inner_x1 - inner_x0) as usize;
    if n > 0 {
        let from = (inner_x0 - f - src_x0) as usize;
        let out = &mut dst[(inner_x0 - dst_x0) as usize..][..n];
        match f {
            1 => taps_sum::<3>(&src[from..from + n + 2], out),
            2 => taps_sum::<5>(&src[from..from + n + 4], out),
            3 => taps_sum::<7>(&src[from..from + n + 6], out),
            4 => taps_sum::<9>(&src[from..from + n + 8], out),
            _ => {
                for (i, o) in out.iter_mut().enumerate() {
                    let w = &src[from + i..=from + i + 2 * f as usize];
                    let mut acc = w[0];
                    for v in &w[1..] {
                        acc += *v;
                    }
                    *o = acc;
                }
            }
        }
    }
}

/// `out[i] = src[i] + src[i + 1] + ... + src[i + T - 1]`, in that order.
#[inline(always)]
fn taps_sum<const T: usize>(src: &[f32], out: &mut [f32]) {
    let n = out.len();
    let lanes: [&[f32]; T] = std::array::from_fn(|k| &src[k..k + n]);
    for (i, o) in out.iter_mut().enumerate() {
        let mut acc = lanes[0][i];
        for lane in &lanes[1..] {
            acc += lane[i];
        }
        *o = acc;
    }
}

/// Window means of row `y`: the vertical sums of the ring's rows over
/// `[y - f, y + f] ∩ clip` (row `k` of the ring is frame row `ring_y0 + k`),
/// scaled by `1 / count` of each clipped window (columns from `x0`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn vertical_means(ring: &[f32], cap: usize, ring_y0: i64, y: i64, clip: Rect, f: i64, x0: i64, out: &mut [f32]) {
    let (a, b) = ((y - f).max(clip.y0), (y + f).min(clip.y1 - 1));
    ring_column_sums(ring, out.len(), cap, (a - ring_y0) as usize, (b - a + 1) as usize, out);
    scale_by_count(out, x0, clip, f, (b - a + 1) as f32);
}

/// `out = rows[first] + rows[first + 1] + ...` (`count` rows, in increasing
/// order), where row `k` of width `w` is stored in slot `k % cap` of `ring`.
#[inline(always)]
fn ring_column_sums(ring: &[f32], w: usize, cap: usize, first: usize, count: usize, out: &mut [f32]) {
    let row = |i: usize| {
        let slot = (first + i) % cap;
        &ring[slot * w..(slot + 1) * w]
    };
    match count {
        3 => rows_sum::<3>(std::array::from_fn(row), out),
        5 => rows_sum::<5>(std::array::from_fn(row), out),
        7 => rows_sum::<7>(std::array::from_fn(row), out),
        9 => rows_sum::<9>(std::array::from_fn(row), out),
        _ => {
            out.copy_from_slice(row(0));
            for i in 1..count {
                for (o, v) in out.iter_mut().zip(row(i)) {
                    *o += *v;
                }
            }
        }
    }
}

/// Accumulate one row of mean weights `wr` (row `y` of `acc_rect`, offset
/// `(dx, dy)`) into the block's numerators and denominator.
#[inline(always)]
fn accumulate(
    num: &mut [Vec<f32>],
    den: &mut [f32],
    values: &[&Plane],
    wr: &[f32],
    (y, dx, dy): (i64, i64, i64),
    acc_rect: Rect,
    block: Rect,
) {
    let aw = acc_rect.width();
    let off = (y - block.y0) as usize * block.width() + (acc_rect.x0 - block.x0) as usize;
    let span = off..off + aw;
    let q = |c: usize| values[c].row(y + dy, acc_rect.x0 + dx, acc_rect.x1 + dx);
    if let [n0, n1, n2] = num {
        // The common case, in one pass: each weight is loaded once.
        let (n0, n1, n2) = (&mut n0[span.clone()], &mut n1[span.clone()], &mut n2[span.clone()]);
        let (q0, q1, q2, d) = (q(0), q(1), q(2), &mut den[span]);
        for i in 0..aw {
            let w = wr[i];
            d[i] += w;
            n0[i] += w * q0[i];
            n1[i] += w * q1[i];
            n2[i] += w * q2[i];
        }
    } else {
        for (d, w) in den[span.clone()].iter_mut().zip(wr.iter()) {
            *d += *w;
        }
        for (c, n) in num.iter_mut().enumerate() {
            for ((n, w), v) in n[span.clone()].iter_mut().zip(wr.iter()).zip(q(c)) {
                *n += *w * *v;
            }
        }
    }
}

#[inline(always)]
fn rows_sum<const T: usize>(rows: [&[f32]; T], out: &mut [f32]) {
    let n = out.len();
    let rows: [&[f32]; T] = std::array::from_fn(|k| &rows[k][..n]);
    for (i, o) in out.iter_mut().enumerate() {
        let mut acc = rows[0][i];
        for row in &rows[1..] {
            acc += row[i];
        }
        *o = acc;
    }
}

/// Turn window sums into means: multiply by `1 / (nx * ny)`, where `nx` is the
/// clipped window width of each column (from `x0`) and `ny` the row's window
/// height; the reciprocal is computed once per distinct count.
#[inline(always)]
fn scale_by_count(row: &mut [f32], x0: i64, clip: Rect, f: i64, ny: f32) {
    let x1 = x0 + row.len() as i64;
    let inner_x0 = (clip.x0 + f).clamp(x0, x1);
    let inner_x1 = (clip.x1 - f).clamp(inner_x0, x1);
    let inner = 1.0 / ((2 * f + 1) as f32 * ny);
    for v in &mut row[(inner_x0 - x0) as usize..(inner_x1 - x0) as usize] {
        *v *= inner;
    }
    for x in (x0..inner_x0).chain(inner_x1..x1) {
        let nx = ((x + f).min(clip.x1 - 1) - (x - f).max(clip.x0) + 1) as f32;
        row[(x - x0) as usize] *= 1.0 / (nx * ny);
    }
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
