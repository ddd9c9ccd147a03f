//! `roomcal calibrate --detections`: a detections file solved instead of images and clouds.
//! `roomcal detect`'s own file of the six-board fixture calibrates as the run on the image
//! and cloud does without the LiDAR's board-face points (which a detections file does not
//! hold); a file that does not fit the room is bad input naming the file and the board.

use std::path::Path;

use crate::common::scratch::Scratch;
use crate::common::{fixture, roomcal};

const ROOM: &str = "six-boards-pandar64/room.toml";

fn path(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn result(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).expect("a result file")).expect("JSON")
}

/// The numbers of a result's camera and extrinsic, in a fixed order.
fn figures(r: &serde_json::Value) -> Vec<f64> {
    let camera = &r["camera"];
    let mut out: Vec<f64> =
        ["fx", "fy", "cx", "cy"].iter().map(|k| camera[k].as_f64().expect("a number")).collect();
    out.extend(
        camera["distortion"].as_array().expect("distortion").iter().map(|v| v.as_f64().unwrap()),
    );
    let e = &r["lidar_to_camera"];
    out.extend(e["rotation"].as_array().expect("rotation").iter().flat_map(|row| {
        row.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>()
    }));
    out.extend(
        e["translation"].as_array().expect("translation").iter().map(|v| v.as_f64().unwrap()),
    );
    out
}

#[test]
fn detects_own_file_calibrates_as_the_run_without_face_points() {
    let dir = Scratch::new("calibrate-detections");
    let (room, image, cloud) = (
        path(&fixture(ROOM)),
        path(&fixture("six-boards-pandar64/image.png")),
        path(&fixture("six-boards-pandar64/cloud.pcd")),
    );
    let detections = dir.join("detections.json");
    let (code, out, err) = roomcal(&[
        "detect",
        "--room",
        &room,
        "--image",
        &image,
        "--cloud",
        &cloud,
        "--out",
        &path(&detections),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    let text = std::fs::read_to_string(&detections).unwrap();
    assert!(text.contains("corner_sigma_px") && text.contains("hole_sigma_m"), "{text}");

    let from_file = dir.join("from-file.json");
    let (code, out, err) = roomcal(&[
        "calibrate",
        "--room",
        &room,
        "--detections",
        &path(&detections),
        "--out",
        &path(&from_file),
    ]);
    println!("{out}{err}");
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.starts_with("roomcal calibrate: accepted ("), "{out}");

    let from_run = dir.join("from-run.json");
    let (code, out, err) = roomcal(&[
        "calibrate",
        "--room",
        &room,
        "--image",
        &image,
        "--cloud",
        &cloud,
        "--without-planes",
        "--out",
        &path(&from_run),
    ]);
    assert_eq!(code, 0, "{out}{err}");
    let (a, b) = (figures(&result(&from_file)), figures(&result(&from_run)));
    assert_eq!(a.len(), b.len());
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!(
            (x - y).abs() <= 1e-9 * (1.0 + y.abs()),
            "figure {k}: {x} from the file, {y} from the run"
        );
    }
}

#[test]
fn a_detections_file_that_does_not_fit_the_room_is_bad_input() {
    let dir = Scratch::new("calibrate-detections-bad");
    let room = path(&fixture(ROOM));
    let cases = [
        ("not-json.json", "boards = 1".to_string(), "not a detections file"),
        ("empty.json", r#"{"boards": []}"#.to_string(), "no board in the file"),
        (
            "corners.json",
            r#"{"boards": [{"frame": 0, "corners_px": [[1.0, 2.0], [3.0, 4.0]]}]}"#.to_string(),
            "boards[0]: 2 corners_px, the room's board has",
        ),
        (
            "holes.json",
            r#"{"boards": [{"frame": 0, "holes_lidar": [[1.0, 2.0, 3.0]]}]}"#.to_string(),
            "boards[0]: 1 holes_lidar, the room's board has 4 holes",
        ),
        (
            "frame.json",
            r#"{"boards": [{"frame": 4000, "holes_lidar": [[1,2,3],[1,2,3],[1,2,3],[1,2,3]]}]}"#
                .to_string(),
            "boards[0]: frame 4000, at most",
        ),
        (
            "sigma.json",
            r#"{"boards": [{"frame": 0, "holes_lidar": [[1,2,3],[1,2,3],[1,2,3],[1,2,3]], "hole_sigma_m": -1}]}"#
                .to_string(),
            "boards[0]: hole_sigma_m must be a positive number",
        ),
    ];
    let huge = " ".repeat(17 << 20) + r#"{"boards": []}"#;
    let cases = cases.into_iter().chain([("huge.json", huge, "larger than 16 MiB")]);
    for (name, text, says) in cases {
        let file = dir.join(name);
        std::fs::write(&file, text).unwrap();
        let out = dir.join("result.json");
        let (code, stdout, stderr) = roomcal(&[
            "calibrate",
            "--room",
            &room,
            "--detections",
            &path(&file),
            "--out",
            &path(&out),
        ]);
        assert_eq!(code, 2, "{name}: {stdout}{stderr}");
        assert!(stderr.contains(&path(&file)) && stderr.contains(says), "{name}: {stderr}");
        assert!(!out.exists(), "{name}: a result was written");
    }
    let (code, _, stderr) =
        roomcal(&["calibrate", "--room", &room, "--detections", "x.json", "--image", "y.png"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("cannot be used with"), "{stderr}");
}
