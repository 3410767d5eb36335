//! One integration-test binary; each module covers one surface.

mod cli;
mod common;
mod exr_io;
mod filter_math;
mod fuzz_regressions;
mod malformed;
mod memory;
mod nonfinite;
mod reference;
mod robustness;
mod simd;
mod streaming;
mod tiling;
