//! Any bytes through both EXR reading paths (see `nldenoise::fuzzing::read`).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| nldenoise::fuzzing::read(data));
