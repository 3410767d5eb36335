//! The block kernel's AVX-512 loops alone, in nanoseconds per 16 samples
//! (docs/performance.md, session 47): each loop on rows that stay in L1 (the
//! pushes also on as many rings as a full-filter step holds, in turn), three
//! forms of the boxes' horizontal window sums, and, with `PRIM=1`, the
//! throughput of single AVX-512 instruction kinds and of pairs of kinds (12
//! independent chains). Convert to cycles with the clock of `cargo bench
//! --bench peak -- clock`; compare with a loop's share of a real run
//! (`benches/kernel_profile.sh`). Needs a CPU with AVX-512.
//!
//!   cargo run --release --example component_rates [REPS]
//!   PRIM=1 cargo run --release --example component_rates
//!   WIDTH=256 cargo run --release --example component_rates   # rows of 256 samples
use std::hint::black_box;
use std::time::Instant;

#[cfg(target_arch = "x86_64")]
use nldenoise::filter::kernels::{self, GuideRow, ProductLane};

/// Samples per row: `WIDTH` (default 960, a block's width at 1080p; at
/// least 64, the guides' kernel's chunk).
fn width() -> usize {
    std::env::var("WIDTH").ok().and_then(|w| w.parse().ok()).unwrap_or(960).max(64)
}

fn time(name: &str, chunks_per_rep: usize, reps: usize, mut f: impl FnMut()) {
    f();
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t = Instant::now();
        for _ in 0..reps {
            f();
        }
        best = best.min(t.elapsed().as_secs_f64());
    }
    let ns = best * 1e9 / (reps * chunks_per_rep) as f64;
    println!("{name:48} {ns:7.3} ns per 16 samples");
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma,avx2,f16c")]
fn distance(d: &mut [f32], m: &mut [f32], rows: &[Vec<f32>; 12]) {
    let up = [&rows[0][..], &rows[1][..], &rows[2][..]];
    let uq = [&rows[3][1..], &rows[4][1..], &rows[5][1..]];
    let vp = [&rows[6][..], &rows[7][..], &rows[8][..]];
    let vq = [&rows[9][1..], &rows[10][1..], &rows[11][1..]];
    kernels::colour_distance_pair_rgb::<16, true>(d, m, up, uq, vp, vq, (1.0, 1e-10, 0.2));
}

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(20_000);
    #[cfg(target_arch = "x86_64")]
    if !(is_x86_feature_detected!("avx512f")
        && is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("fma")
        && is_x86_feature_detected!("f16c"))
    {
        println!("this CPU lacks AVX-512 (or AVX2, FMA, F16C): nothing to measure");
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if std::env::var("PRIM").is_ok() {
        for (name, f, ops) in prim::ALL {
            let reps = 20_000_000;
            let mut best = f64::MAX;
            for _ in 0..3 {
                let t = Instant::now();
                // SAFETY: the CPU has avx512f, f16c and fma (checked above).
                black_box(unsafe { f(black_box(reps)) });
                best = best.min(t.elapsed().as_secs_f64());
            }
            let per = best * 1e9 / (reps * 12) as f64;
            println!("{name:16} {per:6.3} ns per step of a chain ({ops} instructions): {:.2} per ns", ops / per);
        }
        return;
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the kernels and variants called below need avx512f (and the
    // distance's wrapper avx2, fma and f16c), checked above.
    unsafe {
        let n = width();
        let chunks = n / 16;
        let src: Vec<f32> = (0..n + 6).map(|i| ((i * 37) % 101) as f32 * 0.01).collect();
        let mut ring = vec![0i32; n];
        let mut run = vec![0i32; n];
        time("taps_push F=3 (h1 case), one ring in L1", chunks, reps, || {
            kernels::taps_push_avx512::<3, true, 2>(black_box(&src), &mut ring, &mut run, 1e6)
        });
        time("taps_push F=3 (h2 case), one ring in L1", chunks, reps, || {
            kernels::taps_push_avx512::<3, false, 2>(black_box(&src), &mut ring, &mut run, 1e6)
        });
        // A full-filter step: 2 jobs x 2 sides x 7 lanes x 2 boxes, each a
        // ring of 7 rows and a running row.
        let boxes = 56;
        let mut rings: Vec<Vec<i32>> = (0..boxes * 7).map(|_| vec![0i32; n.next_multiple_of(16)]).collect();
        let mut runs: Vec<Vec<i32>> = (0..boxes).map(|_| vec![0i32; n.next_multiple_of(16)]).collect();
        let mut row = 0usize;
        time("taps_push F=3, 56 boxes' rings in turn (1.6 MiB)", chunks * boxes, reps / boxes + 1, || {
            row = (row + 1) % 7;
            for b in 0..boxes {
                let (r, s) = (&mut rings[b * 7 + row][..n], &mut runs[b][..n]);
                kernels::taps_push_avx512::<3, false, 2>(black_box(&src), r, s, 1e6);
            }
        });
        let sums: Vec<i32> = (0..n).map(|i| -(((i * 7919) % 100_000) as i32)).collect();
        let tf: Vec<f32> = (0..n).map(|i| -(((i * 31) % 97) as f32) * 0.1).collect();
        let mut dst = vec![0f32; n];
        time("weights_avx512 guided", chunks, reps, || {
            kernels::weights_avx512::<true>(black_box(&sums), &tf, &mut dst, -1e-4, 10)
        });
        let rows: [Vec<f32>; 12] =
            std::array::from_fn(|c| (0..n + 8).map(|i| ((i * (c + 3)) % 53) as f32 * 0.02).collect());
        let (mut d, mut m) = (vec![0f32; n], vec![0f32; n]);
        time("colour_distance_pair_rgb (pair: 2 offsets)", chunks, reps, || distance(&mut d, &mut m, &rows));
        let halves: Vec<Vec<half::f16>> = (0..14)
            .map(|c| (0..n + 8).map(|i| half::f16::from_f32(((i * (c + 5)) % 61) as f32 / 61.0)).collect())
            .collect();
        let fp: Vec<GuideRow> = (0..7).map(|c| GuideRow::Half(&halves[c][..n])).collect();
        let fq: Vec<GuideRow> = (0..7).map(|c| GuideRow::Half(&halves[7 + c][1..n + 1])).collect();
        let inv: Vec<Vec<f32>> = (0..3).map(|g| vec![-0.5 - g as f32; n]).collect();
        let (mut o1, mut o2) = (vec![0f32; n], vec![0f32; n]);
        time("guide_pair_products (3,3,1) half, 2 lanes", chunks, reps, || {
            let lanes = [
                Some(ProductLane { from: 0, out: &mut o1[..], inv: [&inv[0], &inv[1], &inv[2], &inv[0]] }),
                Some(ProductLane { from: 0, out: &mut o2[..], inv: [&inv[0], &inv[1], &inv[2], &inv[0]] }),
            ];
            kernels::guide_pair_products_avx512(n, (&fp, &fq), &[3, 6, 7], lanes)
        });
        black_box((&ring, &run, &dst, &d, &m, &o1, &o2));
        let s2: Vec<f32> = (0..n + 64).map(|i| ((i * 37) % 101) as f32 * 0.01).collect();
        let mut outbuf = vec![0f32; n + 16];
        let off = outbuf.as_ptr().align_offset(64);
        let mut out = vec![0f32; n];
        let out_al = &mut outbuf[off..off + n];
        time("taps: 4 shuffles (the kernel's form)", chunks, reps, || taps_variants::shuffles(black_box(&s2), out_al));
        out.copy_from_slice(out_al);
        let a = out.clone();
        time("taps: 7 unaligned loads, store", chunks, reps, || taps_variants::loads(black_box(&s2), &mut out));
        assert!(a == out);
        time("taps: 2 shuffles, 3 loads, store", chunks, reps, || taps_variants::mixed(black_box(&s2), &mut out));
        assert!(a == out);
    }
}

/// Variants of the 7-tap window sums of a row (the same order of adds:
/// `((p[i] + p[i + 2]) + p[i + 4]) + s[i + 6]`, `p[j] = s[j] + s[j + 1]`).
#[cfg(target_arch = "x86_64")]
mod taps_variants {
    use std::arch::x86_64::*;

    #[inline(always)]
    unsafe fn ld(s: &[f32], i: usize) -> __m512 {
        unsafe { _mm512_loadu_ps(s.as_ptr().add(i)) }
    }
    #[inline(always)]
    fn al<const K: i32>(a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_castsi512_ps(_mm512_alignr_epi32::<K>(_mm512_castps_si512(b), _mm512_castps_si512(a))) }
    }

    /// In registers: four two-source shuffles per chunk (the kernel's form).
    #[target_feature(enable = "avx512f")]
    pub(crate) fn shuffles(s: &[f32], out: &mut [f32]) {
        let n = out.len();
        assert!(s.len() >= n + 48);
        unsafe {
            let (mut x0, mut x1) = (ld(s, 0), ld(s, 16));
            let mut p0 = _mm512_add_ps(x0, al::<1>(x0, x1));
            let mut i = 0;
            while i + 16 <= n {
                let x2 = ld(s, i + 32);
                let p1 = _mm512_add_ps(x1, al::<1>(x1, x2));
                let mut acc = _mm512_add_ps(p0, al::<2>(p0, p1));
                acc = _mm512_add_ps(acc, al::<4>(p0, p1));
                acc = _mm512_add_ps(acc, al::<6>(x0, x1));
                _mm512_storeu_ps(out.as_mut_ptr().add(i), acc);
                (x0, x1, p0) = (x1, x2, p1);
                i += 16;
            }
        }
    }

    /// Unaligned loads instead of every shuffle.
    #[target_feature(enable = "avx512f")]
    pub(crate) fn loads(s: &[f32], out: &mut [f32]) {
        let n = out.len();
        assert!(s.len() >= n + 48);
        unsafe {
            let mut i = 0;
            while i + 16 <= n {
                let p0 = _mm512_add_ps(ld(s, i), ld(s, i + 1));
                let p2 = _mm512_add_ps(ld(s, i + 2), ld(s, i + 3));
                let p4 = _mm512_add_ps(ld(s, i + 4), ld(s, i + 5));
                let acc = _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(p0, p2), p4), ld(s, i + 6));
                _mm512_storeu_ps(out.as_mut_ptr().add(i), acc);
                i += 16;
            }
        }
    }

    /// The pair sums from two unaligned loads, `p[i + 2]` and `p[i + 4]`
    /// by two shuffles, `s[i + 6]` by an unaligned load.
    #[target_feature(enable = "avx512f")]
    pub(crate) fn mixed(s: &[f32], out: &mut [f32]) {
        let n = out.len();
        assert!(s.len() >= n + 48);
        unsafe {
            let mut p0 = _mm512_add_ps(ld(s, 0), ld(s, 1));
            let mut i = 0;
            while i + 16 <= n {
                let p1 = _mm512_add_ps(ld(s, i + 16), ld(s, i + 17));
                let mut acc = _mm512_add_ps(p0, al::<2>(p0, p1));
                acc = _mm512_add_ps(acc, al::<4>(p0, p1));
                acc = _mm512_add_ps(acc, ld(s, i + 6));
                _mm512_storeu_ps(out.as_mut_ptr().add(i), acc);
                p0 = p1;
                i += 16;
            }
        }
    }
}

/// Throughput of single instruction kinds and pairs of kinds: 12 independent
/// chains, `reps` iterations; returns a value to keep the work alive.
#[cfg(target_arch = "x86_64")]
mod prim {
    use std::arch::x86_64::*;
    macro_rules! rate {
        ($name:ident, |$v:ident, $b:ident| $body:expr) => {
            #[target_feature(enable = "avx512f,f16c,fma")]
            pub(crate) fn $name(reps: usize) -> f32 {
                let mut a = [_mm512_set1_ps(1.0); 12];
                for (k, v) in a.iter_mut().enumerate() {
                    *v = _mm512_set1_ps(1.0 + k as f32 * 1e-3);
                }
                let $b = _mm512_set1_ps(1.0000001);
                for _ in 0..reps {
                    for $v in a.iter_mut() {
                        *$v = $body;
                    }
                }
                let mut s = a[0];
                for v in &a[1..] {
                    s = _mm512_add_ps(s, *v);
                }
                _mm512_reduce_add_ps(s)
            }
        };
    }
    fn al<const K: i32>(a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_castsi512_ps(_mm512_alignr_epi32::<K>(_mm512_castps_si512(b), _mm512_castps_si512(a))) }
    }
    rate!(add, |v, b| _mm512_add_ps(*v, b));
    rate!(fma, |v, b| _mm512_fmadd_ps(*v, b, b));
    rate!(add_valign, |v, b| _mm512_add_ps(al::<3>(*v, b), b));
    rate!(fma_valign, |v, b| _mm512_fmadd_ps(al::<3>(*v, b), b, b));
    rate!(fma_add, |v, b| _mm512_add_ps(_mm512_fmadd_ps(*v, b, b), b));
    rate!(cvt_i2f, |v, b| _mm512_add_ps(_mm512_cvtepi32_ps(_mm512_castps_si512(*v)), b));
    rate!(cvt_f2i, |v, b| _mm512_castsi512_ps(_mm512_add_epi32(_mm512_cvtps_epi32(*v), _mm512_castps_si512(b))));
    rate!(cvtph, |v, b| _mm512_add_ps(_mm512_cvtph_ps(_mm512_castsi512_si256(_mm512_castps_si512(*v))), b));
    rate!(div, |v, b| _mm512_div_ps(*v, b));
    rate!(min, |v, b| _mm512_min_ps(*v, b));

    /// A measured kind: its name, its loop of `reps` steps, its operations per step.
    pub(crate) type Kind = (&'static str, unsafe fn(usize) -> f32, f64);

    /// (A kind alone whose steps LLVM can merge, such as shifts by
    /// `valignd` or integer adds of a constant, would be measured wrong: each
    /// shift is measured after an add or a fused multiply-add.)
    pub(crate) const ALL: [Kind; 10] = [
        ("add", add, 1.0),
        ("fma", fma, 1.0),
        ("valignd+add", add_valign, 2.0),
        ("valignd+fma", fma_valign, 2.0),
        ("fma+add", fma_add, 2.0),
        ("cvtdq2ps+add", cvt_i2f, 2.0),
        ("cvtps2dq+paddd", cvt_f2i, 2.0),
        ("cvtph2ps+add", cvtph, 2.0),
        ("div", div, 1.0),
        ("min", min, 1.0),
    ];
}
