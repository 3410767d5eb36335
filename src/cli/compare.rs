//! `nldenoise compare A B`: metrics of A against the reference B.

use std::path::PathBuf;

use anyhow::bail;
use std::fmt::Write as _;

use clap::Args;
use nldenoise::exrio;
use nldenoise::metrics;

/// Arguments of `compare`.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The frame to measure.
    pub a: PathBuf,
    /// The reference frame.
    pub b: PathBuf,
    /// Channels to compare (default: R,G,B).
    #[arg(long, value_delimiter = ',', default_value = "R,G,B")]
    pub channels: Vec<String>,
}

pub fn run(a: CompareArgs) -> anyhow::Result<()> {
    let fa = exrio::read_frame(&a.a)?;
    let fb = exrio::read_frame(&a.b)?;
    if fa.data_window != fb.data_window {
        bail!(
            "{} and {} have different data windows ({:?} vs {:?})",
            a.a.display(),
            a.b.display(),
            fa.data_window,
            fb.data_window
        );
    }
    let mut xs = Vec::new();
    let mut rs = Vec::new();
    for ch in &a.channels {
        let get = |f: &exrio::Frame, p: &PathBuf| {
            f.plane(ch).ok_or_else(|| {
                anyhow::anyhow!("{}: no channel {ch:?} (channels: {})", p.display(), f.channel_names().join(", "))
            })
        };
        xs.push(get(&fa, &a.a)?);
        rs.push(get(&fb, &a.b)?);
    }
    let mut o = String::new();
    let m = metrics::compare(
        &xs.iter().map(|p| p.data()).collect::<Vec<_>>(),
        &rs.iter().map(|p| p.data()).collect::<Vec<_>>(),
    );
    writeln!(o, "relMSE: {:.6e}", m.rel_mse)?;
    writeln!(o, "MSE: {:.6e}", m.mse)?;
    writeln!(o, "PSNR: {:.3}", m.psnr)?;
    writeln!(o, "max_abs_diff: {:.6e}", m.max_abs_diff)?;
    writeln!(o, "bitwise_identical: {}", if m.bitwise_identical { "yes" } else { "no" })?;
    if m.non_finite > 0 {
        writeln!(o, "non_finite_samples: {}", m.non_finite)?;
    }
    super::out(&o)
}
