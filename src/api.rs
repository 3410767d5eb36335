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
    let out = filter::denoise_region(&inputs, rect, rect, params)?;
    drop(inputs);
    let mut replaced = Vec::new();
    let pairs = roles.colour.iter().zip(&out.colour).chain(
        roles
            .layers
            .iter()
            .zip(&out.layers)
            .flat_map(|(l, p)| l.channels.iter().zip(p)),
    );
    for (name, plane) in pairs {
        frame.set_channel(if half {
            Channel::from_f32_as_half(name, plane.data())
        } else {
            Channel::from_f32(name, plane.data().to_vec())
        });
        replaced.push(name.clone());
    }
    Ok(Report {
        roles,
        halo: pipeline.halo(),
        replaced,
    })
}

/// Read `input`, denoise it, and write `output` atomically.
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
