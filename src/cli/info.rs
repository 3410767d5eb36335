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
    let mut o = String::new();
    o.push_str(&format!("file: {}\n", a.input.display()));
    o.push_str(&format!(
        "data window: ({}, {}) - ({}, {})  {} x {}\n",
        dw.x0,
        dw.y0,
        dw.x1 - 1,
        dw.y1 - 1,
        dw.width(),
        dw.height()
    ));
    if let Some(l) = &frame.layout {
        o.push_str(&format!(
            "layout: {}, {} compression, {} line order\n",
            l.blocks, l.compression, l.line_order
        ));
    }
    let roles = roles::detect(&a.input, &frame.channel_names(), &a.channels.options())?;
    o.push_str(&format!("channels ({}):\n", frame.channels.len()));
    for c in &frame.channels {
        o.push_str(&format!(
            "  {:<24} {:<6} {}\n",
            c.name,
            c.kind.to_string(),
            roles.role_of(&c.name)
        ));
    }
    o.push_str(&format!("denoiser will use:\n"));
    o.push_str(&format!("  colour: {}\n", roles.colour.join(",")));
    match &roles.variance {
        roles::VarianceRole::Sample(v) => {
            o.push_str(&format!("  variance: sample variance {}\n", v.join(",")))
        }
        roles::VarianceRole::Halves(x, y) => o.push_str(&format!(
            "  variance: (A-B)^2/4 from {} and {}\n",
            x.join(","),
            y.join(",")
        )),
    }
    if roles.features.is_empty() {
        o.push_str(&format!("  features: none (colour-only NL-means)\n"));
    }
    for f in &roles.features {
        o.push_str(&format!(
            "  feature {}: {}{}\n",
            f.name,
            f.channels.join(","),
            f.variance
                .as_ref()
                .map_or(" (no variance)".to_string(), |v| format!(
                    " with variance {}",
                    v.join(",")
                ))
        ));
    }
    if roles.layers.is_empty() {
        o.push_str(&format!(
            "  light layers: none (the beauty is filtered directly)\n"
        ));
    }
    for l in &roles.layers {
        o.push_str(&format!(
            "  light layer {}: {}\n",
            l.name,
            l.channels.join(",")
        ));
    }
    for n in &roles.notes {
        o.push_str(&format!("  note: {n}\n"));
    }
    if a.plan {
        let params = a.filter.params()?;
        let inputs_shape = InputShape {
            feature_has_variance: roles
                .features
                .iter()
                .map(|f| f.variance.is_some())
                .collect(),
            layers: roles.layers.len(),
        };
        o.push_str(&format!("plan:\n"));
        for line in Pipeline::new(params, inputs_shape).describe() {
            o.push_str(&format!("  {line}\n"));
        }
    }
    super::out(&o)
}
