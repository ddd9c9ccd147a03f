//! The picture's drawing: the dimmed frame, the LiDAR points coloured by range through
//! their palettes ([`Palette`]), and the marks (dots, crosses, rings, labels on panels).

use image::{Rgb, RgbImage};

use super::layout::Rect;
use crate::font;
use crate::geometry::{Camera, Se3, Vec2, Vec3};
use crate::lidar::Point;

/// How one LiDAR's points are coloured by range: the full rainbow when the picture holds
/// one LiDAR, a family of hues of its own per LiDAR when it holds several. Every colour
/// of every palette has a channel at 0, so none comes near the white corner marks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Palette {
    /// Near red through yellow, green, cyan and blue to far violet.
    Rainbow,
    /// The `k`-th family of [`FAMILIES`] (cycling), near bright, far dark.
    Family(usize),
}

/// Hue spans (degrees, near → far) of the per-LiDAR families: blue, amber, green,
/// purple — at least 35° apart, so two LiDARs' points never share a hue.
const FAMILIES: [(f64, f64); 4] = [(185.0, 240.0), (25.0, 60.0), (95.0, 140.0), (285.0, 330.0)];

impl Palette {
    /// LiDAR `index` of `count` in one picture.
    pub fn for_lidar(index: usize, count: usize) -> Palette {
        if count <= 1 {
            Palette::Rainbow
        } else {
            Palette::Family(index)
        }
    }

    /// The colour at `t` (0 near … 1 far of the colour span), clamped.
    pub fn colour(self, t: f64) -> Rgb<u8> {
        let t = t.clamp(0.0, 1.0);
        match self {
            Palette::Rainbow => hue(t * 270.0, 1.0),
            Palette::Family(k) => {
                let (near, far) = FAMILIES[k % FAMILIES.len()];
                hue(near + (far - near) * t, 1.0 - 0.45 * t)
            }
        }
    }
}

/// The camera's grey frame, dimmed, as the picture's background; a frame of another size
/// than the camera's draws black where it has no pixel.
pub fn grey_frame(grey: &[u8], camera: &Camera) -> RgbImage {
    let (w, h) = (camera.width, camera.height);
    RgbImage::from_fn(w, h, |x, y| {
        let g = grey.get((y * w + x) as usize).map_or(0, |g| g / 2 + 40);
        Rgb([g, g, g])
    })
}

/// One cloud to draw: its LiDAR → camera motion, its points and its palette.
pub type Cloud<'a> = (Se3, &'a [Point], Palette);

/// Every cloud's points in view, each moved by its own motion, as dots coloured by their
/// range from the camera through the cloud's palette; returns the range the colours span
/// (`None` when no point is in view) and how many points of each cloud were drawn. Two
/// passes over the points, the first for the span, so that no per-point buffer is made: a
/// rig's daemon draws a picture per camera from every LiDAR's accumulated sweeps (half a
/// million points) within its memory budget.
pub fn draw_points(
    image: &mut RgbImage,
    camera: &Camera,
    clouds: &[Cloud<'_>],
) -> (Option<f64>, Vec<usize>) {
    let view = ViewBounds::of(camera);
    let mut drawn = vec![0; clouds.len()];
    let Some(max) =
        colour_span(clouds.iter().flat_map(|c| in_view(*c, &view, camera).map(|(_, r)| r)))
    else {
        return (None, drawn);
    };
    for (cloud, count) in clouds.iter().zip(&mut drawn) {
        for (px, range) in in_view(*cloud, &view, camera) {
            dot(image, &px, 1, cloud.2.colour(range / max));
            *count += 1;
        }
    }
    (Some(max), drawn)
}

/// The range (m) the colour scale spans: the 98th percentile of the drawn points' ranges
/// rounded up to 5 m, so that a few far returns do not wash the scene into one colour.
pub fn colour_span(ranges: impl Iterator<Item = f64>) -> Option<f64> {
    // The 98th percentile from a histogram of 1 cm bins (the span is rounded up to 5 m, so
    // the bin is exact enough) instead of a sort of every range.
    const BIN_M: f64 = 0.01;
    const BINS: usize = 50_000; // 500 m; farther ranges count in the last bin
    let mut counts = vec![0u32; BINS];
    let mut total = 0usize;
    for r in ranges.filter(|r| r.is_finite() && *r >= 0.0) {
        counts[((r / BIN_M) as usize).min(BINS - 1)] += 1;
        total += 1;
    }
    if total == 0 {
        return None;
    }
    let at = (total - 1) * 98 / 100;
    let (mut seen, mut bin) = (0usize, 0usize);
    for (k, &n) in counts.iter().enumerate() {
        seen += n as usize;
        if seen > at {
            bin = k;
            break;
        }
    }
    let p98 = (bin as f64 + 0.5) * BIN_M;
    Some(((p98 / 5.0).ceil() * 5.0).max(5.0))
}

pub fn put(image: &mut RgbImage, x: i64, y: i64, colour: Rgb<u8>) {
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

pub fn dot(image: &mut RgbImage, at: &Vec2, radius: i64, colour: Rgb<u8>) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for dy in -radius..=radius {
        for dx in -radius..=radius {
            put(image, cx + dx, cy + dy, colour);
        }
    }
}

pub fn cross(image: &mut RgbImage, at: &Vec2, size: i64, colour: Rgb<u8>) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for d in -size..=size {
        put(image, cx + d, cy, colour);
        put(image, cx, cy + d, colour);
    }
}

/// A cross in `colour` over a one-pixel `outline`, legible on any background.
pub fn outlined_cross(
    image: &mut RgbImage,
    at: &Vec2,
    size: i64,
    colour: Rgb<u8>,
    outline: Rgb<u8>,
) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for d in -size - 1..=size + 1 {
        for w in -1..=1 {
            put(image, cx + d, cy + w, outline);
            put(image, cx + w, cy + d, outline);
        }
    }
    cross(image, at, size, colour);
}

pub fn diagonal_cross(image: &mut RgbImage, at: &Vec2, size: i64, colour: Rgb<u8>) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for d in -size..=size {
        for w in 0..2 {
            put(image, cx + d + w, cy + d, colour);
            put(image, cx + d + w, cy - d, colour);
        }
    }
}

pub fn ring(image: &mut RgbImage, at: &Vec2, radius: f64, colour: Rgb<u8>) {
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

/// A straight line from `from` to `to`, `width` pixels wide.
pub fn line(image: &mut RgbImage, from: &Vec2, to: &Vec2, width: i64, colour: Rgb<u8>) {
    let steps = (to - from).norm().ceil().min(10_000.0) as usize;
    for k in 0..=steps {
        let p = from + (to - from) * (k as f64 / steps.max(1) as f64);
        let (x, y) = (p.x.round() as i64, p.y.round() as i64);
        for w in 0..width {
            put(image, x + w, y, colour);
            put(image, x, y + w, colour);
        }
    }
}

/// Font scale for an image: 2 on a 1920-pixel frame, never below 1.
pub fn text_scale(image: &RgbImage) -> u32 {
    (image.width() / 900).max(1)
}

/// Height in pixels of `lines` lines of text at `scale`.
pub fn lines_height(lines: usize, scale: u32) -> i64 {
    lines as i64 * i64::from(font::LINE_HEIGHT * scale)
}

/// The box a [`label`] of `text` takes at `scale`.
pub fn label_size(text: &str, scale: u32) -> (i64, i64) {
    let s = i64::from(scale);
    (i64::from(font::text_width(text, scale)) + 4 * s, 9 * s)
}

/// One label on a dark panel filling `at` (a box of [`label_size`]).
pub fn label(image: &mut RgbImage, at: &Rect, text: &str, colour: Rgb<u8>, scale: u32) {
    let s = i64::from(scale);
    panel(image, at);
    font::draw_text(image, at.x + 2 * s, at.y + s, scale, text, colour);
}

/// The fully saturated colour of `degrees` at brightness `value` (0–1).
fn hue(degrees: f64, value: f64) -> Rgb<u8> {
    let h = degrees.rem_euclid(360.0) / 60.0;
    let x = 1.0 - (h % 2.0 - 1.0).abs();
    let (r, g, b) = match h as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    let v = |c: f64| (c * value * 255.0) as u8;
    Rgb([v(r), v(g), v(b)])
}

/// The cloud's points in view: pixel and range from the camera.
fn in_view<'c>(
    (motion, points, _): Cloud<'c>,
    view: &'c ViewBounds,
    camera: &'c Camera,
) -> impl Iterator<Item = (Vec2, f64)> + 'c {
    points.iter().filter_map(move |p| {
        let q = motion.act(&p.position());
        view.project(camera, &q).map(|px| (px, q.norm()))
    })
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

/// Darkens a box so that text on it reads over any frame.
fn panel(image: &mut RgbImage, at: &Rect) {
    let (w, h) = (i64::from(image.width()), i64::from(image.height()));
    for py in at.y.max(0)..(at.y + at.h).min(h) {
        for px in at.x.max(0)..(at.x + at.w).min(w) {
            let p = image.get_pixel_mut(px as u32, py as u32);
            p.0 = p.0.map(|v| v / 4);
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geometry::{CameraModel, Mat3};

    /// A 200 × 100 pinhole without distortion, the report's unit tests' camera.
    pub(in crate::report) fn camera() -> Camera {
        Camera {
            model: CameraModel::PinholeRadtan,
            width: 200,
            height: 100,
            fx: 100.0,
            fy: 100.0,
            cx: 100.0,
            cy: 50.0,
            distortion: [0.0; 5],
        }
    }

    fn point(x: f32, y: f32, z: f32) -> Point {
        Point { x, y, z, intensity: 0.0, ring: 0, time: 0.0 }
    }

    #[test]
    fn each_cloud_is_drawn_through_its_own_motion_and_palette() {
        // Both clouds hold the same point; the second LiDAR sits 1 m to the camera's right.
        let cloud = [point(0.0, 0.0, 4.0)];
        let right = Se3 { rotation: Mat3::identity(), translation: Vec3::new(1.0, 0.0, 0.0) };
        let grey = vec![0u8; 200 * 100];
        let (a, b) = (Palette::Family(0), Palette::Family(1));
        let clouds = [(Se3::identity(), &cloud[..], a), (right, &cloud[..], b)];
        let mut picture = grey_frame(&grey, &camera());
        let (span, drawn) = draw_points(&mut picture, &camera(), &clouds);
        assert_eq!(span, Some(5.0));
        assert_eq!(drawn, vec![1, 1]);
        let at = |x: u32, y: u32| *picture.get_pixel(x, y);
        assert_eq!(at(100, 50), a.colour(4.0 / 5.0), "the first at the principal point");
        assert_eq!(
            at(125, 50),
            b.colour(17f64.sqrt() / 5.0),
            "the second 25 px right (1 m at 4 m)"
        );
        assert_eq!(at(112, 50), Rgb([40, 40, 40]), "nothing between them");
    }

    #[test]
    fn nothing_in_view_spans_no_range() {
        let behind = [point(0.0, 0.0, -4.0)];
        let grey = vec![0u8; 200 * 100];
        let mut picture = grey_frame(&grey, &camera());
        let clouds = [(Se3::identity(), &behind[..], Palette::Rainbow)];
        assert_eq!(draw_points(&mut picture, &camera(), &clouds), (None, vec![0]));
        assert!(picture.pixels().all(|p| p[0] == p[1] && p[1] == p[2]));
    }

    #[test]
    fn the_colour_span_is_the_98th_percentile_rounded_up_to_5_m() {
        // 100 ranges 0.1 … 10 m: the 98th percentile (index 97) is 9.8 m → 10 m.
        let ranges = (1..=100).map(|k| f64::from(k) * 0.1);
        assert_eq!(colour_span(ranges), Some(10.0));
        assert_eq!(colour_span([1.0, 2.0].into_iter()), Some(5.0));
        assert_eq!(colour_span([f64::NAN].into_iter()), None);
        assert_eq!(colour_span(core::iter::once(1e6)), Some(500.0));
    }

    fn distance(a: Rgb<u8>, b: Rgb<u8>) -> f64 {
        let d = |i: usize| f64::from(a[i]) - f64::from(b[i]);
        (d(0) * d(0) + d(1) * d(1) + d(2) * d(2)).sqrt()
    }

    #[test]
    fn no_palette_comes_near_the_corner_marks_and_families_stay_apart() {
        let palettes = [Palette::Rainbow, Palette::Family(0), Palette::Family(1)];
        let palettes = [&palettes[..], &[Palette::Family(2), Palette::Family(3)]].concat();
        let ts = || (0..=1000).map(|k| f64::from(k) / 1000.0);
        for p in &palettes {
            for t in ts() {
                let c = p.colour(t);
                assert!(distance(c, super::super::CORNER) >= 250.0, "{p:?} at {t}: {c:?}");
            }
        }
        // Two LiDARs' points at one range never take one colour.
        for (i, a) in palettes[1..].iter().enumerate() {
            for b in &palettes[i + 2..] {
                for t in ts() {
                    let (ca, cb) = (a.colour(t), b.colour(t));
                    assert!(distance(ca, cb) > 80.0, "{a:?} {b:?} at {t}: {ca:?} {cb:?}");
                }
            }
        }
    }
}
