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

/// What went wrong while loading an image or detecting in it; file errors name the file.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    /// The file could not be read.
    #[error("cannot read image {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    /// The file is not a PNG/JPEG we can decode (corrupt, truncated or another format).
    #[error("cannot decode image {path} (corrupt, truncated or not PNG/JPEG): {source}")]
    Decode { path: PathBuf, source: image::ImageError },
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

/// Decodes a PNG or JPEG file (grey or colour, 8 or 16 bit) to 8-bit grey.
pub fn load_grey(path: impl AsRef<Path>) -> Result<GreyImage, DetectError> {
    let path = path.as_ref();
    let bytes =
        std::fs::read(path).map_err(|source| DetectError::Io { path: path.into(), source })?;
    let decoded = image::load_from_memory(&bytes)
        .map_err(|source| DetectError::Decode { path: path.into(), source })?;
    let grey = decoded.into_luma8();
    let (width, height) = grey.dimensions();
    Ok(GreyImage { width, height, data: grey.into_raw() })
}
