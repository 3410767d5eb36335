//! The progress bar of `denoise` on a terminal.
//!
//! The streaming engine reports each filtered tile as a `tracing` event
//! (`engine::PROGRESS_TARGET`, fields `done` and `total` in pixels); the
//! [`ProgressLayer`] turns those into an indicatif bar on stderr. The log
//! lines go through [`BarWriter`], which prints them above the bar. The bar
//! is drawn only when stderr is a terminal and `-q` is not given: a farm's
//! log file gets the log lines only.

use std::io::{self, IsTerminal, Write};
use std::sync::OnceLock;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tracing::field::{Field, Visit};
use tracing_subscriber::fmt::MakeWriter;
use tracing_subscriber::layer::{Context, Layer};

static BAR: OnceLock<ProgressBar> = OnceLock::new();

/// The process's bar: drawn on stderr when `show` and stderr is a
/// terminal, hidden (every call a no-op) otherwise.
pub fn init(show: bool) -> ProgressBar {
    BAR.get_or_init(|| {
        if !(show && io::stderr().is_terminal()) {
            return ProgressBar::hidden();
        }
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
        let style = ProgressStyle::with_template("{msg} [{bar:40}] {percent:>3}% {elapsed_precise} (eta {eta})")
            .map(|s| s.progress_chars("=> "))
            .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        bar
    })
    .clone()
}

/// A new frame: the bar starts again from zero with `label`.
pub fn start(label: String) {
    if let Some(bar) = BAR.get() {
        bar.reset();
        bar.set_length(0);
        bar.set_message(label);
    }
}

/// The frame is done (or failed, or the run was interrupted): clear the bar.
pub fn finish() {
    if let Some(bar) = BAR.get() {
        bar.finish_and_clear();
    }
}

/// Moves the bar on the engine's progress events.
pub struct ProgressLayer(pub ProgressBar);

impl<S: tracing::Subscriber> Layer<S> for ProgressLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _: Context<'_, S>) {
        let mut fields = Fields::default();
        event.record(&mut fields);
        if let (Some(done), Some(total)) = (fields.done, fields.total) {
            if self.0.length() != Some(total) {
                self.0.set_length(total);
            }
            // Tiles filtered in parallel may report out of order.
            if done > self.0.position() {
                self.0.set_position(done);
            }
        }
    }
}

#[derive(Default)]
struct Fields {
    done: Option<u64>,
    total: Option<u64>,
}

impl Visit for Fields {
    fn record_u64(&mut self, field: &Field, value: u64) {
        match field.name() {
            "done" => self.done = Some(value),
            "total" => self.total = Some(value),
            _ => {}
        }
    }

    fn record_debug(&mut self, _: &Field, _: &dyn std::fmt::Debug) {}
}

/// stderr for the log lines: each line is printed with the bar lifted, so
/// lines and bar never share a terminal line.
#[derive(Clone)]
pub struct BarWriter(pub ProgressBar);

impl<'a> MakeWriter<'a> for BarWriter {
    type Writer = BarLine;

    fn make_writer(&'a self) -> BarLine {
        BarLine { bar: self.0.clone(), buf: Vec::new() }
    }
}

/// One log line, printed when dropped.
pub struct BarLine {
    bar: ProgressBar,
    buf: Vec<u8>,
}

impl Write for BarLine {
    fn write(&mut self, b: &[u8]) -> io::Result<usize> {
        self.buf.extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Drop for BarLine {
    fn drop(&mut self) {
        let buf = std::mem::take(&mut self.buf);
        self.bar.suspend(|| {
            let _ = io::stderr().write_all(&buf);
        });
    }
}
