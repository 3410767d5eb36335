//! The engine's progress events (`engine::PROGRESS_TARGET`), which drive the
//! CLI's progress bar: one per tile, counting the frame's output pixels up to
//! the total. A test binary of its own, since it installs the process's
//! global `tracing` subscriber (the engine's stages run on their own threads).

use std::sync::Mutex;

use nldenoise::engine::synthetic::{Synthetic, SyntheticSource};
use nldenoise::engine::{PROGRESS_TARGET, StreamOptions, denoise_stream};
use nldenoise::exrio::roles::{self, RoleOptions};
use nldenoise::exrio::stream::NullSink;
use nldenoise::filter::Params;
use nldenoise::geom::Rect;
use tracing::field::{Field, Visit};
use tracing_subscriber::layer::{Context, Layer};
use tracing_subscriber::prelude::*;

static EVENTS: Mutex<Vec<(String, u64, u64)>> = Mutex::new(Vec::new());

struct Collect;

#[derive(Default)]
struct Fields(Option<u64>, Option<u64>);

impl Visit for Fields {
    fn record_u64(&mut self, field: &Field, value: u64) {
        match field.name() {
            "done" => self.0 = Some(value),
            "total" => self.1 = Some(value),
            _ => {}
        }
    }

    fn record_debug(&mut self, _: &Field, _: &dyn std::fmt::Debug) {}
}

impl<S: tracing::Subscriber> Layer<S> for Collect {
    fn on_event(&self, event: &tracing::Event<'_>, _: Context<'_, S>) {
        let mut f = Fields::default();
        event.record(&mut f);
        if let (Some(done), Some(total)) = (f.0, f.1) {
            EVENTS.lock().unwrap().push((event.metadata().target().to_string(), done, total));
        }
    }
}

#[test]
fn progress_counts_every_tile_up_to_the_frame() {
    tracing_subscriber::registry().with(Collect).init();
    let frame = Rect::from_origin_size(3, -2, 70, 45);
    let mut source = SyntheticSource::new(Synthetic { frame, features: true, layers: false, sigma: 0.05 });
    let names = nldenoise::engine::RowSource::channel_names(&source);
    let roles = roles::detect("synthetic".as_ref(), &names, &RoleOptions::default()).unwrap();
    let params = Params { search_radius: 2, patch_radius: 1, ..Params::default() };
    let opts = StreamOptions { tile_size: 16, threads: 2, memory_limit: 1 << 30, ..StreamOptions::default() };
    let report = denoise_stream(&mut source, &mut NullSink::default(), &roles, &params, &opts).unwrap();

    let events = EVENTS.lock().unwrap().clone();
    assert_eq!(events.len(), report.tiles, "one event per tile");
    assert!(report.tiles > 4, "the frame must be cut into several tiles");
    assert!(events.iter().all(|(target, _, total)| target == PROGRESS_TARGET && *total == frame.area() as u64));
    // Each tile adds its pixels once: the counts, in any order, are distinct
    // and the largest is the whole frame.
    let mut done: Vec<u64> = events.iter().map(|e| e.1).collect();
    done.sort_unstable();
    done.dedup();
    assert_eq!(done.len(), events.len(), "counts must be distinct");
    assert!(done[0] > 0);
    assert_eq!(*done.last().unwrap(), frame.area() as u64);
}
