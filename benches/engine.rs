//! End-to-end frame times from memory through the streaming engine (its
//! default plan, as `nldenoise denoise` runs: tiles of up to 512 pixels, or
//! wide ones where `engine::budget::wide_tiles` plans them; halo
//! recomputation included; no file I/O): 1080p, colour-only and the
//! full default filter (albedo, normal and depth features, direct and
//! indirect light layers), r = 10, f = 3, on 1 and 2 threads; and the
//! whole-frame path for comparison. 4K runs are opt-in (each sample takes up
//! to a minute): `NLDENOISE_BENCH_4K=1 cargo bench --bench engine`.
//!
//! `examples/timing.rs` measures the same thing as one CSV line per run, for
//! the plots in docs/performance.md (`bash benches/scaling.sh`).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nldenoise::api;
use nldenoise::engine::synthetic::Synthetic;
use nldenoise::engine::{StreamOptions, denoise_stream};
use nldenoise::exrio::Frame;
use nldenoise::exrio::roles::{self, RoleOptions, Selection};
use nldenoise::exrio::stream::{FrameSource, NullSink};
use nldenoise::filter::Params;
use nldenoise::geom::Rect;

fn options(full: bool) -> RoleOptions {
    if full {
        RoleOptions { layers: Selection::Auto, ..RoleOptions::default() }
    } else {
        RoleOptions { features: Selection::None, ..RoleOptions::default() }
    }
}

fn frame(w: usize, h: usize, full: bool) -> Frame {
    Synthetic { frame: Rect::from_origin_size(0, 0, w, h), features: full, layers: full, sigma: 0.05 }.to_frame()
}

fn bench(c: &mut Criterion) {
    let params = Params::default();
    let offsets = ((2 * params.search_radius + 1) * (2 * params.search_radius + 1)) as u64;
    let mut sizes = vec![("1080p", 1920, 1080)];
    if std::env::var_os("NLDENOISE_BENCH_4K").is_some() {
        sizes.push(("4k", 3840, 2160));
    }
    for (label, w, h) in sizes {
        let mut g = c.benchmark_group(format!("{label}_r10_f3"));
        g.sample_size(10);
        // Elements are pixel-offsets: one search offset applied to one pixel.
        g.throughput(Throughput::Elements((w * h) as u64 * offsets));
        for full in [false, true] {
            let frame = frame(w, h, full);
            let opts = options(full);
            let roles = roles::detect("bench".as_ref(), &frame.channel_names(), &opts).unwrap();
            let mode = if full { "full_default_features_layers" } else { "colour_only" };
            for threads in [1, 2] {
                let stream = StreamOptions { threads, memory_limit: 8 << 30, ..StreamOptions::default() };
                g.bench_function(format!("{mode}_streaming_{threads}thread"), |b| {
                    b.iter(|| {
                        let mut sink = NullSink::default();
                        denoise_stream(&mut FrameSource::new(&frame), &mut sink, &roles, &params, &stream).unwrap();
                        assert_eq!(sink.rows, h);
                    })
                });
            }
            if label == "1080p" {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
                g.bench_function(format!("{mode}_whole_frame_2thread"), |b| {
                    b.iter(|| {
                        let mut f = frame.clone();
                        pool.install(|| api::denoise_frame(&mut f, "bench".as_ref(), &opts, &params, false).unwrap())
                    })
                });
            }
        }
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
