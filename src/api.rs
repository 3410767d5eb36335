//! The library's entry points: denoise a frame held in memory, or a file.
//!
//! Both the CLI and embedding tools go through here, so that channel roles,
//! parameters and output conventions are the same everywhere.

use std::path::Path;

use crate::error::Error;
use crate::exrio::roles::{self, ChannelRoles, RoleOptions};
use crate::exrio::{self, Channel, Frame, WriteOptions};
use crate::filter::{self, Params};

/// What a denoise did, for logs and reports.
#[derive(Clone, Debug)]
pub struct Report {
    /// The roles chosen for the channels.
    pub roles: ChannelRoles,
    /// The halo the pipeline needs (pixels).
    pub halo: usize,
    /// Channels whose values were replaced.
    pub replaced: Vec<String>,
    /// Pixels that had an unusable input sample (NaN, infinite, out of range)
    /// repaired before filtering.
    pub repaired: usize,
}

/// Denoise `frame` in place: the beauty and light layers are replaced by their
/// denoised values (as `f32`, or `f16` with `half`); every other channel is
/// kept unchanged. `source` names the frame in errors.
pub fn denoise_frame(
    frame: &mut Frame,
    source: &Path,
    opts: &RoleOptions,
    params: &Params,
    half: bool,
) -> Result<Report, Error> {
    params.validate()?;
    let roles = roles::detect(source, &frame.channel_names(), opts)?;
    let inputs = roles.inputs(frame);
    let pipeline = filter::Pipeline::new(*params, filter::InputShape::of(&inputs));
    let rect = frame.data_window;
    let out = filter::denoise_region(&inputs, rect, rect, params).map_err(|e| e.in_file(source))?;
    drop(inputs);
    let mut replaced = Vec::new();
    let pairs = roles
        .colour
        .iter()
        .zip(&out.colour)
        .chain(roles.layers.iter().zip(&out.layers).flat_map(|(l, p)| l.channels.iter().zip(p)));
    for (name, plane) in pairs {
        frame.set_channel(if half {
            Channel::from_f32_as_half(name, plane.data())
        } else {
            Channel::from_f32(name, plane.data().to_vec())
        });
        replaced.push(name.clone());
    }
    Ok(Report { roles, halo: pipeline.halo(), replaced, repaired: out.repaired })
}

/// Read `input`, denoise it, and write `output` atomically, every input
/// channel kept. For the denoised channels alone (the CLI's
/// `--denoised-only` with `--tile-size 0`), call [`denoise_frame`], keep
/// the channels its [`Report::replaced`] names
/// (`frame.channels.retain(|c| report.replaced.contains(&c.name))`) and
/// write the frame; streamed, set [`crate::engine::StreamOptions::carry`]
/// to false in [`denoise_file_streaming`].
pub fn denoise_file(
    input: &Path,
    output: &Path,
    opts: &RoleOptions,
    params: &Params,
    half: bool,
    write: &WriteOptions,
) -> Result<Report, Error> {
    params.validate()?;
    let mut frame = exrio::read_frame(input)?;
    let report = denoise_frame(&mut frame, input, opts, params, half)?;
    exrio::write_frame(output, &frame, write)?;
    Ok(report)
}

/// Stream `input` to `output` through the tiled engine in bounded memory.
///
/// The output holds every input channel; the denoised ones are `f32` (or
/// `f16` with `opts.half`), the others keep their type and bits. With
/// `opts.carry` false it holds the denoised channels alone. Written to a
/// temporary file and renamed into place when complete.
pub fn denoise_file_streaming(
    input: &Path,
    output: &Path,
    roles_opts: &RoleOptions,
    params: &Params,
    opts: &crate::engine::StreamOptions,
    compression: exrio::OutputCompression,
) -> Result<(Report, crate::engine::StreamReport), Error> {
    use crate::engine::{self, RowSource};
    use exrio::stream::{ExrSink, ExrSource, SinkChannel};
    params.validate()?;
    let mut source = ExrSource::open(input)?;
    let names = source.channel_names();
    let roles = roles::detect(input, &names, roles_opts)?;
    let outputs = roles.outputs();
    // The sink's channels, as the engine will hand them over.
    let channels: Vec<SinkChannel> = engine::sink_channels(&names, &roles, opts.carry)
        .map_err(|e| e.in_file(input))?
        .into_iter()
        .map(|i| SinkChannel {
            name: names[i].clone(),
            kind: if outputs.contains(&names[i]) {
                if opts.half { exrio::SampleKind::F16 } else { exrio::SampleKind::F32 }
            } else {
                source.kinds()[i]
            },
        })
        .collect();
    let mut opts = *opts;
    opts.out_block_rows = compression.to_exr().scan_lines_per_block();
    let mut sink = ExrSink::create(
        output,
        source.data_window(),
        &channels,
        (compression, opts.zip_level),
        Some(source.header()),
        opts.threads,
    )?;
    let stream = engine::denoise_stream(&mut source, &mut sink, &roles, params, &opts).map_err(|e| e.in_file(input))?;
    Ok((Report { halo: stream.halo, replaced: outputs, roles, repaired: stream.repaired }, stream))
}
