//! Embedding the engine without files: a renderer-like row source feeds the
//! denoiser, and a sink receives denoised rows in increasing y, in bounded
//! memory. Run with `cargo run --release --example stream_rows`.

use nldenoise::engine::synthetic::{Synthetic, SyntheticSource};
use nldenoise::engine::{RowSink, RowSource, StreamOptions, denoise_stream};
use nldenoise::exrio::roles::{self, RoleOptions};
use nldenoise::filter::Params;
use nldenoise::geom::Rect;
use nldenoise::image::ChannelRows;

/// A sink that measures the error of the denoised beauty against the clean image.
struct ErrorMeter {
    spec: Synthetic,
    names: Vec<String>,
    rows_seen: usize,
    sq_err_noisy: f64,
    sq_err: f64,
}

impl RowSink for ErrorMeter {
    fn write_rows(&mut self, rows: Vec<ChannelRows>) -> Result<(), nldenoise::Error> {
        for (name, r) in self.names.iter().zip(&rows) {
            let c = match name.as_str() {
                "R" => 0,
                "G" => 1,
                "B" => 2,
                _ => continue,
            };
            for (i, v) in r.samples.to_f32().iter().enumerate() {
                let (x, y) = (r.rect.x0 + (i % r.rect.width()) as i64, r.rect.y0 + (i / r.rect.width()) as i64);
                let clean = self.spec.clean(x, y, c) as f64;
                self.sq_err += (*v as f64 - clean).powi(2);
                self.sq_err_noisy += (self.spec.sample(name, x, y) as f64 - clean).powi(2);
            }
        }
        self.rows_seen += rows[0].rect.height();
        Ok(())
    }

    fn finish(&mut self) -> Result<(), nldenoise::Error> {
        Ok(())
    }
}

fn main() -> Result<(), nldenoise::Error> {
    let spec = Synthetic { frame: Rect::from_origin_size(0, 0, 640, 360), features: true, layers: false, sigma: 0.05 };
    let mut source = SyntheticSource::new(spec);
    let names = source.channel_names();
    let roles = roles::detect("synthetic".as_ref(), &names, &RoleOptions::default())?;
    let mut sink = ErrorMeter { spec, names, rows_seen: 0, sq_err_noisy: 0.0, sq_err: 0.0 };
    let opts = StreamOptions { tile_size: 128, memory_limit: 64 << 20, ..StreamOptions::default() };
    let report = denoise_stream(&mut source, &mut sink, &roles, &Params::default(), &opts)?;
    println!(
        "{} rows in {} bands of {} rows, {} tiles; beauty MSE {:.3e} -> {:.3e}",
        sink.rows_seen,
        report.bands,
        report.plan.band_rows,
        report.tiles,
        sink.sq_err_noisy / (3.0 * spec.frame.area() as f64),
        sink.sq_err / (3.0 * spec.frame.area() as f64)
    );
    Ok(())
}
