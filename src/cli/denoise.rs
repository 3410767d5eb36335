//! `nldenoise denoise INPUT... -o OUTPUT`: one frame, or a batch of frames
//! (a frame sequence `shot.####.exr`, or several files into a folder).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::bail;
use clap::Args;
use nldenoise::api;
use nldenoise::engine::{StreamOptions, budget};
use nldenoise::exrio::{self, OutputCompression};
use nldenoise::sequence;
use tracing::{error, info};

use super::{ChannelArgs, FilterArgs, thread_pool};

/// Arguments of `denoise`.
#[derive(Args, Debug)]
pub struct DenoiseArgs {
    /// Noisy EXR frame; or a frame sequence, `shot.####.exr` or `shot.%04d.exr` (every frame
    /// present, or those of --frames); or several frames (with -o a folder).
    #[arg(required = true, num_args = 1.., value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Where to write the denoised frame (written atomically): a file; for a sequence a frame
    /// pattern (`den.####.exr`) or an existing folder; for several inputs an existing folder
    /// (each frame under its input's file name).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Frames of a sequence input: `1001-1100`, `1001-1100x2` (every 2nd), `1001,1050`, or a mix;
    /// default: every frame whose file matches the pattern.
    #[arg(long, value_name = "LIST")]
    pub frames: Option<String>,
    /// Leave frames whose output file already exists (resume an interrupted batch).
    #[arg(long)]
    pub skip_existing: bool,
    /// Go on with the next frames when a frame fails (the run still exits with 1, listing the
    /// failed frames); by default a batch stops at its first failed frame.
    #[arg(long)]
    pub keep_going: bool,
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
    /// Write the denoised channels alone (the beauty, and the light layers with --layers);
    /// by default every input channel is carried through unchanged. Smaller files, faster
    /// runs: a 31-channel 1080p frame with the default filter took 0.38x the bytes and
    /// 0.79x the time
    #[arg(long)]
    pub denoised_only: bool,
    /// Largest tile size in pixels for the streaming engine (tiles are evened out over the
    /// frame: 1920x1080 gets 480x360); tiles may be twice as wide where every thread still
    /// gets one per band (1080p on two threads: 960x360); 0 filters the whole frame in memory.
    #[arg(long, default_value_t = 512)]
    pub tile_size: usize,
    /// Memory limit (e.g. 512M, 4G): the streaming engine's budget, or the largest frame read whole
    /// with --tile-size 0; default: half of the available memory.
    #[arg(long, value_parser = budget::parse_size)]
    pub memory_limit: Option<u64>,
    /// Output compression.
    #[arg(long, value_enum, default_value_t = OutputCompression::Zip)]
    pub compression: OutputCompression,
    /// ZIP and ZIPS compression level, 1 (fastest) to 12 (smallest files); OpenEXR's own
    /// default is 4. Denoised 32-bit channels hardly compress: on a 1080p frame with 31
    /// channels, level 4 wrote 0.7 % fewer bytes than level 1 in about 5 % more time.
    #[arg(long, default_value_t = exrio::zip::DEFAULT_LEVEL, value_parser = zip_levels())]
    pub zip_level: i32,
}

/// `--zip-level`'s parser: the levels of [`exrio::zip::LEVELS`] (clap's
/// ranges take `i64` bounds).
fn zip_levels() -> clap::builder::RangedI64ValueParser<i32> {
    let levels = exrio::zip::LEVELS;
    clap::value_parser!(i32).range(i64::from(*levels.start())..=i64::from(*levels.end()))
}

pub fn run(a: DenoiseArgs) -> anyhow::Result<()> {
    // Every argument is checked before the first frame is read.
    let params = a.filter.params()?;
    let jobs = sequence::plan(&a.inputs, &a.output, a.frames.as_deref())?;
    let batch = jobs.len() > 1 || jobs[0].frame.is_some();
    if batch {
        run_batch(&a, &params, &jobs)?;
    } else {
        run_job(&a, &params, &jobs[0], "")?;
    }
    if let Some(peak) = budget::peak_rss_bytes() {
        info!("peak resident memory: {:.1} MiB", peak as f64 / 1048576.0);
    }
    Ok(())
}

/// The frames one after the other (each uses every thread), stopping at the
/// first failure unless `--keep-going`; any failure fails the run.
fn run_batch(a: &DenoiseArgs, params: &nldenoise::filter::Params, jobs: &[sequence::Job]) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let n = jobs.len();
    let (mut done, mut skipped, mut failed) = (0, 0, Vec::new());
    for (i, job) in jobs.iter().enumerate() {
        let at = format!("[{}/{n}] ", i + 1);
        match run_job(a, params, job, &at) {
            Ok(true) => done += 1,
            Ok(false) => skipped += 1,
            Err(e) if a.keep_going => {
                error!("{at}{}", super::report(&e));
                failed.push(job.input.display().to_string());
            }
            Err(e) => bail!(
                "{}\n  the batch stopped at frame {} of {n} ({done} denoised before it); \
                 --keep-going goes on past failed frames",
                super::report(&e),
                i + 1
            ),
        }
    }
    info!(
        "batch of {n} frames in {:.2}s: {done} denoised, {skipped} skipped, {} failed",
        t0.elapsed().as_secs_f64(),
        failed.len()
    );
    if !failed.is_empty() {
        bail!("{} of {n} frames failed: {}", failed.len(), failed.join(", "));
    }
    Ok(())
}

/// One job, its log lines and progress bar labelled with `at`: `Ok(false)`
/// when `--skip-existing` finds its output, `Ok(true)` once denoised.
fn run_job(a: &DenoiseArgs, params: &nldenoise::filter::Params, job: &sequence::Job, at: &str) -> anyhow::Result<bool> {
    if a.skip_existing && job.output.exists() {
        info!("{at}{} exists, skipped (--skip-existing)", job.output.display());
        return Ok(false);
    }
    super::progress::start(format!("{at}{}", job.input.display()));
    let done = denoise_one(a, params, &job.input, &job.output);
    super::progress::finish();
    done.map(|()| true)
}

/// One frame: streamed through the tiled engine, or whole (`--tile-size 0`).
fn denoise_one(a: &DenoiseArgs, params: &nldenoise::filter::Params, input: &Path, output: &Path) -> anyhow::Result<()> {
    let t0 = Instant::now();
    if a.tile_size == 0 {
        whole_frame(a, params, input, output)?;
    } else {
        let opts = StreamOptions {
            tile_size: a.tile_size,
            threads: a.threads,
            memory_limit: a.memory_limit.unwrap_or_else(budget::default_limit_bytes),
            half: a.half,
            zip_level: a.zip_level,
            carry: !a.denoised_only,
            ..StreamOptions::default()
        };
        let (report, _) =
            api::denoise_file_streaming(input, output, &a.channels.options(), params, &opts, a.compression)?;
        for n in &report.roles.notes {
            info!("{}: {n}", input.display());
        }
    }
    info!("{} -> {} in {:.2}s", input.display(), output.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

/// `--tile-size 0`: read the whole frame, filter it in memory, write it.
fn whole_frame(a: &DenoiseArgs, params: &nldenoise::filter::Params, input: &Path, output: &Path) -> anyhow::Result<()> {
    let pool = thread_pool(a.threads)?;
    let t0 = Instant::now();
    let limit = a.memory_limit.unwrap_or_else(budget::default_limit_bytes);
    let mut frame = exrio::read_frame_within(input, limit)?;
    let rect = frame.data_window;
    info!(
        "read {} ({}x{}, {} channels) in {:.2}s",
        input.display(),
        rect.width(),
        rect.height(),
        frame.channels.len(),
        t0.elapsed().as_secs_f64()
    );
    let t1 = Instant::now();
    let report = pool.install(|| api::denoise_frame(&mut frame, input, &a.channels.options(), params, a.half))?;
    for n in &report.roles.notes {
        info!("{}: {n}", input.display());
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
    if a.denoised_only {
        frame.channels.retain(|c| report.replaced.contains(&c.name));
    }
    let t2 = Instant::now();
    exrio::stream::write_frame_streamed(output, &frame, (a.compression, a.zip_level), a.threads)?;
    info!("wrote {} in {:.2}s", output.display(), t2.elapsed().as_secs_f64());
    Ok(())
}
