//! The committed fixtures are what `roomcal simulate` makes: each `truth.json` is compared
//! with a fresh simulation of the same room, seed and options (rendered at one sample per
//! pixel: the truth does not depend on the image quality).

use std::path::{Path, PathBuf};

use roomcal::geometry::CameraModel;
use roomcal::sim::{simulate, ImageNoise, SimOptions, Truth};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(name)
}

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
        "four-boards-vlp32c",
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
