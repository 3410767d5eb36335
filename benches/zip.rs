//! The output's ZIP encoding: libdeflate (what the streaming writer uses,
//! `nldenoise::exrio::zip::encode`) against zlib-rs through `flate2` (what
//! it used before, kept here as the comparison), both at OpenEXR's level 4,
//! and libdeflate at the writer's default level 1 (`zip::DEFAULT_LEVEL`),
//! on the same blocks, in one run: the scanline blocks of a real `denoise`
//! output (a synthetic 960x272 frame with features and light layers,
//! denoised with `--layers auto`: 31 channels, the denoised ones `f32`, as
//! in `benches/opencv_compare.sh`'s file run). The byte preparation is
//! timed on its own too. The compressed sizes are printed before the
//! timings.
//!
//! `cargo bench --bench zip`

use std::io::Write;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nldenoise::api;
use nldenoise::engine::StreamOptions;
use nldenoise::engine::synthetic::Synthetic;
use nldenoise::exrio::roles::{RoleOptions, Selection};
use nldenoise::exrio::zip::{DEFAULT_LEVEL, OPENEXR_LEVEL, encode, prepare};
use nldenoise::exrio::{self, OutputCompression, WriteOptions};
use nldenoise::filter::Params;
use nldenoise::geom::Rect;

/// The uncompressed scanline blocks of a denoised frame.
fn denoised_blocks() -> Vec<Vec<u8>> {
    let dir = tempfile::tempdir().expect("temporary directory");
    let (input, output) = (dir.path().join("in.exr"), dir.path().join("out.exr"));
    let frame = Synthetic { frame: Rect::from_origin_size(0, 0, 960, 272), features: true, layers: true, sigma: 0.05 }
        .to_frame();
    let write = WriteOptions { compression: OutputCompression::Zip, tiles: None, decreasing: false };
    exrio::write_frame(&input, &frame, &write).expect("write the input");
    let roles = RoleOptions { layers: Selection::Auto, ..RoleOptions::default() };
    api::denoise_file_streaming(
        &input,
        &output,
        &roles,
        &Params::default(),
        &StreamOptions::default(),
        OutputCompression::Zip,
    )
    .expect("denoise");
    let file = std::io::BufReader::new(std::fs::File::open(&output).expect("open the output"));
    let reader = exr::block::read(file, false).expect("read the output");
    let meta = reader.meta_data().clone();
    reader
        .all_chunks(false)
        .expect("chunks")
        .map(|c| exr::block::UncompressedBlock::decompress_chunk(c.expect("chunk"), &meta, false).expect("block").data)
        .collect()
}

/// zlib-rs at the same level, on the same prepared bytes.
fn zlib_rs(data: &[u8]) -> Vec<u8> {
    let prepared = prepare(data);
    let mut encoder = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(data.len() / 2),
        flate2::Compression::new(OPENEXR_LEVEL as u32),
    );
    encoder.write_all(&prepared).expect("in memory");
    encoder.finish().expect("in memory")
}

fn bench(c: &mut Criterion) {
    let blocks = denoised_blocks();
    let raw: usize = blocks.iter().map(Vec::len).sum();
    let size = |f: &dyn Fn(&[u8]) -> Vec<u8>| blocks.iter().map(|b| f(b).len()).sum::<usize>();
    let (ours, before) = (size(&|b| encode(b, OPENEXR_LEVEL).expect("encode")), size(&zlib_rs));
    let fast = size(&|b| encode(b, DEFAULT_LEVEL).expect("encode"));
    println!(
        "{} blocks, {raw} bytes: level {OPENEXR_LEVEL}: libdeflate {ours} bytes ({:.4}), zlib-rs {before} bytes \
         ({:.4}); level {DEFAULT_LEVEL}: libdeflate {fast} bytes ({:.4})",
        blocks.len(),
        ours as f64 / raw as f64,
        before as f64 / raw as f64,
        fast as f64 / raw as f64
    );
    let mut g = c.benchmark_group("zip_denoised_960x272");
    g.throughput(Throughput::Bytes(raw as u64));
    g.bench_function("libdeflate", |b| {
        b.iter(|| blocks.iter().map(|d| encode(d, OPENEXR_LEVEL).expect("encode").len()).sum::<usize>())
    });
    g.bench_function("libdeflate_level1", |b| {
        b.iter(|| blocks.iter().map(|d| encode(d, DEFAULT_LEVEL).expect("encode").len()).sum::<usize>())
    });
    g.bench_function("zlib_rs", |b| b.iter(|| blocks.iter().map(|d| zlib_rs(d).len()).sum::<usize>()));
    g.bench_function("preparation_only", |b| b.iter(|| blocks.iter().map(|d| prepare(d).len()).sum::<usize>()));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
