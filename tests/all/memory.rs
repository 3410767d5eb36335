//! Bounded memory: a frame whose decoded channels are more than 8x the memory
//! limit is denoised within the limit, measured on the process's own peak
//! resident set (Linux `VmHWM`, printed by `nldenoise -v`).

use assert_cmd::Command;
use nldenoise::engine::synthetic::{Synthetic, SyntheticSource};
use nldenoise::engine::{RowSink, RowSource};
use nldenoise::exrio::stream::{ExrSink, SinkChannel};
use nldenoise::exrio::{OutputCompression, SampleKind};
use nldenoise::geom::Rect;

#[test]
fn frame_eight_times_the_limit_stays_within_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("big.exr");
    let frame = Rect::from_origin_size(0, 0, 1024, 8192);
    let mut source = SyntheticSource::new(Synthetic { frame, features: false, layers: false, sigma: 0.05 });
    let names = source.channel_names();
    let channels: Vec<SinkChannel> = names
        .iter()
        .zip(source.is_half())
        .map(|(n, h)| SinkChannel { name: n.clone(), kind: if h { SampleKind::F16 } else { SampleKind::F32 } })
        .collect();
    let all: Vec<usize> = (0..names.len()).collect();
    let mut sink = ExrSink::create(&input, frame, &channels, (OutputCompression::None, 1), None, 0).unwrap();
    for band in frame.row_bands(256) {
        sink.write_rows(source.read_rows(&all, band).unwrap()).unwrap();
    }
    sink.finish().unwrap();

    let limit_mib = 32u64;
    let decoded_bytes = frame.area() as u64 * names.len() as u64 * 4;
    assert!(decoded_bytes >= 8 * (limit_mib << 20), "the frame must be at least 8x the limit");

    let out = dir.path().join("out.exr");
    let assert = Command::cargo_bin("nldenoise")
        .unwrap()
        .args(["-v", "denoise"])
        .arg(&input)
        .arg("-o")
        .arg(&out)
        .args([
            "--memory-limit",
            &format!("{limit_mib}M"),
            "--search-radius",
            "2",
            "--patch-radius",
            "1",
            "--compression",
            "none",
        ])
        .env_remove("RUST_LOG")
        .assert()
        .success();
    let log = String::from_utf8(assert.get_output().stderr.clone()).unwrap();
    let peak_mib: f64 = log
        .lines()
        .find_map(|l| l.split("peak resident memory: ").nth(1))
        .and_then(|s| s.trim_end_matches(" MiB").trim().parse().ok())
        .unwrap_or_else(|| panic!("no peak memory line in:\n{log}"));
    assert!(peak_mib < limit_mib as f64, "peak {peak_mib} MiB over the {limit_mib} MiB limit\n{log}");
    assert!(peak_mib > 1.0, "implausible peak {peak_mib} MiB");
    let meta = std::fs::metadata(&out).unwrap();
    assert!(meta.len() > decoded_bytes / 4, "output looks incomplete: {} bytes", meta.len());
}
