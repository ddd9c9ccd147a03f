//! The rig file (`roomcal::rig`): DESIGN.md's example reads as written; every refusal
//! names the file, the sensor and the key; the room's `[camera]`/`[lidar]` are the
//! one-pair rig.

use std::path::Path;

use roomcal::rig::{parse, Rig, SensorKind};

const DESIGN_EXAMPLE: &str = r#"
[[camera]]
name = "front"
model = "pinhole-radtan"
width = 1920
height = 1200
[[lidar]]
name = "top"
model = "pandar64"
rotation = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]
translation = [0.05, -0.5, -0.3]
"#;

fn error_of(text: &str) -> String {
    parse(text, Path::new("rig.toml")).expect_err("refused").to_string()
}

#[test]
fn the_design_example_reads() {
    let rig = parse(DESIGN_EXAMPLE, Path::new("rig.toml")).unwrap();
    assert_eq!(rig.cameras.len(), 1);
    assert_eq!(rig.lidars[0].name.as_str(), "top");
    assert_eq!(rig.find("top"), Some((SensorKind::Lidar, 0)));
    assert_eq!(rig.find("front"), Some((SensorKind::Camera, 0)));
    assert_eq!(rig.find("rear"), None);
    let t = rig.lidar_to_camera(0, 0).translation;
    assert_eq!([t.x, t.y, t.z], [0.05, -0.5, -0.3]);
}

#[test]
fn the_example_rig_reads_and_pairs_compose_through_the_first_camera() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rig.toml");
    let rig = roomcal::rig::load(&path).unwrap();
    assert_eq!((rig.cameras.len(), rig.lidars.len()), (2, 2));
    let room = roomcal::room::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/room.toml"))
        .unwrap();
    // The bumper LiDAR seen from the wide camera: wide⁻¹ ∘ bumper, written as the pair room's [lidar].
    let pair = rig.pair_room(&room, 1, Some(1));
    assert_eq!(pair.camera.fx, Some(960.0));
    let lidar = pair.lidar.clone().unwrap();
    let expected = rig.cameras[1].to_reference.inverse().compose(&rig.lidars[1].to_reference);
    for i in 0..3 {
        assert!((lidar.translation[i] - expected.translation[i]).abs() < 1e-12);
    }
    pair.validate().unwrap();
}

#[test]
fn a_room_is_the_one_pair_rig() {
    let room = roomcal::room::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/room.toml"))
        .unwrap();
    let rig = Rig::from_room(&room);
    assert_eq!(rig.cameras[0].name.as_str(), "camera");
    assert_eq!(rig.lidars[0].name.as_str(), "lidar");
    assert_eq!(rig.pair_room(&room, 0, Some(0)), room);
}

#[test]
fn a_cameras_region_is_its_pair_rooms_and_the_rooms_otherwise() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rig.toml");
    let rig = roomcal::rig::load(&path).unwrap();
    let room_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/room.toml");
    let room = roomcal::room::load(&room_path).unwrap();
    let (front, wide) = (rig.find("front").unwrap().1, rig.find("wide").unwrap().1);
    assert_eq!(rig.cameras[wide].region, Some([0.15, 0.15, 0.85, 0.85]));
    assert_eq!(rig.pair_room(&room, wide, None).quality.region, [0.15, 0.15, 0.85, 0.85]);
    assert_eq!(rig.cameras[front].region, None);
    assert_eq!(rig.pair_room(&room, front, None).quality.region, room.quality.region);
}

#[test]
fn every_refusal_names_the_file_the_sensor_and_the_key() {
    let cases: &[(&str, &str, &[&str])] = &[
        ("name = \"front\"", "name = \"Front\"", &["rig.toml", "camera 1", "`name`", "Front"]),
        ("name = \"top\"", "name = \"front\"", &["rig.toml", "lidar `front`", "unique"]),
        ("width = 1920", "width = 10", &["rig.toml", "camera `front`", "camera.width"]),
        (
            "translation = [0.05, -0.5, -0.3]",
            "translation = [0.05, -0.5]",
            &["lidar `top`", "`translation`", "3 numbers"],
        ),
        ("translation = [0.05, -0.5, -0.3]", "", &["lidar `top`", "`translation` is missing"]),
        (
            "[0.0, 0.0, -1.0], [1.0",
            "[0.0, 0.0, -1.0], [2.0",
            &["lidar `top`", "`rotation`", "orthonormal"],
        ),
        (
            "translation = [0.05, -0.5, -0.3]",
            "translation = [0.05, nan, -0.3]",
            &["lidar `top`", "`translation[1]`"],
        ),
        ("model = \"pandar64\"", "model = \"pandar65\"", &["rig.toml", "pandar65"]),
        (
            "height = 1200",
            "height = 1200\nrotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
            &["camera `front`", "`rotation`", "reference"],
        ),
        ("height = 1200", "height = 1200\nlens = 3", &["rig.toml", "lens"]),
        (
            "height = 1200",
            "height = 1200\nregion = [0.6, 0.0, 0.4, 1.0]",
            &["rig.toml", "camera `front`", "`region`", "empty"],
        ),
        (
            "height = 1200",
            "height = 1200\nregion = [0.0, -0.1, 1.0, 1.0]",
            &["camera `front`", "`region[1]` = -0.1"],
        ),
    ];
    for (from, to, needles) in cases {
        assert!(DESIGN_EXAMPLE.contains(from), "{from}");
        let message = error_of(&DESIGN_EXAMPLE.replacen(from, to, 1));
        for needle in *needles {
            assert!(message.contains(needle), "`{needle}` not in: {message}");
        }
    }
    let no_camera = DESIGN_EXAMPLE.split("[[lidar]]").nth(1).unwrap();
    assert!(error_of(&format!("[[lidar]]{no_camera}")).contains("at least one camera"));
    assert!(roomcal::rig::load(Path::new("/nonexistent/rig.toml"))
        .unwrap_err()
        .to_string()
        .contains("/nonexistent/rig.toml"));
}
