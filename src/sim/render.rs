//! The camera frame: every pixel's sub-samples traced through the exact inverse of the
//! camera model into the room, with vignetting and uneven light, blurred by the lens
//! before the pixels integrate it, then sensor noise.
//!
//! The lens blur acts on the light before it reaches the pixels, so it is applied to the
//! sub-samples, at their resolution, and only then are they averaged into pixels: the
//! pixel values are the scene seen through the lens's Gaussian and the pixel's square, as
//! a real sensor's are. Blurring whole pixels instead (box first, then a Gaussian sampled
//! at whole-pixel offsets) gives a staircase point-spread function whose aliasing moved
//! checkerboard corners by ±0.03 px depending on where they fell within a pixel.

use crate::geometry::{Camera, Se3, Vec2, Vec3};

use super::rng::Rng;
use super::world::{Surface, World};

/// How the camera image is degraded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageNoise {
    /// Sub-samples per pixel: `supersample²`; on a rank-1 lattice without blur, with it
    /// one per cell of a `supersample × supersample` grid, placed n-rooks (blurred at that
    /// grid's resolution).
    pub supersample: u32,
    /// Gaussian blur σ (px); 0 turns it off.
    pub blur_px: f64,
    /// Sensor noise σ (grey levels); 0 turns it off.
    pub noise_grey: f64,
    /// Light fall-off at the image corner (0 none, 0.3 = 30 % darker).
    pub vignetting: f64,
    /// Left-to-right light gradient (0 none, 0.2 = ±10 %).
    pub gradient: f64,
}

impl Default for ImageNoise {
    fn default() -> Self {
        ImageNoise { supersample: 4, blur_px: 0.7, noise_grey: 2.0, vignetting: 0.3, gradient: 0.2 }
    }
}

/// Renders the grey frame (row-major, `width × height`) the camera at `camera_in_lidar`
/// (camera → LiDAR frame) sees of the world.
pub fn render(
    world: &World,
    camera: &Camera,
    camera_in_lidar: &Se3,
    noise: &ImageNoise,
    rng: &mut Rng,
) -> Vec<u8> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut radiance = vec![0f32; w * h];
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(8);
    let rows_per_chunk = h.div_ceil(threads);
    std::thread::scope(|scope| {
        for (chunk, out) in radiance.chunks_mut(rows_per_chunk * w).enumerate() {
            let first_row = chunk * rows_per_chunk;
            scope.spawn(move || {
                let tracer = Tracer { world, camera, camera_in_lidar, noise };
                if noise.blur_px > 0.0 {
                    tracer.shade_rows_blurred(first_row, out);
                } else {
                    tracer.shade_rows(first_row, out);
                }
            });
        }
    });
    radiance
        .iter()
        .map(|&v| {
            let n = if noise.noise_grey > 0.0 { rng.normal() * noise.noise_grey } else { 0.0 };
            (v as f64 + n).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// Traces one band of rows.
struct Tracer<'a> {
    world: &'a World,
    camera: &'a Camera,
    camera_in_lidar: &'a Se3,
    noise: &'a ImageNoise,
}

impl Tracer<'_> {
    /// Shades the rows from `first_row` on into `out` (whole rows).
    ///
    /// The model is inverted exactly at every pixel corner; sub-samples inside a pixel
    /// interpolate the four corner rays bilinearly. Over one pixel the inverse mapping is
    /// flat to far below 1e-4 px even at |k1| = 0.4, and this is sixteen times fewer
    /// iterative inversions than one per sub-sample. Where a corner has no ray (outside
    /// the model's domain) the sub-samples are inverted one by one.
    fn shade_rows(&self, first_row: usize, out: &mut [f32]) {
        let w = self.camera.width as usize;
        let mut top = self.corner_rays(first_row);
        for (r, row_out) in out.chunks_mut(w).enumerate() {
            let y = first_row + r;
            let bottom = self.corner_rays(y + 1);
            for (x, value) in row_out.iter_mut().enumerate() {
                let corners = [top[x], top[x + 1], bottom[x], bottom[x + 1]];
                *value = self.shade_pixel(x, y, corners) as f32;
            }
            top = bottom;
        }
    }

    /// Shades the rows from `first_row` on into `out` (whole rows) through the lens blur:
    /// band by band, the sub-samples of the band's rows and of enough rows round them, one
    /// per cell of a `supersample × supersample` grid per pixel, blurred at that resolution, averaged
    /// into pixels. Every band gives what one whole-image pass would.
    fn shade_rows_blurred(&self, first_row: usize, out: &mut [f32]) {
        const BAND_ROWS: usize = 32;
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let s = self.noise.supersample.max(1) as usize;
        let kernel = gaussian_kernel(self.noise.blur_px * s as f64);
        let margin = kernel.len() / 2;
        let (fine_w, fine_h) = (w * s, h * s);
        for (band, band_out) in out.chunks_mut(BAND_ROWS * w).enumerate() {
            let y0 = first_row + band * BAND_ROWS;
            let rows = band_out.len() / w;
            let lo = (y0 * s).saturating_sub(margin);
            let hi = ((y0 + rows) * s + margin).min(fine_h);
            let mut fine = self.shade_fine_rows(lo, hi, s);
            let mut tmp = vec![0f32; fine.len()];
            convolve_lines(&fine, &mut tmp, &kernel, hi - lo, fine_w, fine_w, 1);
            convolve_lines(&tmp, &mut fine, &kernel, fine_w, hi - lo, 1, fine_w);
            let norm = 1.0 / (s * s) as f32;
            for (r, row_out) in band_out.chunks_mut(w).enumerate() {
                let first_fine = (y0 + r) * s - lo;
                for (x, value) in row_out.iter_mut().enumerate() {
                    let sum: f32 = (0..s)
                        .map(|j| fine[(first_fine + j) * fine_w + x * s..][..s].iter().sum::<f32>())
                        .sum();
                    *value = sum * norm;
                }
            }
        }
    }

    /// Radiance of the sub-sample rows `lo..hi` (`s` per pixel row, `s` per pixel column),
    /// row-major, before any blur.
    fn shade_fine_rows(&self, lo: usize, hi: usize, s: usize) -> Vec<f32> {
        let w = self.camera.width as usize;
        let mut fine = vec![0f32; (hi - lo) * w * s];
        let mut top = self.corner_rays(lo / s);
        let mut bottom = self.corner_rays(lo / s + 1);
        let mut top_row = lo / s;
        for (j, fine_row) in (lo..hi).zip(fine.chunks_mut(w * s)) {
            let y = j / s;
            if y != top_row {
                top = std::mem::replace(&mut bottom, self.corner_rays(y + 1));
                top_row = y;
            }
            let row = j % s;
            for (x, cell) in fine_row.chunks_mut(s).enumerate() {
                let corners = [top[x], top[x + 1], bottom[x], bottom[x + 1]];
                for (i, value) in cell.iter_mut().enumerate() {
                    // Each cell's sample sits off its centre so that the pixel's s² samples
                    // fall in s² different sub-rows and sub-columns (n rooks): an edge along
                    // either axis is then resolved in 1/s² px steps, not 1/s.
                    let fx = (i as f64 + (row as f64 + 0.5) / s as f64) / s as f64;
                    let fy = (row as f64 + (i as f64 + 0.5) / s as f64) / s as f64;
                    let albedo = self.albedo_at(x, y, fx, fy, corners);
                    let light = illumination(
                        self.camera,
                        self.noise,
                        x as f64 - 0.5 + fx,
                        y as f64 - 0.5 + fy,
                    );
                    *value = (255.0 * albedo * light) as f32;
                }
            }
        }
        fine
    }

    /// The rays through the top-left corners of pixel row `y`'s pixels, and past its last
    /// pixel (`width + 1` of them; `None` outside the model's domain).
    fn corner_rays(&self, y: usize) -> Vec<Option<Vec3>> {
        (0..=self.camera.width as usize)
            .map(|x| self.camera.unproject(&Vec2::new(x as f64 - 0.5, y as f64 - 0.5)))
            .collect()
    }

    /// Mean grey level over the pixel's sub-samples (pixel centres at integer
    /// coordinates, as OpenCV has them), with the light falling on it.
    fn shade_pixel(&self, x: usize, y: usize, corners: [Option<Vec3>; 4]) -> f64 {
        let n = self.noise.supersample.max(1).pow(2);
        let generator = lattice_generator(n);
        let mut sum = 0.0;
        for k in 0..n {
            // A rank-1 lattice: every row and column of the pixel holds one sample, so an
            // edge along either axis is resolved in 1/n px steps rather than 1/√n.
            let fx = (k as f64 + 0.5) / n as f64;
            let fy = ((k * generator) % n) as f64 / n as f64 + 0.5 / n as f64;
            sum += self.albedo_at(x, y, fx, fy, corners);
        }
        let albedo = sum / n as f64;
        255.0 * albedo * illumination(self.camera, self.noise, x as f64, y as f64)
    }

    /// The albedo seen at (fx, fy) ∈ [0, 1)² within pixel (x, y), whose corner rays are
    /// `corners` (top left, top right, bottom left, bottom right), integrated over the
    /// sample's share of the pixel (1/supersample of it along each axis) where it falls on
    /// a board's checker ([`World::board_albedo_over`]).
    fn albedo_at(&self, x: usize, y: usize, fx: f64, fy: f64, corners: [Option<Vec3>; 4]) -> f64 {
        let [Some(a), Some(b), Some(c), Some(d)] = corners else {
            let ray = self.camera.unproject(&Vec2::new(x as f64 - 0.5 + fx, y as f64 - 0.5 + fy));
            return ray.map_or(0.0, |ray| self.albedo_seen(&ray, None));
        };
        let ray =
            a * (1.0 - fx) * (1.0 - fy) + b * fx * (1.0 - fy) + c * (1.0 - fx) * fy + d * fx * fy;
        // The ray's change across the sample's cell, along the pixel's x and y.
        let cell = 1.0 / self.noise.supersample.max(1) as f64;
        let along_x = ((b - a) * (1.0 - fy) + (d - c) * fy) * cell;
        let along_y = ((c - a) * (1.0 - fx) + (d - b) * fx) * cell;
        self.albedo_seen(&ray, Some((along_x, along_y)))
    }

    /// The albedo of whatever the camera ray `ray` (camera frame, any length) looks at,
    /// averaged over a board's checker across the parallelogram the rays `ray ± along_x/2
    /// ± along_y/2` cut from the board's plane (its bounding box in the board's axes).
    fn albedo_seen(&self, ray: &Vec3, footprint: Option<(Vec3, Vec3)>) -> f64 {
        let scale = ray.norm();
        let dir = self.camera_in_lidar.rotation * ray / scale;
        let Some(hit) = self.world.cast(&self.camera_in_lidar.translation, &dir) else {
            return 0.0;
        };
        match hit.surface {
            Surface::Board { index, x, y } => {
                let Some((along_x, along_y)) = footprint else {
                    return self.world.board_albedo(x, y);
                };
                let to_board =
                    self.world.boards[index].rotation.transpose() * self.camera_in_lidar.rotation;
                // A ray v meets the plane at t·v, t = (n·p₀)/(n·v): a change δv moves the hit by
                // t·(δv − v·(n·δv)/(n·v)), here in the board's axes (its normal is z).
                let (v, t) = (to_board * ray, hit.distance / scale);
                let moved = |delta: Vec3| {
                    let delta = to_board * delta;
                    (delta - v * (delta.z / v.z)) * t
                };
                let (dx, dy) = (moved(along_x), moved(along_y));
                let (width, height) = (dx.x.abs() + dy.x.abs(), dx.y.abs() + dy.y.abs());
                self.world.board_albedo_over(x, y, width, height)
            }
            Surface::Background { albedo } => albedo,
        }
    }
}

/// The generator of a rank-1 lattice of `n` points: the integer coprime with `n`
/// nearest to n/φ (the golden ratio spreads the points most evenly).
fn lattice_generator(n: u32) -> u32 {
    let ideal = (n as f64 / 1.618_033_988_75).round() as u32;
    (0..n)
        .flat_map(|d| [ideal.saturating_sub(d), ideal + d])
        .find(|&g| g > 0 && gcd(g, n) == 1)
        .unwrap_or(1)
}

fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// Light reaching the sensor at (x, y): vignetting and a left-to-right gradient.
fn illumination(camera: &Camera, noise: &ImageNoise, x: f64, y: f64) -> f64 {
    let (w, h) = (camera.width as f64, camera.height as f64);
    let (dx, dy) = ((x - w / 2.0) / (w / 2.0), (y - h / 2.0) / (h / 2.0));
    let r2 = (dx * dx + dy * dy) / 2.0;
    (1.0 - noise.vignetting * r2) * (1.0 + noise.gradient * (x / w - 0.5))
}

/// A normalised Gaussian kernel of `sigma` samples, cut at 3σ.
fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f64> =
        (-radius..=radius).map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp()).collect();
    let norm: f64 = kernel.iter().sum();
    kernel.iter().map(|k| (k / norm) as f32).collect()
}

/// Convolves `lines` lines of `len` samples (line `i` starts at `i · line_step`,
/// samples `step` apart) with a centred kernel, clamping at the ends.
fn convolve_lines(
    src: &[f32],
    dst: &mut [f32],
    kernel: &[f32],
    lines: usize,
    len: usize,
    line_step: usize,
    step: usize,
) {
    let radius = (kernel.len() / 2) as isize;
    for line in 0..lines {
        let at = |k: usize| line * line_step + k * step;
        for i in 0..len {
            dst[at(i)] = kernel
                .iter()
                .enumerate()
                .map(|(k, kv)| {
                    let j = (i as isize + k as isize - radius).clamp(0, len as isize - 1) as usize;
                    kv * src[at(j)]
                })
                .sum();
        }
    }
}
