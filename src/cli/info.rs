//! `nldenoise info FILE`: channels, their roles, and the filter plan.

use std::path::PathBuf;

use std::fmt::Write as _;

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
    if let Some(l) = &frame.layout {
        writeln!(o, "layout: {}, {} compression, {} line order", l.blocks, l.compression, l.line_order)?;
    }
    let roles = roles::detect(&a.input, &frame.channel_names(), &a.channels.options())?;
    writeln!(o, "channels ({}):", frame.channels.len())?;
    for c in &frame.channels {
        writeln!(o, "  {:<24} {:<6} {}", c.name, c.kind.to_string(), roles.role_of(&c.name))?;
    }
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
        writeln!(
            o,
            "  feature {}: {}{}",
            f.name,
            f.channels.join(","),
            f.variance.as_ref().map_or(" (no variance)".to_string(), |v| format!(" with variance {}", v.join(",")))
        )?;
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
        let inputs_shape = InputShape {
            feature_has_variance: roles.features.iter().map(|f| f.variance.is_some()).collect(),
            layers: roles.layers.len(),
        };
        writeln!(o, "plan:")?;
        for line in Pipeline::new(params, inputs_shape).describe() {
            writeln!(o, "  {line}")?;
        }
    }
    super::out(&o)
}
