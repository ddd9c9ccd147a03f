//! Hostile input to the command line (the input limits, docs/limits.md): every case a new user
//! found is run over the binary and must end with exit code 2 and a message naming the
//! file, the key or field, and the problem — never a panic (101), an abort (134), a run to
//! the quality gate (3) or a silent success (0).
//!
//! The inputs are the design's room (`config/room.toml`) and the `six-boards-pandar64`
//! fixture (made by `roomcal simulate`), altered in a temporary folder.

use crate::common::png::png_claiming;
use crate::common::{fixture, roomcal};
use std::ffi::OsStr;
use std::path::{Path, PathBuf};

const ROOM: &str = include_str!("../../config/room.toml");
const ROOM_PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml");

/// A fresh folder for one test's files.
fn scratch(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("hostile_cli").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs roomcal; returns its exit code and stderr. A panic or an abort fails the test here.
fn roomcal_no_crash(args: &[&OsStr]) -> (i32, String) {
    let (code, _, stderr) = roomcal(args);
    assert!(
        !matches!(code, 101 | 134 | -1) && !stderr.contains("panicked"),
        "roomcal {args:?} crashed (exit {code}):\n{stderr}"
    );
    (code, stderr)
}

/// Asserts exit code 2 and that stderr holds every one of `words`.
fn assert_refused(what: &str, (code, stderr): (i32, String), words: &[&str]) {
    assert_eq!(code, 2, "{what}: exit {code}, expected 2 (bad input):\n{stderr}");
    for w in words {
        assert!(stderr.contains(w), "{what}: `{w}` missing from:\n{stderr}");
    }
}

/// `roomcal detect` on the image `image` in the example room, its output in `dir`.
fn detect_image(dir: &Path, image: &Path) -> (i32, String) {
    roomcal_no_crash(&[
        "detect".as_ref(),
        "--room".as_ref(),
        ROOM_PATH.as_ref(),
        "--image".as_ref(),
        image.as_ref(),
        "--out".as_ref(),
        dir.join("o.json").as_ref(),
    ])
}

/// `roomcal detect` on the fixture's image and cloud with the room file `room`.
fn detect_with_room(dir: &Path, room: &str) -> (i32, String) {
    let path = dir.join("room.toml");
    std::fs::write(&path, room).unwrap();
    let (image, cloud, out) = (
        fixture("six-boards-pandar64/image.png"),
        fixture("six-boards-pandar64/cloud.pcd"),
        dir.join("out.json"),
    );
    roomcal_no_crash(&[
        "detect".as_ref(),
        "--room".as_ref(),
        path.as_ref(),
        "--image".as_ref(),
        image.as_ref(),
        "--cloud".as_ref(),
        cloud.as_ref(),
        "--out".as_ref(),
        out.as_ref(),
    ])
}

#[test]
fn room_numbers_out_of_range_are_refused_with_their_key() {
    let dir = scratch("room");
    let holes = "holes = [[-0.45, -0.35], [0.45, -0.35], [-0.45, 0.35], [0.45, 0.35]]";
    let rotation = "rotation = [[0.0, -1.0, 0.0]";
    let translation = "translation = [0.05, 0.42, -0.28]";
    let camera = "width = 1920\nheight = 1200";
    let cases: &[(&str, &str, &[&str])] = &[
        ("width = 1.2", "width = 1e308", &["board.width", "1e308", "at most 5 m"]),
        ("width = 1.2", "width = 1e6", &["board.width", "1e6"]),
        ("width = 1.2", "width = 1e4", &["board.width", "10000"]),
        ("width = 1.2", "width = 1000.0", &["board.width", "1000"]),
        ("width = 1.2", "width = nan", &["board.width", "NaN"]),
        ("square = 0.08", "square = 1e-300", &["board.square", "0.005"]),
        ("inner_corners = [7, 5]", "inner_corners = [7, 5, 3]", &["inner_corners", "exactly 2"]),
        (holes, "holes = [[-0.45, -0.35, 0.1]]", &["holes", "exactly 2"]),
        (holes, "holes = [[nan, -0.35]]", &["board.holes[0][0]", "NaN"]),
        ("hole_radius = 0.08", "hole_radius = inf", &["board.hole_radius", "inf"]),
        (camera, "width = 1920\nheight = 1200\ncx = nan", &["camera.cx", "NaN", "[0, 1920] px"]),
        (camera, "width = 1920\nheight = 1200\ncx = 1e308", &["camera.cx"]),
        (camera, "width = 1920\nheight = 1200\ncx = -1e308", &["camera.cx"]),
        (camera, "width = 1920\nheight = 1200\nfx = 1e308", &["camera.fx", "px"]),
        (camera, "width = 1920\nheight = 1200\nfy = 0.0", &["camera.fy"]),
        (
            camera,
            "width = 1920\nheight = 1200\ndistortion = [nan, 0.0, 0.0, 0.0, 0.0]",
            &["camera.distortion[0]", "NaN"],
        ),
        (camera, "width = 100000\nheight = 1200", &["camera.width", "100000", "16384"]),
        (camera, "width = 16000\nheight = 16000", &["camera.width", "pixels"]),
        (rotation, "rotation = [[nan, -1.0, 0.0]", &["lidar.rotation[0][0]", "NaN"]),
        (translation, "translation = [nan, 0.42, -0.28]", &["lidar.translation[0]", "NaN"]),
        (translation, "translation = [inf, 0.42, -0.28]", &["lidar.translation[0]", "inf"]),
        (
            translation,
            "translation = [1e308, 0.42, -0.28]",
            &["lidar.translation[0]", "[-10, 10] m"],
        ),
        (translation, "translation = [0.05, 0.42]", &["translation", "exactly 3"]),
    ];
    for &(from, to, words) in cases {
        assert!(ROOM.contains(from), "{from}");
        let outcome = detect_with_room(&dir, &ROOM.replacen(from, to, 1));
        assert_refused(to, outcome, &[&["room.toml"], words].concat());
    }
    for (key, value) in [
        ("max_corner_rms_px", "nan"),
        ("max_corner_rms_px", "-1.0"),
        ("max_hole_rms_px", "inf"),
        ("min_coverage", "1.5"),
        ("max_change_focal_rel", "0.0"),
        ("max_sigma_rotation_deg", "-1.0"),
    ] {
        let room = format!("{ROOM}\n[quality]\n{key} = {value}\n");
        let outcome = detect_with_room(&dir, &room);
        assert_refused(
            &format!("{key} = {value}"),
            outcome,
            &["room.toml", &format!("quality.{key}")],
        );
    }
}

/// The fixture's frame as JPEG bytes.
fn fixture_jpeg() -> Vec<u8> {
    let grey = image::open(fixture("six-boards-pandar64/image.png")).unwrap().into_luma8();
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 90).encode_image(&grey).unwrap();
    bytes
}

#[test]
fn truncated_images_are_refused_as_truncated() {
    let dir = scratch("truncated");
    let png = std::fs::read(fixture("six-boards-pandar64/image.png")).unwrap();
    let jpeg = fixture_jpeg();
    for (name, bytes) in [("half.png", &png), ("half.jpg", &jpeg), ("cut.jpg", &jpeg)] {
        let cut = if name == "cut.jpg" { bytes.len() - 2 } else { bytes.len() / 2 };
        let path = dir.join(name);
        std::fs::write(&path, &bytes[..cut]).unwrap();
        let outcome = detect_image(&dir, &path);
        assert_refused(name, outcome, &[name, "truncated"]);
    }
    // The whole JPEG still decodes (the end marker is found).
    let whole = dir.join("whole.jpg");
    std::fs::write(&whole, &jpeg).unwrap();
    let (code, stderr) = detect_image(&dir, &whole);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn huge_png_is_refused_from_its_header() {
    let dir = scratch("huge_png");
    let path = dir.join("huge.png");
    std::fs::write(&path, png_claiming(20000, 20000)).unwrap();
    let outcome = detect_image(&dir, &path);
    assert_refused("20000² PNG", outcome, &["huge.png", "20000x20000"]);
}

/// A binary PCD with fields x y z (F4) and `points` records from `xyz`.
fn pcd_binary(header_extra: &str, points: usize, xyz: &[[f32; 3]]) -> Vec<u8> {
    let mut bytes = format!(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n{header_extra}POINTS {points}\nDATA binary\n"
    )
    .into_bytes();
    for p in xyz {
        for v in p {
            bytes.extend(v.to_le_bytes());
        }
    }
    bytes
}

/// `roomcal detect` on the fixture's room and image with the cloud file `name` = `bytes`.
fn detect_with_cloud(dir: &Path, name: &str, bytes: &[u8]) -> (i32, String) {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    roomcal_no_crash(&[
        "detect".as_ref(),
        "--room".as_ref(),
        ROOM_PATH.as_ref(),
        "--cloud".as_ref(),
        path.as_ref(),
        "--out".as_ref(),
        dir.join("o.json").as_ref(),
    ])
}

#[test]
fn clouds_without_usable_points_or_with_lying_headers_are_refused() {
    let dir = scratch("clouds");
    let nan = [f32::NAN, 1.0, 2.0];
    let inf = [f32::INFINITY, 1.0, 2.0];
    let cases: Vec<(&str, Vec<u8>, &[&str])> = vec![
        (
            "nan.pcd",
            pcd_binary("WIDTH 3\nHEIGHT 1\n", 3, &[nan, inf, [0.0; 3]]),
            &["no usable point"],
        ),
        ("empty.pcd", pcd_binary("WIDTH 0\nHEIGHT 1\n", 0, &[]), &["no usable point"]),
        (
            "width.pcd",
            pcd_binary("WIDTH 5\nHEIGHT 1\n", 2, &[[1.0; 3], [2.0; 3]]),
            &["POINTS 2", "WIDTH"],
        ),
        (
            "garbage.pcap",
            b"this is not a capture, just text".to_vec(),
            &["not a pcap or pcapng capture"],
        ),
        ("short.pcap", b"ab".to_vec(), &["truncated"]),
    ];
    for (name, bytes, words) in cases {
        assert_refused(name, detect_with_cloud(&dir, name, &bytes), &[&[name][..], words].concat());
    }
    // binary_compressed whose header claims 0xFFFFFFFF uncompressed bytes.
    let mut full = Vec::new();
    let points: Vec<roomcal::lidar::Point> = (0..1000)
        .map(|i| roomcal::lidar::Point { x: 1.0 + i as f32, y: 2.0, z: 3.0, ..Default::default() })
        .collect();
    roomcal::lidar::pcd::encode(
        &points,
        roomcal::lidar::pcd::PcdFormat::BinaryCompressed,
        &mut full,
    );
    let head = full.windows(18).position(|w| w == b"binary_compressed\n").unwrap() + 18;
    full[head + 4..head + 8].copy_from_slice(&u32::MAX.to_le_bytes());
    let outcome = detect_with_cloud(&dir, "lying.pcd", &full);
    assert_refused("lying.pcd", outcome, &["lying.pcd", "uncompressed size 4294967295"]);
}

#[test]
fn a_capture_is_told_by_its_bytes_not_its_name() {
    let dir = scratch("sniff");
    let capture = std::fs::read(fixture("six-boards-pandar64/cloud.pcap")).unwrap();
    let (code, stderr) = detect_with_cloud(&dir, "capture.pcd", &capture);
    assert_eq!(code, 0, "a pcap named .pcd is decoded as a capture:\n{stderr}");
    let pcd = std::fs::read(fixture("six-boards-pandar64/cloud.pcd")).unwrap();
    let (code, stderr) = detect_with_cloud(&dir, "cloud.pcap", &pcd);
    assert_refused(
        "PCD named .pcap",
        (code, stderr),
        &["cloud.pcap", "not a pcap or pcapng capture"],
    );
}

/// A result file of the fixture's camera with `camera` fields and `rotation` replaced.
fn result_json(fx: &str, rotation: &str) -> String {
    format!(
        r#"{{"status": "accepted",
  "camera": {{"model": "pinhole-radtan", "width": 1920, "height": 1200,
             "fx": {fx}, "fy": 1370.0, "cx": 960.0, "cy": 600.0, "distortion": [-0.18, 0.0, 0.0, 0.0, 0.0]}},
  "lidar_to_camera": {{"rotation": {rotation}, "translation": [0.05, 0.42, -0.28]}},
  "uncertainty": {{"fx": 0.0, "fy": 0.0, "cx": 0.0, "cy": 0.0, "rotation_deg": 0.0, "translation_m": 0.0}},
  "quality": {{"corner_rms_px": 0.0, "hole_rms_px": 0.0, "boards": 6}},
  "boards": []}}"#
    )
}

const ROTATION: &str = "[[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]";

#[test]
fn overlay_and_current_refuse_a_calibration_that_cannot_be() {
    let dir = scratch("overlay");
    let (image, cloud, out) = (
        fixture("six-boards-pandar64/image.png"),
        fixture("six-boards-pandar64/cloud.pcd"),
        dir.join("o.png"),
    );
    let cases: &[(&str, &str, &[&str])] = &[
        ("0.0", ROTATION, &["camera.fx", "= 0"]),
        ("-5.0", ROTATION, &["camera.fx", "-5"]),
        ("1e308", ROTATION, &["camera.fx", "1e308"]),
        (
            "1370.0",
            "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]",
            &["lidar_to_camera.rotation", "orthonormal"],
        ),
        ("1370.0", "[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]", &["not a calibration result"]),
        ("NaN", ROTATION, &["not a calibration result"]),
    ];
    for &(fx, rotation, words) in cases {
        let calibration = dir.join("result.json");
        std::fs::write(&calibration, result_json(fx, rotation)).unwrap();
        let outcome = roomcal_no_crash(&[
            "overlay".as_ref(),
            "--calibration".as_ref(),
            calibration.as_ref(),
            "--image".as_ref(),
            image.as_ref(),
            "--cloud".as_ref(),
            cloud.as_ref(),
            "--out".as_ref(),
            out.as_ref(),
        ]);
        assert_refused(&format!("overlay fx {fx}"), outcome, &[&["result.json"], words].concat());
    }
    // The same loader guards `calibrate --current`: refused before any image is read.
    let current = dir.join("current.json");
    std::fs::write(&current, result_json("-5.0", ROTATION)).unwrap();
    let outcome = roomcal_no_crash(&[
        "calibrate".as_ref(),
        "--room".as_ref(),
        ROOM_PATH.as_ref(),
        "--image".as_ref(),
        image.as_ref(),
        "--current".as_ref(),
        current.as_ref(),
        "--out".as_ref(),
        dir.join("r.json").as_ref(),
    ]);
    assert_refused("calibrate --current fx -5", outcome, &["current.json", "camera.fx"]);
    // A valid calibration draws.
    let calibration = dir.join("good.json");
    std::fs::write(&calibration, result_json("1370.0", ROTATION)).unwrap();
    let (code, stderr) = roomcal_no_crash(&[
        "overlay".as_ref(),
        "--calibration".as_ref(),
        calibration.as_ref(),
        "--image".as_ref(),
        image.as_ref(),
        "--cloud".as_ref(),
        cloud.as_ref(),
        "--out".as_ref(),
        out.as_ref(),
    ]);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn a_jpeg_whose_header_claims_more_than_its_data_holds_is_refused_as_truncated() {
    let dir = scratch("jpeg-header-lie");
    // A whole 16×16 JPEG (end marker and all) whose frame header is rewritten to 1920×1200.
    let grey = image::GrayImage::from_fn(16, 16, |x, y| image::Luma([(x * 16 + y) as u8]));
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90).encode_image(&grey).unwrap();
    let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC0]).expect("a baseline frame header");
    jpeg[sof + 5..sof + 7].copy_from_slice(&1200u16.to_be_bytes());
    jpeg[sof + 7..sof + 9].copy_from_slice(&1920u16.to_be_bytes());
    let path = dir.join("lying.jpg");
    std::fs::write(&path, &jpeg).unwrap();
    let outcome = detect_image(&dir, &path);
    assert_refused(
        "lying.jpg",
        outcome,
        &["lying.jpg", "truncated", "1920x1200", "bytes of image data"],
    );
}

#[test]
fn lists_beyond_their_capacity_name_the_list_and_its_maximum() {
    let dir = scratch("capacity");
    let holes = "holes = [[-0.45, -0.35], [0.45, -0.35], [-0.45, 0.35], [0.45, 0.35]]";
    let nine = format!("holes = [{}]", ["[0.1, 0.1]"; 9].join(", "));
    let outcome = detect_with_room(&dir, &ROOM.replacen(holes, &nine, 1));
    assert_refused("9 holes", outcome, &["room.toml", "9 holes", "more than the 8"]);
    let six = "height = 1200\ndistortion = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]";
    let outcome = detect_with_room(&dir, &ROOM.replacen("height = 1200", six, 1));
    assert_refused("6 coefficients", outcome, &["6 distortion coefficients", "more than the 5"]);

    let lidar = |i: usize| format!("[[lidar]]\nname = \"l{i}\"\nmodel = \"pandar64\"\n");
    let camera = |i: usize| {
        format!("[[camera]]\nname = \"c{i}\"\nmodel = \"pinhole-radtan\"\nwidth = 1920\nheight = 1200\n")
    };
    let rig_cases = [
        (camera(0) + &(0..9).map(lidar).collect::<String>(), "9 LiDARs", "more than the 8"),
        ((0..500).map(camera).collect::<String>(), "500 cameras", "more than the 8"),
    ];
    for (text, count, maximum) in rig_cases {
        let message = roomcal::rig::parse(&text, Path::new("rig.toml")).unwrap_err().to_string();
        for word in ["rig.toml", count, maximum] {
            assert!(message.contains(word), "`{word}` missing from: {message}");
        }
        assert!(message.len() < 1000, "{} bytes: {message}", message.len());
    }
}
