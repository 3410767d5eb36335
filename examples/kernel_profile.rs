//! Runs the NL-means kernel alone for profiling (`perf record`):
//! `cargo run --release --example kernel_profile -- [colour|joint] [iterations]`.

use nldenoise::filter::{self, Buffer, Feature, FrameInputs, Params, VarianceSource};
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

fn main() {
    let mode = std::env::args().nth(1).unwrap_or_else(|| "colour".into());
    let iters: usize = std::env::args().nth(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let frame = Rect::from_origin_size(0, 0, 320, 180);
    let params = Params::default();
    let inputs = if mode == "joint" {
        FrameInputs {
            colour: buffer(frame, "beauty", 1),
            features: vec![
                Feature {
                    name: "albedo".into(),
                    values: (0..3).map(|c| plane(frame, 10 + c)).collect(),
                    variance: None,
                },
                Feature { name: "N".into(), values: (0..3).map(|c| plane(frame, 20 + c)).collect(), variance: None },
            ],
            layers: vec![buffer(frame, "direct", 30), buffer(frame, "indirect", 40)],
        }
    } else {
        FrameInputs { colour: buffer(frame, "beauty", 1), features: vec![], layers: vec![] }
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let offsets = (2 * params.search_radius + 1).pow(2) as f64;
    for _ in 0..iters {
        let t = std::time::Instant::now();
        let out = pool.install(|| filter::denoise_region(&inputs, frame, frame, &params).unwrap());
        let s = t.elapsed().as_secs_f64();
        println!(
            "{mode}: {:.1} ms, {:.2} ns per pixel-offset, checksum {}",
            s * 1e3,
            s * 1e9 / (frame.area() as f64 * offsets),
            out.colour[0].data().iter().map(|v| *v as f64).sum::<f64>()
        );
    }
}
