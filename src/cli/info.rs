//! `nldenoise info FILE`: channels, their roles, and the filter plan.

use std::path::PathBuf;

use clap::Args;
use nldenoise::exrio::{self, roles};
use nldenoise::filter::{InputShape, Pipeline};

use super::{ChannelArgs, FilterArgs};

/// Arguments of `info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// EXR frame to describe.
    pub input: PathBuf,
    /// Also print the filter plan: every stage's reach and the derived halo.
    #[arg(long)]
    pub plan: bool,
    #[command(flatten)]
    pub filter: FilterArgs,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

pub fn run(a: InfoArgs) -> anyhow::Result<()> {
    let frame = exrio::read_frame(&a.input)?;
    let dw = frame.data_window;
    println!("file: {}", a.input.display());
    println!("data window: ({}, {}) - ({}, {})  {} x {}", dw.x0, dw.y0, dw.x1 - 1, dw.y1 - 1, dw.width(), dw.height());
    if let Some(l) = &frame.layout {
        println!("layout: {}, {} compression, {} line order", l.blocks, l.compression, l.line_order);
    }
    let roles = roles::detect(&a.input, &frame.channel_names(), &a.channels.options())?;
    println!("channels ({}):", frame.channels.len());
    for c in &frame.channels {
        println!("  {:<24} {:<6} {}", c.name, c.kind.to_string(), roles.role_of(&c.name));
    }
    println!("denoiser will use:");
    println!("  colour: {}", roles.colour.join(","));
    match &roles.variance {
        roles::VarianceRole::Sample(v) => println!("  variance: sample variance {}", v.join(",")),
        roles::VarianceRole::Halves(x, y) => println!("  variance: (A-B)^2/4 from {} and {}", x.join(","), y.join(",")),
    }
    if roles.features.is_empty() {
        println!("  features: none (colour-only NL-means)");
    }
    for f in &roles.features {
        println!(
            "  feature {}: {}{}",
            f.name,
            f.channels.join(","),
            f.variance.as_ref().map_or(" (no variance)".to_string(), |v| format!(" with variance {}", v.join(",")))
        );
    }
    if roles.layers.is_empty() {
        println!("  light layers: none (the beauty is filtered directly)");
    }
    for l in &roles.layers {
        println!("  light layer {}: {}", l.name, l.channels.join(","));
    }
    for n in &roles.notes {
        println!("  note: {n}");
    }
    if a.plan {
        let params = a.filter.params()?;
        let inputs_shape = InputShape {
            feature_has_variance: roles.features.iter().map(|f| f.variance.is_some()).collect(),
            layers: roles.layers.len(),
        };
        println!("plan:");
        for line in Pipeline::new(params, inputs_shape).describe() {
            println!("  {line}");
        }
    }
    Ok(())
}
