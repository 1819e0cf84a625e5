//! Strip/tile decompression and 12-bit unpacking for the samples the `tiff` crate cannot decode.
//!
//! Sources: TIFF 6.0 specification (Adobe, 1992), section 9 (PackBits), section 13 (LZW, with
//! the TIFF "early change" of the code width), and the Adobe Deflate technote (zlib stream, RFC
//! 1950/1951). The LZW and Deflate bit streams are decoded by `weezl` and `flate2`, the crates
//! the `tiff` decoder itself uses.

use std::io::Read;

/// Undoes PackBits into exactly `need` bytes (`out` is cleared first).
///
/// A header byte `n` (as i8) is followed by `n + 1` literal bytes for `0 <= n <= 127`, by one
/// byte repeated `1 - n` times for `-127 <= n <= -1`; `-128` is a no-op. Rows may be packed one
/// by one or across row ends: both give the same byte stream here.
pub(crate) fn unpackbits(src: &[u8], need: usize, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    out.reserve(need);
    let mut i = 0;
    while out.len() < need && i < src.len() {
        let n = src[i] as i8;
        i += 1;
        if n >= 0 {
            let len = n as usize + 1;
            let Some(lit) = src.get(i..i + len) else {
                return Err(format!(
                    "PackBits literal run of {len} bytes cut off by the end of the chunk"
                ));
            };
            out.extend_from_slice(lit);
            i += len;
        } else if n != -128 {
            let len = (1 - i16::from(n)) as usize;
            let Some(&b) = src.get(i) else {
                return Err("PackBits repeat run cut off by the end of the chunk".into());
            };
            out.resize(out.len() + len, b);
            i += 1;
        }
    }
    if out.len() < need {
        return Err(format!(
            "PackBits data gives {} of the {need} bytes expected",
            out.len()
        ));
    }
    out.truncate(need);
    Ok(())
}

/// Undoes TIFF LZW (MSB-first codes, early change) into exactly `need` bytes.
pub(crate) fn unlzw(src: &[u8], need: usize, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    out.resize(need, 0);
    let mut dec = weezl::decode::Decoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8);
    let (mut inp, mut filled) = (src, 0);
    while filled < need {
        let r = dec.decode_bytes(inp, &mut out[filled..]);
        inp = &inp[r.consumed_in..];
        filled += r.consumed_out;
        match r.status {
            Ok(weezl::LzwStatus::Ok) if r.consumed_in > 0 || r.consumed_out > 0 => {}
            Ok(_) => break,
            Err(e) => return Err(format!("LZW data cannot be decoded: {e}")),
        }
    }
    if filled < need {
        return Err(format!(
            "LZW data gives {filled} of the {need} bytes expected"
        ));
    }
    Ok(())
}

/// Undoes Deflate (a zlib stream) into exactly `need` bytes.
pub(crate) fn inflate(src: &[u8], need: usize, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    out.resize(need, 0);
    flate2::read::ZlibDecoder::new(src)
        .read_exact(out)
        .map_err(|e| format!("Deflate data cannot be decoded into {need} bytes: {e}"))
}

/// Unpacks one row of 12-bit samples into `dst` (`dst.len()` samples).
///
/// Samples are packed MSB-first (TIFF FillOrder 1) whatever the file's byte order, each row
/// starting on a byte boundary: two pixels from three bytes,
/// `p0 = b0 << 4 | b1 >> 4`, `p1 = (b1 & 0xF) << 8 | b2`; an odd last pixel uses two bytes.
/// `src` must hold at least `ceil(1.5 * dst.len())` bytes.
pub(crate) fn unpack12_row(src: &[u8], dst: &mut [f64]) {
    let pairs = dst.len() / 2;
    for (d, s) in dst.chunks_exact_mut(2).zip(src.chunks_exact(3)) {
        let (b0, b1, b2) = (u16::from(s[0]), u16::from(s[1]), u16::from(s[2]));
        d[0] = f64::from(b0 << 4 | b1 >> 4);
        d[1] = f64::from((b1 & 0xF) << 8 | b2);
    }
    if dst.len() % 2 == 1 {
        let s = &src[3 * pairs..];
        dst[2 * pairs] = f64::from(u16::from(s[0]) << 4 | u16::from(s[1]) >> 4);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Test-side packer, written from the TIFF rule independently of `unpack12_row`.
    fn pack12(vals: &[u16]) -> Vec<u8> {
        let mut bits: Vec<bool> = vals
            .iter()
            .flat_map(|&v| (0..12).rev().map(move |k| v >> k & 1 == 1))
            .collect();
        while !bits.len().is_multiple_of(8) {
            bits.push(false);
        }
        bits.chunks(8)
            .map(|c| c.iter().fold(0u8, |acc, &b| acc << 1 | u8::from(b)))
            .collect()
    }

    #[test]
    fn unpack12_known_bytes() {
        // 0xABC, 0x123, 0xFFF -> AB C1 23 FF F0
        let src = [0xAB, 0xC1, 0x23, 0xFF, 0xF0];
        let mut dst = [0.0; 3];
        unpack12_row(&src, &mut dst);
        assert_eq!(dst, [2748.0, 291.0, 4095.0]);
    }

    #[test]
    fn packbits_spec_example() {
        // TIFF 6.0 section 9 example
        let packed = [
            0xFE, 0xAA, 0x02, 0x80, 0x00, 0x2A, 0xFD, 0xAA, 0x03, 0x80, 0x00, 0x2A, 0x22, 0xF7,
            0xAA,
        ];
        let unpacked = [
            0xAA, 0xAA, 0xAA, 0x80, 0x00, 0x2A, 0xAA, 0xAA, 0xAA, 0xAA, 0x80, 0x00, 0x2A, 0x22,
            0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA,
        ];
        let mut out = Vec::new();
        unpackbits(&packed, unpacked.len(), &mut out).unwrap();
        assert_eq!(out, unpacked);
        assert!(unpackbits(&packed, unpacked.len() + 1, &mut out).is_err());
        assert!(unpackbits(&packed[..5], 6, &mut out).is_err());
    }

    #[test]
    fn corrupt_streams_are_errors() {
        let mut out = Vec::new();
        assert!(inflate(b"not zlib at all", 10, &mut out).is_err());
        assert!(unlzw(&[0xFF; 8], 100, &mut out).is_err());
    }

    proptest! {
        #[test]
        fn unpack12_inverts_pack12(vals in proptest::collection::vec(0u16..4096, 1..64)) {
            let packed = pack12(&vals);
            prop_assert_eq!(packed.len(), (vals.len() * 12).div_ceil(8));
            let mut dst = vec![0.0; vals.len()];
            unpack12_row(&packed, &mut dst);
            let want: Vec<f64> = vals.iter().map(|&v| f64::from(v)).collect();
            prop_assert_eq!(dst, want);
        }

        #[test]
        fn deflate_round_trip(data in proptest::collection::vec(any::<u8>(), 0..500)) {
            use std::io::Write;
            let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            enc.write_all(&data).unwrap();
            let z = enc.finish().unwrap();
            let mut out = Vec::new();
            inflate(&z, data.len(), &mut out).unwrap();
            prop_assert_eq!(out, data);
        }

        #[test]
        fn lzw_round_trip(data in proptest::collection::vec(0u8..4, 1..2000)) {
            let z = weezl::encode::Encoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8).encode(&data).unwrap();
            let mut out = Vec::new();
            unlzw(&z, data.len(), &mut out).unwrap();
            prop_assert_eq!(out, data);
        }
    }
}
