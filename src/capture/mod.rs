//! Camera input (std): the [`FrameSource`] trait, grey frames, replay of image files,
//! pixel-format conversion, and (feature `v4l2`) V4L2 devices.
//!
//! Sources are synchronous: replay is paced by the caller from [`FrameSource::period`],
//! a device blocks in `next_frame` until its next buffer (the daemon runs it on a
//! blocking thread). A source that fails is reopened by the caller with [`Backoff`].

use std::path::{Path, PathBuf};
use std::time::Duration;

pub mod pixel;
#[cfg(feature = "v4l2")]
pub mod v4l2;

/// An 8-bit grey image, row-major without padding, with its capture time.
#[derive(Clone, Debug, PartialEq)]
pub struct GreyFrame {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
    /// Seconds on the source's clock (device timestamp, or replay time).
    pub time: f64,
}

/// Errors of camera sources; each names the device or file.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("camera {device}: no such device")]
    NoDevice { device: String },
    #[error("camera {device}: {message}")]
    Device { device: String, message: String },
    #[error("camera {device}: {source}")]
    Pixel { device: String, source: pixel::PixelError },
    #[error("image {path}: {message}")]
    Image { path: PathBuf, message: String },
    /// An image file refused by the loader (its message names the file).
    #[error(transparent)]
    Load(#[from] crate::detect::DetectError),
    #[error("replay {path}: no PNG or JPEG images found")]
    Empty { path: PathBuf },
    #[error("camera source `{0}`: expected v4l2:DEVICE or replay:PATH")]
    BadSource(String),
}

/// Grey frames from a camera or a replay.
pub trait FrameSource: Send {
    /// What this source reads (device path or replay path), for messages.
    fn name(&self) -> &str;
    /// The next frame; blocks until a device delivers one.
    fn next_frame(&mut self) -> Result<GreyFrame, CaptureError>;
    /// Interval the caller should wait between frames (replay), `None` for devices that
    /// pace themselves.
    fn period(&self) -> Option<Duration>;
}

/// The mean of several frames of the same size (a static scene: averaging lowers the
/// noise before detection); `None` if there are none or their sizes differ.
pub fn average_frames(frames: &[GreyFrame]) -> Option<GreyFrame> {
    let mut sum = FrameSum::default();
    for f in frames {
        sum.add(f).ok()?;
    }
    sum.into_mean()
}

/// The rounded per-pixel mean of equally long pixel buffers; `None` if there are none or
/// their lengths differ.
pub fn mean_pixels(frames: &[&[u8]]) -> Option<Vec<u8>> {
    let mut sum = FrameSum::default();
    for f in frames {
        sum.add_pixels(f).ok()?;
    }
    sum.into_mean().map(|m| m.pixels)
}

/// The rounded per-pixel mean of a standing vehicle's frames read one at a time by `load`
/// (each checked to be the camera's size): only the running sum and one frame are held,
/// whatever the number of files. `Ok(None)` without files; a frame of another size than
/// the first is refused through `mismatch`.
pub fn mean_image<P, E>(
    paths: &[P],
    mut load: impl FnMut(&P) -> Result<crate::detect::GreyImage, E>,
    mismatch: impl Fn(&P, FrameSizeMismatch) -> E,
) -> Result<Option<crate::detect::GreyImage>, E> {
    let mut sum = FrameSum::default();
    for path in paths {
        let image = load(path)?;
        let frame =
            GreyFrame { width: image.width, height: image.height, pixels: image.data, time: 0.0 };
        sum.add(&frame).map_err(|e| mismatch(path, e))?;
    }
    Ok(sum.into_mean().map(|m| crate::detect::GreyImage {
        width: m.width,
        height: m.height,
        data: m.pixels,
    }))
}

/// The running per-pixel sum of a static scene's frames: their rounded mean without
/// keeping the frames. The daemon sums each camera's frames as they arrive (a run's five
/// 1920×1200 frames of two cameras held 23 MB as frames) and turns the sums into means
/// before it calibrates, so the sums are gone while the detectors and the solve run.
/// The sum takes 2 bytes a pixel up to [`NARROW_FRAMES`] frames, 4 beyond.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameSum {
    width: u32,
    height: u32,
    sum: Sum,
    frames: u32,
    time: f64,
}

/// Most frames whose sum fits 16 bits a pixel (257 × 255 ≤ 65535): the daemon's runs
/// (at most 100 frames) and any usual standing vehicle's files.
pub const NARROW_FRAMES: u32 = (u16::MAX / u8::MAX as u16) as u32;

/// Per-pixel sums: 16 bits while they cannot overflow, then 32.
#[derive(Clone, Debug, PartialEq)]
enum Sum {
    Narrow(Vec<u16>),
    Wide(Vec<u32>),
}

impl Default for Sum {
    fn default() -> Self {
        Sum::Narrow(Vec::new())
    }
}

/// A frame that [`FrameSum::add`] refused: its size is not the first frame's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("a {got_w}×{got_h} frame among {want_w}×{want_h} frames")]
pub struct FrameSizeMismatch {
    pub got_w: u32,
    pub got_h: u32,
    pub want_w: u32,
    pub want_h: u32,
}

impl FrameSum {
    /// Adds a frame; the first one sets the size, a later one of another size is refused
    /// (the sum is unchanged).
    pub fn add(&mut self, frame: &GreyFrame) -> Result<(), FrameSizeMismatch> {
        let mismatch = FrameSizeMismatch {
            got_w: frame.width,
            got_h: frame.height,
            want_w: self.width,
            want_h: self.height,
        };
        if self.frames > 0 && (frame.width, frame.height) != (self.width, self.height) {
            return Err(mismatch);
        }
        self.add_pixels(&frame.pixels).map_err(|()| mismatch)?;
        (self.width, self.height) = (frame.width, frame.height);
        self.time += frame.time;
        Ok(())
    }

    /// Frames summed so far.
    pub fn frames(&self) -> usize {
        self.frames as usize
    }

    /// The rounded mean frame (time: the frames' mean); `None` before the first frame.
    pub fn into_mean(self) -> Option<GreyFrame> {
        let n = self.frames;
        if n == 0 {
            return None;
        }
        let mean = |s: u32| ((s + n / 2) / n) as u8;
        let pixels = match self.sum {
            Sum::Narrow(sum) => sum.into_iter().map(|s| mean(u32::from(s))).collect(),
            Sum::Wide(sum) => sum.into_iter().map(mean).collect(),
        };
        Some(GreyFrame {
            width: self.width,
            height: self.height,
            pixels,
            time: self.time / n as f64,
        })
    }

    /// Adds one buffer of pixels; `Err` (sum unchanged) when its length is not the first's.
    fn add_pixels(&mut self, pixels: &[u8]) -> Result<(), ()> {
        if self.frames == 0 {
            self.sum = Sum::Narrow(vec![0; pixels.len()]);
        }
        if self.frames == NARROW_FRAMES {
            if let Sum::Narrow(narrow) = &self.sum {
                self.sum = Sum::Wide(narrow.iter().map(|&s| u32::from(s)).collect());
            }
        }
        match &mut self.sum {
            Sum::Narrow(sum) if sum.len() == pixels.len() => {
                sum.iter_mut().zip(pixels).for_each(|(s, &p)| *s += u16::from(p));
            }
            Sum::Wide(sum) if sum.len() == pixels.len() => {
                sum.iter_mut().zip(pixels).for_each(|(s, &p)| *s += u32::from(p));
            }
            _ => return Err(()),
        }
        self.frames += 1;
        Ok(())
    }
}

/// Exponential backoff for reopening a failed device: `initial`, doubling up to `max`,
/// back to `initial` after a success. Pure: the caller sleeps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    next: Duration,
}

impl Backoff {
    /// A backoff from `initial` to `max`.
    pub fn new(initial: Duration, max: Duration) -> Self {
        Backoff { initial, max, next: initial }
    }

    /// The delay before the next attempt (and doubles the following one).
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }

    /// Call after a success.
    pub fn reset(&mut self) {
        self.next = self.initial;
    }
}

impl Default for Backoff {
    /// 0.5 s doubling to 30 s.
    fn default() -> Self {
        Backoff::new(Duration::from_millis(500), Duration::from_secs(30))
    }
}

/// Replay of an image file or a folder of PNG/JPEG images (sorted by name), looped.
/// Every image's header is checked when the source opens and the first is decoded; the
/// others are decoded when served, so one decoded image is held whatever the folder holds.
#[derive(Debug)]
pub struct ImageReplay {
    name: String,
    files: Vec<PathBuf>,
    /// The last decoded image and its index in `files`.
    current: (usize, GreyFrame),
    next: usize,
    served: u64,
    period: Duration,
}

impl ImageReplay {
    /// Opens `path` (a file, or a folder of images) replayed every `period`.
    pub fn open(path: &Path, period: Duration) -> Result<Self, CaptureError> {
        let files = image_files(path)?;
        let Some(first) = files.first() else {
            return Err(CaptureError::Empty { path: path.to_path_buf() });
        };
        for file in &files[1..] {
            crate::detect::image_size(file)?;
        }
        let current = (0, load_grey(first)?);
        Ok(ImageReplay {
            name: path.display().to_string(),
            files,
            current,
            next: 0,
            served: 0,
            period,
        })
    }

    /// Number of distinct images.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// Never true for an opened replay.
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }
}

impl FrameSource for ImageReplay {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self) -> Result<GreyFrame, CaptureError> {
        if self.current.0 != self.next {
            // The old frame goes before the new one is decoded: one is held at a time.
            self.current.1 = GreyFrame { width: 0, height: 0, pixels: Vec::new(), time: 0.0 };
            self.current = (self.next, load_grey(&self.files[self.next])?);
        }
        let mut frame = self.current.1.clone();
        frame.time = self.served as f64 * self.period.as_secs_f64();
        self.next = (self.next + 1) % self.files.len();
        self.served += 1;
        Ok(frame)
    }

    fn period(&self) -> Option<Duration> {
        Some(self.period)
    }
}

/// Decodes a PNG or JPEG file to grey (colour is converted to luma).
pub fn load_grey(path: &Path) -> Result<GreyFrame, CaptureError> {
    let image = crate::detect::load_grey(path)?;
    Ok(GreyFrame { width: image.width, height: image.height, pixels: image.data, time: 0.0 })
}

/// The image itself, or a folder's PNG/JPEG files sorted by name.
fn image_files(path: &Path) -> Result<Vec<PathBuf>, CaptureError> {
    let err = |e: std::io::Error| CaptureError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let meta = std::fs::metadata(path).map_err(err)?;
    if !meta.is_dir() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files = Vec::new();
    for entry in std::fs::read_dir(path).map_err(err)? {
        let p = entry.map_err(err)?.path();
        let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        if matches!(ext.as_str(), "png" | "jpg" | "jpeg") {
            files.push(p);
        }
    }
    files.sort();
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(v: u8, time: f64) -> GreyFrame {
        GreyFrame { width: 2, height: 1, pixels: vec![v, 255 - v], time }
    }

    #[test]
    fn average_rounds_and_rejects_mixed_sizes() {
        let avg = average_frames(&[frame(10, 0.0), frame(13, 1.0)]).unwrap();
        assert_eq!(avg.pixels, vec![12, 244]);
        assert_eq!(avg.time, 0.5);
        let mut odd = frame(1, 0.0);
        odd.width = 1;
        odd.pixels.truncate(1);
        assert!(average_frames(&[frame(1, 0.0), odd]).is_none());
        assert!(average_frames(&[]).is_none());
    }

    #[test]
    fn a_frame_sum_refuses_another_size_and_keeps_what_it_had() {
        let mut sum = FrameSum::default();
        assert!(sum.clone().into_mean().is_none());
        sum.add(&frame(10, 0.0)).unwrap();
        let mut odd = frame(1, 0.0);
        odd.width = 1;
        odd.pixels.truncate(1);
        let e = sum.add(&odd).unwrap_err();
        assert_eq!(e.to_string(), "a 1×1 frame among 2×1 frames");
        sum.add(&frame(13, 1.0)).unwrap();
        assert_eq!(sum.frames(), 2);
        let mean = sum.into_mean().unwrap();
        assert_eq!((mean.pixels, mean.time, mean.width), (vec![12, 244], 0.5, 2));
    }

    #[test]
    fn a_frame_sum_widens_past_the_frames_sixteen_bits_hold() {
        let mut sum = FrameSum::default();
        let frames = NARROW_FRAMES + 43;
        for i in 0..frames {
            sum.add(&frame(if i % 3 == 0 { 0 } else { 255 }, 0.0)).unwrap();
        }
        assert!(matches!(sum.sum, Sum::Wide(_)));
        let zeros = frames.div_ceil(3);
        let want = ((255 * (frames - zeros) + frames / 2) / frames) as u8;
        assert_eq!(sum.into_mean().unwrap().pixels[0], want);
    }

    #[test]
    fn backoff_doubles_caps_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(350));
        let d: Vec<u128> = (0..4).map(|_| b.next_delay().as_millis()).collect();
        assert_eq!(d, [100, 200, 350, 350]);
        b.reset();
        assert_eq!(b.next_delay().as_millis(), 100);
    }
}
