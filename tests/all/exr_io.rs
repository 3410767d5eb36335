//! EXR round trips: f16/f32, scanline/tiled, both line orders, non-zero
//! data-window origin; the output keeps every channel.

use nldenoise::exrio::{self, Channel, Frame, OutputCompression, SampleKind, WriteOptions};
use nldenoise::geom::Rect;

use crate::common::Rng;

fn sample_frame(dw: Rect) -> Frame {
    let mut rng = Rng::new(5);
    let n = dw.area();
    let vals = |rng: &mut Rng| (0..n).map(|_| rng.uniform() * 4.0 - 1.0).collect::<Vec<f32>>();
    let mut channels = vec![
        Channel::from_f32_as_half("R", &vals(&mut rng)),
        Channel::from_f32_as_half("G", &vals(&mut rng)),
        Channel::from_f32("B", vals(&mut rng)),
        Channel::from_f32("var.R", vals(&mut rng)),
    ];
    channels.sort_by(|a, b| a.name.cmp(&b.name));
    Frame::new(dw, channels)
}

#[test]
fn round_trip_every_layout() {
    let dir = tempfile::tempdir().unwrap();
    for dw in [Rect::from_origin_size(0, 0, 37, 21), Rect::from_origin_size(-13, 40, 20, 33)] {
        let frame = sample_frame(dw);
        for (tiles, decreasing, compression) in [
            (None, false, OutputCompression::Zip),
            (None, true, OutputCompression::Piz),
            (Some((16, 8)), false, OutputCompression::Zips),
            (Some((8, 8)), true, OutputCompression::None),
            (None, false, OutputCompression::Rle),
        ] {
            let path = dir.path().join("rt.exr");
            exrio::write_frame(&path, &frame, &WriteOptions { compression, tiles, decreasing }).unwrap();
            let back = exrio::read_frame(&path).unwrap();
            assert_eq!(back.data_window, dw);
            assert_eq!(back.channel_names(), frame.channel_names());
            for (a, b) in frame.channels.iter().zip(&back.channels) {
                assert_eq!(a.kind, b.kind, "{}", a.name);
                let (va, vb) = (a.to_f32(), b.to_f32());
                assert!(
                    va.iter().zip(&vb).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "{} differs ({tiles:?}, {decreasing})",
                    a.name
                );
            }
            let layout = back.layout.unwrap();
            assert_eq!(layout.blocks.starts_with("tiled"), tiles.is_some());
        }
    }
}

#[test]
fn f16_and_f32_kinds_are_reported() {
    let frame = sample_frame(Rect::from_origin_size(0, 0, 4, 4));
    assert_eq!(frame.channel("R").unwrap().kind, SampleKind::F16);
    assert_eq!(frame.channel("B").unwrap().kind, SampleKind::F32);
}

#[test]
fn unreadable_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("garbage.exr");
    std::fs::write(&bad, b"this is not an EXR file at all").unwrap();
    let e = exrio::read_frame(&bad).unwrap_err().to_string();
    assert!(e.contains("garbage.exr"), "{e}");
    let missing = dir.path().join("missing.exr");
    let e = exrio::read_frame(&missing).unwrap_err().to_string();
    assert!(e.contains("missing.exr"), "{e}");
    // A truncated file.
    let good = dir.path().join("good.exr");
    exrio::write_frame(&good, &sample_frame(Rect::from_origin_size(0, 0, 30, 30)), &WriteOptions::default()).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let cut = dir.path().join("cut.exr");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let e = exrio::read_frame(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.exr"), "{e}");
}

#[test]
fn failed_write_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("no_such_dir").join("out.exr");
    let e = exrio::write_frame(&target, &sample_frame(Rect::from_origin_size(0, 0, 4, 4)), &WriteOptions::default())
        .unwrap_err();
    assert!(e.to_string().contains("out.exr"), "{e}");
    assert!(!target.exists());
}
