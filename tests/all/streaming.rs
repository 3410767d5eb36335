//! The streaming engine equals whole-frame filtering bit for bit, through real
//! EXR files, for every tile size, thread count, input kind, sample type and
//! file layout; and it stays within its memory limit.

use std::path::Path;

use nldenoise::api;
use nldenoise::engine::StreamOptions;
use nldenoise::exrio::roles::{RoleOptions, Selection, VarianceChoice};
use nldenoise::exrio::{self, Channel, Frame, OutputCompression, WriteOptions};
use nldenoise::filter::{FrameInputs, Params, VarianceSource};
use nldenoise::geom::Rect;
use nldenoise::image::Plane;
use proptest::prelude::*;

use crate::common::{ALL_KINDS, Kinds, frame_inputs, small_params};

/// Store synthetic inputs under the channel names of production files.
fn to_frame(inputs: &FrameInputs, frame: Rect, half: bool) -> Frame {
    let mut channels = Vec::new();
    let mut put = |name: String, p: &Plane, may_half: bool| {
        channels.push(if half && may_half {
            Channel::from_f32_as_half(name, p.data())
        } else {
            Channel::from_f32(name, p.data().to_vec())
        });
    };
    let rgb = ["R", "G", "B"];
    for (c, p) in rgb.iter().zip(&inputs.colour.values) {
        put(c.to_string(), p, true);
    }
    match &inputs.colour.variance {
        VarianceSource::Sample(v) => rgb.iter().zip(v).for_each(|(c, p)| put(format!("var.{c}"), p, false)),
        VarianceSource::Halves { a, b } => {
            rgb.iter().zip(a).for_each(|(c, p)| put(format!("A.{c}"), p, true));
            rgb.iter().zip(b).for_each(|(c, p)| put(format!("B.{c}"), p, true));
        }
    }
    for f in &inputs.features {
        let leaves: Vec<String> = match f.name.as_str() {
            "albedo" => rgb.iter().map(|l| format!("albedo.{l}")).collect(),
            "N" => ["X", "Y", "Z"].iter().map(|l| format!("N.{l}")).collect(),
            _ => vec![f.name.clone()],
        };
        for (n, p) in leaves.iter().zip(&f.values) {
            put(n.clone(), p, f.name != "Z");
        }
        if let Some(v) = &f.variance {
            for (n, p) in leaves.iter().zip(v) {
                let vn = if f.name == "Z" { "Z_var".to_string() } else { n.replacen('.', "_var.", 1) };
                put(vn, p, false);
            }
        }
    }
    for l in &inputs.layers {
        let VarianceSource::Sample(v) = &l.variance else { unreachable!("layers use sample variance") };
        for ((c, p), pv) in rgb.iter().zip(&l.values).zip(v) {
            put(format!("{}.{c}", l.name), p, true);
            put(format!("var.{}.{c}", l.name), pv, false);
        }
    }
    // A carried channel the filter never reads.
    put("mask.A".into(), &Plane::from_fn(frame, |x, y| ((x * 31 + y * 17) % 7) as f32 * 0.25), true);
    channels.sort_by(|a, b| a.name.cmp(&b.name));
    Frame::new(frame, channels)
}

fn role_options(kinds: Kinds) -> RoleOptions {
    RoleOptions {
        variance: if kinds.halves { VarianceChoice::Halves } else { VarianceChoice::Auto },
        features: if kinds.features { Selection::Auto } else { Selection::None },
        layers: if kinds.layers { Selection::Auto } else { Selection::None },
        maps: vec![],
    }
}

fn channel_bits(path: &Path) -> Vec<(String, Vec<u32>)> {
    let f = exrio::read_frame(path).unwrap();
    f.channels.iter().map(|c| (c.name.clone(), c.to_f32().iter().map(|v| v.to_bits()).collect())).collect()
}

struct Case {
    frame: Rect,
    kinds: Kinds,
    params: Params,
    half: bool,
    layout: WriteOptions,
}

/// Whole-frame output bits, then for every (tile, threads): streaming output bits must match.
fn check(case: &Case, schedules: &[(usize, usize)]) {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.exr");
    let inputs = frame_inputs(case.frame, 99, case.kinds);
    exrio::write_frame(&input, &to_frame(&inputs, case.frame, case.half), &case.layout).unwrap();
    let opts = role_options(case.kinds);
    let whole = dir.path().join("whole.exr");
    api::denoise_file(&input, &whole, &opts, &case.params, false, &WriteOptions::default()).unwrap();
    let want = channel_bits(&whole);
    for &(tile, threads) in schedules {
        let out = dir.path().join(format!("s{tile}_{threads}.exr"));
        let so = StreamOptions { tile_size: tile, threads, memory_limit: 1 << 30, ..StreamOptions::default() };
        api::denoise_file_streaming(&input, &out, &opts, &case.params, &so, OutputCompression::Zip).unwrap();
        let got = channel_bits(&out);
        assert_eq!(got.len(), want.len());
        for ((gn, g), (wn, w)) in got.iter().zip(&want) {
            assert_eq!(gn, wn);
            assert!(
                g == w,
                "channel {gn} differs: tile {tile}, {threads} threads, {:?}, {:?}, half {}, {:?}",
                case.frame,
                case.kinds,
                case.half,
                case.layout
            );
        }
    }
}

const SCHEDULES: &[(usize, usize)] = &[(1, 2), (7, 1), (16, 3), (64, 4), (256, 2), (10_000, 1)];

#[test]
fn streaming_equals_whole_frame_for_every_input_kind() {
    for kinds in ALL_KINDS {
        let case = Case {
            frame: Rect::from_origin_size(-9, 13, 45, 31),
            kinds,
            params: small_params(3, 1),
            half: true,
            layout: WriteOptions::default(),
        };
        check(&case, SCHEDULES);
    }
}

#[test]
fn streaming_equals_whole_frame_for_every_file_layout() {
    let layouts = [
        WriteOptions { compression: OutputCompression::Zip, tiles: None, decreasing: true },
        WriteOptions { compression: OutputCompression::Piz, tiles: Some((16, 8)), decreasing: false },
        WriteOptions { compression: OutputCompression::Rle, tiles: Some((8, 8)), decreasing: true },
        WriteOptions { compression: OutputCompression::None, tiles: None, decreasing: false },
    ];
    for (i, layout) in layouts.into_iter().enumerate() {
        let case = Case {
            frame: Rect::from_origin_size(3, -5, 37, 26),
            kinds: ALL_KINDS[i % 4],
            params: small_params(2, 2),
            half: i % 2 == 0,
            layout,
        };
        check(&case, &[(1, 1), (7, 2), (64, 2)]);
    }
}

#[test]
fn streaming_equals_whole_frame_on_thin_frames_and_default_parameters() {
    for frame in
        [Rect::from_origin_size(0, 0, 1, 37), Rect::from_origin_size(0, 0, 41, 1), Rect::from_origin_size(-2, -2, 3, 2)]
    {
        let case = Case {
            frame,
            kinds: ALL_KINDS[2],
            params: small_params(4, 2),
            half: false,
            layout: WriteOptions::default(),
        };
        check(&case, &[(1, 1), (7, 2), (300, 4)]);
    }
    // The shipped defaults (r=10, f=3, every prefilter) on a frame that is not a multiple of the tiles.
    let case = Case {
        frame: Rect::from_origin_size(0, 0, 70, 45),
        kinds: ALL_KINDS[1],
        params: Params::default(),
        half: true,
        layout: WriteOptions::default(),
    };
    check(&case, &[(16, 2), (64, 2)]);
}

#[test]
fn streaming_with_thin_end_bands_equals_whole_frame() {
    // Bands of 150 rows, which the engine cuts 64, 108, 108, 106, 64: thin
    // first and last bands (`engine::stream_bands`), the rest evened out.
    let case = Case {
        frame: Rect::from_origin_size(-3, 5, 24, 450),
        kinds: ALL_KINDS[3],
        params: small_params(3, 1),
        half: false,
        layout: WriteOptions::default(),
    };
    check(&case, &[(200, 1), (200, 2), (150, 3)]);
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("in.exr"), dir.path().join("out.exr"));
    let inputs = frame_inputs(case.frame, 99, case.kinds);
    exrio::write_frame(&input, &to_frame(&inputs, case.frame, false), &case.layout).unwrap();
    let so = StreamOptions { tile_size: 200, threads: 2, memory_limit: 1 << 30, ..StreamOptions::default() };
    let opts = role_options(case.kinds);
    let (_, stream) =
        api::denoise_file_streaming(&input, &out, &opts, &case.params, &so, OutputCompression::Zip).unwrap();
    assert_eq!((stream.plan.band_rows, stream.bands), (150, 5));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, .. ProptestConfig::default() })]
    #[test]
    fn random_streaming_runs_are_bit_exact(
        w in 1usize..30, h in 1usize..30, x0 in -10i64..10, y0 in -10i64..10,
        tile in 1usize..20, threads in 1usize..5, r in 0usize..4, f in 0usize..3,
        kind in 0usize..4, half in any::<bool>(), tiled in any::<bool>(), decreasing in any::<bool>(),
    ) {
        let layout = WriteOptions { compression: OutputCompression::Zips, tiles: tiled.then_some((8, 4)), decreasing };
        let case = Case { frame: Rect::from_origin_size(x0, y0, w, h), kinds: ALL_KINDS[kind], params: small_params(r, f), half, layout };
        check(&case, &[(tile, threads)]);
    }
}

#[test]
fn a_limit_below_the_minimum_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.exr");
    let frame = Rect::from_origin_size(0, 0, 64, 32);
    exrio::write_frame(&input, &to_frame(&frame_inputs(frame, 1, ALL_KINDS[0]), frame, true), &WriteOptions::default())
        .unwrap();
    let out = dir.path().join("out.exr");
    let so = StreamOptions { tile_size: 64, threads: 1, memory_limit: 1 << 20, ..StreamOptions::default() };
    let e = api::denoise_file_streaming(
        &input,
        &out,
        &role_options(ALL_KINDS[0]),
        &Params::default(),
        &so,
        OutputCompression::Zip,
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("memory limit") && msg.contains("minimum"), "{msg}");
    assert!(!out.exists());
}

/// The streaming sink's own ZIP encoder (one and sixteen scanlines per
/// chunk, compressible and incompressible chunks) writes files that decode
/// to the same bits as the `exr` crate's uncompressed and PIZ output of the
/// same run; the ZIP files are smaller than the uncompressed one.
#[test]
fn zip_chunks_decode_to_the_same_bits() {
    let dir = tempfile::tempdir().unwrap();
    let frame = Rect::from_origin_size(-3, 5, 45, 37);
    let kinds = ALL_KINDS[ALL_KINDS.len() - 1];
    let inputs = frame_inputs(frame, 5, kinds);
    let mut f = to_frame(&inputs, frame, true);
    // A constant channel compresses to almost nothing; the noisy ones barely.
    f.channels.push(Channel::from_f32_as_half("flat", Plane::filled(frame, 0.25).data()));
    let input = dir.path().join("in.exr");
    exrio::write_frame(&input, &f, &WriteOptions::default()).unwrap();
    let (opts, params) = (role_options(kinds), small_params(2, 1));
    let so = StreamOptions { tile_size: 16, threads: 2, memory_limit: 1 << 30, ..StreamOptions::default() };
    let mut outputs = Vec::new();
    for c in [OutputCompression::None, OutputCompression::Piz, OutputCompression::Zips, OutputCompression::Zip] {
        let out = dir.path().join(format!("{c:?}.exr"));
        api::denoise_file_streaming(&input, &out, &opts, &params, &so, c).unwrap();
        outputs.push((c, std::fs::metadata(&out).unwrap().len(), channel_bits(&out)));
    }
    let (_, raw_len, want) = &outputs[0];
    assert!(want.iter().any(|(n, _)| n == "flat"));
    for (c, len, got) in &outputs[1..] {
        assert!(got == want, "{c:?} decodes to different bits");
        if matches!(c, OutputCompression::Zips | OutputCompression::Zip) {
            assert!(len < raw_len, "{c:?}: {len} bytes, uncompressed {raw_len}");
        }
    }
}

/// A file source told which channels a run reads (`select_channels`, as
/// the engine does with `carry` false) decodes those alone, to the bits it
/// reads without the hint, in every file layout; asking it for another is
/// an error naming the file, not a panic or wrong rows.
#[test]
fn a_file_source_decodes_the_selected_channels_alone() {
    use nldenoise::engine::RowSource;
    use nldenoise::exrio::stream::ExrSource;
    let dir = tempfile::tempdir().unwrap();
    let frame = Rect::from_origin_size(2, -4, 37, 29);
    let kinds = ALL_KINDS[ALL_KINDS.len() - 1];
    let f = to_frame(&frame_inputs(frame, 9, kinds), frame, true);
    assert!(f.channels.len() > 4);
    let layouts = [
        WriteOptions { compression: OutputCompression::Zip, tiles: None, decreasing: false },
        WriteOptions { compression: OutputCompression::Piz, tiles: Some((16, 8)), decreasing: false },
        WriteOptions { compression: OutputCompression::None, tiles: Some((8, 8)), decreasing: true },
    ];
    for (i, options) in layouts.iter().enumerate() {
        let path = dir.path().join(format!("in{i}.exr"));
        exrio::write_frame(&path, &f, options).unwrap();
        let selected = [1, 3, f.channels.len() - 1];
        let mut all = ExrSource::open(&path).unwrap();
        let mut some = ExrSource::open(&path).unwrap();
        some.select_channels(&selected);
        // Overlapping windows down the frame, as the engine asks.
        for (y0, y1) in [(-4, 9), (3, 17), (15, 25)] {
            let rows = Rect { y0, y1, ..frame };
            let want = all.read_rows(&selected, rows).unwrap();
            let got = some.read_rows(&selected, rows).unwrap();
            assert!(got == want, "layout {i}, rows {y0}..{y1}");
        }
        let err = some.read_rows(&[0], Rect { y0: 20, y1: 25, ..frame }).unwrap_err().to_string();
        assert!(err.contains(&format!("in{i}.exr")) && err.contains("not selected"), "{err}");
    }
}
