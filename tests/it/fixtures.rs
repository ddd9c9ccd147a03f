//! The committed fixtures are what `roomcal simulate` makes: each `truth.json` is compared
//! with a fresh simulation of the same room, seed and options (rendered at one sample per
//! pixel: the truth does not depend on the image quality).

use crate::common::fixture;
use std::path::Path;

use roomcal::geometry::CameraModel;
use roomcal::sim::{simulate, ImageNoise, SimOptions, Truth};

fn check(name: &str, room: &str, options: SimOptions) {
    let room = roomcal::room::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(room)).unwrap();
    let options =
        SimOptions { image: ImageNoise { supersample: 1, ..ImageNoise::default() }, ..options };
    let fresh = simulate(&room, &options).unwrap();
    let text = std::fs::read_to_string(fixture(name).join("truth.json")).unwrap();
    let stored: Truth = serde_json::from_str(&text).unwrap();
    assert_eq!(
        stored, fresh.truth,
        "{name}: truth.json differs from a fresh simulation; regenerate it (fixtures/README.md)"
    );
    let stored_room = roomcal::room::load(&fixture(name).join("room.toml")).unwrap();
    assert_eq!(stored_room, fresh.room, "{name}: room.toml differs");
    let image = image::open(fixture(name).join("image.png")).unwrap();
    assert_eq!(
        (image.width(), image.height()),
        (fresh.truth.camera.width, fresh.truth.camera.height)
    );
    if let Some(cloud) = &fresh.cloud {
        let stored_cloud = roomcal::lidar::pcd::read(fixture(name).join("cloud.pcd")).unwrap();
        assert_eq!(stored_cloud.len(), cloud.len(), "{name}: cloud.pcd point count");
    }
}

#[test]
fn six_boards_pandar64() {
    check(
        "six-boards-pandar64",
        "config/room.toml",
        SimOptions { seed: 7, ..SimOptions::default() },
    );
}

#[test]
fn four_boards_vlp32c() {
    check(
        "four-boards-vlp32c-rejected",
        "fixtures/rooms/four-boards-vlp32c.toml",
        SimOptions {
            seed: 8,
            hfov_deg: Some(90.0),
            distortion: Some(vec![-0.3, 0.1, 0.0005, -0.0004, -0.012]),
            ..SimOptions::default()
        },
    );
}

#[test]
fn intrinsics_fisheye() {
    check(
        "intrinsics-fisheye",
        "fixtures/rooms/intrinsics-fisheye.toml",
        SimOptions { seed: 9, hfov_deg: Some(120.0), ..SimOptions::default() },
    );
    let room = roomcal::room::load(&fixture("intrinsics-fisheye").join("room.toml")).unwrap();
    assert_eq!(room.camera.model, CameraModel::Fisheye);
    assert!(room.intrinsics_only());
}

/// The surveyed room: `room.toml` is `roomcal survey`'s output from visits 1–8 of one
/// simulated room, and the scene (image, capture, truth) is visit 9, a vehicle the survey
/// was not made from (fixtures/README.md). Its truth and the room truth are still what the
/// simulator makes (nine renders: the costliest fixture check), and the room file holds a
/// survey of every board from 8 visits.
#[test]
fn surveyed_pandar64_truth() {
    let name = "surveyed-pandar64";
    let base = roomcal::room::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/room.toml"))
        .unwrap();
    let options = SimOptions {
        seed: SURVEYED_SEED,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let fresh = roomcal::sim::visits::simulate_visits(&base, &options, 9).unwrap();
    let stored: roomcal::sim::visits::VisitTruth =
        serde_json::from_str(&std::fs::read_to_string(fixture(name).join("truth.json")).unwrap())
            .unwrap();
    assert_eq!(
        (&stored.scene, &stored.room_to_camera),
        (&fresh.visits[8].scene.truth, &roomcal::result::Extrinsic::from_se3(&fresh.visits[8].room_to_camera)),
        "{name}: truth.json differs from visit 9 of a fresh simulation; regenerate it (fixtures/README.md)"
    );
    let room_truth: roomcal::sim::visits::RoomTruth = serde_json::from_str(
        &std::fs::read_to_string(fixture(name).join("room-truth.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(room_truth, fresh.truth, "{name}: room-truth.json differs");
    let room = roomcal::room::load(&fixture(name).join("room.toml")).unwrap();
    let survey = room.survey.as_ref().expect("the fixture's room file has a [survey]");
    assert_eq!((survey.visits, survey.boards.len()), (8, fresh.truth.boards.len()));
}

/// `roomcal calibrate` of the surveyed fixture's scene uses the survey (`camera_in_room`
/// in the result), is accepted, and meets the truth within 3σ of what it reports.
#[test]
fn surveyed_pandar64_calibrates_in_the_surveyed_room() {
    let name = "surveyed-pandar64";
    let stored: roomcal::sim::visits::VisitTruth =
        serde_json::from_str(&std::fs::read_to_string(fixture(name).join("truth.json")).unwrap())
            .unwrap();
    let result = calibrate_fixture(name);
    assert_eq!(result.status, roomcal::result::Status::Accepted, "{:?}", result.reason);
    assert!(result.camera_in_room.is_some(), "the calibration did not use the survey");
    let truth = &stored.scene;
    let (r, t, u) = (&result.camera, &truth.camera, &result.uncertainty);
    let errors = [
        ("fx", (r.fx - t.fx).abs(), u.fx),
        ("fy", (r.fy - t.fy).abs(), u.fy),
        ("cx", (r.cx - t.cx).abs(), u.cx),
        ("cy", (r.cy - t.cy).abs(), u.cy),
    ];
    let (rotation_err, translation_err) = truth
        .lidar_to_camera
        .as_ref()
        .unwrap()
        .difference(result.lidar_to_camera.as_ref().unwrap());
    println!(
        "{name}: fx {:.3} % (σ {:.3} %), cx {:.2} px (σ {:.2}), cy {:.2} px (σ {:.2}), rotation {rotation_err:.4}° (σ {:.4}°), translation {:.2} mm (σ {:.2} mm)",
        100.0 * errors[0].1 / t.fx,
        100.0 * u.fx / t.fx,
        errors[2].1,
        u.cx,
        errors[3].1,
        u.cy,
        u.rotation_deg,
        translation_err * 1e3,
        u.translation_m * 1e3
    );
    for (what, error, sigma) in errors {
        assert!(error <= 3.0 * sigma, "{name}: {what} off by {error} (3σ = {})", 3.0 * sigma);
    }
    // Rotation and translation errors are norms over three axes, their σ the worst axis.
    let norm3 = 3.0 * 3f64.sqrt();
    assert!(rotation_err <= norm3 * u.rotation_deg, "rotation off by {rotation_err}°");
    assert!(translation_err <= norm3 * u.translation_m, "translation off by {translation_err} m");
}

/// The seed of the surveyed fixture's simulation (fixtures/README.md).
const SURVEYED_SEED: u64 = 13;

/// `roomcal calibrate` on a fixture's room, image and capture; the result file.
fn calibrate_fixture(name: &str) -> roomcal::result::CalibrationResult {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("fixtures-{name}.json"));
    let dir = fixture(name);
    let run = std::process::Command::new(crate::common::BIN)
        .arg("calibrate")
        .arg("--room")
        .arg(dir.join("room.toml"))
        .arg("--image")
        .arg(dir.join("image.png"))
        .arg("--cloud")
        .arg(dir.join("cloud.pcap"))
        .arg("--lidar-calibration")
        .arg(dir.join("angles.csv"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    println!("{}", String::from_utf8_lossy(&run.stdout));
    serde_json::from_str(&std::fs::read_to_string(&out).unwrap_or_else(|e| {
        panic!("{name}: no result ({e}): {}", String::from_utf8_lossy(&run.stderr))
    }))
    .unwrap()
}
