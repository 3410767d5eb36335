//! Filter throughput in pixel-offsets per second (one search offset applied to
//! one pixel): colour-only and joint (features + layers), r = 10, f = 3, on a
//! synthetic 320x180 frame, on one thread, for every instruction-set tier this
//! CPU has (`filter::simd`). Run with `cargo bench --bench filter`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nldenoise::filter::{self, Buffer, Feature, FrameInputs, Params, VarianceSource, simd};
use nldenoise::geom::Rect;
use nldenoise::image::Plane;

fn plane(frame: Rect, seed: u32) -> Plane {
    let mut s = seed.wrapping_mul(2_654_435_761).max(1);
    Plane::from_fn(frame, |x, y| {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        let base = if (x / 17 + y / 11) % 2 == 0 { 0.3 } else { 0.7 };
        base + (s % 1000) as f32 * 1e-4
    })
}

fn buffer(frame: Rect, name: &str, seed: u32) -> Buffer {
    Buffer {
        name: name.into(),
        values: (0..3).map(|c| plane(frame, seed + c)).collect(),
        variance: VarianceSource::Sample((0..3).map(|_| Plane::filled(frame, 0.003)).collect()),
    }
}

fn bench(c: &mut Criterion) {
    let frame = Rect::from_origin_size(0, 0, 320, 180);
    let params = Params::default();
    let offsets = (2 * params.search_radius + 1).pow(2) as u64;
    let colour = FrameInputs { colour: buffer(frame, "beauty", 1), features: vec![], layers: vec![] };
    let joint = FrameInputs {
        colour: buffer(frame, "beauty", 1),
        features: vec![
            Feature { name: "albedo".into(), values: (0..3).map(|c| plane(frame, 10 + c)).collect(), variance: None },
            Feature { name: "N".into(), values: (0..3).map(|c| plane(frame, 20 + c)).collect(), variance: None },
        ],
        layers: vec![buffer(frame, "direct", 30), buffer(frame, "indirect", 40)],
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let mut g = c.benchmark_group("nlmeans_320x180_r10_f3_1thread");
    g.sample_size(10);
    g.throughput(Throughput::Elements(frame.area() as u64 * offsets));
    for tier in simd::Tier::ALL.into_iter().filter(|t| t.available()) {
        simd::force(Some(tier));
        g.bench_function(format!("colour_only_{tier:?}"), |b| {
            b.iter(|| pool.install(|| filter::denoise_region(&colour, frame, frame, &params).unwrap()))
        });
        g.bench_function(format!("joint_features_and_two_layers_{tier:?}"), |b| {
            b.iter(|| pool.install(|| filter::denoise_region(&joint, frame, frame, &params).unwrap()))
        });
    }
    simd::force(None);
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
