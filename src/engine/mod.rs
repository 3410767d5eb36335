//! The streaming tiled engine: the only module that knows threads.
//!
//! A frame flows through in row bands. The **reader** (the calling
//! [`RowSource`]) produces, for each band, the filter's channels over the band
//! plus the halo above and below, and the other channels over the band; the
//! **filter** stage cuts the band into tiles and filters them in parallel
//! (rayon), each tile reading only `(tile ⊕ halo) ∩ frame`, with up to
//! [`BandPlan::bands_in_flight`] bands' tiles queued at once (no barrier at
//! a band's end); the **writer**
//! hands complete rows, in increasing y, to the [`RowSink`]. Bounded
//! `crossbeam-channel` queues connect the stages, so a slow stage holds the
//! others back and memory stays within the [`budget`]. Because every filter
//! stage is defined on frame coordinates (see `filter`), the output equals
//! whole-frame filtering bit for bit, whatever the tile size or thread count.

pub mod budget;
pub mod synthetic;

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::bounded;
use rayon::prelude::*;
use tracing::{debug, info, info_span};

use crate::error::Error;
use crate::exrio::roles::ChannelRoles;
use crate::filter::nlmeans::ScratchShape;
use crate::filter::{FrameInputs, Params, Pipeline, PreparedRegion};
use crate::geom::Rect;
use crate::image::{ChannelRows, Plane, Samples};
use budget::{BandPlan, BudgetInput};

/// Where the engine reads rows from (a file, a renderer, ...).
pub trait RowSource: Send {
    /// The frame's data window.
    fn data_window(&self) -> Rect;
    /// Channel names, in the order `read_rows` indexes them.
    fn channel_names(&self) -> Vec<String>;
    /// Rows per storage block (a hint for the memory budget).
    fn block_rows(&self) -> usize {
        16
    }
    /// Bytes per sample of each channel as the source stores them (a hint
    /// for the memory budget; 4 when unknown).
    fn sample_bytes(&self) -> Vec<usize> {
        vec![4; self.channel_names().len()]
    }
    /// Which channels the run's [`read_rows`](RowSource::read_rows) calls
    /// will ask for: called once, before the first of them. A hint: a source
    /// may skip decoding the others (with [`StreamOptions::carry`] false,
    /// every channel the filter does not use); the default ignores it.
    fn select_channels(&mut self, _channels: &[usize]) {}
    /// The given channels over full-width `rows` (inside the data window).
    /// Calls come with non-decreasing `rows.y0`; consecutive requests overlap
    /// by the halo.
    fn read_rows(&mut self, channels: &[usize], rows: Rect) -> Result<Vec<ChannelRows>, Error>;
}

/// Where the engine writes denoised rows.
pub trait RowSink: Send {
    /// The next full-width rows of every channel of the sink (the source's
    /// channels, or with [`StreamOptions::carry`] false its denoised ones
    /// alone, in the source's channel order), in increasing y, each row
    /// exactly once.
    fn write_rows(&mut self, rows: Vec<ChannelRows>) -> Result<(), Error>;
    /// All rows were written: complete the output.
    fn finish(&mut self) -> Result<(), Error>;
}

/// How to stream.
#[derive(Clone, Copy, Debug)]
pub struct StreamOptions {
    /// Largest tile size in pixels (the tile height is the band height); the
    /// plan evens the sizes out over the frame (`budget::even`).
    pub tile_size: usize,
    /// Worker threads (0 = one per core).
    pub threads: usize,
    /// Memory limit in bytes.
    pub memory_limit: u64,
    /// Write denoised channels as f16.
    pub half: bool,
    /// Rows per block of the sink (a hint for the memory budget).
    pub out_block_rows: usize,
    /// The ZIP level of a file sink (`exrio::zip::LEVELS`).
    pub zip_level: i32,
    /// Carry the channels that are not denoised through to the sink
    /// (default); false: the sink gets the denoised channels alone, and the
    /// source's other channels are not read. The memory estimate still
    /// counts the carried rows (an upper bound).
    pub carry: bool,
}

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            tile_size: 512,
            threads: 0,
            memory_limit: budget::default_limit_bytes(),
            half: false,
            out_block_rows: 16,
            zip_level: crate::exrio::zip::DEFAULT_LEVEL,
            carry: true,
        }
    }
}

/// What a streaming run did.
#[derive(Clone, Debug)]
pub struct StreamReport {
    /// The schedule chosen by the budget.
    pub plan: BandPlan,
    /// The pipeline's halo.
    pub halo: usize,
    /// Bands processed.
    pub bands: usize,
    /// Tiles filtered.
    pub tiles: usize,
    /// Pixels filtered including halo recomputation, over output pixels
    /// (1.0 = no overhead): `sum over tiles of |(tile ⊕ halo) ∩ frame| / |frame|`.
    pub halo_overhead: f64,
    /// Time the reader spent reading and decoding.
    pub read_time: Duration,
    /// Time the filter stage spent filtering.
    pub filter_time: Duration,
    /// Time the writer spent handing rows to the sink.
    pub write_time: Duration,
    /// Time the workers spent in the NL-means kernel's blocks, summed over
    /// threads: over `threads x` the run's wall time, the share of the
    /// workers' time in the kernel (the rest is the stages before it, the
    /// tiles' copies, and waits).
    pub kernel_time: Duration,
    /// Pixels that had an unusable input sample (NaN, infinite, out of
    /// range) repaired before filtering (`filter::repair`).
    pub repaired: usize,
}

/// What the filter stage counts.
#[derive(Default)]
struct FilterCounters {
    kernel: Duration,
    tiles: usize,
    filtered_px: usize,
    repaired: usize,
}

/// The target of the engine's progress events: one `TRACE` event per
/// filtered tile, with the fields `done` and `total` (output pixels of the
/// frame filtered so far, and in all). Events of tiles filtered in parallel
/// may arrive out of order: the largest `done` is the progress. A
/// `tracing` layer filtering on this target drives a progress display (the
/// CLI's bar) without the engine knowing about it.
pub const PROGRESS_TARGET: &str = "nldenoise::progress";

struct BandIn {
    band: Rect,
    /// The filter's channels over `(band ⊕ halo rows) ∩ frame`.
    filter_rows: Vec<ChannelRows>,
    /// The other channels over the band.
    other_rows: Vec<ChannelRows>,
}

/// Indices of the source's channels that the roles use, which are denoised
/// outputs, which are read only to be carried through, and which the sink
/// gets (in its order).
struct ChannelPlan {
    filter_idx: Vec<usize>,
    other_idx: Vec<usize>,
    output_idx: Vec<usize>,
    sink_idx: Vec<usize>,
}

impl ChannelPlan {
    /// Whether the sink gets channel `i` of the source.
    fn sinks(&self, i: usize) -> bool {
        self.sink_idx.binary_search(&i).is_ok()
    }
}

fn channel_plan(names: &[String], roles: &ChannelRoles, carry: bool) -> Result<ChannelPlan, Error> {
    let index = |n: &str| {
        names
            .iter()
            .position(|c| c == n)
            .ok_or_else(|| Error::InvalidInput(format!("channel {n} is not in the source")))
    };
    let mut filter_idx = Vec::new();
    for n in roles.inputs_channels() {
        let i = index(&n)?;
        if !filter_idx.contains(&i) {
            filter_idx.push(i);
        }
    }
    let output_idx: Vec<usize> = roles.outputs().iter().map(|n| index(n)).collect::<Result<_, _>>()?;
    let (other_idx, sink_idx) = if carry {
        ((0..names.len()).filter(|i| !filter_idx.contains(i)).collect(), (0..names.len()).collect())
    } else {
        let mut sink: Vec<usize> = output_idx.clone();
        sink.sort_unstable();
        (Vec::new(), sink)
    };
    Ok(ChannelPlan { filter_idx, other_idx, output_idx, sink_idx })
}

/// The source channels (indices into `names`, in its order) that
/// [`denoise_stream`] hands its sink: every channel, or with `carry` false
/// the denoised ones alone. A sink that needs its channel list up front (a
/// file's header) takes it from here.
pub fn sink_channels(names: &[String], roles: &ChannelRoles, carry: bool) -> Result<Vec<usize>, Error> {
    Ok(channel_plan(names, roles, carry)?.sink_idx)
}

/// The halo, the schedule the memory budget allows, and the thread count for
/// streaming `source` with these roles, parameters and options.
pub fn plan_stream(
    source: &dyn RowSource,
    roles: &ChannelRoles,
    params: &Params,
    opts: &StreamOptions,
) -> Result<(usize, BandPlan, usize), Error> {
    let cp = channel_plan(&source.channel_names(), roles, opts.carry)?;
    plan_with(source, roles, params, opts, &cp)
}

fn plan_with(
    source: &dyn RowSource,
    roles: &ChannelRoles,
    params: &Params,
    opts: &StreamOptions,
    cp: &ChannelPlan,
) -> Result<(usize, BandPlan, usize), Error> {
    let frame = source.data_window();
    let channels = source.channel_names().len();
    let sample_bytes = source.sample_bytes();
    let shape = roles.shape();
    let halo = Pipeline::new(*params, shape.clone()).halo();
    let threads =
        if opts.threads == 0 { std::thread::available_parallelism().map_or(1, |n| n.get()) } else { opts.threads };
    let plan = budget::plan(
        &BudgetInput {
            width: frame.width(),
            height: frame.height(),
            halo,
            channels,
            bytes_all: sample_bytes.iter().sum(),
            filter_channels: cp.filter_idx.len(),
            bytes_filter: cp.filter_idx.iter().map(|&i| sample_bytes[i]).sum(),
            output_channels: cp.output_idx.len(),
            // Plus the guides' half-float copies (`nlmeans::GuideFeature::half`):
            // half a plane per feature channel.
            filter_planes: cp.filter_idx.len()
                + 2 * cp.output_idx.len()
                + roles.features.iter().map(|f| f.channels.len()).sum::<usize>().div_ceil(2),
            block_rows: source.block_rows(),
            out_block_rows: opts.out_block_rows,
            threads,
            // The EXR sink encodes on as many threads of its own
            // (the `threads` of `ExrSink::create`, as `api` creates it).
            writer_threads: threads,
            kernel: ScratchShape {
                search_radius: params.search_radius,
                patch_radius: params.patch_radius,
                // Every denoised channel's numerator, one denominator per job.
                jobs: shape.layers.max(1),
                accumulators: cp.output_idx.len() + shape.layers.max(1),
                guides: shape.feature_has_variance.len(),
            },
        },
        opts.tile_size,
        opts.memory_limit,
    )?;
    Ok((halo, plan, threads))
}

/// The thinnest first or last band [`stream_bands`] cuts.
const END_BAND_MIN: usize = 64;

/// The row bands a frame streams in, none taller than `rows`: a quarter
/// band (at least [`END_BAND_MIN`] rows) first and last, and the rows
/// between cut into bands of (nearly) equal height. Until the first band is
/// read, no core filters, and after the last band is filtered, its rows are
/// still to be encoded: thin end bands shorten both waits. A frame of at
/// most `rows` rows is one band; bands under twice [`END_BAND_MIN`] (the
/// memory-bounded plans' short bands) are not cut thinner, as a thin band's
/// borders (the kernel's `4f + dy` extra distance rows, the halo) would cost
/// more than they save. The bands do not change a bit of the output.
fn stream_bands(frame: Rect, rows: usize) -> Vec<Rect> {
    let (h, rows) = (frame.height(), rows.max(1));
    let end = rows.div_ceil(4).max(END_BAND_MIN);
    if h <= rows || rows < 2 * END_BAND_MIN {
        return frame.row_bands(rows);
    }
    let band = |y0: i64, y1: i64| Rect { y0, y1, ..frame };
    let middle = band(frame.y0 + end as i64, frame.y1 - end as i64);
    let mut out = vec![band(frame.y0, middle.y0)];
    out.extend(middle.row_bands(crate::geom::even(middle.height(), rows)));
    out.push(band(middle.y1, frame.y1));
    out
}

/// Denoise a frame from `source` to `sink` in bounded memory.
pub fn denoise_stream(
    source: &mut dyn RowSource,
    sink: &mut dyn RowSink,
    roles: &ChannelRoles,
    params: &Params,
    opts: &StreamOptions,
) -> Result<StreamReport, Error> {
    params.validate()?;
    let frame = source.data_window();
    let names = source.channel_names();
    let cp = channel_plan(&names, roles, opts.carry)?;
    let (halo, plan, threads) = plan_with(source, roles, params, opts, &cp)?;
    info!(
        "plan: bands of {} rows, tiles {}x{} (kernel blocks up to {} rows), halo {halo}, queue depth {}, {} bands in flight, estimated peak {:.1} MiB of {:.1} MiB allowed",
        plan.band_rows,
        plan.tile_width,
        plan.band_rows,
        plan.kernel_rows,
        plan.queue_depth,
        plan.bands_in_flight,
        plan.estimate_bytes as f64 / 1048576.0,
        opts.memory_limit as f64 / 1048576.0
    );
    let pool =
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| Error::Internal(e.to_string()))?;
    let bands = stream_bands(frame, plan.band_rows);
    let n_bands = bands.len();

    let (in_tx, in_rx) = bounded::<Result<BandIn, Error>>(plan.queue_depth);
    let (out_tx, out_rx) = bounded::<Result<Vec<ChannelRows>, Error>>(plan.queue_depth);
    let mut report = StreamReport {
        plan,
        halo,
        bands: n_bands,
        tiles: 0,
        halo_overhead: 0.0,
        read_time: Duration::ZERO,
        filter_time: Duration::ZERO,
        write_time: Duration::ZERO,
        kernel_time: Duration::ZERO,
        repaired: 0,
    };
    let mut read: Vec<usize> = cp.filter_idx.iter().chain(&cp.other_idx).copied().collect();
    read.sort_unstable();
    source.select_channels(&read);
    let names_ref = &names;
    let cp_ref = &cp;
    let pool_ref = &pool;

    let (read_res, filter_res, write_res) = std::thread::scope(|s| {
        // Reader.
        let reader = s.spawn(move || {
            let mut spent = Duration::ZERO;
            for (i, band) in bands.into_iter().enumerate() {
                let _span = info_span!("read", band = i).entered();
                let t = Instant::now();
                let window = Rect { y0: band.y0 - halo as i64, y1: band.y1 + halo as i64, ..band }.intersect(&frame);
                let res = pool_ref.install(|| -> Result<BandIn, Error> {
                    let filter_rows = source.read_rows(&cp_ref.filter_idx, window)?;
                    let other_rows = source.read_rows(&cp_ref.other_idx, band)?;
                    Ok(BandIn { band, filter_rows, other_rows })
                });
                spent += t.elapsed();
                let failed = res.is_err();
                if in_tx.send(res).is_err() || failed {
                    break;
                }
            }
            spent
        });
        // Filter: up to `plan.bands_in_flight` bands' tiles queued in the pool
        // at once, so the next band's tiles start while the last tiles of a band
        // finish (no thread waits at a band's end); bands leave in order.
        let filter = s.spawn(move || {
            let ctx = BandCtx {
                frame,
                halo,
                plan: &plan,
                roles,
                params,
                names: names_ref,
                cp: cp_ref,
                half: opts.half,
                kernel_ns: AtomicU64::new(0),
            };
            let mut counters = FilterCounters::default();
            let (done_px, cancel) = (AtomicUsize::new(0), AtomicBool::new(false));
            let (done_px, cancel) = (&done_px, &cancel);
            let mut busy = Busy::default();
            pool_ref.in_place_scope(|scope| {
                let mut in_flight: VecDeque<InFlight> = VecDeque::new();
                // Hand the oldest band to the writer; false once the run stops.
                let finish_oldest =
                    |in_flight: &mut VecDeque<InFlight>, busy: &mut Busy, counters: &mut FilterCounters| {
                        let Some(band) = in_flight.pop_front() else { return true };
                        let res = band.finish(&ctx, counters);
                        if in_flight.is_empty() {
                            busy.stop();
                        }
                        let failed = res.is_err();
                        out_tx.send(res).is_ok() && !failed
                    };
                let mut stopped = false;
                for msg in in_rx {
                    busy.start();
                    let (work, carried) = match msg {
                        Ok(b) => {
                            let _span = info_span!("filter", y0 = b.band.y0).entered();
                            let (work, carried) =
                                prepare_band(b, &ctx, in_flight.is_empty().then_some(pool_ref), &mut counters);
                            (Arc::new(work), carried)
                        }
                        Err(e) => {
                            let _ = out_tx.send(Err(e));
                            stopped = true;
                            break;
                        }
                    };
                    let (tx, rx) = bounded(work.tiles.len());
                    for &t in &work.tiles {
                        let (work, tx) = (Arc::clone(&work), tx.clone());
                        let ctx = &ctx;
                        scope.spawn(move |scope| start_tile(scope, work, t, ctx, (tx, done_px, cancel)));
                    }
                    in_flight.push_back(InFlight { work, results: rx, carried });
                    if in_flight.len() >= plan.bands_in_flight
                        && !finish_oldest(&mut in_flight, &mut busy, &mut counters)
                    {
                        stopped = true;
                        break;
                    }
                }
                while !stopped && !in_flight.is_empty() {
                    stopped = !finish_oldest(&mut in_flight, &mut busy, &mut counters);
                }
                // After a failure the bands still in flight are dropped: their
                // tiles are skipped, and the scope waits for them to return.
                cancel.store(true, Ordering::Relaxed);
            });
            counters.kernel = Duration::from_nanos(ctx.kernel_ns.load(Ordering::Relaxed));
            (busy.total, counters)
        });
        // Writer (this thread).
        let mut spent = Duration::ZERO;
        let mut written = 0usize;
        let mut result: Result<(), Error> = Ok(());
        for msg in out_rx.iter() {
            let t = Instant::now();
            let _span = info_span!("write", band = written).entered();
            let r = msg.and_then(|rows| sink.write_rows(rows));
            spent += t.elapsed();
            if let Err(e) = r {
                result = Err(e);
                break;
            }
            written += 1;
        }
        drop(out_rx);
        let read = reader.join().map_err(|_| Error::Internal("the reader thread panicked".into()));
        let filt = filter.join().map_err(|_| Error::Internal("the filter thread panicked".into()));
        if result.is_ok() && written != n_bands {
            result = Err(Error::Internal(format!("only {written} of {n_bands} bands were produced")));
        }
        (read, filt, result.map(|_| spent))
    });
    report.read_time = read_res?;
    let (ft, counters) = filter_res?;
    report.filter_time = ft;
    report.tiles = counters.tiles;
    report.halo_overhead = counters.filtered_px as f64 / frame.area().max(1) as f64;
    report.repaired = counters.repaired;
    report.kernel_time = counters.kernel;
    report.write_time = write_res?;
    let t = Instant::now();
    sink.finish()?;
    report.write_time += t.elapsed();
    info!(
        "streamed {} bands, {} tiles: read {:.2}s, filter {:.2}s, write {:.2}s (stage busy times; stages overlap); kernel {:.2}s over all threads; halo recomputation x{:.3}",
        report.bands,
        report.tiles,
        report.read_time.as_secs_f64(),
        report.filter_time.as_secs_f64(),
        report.write_time.as_secs_f64(),
        report.kernel_time.as_secs_f64(),
        report.halo_overhead
    );
    info!("{} pixels had NaN, infinite or out-of-range inputs and were repaired", report.repaired);
    Ok(report)
}

/// What every band of a run shares.
struct BandCtx<'a> {
    frame: Rect,
    halo: usize,
    plan: &'a BandPlan,
    roles: &'a ChannelRoles,
    params: &'a Params,
    names: &'a [String],
    cp: &'a ChannelPlan,
    half: bool,
    /// Nanoseconds the workers spent in kernel blocks, summed.
    kernel_ns: AtomicU64,
}

/// A band being filtered, shared by its tile tasks.
struct BandWork {
    band: Rect,
    inputs: Arc<FrameInputs>,
    tiles: Vec<Rect>,
    /// Each finished tile's denoised channels (the sink's order), joined
    /// into the band's rows once every tile is done ([`band_rows`]).
    tile_outputs: Mutex<Vec<(Rect, Vec<Plane>)>>,
    repaired: AtomicUsize,
}

/// A band whose tiles are queued or running.
struct InFlight {
    work: Arc<BandWork>,
    /// One message per tile.
    results: crossbeam_channel::Receiver<Result<(), Error>>,
    /// The channels carried through (not denoised), by source index.
    carried: Vec<(usize, ChannelRows)>,
}

impl InFlight {
    /// Wait for the band's tiles and assemble its rows (every channel of the
    /// sink, in the source's order).
    fn finish(self, ctx: &BandCtx<'_>, counters: &mut FilterCounters) -> Result<Vec<ChannelRows>, Error> {
        let InFlight { work, results, carried } = self;
        let mut first_err = None;
        for _ in 0..work.tiles.len() {
            match results.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    first_err.get_or_insert(e);
                }
                Err(_) => {
                    first_err.get_or_insert(Error::Internal("a tile worker panicked".into()));
                }
            }
        }
        if let Some(e) = first_err {
            return Err(e);
        }
        counters.repaired += work.repaired.load(Ordering::Relaxed);
        let tile_outputs = std::mem::take(
            &mut *work.tile_outputs.lock().map_err(|_| Error::Internal("a tile worker panicked".into()))?,
        );
        let out_planes = band_rows(work.band, ctx.cp.output_idx.len(), tile_outputs)?;
        // (The tasks may still hold their handles for a moment: the planes
        // are taken, not the `Arc` unwrapped.)
        let mut out: Vec<Option<ChannelRows>> = (0..ctx.names.len()).map(|_| None).collect();
        for (i, r) in carried {
            out[i] = Some(r);
        }
        for (&i, p) in ctx.cp.output_idx.iter().zip(out_planes) {
            let samples = if ctx.half { Samples::half_from_f32(p.data()) } else { Samples::F32(p.into_vec()) };
            out[i] = Some(ChannelRows { rect: work.band, samples });
        }
        debug!("band {:?}: {} tiles", work.band, work.tiles.len());
        ctx.cp
            .sink_idx
            .iter()
            .map(|&i| {
                out[i]
                    .take()
                    .ok_or_else(|| Error::Internal(format!("channel {} missing from band output", ctx.names[i])))
            })
            .collect()
    }
}

/// The band's planes of `channels` denoised channels from its tiles'
/// (`(tile, planes)`, any order; the tiles cover the band in a grid): each
/// row the tiles' rows one after the other in `x`. Each sample is written
/// once, where filling the band's planes first and pasting each tile into
/// them wrote it twice; each channel's tile planes are freed once that
/// channel is joined.
fn band_rows(band: Rect, channels: usize, mut tiles: Vec<(Rect, Vec<Plane>)>) -> Result<Vec<Plane>, Error> {
    tiles.sort_by_key(|(t, _)| (t.y0, t.x0));
    let rects: Vec<Rect> = tiles.iter().map(|(t, _)| *t).collect();
    let mut planes: Vec<Vec<Option<Plane>>> =
        tiles.into_iter().map(|(_, p)| p.into_iter().map(Some).collect()).collect();
    let mismatch = || Error::Internal(format!("the tiles of band {band:?} do not cover it"));
    if planes.iter().any(|p| p.len() != channels) {
        return Err(mismatch());
    }
    (0..channels)
        .map(|c| {
            let parts: Vec<Plane> = planes.iter_mut().map(|p| p[c].take().expect("each channel taken once")).collect();
            let mut data = Vec::with_capacity(band.area());
            for y in band.y0..band.y1 {
                let mut x = band.x0;
                for (t, part) in rects.iter().zip(&parts).filter(|(t, _)| t.y0 <= y && y < t.y1) {
                    if t.x0 != x || part.rect() != *t {
                        return Err(mismatch());
                    }
                    data.extend_from_slice(part.row(y, t.x0, t.x1));
                    x = t.x1;
                }
                if x != band.x1 {
                    return Err(mismatch());
                }
            }
            Plane::from_vec(band, data).ok_or_else(mismatch)
        })
        .collect()
}

/// The time a stage had work in hand.
#[derive(Default)]
struct Busy {
    since: Option<Instant>,
    total: Duration,
}

impl Busy {
    fn start(&mut self) {
        self.since.get_or_insert_with(Instant::now);
    }

    fn stop(&mut self) {
        if let Some(t) = self.since.take() {
            self.total += t.elapsed();
        }
    }
}

/// A band's `f32` input planes and its tiles.
fn prepare_band(
    b: BandIn,
    ctx: &BandCtx<'_>,
    pool: Option<&rayon::ThreadPool>,
    counters: &mut FilterCounters,
) -> (BandWork, Vec<(usize, ChannelRows)>) {
    let BandIn { band, filter_rows, other_rows } = b;
    let cp = ctx.cp;
    // Filter channels that are carried (not denoised) go out over the band only.
    let mut carried: Vec<(usize, ChannelRows)> = Vec::new();
    for (&i, r) in cp.filter_idx.iter().zip(&filter_rows) {
        if !cp.output_idx.contains(&i) && cp.sinks(i) {
            carried.push((i, r.rows(band.y0, band.y1)));
        }
    }
    carried.extend(cp.other_idx.iter().copied().zip(other_rows));
    // f32 planes, each converted once and moved into the inputs at its last use.
    let uses = ctx.roles.inputs_channels();
    // Each channel's rows are freed once converted. With no band in flight the
    // workers are idle and convert; else this thread does, beside them (a job
    // given to the pool would wait behind the queued tiles).
    let converted: Vec<Plane> = match pool {
        Some(pool) => pool.install(|| filter_rows.into_par_iter().map(ChannelRows::into_plane).collect()),
        None => filter_rows.into_iter().map(ChannelRows::into_plane).collect(),
    };
    let mut planes: Vec<(String, Option<Plane>, usize)> = Vec::new();
    for (&i, plane) in cp.filter_idx.iter().zip(converted) {
        let n = uses.iter().filter(|u| **u == ctx.names[i]).count();
        planes.push((ctx.names[i].clone(), Some(plane), n));
    }
    let inputs = ctx.roles.inputs_with(|n| {
        let slot = planes.iter_mut().find(|(name, _, _)| name == n).expect("role channel read");
        slot.2 -= 1;
        if slot.2 == 0 { slot.1.take().expect("plane still there") } else { slot.1.clone().expect("plane still there") }
    });
    drop(planes);
    let tiles = band.tiles(ctx.plan.tile_width, ctx.plan.band_rows);
    counters.tiles += tiles.len();
    counters.filtered_px += tiles.iter().map(|t| t.expand(ctx.halo).intersect(&ctx.frame).area()).sum::<usize>();
    let work = BandWork {
        band,
        inputs: Arc::new(inputs),
        tile_outputs: Mutex::new(Vec::with_capacity(tiles.len())),
        tiles,
        repaired: AtomicUsize::new(0),
    };
    (work, carried)
}

/// What a tile's tasks report to: its band's results channel, the frame's
/// progress, the run's cancel flag.
type TileReport<'a> = (crossbeam_channel::Sender<Result<(), Error>>, &'a AtomicUsize, &'a AtomicBool);

/// A tile being filtered, shared by its blocks' tasks.
struct TileWork<'a> {
    band: Arc<BandWork>,
    tile: Rect,
    region: PreparedRegion<'static>,
    /// Each block's result, in the order of its blocks.
    results: Mutex<Vec<Option<Vec<Vec<Plane>>>>>,
    remaining: AtomicUsize,
    report: TileReport<'a>,
}

/// A tile's task: the stages before the kernel, then one task per kernel
/// block, queued on this worker (idle workers take them). No task waits
/// for another: a worker never holds a tile open while it runs other work,
/// so a band's last tiles are not held up by the next band's.
fn start_tile<'s>(
    scope: &rayon::Scope<'s>,
    band: Arc<BandWork>,
    tile: Rect,
    ctx: &'s BandCtx<'s>,
    report: TileReport<'s>,
) {
    // After a failure, the queued tiles are skipped.
    if report.2.load(Ordering::Relaxed) {
        let _ = report.0.send(Err(Error::Internal("cancelled".into())));
        return;
    }
    // The tile reads the band's planes in place (no copy of its window).
    let region = match PreparedRegion::shared(Arc::clone(&band.inputs), ctx.frame, tile, ctx.params) {
        Ok(region) => region,
        Err(e) => {
            let _ = report.0.send(Err(e));
            return;
        }
    };
    let blocks = region.blocks_of(ctx.plan.kernel_rows);
    let work = Arc::new(TileWork {
        band,
        tile,
        results: Mutex::new(vec![None; blocks.len()]),
        remaining: AtomicUsize::new(blocks.len()),
        region,
        report,
    });
    if blocks.is_empty() {
        finish_tile(&work, ctx);
    }
    for (i, block) in blocks.into_iter().enumerate() {
        let work = Arc::clone(&work);
        scope.spawn(move |_| {
            if !work.report.2.load(Ordering::Relaxed) {
                let t = Instant::now();
                let r = work.region.filter_block(block);
                ctx.kernel_ns.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
                if let Ok(mut results) = work.results.lock() {
                    results[i] = Some(r);
                }
            }
            if work.remaining.fetch_sub(1, Ordering::AcqRel) == 1 {
                finish_tile(&work, ctx);
            }
        });
    }
}

/// A tile's last block is done: assemble the tile and hand its planes to
/// the band, which joins its tiles' rows once every tile is done
/// ([`band_rows`]).
fn finish_tile(work: &TileWork<'_>, ctx: &BandCtx<'_>) {
    let res = (|| {
        let poisoned = || Error::Internal("a tile worker panicked".into());
        let results = std::mem::take(&mut *work.results.lock().map_err(|_| poisoned())?);
        let Some(blocks) = results.into_iter().collect::<Option<Vec<_>>>() else {
            return Err(Error::Internal("cancelled".into()));
        };
        let d = work.region.finish(blocks);
        work.band.repaired.fetch_add(d.repaired, Ordering::Relaxed);
        let planes: Vec<Plane> = d.colour.into_iter().chain(d.layers.into_iter().flatten()).collect();
        work.band.tile_outputs.lock().map_err(|_| poisoned())?.push((work.tile, planes));
        let (t, done_px) = (work.tile, work.report.1);
        let done = done_px.fetch_add(t.area(), Ordering::Relaxed) + t.area();
        tracing::trace!(target: PROGRESS_TARGET, done = done as u64, total = ctx.frame.area() as u64);
        Ok(())
    })();
    let _ = work.report.0.send(res);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bands tile the frame in order, each between 1 and `rows` rows.
    fn check(frame: Rect, rows: usize) -> Vec<usize> {
        let bands = stream_bands(frame, rows);
        let mut y = frame.y0;
        for b in &bands {
            assert_eq!((b.x0, b.x1, b.y0), (frame.x0, frame.x1, y), "{bands:?}");
            assert!(b.y1 > b.y0 && b.height() <= rows, "{bands:?}");
            y = b.y1;
        }
        assert_eq!(y, frame.y1);
        bands.iter().map(Rect::height).collect()
    }

    /// `band_rows` joins a grid of tiles, given in any order, into the band's
    /// planes sample for sample, and refuses tiles that leave a gap.
    #[test]
    fn band_rows_join_the_tiles_of_a_grid() {
        let band = Rect { x0: -3, y0: 10, x1: 17, y1: 25 };
        let value = |c: usize| move |x: i64, y: i64| (c * 10_000) as f32 + (y * 100 + x) as f32;
        let tiles = band.tiles(7, 6);
        assert!(tiles.len() > 4, "{tiles:?}");
        let outputs = |tiles: &[Rect]| -> Vec<(Rect, Vec<Plane>)> {
            tiles.iter().rev().map(|&t| (t, (0..3).map(|c| Plane::from_fn(t, value(c))).collect())).collect()
        };
        let joined = band_rows(band, 3, outputs(&tiles)).unwrap();
        for (c, p) in joined.iter().enumerate() {
            assert_eq!(*p, Plane::from_fn(band, value(c)));
        }
        // A missing tile, or a tile's planes over another rect, is an error.
        assert!(band_rows(band, 3, outputs(&tiles[1..])).is_err());
        let mut wrong = outputs(&tiles);
        wrong[0].1[1] = Plane::from_fn(tiles[1], value(1));
        assert_ne!(wrong[0].0, tiles[1]);
        assert!(band_rows(band, 3, wrong).is_err());
    }

    #[test]
    fn stream_bands_thin_at_both_ends() {
        let f = |h| Rect::from_origin_size(-5, 7, 100, h);
        assert_eq!(check(f(1080), 360), [90, 300, 300, 300, 90]);
        assert_eq!(check(f(2160), 432), [108, 389, 389, 389, 389, 388, 108]);
        // A frame of at most `rows` rows is one band.
        assert_eq!(check(f(360), 360), [360]);
        assert_eq!(check(f(361), 360), [90, 181, 90]);
        // Short memory-bounded bands are not cut further; short plans' ends
        // are at least 64 rows.
        assert_eq!(check(f(100), 32), [32, 32, 32, 4]);
        assert_eq!(check(f(300), 127), [127, 127, 46]);
        assert_eq!(check(f(300), 128), [64, 86, 86, 64]);
        for h in 1..300 {
            for rows in [1, 16, 63, 64, 65, 100, 128, 299] {
                check(f(h), rows);
            }
        }
    }
}
