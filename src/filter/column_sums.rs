//! Vertical window sums of a lane's rows (the second half of each separable
//! box of SPEC §4), anchored to frame rows.
//!
//! A whole window covers `T = 2f + 1` rows `[a, a + 2f]`. The frame's rows
//! are cut into blocks of `T` rows starting at the multiples of `T` (frame
//! coordinates, never a tile's or a block's), so a whole window is either one
//! block or the tail of one block and the head of the next. Each block keeps
//! two running sums of its rows `h`:
//!
//! - the prefix `P[b] = ((h[s] + h[s + 1]) + ...) + h[b]` from the block's
//!   first row `s`, updated as each row arrives (one add per sample);
//! - the suffix `S[a] = h[a] + (h[a + 1] + (... + h[e]))` to its last row
//!   `e`, computed when the block is complete (one add per sample).
//!
//! A whole window is then `P[a + 2f]` when `a` starts a block and
//! `S[a] + P[a + 2f]` otherwise: at most 2 adds per sample plus the two
//! running sums, against `2f` adds for a direct sum (van Herk / Gil-Werman
//! for sums). Each is a fixed expression of the window's samples chosen by
//! frame coordinates alone, so whichever block, tile or lane computes a
//! window gets the same bits, as SPEC §6 requires of running sums ("anchor
//! the running sums to frame coordinates").
//!
//! A window clipped by the offset's valid rectangle adds its rows in
//! increasing order from the ring of the last `T` rows.
//!
//! The methods that add rows take the tier's chunk width `W` of the row
//! loops (`kernels::CHUNK`, or `kernels::CHUNK_AVX512`), which changes no
//! bit (the tests compare both).

use super::kernels::{chunk, chunk_mut, rows_sum};
use super::nlmeans::{Aligned, stride};
use crate::geom::Rect;

/// The rows of one lane's box (distances or weights) within a step, with
/// their frame-anchored running sums.
pub(super) struct ColumnBox {
    /// The last `T` rows `h` (row `y` in slot `(y - y0) % T`).
    ring: Aligned,
    /// The suffix sums `S` of the last complete block, in the same slots.
    suffix: Aligned,
    /// The prefix sum `P` of the current block up to the last row pushed.
    prefix: Aligned,
    stride: usize,
    cap: usize,
    /// The frame row `P` ends at (checked by debug builds).
    prefix_row: i64,
}

impl ColumnBox {
    /// Buffers for rows of up to `width` samples and windows of `cap = 2f + 1` rows.
    pub(super) fn new(width: usize, cap: usize) -> ColumnBox {
        let st = stride(width);
        ColumnBox {
            ring: Aligned::zeroed(st * cap),
            suffix: Aligned::zeroed(st * cap),
            prefix: Aligned::zeroed(st),
            stride: st,
            cap,
            prefix_row: i64::MIN,
        }
    }

    /// Samples held: the ring, the suffixes and the prefix row.
    pub(super) fn samples(width: usize, cap: usize) -> u64 {
        (stride(width) * (2 * cap + 1)) as u64
    }

    #[inline(always)]
    fn slot(&self, y: i64, y0: i64) -> usize {
        debug_assert!(y >= y0, "row {y} before the step's first row {y0}");
        (y - y0) as usize % self.cap
    }

    /// The ring slot to write frame row `y` into (`y0`: the step's first row
    /// of this box), `w` samples; then call [`ColumnBox::pushed`].
    #[inline(always)]
    pub(super) fn row_mut(&mut self, y: i64, y0: i64, w: usize) -> &mut [f32] {
        let at = self.slot(y, y0) * self.stride;
        &mut self.ring[at..at + w]
    }

    /// Row `y` (`w` samples) was written: extend the block's prefix with it
    /// and, when it ends its block, form the block's suffixes.
    #[inline(always)]
    pub(super) fn pushed<const W: usize>(&mut self, y: i64, y0: i64, w: usize) {
        let t = self.cap as i64;
        let at = self.slot(y, y0) * self.stride;
        let (ring, prefix) = (&self.ring[at..at + w], &mut self.prefix[..w]);
        let r = block_row(y, t);
        if r == 0 || y == y0 {
            prefix.copy_from_slice(ring);
        } else {
            add_assign::<W>(prefix, ring);
        }
        self.prefix_row = y;
        if r == t - 1 {
            // `S[j] = S[j + 1] + h[j]` for `j` from `y - 1` down to the
            // block's second row (its first is never needed: a window
            // starting there is `P`), or to the step's first row.
            let lo = (y - t + 2).max(y0);
            if lo < y {
                let rows = (y - lo) as usize;
                let shape = (self.slot(y - 1, y0), self.cap, self.stride, w);
                suffix_rows::<W>(&self.ring, &mut self.suffix, at, rows, shape);
            }
        }
    }

    /// Window sums of row `y`: the vertical sums over `[y - f, y + f] ∩ clip`
    /// (`y0`: the step's first row of this box); returns the window's
    /// height. A whole window's last row must be the last row pushed.
    #[inline(always)]
    pub(super) fn sums<const W: usize>(&self, y0: i64, y: i64, clip: Rect, f: i64, out: &mut [f32]) -> f32 {
        let w = out.len();
        match self.whole(y0, y, clip, f, w) {
            Ok((head, Some(tail))) => rows_sum::<W, 2>([head, tail], out),
            Ok((head, None)) => out.copy_from_slice(head),
            Err(count) => self.clipped::<W>(y0, y, clip, f, count, out),
        }
        self.height(y, clip, f)
    }

    /// The window sums of row `y` (as [`ColumnBox::sums`], `w` samples) as
    /// the rows whose sum they are: `head + tail`, or `head` alone (a
    /// window starting a block: its prefix). A clipped window's sums are
    /// written into `out`, which is then the head.
    #[inline(always)]
    pub(super) fn window<'a, const W: usize>(
        &'a self,
        y0: i64,
        y: i64,
        clip: Rect,
        f: i64,
        out: &'a mut [f32],
    ) -> (f32, &'a [f32], Option<&'a [f32]>) {
        let ny = self.height(y, clip, f);
        match self.whole(y0, y, clip, f, out.len()) {
            Ok((head, tail)) => (ny, head, tail),
            Err(count) => {
                self.clipped::<W>(y0, y, clip, f, count, out);
                (ny, out, None)
            }
        }
    }

    /// The height of row `y`'s window.
    #[inline(always)]
    fn height(&self, y: i64, clip: Rect, f: i64) -> f32 {
        ((y + f).min(clip.y1 - 1) - (y - f).max(clip.y0) + 1) as f32
    }

    /// A whole window's rows (see [`ColumnBox::window`]), or the height of
    /// a clipped one.
    #[inline(always)]
    pub(super) fn whole(
        &self,
        y0: i64,
        y: i64,
        clip: Rect,
        f: i64,
        w: usize,
    ) -> Result<(&[f32], Option<&[f32]>), usize> {
        let (a, b) = ((y - f).max(clip.y0), (y + f).min(clip.y1 - 1));
        let count = (b - a + 1) as usize;
        if count != self.cap {
            return Err(count);
        }
        debug_assert_eq!(self.prefix_row, b, "a whole window is summed right after its last row");
        let prefix = &self.prefix[..w];
        let r = block_row(a, self.cap as i64) as usize;
        if r == 0 {
            return Ok((prefix, None));
        }
        let at = self.slot(a, y0) * self.stride;
        // The block's last row is its own suffix.
        let head = if r == self.cap - 1 { &self.ring[at..at + w] } else { &self.suffix[at..at + w] };
        Ok((head, Some(prefix)))
    }

    /// A clipped window's sums: its `count` rows added in increasing order.
    #[inline(always)]
    fn clipped<const W: usize>(&self, y0: i64, y: i64, clip: Rect, f: i64, count: usize, out: &mut [f32]) {
        let first = ((y - f).max(clip.y0) - y0) as usize;
        ring_column_sums::<W>(&self.ring, self.stride, self.cap, first, count, out);
    }
}

/// Row `y`'s index in its block of `t` rows (`y.rem_euclid(t)`, which the
/// tier wrappers would call out of line).
#[inline(always)]
fn block_row(y: i64, t: i64) -> i64 {
    let r = y % t;
    if r < 0 { r + t } else { r }
}

/// The suffixes of a block's `rows` rows before its last (ring row at
/// `last`), from the row in slot `first` back (slots wrap at `cap`, `stride`
/// samples apart): `S = S_next + h` (`+` commutes exactly), the last row
/// being its own suffix.
#[inline(always)]
fn suffix_rows<const W: usize>(
    ring: &[f32],
    suffix: &mut [f32],
    last: usize,
    rows: usize,
    (first, cap, stride, w): (usize, usize, usize, usize),
) {
    // Row by row: the suffix just formed is read back from L1, and each
    // row pays its set-up once rather than once per chunk.
    let mut s = first;
    for k in 0..rows {
        let at = s * stride;
        let h = &ring[at..at + w];
        if k == 0 {
            rows_sum::<W, 2>([&ring[last..last + w], h], &mut suffix[at..at + w]);
        } else {
            let from = if s + 1 == cap { 0 } else { s + 1 } * stride;
            let (next, out) = rows_pair(suffix, from, at, w);
            rows_sum::<W, 2>([next, h], out);
        }
        s = if s == 0 { cap - 1 } else { s - 1 };
    }
}

/// Row `from` of `buf` to read and row `to` to write (distinct, `w` samples each).
#[inline(always)]
fn rows_pair(buf: &mut [f32], from: usize, to: usize, w: usize) -> (&[f32], &mut [f32]) {
    if from < to {
        let (a, b) = buf.split_at_mut(to);
        (&a[from..from + w], &mut b[..w])
    } else {
        let (a, b) = buf.split_at_mut(from);
        (&b[..w], &mut a[to..to + w])
    }
}

/// `a += b`.
#[inline(always)]
fn add_assign<const W: usize>(a: &mut [f32], b: &[f32]) {
    let n = a.len();
    let b = &b[..n];
    if n < W {
        for (x, y) in a.iter_mut().zip(b) {
            *x += *y;
        }
        return;
    }
    // Whole chunks, then the rest (an update in place: no overlapping chunk).
    let whole = n / W * W;
    for i in (0..whole).step_by(W) {
        let (mut x, y) = (*chunk::<W>(a, i), chunk::<W>(b, i));
        for k in 0..W {
            x[k] += y[k];
        }
        *chunk_mut::<W>(a, i) = x;
    }
    for i in whole..n {
        a[i] += b[i];
    }
}

/// `out = rows[first] + rows[first + 1] + ...` (`count` rows, in increasing
/// order), where row `k` is stored in slot `k % cap` of `ring`, slots
/// `stride` samples apart.
#[inline(always)]
pub(super) fn ring_column_sums<const W: usize>(
    ring: &[f32],
    stride: usize,
    cap: usize,
    first: usize,
    count: usize,
    out: &mut [f32],
) {
    let w = out.len();
    let row = |i: usize| {
        let slot = (first + i) % cap;
        &ring[slot * stride..slot * stride + w]
    };
    out.copy_from_slice(row(0));
    for i in 1..count {
        add_assign::<W>(out, row(i));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Push rows `y0..y1` of `h` (row `y` = `h(y)`) and collect the window
    /// sums of every row whose window is complete, as the kernel does.
    /// Every chunk width of the tiers gives the same bits.
    fn run(h: &dyn Fn(i64, usize) -> f32, w: usize, f: i64, y0: i64, y1: i64, clip: Rect) -> Vec<(i64, Vec<f32>)> {
        use crate::filter::kernels::{CHUNK, CHUNK_AVX512};
        let narrow = run_with::<CHUNK>(h, w, f, y0, y1, clip);
        let bits = |v: &[(i64, Vec<f32>)]| {
            v.iter().map(|(y, r)| (*y, r.iter().map(|x| x.to_bits()).collect::<Vec<_>>())).collect::<Vec<_>>()
        };
        assert_eq!(bits(&run_with::<CHUNK_AVX512>(h, w, f, y0, y1, clip)), bits(&narrow), "chunk widths");
        narrow
    }

    fn run_with<const W: usize>(
        h: &dyn Fn(i64, usize) -> f32,
        w: usize,
        f: i64,
        y0: i64,
        y1: i64,
        clip: Rect,
    ) -> Vec<(i64, Vec<f32>)> {
        let cap = (2 * f + 1) as usize;
        let mut b = ColumnBox::new(w, cap);
        let mut out = Vec::new();
        // Rows whose window lies in the rows pushed (or is clipped at the top).
        let mut next = if y0 == clip.y0 { y0 } else { y0 + f };
        for y in y0..y1 {
            for (i, v) in b.row_mut(y, y0, w).iter_mut().enumerate() {
                *v = h(y, i);
            }
            b.pushed::<W>(y, y0, w);
            while next < y1 && (next + f).min(clip.y1 - 1) <= y {
                let mut o = vec![0.0; w];
                b.sums::<W>(y0, next, clip, f, &mut o);
                out.push((next, o));
                next += 1;
            }
        }
        out
    }

    fn value(y: i64, i: usize) -> f32 {
        // Values whose sums round differently in different orders.
        let s = ((y * 7919 + i as i64 * 104729) % 1000) as f32;
        (s * 0.001 + 1.0) * if (y + i as i64) % 3 == 0 { 1e3 } else { 1.1e-3 }
    }

    /// The expression of the module's doc, computed directly.
    fn expected(y: i64, i: usize, f: i64, clip: Rect) -> f32 {
        let t = 2 * f + 1;
        let (a, b) = ((y - f).max(clip.y0), (y + f).min(clip.y1 - 1));
        if b - a + 1 != t {
            let mut acc = value(a, i);
            for j in a + 1..=b {
                acc += value(j, i);
            }
            return acc;
        }
        let s = b - b.rem_euclid(t);
        let mut p = value(s, i);
        for j in s + 1..=b {
            p += value(j, i);
        }
        if a == s {
            return p;
        }
        let mut q = value(s - 1, i);
        for j in (a..s - 1).rev() {
            q += value(j, i);
        }
        q + p
    }

    #[test]
    fn anchored_sums_match_their_expression_whatever_the_first_row() {
        for f in [0, 1, 2, 3, 5] {
            for w in [5, 16, 37, 150] {
                let clip = Rect { x0: 0, x1: w as i64, y0: -11, y1: 40 };
                for y0 in [-11, -9, -4, 0, 3, 6] {
                    for (y, row) in run(&value, w, f, y0, clip.y1, clip) {
                        for (i, v) in row.iter().enumerate() {
                            let e = expected(y, i, f, clip);
                            assert_eq!(v.to_bits(), e.to_bits(), "f {f} w {w} first row {y0}: row {y} col {i}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn anchored_sums_are_window_sums() {
        let (f, w) = (3, 20);
        let clip = Rect { x0: 0, x1: w as i64, y0: 0, y1: 30 };
        let rows = run(&value, w, f, 0, 30, clip);
        assert_eq!(rows.len(), 30);
        for (y, row) in rows {
            for (i, v) in row.iter().enumerate() {
                let exact: f64 = ((y - f).max(0)..=(y + f).min(29)).map(|j| value(j, i) as f64).sum();
                assert!(((*v as f64) - exact).abs() <= 1e-5 * exact, "row {y} col {i}: {v} vs {exact}");
            }
        }
    }
}
