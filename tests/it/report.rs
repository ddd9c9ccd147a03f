//! The report picture (`roomcal::report`): text and colour bars below the frame, refused
//! planes tagged beside their marks, corners in a colour no LiDAR point takes, one colour
//! family and bar per LiDAR, and no LiDAR marks on an intrinsics-only run.

use image::{Rgb, RgbImage};
use roomcal::detect::holes::{Refusal, RefusedBoard};
use roomcal::geometry::{Camera, CameraModel, Se3, Vec2, Vec3};
use roomcal::lidar::Point;
use roomcal::report::{
    report, Palette, ReportBoard, ReportInput, ReportLidar, CORNER, HOLE_CAMERA, HOLE_LIDAR,
    REFUSED,
};

use crate::common::scratch::Scratch;
use crate::common::{fixture, roomcal};

const WIDTH: u32 = 960;
const HEIGHT: u32 = 600;

fn camera() -> Camera {
    Camera {
        model: CameraModel::PinholeRadtan,
        width: WIDTH,
        height: HEIGHT,
        fx: 600.0,
        fy: 600.0,
        cx: 480.0,
        cy: 300.0,
        distortion: [0.0; 5],
    }
}

/// A wall of points `z` metres ahead (camera frame) over the part of the frame between
/// the pixels `from` and `to`, a point every 10 px.
fn wall(z: f64, from: (f64, f64), to: (f64, f64)) -> Vec<Point> {
    let mut points = Vec::new();
    let mut y = from.1;
    while y < to.1 {
        let mut x = from.0;
        while x < to.0 {
            let (px, py) = ((x - 480.0) / 600.0 * z, (y - 300.0) / 600.0 * z);
            points.push(Point {
                x: px as f32,
                y: py as f32,
                z: z as f32,
                intensity: 0.0,
                ring: 0,
                time: 0.0,
            });
            x += 10.0;
        }
        y += 10.0;
    }
    points
}

/// A 9 × 6 grid of corners with its top-left corner at `at`, 12 px apart.
fn grid(at: (f64, f64)) -> Vec<Vec2> {
    (0..6)
        .flat_map(|r| {
            (0..9).map(move |c| Vec2::new(at.0 + 12.0 * c as f64, at.1 + 12.0 * r as f64))
        })
        .collect()
}

fn refused_at(centroid: Vec3) -> RefusedBoard {
    RefusedBoard {
        centroid,
        normal: Vec3::new(0.0, 0.0, 1.0),
        points: 120,
        hole_scan_lines: Default::default(),
        best_guess: None,
        reason: Refusal::NoHoleGaps { chords: 1 },
    }
}

fn frame_part(picture: &RgbImage) -> RgbImage {
    image::imageops::crop_imm(picture, 0, 0, WIDTH, HEIGHT).to_image()
}

/// A colour some range palette gives: saturated, one channel at 0.
fn palette_like(p: &Rgb<u8>) -> bool {
    p.0.iter().min() == Some(&0) && p.0.iter().max().is_some_and(|m| *m >= 128)
}

#[test]
fn text_and_the_colour_bar_stay_off_the_frame_and_refused_planes_get_short_tags() {
    let grey = vec![100u8; (WIDTH * HEIGHT) as usize];
    // Points only in the frame's top half; the old colour bar sat in its lower right.
    let cloud = wall(6.0, (0.0, 0.0), (960.0, 280.0));
    let corners = [grid((100.0, 380.0)), grid((400.0, 380.0))];
    let boards = corners
        .iter()
        .enumerate()
        .map(|(number, c)| ReportBoard { number, corners: c, holes_camera: vec![] })
        .collect();
    // Three refused planes at one spot: three tags, none over another.
    let refused: [RefusedBoard; 3] = std::array::from_fn(|_| refused_at(Vec3::new(0.0, 0.5, 5.0)));
    let lidar = ReportLidar {
        name: None,
        to_camera: Some(Se3::identity()),
        clouds: vec![&cloud],
        holes: vec![],
        refused: &refused,
    };
    let input = ReportInput {
        grey: &grey,
        camera: camera(),
        boards,
        lidars: vec![lidar],
        lines: vec![("ACCEPTED".into(), Rgb([90, 255, 90]))],
        map: None,
    };
    let picture = report(&input);
    assert_eq!(picture.width(), WIDTH);
    assert!(picture.height() > HEIGHT + 60, "no footer below the frame");
    let frame = frame_part(&picture);
    // No palette colour in the frame's lower half but for the points: the bar is below.
    let low = (0..WIDTH).flat_map(|x| (320..HEIGHT).map(move |y| (x, y)));
    let stray = low
        .map(|(x, y)| frame.get_pixel(x, y))
        .filter(|p| **p != REFUSED && palette_like(p))
        .count();
    assert_eq!(stray, 0, "palette colours in the frame's lower half: the bar is on the frame");
    // The bar below: both ends of the rainbow in the footer.
    let footer: Vec<&Rgb<u8>> =
        picture.enumerate_pixels().filter(|(_, y, _)| *y >= HEIGHT).map(|(_, _, p)| p).collect();
    for end in [Palette::Rainbow.colour(0.0), Palette::Rainbow.colour(1.0)] {
        assert!(footer.iter().any(|p| **p == end), "{end:?} not in the footer's bar");
    }
    // Refused planes: their orange on the frame stays around the mark (rings and short
    // tags), the sentences are in the footer.
    let mark = (480.0, 300.0 + 0.5 / 5.0 * 600.0);
    let far = frame
        .enumerate_pixels()
        .filter(|(_, _, p)| **p == REFUSED)
        .map(|(x, y, _)| ((f64::from(x) - mark.0).powi(2) + (f64::from(y) - mark.1).powi(2)).sqrt())
        .fold(0.0, f64::max);
    // The ring reaches 18 px; the tags stand beyond it, the sentences are not there.
    assert!(far > 30.0 && far < 150.0, "refused orange reaches {far:.0} px from its mark");
    let orange_below = footer.iter().filter(|p| ***p == REFUSED).count();
    assert!(
        orange_below > 3 * 300,
        "the three sentences are not in the footer ({orange_below} px)"
    );
    // Corners white over black, a colour no point takes.
    let white = frame.pixels().filter(|p| **p == CORNER).count();
    assert!(white >= 2 * 54 * 15, "corners not marked: {white} px");
}

#[test]
fn each_lidar_has_its_own_colour_family_and_named_bar() {
    let grey = vec![100u8; (WIDTH * HEIGHT) as usize];
    let left = wall(4.0, (0.0, 0.0), (400.0, 600.0));
    let right = wall(8.0, (560.0, 200.0), (760.0, 400.0));
    let lidar = |name, cloud| ReportLidar {
        name: Some(name),
        to_camera: Some(Se3::identity()),
        clouds: vec![cloud],
        holes: vec![],
        refused: &[],
    };
    let input = ReportInput {
        grey: &grey,
        camera: camera(),
        boards: vec![],
        lidars: vec![lidar("top", &left[..]), lidar("bumper", &right[..])],
        lines: vec![],
        map: None,
    };
    let picture = report(&input);
    let frame = frame_part(&picture);
    // The colour span is 10 m (the 98th percentile of 4–8.9 m, rounded up to 5 m).
    let expected = |palette: Palette, x: f64, y: f64, z: f64| {
        let (px, py) = ((x - 480.0) / 600.0 * z, (y - 300.0) / 600.0 * z);
        palette.colour((px * px + py * py + z * z).sqrt() / 10.0)
    };
    assert_eq!(*frame.get_pixel(200, 300), expected(Palette::Family(0), 200.0, 300.0, 4.0));
    assert_eq!(*frame.get_pixel(700, 300), expected(Palette::Family(1), 700.0, 300.0, 8.0));
    // One bar per LiDAR below the frame, each in its family.
    let footer: Vec<&Rgb<u8>> =
        picture.enumerate_pixels().filter(|(_, y, _)| *y >= HEIGHT).map(|(_, _, p)| p).collect();
    for family in [Palette::Family(0), Palette::Family(1)] {
        for t in [0.0, 1.0] {
            let c = family.colour(t);
            assert!(footer.iter().any(|p| **p == c), "{family:?} at {t}: no bar");
        }
    }
}

#[test]
fn an_intrinsics_only_run_draws_no_hole_marks_points_or_bar() {
    let dir = Scratch::new("report-intrinsics");
    let report = dir.join("report.png");
    let d = |f: &str| fixture("intrinsics-fisheye").join(f).display().to_string();
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        &d("room.toml"),
        "--image",
        &d("image.png"),
        "--out",
        &dir.join("r.json").display().to_string(),
        "--report",
        &report.display().to_string(),
    ]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    let picture = image::open(&report).unwrap().to_rgb8();
    assert!(picture.height() > 800, "no footer");
    for colour in [HOLE_CAMERA, HOLE_LIDAR] {
        assert!(!picture.pixels().any(|p| *p == colour), "a hole mark {colour:?} drawn");
    }
    assert!(!picture.pixels().any(palette_like), "LiDAR colours without a LiDAR");
    let white = picture.pixels().filter(|p| **p == CORNER).count();
    // 17 px a cross; a far board's crosses overlap.
    assert!(white > 6 * 54 * 10, "corners not marked: {white} px");
}
