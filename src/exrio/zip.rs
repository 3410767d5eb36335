//! ZIP chunks of the streaming reader and writer, with libdeflate (through
//! `libdeflater`) instead of the `exr` crate's `zune-inflate` decoder and
//! `miniz_oxide` encoder.
//!
//! The bytes are prepared exactly as OpenEXR's ZIP compressor does (and as
//! `exr` does): the block's little-endian bytes split into even and odd
//! halves, then replaced by their differences (`+ 128`, wrapping), then
//! zlib-compressed with libdeflate, which OpenEXR itself uses since 3.2, at
//! a level of the writer's choice ([`DEFAULT_LEVEL`] unless asked;
//! OpenEXR's default is [`OPENEXR_LEVEL`]; any level gives a standard
//! stream). A chunk that would not shrink is stored raw, as OpenEXR and
//! `exr` do, and readers expect. The writer prepares a
//! block straight from its rows, and the reader decodes samples straight
//! from the two halves, so neither makes an interleaved copy of a block;
//! their block-sized buffers are reused through a [`ScratchPool`].
//!
//! Why: in a 31-channel 1080p `denoise` run, `miniz_oxide`'s deflate took
//! 29 % of the CPU time (perf, 2026-11-22); zlib-rs cut the run's user time
//! by 6 %, and still took about a fifth of it (2026-11-23). libdeflate at
//! level 4 encodes the same blocks in about four fifths of zlib-rs's time,
//! into slightly fewer bytes, and at level 1 in 0.82x its own level-4 time,
//! into 0.5 % more (`cargo bench --bench zip`, `docs/performance.md`). Fresh block-sized buffers for every block made
//! most of a memory-bounded run's page faults (docs/performance.md,
//! "Session 15").

use std::cell::RefCell;

use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock, CompressedTileBlock};
use exr::block::{BlockIndex, UncompressedBlock};
use exr::compression::Compression;
use exr::error::Error;
use exr::meta::header::Header;
use exr::meta::{BlockDescription, MetaData};

/// OpenEXR's default ZIP compression level (also the `exr` crate's).
pub const OPENEXR_LEVEL: i32 = 4;

/// The streaming writer's default level: libdeflate's fastest. On the
/// 31-channel 1080p file run of `benches/opencv_compare.sh` it cut the
/// run's wall time and CPU time by about 5 % against level 4, for files
/// 0.7 % larger (two real renders' outputs: 0.9 and 1.8 % larger), since
/// denoised `f32` samples hardly compress at any level
/// (docs/performance.md, session 34; `cargo bench --bench zip` compares
/// the levels).
pub const DEFAULT_LEVEL: i32 = 1;

/// The levels libdeflate takes (1 fastest, 12 smallest).
pub const LEVELS: std::ops::RangeInclusive<i32> = 1..=12;

/// What is wrong with `level`, when it is not one of [`LEVELS`].
pub fn level_error(level: i32) -> Option<String> {
    (!LEVELS.contains(&level)).then(|| format!("zip level {level} is not one of {}..={}", LEVELS.start(), LEVELS.end()))
}

/// Block-sized buffers, reused from block to block (see [`ScratchPool`]).
#[derive(Default)]
pub struct Scratch {
    prepared: Vec<u8>,
    out: Vec<u8>,
}

/// The [`Scratch`]es of one stage (the reader of a file, or its writer),
/// shared by its workers: each block borrows one and gives it back, so the
/// pool holds at most one per concurrent worker, for as long as the file is
/// read or written.
///
/// Buffers above glibc's mmap threshold (`engine::budget::bound_allocator`)
/// are mapped fresh and unmapped on every allocation, and each of their pages
/// costs a fault on first write: block-sized buffers allocated per block made
/// a quarter of the page faults of a 1080p file run, and most of a
/// narrow-band memory-bounded run's (`perf record -e page-faults`,
/// docs/performance.md). `engine::budget` counts the pool.
#[derive(Default)]
pub struct ScratchPool(std::sync::Mutex<Vec<Scratch>>);

impl ScratchPool {
    /// Run `f` with a scratch of this pool (a new one when all are in use).
    pub fn with<R>(&self, f: impl FnOnce(&mut Scratch) -> R) -> R {
        let mut scratch = self.0.lock().ok().and_then(|mut v| v.pop()).unwrap_or_default();
        let result = f(&mut scratch);
        if let Ok(mut v) = self.0.lock() {
            v.push(scratch);
        }
        result
    }
}

/// The ZIP compressions (one or sixteen scanlines per block).
fn is_zip(header: &Header) -> bool {
    matches!(header.compression, Compression::ZIP1 | Compression::ZIP16) && cfg!(target_endian = "little")
}

/// Compress one block into its chunk. `lines` gives the block's lines of
/// native bytes in file order (each row, each channel), and may be called
/// more than once. ZIP scanline blocks are prepared straight from the lines
/// and deflated here; anything else (another compression, tiles, a
/// big-endian machine, whose native bytes need swapping first) goes to the
/// `exr` crate as one buffer.
pub(crate) fn compress_block<'a, I: Iterator<Item = &'a [u8]>>(
    index: BlockIndex,
    headers: &[Header],
    scratch: &mut Scratch,
    level: i32,
    lines: impl Fn() -> I,
) -> exr::error::Result<Chunk> {
    let header = &headers[index.layer];
    let expected = header.channels.bytes_per_pixel * index.pixel_size.area();
    if !is_zip(header) || !matches!(header.blocks, BlockDescription::ScanLines) {
        return UncompressedBlock { index, data: lines().collect::<Vec<_>>().concat() }.compress_to_chunk(headers);
    }
    let y = i32::try_from(index.pixel_position.y())
        .ok()
        .and_then(|y| y.checked_add(header.own_attributes.layer_position.y()))
        .ok_or_else(|| Error::Invalid("block position out of range".into()))?;
    let Scratch { prepared, out } = scratch;
    if prepare_lines(lines(), prepared) != Some(expected) {
        return Err(Error::Invalid("block lines do not add up to the block's size".into()));
    }
    let n = deflate(prepared, out, level)?;
    // Only store the compressed bytes when they are smaller than the raw ones.
    let compressed_pixels_le = if n < expected { out[..n].to_vec() } else { lines().collect::<Vec<_>>().concat() };
    Ok(Chunk {
        layer_index: index.layer,
        compressed_block: CompressedBlock::ScanLine(CompressedScanLineBlock { y_coordinate: y, compressed_pixels_le }),
    })
}

/// OpenEXR's ZIP encoding of little-endian block bytes: [`prepare`], then a
/// zlib stream from libdeflate at `level` (one of [`LEVELS`]).
pub fn encode(data: &[u8], level: i32) -> exr::error::Result<Vec<u8>> {
    let mut out = Vec::new();
    let n = deflate(&prepare(data), &mut out, level)?;
    out.truncate(n);
    Ok(out)
}

/// The zlib stream of prepared bytes at `level` into a reused buffer: `out[..n]`.
fn deflate(prepared: &[u8], out: &mut Vec<u8>, level: i32) -> exr::error::Result<usize> {
    thread_local! {
        // A compressor holds its match finder's tables: one per thread and
        // level, reused.
        static COMPRESSOR: RefCell<Option<(i32, libdeflater::Compressor)>> = const { RefCell::new(None) };
    }
    let fail = |what: String| Error::Invalid(format!("zip compression: {what}").into());
    if let Some(e) = level_error(level) {
        return Err(fail(e));
    }
    COMPRESSOR.with_borrow_mut(|slot| {
        let c = match slot {
            Some((l, c)) if *l == level => c,
            _ => {
                let lvl = libdeflater::CompressionLvl::new(level).map_err(|e| fail(format!("level {level}: {e:?}")))?;
                &mut slot.insert((level, libdeflater::Compressor::new(lvl))).1
            }
        };
        out.resize(c.zlib_compress_bound(prepared.len()), 0);
        c.zlib_compress(prepared, out).map_err(|e| fail(e.to_string()))
    })
}

/// OpenEXR's ZIP preparation of little-endian block bytes: the even bytes,
/// then the odd ones, each replaced by its difference to the previous one
/// plus 128 (wrapping).
pub fn prepare(data: &[u8]) -> Vec<u8> {
    let n = data.len();
    let mut prepared = Vec::new();
    if n.is_multiple_of(2) {
        prepare_lines(std::iter::once(data), &mut prepared);
        return prepared;
    }
    // An odd length (never a block's: every sample is 2 or 4 bytes): the
    // even half has the unpaired last byte.
    prepare_lines(std::iter::once(&data[..n - 1]), &mut prepared);
    let half = n.div_ceil(2);
    prepared.insert(half - 1, data[n - 1].wrapping_sub(if n > 1 { data[n - 3] } else { 0 }).wrapping_add(128));
    if n == 1 {
        prepared[0] = data[0];
    } else {
        prepared[half] = data[1].wrapping_sub(data[n - 1]).wrapping_add(128);
    }
    prepared
}

/// [`prepare`] of the concatenation of `lines`, each of an even number of
/// bytes, written into a reused buffer without the concatenation; returns
/// the byte count, or `None` for a line of an odd number of bytes. One pass over consecutive byte pairs, written so that it
/// vectorises: the even and odd outputs at `i` are the differences of pair
/// `i` and pair `i - 1`; the odd half's first byte follows the even half's
/// last.
fn prepare_lines<'a>(lines: impl Iterator<Item = &'a [u8]>, prepared: &mut Vec<u8>) -> Option<usize> {
    let lines: smallvec::SmallVec<[&[u8]; 64]> = lines.collect();
    if lines.iter().any(|l| !l.len().is_multiple_of(2)) {
        return None;
    }
    let n: usize = lines.iter().map(|l| l.len()).sum();
    prepared.clear();
    prepared.resize(n, 0);
    if n == 0 {
        return Some(0);
    }
    let (even, odd) = prepared.split_at_mut(n / 2);
    let mut k = 0;
    let mut prev: Option<[u8; 2]> = None;
    for line in lines.iter().filter(|l| l.len() >= 2) {
        let m = line.len() / 2;
        let (e, o) = (&mut even[k..k + m], &mut odd[k..k + m]);
        match prev {
            None => e[0] = line[0],
            Some(p) => {
                e[0] = line[0].wrapping_sub(p[0]).wrapping_add(128);
                o[0] = line[1].wrapping_sub(p[1]).wrapping_add(128);
            }
        }
        let pairs = line.chunks_exact(2).zip(line[2..].chunks_exact(2));
        for ((prev, pair), (e, o)) in pairs.zip(e.iter_mut().zip(o.iter_mut()).skip(1)) {
            *e = pair[0].wrapping_sub(prev[0]).wrapping_add(128);
            *o = pair[1].wrapping_sub(prev[1]).wrapping_add(128);
        }
        prev = Some([line[2 * m - 2], line[2 * m - 1]]);
        k += m;
    }
    // The odd half's first byte: the first odd byte after the last even one.
    let first_odd = lines.iter().find(|l| l.len() >= 2).map_or(0, |l| l[1]);
    odd[0] = first_odd.wrapping_sub(prev.map_or(0, |p| p[0])).wrapping_add(128);
    Some(n)
}

/// A block's native bytes as the decoder hands them over.
#[derive(Clone, Copy)]
pub(crate) enum BlockBytes<'a> {
    /// In file order.
    Plain(&'a [u8]),
    /// ZIP's even and odd halves (byte `2i` is `even[i]`, byte `2i + 1` is
    /// `odd[i]`), left split: a line (an even byte range) reads its samples
    /// from both halves directly, so the block is never interleaved.
    Split { even: &'a [u8], odd: &'a [u8] },
}

impl BlockBytes<'_> {
    /// Bytes in the block.
    pub(crate) fn len(&self) -> usize {
        match self {
            BlockBytes::Plain(b) => b.len(),
            BlockBytes::Split { even, odd } => even.len() + odd.len(),
        }
    }
}

/// Decode one chunk and hand its block's bytes to `f`: ZIP chunks inflated
/// by libdeflate into `scratch` (no block-sized allocation once the scratch
/// has grown) and handed over split ([`BlockBytes::Split`]), anything else
/// decoded by the `exr` crate. The block's position is checked as `exr`
/// checks it.
pub(crate) fn with_block<R>(
    chunk: Chunk,
    meta: &MetaData,
    scratch: &mut Scratch,
    f: impl FnOnce(BlockIndex, BlockBytes<'_>) -> R,
) -> exr::error::Result<R> {
    let header = meta.headers.get(chunk.layer_index).ok_or_else(|| Error::Invalid("chunk layer index".into()))?;
    if !is_zip(header) || header.deep {
        let block = UncompressedBlock::decompress_chunk(chunk, meta, false)?;
        return Ok(f(block.index, BlockBytes::Plain(&block.data)));
    }
    let tile = header.get_block_data_indices(&chunk.compressed_block)?;
    let bounds = header.get_absolute_block_pixel_coordinates(tile)?;
    bounds.validate(Some(header.layer_size))?;
    let max = header.max_block_pixel_size();
    if bounds.size.x() > max.x() || bounds.size.y() > max.y() {
        return Err(Error::Invalid("block larger than the header's block size".into()));
    }
    let index = BlockIndex {
        layer: chunk.layer_index,
        pixel_position: bounds.position.to_usize("block position")?,
        level: tile.level_index,
        pixel_size: bounds.size,
    };
    let expected = bounds.size.area() * header.channels.bytes_per_pixel;
    let compressed = match chunk.compressed_block {
        CompressedBlock::ScanLine(CompressedScanLineBlock { compressed_pixels_le, .. })
        | CompressedBlock::Tile(CompressedTileBlock { compressed_pixels_le, .. }) => compressed_pixels_le,
        _ => return Err(Error::NotSupported("deep data".into())),
    };
    // A chunk that did not shrink is stored raw.
    if compressed.len() == expected {
        return Ok(f(index, BlockBytes::Plain(&compressed)));
    }
    thread_local! {
        static DECOMPRESSOR: RefCell<libdeflater::Decompressor> = RefCell::new(libdeflater::Decompressor::new());
    }
    let prepared = &mut scratch.prepared;
    prepared.clear();
    prepared.resize(expected, 0);
    let n = DECOMPRESSOR
        .with_borrow_mut(|d| d.zlib_decompress(&compressed, prepared))
        .map_err(|_| Error::Invalid("zlib-compressed data malformed".into()))?;
    // Freed before the samples are made (`engine::budget` counts on it).
    drop(compressed);
    if n != expected {
        return Err(Error::Invalid("zlib-compressed data has the wrong size".into()));
    }
    undo_differences(prepared);
    let (even, odd) = prepared.split_at(expected.div_ceil(2));
    Ok(f(index, BlockBytes::Split { even, odd }))
}

/// The running sums that undo [`prepare`]'s differences, in place.
fn undo_differences(prepared: &mut [u8]) {
    if let Some(&first) = prepared.first() {
        let mut previous = first;
        for b in &mut prepared[1..] {
            previous = b.wrapping_add(previous).wrapping_sub(128);
            *b = previous;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The encoding round-trips through the `exr` crate's ZIP decoder: a
    /// file written with it decodes to the same samples (tested end to end
    /// in `tests/all`); here, the byte preparation inverts exactly, for odd
    /// lengths too.
    #[test]
    fn prepared_bytes_invert() {
        // Every level, switching between them on one thread (its compressor is
        // made again for a new level).
        for (k, len) in [0usize, 1, 2, 3, 4, 5, 17, 1000, 1001, 5000].into_iter().enumerate() {
            let data: Vec<u8> = (0..len).map(|i| ((i * 7919 + 13) % 251) as u8).collect();
            for level in LEVELS.map(|l| 1 + (l - 1 + k as i32) % LEVELS.end()) {
                let z = encode(&data, level).unwrap();
                let mut dec = Vec::new();
                std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(&z[..]), &mut dec).unwrap();
                undo_differences(&mut dec);
                let (even, odd) = dec.split_at(len.div_ceil(2));
                let back: Vec<u8> = (0..len).map(|i| if i % 2 == 0 { even[i / 2] } else { odd[i / 2] }).collect();
                assert_eq!(back, data, "len {len}, level {level}");
            }
        }
        for level in [0, 13, -1] {
            assert!(encode(&[1, 2, 3], level).is_err(), "level {level}");
        }
    }

    /// The levels make different streams of the same bytes (the level is
    /// applied), and the highest packs smaller than the fastest.
    #[test]
    fn levels_are_applied() {
        let data: Vec<u8> = (0..20_000u32).map(|i| ((i * i) % 61 + (i / 7) % 3) as u8).collect();
        let (fast, small) = (encode(&data, 1).unwrap(), encode(&data, 12).unwrap());
        assert_ne!(fast, small);
        assert!(small.len() < fast.len(), "level 12: {} bytes, level 1: {}", small.len(), fast.len());
    }

    /// Preparing a block line by line gives the bytes of preparing the
    /// concatenated lines, whatever the cut (empty lines included), into a
    /// buffer that held a longer block before.
    #[test]
    fn lines_prepare_as_their_concatenation() {
        let data: Vec<u8> = (0..600).map(|i| ((i * 7919 + 13) % 251) as u8).collect();
        let mut prepared = vec![9u8; 1000];
        for cuts in [vec![600], vec![2, 598], vec![0, 4, 0, 300, 296], vec![2; 300], vec![298, 2, 300]] {
            let mut at = 0;
            let lines: Vec<&[u8]> = cuts
                .iter()
                .map(|&c| {
                    at += c;
                    &data[at - c..at]
                })
                .collect();
            assert_eq!(prepare_lines(lines.into_iter(), &mut prepared), Some(600));
            assert_eq!(prepared, prepare(&data), "cuts {cuts:?}");
        }
        assert_eq!(prepare_lines([&data[..3], &data[3..]].into_iter(), &mut prepared), None, "a half sample");
    }

    /// The reader's libdeflate path decodes each ZIP chunk (compressed by
    /// the `exr` crate's writer, and by ours) to the bytes `exr` decodes,
    /// with one pool's scratch reused from chunk to chunk; a damaged chunk is
    /// an error, not a panic.
    #[test]
    fn chunks_decode_as_exr_decodes_them() {
        use crate::exrio::{Channel, Frame, OutputCompression, WriteOptions, write_frame};
        use crate::geom::Rect;
        let interleave = |b: BlockBytes<'_>| match b {
            BlockBytes::Plain(p) => p.to_vec(),
            BlockBytes::Split { even, odd } => {
                (0..even.len() + odd.len()).map(|i| if i % 2 == 0 { even[i / 2] } else { odd[i / 2] }).collect()
            }
        };
        let dw = Rect::from_origin_size(3, -2, 37, 41);
        let wave = |k: usize| (0..dw.area()).map(move |i| ((i * (7 + k)) as f32 * 0.013).sin() * 3.0 + k as f32);
        let frame = Frame::new(
            dw,
            vec![
                Channel::from_f32("B", wave(1).collect()),
                Channel::from_f32_as_half("G", &wave(2).collect::<Vec<_>>()),
                Channel::from_f32("R", vec![0.25; dw.area()]),
            ],
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("zip.exr");
        let opts = WriteOptions { compression: OutputCompression::Zip, ..Default::default() };
        write_frame(&path, &frame, &opts).unwrap();
        let reader = exr::block::read(std::io::BufReader::new(std::fs::File::open(&path).unwrap()), false).unwrap();
        let meta = reader.meta_data().clone();
        let chunks: Vec<Chunk> = reader.all_chunks(false).unwrap().map(|c| c.unwrap()).collect();
        assert!(chunks.len() > 2);
        let pool = ScratchPool::default();
        let mut damaged = 0;
        for chunk in chunks {
            let expected = UncompressedBlock::decompress_chunk(chunk.clone(), &meta, false).unwrap();
            let got = pool.with(|s| with_block(chunk.clone(), &meta, s, |i, d| (i, interleave(d)))).unwrap();
            assert_eq!(got, (expected.index, expected.data.clone()));
            // Our encoder's chunk of the same block, given as two lines,
            // decodes to the same bytes too.
            let half = expected.data.len() / 2 / 4 * 4;
            let lines = || [&expected.data[..half], &expected.data[half..]].into_iter();
            let ours = pool.with(|s| compress_block(expected.index, &meta.headers, s, DEFAULT_LEVEL, lines)).unwrap();
            assert_eq!(pool.with(|s| with_block(ours, &meta, s, |_, d| interleave(d))).unwrap(), expected.data);
            // Damage: a truncated deflate stream, and a flipped byte inside it.
            let mut broken = chunk.clone();
            if let CompressedBlock::ScanLine(b) = &mut broken.compressed_block {
                if b.compressed_pixels_le.len() == expected.data.len() {
                    continue; // stored raw: nothing to damage
                }
                let mut cut = b.clone();
                cut.compressed_pixels_le.truncate(cut.compressed_pixels_le.len() / 2);
                let cut = Chunk { layer_index: 0, compressed_block: CompressedBlock::ScanLine(cut) };
                assert!(pool.with(|s| with_block(cut, &meta, s, |_, _| ())).is_err());
                b.compressed_pixels_le[2] ^= 0xff;
                damaged += 1;
            }
            let _ = pool.with(|s| with_block(broken, &meta, s, |_, d| d.len()));
        }
        assert!(damaged > 0, "no compressed chunk was damaged");
        assert_eq!(pool.0.lock().unwrap().len(), 1, "one worker, one scratch");
    }
}
