//! The camera frame: every pixel's sub-samples traced through the exact inverse of the
//! camera model into the room, then lens blur, vignetting, uneven light and sensor noise.

use crate::geometry::{Camera, Se3, Vec2};

use super::rng::Rng;
use super::world::{Surface, World};

/// How the camera image is degraded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageNoise {
    /// Sub-samples per pixel along each axis.
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
                for (i, value) in out.iter_mut().enumerate() {
                    let (x, y) = (i % w, first_row + i / w);
                    *value = shade_pixel(world, camera, camera_in_lidar, noise, x, y) as f32;
                }
            });
        }
    });
    if noise.blur_px > 0.0 {
        gaussian_blur(&mut radiance, w, h, noise.blur_px);
    }
    radiance
        .iter()
        .map(|&v| {
            let n = if noise.noise_grey > 0.0 { rng.normal() * noise.noise_grey } else { 0.0 };
            (v as f64 + n).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// Mean grey level over the pixel's sub-samples (pixel centres at integer coordinates,
/// as OpenCV has them), with the light falling on it.
fn shade_pixel(
    world: &World,
    camera: &Camera,
    camera_in_lidar: &Se3,
    noise: &ImageNoise,
    x: usize,
    y: usize,
) -> f64 {
    let s = noise.supersample.max(1);
    let mut sum = 0.0;
    for j in 0..s {
        for i in 0..s {
            let px = Vec2::new(
                x as f64 - 0.5 + (i as f64 + 0.5) / s as f64,
                y as f64 - 0.5 + (j as f64 + 0.5) / s as f64,
            );
            sum += albedo_seen(world, camera, camera_in_lidar, &px);
        }
    }
    let albedo = sum / (s * s) as f64;
    255.0 * albedo * illumination(camera, noise, x as f64, y as f64)
}

/// The albedo of whatever the pixel position looks at (dark where the model has no ray).
fn albedo_seen(world: &World, camera: &Camera, camera_in_lidar: &Se3, px: &Vec2) -> f64 {
    let Some(ray) = camera.unproject(px) else { return 0.0 };
    let dir = camera_in_lidar.rotation * ray;
    match world.cast(&camera_in_lidar.translation, &dir) {
        Some(hit) => match hit.surface {
            Surface::Board { x, y, .. } => world.board_albedo(x, y),
            Surface::Background { albedo } => albedo,
        },
        None => 0.0,
    }
}

/// Light reaching the sensor at (x, y): vignetting and a left-to-right gradient.
fn illumination(camera: &Camera, noise: &ImageNoise, x: f64, y: f64) -> f64 {
    let (w, h) = (camera.width as f64, camera.height as f64);
    let (dx, dy) = ((x - w / 2.0) / (w / 2.0), (y - h / 2.0) / (h / 2.0));
    let r2 = (dx * dx + dy * dy) / 2.0;
    (1.0 - noise.vignetting * r2) * (1.0 + noise.gradient * (x / w - 0.5))
}

/// Separable Gaussian blur in place, borders clamped.
fn gaussian_blur(image: &mut [f32], w: usize, h: usize, sigma: f64) {
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] = kernel
                .iter()
                .enumerate()
                .map(|(k, kv)| {
                    let xx = (x as isize + k as isize - radius).clamp(0, w as isize - 1) as usize;
                    kv * image[y * w + xx]
                })
                .sum();
        }
    }
    for y in 0..h {
        for x in 0..w {
            image[y * w + x] = kernel
                .iter()
                .enumerate()
                .map(|(k, kv)| {
                    let yy = (y as isize + k as isize - radius).clamp(0, h as isize - 1) as usize;
                    kv * tmp[yy * w + x]
                })
                .sum();
        }
    }
}
