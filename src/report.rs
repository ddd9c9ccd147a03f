//! The overlay report: the camera frame with the LiDAR points projected through the
//! solved calibration (coloured by range), the detected corners, and each board's hole
//! centres as the camera places them and as the LiDAR measured them.

use image::{Rgb, RgbImage};

use crate::geometry::{Camera, Se3, Vec2, Vec3};
use crate::lidar::Point;

/// Colours of the report's marks.
const CORNER: Rgb<u8> = Rgb([0, 230, 0]);
const HOLE_CAMERA: Rgb<u8> = Rgb([40, 120, 255]);
const HOLE_LIDAR: Rgb<u8> = Rgb([255, 40, 40]);

/// One board as the report draws it.
pub struct ReportBoard<'a> {
    pub corners: &'a [Vec2],
    /// Hole centres carried into the camera frame through the board's pose.
    pub holes_camera: Vec<Vec3>,
    /// The LiDAR's hole centres (LiDAR frame).
    pub holes_lidar: &'a [Vec3],
}

/// Draws the overlay on a grey frame.
pub fn overlay(
    grey: &[u8],
    camera: &Camera,
    lidar_to_camera: Option<&Se3>,
    clouds: &[&[Point]],
    boards: &[ReportBoard<'_>],
) -> RgbImage {
    let (w, h) = (camera.width, camera.height);
    let mut image = RgbImage::from_fn(w, h, |x, y| {
        let g = grey[(y * w + x) as usize] / 2 + 40;
        Rgb([g, g, g])
    });
    if let Some(t) = lidar_to_camera {
        let view = ViewBounds::of(camera);
        for p in clouds.iter().flat_map(|c| c.iter()) {
            let q = t.act(&Vec3::new(p.x as f64, p.y as f64, p.z as f64));
            if let Some(px) = view.project(camera, &q) {
                dot(&mut image, &px, 1, range_colour(q.norm()));
            }
        }
    }
    for board in boards {
        for c in board.corners {
            cross(&mut image, c, 4, CORNER);
        }
        for h in &board.holes_camera {
            if let Some(px) = camera.project(h) {
                ring(&mut image, &px, 9.0, HOLE_CAMERA);
            }
        }
        if let Some(t) = lidar_to_camera {
            for h in board.holes_lidar {
                if let Some(px) = camera.project(&t.act(h)) {
                    ring(&mut image, &px, 6.0, HOLE_LIDAR);
                    cross(&mut image, &px, 3, HOLE_LIDAR);
                }
            }
        }
    }
    image
}

/// The part of the undistorted image plane (x/z, y/z) the image sees, with a margin: a
/// radial-tangential lens folds points far outside it back into the frame, so points
/// beyond it are not drawn.
struct ViewBounds {
    min: Vec2,
    max: Vec2,
}

impl ViewBounds {
    fn of(camera: &Camera) -> ViewBounds {
        let (w, h) = (camera.width as f64, camera.height as f64);
        let mut min = Vec2::new(f64::MAX, f64::MAX);
        let mut max = Vec2::new(f64::MIN, f64::MIN);
        for k in 0..=16 {
            let t = k as f64 / 16.0;
            for px in [
                Vec2::new(t * w, 0.0),
                Vec2::new(t * w, h),
                Vec2::new(0.0, t * h),
                Vec2::new(w, t * h),
            ] {
                if let Some(ray) = camera.unproject(&px).filter(|r| r.z > 1e-6) {
                    let n = Vec2::new(ray.x / ray.z, ray.y / ray.z);
                    min = Vec2::new(min.x.min(n.x), min.y.min(n.y));
                    max = Vec2::new(max.x.max(n.x), max.y.max(n.y));
                }
            }
        }
        let margin = (max - min) * 0.1;
        ViewBounds { min: min - margin, max: max + margin }
    }

    /// The pixel of a camera-frame point inside the view (fisheyes: any point in front).
    fn project(&self, camera: &Camera, q: &Vec3) -> Option<Vec2> {
        if camera.model == crate::geometry::CameraModel::PinholeRadtan {
            if q.z <= 0.0 {
                return None;
            }
            let n = Vec2::new(q.x / q.z, q.y / q.z);
            if n.x < self.min.x || n.y < self.min.y || n.x > self.max.x || n.y > self.max.y {
                return None;
            }
        }
        camera.project(q)
    }
}

/// A rainbow over 0–30 m (near red, far violet).
fn range_colour(range: f64) -> Rgb<u8> {
    let t = (range / 30.0).clamp(0.0, 1.0);
    let hue = t * 270.0;
    let x = 1.0 - ((hue / 60.0) % 2.0 - 1.0).abs();
    let (r, g, b) = match (hue / 60.0) as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        _ => (x, 0.0, 1.0),
    };
    Rgb([(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8])
}

fn put(image: &mut RgbImage, x: i64, y: i64, colour: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < image.width() && (y as u32) < image.height() {
        image.put_pixel(x as u32, y as u32, colour);
    }
}

/// Integer pixel of a mark, `None` far outside the image (projections of points behind
/// a wide lens can land anywhere).
fn anchor(image: &RgbImage, at: &Vec2) -> Option<(i64, i64)> {
    let margin = 64.0;
    let inside = at.x > -margin
        && at.y > -margin
        && at.x < image.width() as f64 + margin
        && at.y < image.height() as f64 + margin;
    inside.then(|| (at.x.round() as i64, at.y.round() as i64))
}

fn dot(image: &mut RgbImage, at: &Vec2, radius: i64, colour: Rgb<u8>) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for dy in -radius..=radius {
        for dx in -radius..=radius {
            put(image, cx + dx, cy + dy, colour);
        }
    }
}

fn cross(image: &mut RgbImage, at: &Vec2, size: i64, colour: Rgb<u8>) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for d in -size..=size {
        put(image, cx + d, cy, colour);
        put(image, cx, cy + d, colour);
    }
}

fn ring(image: &mut RgbImage, at: &Vec2, radius: f64, colour: Rgb<u8>) {
    if anchor(image, at).is_none() {
        return;
    }
    let steps = (radius * 8.0) as usize;
    for k in 0..steps {
        let a = k as f64 / steps as f64 * std::f64::consts::TAU;
        put(
            image,
            (at.x + radius * a.cos()).round() as i64,
            (at.y + radius * a.sin()).round() as i64,
            colour,
        );
    }
}
