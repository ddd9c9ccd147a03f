//! Detection (std): image → every checkerboard's ordered sub-pixel corners; cloud →
//! every board and its hole centres.
//!
//! [`ChessboardDetector`] finds every board of the room's pattern in one grey frame with
//! a workspace sized once per image size; [`load_grey`] decodes a PNG or JPEG file to the
//! 8-bit grey frame the detector takes.

pub mod chessboard;
pub mod holes;
pub mod planes;

use std::path::{Path, PathBuf};

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
    /// The file ends before its image data does (a JPEG without its end marker after the
    /// scan, a PNG whose data stops early).
    #[error("image {path} is truncated: {what}")]
    Truncated { path: PathBuf, what: &'static str },
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

/// Decodes a PNG or JPEG file (grey or colour, 8 or 16 bit) to 8-bit grey. The size is
/// read from the header first and refused above [`MAX_IMAGE_PIXELS`]; a file that ends
/// before its image data is refused as truncated (decoders fill the missing rows silently).
pub fn load_grey(path: impl AsRef<Path>) -> Result<GreyImage, DetectError> {
    let path = path.as_ref();
    let bytes =
        std::fs::read(path).map_err(|source| DetectError::Io { path: path.into(), source })?;
    let (width, height) = dimensions_of(&bytes, path)?;
    if u64::from(width) * u64::from(height) > MAX_IMAGE_PIXELS {
        return Err(DetectError::TooLarge { path: path.into(), width, height });
    }
    if let Some(what) = truncation(&bytes) {
        return Err(DetectError::Truncated { path: path.into(), what });
    }
    let decoded = reader(&bytes, path)?
        .decode()
        .map_err(|source| DetectError::Decode { path: path.into(), source })?;
    let grey = decoded.into_luma8();
    let (width, height) = grey.dimensions();
    Ok(GreyImage { width, height, data: grey.into_raw() })
}

/// The width and height an image file's header declares; nothing is decoded.
pub fn image_size(path: impl AsRef<Path>) -> Result<(u32, u32), DetectError> {
    let path = path.as_ref();
    let io = |source| DetectError::Io { path: path.into(), source };
    let file = std::fs::File::open(path).map_err(io)?;
    let reader =
        image::ImageReader::new(std::io::BufReader::new(file)).with_guessed_format().map_err(io)?;
    reader.into_dimensions().map_err(|source| DetectError::Decode { path: path.into(), source })
}

/// A decoder over `bytes` with its format sniffed from the bytes, not the file name, and
/// allocation limits matching [`MAX_IMAGE_PIXELS`] (16-bit RGBA at most).
fn reader<'b>(
    bytes: &'b [u8],
    path: &Path,
) -> Result<image::ImageReader<std::io::Cursor<&'b [u8]>>, DetectError> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|source| DetectError::Io { path: path.into(), source })?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_IMAGE_PIXELS * 8);
    reader.limits(limits);
    Ok(reader)
}

fn dimensions_of(bytes: &[u8], path: &Path) -> Result<(u32, u32), DetectError> {
    reader(bytes, path)?
        .into_dimensions()
        .map_err(|source| DetectError::Decode { path: path.into(), source })
}

/// Why the file is cut short, if it is: a JPEG must carry its end-of-image marker after
/// its first scan (inside entropy-coded data 0xFF is always followed by 0x00 or a restart
/// marker, so 0xFF 0xD9 there is the end marker); a PNG must end with its IEND chunk.
fn truncation(bytes: &[u8]) -> Option<&'static str> {
    const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
    const PNG_END: &[u8] = b"IEND\xae\x42\x60\x82";
    if bytes.starts_with(&[0xFF, 0xD8]) {
        let scan = bytes.windows(2).position(|w| w == [0xFF, 0xDA])?;
        let ends = bytes[scan..].windows(2).any(|w| w == [0xFF, 0xD9]);
        return (!ends).then_some("the JPEG ends inside its image data (no end-of-image marker)");
    }
    if bytes.starts_with(PNG_SIGNATURE) {
        let ends = bytes.windows(PNG_END.len()).rev().take(64).any(|w| w == PNG_END);
        return (!ends).then_some("the PNG ends before its IEND chunk");
    }
    None
}
