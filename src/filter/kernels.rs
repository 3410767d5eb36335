//! The inner arithmetic shared by every stage: a deterministic `exp`, box means
//! clipped to a frame-defined rectangle, and per-row distance kernels.
//!
//! Bit-exactness rules (SPEC §6) live here: every output sample is computed by
//! the same sequence of operations whatever region is being evaluated — each
//! window sum is a fixed expression of its samples (`box_mean` adds them in
//! increasing frame coordinate), counts
//! come from frame-defined clip rectangles, `exp` is our own polynomial, and
//! every fused multiply-add is an explicit `f32::mul_add` (one rounding on
//! every path, see [`super::simd`]), never a contraction left to the compiler.

use crate::geom::Rect;

/// The weight `2^min(0, t)` for a distance already scaled to `t = -d log2(e)`
/// (the filters fold `-log2(e)` into the scale of their box means, so this
/// is `exp(-max(0, d))`), with `t` clamped below at -126 and NaN mapped there.
///
/// `2^t = 2^n 2^f` with `n = round(t)` (read from the mantissa bits after
/// adding `1.5 * 2^23`), `f = t - n` in `[-0.5, 0.5]`, and `2^f` from a
/// degree-5 polynomial fitted for relative error (with `p(0) = 1`),
/// evaluated by Horner's rule with fused multiply-adds. Pure `f32`
/// arithmetic, no libm `exp`: the same bits on every platform and path.
/// The result is always a
/// normal number in `[2^-126, 1]`; its relative error against `2^t` is below
/// 3e-7 on `[-126, 0]` (tested below).
#[inline(always)]
pub fn exp2_weight(t: f32) -> f32 {
    // One implementation for one sample and for chunks: the same bits.
    exp2_weight_lanes([t])[0]
}

/// [`exp2_weight`] of every sample of a chunk, one operation at a time across
/// the chunk: each sample gets exactly [`exp2_weight`]'s operations (so the
/// same bits), but the compiled code runs the chunk's vectors in lockstep,
/// each operation on all of them before the next, instead of one vector's
/// whole dependent chain (about a dozen operations) after another's. In
/// lockstep the out-of-order core needs fewer waiting operations in flight
/// to keep its pipes busy: `benches/peak.rs`'s `mix_recip_exp2` compares
/// the two forms (1.28-1.39x on session 20's Zen 5), and `weight_row` uses this one
/// (docs/performance.md, session 20).
#[inline(always)]
pub fn exp2_weight_lanes<const W: usize>(t: [f32; W]) -> [f32; W] {
    exp2_weight_scaled_lanes(t, 0)
}

/// [`exp2_weight_lanes`] times `2^e`, exactly: the power of two `2^(n + e)`
/// instead of `2^n` in its last multiply, no extra operation. The weights'
/// box (`column_sums::Quantiser::weights`) takes its rows already
/// scaled by its `2^s` this way. `e` must lie in `[0, 127]`, so that
/// `2^(n + e)` with `n` in `[-126, 0]` stays a normal number (the result
/// is then `exp2_weight(t) * 2^e` with no rounding: a product by a power of
/// two of a normal number that stays normal).
#[inline(always)]
pub fn exp2_weight_scaled_lanes<const W: usize>(t: [f32; W], e: i32) -> [f32; W] {
    debug_assert!((0..=127).contains(&e));
    // Two selects that map to min/max instructions; NaN fails `t > -126` and
    // lands on the clamp value.
    let t = lanes(t, |t| if t > -126.0 { t } else { -126.0 });
    let t = lanes(t, |t| if t < 0.0 { t } else { 0.0 });
    let tr = lanes(t, |t| t + EXP2_ROUND);
    let f = lanes2(t, tr, |t, tr| t - (tr - EXP2_ROUND));
    let c = EXP2_POLY;
    let mut p = lanes(f, |f| c[0].mul_add(f, c[1]));
    for &ck in &c[2..] {
        p = lanes2(p, f, |p, f| p.mul_add(f, ck));
    }
    lanes2(p, tr, |p, tr| {
        // `tr`'s low mantissa bits hold the integer `n` in [-126, 0]: read it
        // with an integer subtraction (a float-to-int cast would be scalarised).
        let ni = (tr.to_bits() as i32).wrapping_sub(EXP2_ROUND.to_bits() as i32);
        p * f32::from_bits(((ni + 127 + e) as u32) << 23)
    })
}

/// The coefficients of [`exp2_weight`]'s polynomial `2^f ~ p(f)`, highest
/// degree first (Horner's rule). The constant term is exactly 1, so integer
/// `t` give exact powers of two.
// Fitted, not ln 2 (0.693_147_2): the lower degrees absorb the difference.
#[allow(clippy::approx_constant)]
const EXP2_POLY: [f32; 6] = [1.326_470_2e-3, 9.671_505e-3, 5.550_733_6e-2, 2.402_224_2e-1, 0.693_147, 1.0];

/// `1.5 * 2^23`: adding it to `t` in `[-126, 0]` rounds `t` to an integer
/// (to even), which its low mantissa bits then hold.
const EXP2_ROUND: f32 = 12_582_912.0;

/// The weights of a row on the AVX-512 tier: `dst[i]` is
/// [`exp2_weight_scaled_lanes`] (times `2^e`) of `t = sums[i] as f32 * inner`,
/// with `GUIDED` of `if tf[i] < t { tf[i] } else { t }`, with the same bits
/// and, as written, three operations fewer per sample (13 instead of 16;
/// four with `GUIDED`, 13 instead of 17, counting the argument's own
/// conversion, scale and minimum):
///
/// * the power of two `2^n` is applied by `vscalefps` from `n` as a float
///   (`tr - 1.5 * 2^23`, which the reduction computes anyway) instead of
///   an integer subtraction, an integer addition (the bias and `e`), a
///   shift and a multiply: `vscalefps` rounds the
///   exact product `p 2^n` once, as the multiply does;
/// * `2^e` is folded into the polynomial's coefficients: each of its fused
///   multiply-adds then gives its value times `2^e` exactly (no value
///   comes near the ends of the exponent range for `e` in `[0, 127]`);
/// * with `GUIDED`, no clamp at 0: the caller's `tf` are never NaN and never
///   above 0 (they are minima folded from 0), so `t` is at most `+0`, and a
///   `-0` left unclamped gives `f = -0` where the clamp gave `+0`, which the
///   polynomial's fused multiply-adds (`p * f + c`, `c != 0`) turn into the
///   same bits.
///
/// `n = dst.len()` samples, any `n` (masked loads and stores at the end).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn weights_avx512<const GUIDED: bool>(sums: &[i32], tf: &[f32], dst: &mut [f32], inner: f32, e: i32) {
    use std::arch::x86_64::*;
    const V: usize = 4;
    let n = dst.len();
    assert!(sums.len() >= n && (!GUIDED || tf.len() >= n), "a sum (and a guide) per weight");
    assert!((0..=127).contains(&e), "the weights' scale 2^e");
    let consts = WeightConsts::new(inner, e);
    // Whole chunks unmasked (constant masks: plain loads and stores), then
    // the last one masked.
    let mut i = 0;
    while i + 16 * V <= n {
        // SAFETY: samples `i..i + 64` lie below `n`; avx512f (see above).
        unsafe { weights_chunk::<GUIDED, V>((sums, tf, dst), None, i, [0xFFFF; V], &consts) };
        i += 16 * V;
    }
    if i < n {
        let masks: [__mmask16; V] = std::array::from_fn(|v| {
            let left = n.saturating_sub(i + 16 * v);
            if left >= 16 { 0xFFFF } else { ((1u32 << left) - 1) as u16 }
        });
        // SAFETY: the masks keep the samples below `n`; avx512f (see above).
        unsafe { weights_chunk::<GUIDED, V>((sums, tf, dst), None, i, masks, &consts) };
    }
}

/// [`weights_avx512`] of up to 16 samples, each with its own factor:
/// `t = sums[i] as f32 * factors[i]` (the columns whose windows the frame
/// clips, each scaled by its own count), the same bits as the lanes form
/// on each sample.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn weights_factors_avx512<const GUIDED: bool>(
    sums: &[i32],
    tf: &[f32],
    dst: &mut [f32],
    factors: &[f32],
    e: i32,
) {
    use std::arch::x86_64::*;
    let n = dst.len();
    assert!(n <= 16 && sums.len() >= n && factors.len() >= n && (!GUIDED || tf.len() >= n), "up to 16 samples");
    assert!((0..=127).contains(&e), "the weights' scale 2^e");
    let consts = WeightConsts::new(0.0, e);
    let mask = ((1u32 << n) - 1) as __mmask16;
    // SAFETY: the mask keeps the samples below `n`; avx512f (see above).
    unsafe { weights_chunk::<GUIDED, 1>((sums, tf, dst), Some(factors), 0, [mask], &consts) };
}

/// [`weights_avx512`]'s constants, as vectors.
#[cfg(target_arch = "x86_64")]
struct WeightConsts {
    c: [std::arch::x86_64::__m512; 6],
    inner: std::arch::x86_64::__m512,
    round: std::arch::x86_64::__m512,
    floor: std::arch::x86_64::__m512,
}

#[cfg(target_arch = "x86_64")]
impl WeightConsts {
    /// The constants for the factor `inner` and the scale `2^e` (`e` in
    /// `[0, 127]`): the polynomial's coefficients times `2^e`, exactly.
    #[inline(always)]
    fn new(inner: f32, e: i32) -> WeightConsts {
        use std::arch::x86_64::*;
        let scale = f32::from_bits(((127 + e) as u32) << 23);
        // SAFETY: reached only from the AVX-512 kernels (avx512f).
        unsafe {
            let mut c = [_mm512_setzero_ps(); 6];
            for (v, x) in c.iter_mut().zip(EXP2_POLY) {
                *v = _mm512_set1_ps(x * scale);
            }
            WeightConsts {
                c,
                inner: _mm512_set1_ps(inner),
                round: _mm512_set1_ps(EXP2_ROUND),
                floor: _mm512_set1_ps(-126.0),
            }
        }
    }
}

/// [`weights_avx512`] on the `V` vectors from `i`, vector `v` on the
/// samples its mask `masks[v]` keeps; each sample's factor from `factors`
/// if given, else `k.inner`.
///
/// # Safety
/// The CPU must support AVX-512F; the masked samples must lie inside
/// `sums`, `dst`, `factors` (if given) and (with `GUIDED`) `tf`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn weights_chunk<const GUIDED: bool, const V: usize>(
    (sums, tf, dst): (&[i32], &[f32], &mut [f32]),
    factors: Option<&[f32]>,
    i: usize,
    masks: [std::arch::x86_64::__mmask16; V],
    k: &WeightConsts,
) {
    use std::arch::x86_64::*;
    // SAFETY (the whole body): the caller's CPU supports AVX-512F and the
    // masks keep samples inside the rows.
    unsafe {
        let mut t = [_mm512_setzero_ps(); V];
        for v in 0..V {
            let at = i + 16 * v;
            let s = _mm512_maskz_loadu_epi32(masks[v], sums.as_ptr().wrapping_add(at));
            let factor = match factors {
                Some(f) => _mm512_maskz_loadu_ps(masks[v], f.as_ptr().wrapping_add(at)),
                None => k.inner,
            };
            t[v] = _mm512_mul_ps(_mm512_cvtepi32_ps(s), factor);
            if GUIDED {
                // `if g < t { g } else { t }`: `vminps` returns its second
                // operand unless the first is smaller.
                t[v] = _mm512_min_ps(_mm512_maskz_loadu_ps(masks[v], tf.as_ptr().wrapping_add(at)), t[v]);
            }
            // `if t > -126 { t } else { -126 }`, NaN to -126.
            t[v] = _mm512_max_ps(t[v], k.floor);
            if !GUIDED {
                t[v] = _mm512_min_ps(t[v], _mm512_setzero_ps());
            }
        }
        // Plain loops, not `map`: LLVM left `map` on vectors out of line.
        let (mut nf, mut f, mut p) = ([_mm512_setzero_ps(); V], [_mm512_setzero_ps(); V], [_mm512_setzero_ps(); V]);
        for v in 0..V {
            nf[v] = _mm512_sub_ps(_mm512_add_ps(t[v], k.round), k.round);
            f[v] = _mm512_sub_ps(t[v], nf[v]);
            p[v] = _mm512_fmadd_ps(k.c[0], f[v], k.c[1]);
        }
        for ck in &k.c[2..] {
            for v in 0..V {
                p[v] = _mm512_fmadd_ps(p[v], f[v], *ck);
            }
        }
        for v in 0..V {
            let w = _mm512_scalef_ps(p[v], nf[v]);
            _mm512_mask_storeu_ps(dst.as_mut_ptr().wrapping_add(i + 16 * v), masks[v], w);
        }
    }
}

/// `f` of every sample of a chunk.
#[inline(always)]
pub fn lanes<const W: usize>(a: [f32; W], f: impl Fn(f32) -> f32) -> [f32; W] {
    let mut o = a;
    for k in 0..W {
        o[k] = f(a[k]);
    }
    o
}

/// `f` of every pair of samples of two chunks.
#[inline(always)]
pub fn lanes2<const W: usize>(a: [f32; W], b: [f32; W], f: impl Fn(f32, f32) -> f32) -> [f32; W] {
    let mut o = a;
    for k in 0..W {
        o[k] = f(a[k], b[k]);
    }
    o
}

/// The factor turning a sum of per-channel distances into `t` of
/// [`exp2_weight`]: `-log2(e) / channels`.
pub fn log2_distance_scale(channels: usize) -> f32 {
    -std::f32::consts::LOG2_E / channels as f32
}

/// Box mean of radius `radius` of `src`, evaluated on `dst_rect`.
///
/// The window of pixel `p` is `[p - radius, p + radius]^2 ∩ clip`; its samples
/// are summed horizontally in increasing x (starting from `0.0`), the row sums
/// vertically in increasing y, and the total divided by the window's pixel
/// count. `clip` must be defined by the frame (never by a tile) and `src` must
/// cover `(dst_rect ⊕ radius) ∩ clip`; `dst_rect` must lie inside `clip`.
/// `scratch` is reused between calls to avoid allocation.
#[inline(always)]
pub fn box_mean(
    src: &[f32],
    src_rect: Rect,
    clip: Rect,
    radius: usize,
    dst_rect: Rect,
    dst: &mut [f32],
    scratch: &mut Vec<f32>,
) {
    debug_assert!(clip.contains_rect(&dst_rect));
    debug_assert_eq!(dst.len(), dst_rect.area());
    if dst_rect.is_empty() {
        return;
    }
    let f = radius as i64;
    let rows = Rect {
        x0: dst_rect.x0,
        x1: dst_rect.x1,
        y0: (dst_rect.y0 - f).max(clip.y0),
        y1: (dst_rect.y1 + f).min(clip.y1),
    };
    debug_assert!(src_rect.contains_rect(&Rect {
        x0: (dst_rect.x0 - f).max(clip.x0),
        x1: (dst_rect.x1 + f).min(clip.x1),
        ..rows
    }));
    let w = dst_rect.width();
    scratch.clear();
    scratch.resize(rows.area(), 0.0);
    let sw = src_rect.width();
    // Columns whose whole window lies inside the clip take the vectorisable path.
    let inner_x0 = (clip.x0 + f).max(dst_rect.x0).min(dst_rect.x1);
    let inner_x1 = (clip.x1 - f).min(dst_rect.x1).max(inner_x0);
    for (ri, y) in (rows.y0..rows.y1).enumerate() {
        let src_row = &src[(y - src_rect.y0) as usize * sw..][..sw];
        let h = &mut scratch[ri * w..(ri + 1) * w];
        for x in (dst_rect.x0..inner_x0).chain(inner_x1..dst_rect.x1) {
            let a = (x - f).max(clip.x0);
            let b = (x + f).min(clip.x1 - 1);
            let mut acc = 0.0f32;
            for xx in a..=b {
                acc += src_row[(xx - src_rect.x0) as usize];
            }
            h[(x - dst_rect.x0) as usize] = acc;
        }
        if inner_x1 > inner_x0 {
            let n = (inner_x1 - inner_x0) as usize;
            let out = &mut h[(inner_x0 - dst_rect.x0) as usize..][..n];
            out.fill(0.0);
            for k in 0..=2 * f {
                let s = &src_row[(inner_x0 - f + k - src_rect.x0) as usize..][..n];
                for (o, v) in out.iter_mut().zip(s) {
                    *o += *v;
                }
            }
        }
    }
    // Each window's sum is scaled by `1 / count`, the reciprocal computed once
    // per distinct count (the same division for every pixel with that count).
    let nx_of = |x: i64| ((x + f).min(clip.x1 - 1) - (x - f).max(clip.x0) + 1) as f32;
    for y in dst_rect.y0..dst_rect.y1 {
        let a = (y - f).max(clip.y0);
        let b = (y + f).min(clip.y1 - 1);
        let ny = (b - a + 1) as f32;
        let out = &mut dst[(y - dst_rect.y0) as usize * w..][..w];
        out.fill(0.0);
        for yy in a..=b {
            let h = &scratch[(yy - rows.y0) as usize * w..][..w];
            for (o, v) in out.iter_mut().zip(h) {
                *o += *v;
            }
        }
        let inner = 1.0 / ((2 * f + 1) as f32 * ny);
        let (i0, i1) = ((inner_x0 - dst_rect.x0) as usize, (inner_x1 - dst_rect.x0) as usize);
        for o in &mut out[i0..i1] {
            *o *= inner;
        }
        for i in (0..i0).chain(i1..w) {
            out[i] *= 1.0 / (nx_of(dst_rect.x0 + i as i64) * ny);
        }
    }
}

/// One channel's non-uniform-variance distance (SPEC §2) for a row, for a
/// pair of offsets at once:
/// `fwd[i] += ((up - uq)^2 - alpha (vp + min(vp, vq))) / (eps + k2 (vp + vq))`,
/// which is `d2_c(p, p + n)` with `up = u(p)`, `uq = u(p + n)`, and `mir[i]`
/// the same with the roles of `vp` and `vq` swapped, `d2_c(p + n, p)`: the
/// distance of pixel `p + n` for offset `-n`. The squared difference, the
/// minimum, the denominator's sum and its reciprocal are symmetric and
/// computed once; the reciprocal is an IEEE division (`1 / x`, correctly
/// rounded on every path), and both the variance term's subtractions and
/// the accumulation are fused multiply-adds.
/// The variance term is subtracted in two steps, its shared part first:
/// `e = d2 - alpha min(vp, vq)`, then `e - alpha vp` (and `e - alpha vq`
/// for `mir`), one operation fewer than forming `vp + min` and `vq + min`
/// (session 24); two roundings either way.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn accumulate_colour_distance_pair(
    fwd: &mut [f32],
    mir: &mut [f32],
    up: &[f32],
    uq: &[f32],
    vp: &[f32],
    vq: &[f32],
    alpha: f32,
    eps: f32,
    k2: f32,
) {
    let n = fwd.len();
    let (mir, up, uq, vp, vq) = (&mut mir[..n], &up[..n], &uq[..n], &vp[..n], &vq[..n]);
    for i in 0..n {
        let d = up[i] - uq[i];
        let d2 = d * d;
        let m = if vq[i] < vp[i] { vq[i] } else { vp[i] };
        let r = 1.0 / k2.mul_add(vp[i] + vq[i], eps);
        let e = (-alpha).mul_add(m, d2);
        fwd[i] = (-alpha).mul_add(vp[i], e).mul_add(r, fwd[i]);
        mir[i] = (-alpha).mul_add(vq[i], e).mul_add(r, mir[i]);
    }
}

/// Samples per chunk of the row loops on the AVX2 and portable tiers: two
/// AVX2 vectors.
///
/// A row loop written over chunks of `W` samples compiles to whole vectors
/// only: a row of `n >= W` samples is covered by the chunks starting at
/// `0, W, ...` and a last one ending at `n`, which overlaps its predecessor
/// (see [`chunk_start`]). For a loop whose output is not one of its inputs,
/// or whose update is idempotent (a minimum), the overlapped samples get the
/// same bits twice; an in-place update runs whole chunks, then the rest one
/// sample at a time. Every sample gets the same operations whichever chunk,
/// or the scalar rest, computes it, so the chunk width never changes a bit
/// (the AVX-512 tier uses [`CHUNK_AVX512`]). The compiler's
/// own vector loops end in a scalar loop of up to 32 samples, which on rows
/// of a few hundred samples cost about as much as the vector part.
pub const CHUNK: usize = 16;

/// Samples per chunk on the AVX-512 tier: four AVX-512 vectors, so that the
/// per-chunk integer work (the clamped start, the loop) is spread over four
/// vectors' arithmetic. The AVX2 tier measured slower with chunks wider
/// than [`CHUNK`] (it has 16 vector registers to AVX-512's 32;
/// docs/performance.md, session 16).
pub const CHUNK_AVX512: usize = 64;

// The AVX-512 and half-float kernels (`taps_sum_avx512`,
// `feature_square_sum_half_*`) handle one 16-lane vector per chunk of `CHUNK`.
const _: () = assert!(CHUNK == 16, "the 16-lane kernels need 16-sample chunks");

/// The number of chunks of `W` samples covering a row of `n >= W` samples.
#[inline(always)]
pub fn chunk_count<const W: usize>(n: usize) -> usize {
    n.div_ceil(W)
}

/// Where chunk `c` of a row of `n >= W` samples starts: the last chunk
/// ends at `n`.
#[inline(always)]
pub fn chunk_start<const W: usize>(c: usize, n: usize) -> usize {
    (c * W).min(n - W)
}

/// The chunk of `W` samples of `s` starting at `i`, which must be at most
/// `s.len() - W` (debug builds check it; release builds clamp `i` to it).
///
/// The clamp keeps this sound without a bounds check per chunk: in the
/// chunk loops `i` is [`chunk_start`] of a row cut to `s.len()` samples, and
/// the compiler folds the clamp into the one `chunk_start` already applies.
/// What is left per call is the test `s.len() >= W`, the same for every
/// chunk of a row.
#[inline(always)]
pub fn chunk<const W: usize>(s: &[f32], i: usize) -> &[f32; W] {
    chunk_of(s, i)
}

/// [`chunk`] for any sample type.
#[inline(always)]
pub fn chunk_of<T, const W: usize>(s: &[T], i: usize) -> &[T; W] {
    debug_assert!(i + W <= s.len());
    assert!(s.len() >= W, "a chunk is W samples");
    let i = i.min(s.len() - W);
    // SAFETY: `i + W <= s.len()`, and `[T; W]` has the alignment of `T`.
    unsafe { &*s.as_ptr().add(i).cast::<[T; W]>() }
}

/// A copy of the chunk of `W` integers of `s` starting at `i` (as [`chunk`]).
#[inline(always)]
pub fn chunk_i32<const W: usize>(s: &[i32], i: usize) -> [i32; W] {
    *chunk_of(s, i)
}

/// The chunk of `s` starting at `i`, to write (as [`chunk`]).
#[inline(always)]
pub fn chunk_mut<const W: usize>(s: &mut [f32], i: usize) -> &mut [f32; W] {
    debug_assert!(i + W <= s.len());
    assert!(s.len() >= W, "a chunk is W samples");
    let i = i.min(s.len() - W);
    // SAFETY: as in `chunk`; `s` is borrowed mutably for the chunk's lifetime.
    unsafe { &mut *s.as_mut_ptr().add(i).cast::<[f32; W]>() }
}

/// Each row of `rows` cut to its first `n` samples. A plain loop: the
/// standard `array::map` and `array::from_fn` stay out-of-line calls (each
/// with a `vzeroupper`) inside the block kernel's tier wrappers.
#[inline(always)]
pub fn cut<T, const N: usize>(rows: [&[T]; N], n: usize) -> [&[T]; N] {
    let mut out = rows;
    for r in out.iter_mut() {
        *r = &r[..n];
    }
    out
}

/// `out = ((rows[0] + rows[1]) + ...) + rows[T - 1]`, chunk by chunk (the last
/// chunk overlaps its predecessor: `out` is not an input).
#[inline(always)]
pub fn rows_sum<const W: usize, const T: usize>(rows: [&[f32]; T], out: &mut [f32]) {
    let n = out.len();
    if n < W {
        let rows = cut(rows, n);
        for (i, o) in out.iter_mut().enumerate() {
            let mut acc = rows[0][i];
            for row in &rows[1..] {
                acc += row[i];
            }
            *o = acc;
        }
        return;
    }
    for c in 0..chunk_count::<W>(n) {
        let i = chunk_start::<W>(c, n);
        let mut acc = *chunk::<W>(rows[0], i);
        for row in &rows[1..] {
            let r = chunk::<W>(row, i);
            for k in 0..W {
                acc[k] += r[k];
            }
        }
        *chunk_mut::<W>(out, i) = acc;
    }
}

/// The window sums of `2F + 1` taps,
/// `out[i] = ((p[i] + p[i + 2]) + ... + p[i + 2F - 2]) + src[i + 2F]`
/// with `p[j] = src[j] + src[j + 1]` (`src` holds `out.len() + 2F`
/// samples; with `F = 3`, the 7-tap sums
/// `((p[i] + p[i + 2]) + p[i + 4]) + src[i + 6]`), for `F` from 1 to 4:
/// the same expression as the portable pair sums ([`rows_sum`] of the pair
/// rows), its shifted operands formed in registers (`valignd`) from one load
/// per chunk instead of `F + 2` loads, most of them split across cache
/// lines, and a stored pair row. The kernel pushes these sums straight into
/// its boxes ([`taps_push_avx512`], the same register sums); this stored
/// form is their reference, tested against the expression.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn taps_sum_avx512<const F: usize>(src: &[f32], out: &mut [f32]) {
    use std::arch::x86_64::*;
    let n = out.len();
    assert_eq!(src.len(), n + 2 * F, "a window of 2F + 1 taps per output");
    if n < CHUNK {
        for (i, o) in out.iter_mut().enumerate() {
            let p = |j: usize| src[j] + src[j + 1];
            let mut acc = p(i);
            for k in 1..F {
                acc += p(i + 2 * k);
            }
            *o = acc + src[i + 2 * F];
        }
        return;
    }
    let full = n / CHUNK;
    let mut taps = Taps::<F>::new(src);
    for c in 0..full {
        let i = c * CHUNK;
        // The row's interior needs no masked load (see `taps_push_avx512`).
        let o = if i + 3 * CHUNK <= src.len() { taps.next_whole(i) } else { taps.next(i) };
        // SAFETY: `i + 16 <= n`.
        unsafe { _mm512_storeu_ps(out.as_mut_ptr().add(i), o) };
    }
    if !n.is_multiple_of(CHUNK) {
        // The last 16 outputs (overlapping the previous chunk), from scratch.
        let i = n - CHUNK;
        let o = Taps::<F>::new(&src[i..]).next(0);
        // SAFETY: `i + 16 == n`.
        unsafe { _mm512_storeu_ps(out.as_mut_ptr().add(i), o) };
    }
}

/// The window sums of [`taps_sum_avx512`] (the same expression, bit for
/// bit), pushed straight into a box's row, without storing them: each
/// sum `x` becomes `v = round(x)` (to nearest, ties to even), clamped
/// first to `[-limit, limit]` with `CLAMP` (NaN to `-limit`), exactly as
/// `column_sums::Quantiser` does one sample; then `ring[i] = v` and the
/// running sum `run[i]` becomes `v` (`CASE` 0), `run[i] + v` (1) or
/// `run[i] + v - ring[i]` (2, the old `ring[i]`), wrapping. `src` holds
/// `ring.len() + 2F` samples; the last chunk is masked, so every column is
/// pushed once.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn taps_push_avx512<const F: usize, const CLAMP: bool, const CASE: u8>(
    src: &[f32],
    ring: &mut [i32],
    run: &mut [i32],
    limit: f32,
) {
    use std::arch::x86_64::*;
    let n = ring.len();
    assert!(run.len() == n && src.len() == n + 2 * F, "a window of 2F + 1 taps per pushed sample");
    // Columns `i..i + 16` (those of `k`) of the sums `x`, pushed.
    let mut push = |i: usize, x: __m512, k: __mmask16| {
        // SAFETY: `i < n`, and the mask selects only the columns below `n`.
        unsafe { push_vector::<CLAMP, CASE>(ring.as_mut_ptr().add(i), run.as_mut_ptr().add(i), x, k, limit) };
    };
    let mut taps = Taps::<F>::new(src);
    // The row's interior, where every load of `Taps::next` (up to sample
    // `i + 48` of `src`) and every store (up to column `i + 16 <= n`, as
    // `2F < 32`) is whole: no mask to form or test per chunk.
    let mut i = 0;
    while i + 3 * CHUNK <= src.len() {
        let x = taps.next_whole(i);
        push(i, x, 0xFFFF);
        i += CHUNK;
    }
    // Its end, masked.
    while i < n {
        let x = taps.next(i);
        let k: __mmask16 = if n - i >= CHUNK { 0xFFFF } else { (1u16 << (n - i)) - 1 };
        push(i, x, k);
        i += CHUNK;
    }
}

/// The sums `x` of 16 columns (those of `k`) pushed into a box's ring
/// slot `rp` and running sums `sp` as [`taps_push_avx512`] pushes them.
///
/// # Safety
/// The CPU must support AVX-512F, and the lanes of `k` must lie inside the
/// rows `rp` and `sp` point into.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn push_vector<const CLAMP: bool, const CASE: u8>(
    rp: *mut i32,
    sp: *mut i32,
    x: std::arch::x86_64::__m512,
    k: std::arch::x86_64::__mmask16,
    limit: f32,
) {
    use std::arch::x86_64::*;
    // SAFETY: the caller's.
    unsafe {
        // `max` returns its second operand when the first is NaN.
        let x = if CLAMP { _mm512_min_ps(_mm512_max_ps(x, _mm512_set1_ps(-limit)), _mm512_set1_ps(limit)) } else { x };
        let v = _mm512_cvt_roundps_epi32::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(x);
        let s = match CASE {
            0 => v,
            1 => _mm512_add_epi32(masked::load_epi32(k, sp), v),
            _ => _mm512_sub_epi32(_mm512_add_epi32(masked::load_epi32(k, sp), v), masked::load_epi32(k, rp)),
        };
        masked::store_epi32(rp, k, v);
        masked::store_epi32(sp, k, s);
    }
}

/// The clipped windows of a row next to its clip's edge, summed and pushed
/// in one masked vector: the columns `x0..x0 + ring.len()` (at most 16),
/// with `win = ((c0, c1), f, x0)` each column `x`'s window
/// `[x - f, x + f] ∩ [c0, c1)` summed from its first sample in increasing
/// x (from `-0`, which adds exactly: the scalar sum's bits), then pushed
/// as [`taps_push_avx512`] pushes a sum. `src` holds the row from column
/// `src_x0` and covers every window.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
pub unsafe fn clipped_push_avx512<const CLAMP: bool, const CASE: u8>(
    src: &[f32],
    src_x0: i64,
    ((c0, c1), f, x0): ((i64, i64), i64, i64),
    ring: &mut [i32],
    run: &mut [i32],
    limit: f32,
) {
    use std::arch::x86_64::*;
    let n = ring.len();
    assert!(n <= 16 && run.len() == n && n > 0, "at most 16 columns");
    let (first, last) = ((x0 - f).max(c0), (x0 + n as i64 - 1 + f).min(c1 - 1));
    assert!(first >= src_x0 && last < src_x0 + src.len() as i64, "the windows inside the row");
    let all: __mmask16 = ((1u32 << n) - 1) as u16;
    // Lane `i` is column `x0 + i`: its window's first and last columns.
    let x = _mm512_add_epi32(
        _mm512_set1_epi32(x0 as i32),
        _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
    );
    let a = _mm512_max_epi32(_mm512_sub_epi32(x, _mm512_set1_epi32(f as i32)), _mm512_set1_epi32(c0 as i32));
    let b = _mm512_min_epi32(_mm512_add_epi32(x, _mm512_set1_epi32(f as i32)), _mm512_set1_epi32(c1 as i32 - 1));
    let mut acc = _mm512_set1_ps(-0.0);
    for t in 0..=2 * f {
        // Tap `t` of lane `i`: column `x0 + i - f + t`.
        let col = _mm512_add_epi32(x, _mm512_set1_epi32((t - f) as i32));
        let k = all & _mm512_cmpge_epi32_mask(col, a) & _mm512_cmple_epi32_mask(col, b);
        // SAFETY: the lanes of `k` read columns `first..=last`, inside
        // `src` (asserted); the pointer to lane 0 is formed with
        // `wrapping_offset`.
        let v = unsafe { _mm512_maskz_loadu_ps(k, src.as_ptr().wrapping_offset((x0 - f + t - src_x0) as isize)) };
        acc = _mm512_mask_add_ps(acc, k, acc, v);
    }
    // SAFETY: the lanes of `all` are the `n` columns of `ring` and `run`.
    unsafe { push_vector::<CLAMP, CASE>(ring.as_mut_ptr(), run.as_mut_ptr(), acc, all, limit) };
}

/// Masked loads and stores of 16 lanes that run as plain ones when the mask
/// keeps every lane (a row's interior), for [`taps_push_avx512`]. On AMD's
/// Zen 4 the pushes with plain loads and stores inside their rows took
/// 0.95-0.97x the full filter's time (session 31, docs/performance.md);
/// the same change in the weights' and the guides' loops as well measured
/// no further gain. The same lanes are read and written either way, so the
/// same bits.
///
/// # Safety
/// The CPU must support AVX-512F, and the lanes `k` keeps must lie inside
/// the row `p` points into.
#[cfg(target_arch = "x86_64")]
mod masked {
    use std::arch::x86_64::*;

    /// `_mm512_maskz_loadu_ps`.
    #[inline(always)]
    pub(super) unsafe fn load_ps(k: __mmask16, p: *const f32) -> __m512 {
        // SAFETY: the caller's (see the module).
        unsafe { if k == u16::MAX { _mm512_loadu_ps(p) } else { _mm512_maskz_loadu_ps(k, p) } }
    }

    /// `_mm512_maskz_loadu_epi32`.
    #[inline(always)]
    pub(super) unsafe fn load_epi32(k: __mmask16, p: *const i32) -> __m512i {
        // SAFETY: the caller's (see the module).
        unsafe { if k == u16::MAX { _mm512_loadu_si512(p.cast()) } else { _mm512_maskz_loadu_epi32(k, p) } }
    }

    /// `_mm512_mask_storeu_epi32`.
    #[inline(always)]
    pub(super) unsafe fn store_epi32(p: *mut i32, k: __mmask16, v: __m512i) {
        // SAFETY: the caller's (see the module).
        unsafe { if k == u16::MAX { _mm512_storeu_si512(p.cast(), v) } else { _mm512_mask_storeu_epi32(p, k, v) } }
    }
}

/// The window sums of `2F + 1` taps of consecutive chunks of a row `src`
/// (AVX-512): the samples from the chunk's start and 16 further (`x0`,
/// `x1`), and their pair sums `p[j] = src[j] + src[j + 1]` (`p0`), carried
/// to the next chunk. `F` from 1 to 4: every shifted operand lies within
/// the two vectors it is taken from.
#[cfg(target_arch = "x86_64")]
struct Taps<'a, const F: usize> {
    src: &'a [f32],
    x0: std::arch::x86_64::__m512,
    x1: std::arch::x86_64::__m512,
    p0: std::arch::x86_64::__m512,
}

#[cfg(target_arch = "x86_64")]
impl<'a, const F: usize> Taps<'a, F> {
    /// Ready for the chunk at 0.
    #[inline(always)]
    fn new(src: &'a [f32]) -> Taps<'a, F> {
        use std::arch::x86_64::*;
        const { assert!(F >= 1 && F <= 4, "windows of 3 to 9 taps") };
        let (x0, x1) = (Self::load(src, 0), Self::load(src, CHUNK));
        // SAFETY: the callers run only on CPUs with avx512f (their wrappers' target feature).
        let p0 = unsafe { _mm512_add_ps(x0, valign::<1>(x0, x1)) };
        Taps { src, x0, x1, p0 }
    }

    /// Samples `at..at + 16` of `src`, lanes past its end zero (masked
    /// off, so never read).
    #[inline(always)]
    fn load(src: &[f32], at: usize) -> std::arch::x86_64::__m512 {
        use std::arch::x86_64::*;
        let len = src.len();
        let k: __mmask16 = if at >= len {
            0
        } else if len - at >= 16 {
            0xFFFF
        } else {
            (1u16 << (len - at)) - 1
        };
        // SAFETY: the mask selects only lanes inside `src`; masked-off
        // lanes are not accessed (avx512f: see `new`).
        unsafe { masked::load_ps(k, src.as_ptr().wrapping_add(at)) }
    }

    /// The sums of outputs `i..i + 16`, `i` the chunk after the previous call's (0 first).
    #[inline(always)]
    fn next(&mut self, i: usize) -> std::arch::x86_64::__m512 {
        let x2 = Self::load(self.src, i + 2 * CHUNK);
        self.next_with(x2)
    }

    /// [`Taps::next`] where samples `i + 32..i + 48` lie inside `src`
    /// (checked): one plain load, no mask.
    #[inline(always)]
    fn next_whole(&mut self, i: usize) -> std::arch::x86_64::__m512 {
        use std::arch::x86_64::*;
        assert!(i + 3 * CHUNK <= self.src.len(), "a whole chunk");
        // SAFETY: the samples lie inside `src` (above; avx512f: see `new`).
        let x2 = unsafe { _mm512_loadu_ps(self.src.as_ptr().add(i + 2 * CHUNK)) };
        self.next_with(x2)
    }

    /// The sums of the next chunk, given the samples 32 further (`x2`).
    #[inline(always)]
    fn next_with(&mut self, x2: std::arch::x86_64::__m512) -> std::arch::x86_64::__m512 {
        use std::arch::x86_64::*;
        let (x0, x1, p0) = (self.x0, self.x1, self.p0);
        // SAFETY: avx512f, see `new`.
        unsafe {
            let p1 = _mm512_add_ps(x1, valign::<1>(x1, x2));
            // `((p[i] + p[i + 2]) + ...) + p[i + 2F - 2]`, in that order.
            let mut acc = p0;
            if F >= 2 {
                acc = _mm512_add_ps(acc, valign::<2>(p0, p1));
            }
            if F >= 3 {
                acc = _mm512_add_ps(acc, valign::<4>(p0, p1));
            }
            if F >= 4 {
                acc = _mm512_add_ps(acc, valign::<6>(p0, p1));
            }
            // Then `src[i + 2F]`.
            let last = match F {
                1 => valign::<2>(x0, x1),
                2 => valign::<4>(x0, x1),
                3 => valign::<6>(x0, x1),
                _ => valign::<8>(x0, x1),
            };
            let o = _mm512_add_ps(acc, last);
            (self.x0, self.x1, self.p0) = (x1, x2, p1);
            o
        }
    }
}

/// `(a:b)` shifted down by `K` lanes: lane `j` is `a[j + K]`, or `b[j + K - 16]`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn valign<const K: i32>(a: std::arch::x86_64::__m512, b: std::arch::x86_64::__m512) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    // SAFETY: avx512f, see `Taps::new`.
    unsafe { _mm512_castsi512_ps(_mm512_alignr_epi32::<K>(_mm512_castps_si512(b), _mm512_castps_si512(a))) }
}

/// The variance term's subtraction `d2 - alpha s` as one fused multiply-add,
/// or, with `ALPHA_ONE` (the caller has checked `alpha == 1`, the default), as
/// the subtraction `d2 - s`. The two give the same bits: `-1 * s` is exact,
/// so the fused multiply-add rounds exactly the sum the subtraction rounds,
/// signed zeros, infinities and NaNs included. On CPUs whose adds run on other
/// pipes than their multiplies and fused multiply-adds (AMD Zen), the
/// subtraction moves work off the busier pipes.
#[inline(always)]
fn variance_term<const ALPHA_ONE: bool>(alpha: f32, s: f32, d2: f32) -> f32 {
    if ALPHA_ONE { d2 - s } else { (-alpha).mul_add(s, d2) }
}

/// [`accumulate_colour_distance_pair`] over three channels at once into
/// zeroed rows: `fwd[i] = ((0 + t0) + t1) + t2` (and `mir` likewise), the
/// same operations as three calls on rows filled with zeros, without the rows'
/// round trips through memory. With `ALPHA_ONE` (the caller has checked
/// `alpha == 1`), the variance term `d2 - alpha s` is a subtraction instead
/// of a fused multiply-add, with the same bits (see `variance_term`).
#[inline(always)]
pub fn colour_distance_pair_rgb<const W: usize, const ALPHA_ONE: bool>(
    fwd: &mut [f32],
    mir: &mut [f32],
    up: [&[f32]; 3],
    uq: [&[f32]; 3],
    vp: [&[f32]; 3],
    vq: [&[f32]; 3],
    (alpha, eps, k2): (f32, f32, f32),
) {
    let n = fwd.len();
    let mir = &mut mir[..n];
    let (up, uq, vp, vq) = (cut(up, n), cut(uq, n), cut(vp, n), cut(vq, n));
    // Channel c's terms of both directions, added to `a` and `b`.
    let step = |(a, b): (f32, f32), up: f32, uq: f32, vp: f32, vq: f32| {
        let d = up - uq;
        let d2 = d * d;
        let m = if vq < vp { vq } else { vp };
        let r = 1.0 / k2.mul_add(vp + vq, eps);
        let e = variance_term::<ALPHA_ONE>(alpha, m, d2);
        (variance_term::<ALPHA_ONE>(alpha, vp, e).mul_add(r, a), variance_term::<ALPHA_ONE>(alpha, vq, e).mul_add(r, b))
    };
    if n < W {
        for i in 0..n {
            let mut ab = (0.0f32, 0.0f32);
            for c in 0..3 {
                ab = step(ab, up[c][i], uq[c][i], vp[c][i], vq[c][i]);
            }
            (fwd[i], mir[i]) = ab;
        }
        return;
    }
    for ch in 0..chunk_count::<W>(n) {
        let i = chunk_start::<W>(ch, n);
        let (mut a, mut b) = ([0.0f32; W], [0.0f32; W]);
        for c in 0..3 {
            let (up, uq, vp, vq) =
                (chunk::<W>(up[c], i), chunk::<W>(uq[c], i), chunk::<W>(vp[c], i), chunk::<W>(vq[c], i));
            for k in 0..W {
                (a[k], b[k]) = step((a[k], b[k]), up[k], uq[k], vp[k], vq[k]);
            }
        }
        (*chunk_mut::<W>(fwd, i), *chunk_mut::<W>(mir, i)) = (a, b);
    }
}

/// One row of each of `C` channels.
pub type ChannelRowsRef<'a, const C: usize> = [&'a [f32]; C];

/// One feature's rows for [`fold_feature_term`]: the feature at `p` and at
/// `q = p + n`, the variances at both when the feature has one, and the
/// per-pixel weight factors `inv_den` (one plane for every channel when the
/// feature has no variance, one per channel when it has).
pub struct FeatureRows<'a, const C: usize> {
    /// The feature's channels at `p`.
    pub fp: [&'a [f32]; C],
    /// The feature's channels at `q`.
    pub fq: [&'a [f32]; C],
    /// The variances at `p` and at `q`.
    pub var: Option<(ChannelRowsRef<'a, C>, ChannelRowsRef<'a, C>)>,
    /// The weight factors at `p` (only the first is read without a variance).
    pub inv_den: [&'a [f32]; C],
}

/// Fold one feature's term of the feature weight's argument (SPEC §3) for a
/// row into `out` by a NaN-safe minimum (a NaN term never wins; with `FIRST`,
/// `out` starts from 0):
///
/// * without variance, `t = inv_den_0 * (((0 + d_0^2) + d_1^2) + ...)`, one
///   multiply by the denominator shared by the channels;
/// * with variance, `t = ((0 + n_0 inv_den_0) + n_1 inv_den_1) + ...` with
///   `n_c = d_c^2 - (vp_c + min(vp_c, vq_c))`,
///
/// where `d_c = fp_c - fq_c`, every `+ x y` one fused multiply-add. All the
/// channels are read in one pass, the sum kept in a register.
#[inline(always)]
pub fn fold_feature_term<const W: usize, const C: usize, const FIRST: bool>(
    out: &mut [f32],
    rows: &FeatureRows<'_, C>,
) {
    let n = out.len();
    let (fp, fq) = (cut(rows.fp, n), cut(rows.fq, n));
    let fold = |o: f32, t: f32| fold_min(if FIRST { 0.0 } else { o }, t);
    // The fold is idempotent: an overlapping last chunk gives the same bits.
    match rows.var {
        None => {
            let inv = &rows.inv_den[0][..n];
            if n < W {
                for i in 0..n {
                    out[i] = fold(out[i], square_sum_at(&fp, &fq, i) * inv[i]);
                }
                return;
            }
            for ch in 0..chunk_count::<W>(n) {
                let i = chunk_start::<W>(ch, n);
                let s = square_sum_chunk::<W, C>(&fp, &fq, i);
                let (mut o, inv) = (*chunk::<W>(out, i), chunk::<W>(inv, i));
                for k in 0..W {
                    o[k] = fold(o[k], s[k] * inv[k]);
                }
                *chunk_mut::<W>(out, i) = o;
            }
        }
        Some((vp, vq)) => {
            let (vp, vq, inv) = (cut(vp, n), cut(vq, n), cut(rows.inv_den, n));
            if n < W {
                for i in 0..n {
                    let mut a = 0.0f32;
                    for c in 0..C {
                        a = variance_step(a, fp[c][i], fq[c][i], vp[c][i], vq[c][i], inv[c][i]);
                    }
                    out[i] = fold(out[i], a);
                }
                return;
            }
            for ch in 0..chunk_count::<W>(n) {
                let i = chunk_start::<W>(ch, n);
                let mut a = [0.0f32; W];
                for c in 0..C {
                    let (p, q) = (chunk::<W>(fp[c], i), chunk::<W>(fq[c], i));
                    let (x, y, v) = (chunk::<W>(vp[c], i), chunk::<W>(vq[c], i), chunk::<W>(inv[c], i));
                    for k in 0..W {
                        a[k] = variance_step(a[k], p[k], q[k], x[k], y[k], v[k]);
                    }
                }
                let mut o = *chunk::<W>(out, i);
                for k in 0..W {
                    o[k] = fold(o[k], a[k]);
                }
                *chunk_mut::<W>(out, i) = o;
            }
        }
    }
}

/// The variance rows at `p` and at `q` of any number of channels.
pub type VarianceRows<'a> = (&'a [&'a [f32]], &'a [&'a [f32]]);

/// [`fold_feature_term`] for any number of channels (rows as slices, not
/// arrays): the same operations per pixel, for features of more than four
/// channels.
pub fn fold_feature_term_any(
    out: &mut [f32],
    fp: &[&[f32]],
    fq: &[&[f32]],
    var: Option<VarianceRows<'_>>,
    inv_den: &[&[f32]],
    first: bool,
) {
    for i in 0..out.len() {
        let t = match var {
            None => fp.iter().zip(fq).fold(0.0f32, |s, (p, q)| plain_step(s, p[i], q[i])) * inv_den[0][i],
            Some((vp, vq)) => (0..fp.len())
                .fold(0.0f32, |a, c| variance_step(a, fp[c][i], fq[c][i], vp[c][i], vq[c][i], inv_den[c][i])),
        };
        out[i] = fold_min(if first { 0.0 } else { out[i] }, t);
    }
}

/// `out[i] = ((0 + d_0^2) + d_1^2) + ...` with `d_c = fp_c - fq_c`: the sum
/// [`fold_feature_term`] multiplies by the denominator for a feature without
/// variance. It is symmetric: the pair `(q, p)` gives the same bits (a
/// difference only changes sign), so offsets `n` and `-n` share it.
#[inline(always)]
pub fn feature_square_sum<const W: usize, const C: usize>(
    out: &mut [f32],
    fp: ChannelRowsRef<'_, C>,
    fq: ChannelRowsRef<'_, C>,
) {
    let n = out.len();
    let (fp, fq) = (cut(fp, n), cut(fq, n));
    if n < W {
        for (i, o) in out.iter_mut().enumerate() {
            *o = square_sum_at(&fp, &fq, i);
        }
        return;
    }
    for ch in 0..chunk_count::<W>(n) {
        let i = chunk_start::<W>(ch, n);
        *chunk_mut::<W>(out, i) = square_sum_chunk::<W, C>(&fp, &fq, i);
    }
}

/// The half kernels' rows cut to `out.len()` samples, or `None` when the row
/// is shorter than a chunk, after writing its square sums one sample at a
/// time (the same operations).
#[inline(always)]
#[allow(clippy::type_complexity)]
fn half_rows_of_chunks<'a, const C: usize>(
    out: &mut [f32],
    fp: [&'a [half::f16]; C],
    fq: [&'a [half::f16]; C],
) -> Option<([&'a [half::f16]; C], [&'a [half::f16]; C])> {
    let n = out.len();
    let (mut p, mut q): ([&[half::f16]; C], [&[half::f16]; C]) = ([&[]; C], [&[]; C]);
    for c in 0..C {
        (p[c], q[c]) = (&fp[c][..n], &fq[c][..n]);
    }
    if n >= CHUNK {
        return Some((p, q));
    }
    for (i, o) in out.iter_mut().enumerate() {
        let mut s = 0.0f32;
        for c in 0..C {
            s = plain_step(s, p[c][i].to_f32(), q[c][i].to_f32());
        }
        *o = s;
    }
    None
}

/// [`feature_square_sum`] of a feature stored as half floats (see
/// [`HalfPlane`](crate::image::HalfPlane)): each chunk of 16 samples widened
/// by one `vcvtph2ps` (exact), then the same operations, so the same bits
/// in half the bytes read.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn feature_square_sum_half_avx512<const C: usize>(
    out: &mut [f32],
    fp: [&[half::f16]; C],
    fq: [&[half::f16]; C],
) {
    use std::arch::x86_64::*;
    let n = out.len();
    let Some((p, q)) = half_rows_of_chunks(out, fp, fq) else { return };
    // 16 samples of `row` from `i` (`i + CHUNK <= row.len()`), widened.
    let widen = |row: &[half::f16], i: usize| {
        debug_assert!(i + CHUNK <= row.len());
        // SAFETY: the chunk `i..i + CHUNK` lies inside `row` (checked by
        // the callers' `chunk_start`); an unaligned 32-byte load.
        unsafe { _mm512_cvtph_ps(_mm256_loadu_si256(row.as_ptr().add(i).cast())) }
    };
    for ch in 0..chunk_count::<CHUNK>(n) {
        let i = chunk_start::<CHUNK>(ch, n);
        let mut s = _mm512_setzero_ps();
        for c in 0..C {
            let d = _mm512_sub_ps(widen(p[c], i), widen(q[c], i));
            s = _mm512_fmadd_ps(d, d, s);
        }
        // SAFETY: `i + CHUNK <= n = out.len()`.
        unsafe { _mm512_storeu_ps(out.as_mut_ptr().add(i), s) };
    }
}

/// [`feature_square_sum_half_avx512`] for the AVX2 tier: each chunk of 16
/// samples widened by two `vcvtph2ps` of 8 (F16C, exact), then the same
/// operations, so the same bits in half the bytes read.
///
/// # Safety
/// The CPU must support AVX2, FMA and F16C.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
#[inline]
pub unsafe fn feature_square_sum_half_avx2<const C: usize>(
    out: &mut [f32],
    fp: [&[half::f16]; C],
    fq: [&[half::f16]; C],
) {
    use std::arch::x86_64::*;
    let n = out.len();
    let Some((p, q)) = half_rows_of_chunks(out, fp, fq) else { return };
    // 8 samples of `row` from `i` (`i + 8 <= row.len()`), widened.
    let widen = |row: &[half::f16], i: usize| {
        debug_assert!(i + CHUNK / 2 <= row.len());
        // SAFETY: the samples `i..i + 8` lie inside `row` (the callers'
        // `chunk_start` keeps `i + CHUNK <= n`); an unaligned 16-byte load.
        unsafe { _mm256_cvtph_ps(_mm_loadu_si128(row.as_ptr().add(i).cast())) }
    };
    for ch in 0..chunk_count::<CHUNK>(n) {
        let i = chunk_start::<CHUNK>(ch, n);
        for j in [i, i + CHUNK / 2] {
            let mut s = _mm256_setzero_ps();
            for c in 0..C {
                let d = _mm256_sub_ps(widen(p[c], j), widen(q[c], j));
                s = _mm256_fmadd_ps(d, d, s);
            }
            // SAFETY: `j + 8 <= i + CHUNK <= n = out.len()`.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(j), s) };
        }
    }
}

/// The most channels, over all its guides, [`guide_pair_products_avx512`] reads.
pub const PAIR_GUIDE_CHANNELS_MAX: usize = 16;

/// One lane of [`guide_pair_products_avx512`]: its row of the guides'
/// weight argument and each guide's factors for the same pixels.
pub struct ProductLane<'a> {
    /// Where the lane's first pixel lies in the pair's row, in samples.
    pub from: usize,
    /// The lane's row, written from its first sample (`out.len()` samples).
    pub out: &'a mut [f32],
    /// Guide `g`'s factors `inv_g` at the lane's pixels, `out.len()` each.
    pub inv: [&'a [f32]; PRODUCTS_MAX],
}

/// A guide channel's row for [`guide_pair_products_avx512`]: `f32`, or
/// half floats (see [`HalfPlane`](crate::image::HalfPlane)), widened
/// exactly where they are read (widening each row once into a scratch row
/// shared by a step's pairs measured slower, docs/performance.md session 26).
#[derive(Clone, Copy)]
pub enum GuideRow<'a> {
    /// Samples stored as `f32`.
    Full(&'a [f32]),
    /// Samples stored as half floats.
    Half(&'a [half::f16]),
}

impl GuideRow<'_> {
    /// The row's length in samples.
    pub fn len(&self) -> usize {
        match self {
            GuideRow::Full(r) => r.len(),
            GuideRow::Half(r) => r.len(),
        }
    }

    /// Whether the row is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The `16 V` samples from `i`, as `f32` (`i + 16 V <= self.len()`).
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline]
    unsafe fn load_chunk<const V: usize>(self, i: usize) -> [std::arch::x86_64::__m512; V] {
        use std::arch::x86_64::*;
        assert!(i + 16 * V <= self.len(), "a chunk inside the row");
        let mut out = [_mm512_setzero_ps(); V];
        // SAFETY (both arms): the chunk lies inside the row (asserted);
        // unaligned loads, the halves widened by one `vcvtph2ps` (exact).
        match self {
            GuideRow::Full(r) => {
                for (v, o) in out.iter_mut().enumerate() {
                    *o = unsafe { _mm512_loadu_ps(r.as_ptr().add(i + 16 * v)) };
                }
            }
            GuideRow::Half(r) => {
                for (v, o) in out.iter_mut().enumerate() {
                    *o = unsafe { _mm512_cvtph_ps(_mm256_loadu_si256(r.as_ptr().add(i + 16 * v).cast())) };
                }
            }
        }
        out
    }
}

/// [`feature_square_sum`] of every guide of a pair of offsets followed by
/// [`fold_feature_products`] (from 0) of both its lanes, in one pass: each
/// chunk's square sums stay in registers instead of a stored row read back
/// by each lane. Guide `g` has the channels `ends[g - 1]..ends[g]` (from 0)
/// of `fp` and `fq` (rows of `n >= CHUNK_AVX512` samples, `f32` or half
/// floats); a lane gets `min(0, s_0 inv_0, s_1 inv_1, ...)` folded as
/// `fold_min` folds it, guide by guide, for its pixels
/// `from..from + out.len()` of the pair's row (masked loads and stores
/// where a chunk covers it in part).
/// The same operations on each sample as the two stored passes, so the same
/// bits.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn guide_pair_products_avx512(
    n: usize,
    (fp, fq): (&[GuideRow<'_>], &[GuideRow<'_>]),
    ends: &[usize],
    mut lanes: [Option<ProductLane<'_>>; 2],
) {
    let k = ends.len();
    assert!(n >= CHUNK_AVX512 && (1..=PRODUCTS_MAX).contains(&k), "{n} samples, {k} guides");
    let channels = ends[k - 1];
    assert!(channels <= PAIR_GUIDE_CHANNELS_MAX && fp.len() == channels && fq.len() == channels);
    assert!(ends.windows(2).all(|e| e[0] < e[1]) && ends[0] > 0, "every guide has a channel");
    for c in 0..channels {
        assert!(fp[c].len() >= n && fq[c].len() >= n, "the channels' rows hold the pair's samples");
    }
    for lane in lanes.iter().flatten() {
        let len = lane.out.len();
        assert!(len > 0 && lane.from + len <= n, "a lane lies inside the pair's row");
        assert!(lane.inv[..k].iter().all(|r| r.len() >= len), "the factors cover the lane");
    }
    // SAFETY: the caller's CPU supports AVX-512F.
    unsafe {
        match k {
            1 => guide_pair_products::<1>(n, (fp, fq), ends, &mut lanes),
            2 => guide_pair_products::<2>(n, (fp, fq), ends, &mut lanes),
            3 => guide_pair_products::<3>(n, (fp, fq), ends, &mut lanes),
            _ => guide_pair_products::<4>(n, (fp, fq), ends, &mut lanes),
        }
    }
}

/// [`guide_pair_products_avx512`] for `K` guides, on chunks of
/// [`CHUNK_AVX512`] samples (four vectors: the per-chunk and per-channel
/// integer work spread over four vectors' arithmetic), the last one
/// overlapping its predecessor (the lanes' rows are outputs only).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn guide_pair_products<const K: usize>(
    n: usize,
    (fp, fq): (&[GuideRow<'_>], &[GuideRow<'_>]),
    ends: &[usize],
    lanes: &mut [Option<ProductLane<'_>>; 2],
) {
    use std::arch::x86_64::*;
    const V: usize = CHUNK_AVX512 / 16;
    // The bits `j` of a chunk from `i` whose sample `i + j` lies in `a..b`.
    let below = |m: usize| if m >= 64 { u64::MAX } else { (1u64 << m) - 1 };
    let in_lane = |(a, b): (usize, usize), i: usize| below(b.saturating_sub(i)) & !below(a.saturating_sub(i));
    for ch in 0..chunk_count::<CHUNK_AVX512>(n) {
        let i = chunk_start::<CHUNK_AVX512>(ch, n);
        let mut s = [[_mm512_setzero_ps(); V]; K];
        let mut c = 0;
        for (g, sg) in s.iter_mut().enumerate() {
            while c < ends[g] {
                // SAFETY: `i + CHUNK_AVX512 <= n <= len` of both rows
                // (asserted by the caller).
                let (p, q) = unsafe { (fp[c].load_chunk::<V>(i), fq[c].load_chunk::<V>(i)) };
                for v in 0..V {
                    let d = _mm512_sub_ps(p[v], q[v]);
                    sg[v] = _mm512_fmadd_ps(d, d, sg[v]);
                }
                c += 1;
            }
        }
        for lane in lanes.iter_mut().flatten() {
            let (a, b) = (lane.from, lane.from + lane.out.len());
            let m = in_lane((a, b), i);
            if m == 0 {
                continue;
            }
            // Sample `i - a` of the lane's rows (`wrapping_`: it may lie
            // before their start; the masked-off samples are not touched).
            let at = i.wrapping_sub(a);
            for v in 0..V {
                let mask = (m >> (16 * v)) as u16;
                let at = at.wrapping_add(16 * v);
                let mut o = _mm512_setzero_ps();
                for (g, sg) in s.iter().enumerate() {
                    // SAFETY: the mask keeps the samples `0..out.len()` of
                    // the factors' rows (asserted to hold them).
                    let inv = unsafe { _mm512_maskz_loadu_ps(mask, lane.inv[g].as_ptr().wrapping_add(at)) };
                    // `fold_min(o, t)`: `t` only when it is smaller
                    // (`vminps` returns its second operand on equality or a NaN).
                    o = _mm512_min_ps(_mm512_mul_ps(sg[v], inv), o);
                }
                // SAFETY: the mask keeps the samples `a..b` of the pair's
                // row, `0..out.len()` of the lane's.
                unsafe { _mm512_mask_storeu_ps(lane.out.as_mut_ptr().wrapping_add(at), mask, o) };
            }
        }
    }
}

/// One lane of [`guide_variance_pair_avx512`]: where its first pixel lies in
/// the pair's row (in samples), its row of the guides' weight argument
/// (`out.len()` samples), and the feature's factors `inv_den` of each
/// channel at the lane's pixels (`out.len()` each).
pub type VarianceLane<'a, const C: usize> = (usize, &'a mut [f32], [&'a [f32]; C]);

/// [`fold_feature_term`] with variance, for both lanes of a pair of offsets
/// `n` and `-n` in one pass over the pair's rows: the forward lane's term at
/// `p` is `variance_step` over the channels of `(fp, fq, vp, vq)` with its
/// factors, the mirror lane's at `p + n` the same with the roles of `p` and
/// `q` swapped, each folded into its lane's row (from 0 when `first`) by the
/// NaN-safe minimum. The same operations per sample as the per-lane
/// [`fold_feature_term`] (the difference `q - p` is exactly `-(p - q)`, so
/// both lanes share one; each lane keeps its own minimum of the variances,
/// whose operand order decides which of a NaN and a number it gives), so
/// the same bits; each channel's rows are read once for both lanes instead
/// of once per lane.
/// Rows of `n >= 16` samples; the last chunk overlaps its predecessor (the
/// fold is idempotent).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn guide_variance_pair_avx512<const C: usize>(
    n: usize,
    (fp, fq): (&[&[f32]; C], &[&[f32]; C]),
    (vp, vq): (&[&[f32]; C], &[&[f32]; C]),
    first: bool,
    lanes: [Option<VarianceLane<'_, C>>; 2],
) {
    use std::arch::x86_64::*;
    assert!(n >= 16, "{n} samples");
    for c in 0..C {
        assert!(fp[c].len() >= n && fq[c].len() >= n && vp[c].len() >= n && vq[c].len() >= n, "the pair's rows");
    }
    for (from, out, inv) in lanes.iter().flatten() {
        let len = out.len();
        assert!(len > 0 && from + len <= n, "a lane lies inside the pair's row");
        assert!(inv.iter().all(|r| r.len() >= len), "the factors cover the lane");
    }
    // The bits `k` of a chunk from `i` whose sample `i + k` lies in the lane.
    let in_lane = |lane: &Option<VarianceLane<'_, C>>, i: usize| -> u16 {
        let Some((from, out, _)) = lane else { return 0 };
        let (lo, hi) = (from.saturating_sub(i).min(16), (from + out.len()).saturating_sub(i).min(16));
        if hi <= lo { 0 } else { (((1u32 << hi) - 1) & !((1u32 << lo) - 1)) as u16 }
    };
    let [mut fwd, mut mir] = lanes;
    for ch in 0..chunk_count::<16>(n) {
        let i = chunk_start::<16>(ch, n);
        let (mf, mm) = (in_lane(&fwd, i), in_lane(&mir, i));
        // Sample `i - from` of a lane's rows (`wrapping_`: it may lie before
        // their start; the masked-off samples are not touched).
        let at_f = fwd.as_ref().map_or(0, |l| i.wrapping_sub(l.0));
        let at_m = mir.as_ref().map_or(0, |l| i.wrapping_sub(l.0));
        let (mut af, mut am) = (_mm512_setzero_ps(), _mm512_setzero_ps());
        for c in 0..C {
            // SAFETY: `i + 16 <= n <= len` of every pair row (asserted); the
            // masks keep the samples `0..out.len()` of the factors' rows.
            unsafe {
                let p = _mm512_loadu_ps(fp[c].as_ptr().add(i));
                let q = _mm512_loadu_ps(fq[c].as_ptr().add(i));
                let x = _mm512_loadu_ps(vp[c].as_ptr().add(i));
                let y = _mm512_loadu_ps(vq[c].as_ptr().add(i));
                let d = _mm512_sub_ps(p, q);
                if let Some((_, _, inv)) = &fwd
                    && mf != 0
                {
                    // `vq < vp ? vq : vp`, then `d d - (vp + m)` and the factor.
                    let e = _mm512_fmsub_ps(d, d, _mm512_add_ps(x, _mm512_min_ps(y, x)));
                    let f = _mm512_maskz_loadu_ps(mf, inv[c].as_ptr().wrapping_add(at_f));
                    af = _mm512_fmadd_ps(e, f, af);
                }
                if let Some((_, _, inv)) = &mir
                    && mm != 0
                {
                    // The pair `(q, p)`: `vp < vq ? vp : vq`, `(-d)^2 = d^2`.
                    let e = _mm512_fmsub_ps(d, d, _mm512_add_ps(y, _mm512_min_ps(x, y)));
                    let f = _mm512_maskz_loadu_ps(mm, inv[c].as_ptr().wrapping_add(at_m));
                    am = _mm512_fmadd_ps(e, f, am);
                }
            }
        }
        for (lane, mask, at, a) in [(&mut fwd, mf, at_f, af), (&mut mir, mm, at_m, am)] {
            let Some((_, out, _)) = lane else { continue };
            if mask == 0 {
                continue;
            }
            let ptr = out.as_mut_ptr().wrapping_add(at);
            // SAFETY: the mask keeps the samples `0..out.len()` of the lane's row.
            unsafe {
                let o = if first { _mm512_setzero_ps() } else { _mm512_maskz_loadu_ps(mask, ptr) };
                // `fold_min(o, t)`: `t` only when it is smaller.
                _mm512_mask_storeu_ps(ptr, mask, _mm512_min_ps(a, o));
            }
        }
    }
}

/// Sample `i` of the square sum `((0 + d_0^2) + d_1^2) + ...`, `d_c = fp_c - fq_c`.
#[inline(always)]
fn square_sum_at<const C: usize>(fp: &[&[f32]; C], fq: &[&[f32]; C], i: usize) -> f32 {
    let mut s = 0.0f32;
    for c in 0..C {
        s = plain_step(s, fp[c][i], fq[c][i]);
    }
    s
}

/// [`square_sum_at`] for the chunk starting at `i`.
#[inline(always)]
fn square_sum_chunk<const W: usize, const C: usize>(fp: &[&[f32]; C], fq: &[&[f32]; C], i: usize) -> [f32; W] {
    let mut s = [0.0f32; W];
    for c in 0..C {
        let (p, q) = (chunk::<W>(fp[c], i), chunk::<W>(fq[c], i));
        for k in 0..W {
            s[k] = plain_step(s[k], p[k], q[k]);
        }
    }
    s
}

/// [`feature_square_sum`] for any number of channels.
pub fn feature_square_sum_any(out: &mut [f32], fp: &[&[f32]], fq: &[&[f32]]) {
    for (i, o) in out.iter_mut().enumerate() {
        *o = fp.iter().zip(fq).fold(0.0f32, |s, (p, q)| plain_step(s, p[i], q[i]));
    }
}

/// The most guides [`fold_feature_products`] folds in one pass.
pub const PRODUCTS_MAX: usize = 4;

/// Fold `t_g = s_g * inv_g` of every guide `g` (in order, 1 to
/// [`PRODUCTS_MAX`]) into `out` by the NaN-safe minimum of
/// [`fold_feature_term`] (from 0 when `first`), in one pass: the same bits
/// as [`fold_feature_term`] without variance for each guide in turn, given
/// each `s_g` from [`feature_square_sum`].
#[inline(always)]
pub fn fold_feature_products<const W: usize>(out: &mut [f32], s: &[&[f32]], inv: &[&[f32]], first: bool) {
    assert_eq!(s.len(), inv.len(), "each guide's square sums have their factors");
    match s.len() {
        1 => fold_products::<W, 1>(out, s, inv, first),
        2 => fold_products::<W, 2>(out, s, inv, first),
        3 => fold_products::<W, 3>(out, s, inv, first),
        4 => fold_products::<W, 4>(out, s, inv, first),
        k => panic!("{k} guides in one pass (1 to PRODUCTS_MAX)"),
    }
}

/// [`fold_feature_products`] for `K` guides.
#[inline(always)]
fn fold_products<const W: usize, const K: usize>(out: &mut [f32], s: &[&[f32]], inv: &[&[f32]], first: bool) {
    let n = out.len();
    let (mut sr, mut ir): ([&[f32]; K], [&[f32]; K]) = ([&[]; K], [&[]; K]);
    for g in 0..K {
        (sr[g], ir[g]) = (&s[g][..n], &inv[g][..n]);
    }
    if n < W {
        for i in 0..n {
            let mut o = if first { 0.0 } else { out[i] };
            for g in 0..K {
                o = fold_min(o, sr[g][i] * ir[g][i]);
            }
            out[i] = o;
        }
        return;
    }
    // The fold is idempotent: an overlapping last chunk gives the same bits.
    for ch in 0..chunk_count::<W>(n) {
        let i = chunk_start::<W>(ch, n);
        let mut o = if first { [0.0f32; W] } else { *chunk::<W>(out, i) };
        for g in 0..K {
            let (x, v) = (chunk::<W>(sr[g], i), chunk::<W>(ir[g], i));
            for j in 0..W {
                o[j] = fold_min(o[j], x[j] * v[j]);
            }
        }
        *chunk_mut::<W>(out, i) = o;
    }
}

/// The guides' NaN-safe minimum: `t` replaces `o` only when it is smaller,
/// so a NaN term never wins over a finite one.
#[inline(always)]
fn fold_min(o: f32, t: f32) -> f32 {
    if t < o { t } else { o }
}

/// `s + (p - q)^2`, one fused multiply-add.
#[inline(always)]
fn plain_step(s: f32, p: f32, q: f32) -> f32 {
    let d = p - q;
    d.mul_add(d, s)
}

/// `a + ((p - q)^2 - (vp + min(vp, vq))) * inv`, two fused multiply-adds.
#[inline(always)]
fn variance_step(a: f32, p: f32, q: f32, vp: f32, vq: f32, inv: f32) -> f32 {
    let d = p - q;
    let m = if vq < vp { vq } else { vp };
    d.mul_add(d, -(vp + m)).mul_add(inv, a)
}

/// A mean weight as the accumulation reads it: an `f32`, or a whole
/// window's integer sum from the weights' box, converted as it is read
/// (`f32(R)`, the same value a stored copy would hold).
pub trait WeightSample: Copy {
    /// Whether the samples are the box's `i32` sums.
    const INT: bool;
    /// The sample's value.
    fn value(self) -> f32;
}

impl WeightSample for f32 {
    const INT: bool = false;
    #[inline(always)]
    fn value(self) -> f32 {
        self
    }
}

impl WeightSample for i32 {
    const INT: bool = true;
    #[inline(always)]
    fn value(self) -> f32 {
        self as f32
    }
}

/// One lane of [`edge_columns_avx512`]: it covers the columns `lo..hi` of
/// the call's span, and its mean weights, their factors and its three
/// channels' values are given over those columns only.
#[derive(Clone, Copy)]
pub struct EdgeLane<'a, T> {
    /// The first column covered (from the span's start).
    pub lo: usize,
    /// One past the last.
    pub hi: usize,
    /// The lane's mean weights over `lo..hi`.
    pub w: &'a [T],
    /// Their factors (see [`SideFactors`]).
    pub fac: &'a [f32],
    /// Its three channels' values over `lo..hi`.
    pub values: [&'a [f32]; 3],
}

/// The accumulation's columns next to the frame's side that only some
/// lanes cover (at most 16, `d.len()`), in one masked vector: each lane's
/// term `w fac` is added to the denominator and `w fac v_c` to numerator
/// `c` in the columns it covers, lanes in order, one add or fused
/// multiply-add each (the scalar loop's operations: the same bits); the
/// other columns keep their sums exactly (masked operations).
///
/// # Safety
/// The CPU must support AVX-512F and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
pub unsafe fn edge_columns_avx512<T: WeightSample>([d, n0, n1, n2]: [&mut [f32]; 4], lanes: &[EdgeLane<'_, T>]) {
    use std::arch::x86_64::*;
    let n = d.len();
    assert!(n <= 16 && n0.len() == n && n1.len() == n && n2.len() == n, "at most 16 columns");
    let bits = |a: usize, b: usize| ((((1u32 << b) - 1) & !((1u32 << a) - 1)) & 0xFFFF) as __mmask16;
    let all = bits(0, n);
    // SAFETY (every load and store): a masked lane is never read or
    // written; the others lie inside their slice (`lo..hi` of the span is
    // the slice's `0..hi - lo`, asserted below), the pointers to a slice's
    // lane 0 formed with `wrapping_sub`.
    unsafe {
        let (mut dd, mut a0, mut a1, mut a2) = (
            _mm512_maskz_loadu_ps(all, d.as_ptr()),
            _mm512_maskz_loadu_ps(all, n0.as_ptr()),
            _mm512_maskz_loadu_ps(all, n1.as_ptr()),
            _mm512_maskz_loadu_ps(all, n2.as_ptr()),
        );
        for l in lanes {
            let m = l.hi.saturating_sub(l.lo);
            assert!(l.hi <= n && l.w.len() >= m && l.fac.len() >= m && l.values.iter().all(|v| v.len() >= m));
            if m == 0 {
                continue;
            }
            let k = bits(l.lo, l.hi);
            let at = |p: *const f32| p.wrapping_sub(l.lo);
            let w = l.w.as_ptr().wrapping_sub(l.lo);
            let wg = if T::INT {
                _mm512_cvtepi32_ps(_mm512_maskz_loadu_epi32(k, w.cast()))
            } else {
                _mm512_maskz_loadu_ps(k, w.cast())
            };
            let wg = _mm512_mul_ps(wg, _mm512_maskz_loadu_ps(k, at(l.fac.as_ptr())));
            dd = _mm512_mask_add_ps(dd, k, dd, wg);
            a0 = _mm512_mask3_fmadd_ps(wg, _mm512_maskz_loadu_ps(k, at(l.values[0].as_ptr())), a0, k);
            a1 = _mm512_mask3_fmadd_ps(wg, _mm512_maskz_loadu_ps(k, at(l.values[1].as_ptr())), a1, k);
            a2 = _mm512_mask3_fmadd_ps(wg, _mm512_maskz_loadu_ps(k, at(l.values[2].as_ptr())), a2, k);
        }
        _mm512_mask_storeu_ps(d.as_mut_ptr(), all, dd);
        _mm512_mask_storeu_ps(n0.as_mut_ptr(), all, a0);
        _mm512_mask_storeu_ps(n1.as_mut_ptr(), all, a1);
        _mm512_mask_storeu_ps(n2.as_mut_ptr(), all, a2);
    }
}

/// The factors of [`fused_rgb_shifted_avx512`]'s mean weights in a row
/// clipped at the frame's left or right side.
#[derive(Clone, Copy)]
pub struct SideFactors<'a, const G: usize> {
    /// Each lane's factor for each of its samples (indexed as its weights).
    pub fac: [&'a [f32]; G],
    /// The vectors `whole.0..whole.1` (16 samples each, from the first)
    /// whose every factor is 1: read without a multiply.
    pub whole: (usize, usize),
}

impl<const G: usize> SideFactors<'_, G> {
    /// No factors (for a call without `SCALED`).
    pub const NONE: Self = SideFactors { fac: [&[]; G], whole: (0, 0) };
}

/// The block kernel's fused accumulation (`nlmeans::fused_rgb`) for `G <= 7` lanes of consecutive `dx` on the AVX-512 tier:
/// `rows[c]` is channel `c`'s row from the smallest `dx` (`len + G - 1`
/// samples), lane `g` reads it from offset `g` (or `G - 1 - g` with `REV`).
/// Each vector of a lane is formed from the row's two vectors at the
/// sample (`valignd`) instead of a load of its own: unaligned 64-byte loads
/// split across cache lines, and the lanes' seven of them per channel cost
/// the accumulation 5-7 % of the filter's time (docs/performance.md,
/// session 21). Every sample gets `fused_rgb`'s operations in its order
/// (the lanes' terms in lane order, one fused multiply-add each), so the
/// same bits; the samples after the last whole vector as `fused_rgb`'s rest.
/// Each lane's mean weights are `f32`, or the weights' box's integer sums
/// (`i32`, converted as they are read). With `SCALED`, each mean weight
/// outside `scale`'s whole vectors is multiplied by its factor as it is
/// read (a clipped window's `k / (nx ny)`, or exactly 1).
///
/// # Safety
/// The CPU must support AVX-512F and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
#[allow(clippy::needless_range_loop)]
pub unsafe fn fused_rgb_shifted_avx512<const G: usize, const REV: bool, const SCALED: bool, T: WeightSample>(
    [d, n0, n1, n2]: [&mut [f32]; 4],
    w: [&[T]; G],
    rows: [&[f32]; 3],
    scale: SideFactors<'_, G>,
) {
    use std::arch::x86_64::*;
    const { assert!(G >= 1 && G <= 7) };
    let n = d.len();
    let len = n + G - 1;
    let (n0, n1, n2) = (&mut n0[..n], &mut n1[..n], &mut n2[..n]);
    let rows = cut(rows, len);
    let w = cut(w, n);
    let fac = if SCALED { cut(scale.fac, n) } else { scale.fac };
    let off = |g: usize| if REV { G - 1 - g } else { g };
    // Lane `j` of `sh!(k, a, b)` is `a[j + k]`, or `b[j + k - 16]`.
    macro_rules! sh {
        ($k:literal, $a:expr, $b:expr) => {
            _mm512_castsi512_ps(_mm512_alignr_epi32::<$k>(_mm512_castps_si512($b), _mm512_castps_si512($a)))
        };
    }
    for c in 0..n / 16 {
        let i = c * 16;
        // Samples `i + 16..` of a row: the first `G - 1` always exist
        // (`i + 16 <= n`); lanes past the row's end are masked off, never read.
        let rest = len - (i + 16);
        let k: __mmask16 = if rest >= 16 { 0xFFFF } else { (1u16 << rest) - 1 };
        let mut v = [[_mm512_setzero_ps(); 7]; 3];
        for (vc, row) in v.iter_mut().zip(rows) {
            // SAFETY: `i + 16 <= n <= len`, and the mask keeps the second
            // load inside the row.
            let (a, b) = unsafe {
                (_mm512_loadu_ps(row.as_ptr().add(i)), _mm512_maskz_loadu_ps(k, row.as_ptr().wrapping_add(i + 16)))
            };
            *vc = [a, sh!(1, a, b), sh!(2, a, b), sh!(3, a, b), sh!(4, a, b), sh!(5, a, b), sh!(6, a, b)];
        }
        // SAFETY (every load and store below): `i + 16 <= n`, the length of
        // each of these rows.
        unsafe {
            let mut dd = _mm512_loadu_ps(d.as_ptr().add(i));
            let mut a0 = _mm512_loadu_ps(n0.as_ptr().add(i));
            let mut a1 = _mm512_loadu_ps(n1.as_ptr().add(i));
            let mut a2 = _mm512_loadu_ps(n2.as_ptr().add(i));
            // A vector at the frame's side: its lanes' factors.
            let scaled = SCALED && !(scale.whole.0 <= c && c < scale.whole.1);
            for g in 0..G {
                let at = w[g].as_ptr().add(i);
                // An integer sum converts as `value` does (`f32(R)`, rounded to nearest).
                let mut wg =
                    if T::INT { _mm512_cvtepi32_ps(_mm512_loadu_si512(at.cast())) } else { _mm512_loadu_ps(at.cast()) };
                if scaled {
                    wg = _mm512_mul_ps(wg, _mm512_loadu_ps(fac[g].as_ptr().add(i)));
                }
                let o = off(g);
                dd = _mm512_add_ps(dd, wg);
                a0 = _mm512_fmadd_ps(wg, v[0][o], a0);
                a1 = _mm512_fmadd_ps(wg, v[1][o], a1);
                a2 = _mm512_fmadd_ps(wg, v[2][o], a2);
            }
            _mm512_storeu_ps(d.as_mut_ptr().add(i), dd);
            _mm512_storeu_ps(n0.as_mut_ptr().add(i), a0);
            _mm512_storeu_ps(n1.as_mut_ptr().add(i), a1);
            _mm512_storeu_ps(n2.as_mut_ptr().add(i), a2);
        }
    }
    for i in n / 16 * 16..n {
        let (mut dd, mut a0, mut a1, mut a2) = (d[i], n0[i], n1[i], n2[i]);
        for g in 0..G {
            let wg = if SCALED { w[g][i].value() * fac[g][i] } else { w[g][i].value() };
            let o = off(g);
            dd += wg;
            a0 = wg.mul_add(rows[0][i + o], a0);
            a1 = wg.mul_add(rows[1][i + o], a1);
            a2 = wg.mul_add(rows[2][i + o], a2);
        }
        (d[i], n0[i], n1[i], n2[i]) = (dd, a0, a1, a2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether the CPU has AVX-512F (the test says it skipped when not).
    #[cfg(target_arch = "x86_64")]
    fn avx512_or_skip() -> bool {
        let has = std::arch::is_x86_feature_detected!("avx512f");
        if !has {
            eprintln!("skipped: this CPU has no AVX-512F");
        }
        has
    }

    /// Pseudo-random values (xorshift from `seed`) in `[-shift, 1 - shift)`
    /// times a power of ten from `10^-(decades / 2)` on, `decades` of them:
    /// mixed signs and magnitudes, so that the order of operations shows.
    #[cfg(target_arch = "x86_64")]
    fn mixed_values(seed: u32, shift: f32, decades: u32) -> impl FnMut() -> f32 {
        let mut state = seed;
        move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state as f32 / u32::MAX as f32 - shift) * 10f32.powi((state % decades) as i32 - (decades / 2) as i32)
        }
    }

    /// The AVX2 and AVX-512 square sums of half-float rows (each where the
    /// CPU has it) give the bits of [`feature_square_sum`] on the same
    /// samples as `f32`, for rows shorter than, equal to and not a multiple
    /// of a chunk.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn half_square_sums_match_the_f32_kernel() {
        type Kernel = unsafe fn(&mut [f32], [&[half::f16]; 3], [&[half::f16]; 3]);
        let mut kernels: Vec<(&str, Kernel)> = Vec::new();
        if crate::filter::simd::Tier::Avx2.available() {
            kernels.push(("avx2", feature_square_sum_half_avx2::<3>));
        }
        if avx512_or_skip() {
            kernels.push(("avx512", feature_square_sum_half_avx512::<3>));
        }
        // Halves of mixed magnitude and sign.
        let mut values = mixed_values(0x9e37_79b9, 0.4, 5);
        let mut next = || half::f16::from_f32(values());
        for n in (1..40).chain([63, 64, 65, 100, 513]) {
            let rows: Vec<Vec<half::f16>> = (0..6).map(|_| (0..n).map(|_| next()).collect()).collect();
            let wide: Vec<Vec<f32>> = rows.iter().map(|r| r.iter().map(|h| h.to_f32()).collect()).collect();
            let mut want = vec![f32::NAN; n];
            feature_square_sum::<CHUNK, 3>(&mut want, [&wide[0], &wide[1], &wide[2]], [&wide[3], &wide[4], &wide[5]]);
            // The AVX-512 tier's chunk width gives the same bits.
            let mut wide_chunks = vec![f32::NAN; n];
            let (p, q) = ([&wide[0][..], &wide[1], &wide[2]], [&wide[3][..], &wide[4], &wide[5]]);
            feature_square_sum::<CHUNK_AVX512, 3>(&mut wide_chunks, p, q);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&wide_chunks), bits(&want), "n = {n}");
            for (name, kernel) in &kernels {
                let mut got = vec![f32::NAN; n];
                // SAFETY: the CPU features of each kernel were detected above.
                unsafe { kernel(&mut got, [&rows[0], &rows[1], &rows[2]], [&rows[3], &rows[4], &rows[5]]) };
                let (g, w): (Vec<u32>, Vec<u32>) =
                    (got.iter().map(|v| v.to_bits()).collect(), want.iter().map(|v| v.to_bits()).collect());
                assert_eq!(g, w, "{name}, n = {n}");
            }
        }
    }

    /// The one-pass guide products give both lanes the bits of the stored
    /// path (each guide's [`feature_square_sum`], then
    /// [`fold_feature_products`] from 0): guides of 1 to 4 channels, `f32`
    /// and half-float rows, lanes covering a row in full or in part (chunk
    /// edges inside them), the factors negative as the weight's are, and
    /// samples that give infinite or NaN terms and zeros of either sign,
    /// where the minimum's operand order shows.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn guide_pair_products_match_the_stored_path() {
        if !avx512_or_skip() {
            return;
        }
        let mut next = mixed_values(0x1234_5677, 0.5, 5);
        let mut special = 0u32;
        let mut value = move || {
            special = special.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            match (special >> 16) % 41 {
                0 => f32::INFINITY,
                1 => 0.0,
                2 => -0.0,
                _ => half::f16::from_f32(next()).to_f32(),
            }
        };
        let layouts: [&[usize]; 5] = [&[3, 3, 1], &[1], &[2, 4], &[1, 1, 1, 1], &[4, 3, 2, 1]];
        for (t, layout) in layouts.iter().enumerate() {
            for n in [64, 65, 100, 128, 129, 203] {
                let channels: usize = layout.iter().sum();
                let mut rows: Vec<Vec<f32>> = (0..2 * channels).map(|_| (0..n).map(|_| value()).collect()).collect();
                // `inf - inf` in the first guide at a sample of every lane.
                (rows[0][n - 7], rows[channels][n - 7]) = (f32::INFINITY, f32::INFINITY);
                let halves: Vec<Vec<half::f16>> =
                    rows.iter().map(|r| r.iter().map(|v| half::f16::from_f32(*v)).collect()).collect();
                // Lanes: the whole row, and parts starting or ending inside a chunk.
                let spans = [(0, n), (3, n - 5), (17, n), (0, n - 1), (n - 20, n)];
                let (a, b) = (spans[t % spans.len()], spans[(t + 2) % spans.len()]);
                let invs: Vec<Vec<f32>> = (0..2 * layout.len())
                    .map(|j| (0..n).map(|i| if (i + j) % 13 == 0 { -0.0 } else { -(value().abs() + 0.5) }).collect())
                    .collect();
                // The stored path.
                let mut sums = vec![vec![0.0f32; n]; layout.len()];
                let mut c = 0;
                for (g, &k) in layout.iter().enumerate() {
                    let p: Vec<&[f32]> = (c..c + k).map(|i| &rows[i][..]).collect();
                    let q: Vec<&[f32]> = (c..c + k).map(|i| &rows[channels + i][..]).collect();
                    feature_square_sum_any(&mut sums[g], &p, &q);
                    c += k;
                }
                // Infinite samples give infinite and NaN terms (`inf - inf`, `inf * 0`).
                assert!(sums.iter().flatten().any(|v| v.is_nan()), "{layout:?}, n = {n}: no NaN square sum");
                let want = |lane: usize, (x0, x1): (usize, usize)| {
                    let mut out = vec![f32::NAN; x1 - x0];
                    let s: Vec<&[f32]> = sums.iter().map(|r| &r[x0..x1]).collect();
                    let inv: Vec<&[f32]> = (0..layout.len()).map(|g| &invs[lane * layout.len() + g][x0..x1]).collect();
                    fold_feature_products::<CHUNK_AVX512>(&mut out, &s, &inv, true);
                    out
                };
                let mut ends = vec![];
                for k in layout.iter() {
                    ends.push(ends.last().copied().unwrap_or(0) + k);
                }
                for half_rows in [false, true] {
                    let row = |i: usize| if half_rows { GuideRow::Half(&halves[i]) } else { GuideRow::Full(&rows[i]) };
                    let fp: Vec<GuideRow> = (0..channels).map(row).collect();
                    let fq: Vec<GuideRow> = (channels..2 * channels).map(row).collect();
                    let mut outs = [vec![f32::NAN; a.1 - a.0], vec![f32::NAN; b.1 - b.0]];
                    let [oa, ob] = &mut outs;
                    let lane = |l: usize, (x0, x1): (usize, usize), out| {
                        let mut inv: [&[f32]; PRODUCTS_MAX] = [&[]; PRODUCTS_MAX];
                        for (g, r) in inv.iter_mut().take(layout.len()).enumerate() {
                            *r = &invs[l * layout.len() + g][x0..x1];
                        }
                        Some(ProductLane { from: x0, out, inv })
                    };
                    // SAFETY: AVX-512F was detected above.
                    unsafe { guide_pair_products_avx512(n, (&fp, &fq), &ends, [lane(0, a, oa), lane(1, b, ob)]) };
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    let at = format!("layout {layout:?}, n = {n}, halves {half_rows}");
                    assert_eq!(bits(&outs[0]), bits(&want(0, a)), "forward lane, {at}");
                    assert_eq!(bits(&outs[1]), bits(&want(1, b)), "mirror lane, {at}");
                    assert!(outs.iter().flatten().any(|v| *v < 0.0), "{at}: the terms are not all zero");
                }
            }
        }
    }

    /// The paired kernel of guides with variance gives each lane the bits
    /// of the per-lane pass ([`fold_feature_term`] with the lane's own
    /// pixels as `p`), folded from 0 or into earlier terms: rows shorter
    /// than, equal to and not a multiple of a chunk, lanes starting and
    /// ending inside chunks, ties between the variances (zeros of either
    /// sign among them), NaN variances (where the minimum's operand order
    /// shows), infinite samples and negative factors as the weight's are.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn guide_variance_pair_matches_the_per_lane_pass() {
        if !avx512_or_skip() {
            return;
        }
        fn check<const C: usize>(seed: u32) {
            let mut next = mixed_values(seed, 0.5, 5);
            let mut special = seed;
            let mut pick = move || {
                special = special.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                (special >> 16) % 29
            };
            for n in [16, 17, 53, 64, 100] {
                let mut value = |variance: bool| match pick() {
                    0 if !variance => f32::INFINITY,
                    0 => f32::NAN,
                    1 => 0.0,
                    2 => -0.0,
                    _ if variance => next().abs(),
                    _ => next(),
                };
                let rows = |value: &mut dyn FnMut(bool) -> f32, variance: bool| -> Vec<Vec<f32>> {
                    (0..C).map(|_| (0..n).map(|_| value(variance)).collect()).collect()
                };
                let (mut fp, fq) = (rows(&mut value, false), rows(&mut value, false));
                let (mut vp, mut vq) = (rows(&mut value, true), rows(&mut value, true));
                // An infinite sample inside every lane; ties: equal
                // variances, and `+0` against `-0` both ways.
                fp[0][n - 7] = f32::INFINITY;
                for c in 0..C {
                    for i in (c..n).step_by(5) {
                        vq[c][i] = vp[c][i];
                    }
                    for i in (c + 2..n).step_by(11) {
                        (vp[c][i], vq[c][i]) = if i % 2 == 0 { (0.0, -0.0) } else { (-0.0, 0.0) };
                    }
                }
                let inv: Vec<Vec<f32>> = (0..2 * C)
                    .map(|j| (0..n).map(|i| if (i + j) % 13 == 0 { -0.0 } else { -(next().abs() + 0.5) }).collect())
                    .collect();
                let earlier: Vec<f32> = (0..n).map(|i| if i % 7 == 0 { 0.0 } else { -next().abs() }).collect();
                fn arr<const C: usize>(v: &[Vec<f32>], (x0, x1): (usize, usize)) -> [&[f32]; C] {
                    let mut a: [&[f32]; C] = [&[]; C];
                    for (c, r) in a.iter_mut().enumerate() {
                        *r = &v[c][x0..x1];
                    }
                    a
                }
                let spans = [(0, n), (3, n - 5), (1, n), (0, n - 1), (n - 16, n)];
                for (t, first) in [(0, true), (1, false), (2, true), (3, false)] {
                    let (a, b) = (spans[t % spans.len()], spans[(t + 2) % spans.len()]);
                    // The per-lane pass: the forward lane's pixels are `p`, the mirror's `q`.
                    let want = |(x0, x1): (usize, usize), mirror: bool| {
                        let mut out = earlier[x0..x1].to_vec();
                        let (p, q, v, w) = if mirror { (&fq, &fp, &vq, &vp) } else { (&fp, &fq, &vp, &vq) };
                        let inv = arr(&inv[if mirror { C } else { 0 }..], (x0, x1));
                        let rows = FeatureRows::<C> {
                            fp: arr(p, (x0, x1)),
                            fq: arr(q, (x0, x1)),
                            var: Some((arr(v, (x0, x1)), arr(w, (x0, x1)))),
                            inv_den: inv,
                        };
                        if first {
                            fold_feature_term::<16, C, true>(&mut out, &rows);
                        } else {
                            fold_feature_term::<16, C, false>(&mut out, &rows);
                        }
                        out
                    };
                    let mut oa = earlier[a.0..a.1].to_vec();
                    let mut ob = earlier[b.0..b.1].to_vec();
                    let lanes =
                        [Some((a.0, &mut oa[..], arr(&inv[..C], a))), Some((b.0, &mut ob[..], arr(&inv[C..], b)))];
                    let all = (0, n);
                    // SAFETY: AVX-512F was detected above.
                    unsafe {
                        guide_variance_pair_avx512::<C>(
                            n,
                            (&arr(&fp, all), &arr(&fq, all)),
                            (&arr(&vp, all), &arr(&vq, all)),
                            first,
                            lanes,
                        )
                    };
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    let at = format!("C = {C}, n = {n}, lanes {a:?} and {b:?}, first {first}");
                    assert_eq!(bits(&oa), bits(&want(a, false)), "forward lane, {at}");
                    assert_eq!(bits(&ob), bits(&want(b, true)), "mirror lane, {at}");
                    assert!(oa.iter().chain(&ob).any(|v| *v < 0.0), "{at}: the terms are not all zero");
                }
            }
        }
        check::<1>(0x2468_ace1);
        check::<2>(0x1357_9bdf);
        check::<3>(0x0f0f_1e1e);
        check::<4>(0x7777_1234);
    }

    /// The AVX-512 window sums give the bits of the expression every other
    /// tier computes, for windows of 3 to 9 taps and rows shorter than,
    /// equal to and not a multiple of a chunk.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn taps_sum_avx512_matches_the_pair_sum_expression() {
        if !avx512_or_skip() {
            return;
        }
        fn check<const F: usize>(seed: u32) {
            // Values of mixed magnitude and sign, so that the order of the adds shows.
            let mut next = mixed_values(seed, 0.3, 7);
            for n in (1..50).chain([63, 64, 65, 100, 513]) {
                let src: Vec<f32> = (0..n + 2 * F).map(|_| next()).collect();
                let mut out = vec![f32::NAN; n];
                // SAFETY: AVX-512F was detected by the caller.
                unsafe { taps_sum_avx512::<F>(&src, &mut out) };
                // The portable tiers' pair sums: `rows_sum` of the pair rows and `src` shifted.
                let pairs: Vec<f32> = (0..n + 2 * F - 1).map(|j| src[j] + src[j + 1]).collect();
                for (i, o) in out.iter().enumerate() {
                    let mut want = pairs[i];
                    for k in 1..F {
                        want += pairs[i + 2 * k];
                    }
                    want += src[i + 2 * F];
                    assert_eq!(o.to_bits(), want.to_bits(), "F = {F}, n = {n}, i = {i}");
                }
            }
        }
        check::<1>(0x2545_f491);
        check::<2>(0x1234_5679);
        check::<3>(0x0bad_cafe);
        check::<4>(0x7f4a_7c15);
    }

    #[test]
    fn exp2_weight_matches_f64_within_bound() {
        let mut worst = 0.0f64;
        let mut t = -126.0f32;
        while t <= 0.0 {
            let got = exp2_weight(t) as f64;
            let want = (t as f64).exp2();
            worst = worst.max(((got - want) / want).abs());
            t += 0.000_93;
        }
        // Every float of one unit interval near zero (the polynomial's range).
        for bits in ((-1.0f32).to_bits()..=(-0.5f32).to_bits()).step_by(3) {
            let t = f32::from_bits(bits);
            worst = worst.max(((exp2_weight(t) as f64) / (t as f64).exp2() - 1.0).abs());
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
        assert_eq!(exp2_weight(0.0), 1.0);
        assert_eq!(exp2_weight(5.0), 1.0);
        assert_eq!(exp2_weight(-1.0), 0.5);
        let floor = exp2_weight(-126.0);
        assert!(floor.is_normal() && floor < 1.2e-38);
        assert_eq!(exp2_weight(f32::NAN), floor);
        assert_eq!(exp2_weight(f32::NEG_INFINITY), floor);
        assert_eq!(exp2_weight(-1e30), floor);
    }

    /// The lockstep form over a chunk gives the bits of [`exp2_weight`]
    /// (the same form over one sample) for every sample:
    /// every float of `[-2, 0]` with a stride, the clamps' edges, positive
    /// values, infinities and NaN, in chunks of both widths the tiers use.
    #[test]
    fn exp2_weight_lanes_matches_exp2_weight() {
        let mut ts: Vec<f32> = ((-0.0f32).to_bits()..=(-2.0f32).to_bits()).step_by(101).map(f32::from_bits).collect();
        ts.extend((0..4000).map(|i| -130.0 + i as f32 * 0.0331));
        ts.extend([0.0, -0.0, 1e-40, -1e-40, 5.0, -126.0, -125.999_99, -126.000_01, f32::NAN, f32::INFINITY]);
        ts.extend([f32::NEG_INFINITY, f32::MAX, f32::MIN, -1e30]);
        assert!(ts.len() > 10_000_000, "the sweep of [-2, 0] is not empty");
        fn check<const W: usize>(ts: &[f32]) -> usize {
            let mut checked = 0;
            for c in ts.chunks(W) {
                let mut t = [0.0f32; W];
                t[..c.len()].copy_from_slice(c);
                let got = exp2_weight_lanes(t);
                for k in 0..W {
                    assert_eq!(got[k].to_bits(), exp2_weight(t[k]).to_bits(), "t = {:e}", t[k]);
                }
                checked += W;
            }
            checked
        }
        assert!(check::<CHUNK>(&ts) >= ts.len());
        assert!(check::<CHUNK_AVX512>(&ts) >= ts.len());
        // Scaled by `2^e`: exactly the weight times `2^e`.
        for e in [0, 1, 13, 25, 127] {
            for t in ts.iter().step_by(97) {
                let want = exp2_weight(*t) * 2f32.powi(e);
                assert_eq!(exp2_weight_scaled_lanes([*t], e)[0].to_bits(), want.to_bits(), "t = {t:e}, e = {e}");
            }
        }
    }

    /// The AVX-512 weights kernel gives, sample by sample, the bits of the
    /// lanes form that the other tiers run (`nlmeans::weight_row`), with and
    /// without guides, for every scale `2^e` the boxes use, rows of any
    /// length (masked ends), arguments over the clamps' range and beyond on
    /// both sides, and guide arguments at `+0`, `-0`, `-inf` and in between;
    /// and `weights_factors_avx512` with a factor per sample.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn weights_avx512_match_the_lanes_form() {
        if !avx512_or_skip() {
            return;
        }
        let mut next = mixed_values(0x0bad_cafe, 0.7, 2);
        // Window sums from 0 to about +-1e8, and the arguments' scale as the
        // filter's (`-log2(e) / channels / 2^s` over the patch's count).
        let sums: Vec<i32> = (0..4096)
            .map(|i| match i % 53 {
                0 => 0,
                1 => i32::MAX / 64,
                _ => (next() * 1.5e8 / (1 + i % 7 * 1000) as f32) as i32,
            })
            .collect();
        let guides: Vec<f32> = (0..4096)
            .map(|i| match i % 29 {
                0 => 0.0,
                1 => -0.0,
                2 => f32::NEG_INFINITY,
                _ => -(next().abs() * 10f32.powi(i % 4)),
            })
            .collect();
        // Each weight against the lanes form of its argument; the samples
        // past the row untouched. Returns the samples checked.
        let check = |got: &[f32], n: usize, s: &[i32], factor: &dyn Fn(usize) -> f32, g: &[f32], guided: bool, e| {
            for i in 0..n {
                let t = s[i] as f32 * factor(i);
                let t = if guided && g[i] < t { g[i] } else { t };
                let want = exp2_weight_scaled_lanes([t], e)[0];
                assert_eq!(got[i].to_bits(), want.to_bits(), "t = {t:e}, e = {e}, guided {guided}, n = {n}");
            }
            assert!(got[n..].iter().all(|v| v.is_nan()), "a weight written past the row");
            n
        };
        let mut checked = [0usize; 2];
        for inner in [-1.443e-5f32, -3.1e-6, -0.47, 2.0e-6] {
            for e in [0, 1, 13, 40, 127] {
                for n in [1, 15, 16, 17, 63, 64, 65, 100, 203, 4000] {
                    for guided in [false, true] {
                        let (s, g) = (&sums[..n], &guides[96..96 + n]);
                        let mut got = vec![f32::NAN; n + 3];
                        // SAFETY: avx512f was detected above.
                        unsafe {
                            if guided {
                                weights_avx512::<true>(s, g, &mut got[..n], inner, e);
                            } else {
                                weights_avx512::<false>(s, &[], &mut got[..n], inner, e);
                            }
                        }
                        checked[guided as usize] += check(&got, n, s, &|_| inner, g, guided, e);
                    }
                }
            }
        }
        // Up to 16 samples with a factor each (the clipped columns' counts).
        for n in 1..=16 {
            for e in [0, 13, 127] {
                let (s, g) = (&sums[n * 7..n * 8], &guides[n..2 * n]);
                let factors: Vec<f32> = (0..n).map(|i| -1.443e-5 * 49.0 / ((4 + i % 4) * (4 + i % 3)) as f32).collect();
                for guided in [false, true] {
                    let mut got = [f32::NAN; 17];
                    // SAFETY: avx512f was detected above.
                    unsafe {
                        if guided {
                            weights_factors_avx512::<true>(s, g, &mut got[..n], &factors, e);
                        } else {
                            weights_factors_avx512::<false>(s, &[], &mut got[..n], &factors, e);
                        }
                    }
                    check(&got, n, s, &|i| factors[i], g, guided, e);
                }
            }
        }
        // Both sides of the clamps were reached.
        let ts = sums.iter().map(|s| *s as f32 * -3.1e-6);
        assert!(ts.clone().any(|t| t > 0.5) && ts.clone().any(|t| t < -130.0), "arguments beyond both clamps");
        assert!(checked.iter().all(|c| *c > 90_000), "{checked:?}");
    }

    /// The array kernel (channel counts 1 to 4, with and without variance,
    /// first feature or not) and the any-count kernel give the same bits, and
    /// both match the formula in f64 (no variance: `inv * sum d^2`).
    #[test]
    fn feature_term_kernels_agree() {
        fn check<const C: usize>(n: usize) {
            let rows_of = |seed: usize| -> Vec<Vec<f32>> {
                (0..C)
                    .map(|c| (0..n).map(|i| (((i + 3 * c + seed) * 7919) % 211) as f32 * 0.013 - 1.1).collect())
                    .collect()
            };
            let (fp, fq, vp, vq) = (rows_of(1), rows_of(5), rows_of(9), rows_of(13));
            let (vp, vq): (Vec<Vec<f32>>, Vec<Vec<f32>>) = (
                vp.iter().map(|r| r.iter().map(|v| v.abs() * 0.01).collect()).collect(),
                vq.iter().map(|r| r.iter().map(|v| v.abs() * 0.01).collect()).collect(),
            );
            let inv: Vec<Vec<f32>> = rows_of(17).iter().map(|r| r.iter().map(|v| -(v.abs() + 0.5)).collect()).collect();
            fn arr<const C: usize>(rows: &[Vec<f32>]) -> [&[f32]; C] {
                std::array::from_fn(|c| &rows[c][..])
            }
            fn sl(rows: &[Vec<f32>]) -> Vec<&[f32]> {
                rows.iter().map(|r| &r[..]).collect()
            }
            let prior: Vec<f32> = (0..n).map(|i| -((i % 5) as f32) * 0.3).collect();
            for with_var in [false, true] {
                let rows = FeatureRows::<C> {
                    fp: arr(&fp),
                    fq: arr(&fq),
                    var: with_var.then(|| (arr(&vp), arr(&vq))),
                    inv_den: arr(&inv),
                };
                let (svp, svq) = (sl(&vp), sl(&vq));
                let var = with_var.then_some((&svp[..], &svq[..]));
                for first in [true, false] {
                    let (mut a, mut b, mut c) = (prior.clone(), prior.clone(), prior.clone());
                    if first {
                        fold_feature_term::<CHUNK, C, true>(&mut a, &rows);
                        fold_feature_term::<CHUNK_AVX512, C, true>(&mut c, &rows);
                    } else {
                        fold_feature_term::<CHUNK, C, false>(&mut a, &rows);
                        fold_feature_term::<CHUNK_AVX512, C, false>(&mut c, &rows);
                    }
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&c), bits(&a), "chunk widths, C={C} var={with_var} first={first}");
                    fold_feature_term_any(&mut b, &sl(&fp), &sl(&fq), var, &sl(&inv), first);
                    for i in 0..n {
                        assert_eq!(a[i].to_bits(), b[i].to_bits(), "C={C} var={with_var} first={first} i={i}");
                        let t: f64 = if with_var {
                            (0..C)
                                .map(|c| {
                                    let d = fp[c][i] as f64 - fq[c][i] as f64;
                                    let m = vp[c][i].min(vq[c][i]) as f64;
                                    (d * d - (vp[c][i] as f64 + m)) * inv[c][i] as f64
                                })
                                .sum()
                        } else {
                            inv[0][i] as f64 * (0..C).map(|c| (fp[c][i] as f64 - fq[c][i] as f64).powi(2)).sum::<f64>()
                        };
                        let want = t.min(if first { 0.0 } else { prior[i] as f64 });
                        assert!((a[i] as f64 - want).abs() <= 1e-5 * (1.0 + want.abs()), "C={C}: {} vs {want}", a[i]);
                    }
                }
            }
        }
        // Shorter than a chunk of either width, between them, and longer.
        for n in [5, 37, 150] {
            check::<1>(n);
            check::<2>(n);
            check::<3>(n);
            check::<4>(n);
        }
    }

    /// One pass over 1 to 4 guides' products gives the bits of one
    /// [`fold_feature_term`] per guide in turn (no variance, square sums
    /// from [`feature_square_sum`]), on rows shorter and longer than a chunk.
    #[test]
    fn one_pass_products_match_a_fold_per_guide() {
        for n in [5, 37, 150] {
            let row = |seed: usize| -> Vec<f32> {
                (0..n).map(|i| (((i + seed) * 7919) % 211) as f32 * 0.013 - 1.1).collect()
            };
            let guides: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = (0..4)
                .map(|g| (row(3 * g), row(3 * g + 1), row(3 * g + 2).iter().map(|v| -v.abs()).collect()))
                .collect();
            let prior: Vec<f32> = (0..n).map(|i| -((i % 5) as f32) * 0.3).collect();
            for k in 1..=PRODUCTS_MAX {
                for first in [true, false] {
                    let mut want = prior.clone();
                    let mut sums = Vec::new();
                    for (g, (p, q, inv)) in guides[..k].iter().enumerate() {
                        let mut s = vec![0.0; n];
                        feature_square_sum::<CHUNK, 1>(&mut s, [p], [q]);
                        let rows = FeatureRows::<1> { fp: [p], fq: [q], var: None, inv_den: [inv] };
                        if first && g == 0 {
                            fold_feature_term::<CHUNK, 1, true>(&mut want, &rows);
                        } else {
                            fold_feature_term::<CHUNK, 1, false>(&mut want, &rows);
                        }
                        sums.push(s);
                    }
                    let mut got = prior.clone();
                    let s: Vec<&[f32]> = sums.iter().map(|s| &s[..]).collect();
                    let inv: Vec<&[f32]> = guides[..k].iter().map(|g| &g.2[..]).collect();
                    fold_feature_products::<CHUNK>(&mut got, &s, &inv, first);
                    let mut wide = prior.clone();
                    fold_feature_products::<CHUNK_AVX512>(&mut wide, &s, &inv, first);
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&got), bits(&want), "n={n} k={k} first={first}");
                    assert_eq!(bits(&wide), bits(&want), "chunk width, n={n} k={k} first={first}");
                }
            }
        }
    }

    /// With `alpha == 1`, the subtraction of [`variance_term`] gives the
    /// fused multiply-add's bits, on special values (signed zeros,
    /// infinities, NaN, subnormals) and on a sweep of mixed magnitudes; and
    /// so does the whole three-channel distance kernel. Fails if the
    /// subtraction's operands are swapped or the term is computed otherwise.
    #[test]
    fn alpha_one_subtraction_matches_the_fused_multiply_add() {
        let special = [0.0f32, -0.0, 1.0, -1.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1e-40, -1e-40, 3.4e38];
        let mut sweep = Vec::new();
        let mut x = 1e-30f32;
        while x < 1e30 {
            sweep.extend([x, -x, x * 1.37, -x * 0.71]);
            x *= 1.7;
        }
        let values: Vec<f32> = special.iter().chain(&sweep).copied().collect();
        for &s in &values {
            for &d2 in &values {
                let (sub, fma) = (variance_term::<true>(1.0, s, d2), variance_term::<false>(1.0, s, d2));
                assert!(sub.to_bits() == fma.to_bits() || (sub.is_nan() && fma.is_nan()), "s {s:e} d2 {d2:e}");
            }
        }
        // The kernel: 150 samples (for either chunk width, whole chunks and
        // an overlapping last one), variances non-negative as in the filter.
        let n = 150;
        let row = |k: usize, scale: f32| -> Vec<f32> {
            (0..n).map(|i| values[(i * 7 + k * 13) % values.len()].abs().min(1e6) * scale).collect()
        };
        let (u, v): (Vec<Vec<f32>>, Vec<Vec<f32>>) =
            ((0..6).map(|k| row(k, 1.0)).collect(), (0..6).map(|k| row(k + 6, 0.5)).collect());
        fn refs(r: &[Vec<f32>], a: usize) -> [&[f32]; 3] {
            [&r[a], &r[a + 1], &r[a + 2]]
        }
        let run = |one: bool, wide: bool| {
            let (mut f, mut m) = (vec![0.0f32; n], vec![0.0f32; n]);
            let (up, uq, vp, vq) = (refs(&u, 0), refs(&u, 3), refs(&v, 0), refs(&v, 3));
            let c = (1.0, 1e-10, 0.2025);
            match (one, wide) {
                (true, false) => colour_distance_pair_rgb::<CHUNK, true>(&mut f, &mut m, up, uq, vp, vq, c),
                (false, false) => colour_distance_pair_rgb::<CHUNK, false>(&mut f, &mut m, up, uq, vp, vq, c),
                (true, true) => colour_distance_pair_rgb::<CHUNK_AVX512, true>(&mut f, &mut m, up, uq, vp, vq, c),
                (false, true) => colour_distance_pair_rgb::<CHUNK_AVX512, false>(&mut f, &mut m, up, uq, vp, vq, c),
            }
            f.iter().chain(&m).map(|x| x.to_bits()).collect::<Vec<_>>()
        };
        assert_eq!(run(true, false), run(false, false));
        // The AVX-512 tier's chunk width gives the same bits.
        assert_eq!(run(true, true), run(false, false));
        assert_eq!(run(false, true), run(false, false));
    }

    #[test]
    fn the_distance_pair_divides_and_scales_exactly_by_powers_of_two() {
        // The reciprocal is a correctly rounded division, the same on every
        // path, and the kernel relies on it scaling exactly: it passes
        // `eps 2^-s` and `k^2 2^-s` to get the distances times `2^s`
        // (`nlmeans::distance_rows`). Checked on the pair kernel itself, so
        // an approximate reciprocal put back in would fail here.
        let n = 37;
        let up: Vec<f32> = (0..n).map(|i| 0.3 + (i * 7919 % 101) as f32 * 0.013).collect();
        let uq: Vec<f32> = (0..n).map(|i| 0.2 + (i * 104_729 % 97) as f32 * 0.017).collect();
        let vp: Vec<f32> = (0..n).map(|i| 1e-4 + (i * 31 % 89) as f32 * 3.1e-4).collect();
        let vq: Vec<f32> = (0..n).map(|i| 2e-4 + (i * 17 % 83) as f32 * 2.9e-4).collect();
        let (alpha, eps, k2) = (1.0f32, 1e-10f32, 0.45f32 * 0.45);
        let run = |scale: f32| {
            let (mut fwd, mut mir) = (vec![0.0f32; n], vec![0.0f32; n]);
            accumulate_colour_distance_pair(&mut fwd, &mut mir, &up, &uq, &vp, &vq, alpha, eps * scale, k2 * scale);
            (fwd, mir)
        };
        let (fwd, mir) = run(1.0);
        for i in 0..n {
            // The division itself: the reciprocal of the rounded denominator.
            let r = 1.0 / k2.mul_add(vp[i] + vq[i], eps);
            let m = vp[i].min(vq[i]);
            let e = (-alpha).mul_add(m, (up[i] - uq[i]) * (up[i] - uq[i]));
            assert_eq!(fwd[i].to_bits(), ((-alpha).mul_add(vp[i], e) * r).to_bits(), "fwd {i}");
            assert_eq!(mir[i].to_bits(), ((-alpha).mul_add(vq[i], e) * r).to_bits(), "mir {i}");
        }
        for k in [-40, -13, -1, 1, 13, 40] {
            let (f2, m2) = run(2f32.powi(-k));
            for i in 0..n {
                assert_eq!(f2[i].to_bits(), (fwd[i] * 2f32.powi(k)).to_bits(), "fwd {i}, k = {k}");
                assert_eq!(m2[i].to_bits(), (mir[i] * 2f32.powi(k)).to_bits(), "mir {i}, k = {k}");
            }
        }
    }

    #[test]
    fn box_mean_matches_direct_sum_and_is_region_invariant() {
        let src_rect = Rect::from_origin_size(-2, 3, 17, 11);
        let src: Vec<f32> = (0..src_rect.area()).map(|i| ((i * 7919) % 101) as f32 * 0.37).collect();
        let clip = Rect { x0: -1, y0: 3, x1: 14, y1: 13 };
        let full = clip;
        let mut whole = vec![0.0; full.area()];
        let mut scratch = Vec::new();
        box_mean(&src, src_rect, clip, 2, full, &mut whole, &mut scratch);
        for sub in [Rect { x0: 3, y0: 5, x1: 9, y1: 8 }, Rect { x0: -1, y0: 3, x1: 0, y1: 13 }] {
            let mut part = vec![0.0; sub.area()];
            box_mean(&src, src_rect, clip, 2, sub, &mut part, &mut scratch);
            for y in sub.y0..sub.y1 {
                for x in sub.x0..sub.x1 {
                    let a = part[((y - sub.y0) * sub.width() as i64 + x - sub.x0) as usize];
                    let b = whole[((y - full.y0) * full.width() as i64 + x - full.x0) as usize];
                    assert_eq!(a.to_bits(), b.to_bits());
                    let mut sum = 0.0f64;
                    let mut n = 0.0;
                    for yy in (y - 2).max(clip.y0)..=(y + 2).min(clip.y1 - 1) {
                        for xx in (x - 2).max(clip.x0)..=(x + 2).min(clip.x1 - 1) {
                            sum += src[((yy - src_rect.y0) * 17 + xx - src_rect.x0) as usize] as f64;
                            n += 1.0;
                        }
                    }
                    assert!(((sum / n) - a as f64).abs() < 1e-4, "{x},{y}");
                }
            }
        }
    }
}
