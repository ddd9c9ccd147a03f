//! `roomcal calibrate` end to end: the binary on a fixture scene (detect → associate →
//! solve → gate → result, YAML and report), the real OpenCV images for the intrinsics,
//! and the exit codes for bad input and rejected runs.

use std::path::PathBuf;

use roomcal::result::{CalibrationResult, Status};
use roomcal::sim::Truth;

use crate::common::scratch::Scratch;
use crate::common::{fixture, roomcal, root};

#[test]
fn calibrates_the_six_board_fixture() {
    let dir = Scratch::new("e2e-six");
    let (out, report) = (dir.join("result.json"), dir.join("report.png"));
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        fixture("six-boards-pandar64/room.toml").to_str().unwrap(),
        "--image",
        fixture("six-boards-pandar64/image.png").to_str().unwrap(),
        "--cloud",
        fixture("six-boards-pandar64/cloud.pcd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    let text = stdout + &stderr;
    println!("{text}");
    assert_eq!(code, 0, "{text}");
    let result: CalibrationResult =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let truth: Truth = serde_json::from_str(
        &std::fs::read_to_string(fixture("six-boards-pandar64/truth.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(result.status, Status::Accepted);
    assert_eq!(result.quality.boards, 6);
    let (r, t, u) = (&result.camera, &truth.camera, &result.uncertainty);
    let fx_err = (r.fx - t.fx).abs();
    let principal_err = (r.cx - t.cx).abs().max((r.cy - t.cy).abs());
    let (rotation_err, translation_err) = truth
        .lidar_to_camera
        .as_ref()
        .unwrap()
        .difference(result.lidar_to_camera.as_ref().unwrap());
    println!(
        "errors: fx {fx_err:.2} px ({:.3} %), principal {principal_err:.2} px, rotation {rotation_err:.4}°, translation {:.1} mm; corner RMS {:.3} px",
        fx_err / t.fx * 100.0,
        translation_err * 1000.0,
        result.quality.corner_rms_px
    );
    assert!(fx_err < 4.0 * u.fx + 0.5, "fx off by {fx_err} px (σ {})", u.fx);
    assert!(
        principal_err < 4.0 * u.cx.max(u.cy) + 0.5,
        "principal point off by {principal_err} px"
    );
    assert!(rotation_err < 4.0 * u.rotation_deg + 0.01, "rotation off by {rotation_err}°");
    assert!(
        translation_err < 4.0 * u.translation_m + 0.002,
        "translation off by {translation_err} m"
    );
    assert!(result.quality.corner_rms_px < 0.1);
    let yaml = std::fs::read_to_string(out.with_extension("yaml")).unwrap();
    assert!(
        yaml.starts_with("%YAML:1.0")
            && yaml.contains("camera_matrix")
            && yaml.contains("lidar_to_camera")
    );
    let overlay = image::open(&report).unwrap();
    // The frame above a footer of text (status, figures, legend, range bar).
    assert_eq!(overlay.width(), 1920);
    assert!(overlay.height() > 1200, "no footer: {}", overlay.height());
}

#[test]
fn a_room_with_one_board_more_than_seen_is_rejected_with_exit_3() {
    let dir = Scratch::new("e2e-reject");
    let room = std::fs::read_to_string(fixture("six-boards-pandar64/room.toml")).unwrap();
    let seven = dir.join("room.toml");
    std::fs::write(&seven, room.replace("count = 6", "count = 7")).unwrap();
    let out = dir.join("result.json");
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        seven.to_str().unwrap(),
        "--image",
        fixture("six-boards-pandar64/image.png").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let text = stdout + &stderr;
    assert_eq!(code, 3, "{text}");
    let result: CalibrationResult =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(result.status, Status::Rejected);
    assert!(result.reason.unwrap().contains("needs 7"));
}

#[test]
fn bad_input_exits_2_naming_the_file() {
    let dir = Scratch::new("e2e-bad");
    // An image of another size than the room's camera.
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        fixture("six-boards-pandar64/room.toml").to_str().unwrap(),
        "--image",
        fixture("intrinsics-fisheye/image.png").to_str().unwrap(),
        "--out",
        dir.join("r.json").to_str().unwrap(),
    ]);
    let text = stdout + &stderr;
    assert_eq!(code, 2, "{text}");
    assert!(text.contains("intrinsics-fisheye/image.png") && text.contains("1280x800"), "{text}");
    // A truncated PNG.
    let bytes = std::fs::read(fixture("six-boards-pandar64/image.png")).unwrap();
    let cut = dir.join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        fixture("six-boards-pandar64/room.toml").to_str().unwrap(),
        "--image",
        cut.to_str().unwrap(),
        "--out",
        dir.join("r.json").to_str().unwrap(),
    ]);
    let text = stdout + &stderr;
    assert_eq!(code, 2, "{text}");
    assert!(text.contains("cut.png"), "{text}");
}

#[test]
fn intrinsics_on_the_real_opencv_images() {
    let data = root().join("../shared/data/chessboard/opencv-left");
    if !data.exists() {
        crate::common::skipped(format_args!("{} is absent", data.display()));
        return;
    }
    let dir = Scratch::new("e2e-opencv");
    let room = dir.join("room.toml");
    std::fs::write(
        &room,
        "[board]\nwidth = 0.3\nheight = 0.22\ninner_corners = [9, 6]\nsquare = 0.025\nhole_radius = 0.0\nholes = []\ncount = 1\n\n\
         [camera]\nmodel = \"pinhole-radtan\"\nwidth = 640\nheight = 480\n",
    )
    .unwrap();
    let out = dir.join("result.json");
    let mut args: Vec<String> =
        ["calibrate", "--room", room.to_str().unwrap(), "--out", out.to_str().unwrap()]
            .map(String::from)
            .to_vec();
    let mut images: Vec<PathBuf> = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    images.sort();
    for image in &images {
        args.push("--image".into());
        args.push(image.to_string_lossy().into_owned());
    }
    let (code, stdout, stderr) = roomcal(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let text = stdout + &stderr;
    println!("{text}");
    assert_eq!(code, 0, "{text}");
    let result: CalibrationResult =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(result.quality.boards, 13);
    assert!(result.lidar_to_camera.is_none());
    // OpenCV's own calibration of these views (the data's README).
    let (fx, cx, cy) = (535.916, 342.283, 235.571);
    let c = &result.camera;
    println!(
        "vs OpenCV: fx {:+.3} % fy {:+.3} %, cx {:+.2} px, cy {:+.2} px",
        (c.fx - fx) / fx * 100.0,
        (c.fy - fx) / fx * 100.0,
        c.cx - cx,
        c.cy - cy
    );
    assert!(((c.fx - fx) / fx).abs() < 0.005 && ((c.fy - fx) / fx).abs() < 0.005);
    assert!((c.cx - cx).abs() < 2.0 && (c.cy - cy).abs() < 2.0);
}
