//! `roomcal detect` in a surveyed room, over the binary, on the surveyed fixture
//! (fixtures/surveyed-pandar64: a vehicle the survey was not made from): every camera
//! board and every LiDAR board is reported with the surveyed board it is, and that is the
//! right one — checked against the simulator's truth (which truth board each detection
//! is, from its pixels or hole centres; which surveyed board each truth board is, from
//! the room truth, whose frame the survey's file frame is within the parking spread).
//! Without a `[survey]` no identity is written.

use crate::common::fixture;
use crate::common::BIN;
use std::path::Path;
use std::process::Command;

use roomcal::result::Detections;
use roomcal::sim::visits::{RoomTruth, VisitTruth};

/// `roomcal COMMAND --room ROOM` on the fixture's image and capture, writing `out`.
fn on_fixture(command: &str, room: &Path, out: &Path) -> std::process::Output {
    Command::new(BIN)
        .args([command, "--room"])
        .arg(room)
        .arg("--image")
        .arg(fixture("surveyed-pandar64/image.png"))
        .arg("--cloud")
        .arg(fixture("surveyed-pandar64/cloud.pcap"))
        .arg("--lidar-calibration")
        .arg(fixture("surveyed-pandar64/angles.csv"))
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

fn detect(room: &Path, out: &Path) -> (Detections, String) {
    let run = on_fixture("detect", room, out);
    let text = String::from_utf8_lossy(&run.stdout).to_string();
    assert!(run.status.success(), "detect: {text}{}", String::from_utf8_lossy(&run.stderr));
    (serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap(), text)
}

fn read<T: serde::de::DeserializeOwned>(path: &Path) -> T {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt()
}

fn mean<const N: usize>(points: &[[f64; N]]) -> [f64; N] {
    core::array::from_fn(|i| points.iter().map(|p| p[i]).sum::<f64>() / points.len() as f64)
}

/// The index of the item of `items` nearest to `at` under `key`.
fn nearest<T>(items: &[T], at: &[f64], key: impl Fn(&T) -> Vec<f64>) -> usize {
    (0..items.len())
        .min_by(|&a, &b| distance(&key(&items[a]), at).total_cmp(&distance(&key(&items[b]), at)))
        .unwrap()
}

#[test]
fn detect_names_the_surveyed_board_of_every_detection() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("survey_detect.json");
    let (detections, text) = detect(&fixture("surveyed-pandar64/room.toml"), &out);
    println!("{text}");
    let truth: VisitTruth = read(&fixture("surveyed-pandar64/truth.json"));
    let room_truth: RoomTruth = read(&fixture("surveyed-pandar64/room-truth.json"));
    let room = roomcal::room::load(&fixture("surveyed-pandar64/room.toml")).unwrap();
    let survey = room.survey.unwrap();
    // Which truth board each surveyed board is, and whether its frame is the truth's turned
    // by 180° (board 0's frame was the first visit's detector order).
    let survey_truth: Vec<(usize, bool)> = survey
        .boards
        .iter()
        .map(|b| {
            let t = nearest(&room_truth.boards, &b.translation, |t| t.translation.to_vec());
            let d = distance(&room_truth.boards[t].translation, &b.translation);
            assert!(
                d < 0.5,
                "surveyed board at {:?} is {d} m from every truth board",
                b.translation
            );
            let (angle, _) = room_truth.boards[t].difference(&roomcal::result::Extrinsic {
                rotation: b.rotation,
                translation: b.translation,
            });
            (t, angle > 90.0)
        })
        .collect();
    let (mut cameras, mut lidars) = (0, 0);
    for board in &detections.boards {
        let k = board.surveyed_board.expect("every detection of this scene is identified") as usize;
        let (truth_board, flipped) = survey_truth[k];
        if !board.corners_px.is_empty() {
            cameras += 1;
            let seen = nearest(&truth.scene.boards, &mean(&board.corners_px), |t| {
                mean(&t.corners_px).to_vec()
            });
            assert_eq!(seen, truth_board, "camera board identified as surveyed board {k}");
            // The detector's first corner is the truth's first, or its last (half-turned).
            let corners = &truth.scene.boards[seen].corners_px;
            let reversed = distance(&board.corners_px[0], corners.last().unwrap())
                < distance(&board.corners_px[0], &corners[0]);
            assert_eq!(board.half_turned, reversed != flipped, "surveyed board {k}'s half-turn");
        } else {
            lidars += 1;
            let seen = nearest(&truth.scene.boards, &mean(&board.holes_lidar), |t| {
                mean(&t.holes_lidar).to_vec()
            });
            assert_eq!(seen, truth_board, "LiDAR board identified as surveyed board {k}");
        }
    }
    assert!(cameras >= 4 && lidars >= 2, "{cameras} camera and {lidars} LiDAR boards");
    assert!(text.contains("camera board 0: surveyed board"), "{text}");
    assert!(text.contains("LiDAR board 0: surveyed board"), "{text}");
}

#[test]
fn detect_without_a_survey_writes_no_identity() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("survey_detect_free");
    std::fs::create_dir_all(&dir).unwrap();
    let mut room = roomcal::room::load(&fixture("surveyed-pandar64/room.toml")).unwrap();
    room.survey = None;
    let path = dir.join("room.toml");
    std::fs::write(&path, roomcal::room::to_toml(&room)).unwrap();
    let (detections, text) = detect(&path, &dir.join("detections.json"));
    assert!(!detections.boards.is_empty());
    assert!(detections.boards.iter().all(|b| b.surveyed_board.is_none() && !b.half_turned));
    let json = std::fs::read_to_string(dir.join("detections.json")).unwrap();
    assert!(!json.contains("surveyed_board") && !json.contains("half_turned"), "{json}");
    assert!(!text.contains("surveyed board"), "{text}");
}

/// In a surveyed room `detect` finds the LiDAR's boards where `calibrate` finds them (where
/// the room expects them, from the camera's room pose): every board the calibration paired
/// with the LiDAR is among detect's, hole for hole.
#[test]
fn detect_reports_the_lidar_boards_the_calibration_uses() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("survey_detect_same");
    std::fs::create_dir_all(&dir).unwrap();
    let (detections, _) =
        detect(&fixture("surveyed-pandar64/room.toml"), &dir.join("detections.json"));
    let result = dir.join("result.json");
    let run = on_fixture("calibrate", &fixture("surveyed-pandar64/room.toml"), &result);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let result: serde_json::Value = read(&result);
    let found: Vec<&Vec<[f64; 3]>> =
        detections.boards.iter().map(|b| &b.holes_lidar).filter(|h| !h.is_empty()).collect();
    let mut paired = 0;
    for board in result["boards"].as_array().unwrap() {
        let Some(holes) = board["holes_lidar"].as_array().filter(|h| !h.is_empty()) else {
            continue;
        };
        paired += 1;
        let holes: Vec<Vec<f64>> = holes
            .iter()
            .map(|h| h.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect())
            .collect();
        let same =
            |d: &&Vec<[f64; 3]>| holes.iter().all(|h| d.iter().any(|p| distance(p, h) < 1e-6));
        assert!(found.iter().any(same), "calibration's LiDAR board {holes:?} not among detect's");
    }
    assert!(paired >= 2, "the calibration paired {paired} LiDAR boards");
}
