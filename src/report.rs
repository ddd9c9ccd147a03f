//! The overlay report: the camera frame with the LiDAR points projected through the
//! solved calibration (coloured by range, with its colour bar), the detected corners, each
//! board's hole centres as the camera places them and as the LiDAR measured them, and —
//! for a calibration run — the board numbers, a legend of the marks, the status, the σ and
//! RMS figures and the LiDAR planes that were refused, each with its reason. A rig's picture
//! ([`rig_camera_report`]) is one camera's: every LiDAR's sweep and hole centres through the
//! solved rig, the camera's corners, the rig's and the sensors' verdicts. Text is drawn
//! with the built-in bitmap font ([`crate::font`]).

use image::{Rgb, RgbImage};

use crate::calibrate::{Calibration, CameraBoard, LidarBoard};
use crate::detect::holes::RefusedBoard;
use crate::font;
use crate::geometry::{Camera, Se3, Vec2, Vec3};
use crate::lidar::Point;
use crate::result::Status;

/// Colours of the report's marks.
const CORNER: Rgb<u8> = Rgb([0, 230, 0]);
const HOLE_CAMERA: Rgb<u8> = Rgb([40, 120, 255]);
const HOLE_LIDAR: Rgb<u8> = Rgb([255, 40, 40]);
const REFUSED: Rgb<u8> = Rgb([255, 160, 0]);
const TEXT: Rgb<u8> = Rgb([255, 255, 255]);
const ACCEPTED_TEXT: Rgb<u8> = Rgb([90, 255, 90]);
const REJECTED_TEXT: Rgb<u8> = Rgb([255, 90, 90]);

/// One board as the report draws it.
pub struct ReportBoard<'a> {
    /// The board's number in the result file's `boards` (and the summary's lines).
    pub number: usize,
    pub corners: &'a [Vec2],
    /// Hole centres carried into the camera frame through the board's pose.
    pub holes_camera: Vec<Vec3>,
    /// The LiDAR's hole centres (LiDAR frame).
    pub holes_lidar: &'a [Vec3],
}

/// The report of a calibration run on its first frame: [`overlay`] plus the board numbers,
/// the legend, the status with the σ and RMS figures, and the refused LiDAR planes (LiDAR
/// frame) drawn where they stand with their reasons.
pub fn calibration_report(
    grey: &[u8],
    clouds: &[&[Point]],
    run: &Calibration,
    refused: &[RefusedBoard],
) -> RgbImage {
    let boards: Vec<ReportBoard<'_>> = run
        .boards
        .iter()
        .enumerate()
        .filter(|(_, b)| b.frame == 0)
        .map(|(number, b)| ReportBoard {
            number,
            corners: &b.corners,
            holes_camera: run.holes_in_camera(b),
            holes_lidar: &b.holes_lidar,
        })
        .collect();
    let extrinsic = run.lidar_to_camera.as_ref();
    let (mut image, range_max) = frame_with_marks(grey, &run.camera, extrinsic, clouds, &boards);
    let scale = text_scale(&image);
    for board in &boards {
        label_board(&mut image, board, scale);
    }
    let refused_lines = draw_refused(&mut image, &run.camera, extrinsic, refused, scale);
    let mut left = status_lines(run);
    left.extend(refused_lines.into_iter().map(|l| (l, REFUSED)));
    let legend = legend_entries(extrinsic.is_some(), !refused.is_empty());
    with_footer(&image, &left, &legend, range_max, scale)
}

/// Draws the overlay on a grey frame, with the colour bar of the points' ranges.
pub fn overlay(
    grey: &[u8],
    camera: &Camera,
    lidar_to_camera: Option<&Se3>,
    clouds: &[&[Point]],
    boards: &[ReportBoard<'_>],
) -> RgbImage {
    let (image, range_max) = frame_with_marks(grey, camera, lidar_to_camera, clouds, boards);
    with_range_bar(image, range_max)
}

/// What one camera's picture of a rig marks: the camera's detected boards, and per LiDAR
/// (the rig's order) its sweep and the boards it placed (hole centres, LiDAR frame).
pub struct RigMarks<'a> {
    pub corners: &'a [CameraBoard],
    pub sweeps: &'a [&'a [Point]],
    pub lidar_boards: &'a [&'a [LidarBoard]],
}

/// Camera `camera` (its index in `rig`) of a rig's `result`: its frame `grey` with every
/// LiDAR's sweep drawn through the solved rig — the camera's solved intrinsics, LiDAR →
/// camera through the first camera ([`crate::result::RigResult::between`]), each cloud
/// through its own motion and coloured by range — the camera's detected corners, every LiDAR's hole centres
/// through the same motions (where they fall on the corners' boards' holes, the rig agrees
/// with itself), and a footer with the rig's verdict, this camera's intrinsics and σ, each
/// sensor's verdict and the legend. `None` when the camera has no solved model; a LiDAR
/// without an extrinsic is left out.
pub fn rig_camera_report(
    rig: &crate::rig::Rig,
    result: &crate::result::RigResult,
    camera: usize,
    grey: &[u8],
    marks: &RigMarks<'_>,
) -> Option<RgbImage> {
    let name = rig.cameras.get(camera)?.name.as_str();
    let solved = result.sensors.get(name)?.camera.as_ref()?.to_camera();
    let motions: Vec<Option<Se3>> =
        rig.lidars.iter().map(|l| result.between(&l.name, name)).collect();
    let clouds: Vec<(Se3, &[Point])> = (motions.iter().zip(marks.sweeps))
        .filter_map(|(motion, sweep)| Some(((*motion)?, *sweep)))
        .collect();
    let mut image = grey_frame(grey, &solved);
    let range_max = draw_points(&mut image, &solved, &clouds);
    for corner in marks.corners.iter().flat_map(|b| &b.corners) {
        cross(&mut image, corner, 4, CORNER);
    }
    for (motion, boards) in motions.iter().zip(marks.lidar_boards) {
        let Some(motion) = motion else { continue };
        for hole in boards.iter().flat_map(|b| &b.holes) {
            if let Some(px) = solved.project(&motion.act(hole)) {
                ring(&mut image, &px, 6.0, HOLE_LIDAR);
                cross(&mut image, &px, 3, HOLE_LIDAR);
            }
        }
    }
    let legend = [
        (Mark::Corner, "detected checkerboard corners"),
        (Mark::HoleFromLidar, "hole centres from each LiDAR (through the solved rig)"),
        (Mark::Points, "LiDAR points, coloured by range"),
    ];
    let scale = text_scale(&image);
    Some(with_footer(&image, &rig_status_lines(rig, result, name), &legend, range_max, scale))
}

/// A verdict as the pictures write it: `ACCEPTED`, or `REJECTED: reason`, in its colour.
fn verdict(status: Status, reason: Option<&str>) -> (String, Rgb<u8>) {
    match status {
        Status::Accepted => ("ACCEPTED".to_string(), ACCEPTED_TEXT),
        Status::Rejected => {
            (format!("REJECTED: {}", reason.unwrap_or("no reason given")), REJECTED_TEXT)
        }
    }
}

/// The rig's verdict, camera `name`'s intrinsics and σ, and each sensor's verdict.
fn rig_status_lines(
    rig: &crate::rig::Rig,
    result: &crate::result::RigResult,
    name: &str,
) -> Vec<(String, Rgb<u8>)> {
    let (rig_verdict, colour) = verdict(result.pair.status, result.pair.reason.as_deref());
    let mut lines =
        vec![(format!("rig of {} sensors: {rig_verdict}", result.sensors.len()), colour)];
    if let Some(entry) = result.sensors.get(name) {
        if let (Some(c), Some(u)) = (&entry.camera, &entry.uncertainty) {
            lines.push((
                format!(
                    "camera {name}: fx {:.2} fy {:.2} (σ {:.2}) cx {:.2} cy {:.2} (σ {:.2} {:.2}) px",
                    c.fx, c.fy, u.fx, c.cx, c.cy, u.cx, u.cy
                ),
                TEXT,
            ));
        }
    }
    let sensors = rig.cameras.iter().map(|c| ("camera", c.name.as_str()));
    for (kind, sensor) in sensors.chain(rig.lidars.iter().map(|l| ("LiDAR", l.name.as_str()))) {
        if let Some(entry) = result.sensors.get(sensor) {
            let (text, colour) = verdict(entry.status, entry.reason.as_deref());
            lines.push((format!("{kind} {sensor}: {text}"), colour));
        }
    }
    lines
}

/// `report.png` → `report-NAME.png`: where one camera's picture of a rig's report goes.
pub fn camera_path(report: &std::path::Path, name: &str) -> std::path::PathBuf {
    let stem = report.file_stem().map_or_else(|| "report".into(), |s| s.to_string_lossy());
    let file = match report.extension() {
        Some(ext) => format!("{stem}-{name}.{}", ext.to_string_lossy()),
        None => format!("{stem}-{name}"),
    };
    report.with_file_name(file)
}

/// `image` with the range colour bar in its lower right corner when points were drawn.
fn with_range_bar(mut image: RgbImage, range_max: Option<f64>) -> RgbImage {
    if let Some(max) = range_max {
        let scale = text_scale(&image);
        let s = i64::from(scale);
        let (w, h) = (i64::from(image.width()), i64::from(image.height()));
        let length = (w / 4).max(60);
        let height = range_bar_height(scale);
        let (x, y) = (w - length - 20 * s, h - height - 10 * s);
        panel(&mut image, x - 6 * s, y - 4 * s, length + 16 * s, height + 6 * s);
        draw_range_bar(&mut image, x, y, length, max, scale);
    }
    image
}

/// The camera's grey frame, dimmed, as the picture's background; a frame of another size
/// than the camera's draws black where it has no pixel.
fn grey_frame(grey: &[u8], camera: &Camera) -> RgbImage {
    let (w, h) = (camera.width, camera.height);
    RgbImage::from_fn(w, h, |x, y| {
        let g = grey.get((y * w + x) as usize).map_or(0, |g| g / 2 + 40);
        Rgb([g, g, g])
    })
}

/// Every cloud's points in view, each moved by its own LiDAR → camera motion, as dots
/// coloured by their range from the camera; the range the colours span (`None` when no
/// point is in view). Two passes over the points, the first for the span, so that no
/// per-point buffer is made: a rig's daemon draws a picture per camera from every LiDAR's
/// accumulated sweeps (half a million points) within its memory budget.
fn draw_points(image: &mut RgbImage, camera: &Camera, clouds: &[(Se3, &[Point])]) -> Option<f64> {
    let view = ViewBounds::of(camera);
    let in_view = || {
        clouds.iter().flat_map(|(t, c)| c.iter().map(move |p| (t, p))).filter_map(|(t, p)| {
            let q = t.act(&p.position());
            view.project(camera, &q).map(|px| (px, q.norm()))
        })
    };
    let max = colour_span(in_view().map(|(_, r)| r))?;
    for (px, range) in in_view() {
        dot(image, &px, 1, range_colour(range / max));
    }
    Some(max)
}

/// The frame with the LiDAR points (coloured by range) and every board's marks; returns
/// the range the colours span (`None` without points drawn).
fn frame_with_marks(
    grey: &[u8],
    camera: &Camera,
    lidar_to_camera: Option<&Se3>,
    clouds: &[&[Point]],
    boards: &[ReportBoard<'_>],
) -> (RgbImage, Option<f64>) {
    let mut image = grey_frame(grey, camera);
    let range_max = lidar_to_camera.and_then(|t| {
        let pairs: Vec<(Se3, &[Point])> = clouds.iter().map(|c| (*t, *c)).collect();
        draw_points(&mut image, camera, &pairs)
    });
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
    (image, range_max)
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

/// The range (m) the colour scale spans: the 98th percentile of the drawn points' ranges
/// rounded up to 5 m, so that a few far returns do not wash the scene into one colour.
fn colour_span(ranges: impl Iterator<Item = f64>) -> Option<f64> {
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

/// A rainbow over `t` in 0–1 (near red, far violet).
fn range_colour(t: f64) -> Rgb<u8> {
    let t = t.clamp(0.0, 1.0);
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

/// Font scale for an image: 2 on a 1920-pixel frame, never below 1.
fn text_scale(image: &RgbImage) -> u32 {
    (image.width() / 900).max(1)
}

/// Darkens a rectangle so that text on it reads over any frame.
fn panel(image: &mut RgbImage, x: i64, y: i64, w: i64, h: i64) {
    for py in y.max(0)..(y + h).min(i64::from(image.height())) {
        for px in x.max(0)..(x + w).min(i64::from(image.width())) {
            let p = image.get_pixel_mut(px as u32, py as u32);
            p.0 = p.0.map(|v| v / 4);
        }
    }
}

/// Height in pixels of `lines` lines of text at `scale`.
fn lines_height(lines: usize, scale: u32) -> i64 {
    lines as i64 * i64::from(font::LINE_HEIGHT * scale)
}

/// One label on a dark panel, its top-left corner at (`x`, `y`) moved inside the image.
fn label(image: &mut RgbImage, x: i64, y: i64, text: &str, colour: Rgb<u8>, scale: u32) {
    let s = i64::from(scale);
    let (w, h) = (i64::from(font::text_width(text, scale)) + 4 * s, 9 * s);
    let x = x.min(i64::from(image.width()) - w).max(0);
    let y = y.min(i64::from(image.height()) - h).max(0);
    panel(image, x, y, w, h);
    font::draw_text(image, x + 2 * s, y + s, scale, text, colour);
}

/// `text` broken at spaces into lines of at most `chars` characters, continuation lines
/// indented (a word longer than a line is cut).
fn wrap(text: &str, chars: usize) -> Vec<String> {
    const INDENT: &str = "    ";
    let mut lines = Vec::new();
    let mut current = String::new();
    for word in text.split(' ') {
        let word: String = word.chars().take(chars.saturating_sub(INDENT.len())).collect();
        if !current.is_empty() && current.chars().count() + 1 + word.chars().count() > chars {
            lines.push(std::mem::replace(&mut current, INDENT.to_string()));
        } else if !current.is_empty() {
            current.push(' ');
        }
        current.push_str(&word);
    }
    lines.push(current);
    lines
}

/// Height of the range bar with its title and tick labels.
fn range_bar_height(scale: u32) -> i64 {
    lines_height(2, scale) + 8 * i64::from(scale)
}

/// The colour scale of the LiDAR points: a bar `length` pixels long from 0 to `max`
/// metres with labelled ticks, its title above; top-left corner at (`x`, `y`).
fn draw_range_bar(image: &mut RgbImage, x: i64, y: i64, length: i64, max: f64, scale: u32) {
    let s = i64::from(scale);
    let line = lines_height(1, scale);
    let thick = 6 * s;
    font::draw_text(image, x, y, scale, "LiDAR point range (m)", TEXT);
    let bar_y = y + line;
    for i in 0..=length {
        let colour = range_colour(i as f64 / length as f64);
        for dy in 0..thick {
            put(image, x + i, bar_y + dy, colour);
        }
    }
    let step = if max <= 10.0 {
        1.0
    } else if max <= 30.0 {
        5.0
    } else {
        10.0
    };
    let ticks = (max / step).round() as i64;
    for k in 0..=ticks {
        let metres = k as f64 * step;
        let at = x + (metres / max * length as f64).round() as i64;
        for dy in thick..thick + 2 * s {
            put(image, at, bar_y + dy, TEXT);
        }
        let text = format!("{metres:.0}");
        let half = i64::from(font::text_width(&text, scale)) / 2;
        font::draw_text(image, at - half, bar_y + thick + 3 * s, scale, &text, TEXT);
    }
}

/// The board's number just above its top row of corners.
fn label_board(image: &mut RgbImage, board: &ReportBoard<'_>, scale: u32) {
    if board.corners.is_empty() {
        return;
    }
    let n = board.corners.len() as f64;
    let mid_x = board.corners.iter().map(|c| c.x).sum::<f64>() / n;
    let top = board.corners.iter().map(|c| c.y).fold(f64::INFINITY, f64::min);
    let big = scale + 1;
    let text = format!("board {}", board.number);
    let half = i64::from(font::text_width(&text, big)) / 2;
    let height = lines_height(1, big);
    label(image, mid_x as i64 - half, top as i64 - height - 6 * i64::from(big), &text, TEXT, big);
}

/// Marks each refused plane where the extrinsic puts it (an orange ✕ in a ring with its
/// tag and reason) and returns one line per refused plane for the footer.
fn draw_refused(
    image: &mut RgbImage,
    camera: &Camera,
    lidar_to_camera: Option<&Se3>,
    refused: &[RefusedBoard],
    scale: u32,
) -> Vec<String> {
    let s = i64::from(scale);
    let mut lines = Vec::new();
    for (k, plane) in refused.iter().enumerate() {
        let tag = format!("R{}", k + 1);
        let pixel = lidar_to_camera.and_then(|t| {
            let q = t.act(&plane.centroid);
            (q.z > 0.0).then(|| camera.project(&q)).flatten()
        });
        let inside = pixel.filter(|px| {
            (0.0..f64::from(image.width())).contains(&px.x)
                && (0.0..f64::from(image.height())).contains(&px.y)
        });
        if let Some(px) = inside {
            diagonal_cross(image, &px, 12 * s, REFUSED);
            ring(image, &px, 18.0 * s as f64, REFUSED);
            let text = format!("{tag}: refused: {}", plane.reason);
            let (x, y) = (px.x as i64, px.y as i64);
            // Beside the mark, on whichever side has room.
            let width = i64::from(font::text_width(&text, scale)) + 4 * s;
            let left = if x + 22 * s + width <= i64::from(image.width()) {
                x + 22 * s
            } else {
                x - 22 * s - width
            };
            label(image, left, y - 5 * s, &text, REFUSED, scale);
        }
        let place = if inside.is_some() { "" } else { " (outside the picture)" };
        lines.push(format!("{tag}{place}: {plane}"));
    }
    lines
}

/// The marks the legend explains.
#[derive(Clone, Copy)]
enum Mark {
    Corner,
    HoleFromBoard,
    HoleFromLidar,
    Points,
    Refused,
}

fn legend_entries(with_lidar: bool, with_refused: bool) -> Vec<(Mark, &'static str)> {
    let mut entries = vec![
        (Mark::Corner, "detected checkerboard corners"),
        (Mark::HoleFromBoard, "hole centres from the board (camera's board pose)"),
    ];
    if with_lidar {
        entries.push((Mark::HoleFromLidar, "hole centres from the LiDAR (through the extrinsic)"));
        entries.push((Mark::Points, "LiDAR points, coloured by range"));
    }
    if with_refused {
        entries.push((Mark::Refused, "LiDAR plane refused as a board (tag R1, R2, ...)"));
    }
    entries
}

/// The legend, each mark drawn as in the picture before its meaning; returns its height.
fn draw_legend(image: &mut RgbImage, x: i64, y: i64, entries: &[(Mark, &str)], scale: u32) -> i64 {
    let s = i64::from(scale);
    let line = lines_height(1, scale);
    for (k, (mark, text)) in entries.iter().enumerate() {
        let top = y + k as i64 * line;
        let at = Vec2::new((x + 6 * s) as f64, (top + 3 * s) as f64);
        let colour = match mark {
            Mark::Corner => {
                cross(image, &at, 4 * s, CORNER);
                CORNER
            }
            Mark::HoleFromBoard => {
                ring(image, &at, 4.0 * s as f64, HOLE_CAMERA);
                HOLE_CAMERA
            }
            Mark::HoleFromLidar => {
                ring(image, &at, 3.0 * s as f64, HOLE_LIDAR);
                cross(image, &at, 2 * s, HOLE_LIDAR);
                HOLE_LIDAR
            }
            Mark::Points => {
                for (i, t) in [0.05, 0.35, 0.65, 0.95].iter().enumerate() {
                    let p = Vec2::new(at.x + (i as f64 - 1.5) * 3.0 * s as f64, at.y);
                    dot(image, &p, s / 2, range_colour(*t));
                }
                TEXT
            }
            Mark::Refused => {
                diagonal_cross(image, &at, 3 * s, REFUSED);
                REFUSED
            }
        };
        font::draw_text(image, x + 16 * s, top, scale, text, colour);
    }
    lines_height(entries.len(), scale)
}

/// The status (coloured by the verdict) and the σ and RMS figures.
fn status_lines(run: &Calibration) -> Vec<(String, Rgb<u8>)> {
    let r = &run.result;
    let (u, c, q) = (&r.uncertainty, &r.camera, &r.quality);
    let mut lines = vec![verdict(r.status, r.reason.as_deref())];
    lines.push((format!("fx {:.2} fy {:.2} px (σ {:.2} {:.2})", c.fx, c.fy, u.fx, u.fy), TEXT));
    lines.push((format!("cx {:.2} cy {:.2} px (σ {:.2} {:.2})", c.cx, c.cy, u.cx, u.cy), TEXT));
    if run.lidar_to_camera.is_some() {
        let (deg, mm) = (u.rotation_deg, u.translation_m * 1e3);
        lines.push((format!("extrinsic σ {deg:.3}° / {mm:.1} mm (largest axis)"), TEXT));
    }
    let (corners, holes, boards) = (q.corner_rms_px, q.hole_rms_px, q.boards);
    let lidar = run.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count();
    lines.push((
        format!("RMS corners {corners:.3} px, holes {holes:.3} px; {boards} boards used, {lidar} with LiDAR holes"),
        TEXT,
    ));
    lines
}

/// The frame above a footer: `left` lines (wrapped) on the left, the legend and the range
/// bar on the right, so that no text hides the scene.
fn with_footer(
    frame: &RgbImage,
    left: &[(String, Rgb<u8>)],
    legend: &[(Mark, &str)],
    range_max: Option<f64>,
    scale: u32,
) -> RgbImage {
    let s = i64::from(scale);
    let width = i64::from(frame.width());
    let split = width * 11 / 20;
    let chars = ((split - 20 * s) / i64::from(font::ADVANCE * scale)).max(10) as usize;
    let wrapped: Vec<(String, Rgb<u8>)> =
        left.iter().flat_map(|(t, c)| wrap(t, chars).into_iter().map(move |l| (l, *c))).collect();
    let bar = range_max.map_or(0, |_| range_bar_height(scale) + 6 * s);
    let right = lines_height(legend.len(), scale) + bar;
    let footer = lines_height(wrapped.len(), scale).max(right) + 16 * s;
    let height = i64::from(frame.height()) + footer;
    let mut image = RgbImage::from_pixel(frame.width(), height as u32, Rgb([24, 24, 24]));
    image::imageops::replace(&mut image, frame, 0, 0);
    let top = i64::from(frame.height()) + 8 * s;
    for (k, (text, colour)) in wrapped.iter().enumerate() {
        font::draw_text(&mut image, 10 * s, top + lines_height(k, scale), scale, text, *colour);
    }
    let legend_height = draw_legend(&mut image, split, top, legend, scale);
    if let Some(max) = range_max {
        let length = width - split - 30 * s;
        draw_range_bar(&mut image, split, top + legend_height + 6 * s, length, max, scale);
    }
    image
}

fn diagonal_cross(image: &mut RgbImage, at: &Vec2, size: i64, colour: Rgb<u8>) {
    let Some((cx, cy)) = anchor(image, at) else { return };
    for d in -size..=size {
        for w in 0..2 {
            put(image, cx + d + w, cy + d, colour);
            put(image, cx + d + w, cy - d, colour);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{CameraModel, Mat3};

    fn camera() -> Camera {
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
    fn each_cloud_is_drawn_through_its_own_motion() {
        // Both clouds hold the same point; the second LiDAR sits 1 m to the camera's right.
        let cloud = [point(0.0, 0.0, 4.0)];
        let right = Se3 { rotation: Mat3::identity(), translation: Vec3::new(1.0, 0.0, 0.0) };
        let grey = vec![0u8; 200 * 100];
        let clouds = [(Se3::identity(), &cloud[..]), (right, &cloud[..])];
        let mut picture = grey_frame(&grey, &camera());
        assert!(draw_points(&mut picture, &camera(), &clouds).is_some());
        let coloured = |x: u32, y: u32| {
            let p = picture.get_pixel(x, y);
            p[0] != p[1] || p[1] != p[2]
        };
        assert!(coloured(100, 50), "the first LiDAR's point at the principal point");
        assert!(coloured(125, 50), "the second's 25 px to the right (1 m at 4 m, f 100)");
        assert!(!coloured(112, 50), "nothing between them");
    }

    #[test]
    fn nothing_in_view_draws_no_colour_bar() {
        let behind = [point(0.0, 0.0, -4.0)];
        let grey = vec![0u8; 200 * 100];
        let mut picture = grey_frame(&grey, &camera());
        let span = draw_points(&mut picture, &camera(), &[(Se3::identity(), &behind[..])]);
        assert_eq!(span, None, "no range to span: no colour bar");
        let picture = with_range_bar(picture, span);
        assert!(picture.pixels().all(|p| p[0] == p[1] && p[1] == p[2]));
    }

    #[test]
    fn a_cameras_picture_takes_its_name_before_the_extension() {
        let path = std::path::Path::new("/store/last-run.png");
        assert_eq!(camera_path(path, "wide"), std::path::Path::new("/store/last-run-wide.png"));
        assert_eq!(
            camera_path(std::path::Path::new("out"), "front"),
            std::path::Path::new("out-front")
        );
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
}
