//! The memory budget: from a byte limit to band height, tile width and queue
//! depths. Memory is bounded here and only here.
//!
//! Model, following the data through the stages (`W` frame width, `h` halo,
//! `window = band + 2h`, sizes in the file's own sample types unless noted):
//!
//! * reader cache: decoded blocks covering one window, every channel:
//!   `W × (window + 2·block_rows) × bytes_all`;
//! * one band input = filter channels over the window + other channels over
//!   the band; `depth + 1` of them queued or being read, one being filtered;
//! * the filter stage's `f32` planes of the filter channels over the window,
//!   for each of the bands whose tiles it has queued (`in_flight`: two when
//!   they fit the limit, else one);
//! * tile working sets: `threads × 4 × (tile + 2h) × window × filter_planes × 4`
//!   (the filter's intermediates, the guides' half-float copies counted as
//!   half a plane per feature channel, and room for a copy of the tile's
//!   window of inputs: tiles read the band's planes in place, but one that
//!   repairs a sample filters a repaired copy);
//! * band outputs (`f32` denoised channels plus the rest), `depth + 1 +
//!   in_flight` of them: the bands being filtered, one finished and waiting
//!   for the writer, and `depth` queued;
//! * the writer: rows waiting for their block, a band's compressed blocks,
//!   and its encoders' scratch (`exrio::zip::ScratchPool`: prepared and
//!   deflated bytes of one block per encoder; the encoders are the sink's
//!   threads, as many as the engine's, at most one per block of a band);
//! * the reader's blocks being decompressed and decoded, one per thread,
//!   twice (compressed then inflated bytes, inflated bytes then samples; the
//!   inflated buffers stay in the reader's scratch pool);
//! * a fixed allowance for the program, thread stacks and allocator slack.

use crate::error::Error;
use crate::filter::nlmeans::ScratchShape;

/// Fixed allowance for code, stacks and allocator slack (the binary's own
/// peak on a tiny frame is about 11 MiB).
pub const BASE_BYTES: u64 = 12 << 20;

/// What the budget needs to know about the frame and pipeline.
#[derive(Clone, Copy, Debug)]
pub struct BudgetInput {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Halo of the pipeline.
    pub halo: usize,
    /// Channels in the file (all are read and written).
    pub channels: usize,
    /// Bytes per pixel of all channels, in the file's sample types.
    pub bytes_all: usize,
    /// Channels the filter reads.
    pub filter_channels: usize,
    /// Bytes per pixel of the channels the filter reads, in the file's types.
    pub bytes_filter: usize,
    /// Channels the filter writes (denoised, `f32`).
    pub output_channels: usize,
    /// Planes a tile's filter holds at once (inputs, intermediates, outputs).
    pub filter_planes: usize,
    /// Rows per block of the input file (scanline block height or tile height).
    pub block_rows: usize,
    /// Rows per block of the output file.
    pub out_block_rows: usize,
    /// Worker threads.
    pub threads: usize,
    /// Threads the sink encodes blocks on.
    pub writer_threads: usize,
    /// What sizes the filter kernel's working memory (per thread).
    pub kernel: ScratchShape,
}

/// The chosen schedule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BandPlan {
    /// Rows per band (tile height).
    pub band_rows: usize,
    /// Tile width.
    pub tile_width: usize,
    /// The kernel's block height in a tile (`nlmeans::block_rows`: tall
    /// for one thread or [`wide_tiles`]).
    pub kernel_rows: usize,
    /// Capacity of each bounded queue between stages (0: rendezvous hand-off).
    pub queue_depth: usize,
    /// Bands whose tiles the filter stage queues at once (1 or
    /// [`MAX_BANDS_IN_FLIGHT`]): with two, a band's tiles start while the
    /// previous band's last tiles finish, so no thread waits at a band's end.
    pub bands_in_flight: usize,
    /// Estimated peak bytes.
    pub estimate_bytes: u64,
}

/// The most bands the filter stage queues at once.
pub const MAX_BANDS_IN_FLIGHT: usize = 2;

/// Estimated peak bytes for a schedule whose kernel blocks are at most
/// `kernel_rows` tall.
pub fn estimate(
    b: &BudgetInput,
    (band_rows, tile_width, kernel_rows): (usize, usize, usize),
    depth: usize,
    in_flight: usize,
) -> u64 {
    let w = b.width as u64;
    let h = b.halo as u64;
    let band = band_rows as u64;
    let window = (band + 2 * h).min(b.height as u64);
    let cache = w * (window + 2 * b.block_rows as u64) * b.bytes_all as u64;
    let band_in = w * (window * b.bytes_filter as u64 + band * (b.bytes_all - b.bytes_filter) as u64);
    let inputs = (depth as u64 + 2) * band_in;
    let planes = in_flight as u64 * w * window * b.filter_channels as u64 * 4;
    let tile = tile_width.min(b.width) as u64;
    let tiles = b.threads as u64 * 4 * (tile + 2 * h).min(w) * window * b.filter_planes as u64 * 4;
    let band_out = w * band * (b.output_channels as u64 * 4 + b.bytes_all as u64);
    let outputs = (depth + 1 + in_flight) as u64 * band_out;
    // The writer: rows waiting for their block, a band's compressed blocks
    // (stored raw when they do not shrink), and two block-sized buffers per
    // encoder.
    let out_px = b.output_channels as u64 * 4 + b.bytes_all as u64;
    let obr = b.out_block_rows.max(1) as u64;
    // A band completes at most `band / obr + 1` blocks at once.
    let encoders = (b.writer_threads.max(1) as u64).min(band / obr + 1);
    let writer = w * (band + obr) * out_px + w * band.max(obr) * out_px + encoders * 2 * w * obr * out_px;
    // The reader: blocks being decompressed and decoded, one per thread, twice
    // (a chunk's compressed bytes are freed once inflated).
    let decoding = b.threads as u64 * 2 * w * b.block_rows as u64 * b.bytes_all as u64;
    // The kernel's blocks: one per thread at a time, as tall as the engine
    // cuts them.
    let block_rows = band_rows.min(kernel_rows);
    let kernel = b.threads as u64 * b.kernel.bytes(tile as usize, block_rows);
    BASE_BYTES + cache + inputs + planes + tiles + outputs + writer + decoding + kernel
}

/// How many times `tile_size` a tile may be wide where [`wide_tiles`] allows.
pub const WIDE_TILES: usize = 2;

/// Whether a frame `b.width` wide gets tiles [`WIDE_TILES`] times
/// `tile_size` wide: where each band still has at least one of them per
/// thread (at the default tile size of 512: one thread always, two
/// threads from 1025 columns up, 1080p among them).
/// The kernel's blocks follow the tile's width (up to 1024 columns) and set
/// up half as many rows per sample, and in wide tiles they are tall
/// (`nlmeans::block_rows`): one block per tile and thread at 1080p on two
/// threads, fewer border rows recomputed. On the Zen 4 of sessions 39-42
/// (docs/performance.md): 0.93-0.94x the full filter's time on one thread;
/// on two threads at 1080p (one wide tile of one block per thread and
/// band, against tiles of 480 with 128-row blocks), from memory 0.966x by
/// the median of 86 alternating rounds' ratios (faster in 62; level in
/// session 41's second hour) and level over 94 more in session 42 (0.991
/// over 54, 1.001 over 40), the full filter's file run 0.98x (session
/// 42), the light layers alone 0.93x, the colour-only and feature-guided
/// kernels (one job) level, the default filter's file run level; at 4K on
/// two threads the wide tiles about 0.97-0.98x (session 39) and tall
/// blocks in them 0.96x by the median of 8 rounds. Neither the tiles nor
/// the blocks change a bit of the output.
pub fn wide_tiles(b: &BudgetInput, tile_size: usize) -> bool {
    tile_size > 0 && b.width.div_ceil(WIDE_TILES * tile_size) >= b.threads.max(1)
}

/// The kernel's block height for tiles that are (or are not) [`wide_tiles`].
fn kernel_rows(b: &BudgetInput, wide: bool) -> usize {
    crate::filter::nlmeans::block_rows(b.threads, wide)
}

/// The largest tiles (at most `tile_size` tall, and at most `tile_size`
/// wide, or [`WIDE_TILES`] times that where [`wide_tiles`] allows and the
/// wider tiles fit the limit with full bands, two in flight) that fit in
/// `limit_bytes`.
///
/// Most of the memory is proportional to full-width rows, so the band height
/// shrinks first; the tile width (whose cost is halo recomputation) shrinks
/// only once bands are a single row. The chosen sizes are then evened out
/// over the frame ([`even`]): a 1080-row frame gets three bands of 360 rows
/// rather than 512, 512 and a 56-row sliver whose tiles cost more per pixel
/// (the kernel recomputes a border around each block) and leave a thread idle.
pub fn plan(b: &BudgetInput, tile_size: usize, limit_bytes: u64) -> Result<BandPlan, Error> {
    let band = tile_size.max(1).min(b.height.max(1));
    if wide_tiles(b, tile_size) {
        let wide = (WIDE_TILES * tile_size).min(b.width.max(1));
        // Only at full band height with two bands in flight: under a tight
        // limit, taller bands (less halo) and a second band in flight (no
        // idle thread at a band's end) are worth more than wider tiles.
        let tall = kernel_rows(b, true);
        if estimate(b, (band, wide, tall), 0, MAX_BANDS_IN_FLIGHT) <= limit_bytes {
            return plan_from(b, band, (wide, tall), limit_bytes);
        }
    }
    plan_from(b, band, (tile_size.max(1).min(b.width.max(1)), kernel_rows(b, false)), limit_bytes)
}

/// [`plan`] from bands `band` rows tall and tiles `tile_w` wide (blocks at
/// most `kernel_rows` tall), shrunk until the estimate fits.
fn plan_from(
    b: &BudgetInput,
    mut band: usize,
    (mut tile_w, kernel_rows): (usize, usize),
    limit_bytes: u64,
) -> Result<BandPlan, Error> {
    // Rendezvous hand-offs: stages overlap, but no band waits in a queue, so
    // the peak stays close to the steady state whatever the timing.
    let depth = 0;
    loop {
        // A second band in flight goes before the band height (shorter bands
        // recompute more halo rows).
        let fits = [MAX_BANDS_IN_FLIGHT, 1]
            .into_iter()
            .find(|&n| estimate(b, (band, tile_w, kernel_rows), depth, n) <= limit_bytes);
        if let Some(in_flight) = fits {
            // Evening out never grows a size, so the estimate still fits.
            let (band, tile_w) = (even(b.height, band), even(b.width, tile_w));
            let estimate_bytes = estimate(b, (band, tile_w, kernel_rows), depth, in_flight);
            return Ok(BandPlan {
                band_rows: band,
                tile_width: tile_w,
                kernel_rows,
                queue_depth: depth,
                bands_in_flight: in_flight,
                estimate_bytes,
            });
        }
        let est = estimate(b, (band, tile_w, kernel_rows), depth, 1);
        if band > 1 {
            band = band.div_ceil(2);
        } else if tile_w > 1 {
            tile_w = tile_w.div_ceil(2);
        } else {
            return Err(Error::Budget { needed: est, limit: limit_bytes, width: b.width, height: b.height });
        }
    }
}

pub use crate::geom::even;

/// Keep the C allocator's resident set within the budget without a page
/// fault per fresh buffer (Linux glibc). Three settings, each measured
/// (docs/performance.md, "Bounded memory"):
///
/// - `M_MMAP_THRESHOLD = 4 MiB`, which also disables glibc's dynamic
///   threshold: larger buffers (a band's planes from 4K up) are mapped on
///   allocation and unmapped on free. Without it, after the first large
///   free glibc served multi-MiB buffers from arenas that kept them, and
///   the resident set exceeded the budget by half (436 MiB instead of 274
///   MiB on a 16384-wide frame). Until session 41 the threshold was 1 MiB;
///   the wide tiles' planes (1.6 MiB with their halo at 1080p, 1.9 MiB at
///   4K) and tall blocks' accumulators (up to 1.5 MiB) then were mapped,
///   faulted in and unmapped (a TLB shootdown each) per tile and block: the
///   1080p file run on two threads with wide tiles took 1.07x the time of
///   narrow ones, and on one thread (wide tiles since session 39) 1.05x
///   the time it takes at 4 MiB. At 2 MiB, a 1080p band's planes (3 MiB)
///   still were, and the filter from memory took 1.03x the time of glibc's
///   default policy; at 4 MiB the same time (docs/performance.md, session
///   41).
/// - `M_ARENA_MAX = 1`: every thread allocates from one arena, so the
///   buffers below the threshold (a tile's planes, a block's accumulators)
///   that one thread frees serve the next allocations, whichever thread
///   makes them.
/// - `M_TRIM_THRESHOLD` at its largest (2 GiB): the arena keeps the pages
///   it has grown to instead of giving back its free top (by default
///   whenever more than 128 KiB are free there, which setting the mmap
///   threshold leaves fixed). The arena's extent is what the budget's
///   peak already holds; given back, it was faulted in again by the next
///   band or frame. A batch of six 1080p frames with the full filter took
///   130 thousand page faults instead of 560 thousand (medians) and 0.93x
///   the time; 4K frames, whose band planes are mapped, the same time; a
///   16384x4096 frame under a 256 MiB limit 64 thousand faults instead
///   of 450 thousand, its peak 2-3 % higher, far under the limit
///   (docs/performance.md, session 43). The arena's pages stay the
///   process's until it exits.
///
/// With the earlier 256 KiB threshold and an arena per thread, every
/// block's and tile's buffers were fresh pages, each page a fault and each
/// free a TLB shootdown. Against that, a 1080p file run takes 12 % less
/// time; the peak on 16384-wide frames rose from about 252 MiB to 267-278
/// MiB, under the budget's estimate.
///
/// The CLI calls this at start, before it starts any thread; embedders who
/// want the budget to hold should call it once too, as early. It changes
/// process-wide allocator policy; elsewhere it does nothing.
pub fn bound_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only adjusts glibc's allocator parameters; it is
    // thread-safe and has no memory-safety preconditions.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
        libc::mallopt(libc::M_MMAP_THRESHOLD, 4 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

/// glibc's tunable (2.35 and later) that has its allocator ask the kernel
/// for transparent huge pages: `madvise(MADV_HUGEPAGE)` on each extension
/// of its heap, rounded to 2 MiB, and on each mapped chunk.
pub const HUGE_PAGES_TUNABLE: &str = "glibc.malloc.hugetlb=1";

/// The environment variable [`exec_with_huge_pages`] reads: `0` turns the
/// re-execution off; it is set to [`HUGE_PAGES_DONE`] in the re-executed
/// process, so that it happens at most once (even where glibc drops
/// `GLIBC_TUNABLES`, as it does for set-user-ID programs).
pub const HUGE_PAGES_ENV: &str = "NLDENOISE_HUGE_PAGES";

/// [`HUGE_PAGES_ENV`]'s value in the re-executed process.
pub const HUGE_PAGES_DONE: &str = "re-executed";

/// Whether this process started with [`HUGE_PAGES_TUNABLE`] in
/// `GLIBC_TUNABLES` (by [`exec_with_huge_pages`] or its caller).
pub fn huge_pages_requested() -> bool {
    std::env::var_os("GLIBC_TUNABLES")
        .is_some_and(|t| t.to_string_lossy().split(':').any(|kv| kv == HUGE_PAGES_TUNABLE))
}

/// Runs this program again, in the same process, with
/// [`HUGE_PAGES_TUNABLE`] added to `GLIBC_TUNABLES`, so that the memory
/// its allocator takes from the kernel comes in 2 MiB pages where the
/// kernel's transparent huge pages are `madvise` (the common default,
/// under which glibc's heap otherwise gets none). The tunable is read
/// only when a program starts, hence the `exec`.
///
/// Measured on an Intel Xeon (2 cores under KVM, THP `madvise`, Linux
/// 6.18; docs/performance.md, session 51): a cold 1080p run of the full
/// filter took 16 thousand page faults instead of 170 thousand, 0.23-0.34
/// s of system time instead of 0.40-0.52 s, and 0.90x and 0.97x the wall
/// time by two A/Bs' medians; the 1080p file run 1.5 thousand faults
/// instead of 109 thousand and 0.94x the CPU time, the same output bytes;
/// a run under `--memory-limit 192M` the same peak. On the AMD Zen 4
/// host of session 43 the same tunable had cost system time instead
/// (1.1x the run's time), probably the kernel compacting memory too
/// fragmented for huge pages (defrag `madvise` compacts on the fault,
/// not measured there); such a host can turn this off with
/// `NLDENOISE_HUGE_PAGES=0`.
///
/// Returns without doing anything when `GLIBC_TUNABLES` already names
/// `glibc.malloc.hugetlb` (the caller's own choice), when
/// [`HUGE_PAGES_ENV`] is `0` (a user who opts out) or [`HUGE_PAGES_DONE`]
/// (the re-execution itself), under valgrind (which an `exec` of
/// `/proc/self/exe` would break), when the kernel's huge pages are `never` or
/// unknown, and when the `exec` fails (the program then runs as it is).
/// Call it first thing in `main`, before any thread starts; it is for
/// programs (the CLI, the benchmarks), not for libraries. Elsewhere than
/// Linux with glibc it does nothing.
pub fn exec_with_huge_pages() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::process::CommandExt;
        let tunables = std::env::var_os("GLIBC_TUNABLES").unwrap_or_default();
        let choice = std::env::var_os(HUGE_PAGES_ENV);
        // Under valgrind, whose preload library is in LD_PRELOAD, an exec of
        // /proc/self/exe would start valgrind's own tool, which refuses to run.
        let under_valgrind = std::env::var_os("LD_PRELOAD").is_some_and(|p| p.to_string_lossy().contains("vgpreload"));
        if tunables.to_string_lossy().contains("glibc.malloc.hugetlb")
            || choice.is_some_and(|v| v == "0" || v == HUGE_PAGES_DONE)
            || under_valgrind
        {
            return;
        }
        match std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled") {
            Ok(mode) if !mode.contains("[never]") => {}
            _ => return,
        }
        let mut value = tunables;
        if !value.is_empty() {
            value.push(":");
        }
        value.push(HUGE_PAGES_TUNABLE);
        let mut args = std::env::args_os();
        let arg0 = args.next().unwrap_or_default();
        // `exec` returns only if it failed; the program then goes on as it is.
        let _ = std::process::Command::new("/proc/self/exe")
            .arg0(arg0)
            .args(args)
            .env("GLIBC_TUNABLES", value)
            .env(HUGE_PAGES_ENV, HUGE_PAGES_DONE)
            .exec();
    }
}

/// A default limit: half of the memory available now (at least 256 MiB).
pub fn default_limit_bytes() -> u64 {
    let avail = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        s.lines()
            .find(|l| l.starts_with("MemAvailable:"))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kb| kb.parse::<u64>().ok())
    });
    avail.map_or(4 << 30, |kb| (kb * 1024 / 2).max(256 << 20))
}

/// Parse `512M`, `2G`, `1.5GiB`, `300000000` into bytes.
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let n: f64 = num.parse().map_err(|_| format!("{s:?} is not a size (e.g. 512M, 2G)"))?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" | "kib" => 1024.0,
        "m" | "mb" | "mib" => 1024.0 * 1024.0,
        "g" | "gb" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tb" | "tib" => 1024.0f64.powi(4),
        other => {
            return Err(format!("unknown size unit {other:?} in {s:?} (use K, M, G, T)"));
        }
    };
    let bytes = n * mult;
    if !bytes.is_finite() || bytes < 1.0 {
        return Err(format!("{s:?} is not a positive size"));
    }
    Ok(bytes as u64)
}

/// The peak resident memory of this process so far (Linux `VmHWM`), in bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse::<u64>().ok().map(|kb| kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shared scenes' layout: 38 channels (24 half, 14 float), 16 read by the filter.
    fn input(width: usize, height: usize) -> BudgetInput {
        BudgetInput {
            width,
            height,
            halo: 21,
            channels: 38,
            bytes_all: 24 * 2 + 14 * 4,
            filter_channels: 16,
            bytes_filter: 9 * 2 + 7 * 4,
            output_channels: 3,
            filter_planes: 22,
            block_rows: 16,
            out_block_rows: 16,
            threads: 2,
            writer_threads: 2,
            kernel: ScratchShape { search_radius: 10, patch_radius: 3, jobs: 2, accumulators: 8, guides: 3 },
        }
    }

    #[test]
    fn sizes_are_evened_out_over_the_frame() {
        assert_eq!(even(1080, 512), 360);
        assert_eq!(even(1920, 512), 480);
        assert_eq!(even(2160, 512), 432);
        assert_eq!(even(1024, 512), 512);
        assert_eq!(even(100, 512), 100);
        assert_eq!(even(513, 512), 257);
        let p = plan(&BudgetInput { threads: 4, ..input(1920, 1080) }, 512, 8 << 30).unwrap();
        assert_eq!((p.band_rows, p.tile_width, p.bands_in_flight), (360, 480, MAX_BANDS_IN_FLIGHT));
        // Never larger than asked, and the parts cover the frame in the same count.
        for total in 1..600 {
            for size in [1, 7, 64, 256, 512] {
                let e = even(total, size);
                assert!(e <= size.max(1) && total.div_ceil(e) == total.div_ceil(size), "{total} {size}");
            }
        }
    }

    #[test]
    fn plan_fits_the_limit_and_shrinks_tiles() {
        let b = input(16384, 16384);
        // Wide tiles where they fit at full band height (`wide_tiles`).
        let big = plan(&b, 256, 8 << 30).unwrap();
        assert_eq!((big.band_rows, big.tile_width), (256, 2 * 256));
        let small = plan(&b, 256, 512 << 20).unwrap();
        assert!(small.estimate_bytes <= 512 << 20);
        assert!(small.band_rows < 256);
        assert_eq!(small.tile_width, 256, "tiles keep their width while bands can shrink");
        // Between one band's and two bands' estimates, the plan keeps its
        // band height and queues one band at a time.
        let (one, two) = (estimate(&b, (256, 256, 128), 0, 1), estimate(&b, (256, 256, 128), 0, 2));
        assert!(one < two);
        let p = plan(&b, 256, (one + two) / 2).unwrap();
        assert_eq!((p.band_rows, p.tile_width, p.kernel_rows, p.bands_in_flight), (256, 256, 128, 1));
        assert_eq!(p.estimate_bytes, one);
        let e = plan(&b, 256, 32 << 20).unwrap_err().to_string();
        assert!(e.contains("memory limit"), "{e}");
    }

    #[test]
    fn wide_tiles_of_tall_blocks_where_every_thread_gets_one_per_band() {
        let with = |w: usize, h: usize, threads: usize| BudgetInput { threads, ..input(w, h) };
        let shape = |p: BandPlan| (p.band_rows, p.tile_width, p.kernel_rows);
        // Two threads: 1080p and 4K get 960-wide tiles of tall blocks.
        assert_eq!(shape(plan(&with(1920, 1080, 2), 512, 8 << 30).unwrap()), (360, 960, 384));
        assert_eq!(shape(plan(&with(3840, 2160, 2), 512, 8 << 30).unwrap()), (432, 960, 384));
        // Three threads at 1080p: two wide tiles per band are too few.
        assert_eq!(shape(plan(&with(1920, 1080, 3), 512, 8 << 30).unwrap()), (360, 480, 128));
        assert_eq!(shape(plan(&with(3840, 2160, 3), 512, 8 << 30).unwrap()), (432, 960, 384));
        // One thread: wide from one wide tile per band up, tall blocks always.
        assert_eq!(shape(plan(&with(1920, 1080, 1), 512, 8 << 30).unwrap()), (360, 960, 384));
        assert_eq!(shape(plan(&with(1024, 1080, 1), 512, 8 << 30).unwrap()), (360, 1024, 384));
        assert_eq!(shape(plan(&with(1024, 1080, 2), 512, 8 << 30).unwrap()), (360, 512, 128));
        // Whatever the kernel: colour-only, one job with guides, two jobs without.
        for kernel in [
            ScratchShape { jobs: 1, accumulators: 4, guides: 0, ..input(1920, 1080).kernel },
            ScratchShape { jobs: 1, ..input(1920, 1080).kernel },
            ScratchShape { guides: 0, ..input(1920, 1080).kernel },
        ] {
            let b = BudgetInput { kernel, ..input(1920, 1080) };
            assert_eq!(shape(plan(&b, 512, 8 << 30).unwrap()), (360, 960, 384));
        }
        // A limit the wide tiles' full bands do not fit: the usual width,
        // bands shrunk from there.
        let b = with(3840, 2160, 2);
        let limit = estimate(&b, (512, 1024, 384), 0, MAX_BANDS_IN_FLIGHT) - 1;
        assert!(estimate(&b, (512, 512, 128), 0, MAX_BANDS_IN_FLIGHT) <= limit, "the narrow tiles fit this limit");
        let p = plan(&b, 512, limit).unwrap();
        assert_eq!((shape(p), p.bands_in_flight), ((432, 480, 128), MAX_BANDS_IN_FLIGHT));
        assert!(p.estimate_bytes <= limit);
    }

    /// The writer's scratch is counted per encoder, and a band never keeps
    /// more encoders busy than it completes blocks.
    #[test]
    fn writer_scratch_is_counted_per_busy_encoder() {
        let with = |threads: usize, band: usize| {
            estimate(&BudgetInput { writer_threads: threads, ..input(4096, 4096) }, (band, 256, 128), 0, 1)
        };
        let block = 2 * 4096 * 16 * (3 * 4 + 24 * 2 + 14 * 4) as u64;
        assert_eq!(with(2, 64) - with(1, 64), block);
        assert_eq!(with(64, 64), with(5, 64), "64 rows complete at most 5 blocks of 16");
        assert!(with(5, 64) > with(4, 64));
        assert_eq!(with(8, 8), with(1, 8), "8 rows complete at most one block");
    }

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("512M").unwrap(), 512 << 20);
        assert_eq!(parse_size("2G").unwrap(), 2 << 30);
        assert_eq!(parse_size("1.5GiB").unwrap(), 3 << 29);
        assert_eq!(parse_size("1000").unwrap(), 1000);
        assert!(parse_size("12Q").is_err());
        assert!(parse_size("0").is_err());
    }
}
