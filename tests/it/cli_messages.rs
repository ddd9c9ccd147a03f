//! What a person reads from the command line: the binary run on the fixtures (calibrate,
//! its `--quiet` and `--json` forms, detect, a rejected run, bad input and `--help`), its
//! stdout and stderr checked for Rust's debug dumps (`{`, `Some(`, `[[`) and for the
//! summary's promised lines.

use std::path::Path;

use crate::common::scratch::Scratch;
use crate::common::{fixture, roomcal, root};

/// Fails on any sign of `Debug` formatting of an internal type.
fn assert_plain(what: &str, text: &str) {
    for mark in ["{", "Some(", "[["] {
        assert!(!text.contains(mark), "{what}: `{mark}` in the output:\n{text}");
    }
}

fn calibrate_six(dir: &Path, extra: &[&str]) -> (i32, String, String) {
    let out = dir.join("result.json");
    let mut args = vec![
        "calibrate".to_string(),
        "--room".into(),
        fixture("six-boards-pandar64/room.toml").to_string_lossy().into_owned(),
        "--image".into(),
        fixture("six-boards-pandar64/image.png").to_string_lossy().into_owned(),
        "--cloud".into(),
        fixture("six-boards-pandar64/cloud.pcd").to_string_lossy().into_owned(),
        "--out".into(),
        out.to_string_lossy().into_owned(),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    roomcal(&args.iter().map(String::as_str).collect::<Vec<_>>())
}

#[test]
fn calibrate_summary_is_plain_sentences_with_rpy_and_one_line_per_board() {
    let dir = Scratch::new("cli-summary");
    let (code, stdout, stderr) = calibrate_six(&dir, &[]);
    println!("{stdout}{stderr}");
    assert_eq!(code, 0);
    assert_plain("calibrate", &(stdout.clone() + &stderr));
    assert!(stdout.starts_with("roomcal calibrate: accepted ("), "{stdout}");
    assert!(stdout.contains("roll ") && stdout.contains("pitch ") && stdout.contains("yaw "));
    assert!(stdout.contains("vs nominal"), "{stdout}");
    let boards = stdout.lines().filter(|l| l.trim_start().starts_with("board ")).count();
    assert_eq!(boards, 6, "{stdout}");
    // The fixture's LiDAR refuses some board-sized planes: each refusal is one sentence
    // saying where the plane is, why, and what to do; at most three per piece of advice,
    // the rest summed up in a line.
    let mut per_advice = std::collections::BTreeMap::<&str, usize>::new();
    for line in stderr.lines() {
        if line.contains("more plane(s) refused likewise, not listed (if it is a board, ") {
            continue;
        }
        assert!(line.contains("cloud.pcd: plane of ") && line.contains(" m away ("), "{line}");
        assert!(line.contains("not used as a board (if it is a board, "), "{line}");
        *per_advice.entry(line.rsplit_once(" (if it is a board, ").unwrap().1).or_default() += 1;
    }
    assert!(per_advice.values().all(|&n| n <= 3), "{stderr}");
}

#[test]
fn quiet_prints_the_status_line_and_json_the_result_file() {
    let dir = Scratch::new("cli-quiet-json");
    let (code, stdout, stderr) = calibrate_six(&dir, &["--quiet"]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.starts_with("roomcal calibrate: accepted"), "{stdout}");
    assert!(stderr.is_empty(), "{stderr}");

    let (code, stdout, _) = calibrate_six(&dir, &["--json"]);
    assert_eq!(code, 0);
    let printed: serde_json::Value = serde_json::from_str(&stdout).expect("stdout is JSON");
    let file: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("result.json")).unwrap()).unwrap();
    assert_eq!(printed, file);
}

#[test]
fn rejected_run_keeps_exit_code_3_and_says_why_in_one_plain_line() {
    // Six boards needed, the four-board fixture's room asks for them all: at count 7 the
    // gate must reject (the room file is the fixture's with a larger count).
    let dir = Scratch::new("cli-rejected");
    let room = std::fs::read_to_string(fixture("four-boards-vlp32c-rejected/room.toml")).unwrap();
    let room = room.replace("count = 4", "count = 7");
    assert!(room.contains("count = 7"), "the fixture room changed: {room}");
    let room_path = dir.join("room.toml");
    std::fs::write(&room_path, room).unwrap();
    let out = dir.join("result.json");
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        room_path.to_str().unwrap(),
        "--image",
        fixture("four-boards-vlp32c-rejected/image.png").to_str().unwrap(),
        "--cloud",
        fixture("four-boards-vlp32c-rejected/cloud.pcd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(code, 3, "{stdout}{stderr}");
    assert_plain("rejected", &(stdout.clone() + &stderr));
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.starts_with("roomcal calibrate: rejected: frame 0: "), "{stdout}");
}

#[test]
fn a_run_stopped_before_its_solve_prints_no_placeholder_as_a_result() {
    // The six-board room's image with another room's sweep: no LiDAR board pairs with a
    // camera board, so nothing is solved. The summary must not print the result file's
    // placeholder extrinsic as a LiDAR found far from its mounting.
    let dir = Scratch::new("cli-unsolved");
    let out = dir.join("result.json");
    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        fixture("six-boards-pandar64/room.toml").to_str().unwrap(),
        "--image",
        fixture("six-boards-pandar64/image.png").to_str().unwrap(),
        "--cloud",
        fixture("four-boards-vlp32c-rejected/cloud.pcd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 3, "{stdout}{stderr}");
    assert_plain("unsolved", &(stdout.clone() + &stderr));
    assert!(stdout.starts_with("roomcal calibrate: rejected: "), "{stdout}");
    assert!(stdout.contains("  solved      nothing: the run stopped before the solve"), "{stdout}");
    for placeholder in ["vs nominal", "  camera      ", "  distortion  "] {
        assert!(!stdout.contains(placeholder), "`{placeholder}` printed:\n{stdout}");
    }
    assert!(stdout.contains("  written     "), "{stdout}");
    assert!(out.exists(), "the rejected run's result file is still written");
}

#[test]
fn detect_and_bad_input_messages_are_plain() {
    let dir = Scratch::new("cli-detect");
    let out = dir.join("detections.json");
    let (code, stdout, stderr) = roomcal(&[
        "detect",
        "--room",
        fixture("six-boards-pandar64/room.toml").to_str().unwrap(),
        "--image",
        fixture("six-boards-pandar64/image.png").to_str().unwrap(),
        "--cloud",
        fixture("six-boards-pandar64/cloud.pcd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert_plain("detect", &(stdout + &stderr));

    let (code, stdout, stderr) = roomcal(&[
        "calibrate",
        "--room",
        fixture("six-boards-pandar64/room.toml").to_str().unwrap(),
        "--image",
        "/nonexistent/frame.png",
    ]);
    assert_eq!(code, 2);
    assert_plain("bad input", &(stdout + &stderr));
    assert!(stderr.contains("/nonexistent/frame.png"), "{stderr}");
}

#[test]
fn every_help_says_what_it_is_for_with_an_example() {
    let (code, top, _) = roomcal(&["--help"]);
    assert_eq!(code, 0);
    assert!(top.contains("Example: roomcal calibrate "), "{top}");
    for sub in ["calibrate", "detect", "overlay", "simulate", "survey", "daemon", "decode", "query"]
    {
        let (code, help, stderr) = roomcal(&[sub, "--help"]);
        assert_eq!(code, 0, "{sub}: {stderr}");
        let purpose = help.lines().next().unwrap_or_default();
        assert!(purpose.split(' ').count() >= 5, "{sub}: first line {purpose:?}");
        assert!(help.contains(&format!("Example: roomcal {sub} ")), "{sub}:\n{help}");
    }
}

#[test]
fn report_picture_carries_the_frame_and_a_footer_with_status_legend_and_range_bar() {
    let dir = Scratch::new("cli-report");
    let report = dir.join("report.png");
    let (code, stdout, stderr) =
        calibrate_six(&dir, &["--quiet", "--report", report.to_str().unwrap()]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    let picture = image::open(&report).unwrap().to_rgb8();
    let frame = roomcal::detect::load_grey(fixture("six-boards-pandar64/image.png")).unwrap();
    assert_eq!(picture.width(), frame.width);
    assert!(picture.height() > frame.height + 60, "no footer: {}", picture.height());
    let footer: Vec<[u8; 3]> = (frame.height..picture.height())
        .flat_map(|y| (0..picture.width()).map(move |x| (x, y)))
        .map(|(x, y)| picture.get_pixel(x, y).0)
        .collect();
    let count = |colour: [u8; 3]| footer.iter().filter(|p| **p == colour).count();
    // The status in its verdict's green, the refused planes' lines in orange, the legend's
    // corner mark in the corners' white and the range bar's near end in red.
    assert!(count([90, 255, 90]) > 100, "no ACCEPTED text in the footer");
    assert!(count([255, 160, 0]) > 100, "no refused-plane lines in the footer");
    assert!(count(roomcal::report::CORNER.0) > 20, "no corner legend");
    let near_red = footer.iter().filter(|p| p[0] == 255 && p[1] < 60 && p[2] == 0).count();
    assert!(near_red > 50, "no range bar");
}

/// A ring of boards needs the lens the room's own are laid out for, at most ten boards, and
/// vehicles to lay it out around: each refusal is exit 2 naming what is wrong.
#[test]
fn simulate_refuses_a_ring_it_cannot_lay_out() {
    let dir = Scratch::new("cli-ring");
    let out = dir.to_str().unwrap();
    let room = root().join("config/wide-room.toml");
    let room = room.to_str().unwrap();
    let cases: [(&[&str], &str); 3] = [
        (&["--ring-boards", "4"], "--inner-fov"),
        (&["--ring-boards", "11", "--inner-fov", "60"], "11 is not in 1..=10"),
        (&["--ring-boards", "4", "--inner-fov", "60"], "give --visits or --rig"),
    ];
    for (extra, says) in cases {
        let mut args = vec!["simulate", "--room", room, "--out", out];
        args.extend_from_slice(extra);
        let (code, stdout, stderr) = roomcal(&args);
        assert_eq!(code, 2, "{extra:?}: {stdout}{stderr}");
        assert!(stderr.contains(says), "{extra:?}: {stderr}");
    }
}
