//! Write a large synthetic noisy frame in bounded memory, band by band, from
//! the procedural source through the streaming EXR sink.
//!
//! `cargo run --release --example make_big_frame -- WIDTH HEIGHT OUT.exr [--features] [--layers] [--compression none|rle|zips|zip|piz]`
//!
//! Channels: `R,G,B`, half buffers `A.*`/`B.*` (f16), `var.*` (f32), and with
//! `--features` also `albedo.*`, `N.*` (f16) and `Z` (f32); with `--layers`,
//! `direct.*`, `indirect.*` (f16) and their variances `var.direct.*`, `var.indirect.*` (f32).

use std::path::PathBuf;

use nldenoise::engine::synthetic::{Synthetic, SyntheticSource};
use nldenoise::engine::{RowSink, RowSource};
use nldenoise::exrio::stream::{ExrSink, SinkChannel};
use nldenoise::exrio::{OutputCompression, SampleKind};
use nldenoise::geom::Rect;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!("usage: make_big_frame WIDTH HEIGHT OUT.exr [--features] [--layers] [--compression NAME]");
        std::process::exit(2);
    }
    let (Ok(width), Ok(height)) = (args[0].parse::<usize>(), args[1].parse::<usize>()) else {
        eprintln!("WIDTH and HEIGHT must be whole numbers");
        std::process::exit(2);
    };
    let out = PathBuf::from(&args[2]);
    let compression =
        match args.iter().position(|a| a == "--compression").and_then(|i| args.get(i + 1)).map(String::as_str) {
            Some("none") => OutputCompression::None,
            Some("rle") => OutputCompression::Rle,
            Some("zips") => OutputCompression::Zips,
            Some("piz") => OutputCompression::Piz,
            _ => OutputCompression::Zip,
        };
    let frame = Rect::from_origin_size(0, 0, width, height);
    let mut source = SyntheticSource::new(Synthetic {
        frame,
        features: args.iter().any(|a| a == "--features"),
        layers: args.iter().any(|a| a == "--layers"),
        sigma: 0.05,
    });
    let channels: Vec<SinkChannel> = source
        .channel_names()
        .into_iter()
        .zip(source.is_half())
        .map(|(name, half)| SinkChannel { name, kind: if half { SampleKind::F16 } else { SampleKind::F32 } })
        .collect();
    let all: Vec<usize> = (0..channels.len()).collect();
    let result = ExrSink::create(&out, frame, &channels, (compression, nldenoise::exrio::zip::OPENEXR_LEVEL), None, 0)
        .and_then(|mut sink| {
            for band in frame.row_bands(64) {
                sink.write_rows(source.read_rows(&all, band)?)?;
            }
            sink.finish()
        });
    match result {
        Ok(()) => eprintln!("wrote {} ({width}x{height}, {} channels)", out.display(), channels.len()),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
