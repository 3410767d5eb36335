//! ZIP compression of the streaming writer's scanline chunks with libdeflate
//! (through `libdeflater`), instead of the `exr` crate's `miniz_oxide` encoder.
//!
//! The bytes are prepared exactly as OpenEXR's ZIP compressor does (and as
//! `exr` does): the block's little-endian bytes split into even and odd
//! halves, then replaced by their differences (`+ 128`, wrapping), then
//! zlib-compressed at OpenEXR's default level 4 with libdeflate, which
//! OpenEXR itself uses since 3.2. A chunk that would not shrink is stored
//! raw, as OpenEXR and `exr` do, and readers expect.
//!
//! Why: in a 31-channel 1080p `denoise` run, `miniz_oxide`'s deflate took
//! 29 % of the CPU time (perf, 2026-11-22); zlib-rs cut the run's user time
//! by 6 %, and still took about a fifth of it (2026-11-23). libdeflate at
//! the same level encodes the same blocks in about four fifths of
//! zlib-rs's time, into slightly fewer bytes (`cargo bench --bench zip`,
//! `docs/performance.md`).

use std::cell::RefCell;

use exr::block::UncompressedBlock;
use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock};
use exr::compression::Compression;
use exr::meta::BlockDescription;
use exr::meta::header::Header;

/// OpenEXR's default ZIP compression level (also the `exr` crate's).
pub const LEVEL: i32 = 4;

/// Compress one block into its chunk: ZIP scanline blocks here, anything
/// else (another compression, tiles, a big-endian machine, whose native
/// bytes need swapping first) with the `exr` crate.
pub(crate) fn compress_block(block: UncompressedBlock, headers: &[Header]) -> exr::error::Result<Chunk> {
    let header = &headers[block.index.layer];
    let zip = matches!(header.compression, Compression::ZIP1 | Compression::ZIP16);
    let expected = header.channels.bytes_per_pixel * block.index.pixel_size.area();
    if !zip
        || !matches!(header.blocks, BlockDescription::ScanLines)
        || cfg!(target_endian = "big")
        || block.data.len() != expected
    {
        return block.compress_to_chunk(headers);
    }
    let y = i32::try_from(block.index.pixel_position.y())
        .ok()
        .and_then(|y| y.checked_add(header.own_attributes.layer_position.y()))
        .ok_or_else(|| exr::error::Error::Invalid("block position out of range".into()))?;
    let compressed = encode(&block.data)?;
    // Only store the compressed bytes when they are smaller than the raw ones.
    let compressed_pixels_le = if compressed.len() < block.data.len() { compressed } else { block.data };
    Ok(Chunk {
        layer_index: block.index.layer,
        compressed_block: CompressedBlock::ScanLine(CompressedScanLineBlock { y_coordinate: y, compressed_pixels_le }),
    })
}

/// OpenEXR's ZIP encoding of little-endian block bytes: [`prepare`], then a
/// zlib stream from libdeflate at [`LEVEL`].
pub fn encode(data: &[u8]) -> exr::error::Result<Vec<u8>> {
    thread_local! {
        // A compressor holds its match finder's tables: one per thread, reused.
        static COMPRESSOR: RefCell<Option<libdeflater::Compressor>> = const { RefCell::new(None) };
    }
    let prepared = prepare(data);
    let fail = |what: String| exr::error::Error::Invalid(format!("zip compression: {what}").into());
    COMPRESSOR.with_borrow_mut(|slot| {
        let c = match slot {
            Some(c) => c,
            None => slot.insert(libdeflater::Compressor::new(
                libdeflater::CompressionLvl::new(LEVEL).map_err(|e| fail(format!("{e:?}")))?,
            )),
        };
        let mut out = vec![0u8; c.zlib_compress_bound(prepared.len())];
        let n = c.zlib_compress(&prepared, &mut out).map_err(|e| fail(e.to_string()))?;
        out.truncate(n);
        Ok(out)
    })
}

/// OpenEXR's ZIP preparation of little-endian block bytes: the even bytes,
/// then the odd ones, each replaced by its difference to the previous one
/// plus 128 (wrapping). One pass over consecutive byte pairs, written so that
/// it vectorises: the even and odd outputs at `i` are the differences of
/// pair `i` and pair `i - 1`; the odd half's first byte follows the even
/// half's last.
pub fn prepare(data: &[u8]) -> Vec<u8> {
    let n = data.len();
    let half = n.div_ceil(2);
    let mut prepared = vec![0u8; n];
    if n == 0 {
        return prepared;
    }
    let (even, odd) = prepared.split_at_mut(half);
    even[0] = data[0];
    let pairs = data.chunks_exact(2).zip(data.get(2..).unwrap_or_default().chunks_exact(2));
    for ((prev, pair), (e, o)) in pairs.zip(even.iter_mut().zip(odd.iter_mut()).skip(1)) {
        *e = pair[0].wrapping_sub(prev[0]).wrapping_add(128);
        *o = pair[1].wrapping_sub(prev[1]).wrapping_add(128);
    }
    if n % 2 == 1 && n > 1 {
        // The unpaired last byte is the even half's last.
        even[half - 1] = data[n - 1].wrapping_sub(data[n - 3]).wrapping_add(128);
    }
    if let Some(o) = odd.first_mut() {
        *o = data[1].wrapping_sub(data[2 * (half - 1)]).wrapping_add(128);
    }
    prepared
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The encoding round-trips through the `exr` crate's ZIP decoder: a
    /// file written with it decodes to the same samples (tested end to end
    /// in `tests/all`); here, the byte preparation inverts exactly.
    #[test]
    fn prepared_bytes_invert() {
        for len in [0usize, 1, 2, 3, 4, 5, 17, 1000] {
            let data: Vec<u8> = (0..len).map(|i| ((i * 7919 + 13) % 251) as u8).collect();
            let z = encode(&data).unwrap();
            let mut dec = Vec::new();
            std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(&z[..]), &mut dec).unwrap();
            // Undo the differences, then re-interleave.
            for i in 1..dec.len() {
                dec[i] = dec[i].wrapping_add(dec[i - 1]).wrapping_sub(128);
            }
            let (even, odd) = dec.split_at(len.div_ceil(2));
            let back: Vec<u8> = (0..len).map(|i| if i % 2 == 0 { even[i / 2] } else { odd[i / 2] }).collect();
            assert_eq!(back, data, "len {len}");
        }
    }
}
