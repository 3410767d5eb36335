//! Every input kept under `fuzz/regressions/` (findings of the fuzzers, and
//! the seed corpus) replayed through both fuzz targets' bodies: no panic.

use std::path::Path;

#[test]
fn fuzz_regressions_and_seeds_replay_without_panic() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let mut files = Vec::new();
    for dir in ["regressions", "corpus/read", "corpus/denoise"] {
        for e in std::fs::read_dir(root.join(dir)).unwrap().flatten() {
            files.push(e.path());
        }
    }
    assert!(files.len() >= 12, "{} inputs", files.len());
    for f in files {
        let data = std::fs::read(&f).unwrap();
        for (target, run) in [("read", nldenoise::fuzzing::read as fn(&[u8])), ("denoise", nldenoise::fuzzing::denoise)]
        {
            let r = std::panic::catch_unwind(|| run(&data));
            assert!(r.is_ok(), "{target} panicked on {}", f.display());
        }
    }
}
