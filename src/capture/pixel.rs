//! Camera pixel formats → 8-bit grey (std, independent of V4L2): the conversions the V4L2
//! source applies to each dequeued buffer, tested here on byte vectors.
//!
//! Grey is the luma plane: YUYV/UYVY keep their Y bytes, NV12 its Y plane, GREY is copied,
//! MJPEG is decoded (the `image` crate) and converted to luma.

/// A camera pixel format roomcal converts from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit luma only (`GREY`).
    Grey,
    /// Packed 4:2:2, Y0 U Y1 V (`YUYV`).
    Yuyv,
    /// Packed 4:2:2, U Y0 V Y1 (`UYVY`).
    Uyvy,
    /// Planar 4:2:0, a Y plane then interleaved UV (`NV12`).
    Nv12,
    /// Motion JPEG, one JPEG per buffer (`MJPG`).
    Mjpeg,
}

/// Why a buffer could not be converted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PixelError {
    #[error("{format:?} buffer too short for {width}×{height} (stride {stride}): {got} bytes, need {need}")]
    Short { format: PixelFormat, width: u32, height: u32, stride: usize, got: usize, need: usize },
    #[error("{format:?} stride {stride} is below the row length {row}")]
    Stride { format: PixelFormat, stride: usize, row: usize },
    #[error("MJPEG frame does not decode: {0}")]
    Jpeg(String),
    #[error("MJPEG frame is {got_w}×{got_h}, expected {width}×{height}")]
    Size { width: u32, height: u32, got_w: u32, got_h: u32 },
    #[error("unsupported pixel format `{0}` (supported: YUYV, UYVY, GREY, NV12, MJPG)")]
    Unsupported(String),
}

impl PixelFormat {
    /// The V4L2 FourCC.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Uyvy => *b"UYVY",
            PixelFormat::Nv12 => *b"NV12",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }

    /// The format of a FourCC.
    pub fn from_fourcc(code: [u8; 4]) -> Result<Self, PixelError> {
        Ok(match &code {
            b"GREY" => PixelFormat::Grey,
            b"YUYV" => PixelFormat::Yuyv,
            b"UYVY" => PixelFormat::Uyvy,
            b"NV12" => PixelFormat::Nv12,
            b"MJPG" => PixelFormat::Mjpeg,
            _ => return Err(PixelError::Unsupported(String::from_utf8_lossy(&code).into_owned())),
        })
    }

    /// Bytes per pixel in a row of the luma-carrying plane (0 for compressed formats).
    pub fn row_bytes(self, width: u32) -> usize {
        match self {
            PixelFormat::Grey | PixelFormat::Nv12 => width as usize,
            PixelFormat::Yuyv | PixelFormat::Uyvy => 2 * width as usize,
            PixelFormat::Mjpeg => 0,
        }
    }
}

/// Converts one buffer of `format` (`stride` bytes per row of the luma plane; 0 = tight)
/// to `width × height` grey pixels in `out` (resized; its capacity is reused).
pub fn to_grey(
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
    src: &[u8],
    out: &mut Vec<u8>,
) -> Result<(), PixelError> {
    if format == PixelFormat::Mjpeg {
        return mjpeg_to_grey(width, height, src, out);
    }
    let row = format.row_bytes(width);
    let stride = if stride == 0 { row } else { stride };
    if stride < row {
        return Err(PixelError::Stride { format, stride, row });
    }
    let h = height as usize;
    let need = if h == 0 { 0 } else { stride * (h - 1) + row };
    if src.len() < need {
        return Err(PixelError::Short { format, width, height, stride, got: src.len(), need });
    }
    out.clear();
    out.reserve(width as usize * h);
    for y in 0..h {
        let line = &src[y * stride..y * stride + row];
        match format {
            PixelFormat::Grey | PixelFormat::Nv12 => out.extend_from_slice(line),
            PixelFormat::Yuyv => out.extend(line.iter().step_by(2)),
            PixelFormat::Uyvy => out.extend(line.iter().skip(1).step_by(2)),
            PixelFormat::Mjpeg => {}
        }
    }
    Ok(())
}

fn mjpeg_to_grey(width: u32, height: u32, src: &[u8], out: &mut Vec<u8>) -> Result<(), PixelError> {
    let img = image::load_from_memory_with_format(src, image::ImageFormat::Jpeg)
        .map_err(|e| PixelError::Jpeg(e.to_string()))?
        .into_luma8();
    if img.width() != width || img.height() != height {
        return Err(PixelError::Size { width, height, got_w: img.width(), got_h: img.height() });
    }
    out.clear();
    out.extend_from_slice(img.as_raw());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_and_uyvy_keep_luma() {
        let yuyv = [10, 128, 20, 129, 30, 130, 40, 131];
        let mut out = Vec::new();
        to_grey(PixelFormat::Yuyv, 2, 2, 0, &yuyv, &mut out).unwrap();
        assert_eq!(out, [10, 20, 30, 40]);
        let uyvy = [128, 11, 129, 21, 130, 31, 131, 41];
        to_grey(PixelFormat::Uyvy, 2, 2, 0, &uyvy, &mut out).unwrap();
        assert_eq!(out, [11, 21, 31, 41]);
    }

    #[test]
    fn stride_padding_is_skipped() {
        // 2×2 GREY with 3 bytes per row (one padding byte).
        let grey = [1, 2, 99, 3, 4];
        let mut out = Vec::new();
        to_grey(PixelFormat::Grey, 2, 2, 3, &grey, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3, 4]);
    }

    #[test]
    fn nv12_takes_the_y_plane() {
        let mut nv12 = vec![5u8, 6, 7, 8];
        nv12.extend_from_slice(&[128, 128]);
        let mut out = Vec::new();
        to_grey(PixelFormat::Nv12, 2, 2, 0, &nv12, &mut out).unwrap();
        assert_eq!(out, [5, 6, 7, 8]);
    }

    #[test]
    fn short_buffers_and_bad_strides_are_errors() {
        let mut out = Vec::new();
        let e = to_grey(PixelFormat::Yuyv, 4, 2, 0, &[0; 15], &mut out).unwrap_err();
        assert!(matches!(e, PixelError::Short { need: 16, got: 15, .. }), "{e}");
        let e = to_grey(PixelFormat::Grey, 4, 2, 3, &[0; 16], &mut out).unwrap_err();
        assert!(matches!(e, PixelError::Stride { .. }), "{e}");
        assert!(PixelFormat::from_fourcc(*b"RGB3").is_err());
        assert_eq!(PixelFormat::from_fourcc(*b"NV12"), Ok(PixelFormat::Nv12));
    }

    #[test]
    fn mjpeg_decodes_to_grey_and_checks_size() {
        let img = image::GrayImage::from_fn(16, 8, |x, _| image::Luma([(x * 16) as u8]));
        let mut jpeg = Vec::new();
        image::DynamicImage::ImageLuma8(img)
            .write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
            .unwrap();
        let mut out = Vec::new();
        to_grey(PixelFormat::Mjpeg, 16, 8, 0, &jpeg, &mut out).unwrap();
        assert_eq!(out.len(), 128);
        // A gradient survives JPEG within a few grey levels.
        assert!((i32::from(out[15]) - 240).abs() < 12, "{}", out[15]);
        assert!(matches!(
            to_grey(PixelFormat::Mjpeg, 8, 8, 0, &jpeg, &mut out),
            Err(PixelError::Size { .. })
        ));
        assert!(matches!(
            to_grey(PixelFormat::Mjpeg, 16, 8, 0, b"nope", &mut out),
            Err(PixelError::Jpeg(_))
        ));
    }
}
