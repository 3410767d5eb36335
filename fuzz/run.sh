#!/usr/bin/env bash
# Run one fuzz target for a while: bash fuzz/run.sh read|denoise [SECONDS]
# Needs the nightly toolchain and cargo-fuzz (installed here if missing).
# New inputs go to target/fuzz-corpus/TARGET (not committed); the seeds in
# fuzz/corpus/TARGET come from `cargo run --example make_fuzz_corpus`.
# Crashes are written to fuzz/artifacts/TARGET: keep them as regression tests
# (tests/all/fuzz_regressions.rs replays every file under fuzz/regressions/).
set -euo pipefail
cd "$(dirname "$0")"
target=${1:?usage: fuzz/run.sh read|denoise [seconds]}
seconds=${2:-600}
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
work=../target/fuzz-corpus/$target
mkdir -p "$work" "artifacts/$target"
extra=()
# The denoise target starts and stops worker threads on every input; their
# thread-exit bookkeeping (__cxa_thread_atexit, 64 bytes) is reported as a
# leak by LeakSanitizer. Our code allocates through Rust only, so leak
# detection is off for that target (it stays on for `read`).
[[ $target == denoise ]] && extra=(-detect_leaks=0)
cargo +nightly fuzz run "$target" -O "$work" "corpus/$target" -- "${extra[@]}" \
    -max_total_time="$seconds" -max_len=65536 -rss_limit_mb=2048 -timeout=20 \
    -artifact_prefix="artifacts/$target/" -print_final_stats=1
