//! The machine's peak floating-point rate for the operations the filter uses,
//! measured with independent chains `a = a * m + c` on 16 accumulators of one
//! vector each, per tier (AVX-512: 16 lanes, AVX2: 8 lanes, portable), on 1
//! and 2 threads. `cargo bench --bench peak`.
//!
//! - `peak_mul_add_f32`: a separate multiply and add, 2 operations (2 flops)
//!   per lane per step: the rate of plain add/mul/min/max operations.
//! - `peak_fma_f32` (AVX2 and AVX-512 tiers): one fused multiply-add, 1
//!   operation (2 flops) per lane per step.
//!
//! - `mix_recip_exp2`: a Newton reciprocal (`newton_recip` below, the
//!   filter's until session 31, when it took up an IEEE division) and the
//!   filter's `kernels::exp2_weight` on rows that stay in L1,
//!   `exp2_weight(newton_recip(a) * b)` per sample, compiled for the tier:
//!   18 counted operations per sample
//!   (the reciprocal's 6 fused multiply-adds, the multiply, the weight's 11;
//!   integer bit operations not counted, as in docs/performance.md; the
//!   reciprocal has had five since session 24, so the rate reported is
//!   18/17 of the operations run). Each
//!   sample's operations depend on one another, as in the filter's loops:
//!   the rate a row loop of the filter's arithmetic reaches with no memory
//!   traffic beyond L1, below the independent chains' peak.
//!   `avx512_16_lockstep` runs the weight as `kernels::exp2_weight_lanes`
//!   (each operation on a whole 64-sample chunk before the next, as the
//!   filter's `weight_row` does): the same operations, in another order.
//! - `distance_recip_div`: the colour distance's per-channel arithmetic over
//!   rows in L1 (one thread), its reciprocal as `newton_recip` or as the
//!   IEEE division the filter uses since session 31; throughput in
//!   pixel-channels per second.
//! - `weights_row`: a row of guided weights over rows in L1 (one thread),
//!   in the lanes form the portable and AVX2 tiers run or by
//!   `kernels::weights_avx512` (the same bits); throughput in weights per
//!   second.
//!
//! - `clock_add_chain`: four dependent integer adds per loop step (one
//!   cycle each: the loop's own instructions run beside the chain), on 1
//!   and 2 threads: elements/s is the core's clock, which turns the
//!   filter's nanoseconds per pixel-offset into cycles on a machine
//!   without hardware counters (under KVM `/proc/cpuinfo` shows a fixed
//!   nominal rate, not the clock the cores run at).
//!
//! - `memory_rates` (AVX-512, one thread): 512-bit loads (each into a
//!   `vmaxps` on one of four accumulators) and 512-bit stores over a buffer
//!   of 16 KiB (it stays in L1) and of 512 KiB (in L2, out of L1), four
//!   unrolled per loop step; elements/s is vectors per second, and the
//!   clock over it the cycles a vector load or store takes: the memory
//!   side of the kernel's rate, as `peak_*` is its arithmetic side.
//!
//! Throughput is reported in elements/s = operations per second.
//! docs/performance.md divides the filter's operation count (an FMA counts
//! once) by its time and by the operation peak.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};

const ACC: usize = 16;
const STEPS: usize = 2_000_000;

#[inline(always)]
fn chains<const L: usize>(steps: usize, seed: f32) -> f32 {
    let mut a = [[seed; L]; ACC];
    for (i, acc) in a.iter_mut().enumerate() {
        acc.iter_mut().enumerate().for_each(|(l, v)| *v += (i * L + l) as f32 * 1e-3);
    }
    let m = black_box([0.999_999_9f32; L]);
    let c = black_box([1e-7f32; L]);
    for _ in 0..steps {
        for acc in a.iter_mut() {
            for l in 0..L {
                acc[l] = acc[l] * m[l] + c[l];
            }
        }
    }
    a.iter().flatten().sum()
}

// Explicit intrinsics for the vector tiers: the compiler must not be trusted
// to keep 16 accumulators in registers through a generic loop. One chain
// runner per tier and step: `$step(v, m, c)` is `v * m + c`, separate or fused.
macro_rules! vector_chains {
    ($name:ident, $feature:literal, $vec:ident, $lanes:literal, $set1:ident, $add:ident, $zero:ident, $store:ident,
     |$v:ident, $m:ident, $c:ident| $step:expr) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $feature)]
        fn $name(steps: usize) -> f32 {
            use std::arch::x86_64::*;
            let $m = $set1(black_box(0.999_999_9));
            let $c = $set1(black_box(1e-7));
            let mut a: [$vec; ACC] = std::array::from_fn(|i| $set1(1.0 + i as f32 * 1e-3));
            for _ in 0..steps {
                for $v in a.iter_mut() {
                    *$v = $step;
                }
            }
            let mut out = [0.0f32; $lanes];
            let sum = a.iter().fold($zero(), |s, v| $add(s, *v));
            // SAFETY: `out` holds one vector of floats.
            unsafe { $store(out.as_mut_ptr(), sum) };
            out.iter().sum()
        }
    };
}

// The two vector tiers' intrinsics, bound once.
macro_rules! avx512_chains {
    ($name:ident, $feature:literal, $step:expr) => {
        vector_chains!(
            $name,
            $feature,
            __m512,
            16,
            _mm512_set1_ps,
            _mm512_add_ps,
            _mm512_setzero_ps,
            _mm512_storeu_ps,
            |v, m, c| $step(v, m, c)
        );
    };
}
macro_rules! avx2_chains {
    ($name:ident, $feature:literal, $step:expr) => {
        vector_chains!(
            $name,
            $feature,
            __m256,
            8,
            _mm256_set1_ps,
            _mm256_add_ps,
            _mm256_setzero_ps,
            _mm256_storeu_ps,
            |v, m, c| $step(v, m, c)
        );
    };
}

avx512_chains!(chains_avx512, "avx512f", |v: &mut __m512, m, c| _mm512_add_ps(_mm512_mul_ps(*v, m), c));
avx2_chains!(chains_avx2, "avx2", |v: &mut __m256, m, c| _mm256_add_ps(_mm256_mul_ps(*v, m), c));
avx512_chains!(fma_chains_avx512, "avx512f,fma", |v: &mut __m512, m, c| _mm512_fmadd_ps(*v, m, c));
avx2_chains!(fma_chains_avx2, "avx2,fma", |v: &mut __m256, m, c| _mm256_fmadd_ps(*v, m, c));

/// Samples of one row of the mix (3 x 4 KiB rows in L1) and its repetitions.
const MIX_ROW: usize = 1024;
const MIX_REPS: usize = 20_000;

/// `1 / x` from add/mul only, the filter's reciprocal until session 31
/// (docs/performance.md): a bit-level first guess refined by one third-order
/// step and one Newton step (five fused multiply-adds), within 2.5e-7 of
/// `1 / x` over `[1e-30, 1e37]`.
#[inline(always)]
fn newton_recip(x: f32) -> f32 {
    let y = f32::from_bits(0x7EF3_11C3u32.wrapping_sub(x.to_bits()));
    let e = (-x).mul_add(y, 1.0);
    let y = y.mul_add(e.mul_add(e, e), y);
    y.mul_add((-x).mul_add(y, 1.0), y)
}

/// Counted operations per sample of the mix (see the module's docs).
const MIX_OPS: usize = 18;

/// The mix over rows in L1: per sample, or with `LOCKSTEP` the weight in
/// the filter's lockstep form (`kernels::exp2_weight_lanes` over chunks of
/// `kernels::CHUNK_AVX512` samples, as `weight_row` runs it): the same
/// operations and bits per sample, each operation on the whole chunk
/// before the next.
#[inline(always)]
fn mix_rows<const LOCKSTEP: bool>(reps: usize) -> f32 {
    use nldenoise::filter::kernels::{CHUNK_AVX512 as W, exp2_weight, exp2_weight_lanes};
    let a: Vec<f32> = (0..MIX_ROW).map(|i| 0.5 + (i % 97) as f32 * 0.01).collect();
    let b: Vec<f32> = (0..MIX_ROW).map(|i| -((i % 89) as f32) * 0.1).collect();
    let mut out = vec![0.0f32; MIX_ROW];
    for _ in 0..reps {
        let (a, b) = (black_box(&a[..]), black_box(&b[..]));
        if LOCKSTEP {
            for ((o, x), y) in out.chunks_exact_mut(W).zip(a.chunks_exact(W)).zip(b.chunks_exact(W)) {
                let mut t = [0.0f32; W];
                for k in 0..W {
                    t[k] = newton_recip(x[k]) * y[k];
                }
                o.copy_from_slice(&exp2_weight_lanes(t));
            }
        } else {
            for ((o, &x), &y) in out.iter_mut().zip(a).zip(b) {
                *o = exp2_weight(newton_recip(x) * y);
            }
        }
        black_box(&mut out);
    }
    out.iter().sum()
}

/// The colour distance's per-channel arithmetic (as
/// `kernels::colour_distance_pair_rgb` with `alpha = 1`, one direction),
/// three channels into 64-sample chunks, over rows in L1, with the
/// denominator's reciprocal as [`newton_recip`] or, with `DIV`, as the IEEE
/// division the filter uses (both the same bits on every tier).
#[inline(always)]
fn distance_rows<const DIV: bool>(reps: usize) -> f32 {
    let u: Vec<f32> = (0..3 * MIX_ROW + 64).map(|i| 0.5 + (i % 97) as f32 * 0.01).collect();
    let v: Vec<f32> = (0..3 * MIX_ROW + 64).map(|i| 0.01 + (i % 89) as f32 * 0.001).collect();
    let mut out = vec![0.0f32; MIX_ROW];
    for _ in 0..reps {
        let (u, v) = (black_box(&u[..]), black_box(&v[..]));
        for (c, o) in out.chunks_exact_mut(64).enumerate() {
            let mut a = [0.0f32; 64];
            for ch in 0..3 {
                let at = ch * MIX_ROW + c * 64;
                let (up, uq, vp, vq) = (&u[at..at + 64], &u[at + 1..at + 65], &v[at..at + 64], &v[at + 1..at + 65]);
                for k in 0..64 {
                    let d = up[k] - uq[k];
                    let m = if vq[k] < vp[k] { vq[k] } else { vp[k] };
                    let x = 0.2025f32.mul_add(vp[k] + vq[k], 1e-10);
                    let r = if DIV { 1.0 / x } else { newton_recip(x) };
                    a[k] = (d * d - (vp[k] + m)).mul_add(r, a[k]);
                }
            }
            o.copy_from_slice(&a);
        }
        black_box(&mut out);
    }
    out.iter().sum()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn distance_recip_avx512(reps: usize) -> f32 {
    distance_rows::<false>(reps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn distance_div_avx512(reps: usize) -> f32 {
    distance_rows::<true>(reps)
}

/// A row of weights from window sums and guide arguments, over rows in L1:
/// `nlmeans::weight_row`'s whole windows, as the portable and AVX2 tiers
/// compute them (`kernels::exp2_weight_scaled_lanes` on 64-sample chunks,
/// with `LANES`) or as the AVX-512 tier does (`kernels::weights_avx512`):
/// the same bits, 17 and 13 operations per weight as written.
#[inline(always)]
fn weight_rows<const LANES: bool>(reps: usize) -> f32 {
    use nldenoise::filter::kernels::{CHUNK_AVX512 as W, exp2_weight_scaled_lanes};
    let sums: Vec<i32> = (0..MIX_ROW).map(|i| ((i * 7919) % 400_000) as i32 - 20_000).collect();
    let tf: Vec<f32> = (0..MIX_ROW).map(|i| -((i % 83) as f32) * 0.7).collect();
    let (inner, e) = (-1.2e-4f32, 20);
    let mut out = vec![0.0f32; MIX_ROW];
    for _ in 0..reps {
        let (sums, tf) = (black_box(&sums[..]), black_box(&tf[..]));
        if LANES {
            for ((o, s), g) in out.chunks_exact_mut(W).zip(sums.chunks_exact(W)).zip(tf.chunks_exact(W)) {
                let mut t = [0.0f32; W];
                for k in 0..W {
                    let x = s[k] as f32 * inner;
                    t[k] = if g[k] < x { g[k] } else { x };
                }
                o.copy_from_slice(&exp2_weight_scaled_lanes(t, e));
            }
        } else {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: called only from `weights_kernel_avx512`, whose CPU has AVX-512F.
            unsafe {
                nldenoise::filter::kernels::weights_avx512::<true>(sums, tf, &mut out, inner, e)
            };
        }
        black_box(&mut out);
    }
    out.iter().sum()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn weights_lanes_avx512(reps: usize) -> f32 {
    weight_rows::<true>(reps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn weights_kernel_avx512(reps: usize) -> f32 {
    weight_rows::<false>(reps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn mix_avx512(reps: usize) -> f32 {
    mix_rows::<false>(reps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn mix_lockstep_avx512(reps: usize) -> f32 {
    mix_rows::<true>(reps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn mix_avx2(reps: usize) -> f32 {
    mix_rows::<false>(reps)
}

fn portable(steps: usize) -> f32 {
    chains::<4>(steps, 1.0)
}

/// A chain runner: steps in, a checksum out.
type Chains = fn(usize) -> f32;

/// Steps of [`add_chain`] per run: a billion adds.
#[cfg(target_arch = "x86_64")]
const CLOCK_STEPS: usize = 250_000_000;

/// `steps` steps of four dependent integer adds: four cycles per step on
/// the cores we ran on (an add's latency is one cycle).
#[cfg(target_arch = "x86_64")]
fn add_chain(steps: usize) -> f32 {
    let mut x = black_box(0u64);
    for _ in 0..steps {
        // SAFETY: register arithmetic only.
        unsafe {
            std::arch::asm!(
                "add {0}, 1",
                "add {0}, 1",
                "add {0}, 1",
                "add {0}, 1",
                inout(reg) x,
                options(nomem, nostack, pure)
            )
        };
    }
    x as f32
}

/// Buffer sizes of `memory_rates`, in bytes: L1-resident and L2-resident.
#[cfg(target_arch = "x86_64")]
const MEMORY_BYTES: [usize; 2] = [16 << 10, 512 << 10];

/// Vectors loaded or stored per `memory_rates` run: 2 GB worth.
#[cfg(target_arch = "x86_64")]
const MEMORY_VECTORS: usize = 2_000_000_000 / 64;

/// `MEMORY_VECTORS` 512-bit loads over `buf`, again and again, each into a
/// `vmaxps` on one of four accumulators (so loads, not the dependency, limit).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn vector_loads(buf: &[f32]) -> f32 {
    use std::arch::x86_64::*;
    let n = buf.len() / 16;
    assert!(n.is_multiple_of(4) && n > 0, "whole steps of four vectors");
    let mut a = [_mm512_setzero_ps(); 4];
    for _ in 0..MEMORY_VECTORS / n {
        for i in (0..n).step_by(4) {
            for (k, acc) in a.iter_mut().enumerate() {
                // SAFETY: `i + k < n`: inside `buf`.
                *acc = _mm512_max_ps(*acc, unsafe { _mm512_loadu_ps(buf.as_ptr().add(16 * (i + k))) });
            }
        }
    }
    _mm512_reduce_add_ps(_mm512_add_ps(_mm512_add_ps(a[0], a[1]), _mm512_add_ps(a[2], a[3])))
}

/// `MEMORY_VECTORS` 512-bit stores over `buf`, again and again.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn vector_stores(buf: &mut [f32]) -> f32 {
    use std::arch::x86_64::*;
    let n = buf.len() / 16;
    assert!(n.is_multiple_of(4) && n > 0, "whole steps of four vectors");
    let mut v = _mm512_set1_ps(1.0);
    for _ in 0..MEMORY_VECTORS / n {
        for i in (0..n).step_by(4) {
            for k in 0..4 {
                // SAFETY: `i + k < n`: inside `buf`.
                unsafe { _mm512_storeu_ps(buf.as_mut_ptr().add(16 * (i + k)), v) };
            }
        }
        v = _mm512_add_ps(v, _mm512_set1_ps(1e-7));
    }
    buf[0]
}

/// `f(steps)` on `threads` threads at once; the sum of their checksums.
fn on_threads(threads: usize, f: Chains, steps: usize) -> f32 {
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(move || f(black_box(steps)))).collect();
        handles.into_iter().map(|h| h.join().unwrap()).sum()
    })
}

fn bench(c: &mut Criterion) {
    #[cfg(target_arch = "x86_64")]
    {
        let mut g = c.benchmark_group("clock_add_chain");
        g.sample_size(10);
        for threads in [1usize, 2] {
            g.throughput(Throughput::Elements((4 * CLOCK_STEPS * threads) as u64));
            g.bench_function(format!("{threads}thread"), |b| b.iter(|| on_threads(threads, add_chain, CLOCK_STEPS)));
        }
        g.finish();
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        let mut g = c.benchmark_group("memory_rates");
        g.sample_size(10);
        for bytes in MEMORY_BYTES {
            let mut buf = vec![1.0f32; bytes / 4];
            let vectors = MEMORY_VECTORS / (buf.len() / 16) * (buf.len() / 16);
            g.throughput(Throughput::Elements(vectors as u64));
            let kib = bytes >> 10;
            // SAFETY: the CPU supports AVX-512F (detected above).
            g.bench_function(format!("load512_{kib}KiB"), |b| b.iter(|| unsafe { vector_loads(black_box(&buf)) }));
            // SAFETY: as above.
            g.bench_function(format!("store512_{kib}KiB"), |b| {
                b.iter(|| unsafe { vector_stores(black_box(&mut buf)) })
            });
        }
        g.finish();
    }
    let mut g = c.benchmark_group("peak_mul_add_f32");
    g.sample_size(10);
    let mut tiers: Vec<(&str, usize, Chains)> = vec![("portable_4", 4, portable)];
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: called only when the CPU has AVX2.
            tiers.push(("avx2_8", 8, |n| unsafe { chains_avx2(n) }));
        }
        if std::is_x86_feature_detected!("avx512f") {
            // SAFETY: called only when the CPU has AVX-512F.
            tiers.push(("avx512_16", 16, |n| unsafe { chains_avx512(n) }));
        }
    }
    for (name, lanes, f) in tiers {
        for threads in [1usize, 2] {
            g.throughput(Throughput::Elements((2 * ACC * lanes * STEPS * threads) as u64));
            g.bench_function(format!("{name}_{threads}thread"), |b| b.iter(|| on_threads(threads, f, STEPS)));
        }
    }
    g.finish();
    let mut g = c.benchmark_group("peak_fma_f32");
    g.sample_size(10);
    let mut fma_tiers: Vec<(&str, usize, Chains)> = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        let fma = std::is_x86_feature_detected!("fma");
        if fma && std::is_x86_feature_detected!("avx2") {
            // SAFETY: called only when the CPU has AVX2 and FMA.
            fma_tiers.push(("avx2_8", 8, |n| unsafe { fma_chains_avx2(n) }));
        }
        if fma && std::is_x86_feature_detected!("avx512f") {
            // SAFETY: called only when the CPU has AVX-512F and FMA.
            fma_tiers.push(("avx512_16", 16, |n| unsafe { fma_chains_avx512(n) }));
        }
    }
    for (name, lanes, f) in fma_tiers {
        for threads in [1usize, 2] {
            g.throughput(Throughput::Elements((ACC * lanes * STEPS * threads) as u64));
            g.bench_function(format!("{name}_{threads}thread"), |b| b.iter(|| on_threads(threads, f, STEPS)));
        }
    }
    g.finish();
    let mut g = c.benchmark_group("mix_recip_exp2");
    g.sample_size(10);
    let mut mix_tiers: Vec<(&str, Chains)> = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        let fma = std::is_x86_feature_detected!("fma");
        if fma && std::is_x86_feature_detected!("avx2") {
            // SAFETY: called only when the CPU has AVX2 and FMA.
            mix_tiers.push(("avx2_8", |n| unsafe { mix_avx2(n) }));
        }
        if fma && std::is_x86_feature_detected!("avx512f") {
            // SAFETY: called only when the CPU has AVX-512F and FMA.
            mix_tiers.push(("avx512_16", |n| unsafe { mix_avx512(n) }));
            // SAFETY: as above.
            mix_tiers.push(("avx512_16_lockstep", |n| unsafe { mix_lockstep_avx512(n) }));
        }
    }
    for (name, f) in mix_tiers {
        for threads in [1usize, 2] {
            g.throughput(Throughput::Elements((MIX_OPS * MIX_ROW * MIX_REPS * threads) as u64));
            g.bench_function(format!("{name}_{threads}thread"), |b| b.iter(|| on_threads(threads, f, MIX_REPS)));
        }
    }
    g.finish();
    // Samples (pixel-channels) per second of the distance's arithmetic.
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("fma") && std::is_x86_feature_detected!("avx512f") {
        let mut g = c.benchmark_group("distance_recip_div");
        g.sample_size(10);
        g.throughput(Throughput::Elements((3 * MIX_ROW * MIX_REPS) as u64));
        let variants: [(&str, Chains); 2] = [
            // SAFETY: called only when the CPU has AVX-512F and FMA.
            ("avx512_16_recip", |n| unsafe { distance_recip_avx512(n) }),
            // SAFETY: as above.
            ("avx512_16_div", |n| unsafe { distance_div_avx512(n) }),
        ];
        for (name, f) in variants {
            g.bench_function(name, |b| b.iter(|| on_threads(1, f, MIX_REPS)));
        }
        g.finish();
    }
    // Weights per second: the lanes form against `kernels::weights_avx512`
    // (the same bits), rows in L1, one thread.
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("fma") && std::is_x86_feature_detected!("avx512f") {
        let mut g = c.benchmark_group("weights_row");
        g.sample_size(10);
        g.throughput(Throughput::Elements((MIX_ROW * MIX_REPS) as u64));
        let variants: [(&str, Chains); 2] = [
            // SAFETY: called only when the CPU has AVX-512F and FMA.
            ("avx512_16_lanes_form", |n| unsafe { weights_lanes_avx512(n) }),
            // SAFETY: as above.
            ("avx512_16_weights_avx512", |n| unsafe { weights_kernel_avx512(n) }),
        ];
        for (name, f) in variants {
            g.bench_function(name, |b| b.iter(|| on_threads(1, f, MIX_REPS)));
        }
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
