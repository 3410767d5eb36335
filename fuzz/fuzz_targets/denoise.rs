//! Any bytes through the whole denoise (see `nldenoise::fuzzing::denoise`).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| nldenoise::fuzzing::denoise(data));
