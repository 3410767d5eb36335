//! Command-line front end: arguments (clap), logging, and the subcommands.
//! Each subcommand validates its arguments into library types and calls the
//! library; errors are reported with `anyhow` context and exit code 1 (2 for
//! usage errors, from clap).

mod compare;
mod denoise;
mod info;
mod progress;
mod quality;

use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use nldenoise::exrio::roles::{MAP_HELP, RoleOptions, Selection, VarianceChoice};
use nldenoise::filter::{FeaturePrefilter, Params};

/// Variance-aware, feature-guided NL-means denoiser for Monte Carlo renderings (EXR in, EXR out).
#[derive(Parser, Debug)]
#[command(name = "nldenoise", version, about, propagate_version = true)]
struct Cli {
    /// More log output (-v: stages and timings, -vv: debug). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Only errors.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Denoise an EXR frame, or a batch: a frame sequence (shot.####.exr) or several frames into a folder.
    Denoise(denoise::DenoiseArgs),
    /// Print a frame's channels, the role chosen for each, and what the denoiser will use.
    Info(info::InfoArgs),
    /// Compare two EXR frames (B is the reference): relMSE, MSE, PSNR, max_abs_diff, bitwise_identical.
    Compare(compare::CompareArgs),
    /// Denoise every noisy file of a scenes folder and write the quality report.
    Quality(quality::QualityArgs),
}

/// Filter parameters shared by `denoise`, `info` and `quality`.
#[derive(Args, Debug, Clone)]
pub struct FilterArgs {
    /// Search radius r (window (2r+1)^2).
    #[arg(long, default_value_t = Params::default().search_radius)]
    pub search_radius: usize,
    /// Patch radius f.
    #[arg(long, default_value_t = Params::default().patch_radius)]
    pub patch_radius: usize,
    /// Colour strength k.
    #[arg(long, default_value_t = Params::default().strength)]
    pub strength: f32,
    /// Variance cancellation alpha.
    #[arg(long, default_value_t = Params::default().alpha)]
    pub alpha: f32,
    /// Feature strength kf.
    #[arg(long, default_value_t = Params::default().feature_strength)]
    pub feature_strength: f32,
    /// Feature gradient floor tau.
    #[arg(long, default_value_t = Params::default().tau)]
    pub tau: f32,
    /// Variance prefilter radius rho: v' = max(v, box_rho(v)); 0 turns it off.
    #[arg(long, default_value_t = Params::default().variance_prefilter_radius)]
    pub variance_prefilter: usize,
    /// Radius of the variance prefilter applied to feature variances; 0 turns it off.
    #[arg(long, default_value_t = Params::default().feature_variance_prefilter_radius)]
    pub feature_variance_prefilter: usize,
    /// Use feature variances in the feature distance (Rousselle 2013).
    #[arg(long, default_value_t = Params::default().feature_variance, action = clap::ArgAction::Set)]
    pub feature_variance: bool,
    /// Feature prefilter search radius (NL-means of each feature with its own variance); 0 turns it off.
    #[arg(long, default_value_t = Params::default().feature_prefilter.search_radius)]
    pub feature_prefilter_radius: usize,
    /// Feature prefilter patch radius.
    #[arg(long, default_value_t = Params::default().feature_prefilter.patch_radius)]
    pub feature_prefilter_patch: usize,
    /// Feature prefilter strength.
    #[arg(long, default_value_t = Params::default().feature_prefilter.strength)]
    pub feature_prefilter_strength: f32,
}

impl FilterArgs {
    /// Validated parameters.
    pub fn params(&self) -> anyhow::Result<Params> {
        let p = Params {
            search_radius: self.search_radius,
            patch_radius: self.patch_radius,
            strength: self.strength,
            alpha: self.alpha,
            feature_strength: self.feature_strength,
            tau: self.tau,
            variance_prefilter_radius: self.variance_prefilter,
            feature_variance: self.feature_variance,
            feature_variance_prefilter_radius: self.feature_variance_prefilter,
            feature_prefilter: FeaturePrefilter {
                search_radius: self.feature_prefilter_radius,
                patch_radius: self.feature_prefilter_patch,
                strength: self.feature_prefilter_strength,
            },
            ..Params::default()
        };
        p.validate()?;
        Ok(p)
    }
}

/// Channel selection shared by `denoise` and `info`.
#[derive(Args, Debug, Clone)]
pub struct ChannelArgs {
    /// Variance of the mean: sample-variance channels, half-buffer difference, or auto.
    #[arg(long, value_enum, default_value_t = VarianceChoice::Auto)]
    pub variance: VarianceChoice,
    /// Guide features: auto (albedo, normal, depth as found), none, or a list such as albedo,N.
    #[arg(long, default_value = "auto")]
    pub features: Selection,
    /// Light layers filtered separately and summed: auto (direct+indirect), none, or a list.
    /// Off by default: measured worse than filtering the beauty at 16 spp (docs/quality.md).
    #[arg(long, default_value = "none")]
    pub layers: Selection,
    #[arg(long = "map", value_name = "ROLE=CH,...", help = MAP_HELP)]
    pub maps: Vec<String>,
}

impl ChannelArgs {
    /// As library options.
    pub fn options(&self) -> RoleOptions {
        RoleOptions {
            variance: self.variance,
            features: self.features.clone(),
            layers: self.layers.clone(),
            maps: self.maps.clone(),
        }
    }
}

fn init_logging(verbose: u8, quiet: bool) {
    use tracing_subscriber::filter::Targets;
    use tracing_subscriber::prelude::*;
    use tracing_subscriber::{EnvFilter, fmt};
    let default = match (quiet, verbose) {
        (true, _) => "error",
        (false, 0) => "warn",
        (false, 1) => "info",
        _ => "debug",
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
    // The progress bar (on a terminal, without -q) takes the engine's progress
    // events; the log lines are printed above it.
    let bar = progress::init(!quiet);
    let lines = fmt::layer()
        .with_writer(progress::BarWriter(bar.clone()))
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .with_filter(filter);
    let progress = progress::ProgressLayer(bar)
        .with_filter(Targets::new().with_target(nldenoise::engine::PROGRESS_TARGET, tracing::Level::TRACE));
    let _ = tracing_subscriber::registry().with(lines).with(progress).try_init();
}

/// Run the command line; never panics on bad input.
pub fn main() -> ExitCode {
    // Fresh memory in 2 MiB pages (a re-execution, at most once; before any thread).
    nldenoise::engine::budget::exec_with_huge_pages();
    let cli = Cli::parse();
    nldenoise::engine::budget::bound_allocator();
    // Interrupted (Ctrl-C, a farm's SIGTERM): leave no temporary output behind.
    let _ = ctrlc::set_handler(|| {
        progress::finish();
        nldenoise::exrio::remove_unfinished_outputs();
        eprintln!("error: interrupted; the unfinished output was removed (frames a batch completed before stay)");
        std::process::exit(130);
    });
    init_logging(cli.verbose, cli.quiet);
    if nldenoise::engine::budget::huge_pages_requested() {
        let tunables = std::env::var("GLIBC_TUNABLES").unwrap_or_default();
        tracing::debug!("allocator: transparent huge pages requested (GLIBC_TUNABLES={tunables})");
    }
    let result = match cli.command {
        Command::Denoise(a) => denoise::run(a),
        Command::Info(a) => info::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Quality(a) => quality::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", report(&e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes on one line, `outer: cause: ...`, leaving out a
/// cause whose text the line already holds (the library's errors print their
/// source within their own message, and would otherwise repeat it).
pub fn report(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.is_empty() {
            line = text;
        } else if !line.contains(&text) {
            line = format!("{line}: {text}");
        }
    }
    line
}

/// Print to stdout; a closed pipe (`| head`) ends output quietly instead of panicking.
pub fn out(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    match stdout.write_all(text.as_bytes()).and_then(|_| stdout.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}

/// A rayon pool with `threads` workers (0 = one per core).
pub fn thread_pool(threads: usize) -> anyhow::Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new().num_threads(threads).build()?)
}
