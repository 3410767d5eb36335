//! `nldenoise info FILE`: channels, their roles, and the filter plan. Reads
//! the header only (the pixels are never decoded), so it is instant on any
//! frame size.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use nldenoise::engine::{self, RowSource, StreamOptions, budget};
use nldenoise::exrio::stream::ExrSource;
use nldenoise::exrio::{self, roles};
use nldenoise::filter::Pipeline;

use super::{ChannelArgs, FilterArgs};

/// Arguments of `info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// EXR frame to describe.
    pub input: PathBuf,
    /// Also print the filter plan: every stage's reach, the derived halo, and
    /// the streaming schedule for `--tile-size` and `--memory-limit`.
    #[arg(long)]
    pub plan: bool,
    /// Tile size the streaming schedule starts from.
    #[arg(long, default_value_t = 512)]
    pub tile_size: usize,
    /// Memory limit for the streaming schedule (default: half of the available memory).
    #[arg(long, value_parser = budget::parse_size)]
    pub memory_limit: Option<u64>,
    /// Worker threads assumed by the schedule (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    #[command(flatten)]
    pub filter: FilterArgs,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

pub fn run(a: InfoArgs) -> anyhow::Result<()> {
    let source = ExrSource::open(&a.input)?;
    let dw = source.data_window();
    let names = source.channel_names();
    let mut o = String::new();
    writeln!(o, "file: {}", a.input.display())?;
    writeln!(
        o,
        "data window: ({}, {}) - ({}, {})  {} x {}",
        dw.x0,
        dw.y0,
        dw.x1 - 1,
        dw.y1 - 1,
        dw.width(),
        dw.height()
    )?;
    let l = exrio::layout_of(source.header());
    writeln!(o, "layout: {}, {} compression, {} line order", l.blocks, l.compression, l.line_order)?;
    let roles = roles::detect(&a.input, &names, &a.channels.options());
    writeln!(o, "channels ({}):", names.len())?;
    for (name, kind) in names.iter().zip(source.kinds()) {
        let role = roles.as_ref().map_or(String::new(), |r| r.role_of(name));
        writeln!(o, "  {:<24} {:<6} {}", name, kind.to_string(), role)?;
    }
    // A file the denoiser cannot use as mapped (a `denoise --denoised-only`
    // output, say) still gets its channels listed, then the reason, with a
    // failing exit.
    let roles = match roles {
        Ok(roles) => roles,
        Err(e) => {
            super::out(&o)?;
            return Err(e.into());
        }
    };
    writeln!(o, "denoiser will use:")?;
    writeln!(o, "  colour: {}", roles.colour.join(","))?;
    match &roles.variance {
        roles::VarianceRole::Sample(v) => writeln!(o, "  variance: sample variance {}", v.join(","))?,
        roles::VarianceRole::Halves(x, y) => {
            writeln!(o, "  variance: (A-B)^2/4 from {} and {}", x.join(","), y.join(","))?
        }
    }
    if roles.features.is_empty() {
        writeln!(o, "  features: none (colour-only NL-means)")?;
    }
    for f in &roles.features {
        let var =
            f.variance.as_ref().map_or(" (no variance)".to_string(), |v| format!(" with variance {}", v.join(",")));
        writeln!(o, "  feature {}: {}{var}", f.name, f.channels.join(","))?;
    }
    if roles.layers.is_empty() {
        writeln!(o, "  light layers: none (the beauty is filtered directly)")?;
    }
    for l in &roles.layers {
        writeln!(o, "  light layer {}: {}", l.name, l.channels.join(","))?;
    }
    for n in &roles.notes {
        writeln!(o, "  note: {n}")?;
    }
    if a.plan {
        let params = a.filter.params()?;
        let shape = roles.shape();
        writeln!(o, "plan:")?;
        for line in Pipeline::new(params, shape).describe() {
            writeln!(o, "  {line}")?;
        }
        let opts = StreamOptions {
            tile_size: a.tile_size.max(1),
            threads: a.threads,
            memory_limit: a.memory_limit.unwrap_or_else(budget::default_limit_bytes),
            ..StreamOptions::default()
        };
        match engine::plan_stream(&source, &roles, &params, &opts) {
            Ok((_, p, threads)) => writeln!(
                o,
                "  streaming: bands of {} rows, tiles {}x{} (kernel blocks up to {} rows), {} threads, queue depth {}, {} bands in flight, estimated peak {:.1} MiB of {:.1} MiB",
                p.band_rows,
                p.tile_width,
                p.band_rows,
                p.kernel_rows,
                threads,
                p.queue_depth,
                p.bands_in_flight,
                p.estimate_bytes as f64 / 1048576.0,
                opts.memory_limit as f64 / 1048576.0
            )?,
            Err(e) => writeln!(o, "  streaming: {e}")?,
        }
    }
    super::out(&o)
}
