//! One step of the block kernel replayed from its AVX-512 loops on
//! synthetic buffers (docs/performance.md, session 48), to compare the
//! loops' time together with the sum of their times alone. For each row of
//! a block (`ROWS`, `WIDTH`), as the kernel runs a step of seven pairs of
//! offsets: every job's (light layer's) seven pairs' colour distances (`d`)
//! and their fourteen pushes into the distance boxes (`p`); the guides'
//! products of the seven pairs with `GUIDES=1` (`g`: albedo, normal and
//! depth as half floats); then, job by job, fourteen lanes' weights (`w`,
//! guided with `GUIDES=1`) and pushes into the weight boxes (`q`), and both
//! sides' accumulation of seven lanes into the job's numerators and
//! denominator (`a`, the kernel's `kernels::fused_rgb_shifted_avx512`;
//! `A` instead: the path of a row clipped at the frame's side, each
//! lane's sums in its first and last vectors multiplied by its factors as
//! they are read, as the kernel does since session 49; in session 48 `A`
//! replayed that row's former path, the sums converted into a row of `f32`
//! first). `JOBS` (default 1) is 1 for colour-only, 2 for the full filter.
//!
//! `STAGES` picks the stages that run (default `dpgwqa`); `SPLIT=1` runs
//! every stage alone and then all of them, alternately for `ROUNDS`
//! rounds, and prints each one's minimum, the sum of the stages' minima
//! and the step's over that sum. `FIXED=1` reads and writes row 0 of every
//! plane (or a list of classes: `in` the distances' inputs, `guides`,
//! `acc` the accumulators, `val` the accumulated values) instead of walking
//! the block's rows. `STAGGER` (samples, default 80) shifts plane `k`'s
//! first sample by `k` times it, modulo 4 KiB: with 0, every plane starts
//! at the same place in the L1 cache's sets (about 15-20 % slower for the
//! full filter here; the kernel's own planes staggered alike were no
//! faster, session 48). `DIST=1..5` replaces stage `d` with a variant of the
//! colour distance's loop (see `dist_variant`; session 50), `ALPHA_FMA=1`
//! runs the kernel's loop with its variance terms as fused multiply-adds. Nanoseconds and cycles (at `GHZ`, default 3.5) per
//! pixel-offset. Needs a CPU with AVX-512.
//!
//!   cargo run --release --example step_replay [REPS]
//!   SPLIT=1 JOBS=2 GUIDES=1 cargo run --release --example step_replay
//!   STAGES=d FIXED=in cargo run --release --example step_replay
use std::hint::black_box;
use std::time::Instant;

#[cfg(target_arch = "x86_64")]
use nldenoise::filter::kernels::{self, GuideRow, ProductLane};

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|w| w.parse().ok()).unwrap_or(default)
}

/// Seven lanes per side, the kernel's `GROUP_MAX`.
const G: usize = 7;
/// Patch radius: windows of 7 taps.
const F: usize = 3;
/// Rows per ring: `2F + 1`.
const CAP: usize = 2 * F + 1;

/// A box: its ring of `CAP` rows and its running sums.
struct Box {
    ring: Vec<Vec<i32>>,
    run: Vec<i32>,
}

impl Box {
    fn new(n: usize) -> Box {
        Box { ring: (0..CAP).map(|_| vec![0; n]).collect(), run: vec![0; n] }
    }
}

/// A job (a light layer): its values and variances, its boxes, and its
/// accumulators (per side: the denominator and three numerators).
struct Job {
    u: Vec<Plane<f32>>,
    v: Vec<Plane<f32>>,
    h1: Vec<Box>,
    h2: Vec<Box>,
    num: Vec<Plane<f32>>,
}

impl Job {
    fn new(j: usize, rows: usize, span: usize, n: usize, mid: usize) -> Job {
        Job {
            u: (0..3).map(|c| plane(rows, span, 6 * j + c, 0.0)).collect(),
            v: (0..3).map(|c| plane(rows, span, 6 * j + c + 3, 0.01)).collect(),
            h1: (0..2 * G).map(|_| Box::new(mid)).collect(),
            h2: (0..2 * G).map(|_| Box::new(n)).collect(),
            num: (0..4)
                .map(|c| {
                    let off = stagger(40 + 4 * j + c);
                    Plane { data: vec![0f32; off + n * rows], width: n, off }
                })
                .collect(),
        }
    }
}

/// A plane: rows of `width` samples, one after the other in one buffer
/// (as the band's planes and the block's accumulators are), `plane[y]` row
/// `y`.
struct Plane<T> {
    data: Vec<T>,
    width: usize,
    /// Where row 0 starts in `data`.
    off: usize,
}

impl<T> std::ops::Index<usize> for Plane<T> {
    type Output = [T];
    fn index(&self, y: usize) -> &[T] {
        &self.data[self.off + y * self.width..self.off + (y + 1) * self.width]
    }
}

impl<T> std::ops::IndexMut<usize> for Plane<T> {
    fn index_mut(&mut self, y: usize) -> &mut [T] {
        &mut self.data[self.off + y * self.width..self.off + (y + 1) * self.width]
    }
}

/// `rows` rows of `width` samples each, values in `[lo, lo + 1)`.
fn plane(rows: usize, width: usize, seed: usize, lo: f32) -> Plane<f32> {
    let off = stagger(seed);
    let data = (0..off + rows * width)
        .map(|i| {
            let (y, x) = (i.saturating_sub(off) / width, i.saturating_sub(off) % width);
            lo + ((x * 37 + y * 101 + seed * 13) % 97) as f32 / 97.0
        })
        .collect();
    Plane { data, width, off }
}

/// Plane `seed`'s first sample: `STAGGER` (default 0) samples times its
/// seed, modulo 1024 (4 KiB), so that planes allocated alike start at
/// different places in the L1 cache's sets.
fn stagger(seed: usize) -> usize {
    seed * env_usize("STAGGER", 80) % 1024
}

fn main() {
    #[cfg(target_arch = "x86_64")]
    {
        if !(is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma")) {
            println!("this CPU lacks AVX-512 (or FMA): nothing to measure");
            return;
        }
        let reps = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(4usize);
        let ghz: f64 = std::env::var("GHZ").ok().and_then(|g| g.parse().ok()).unwrap_or(3.5);
        let guided = std::env::var("GUIDES").is_ok_and(|v| v == "1");
        let all = std::env::var("STAGES").unwrap_or_else(|_| "dpgwqa".into());
        let all: String = all.chars().filter(|&c| c != 'g' || guided).collect();
        let line = |stages: &str, ns: f64| println!("{stages:8} {ns:.3} ns, {:.2} cycles per pixel-offset", ns * ghz);
        if std::env::var("SPLIT").is_ok_and(|v| v == "1") {
            let mut kinds: Vec<String> = all.chars().map(String::from).collect();
            kinds.push(all.clone());
            let mut best = vec![f64::MAX; kinds.len()];
            for _ in 0..env_usize("ROUNDS", 3) {
                for (k, stages) in kinds.iter().enumerate() {
                    // SAFETY: avx512f and fma, checked above.
                    best[k] = best[k].min(unsafe { run(stages, reps) });
                }
            }
            for (stages, ns) in kinds.iter().zip(&best) {
                line(stages, *ns);
            }
            let sum: f64 = best[..best.len() - 1].iter().sum();
            line("sum", sum);
            println!("together over the sum: {:.3}", best[best.len() - 1] / sum);
        } else {
            // SAFETY: avx512f and fma, checked above.
            line(&all, unsafe { run(&all, reps) });
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma,avx2,f16c")]
fn run(stages: &str, reps: usize) -> f64 {
    let n = env_usize("WIDTH", 960);
    let rows = env_usize("ROWS", 134);
    // `FIXED=1` (every class) or a list of `in` (the distances' inputs),
    // `guides`, `acc` (the accumulators), `val` (the accumulated values).
    let fixed_list = std::env::var("FIXED").unwrap_or_default();
    let fixed = |class: &str| fixed_list == "1" || fixed_list.split(',').any(|c| c == class);
    let on = |c: char| stages.contains(c);
    let dy = 1usize;
    let dist_mode = env_usize("DIST", 0);
    let alpha_fma = std::env::var("ALPHA_FMA").is_ok_and(|v| v == "1");
    // The pairs' rows: `outer` (the block widened by 2F) and the seven
    // offsets' spread; the distance boxes' rows `mid` (widened by F).
    let (outer, mid) = (n + 4 * F, n + 2 * F);
    let span = outer + G + 32;
    let jobs: Vec<Job> = (0..env_usize("JOBS", 1)).map(|j| Job::new(j, rows + dy, span, n, mid)).collect();
    let guided = std::env::var("GUIDES").is_ok_and(|v| v == "1");
    // The guides: albedo (3 channels), normal (3) and depth (1) as half
    // floats, and each guide's factor per pixel.
    let halves: Vec<Plane<half::f16>> = (0..7)
        .map(|c| {
            let p = plane(rows + dy, span, 20 + c, 0.0);
            Plane { data: p.data.iter().map(|&x| half::f16::from_f32(x)).collect(), width: span, off: p.off }
        })
        .collect();
    let inv: Vec<Plane<f32>> = (0..3).map(|g| plane(rows + dy, span, 30 + g, -2.0)).collect();
    let mut tf: Vec<Vec<f32>> = (0..2 * G).map(|_| vec![0f32; mid]).collect();
    let (mut d, mut m) = (vec![0f32; outer + G], vec![0f32; outer + G]);
    let mut wt = vec![0f32; mid];
    // A lane's factors at the frame's side: a window clipped to 4-6 of its
    // 7 columns in the first and last `F` samples, exactly 1 elsewhere.
    let fac: Vec<f32> = (0..n).map(|x| CAP as f32 / (F + 1 + x.min(n - 1 - x).min(F)) as f32).collect();
    let consts = (1.0f32, 1e-10f32 / 1024.0, 0.2f32 / 1024.0);
    let mut jobs = jobs;
    let mut step = |y: usize| {
        let slot = y % CAP;
        let row = |class: &str| if fixed(class) { 0 } else { y };
        let (y, yg, ya, yv) = (row("in"), row("guides"), row("acc"), row("val"));
        let (yq, ygq) = (y + dy, yg + dy);
        // 1. Every job's distances and their pushes, pair by pair.
        for job in jobs.iter_mut() {
            let (u, v) = (&job.u, &job.v);
            for g in 0..G {
                if on('d') {
                    let up = [&u[0][y][..], &u[1][y][..], &u[2][y][..]];
                    let uq = [&u[0][yq][g + 1..], &u[1][yq][g + 1..], &u[2][yq][g + 1..]];
                    let vp = [&v[0][y][..], &v[1][y][..], &v[2][y][..]];
                    let vq = [&v[0][yq][g + 1..], &v[1][yq][g + 1..], &v[2][yq][g + 1..]];
                    let w = outer + g + 1;
                    if dist_mode > 0 {
                        dist_variant(dist_mode, &mut d[..w], &mut m[..w], up, uq, vp, vq, consts);
                    } else if alpha_fma {
                        kernels::colour_distance_pair_rgb::<16, false>(
                            &mut d[..w],
                            &mut m[..w],
                            up,
                            uq,
                            vp,
                            vq,
                            consts,
                        );
                    } else {
                        kernels::colour_distance_pair_rgb::<16, true>(&mut d[..w], &mut m[..w], up, uq, vp, vq, consts);
                    }
                }
                if on('p') {
                    for (side, row) in [(0, &d[..mid + 2 * F]), (1, &m[g + 1..g + 1 + mid + 2 * F])] {
                        let b = &mut job.h1[side * G + g];
                        // SAFETY: avx512f (this function's target feature).
                        unsafe { kernels::taps_push_avx512::<F, true, 2>(row, &mut b.ring[slot], &mut b.run, 1e9) };
                    }
                }
            }
        }
        // 2. The guides' weight argument of every lane, once for every job.
        if guided && on('g') {
            let fp: Vec<GuideRow> = halves.iter().map(|h| GuideRow::Half(&h[yg][..])).collect();
            for g in 0..G {
                let fq: Vec<GuideRow> = halves.iter().map(|h| GuideRow::Half(&h[ygq][g + 1..])).collect();
                let (fwd, mir) = tf.split_at_mut(G);
                let lanes = [
                    Some(ProductLane {
                        from: 0,
                        out: &mut fwd[g][..],
                        inv: [&inv[0][yg][..], &inv[1][yg][..], &inv[2][yg][..], &inv[0][yg][..]],
                    }),
                    Some(ProductLane {
                        from: g + 1,
                        out: &mut mir[g][..],
                        inv: [&inv[0][ygq][g + 1..], &inv[1][ygq][g + 1..], &inv[2][ygq][g + 1..], &inv[0][ygq][..]],
                    }),
                ];
                // SAFETY: avx512f.
                unsafe { kernels::guide_pair_products_avx512(mid + G, (&fp, &fq), &[3, 6, 7], lanes) };
            }
        }
        // Each job's weights and their pushes, then its accumulation.
        for job in jobs.iter_mut().rev() {
            for lane in (0..2 * G).rev() {
                if on('w') {
                    // SAFETY: avx512f.
                    unsafe {
                        if guided {
                            kernels::weights_avx512::<true>(&job.h1[lane].run, &tf[lane], &mut wt, -1e-3, 20)
                        } else {
                            kernels::weights_avx512::<false>(&job.h1[lane].run, &[], &mut wt, -1e-3, 20)
                        }
                    };
                }
                if on('q') {
                    let b = &mut job.h2[lane];
                    // SAFETY: avx512f.
                    unsafe { kernels::taps_push_avx512::<F, false, 2>(&wt, &mut b.ring[slot], &mut b.run, 0.0) };
                }
            }
            let Job { u, h2, num, .. } = job;
            // The forward side's pixels `p` in row `ya` take the values at
            // `p + n`, the mirror side's pixels `p + n` (row `ya + dy`)
            // those at `p`; both add into the job's accumulators.
            let vals = |side: usize| {
                let y = if side == 0 { yv + dy } else { yv };
                [&u[0][y][1..], &u[1][y][1..], &u[2][y][1..]]
            };
            let ya = |side: usize| if side == 0 { ya } else { ya + dy };
            if on('a') || on('A') {
                // Every vector but the first and last reads its sums as they are.
                let scale = kernels::SideFactors { fac: [&fac[..]; G], whole: (1, (n / 16).saturating_sub(1)) };
                for side in 0..2 {
                    let w: [&[i32]; G] = std::array::from_fn(|g| &h2[side * G + g].run[..]);
                    let [d, n0, n1, n2] = &mut num[..] else { unreachable!() };
                    let y = ya(side);
                    let acc = [&mut d[y], &mut n0[y], &mut n1[y], &mut n2[y]];
                    // SAFETY: avx512f and fma (this function's target features).
                    unsafe {
                        if on('A') {
                            kernels::fused_rgb_shifted_avx512::<G, false, true, _>(acc, w, vals(side), scale)
                        } else {
                            let none = kernels::SideFactors::NONE;
                            kernels::fused_rgb_shifted_avx512::<G, false, false, _>(acc, w, vals(side), none)
                        }
                    };
                }
            }
        }
    };
    for y in 0..rows {
        step(y);
    }
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t = Instant::now();
        for _ in 0..reps {
            for y in 0..rows {
                step(black_box(y));
            }
        }
        best = best.min(t.elapsed().as_secs_f64());
    }
    black_box(&jobs);
    // Pixel-offsets: every row's fourteen lanes of `n` pixels.
    best * 1e9 / (reps * rows * 2 * G * n) as f64
}

/// Probe variants of the colour distance's loop (`DIST`; with `alpha` 1,
/// the kernel's default): 1 the kernel's arithmetic in intrinsics, 2 its
/// divisions replaced by multiplies, 3 by `vrcp14ps`, 4 the variances not
/// loaded (each derived from its value by an add), 5 channel 0's rows
/// loaded for all three channels. 2-5 are bounds (wrong results): what the
/// loop waits on (docs/performance.md, session 50). Whole vectors only:
/// the last `n % 16` samples of `fwd` and `mir` are left as they were.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma,avx2,f16c")]
#[allow(clippy::too_many_arguments)]
fn dist_variant(
    mode: usize,
    fwd: &mut [f32],
    mir: &mut [f32],
    up: [&[f32]; 3],
    uq: [&[f32]; 3],
    vp: [&[f32]; 3],
    vq: [&[f32]; 3],
    (_alpha, eps, k2): (f32, f32, f32),
) {
    use std::arch::x86_64::*;
    let n = fwd.len();
    assert!(mir.len() >= n && [up, uq, vp, vq].iter().flatten().all(|r| r.len() >= n), "rows of n samples");
    let (k2v, epsv) = (_mm512_set1_ps(k2), _mm512_set1_ps(eps));
    let one = _mm512_set1_ps(1.0);
    let mut i = 0;
    while i + 16 <= n {
        let (mut a, mut b) = (_mm512_setzero_ps(), _mm512_setzero_ps());
        for c in 0..3 {
            // SAFETY: `i + 16 <= n`, and every row holds `n` samples (asserted).
            unsafe {
                let cc = if mode == 5 { 0 } else { c };
                let pu = _mm512_loadu_ps(up[cc].as_ptr().add(i));
                let qu = _mm512_loadu_ps(uq[cc].as_ptr().add(i));
                let (pv, qv) = if mode == 4 {
                    (_mm512_add_ps(pu, one), _mm512_add_ps(qu, one))
                } else {
                    (_mm512_loadu_ps(vp[cc].as_ptr().add(i)), _mm512_loadu_ps(vq[cc].as_ptr().add(i)))
                };
                let d = _mm512_sub_ps(pu, qu);
                let d2 = _mm512_mul_ps(d, d);
                let m = _mm512_min_ps(qv, pv);
                let den = _mm512_fmadd_ps(k2v, _mm512_add_ps(pv, qv), epsv);
                let r = match mode {
                    2 => _mm512_mul_ps(den, den),
                    3 => _mm512_rcp14_ps(den),
                    _ => _mm512_div_ps(one, den),
                };
                let e = _mm512_sub_ps(d2, m);
                a = _mm512_fmadd_ps(_mm512_sub_ps(e, pv), r, a);
                b = _mm512_fmadd_ps(_mm512_sub_ps(e, qv), r, b);
            }
        }
        // SAFETY: as the loads.
        unsafe {
            _mm512_storeu_ps(fwd.as_mut_ptr().add(i), a);
            _mm512_storeu_ps(mir.as_mut_ptr().add(i), b);
        }
        i += 16;
    }
}
