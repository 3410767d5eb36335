//! One integration-test binary; each module covers one surface.

mod cli;
mod common;
mod exr_io;
mod filter_math;
mod malformed;
mod memory;
mod nonfinite;
mod reference;
mod simd;
mod streaming;
mod tiling;
