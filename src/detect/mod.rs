//! Detection (std): image → every checkerboard's ordered sub-pixel corners; cloud →
//! every board and its hole centres.
//!
//! [`ChessboardDetector`] finds every board of the room's pattern in one grey frame with
//! a workspace sized once per image size; [`load_grey`] decodes a PNG or JPEG file to the
//! 8-bit grey frame the detector takes.

pub mod chessboard;
pub mod holes;
pub mod planes;

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use image::ImageDecoder;

pub use chessboard::{Board, ChessboardDetector, Corner, MAX_BOARD_CORNERS};

/// An 8-bit grey image, row-major, `width * height` bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GreyImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

/// Most pixels of an image file: the room file's camera limit, checked from the file's
/// header before anything is decoded.
pub use crate::target::MAX_IMAGE_PIXELS;

/// Most bytes an image file may hold, and most bytes its pixels may decode to before they
/// are made grey (pixels × the bytes a pixel of the file's format takes, read from the
/// header): with [`MAX_IMAGE_PIXELS`] this keeps reading one frame within the memory budget
/// of docs/limits.md whatever the format (a 16-bit RGBA pixel decodes to 8 bytes).
pub const MAX_DECODED_BYTES: u64 = 64 << 20;

/// What went wrong while loading an image or detecting in it; file errors name the file.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    /// The file could not be read.
    #[error("cannot read image {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    /// The file is not a PNG/JPEG we can decode (corrupt, truncated or another format).
    #[error("cannot decode image {path} (corrupt, truncated or not PNG/JPEG): {source}")]
    Decode { path: PathBuf, source: image::ImageError },
    /// The header's size is beyond [`MAX_IMAGE_PIXELS`]; nothing was decoded.
    #[error(
        "image {path}: {width}x{height} pixels, more than the {} pixels roomcal decodes",
        MAX_IMAGE_PIXELS
    )]
    TooLarge { path: PathBuf, width: u32, height: u32 },
    /// The header's pixels decode to more than [`MAX_DECODED_BYTES`]; nothing was decoded.
    #[error(
        "image {path}: {width}x{height} pixels of {format:?} ({bytes_per_pixel} bytes a pixel) \
         decode to {bytes} bytes, more than the {} bytes roomcal decodes",
        MAX_DECODED_BYTES
    )]
    TooManyBytes {
        path: PathBuf,
        width: u32,
        height: u32,
        format: image::ColorType,
        bytes_per_pixel: u8,
        bytes: u64,
    },
    /// The file is bigger than [`MAX_DECODED_BYTES`]; nothing was read.
    #[error(
        "image {path}: the file holds {bytes} bytes, more than the {} bytes roomcal reads",
        MAX_DECODED_BYTES
    )]
    FileTooLarge { path: PathBuf, bytes: u64 },
    /// The file ends before its image data does (a JPEG without its end marker after the
    /// scan, a PNG whose data stops early).
    #[error("image {path} is truncated: {what}")]
    Truncated { path: PathBuf, what: &'static str },
    /// A JPEG's scan is too short for the size its header declares (a decoder would fill
    /// the missing rows silently).
    #[error(
        "image {path} is truncated: its header says {width}x{height} pixels, whose {blocks} \
         blocks need at least {needed} bytes of image data; the file holds {present}"
    )]
    ShortScan { path: PathBuf, width: u32, height: u32, blocks: u64, needed: u64, present: u64 },
    /// The frame has not the size the detector was built for.
    #[error("image has {got} bytes, the detector expects {width}x{height} = {} bytes", (*.width as u64) * (*.height as u64))]
    FrameSize { width: u32, height: u32, got: usize },
    /// The image is too small to hold a board (or has a zero side).
    #[error(
        "image size {width}x{height} is too small for the chessboard detector (at least 32x32)"
    )]
    ImageTooSmall { width: u32, height: u32 },
    /// The board's pattern cannot be handled by the detector.
    #[error("`board.inner_corners` = [{cols}, {rows}]: the detector needs 2..={max} corners per side and at most {} in all", MAX_BOARD_CORNERS)]
    Pattern { cols: u32, rows: u32, max: u32 },
}

/// Decodes a PNG or JPEG file (grey or colour, 8 or 16 bit) to 8-bit grey. The header is
/// read first: above [`MAX_IMAGE_PIXELS`] pixels, or pixels that decode to more than
/// [`MAX_DECODED_BYTES`], nothing is decoded. A file that ends before its image data, or a
/// JPEG whose scan is too short for its header's size, is refused as truncated (decoders
/// fill the missing rows silently). The file is streamed, never held whole.
pub fn load_grey(path: impl AsRef<Path>) -> Result<GreyImage, DetectError> {
    let path = path.as_ref();
    let io = |source| DetectError::Io { path: path.into(), source };
    let decode = |source| DetectError::Decode { path: path.into(), source };
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len > MAX_DECODED_BYTES {
        return Err(DetectError::FileTooLarge { path: path.into(), bytes: len });
    }
    let decoder = reader(BufReader::new(file), path)?.into_decoder().map_err(decode)?;
    check_decoded_size(&decoder, path)?;
    check_complete(path)?;
    let grey = image::DynamicImage::from_decoder(decoder).map_err(decode)?.into_luma8();
    let (width, height) = grey.dimensions();
    Ok(GreyImage { width, height, data: grey.into_raw() })
}

/// The width and height an image file's header declares; nothing is decoded.
pub fn image_size(path: impl AsRef<Path>) -> Result<(u32, u32), DetectError> {
    let path = path.as_ref();
    let io = |source| DetectError::Io { path: path.into(), source };
    let file = File::open(path).map_err(io)?;
    reader(BufReader::new(file), path)?
        .into_dimensions()
        .map_err(|source| DetectError::Decode { path: path.into(), source })
}

/// A decoder with its format sniffed from the bytes, not the file name, and allocation
/// limits matching [`MAX_DECODED_BYTES`].
fn reader<R: BufRead + Seek>(input: R, path: &Path) -> Result<image::ImageReader<R>, DetectError> {
    let mut reader = image::ImageReader::new(input)
        .with_guessed_format()
        .map_err(|source| DetectError::Io { path: path.into(), source })?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_DECODED_BYTES);
    reader.limits(limits);
    Ok(reader)
}

/// Refuses a header whose pixels, or whose decoded bytes, are beyond the limits.
fn check_decoded_size(decoder: &impl ImageDecoder, path: &Path) -> Result<(), DetectError> {
    let (width, height) = decoder.dimensions();
    if u64::from(width) * u64::from(height) > MAX_IMAGE_PIXELS {
        return Err(DetectError::TooLarge { path: path.into(), width, height });
    }
    let bytes = decoder.total_bytes();
    if bytes > MAX_DECODED_BYTES {
        let format = decoder.color_type();
        let bytes_per_pixel = format.bytes_per_pixel();
        return Err(DetectError::TooManyBytes {
            path: path.into(),
            width,
            height,
            format,
            bytes_per_pixel,
            bytes,
        });
    }
    Ok(())
}

/// Refuses a file cut short: a PNG must end with its IEND chunk; a JPEG must carry its
/// end-of-image marker after its first scan, and that scan must hold the bits its frame's
/// blocks need at least (see [`JpegFrame::min_scan_bytes`]).
fn check_complete(path: &Path) -> Result<(), DetectError> {
    const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
    let io = |source| DetectError::Io { path: path.into(), source };
    let truncated = |what| DetectError::Truncated { path: path.into(), what };
    let mut file = BufReader::new(File::open(path).map_err(io)?);
    let mut start = [0u8; 8];
    let got = read_up_to(&mut file, &mut start).map_err(io)?;
    if start[..got].starts_with(&[0xFF, 0xD8]) {
        file.seek(SeekFrom::Start(2)).map_err(io)?;
        return match jpeg_scan(&mut file).map_err(io)? {
            None => Err(truncated("the JPEG ends inside its image data (no end-of-image marker)")),
            Some((frame, present)) if present < frame.min_scan_bytes() => {
                Err(DetectError::ShortScan {
                    path: path.into(),
                    width: frame.width,
                    height: frame.height,
                    blocks: frame.blocks,
                    needed: frame.min_scan_bytes(),
                    present,
                })
            }
            Some(_) => Ok(()),
        };
    }
    if start[..got] == *PNG_SIGNATURE && !png_ends(file.get_mut()).map_err(io)? {
        return Err(truncated("the PNG ends before its IEND chunk"));
    }
    Ok(())
}

/// Whether the IEND chunk is among the file's last bytes.
fn png_ends(file: &mut File) -> std::io::Result<bool> {
    const PNG_END: &[u8] = b"IEND\xae\x42\x60\x82";
    let len = file.seek(SeekFrom::End(0))?;
    file.seek(SeekFrom::Start(len.saturating_sub(72)))?;
    let mut tail = Vec::with_capacity(72);
    file.read_to_end(&mut tail)?;
    Ok(tail.windows(PNG_END.len()).any(|w| w == PNG_END))
}

/// A JPEG frame's size and what its scans must hold at least.
struct JpegFrame {
    width: u32,
    height: u32,
    /// 8×8 blocks over all components (without the padding to whole MCUs).
    blocks: u64,
    /// The fewest bits a block can be coded in: baseline and extended Huffman code each
    /// block with a DC code and an end-of-block code of at least one bit each; a
    /// progressive frame's first DC scan codes each block with one bit at least; other
    /// codings (arithmetic, lossless) get no bound.
    bits_per_block: u64,
}

impl JpegFrame {
    /// The fewest bytes of entropy-coded data the frame's blocks fit in.
    fn min_scan_bytes(&self) -> u64 {
        (self.blocks * self.bits_per_block).div_ceil(8)
    }

    /// The frame of an SOFn segment (`code` its marker, `data` after the length).
    fn parse(code: u8, data: &[u8]) -> Option<JpegFrame> {
        let height = u32::from(u16::from_be_bytes([*data.get(1)?, *data.get(2)?]));
        let width = u32::from(u16::from_be_bytes([*data.get(3)?, *data.get(4)?]));
        let components: Vec<(u64, u64)> = data
            .get(6..6 + 3 * usize::from(*data.get(5)?))?
            .chunks(3)
            .map(|c| (u64::from(c[1] >> 4), u64::from(c[1] & 15)))
            .collect();
        let h_max = components.iter().map(|c| c.0).max()?.max(1);
        let v_max = components.iter().map(|c| c.1).max()?.max(1);
        let (w, h) = (u64::from(width), u64::from(height));
        let blocks = components
            .iter()
            .map(|&(hs, vs)| {
                (w * hs).div_ceil(h_max).div_ceil(8) * (h * vs).div_ceil(v_max).div_ceil(8)
            })
            .sum();
        let bits_per_block = match code {
            0xC0 | 0xC1 => 2,
            0xC2 => 1,
            _ => 0,
        };
        Some(JpegFrame { width, height, blocks, bits_per_block })
    }
}

/// Walks a JPEG's segments after its start marker to the first scan, then counts the
/// bytes from there to the end-of-image marker (inside entropy-coded data 0xFF is always
/// followed by 0x00 or a restart marker, so 0xFF 0xD9 there is the end). `None` when the
/// file ends first. A file without a frame header gets a frame of no blocks (no bound):
/// the decoder refuses it.
fn jpeg_scan(input: &mut impl BufRead) -> std::io::Result<Option<(JpegFrame, u64)>> {
    let mut frame = JpegFrame { width: 0, height: 0, blocks: 0, bits_per_block: 0 };
    loop {
        let Some(code) = next_marker(input)? else { return Ok(None) };
        match code {
            0xD9 => return Ok(None),
            0x01 | 0xD0..=0xD8 => continue,
            _ => {}
        }
        let mut len = [0u8; 2];
        if read_up_to(input, &mut len)? < 2 {
            return Ok(None);
        }
        let body = u64::from(u16::from_be_bytes(len).saturating_sub(2));
        let mut data = Vec::new();
        input.take(body).read_to_end(&mut data)?;
        let is_frame = matches!(code, 0xC0..=0xCF) && !matches!(code, 0xC4 | 0xC8 | 0xCC);
        if is_frame {
            frame = JpegFrame::parse(code, &data).unwrap_or(frame);
        }
        if code == 0xDA {
            return Ok(scan_bytes(input)?.map(|present| (frame, present)));
        }
    }
}

/// The bytes up to and including the end-of-image marker, `None` without one.
fn scan_bytes(input: &mut impl BufRead) -> std::io::Result<Option<u64>> {
    let (mut present, mut after_ff) = (0u64, false);
    loop {
        let chunk = input.fill_buf()?;
        if chunk.is_empty() {
            return Ok(None);
        }
        for (i, &b) in chunk.iter().enumerate() {
            if after_ff && b == 0xD9 {
                return Ok(Some(present + i as u64 + 1));
            }
            after_ff = b == 0xFF;
        }
        let n = chunk.len();
        present += n as u64;
        input.consume(n);
    }
}

/// The next marker's code: 0xFF (any fill bytes) then the code; bytes between segments are
/// skipped as decoders skip them. `None` at the end of the file.
fn next_marker(input: &mut impl BufRead) -> std::io::Result<Option<u8>> {
    let mut byte = [0u8; 1];
    let mut after_ff = false;
    loop {
        if read_up_to(input, &mut byte)? == 0 {
            return Ok(None);
        }
        match byte[0] {
            0xFF => after_ff = true,
            code if after_ff && code != 0x00 => return Ok(Some(code)),
            _ => after_ff = false,
        }
    }
}

/// Reads until `buf` is full or the input ends; how many bytes were read.
fn read_up_to(input: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match input.read(&mut buf[got..])? {
            0 => break,
            n => got += n,
        }
    }
    Ok(got)
}
