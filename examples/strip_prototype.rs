//! A measurement, not part of the filter: the colour-only NL-means of the
//! block kernel (SPEC §4, r = 10, f = 3) in another loop order, to test
//! whether keeping every intermediate in registers and on the stack pays
//! on this machine (docs/performance.md, session 18).
//!
//! The prototype takes one offset at a time over strips of `16 S` output
//! columns and walks each strip down the block's rows. Its rows of
//! distances, patch distances and weights are vectors in registers. Its
//! two boxes' last seven rows are small stack rings, read back from L1.
//!
//! It leaves out what the kernel has and this test does not need. There
//! are no frame borders (interior pixels only), no pairing of `n` with
//! `-n` (each distance is computed directly), and no frame-anchored
//! vertical sums: its column sums add the window's seven rows in order,
//! so it is not tile-invariant, and its bits differ slightly from the
//! kernel's. It runs on AVX-512 machines only.
//!
//!   cargo run --release --example strip_prototype [S] [WIDTH] [HEIGHT] [RUNS]
//!
//! S (output vectors per strip) is 1, 2, 4 (the default) or 7; the frame
//! is 960x540 by default, at least 480 wide.
//!
//! It prints the best of RUNS times for the prototype and for the library's
//! kernel (`filter::nlmeans::nlmeans`, one thread) on the same interior
//! region of a random frame, in ns per pixel-offset, and the largest
//! relative difference between their outputs; it fails (exit status 1)
//! when that exceeds 1e-4, a sign that the prototype computes something
//! else.

#[cfg(target_arch = "x86_64")]
mod strip {
    use std::arch::x86_64::*;

    pub const F: usize = 3;

    /// The kernel's reciprocal of session 18, when this prototype was written
    /// (a Newton form, `kernels::recip` until session 31), 16 lanes.
    #[target_feature(enable = "avx512f,fma")]
    #[inline]
    fn recip(x: __m512) -> __m512 {
        let one = _mm512_set1_ps(1.0);
        let mut y = _mm512_castsi512_ps(_mm512_sub_epi32(_mm512_set1_epi32(0x7EF3_11C3), _mm512_castps_si512(x)));
        for _ in 0..3 {
            y = _mm512_fmadd_ps(y, _mm512_fnmadd_ps(x, y, one), y);
        }
        y
    }

    /// The kernel's `exp2_weight`, 16 lanes.
    #[target_feature(enable = "avx512f,fma")]
    #[inline]
    // The kernel's fitted coefficients; its `0.693_147` is not ln 2.
    #[allow(clippy::approx_constant)]
    fn exp2_weight(t: __m512) -> __m512 {
        const ROUND: f32 = 12_582_912.0;
        let t = _mm512_min_ps(_mm512_max_ps(t, _mm512_set1_ps(-126.0)), _mm512_setzero_ps());
        let tr = _mm512_add_ps(t, _mm512_set1_ps(ROUND));
        let f = _mm512_sub_ps(t, _mm512_sub_ps(tr, _mm512_set1_ps(ROUND)));
        let ni = _mm512_sub_epi32(_mm512_castps_si512(tr), _mm512_set1_epi32(ROUND.to_bits() as i32));
        let mut p = _mm512_set1_ps(1.326_470_2e-3);
        for c in [9.671_505e-3, 5.550_733_6e-2, 2.402_224_2e-1, 0.693_147, 1.0] {
            p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(c));
        }
        let scale = _mm512_slli_epi32::<23>(_mm512_add_epi32(ni, _mm512_set1_epi32(127)));
        _mm512_mul_ps(p, _mm512_castsi512_ps(scale))
    }

    /// `(a:b)` shifted down by `K` lanes.
    macro_rules! sh {
        ($k:literal, $a:expr, $b:expr) => {
            _mm512_castsi512_ps(_mm512_alignr_epi32::<$k>(_mm512_castps_si512($b), _mm512_castps_si512($a)))
        };
    }

    /// The 7-tap window sums of the samples in `v` (`N + 1` vectors, the
    /// last one only read): `((p0 + p2) + p4) + x6` with `pk` the pair sum
    /// of samples `k, k + 1`, the kernel's expression.
    #[target_feature(enable = "avx512f,fma")]
    #[inline]
    fn taps7<const N: usize, const M: usize>(v: &[__m512; M]) -> [__m512; N] {
        const { assert!(M == N + 1) };
        let mut out = [_mm512_setzero_ps(); N];
        for j in 0..N {
            let (a, b) = (v[j], v[j + 1]);
            let p0 = _mm512_add_ps(a, sh!(1, a, b));
            // Only the first 4 lanes of `p1` are used: `b`'s last lane
            // pairs with anything.
            let p1 = _mm512_add_ps(b, sh!(1, b, b));
            let acc = _mm512_add_ps(_mm512_add_ps(p0, sh!(2, p0, p1)), sh!(4, p0, p1));
            out[j] = _mm512_add_ps(acc, sh!(6, a, b));
        }
        out
    }

    /// A frame's three channels and their variances, `w` samples a row.
    pub struct Frame {
        pub w: usize,
        pub u: [Vec<f32>; 3],
        pub v: [Vec<f32>; 3],
    }

    /// The block's rows `by0..by0 + bh`, columns `bx0..bx0 + bw` (a multiple
    /// of `16 S`, every read inside the frame): numerators and denominator
    /// (`bw` samples a row), accumulated over every offset of radius `r`.
    /// `S` output vectors a strip, `D = S + 1` vectors of weights.
    ///
    /// # Safety
    /// The CPU must support AVX-512F and FMA, and the block with its
    /// border of `r + 2f` must lie inside the frame.
    #[target_feature(enable = "avx512f,fma")]
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    pub unsafe fn filter<const S: usize, const D: usize, const DD: usize>(
        img: &Frame,
        r: i64,
        k2: f32,
        (bx0, by0, bw, bh): (usize, usize, usize, usize),
        num: &mut [Vec<f32>; 3],
        den: &mut [f32],
    ) {
        const { assert!(D == S + 1 && DD == D + 1) };
        let w = img.w as i64;
        let (k2, eps) = (_mm512_set1_ps(k2), _mm512_set1_ps(1e-10));
        let kd = _mm512_set1_ps(-std::f32::consts::LOG2_E / 3.0 / ((2 * F + 1) * (2 * F + 1)) as f32);
        let (f, y_first, y_end) = (F as i64, by0 as i64 - 2 * F as i64, (by0 + bh) as i64 + 2 * F as i64);
        // Every read, checked once: the lowest and the highest sample any
        // offset's distances or accumulation read (the distances' last
        // vector runs up to 32 - 2f columns past the block).
        let (reach, len) = (r + 2 * f, img.u.iter().chain(&img.v).map(Vec::len).min().unwrap_or(0) as i64);
        let lowest = (y_first - r) * w + bx0 as i64 - reach;
        let highest = (y_end - 1 + r) * w + (bx0 + bw) as i64 + 32 - 2 * f + r + 16;
        assert!(lowest >= 0 && highest <= len, "the block with its border inside the frame");
        assert!(num.iter().all(|n| n.len() >= bw * bh) && den.len() >= bw * bh, "block-sized accumulators");
        let (u, v) = (img.u.each_ref().map(|p| p.as_ptr()), img.v.each_ref().map(|p| p.as_ptr()));
        let (nums, dens) = (num.each_mut().map(|n| n.as_mut_ptr()), den.as_mut_ptr());
        // Samples `at..at + 16` of plane `p` (pointers hoisted: the
        // compiler would otherwise reload each plane's pointer and length
        // for every vector).
        macro_rules! load {
            ($p:expr, $at:expr) => {{
                let (p, at): (*const f32, i64) = ($p, $at);
                debug_assert!(lowest <= at && at + 16 <= highest);
                // SAFETY: `lowest <= at` and `at + 16 <= highest`, checked above.
                unsafe { _mm512_loadu_ps(p.offset(at as isize)) }
            }};
        }
        for dy in -r..=r {
            for dx in -r..=r {
                for sx in (bx0..bx0 + bw).step_by(16 * S) {
                    // Weights (and patch distances) from column sx - f, distances from sx - 2f.
                    let xd = sx as i64 - 2 * f;
                    let mut ring1 = [[_mm512_setzero_ps(); D]; 7];
                    let mut ring2 = [[_mm512_setzero_ps(); S]; 7];
                    for yd in y_first..y_end {
                        let mut dv = [_mm512_setzero_ps(); DD];
                        for (j, out) in dv.iter_mut().enumerate() {
                            let p = yd * w + xd + 16 * j as i64;
                            let q = p + dy * w + dx;
                            let mut acc = _mm512_setzero_ps();
                            for c in 0..3 {
                                let (up, uq) = (load!(u[c], p), load!(u[c], q));
                                let (vp, vq) = (load!(v[c], p), load!(v[c], q));
                                let d = _mm512_sub_ps(up, uq);
                                let m = _mm512_min_ps(vq, vp);
                                let rr = recip(_mm512_fmadd_ps(k2, _mm512_add_ps(vp, vq), eps));
                                let t = _mm512_sub_ps(_mm512_mul_ps(d, d), _mm512_add_ps(vp, m));
                                acc = _mm512_fmadd_ps(t, rr, acc);
                            }
                            *out = acc;
                        }
                        ring1[(yd - y_first) as usize % 7] = taps7::<D, DD>(&dv);
                        let yw = yd - f;
                        if yw < by0 as i64 - f {
                            continue;
                        }
                        let base = (yw - f - y_first) as usize;
                        let mut wv = [_mm512_setzero_ps(); D];
                        for (j, out) in wv.iter_mut().enumerate() {
                            let mut s = ring1[base % 7][j];
                            for k in 1..7 {
                                s = _mm512_add_ps(s, ring1[(base + k) % 7][j]);
                            }
                            *out = exp2_weight(_mm512_mul_ps(s, kd));
                        }
                        ring2[(yw - (by0 as i64 - f)) as usize % 7] = taps7::<S, D>(&wv);
                        let ya = yw - f;
                        if ya < by0 as i64 {
                            continue;
                        }
                        let base = (ya - f - (by0 as i64 - f)) as usize;
                        for j in 0..S {
                            let mut wt = ring2[base % 7][j];
                            for k in 1..7 {
                                wt = _mm512_add_ps(wt, ring2[(base + k) % 7][j]);
                            }
                            let x = sx + 16 * j;
                            let o = (ya as usize - by0) * bw + (x - bx0);
                            let q = (ya + dy) * w + x as i64 + dx;
                            let uq = [load!(u[0], q), load!(u[1], q), load!(u[2], q)];
                            debug_assert!(o + 16 <= bw * bh);
                            // SAFETY: `o + 16 <= bw * bh` (`x + 16 <= bx0 + bw`,
                            // `ya < by0 + bh`), within the accumulators, checked above.
                            unsafe {
                                let dp = dens.add(o);
                                _mm512_storeu_ps(dp, _mm512_add_ps(_mm512_loadu_ps(dp), wt));
                                for (np, uc) in nums.iter().zip(&uq) {
                                    let np = np.add(o);
                                    _mm512_storeu_ps(np, _mm512_fmadd_ps(wt, *uc, _mm512_loadu_ps(np)));
                                }
                            }
                        }
                    }
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn main() {
    use nldenoise::filter::nlmeans::{Job, NlmSettings, nlmeans};
    use nldenoise::geom::Rect;
    use nldenoise::image::Plane;
    use std::time::Instant;
    use strip::{F, Frame, filter};

    let a: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, d: usize| a.get(i).map_or(d, |s| s.parse().expect("a number"));
    let (s, w, h, runs) = (arg(0, 4), arg(1, 960), arg(2, 540), arg(3, 3));
    if ![1, 2, 4, 7].contains(&s) {
        eprintln!("strip_prototype: S must be 1, 2, 4 or 7 (a divisor of the 448-column blocks' 28 vectors)");
        std::process::exit(2);
    }
    if !(is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma")) {
        println!("strip_prototype: needs AVX-512F and FMA; nothing measured");
        return;
    }
    let r = 10usize;
    let pad = r + 2 * F;
    // Blocks of 448 columns (a multiple of 16 S for S = 1, 2, 4, 7) and up to 128 rows.
    let (bw, bh_max) = (448usize, 128usize);
    if w < bw + 2 * pad || h <= 2 * pad {
        eprintln!("strip_prototype: the frame must be at least {} x {}", bw + 2 * pad, 2 * pad + 1);
        std::process::exit(2);
    }
    let region = Rect::from_origin_size(pad as i64, pad as i64, (w - 2 * pad) / bw * bw, h - 2 * pad);
    let mut seed = 0x2545_f491u32;
    let mut next = move || {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (seed >> 8) as f32 / 16_777_216.0
    };
    // A smooth image with noise, and a variance of the noise's size. Each
    // plane has 64 samples past the frame's end: the bottom-right block's
    // last distance vectors may read past the frame's last row (the bound
    // `filter` checks reaches up to 36 samples past it when the region
    // ends at the frame's border of r + 2f).
    let mut plane = |c: usize, var: bool| -> Vec<f32> {
        (0..w * h + 64)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                if var {
                    0.002 + 0.002 * next()
                } else {
                    0.5 + 0.3 * ((x * 0.02 + c as f32).sin() * (y * 0.015).cos()) + 0.1 * (next() - 0.5)
                }
            })
            .collect()
    };
    let img = Frame {
        w,
        u: [plane(0, false), plane(1, false), plane(2, false)],
        v: [plane(0, true), plane(1, true), plane(2, true)],
    };
    let strength = 0.45f32;

    let mut proto = (f64::INFINITY, Vec::new());
    for _ in 0..runs {
        let t = Instant::now();
        let mut out = vec![[0.0f32; 3]; region.area()];
        for by in (region.y0 as usize..region.y1 as usize).step_by(bh_max) {
            let bh = bh_max.min(region.y1 as usize - by);
            for bx in (region.x0 as usize..region.x1 as usize).step_by(bw) {
                let mut num = [vec![0.0f32; bw * bh], vec![0.0; bw * bh], vec![0.0; bw * bh]];
                let mut den = vec![0.0f32; bw * bh];
                let block = (bx, by, bw, bh);
                // SAFETY: AVX-512F and FMA were detected; the region keeps a border of r + 2f.
                unsafe {
                    match s {
                        1 => filter::<1, 2, 3>(&img, r as i64, strength * strength, block, &mut num, &mut den),
                        2 => filter::<2, 3, 4>(&img, r as i64, strength * strength, block, &mut num, &mut den),
                        7 => filter::<7, 8, 9>(&img, r as i64, strength * strength, block, &mut num, &mut den),
                        // 4, the default (checked above).
                        _ => filter::<4, 5, 6>(&img, r as i64, strength * strength, block, &mut num, &mut den),
                    }
                }
                for i in 0..bw * bh {
                    let (y, x) = (by + i / bw - region.y0 as usize, bx + i % bw - region.x0 as usize);
                    out[y * region.width() + x] = [num[0][i] / den[i], num[1][i] / den[i], num[2][i] / den[i]];
                }
            }
        }
        proto = (proto.0.min(t.elapsed().as_secs_f64()), out);
    }

    let frame = Rect::from_origin_size(0, 0, w, h);
    let planes = |p: &[Vec<f32>; 3]| -> Vec<Plane> {
        p.iter().map(|v| Plane::from_vec(frame, v[..w * h].to_vec()).expect("frame-sized")).collect()
    };
    let (values, variance) = (planes(&img.u), planes(&img.v));
    let job = Job { values: values.iter().collect(), variance: variance.iter().collect() };
    let settings = NlmSettings { search_radius: r, patch_radius: F, strength, alpha: 1.0, eps: 1e-10 };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("a pool");
    let mut kernel = (f64::INFINITY, Vec::new());
    for _ in 0..runs {
        let t = Instant::now();
        let out = pool.install(|| nlmeans(std::slice::from_ref(&job), &[], frame, region, &settings));
        kernel = (kernel.0.min(t.elapsed().as_secs_f64()), out);
    }

    let mut worst = 0.0f64;
    for y in region.y0..region.y1 {
        for x in region.x0..region.x1 {
            let i = ((y - region.y0) * region.width() as i64 + (x - region.x0)) as usize;
            for c in 0..3 {
                let want = kernel.1[0][c].row(y, x, x + 1)[0] as f64;
                worst = worst.max(((proto.1[i][c] as f64 - want) / want.abs().max(1e-6)).abs());
            }
        }
    }
    // The two differ only in the rounding of the column sums: anything
    // larger means the prototype computes something else, and its time
    // would mean nothing.
    if worst > 1e-4 {
        eprintln!("strip_prototype: the prototype's output differs from the kernel's by {worst:.1e} (relative)");
        std::process::exit(1);
    }
    let po = region.area() as f64 * ((2 * r + 1) * (2 * r + 1)) as f64;
    println!(
        "region {}x{}, one thread: prototype (S = {s}) {:.3} s = {:.3} ns per pixel-offset; kernel {:.3} s = {:.3} ns; largest relative difference {worst:.1e}",
        region.width(),
        region.height(),
        proto.0,
        proto.0 * 1e9 / po,
        kernel.0,
        kernel.0 * 1e9 / po,
    );
}

#[cfg(not(target_arch = "x86_64"))]
fn main() {
    println!("strip_prototype: needs an x86_64 CPU with AVX-512; nothing measured");
}
