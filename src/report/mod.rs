//! The report picture: one camera's frame with every LiDAR's points projected through the
//! solved calibration (each LiDAR coloured by range in its own palette), the detected
//! corners, each board's hole centres as the camera places them and as each LiDAR measured
//! them, the board numbers, and the LiDAR planes that were refused, each marked with a
//! short tag (R1, R2, …); below the frame a footer holds the verdicts and figures, the
//! refused planes' sentences by tag, the legend and one range colour bar per LiDAR.
//!
//! One drawing, [`report`], of one [`ReportInput`]: a one-pair run's picture
//! ([`ReportInput::calibration`]) is a rig's ([`ReportInput::rig`]) with one camera and one
//! LiDAR, and `roomcal overlay`'s ([`overlay`]) is one without verdicts. Labels are placed
//! so that none covers another ([`place_labels`]); text is drawn with the built-in bitmap
//! font ([`crate::font`]).

mod contour;
mod draw;
mod footer;
mod layout;

use image::{Rgb, RgbImage};

use crate::calibrate::{Calibration, CameraBoard, LidarBoard};
use crate::detect::holes::RefusedBoard;
use crate::geometry::{Camera, Se3, Vec2, Vec3};
use crate::lidar::Point;
use crate::result::{ProjectionMap, Status};
pub use draw::Palette;
use draw::{diagonal_cross, label, label_size, line, outlined_cross, ring, Cloud};
use footer::{Bar, Mark};
pub use layout::{place_labels, LabelRequest, Rect};

/// Colours of the report's marks. The corners' white with a black outline is a colour no
/// range palette takes (each [`Palette`] colour has a channel at 0).
pub const CORNER: Rgb<u8> = Rgb([255, 255, 255]);
pub const CORNER_OUTLINE: Rgb<u8> = Rgb([0, 0, 0]);
pub const HOLE_CAMERA: Rgb<u8> = Rgb([40, 120, 255]);
pub const HOLE_LIDAR: Rgb<u8> = Rgb([255, 40, 40]);
pub const REFUSED: Rgb<u8> = Rgb([255, 160, 0]);
pub const TEXT: Rgb<u8> = Rgb([225, 225, 225]);
pub const ACCEPTED_TEXT: Rgb<u8> = Rgb([90, 255, 90]);
pub const REJECTED_TEXT: Rgb<u8> = Rgb([255, 90, 90]);
/// The projection map's contours: a pink no range palette takes (each has a channel at 0).
pub const CONTOUR: Rgb<u8> = Rgb([255, 110, 230]);

/// The projection map's contour levels (px, 1σ): within a pixel, a few, an overlay off.
pub const CONTOUR_LEVELS_PX: [f64; 3] = [1.0, 3.0, 10.0];

/// Everything one picture shows.
pub struct ReportInput<'a> {
    /// The camera's frame: 8-bit grey, row-major, of the camera's size.
    pub grey: &'a [u8],
    /// The camera's solved model.
    pub camera: Camera,
    pub boards: Vec<ReportBoard<'a>>,
    /// The LiDARs (a rig's in its order: each LiDAR's palette follows its place).
    pub lidars: Vec<ReportLidar<'a>>,
    /// The footer's text: the verdicts and figures, each line in its colour.
    pub lines: Vec<(String, Rgb<u8>)>,
    /// The camera's projection map, drawn as contours at [`CONTOUR_LEVELS_PX`].
    pub map: Option<&'a ProjectionMap>,
}

/// One board as the report draws it.
#[derive(Clone)]
pub struct ReportBoard<'a> {
    /// The board's number (one-pair runs: its place in the result file's `boards`; rigs:
    /// its place among the camera's detected boards).
    pub number: usize,
    pub corners: &'a [Vec2],
    /// Hole centres carried into the camera frame through the board's pose (drawn when a
    /// LiDAR is drawn, to compare with its hole centres).
    pub holes_camera: Vec<Vec3>,
}

/// One LiDAR as the report draws it.
pub struct ReportLidar<'a> {
    /// Its name in the rig (`None`: the room's one LiDAR).
    pub name: Option<&'a str>,
    /// LiDAR → camera; `None` draws none of its points, holes or refused planes.
    pub to_camera: Option<Se3>,
    pub clouds: Vec<&'a [Point]>,
    /// Its boards' hole centres (LiDAR frame).
    pub holes: Vec<&'a [Vec3]>,
    /// Its planes that were refused as boards.
    pub refused: &'a [RefusedBoard],
}

/// The picture of `input`: the frame with its marks and labels above the footer.
pub fn report(input: &ReportInput<'_>) -> RgbImage {
    let camera = &input.camera;
    let mut image = draw::grey_frame(input.grey, camera);
    let scale = draw::text_scale(&image);
    let count = input.lidars.len();
    let placed: Vec<(usize, &ReportLidar<'_>, Se3)> =
        (input.lidars.iter().enumerate()).filter_map(|(k, l)| Some((k, l, l.to_camera?))).collect();
    let clouds: Vec<Cloud<'_>> = (placed.iter())
        .flat_map(|(k, l, t)| l.clouds.iter().map(move |c| (*t, *c, Palette::for_lidar(*k, count))))
        .collect();
    let (range_max, drawn) = draw::draw_points(&mut image, camera, &clouds);
    let marks = draw_marks(&mut image, input, &placed);
    let contours = input.map.map(|m| contour::draw(&mut image, m, &CONTOUR_LEVELS_PX, CONTOUR));
    let refused = draw_refused(&mut image, input, scale);
    let contour_labels = contours.as_deref().unwrap_or_default();
    draw_labels(&mut image, input, &refused, contour_labels, scale);
    let mut left = input.lines.clone();
    left.extend(refused.iter().map(|r| (r.sentence.clone(), REFUSED)));
    let mut legend = legend(input, marks, drawn.iter().any(|n| *n > 0), !refused.is_empty());
    if let (Some(map), false) = (input.map, contour_labels.is_empty()) {
        let levels: Vec<String> = CONTOUR_LEVELS_PX.iter().map(|l| l.to_string()).collect();
        let text = format!("projection 1σ contours: {} px at {} m", levels.join(", "), map.range_m);
        legend.push((Mark::Contour, text));
    }
    let bars = bars(input, &clouds, &drawn);
    footer::with_footer(&image, &left, &legend, &bars, range_max, scale)
}

impl<'a> ReportInput<'a> {
    /// A one-pair calibration run on its first frame `grey`: its boards of that frame,
    /// the LiDAR's `clouds` and `refused` planes through its extrinsic, the status with
    /// the σ and RMS figures.
    pub fn calibration(
        grey: &'a [u8],
        clouds: &[&'a [Point]],
        run: &'a Calibration,
        refused: &'a [RefusedBoard],
    ) -> ReportInput<'a> {
        let first = || run.boards.iter().enumerate().filter(|(_, b)| b.frame == 0);
        let boards = first()
            .map(|(number, b)| ReportBoard {
                number,
                corners: &b.corners,
                holes_camera: run.holes_in_camera(b),
            })
            .collect();
        let has_lidar = run.lidar_to_camera.is_some() || !clouds.is_empty() || !refused.is_empty();
        let lidar = ReportLidar {
            name: None,
            to_camera: run.lidar_to_camera,
            clouds: clouds.to_vec(),
            holes: first().map(|(_, b)| b.holes_lidar.as_slice()).collect(),
            refused,
        };
        ReportInput {
            grey,
            camera: run.camera,
            boards,
            lidars: if has_lidar { vec![lidar] } else { Vec::new() },
            lines: status_lines(run),
            map: run.result.projection_uncertainty.as_ref(),
        }
    }

    /// Camera `camera` (its index in `rig`) of a rig's `result` on its frame `grey`: the
    /// camera's solved intrinsics and detected boards, every LiDAR's sweep and hole centres
    /// through the solved rig (LiDAR → camera through the first camera,
    /// [`crate::result::RigResult::between`]; a LiDAR without one is not drawn), the rig's
    /// verdict, this camera's intrinsics and σ and each sensor's verdict. `None` when the
    /// camera has no solved model.
    pub fn rig(
        rig: &'a crate::rig::Rig,
        result: &'a crate::result::RigResult,
        camera: usize,
        grey: &'a [u8],
        marks: &RigMarks<'a>,
    ) -> Option<ReportInput<'a>> {
        let name = rig.cameras.get(camera)?.name.as_str();
        let solved = result.sensors.get(name)?.camera.as_ref()?.to_camera();
        let boards = (marks.corners.iter().enumerate())
            .map(|(number, b)| ReportBoard { number, corners: &b.corners, holes_camera: vec![] })
            .collect();
        let lidars = (rig.lidars.iter().enumerate())
            .map(|(l, lidar)| ReportLidar {
                name: Some(lidar.name.as_str()),
                to_camera: result.between(&lidar.name, name),
                clouds: marks.sweeps.get(l).copied().into_iter().collect(),
                holes: marks
                    .lidar_boards
                    .get(l)
                    .map_or(Vec::new(), |bs| bs.iter().map(|b| b.holes.as_slice()).collect()),
                refused: &[],
            })
            .collect();
        let lines = rig_status_lines(rig, result, name);
        let map = result.sensors.get(name)?.projection_uncertainty.as_ref();
        Some(ReportInput { grey, camera: solved, boards, lidars, lines, map })
    }
}

/// What one camera's picture of a rig marks: the camera's detected boards, and per LiDAR
/// (the rig's order) its sweep and the boards it placed (hole centres, LiDAR frame).
pub struct RigMarks<'a> {
    pub corners: &'a [CameraBoard],
    pub sweeps: &'a [&'a [Point]],
    pub lidar_boards: &'a [&'a [LidarBoard]],
}

/// `roomcal overlay`'s picture: the frame with the LiDAR points through `lidar_to_camera`
/// and the boards' marks, with the legend and the colour bar below it (no verdicts).
pub fn overlay(
    grey: &[u8],
    camera: &Camera,
    lidar_to_camera: Option<&Se3>,
    clouds: &[&[Point]],
    boards: &[ReportBoard<'_>],
) -> RgbImage {
    let lidar = ReportLidar {
        name: None,
        to_camera: lidar_to_camera.copied(),
        clouds: clouds.to_vec(),
        holes: Vec::new(),
        refused: &[],
    };
    let input = ReportInput {
        grey,
        camera: *camera,
        boards: boards.to_vec(),
        lidars: vec![lidar],
        lines: Vec::new(),
        map: None,
    };
    report(&input)
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

/// Which kinds of mark [`draw_marks`] drew.
#[derive(Clone, Copy, Default)]
struct Drawn {
    corners: bool,
    board_holes: bool,
    lidar_holes: bool,
}

/// The boards' hole centres (when a LiDAR is drawn), every drawn LiDAR's hole centres, and
/// the corners on top.
fn draw_marks(
    image: &mut RgbImage,
    input: &ReportInput<'_>,
    placed: &[(usize, &ReportLidar<'_>, Se3)],
) -> Drawn {
    let camera = &input.camera;
    let mut drawn = Drawn::default();
    if !placed.is_empty() {
        for h in input.boards.iter().flat_map(|b| &b.holes_camera) {
            if let Some(px) = camera.project(h) {
                ring(image, &px, 9.0, HOLE_CAMERA);
                drawn.board_holes = true;
            }
        }
    }
    for (_, lidar, t) in placed {
        for h in lidar.holes.iter().flat_map(|h| h.iter()) {
            if let Some(px) = camera.project(&t.act(h)) {
                ring(image, &px, 6.0, HOLE_LIDAR);
                draw::cross(image, &px, 3, HOLE_LIDAR);
                drawn.lidar_holes = true;
            }
        }
    }
    for c in input.boards.iter().flat_map(|b| b.corners) {
        outlined_cross(image, c, 4, CORNER, CORNER_OUTLINE);
        drawn.corners = true;
    }
    drawn
}

/// A refused plane: its tag, where it is drawn (`None`: outside the picture or without an
/// extrinsic) and its footer sentence.
struct Refused {
    tag: String,
    pixel: Option<Vec2>,
    sentence: String,
}

/// The ring's radius of a refused plane's mark at `scale`.
fn refused_radius(scale: u32) -> f64 {
    18.0 * f64::from(scale)
}

/// Marks each refused plane where its LiDAR's extrinsic puts it (an orange ✕ in a ring);
/// returns them tagged R1, R2, … across the LiDARs, with their sentences for the footer.
fn draw_refused(image: &mut RgbImage, input: &ReportInput<'_>, scale: u32) -> Vec<Refused> {
    let camera = &input.camera;
    let named = input.lidars.len() > 1;
    let planes = input.lidars.iter().flat_map(|l| l.refused.iter().map(move |p| (l, p)));
    let mut out = Vec::new();
    for (k, (lidar, plane)) in planes.enumerate() {
        let tag = format!("R{}", k + 1);
        let pixel = lidar.to_camera.and_then(|t| {
            let q = t.act(&plane.centroid);
            (q.z > 0.0).then(|| camera.project(&q)).flatten()
        });
        let inside = pixel.filter(|px| {
            (0.0..f64::from(image.width())).contains(&px.x)
                && (0.0..f64::from(image.height())).contains(&px.y)
        });
        if let Some(px) = &inside {
            diagonal_cross(image, px, 12 * i64::from(scale), REFUSED);
            ring(image, px, refused_radius(scale), REFUSED);
        }
        let whose = match (named, lidar.name) {
            (true, Some(name)) => format!(" (LiDAR {name})"),
            _ => String::new(),
        };
        let place = match (inside, lidar.to_camera) {
            (Some(_), _) => "",
            (None, Some(_)) => " (outside the picture)",
            (None, None) => " (not drawn: no extrinsic)",
        };
        out.push(Refused { sentence: format!("{tag}{whose}{place}: {plane}"), tag, pixel: inside });
    }
    out
}

/// The board numbers and the refused planes' tags, each placed where it covers no other
/// label ([`place_labels`]) and, where there is room, no board's corners or refused mark;
/// a tag set off from its mark gets a line to it.
fn draw_labels(
    image: &mut RgbImage,
    input: &ReportInput<'_>,
    refused: &[Refused],
    contours: &[(f64, Vec2)],
    scale: u32,
) {
    let s = i64::from(scale);
    let big = scale + 1;
    let boxes: Vec<Option<Rect>> = input.boards.iter().map(|b| corner_box(b, 4 * s)).collect();
    let radius = refused_radius(scale);
    let rings = refused.iter().filter_map(|r| r.pixel).map(|px| Rect {
        x: (px.x - radius) as i64,
        y: (px.y - radius) as i64,
        w: 2 * radius as i64 + 1,
        h: 2 * radius as i64 + 1,
    });
    let avoid: Vec<Rect> = boxes.iter().flatten().copied().chain(rings).collect();
    let mut texts: Vec<(String, Rgb<u8>, u32, Option<Vec2>)> = Vec::new();
    let mut requests = Vec::new();
    for (board, area) in input.boards.iter().zip(&boxes) {
        let Some(area) = area else { continue };
        let text = format!("board {}", board.number);
        requests.push(LabelRequest {
            anchor: (area.x + area.w / 2, area.y),
            size: label_size(&text, big),
        });
        texts.push((text, TEXT, big, None));
    }
    for r in refused {
        let Some(px) = r.pixel else { continue };
        requests.push(LabelRequest {
            anchor: (px.x as i64, px.y as i64),
            size: label_size(&r.tag, scale),
        });
        texts.push((r.tag.clone(), REFUSED, scale, Some(px)));
    }
    for (level, px) in contours {
        let text = format!("{level} px");
        requests.push(LabelRequest {
            anchor: (px.x as i64, px.y as i64),
            size: label_size(&text, scale),
        });
        texts.push((text, CONTOUR, scale, None));
    }
    let size = (i64::from(image.width()), i64::from(image.height()));
    let spots = place_labels(size, &avoid, &requests);
    // Leaders first, so that no line crosses a label's text.
    for (spot, (_, colour, _, mark)) in spots.iter().zip(&texts) {
        if let (Some(spot), Some(px)) = (spot, mark) {
            leader(image, px, radius, spot, *colour);
        }
    }
    for (spot, (text, colour, text_scale, _)) in spots.iter().zip(&texts) {
        if let Some(spot) = spot {
            label(image, spot, text, *colour, *text_scale);
        }
    }
}

/// The box around a board's corners, `pad` pixels wider on each side (`None`: no corners).
fn corner_box(board: &ReportBoard<'_>, pad: i64) -> Option<Rect> {
    let first = board.corners.first()?;
    let (mut min, mut max) = (*first, *first);
    for c in board.corners {
        min = Vec2::new(min.x.min(c.x), min.y.min(c.y));
        max = Vec2::new(max.x.max(c.x), max.y.max(c.y));
    }
    let (x, y) = (min.x as i64 - pad, min.y as i64 - pad);
    Some(Rect { x, y, w: (max.x - min.x) as i64 + 2 * pad, h: (max.y - min.y) as i64 + 2 * pad })
}

/// A line from a mark's ring (radius `radius` around `mark`) to its label's box, when the
/// box stands off the ring.
fn leader(image: &mut RgbImage, mark: &Vec2, radius: f64, spot: &Rect, colour: Rgb<u8>) {
    let nearest = Vec2::new(
        mark.x.clamp(spot.x as f64, (spot.x + spot.w) as f64),
        mark.y.clamp(spot.y as f64, (spot.y + spot.h) as f64),
    );
    let gap = (nearest - mark).norm();
    if gap > radius + 6.0 {
        let from = mark + (nearest - mark) * (radius / gap);
        line(image, &from, &nearest, 2, colour);
    }
}

/// The legend's entries for the marks the picture holds.
fn legend(
    input: &ReportInput<'_>,
    marks: Drawn,
    points: bool,
    refused: bool,
) -> Vec<(Mark, String)> {
    let several = input.lidars.len() > 1;
    let mut entries = Vec::new();
    if marks.corners {
        entries.push((Mark::Corner, "detected checkerboard corners (board N: its number)".into()));
    }
    if marks.board_holes {
        entries.push((
            Mark::HoleFromBoard,
            "hole centres from the board (camera's board pose)".into(),
        ));
    }
    if marks.lidar_holes {
        let text = match several {
            true => "hole centres from each LiDAR (through the solved rig)",
            false => "hole centres from the LiDAR (through the extrinsic)",
        };
        entries.push((Mark::HoleFromLidar, text.into()));
    }
    if points {
        let text = match several {
            true => "LiDAR points by range, one colour family per LiDAR (bars below)",
            false => "LiDAR points, coloured by range (bar below)",
        };
        entries.push((Mark::Points(input.lidars.len()), text.into()));
    }
    if refused {
        entries.push((
            Mark::Refused,
            "LiDAR plane refused as a board (R1, R2, ...: see the left)".into(),
        ));
    }
    entries
}

/// One range bar per LiDAR whose points were drawn, titled with its name.
fn bars(input: &ReportInput<'_>, clouds: &[Cloud<'_>], drawn: &[usize]) -> Vec<Bar> {
    let count = input.lidars.len();
    let mut out: Vec<Bar> = Vec::new();
    for (k, lidar) in input.lidars.iter().enumerate() {
        let palette = Palette::for_lidar(k, count);
        let shown = clouds.iter().zip(drawn).any(|(c, n)| c.2 == palette && *n > 0);
        if !shown || lidar.to_camera.is_none() {
            continue;
        }
        let title = match lidar.name {
            Some(name) if count > 1 => format!("LiDAR {name}: point range (m)"),
            _ => "LiDAR point range (m)".to_string(),
        };
        out.push(Bar { title, palette });
    }
    out
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

/// The status (coloured by the verdict) and the σ and RMS figures; the LiDAR's figures
/// only for a run with a LiDAR.
fn status_lines(run: &Calibration) -> Vec<(String, Rgb<u8>)> {
    let r = &run.result;
    let (u, c, q) = (&r.uncertainty, &r.camera, &r.quality);
    let mut lines = vec![verdict(r.status, r.reason.as_deref())];
    lines.push((format!("fx {:.2} fy {:.2} px (σ {:.2} {:.2})", c.fx, c.fy, u.fx, u.fy), TEXT));
    lines.push((format!("cx {:.2} cy {:.2} px (σ {:.2} {:.2})", c.cx, c.cy, u.cx, u.cy), TEXT));
    let (corners, boards) = (q.corner_rms_px, q.boards);
    let rms = match run.lidar_to_camera {
        Some(_) => {
            let (deg, mm) = (u.rotation_deg, u.translation_m * 1e3);
            lines.push((format!("extrinsic σ {deg:.3}° / {mm:.1} mm (largest axis)"), TEXT));
            let lidar = run.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count();
            format!(
                "RMS corners {corners:.3} px, holes {:.3} px; {boards} boards used, {lidar} with LiDAR holes",
                q.hole_rms_px
            )
        }
        None => format!("RMS corners {corners:.3} px; {boards} boards used"),
    };
    lines.push((rms, TEXT));
    lines
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

#[cfg(test)]
mod tests {
    use super::draw::tests::camera;
    use super::*;

    #[test]
    fn without_a_lidar_only_the_corners_are_drawn_and_explained() {
        // The board's holes are known (through its pose) but no LiDAR is there to compare.
        let corners = [Vec2::new(50.0, 50.0), Vec2::new(60.0, 50.0)];
        let board = ReportBoard {
            number: 0,
            corners: &corners,
            holes_camera: vec![Vec3::new(0.0, 0.0, 2.0)],
        };
        let grey = vec![0u8; 200 * 100];
        let input = ReportInput {
            grey: &grey,
            camera: camera(),
            boards: vec![board],
            lidars: vec![],
            lines: vec![],
            map: None,
        };
        let mut image = draw::grey_frame(&grey, &camera());
        let marks = draw_marks(&mut image, &input, &[]);
        assert!(marks.corners && !marks.board_holes && !marks.lidar_holes);
        assert!(!image.pixels().any(|p| *p == HOLE_CAMERA), "a hole ring drawn");
        let entries = legend(&input, marks, false, false);
        assert_eq!(entries.iter().map(|(m, _)| *m).collect::<Vec<_>>(), vec![Mark::Corner]);
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
}
