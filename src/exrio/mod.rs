//! All contact with the `exr` crate: reading a frame's channels, writing the
//! denoised frame atomically, and mapping channel names to roles ([`roles`]).

pub mod roles;
pub mod stream;
pub mod zip;

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
        Channel::new(name, Samples::half_from_f32(samples))
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
///
/// Also checks the header against the file's actual size before anything is
/// allocated from it: every chunk needs an 8-byte entry in the offset table
/// and at least a chunk header, so a header whose data window implies more
/// chunks than the file can hold is corrupt (or the file truncated).
pub(crate) fn check_supported(
    path: &Path,
    meta: &exr::meta::MetaData,
    file_len: u64,
) -> std::result::Result<exr::meta::header::Header, Error> {
    if meta.headers.len() != 1 {
        return Err(exr_err(
            path,
            format!("has {} parts; only single-part EXR files are supported", meta.headers.len()),
        ));
    }
    let header = &meta.headers[0];
    let min_bytes = (header.chunk_count as u64).saturating_mul(MIN_CHUNK_BYTES);
    if min_bytes > file_len {
        return Err(exr_err(
            path,
            format!(
                "the header declares a {}x{} data window in {} chunks, which needs at least {min_bytes} bytes, \
                 but the file has {file_len}: the header is corrupt or the file truncated",
                header.layer_size.0, header.layer_size.1, header.chunk_count
            ),
        ));
    }
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

/// Make attributes copied from an input file writable: a leniently read header
/// may hold values the EXR writer refuses (custom attributes under reserved
/// names, invalid values, a zero pixel aspect ratio, ...). Such attributes are
/// dropped or reset to their defaults; returns one note per change.
pub(crate) fn sanitize_attributes(
    shared: &mut ImageAttributes,
    own: &mut LayerAttributes,
    data_window: IntegerBounds,
) -> Vec<String> {
    use exr::meta::attribute::validate;
    let mut notes = Vec::new();
    let reserved = |name: &Text| exr::meta::header::standard_names::ALL.iter().any(|r| name.bytes() == *r);
    let dw = data_window;
    let keep = |name: &Text, value: &AttributeValue, notes: &mut Vec<String>| {
        let mut long = true;
        let ok = !reserved(name) && validate(name, value, &mut long, false, dw, true).is_ok();
        if !ok {
            notes.push(format!("attribute `{name}` of the input is invalid and was not copied"));
        }
        ok
    };
    shared.other.retain(|n, v| keep(n, v, &mut notes));
    own.other.retain(|n, v| keep(n, v, &mut notes) && !shared.other.contains_key(n));
    if !shared.pixel_aspect.is_normal() || !(1.0e-6..=1.0e6).contains(&shared.pixel_aspect) {
        notes.push(format!("pixel aspect ratio {} of the input is invalid; written as 1", shared.pixel_aspect));
        shared.pixel_aspect = 1.0;
    }
    if !own.screen_window_width.is_finite() || own.screen_window_width < 0.0 {
        notes.push(format!("screen window width {} of the input is invalid; written as 1", own.screen_window_width));
        own.screen_window_width = 1.0;
    }
    if shared.display_window.validate(None).is_err() || shared.display_window.size == Vec2(0, 0) {
        notes.push("display window of the input is invalid; written as the data window".into());
        shared.display_window = data_window;
    }
    if own.preview.as_ref().is_some_and(|p| p.validate(true).is_err()) {
        notes.push("preview image of the input is invalid and was not copied".into());
        own.preview = None;
    }
    notes
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

/// Smallest possible chunk: its offset-table entry (8 bytes), a scanline
/// chunk's y and size fields (8 bytes) and one byte of data.
const MIN_CHUNK_BYTES: u64 = 17;

/// Read a single-part, flat (non-deep) EXR frame, scanline or tiled, any line
/// order, with f16, f32 or u32 channels. Only the largest resolution level of
/// a mip-mapped file is read. A frame whose samples would need more than half
/// the available memory is refused before it is decoded (see
/// [`read_frame_within`]).
pub fn read_frame(path: &Path) -> std::result::Result<Frame, Error> {
    read_frame_within(path, crate::engine::budget::default_limit_bytes())
}

/// [`read_frame`], refusing (before decoding anything) a frame whose decoded
/// samples would exceed `limit_bytes`.
pub fn read_frame_within(path: &Path, limit_bytes: u64) -> std::result::Result<Frame, Error> {
    let io_err = |e: std::io::Error| Error::Io { path: path.to_path_buf(), source: e };
    let file_len = std::fs::metadata(path).map_err(io_err)?.len();
    let file = std::io::BufReader::new(File::open(path).map_err(io_err)?);
    read_frame_from(path, file, file_len, limit_bytes)
}

/// [`read_frame_within`] from the bytes of a file held in memory; `name` is used in errors.
pub fn read_frame_from_bytes(name: &Path, bytes: &[u8], limit_bytes: u64) -> std::result::Result<Frame, Error> {
    read_frame_from(name, std::io::Cursor::new(bytes), bytes.len() as u64, limit_bytes)
}

fn read_frame_from(
    path: &Path,
    mut file: impl std::io::Read + std::io::Seek + Send,
    file_len: u64,
    limit_bytes: u64,
) -> std::result::Result<Frame, Error> {
    let io_err = |e: std::io::Error| Error::Io { path: path.to_path_buf(), source: e };
    let meta = exr::meta::MetaData::read_from_buffered(&mut file, false).map_err(|e| match e {
        exr::error::Error::Io(io) => io_err(io),
        other => exr_err(path, format!("not a readable EXR file: {other}")),
    })?;
    file.seek(std::io::SeekFrom::Start(0)).map_err(io_err)?;
    let header = check_supported(path, &meta, file_len)?;
    let bytes = (header.layer_size.0 as u64)
        .saturating_mul(header.layer_size.1 as u64)
        .saturating_mul(header.channels.list.iter().map(|c| c.sample_type.bytes_per_sample() as u64).sum());
    if bytes > limit_bytes {
        return Err(exr_err(
            path,
            format!(
                "its {}x{} frame with {} channels decodes to {bytes} bytes, more than the memory limit of \
                 {limit_bytes} bytes for whole-frame reading; stream it instead (the default --tile-size) \
                 or raise --memory-limit",
                header.layer_size.0,
                header.layer_size.1,
                header.channels.list.len()
            ),
        ));
    }
    let layout = layout_of(&header);
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(file)
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

/// Temporary files being written by this process (see [`remove_unfinished_outputs`]).
static UNFINISHED: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Remove every temporary output file this process is still writing. Nothing
/// is ever written at an output path before it is complete, so after this no
/// trace of the unfinished outputs remains. The CLI calls it when it receives
/// SIGINT, SIGTERM or SIGHUP; embedders with their own signal handling can do
/// the same. (SIGKILL cannot be caught: a hidden `.NAME.nldenoise-*.tmp` file
/// may then remain beside the output, never a partial file at its path.)
pub fn remove_unfinished_outputs() {
    let list = UNFINISHED.lock().unwrap_or_else(|e| e.into_inner());
    for tmp in list.iter() {
        let _ = std::fs::remove_file(tmp);
    }
}

/// A temporary file beside `path` that is renamed over it on success and removed otherwise.
pub(crate) struct AtomicTarget {
    pub(crate) tmp: PathBuf,
    pub(crate) done: bool,
}

impl AtomicTarget {
    pub(crate) fn new(path: &Path) -> AtomicTarget {
        static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out.exr".into());
        let tmp = path.with_file_name(format!(".{name}.nldenoise-{}-{n}.tmp", std::process::id()));
        UNFINISHED.lock().unwrap_or_else(|e| e.into_inner()).push(tmp.clone());
        AtomicTarget { tmp, done: false }
    }
}

impl Drop for AtomicTarget {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.tmp);
        }
        UNFINISHED.lock().unwrap_or_else(|e| e.into_inner()).retain(|p| p != &self.tmp);
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
    let mut image_attrs = frame.image_attributes.clone();
    if let Some(shared) = image_attrs.as_mut() {
        for note in
            sanitize_attributes(shared, &mut layer_attrs, IntegerBounds::new(Vec2(dw.x0 as i32, dw.y0 as i32), size))
        {
            tracing::warn!("{}: {note}", path.display());
        }
    }
    let layer = Layer::new(size, layer_attrs, encoding, AnyChannels::sort(list));
    let mut image = Image::from_layer(layer);
    if let Some(attrs) = image_attrs {
        image.attributes = attrs;
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
