//! `nldenoise denoise INPUT -o OUTPUT`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use nldenoise::exrio::{self, Channel, OutputCompression, WriteOptions, roles};
use nldenoise::filter::{self, InputShape, Pipeline};
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
    /// Output compression.
    #[arg(long, value_enum, default_value_t = OutputCompression::Zip)]
    pub compression: OutputCompression,
}

pub fn run(a: DenoiseArgs) -> anyhow::Result<()> {
    let params = a.filter.params()?;
    let t0 = Instant::now();
    let mut frame = exrio::read_frame(&a.input)?;
    let roles = roles::detect(&a.input, &frame.channel_names(), &a.channels.options())?;
    for n in &roles.notes {
        tracing::warn!("{}: {n}", a.input.display());
    }
    let inputs = roles.inputs(&frame);
    let rect = frame.data_window;
    info!(
        "read {} ({}x{}, {} channels) in {:.2}s",
        a.input.display(),
        rect.width(),
        rect.height(),
        frame.channels.len(),
        t0.elapsed().as_secs_f64()
    );
    let pipeline = Pipeline::new(params, InputShape::of(&inputs));
    for line in pipeline.describe() {
        info!("{line}");
    }
    let pool = thread_pool(a.threads)?;
    let t1 = Instant::now();
    let out = pool
        .install(|| filter::denoise_region(&inputs, rect, rect, &params))
        .with_context(|| format!("{}: denoising failed", a.input.display()))?;
    info!("filtered in {:.2}s on {} threads", t1.elapsed().as_secs_f64(), pool.current_num_threads());
    drop(inputs);
    let mut put = |name: &str, plane: &nldenoise::image::Plane| {
        frame.set_channel(if a.half { Channel::from_f32_as_half(name, plane.data()) } else { Channel::from_f32(name, plane.data().to_vec()) });
    };
    for (name, plane) in roles.colour.iter().zip(&out.colour) {
        put(name, plane);
    }
    for (layer, planes) in roles.layers.iter().zip(&out.layers) {
        for (name, plane) in layer.channels.iter().zip(planes) {
            put(name, plane);
        }
    }
    let t2 = Instant::now();
    exrio::write_frame(&a.output, &frame, &WriteOptions { compression: a.compression, ..Default::default() })?;
    info!("wrote {} in {:.2}s", a.output.display(), t2.elapsed().as_secs_f64());
    Ok(())
}
