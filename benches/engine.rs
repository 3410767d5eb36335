//! Streaming engine vs whole-frame filtering on a 1920x1080 frame with
//! colour, half buffers, variance and features (default parameters), both from
//! memory (no file I/O): the cost of tiling. Run with
//! `cargo bench --bench engine`; the halo recomputation factor is printed.

use criterion::{Criterion, criterion_group, criterion_main};
use nldenoise::api;
use nldenoise::engine::synthetic::{Synthetic, SyntheticSource};
use nldenoise::engine::{RowSource, StreamOptions, denoise_stream};
use nldenoise::exrio::roles::{self, RoleOptions};
use nldenoise::exrio::stream::{FrameSource, NullSink};
use nldenoise::exrio::{Channel, Frame};
use nldenoise::filter::Params;
use nldenoise::geom::Rect;

fn frame_1080p() -> Frame {
    let rect = Rect::from_origin_size(0, 0, 1920, 1080);
    let mut src = SyntheticSource::new(Synthetic { frame: rect, features: true, layers: false, sigma: 0.05 });
    let names = src.channel_names();
    let all: Vec<usize> = (0..names.len()).collect();
    let rows = src.read_rows(&all, rect).unwrap();
    let channels = names
        .iter()
        .zip(rows)
        .zip(src.is_half())
        .map(|((n, r), h)| {
            let v = r.samples.to_f32();
            if h { Channel::from_f32_as_half(n.clone(), &v) } else { Channel::from_f32(n.clone(), v) }
        })
        .collect();
    Frame::new(rect, channels)
}

fn bench(c: &mut Criterion) {
    let frame = frame_1080p();
    let params = Params::default();
    let opts = RoleOptions::default();
    let roles = roles::detect("bench".as_ref(), &frame.channel_names(), &opts).unwrap();
    let stream_opts = StreamOptions { memory_limit: 4 << 30, ..StreamOptions::default() };
    let mut g = c.benchmark_group("1080p_default_filter");
    g.sample_size(10);
    g.bench_function("whole_frame", |b| {
        b.iter(|| {
            let mut f = frame.clone();
            api::denoise_frame(&mut f, "bench".as_ref(), &opts, &params, false).unwrap()
        })
    });
    g.bench_function("streaming_tile_256", |b| {
        b.iter(|| {
            let mut sink = NullSink::default();
            let report =
                denoise_stream(&mut FrameSource::new(&frame), &mut sink, &roles, &params, &stream_opts).unwrap();
            assert_eq!(sink.rows, 1080);
            report.halo_overhead
        })
    });
    g.finish();
    let mut sink = NullSink::default();
    let report = denoise_stream(&mut FrameSource::new(&frame), &mut sink, &roles, &params, &stream_opts).unwrap();
    println!(
        "halo recomputation: the tiles filter {:.3}x the frame's pixels (halo {} px, {} tiles)",
        report.halo_overhead, report.halo, report.tiles
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
