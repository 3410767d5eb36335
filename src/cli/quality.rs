//! `nldenoise quality --scenes DIR`: denoise every noisy file of a scenes
//! folder (`<scene>_<spp>spp.exr` beside `<scene>_ref.exr`) with several
//! configurations, and write a Markdown report with relMSE tables, timings and
//! PNG crops (noisy | denoised | reference).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use nldenoise::api;
use nldenoise::exrio::roles::{RoleOptions, Selection, VarianceChoice};
use nldenoise::exrio::{self, Frame};
use nldenoise::filter::{FeaturePrefilter, Params};
use nldenoise::metrics;
use nldenoise::preview::Rgb8;

use super::{FilterArgs, thread_pool};

/// Arguments of `quality`.
#[derive(Args, Debug)]
pub struct QualityArgs {
    /// Folder with `<scene>_<spp>spp.exr` and `<scene>_ref.exr` files.
    #[arg(long, default_value = "../shared/scenes")]
    pub scenes: PathBuf,
    /// Where to write the report (Markdown) ; PNG crops go beside it in `quality/`.
    #[arg(long, default_value = "docs/quality.md")]
    pub report: PathBuf,
    /// Also run the parameter sweeps used to choose the defaults.
    #[arg(long)]
    pub sweep: bool,
    /// Worker threads (0 = one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Parameters of the "default" configuration (the tool's defaults unless overridden).
    #[command(flatten)]
    pub filter: FilterArgs,
}

struct Config {
    name: String,
    opts: RoleOptions,
    params: Params,
}

fn config(name: &str, features: Selection, layers: Selection, variance: VarianceChoice, params: Params) -> Config {
    Config { name: name.to_string(), opts: RoleOptions { variance, features, layers, maps: vec![] }, params }
}

/// The slides' filter: no variance prefilter, features with the gradient term only.
fn slides() -> Params {
    Params {
        variance_prefilter_radius: 0,
        feature_variance: false,
        feature_prefilter: FeaturePrefilter { search_radius: 0, ..Params::default().feature_prefilter },
        ..Params::default()
    }
}

fn main_configs(default: Params) -> Vec<Config> {
    use Selection::{Auto, None};
    use VarianceChoice::Auto as VA;
    vec![
        config("default (`nldenoise denoise` with no options)", Auto, None, VA, default),
        config("colour-only, slides (var.*, no prefilter)", None, None, VA, slides()),
        config("joint, slides (albedo+N+Z, gradient term only)", Auto, None, VA, slides()),
        config("joint + layers, slides", Auto, Auto, VA, slides()),
        config("joint + layers, default parameters", Auto, Auto, VA, default),
    ]
}

/// One sweep per default that was chosen by measurement; each varies one
/// setting around the defaults.
fn sweep_configs(default: Params) -> Vec<Config> {
    use Selection::{Auto, List, None};
    let va = VarianceChoice::Auto;
    let list = |s: &str| List(s.split(',').map(str::to_string).collect());
    let mut v = Vec::new();
    for var in [VarianceChoice::Sample, VarianceChoice::Halves] {
        for rho in [0, 1, 2, 3] {
            let name = format!("rho: colour-only, {var:?} variance, rho={rho}").to_lowercase();
            v.push(config(&name, None, None, var, Params { variance_prefilter_radius: rho, ..slides() }));
        }
    }
    for rho in [0, 2] {
        v.push(config(
            &format!("rho: default guides, rho={rho}"),
            Auto,
            None,
            va,
            Params { variance_prefilter_radius: rho, ..default },
        ));
    }
    for (name, feats) in [("none", None), ("albedo", list("albedo")), ("albedo,N", list("albedo,N")), ("Z", list("Z"))]
    {
        v.push(config(&format!("features: {name}"), feats, None, va, default));
    }
    v.push(config("feature variance terms off", Auto, None, va, Params { feature_variance: false, ..default }));
    for frho in [0, 2] {
        v.push(config(
            &format!("feature variance prefilter {frho}"),
            Auto,
            None,
            va,
            Params { feature_variance_prefilter_radius: frho, ..default },
        ));
    }
    for (r, f) in [(0, 2), (5, 3)] {
        let fp = FeaturePrefilter { search_radius: r, patch_radius: f, ..default.feature_prefilter };
        v.push(config(
            &format!("feature prefilter r={r} f={f}"),
            Auto,
            None,
            va,
            Params { feature_prefilter: fp, ..default },
        ));
    }
    v
}

struct Scene {
    name: String,
    spp: u32,
    noisy: PathBuf,
    reference: PathBuf,
}

fn find_scenes(dir: &Path) -> anyhow::Result<Vec<Scene>> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("{}: cannot list", dir.display()))? {
        let path = e?.path();
        let Some(stem) = path.file_stem().and_then(|s| s.to_str()).map(str::to_string) else {
            continue;
        };
        if path.extension().and_then(|s| s.to_str()) != Some("exr") {
            continue;
        }
        let Some((scene, spp)) = stem.rsplit_once('_') else {
            continue;
        };
        let Some(spp) = spp.strip_suffix("spp").and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        let reference = dir.join(format!("{scene}_ref.exr"));
        if reference.exists() {
            out.push(Scene { name: scene.to_string(), spp, noisy: path, reference });
        }
    }
    out.sort_by(|a, b| (a.spp, &a.name).cmp(&(b.spp, &b.name)));
    if out.is_empty() {
        bail!("{}: no <scene>_<spp>spp.exr files with a <scene>_ref.exr beside them", dir.display());
    }
    Ok(out)
}

fn rgb(frame: &Frame, path: &Path) -> anyhow::Result<[Vec<f32>; 3]> {
    let get =
        |c: &str| frame.plane(c).map(|p| p.into_vec()).with_context(|| format!("{}: no channel {c}", path.display()));
    Ok([get("R")?, get("G")?, get("B")?])
}

fn rel_mse(x: &[Vec<f32>; 3], r: &[Vec<f32>; 3]) -> f64 {
    metrics::compare(&[&x[0], &x[1], &x[2]], &[&r[0], &r[1], &r[2]]).rel_mse
}

struct Row {
    noisy: f64,
    denoised: f64,
    seconds: f64,
}

fn geo_mean(v: &[f64]) -> f64 {
    (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp()
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!("{cpu}, {} hardware threads", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1))
}

fn table(o: &mut String, scenes: &[Scene], cfg: &Config, rows: &[Row]) {
    let _ = writeln!(o, "\n### {}\n", cfg.name);
    let _ = writeln!(o, "| file | noisy relMSE | denoised relMSE | reduction | seconds |");
    let _ = writeln!(o, "|---|---|---|---|---|");
    for (s, r) in scenes.iter().zip(rows) {
        let _ = writeln!(
            o,
            "| {}_{:04}spp | {:.5} | {:.5} | {:.2}x | {:.2} |",
            s.name,
            s.spp,
            r.noisy,
            r.denoised,
            r.noisy / r.denoised,
            r.seconds
        );
    }
    let mut spps: Vec<u32> = scenes.iter().map(|s| s.spp).collect();
    spps.dedup();
    for spp in spps {
        let red: Vec<f64> =
            scenes.iter().zip(rows).filter(|(s, _)| s.spp == spp).map(|(_, r)| r.noisy / r.denoised).collect();
        let _ = writeln!(o, "| **geometric-mean reduction, {spp} spp** | | | **{:.2}x** | |", geo_mean(&red));
    }
}

pub fn run(a: QualityArgs) -> anyhow::Result<()> {
    let default = a.filter.params()?;
    let pool = thread_pool(a.threads)?;
    let scenes = find_scenes(&a.scenes)?;
    let img_dir = a.report.with_file_name("quality");
    std::fs::create_dir_all(&img_dir).with_context(|| format!("{}: cannot create", img_dir.display()))?;
    let configs = main_configs(default);
    let sweeps = if a.sweep { sweep_configs(default) } else { Vec::new() };
    let mut results: Vec<Vec<Row>> = (0..configs.len() + sweeps.len()).map(|_| Vec::new()).collect();
    let mut grids: Vec<(String, Vec<Rgb8>)> = Vec::new();

    for scene in &scenes {
        let noisy = exrio::read_frame(&scene.noisy)?;
        let reference = exrio::read_frame(&scene.reference)?;
        let (n_rgb, r_rgb) = (rgb(&noisy, &scene.noisy)?, rgb(&reference, &scene.reference)?);
        let noisy_rel = rel_mse(&n_rgb, &r_rgb);
        for (i, cfg) in configs.iter().chain(&sweeps).enumerate() {
            let mut frame = noisy.clone();
            let t = Instant::now();
            pool.install(|| api::denoise_frame(&mut frame, &scene.noisy, &cfg.opts, &cfg.params, false))?;
            let seconds = t.elapsed().as_secs_f64();
            let d_rgb = rgb(&frame, &scene.noisy)?;
            let denoised = rel_mse(&d_rgb, &r_rgb);
            eprintln!(
                "{}_{:04}spp  {:<60} {:.5} -> {:.5} ({:.2}x) {:.2}s",
                scene.name,
                scene.spp,
                cfg.name,
                noisy_rel,
                denoised,
                noisy_rel / denoised,
                seconds
            );
            results[i].push(Row { noisy: noisy_rel, denoised, seconds });
            if i == 0 {
                let w = noisy.data_window.width();
                let h = noisy.data_window.height();
                let (cw, ch) = (w.min(256), h.min(192));
                let crop = ((w - cw) / 2, (h - ch) / 2, cw, ch);
                let panel = |c: &[Vec<f32>; 3]| Rgb8::from_channels([&c[0], &c[1], &c[2]], w, crop, 1.0);
                let row = Rgb8::hstack(&[panel(&n_rgb), panel(&d_rgb), panel(&r_rgb)], 4);
                match grids.iter_mut().find(|(n, _)| *n == scene.name) {
                    Some((_, rows)) => rows.push(row),
                    None => grids.push((scene.name.clone(), vec![row])),
                }
            }
        }
    }

    let mut o = String::new();
    let date = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d")
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    let _ = writeln!(o, "# Quality report\n");
    let _ = writeln!(
        o,
        "Generated by `cargo run --release -- quality --scenes {}{}` on {} ({}), {} rayon threads. \
relMSE = mean over pixels and R,G,B of (x - ref)^2 / (ref^2 + 0.01) against `<scene>_ref.exr` (SPEC §8). \
Seconds are filter time (no file I/O).\n",
        a.scenes.display(),
        if a.sweep { " --sweep" } else { "" },
        date.unwrap_or_default(),
        machine(),
        pool.current_num_threads()
    );
    let _ = writeln!(o, "Default parameters: `{default:?}`\n");
    let _ = writeln!(o, "## Configurations\n");
    for (cfg, rows) in configs.iter().zip(&results) {
        table(&mut o, &scenes, cfg, rows);
    }
    if !sweeps.is_empty() {
        let _ = writeln!(o, "\n## Sweeps used to choose the defaults\n");
        for (cfg, rows) in sweeps.iter().zip(&results[configs.len()..]) {
            table(&mut o, &scenes, cfg, rows);
        }
    }
    let _ = writeln!(o, "\n## Crops (noisy | default denoised | reference), one row per sample count\n");
    for (name, rows) in grids {
        let file = img_dir.join(format!("{name}.png"));
        Rgb8::vstack(&rows, 4).write_png(&file)?;
        let rel = Path::new("quality").join(format!("{name}.png"));
        let _ = writeln!(o, "**{name}**\n\n![{name}]({})\n", rel.display());
    }
    std::fs::write(&a.report, o).with_context(|| format!("{}: cannot write", a.report.display()))?;
    eprintln!("wrote {}", a.report.display());
    Ok(())
}
