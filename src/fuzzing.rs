//! The bodies of the fuzz targets (`fuzz/`), shared with the regression test
//! that replays every input kept under `fuzz/regressions/`. Errors are the
//! expected outcome of most inputs; a panic, a hang, an allocation beyond the
//! limits or a non-finite denoised sample is a finding.

use std::path::Path;

use crate::engine::{self, RowSource, StreamOptions};
use crate::exrio::roles::{self, RoleOptions, Selection};
use crate::exrio::stream::{ExrSource, NullSink};
use crate::exrio::{self};
use crate::filter::Params;

/// Memory limit given to the readers.
pub const LIMIT: u64 = 256 << 20;

/// Frames larger than this are not denoised (the filter's cost, not its safety, grows).
pub const MAX_DENOISE_PIXELS: usize = 64 * 64;

const NAME: &str = "fuzz.exr";

/// Both reading paths: the whole-frame reader and the streaming source
/// (header, offset table, every band of rows, as the engine reads them).
pub fn read(data: &[u8]) {
    let name = Path::new(NAME);
    if let Ok(frame) = exrio::read_frame_from_bytes(name, data, LIMIT) {
        assert!(frame.channels.iter().all(|c| c.samples().len() == frame.data_window.area()));
    }
    let Ok(mut source) = ExrSource::from_bytes(name, data.to_vec()) else { return };
    let dw = source.data_window();
    let row_bytes = source.sample_bytes().iter().map(|&b| b as u64).sum::<u64>() * dw.width() as u64;
    if row_bytes.saturating_mul(16) > LIMIT {
        return;
    }
    let all: Vec<usize> = (0..source.channel_names().len()).collect();
    for band in dw.row_bands(16) {
        match source.read_rows(&all, band) {
            Ok(rows) => assert!(rows.iter().all(|r| r.samples.len() == r.rect.area())),
            Err(_) => return,
        }
    }
}

/// The whole denoise: streaming (roles, memory plan, tiles, filter) into a
/// sink in memory, and whole-frame filtering of what the reader accepts.
pub fn denoise(data: &[u8]) {
    let name = Path::new(NAME);
    let params = Params { search_radius: 3, patch_radius: 1, ..Params::default() };
    let roles_opts = RoleOptions { layers: Selection::Auto, ..RoleOptions::default() };
    if let Ok(mut source) = ExrSource::from_bytes(name, data.to_vec())
        && source.data_window().area() <= MAX_DENOISE_PIXELS
        && let Ok(roles) = roles::detect(name, &source.channel_names(), &roles_opts)
    {
        let opts = StreamOptions { tile_size: 7, threads: 1, memory_limit: 64 << 20, ..Default::default() };
        let _ = engine::denoise_stream(&mut source, &mut NullSink::default(), &roles, &params, &opts);
    }
    if let Ok(mut frame) = exrio::read_frame_from_bytes(name, data, 64 << 20)
        && frame.data_window.area() <= MAX_DENOISE_PIXELS
        && let Ok(report) = crate::api::denoise_frame(&mut frame, name, &roles_opts, &params, false)
    {
        for n in &report.replaced {
            let c = frame.channel(n).expect("replaced channel exists");
            assert!(c.to_f32().iter().all(|v| v.is_finite()), "non-finite output in {n}");
        }
    }
}
