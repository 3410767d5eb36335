//! End-to-end filter timing from memory (no file I/O): a synthetic frame
//! streamed through the tiled engine into a null sink, as `denoise` does.
//! Prints one CSV line: mode,width,height,threads,radius,seconds (min of runs,
//! or with `REPORT=last` the last run's own time), ns per pixel-offset per
//! thread. With `SHARE=1` each run also prints to stderr its CPU time (the
//! process's, every thread's: a figure the host's other guests move less
//! than the wall time) and the share of the workers' time spent in the
//! kernel's blocks (`StreamReport::kernel_time` over threads x wall time).
//!
//! `cargo run --release --example timing -- MODE WIDTH HEIGHT THREADS [RADIUS] [RUNS]`
//! MODE: `colour` (beauty + variance only), `full` (the default filter with
//! albedo, normal and depth features, and the direct/indirect light layers),
//! `features` (features, no layers) or `layers` (layers, no features);
//! `full-var` is `full` with a variance channel per feature channel
//! (`albedo_var.*`, `N_var.*`, `Z_var`, as renderers such as Mitsuba write
//! them and `../shared/scenes` has them), which the default filter then
//! uses (SPEC §3): the path real renders take.
//! `NLDENOISE_TILE=N` sets the tile size (default: the engine's).

use std::time::Instant;

use nldenoise::engine::synthetic::Synthetic;
use nldenoise::engine::{StreamOptions, denoise_stream};
use nldenoise::exrio::Channel;
use nldenoise::exrio::roles::{self, RoleOptions, Selection};
use nldenoise::exrio::stream::{FrameSource, NullSink};
use nldenoise::filter::Params;
use nldenoise::geom::Rect;
use nldenoise::image::Samples;

fn main() {
    // As `nldenoise` runs: its allocator's fresh memory in 2 MiB pages.
    nldenoise::engine::budget::exec_with_huge_pages();
    // The allocator policy `nldenoise denoise` runs with (and embedders are
    // told to set): since session 43 the runs after a process's first reuse
    // its pages, as a batch's frames do.
    nldenoise::engine::budget::bound_allocator();
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 4 {
        eprintln!("usage: timing MODE WIDTH HEIGHT THREADS [RADIUS] [RUNS]");
        std::process::exit(2);
    }
    // `layers` and `features` run one half of the full filter, to attribute its cost.
    let (features, layers) = match a[0].as_str() {
        "full" | "full-var" => (true, true),
        "features" => (true, false),
        "layers" => (false, true),
        _ => (false, false),
    };
    let (w, h, threads): (usize, usize, usize) = (a[1].parse().unwrap(), a[2].parse().unwrap(), a[3].parse().unwrap());
    let radius: usize = a.get(4).map_or(10, |s| s.parse().unwrap());
    let runs: usize = a.get(5).map_or(3, |s| s.parse().unwrap());
    let rect = Rect::from_origin_size(0, 0, w, h);
    let mut frame = Synthetic { frame: rect, features, layers, sigma: 0.05 }.to_frame();
    if a[0] == "full-var" {
        // Each feature channel's variance: small, varying from pixel to pixel.
        let feature_channels: Vec<String> = frame
            .channel_names()
            .into_iter()
            .filter(|n| n.starts_with("albedo.") || n.starts_with("N.") || n == "Z")
            .collect();
        for name in feature_channels {
            let var_name = match name.split_once('.') {
                Some((base, c)) => format!("{base}_var.{c}"),
                None => format!("{name}_var"),
            };
            let samples = (0..w * h).map(|i| 1e-4 * (1.0 + (i % 7) as f32)).collect();
            frame.channels.push(Channel::new(var_name, Samples::F32(samples)));
        }
    }
    let opts = RoleOptions {
        layers: if layers { Selection::Auto } else { Selection::None },
        features: if features { Selection::Auto } else { Selection::None },
        ..RoleOptions::default()
    };
    let roles = roles::detect("timing".as_ref(), &frame.channel_names(), &opts).unwrap();
    let params = Params { search_radius: radius, ..Params::default() };
    let tile_size: usize =
        std::env::var("NLDENOISE_TILE").ok().and_then(|s| s.parse().ok()).unwrap_or(StreamOptions::default().tile_size);
    let stream = StreamOptions { threads, memory_limit: 8 << 30, tile_size, ..StreamOptions::default() };
    let share = std::env::var("SHARE").is_ok_and(|v| v == "1");
    // The last run's time rather than the best: a warm figure (the last of
    // two) without the best-of-two's bias towards a fast first run.
    let last = std::env::var("REPORT").is_ok_and(|v| v == "last");
    let mut reported = f64::INFINITY;
    for _ in 0..runs {
        let cpu0 = process_cpu_seconds();
        let t = Instant::now();
        let mut sink = NullSink::default();
        let report = denoise_stream(&mut FrameSource::new(&frame), &mut sink, &roles, &params, &stream).unwrap();
        let wall = t.elapsed().as_secs_f64();
        let cpu = process_cpu_seconds() - cpu0;
        reported = if last { wall } else { reported.min(wall) };
        let kernel = report.kernel_time.as_secs_f64();
        if share {
            eprintln!(
                "run {wall:.3} s, cpu {cpu:.3} s, kernel {kernel:.3} s over {threads} threads: {:.3} of the workers' time",
                kernel / (wall * threads as f64)
            );
        }
    }
    let po = (w * h) as f64 * ((2 * radius + 1) * (2 * radius + 1)) as f64;
    println!("{},{w},{h},{threads},{radius},{reported:.3},{:.2}", a[0], reported * 1e9 * threads as f64 / po);
}

/// The CPU time of every thread of this process so far, in seconds.
#[cfg(unix)]
fn process_cpu_seconds() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant
    // every Linux kernel supports.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_PROCESS_CPUTIME_ID) failed");
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Not measured off Unix.
#[cfg(not(unix))]
fn process_cpu_seconds() -> f64 {
    f64::NAN
}
