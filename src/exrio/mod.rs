//! All contact with the `exr` crate: reading a frame's channels, writing the
//! denoised frame atomically, and mapping channel names to roles ([`roles`]).

pub mod roles;
pub mod stream;

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use exr::prelude::*;
use smallvec::SmallVec;

use crate::error::Error;
use crate::geom::Rect;
use crate::image::{Plane, Samples};

/// How a channel's samples are stored in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleKind {
    /// 16-bit float.
    F16,
    /// 32-bit float.
    F32,
    /// 32-bit unsigned integer.
    U32,
}

impl std::fmt::Display for SampleKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SampleKind::F16 => "half",
            SampleKind::F32 => "float",
            SampleKind::U32 => "uint",
        })
    }
}

/// One channel of a frame, with its samples exactly as stored.
#[derive(Clone, Debug)]
pub struct Channel {
    /// Full channel name (`R`, `var.R`, `albedo.G`, ...).
    pub name: String,
    /// Storage type in the file.
    pub kind: SampleKind,
    /// Samples as read (carried unchanged to the output unless replaced).
    samples: Samples,
}

impl Channel {
    /// A channel from samples in their storage type.
    pub fn new(name: impl Into<String>, samples: Samples) -> Channel {
        let kind = match &samples {
            Samples::F16(_) => SampleKind::F16,
            Samples::F32(_) => SampleKind::F32,
            Samples::U32(_) => SampleKind::U32,
        };
        Channel { name: name.into(), kind, samples }
    }

    /// A channel from `f32` samples (stored as `F32`).
    pub fn from_f32(name: impl Into<String>, samples: Vec<f32>) -> Channel {
        Channel::new(name, Samples::F32(samples))
    }

    /// A channel from `f32` samples stored as `F16`.
    pub fn from_f32_as_half(name: impl Into<String>, samples: &[f32]) -> Channel {
        Channel::new(name, Samples::F16(samples.iter().map(|&v| f16::from_f32(v)).collect()))
    }

    /// The samples in their storage type.
    pub fn samples(&self) -> &Samples {
        &self.samples
    }

    /// The samples converted to `f32`.
    pub fn to_f32(&self) -> Vec<f32> {
        self.samples.to_f32()
    }
}

/// How the input file was laid out (reported by `info`).
#[derive(Clone, Debug)]
pub struct Layout {
    /// `scanline` or `tiled WxH`.
    pub blocks: String,
    /// Compression name.
    pub compression: String,
    /// Line order.
    pub line_order: String,
}

/// A whole frame held in memory: its data window, channels and attributes.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The data window in frame (pixel-space) coordinates.
    pub data_window: Rect,
    /// Channels in the file's (alphabetical) order.
    pub channels: Vec<Channel>,
    /// How the source file was laid out, when read from a file.
    pub layout: Option<Layout>,
    image_attributes: Option<ImageAttributes>,
    layer_attributes: Option<LayerAttributes>,
}

impl Frame {
    /// A frame with no attributes (e.g. for tests and generated data).
    pub fn new(data_window: Rect, channels: Vec<Channel>) -> Frame {
        Frame { data_window, channels, layout: None, image_attributes: None, layer_attributes: None }
    }

    /// Channel names in order.
    pub fn channel_names(&self) -> Vec<String> {
        self.channels.iter().map(|c| c.name.clone()).collect()
    }

    /// The channel named `name`.
    pub fn channel(&self, name: &str) -> Option<&Channel> {
        self.channels.iter().find(|c| c.name == name)
    }

    /// The channel named `name` as a plane over the data window.
    pub fn plane(&self, name: &str) -> Option<Plane> {
        self.channel(name)
            .map(|c| Plane::from_vec(self.data_window, c.to_f32()).expect("channel length checked on read"))
    }

    /// Replace (or add) a channel's samples.
    pub fn set_channel(&mut self, channel: Channel) {
        match self.channels.iter_mut().find(|c| c.name == channel.name) {
            Some(c) => *c = channel,
            None => {
                self.channels.push(channel);
                self.channels.sort_by(|a, b| a.name.cmp(&b.name));
            }
        }
    }
}

pub(crate) fn exr_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Exr { path: path.to_path_buf(), message: e.to_string() }
}

fn compression_name(c: Compression) -> String {
    match c {
        Compression::Uncompressed => "none".into(),
        Compression::RLE => "rle".into(),
        Compression::ZIP1 => "zips".into(),
        Compression::ZIP16 => "zip".into(),
        Compression::PIZ => "piz".into(),
        Compression::PXR24 => "pxr24".into(),
        other => format!("{other:?}").to_lowercase(),
    }
}

/// The one header of a file we can denoise: single part, flat, full-resolution channels.
pub(crate) fn check_supported(
    path: &Path,
    meta: &exr::meta::MetaData,
) -> std::result::Result<exr::meta::header::Header, Error> {
    if meta.headers.len() != 1 {
        return Err(exr_err(
            path,
            format!("has {} parts; only single-part EXR files are supported", meta.headers.len()),
        ));
    }
    let header = &meta.headers[0];
    if header.deep {
        return Err(exr_err(path, "is a deep EXR file; only flat images are supported"));
    }
    for ch in header.channels.list.iter() {
        if ch.sampling != Vec2(1, 1) {
            return Err(exr_err(
                path,
                format!(
                    "channel {} is subsampled ({:?}); only full-resolution channels are supported",
                    ch.name, ch.sampling
                ),
            ));
        }
    }
    Ok(header.clone())
}

/// How a file is laid out, from its header.
pub fn layout_of(header: &exr::meta::header::Header) -> Layout {
    Layout {
        blocks: match header.blocks {
            exr::meta::BlockDescription::ScanLines => "scanline".into(),
            exr::meta::BlockDescription::Tiles(t) => format!("tiled {}x{}", t.tile_size.0, t.tile_size.1),
        },
        compression: compression_name(header.compression),
        line_order: format!("{:?}", header.line_order).to_lowercase(),
    }
}

/// Read a single-part, flat (non-deep) EXR frame, scanline or tiled, any line
/// order, with f16, f32 or u32 channels. Only the largest resolution level of
/// a mip-mapped file is read.
pub fn read_frame(path: &Path) -> std::result::Result<Frame, Error> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| match e {
        exr::error::Error::Io(io) => Error::Io { path: path.to_path_buf(), source: io },
        other => exr_err(path, format!("not a readable EXR file: {other}")),
    })?;
    let header = check_supported(path, &meta)?;
    let layout = layout_of(&header);
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| exr_err(path, format!("could not decode: {e}")))?;
    let layer = image.layer_data;
    let pos = layer.attributes.layer_position;
    let data_window = Rect::from_origin_size(pos.0 as i64, pos.1 as i64, layer.size.0, layer.size.1);
    let mut channels = Vec::with_capacity(layer.channel_data.list.len());
    for ch in layer.channel_data.list {
        if ch.sample_data.len() != data_window.area() {
            return Err(exr_err(
                path,
                format!("channel {} has {} samples, expected {}", ch.name, ch.sample_data.len(), data_window.area()),
            ));
        }
        let samples = match ch.sample_data {
            FlatSamples::F16(v) => Samples::F16(v),
            FlatSamples::F32(v) => Samples::F32(v),
            FlatSamples::U32(v) => Samples::U32(v),
        };
        channels.push(Channel::new(ch.name.to_string(), samples));
    }
    Ok(Frame {
        data_window,
        channels,
        layout: Some(layout),
        image_attributes: Some(image.attributes),
        layer_attributes: Some(layer.attributes),
    })
}

/// Output compression choices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum OutputCompression {
    /// No compression.
    None,
    /// Run-length encoding.
    Rle,
    /// Zip, one scanline per block.
    Zips,
    /// Zip, 16 scanlines per block (default).
    #[default]
    Zip,
    /// Wavelet (PIZ).
    Piz,
    /// Lossy 24-bit float (PXR24).
    Pxr24,
}

impl OutputCompression {
    pub(crate) fn to_exr(self) -> Compression {
        match self {
            OutputCompression::None => Compression::Uncompressed,
            OutputCompression::Rle => Compression::RLE,
            OutputCompression::Zips => Compression::ZIP1,
            OutputCompression::Zip => Compression::ZIP16,
            OutputCompression::Piz => Compression::PIZ,
            OutputCompression::Pxr24 => Compression::PXR24,
        }
    }
}

/// How to lay out the written file.
#[derive(Clone, Copy, Debug, Default)]
pub struct WriteOptions {
    /// Compression of every channel.
    pub compression: OutputCompression,
    /// Tile size; `None` writes scanlines.
    pub tiles: Option<(usize, usize)>,
    /// Write blocks in decreasing y.
    pub decreasing: bool,
}

/// A temporary file beside `path` that is renamed over it on success and removed otherwise.
pub(crate) struct AtomicTarget {
    pub(crate) tmp: PathBuf,
    pub(crate) done: bool,
}

impl AtomicTarget {
    pub(crate) fn new(path: &Path) -> AtomicTarget {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out.exr".into());
        let tmp = path.with_file_name(format!(".{name}.nldenoise-{}.tmp", std::process::id()));
        AtomicTarget { tmp, done: false }
    }
}

impl Drop for AtomicTarget {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Write a frame. The file appears at `path` only once completely written
/// (written to a temporary file in the same folder, synced, then renamed), so
/// a failure never leaves a partial file at `path`.
pub fn write_frame(path: &Path, frame: &Frame, opts: &WriteOptions) -> std::result::Result<(), Error> {
    if frame.channels.is_empty() {
        return Err(exr_err(path, "refusing to write a frame with no channels"));
    }
    let dw = frame.data_window;
    let size = Vec2(dw.width(), dw.height());
    let mut layer_attrs = frame.layer_attributes.clone().unwrap_or_default();
    layer_attrs.layer_position = Vec2(dw.x0 as i32, dw.y0 as i32);
    let encoding = Encoding {
        compression: opts.compression.to_exr(),
        blocks: match opts.tiles {
            Some((w, h)) => Blocks::Tiles(Vec2(w, h)),
            None => Blocks::ScanLines,
        },
        line_order: if opts.decreasing { LineOrder::Decreasing } else { LineOrder::Increasing },
    };
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = frame
        .channels
        .iter()
        .map(|c| {
            let flat = match &c.samples {
                Samples::F16(v) => FlatSamples::F16(v.clone()),
                Samples::F32(v) => FlatSamples::F32(v.clone()),
                Samples::U32(v) => FlatSamples::U32(v.clone()),
            };
            AnyChannel::new(c.name.as_str(), flat)
        })
        .collect();
    let layer = Layer::new(size, layer_attrs, encoding, AnyChannels::sort(list));
    let mut image = Image::from_layer(layer);
    if let Some(attrs) = &frame.image_attributes {
        image.attributes = attrs.clone();
    } else {
        image.attributes.display_window = IntegerBounds::new(Vec2(dw.x0 as i32, dw.y0 as i32), size);
    }

    let target = AtomicTarget::new(path);
    let io_err = |p: &Path, e: std::io::Error| Error::Io { path: p.to_path_buf(), source: e };
    let file = File::create(&target.tmp).map_err(|e| io_err(path, e))?;
    let mut writer = BufWriter::new(file);
    image.write().to_buffered(&mut writer).map_err(|e| match e {
        exr::error::Error::Io(io) => io_err(path, io),
        other => exr_err(path, format!("could not encode: {other}")),
    })?;
    let file = writer.into_inner().map_err(|e| io_err(path, e.into_error()))?;
    file.sync_all().map_err(|e| io_err(path, e))?;
    drop(file);
    std::fs::rename(&target.tmp, path).map_err(|e| io_err(path, e))?;
    let mut target = target;
    target.done = true;
    Ok(())
}
