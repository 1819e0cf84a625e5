//! TIFF pages: tags through the `tiff` decoder, samples through it too except for 12-bit data,
//! whose strips or tiles are read, decompressed and unpacked here.
//!
//! The file is read through a seekable reader, never whole: only the headers, the directories
//! and the strips or tiles a page points to are read (the `tiff` decoder streams each chunk
//! through `Read::take` of its byte count; the 12-bit path reads at most what the page needs,
//! [`chunk_read_limit`]), so bytes past the image structure cost nothing.

use crate::decompress::{inflate, unlzw, unpack12_row, unpackbits};
use crate::error::IoErrorKind;
use crate::format::{ByteOrder, compression_name, photometric_name};
use bostrack_core::{Photometric, SampleFormat};
use std::io::{Read, Seek, SeekFrom};
use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;

/// Largest image (width x height) the readers accept: 2^28 pixels, i.e. 2 GiB of f64 samples.
/// It guards against absurd sizes in damaged headers.
pub(crate) const MAX_PIXELS: u64 = 1 << 28;

/// How a page's samples are cut into chunks.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Chunks {
    Strips { rows_per_strip: usize },
    Tiles { width: usize, height: usize },
}

/// What the tags of one page say, checked against what this crate supports.
#[derive(Clone, Debug)]
pub(crate) struct PageHeader {
    pub width: usize,
    pub height: usize,
    pub bits: u16,
    pub format: SampleFormat,
    pub compression: u16,
    pub photometric: Photometric,
    pub chunks: Chunks,
    offsets: Vec<u64>,
    counts: Vec<u64>,
}

/// An open TIFF file read through `R`; one page is current at a time.
pub(crate) struct TiffFile<R: Read + Seek> {
    /// Length of the file in bytes (chunks must lie inside it).
    len: u64,
    dec: Decoder<R>,
    page: usize,
}

impl<R: Read + Seek> TiffFile<R> {
    /// Opens a TIFF file of `len` bytes read through `reader` (positioned anywhere).
    pub(crate) fn open(reader: R, len: u64) -> Result<Self, IoErrorKind> {
        let mut limits = Limits::default();
        limits.decoding_buffer_size = (MAX_PIXELS * 8) as usize;
        let dec = Decoder::new(reader)
            .map_err(IoErrorKind::from_tiff)?
            .with_limits(limits);
        Ok(TiffFile { len, dec, page: 0 })
    }

    pub(crate) fn byte_order(&self) -> ByteOrder {
        match self.dec.byte_order() {
            tiff::tags::ByteOrder::LittleEndian => ByteOrder::LittleEndian,
            tiff::tags::ByteOrder::BigEndian => ByteOrder::BigEndian,
        }
    }

    /// Index of the current page.
    pub(crate) fn page(&self) -> usize {
        self.page
    }

    pub(crate) fn has_more_pages(&self) -> bool {
        self.dec.more_images()
    }

    /// Moves to the next page; `Ok(false)` when there is none.
    pub(crate) fn next_page(&mut self) -> Result<bool, IoErrorKind> {
        if !self.dec.more_images() {
            return Ok(false);
        }
        self.page += 1;
        self.dec
            .next_image()
            .map_err(|e| in_page(self.page, IoErrorKind::from_tiff(e)))?;
        Ok(true)
    }

    /// Number of pages, counted from the current one on (moves to the last page). Pages whose
    /// directory cannot be parsed end the count.
    pub(crate) fn count_remaining_pages(&mut self) -> usize {
        let mut n = 1;
        while let Ok(true) = self.next_page() {
            n += 1;
        }
        n
    }

    /// The current page's tags, rejecting what cannot be decoded.
    pub(crate) fn header(&mut self) -> Result<PageHeader, IoErrorKind> {
        self.header_unpaged().map_err(|e| in_page(self.page, e))
    }

    fn header_unpaged(&mut self) -> Result<PageHeader, IoErrorKind> {
        let tiff = |e| IoErrorKind::from_tiff(e);
        let (w, h) = self.dec.dimensions().map_err(tiff)?;
        let (width, height) = (w as usize, h as usize);
        if u64::from(w) * u64::from(h) > MAX_PIXELS {
            return Err(IoErrorKind::TooLarge {
                width: w.into(),
                height: h.into(),
                limit: MAX_PIXELS,
            });
        }
        let compression = self
            .dec
            .find_tag_unsigned::<u16>(Tag::Compression)
            .map_err(tiff)?
            .unwrap_or(1);
        if !matches!(compression, 1 | 5 | 8 | 32946 | 32773) {
            return Err(IoErrorKind::UnsupportedCompression {
                code: compression,
                name: compression_name(compression),
            });
        }
        let samples = self
            .dec
            .find_tag_unsigned::<u16>(Tag::SamplesPerPixel)
            .map_err(tiff)?
            .unwrap_or(1);
        if samples != 1 {
            return Err(IoErrorKind::Unsupported(format!(
                "{samples} samples per pixel (colour or multi-channel); only single-channel grayscale is read"
            )));
        }
        let pm = self
            .dec
            .find_tag_unsigned::<u16>(Tag::PhotometricInterpretation)
            .map_err(tiff)?;
        let photometric = match pm {
            Some(0) => Photometric::WhiteIsZero,
            Some(1) | None => Photometric::BlackIsZero,
            Some(c) => {
                return Err(IoErrorKind::Unsupported(format!(
                    "photometric interpretation {} ({c}); only BlackIsZero and WhiteIsZero grayscale are read",
                    photometric_name(c)
                )));
            }
        };
        let first = |v: Option<Vec<u16>>| v.and_then(|v| v.first().copied());
        let sf = first(
            self.dec
                .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)
                .map_err(tiff)?,
        )
        .unwrap_or(1);
        let bits = first(
            self.dec
                .find_tag_unsigned_vec::<u16>(Tag::BitsPerSample)
                .map_err(tiff)?,
        )
        .unwrap_or(1);
        let format = match (sf, bits) {
            (1, 8 | 12 | 16 | 32) => SampleFormat::Unsigned,
            (3, 32 | 64) => SampleFormat::Float,
            _ => {
                let format = match sf {
                    1 => "unsigned",
                    2 => "signed integer",
                    3 => "float",
                    _ => "undefined-format",
                };
                return Err(IoErrorKind::UnsupportedBitDepth { bits, format });
            }
        };
        let fill_order = self
            .dec
            .find_tag_unsigned::<u16>(Tag::FillOrder)
            .map_err(tiff)?
            .unwrap_or(1);
        if fill_order != 1 {
            return Err(IoErrorKind::Unsupported(format!(
                "FillOrder {fill_order} (least significant bit first); only FillOrder 1 is read"
            )));
        }
        let predictor = self
            .dec
            .find_tag_unsigned::<u16>(Tag::Predictor)
            .map_err(tiff)?
            .unwrap_or(1);
        if bits == 12 && predictor != 1 {
            return Err(IoErrorKind::Unsupported(format!(
                "predictor {predictor} with 12-bit samples (libtiff does not write it either)"
            )));
        }
        let tiled = self.dec.get_chunk_type() == tiff::decoder::ChunkType::Tile;
        let (chunks, off_tag, cnt_tag, what) = if tiled {
            let (tw, tl) = self.dec.chunk_dimensions();
            if u64::from(tw) * u64::from(tl) > MAX_PIXELS {
                return Err(IoErrorKind::TooLarge {
                    width: tw.into(),
                    height: tl.into(),
                    limit: MAX_PIXELS,
                });
            }
            (
                Chunks::Tiles {
                    width: tw as usize,
                    height: tl as usize,
                },
                Tag::TileOffsets,
                Tag::TileByteCounts,
                "tile",
            )
        } else {
            let rps = self
                .dec
                .find_tag_unsigned::<u64>(Tag::RowsPerStrip)
                .map_err(tiff)?
                .unwrap_or(u64::MAX);
            let rows_per_strip = rps.clamp(1, h.into()) as usize;
            (
                Chunks::Strips { rows_per_strip },
                Tag::StripOffsets,
                Tag::StripByteCounts,
                "strip",
            )
        };
        let offsets = self
            .dec
            .find_tag_unsigned_vec::<u64>(off_tag)
            .map_err(tiff)?
            .unwrap_or_default();
        let counts = self
            .dec
            .find_tag_unsigned_vec::<u64>(cnt_tag)
            .map_err(tiff)?
            .unwrap_or_default();
        if offsets.len() != counts.len() || offsets.is_empty() {
            return Err(IoErrorKind::Corrupt(format!(
                "{} {what} offsets but {} byte counts",
                offsets.len(),
                counts.len()
            )));
        }
        let len = self.len;
        for (i, (&o, &c)) in offsets.iter().zip(&counts).enumerate() {
            let end = o.saturating_add(c);
            if end > len {
                return Err(IoErrorKind::Truncated(format!(
                    "{what} {i} of {} (bytes {o}..{end}) lies past the end of the file ({len} bytes)",
                    offsets.len()
                )));
            }
        }
        Ok(PageHeader {
            width,
            height,
            bits,
            format,
            compression,
            photometric,
            chunks,
            offsets,
            counts,
        })
    }

    /// Decodes the current page into row-major samples, larger = brighter (WhiteIsZero inverted
    /// exactly once: by the `tiff` crate for 8/16/32-bit and float data, here for 12-bit data).
    pub(crate) fn decode(&mut self, h: &PageHeader) -> Result<Vec<f64>, IoErrorKind> {
        let data = if h.bits == 12 {
            decode12(self.dec.inner(), h)
        } else {
            self.decode_with_tiff_crate(h)
        };
        data.map_err(|e| in_page(self.page, e))
    }

    fn decode_with_tiff_crate(&mut self, h: &PageHeader) -> Result<Vec<f64>, IoErrorKind> {
        // The tiff crate inverts WhiteIsZero itself: (2^bits - 1) - raw for unsigned samples,
        // 1.0 - raw for float samples (checked by the tests on crafted files and on mask.tif).
        let res = self.dec.read_image().map_err(IoErrorKind::from_tiff)?;
        let data: Vec<f64> = match res {
            DecodingResult::U8(v) => v.into_iter().map(f64::from).collect(),
            DecodingResult::U16(v) => v.into_iter().map(f64::from).collect(),
            DecodingResult::U32(v) => v.into_iter().map(f64::from).collect(),
            DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
            DecodingResult::F64(v) => v,
            _ => {
                return Err(IoErrorKind::Unsupported(
                    "sample type of the tiff decoder".into(),
                ));
            }
        };
        if data.len() != h.width * h.height {
            return Err(IoErrorKind::Corrupt(format!(
                "decoded {} samples for a {} x {} image",
                data.len(),
                h.width,
                h.height
            )));
        }
        Ok(data)
    }
}

/// Wraps an error of page `page` > 0 so that its message says which page.
fn in_page(page: usize, e: IoErrorKind) -> IoErrorKind {
    match e {
        IoErrorKind::InPage { .. } => e,
        _ if page == 0 => e,
        _ => IoErrorKind::InPage {
            page,
            kind: Box::new(e),
        },
    }
}

/// The most bytes read from a chunk whose decoded data are `need` bytes: `need` for
/// uncompressed data, `2 need + 4096` for compressed data (PackBits grows data by at most 1/128,
/// LZW with 12-bit codes by at most 1/2, Deflate by a few bytes per 16 KiB block), so a byte
/// count that claims more than the data can need does not make the reader read it.
pub(crate) fn chunk_read_limit(compression: u16, need: usize) -> u64 {
    let need = need as u64;
    if compression == 1 {
        need
    } else {
        2 * need + 4096
    }
}

/// Reads, decompresses and unpacks the 12-bit strips or tiles of one page.
fn decode12<R: Read + Seek>(r: &mut R, h: &PageHeader) -> Result<Vec<f64>, IoErrorKind> {
    let (cw, ch, what) = match h.chunks {
        Chunks::Strips { rows_per_strip } => (h.width, rows_per_strip, "strip"),
        Chunks::Tiles { width, height } => (width, height, "tile"),
    };
    let row_bytes = (cw * 12).div_ceil(8);
    let across = h.width.div_ceil(cw);
    let expected = across * h.height.div_ceil(ch);
    if h.offsets.len() < expected {
        return Err(IoErrorKind::Corrupt(format!(
            "{} {what}s where {expected} are needed",
            h.offsets.len()
        )));
    }
    let mut out = vec![0.0; h.width * h.height];
    let mut scratch = Vec::new();
    let mut raw = Vec::new();
    for (i, (&off, &cnt)) in h.offsets.iter().zip(&h.counts).take(expected).enumerate() {
        let (x0, y0) = ((i % across) * cw, (i / across) * ch);
        let (cols, rows) = (cw.min(h.width - x0), ch.min(h.height - y0));
        let need = row_bytes * rows;
        // the chunk lies inside the file (checked in `header`); read no more than it can need
        let take = cnt.min(chunk_read_limit(h.compression, need));
        raw.clear();
        r.seek(SeekFrom::Start(off)).map_err(IoErrorKind::from_io)?;
        r.by_ref()
            .take(take)
            .read_to_end(&mut raw)
            .map_err(IoErrorKind::from_io)?;
        if (raw.len() as u64) < take {
            return Err(IoErrorKind::Truncated(format!(
                "{what} {i} ends after {} of its {take} bytes",
                raw.len()
            )));
        }
        let src = &raw[..];
        let data: &[u8] = match h.compression {
            1 => src.get(..need).ok_or_else(|| {
                IoErrorKind::Truncated(format!(
                    "{what} {i} holds {} bytes, {need} are needed",
                    src.len()
                ))
            })?,
            32773 => {
                unpackbits(src, need, &mut scratch)
                    .map_err(|e| IoErrorKind::Corrupt(format!("{what} {i}: {e}")))?;
                &scratch
            }
            5 => {
                unlzw(src, need, &mut scratch)
                    .map_err(|e| IoErrorKind::Corrupt(format!("{what} {i}: {e}")))?;
                &scratch
            }
            8 | 32946 => {
                inflate(src, need, &mut scratch)
                    .map_err(|e| IoErrorKind::Corrupt(format!("{what} {i}: {e}")))?;
                &scratch
            }
            c => {
                return Err(IoErrorKind::UnsupportedCompression {
                    code: c,
                    name: compression_name(c),
                });
            }
        };
        for (r, row) in data.chunks_exact(row_bytes).enumerate() {
            let start = (y0 + r) * h.width + x0;
            unpack12_row(row, &mut out[start..start + cols]);
        }
    }
    if h.photometric == Photometric::WhiteIsZero {
        for v in &mut out {
            *v = 4095.0 - *v;
        }
    }
    Ok(out)
}
