//! Malformed files: every truncation point (chunk boundaries and mid-chunk,
//! inside the header), corrupt offset tables, chunks pointing past the end,
//! random bytes, wrong magic and absurd header values. Every case must end in
//! an error naming the file (never a panic), whatever path reads it.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use nldenoise::api;
use nldenoise::engine::StreamOptions;
use nldenoise::exrio::roles::RoleOptions;
use nldenoise::exrio::{self, Channel, Frame, OutputCompression, WriteOptions};
use nldenoise::filter::Params;
use nldenoise::geom::Rect;

use crate::common::Rng;

/// A small valid frame: colour, variance, albedo (so the feature path runs).
fn frame() -> Frame {
    let dw = Rect::from_origin_size(0, 0, 24, 40);
    let mut rng = Rng::new(9);
    let mut ch = Vec::new();
    for name in ["B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "var.B", "var.G", "var.R"] {
        let v: Vec<f32> = (0..dw.area()).map(|_| rng.uniform()).collect();
        ch.push(if name.starts_with("albedo") {
            Channel::from_f32_as_half(name, &v)
        } else {
            Channel::from_f32(name, v)
        });
    }
    Frame::new(dw, ch)
}

pub fn valid_file(dir: &Path, name: &str, opts: WriteOptions) -> Vec<u8> {
    let path = dir.join(name);
    exrio::write_frame(&path, &frame(), &opts).unwrap();
    std::fs::read(&path).unwrap()
}

/// Layouts with several chunks each.
pub fn layouts() -> Vec<(&'static str, WriteOptions)> {
    vec![
        ("scan-zip", WriteOptions { compression: OutputCompression::Zip, ..Default::default() }),
        ("scan-none", WriteOptions { compression: OutputCompression::None, ..Default::default() }),
        (
            "tiled-rle-decreasing",
            WriteOptions { compression: OutputCompression::Rle, tiles: Some((16, 16)), decreasing: true },
        ),
        ("scan-piz", WriteOptions { compression: OutputCompression::Piz, ..Default::default() }),
    ]
}

/// The chunk offsets of a valid single-part file, and where its offset table starts.
pub fn offset_table(bytes: &[u8]) -> (usize, Vec<u64>) {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false).unwrap();
    let n = meta.headers[0].chunk_count;
    // The table ends where the first chunk starts (chunks are written in table order or
    // its reverse, so the smallest offset is right after the table).
    let read = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    // Find the table: the position t such that the n u64 values from t are all in
    // range and the smallest equals t + 8n.
    for t in 8..bytes.len() - 8 * n {
        let offs: Vec<u64> = (0..n).map(|i| read(t + 8 * i)).collect();
        if offs.iter().min() == Some(&((t + 8 * n) as u64)) && offs.iter().all(|&o| (o as usize) < bytes.len()) {
            return (t, offs);
        }
    }
    panic!("no offset table found");
}

type Run<'a> = dyn Fn() -> Result<(), nldenoise::Error> + 'a;

/// What happened when a path read the file.
#[derive(Debug)]
pub enum Outcome {
    Ok,
    Err(String),
    Panic(String),
}

fn guarded(f: impl FnOnce() -> Result<(), nldenoise::Error>) -> Outcome {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => Outcome::Ok,
        Ok(Err(e)) => Outcome::Err(e.to_string()),
        Err(p) => Outcome::Panic(
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default(),
        ),
    }
}

/// Run every reading path on `bytes`: header, whole-frame read, streaming denoise.
/// Returns each path's outcome; checks that no output file is left on error.
pub fn run_all(dir: &Path, bytes: &[u8]) -> Vec<(&'static str, Outcome)> {
    let input = dir.join("in.exr");
    let output = dir.join("out.exr");
    std::fs::write(&input, bytes).unwrap();
    let _ = std::fs::remove_file(&output);
    let params = Params { search_radius: 2, patch_radius: 1, ..Params::default() };
    let opts = StreamOptions { tile_size: 16, threads: 2, memory_limit: 64 << 20, ..StreamOptions::default() };
    let roles = RoleOptions::default();
    let mut out = vec![("read_frame", guarded(|| exrio::read_frame(&input).map(|_| ())))];
    let runs: [(&'static str, &Run); 2] = [
        ("denoise_file", &|| {
            api::denoise_file(&input, &output, &roles, &params, false, &WriteOptions::default()).map(|_| ())
        }),
        ("streaming", &|| {
            api::denoise_file_streaming(&input, &output, &roles, &params, &opts, OutputCompression::Zip).map(|_| ())
        }),
    ];
    for (name, run) in runs {
        let _ = std::fs::remove_file(&output);
        let outcome = guarded(run);
        if !matches!(outcome, Outcome::Ok) {
            assert!(!output.exists(), "{name} failed but left an output file");
        }
        out.push((name, outcome));
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    assert_eq!(std::fs::read(&input).unwrap(), bytes, "the input must never be modified");
    out
}

/// Every outcome is either success or an error that names the file.
fn check(case: &str, outcomes: &[(&str, Outcome)], must_fail: bool, failures: &mut Vec<String>) {
    for (path, o) in outcomes {
        match o {
            Outcome::Panic(m) => failures.push(format!("{case}: {path} panicked: {m}")),
            Outcome::Err(m) if !m.contains("in.exr") => {
                failures.push(format!("{case}: {path}: error does not name the file: {m}"))
            }
            Outcome::Ok if must_fail => failures.push(format!("{case}: {path} accepted a broken file")),
            _ => {}
        }
    }
}

#[test]
fn truncation_at_every_chunk_boundary_and_inside_header_and_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let mut cases = 0;
    for (name, opts) in layouts() {
        let bytes = valid_file(dir.path(), "valid.exr", opts);
        let (table, offsets) = offset_table(&bytes);
        let mut cuts: Vec<usize> = (0..table + 8 * offsets.len()).step_by(5).collect();
        for &o in &offsets {
            let o = o as usize;
            cuts.extend([o, o + 1, o + 4, o + 8, o + 20]);
        }
        let mut sorted = offsets.clone();
        sorted.sort();
        for w in sorted.windows(2) {
            cuts.push(((w[0] + w[1]) / 2) as usize);
        }
        cuts.push(bytes.len() - 1);
        cuts.sort();
        cuts.dedup();
        for cut in cuts.into_iter().filter(|&c| c < bytes.len()) {
            cases += 1;
            let out = run_all(dir.path(), &bytes[..cut]);
            check(&format!("{name} cut at {cut}/{}", bytes.len()), &out, true, &mut failures);
        }
    }
    assert!(cases > 200, "{cases} cases");
    assert!(failures.is_empty(), "{} of {cases} cases failed:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn corrupt_offset_tables_and_chunk_headers() {
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for (name, opts) in layouts() {
        let bytes = valid_file(dir.path(), "valid.exr", opts);
        let (table, offsets) = offset_table(&bytes);
        let n = offsets.len();
        let mut variants: Vec<(String, Vec<u8>, bool)> = Vec::new();
        for i in [0, n / 2, n - 1] {
            for (what, v) in [
                ("past the end", bytes.len() as u64 + 1000),
                ("u64::MAX", u64::MAX),
                ("zero", 0),
                ("into the header", 4),
                ("into the table", table as u64),
                ("another chunk", offsets[(i + 1) % n]),
                ("off by one", offsets[i] + 1),
            ] {
                let mut b = bytes.clone();
                b[table + 8 * i..table + 8 * i + 8].copy_from_slice(&v.to_le_bytes());
                variants.push((format!("{name}: offset {i} {what}"), b, false));
            }
            // Chunk headers: y coordinate / tile coordinates, and the data size field.
            let o = offsets[i] as usize;
            for (what, at, v) in [
                ("chunk y huge", 0usize, i32::MAX),
                ("chunk y negative", 0, -77_777),
                ("chunk size huge", if name.starts_with("tiled") { 16 } else { 4 }, i32::MAX),
                ("chunk size negative", if name.starts_with("tiled") { 16 } else { 4 }, -1),
                ("chunk size zero", if name.starts_with("tiled") { 16 } else { 4 }, 0),
            ] {
                let mut b = bytes.clone();
                b[o + at..o + at + 4].copy_from_slice(&v.to_le_bytes());
                variants.push((format!("{name}: chunk {i} {what}"), b, false));
            }
        }
        // Random bytes over each chunk's payload.
        let mut rng = Rng::new(3);
        for &o in &offsets {
            let mut b = bytes.clone();
            let start = o as usize + 8;
            for k in start..(start + 64).min(b.len()) {
                b[k] = rng.next_u64() as u8;
            }
            variants.push((format!("{name}: garbage in chunk at {o}"), b, false));
        }
        for (case, b, must_fail) in variants {
            let out = run_all(dir.path(), &b);
            check(&case, &out, must_fail, &mut failures);
        }
    }
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn random_bytes_wrong_magic_and_empty_files() {
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let valid = valid_file(dir.path(), "valid.exr", WriteOptions::default());
    let mut rng = Rng::new(11);
    let mut cases: Vec<(String, Vec<u8>)> = vec![
        ("empty".into(), Vec::new()),
        ("magic only".into(), valid[..4].to_vec()),
        ("wrong magic".into(), [b"PNG\x0d".as_slice(), &valid[4..]].concat()),
        ("version 3".into(), [&valid[..4], &[3u8, 0, 0, 0][..], &valid[8..]].concat()),
        ("text".into(), b"this is not an EXR file\n".repeat(40)),
    ];
    for len in [1usize, 7, 100, 5000] {
        cases.push((format!("{len} random bytes"), (0..len).map(|_| rng.next_u64() as u8).collect()));
        let mut b: Vec<u8> = valid[..8].to_vec();
        b.extend((0..len).map(|_| rng.next_u64() as u8));
        cases.push((format!("magic + {len} random bytes"), b));
    }
    // Single-byte flips across the header.
    let (table, _) = offset_table(&valid);
    for at in (8..table).step_by(3) {
        let mut b = valid.clone();
        b[at] ^= 0xA5;
        cases.push((format!("header byte {at} flipped"), b));
    }
    for (case, b) in cases {
        let must_fail = case != "header byte flipped";
        let out = run_all(dir.path(), &b);
        check(&case, &out, must_fail && !case.starts_with("header byte"), &mut failures);
    }
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}

/// Replace the value of attribute `name` (its bytes after the size field).
fn patch_attribute(bytes: &[u8], name: &str, f: impl FnOnce(&mut [u8])) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let key: Vec<u8> = [name.as_bytes(), b"\0"].concat();
    let at = b.windows(key.len()).position(|w| w == key.as_slice()).expect("attribute present");
    let type_end = at + key.len() + b[at + key.len()..].iter().position(|&c| c == 0).unwrap() + 1;
    let size = i32::from_le_bytes(b[type_end..type_end + 4].try_into().unwrap()) as usize;
    f(&mut b[type_end + 4..type_end + 4 + size]);
    b
}

fn set_i32s(v: &mut [u8], values: &[i32]) {
    for (i, x) in values.iter().enumerate() {
        v[4 * i..4 * i + 4].copy_from_slice(&x.to_le_bytes());
    }
}

#[test]
fn absurd_header_values_are_refused_before_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let scan = valid_file(dir.path(), "scan.exr", WriteOptions::default());
    let tiled = valid_file(
        dir.path(),
        "tiled.exr",
        WriteOptions { tiles: Some((16, 16)), compression: OutputCompression::None, ..Default::default() },
    );
    let huge = i32::MAX - 1;
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    for (layout, valid) in [("scanline", &scan), ("tiled", &tiled)] {
        for (what, dw) in [
            ("2^31 x 2^31 data window", [0, 0, huge, huge]),
            ("2^31 wide data window", [0, 0, huge, 39]),
            ("2^31 tall data window", [0, 0, 23, huge]),
            ("data window from -2^31 to 2^31", [i32::MIN + 1, i32::MIN + 1, huge, huge]),
            ("inverted data window", [10, 10, 0, 0]),
            ("100k x 100k data window", [0, 0, 99_999, 99_999]),
        ] {
            cases.push((format!("{layout}: {what}"), patch_attribute(valid, "dataWindow", |v| set_i32s(v, &dw))));
        }
        cases.push((format!("{layout}: unknown compression"), patch_attribute(valid, "compression", |v| v[0] = 200)));
        cases.push((format!("{layout}: unknown line order"), patch_attribute(valid, "lineOrder", |v| v[0] = 9)));
        // The first channel: half -> float changes every chunk's expected size.
        cases.push((
            format!("{layout}: channel type changed"),
            patch_attribute(valid, "channels", |v| {
                let t = v.iter().position(|&c| c == 0).unwrap() + 1;
                v[t] = if v[t] == 1 { 2 } else { 1 };
            }),
        ));
        cases.push((
            format!("{layout}: channel type invalid"),
            patch_attribute(valid, "channels", |v| {
                let t = v.iter().position(|&c| c == 0).unwrap() + 1;
                v[t] = 7;
            }),
        ));
        cases.push((
            format!("{layout}: channel subsampled"),
            patch_attribute(valid, "channels", |v| {
                let t = v.iter().position(|&c| c == 0).unwrap() + 1;
                set_i32s(&mut v[t + 8..], &[2, 2]);
            }),
        ));
        cases.push((
            format!("{layout}: channel sampling zero"),
            patch_attribute(valid, "channels", |v| {
                let t = v.iter().position(|&c| c == 0).unwrap() + 1;
                set_i32s(&mut v[t + 8..], &[0, 0]);
            }),
        ));
    }
    for (what, size) in [("zero", [0, 0]), ("2^31", [huge, huge]), ("1x1", [1, 1])] {
        cases.push((format!("tiled: tile size {what}"), patch_attribute(&tiled, "tiles", |v| set_i32s(v, &size))));
    }
    for (case, b) in cases {
        let out = run_all(dir.path(), &b);
        check(&case, &out, true, &mut failures);
        if std::env::var_os("SHOW").is_some() {
            eprintln!("{case}: {out:?}");
        }
        // The refusal names the problem, not just "failed".
        for (path, o) in &out {
            if let Outcome::Err(m) = o
                && m.len() < 30
            {
                failures.push(format!("{case}: {path}: terse error {m}"));
            }
        }
    }
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}
