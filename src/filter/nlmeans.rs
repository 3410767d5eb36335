//! The patchwise NL-means offset loop (SPEC §4): for every search offset, the
//! per-pixel distance, its patch box mean, the weight, the box mean of the
//! weights, and the weighted accumulation.
//!
//! The region to produce is cut into blocks that are filtered independently
//! (in parallel with rayon); every value is a function of frame coordinates
//! only, so the block grid never changes a bit of the result.

use rayon::prelude::*;

use super::column_sums::{ColumnBox, PushCase, Quantiser};
use super::kernels::{
    CHUNK, CHUNK_AVX512, FeatureRows, PRODUCTS_MAX, WeightSample, accumulate_colour_distance_pair, chunk, chunk_count,
    chunk_i32, chunk_mut, chunk_of, chunk_start, colour_distance_pair_rgb, cut, exp2_weight_scaled_lanes,
    feature_square_sum, feature_square_sum_any, fold_feature_products, fold_feature_term, fold_feature_term_any,
    lanes2, log2_distance_scale, rows_sum,
};
#[cfg(target_arch = "x86_64")]
use super::kernels::{
    EdgeLane, GuideRow, PAIR_GUIDE_CHANNELS_MAX, ProductLane, SideFactors, VarianceLane, clipped_push_avx512,
    edge_columns_avx512, feature_square_sum_half_avx2, feature_square_sum_half_avx512, fused_rgb_shifted_avx512,
    guide_pair_products_avx512, guide_variance_pair_avx512, weights_avx512, weights_factors_avx512,
};
use super::simd;
#[cfg(target_arch = "x86_64")]
use super::simd::Tier;
use crate::geom::{Rect, even};
use crate::image::{HalfPlane, Plane};

/// Largest block of the internal schedule (does not change values); a
/// region is cut into blocks of (nearly) equal size up to these. Taller
/// blocks recompute fewer border rows (a step's distance rows span the
/// block's rows plus `4f + dy`) but give the pool fewer tasks per band, and
/// a band's last blocks leave cores idle: 384 rows (one block per 1080p
/// tile) left more of two cores idle than it saved (session 12). 128 rows
/// cut a 360-row tile (1080p) into three blocks of 120: on the AMD Zen 5
/// machine of session 16, the full filter at 1080p on two threads ran 0.93x
/// the time of 192-row blocks (two of 180), with one thread and at 4K the
/// same time (docs/performance.md, session 16). [`block_rows`] chooses
/// [`BLOCK_H_TALL`] instead for one thread or wide tiles. Blocks are as wide as their
/// region (a tile, or the frame with `--tile-size 0`) up to 1024 columns:
/// where the engine plans wide tiles (`engine::budget::wide_tiles`),
/// blocks 960 wide instead of two of 480 set up half as many rows per
/// sample (0.93-0.94x the full filter's time on one thread, Zen 4,
/// session 39).
const BLOCK_W: usize = 1024;
const BLOCK_H: usize = 128;
/// The block height [`block_rows`] chooses for one thread, or for tiles
/// the engine plans wide (`engine::budget::wide_tiles`): one block per
/// 1080p tile, whose fewer border rows took 0.954-0.984x the time of
/// [`BLOCK_H`] on one thread on the Zen 4 of session 38. On two threads
/// with the wide tiles of session 41 (one per thread and band at 1080p,
/// two at 4K), the full filter from memory took 0.966x the time of
/// 480-wide tiles of 128-row blocks at 1080p (median of 86 rounds, level
/// in the session's second hour, and over 94 rounds in session 42), and
/// 0.96x that of wide tiles of 128-row blocks at 4K (median of 8 rounds;
/// docs/performance.md, session 41).
const BLOCK_H_TALL: usize = 384;

/// The kernel's block height on `threads` threads: 384 rows for one
/// thread, which no coarser grid can leave idle, or for the engine's
/// `wide` tiles (one or more per thread and band, so a band still gives
/// every thread a block), else 128. An internal schedule: the result is
/// the same bits at any height.
pub fn block_rows(threads: usize, wide: bool) -> usize {
    if threads <= 1 || wide { BLOCK_H_TALL } else { BLOCK_H }
}

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
    /// `-log2(e) / (channels kf^2 max(tau, V_c(p), G(p)))`, covering
    /// `(out ⊕ f) ∩ frame`: the factor of the weight argument of
    /// `kernels::exp2_weight`. One plane per channel with a variance; one
    /// plane shared by every channel without (the factor is then the same).
    pub inv_den: Vec<Plane>,
    /// `values` as half floats, when the feature has no variance and every
    /// value is exactly a half (a feature the renderer stored as half): the
    /// AVX2 and AVX-512 tiers' square sums read these, the same samples in
    /// half the bytes. Only an access path: the results do not depend on it.
    pub half: Option<Vec<HalfPlane>>,
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
    let rows = block_rows(rayon::current_num_threads(), false);
    let results: Vec<_> = blocks(out, rows).par_iter().map(|b| filter_block(jobs, features, frame, *b, s)).collect();
    assemble(jobs, out, results)
}

/// The blocks `out` is cut into, at most `rows` tall (see [`block_rows`]):
/// the kernel's unit of work, filtered independently by [`filter_block`]
/// in any order and on any thread. Blocks of (nearly) equal size: no sliver
/// block whose borders cost more than its rows (the grid does not change a
/// bit of the result).
pub fn blocks(out: Rect, rows: usize) -> Vec<Rect> {
    out.tiles(even(out.width(), BLOCK_W), even(out.height(), rows.max(1)))
}

/// The blocks' results ([`filter_block`], any order) pasted into planes over `out`.
pub fn assemble(jobs: &[Job<'_>], out: Rect, blocks: impl IntoIterator<Item = Vec<Vec<Plane>>>) -> Vec<Vec<Plane>> {
    let mut blocks: Vec<Vec<Vec<Plane>>> = blocks.into_iter().collect();
    // One block covering `out` (a 1080p tile on two threads): its planes are
    // the outputs, moved instead of copied into planes filled first.
    if let [only] = &blocks[..]
        && only.len() == jobs.len()
        && only.iter().zip(jobs).all(|(p, j)| p.len() == j.values.len() && p.iter().all(|p| p.rect() == out))
    {
        return blocks.pop().expect("one block");
    }
    let mut outputs: Vec<Vec<Plane>> =
        jobs.iter().map(|j| j.values.iter().map(|_| Plane::filled(out, 0.0)).collect()).collect();
    for block in blocks {
        for (job_out, block_job) in outputs.iter_mut().zip(block) {
            for (plane, part) in job_out.iter_mut().zip(block_job) {
                plane.paste(&part);
            }
        }
    }
    outputs
}

/// What sizes the kernel's working memory (see [`ScratchShape::bytes`]).
#[derive(Clone, Copy, Debug)]
pub struct ScratchShape {
    /// Search radius `r`.
    pub search_radius: usize,
    /// Patch radius `f`.
    pub patch_radius: usize,
    /// Jobs filtered together (light layers, or 1).
    pub jobs: usize,
    /// Numerator and denominator planes of all jobs (at least).
    pub accumulators: usize,
    /// Number of guide features (0 = unguided).
    pub guides: usize,
}

impl ScratchShape {
    /// Bytes of working memory one block of the kernel holds while it runs
    /// (one block per worker thread at a time), for a region of
    /// `width x height`: the numerators and denominators, every job's lanes'
    /// rings and rows, the guides' rows and the shared row buffers; blocks
    /// as tall as [`block_rows`] may choose. Independent of the frame size.
    pub fn bytes(&self, width: usize, height: usize) -> u64 {
        let (bw, bh) = (width.clamp(1, BLOCK_W) as u64, height.clamp(1, BLOCK_H_TALL) as u64);
        let (r, f) = (self.search_radius as u64, self.patch_radius as u64);
        let mid_w = bw + 2 * f;
        let lanes = 2 * GROUP_MAX as u64;
        // Per job and lane: both boxes (rows, running sums, see
        // [`ColumnBox`]) and the mean-weight row, each with up to 15 samples
        // of alignment.
        let cap = (2 * f + 1) as usize;
        let boxes = ColumnBox::samples(mid_w as usize, cap) + ColumnBox::samples(bw as usize, cap);
        let rings = self.jobs.max(1) as u64 * lanes * (boxes + bw + 7 * 15);
        // Per lane a row of the guides' weight argument; a row of square sums per guide.
        let guides = if self.guides > 0 { lanes * (mid_w + 15) + self.guides as u64 * (mid_w + r) } else { 0 };
        // The pair's distance, mirror and pair-sum rows, a lane's
        // patch-distance and weight rows, and every lane's row of factors
        // at the frame's sides.
        let rows = 3 * (bw + 4 * f + r + 15) + 2 * (mid_w + 15) + lanes * (bw + 15);
        4 * (self.accumulators as u64 * bw * bh + rings + guides + rows)
    }
}

/// One block of [`nlmeans`] (one of [`blocks`]) with the kernel compiled
/// for the current [`simd::Tier`]: per job, one plane per channel over `block`.
pub fn filter_block(
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
        // SAFETY: `simd::current` returns AVX2 only when the CPU has avx2, fma and f16c.
        Tier::Avx2 => unsafe { filter_block_avx2(jobs, features, frame, block, s) },
        _ => filter_block_body::<CHUNK, false, false>(jobs, features, frame, block, s),
    }
}

/// One wrapper per tier: the same body compiled with the tier's target feature.
macro_rules! tier_wrapper {
    ($name:ident, $feature:literal, $chunk:expr, $avx512:literal, $avx2:literal) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $feature)]
        fn $name(
            jobs: &[Job<'_>],
            features: &[GuideFeature],
            frame: Rect,
            block: Rect,
            s: &NlmSettings,
        ) -> Vec<Vec<Plane>> {
            filter_block_body::<{ $chunk }, $avx512, $avx2>(jobs, features, frame, block, s)
        }
    };
}

tier_wrapper!(filter_block_avx2, "avx2,fma,f16c", CHUNK, false, true);
tier_wrapper!(filter_block_avx512, "avx512f,fma", CHUNK_AVX512, true, false);

/// The block kernel; inlined into each tier's wrapper so that it (and every
/// kernel it inlines) is compiled for that tier's instruction set. `AVX512`
/// is true in the AVX-512 tier's wrapper only, `AVX2` in the AVX2 tier's
/// only: they select the kernels written for one tier (the same bits). `W`
/// is the tier's chunk width for the row loops ([`CHUNK`], or
/// [`CHUNK_AVX512`] on the AVX-512 tier): it changes which samples a loop
/// iteration computes together, never a sample's operations.
///
/// The offsets are visited as [`offset_schedule`] lists them: the centre,
/// then steps of up to [`GROUP_MAX`] offsets `n` sharing `dy >= 0`, each
/// with their mirrors `-n`. For a step, the distances of `n` and `-n` are
/// computed together (their common terms once, see
/// [`kernels::colour_distance_pair_rgb`](super::kernels::colour_distance_pair_rgb)),
/// and the forward lanes, the mirror lanes and every job (light layer) run in
/// lock step ([`run_step`]).
///
/// For each lane (offset and job) of a step, three passes over the block,
/// interleaved row by row so that no block-sized intermediate exists:
///
/// 1. per row of `d_rect`: the per-pixel distance (summed over channels) and
///    its horizontal window sums into the box `h1` (columns of `w_rect`);
/// 2. per row of `w_rect`, as soon as its window of `h1` rows is complete: the
///    vertical sum (the box's exact integer running sum), scaled by its step
///    and `-log2(e) / (channels count)` (`t`, then `2^min(t, t_f)`), then its
///    horizontal window sums into the box `h2` (columns of `acc_rect`);
/// 3. per row of `acc_rect`, as soon as its window of `h2` rows is complete:
///    the vertical sum (in units of the box's step) times
///    `(2f + 1)^2 / count` (exactly 1, so skipped, away from the borders),
///    and one fused pass accumulating every lane into the numerators and the
///    denominator.
///
/// Every window sum is one fixed expression of the window's samples, over
/// the window clipped to the offset's valid rectangle (a function of the
/// frame). Horizontally, a whole window adds the pair sums of samples
/// `(a, a + 1), (a + 2, a + 3), ...` then its last sample ([`pair_taps_sum`],
/// the pair sums stored in a row); a clipped one adds its samples in
/// increasing coordinate. Vertically, the rows are quantised to integers
/// and summed exactly ([`ColumnBox`]). The same operations for a pixel
/// whichever block, tile or lane computes it.
#[inline(always)]
fn filter_block_body<const W: usize, const AVX512: bool, const AVX2: bool>(
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
    let mut num: Vec<Vec<Aligned>> =
        jobs.iter().map(|j| j.values.iter().map(|_| Aligned::zeroed(area)).collect()).collect();
    let mut den: Vec<Aligned> = jobs.iter().map(|_| Aligned::zeroed(area)).collect();

    let outer = block.expand(2 * s.patch_radius);
    let mid = block.expand(s.patch_radius);
    // Window height: the boxes keep the last 2f + 1 rows of horizontal sums
    // (a vertical window never reaches further back) and their block sums.
    let cap = 2 * s.patch_radius + 1;
    // Every job's forward and mirror lanes (see [`lane_buf`]).
    let mut lanes: Vec<LaneBuffers> = (0..jobs.len() * 2 * GROUP_MAX)
        .map(|i| LaneBuffers {
            h1: ColumnBox::new(
                mid.width(),
                cap,
                Quantiser::distances(cap, jobs[i / (2 * GROUP_MAX)].values.len(), s.alpha, k2),
            ),
            h2: ColumnBox::new(block.width(), cap, Quantiser::weights(cap)),
            mean_w: Aligned::zeroed(block.width()),
        })
        .collect();
    // A pair's rows span at most `outer` widened by `r`.
    let pair_w = outer.width() + s.search_radius;
    let mut scratch = Scratch {
        drow: Aligned::zeroed(pair_w),
        mrow: Aligned::zeroed(pair_w),
        weights: Aligned::zeroed(mid.width()),
        pairs: Aligned::zeroed(pair_w),
        hrow: Aligned::zeroed(mid.width()),
        tf: if features.is_empty() {
            Vec::new()
        } else {
            (0..2 * GROUP_MAX).map(|_| Aligned::zeroed(mid.width())).collect()
        },
        square_sums: vec![0.0f32; features.len() * (mid.width() + s.search_radius)],
        side_factors: (0..2 * GROUP_MAX).map(|_| Aligned::zeroed(block.width())).collect(),
    };
    let geometry = |dx: i64, dy: i64| {
        let valid = frame.valid_for_offset(dx, dy);
        Lane { dx, valid, d: outer.intersect(&valid), w: mid.intersect(&valid), acc: block.intersect(&valid) }
    };

    // Per job, once per block: the constants that scale the distances by
    // their box's `2^s` (`eps` and `k^2` divided by it, see
    // [`distance_rows`]) and the patch mean's scale (channel mean,
    // `-log2(e)` and the box's step `2^-s`), the same for every lane.
    let scales: Vec<JobScales> = jobs
        .iter()
        .enumerate()
        .map(|(j, job)| {
            let q = lanes[lane_buf(j, 0, 0)].h1.quantiser();
            JobScales {
                distance: (s.alpha, s.eps / q.scale(), k2 / q.scale()),
                mean: log2_distance_scale(job.values.len()) * q.step(),
            }
        })
        .collect();
    // The weights' box's scale, through the exponent of their `exp2`.
    let w_exp = lanes[0].h2.quantiser().exponent();
    let ctx = StepCtx { jobs, features, f, block, scales: &scales, w_exp };
    for step in offset_schedule(r) {
        let dy = step.dy;
        if !step.paired {
            // The offsets computed alone (the centre): distances computed directly.
            let mut group = [Lane::EMPTY; GROUP_MAX];
            let mut g = 0;
            for dx in step.dxs {
                let lane = geometry(dx, dy);
                if !lane.acc.is_empty() {
                    group[g] = lane;
                    g += 1;
                }
            }
            let sides = [Side::new(&group[..g], dy, 0), Side::new(&[], -dy, dy)];
            run_step::<W, AVX512, AVX2>(&ctx, &mut num, &mut den, sides, None, &mut lanes, &mut scratch);
            continue;
        }
        // Pairs `n = (dx, dy)` (dy >= 0) and `-n`: the terms the two distances
        // share are computed once, over `u`, the pixels `p` whose `(p, p + n)`
        // either direction needs: `p` for `n`, `p + n` for `-n`.
        let mut pairs = [PairLane { dx: 0, u: Rect::EMPTY, fwd: None, mir: None }; GROUP_MAX];
        let (mut fwd, mut mir) = ([Lane::EMPTY; GROUP_MAX], [Lane::EMPTY; GROUP_MAX]);
        let (mut np, mut nf, mut nm) = (0, 0, 0);
        for dx in step.dxs {
            let (lf, lm) = (geometry(dx, dy), geometry(-dx, -dy));
            if lf.acc.is_empty() && lm.acc.is_empty() {
                continue;
            }
            // Both `lf.d` and `lm.d - n` lie in `valid(n)`; rows are shared by
            // the group (they depend on `dy` only).
            let u = Rect {
                x0: outer.x0.min(outer.x0 - dx).max(lf.valid.x0),
                x1: outer.x1.max(outer.x1 - dx).min(lf.valid.x1),
                y0: (outer.y0 - dy).max(lf.valid.y0),
                y1: outer.y1.min(lf.valid.y1),
            };
            let (mut fwd_idx, mut mir_idx) = (None, None);
            if !lf.acc.is_empty() {
                fwd[nf] = lf;
                fwd_idx = Some(nf);
                nf += 1;
            }
            if !lm.acc.is_empty() {
                mir[nm] = lm;
                mir_idx = Some(nm);
                nm += 1;
            }
            pairs[np] = PairLane { dx, u, fwd: fwd_idx, mir: mir_idx };
            np += 1;
        }
        if np == 0 {
            continue;
        }
        let sides = [Side::new(&fwd[..nf], dy, 0), Side::new(&mir[..nm], -dy, dy)];
        run_step::<W, AVX512, AVX2>(&ctx, &mut num, &mut den, sides, Some(&pairs[..np]), &mut lanes, &mut scratch);
    }

    // Each output written once, as it is divided (no division in place
    // followed by a copy out of the aligned buffer).
    num.iter()
        .zip(&den)
        .map(|(chans, den)| {
            chans
                .iter()
                .map(|n| {
                    let out = n.iter().zip(den.iter()).map(|(v, d)| v / d).collect();
                    Plane::from_vec(block, out).expect("block-sized buffer")
                })
                .collect()
        })
        .collect()
}

/// What every step of a block runs on, besides its lanes.
#[derive(Clone, Copy)]
struct StepCtx<'a, 'j> {
    jobs: &'a [Job<'j>],
    features: &'a [GuideFeature],
    f: i64,
    block: Rect,
    /// Per job.
    scales: &'a [JobScales],
    /// The weights' box's exponent `s` (see [`weight_row`]).
    w_exp: i32,
}

/// A job's constants for its distances and patch means.
#[derive(Clone, Copy)]
struct JobScales {
    /// `(alpha, eps 2^-s, k^2 2^-s)` for [`distance_rows`].
    distance: (f32, f32, f32),
    /// The factor of a window's integer sum in the weight's argument.
    mean: f32,
}

/// Row buffers shared by every step of a block.
struct Scratch {
    /// A pair's (or a lane's) distance row.
    drow: Aligned,
    /// A pair's mirror distance row (discarded for a lane computed alone).
    mrow: Aligned,
    /// A lane's weights of a row.
    weights: Aligned,
    /// Pair sums of a row (see [`pair_taps_sum`]).
    pairs: Aligned,
    /// A lane's horizontal window sums of a row, before its box quantises
    /// them: one row for every box, so that it stays in L1.
    hrow: Aligned,
    /// The guides' weight argument of each lane's current weight row
    /// (lane `g` of side `s` in row `s * GROUP_MAX + g`); empty without guides.
    tf: Vec<Aligned>,
    /// One row of square sums per guide (see [`pair_feature_row`]).
    square_sums: Vec<f32>,
    /// Each lane's mean weights' factors in the rows whose windows are
    /// whole vertically (lane `g` of side `s` in row `s * GROUP_MAX + g`,
    /// see [`side_factors`]).
    side_factors: Vec<Aligned>,
}

/// The buffers of job `j`, side `side` (0 forward, 1 mirror), lane `g`.
fn lane_buf(j: usize, side: usize, g: usize) -> usize {
    (2 * j + side) * GROUP_MAX + g
}

/// One pair of offsets `n = (dx, dy)` and `-n`.
#[derive(Clone, Copy)]
struct PairLane {
    dx: i64,
    /// Pixels `p` whose shared terms of `(p, p + n)` are computed.
    u: Rect,
    /// The forward lane (offset `n`) this pair feeds, when `n` is needed.
    fwd: Option<usize>,
    /// The mirror lane (offset `-n`) this pair feeds, when `-n` is needed.
    mir: Option<usize>,
}

/// The lanes of a step on one side: the forward lanes (offsets `n`), whose
/// rows are the step's rows, or the mirror lanes (offsets `-n`), whose rows
/// are `shift = dy` below (pair row `y` gives pixel `p` in row `y` its
/// distance for `n` and pixel `p + n` in row `y + dy` its distance for `-n`).
#[derive(Clone, Copy)]
struct Side<'a> {
    lanes: &'a [Lane],
    /// The lanes' vertical offset.
    dy: i64,
    /// A lane's row minus the step's row.
    shift: i64,
    /// The rows (of the lanes) of the distances, the weights and the
    /// accumulation, equal for every lane of a side (they depend on `dy` only).
    d_y: (i64, i64),
    w_y: (i64, i64),
    a_y: (i64, i64),
}

impl<'a> Side<'a> {
    fn new(lanes: &'a [Lane], dy: i64, shift: i64) -> Side<'a> {
        let (d_y, w_y, a_y) = match lanes.first() {
            Some(l) => ((l.d.y0, l.d.y1), (l.w.y0, l.w.y1), (l.acc.y0, l.acc.y1)),
            None => ((0, 0), (0, 0), (0, 0)),
        };
        Side { lanes, dy, shift, d_y, w_y, a_y }
    }
}

/// Whether row `y` lies in `rows`.
fn in_rows(rows: (i64, i64), y: i64) -> bool {
    rows.0 <= y && y < rows.1
}

/// Filter one step of the schedule for every job: the three passes of every
/// lane of both sides (and every job) in lock step, row by row.
///
/// The step's rows are the pairs' rows (or, for lanes computed alone, the
/// lanes' own). A pair's distance row feeds its forward lane at once and its
/// mirror lane `dy` rows lower, and both lanes' later passes stay in step:
/// they become ready at the same step row (a lane's window ends at the last
/// row of `valid(n)`, which is the mirror's last row minus `dy`). So no
/// distance plane is stored, the guides' weight argument of a row is
/// computed once for every job (and, without variance, once for both lanes
/// of a pair), and each numerator receives, per pixel, the mirror group's
/// terms before the forward group's (`dy > 0`: the mirror reaches the row
/// first; `dy = 0`: forward, then mirror), a fixed order for every block.
#[inline(always)]
fn run_step<const W: usize, const AVX512: bool, const AVX2: bool>(
    ctx: &StepCtx<'_, '_>,
    num: &mut [Vec<Aligned>],
    den: &mut [Aligned],
    sides: [Side<'_>; 2],
    pairs: Option<&[PairLane]>,
    bufs: &mut [LaneBuffers],
    scratch: &mut Scratch,
) {
    let StepCtx { jobs, features, f, block, scales, w_exp } = *ctx;
    let dy = sides[0].dy;
    // The step rows (a lane's rows minus its side's shift) a pass walks.
    let (mut w_rows, mut a_rows) = ((i64::MAX, i64::MIN), (i64::MAX, i64::MIN));
    // The last step row of a window: the same for both sides.
    let mut valid_y1 = None;
    for side in sides.iter().filter(|side| !side.lanes.is_empty()) {
        w_rows = (w_rows.0.min(side.w_y.0 - side.shift), w_rows.1.max(side.w_y.1 - side.shift));
        a_rows = (a_rows.0.min(side.a_y.0 - side.shift), a_rows.1.max(side.a_y.1 - side.shift));
        valid_y1 = Some(side.lanes[0].valid.y1 - side.shift);
    }
    let Some(valid_y1) = valid_y1 else { return };
    let rows = match pairs {
        Some(p) => p[0].u.y0..p[0].u.y1,
        None => sides[0].d_y.0..sides[0].d_y.1,
    };
    let Scratch { drow, mrow, weights, pairs: psum, hrow, tf, square_sums, side_factors: fac } = scratch;
    side_factors(&sides, f, fac);
    let (mut next_w, mut next_a) = (w_rows.0, a_rows.0);
    for yd in rows {
        // 1. Distance rows and their horizontal sums, every job.
        for (j, job) in jobs.iter().enumerate() {
            let consts = scales[j].distance;
            match pairs {
                None => {
                    let side = &sides[0];
                    for (g, lane) in side.lanes.iter().enumerate() {
                        let (d_rect, w) = (lane.d, lane.d.width());
                        // The pair kernel with its mirror row discarded.
                        let (d, m) = (&mut drow[..w], &mut mrow[..w]);
                        distance_rows::<W>(job, d, m, yd, dy, (d_rect.x0, d_rect.x1), lane.dx, consts);
                        let buf = &mut bufs[lane_buf(j, 0, g)];
                        push_h1::<W, AVX512>(lane, buf, d, d_rect.x0, (yd, side.d_y.0), f, (psum, hrow));
                    }
                }
                Some(pairs) => {
                    for pair in pairs {
                        let (u, dx) = (pair.u, pair.dx);
                        let w = u.width();
                        let (d, m) = (&mut drow[..w], &mut mrow[..w]);
                        distance_rows::<W>(job, d, m, yd, dy, (u.x0, u.x1), dx, consts);
                        // Row `d` holds pixels `p` from `u.x0`, row `m` pixels `p + n`.
                        for (si, row, x0, g) in [(0, &*d, u.x0, pair.fwd), (1, &*m, u.x0 + dx, pair.mir)] {
                            let side = &sides[si];
                            let yl = yd + side.shift;
                            let Some(g) = g.filter(|_| in_rows(side.d_y, yl)) else { continue };
                            let lane = &side.lanes[g];
                            let from = (lane.d.x0 - x0) as usize;
                            let row = &row[from..from + lane.d.width()];
                            push_h1::<W, AVX512>(
                                lane,
                                &mut bufs[lane_buf(j, si, g)],
                                row,
                                lane.d.x0,
                                (yl, side.d_y.0),
                                f,
                                (psum, hrow),
                            );
                        }
                    }
                }
            }
        }
        // 2. Patch distances, weights, and their horizontal sums.
        while next_w < w_rows.1 && (next_w + f).min(valid_y1 - 1) <= yd {
            let y = next_w;
            next_w += 1;
            if !features.is_empty() {
                guide_rows::<W, AVX512, AVX2>(features, &sides, pairs, y, tf, square_sums);
            }
            // The rows whose mean weights become complete with row `y`.
            let first_a = next_a;
            while next_a < a_rows.1 && (next_a + f).min(valid_y1 - 1) <= y {
                next_a += 1;
            }
            let ready = first_a..next_a;
            // The lanes in the reverse of pass 1's order: the boxes pushed
            // last are the likeliest still in L1 (each lane's pass is
            // independent of the others', so the order changes no bit;
            // 0.96-0.97x in interleaved pairs, docs/performance.md session 23).
            for (j, job) in jobs.iter().enumerate().rev() {
                let kd = scales[j].mean;
                for (si, side) in sides.iter().enumerate().rev() {
                    let yl = y + side.shift;
                    if !in_rows(side.w_y, yl) {
                        continue;
                    }
                    for (g, lane) in side.lanes.iter().enumerate().rev() {
                        let buf = &mut bufs[lane_buf(j, si, g)];
                        let ww = lane.w.width();
                        let wt = &mut weights[..ww];
                        let (ny, sums) = buf.h1.window(side.d_y.0, yl, lane.valid, f, ww);
                        // The patch mean's scale (with `kd`) applied inside the
                        // weight's loop.
                        let at = (lane.w.x0, lane.valid, f, ny, kd, w_exp);
                        let guide: &[f32] = if features.is_empty() { &[] } else { &tf[si * GROUP_MAX + g][..ww] };
                        if features.is_empty() {
                            weight_row::<W, false, AVX512>(sums, wt, guide, at);
                        } else {
                            weight_row::<W, true, AVX512>(sums, wt, guide, at);
                        }
                        let h = (&mut hrow[..lane.acc.width()], &mut psum[..]);
                        let (valid, (x0, acc_x0)) = (lane.valid, (lane.w.x0, lane.acc.x0));
                        push_window_sums::<W, AVX512, false>(
                            &mut buf.h2,
                            (yl, side.w_y.0),
                            wt,
                            x0,
                            valid,
                            f,
                            acc_x0,
                            h,
                        );
                    }
                }
                // 3. Mean weights of every lane of a side, accumulated in one
                // pass, right after the job's pass 2 (its boxes' sums still
                // in cache; jobs have their own numerators, so no bit changes).
                for ya in ready.clone() {
                    for (si, side) in sides.iter().enumerate() {
                        let yl = ya + side.shift;
                        if !in_rows(side.a_y, yl) {
                            continue;
                        }
                        let rows = AccRows { j, si, yl, f, block };
                        let fac = &fac[si * GROUP_MAX..][..side.lanes.len()];
                        accumulate_side::<W, AVX512>(job, &mut num[j], &mut den[j], side, bufs, fac, rows);
                    }
                }
            }
        }
    }
    debug_assert!(next_w == w_rows.1 && next_a == a_rows.1);
}

/// Where [`accumulate_side`] reads a side's mean weights: job `j`, side
/// `si`, the lanes' row `yl`, the patch radius and the block.
#[derive(Clone, Copy)]
struct AccRows {
    j: usize,
    si: usize,
    yl: i64,
    f: i64,
    block: Rect,
}

/// Pass 3 of one side's lanes on row `yl`: their mean weights accumulated
/// into job `j`'s numerators and denominator.
///
/// Where every lane's window is whole (no column of the row clipped), the
/// mean weights are the weights' box's row of integer sums, which the
/// accumulation reads and converts. In a row whose windows are whole
/// vertically but clipped at the frame's left or right side (every row of
/// a block at the frame's side), the AVX-512 tier reads the box's sums
/// too, multiplies those of the vectors and columns near the clipped ones
/// by their lane's factors (`fac`, see [`side_factors`]) as it reads them,
/// and takes the columns only some lanes cover in one masked vector per
/// side ([`accumulate_scaled`]; docs/performance.md, session 49: 0.97x the
/// full filter's time at 1080p, where every block touches a side). Where
/// that path does not apply (other tiers, lanes whose `dx` are not
/// consecutive, jobs of other than three channels), such a row forms each
/// lane's mean weights in `mean_w` (converted and scaled) for the columns
/// near the clipped ones and reads the box's sums for the columns between,
/// where every lane's window is whole (session 48). In the rest (rows
/// within `f` of the frame's top or bottom, or too narrow a span of whole
/// windows) every column goes through `mean_w`. A pixel takes its lanes'
/// terms in lane order in every case, a clipped column's mean weight is
/// its integer sum converted then multiplied by the same factor, and a
/// whole column's is its integer sum converted (times a factor of exactly
/// 1, which changes no bit), so the bits are the same whichever path or
/// part of a row a pixel falls in.
#[inline(always)]
fn accumulate_side<const W: usize, const AVX512: bool>(
    job: &Job<'_>,
    num: &mut [Aligned],
    den: &mut [f32],
    side: &Side<'_>,
    bufs: &mut [LaneBuffers],
    fac: &[Aligned],
    AccRows { j, si, yl, f, block }: AccRows,
) {
    let lanes = side.lanes;
    let at = (yl, side.dy, block);
    let k = ((2 * f + 1) * (2 * f + 1)) as f32;
    let vertical = lanes.iter().all(|l| yl - f >= l.valid.y0 && yl + f < l.valid.y1);
    let horizontal = lanes.iter().all(|l| l.acc.x0 >= l.valid.x0 + f && l.acc.x1 <= l.valid.x1 - f);
    // The box's integer sums of every lane (whole windows vertically).
    fn whole_rows<'a>(bufs: &'a [LaneBuffers], lanes: &[Lane], j: usize, si: usize, yl: i64, f: i64) -> LaneRows<'a> {
        lane_rows(lanes, |g, l| {
            bufs[lane_buf(j, si, g)].h2.whole(yl, l.valid, f, l.acc.width()).expect("a whole window")
        })
    }
    if vertical && horizontal {
        // The box's integer sums, read as `f32` by the accumulation.
        let rows = whole_rows(bufs, lanes, j, si, yl, f);
        accumulate::<W, AVX512, i32>(num, den, &job.values, &rows[..lanes.len()], at);
        return;
    }
    // The columns every lane covers, `[c0, c1)` (the accumulation's
    // vector path), and among them those where every lane's window is
    // whole, `[lo, hi)`; the split points `e0` and `e1` lie whole 16-sample
    // chunks from `c0`, so that the three parts' vector loops have no
    // scalar ends but the last part's, as the row's single call had.
    let (c0, c1) = lanes.iter().fold((i64::MIN, i64::MAX), |(a, b), l| (a.max(l.acc.x0), b.min(l.acc.x1)));
    let (lo, hi) = lanes.iter().fold((c0, c1), |(lo, hi), l| (lo.max(l.valid.x0 + f), hi.min(l.valid.x1 - f)));
    let e0 = c0 + (lo - c0 + 15) / 16 * 16;
    let e1 = e0 + (hi - e0).max(0) / 16 * 16;
    #[cfg(target_arch = "x86_64")]
    if AVX512 && vertical {
        let rows = whole_rows(bufs, lanes, j, si, yl, f);
        let whole = if e1 > e0 { (e0, e1) } else { (c0, c0) };
        if accumulate_scaled(num, den, &job.values, &rows[..lanes.len()], fac, whole, at) {
            return;
        }
    }
    let _ = fac;
    let split = vertical && e1 > e0;
    // Each lane's mean weights where they are formed: the columns before
    // `e0` and from `e1` (every column without the split).
    let formed = |l: &Lane| {
        let aw = l.acc.width();
        if split { ((e0 - l.acc.x0) as usize, (e1 - l.acc.x0) as usize, aw) } else { (aw, aw, aw) }
    };
    for (g, lane) in lanes.iter().enumerate() {
        let LaneBuffers { h2, mean_w, .. } = &mut bufs[lane_buf(j, si, g)];
        let (a, b, aw) = formed(lane);
        // Mean weights times the full window's count: numerators and
        // denominator share the factor, and it is exactly 1 where the
        // window is not clipped (no multiply there).
        let mw = &mut mean_w[..aw];
        let ny = h2.sums(side.w_y.0, yl, lane.valid, f, &mut mw[..a]);
        scale_by_count(&mut mw[..a], lane.acc.x0, lane.valid, f, ny, k);
        if b < aw {
            let sums = h2.whole(yl, lane.valid, f, aw).expect("whole vertically");
            for (o, s) in mw[b..].iter_mut().zip(&sums[b..]) {
                *o = *s as f32;
            }
            scale_by_count(&mut mw[b..], lane.acc.x0 + b as i64, lane.valid, f, ny, k);
        }
    }
    let bufs = &*bufs;
    let buf = |g: usize| &bufs[lane_buf(j, si, g)];
    let part = |x0: i64, x1: i64| {
        let mut rows = [LaneRow { w: &[][..], x0: 0, dx: 0 }; GROUP_MAX];
        for (g, (l, row)) in lanes.iter().zip(rows.iter_mut()).enumerate() {
            let (a, b) = ((x0.max(l.acc.x0) - l.acc.x0) as usize, (x1.min(l.acc.x1) - l.acc.x0) as usize);
            *row = LaneRow { w: &buf(g).mean_w[a..b.max(a)], x0: x0.max(l.acc.x0), dx: l.dx };
        }
        rows
    };
    if !split {
        let rows = part(block.x0, block.x1);
        accumulate::<W, AVX512, f32>(num, den, &job.values, &rows[..lanes.len()], at);
        return;
    }
    let left = part(block.x0, e0);
    accumulate::<W, AVX512, f32>(num, den, &job.values, &left[..lanes.len()], at);
    let mut whole = [LaneRow { w: &[][..], x0: 0, dx: 0 }; GROUP_MAX];
    for (g, (l, row)) in lanes.iter().zip(whole.iter_mut()).enumerate() {
        let sums = buf(g).h2.whole(yl, l.valid, f, l.acc.width()).expect("whole vertically");
        *row = LaneRow { w: &sums[(e0 - l.acc.x0) as usize..(e1 - l.acc.x0) as usize], x0: e0, dx: l.dx };
    }
    accumulate::<W, AVX512, i32>(num, den, &job.values, &whole[..lanes.len()], at);
    let right = part(e1, block.x1);
    accumulate::<W, AVX512, f32>(num, den, &job.values, &right[..lanes.len()], at);
}

/// Each lane's factors of its mean weights in a row whose windows are
/// whole vertically (`fac[s * GROUP_MAX + g]` for lane `g` of side `s`,
/// one per column of the lane's accumulation from `acc.x0`): a window
/// clipped at the frame's side to `nx` columns takes `k / (nx ny)`, as
/// [`scale_by_count`] computes it with `ny = 2f + 1`; a whole one takes
/// exactly 1 (`k / (2f + 1)^2`).
fn side_factors(sides: &[Side<'_>; 2], f: i64, fac: &mut [Aligned]) {
    let (k, ny) = (((2 * f + 1) * (2 * f + 1)) as f32, (2 * f + 1) as f32);
    for (si, side) in sides.iter().enumerate() {
        for (g, lane) in side.lanes.iter().enumerate() {
            let row = &mut fac[si * GROUP_MAX + g][..lane.acc.width()];
            let (whole, clipped) = window_columns(lane.acc.x0, row.len(), lane.valid, f);
            row[whole].fill(1.0);
            for (i, nx) in clipped {
                row[i] = k / (nx * ny);
            }
        }
    }
}

/// [`accumulate`] of a row whose windows are whole vertically and clipped
/// at the frame's side, from the box's integer sums `rows` (each lane's
/// `fac` indexed as its sums) on the AVX-512 tier: a mean weight is its sum
/// converted, times its factor outside the columns `whole` (a whole number
/// of 16-sample vectors from the first column every lane covers, where
/// every factor is 1). Returns false, having done nothing, unless the job
/// has three channels and the lanes' `dx` are consecutive (the fused
/// path's case).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn accumulate_scaled(
    num: &mut [Aligned],
    den: &mut [f32],
    values: &[&Plane],
    rows: &[LaneRow<'_, i32>],
    fac: &[Aligned],
    whole: (i64, i64),
    (y, dy, block): (i64, i64, Rect),
) -> bool {
    if rows.len() < 2 || num.len() != 3 {
        return false;
    }
    let Some((dmin, rev)) = consecutive_dx(rows) else { return false };
    let row_off = (y - block.y0) as usize * block.width();
    let end = |l: &LaneRow<'_, i32>| l.x0 + l.w.len() as i64;
    let (c0, c1) = (rows.iter().map(|l| l.x0).max().unwrap_or(0), rows.iter().map(end).min().unwrap_or(0));
    let (u0, u1) = (rows.iter().map(|l| l.x0).min().unwrap_or(0), rows.iter().map(end).max().unwrap_or(0));
    let c1 = c1.max(c0);
    // The columns some lanes miss (at most `G - 1` on each side), each
    // covering lane's term in lane order (as `accumulate`), in a masked
    // vector.
    let edges = [(u0, c0.min(u1)), (c1.max(u0), u1)];
    if edges.iter().any(|(a, b)| b - a > 16) {
        return false;
    }
    for (a, b) in edges {
        if b <= a {
            continue;
        }
        let mut edge = [EdgeLane { lo: 0, hi: 0, w: &[][..], fac: &[][..], values: [&[][..]; 3] }; GROUP_MAX];
        for ((l, fl), e) in rows.iter().zip(fac).zip(edge.iter_mut()) {
            let (lo, hi) = (l.x0.max(a), end(l).min(b));
            if hi <= lo {
                continue;
            }
            let (from, m) = ((lo - l.x0) as usize, (hi - lo) as usize);
            let v = |c: usize| values[c].row(y + dy, lo + l.dx, hi + l.dx);
            let (lo, hi) = ((lo - a) as usize, (hi - a) as usize);
            *e = EdgeLane { lo, hi, w: &l.w[from..][..m], fac: &fl[from..][..m], values: [v(0), v(1), v(2)] };
        }
        let cols = row_off + (a - block.x0) as usize..row_off + (b - block.x0) as usize;
        let [n0, n1, n2] = num else { unreachable!("three channels") };
        let acc = [&mut den[cols.clone()], &mut n0[cols.clone()], &mut n1[cols.clone()], &mut n2[cols]];
        // SAFETY: this runs only in the AVX-512 tier's wrapper (`AVX512`),
        // which runs only on CPUs with avx512f and fma.
        unsafe { edge_columns_avx512(acc, &edge[..rows.len()]) };
    }
    if c1 > c0 {
        let span = row_off + (c0 - block.x0) as usize..row_off + (c1 - block.x0) as usize;
        let vectors = ((whole.0 - c0).max(0) as usize / 16, (whole.1 - c0).max(0) as usize / 16);
        let at = (y + dy, c0, c1, span, vectors, (dmin, rev));
        const _: () = assert!(GROUP_MAX == 7);
        match rows.len() {
            2 => scaled_span::<2>(num, den, values, rows, fac, at),
            3 => scaled_span::<3>(num, den, values, rows, fac, at),
            4 => scaled_span::<4>(num, den, values, rows, fac, at),
            5 => scaled_span::<5>(num, den, values, rows, fac, at),
            6 => scaled_span::<6>(num, den, values, rows, fac, at),
            _ => scaled_span::<GROUP_MAX>(num, den, values, rows, fac, at),
        }
    }
    true
}

/// The fused span of [`accumulate_scaled`], `G` lanes: value row `yq`,
/// columns `[c0, c1)`, the whole vectors `vectors`, the lanes' smallest
/// `dx` and whether they decrease.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::type_complexity)]
fn scaled_span<const G: usize>(
    num: &mut [Aligned],
    den: &mut [f32],
    values: &[&Plane],
    rows: &[LaneRow<'_, i32>],
    fac: &[Aligned],
    (yq, c0, c1, span, whole, (dmin, rev)): (i64, i64, i64, std::ops::Range<usize>, (usize, usize), (i64, bool)),
) {
    let n = (c1 - c0) as usize;
    let from = |g: usize| (c0 - rows[g].x0) as usize;
    let w: [&[i32]; G] = std::array::from_fn(|g| &rows[g].w[from(g)..][..n]);
    let scale = SideFactors { fac: std::array::from_fn(|g| &fac[g][from(g)..][..n]), whole };
    let row = |c: usize| values[c].row(yq, c0 + dmin, c1 + dmin + G as i64 - 1);
    let [n0, n1, n2] = num else { unreachable!("three channels") };
    let (d, n0, n1, n2) = (&mut den[span.clone()], &mut n0[span.clone()], &mut n1[span.clone()], &mut n2[span]);
    let rows3 = [row(0), row(1), row(2)];
    // SAFETY: this runs only in the AVX-512 tier's wrapper (`AVX512`), which
    // runs only on CPUs with avx512f and fma.
    unsafe {
        if rev {
            fused_rgb_shifted_avx512::<G, true, true, i32>([d, n0, n1, n2], w, rows3, scale);
        } else {
            fused_rgb_shifted_avx512::<G, false, true, i32>([d, n0, n1, n2], w, rows3, scale);
        }
    }
}

/// The distances of row `y`, columns `x`, for offset `(dx, dy)` into `d` and
/// for the mirror offset into `m` (pixel `p + (dx, dy)`), summed over the
/// job's channels: `((0 + t_0) + t_1) + ...`, with `consts = (alpha, eps,
/// k^2)`.
///
/// The kernel passes `eps 2^-s` and `k^2 2^-s` (`2^s`: the distances' box's
/// [`Quantiser::scale`](super::column_sums::Quantiser::scale)), which gives
/// the distances times `2^s` exactly: the denominator `eps + k^2 (vp + vq)`
/// is scaled by `2^-s` with no rounding (its fused multiply-add rounds the
/// scaled exact value, a normal number while `eps 2^-s` is, as SPEC's
/// `eps = 1e-10` is), its reciprocal (a correctly rounded division) is the
/// unscaled one times `2^s` exactly, and so is each term and sum after it.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn distance_rows<const W: usize>(
    job: &Job<'_>,
    d: &mut [f32],
    m: &mut [f32],
    y: i64,
    dy: i64,
    x: (i64, i64),
    dx: i64,
    (alpha, eps, k2): (f32, f32, f32),
) {
    if let ([u0, u1, u2], [v0, v1, v2]) = (&job.values[..], &job.variance[..]) {
        let up = [shifted(u0, y, x, 0), shifted(u1, y, x, 0), shifted(u2, y, x, 0)];
        let uq = [shifted(u0, y + dy, x, dx), shifted(u1, y + dy, x, dx), shifted(u2, y + dy, x, dx)];
        let vp = [shifted(v0, y, x, 0), shifted(v1, y, x, 0), shifted(v2, y, x, 0)];
        let vq = [shifted(v0, y + dy, x, dx), shifted(v1, y + dy, x, dx), shifted(v2, y + dy, x, dx)];
        let consts = (alpha, eps, k2);
        // Chunks of `CHUNK` samples on every tier, the AVX-512 one too: with
        // its 64-sample chunks the two lanes' sums and three channels'
        // operands did not fit the 32 registers and spilled (session 33,
        // docs/performance.md: 0.948x the full filter's time). The width
        // never changes a bit (the outputs are not inputs).
        if alpha == 1.0 {
            colour_distance_pair_rgb::<CHUNK, true>(d, m, up, uq, vp, vq, consts);
        } else {
            colour_distance_pair_rgb::<CHUNK, false>(d, m, up, uq, vp, vq, consts);
        }
    } else {
        d.fill(0.0);
        m.fill(0.0);
        for (u, v) in job.values.iter().zip(&job.variance) {
            accumulate_colour_distance_pair(
                d,
                m,
                shifted(u, y, x, 0),
                shifted(u, y + dy, x, dx),
                shifted(v, y, x, 0),
                shifted(v, y + dy, x, dx),
                alpha,
                eps,
                k2,
            );
        }
    }
}

/// Row `y` of `p` over columns `x` shifted by `dx`.
#[inline(always)]
fn shifted(p: &Plane, y: i64, x: (i64, i64), dx: i64) -> &[f32] {
    p.row(y, x.0 + dx, x.1 + dx)
}

/// Push a lane's distance row `d` (frame row `y`, columns from `x0`; `y0`
/// the lane's first row of the step) as its horizontal window sums into
/// the lane's box `h1`.
#[inline(always)]
fn push_h1<const W: usize, const AVX512: bool>(
    lane: &Lane,
    buf: &mut LaneBuffers,
    d: &[f32],
    x0: i64,
    (y, y0): (i64, i64),
    f: i64,
    (pairs, hrow): (&mut [f32], &mut [f32]),
) {
    let h = (&mut hrow[..lane.w.width()], pairs);
    push_window_sums::<W, AVX512, true>(&mut buf.h1, (y, y0), d, x0, lane.valid, f, lane.w.x0, h);
}

/// The order in which a block visits the search offsets: the centre alone,
/// then, for `dy` from 0 to `r`, groups of `n = (dx, dy)` in the half plane
/// (`dy > 0`, or `dy = 0` and `dx > 0`), each followed by its mirror `-n`.
fn offset_schedule(r: i64) -> impl Iterator<Item = Step> {
    let centre = std::iter::once(Step { dy: 0, dxs: 0..1, paired: false });
    let rows = (0..=r).flat_map(move |dy| {
        let first = if dy == 0 { 1 } else { -r };
        offset_groups(first, r).map(move |dxs| Step { dy, dxs, paired: true })
    });
    centre.chain(rows)
}

/// One step of [`offset_schedule`].
struct Step {
    dy: i64,
    dxs: std::ops::Range<i64>,
    /// Whether each offset of the step is filtered with its mirror.
    paired: bool,
}

/// The most search offsets filtered in lock step (one accumulation pass each).
/// Seven cut a row of the search window (`2r + 1 = 21` offsets at r = 10)
/// into three steps instead of six: each step streams the block's inputs
/// and accumulators once, so fewer steps stream less, at the price of
/// more lanes' rings. On the Zen 5 machine of session 19 (one binary, the
/// group size switched at run time), the full filter at 1080p on two
/// threads ran about 0.94x the time of groups of four, colour-only the
/// same time; against the previous binary, 0.95-1.0x in runs of different
/// hours: a gain of a few per cent at most (docs/performance.md).
const GROUP_MAX: usize = 7;

/// The horizontal offsets `first..=last` cut into groups of at most
/// [`GROUP_MAX`], as even as possible, in increasing order.
fn offset_groups(first: i64, last: i64) -> impl Iterator<Item = std::ops::Range<i64>> {
    let n = (last - first + 1).max(0);
    let groups = (n + GROUP_MAX as i64 - 1) / GROUP_MAX as i64;
    let (base, extra) = (n / groups.max(1), n % groups.max(1));
    (0..groups).map(move |i| {
        let start = first + i * base + i.min(extra);
        start..start + base + i64::from(i < extra)
    })
}

/// One search offset of a group and the rectangles of its passes.
#[derive(Clone, Copy)]
struct Lane {
    dx: i64,
    /// Pixels `p` with `p` and `p + (dx, dy)` in the frame.
    valid: Rect,
    /// Where the per-pixel distance is needed.
    d: Rect,
    /// Where the weight is needed.
    w: Rect,
    /// Where the mean weight is accumulated.
    acc: Rect,
}

impl Lane {
    const EMPTY: Lane = Lane { dx: 0, valid: Rect::EMPTY, d: Rect::EMPTY, w: Rect::EMPTY, acc: Rect::EMPTY };
}

/// Ring slots `stride(width)` samples apart start on a cache line (with
/// [`Aligned`] storage): whole-vector loads and stores never straddle two.
pub(super) fn stride(width: usize) -> usize {
    width.next_multiple_of(16)
}

/// A zeroed buffer of 4-byte samples (`f32`, or `i32` for the boxes'
/// quantised rows) whose first sample starts a 64-byte cache line (an
/// AVX-512 vector), so that rows [`stride`] apart each start a line.
pub(super) struct Aligned<T = f32> {
    data: Vec<T>,
    off: usize,
    len: usize,
}

impl<T: Copy + Default> Aligned<T> {
    pub(super) fn zeroed(len: usize) -> Aligned<T> {
        const { assert!(size_of::<T>() == 4) };
        // Written now: the accumulators are read before they are written.
        let data = crate::image::written(T::default(), len + 15);
        let off = data.as_ptr().align_offset(64);
        Aligned { off: if off < 16 { off } else { 0 }, data, len }
    }
}

impl<T> std::ops::Deref for Aligned<T> {
    type Target = [T];
    // Always inlined: an out-of-line call from a tier wrapper costs a
    // `vzeroupper` and the call itself, per row.
    #[inline(always)]
    fn deref(&self) -> &[T] {
        &self.data[self.off..self.off + self.len]
    }
}

impl<T> std::ops::DerefMut for Aligned<T> {
    #[inline(always)]
    fn deref_mut(&mut self) -> &mut [T] {
        &mut self.data[self.off..self.off + self.len]
    }
}

/// The working rows of one lane.
struct LaneBuffers {
    h1: ColumnBox,
    h2: ColumnBox,
    mean_w: Aligned,
}

/// Every lane's box sums of a row (the first `lanes.len()`).
type LaneRows<'a> = [LaneRow<'a, i32>; GROUP_MAX];

/// One lane's row of mean weights `w`, for columns from `x0`.
#[derive(Clone, Copy)]
struct LaneRow<'a, T = f32> {
    w: &'a [T],
    x0: i64,
    dx: i64,
}

/// The accumulation's rows of a side's lanes, lane `g`'s mean weights
/// `w(g, lane)` (the first `lanes.len()` rows).
#[inline(always)]
fn lane_rows<'a, T: Copy>(lanes: &[Lane], w: impl Fn(usize, &Lane) -> &'a [T]) -> [LaneRow<'a, T>; GROUP_MAX] {
    let mut rows = [LaneRow { w: &[], x0: 0, dx: 0 }; GROUP_MAX];
    for (g, (lane, row)) in lanes.iter().zip(rows.iter_mut()).enumerate() {
        *row = LaneRow { w: w(g, lane), x0: lane.acc.x0, dx: lane.dx };
    }
    rows
}

/// Horizontal window sums of one row: `dst[x] = sum of src over
/// [x - f, x + f] ∩ clip` for `x` from `dst_x0`. A whole window (f <= 4)
/// adds the pair sums of columns `(x - f, x - f + 1), (x - f + 2, x - f + 3), ...`
/// then column `x + f` ([`pair_taps_sum`], the pairs in `pairs`; on the
/// AVX-512 tier with `f <= 4`, [`push_window_sums`] forms the same sums in
/// registers instead); a clipped window (or f > 4) starts from its first
/// sample and adds the others in increasing x. `src` starts at column
/// `src_x0` and covers every window.
#[inline(always)]
fn window_sums_row<const W: usize>(
    src: &[f32],
    src_x0: i64,
    clip: Rect,
    f: i64,
    dst_x0: i64,
    dst: &mut [f32],
    pairs: &mut [f32],
) {
    let (inner, from) = clipped_window_sums(src, src_x0, clip, f, dst_x0, dst);
    let n = inner.len();
    if n > 0 {
        let out = &mut dst[inner];
        match f {
            1 => pair_taps_sum::<W, 1, 2>(&src[from..from + n + 2], pairs, out),
            2 => pair_taps_sum::<W, 2, 3>(&src[from..from + n + 4], pairs, out),
            3 => pair_taps_sum::<W, 3, 4>(&src[from..from + n + 6], pairs, out),
            4 => pair_taps_sum::<W, 4, 5>(&src[from..from + n + 8], pairs, out),
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

/// Where the windows of `2f + 1` columns lie whole inside `clip`, in a
/// row of `dst_len` sums from column `dst_x0` of a source row from
/// `src_x0`: the columns `(x0, x1)` (the clipped ones are before and from
/// them), their indices in the row of sums, and where in the source row
/// the first one's window starts.
#[inline(always)]
fn whole_windows(
    src_x0: i64,
    clip: Rect,
    f: i64,
    dst_x0: i64,
    dst_len: usize,
) -> ((i64, i64), std::ops::Range<usize>, usize) {
    let dst_x1 = dst_x0 + dst_len as i64;
    let inner_x0 = (clip.x0 + f).clamp(dst_x0, dst_x1);
    let inner_x1 = (clip.x1 - f).clamp(inner_x0, dst_x1);
    let inner = (inner_x0 - dst_x0) as usize..(inner_x1 - dst_x0) as usize;
    ((inner_x0, inner_x1), inner, (inner_x0 - f - src_x0).max(0) as usize)
}

/// The clipped windows of [`window_sums_row`] (the columns next to `clip`'s
/// edges, each summed in increasing x into `dst`); returns the indices in
/// `dst` of the whole windows, and where in `src` the first one starts
/// ([`whole_windows`]).
#[inline(always)]
fn clipped_window_sums(
    src: &[f32],
    src_x0: i64,
    clip: Rect,
    f: i64,
    dst_x0: i64,
    dst: &mut [f32],
) -> (std::ops::Range<usize>, usize) {
    let dst_x1 = dst_x0 + dst.len() as i64;
    let ((inner_x0, inner_x1), inner, from) = whole_windows(src_x0, clip, f, dst_x0, dst.len());
    for x in (dst_x0..inner_x0).chain(inner_x1..dst_x1) {
        let a = ((x - f).max(clip.x0) - src_x0) as usize;
        let b = ((x + f).min(clip.x1 - 1) - src_x0) as usize;
        let mut acc = src[a];
        for v in &src[a + 1..=b] {
            acc += *v;
        }
        dst[(x - dst_x0) as usize] = acc;
    }
    (inner, from)
}

/// [`window_sums_row`] of `src` pushed as frame row `y` (`y0` as
/// [`ColumnBox::pushed`]) into box `b`, `h` a scratch row of the sums'
/// width. With `AVX512` and `f` from 1 to 4 (the main filter's default 3,
/// the feature prefilter's 2), the whole windows' sums go straight into the
/// box ([`kernels::taps_push_avx512`](super::kernels::taps_push_avx512), the
/// same sums and quantisation), not through `h`: one pass over the row fewer.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn push_window_sums<const W: usize, const AVX512: bool, const CLAMP: bool>(
    b: &mut ColumnBox,
    (y, y0): (i64, i64),
    src: &[f32],
    src_x0: i64,
    clip: Rect,
    f: i64,
    dst_x0: i64,
    (h, pairs): (&mut [f32], &mut [f32]),
) {
    #[cfg(target_arch = "x86_64")]
    if AVX512 && (1..=4).contains(&f) {
        let dst_x1 = dst_x0 + h.len() as i64;
        let ((inner_x0, inner_x1), whole, whole_from) = whole_windows(src_x0, clip, f, dst_x0, h.len());
        let mut slot = b.slot(y, y0, h.len());
        let limit = slot.q.limit();
        let (inner, from) = if inner_x0 - dst_x0 <= 16 && dst_x1 - inner_x1 <= 16 {
            // The clipped windows at each end (at most `f` columns, unless
            // the row is narrower than its windows) in one masked vector.
            for (x0, x1) in [(dst_x0, inner_x0), (inner_x1, dst_x1)] {
                if x1 > x0 {
                    let at = (x0 - dst_x0) as usize..(x1 - dst_x0) as usize;
                    let (ring, run) = (&mut slot.ring[at.clone()], &mut slot.run[at]);
                    let win = ((clip.x0, clip.x1), f, x0);
                    // SAFETY: `AVX512` is true only in the AVX-512 tier's
                    // wrapper, which runs only on CPUs with avx512f.
                    unsafe {
                        match slot.case {
                            PushCase::First => clipped_push_avx512::<CLAMP, 0>(src, src_x0, win, ring, run, limit),
                            PushCase::Filling => clipped_push_avx512::<CLAMP, 1>(src, src_x0, win, ring, run, limit),
                            PushCase::Steady => clipped_push_avx512::<CLAMP, 2>(src, src_x0, win, ring, run, limit),
                        }
                    }
                }
            }
            (whole, whole_from)
        } else {
            let (inner, from) = clipped_window_sums(src, src_x0, clip, f, dst_x0, h);
            slot.push::<CLAMP>(0, &h[..inner.start]);
            slot.push::<CLAMP>(inner.end, &h[inner.end..]);
            (inner, from)
        };
        if !inner.is_empty() {
            let src = &src[from..from + inner.len() + 2 * f as usize];
            let (ring, run) = (&mut slot.ring[inner.clone()], &mut slot.run[inner]);
            // SAFETY: `AVX512` is true only in the AVX-512 tier's wrapper,
            // which runs only on CPUs with avx512f.
            unsafe {
                match f {
                    1 => push_taps::<1, CLAMP>(slot.case, src, ring, run, limit),
                    2 => push_taps::<2, CLAMP>(slot.case, src, ring, run, limit),
                    3 => push_taps::<3, CLAMP>(slot.case, src, ring, run, limit),
                    _ => push_taps::<4, CLAMP>(slot.case, src, ring, run, limit),
                }
            }
        }
        return;
    }
    window_sums_row::<W>(src, src_x0, clip, f, dst_x0, h, pairs);
    b.pushed::<CLAMP>(y, y0, h);
}

/// [`kernels::taps_push_avx512`](super::kernels::taps_push_avx512) of
/// windows of `2F + 1` taps for the box row's push case.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn push_taps<const F: usize, const CLAMP: bool>(
    case: super::column_sums::PushCase,
    src: &[f32],
    ring: &mut [i32],
    run: &mut [i32],
    limit: f32,
) {
    use super::column_sums::PushCase;
    use super::kernels::taps_push_avx512;
    // SAFETY: the caller's.
    unsafe {
        match case {
            PushCase::First => taps_push_avx512::<F, CLAMP, 0>(src, ring, run, limit),
            PushCase::Filling => taps_push_avx512::<F, CLAMP, 1>(src, ring, run, limit),
            PushCase::Steady => taps_push_avx512::<F, CLAMP, 2>(src, ring, run, limit),
        }
    }
}

/// `out[i]`, the sum of `src[i..i + 2F + 1]`, from the pair sums
/// `pairs[j] = src[j] + src[j + 1]`: `((pairs[i] + pairs[i + 2]) + ...) + src[i + 2F]`
/// (`F + 1` adds per output instead of `2F`, the pairs shared by neighbours):
/// the [`rows_sum`] of `T = F + 1` rows, the pair rows and `src` shifted.
#[inline(always)]
fn pair_taps_sum<const W: usize, const F: usize, const T: usize>(src: &[f32], pairs: &mut [f32], out: &mut [f32]) {
    const { assert!(T == F + 1) };
    let n = out.len();
    let m = n + 2 * F - 2;
    let (a, b) = (&src[..m], &src[1..m + 1]);
    let pairs = &mut pairs[..m];
    if m < W {
        for (p, (x, y)) in pairs.iter_mut().zip(a.iter().zip(b)) {
            *p = *x + *y;
        }
    } else {
        for c in 0..chunk_count::<W>(m) {
            let i = chunk_start::<W>(c, m);
            let (mut x, y) = (*chunk::<W>(a, i), chunk::<W>(b, i));
            for k in 0..W {
                x[k] += y[k];
            }
            *chunk_mut::<W>(pairs, i) = x;
        }
    }
    let pairs: &[f32] = pairs;
    let mut rows: [&[f32]; T] = [&[]; T];
    for (k, row) in rows.iter_mut().enumerate() {
        *row = if k < F { &pairs[2 * k..2 * k + n] } else { &src[2 * F..2 * F + n] };
    }
    rows_sum::<W, T>(rows, out);
}

/// The weights of a row (columns from `x0`): `dst[i] = 2^t` with
/// `t = sums[i] * k / (nx * ny)`, where `sums` are the window sums (see
/// [`ColumnBox::window`]), turned into the weight's argument by the patch
/// mean's scale (as [`scale_by_count`]) in the same pass; with `GUIDED`,
/// `2^min(t, tf[i])`: `min(w_c, w_f)` with one exp. Each weight comes
/// times `2^e`, exactly (`e`: the weights' box's `s`, see
/// [`kernels::exp2_weight_scaled_lanes`](super::kernels::exp2_weight_scaled_lanes)).
#[inline(always)]
fn weight_row<const W: usize, const GUIDED: bool, const AVX512: bool>(
    sums: &[i32],
    dst: &mut [f32],
    tf: &[f32],
    (x0, clip, f, ny, k, e): (i64, Rect, i64, f32, f32, i32),
) {
    let n = dst.len();
    let sums = &sums[..n];
    // The guides' arguments are minima folded from 0: never NaN, never
    // above 0 (`kernels::weights_avx512` relies on it).
    debug_assert!(!GUIDED || tf[..n].iter().all(|g| *g <= 0.0), "a guide argument above 0 or NaN");
    let weight = |t: f32, tf: f32| exp2_weight_scaled_lanes([if GUIDED && tf < t { tf } else { t }], e)[0];
    let guide = |i: usize| if GUIDED { tf[i] } else { 0.0 };
    let (unclipped, clipped) = window_columns(x0, n, clip, f);
    let inner = k / ((2 * f + 1) as f32 * ny);
    let (u0, len) = (unclipped.start, unclipped.len());
    // (`AVX512` is never true off x86-64; the `cfg!` keeps the rows computed if it were.)
    if AVX512 && cfg!(target_arch = "x86_64") {
        #[cfg(target_arch = "x86_64")]
        {
            let tf = if GUIDED { &tf[unclipped.clone()] } else { &[][..] };
            // SAFETY: `AVX512` is true only in the AVX-512 tier's wrapper,
            // which runs only on CPUs with avx512f.
            unsafe { weights_avx512::<GUIDED>(&sums[unclipped.clone()], tf, &mut dst[unclipped], inner, e) };
            // The clipped columns (up to `2f`), up to 16 in one vector, each
            // with its own count's factor; the same bits as the scalar loop.
            let mut clipped = clipped.peekable();
            while clipped.peek().is_some() {
                let (mut at, mut s, mut fac, mut g) = ([0usize; 16], [0i32; 16], [0.0f32; 16], [0.0f32; 16]);
                let mut m = 0;
                for (i, nx) in clipped.by_ref().take(16) {
                    (at[m], s[m], fac[m], g[m]) = (i, sums[i], k / (nx * ny), guide(i));
                    m += 1;
                }
                let mut w = [0.0f32; 16];
                // SAFETY: as above.
                unsafe { weights_factors_avx512::<GUIDED>(&s[..m], &g[..m], &mut w[..m], &fac[..m], e) };
                for j in 0..m {
                    dst[at[j]] = w[j];
                }
            }
            return;
        }
    } else if len < W {
        for i in unclipped {
            dst[i] = weight(sums[i] as f32 * inner, guide(i));
        }
    } else {
        for c in 0..chunk_count::<W>(len) {
            let i = u0 + chunk_start::<W>(c, len);
            let (s, g) = (chunk_i32::<W>(sums, i), if GUIDED { *chunk::<W>(tf, i) } else { [0.0; W] });
            let t = lanes2(s.map(|v| v as f32), g, |s, g| {
                let t = s * inner;
                if GUIDED && g < t { g } else { t }
            });
            *chunk_mut::<W>(dst, i) = exp2_weight_scaled_lanes(t, e);
        }
    }
    for (i, nx) in clipped {
        dst[i] = weight(sums[i] as f32 * (k / (nx * ny)), guide(i));
    }
}

/// The columns `x0..x0 + len` split by their window `[x - f, x + f] ∩ clip`:
/// the index range of the columns whose window is whole, and each other
/// column's index with its clipped window width.
#[inline(always)]
fn window_columns(
    x0: i64,
    len: usize,
    clip: Rect,
    f: i64,
) -> (std::ops::Range<usize>, impl Iterator<Item = (usize, f32)>) {
    let x1 = x0 + len as i64;
    let inner_x0 = (clip.x0 + f).clamp(x0, x1);
    let inner_x1 = (clip.x1 - f).clamp(inner_x0, x1);
    let clipped = (x0..inner_x0)
        .chain(inner_x1..x1)
        .map(move |x| ((x - x0) as usize, ((x + f).min(clip.x1 - 1) - (x - f).max(clip.x0) + 1) as f32));
    ((inner_x0 - x0) as usize..(inner_x1 - x0) as usize, clipped)
}

/// Accumulate one row `y` of mean weights of every lane of a group (offsets
/// `(lane.dx, dy)`, in lane order) into the block's numerators and denominator.
///
/// Each numerator and the denominator receive the lanes' terms in lane order
/// whichever loop handles the pixel, so the result equals accumulating the
/// offsets one after the other.
#[inline(always)]
fn accumulate<const W: usize, const AVX512: bool, T: WeightSample>(
    num: &mut [Aligned],
    den: &mut [f32],
    values: &[&Plane],
    rows: &[LaneRow<'_, T>],
    (y, dy, block): (i64, i64, Rect),
) {
    let row_off = (y - block.y0) as usize * block.width();
    let end = |l: &LaneRow<'_, T>| l.x0 + l.w.len() as i64;
    // Columns every lane covers take the fused path; the others (next to the
    // frame's edges) add each covering lane's terms in lane order.
    let (c0, c1) = (rows.iter().map(|l| l.x0).max().unwrap_or(0), rows.iter().map(end).min().unwrap_or(0));
    let (u0, u1) = (rows.iter().map(|l| l.x0).min().unwrap_or(0), rows.iter().map(end).max().unwrap_or(0));
    let c1 = c1.max(c0);
    for x in (u0..c0.min(u1)).chain(c1.max(u0)..u1) {
        let i = row_off + (x - block.x0) as usize;
        for l in rows.iter().filter(|l| l.x0 <= x && x < end(l)) {
            let k = (x - l.x0) as usize;
            let w = l.w[k].value();
            den[i] += w;
            for (c, n) in num.iter_mut().enumerate() {
                n[i] = w.mul_add(values[c].row(y + dy, x + l.dx, x + l.dx + 1)[0], n[i]);
            }
        }
    }
    if c1 > c0 {
        let span = row_off + (c0 - block.x0) as usize..row_off + (c1 - block.x0) as usize;
        // One arm per group size: GROUP_MAX must stay 7 for this match.
        const _: () = assert!(GROUP_MAX == 7);
        let at = ((y, dy), c0, c1, span);
        match rows.len() {
            1 => accumulate_span::<W, 1, AVX512, T>(num, den, values, rows, at),
            2 => accumulate_span::<W, 2, AVX512, T>(num, den, values, rows, at),
            3 => accumulate_span::<W, 3, AVX512, T>(num, den, values, rows, at),
            4 => accumulate_span::<W, 4, AVX512, T>(num, den, values, rows, at),
            5 => accumulate_span::<W, 5, AVX512, T>(num, den, values, rows, at),
            6 => accumulate_span::<W, 6, AVX512, T>(num, den, values, rows, at),
            _ => accumulate_span::<W, GROUP_MAX, AVX512, T>(num, den, values, rows, at),
        }
    }
}

/// The fused accumulation over columns `[c0, c1)` that all `G` lanes cover.
#[inline(always)]
#[allow(clippy::type_complexity)]
fn accumulate_span<const W: usize, const G: usize, const AVX512: bool, T: WeightSample>(
    num: &mut [Aligned],
    den: &mut [f32],
    values: &[&Plane],
    rows: &[LaneRow<'_, T>],
    ((y, dy), c0, c1, span): ((i64, i64), i64, i64, std::ops::Range<usize>),
) {
    let n = (c1 - c0) as usize;
    let mut w: [&[T]; G] = [&[]; G];
    for g in 0..G {
        let (row, from) = (&rows[g], (c0 - rows[g].x0) as usize);
        w[g] = &row.w[from..][..n];
    }
    let q = |c: usize| lane_values::<G, T>(values[c], rows, y + dy, c0, c1);
    let d = &mut den[span.clone()];
    #[cfg(target_arch = "x86_64")]
    if AVX512
        && G >= 2
        && let [n0, n1, n2] = num
        && let Some((dmin, rev)) = consecutive_dx(rows)
    {
        // The lanes read one row per channel at consecutive shifts: two
        // loads per vector and register shifts instead of a load per lane.
        let row = |c: usize| values[c].row(y + dy, c0 + dmin, c1 + dmin + G as i64 - 1);
        let (n0, n1, n2) = (&mut n0[span.clone()], &mut n1[span.clone()], &mut n2[span]);
        let rows3 = [row(0), row(1), row(2)];
        // SAFETY: `AVX512` is true only in the AVX-512 tier's wrapper, which
        // runs only on CPUs with avx512f and fma.
        unsafe {
            let none = SideFactors::NONE;
            if rev {
                fused_rgb_shifted_avx512::<G, true, false, T>([d, n0, n1, n2], w, rows3, none);
            } else {
                fused_rgb_shifted_avx512::<G, false, false, T>([d, n0, n1, n2], w, rows3, none);
            }
        }
        return;
    }
    if let [n0, n1, n2] = num {
        // The common case, in one pass: each weight is loaded once.
        let (n0, n1, n2) = (&mut n0[span.clone()], &mut n1[span.clone()], &mut n2[span]);
        fused_rgb::<W, G, T>([d, n0, n1, n2], w, [q(0), q(1), q(2)]);
    } else {
        for i in 0..n {
            let mut dd = d[i];
            for wg in &w {
                dd += wg[i].value();
            }
            d[i] = dd;
        }
        for (c, nc) in num.iter_mut().enumerate() {
            let (nc, qc) = (&mut nc[span.clone()], q(c));
            for i in 0..n {
                let mut a = nc[i];
                for g in 0..G {
                    a = w[g][i].value().mul_add(qc[g][i], a);
                }
                nc[i] = a;
            }
        }
    }
}

/// When the lanes' `dx` are consecutive (`dx_g = dx_0 + g` or `dx_0 - g`,
/// as in a whole group of the schedule), the smallest `dx` and whether they
/// decrease.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn consecutive_dx<T>(rows: &[LaneRow<'_, T>]) -> Option<(i64, bool)> {
    let s = rows[1].dx - rows[0].dx;
    if (s != 1 && s != -1) || !rows.windows(2).all(|r| r[1].dx - r[0].dx == s) {
        return None;
    }
    Some((rows.iter().map(|r| r.dx).min()?, s == -1))
}

/// Row `y` of `plane` over columns `c0..c1` shifted by each lane's `dx`.
#[inline(always)]
fn lane_values<'a, const G: usize, T>(
    plane: &'a Plane,
    rows: &[LaneRow<'_, T>],
    y: i64,
    c0: i64,
    c1: i64,
) -> [&'a [f32]; G] {
    let mut q: [&[f32]; G] = [&[]; G];
    for (qg, row) in q.iter_mut().zip(rows) {
        *qg = plane.row(y, c0 + row.dx, c1 + row.dx);
    }
    q
}

/// `den += w_g` and `num_c += w_g * q_cg` for `g` in order, three channels
/// (separate `&mut` arguments: the compiler knows they do not alias).
#[inline(always)]
fn fused_rgb<const W: usize, const G: usize, T: WeightSample>(
    [d, n0, n1, n2]: [&mut [f32]; 4],
    w: [&[T]; G],
    [q0, q1, q2]: [[&[f32]; G]; 3],
) {
    let n = d.len();
    let (n0, n1, n2) = (&mut n0[..n], &mut n1[..n], &mut n2[..n]);
    let (w, q0, q1, q2) = (cut(w, n), cut(q0, n), cut(q1, n), cut(q2, n));
    // Whole chunks (an update in place: no overlapping last chunk), then
    // the remaining samples one by one with the same operations.
    let whole = n / W * W;
    for c in 0..whole / W {
        let i = c * W;
        let (mut dd, mut a0, mut a1, mut a2) =
            (*chunk::<W>(d, i), *chunk::<W>(n0, i), *chunk::<W>(n1, i), *chunk::<W>(n2, i));
        for g in 0..G {
            let (wg, x0, x1, x2) =
                (chunk_of::<T, W>(w[g], i), chunk::<W>(q0[g], i), chunk::<W>(q1[g], i), chunk::<W>(q2[g], i));
            for k in 0..W {
                let wk = wg[k].value();
                dd[k] += wk;
                a0[k] = wk.mul_add(x0[k], a0[k]);
                a1[k] = wk.mul_add(x1[k], a1[k]);
                a2[k] = wk.mul_add(x2[k], a2[k]);
            }
        }
        (*chunk_mut::<W>(d, i), *chunk_mut::<W>(n0, i), *chunk_mut::<W>(n1, i), *chunk_mut::<W>(n2, i)) =
            (dd, a0, a1, a2);
    }
    for i in whole..n {
        let (mut dd, mut a0, mut a1, mut a2) = (d[i], n0[i], n1[i], n2[i]);
        for g in 0..G {
            let wg = w[g][i].value();
            dd += wg;
            a0 = wg.mul_add(q0[g][i], a0);
            a1 = wg.mul_add(q1[g][i], a1);
            a2 = wg.mul_add(q2[g][i], a2);
        }
        (d[i], n0[i], n1[i], n2[i]) = (dd, a0, a1, a2);
    }
}

/// Turn window sums into (scaled) means: multiply by `k / (nx * ny)`, where
/// `nx` is the clipped window width of each column (from `x0`) and `ny` the
/// row's window height; the factor is computed once per distinct count.
#[inline(always)]
fn scale_by_count(row: &mut [f32], x0: i64, clip: Rect, f: i64, ny: f32, k: f32) {
    let (unclipped, clipped) = window_columns(x0, row.len(), clip, f);
    let inner = k / ((2 * f + 1) as f32 * ny);
    // Multiplying by exactly 1 changes no bit: skipped.
    if inner != 1.0 {
        for v in &mut row[unclipped] {
            *v *= inner;
        }
    }
    for (i, nx) in clipped {
        row[i] *= k / (nx * ny);
    }
}

/// The guides' weight argument `t_f = -log2(e) max(0, max_j Phi_j^2)` of
/// step row `y` for every lane whose weight row it is (lane `g` of side `s`
/// into `tf[s * GROUP_MAX + g]`; each feature's `inv_den` already holds
/// `-log2(e) / channels`): one pass per feature and row, folded by a minimum.
#[inline(always)]
fn guide_rows<const W: usize, const AVX512: bool, const AVX2: bool>(
    features: &[GuideFeature],
    sides: &[Side<'_>; 2],
    pairs: Option<&[PairLane]>,
    y: i64,
    tf: &mut [Aligned],
    square_sums: &mut [f32],
) {
    let dy = sides[0].dy;
    match pairs {
        None => {
            if !in_rows(sides[0].w_y, y) {
                return;
            }
            for (lane, row) in sides[0].lanes.iter().zip(tf.iter_mut()) {
                let row = &mut row[..lane.w.width()];
                for (j, feat) in features.iter().enumerate() {
                    fold_feature_row::<W>(row, feat, (y, dy, lane.w.x0, lane.w.x1, lane.dx, j == 0));
                }
            }
        }
        Some(pairs) => {
            let (tf_fwd, tf_mir) = tf.split_at_mut(GROUP_MAX);
            let (fwd_row, mir_row) = (in_rows(sides[0].w_y, y), in_rows(sides[1].w_y, y + dy));
            for pair in pairs {
                let fwd = match pair.fwd {
                    Some(g) if fwd_row => Some((sides[0].lanes[g].w, &mut *tf_fwd[g])),
                    _ => None,
                };
                let mir = match pair.mir {
                    Some(g) if mir_row => Some((sides[1].lanes[g].w, &mut *tf_mir[g])),
                    _ => None,
                };
                pair_feature_row::<W, AVX512, AVX2>(features, (pair.dx, dy), y, fwd, mir, square_sums);
            }
        }
    }
}

/// One feature's [`fold_feature_term`] on row `y` (columns `x0..x1`) for
/// offset `(dx, dy)`, into `out` (from 0 when `first`).
#[inline(always)]
fn fold_feature_row<const W: usize>(out: &mut [f32], feat: &GuideFeature, at: (i64, i64, i64, i64, i64, bool)) {
    let (y, dy, x0, x1, dx, first) = at;
    match feat.values.len() {
        1 => fold_feature_rows::<W, 1>(out, feat, at),
        2 => fold_feature_rows::<W, 2>(out, feat, at),
        3 => fold_feature_rows::<W, 3>(out, feat, at),
        4 => fold_feature_rows::<W, 4>(out, feat, at),
        _ => {
            let (fp, fq) = (all_rows(&feat.values, y, x0, x1), all_rows(&feat.values, y + dy, x0 + dx, x1 + dx));
            let var = feat.variance.as_ref().map(|v| (all_rows(v, y, x0, x1), all_rows(v, y + dy, x0 + dx, x1 + dx)));
            let inv_den = all_rows(&feat.inv_den, y, x0, x1);
            let var = var.as_ref().map(|(p, q)| (&p[..], &q[..]));
            fold_feature_term_any(out, &fp, &fq, var, &inv_den, first);
        }
    }
}

/// One feature's [`fold_feature_term`] on row `y` (columns `x0..x1`) for
/// offset `(dx, dy)`, the feature's `C` channels as arrays.
#[inline(always)]
fn fold_feature_rows<const W: usize, const C: usize>(
    out: &mut [f32],
    feat: &GuideFeature,
    (y, dy, x0, x1, dx, first): (i64, i64, i64, i64, i64, bool),
) {
    let last = feat.inv_den.len() - 1;
    // A `match`, not `Option::map`: the closure would stay an out-of-line call.
    #[allow(clippy::manual_map)]
    let rows = FeatureRows::<C> {
        fp: channel_rows(&feat.values, y, x0, x1),
        fq: channel_rows(&feat.values, y + dy, x0 + dx, x1 + dx),
        var: match &feat.variance {
            Some(v) => Some((channel_rows(v, y, x0, x1), channel_rows(v, y + dy, x0 + dx, x1 + dx))),
            None => None,
        },
        inv_den: {
            let mut inv: [&[f32]; C] = [&[]; C];
            for (c, r) in inv.iter_mut().enumerate() {
                *r = feat.inv_den[c.min(last)].row(y, x0, x1);
            }
            inv
        },
    };
    if first { fold_feature_term::<W, C, true>(out, &rows) } else { fold_feature_term::<W, C, false>(out, &rows) }
}

/// The guides' weight argument of the offsets `n = (dx, dy)` and `-n`
/// together, for the pairs `(p, p + n)` with `p` in row `y`: the forward
/// lane's row `y` (columns `fwd.0`, pixels `p`) and the mirror lane's row
/// `y + dy` (columns `mir.0`, pixels `p + n`). A guide without variance
/// gives one square sum per pixel pair ([`feature_square_sum`], the same
/// bits either way) that each lane multiplies by its own pixel's
/// denominator; a guide with variance (whose numerators differ) gives each
/// lane's terms as [`fold_feature_row`] does. `square_sums` holds one row
/// per guide. On the AVX-512 tier, guides without variance skip the stored
/// row: [`fused_guide_products`], the same bits.
#[inline(always)]
fn pair_feature_row<const W: usize, const AVX512: bool, const AVX2: bool>(
    features: &[GuideFeature],
    (dx, dy): (i64, i64),
    y: i64,
    fwd: Option<(Rect, &mut [f32])>,
    mir: Option<(Rect, &mut [f32])>,
    square_sums: &mut [f32],
) {
    // The columns of the pixels `p` either lane needs.
    let xf = fwd.as_ref().map(|(r, _)| (r.x0, r.x1));
    let xm = mir.as_ref().map(|(r, _)| (r.x0 - dx, r.x1 - dx));
    let (x0, x1) = match (xf, xm) {
        (Some(a), Some(b)) => (a.0.min(b.0), a.1.max(b.1)),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => return,
    };
    // The lanes are handed back when the one-pass kernel does not apply.
    #[cfg(target_arch = "x86_64")]
    let (fwd, mir) = match AVX512 && x1 - x0 >= CHUNK_AVX512 as i64 {
        true => match fused_guide_products(features, (dx, dy), y, (x0, (x1 - x0) as usize), fwd, mir) {
            Some(lanes) => lanes,
            None => return,
        },
        false => (fwd, mir),
    };
    #[cfg(target_arch = "x86_64")]
    let (fwd, mir) = match AVX512 && x1 - x0 >= 16 {
        true => match paired_variance_guides(features, (dx, dy), y, (x0, x1), fwd, mir) {
            Some(lanes) => lanes,
            None => return,
        },
        false => (fwd, mir),
    };
    pair_feature_row_stored::<W, AVX512, AVX2>(features, (dx, dy), y, (x0, x1), fwd, mir, square_sums);
}

/// [`pair_feature_row`] on the AVX-512 tier in one pass
/// ([`guide_pair_products_avx512`]) when no guide has a variance (at most
/// [`PRODUCTS_MAX`] guides of at most [`PAIR_GUIDE_CHANNELS_MAX`] channels
/// in all), each guide read as half floats when it has them: the same bits
/// as the stored square sums. Else hands the lanes back. `w >=
/// CHUNK_AVX512` samples from column `x0`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::type_complexity)]
fn fused_guide_products<'r>(
    features: &[GuideFeature],
    (dx, dy): (i64, i64),
    y: i64,
    (x0, w): (i64, usize),
    fwd: Option<(Rect, &'r mut [f32])>,
    mir: Option<(Rect, &'r mut [f32])>,
) -> Option<(Option<(Rect, &'r mut [f32])>, Option<(Rect, &'r mut [f32])>)> {
    let k = features.len();
    let channels: usize = features.iter().map(|f| f.values.len()).sum();
    let fits = (1..=PRODUCTS_MAX).contains(&k)
        && channels <= PAIR_GUIDE_CHANNELS_MAX
        && features.iter().all(|f| f.variance.is_none() && !f.values.is_empty());
    if !fits {
        return Some((fwd, mir));
    }
    let x1 = x0 + w as i64;
    // Each channel's rows at `p` and at `p + n`, guide by guide.
    let mut ends = [0usize; PRODUCTS_MAX];
    let none = GuideRow::Full(&[]);
    let (mut fp, mut fq) = ([none; PAIR_GUIDE_CHANNELS_MAX], [none; PAIR_GUIDE_CHANNELS_MAX]);
    let mut c = 0;
    for (g, feat) in features.iter().enumerate() {
        for (ch, plane) in feat.values.iter().enumerate() {
            (fp[c], fq[c]) = match &feat.half {
                Some(half) => {
                    let h = &half[ch];
                    (GuideRow::Half(h.row(y, x0, x1)), GuideRow::Half(h.row(y + dy, x0 + dx, x1 + dx)))
                }
                None => (GuideRow::Full(plane.row(y, x0, x1)), GuideRow::Full(plane.row(y + dy, x0 + dx, x1 + dx))),
            };
            c += 1;
        }
        ends[g] = c;
    }
    // A lane's pixels `p`: its own columns (forward), or its columns minus
    // `dx` (mirror, whose pixels are `p + n`, in row `y + dy`).
    let lane = |lane: Option<(Rect, &'r mut [f32])>, ly: i64, shift: i64| {
        lane.map(|(r, row)| {
            let mut inv: [&[f32]; PRODUCTS_MAX] = [&[]; PRODUCTS_MAX];
            for (i, feat) in inv.iter_mut().zip(features) {
                *i = feat.inv_den[0].row(ly, r.x0, r.x1);
            }
            ProductLane { from: (r.x0 - shift - x0) as usize, out: &mut row[..r.width()], inv }
        })
    };
    let lanes = [lane(fwd, y, 0), lane(mir, y + dy, dx)];
    // SAFETY: `AVX512` is true only in the AVX-512 tier's wrapper, which
    // runs only on CPUs with avx512f.
    unsafe { guide_pair_products_avx512(w, (&fp[..c], &fq[..c]), &ends[..k], lanes) };
    None
}

/// [`pair_feature_row`] on the AVX-512 tier when every guide has a variance
/// (as real renders' features do) of 1 to 4 channels: each guide's terms of
/// both lanes in one pass ([`guide_variance_pair_avx512`]), guide after guide
/// in order, as the per-lane passes fold them: the same bits. Else hands the
/// lanes back. Columns `x0..x1` of the pixels `p`, at least 16.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::type_complexity)]
fn paired_variance_guides<'r>(
    features: &[GuideFeature],
    (dx, dy): (i64, i64),
    y: i64,
    (x0, x1): (i64, i64),
    fwd: Option<(Rect, &'r mut [f32])>,
    mir: Option<(Rect, &'r mut [f32])>,
) -> Option<(Option<(Rect, &'r mut [f32])>, Option<(Rect, &'r mut [f32])>)> {
    let fits = !features.is_empty()
        && features.iter().all(|f| f.variance.is_some() && (1..=PRODUCTS_MAX).contains(&f.values.len()));
    if !fits {
        return Some((fwd, mir));
    }
    let (mut fwd, mut mir) = (fwd, mir);
    for (j, feat) in features.iter().enumerate() {
        match feat.values.len() {
            1 => paired_variance_guide::<1>(feat, (dx, dy), y, (x0, x1), j == 0, (&mut fwd, &mut mir)),
            2 => paired_variance_guide::<2>(feat, (dx, dy), y, (x0, x1), j == 0, (&mut fwd, &mut mir)),
            3 => paired_variance_guide::<3>(feat, (dx, dy), y, (x0, x1), j == 0, (&mut fwd, &mut mir)),
            _ => paired_variance_guide::<4>(feat, (dx, dy), y, (x0, x1), j == 0, (&mut fwd, &mut mir)),
        }
    }
    None
}

/// One guide of [`paired_variance_guides`], `C` channels.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::type_complexity)]
fn paired_variance_guide<const C: usize>(
    feat: &GuideFeature,
    (dx, dy): (i64, i64),
    y: i64,
    (x0, x1): (i64, i64),
    first: bool,
    (fwd, mir): (&mut Option<(Rect, &mut [f32])>, &mut Option<(Rect, &mut [f32])>),
) {
    let var = feat.variance.as_ref().expect("a guide with variance");
    let (fp, fq) =
        (channel_rows::<C>(&feat.values, y, x0, x1), channel_rows::<C>(&feat.values, y + dy, x0 + dx, x1 + dx));
    let (vp, vq) = (channel_rows::<C>(var, y, x0, x1), channel_rows::<C>(var, y + dy, x0 + dx, x1 + dx));
    // A lane's pixels: its own columns in its own row; the mirror's pixels
    // `p + n` lie `dx` columns right of their `p`.
    fn lane<'a, const C: usize>(
        lane: &'a mut Option<(Rect, &mut [f32])>,
        feat: &'a GuideFeature,
        (ly, shift, x0): (i64, i64, i64),
    ) -> Option<VarianceLane<'a, C>> {
        let last = feat.inv_den.len() - 1;
        lane.as_mut().map(|(r, row)| {
            let mut inv: [&[f32]; C] = [&[]; C];
            for (c, i) in inv.iter_mut().enumerate() {
                *i = feat.inv_den[c.min(last)].row(ly, r.x0, r.x1);
            }
            ((r.x0 - shift - x0) as usize, &mut row[..r.width()], inv)
        })
    }
    let lanes = [lane::<C>(fwd, feat, (y, 0, x0)), lane::<C>(mir, feat, (y + dy, dx, x0))];
    // SAFETY: `AVX512` is true only in the AVX-512 tier's wrapper, which
    // runs only on CPUs with avx512f.
    unsafe { guide_variance_pair_avx512::<C>((x1 - x0) as usize, (&fp, &fq), (&vp, &vq), first, lanes) };
}

/// [`pair_feature_row`] through stored square sums, one row per guide.
#[inline(always)]
#[allow(clippy::type_complexity)]
fn pair_feature_row_stored<const W: usize, const AVX512: bool, const AVX2: bool>(
    features: &[GuideFeature],
    (dx, dy): (i64, i64),
    y: i64,
    (x0, x1): (i64, i64),
    fwd: Option<(Rect, &mut [f32])>,
    mir: Option<(Rect, &mut [f32])>,
    square_sums: &mut [f32],
) {
    let w = (x1 - x0) as usize;
    for (j, feat) in features.iter().enumerate().filter(|(_, f)| f.variance.is_none()) {
        let out = &mut square_sums[j * w..(j + 1) * w];
        let at = (y, dy, x0, x1, dx);
        match feat.values.len() {
            1 => square_sum_rows::<W, 1, AVX512, AVX2>(out, feat, at),
            2 => square_sum_rows::<W, 2, AVX512, AVX2>(out, feat, at),
            3 => square_sum_rows::<W, 3, AVX512, AVX2>(out, feat, at),
            4 => square_sum_rows::<W, 4, AVX512, AVX2>(out, feat, at),
            _ => {
                let fp = all_rows(&feat.values, y, x0, x1);
                let fq = all_rows(&feat.values, y + dy, x0 + dx, x1 + dx);
                feature_square_sum_any(out, &fp, &fq);
            }
        }
    }
    // Each lane: its own row, columns and offset. The guides with variance
    // first, then the products of the others in one pass per (at most)
    // `PRODUCTS_MAX` guides: the minimum is exact, so only the sign of a
    // zero can depend on the order, and the weight `2^min(t_c, t_f)` is the
    // same for either sign.
    for (lane, mirror) in [(fwd, false), (mir, true)] {
        let Some((r, row)) = lane else { continue };
        let row = &mut row[..r.width()];
        let (ly, ldx, ldy, from) = if mirror { (y + dy, -dx, -dy, r.x0 - dx - x0) } else { (y, dx, dy, r.x0 - x0) };
        let mut first = true;
        for feat in features.iter().filter(|f| f.variance.is_some()) {
            fold_feature_row::<W>(row, feat, (ly, ldy, r.x0, r.x1, ldx, first));
            first = false;
        }
        let (mut sums, mut invs) = ([&[][..]; PRODUCTS_MAX], [&[][..]; PRODUCTS_MAX]);
        let mut k = 0;
        for (j, feat) in features.iter().enumerate().filter(|(_, f)| f.variance.is_none()) {
            sums[k] = &square_sums[j * w + from as usize..][..r.width()];
            invs[k] = feat.inv_den[0].row(ly, r.x0, r.x1);
            k += 1;
            if k == PRODUCTS_MAX {
                fold_feature_products::<W>(row, &sums, &invs, first);
                (k, first) = (0, false);
            }
        }
        if k > 0 {
            fold_feature_products::<W>(row, &sums[..k], &invs[..k], first);
        }
    }
}

/// One feature's [`feature_square_sum`] on row `y` (columns `x0..x1`) for
/// offset `(dx, dy)`, the feature's `C` channels as arrays; on the AVX-512
/// tier from its half floats when it has them (the same bits).
#[inline(always)]
fn square_sum_rows<const W: usize, const C: usize, const AVX512: bool, const AVX2: bool>(
    out: &mut [f32],
    feat: &GuideFeature,
    (y, dy, x0, x1, dx): (i64, i64, i64, i64, i64),
) {
    #[cfg(target_arch = "x86_64")]
    if let (true, Some(half)) = (AVX512 || AVX2, &feat.half) {
        let (mut fp, mut fq): ([&[half::f16]; C], [&[half::f16]; C]) = ([&[]; C], [&[]; C]);
        for c in 0..C {
            (fp[c], fq[c]) = (half[c].row(y, x0, x1), half[c].row(y + dy, x0 + dx, x1 + dx));
        }
        if AVX512 {
            // SAFETY: `AVX512` is true only in the AVX-512 tier's wrapper,
            // which runs only on CPUs with avx512f.
            unsafe { feature_square_sum_half_avx512::<C>(out, fp, fq) };
        } else {
            // SAFETY: `AVX2` is true only in the AVX2 tier's wrapper,
            // which runs only on CPUs with avx2, fma and f16c.
            unsafe { feature_square_sum_half_avx2::<C>(out, fp, fq) };
        }
        return;
    }
    feature_square_sum::<W, C>(
        out,
        channel_rows(&feat.values, y, x0, x1),
        channel_rows(&feat.values, y + dy, x0 + dx, x1 + dx),
    );
}

/// Row `y`, columns `x0..x1`, of each of the first `C` planes.
#[inline(always)]
fn channel_rows<const C: usize>(planes: &[Plane], y: i64, x0: i64, x1: i64) -> [&[f32]; C] {
    let mut rows: [&[f32]; C] = [&[]; C];
    for (row, plane) in rows.iter_mut().zip(planes) {
        *row = plane.row(y, x0, x1);
    }
    rows
}

/// Row `y`, columns `x0..x1`, of every plane.
fn all_rows(planes: &[Plane], y: i64, x0: i64, x1: i64) -> Vec<&[f32]> {
    planes.iter().map(|p| p.row(y, x0, x1)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tall blocks for one thread or wide tiles only; blocks cover a
    /// region once, none taller than asked.
    #[test]
    fn tall_blocks_for_one_thread_or_wide_tiles() {
        assert_eq!(block_rows(1, false), BLOCK_H_TALL);
        assert_eq!(block_rows(0, false), BLOCK_H_TALL);
        assert_eq!(block_rows(2, false), BLOCK_H);
        assert_eq!(block_rows(2, true), BLOCK_H_TALL);
        let frame = Rect::from_origin_size(-5, 3, 1920, 1080);
        // Two columns of blocks 960 wide (`BLOCK_W`), three or nine rows.
        assert_eq!(blocks(frame, BLOCK_H_TALL).len(), 2 * 3);
        assert_eq!(blocks(frame, BLOCK_H).len(), 2 * 9);
        for rows in [1, 7, BLOCK_H, BLOCK_H_TALL, 5000] {
            let b = blocks(frame, rows);
            assert_eq!(b.iter().map(|r| r.area()).sum::<usize>(), frame.area());
            assert!(b.iter().all(|r| r.height() <= rows && r.width() <= BLOCK_W && frame.contains_rect(r)));
        }
    }

    /// The AVX-512 fused push of window sums (3 to 9 taps) gives every box the
    /// rows (and so the window sums) of the portable path, sums stored then
    /// pushed: with and without the clamp (NaN, infinities and values past
    /// the clamp in the distances' rows), in each of the three push cases,
    /// for rows shorter than, equal to and not a multiple of a chunk, with
    /// a clipped column at each end.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn fused_push_gives_the_rows_of_the_stored_sums() {
        if !std::arch::is_x86_feature_detected!("avx512f") {
            eprintln!("skipped: this CPU has no AVX-512F");
            return;
        }
        // Patch radii 1 to 4 (windows of 3 to 9 taps); the box keeps `2f + 1` rows.
        fn check<const CLAMP: bool>(f: i64, q: Quantiser, value: &dyn Fn(u32) -> f32) {
            let cap = 2 * f as usize + 1;
            for n in (1..40).chain([47, 48, 49, 110, 129]) {
                let clip = Rect { x0: 2, x1: n as i64 + 6, y0: 0, y1: 30 };
                let (src_x0, dst_x0) = (0i64, 4i64);
                let mut boxes = [ColumnBox::new(n, cap, q), ColumnBox::new(n, cap, q)];
                let mut sums: [Vec<Vec<i32>>; 2] = [Vec::new(), Vec::new()];
                for y in 0..clip.y1 {
                    let src: Vec<f32> = (0..n as u32 + 12).map(|x| value(y as u32 * 1000 + x)).collect();
                    for (k, b) in boxes.iter_mut().enumerate() {
                        let (mut h, mut pairs) = (vec![0.0; n], vec![0.0; n + 12]);
                        let scratch = (&mut h[..], &mut pairs[..]);
                        if k == 0 {
                            push_window_sums::<CHUNK, true, CLAMP>(b, (y, 0), &src, src_x0, clip, f, dst_x0, scratch);
                        } else {
                            push_window_sums::<CHUNK, false, CLAMP>(b, (y, 0), &src, src_x0, clip, f, dst_x0, scratch);
                        }
                        if y >= f {
                            sums[k].push(b.window(0, y - f, clip, f, n).1.to_vec());
                        }
                    }
                }
                assert_eq!(sums[0], sums[1], "f = {f}, n = {n}, clamp {CLAMP}");
                assert!(sums[0].iter().flatten().any(|s| *s != 0), "f = {f}, n = {n}: the sums are not all zero");
            }
        }
        // Distances: mixed magnitudes and signs, scaled by the box's `2^s`,
        // and some samples NaN, infinite or past the clamp.
        for f in 1..=4 {
            let cap = 2 * f as usize + 1;
            let q = Quantiser::distances(cap, 3, 1.0, 0.2025);
            check::<true>(f, q, &|i| match i.wrapping_mul(2_654_435_761) % 97 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => -1e30,
                3 => 1e9,
                h => (h as f32 * 0.37 - 12.0) * q.scale() * if i % 5 == 0 { 1e-3 } else { 1.0 },
            });
            // Weights: in `[0, 1]`, scaled by `2^s` (inside the clamp, unclamped).
            let q = Quantiser::weights(cap);
            check::<false>(f, q, &|i| (i.wrapping_mul(2_654_435_761) % 1000) as f32 * 1e-3 * q.scale());
        }
    }
}
