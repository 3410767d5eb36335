//! `nldenoise denoise INPUT -o OUTPUT`.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use nldenoise::api;
use nldenoise::engine::{StreamOptions, budget};
use nldenoise::exrio::{self, OutputCompression, WriteOptions};
use tracing::info;

use super::{ChannelArgs, FilterArgs, thread_pool};

/// Arguments of `denoise`.
#[derive(Args, Debug)]
pub struct DenoiseArgs {
    /// Noisy EXR frame.
    pub input: PathBuf,
    /// Where to write the denoised frame (written atomically).
    #[arg(short, long)]
    pub output: PathBuf,
    #[command(flatten)]
    pub filter: FilterArgs,
    #[command(flatten)]
    pub channels: ChannelArgs,
    /// Worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Write the denoised channels as half floats (other channels keep their type).
    #[arg(long)]
    pub half: bool,
    /// Largest tile size in pixels for the streaming engine (tiles are evened out over the
    /// frame: 1920x1080 gets 480x360); 0 filters the whole frame in memory.
    #[arg(long, default_value_t = 512)]
    pub tile_size: usize,
    /// Memory limit (e.g. 512M, 4G): the streaming engine's budget, or the largest frame read whole
    /// with --tile-size 0; default: half of the available memory.
    #[arg(long, value_parser = budget::parse_size)]
    pub memory_limit: Option<u64>,
    /// Output compression.
    #[arg(long, value_enum, default_value_t = OutputCompression::Zip)]
    pub compression: OutputCompression,
}

pub fn run(a: DenoiseArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    if a.tile_size == 0 {
        whole_frame(&a)?;
    } else {
        let params = a.filter.params()?;
        let opts = StreamOptions {
            tile_size: a.tile_size,
            threads: a.threads,
            memory_limit: a.memory_limit.unwrap_or_else(budget::default_limit_bytes),
            half: a.half,
            ..StreamOptions::default()
        };
        let (report, _) =
            api::denoise_file_streaming(&a.input, &a.output, &a.channels.options(), &params, &opts, a.compression)?;
        for n in &report.roles.notes {
            info!("{}: {n}", a.input.display());
        }
    }
    info!("{} -> {} in {:.2}s", a.input.display(), a.output.display(), t0.elapsed().as_secs_f64());
    if let Some(peak) = budget::peak_rss_bytes() {
        info!("peak resident memory: {:.1} MiB", peak as f64 / 1048576.0);
    }
    Ok(())
}

/// `--tile-size 0`: read the whole frame, filter it in memory, write it.
fn whole_frame(a: &DenoiseArgs) -> anyhow::Result<()> {
    let params = a.filter.params()?;
    let pool = thread_pool(a.threads)?;
    let t0 = Instant::now();
    let limit = a.memory_limit.unwrap_or_else(budget::default_limit_bytes);
    let mut frame = exrio::read_frame_within(&a.input, limit)?;
    let rect = frame.data_window;
    info!(
        "read {} ({}x{}, {} channels) in {:.2}s",
        a.input.display(),
        rect.width(),
        rect.height(),
        frame.channels.len(),
        t0.elapsed().as_secs_f64()
    );
    let t1 = Instant::now();
    let report = pool.install(|| api::denoise_frame(&mut frame, &a.input, &a.channels.options(), &params, a.half))?;
    for n in &report.roles.notes {
        info!("{}: {n}", a.input.display());
    }
    info!(
        "filtered in {:.2}s on {} threads (halo {} px, {} features, {} layers)",
        t1.elapsed().as_secs_f64(),
        pool.current_num_threads(),
        report.halo,
        report.roles.features.len(),
        report.roles.layers.len()
    );
    info!("{} pixels had NaN, infinite or out-of-range inputs and were repaired", report.repaired);
    let t2 = Instant::now();
    exrio::write_frame(&a.output, &frame, &WriteOptions { compression: a.compression, ..Default::default() })?;
    info!("wrote {} in {:.2}s", a.output.display(), t2.elapsed().as_secs_f64());
    Ok(())
}
