//! Writes the fuzzers' seed corpus: small valid EXR frames in every layout the
//! reader supports, with the channel sets the role detection knows.
//!
//! `cargo run --example make_fuzz_corpus -- fuzz/corpus`

use std::path::PathBuf;

use nldenoise::exrio::{self, Channel, Frame, OutputCompression, WriteOptions};
use nldenoise::geom::Rect;

fn frame(dw: Rect, names: &[&str], half: bool, seed: u32) -> Frame {
    let mut s = seed.wrapping_mul(2_654_435_761);
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut channels: Vec<Channel> = names
        .iter()
        .map(|n| {
            let v: Vec<f32> = (0..dw.area()).map(|_| next()).collect();
            if half { Channel::from_f32_as_half(*n, &v) } else { Channel::from_f32(*n, v) }
        })
        .collect();
    channels.sort_by(|a, b| a.name.cmp(&b.name));
    Frame::new(dw, channels)
}

fn main() {
    let root = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "fuzz/corpus".into()));
    let rgb = ["R", "G", "B"];
    let sample = ["R", "G", "B", "var.R", "var.G", "var.B"];
    let full = ["R", "G", "B", "var.R", "var.G", "var.B", "albedo.R", "albedo.G", "albedo.B", "N.X", "N.Y", "N.Z", "Z"];
    let halves = ["R", "G", "B", "A.R", "A.G", "A.B", "B.R", "B.G", "B.B"];
    let layers = [
        "R",
        "G",
        "B",
        "var.R",
        "var.G",
        "var.B",
        "direct.R",
        "direct.G",
        "direct.B",
        "direct_var.R",
        "direct_var.G",
        "direct_var.B",
        "indirect.R",
        "indirect.G",
        "indirect.B",
        "indirect_var.R",
        "indirect_var.G",
        "indirect_var.B",
    ];
    let cases: Vec<(&str, Rect, &[&str], bool, WriteOptions)> = vec![
        ("rgb_zip", Rect::from_origin_size(0, 0, 8, 6), &rgb, true, WriteOptions::default()),
        (
            "sample_none",
            Rect::from_origin_size(0, 0, 12, 9),
            &sample,
            false,
            WriteOptions { compression: OutputCompression::None, ..Default::default() },
        ),
        (
            "full_rle_tiled",
            Rect::from_origin_size(-3, 5, 13, 11),
            &full,
            true,
            WriteOptions { compression: OutputCompression::Rle, tiles: Some((8, 8)), decreasing: false },
        ),
        (
            "halves_piz_decreasing",
            Rect::from_origin_size(0, 0, 10, 10),
            &halves,
            true,
            WriteOptions { compression: OutputCompression::Piz, tiles: None, decreasing: true },
        ),
        (
            "layers_zips",
            Rect::from_origin_size(2, 2, 9, 7),
            &layers,
            false,
            WriteOptions { compression: OutputCompression::Zips, ..Default::default() },
        ),
        (
            "full_pxr24",
            Rect::from_origin_size(0, 0, 16, 4),
            &full,
            false,
            WriteOptions { compression: OutputCompression::Pxr24, ..Default::default() },
        ),
    ];
    for target in ["read", "denoise"] {
        let dir = root.join(target);
        std::fs::create_dir_all(&dir).expect("create corpus folder");
        for (i, (name, dw, names, half, opts)) in cases.iter().enumerate() {
            let path = dir.join(format!("{name}.exr"));
            exrio::write_frame(&path, &frame(*dw, names, *half, i as u32 + 1), opts).expect("write seed");
        }
    }
    println!("seeds written under {}", root.display());
}
