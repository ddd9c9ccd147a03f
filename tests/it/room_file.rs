//! Room files: the design's example parses; every kind of mistake gets an error that
//! names the file, the key and the problem.

use std::path::Path;

use roomcal::room::{parse, RoomFileError};

const GOOD: &str = include_str!("../../config/room.toml");

fn error_of(text: &str) -> String {
    match parse(text, Path::new("bad-room.toml")) {
        Ok(_) => panic!("accepted a bad room file:\n{text}"),
        Err(e) => {
            let message = e.to_string();
            assert!(
                message.contains("bad-room.toml"),
                "the message does not name the file: {message}"
            );
            message
        }
    }
}

fn assert_mentions(message: &str, words: &[&str]) {
    for w in words {
        assert!(message.contains(w), "`{w}` missing from: {message}");
    }
}

#[test]
fn the_design_example_parses() {
    let room = parse(GOOD, Path::new("room.toml")).expect("the example room is valid");
    assert_eq!(room.board.inner_corners, [7, 5]);
    assert_eq!(room.board.holes.len(), 4);
    assert_eq!(room.board.count, 6);
    assert!(!room.intrinsics_only());
    // Corner 0 is top-left, corner 7 starts the second row.
    let (c0, c1, c7) = (room.board.corner(0), room.board.corner(1), room.board.corner(7));
    assert!((c0.x + 0.24).abs() < 1e-12 && (c0.y + 0.16).abs() < 1e-12);
    assert!((c1.x - c0.x - 0.08).abs() < 1e-12 && (c7.y - c0.y - 0.08).abs() < 1e-12);
}

#[test]
fn intrinsics_only_room_parses() {
    let text = GOOD.replace(
        "holes = [[-0.45, -0.35], [0.45, -0.35], [-0.45, 0.35], [0.45, 0.35]]",
        "holes = []",
    );
    let text = text.split("[lidar]").next().unwrap();
    let room = parse(text, Path::new("room.toml")).expect("intrinsics-only room");
    assert!(room.intrinsics_only());
}

#[test]
fn unknown_key() {
    let m = error_of(&GOOD.replace("count = 6", "count = 6\ncolour = \"red\""));
    assert_mentions(&m, &["unknown field", "colour"]);
}

#[test]
fn missing_field() {
    let m = error_of(&GOOD.replace("square = 0.08", ""));
    assert_mentions(&m, &["missing field", "square"]);
}

#[test]
fn wrong_type() {
    let m = error_of(&GOOD.replace("count = 6", "count = \"six\""));
    assert_mentions(&m, &["count"]);
}

#[test]
fn too_few_inner_corners() {
    let m = error_of(&GOOD.replace("inner_corners = [7, 5]", "inner_corners = [7, 1]"));
    assert_mentions(&m, &["board.inner_corners", "at least 2"]);
}

#[test]
fn hole_overlapping_the_checkerboard() {
    let m =
        error_of(&GOOD.replace("[-0.45, -0.35], [0.45, -0.35]", "[-0.30, -0.20], [0.45, -0.35]"));
    assert_mentions(&m, &["board.holes[0]", "overlaps the checkerboard"]);
}

#[test]
fn hole_outside_the_board() {
    let m = error_of(&GOOD.replace("[-0.45, 0.35], [0.45, 0.35]", "[-0.45, 0.35], [0.55, 0.35]"));
    assert_mentions(&m, &["board.holes[3]", "outside the board"]);
}

#[test]
fn rotation_not_orthonormal() {
    let m = error_of(&GOOD.replace("[0.0, 0.0, -1.0], [1.0", "[0.0, 0.0, -1.0], [1.001"));
    assert_mentions(&m, &["lidar.rotation", "orthonormal"]);
}

#[test]
fn reflection_is_not_a_rotation() {
    let m = error_of(&GOOD.replace("[[0.0, -1.0, 0.0]", "[[0.0, 1.0, 0.0]"));
    assert_mentions(&m, &["lidar.rotation", "orthonormal"]);
}

#[test]
fn rotation_within_tolerance_is_accepted() {
    let text = GOOD.replace("[0.0, 0.0, -1.0], [1.0", "[0.0, 0.0, -1.0], [1.0000000004");
    parse(&text, Path::new("room.toml")).expect("1e-9 off is within tolerance");
}

#[test]
fn non_positive_sizes() {
    for (from, to, key) in [
        ("width = 1.2", "width = 0.0", "board.width"),
        ("height = 1.0", "height = -1.0", "board.height"),
        ("square = 0.08", "square = 0", "board.square"),
        ("hole_radius = 0.08", "hole_radius = -0.08", "board.hole_radius"),
        ("count = 6", "count = 0", "board.count"),
        ("width = 1920", "width = 0", "camera.width"),
    ] {
        let m = error_of(&GOOD.replacen(from, to, 1));
        assert_mentions(&m, &[key, "must be"]);
    }
}

#[test]
fn checkerboard_larger_than_board() {
    let m = error_of(&GOOD.replace("square = 0.08", "square = 0.2"));
    assert_mentions(&m, &["checkerboard", "does not fit"]);
}

#[test]
fn unreadable_file_names_it() {
    let e = roomcal::room::load(Path::new("/nonexistent/room.toml")).unwrap_err();
    assert!(matches!(e, RoomFileError::Read { .. }));
    assert!(e.to_string().contains("/nonexistent/room.toml"));
}

#[test]
fn room_round_trips_through_toml() {
    let room = parse(GOOD, Path::new("room.toml")).unwrap();
    let again = parse(&roomcal::room::to_toml(&room), Path::new("again.toml")).unwrap();
    assert_eq!(room, again);
}

#[test]
fn arrays_must_have_exactly_their_length() {
    for (from, to, key) in [
        ("inner_corners = [7, 5]", "inner_corners = [7, 5, 3]", "inner_corners"),
        ("inner_corners = [7, 5]", "inner_corners = [7]", "inner_corners"),
        ("[-0.45, -0.35], [0.45, -0.35]", "[-0.45, -0.35, 0.0], [0.45, -0.35]", "holes"),
        (
            "translation = [0.05, 0.42, -0.28]",
            "translation = [0.05, 0.42, -0.28, 1]",
            "translation",
        ),
        ("[1.0, 0.0, 0.0]]", "[1.0, 0.0, 0.0, 0.0]]", "rotation"),
    ] {
        let m = error_of(&GOOD.replacen(from, to, 1));
        assert_mentions(&m, &[key, "exactly"]);
    }
}

#[test]
fn every_number_is_range_checked_before_use() {
    let camera = "width = 1920\nheight = 1200";
    for (from, to, key) in [
        ("width = 1.2", "width = 1e308", "`board.width` = 1e308: must be positive and at most 5 m"),
        ("square = 0.08", "square = 0.004", "`board.square` = 0.004"),
        ("hole_radius = 0.08", "hole_radius = nan", "`board.hole_radius` = NaN"),
        (
            camera,
            "width = 1920\nheight = 1200\ncx = 1921.0",
            "`camera.cx` = 1921: must be a finite number in [0, 1920] px",
        ),
        (camera, "width = 1920\nheight = 1200\nfx = 50.0", "`camera.fx` = 50"),
        (
            camera,
            "width = 1920\nheight = 1200\ndistortion = [0.0, 0.0, 0.0, 0.0, 1e3]",
            "`camera.distortion[4]`",
        ),
        (camera, "width = 31\nheight = 1200", "`camera.width` = 31"),
        ("translation = [0.05", "translation = [10.5", "`lidar.translation[0]` = 10.5"),
        ("[[0.0, -1.0, 0.0]", "[[0.0, -inf, 0.0]", "`lidar.rotation[0][1]` = -inf"),
    ] {
        let m = error_of(&GOOD.replacen(from, to, 1));
        assert_mentions(&m, &[key]);
    }
    let m = error_of(&format!("{GOOD}\n[quality]\nmin_boards = 17\n"));
    assert_mentions(&m, &["`quality.min_boards` = 17"]);
    for (line, words) in [
        ("region = [0.5, 0.0, 0.4, 1.0]", &["`quality.region`", "is empty", "u0 < u1"][..]),
        ("region = [0.0, 0.0, 1.5, 1.0]", &["`quality.region[2]` = 1.5"][..]),
        ("region = [0.0, 0.0, 1.0]", &["region = [0.0, 0.0, 1.0]", "length 4"][..]),
        ("max_projection_sigma_px = 0.0", &["`quality.max_projection_sigma_px` = 0"][..]),
    ] {
        assert_mentions(&error_of(&format!("{GOOD}\n[quality]\n{line}\n")), words);
    }
    let judged = format!(
        "{GOOD}\n[quality]\nregion = [0.1, 0.0, 0.9, 1.0]\nmax_projection_sigma_px = 2.5\n"
    );
    let room = parse(&judged, Path::new("room.toml")).expect("a region and a map limit");
    assert_eq!(room.quality.region, [0.1, 0.0, 0.9, 1.0]);
    assert_eq!(room.quality.max_projection_sigma_px, Some(2.5));
    // Nominal intrinsics inside the ranges are accepted.
    let nominal = GOOD.replacen(
        camera,
        "width = 1920\nheight = 1200\nfx = 1400.0\nfy = 1400.0\ncx = 960.0\ncy = 600.0",
        1,
    );
    parse(&nominal, Path::new("room.toml")).expect("sane nominal intrinsics");
}
