//! LZF compression as used by PCD `binary_compressed` (Marc Lehmann's liblzf format).
//!
//! no_std, no allocation: both directions write into a caller-supplied slice. The
//! decompressor checks every read, every write and every back reference, so corrupt or
//! hostile input gives an [`LzfError`], never a panic or an out-of-bounds access.
//!
//! Format: a stream of chunks, each starting with a control byte `c`.
//! * `c < 32`: a literal run of `c + 1` bytes follows.
//! * otherwise a back reference: length `c >> 5` (7 means "add the next byte"), plus 2;
//!   offset `((c & 0x1f) << 8) + next byte + 1` bytes back from the output position.

use core::fmt;

/// Why LZF data could not be decompressed (or compressed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LzfError {
    /// The output slice is too small for the data.
    OutputTooSmall,
    /// The input ends in the middle of a chunk.
    TruncatedInput,
    /// A back reference points before the start of the output.
    BadBackReference,
}

impl fmt::Display for LzfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LzfError::OutputTooSmall => "LZF output buffer too small",
            LzfError::TruncatedInput => "LZF input ends inside a chunk",
            LzfError::BadBackReference => "LZF back reference before the start of the output",
        })
    }
}

/// Longest literal run one control byte can announce.
const MAX_LITERAL: usize = 32;
/// Shortest match worth a back reference.
const MIN_MATCH: usize = 3;
/// Longest match one back reference can encode (7 + 255 + 2).
const MAX_MATCH: usize = 264;
/// Farthest back a reference can point.
const MAX_OFFSET: usize = 8192;
/// log2 of the compressor's hash table size (16 KiB of `u32` on the stack).
const HASH_LOG: u32 = 12;

/// Most output bytes one input byte can yield: a long back reference (control byte,
/// length byte, offset byte) yields at most 264 bytes from 3; a short one 8 from 2; a
/// literal run less than it takes.
pub const MAX_EXPANSION: usize = MAX_MATCH / 3;

/// Upper bound of [`decompress`]'s output for `n` input bytes: what a header claiming an
/// uncompressed size is checked against before a buffer of that size is allocated.
pub const fn max_decompressed_len(n: usize) -> usize {
    n.saturating_mul(MAX_EXPANSION)
}

/// Upper bound of [`compress`]'s output for `n` input bytes (all literals: one control
/// byte per 32 bytes).
pub const fn max_compressed_len(n: usize) -> usize {
    n + n.div_ceil(MAX_LITERAL)
}

/// Decompresses `input` into `output`; returns the number of bytes written.
pub fn decompress(input: &[u8], output: &mut [u8]) -> Result<usize, LzfError> {
    let mut ip = 0;
    let mut op = 0;
    while ip < input.len() {
        let ctrl = usize::from(input[ip]);
        ip += 1;
        if ctrl < MAX_LITERAL {
            let len = ctrl + 1;
            let src = input.get(ip..ip + len).ok_or(LzfError::TruncatedInput)?;
            let dst = output.get_mut(op..op + len).ok_or(LzfError::OutputTooSmall)?;
            copy_short(dst, src);
            ip += len;
            op += len;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                len += usize::from(*input.get(ip).ok_or(LzfError::TruncatedInput)?);
                ip += 1;
            }
            len += 2;
            let low = usize::from(*input.get(ip).ok_or(LzfError::TruncatedInput)?);
            ip += 1;
            let back = ((ctrl & 0x1f) << 8) + low + 1;
            let from = op.checked_sub(back).ok_or(LzfError::BadBackReference)?;
            if output.len() < op + len {
                return Err(LzfError::OutputTooSmall);
            }
            copy_back_reference(output, from, op, len);
            op += len;
        }
    }
    Ok(op)
}

/// Compresses `input` into `output`; returns the number of bytes written. `output` of
/// [`max_compressed_len`] bytes always suffices.
pub fn compress(input: &[u8], output: &mut [u8]) -> Result<usize, LzfError> {
    let mut table = [0u32; 1 << HASH_LOG];
    let mut out = Writer { buf: output, pos: 0, lit_start: 0, lit_len: 0 };
    let mut ip = 0;
    while ip + MIN_MATCH <= input.len() {
        let h = hash(&input[ip..ip + MIN_MATCH]);
        // Table entries hold position + 1 so 0 means "empty".
        let candidate = table[h] as usize;
        table[h] = (ip + 1) as u32;
        if let Some(len) = match_at(input, candidate, ip) {
            out.flush_literals(input)?;
            out.back_reference(ip - (candidate - 1), len)?;
            // Seed the table inside the match so later data can refer to it.
            for p in ip + 1..(ip + len).min(input.len().saturating_sub(MIN_MATCH - 1)) {
                table[hash(&input[p..p + MIN_MATCH])] = (p + 1) as u32;
            }
            ip += len;
        } else {
            out.literal(input, ip)?;
            ip += 1;
        }
    }
    while ip < input.len() {
        out.literal(input, ip)?;
        ip += 1;
    }
    out.flush_literals(input)?;
    Ok(out.pos)
}

/// Copies `len` bytes from `from` to `to` (`from < to`), byte by byte where the ranges
/// overlap, as LZF's run-length trick (offset 1 = repeat the last byte) needs.
fn copy_back_reference(output: &mut [u8], from: usize, to: usize, len: usize) {
    if to - from >= len && len > 16 {
        output.copy_within(from..from + len, to);
    } else {
        // Bounds checked once here, so the loop below needs no per-byte checks.
        let window = &mut output[from..to + len];
        for k in 0..len {
            window[to - from + k] = window[k];
        }
    }
}

/// Copies a literal run (at most 32 bytes): a plain loop beats a `memcpy` call here.
#[inline(always)]
fn copy_short(dst: &mut [u8], src: &[u8]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d = *s;
    }
}

/// Hash of three bytes into the compressor's table.
fn hash(b: &[u8]) -> usize {
    let v = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
    (v.wrapping_mul(2_654_435_761) >> (32 - HASH_LOG)) as usize
}

/// Length of the match between the data at table entry `candidate` (position + 1) and
/// `ip`, if it is usable (in range and at least [`MIN_MATCH`] long).
fn match_at(input: &[u8], candidate: usize, ip: usize) -> Option<usize> {
    let from = candidate.checked_sub(1)?;
    if from >= ip || ip - from > MAX_OFFSET {
        return None;
    }
    let max = (input.len() - ip).min(MAX_MATCH);
    let len = (0..max).take_while(|&k| input[from + k] == input[ip + k]).count();
    (len >= MIN_MATCH).then_some(len)
}

/// Output cursor of the compressor with the pending literal run.
struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
    lit_start: usize,
    lit_len: usize,
}

impl Writer<'_> {
    fn push(&mut self, b: u8) -> Result<(), LzfError> {
        *self.buf.get_mut(self.pos).ok_or(LzfError::OutputTooSmall)? = b;
        self.pos += 1;
        Ok(())
    }

    /// Adds input byte `ip` to the pending literal run.
    fn literal(&mut self, input: &[u8], ip: usize) -> Result<(), LzfError> {
        if self.lit_len == 0 {
            self.lit_start = ip;
        }
        self.lit_len += 1;
        if self.lit_len == MAX_LITERAL {
            self.flush_literals(input)?;
        }
        Ok(())
    }

    fn flush_literals(&mut self, input: &[u8]) -> Result<(), LzfError> {
        if self.lit_len == 0 {
            return Ok(());
        }
        self.push((self.lit_len - 1) as u8)?;
        let src = &input[self.lit_start..self.lit_start + self.lit_len];
        let dst =
            self.buf.get_mut(self.pos..self.pos + src.len()).ok_or(LzfError::OutputTooSmall)?;
        dst.copy_from_slice(src);
        self.pos += src.len();
        self.lit_len = 0;
        Ok(())
    }

    /// Emits a back reference of `len` bytes (3..=264) from `offset` (1..=8192) back.
    fn back_reference(&mut self, offset: usize, len: usize) -> Result<(), LzfError> {
        let off = offset - 1;
        let l = len - 2;
        let hi = (off >> 8) as u8;
        if l < 7 {
            self.push(((l as u8) << 5) | hi)?;
        } else {
            self.push((7 << 5) | hi)?;
            self.push((l - 7) as u8)?;
        }
        self.push(off as u8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roundtrip(data: &[u8]) {
        let mut c = [0u8; 4096];
        let n = compress(data, &mut c).unwrap();
        assert!(n <= max_compressed_len(data.len()));
        let mut d = [0u8; 4096];
        let m = decompress(&c[..n], &mut d).unwrap();
        assert_eq!(&d[..m], data);
    }

    #[test]
    fn known_stream_decodes() {
        // "abc" literal, then a back reference of 6 bytes at offset 3: "abcabcabc".
        let stream = [2, b'a', b'b', b'c', (4 << 5), 2];
        let mut out = [0u8; 9];
        assert_eq!(decompress(&stream, &mut out), Ok(9));
        assert_eq!(&out, b"abcabcabc");
    }

    #[test]
    fn roundtrips() {
        roundtrip(b"");
        roundtrip(b"a");
        roundtrip(
            b"aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa",
        );
        let mut v = [0u8; 3000];
        for (i, b) in v.iter_mut().enumerate() {
            *b = ((i * 7919) % 251) as u8 ^ ((i / 100) as u8);
        }
        roundtrip(&v);
        let zeros = [0u8; 2000];
        roundtrip(&zeros);
    }

    #[test]
    fn compresses_repetitive_data() {
        let zeros = [0u8; 2000];
        let mut c = [0u8; 4096];
        let n = compress(&zeros, &mut c).unwrap();
        assert!(n < 40, "{n}");
    }

    #[test]
    fn expansion_bound_holds_for_the_most_expanding_stream() {
        // One literal byte, then back references of the longest kind (264 bytes from 3).
        let mut stream = [0u8; 2 + 3 * 20];
        stream[..2].copy_from_slice(&[0, b'x']);
        for r in stream[2..].chunks_mut(3) {
            r.copy_from_slice(&[7 << 5, 255, 0]);
        }
        let mut out = [0u8; 1 + 264 * 20];
        let n = decompress(&stream, &mut out).unwrap();
        assert_eq!(n, out.len());
        assert!(n <= max_decompressed_len(stream.len()), "{n} > bound");
        // The bound is tight: this stream (97 % of it) nears it as the stream grows.
        assert!(n as f64 > 0.96 * max_decompressed_len(stream.len()) as f64, "{n}");
        assert!(out.iter().all(|&b| b == b'x'));
    }

    #[test]
    fn rejects_bad_input() {
        let mut out = [0u8; 16];
        assert_eq!(decompress(&[5, 1, 2], &mut out), Err(LzfError::TruncatedInput));
        assert_eq!(decompress(&[0, 1, 0x20, 5], &mut out), Err(LzfError::BadBackReference));
        assert_eq!(decompress(&[0xe0], &mut out), Err(LzfError::TruncatedInput));
        assert_eq!(decompress(&[0, 1, 0xe0, 200, 0], &mut out), Err(LzfError::OutputTooSmall));
        assert_eq!(decompress(&[31; 40], &mut out), Err(LzfError::OutputTooSmall));
        let mut small = [0u8; 2];
        assert_eq!(compress(b"hello", &mut small), Err(LzfError::OutputTooSmall));
    }
}
