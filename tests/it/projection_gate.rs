//! The projection map (`calibrate::projection_map`) in the result file, and the gate that
//! judges it over the room's `[quality] region` when the room gives
//! `max_projection_sigma_px`: end to end through the binary on the bundled fixtures.

use std::path::Path;

use crate::common::scratch::Scratch;
use crate::common::{fixture, roomcal};
use roomcal::result::{CalibrationResult, ProjectionMap, Status};

/// `calibrate` of the surveyed fixture (the README's main job) in `room` (its room file's
/// text): exit code, first stdout line, result file.
fn calibrate_surveyed(dir: &Path, room: &str) -> (i32, String, CalibrationResult) {
    calibrate_surveyed_with(dir, room, &[])
}

fn calibrate_surveyed_with(
    dir: &Path,
    room: &str,
    extra: &[&str],
) -> (i32, String, CalibrationResult) {
    let room_path = dir.join("room.toml");
    std::fs::write(&room_path, room).unwrap();
    let out = dir.join("result.json");
    let scene = fixture("surveyed-pandar64");
    let (code, stdout, stderr) = roomcal(
        &[
            "calibrate",
            "--room",
            room_path.to_str().unwrap(),
            "--image",
            scene.join("image.png").to_str().unwrap(),
            "--cloud",
            scene.join("cloud.pcap").to_str().unwrap(),
            "--lidar-calibration",
            scene.join("angles.csv").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]
        .into_iter()
        .chain(extra.iter().copied())
        .collect::<Vec<_>>(),
    );
    assert!(code == 0 || code == 3, "{stdout}{stderr}");
    let result = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    (code, stdout.lines().next().unwrap_or_default().to_string(), result)
}

/// The surveyed fixture's room file with `lines` first in its `[quality]` table.
fn surveyed_room_with(lines: &str) -> String {
    let text = std::fs::read_to_string(fixture("surveyed-pandar64/room.toml")).unwrap();
    assert!(text.contains("[quality]\n"), "the fixture's room has no [quality] table");
    text.replacen("[quality]\n", &format!("[quality]\n{lines}\n"), 1)
}

fn value(map: &ProjectionMap, u: f64, v: f64) -> f64 {
    let c = map.columns.iter().position(|&x| x == u).unwrap();
    let r = map.rows.iter().position(|&x| x == v).unwrap();
    map.sigma_px[r][c].unwrap()
}

#[test]
fn every_solved_run_carries_its_map_and_a_room_without_a_limit_is_not_judged_by_it() {
    let dir = Scratch::new("map-default");
    let room = std::fs::read_to_string(fixture("surveyed-pandar64/room.toml")).unwrap();
    let (code, line, result) = calibrate_surveyed(&dir, &room);
    assert_eq!((code, result.status), (0, Status::Accepted), "{line}");
    let map = result.projection_uncertainty.expect("an accepted run carries its map");
    assert!(map.lidar, "a run with a LiDAR holds the point in the LiDAR's frame");
    assert_eq!(map.range_m, 10.0);
    assert_eq!((map.columns.len(), map.rows.len()), (17, 11));
    assert_eq!((map.columns[0], *map.columns.last().unwrap()), (0.0, 1919.0));
    assert_eq!((map.rows[0], *map.rows.last().unwrap()), (0.0, 1199.0));
    // The six boards cover the middle: there the extrinsic's σ (0.021°, a few mm) is a
    // fraction of a pixel at 10 m; the image's corners are the lens extrapolated.
    let (centre, corner) = (value(&map, 959.5, 599.5), value(&map, 0.0, 0.0));
    assert!(centre > 0.05 && centre < 0.5, "centre {centre}");
    assert!(corner > 10.0 * centre, "corner {corner}, centre {centre}");
}

#[test]
fn the_report_draws_the_maps_contours_over_the_frame() {
    let dir = Scratch::new("map-report");
    let picture = dir.join("report.png");
    let room = std::fs::read_to_string(fixture("surveyed-pandar64/room.toml")).unwrap();
    let (code, line, _) =
        calibrate_surveyed_with(&dir, &room, &["--report", picture.to_str().unwrap()]);
    assert_eq!(code, 0, "{line}");
    let image = image::open(&picture).unwrap().to_rgb8();
    let contour = roomcal::report::CONTOUR;
    // The frame is the top 1200 rows; the 1 and 3 px contours run down its outer columns
    // (the map's corners reach 4.4 px) and none crosses the middle.
    let on = |x0: u32, x1: u32| (0..1200).flat_map(move |y| (x0..x1).map(move |x| (x, y)));
    let count = |x0, x1| on(x0, x1).filter(|&(x, y)| *image.get_pixel(x, y) == contour).count();
    assert!(
        count(0, 300) > 500 && count(1620, 1920) > 500,
        "{} {}",
        count(0, 300),
        count(1620, 1920)
    );
    assert_eq!(count(600, 1320), 0);
}

#[test]
fn a_room_with_a_limit_refuses_uncovered_corners_and_accepts_its_declared_region() {
    let dir = Scratch::new("map-gate");
    let (code, line, result) =
        calibrate_surveyed(&dir, &surveyed_room_with("max_projection_sigma_px = 3.0"));
    assert_eq!((code, result.status), (3, Status::Rejected), "{line}");
    let reason = result.reason.unwrap();
    assert!(reason.starts_with("a projection is uncertain by "), "{reason}");
    assert!(reason.contains("at most 3 px allowed over the image"), "{reason}");
    // Named at the worst grid pixel, which is in the image's outer columns.
    let map = result.projection_uncertainty.unwrap();
    let worst = map.worst_in([0.0, 0.0, 1.0, 1.0]).unwrap();
    assert!(worst.sigma_px > 3.0);
    let at = format!("at pixel ({:.0}, {:.0})", worst.at_px.x, worst.at_px.y);
    assert!(
        reason.contains(&at) && reason.contains(&format!("{:.2} px", worst.sigma_px)),
        "{reason}"
    );
    assert!(worst.at_px.x < 0.05 * 1919.0 || worst.at_px.x > 0.95 * 1919.0, "{reason}");

    let declared =
        surveyed_room_with("max_projection_sigma_px = 3.0\nregion = [0.05, 0.0, 0.95, 1.0]");
    let (code, line, result) = calibrate_surveyed(&dir, &declared);
    assert_eq!((code, result.status), (0, Status::Accepted), "{line}");
    let inside = result.projection_uncertainty.unwrap().worst_in([0.05, 0.0, 0.95, 1.0]).unwrap();
    assert!(inside.sigma_px <= 3.0, "{inside:?}");
}

#[test]
fn the_rejection_fixture_is_refused_by_its_map_naming_the_corner() {
    let dir = Scratch::new("map-fixture");
    let scene = fixture("four-boards-vlp32c-rejected");
    let out = dir.join("result.json");
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        scene.join("room.toml").to_str().unwrap(),
        "--image",
        scene.join("image.png").to_str().unwrap(),
        "--cloud",
        scene.join("cloud.pcd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(code, 3, "{stdout}{stderr}");
    assert!(
        stdout.starts_with("roomcal calibrate: rejected: a projection is uncertain by ")
            && stdout.contains("at pixel (1919, 0)")
            && stdout.contains("add boards that cover that part of the image"),
        "{stdout}"
    );
}
