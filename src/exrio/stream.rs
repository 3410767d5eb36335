//! Streaming EXR access for the tiled engine: a memory-mapped source that
//! decodes only the chunks a row window needs (located through the offset
//! table, decompressed in parallel, any line order, scanline or tiled), and a
//! sink that writes scanline chunks in increasing y as their rows complete.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Cursor};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::thread::JoinHandle;

use exr::block::BlockIndex;
use exr::block::chunk::Chunk;
use exr::block::lines::LineIndex;
use exr::block::reader::ChunksReader;
use exr::block::writer::ChunksWriter;
use exr::math::Vec2;
use exr::meta::attribute::{ChannelDescription, ChannelList, LineOrder, SampleType, Text};
use exr::meta::header::Header;
use exr::meta::{BlockDescription, MetaData};
use memmap2::Mmap;
use rayon::prelude::*;
use smallvec::SmallVec;

use super::zip::BlockBytes;
use super::{AtomicTarget, OutputCompression, SampleKind, exr_err};
use crate::engine::{RowSink, RowSource};
use crate::error::Error;
use crate::geom::Rect;
use crate::image::{ChannelRows, Samples};

fn kind_of(t: SampleType) -> SampleKind {
    match t {
        SampleType::F16 => SampleKind::F16,
        SampleType::F32 => SampleKind::F32,
        SampleType::U32 => SampleKind::U32,
    }
}

/// One decoded block: its rectangle (frame coordinates) and every channel's samples.
struct DecodedBlock {
    rect: Rect,
    channels: Vec<Samples>,
}

/// The bytes of a file: memory-mapped, or held in memory (fuzzing, embedding).
enum FileBytes {
    Mapped(Mmap),
    Owned(Vec<u8>),
}

impl std::ops::Deref for FileBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            FileBytes::Mapped(m) => m,
            FileBytes::Owned(v) => v,
        }
    }
}

/// A memory-mapped EXR file read row window by row window.
pub struct ExrSource {
    path: PathBuf,
    bytes: FileBytes,
    header: Header,
    data_window: Rect,
    names: Vec<String>,
    kinds: Vec<SampleKind>,
    /// The channels blocks are decoded for (all until
    /// [`RowSource::select_channels`] names some); the others' lines are
    /// checked and skipped.
    selected: Vec<bool>,
    cache: BTreeMap<(i64, i64), DecodedBlock>,
    /// The decoders' block-sized buffers, kept while the file is read.
    scratch: super::zip::ScratchPool,
    /// Chunks decoded so far (a chunk decoded twice counts twice).
    pub chunks_decoded: usize,
}

impl ExrSource {
    /// Map `path` and read its header (single-part, flat, full-resolution channels).
    pub fn open(path: &Path) -> Result<ExrSource, Error> {
        let file = File::open(path).map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
        // SAFETY: the file is opened read-only and only read through this map; if
        // another process truncates it meanwhile, reads may fault (SIGBUS), as for
        // any memory-mapped reader. We never write through the map.
        let mmap = unsafe { Mmap::map(&file) }.map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
        ExrSource::with_bytes(path, FileBytes::Mapped(mmap))
    }

    /// A source over the bytes of an EXR file held in memory; `name` is used in errors.
    pub fn from_bytes(name: &Path, bytes: Vec<u8>) -> Result<ExrSource, Error> {
        ExrSource::with_bytes(name, FileBytes::Owned(bytes))
    }

    fn with_bytes(path: &Path, bytes: FileBytes) -> Result<ExrSource, Error> {
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(&bytes[..]), false)
            .map_err(|e| exr_err(path, format!("not a readable EXR file: {e}")))?;
        let header = super::check_supported(path, &meta, bytes.len() as u64)?;
        check_offset_table(path, &bytes, header.chunk_count)?;
        let pos = header.own_attributes.layer_position;
        let data_window = Rect::from_origin_size(pos.0 as i64, pos.1 as i64, header.layer_size.0, header.layer_size.1);
        let names = header.channels.list.iter().map(|c| c.name.to_string()).collect();
        let kinds: Vec<SampleKind> = header.channels.list.iter().map(|c| kind_of(c.sample_type)).collect();
        Ok(ExrSource {
            selected: vec![true; kinds.len()],
            path: path.to_path_buf(),
            bytes,
            header,
            data_window,
            names,
            kinds,
            cache: BTreeMap::new(),
            scratch: Default::default(),
            chunks_decoded: 0,
        })
    }

    /// The file's header (for copying attributes to the output).
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Storage type of each channel, in channel order.
    pub fn kinds(&self) -> &[SampleKind] {
        &self.kinds
    }

    /// Rows per block (scanline block height, or tile height).
    pub fn block_rows(&self) -> usize {
        match self.header.blocks {
            BlockDescription::ScanLines => self.header.compression.scan_lines_per_block(),
            BlockDescription::Tiles(t) => t.tile_size.1,
        }
    }

    fn decode(&self, index: BlockIndex, data: BlockBytes<'_>) -> Result<DecodedBlock, Error> {
        let dw = self.data_window;
        let BlockIndex { pixel_position, pixel_size, .. } = index;
        let rect = Rect::from_origin_size(
            dw.x0 + pixel_position.0 as i64,
            dw.y0 + pixel_position.1 as i64,
            pixel_size.0,
            pixel_size.1,
        );
        let n = rect.area();
        let mut channels: Vec<Samples> = self
            .kinds
            .iter()
            .map(|k| match k {
                SampleKind::F16 => Samples::F16(Vec::with_capacity(n)),
                SampleKind::F32 => Samples::F32(Vec::with_capacity(n)),
                SampleKind::U32 => Samples::U32(Vec::with_capacity(n)),
            })
            .collect();
        // Lines come in file order: for each row, for each channel.
        for (range, line) in LineIndex::lines_in_block(index, &self.header.channels) {
            if range.end > data.len() || range.start % 2 == 1 {
                return Err(exr_err(
                    &self.path,
                    format!("block at {:?} holds fewer bytes than its lines", (rect.x0, rect.y0)),
                ));
            }
            if !self.selected[line.channel] {
                continue;
            }
            match (data, &mut channels[line.channel]) {
                (BlockBytes::Plain(d), Samples::F16(v)) => {
                    v.extend(d[range].chunks_exact(2).map(|b| half::f16::from_ne_bytes([b[0], b[1]])))
                }
                (BlockBytes::Plain(d), Samples::F32(v)) => {
                    v.extend(d[range].chunks_exact(4).map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]])))
                }
                (BlockBytes::Plain(d), Samples::U32(v)) => {
                    v.extend(d[range].chunks_exact(4).map(|b| u32::from_ne_bytes([b[0], b[1], b[2], b[3]])))
                }
                // ZIP's halves (little-endian machines only): byte 2i of the
                // line is even[i], byte 2i + 1 is odd[i].
                (BlockBytes::Split { even, odd }, samples) => {
                    let r = range.start / 2..range.end / 2;
                    let (e, o) = (&even[r.clone()], &odd[r]);
                    match samples {
                        Samples::F16(v) => v.extend(e.iter().zip(o).map(|(&a, &b)| half::f16::from_le_bytes([a, b]))),
                        Samples::F32(v) => v.extend(
                            e.chunks_exact(2)
                                .zip(o.chunks_exact(2))
                                .map(|(a, b)| f32::from_le_bytes([a[0], b[0], a[1], b[1]])),
                        ),
                        Samples::U32(v) => v.extend(
                            e.chunks_exact(2)
                                .zip(o.chunks_exact(2))
                                .map(|(a, b)| u32::from_le_bytes([a[0], b[0], a[1], b[1]])),
                        ),
                    }
                }
            }
        }
        if channels.iter().zip(&self.selected).any(|(c, &selected)| selected && c.len() != n) {
            return Err(exr_err(
                &self.path,
                format!("block at {:?} decoded to the wrong number of samples", (rect.x0, rect.y0)),
            ));
        }
        Ok(DecodedBlock { rect, channels })
    }

    /// Decode every level-0 block intersecting `rows` that is not cached yet.
    fn fill_cache(&mut self, rows: Rect) -> Result<(), Error> {
        let dw = self.data_window;
        // Blocks entirely above the request are no longer needed (requests go down the frame).
        self.cache.retain(|_, b| b.rect.y1 > rows.y0);
        let cached: Vec<(i64, i64)> = self.cache.keys().copied().collect();
        let wanted = |block: &BlockIndex| {
            let y0 = dw.y0 + block.pixel_position.1 as i64;
            let y1 = y0 + block.pixel_size.1 as i64;
            let x0 = dw.x0 + block.pixel_position.0 as i64;
            block.level == Vec2(0, 0) && y1 > rows.y0 && y0 < rows.y1 && !cached.contains(&(y0, x0))
        };
        let reader = exr::block::read(Cursor::new(&self.bytes[..]), false).map_err(|e| exr_err(&self.path, e))?;
        let filtered = reader
            .filter_chunks(false, |_, _, block| wanted(&block))
            .map_err(|e| exr_err(&self.path, format!("bad offset table: {e}")))?;
        let meta: MetaData = filtered.meta_data().clone();
        let chunks: Vec<Chunk> = filtered
            .collect::<Result<_, _>>()
            .map_err(|e| exr_err(&self.path, format!("could not read a chunk: {e}")))?;
        self.chunks_decoded += chunks.len();
        // Decompress and decode each chunk in one step, so that its raw bytes
        // are freed as soon as its samples exist.
        let decoded: Vec<DecodedBlock> = chunks
            .into_par_iter()
            .map(|c| {
                self.scratch.with(|scratch| {
                    super::zip::with_block(c, &meta, scratch, |index, data| self.decode(index, data))
                        .map_err(|e| exr_err(&self.path, format!("could not decompress a chunk: {e}")))?
                })
            })
            .collect::<Result<_, _>>()?;
        for b in decoded {
            self.cache.insert((b.rect.y0, b.rect.x0), b);
        }
        // Compressed pages already decoded need not stay resident: drop them from
        // this process's mapping (they are re-read from the file if touched again).
        #[cfg(unix)]
        if let FileBytes::Mapped(m) = &self.bytes {
            // SAFETY: the mapping is read-only and file-backed; MADV_DONTNEED only
            // discards our view of clean pages, and no slice of the map is alive here.
            unsafe {
                let _ = m.unchecked_advise(memmap2::UncheckedAdvice::DontNeed);
            }
        }
        Ok(())
    }
}

/// Where a single-part header ends: after the magic number and version, a
/// list of attributes (name, type, size, value), closed by an empty name.
fn header_end(bytes: &[u8]) -> Option<usize> {
    let mut at = 8usize;
    let cstr_end = |from: usize| bytes.get(from..)?.iter().position(|&c| c == 0).map(|n| from + n);
    loop {
        let name_end = cstr_end(at)?;
        if name_end == at {
            return Some(at + 1);
        }
        let type_end = cstr_end(name_end + 1)?;
        let size = i32::from_le_bytes(bytes.get(type_end + 1..type_end + 5)?.try_into().ok()?);
        at = (type_end + 5).checked_add(usize::try_from(size).ok()?)?;
    }
}

/// Check the offset table before anything is decoded, so that a truncated or
/// corrupt file fails at once (not after filtering half of it): every chunk
/// must start after the table and leave room for its own header in the file.
fn check_offset_table(path: &Path, bytes: &[u8], chunk_count: usize) -> Result<(), Error> {
    let start = header_end(bytes).ok_or_else(|| exr_err(path, "the header is not terminated"))?;
    let table_end = chunk_count.checked_mul(8).and_then(|n| n.checked_add(start)).filter(|&e| e <= bytes.len());
    let Some(table_end) = table_end else {
        return Err(exr_err(
            path,
            format!("the file ends inside its offset table of {chunk_count} chunks: the file is truncated"),
        ));
    };
    for (i, entry) in bytes[start..table_end].chunks_exact(8).enumerate() {
        let offset = u64::from_le_bytes(entry.try_into().expect("8 bytes"));
        if offset < table_end as u64 || offset.saturating_add(8) > bytes.len() as u64 {
            return Err(exr_err(
                path,
                format!(
                    "chunk {i} of {chunk_count} starts at byte {offset}, outside the file's {} bytes of chunk data \
                     ({table_end}..{}): the file is truncated or its offset table corrupt",
                    bytes.len() - table_end,
                    bytes.len()
                ),
            ));
        }
    }
    Ok(())
}

impl RowSource for ExrSource {
    fn data_window(&self) -> Rect {
        self.data_window
    }

    fn channel_names(&self) -> Vec<String> {
        self.names.clone()
    }

    fn block_rows(&self) -> usize {
        ExrSource::block_rows(self)
    }

    fn sample_bytes(&self) -> Vec<usize> {
        self.kinds.iter().map(|k| if *k == SampleKind::F16 { 2 } else { 4 }).collect()
    }

    fn select_channels(&mut self, channels: &[usize]) {
        self.selected = (0..self.kinds.len()).map(|i| channels.contains(&i)).collect();
        // Blocks decoded before the selection may lack a channel it adds.
        self.cache.clear();
    }

    fn read_rows(&mut self, channels: &[usize], rows: Rect) -> Result<Vec<ChannelRows>, Error> {
        if let Some(c) = channels.iter().find(|&&c| !self.selected.get(c).copied().unwrap_or(false)) {
            return Err(Error::Internal(format!(
                "{}: channel {c} was not selected for reading (RowSource::select_channels)",
                self.path.display()
            )));
        }
        let rows = Rect { x0: self.data_window.x0, x1: self.data_window.x1, ..rows }.intersect(&self.data_window);
        self.fill_cache(rows)?;
        let w = rows.width();
        let mut out = Vec::with_capacity(channels.len());
        for &c in channels {
            let mut samples = Samples::F32(Vec::new());
            let mut first = true;
            for y in rows.y0..rows.y1 {
                for b in self.cache.values().filter(|b| b.rect.y0 <= y && y < b.rect.y1) {
                    let src = &b.channels[c];
                    if first {
                        samples = src.empty_like(rows.area());
                        first = false;
                    }
                    let off = (y - b.rect.y0) as usize * b.rect.width();
                    samples.extend_from(src, off..off + b.rect.width());
                }
            }
            if samples.len() != rows.area() {
                return Err(exr_err(
                    &self.path,
                    format!("rows {}..{} are not completely covered by the file's chunks", rows.y0, rows.y1),
                ));
            }
            debug_assert_eq!(samples.len(), w * rows.height());
            out.push(ChannelRows { rect: rows, samples });
        }
        Ok(out)
    }
}

/// Description of an output channel.
#[derive(Clone, Debug)]
pub struct SinkChannel {
    /// Name.
    pub name: String,
    /// Storage type.
    pub kind: SampleKind,
}

/// Writes full-width rows, in increasing y, to a scanline EXR file.
///
/// The file is written to a temporary file beside `path` by a writer thread
/// (which compresses chunks in parallel) and renamed into place by
/// [`RowSink::finish`]; if the sink is dropped unfinished, the temporary file
/// is removed and nothing appears at `path`.
pub struct ExrSink {
    path: PathBuf,
    target: Option<AtomicTarget>,
    tx: Option<mpsc::SyncSender<Vec<ChannelRows>>>,
    thread: Option<JoinHandle<Result<(), Error>>>,
    order: Vec<usize>,
}

impl ExrSink {
    /// Create the sink. `template` provides attributes to copy (display window,
    /// layer attributes, ...); the data window, channels and encoding are set here.
    /// The writer compresses blocks on `threads` threads of its own (0 = one
    /// per core): behind `engine::denoise_stream`, pass the engine's thread
    /// count, which `engine::budget` counts one encoder scratch for each.
    /// ZIP blocks are deflated at `zip_level` (one of
    /// [`zip::LEVELS`](super::zip::LEVELS), checked here).
    pub fn create(
        path: &Path,
        data_window: Rect,
        channels: &[SinkChannel],
        (compression, zip_level): (OutputCompression, i32),
        template: Option<&Header>,
        threads: usize,
    ) -> Result<ExrSink, Error> {
        if let Some(e) = super::zip::level_error(zip_level) {
            return Err(exr_err(path, e));
        }
        if channels.is_empty() {
            return Err(exr_err(path, "refusing to write a frame with no channels"));
        }
        if data_window.is_empty() {
            return Err(exr_err(path, "refusing to write an empty data window"));
        }
        // EXR stores channels sorted by name; remember how to reorder rows.
        let mut order: Vec<usize> = (0..channels.len()).collect();
        order.sort_by(|&a, &b| channels[a].name.cmp(&channels[b].name));
        let list: SmallVec<[ChannelDescription; 5]> = order
            .iter()
            .map(|&i| {
                let c = &channels[i];
                let t = match c.kind {
                    SampleKind::F16 => SampleType::F16,
                    SampleKind::F32 => SampleType::F32,
                    SampleKind::U32 => SampleType::U32,
                };
                let name = Text::new_or_none(&c.name)
                    .ok_or_else(|| exr_err(path, format!("channel name {:?} cannot be stored", c.name)))?;
                Ok(ChannelDescription::new(name, t, t != SampleType::F16 && t != SampleType::F32))
            })
            .collect::<Result<_, Error>>()?;
        let size = Vec2(data_window.width(), data_window.height());
        let mut header = Header::new(Text::from("main"), size, list).with_encoding(
            compression.to_exr(),
            BlockDescription::ScanLines,
            LineOrder::Increasing,
        );
        if let Some(t) = template {
            header.shared_attributes = t.shared_attributes.clone();
            header.own_attributes = t.own_attributes.clone();
            let dw = exr::meta::attribute::IntegerBounds::new(Vec2(data_window.x0 as i32, data_window.y0 as i32), size);
            for note in super::sanitize_attributes(&mut header.shared_attributes, &mut header.own_attributes, dw) {
                tracing::warn!("{}: {note}", path.display());
            }
        } else {
            header.shared_attributes.display_window =
                exr::meta::attribute::IntegerBounds::new(Vec2(data_window.x0 as i32, data_window.y0 as i32), size);
        }
        header.own_attributes.layer_position = Vec2(data_window.x0 as i32, data_window.y0 as i32);
        header.channels = ChannelList::new(header.channels.list.clone());

        let target = AtomicTarget::new(path);
        let file = File::create(&target.tmp).map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
        let (tx, rx) = mpsc::sync_channel::<Vec<ChannelRows>>(0);
        let thread_path = path.to_path_buf();
        let thread = std::thread::Builder::new()
            .name("exr-writer".into())
            .spawn(move || write_thread(file, header, data_window, rx, &thread_path, (threads, zip_level)))
            .map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
        Ok(ExrSink { path: path.to_path_buf(), target: Some(target), tx: Some(tx), thread: Some(thread), order })
    }

    fn join(&mut self) -> Result<(), Error> {
        self.tx = None;
        match self.thread.take() {
            Some(t) => {
                t.join().map_err(|_| Error::Internal(format!("{}: the writer thread panicked", self.path.display())))?
            }
            None => Ok(()),
        }
    }
}

/// Collects rows in increasing y and cuts them into scanline blocks, copying
/// each sample once (into the block's bytes).
struct ChunkAssembler {
    dw: Rect,
    lines_per_block: usize,
    next_y: i64,
    next_chunk: usize,
    /// Received bands not yet completely written, in increasing y; each holds
    /// every channel (sorted order) over the same rows.
    pieces: std::collections::VecDeque<Vec<ChannelRows>>,
}

impl ChunkAssembler {
    fn received_to(&self) -> i64 {
        self.pieces.back().map_or(self.next_y, |p| p[0].rect.y1)
    }

    fn push(&mut self, rows: Vec<ChannelRows>) -> Result<(), String> {
        let expected_y0 = self.received_to();
        if rows.is_empty()
            || rows.iter().any(|r| {
                r.rect.y0 != expected_y0
                    || r.rect.y1 != rows[0].rect.y1
                    || r.rect.x0 != self.dw.x0
                    || r.rect.x1 != self.dw.x1
                    || r.samples.len() != r.rect.area()
            })
        {
            return Err(format!("rows must arrive full-width in increasing y, starting at row {expected_y0}"));
        }
        self.pieces.push_back(rows);
        Ok(())
    }

    /// Every block whose rows are all here: its chunk number and block
    /// index. The rows stay until [`ChunkAssembler::release`].
    fn ready_blocks(&mut self) -> Vec<(usize, BlockIndex)> {
        let mut blocks = Vec::new();
        let have = self.received_to();
        while self.next_y < self.dw.y1 {
            let end = (self.next_y + self.lines_per_block as i64).min(self.dw.y1);
            if have < end {
                break;
            }
            let index = BlockIndex {
                layer: 0,
                pixel_position: Vec2(0, (self.next_y - self.dw.y0) as usize),
                pixel_size: Vec2(self.dw.width(), (end - self.next_y) as usize),
                level: Vec2(0, 0),
            };
            blocks.push((self.next_chunk, index));
            self.next_chunk += 1;
            self.next_y = end;
        }
        blocks
    }

    /// A ready block's lines of native bytes, in file order (each row, then
    /// each channel in sorted order), borrowed from the received rows.
    fn lines(&self, index: BlockIndex) -> impl Iterator<Item = &[u8]> {
        let y0 = self.dw.y0 + index.pixel_position.y() as i64;
        (y0..y0 + index.pixel_size.y() as i64).flat_map(move |y| {
            let piece = self.pieces.iter().find(|p| p[0].rect.y0 <= y && y < p[0].rect.y1).expect("rows received");
            piece.iter().map(move |rows| {
                let w = rows.rect.width();
                let off = (y - rows.rect.y0) as usize * w;
                match &rows.samples {
                    Samples::F16(v) => bytemuck::cast_slice(&v[off..off + w]),
                    Samples::F32(v) => bytemuck::cast_slice(&v[off..off + w]),
                    Samples::U32(v) => bytemuck::cast_slice(&v[off..off + w]),
                }
            })
        })
    }

    /// Drop the received rows that every ready block has been assembled from.
    fn release(&mut self) {
        while self.pieces.front().is_some_and(|p| p[0].rect.y1 <= self.next_y) {
            self.pieces.pop_front();
        }
    }

    fn complete(&self) -> bool {
        self.next_y >= self.dw.y1
    }
}

fn write_thread(
    file: File,
    header: Header,
    dw: Rect,
    rx: mpsc::Receiver<Vec<ChannelRows>>,
    path: &Path,
    (threads, zip_level): (usize, i32),
) -> Result<(), Error> {
    let encoders = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("exr-encoder-{i}"))
        .build()
        .map_err(|e| Error::Internal(format!("{}: the writer's threads: {e}", path.display())))?;
    let lines_per_block = header.compression.scan_lines_per_block();
    let mut asm = ChunkAssembler { dw, lines_per_block, next_y: dw.y0, next_chunk: 0, pieces: Default::default() };
    let scratch = super::zip::ScratchPool::default();
    let mut bad_rows: Option<String> = None;
    let mut writer = BufWriter::new(file);
    let result = exr::block::write(&mut writer, smallvec::smallvec![header], true, |meta, chunk_writer| {
        while let Ok(rows) = rx.recv() {
            if let Err(e) = asm.push(rows) {
                bad_rows = Some(e);
                break;
            }
            let blocks = asm.ready_blocks();
            let chunks: Vec<(usize, Chunk)> = encoders.install(|| {
                blocks
                    .into_par_iter()
                    .map(|(i, index)| {
                        scratch
                            .with(|s| {
                                super::zip::compress_block(index, &meta.headers, s, zip_level, || asm.lines(index))
                            })
                            .map(|c| (i, c))
                    })
                    .collect::<Result<_, _>>()
            })?;
            asm.release();
            for (i, c) in chunks {
                chunk_writer.write_chunk(i, c)?;
            }
        }
        Ok(())
    });
    if let Some(e) = bad_rows {
        return Err(Error::InvalidInput(format!("{}: {e}", path.display())));
    }
    // An encoding or I/O error stops the rows too: report it first.
    result.map_err(|e| match e {
        exr::error::Error::Io(io) => Error::Io { path: path.to_path_buf(), source: io },
        other => exr_err(path, format!("could not encode: {other}")),
    })?;
    if !asm.complete() {
        return Err(exr_err(path, "the frame's rows were not all delivered; no file written"));
    }
    let file = writer.into_inner().map_err(|e| Error::Io { path: path.to_path_buf(), source: e.into_error() })?;
    file.sync_all().map_err(|e| Error::Io { path: path.to_path_buf(), source: e })?;
    Ok(())
}

impl RowSink for ExrSink {
    fn write_rows(&mut self, rows: Vec<ChannelRows>) -> Result<(), Error> {
        if rows.len() != self.order.len() {
            return Err(Error::InvalidInput(format!(
                "{} channels of rows given, the sink has {}",
                rows.len(),
                self.order.len()
            )));
        }
        let mut slots: Vec<Option<ChannelRows>> = rows.into_iter().map(Some).collect();
        let sorted: Vec<ChannelRows> =
            self.order.iter().map(|&i| slots[i].take().expect("each channel once")).collect();
        let sent = self.tx.as_ref().map(|tx| tx.send(sorted).is_ok()).unwrap_or(false);
        if !sent {
            // The writer stopped: report its error.
            self.join()?;
            return Err(Error::Internal(format!("{}: the writer stopped", self.path.display())));
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Error> {
        self.join()?;
        let mut target = self.target.take().ok_or_else(|| Error::Internal("sink finished twice".into()))?;
        std::fs::rename(&target.tmp, &self.path).map_err(|e| Error::Io { path: self.path.clone(), source: e })?;
        target.done = true;
        Ok(())
    }
}

impl Drop for ExrSink {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

/// A frame held in memory as a [`RowSource`] (for embedding and benchmarks).
pub struct FrameSource<'a> {
    frame: &'a super::Frame,
}

impl<'a> FrameSource<'a> {
    /// Rows of `frame`.
    pub fn new(frame: &'a super::Frame) -> FrameSource<'a> {
        FrameSource { frame }
    }
}

impl RowSource for FrameSource<'_> {
    fn data_window(&self) -> Rect {
        self.frame.data_window
    }

    fn channel_names(&self) -> Vec<String> {
        self.frame.channel_names()
    }

    fn sample_bytes(&self) -> Vec<usize> {
        self.frame.channels.iter().map(|c| if c.kind == SampleKind::F16 { 2 } else { 4 }).collect()
    }

    fn read_rows(&mut self, channels: &[usize], rows: Rect) -> Result<Vec<ChannelRows>, Error> {
        let dw = self.frame.data_window;
        let rows = Rect { x0: dw.x0, x1: dw.x1, ..rows }.intersect(&dw);
        let range = (rows.y0 - dw.y0) as usize * dw.width()..(rows.y1 - dw.y0) as usize * dw.width();
        Ok(channels
            .iter()
            .map(|&i| {
                let all = self.frame.channels[i].samples();
                let mut samples = all.empty_like(range.len());
                samples.extend_from(all, range.clone());
                ChannelRows { rect: rows, samples }
            })
            .collect())
    }
}

/// Write `frame` at `path` through the streaming writer ([`ExrSink`]):
/// scanline blocks in increasing y, ZIP chunks deflated with libdeflate at
/// `zip_level` on `threads` encoder threads (0 = one per core), written
/// atomically, with the frame's attributes (sanitised as
/// [`write_frame`](super::write_frame) does). What `denoise --tile-size 0`
/// writes: `write_frame` encodes with the `exr` crate's own ZIP encoder, at
/// OpenEXR's level only.
pub fn write_frame_streamed(
    path: &Path,
    frame: &super::Frame,
    (compression, zip_level): (OutputCompression, i32),
    threads: usize,
) -> Result<(), Error> {
    let dw = frame.data_window;
    let template = (frame.image_attributes.is_some() || frame.layer_attributes.is_some()).then(|| {
        let mut h = Header::new(Text::from("main"), Vec2(dw.width(), dw.height()), SmallVec::new());
        match &frame.image_attributes {
            Some(a) => h.shared_attributes = a.clone(),
            None => {
                h.shared_attributes.display_window = exr::meta::attribute::IntegerBounds::new(
                    Vec2(dw.x0 as i32, dw.y0 as i32),
                    Vec2(dw.width(), dw.height()),
                )
            }
        }
        if let Some(a) = &frame.layer_attributes {
            h.own_attributes = a.clone();
        }
        h
    });
    let channels: Vec<SinkChannel> =
        frame.channels.iter().map(|c| SinkChannel { name: c.name.clone(), kind: c.kind }).collect();
    let mut sink = ExrSink::create(path, dw, &channels, (compression, zip_level), template.as_ref(), threads)?;
    let mut source = FrameSource::new(frame);
    let all: Vec<usize> = (0..channels.len()).collect();
    for band in dw.row_bands(64) {
        sink.write_rows(source.read_rows(&all, band)?)?;
    }
    sink.finish()
}

/// A [`RowSink`] that drops the rows (benchmarks) and counts them.
#[derive(Default)]
pub struct NullSink {
    /// Rows received.
    pub rows: usize,
}

impl RowSink for NullSink {
    fn write_rows(&mut self, rows: Vec<ChannelRows>) -> Result<(), Error> {
        self.rows += rows.first().map_or(0, |r| r.rect.height());
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Error> {
        Ok(())
    }
}
