//! V4L2 camera (feature `v4l2`, through the `v4l` crate): opens the device, sets the
//! format and size, streams through mmap buffers and converts each buffer to grey with
//! [`super::pixel`]. A missing device is a [`CaptureError::NoDevice`] naming it; the
//! daemon retries with backoff. Kept thin: everything testable lives in `pixel`.

use std::path::Path;
use std::time::Duration;

use v4l::buffer::Type;
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::pixel::{to_grey, PixelFormat};
use super::{CaptureError, FrameSource, GreyFrame};

/// Formats asked for, in order of preference (cheapest conversion first).
const PREFERRED: [PixelFormat; 5] = [
    PixelFormat::Grey,
    PixelFormat::Yuyv,
    PixelFormat::Uyvy,
    PixelFormat::Nv12,
    PixelFormat::Mjpeg,
];

/// mmap buffers queued.
const BUFFERS: u32 = 4;

/// A streaming V4L2 capture device.
pub struct V4l2Source {
    name: String,
    stream: Stream<'static>,
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
    // Keeps the device open for the stream's lifetime.
    _device: Device,
}

impl V4l2Source {
    /// Opens `path` with its current size in the first supported pixel format.
    pub fn open(path: &Path) -> Result<Self, CaptureError> {
        let name = path.display().to_string();
        if !path.exists() {
            return Err(CaptureError::NoDevice { device: name });
        }
        let dev_err = |what: &str, e: std::io::Error| CaptureError::Device {
            device: path.display().to_string(),
            message: format!("{what}: {e}"),
        };
        let device = Device::with_path(path).map_err(|e| dev_err("open", e))?;
        let current = device.format().map_err(|e| dev_err("get format", e))?;
        let mut chosen = None;
        for want in PREFERRED {
            let mut fmt = current;
            fmt.fourcc = FourCC::new(&want.fourcc());
            if let Ok(got) = device.set_format(&fmt) {
                if got.fourcc == fmt.fourcc {
                    chosen = Some((want, got));
                    break;
                }
            }
        }
        let Some((format, fmt)) = chosen else {
            return Err(CaptureError::Device {
                device: name,
                message: format!(
                    "none of YUYV, UYVY, GREY, NV12, MJPG is offered (current {})",
                    current.fourcc
                ),
            });
        };
        let stream = Stream::with_buffers(&device, Type::VideoCapture, BUFFERS)
            .map_err(|e| dev_err("mmap streaming", e))?;
        Ok(V4l2Source {
            name,
            stream,
            format,
            width: fmt.width,
            height: fmt.height,
            stride: fmt.stride as usize,
            _device: device,
        })
    }
}

impl FrameSource for V4l2Source {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self) -> Result<GreyFrame, CaptureError> {
        let (buf, meta) = self.stream.next().map_err(|e| CaptureError::Device {
            device: self.name.clone(),
            message: format!("dequeue: {e} (device gone?)"),
        })?;
        let used = (meta.bytesused as usize).min(buf.len());
        let mut pixels = Vec::with_capacity((self.width * self.height) as usize);
        to_grey(self.format, self.width, self.height, self.stride, &buf[..used], &mut pixels)
            .map_err(|source| CaptureError::Pixel { device: self.name.clone(), source })?;
        let time = meta.timestamp.sec as f64 + meta.timestamp.usec as f64 * 1e-6;
        Ok(GreyFrame { width: self.width, height: self.height, pixels, time })
    }

    fn period(&self) -> Option<Duration> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_device_is_named() {
        let e = V4l2Source::open(Path::new("/dev/video-roomcal-none")).err().unwrap().to_string();
        assert!(e.contains("/dev/video-roomcal-none") && e.contains("no such device"), "{e}");
    }
}
