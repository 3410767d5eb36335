//! Vertical window sums of a lane's rows (the second half of each separable
//! box of SPEC §4), exact, so that no summation order can show in the bits.
//!
//! A lane's box receives rows `h` (the horizontal window sums of its
//! distances or weights, `f32`) one after the other. Each row is first
//! *quantised*: `q = round(clamp(h, -H, H) * 2^s)` as a 32-bit integer,
//! with `H` and `s` fixed by the box's [`Quantiser`] (a function of the
//! filter's parameters, never of a tile or a block). The rows arrive
//! already scaled by `2^s` (their producers fold the power of two into
//! their own constants, an exact scaling: see [`Quantiser::scale`]), so
//! the box only clamps (distances; the weights' rows cannot leave the
//! range) and rounds. Integer sums are exact
//! whatever their order, so the vertical window sums are kept as a running
//! sum `R(y) = R(y - 1) + q(y) - q(y - 2f - 1)`: two integer operations per
//! sample, one pass per row, whichever row a block or tile starts at. A
//! window's sum is `R` (or, for a window clipped by the offset's valid
//! rectangle, the exact sum of its rows): the distances' box hands it to
//! the weight's loop as an integer, which scales it by `2^-s` with the patch
//! mean's factor (one multiply); the weights' box hands `R` to the
//! accumulation, which reads it as `f32(R)` (since session 24; a stored
//! `f32` copy before), the
//! mean weights in units of `2^-s` (numerators and
//! denominator share the unit, which cancels exactly in their ratio: a power
//! of two; with `filter::repair`'s bound of 1e18 on values, a numerator
//! stays below `441 * 49 * 2^25 * 1e18 < 1e30` at `r = 10`, `f = 3`). Either is a function of the window's quantised rows alone: the
//! same bits in every block, tile, lane and tier, as SPEC §6 requires
//! ("anchor the running sums to frame coordinates": exact sums need no
//! anchor).
//!
//! This replaced (session 23, docs/performance.md) the anchored `f32`
//! prefix and suffix sums (van Herk / Gil-Werman) with one pass per row,
//! instead of a prefix pass, a burst of suffix passes every `2f + 1` rows
//! and an add in every consumer.
//!
//! The quantisation's step and clamp are chosen so that it changes a
//! weight by a few parts per million at most (the clamp by nothing): see
//! [`Quantiser::distances`] and [`Quantiser::weights`] for the bounds,
//! tested below.

use super::nlmeans::{Aligned, stride};
use crate::geom::Rect;

/// How a box turns its `f32` rows into integers: `q = round(clamp(h, -H, H) * scale)`
/// with `scale = 2^s`, and back: `f32(sum) * inv` with `inv = 2^-s`. The
/// producer of the rows applies `scale` (see [`Quantiser::scale`]); the
/// box clamps and rounds.
///
/// `H` and `s` satisfy `T * H * 2^s < 2^31` (`T = 2f + 1` rows per window),
/// so no window sum can overflow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Quantiser {
    /// `H * 2^s`: the clamp, applied after the scale.
    limit: f32,
    scale: f32,
    inv: f32,
    /// `s`.
    exponent: i32,
}

impl Quantiser {
    /// The quantiser whose clamp is `h_max` (or one `f32` step below it),
    /// with the smallest step `2^-s` that keeps the sum of `T = cap` rows at
    /// the clamp below `2^31`.
    fn for_range(h_max: f64, cap: usize) -> Quantiser {
        // A guard for degenerate parameters (`k = 0`): the step stays a
        // normal power of two.
        let h = h_max.clamp(1.0, 2f64.powi(90));
        let s = ((2f64.powi(31) - 1.0) / (cap as f64 * h)).log2().floor() as i32;
        let scale = 2f64.powi(s);
        // `H * 2^s` below `2^31 / T` (an f32 just below it: no sum of `T` reaches `2^31`).
        let limit = (h * scale) as f32;
        let limit =
            if (limit as f64) * cap as f64 >= 2f64.powi(31) { f32::from_bits(limit.to_bits() - 1) } else { limit };
        Quantiser { limit, scale: scale as f32, inv: (1.0 / scale) as f32, exponent: s }
    }

    /// For a box of colour distances: rows `h` are horizontal sums of up to
    /// `T = 2f + 1` per-pixel distances `d`, each the sum over `channels`
    /// of SPEC §2's `d2_c >= -alpha / k^2` (so `h >= -T * channels * alpha / k^2`).
    ///
    /// The clamp changes no weight: a whole window whose sum holds one row
    /// clamped at `H` sums to at least `H - (T - 1) T channels alpha / k^2`,
    /// and `H` is twice what makes that sum's weight `2^-126`, the floor of
    /// `kernels::exp2_weight`, which the unclamped sum (larger) gives too.
    /// A clipped window is a sum over fewer samples divided by a smaller
    /// count: further below the floor. The quantisation error of a window's
    /// sum is at most `T * 2^-(s+1)`, at most `T * 2^-(s+1) / (T^2 channels)`
    /// in its patch mean: for `f = 3`, three channels and SPEC's `alpha` and
    /// `k`, the step is `2^-13` (tested), so below 3e-6 in the patch distance
    /// `D`, a relative change of at most 3e-6 in a weight `exp(-D)`.
    pub(super) fn distances(cap: usize, channels: usize, alpha: f32, k2: f32) -> Quantiser {
        let t = cap as f64;
        let c = channels.max(1) as f64;
        let dm = c * f64::from(alpha.max(0.0)) / f64::from(k2);
        let dm = if dm.is_finite() { dm } else { f64::MAX };
        // `exp2_weight`'s floor: a patch mean of at least 126 / log2(e).
        let floor = 126.0 / std::f64::consts::LOG2_E * c * t * t;
        Quantiser::for_range(2.0 * (floor + t * t * dm), cap)
    }

    /// For a box of weights: rows are horizontal sums of up to `T` weights
    /// in `[0, 1]` (`kernels::exp2_weight` is never NaN), so in `[0, T]`
    /// (each `f32` add rounds monotonically), inside the clamp at `T + 1`:
    /// the box pushes them with [`ColumnBox::pushed`]`::<false>`, no clamp.
    /// For `f = 3` the step is `2^-25`: a window's
    /// sum (at most 49) is within `7 * 2^-26` of the exact sum of its
    /// weights, the patches' mean weights within 2.1e-9 each.
    pub(super) fn weights(cap: usize) -> Quantiser {
        Quantiser::for_range(cap as f64 + 1.0, cap)
    }

    /// `round(clamp(x, -H 2^s, H 2^s))` of a row's sample `x = h 2^s`
    /// (already scaled), NaN to `-H 2^s`.
    #[inline(always)]
    fn quantise(&self, x: f32) -> i32 {
        // Two selects that compile to one `max` and one `min` (a NaN fails
        // the first comparison and lands on `-H 2^s`).
        let x = if x > -self.limit { x } else { -self.limit };
        let x = (if x < self.limit { x } else { self.limit }).round_ties_even();
        // SAFETY: `x` is an integer in `[-2^31 / T, 2^31 / T]`, not NaN.
        unsafe { x.to_int_unchecked::<i32>() }
    }

    /// `round(x)` of a scaled sample known to lie inside the clamp (a
    /// weights' row): [`Quantiser::quantise`] without its clamp, the same
    /// value there.
    #[inline(always)]
    fn rounded(&self, x: f32) -> i32 {
        debug_assert!(x > -self.limit && x < self.limit, "{x} outside the clamp {}", self.limit);
        // SAFETY: `x` lies in `(-2^31 / T, 2^31 / T)` (the caller's bound), not NaN.
        unsafe { x.round_ties_even().to_int_unchecked::<i32>() }
    }

    /// [`Quantiser::quantise`] with `CLAMP`, else [`Quantiser::rounded`].
    #[inline(always)]
    fn pushed_sample<const CLAMP: bool>(&self, x: f32) -> i32 {
        if CLAMP { self.quantise(x) } else { self.rounded(x) }
    }

    /// `2^s`, the factor the box's rows must already carry: the producer of
    /// a row of `h` hands the box `h * 2^s`. A product by a power of two is
    /// exact for normal numbers, and so is each step of a sum of such
    /// products, so a producer may fold it into its constants (the
    /// distances' `eps` and `k^2` divided by it, the weights' exponent
    /// raised by `s`, see [`Quantiser::exponent`]) and give the same bits
    /// as scaling its result.
    pub(super) fn scale(&self) -> f32 {
        self.scale
    }

    /// `s`, for producers that scale through an exponent.
    pub(super) fn exponent(&self) -> i32 {
        self.exponent
    }

    /// `H 2^s`, the clamp of scaled samples (see [`Quantiser::quantise`]).
    pub(super) fn limit(&self) -> f32 {
        self.limit
    }

    /// `2^-s`: a sum of quantised rows is worth `sum * 2^-s`.
    pub(super) fn step(&self) -> f32 {
        self.inv
    }
}

/// The rows of one lane's box (distances or weights) within a step, and
/// their running window sums.
pub(super) struct ColumnBox {
    /// The last `T` rows, quantised (row `y` in slot `(y - y0) % T`).
    ring: Aligned<i32>,
    /// The sum of the last `T` rows pushed (or of all rows, while fewer).
    run: Aligned<i32>,
    /// A clipped window's integer sums.
    clip_sums: Aligned<i32>,
    stride: usize,
    cap: usize,
    q: Quantiser,
    /// The frame row last pushed.
    last_row: i64,
}

impl ColumnBox {
    /// Buffers for rows of up to `width` samples and windows of `cap = 2f + 1` rows.
    pub(super) fn new(width: usize, cap: usize, q: Quantiser) -> ColumnBox {
        let st = stride(width);
        ColumnBox {
            ring: Aligned::zeroed(st * cap),
            run: Aligned::zeroed(st),
            clip_sums: Aligned::zeroed(st),
            stride: st,
            cap,
            q,
            last_row: i64::MIN,
        }
    }

    /// How the box quantises its rows.
    pub(super) fn quantiser(&self) -> Quantiser {
        self.q
    }

    /// Samples (4 bytes each) held: the ring, the running sums and a
    /// clipped window's sums.
    pub(super) fn samples(width: usize, cap: usize) -> u64 {
        (stride(width) * (cap + 2)) as u64
    }

    /// Push frame row `y` (`h`, `w = h.len()` samples already scaled by
    /// [`Quantiser::scale`]; `y0`: the step's first row of this box, rows
    /// pushed in order from it): quantise it into the ring and update the
    /// running sums, in one pass. With `CLAMP` false the samples must lie inside the clamp
    /// (a weights' box, see [`Quantiser::weights`]) and are only rounded.
    #[inline(always)]
    pub(super) fn pushed<const CLAMP: bool>(&mut self, y: i64, y0: i64, h: &[f32]) {
        let mut slot = self.slot(y, y0, h.len());
        slot.push::<CLAMP>(0, h);
    }

    /// The ring slot and running sums that row `y` (`w` samples, `y0` as
    /// [`ColumnBox::pushed`]) updates, for a producer that pushes its
    /// columns in parts ([`PushSlot::push`], or its own kernel doing the
    /// same per sample): every column of the row must be pushed once.
    #[inline(always)]
    pub(super) fn slot(&mut self, y: i64, y0: i64, w: usize) -> PushSlot<'_> {
        debug_assert!(y == y0 || y == self.last_row + 1, "row {y} pushed after {}", self.last_row);
        self.last_row = y;
        let k = (y - y0) as usize;
        let at = k % self.cap * self.stride;
        let case = if k == 0 {
            PushCase::First
        } else if k < self.cap {
            PushCase::Filling
        } else {
            PushCase::Steady
        };
        PushSlot { case, q: self.q, ring: &mut self.ring[at..at + w], run: &mut self.run[..w] }
    }

    /// Window sums of row `y` as `f32` in units of `2^-s`: the vertical sums over `[y - f, y + f] ∩ clip` (`y0`:
    /// the step's first row of this box); returns the window's height. A
    /// whole window's last row must be the last row pushed.
    #[inline(always)]
    pub(super) fn sums(&mut self, y0: i64, y: i64, clip: Rect, f: i64, out: &mut [f32]) -> f32 {
        let w = out.len();
        for (o, s) in out.iter_mut().zip(self.window(y0, y, clip, f, w).1) {
            *o = *s as f32;
        }
        self.height(y, clip, f)
    }

    /// The integer window sums of row `y` (as [`ColumnBox::sums`], `w`
    /// samples, worth `2^-s` each), with the window's height.
    #[inline(always)]
    pub(super) fn window(&mut self, y0: i64, y: i64, clip: Rect, f: i64, w: usize) -> (f32, &[i32]) {
        let ny = self.height(y, clip, f);
        let (a, b) = ((y - f).max(clip.y0), (y + f).min(clip.y1 - 1));
        let count = (b - a + 1) as usize;
        if count == self.cap {
            debug_assert_eq!(self.last_row, b, "a whole window is summed right after its last row");
            return (ny, &self.run[..w]);
        }
        (ny, self.clipped(y0, y, clip, f, count, w))
    }

    /// The height of row `y`'s window.
    #[inline(always)]
    fn height(&self, y: i64, clip: Rect, f: i64) -> f32 {
        ((y + f).min(clip.y1 - 1) - (y - f).max(clip.y0) + 1) as f32
    }

    /// A whole window's integer sums (`w` samples, worth `2^-s` each: the
    /// running sums themselves, which the accumulation reads and converts
    /// to `f32` as it goes), or the height of a clipped one.
    #[inline(always)]
    pub(super) fn whole(&self, y: i64, clip: Rect, f: i64, w: usize) -> Result<&[i32], usize> {
        let (a, b) = ((y - f).max(clip.y0), (y + f).min(clip.y1 - 1));
        let count = (b - a + 1) as usize;
        if count != self.cap {
            return Err(count);
        }
        debug_assert_eq!(self.last_row, b, "a whole window is summed right after its last row");
        Ok(&self.run[..w])
    }

    /// A clipped window's sums: its `count` rows' exact integer sum.
    #[inline(always)]
    fn clipped(&mut self, y0: i64, y: i64, clip: Rect, f: i64, count: usize, w: usize) -> &[i32] {
        let first = ((y - f).max(clip.y0) - y0) as usize;
        let acc = &mut self.clip_sums[..w];
        for k in 0..count {
            let at = (first + k) % self.cap * self.stride;
            let row = &self.ring[at..at + w];
            if k == 0 {
                acc.copy_from_slice(row);
            } else {
                for (a, r) in acc.iter_mut().zip(row) {
                    *a = a.wrapping_add(*r);
                }
            }
        }
        acc
    }
}

/// What a pushed row does to each column's running sum `R`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum PushCase {
    /// The step's first row: `R = q`.
    First,
    /// Fewer than `T` rows before it: `R += q`.
    Filling,
    /// The slot holds row `y - T`, which leaves the window: `R += q - q(y - T)`.
    Steady,
}

/// One row's ring slot and running sums (see [`ColumnBox::slot`]).
pub(super) struct PushSlot<'a> {
    pub(super) case: PushCase,
    pub(super) q: Quantiser,
    /// The ring slot: row `y - T` (in [`PushCase::Steady`]), to be replaced by row `y`.
    pub(super) ring: &'a mut [i32],
    /// The running sums.
    pub(super) run: &'a mut [i32],
}

impl PushSlot<'_> {
    /// Push columns `at..at + h.len()` of the row (`h` scaled as
    /// [`ColumnBox::pushed`] requires, clamped and rounded with `CLAMP`,
    /// else only rounded).
    #[inline(always)]
    pub(super) fn push<const CLAMP: bool>(&mut self, at: usize, h: &[f32]) {
        let q = self.q;
        let w = h.len();
        let (ring, run) = (&mut self.ring[at..at + w], &mut self.run[at..at + w]);
        match self.case {
            PushCase::First => {
                for ((r, s), x) in ring.iter_mut().zip(run.iter_mut()).zip(h) {
                    let v = q.pushed_sample::<CLAMP>(*x);
                    (*r, *s) = (v, v);
                }
            }
            PushCase::Filling => {
                for ((r, s), x) in ring.iter_mut().zip(run.iter_mut()).zip(h) {
                    let v = q.pushed_sample::<CLAMP>(*x);
                    (*r, *s) = (v, s.wrapping_add(v));
                }
            }
            PushCase::Steady => {
                for ((r, s), x) in ring.iter_mut().zip(run.iter_mut()).zip(h) {
                    let v = q.pushed_sample::<CLAMP>(*x);
                    (*r, *s) = (v, s.wrapping_add(v).wrapping_sub(*r));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::kernels::exp2_weight;

    /// Values whose `f32` sums would round differently in different orders.
    fn value(y: i64, i: usize) -> f32 {
        let s = ((y * 7919 + i as i64 * 104729) % 1000) as f32;
        (s * 0.001 + 1.0) * if (y + i as i64) % 3 == 0 { 1e3 } else { 1.1e-3 }
    }

    /// Push rows `y0..y1` (row `y` = `value(y)`, scaled by the quantiser's
    /// `2^s` as the kernel's producers hand them) and collect the integer
    /// and `f32` window sums of every row whose window is complete, as the
    /// kernel does; with `CLAMP` false, pushed unclamped (the rows must lie
    /// inside the clamp).
    fn run<const CLAMP: bool>(
        q: Quantiser,
        w: usize,
        f: i64,
        y0: i64,
        y1: i64,
        clip: Rect,
    ) -> Vec<(i64, Vec<i32>, Vec<f32>)> {
        let cap = (2 * f + 1) as usize;
        let mut b = ColumnBox::new(w, cap, q);
        let mut out = Vec::new();
        // Rows whose window lies in the rows pushed (or is clipped at the top).
        let mut next = if y0 == clip.y0 { y0 } else { y0 + f };
        for y in y0..y1 {
            let row: Vec<f32> = (0..w).map(|i| value(y, i) * q.scale()).collect();
            b.pushed::<CLAMP>(y, y0, &row);
            while next < y1 && (next + f).min(clip.y1 - 1) <= y {
                let mut floats = vec![0.0; w];
                b.sums(y0, next, clip, f, &mut floats);
                let ints = b.window(y0, next, clip, f, w).1.to_vec();
                out.push((next, ints, floats));
                next += 1;
            }
        }
        out
    }

    #[test]
    fn window_sums_are_the_exact_sums_of_the_quantised_rows_whatever_the_first_row() {
        for f in [0, 1, 2, 3, 5] {
            let cap = (2 * f + 1) as usize;
            let q = Quantiser::for_range(2000.0, cap);
            for w in [5, 16, 37, 150] {
                let clip = Rect { x0: 0, x1: w as i64, y0: -11, y1: 40 };
                for y0 in [-11, -9, -4, 0, 3, 6] {
                    let rows = run::<true>(q, w, f, y0, clip.y1, clip);
                    // The values lie inside the clamp: unclamped, the same sums.
                    assert_eq!(rows, run::<false>(q, w, f, y0, clip.y1, clip));
                    for (y, ints, floats) in rows {
                        let (a, b) = ((y - f).max(clip.y0), (y + f).min(clip.y1 - 1));
                        for i in 0..w {
                            let exact: i64 = (a..=b).map(|j| i64::from(q.quantise(value(j, i) * q.scale()))).sum();
                            assert_eq!(i64::from(ints[i]), exact, "f {f} w {w} first row {y0}: row {y} col {i}");
                            assert_eq!(floats[i].to_bits(), (exact as f32).to_bits(), "row {y} col {i}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn window_sums_are_within_half_a_step_per_row_of_the_real_sums() {
        let (f, w) = (3, 20);
        let q = Quantiser::for_range(2000.0, 7);
        let clip = Rect { x0: 0, x1: w as i64, y0: 0, y1: 30 };
        let rows = run::<true>(q, w, f, 0, 30, clip);
        assert_eq!(rows.len(), 30);
        for (y, ints, _) in rows {
            let (a, b) = ((y - f).max(0), (y + f).min(29));
            for (i, v) in ints.iter().enumerate() {
                let real: f64 = (a..=b).map(|j| value(j, i) as f64).sum();
                let bound = (b - a + 1) as f64 * 0.5 * q.step() as f64;
                let got = *v as f64 * q.step() as f64;
                assert!((got - real).abs() <= bound, "row {y} col {i}: {got} vs {real}");
            }
        }
    }

    #[test]
    fn quantise_clamps_and_maps_nan_to_the_lower_clamp() {
        let q = Quantiser::for_range(100.0, 7);
        let top = q.quantise(f32::INFINITY);
        assert_eq!(q.quantise(1e30), top);
        assert_eq!(q.quantise(-1e30), -top);
        assert_eq!(q.quantise(f32::NAN), -top);
        // No sum of `T` rows can overflow.
        assert!(7 * i64::from(top) < 1 << 31);
        assert!(f64::from(top) * f64::from(q.step()) >= 100.0);
    }

    /// The steps the docs state for SPEC's defaults (f = 3, three channels,
    /// alpha = 1, k = 0.45), and the distance clamp's claim: a whole window
    /// holding one row at the clamp and every other sample at the smallest
    /// distance gets `exp2_weight`'s floor.
    #[test]
    fn default_steps_and_the_distance_clamp_change_no_weight() {
        let (cap, channels, alpha, k2) = (7usize, 3usize, 1.0f32, 0.45f32 * 0.45);
        let q = Quantiser::distances(cap, channels, alpha, k2);
        assert_eq!(q.step(), 2f32.powi(-13));
        assert_eq!(Quantiser::weights(cap).step(), 2f32.powi(-25));
        let t = cap as f64;
        let h = f64::from(q.quantise(f32::INFINITY)) * f64::from(q.step());
        // Each of the other six rows: seven pixels at `-channels * alpha / k^2`.
        let lowest = -(t - 1.0) * t * channels as f64 * f64::from(alpha) / f64::from(k2);
        let mean = (h + lowest) / (channels as f64 * t * t);
        let arg = (-mean * std::f64::consts::LOG2_E) as f32;
        assert_eq!(exp2_weight(arg), exp2_weight(-1e30), "mean {mean}");
    }

    /// A weights' row (a horizontal sum of `T` weights of at most 1,
    /// scaled) lies inside the clamp whatever `T`, as
    /// [`ColumnBox::pushed`]`::<false>` requires, and the scale is `2^s`.
    #[test]
    fn weights_rows_lie_inside_the_clamp() {
        for cap in [1usize, 3, 5, 7, 9, 11, 21] {
            let q = Quantiser::weights(cap);
            assert!(cap as f32 * q.scale() < q.limit, "T = {cap}");
            assert_eq!(q.scale(), 2f32.powi(q.exponent()));
            assert_eq!(q.scale() * q.step(), 1.0);
            assert!((0..=127).contains(&q.exponent()));
        }
    }
}
