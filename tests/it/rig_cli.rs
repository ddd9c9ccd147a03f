//! `roomcal simulate|detect|calibrate --rig` over the binary: the example rig
//! (`config/rig.toml`: two cameras, two LiDARs) simulated, detected and calibrated by
//! name; every bad input exits 2 naming it.

use std::path::{Path, PathBuf};

use crate::common::scratch::Scratch;
use crate::common::{roomcal, root};

fn config(file: &str) -> String {
    root().join("config").join(file).to_string_lossy().into_owned()
}

fn calibrate(inputs: &[&str], out: &Path) -> (i32, String, String) {
    calibrate_in(&config("room.toml"), inputs, out)
}

fn calibrate_in(room: &str, inputs: &[&str], out: &Path) -> (i32, String, String) {
    let (room, rig) = (room.to_string(), config("rig.toml"));
    let mut args = vec!["calibrate", "--room", &room, "--rig", &rig];
    args.extend_from_slice(inputs);
    let out = out.to_string_lossy().into_owned();
    args.extend_from_slice(&["--out", &out]);
    roomcal(&args)
}

/// `--image NAME=…` / `--cloud NAME=…` of the example rig's files `simulate --rig` wrote
/// into `dir`.
fn rig_inputs(dir: &Path) -> Vec<String> {
    let sensors = [
        ("--image", "front.png"),
        ("--image", "wide.png"),
        ("--cloud", "top.pcd"),
        ("--cloud", "bumper.pcd"),
    ];
    sensors
        .iter()
        .flat_map(|(flag, file)| {
            let name = file.split('.').next().unwrap_or(file);
            [flag.to_string(), format!("{name}={}", dir.join(file).display())]
        })
        .collect()
}

#[test]
fn bad_rig_inputs_exit_2_naming_them() {
    let dir = Scratch::new("rig-bad");
    let out = dir.join("result.json");
    let all = [
        "--image",
        "front=a.png",
        "--image",
        "wide=b.png",
        "--cloud",
        "top=c.pcd",
        "--cloud",
        "bumper=d.pcd",
    ];
    let cases: &[(&[&str], &[&str])] = &[
        (&["--image", "rear=a.png"], &["unknown sensor `rear`", "front, wide", "top, bumper"]),
        (&["--image", "a.png"], &["--image a.png", "NAME=PATH"]),
        (
            &["--image", "front=a.png", "--cloud", "front=a.pcd"],
            &["`front` is a camera", "--image"],
        ),
        (&["--image", "top=a.png"], &["`top` is a lidar", "--cloud"]),
        (&all[..6], &["lidar `bumper`", "no data", "--cloud bumper=PATH"]),
        (&all[2..], &["camera `front`", "no data"]),
    ];
    for (inputs, needles) in cases {
        let (code, _, stderr) = calibrate(inputs, &out);
        assert_eq!(code, 2, "{inputs:?}: {stderr}");
        for needle in *needles {
            assert!(stderr.contains(needle), "{inputs:?}: `{needle}` not in {stderr}");
        }
    }
    // A rig file with two sensors of one name.
    let twice = dir.join("twice.toml");
    let text =
        std::fs::read_to_string(config("rig.toml")).unwrap().replace("\"bumper\"", "\"top\"");
    std::fs::write(&twice, text).unwrap();
    let (room, twice) = (config("room.toml"), twice.to_string_lossy().into_owned());
    let (code, _, stderr) =
        roomcal(&["calibrate", "--room", &room, "--rig", &twice, "--image", "front=a.png"]);
    assert_eq!(code, 2);
    assert!(
        stderr.contains(&twice) && stderr.contains("lidar `top`") && stderr.contains("unique"),
        "{stderr}"
    );
    // The rig in force (`--current`) must be a rig's result file.
    let not_a_rig = dir.join("pair.json");
    std::fs::write(&not_a_rig, "{\"status\": \"accepted\"}").unwrap();
    let current = not_a_rig.to_string_lossy().into_owned();
    let (code, _, stderr) = calibrate(&[&all[..], &["--current", &current]].concat(), &out);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains(&current) && stderr.contains("not a calibration result"), "{stderr}");
    // A missing file is named.
    let (code, _, stderr) = calibrate(&all, &out);
    assert_eq!(code, 2);
    assert!(stderr.contains("a.png"), "{stderr}");
}

#[test]
fn a_simulated_rig_is_detected_and_calibrated_by_name() {
    let dir = Scratch::new("rig-sim");
    let d = dir.to_string_lossy().into_owned();
    let (room, rig) = (config("room.toml"), config("rig.toml"));
    let (code, stdout, stderr) = roomcal(&[
        "simulate",
        "--room",
        &room,
        "--rig",
        &rig,
        "--out",
        &d,
        "--seed",
        "3",
        "--supersample",
        "1",
    ]);
    assert_eq!(code, 0, "{stderr}");
    println!("{stdout}");
    for file in [
        "front.png",
        "wide.png",
        "top.pcd",
        "bumper.pcd",
        "rig-truth.json",
        "room-truth.json",
        "room.toml",
    ] {
        assert!(dir.join(file).exists(), "{file}");
    }
    let inputs = rig_inputs(&dir);
    let inputs: Vec<&str> = inputs.iter().map(String::as_str).collect();
    let detections = dir.join("detections.json");
    let mut args = vec!["detect", "--room", &room, "--rig", &rig, "--out"];
    let det = detections.to_string_lossy().into_owned();
    args.push(&det);
    args.extend_from_slice(&inputs);
    let (code, _, stderr) = roomcal(&args);
    assert_eq!(code, 0, "{stderr}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&detections).unwrap()).unwrap();
    for name in ["front", "wide", "top", "bumper"] {
        let boards = json["sensors"][name]["boards"].as_array().unwrap();
        println!("detect: {name}: {} boards", boards.len());
        assert!(!boards.is_empty(), "{name} detected no board");
    }
    // The boards are laid out for the 60° camera and cover 25 % of the 90° camera's image:
    // this room's gate asks for 20 % (the default is 35 %).
    let text = std::fs::read_to_string(dir.join("room.toml")).unwrap();
    assert!(text.contains("min_coverage = 0.35"), "{text}");
    let wide_room = dir.join("wide-room.toml");
    std::fs::write(&wide_room, text.replace("min_coverage = 0.35", "min_coverage = 0.2")).unwrap();
    let out = dir.join("result.json");
    let (code, stdout, stderr) = calibrate_in(&wide_room.to_string_lossy(), &inputs, &out);
    println!("{stdout}{stderr}");
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    // One frame with free boards: the gate decides, naming every sensor that fails (the
    // joint solve accepts it: wide→front 2.2 mm, σ 5.1; the composition
    // alone was rejected on σ, wide→front 341 mm off); the result is checked against the
    // truth either way.
    match result["status"].as_str() {
        Some("accepted") => assert_eq!(code, 0, "{stdout}{stderr}"),
        Some("rejected") => {
            assert_eq!(code, 3, "{stdout}{stderr}");
            let reason = result["reason"].as_str().unwrap();
            for (name, sensor) in result["sensors"].as_object().unwrap() {
                let failed = sensor["status"] == "rejected";
                assert_eq!(failed, reason.contains(&format!("`{name}`")), "{name}: {reason}");
            }
        }
        other => panic!("status {other:?}"),
    }
    assert_eq!(result["sensors"].as_object().unwrap().len(), 4);
    assert!(result["camera"]["fx"].is_number() && result["lidar_to_camera"].is_object());
    assert_eq!(result["sensors"]["top"]["lidar"], true);
    assert!(result["sensors"]["wide"]["camera"]["fx"].is_number());
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("rig-truth.json")).unwrap())
            .unwrap();
    assert_extrinsics_within_their_sigma(&result, &truth);
}

/// Every extrinsic of `result` goes to `front` and lies within 3σ of `truth`'s (σ is
/// worst-axis, the error a norm: 3√3σ).
fn assert_extrinsics_within_their_sigma(result: &serde_json::Value, truth: &serde_json::Value) {
    let extrinsics = result["extrinsics"].as_array().unwrap();
    assert_eq!(extrinsics.len(), 3);
    for e in extrinsics {
        let from = e["from"].as_str().unwrap();
        assert_eq!(e["to"], "front");
        let t = &truth["sensors"][from]["to_reference"]["translation"];
        let error: f64 = (0..3)
            .map(|i| (e["translation"][i].as_f64().unwrap() - t[i].as_f64().unwrap()).powi(2))
            .sum::<f64>()
            .sqrt();
        let sigma = e["sigma_translation_m"].as_f64().unwrap();
        println!(
            "{from} → front: translation error {:.2} mm (σ {:.2} mm)",
            error * 1000.0,
            sigma * 1000.0
        );
        assert!(error <= 3.0 * 3f64.sqrt() * sigma, "{from}: {error} m outside 3σ ({sigma} m)");
    }
}

/// `simulate --visits 8 --rig`, `survey` of the visits, `calibrate --rig` of the rig (one
/// more vehicle of that room) in the surveyed room with `--export` and `--json`: the
/// whole rig workflow over the binary.
#[test]
fn a_rig_is_calibrated_in_the_room_its_visits_surveyed() {
    let dir = Scratch::new("rig-surveyed");
    let d = dir.to_string_lossy().into_owned();
    let (room, rig) = (config("room.toml"), config("rig.toml"));
    let simulate = ["simulate", "--room", &room, "--rig", &rig, "--visits", "8", "--out", &d];
    let (code, stdout, stderr) =
        roomcal(&[&simulate[..], &["--seed", "5", "--supersample", "1"]].concat());
    assert_eq!(code, 0, "{stderr}");
    println!("{stdout}");
    let visits: Vec<String> = (1..=8)
        .flat_map(|k| {
            let v = dir.join(format!("visit-{k:02}"));
            [
                "--visit".into(),
                v.join("image.png").display().to_string(),
                v.join("cloud.pcd").display().to_string(),
            ]
        })
        .collect();
    let surveyed = dir.join("surveyed.toml").display().to_string();
    let mut args = vec!["survey", "--room", &room, "--out", &surveyed];
    args.extend(visits.iter().map(String::as_str));
    let (code, _, stderr) = roomcal(&args);
    assert_eq!(code, 0, "survey: {stderr}");

    let mut inputs = rig_inputs(&dir.join("rig"));
    inputs.extend(["--export".into(), dir.join("exports").display().to_string(), "--json".into()]);
    inputs.extend(["--report".into(), dir.join("report.png").display().to_string()]);
    let inputs: Vec<&str> = inputs.iter().map(String::as_str).collect();
    let out = dir.join("result.json");
    let (code, stdout, stderr) = calibrate_in(&surveyed, &inputs, &out);
    assert_eq!(code, 0, "{stdout}{stderr}");
    // --json: stdout is the result file, nothing else.
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(stdout, text);
    let result: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(result["camera_in_room"].is_object(), "not solved in the surveyed room");
    for name in ["front", "wide"] {
        assert!(result["sensors"][name]["camera_in_room"].is_object(), "{name}");
        let text = std::fs::read_to_string(dir.join(format!("exports/{name}.camera_info.yaml")))
            .unwrap_or_else(|e| panic!("{name}.camera_info.yaml: {e}"));
        assert!(text.contains(&format!("camera_name: {name}\n")), "{text}");
    }
    // --report: one picture per camera, the camera's frame (and a footer below it) with
    // every LiDAR's points, the camera's corners (white) and the LiDARs' hole centres (red).
    for name in ["front", "wide"] {
        let path = dir.join(format!("report-{name}.png"));
        let picture = image::open(&path).unwrap_or_else(|e| panic!("{path:?}: {e}")).to_rgb8();
        assert_eq!(picture.width(), 1920, "{name}");
        assert!(picture.height() > 1200, "{name}: no footer");
        let frame = image::imageops::crop_imm(&picture, 0, 0, 1920, 1200).to_image();
        let count = |rgb: [u8; 3]| frame.pixels().filter(|p| p.0 == rgb).count();
        let coloured = frame.pixels().filter(|p| p[0].abs_diff(p[1]) > 40).count();
        assert!(coloured > 10_000, "{name}: {coloured} coloured pixels: no LiDAR points drawn");
        assert!(count(roomcal::report::CORNER.0) > 6 * 35 * 4, "{name}: corners not marked");
        assert!(count([255, 40, 40]) > 3 * 4 * 10, "{name}: LiDAR hole centres not marked");
    }
    let kit = std::fs::read_to_string(dir.join("exports/sensor_kit_calibration.yaml")).unwrap();
    for entry in ["  top:", "  bumper:", "  front/camera_link:", "  wide/camera_link:"] {
        assert!(kit.contains(entry), "{entry} missing: {kit}");
    }
    let calib = std::fs::read_to_string(dir.join("exports/calib.txt")).unwrap();
    assert!(
        calib.starts_with("P0: ")
            && calib.contains("\nP1: ")
            && calib.contains("\nTr_velo_to_cam: ")
    );

    // Against the rig's truth: every extrinsic within 3σ per axis-bound (σ is worst-axis).
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("rig/rig-truth.json")).unwrap())
            .unwrap();
    assert_extrinsics_within_their_sigma(&result, &truth);
}

/// `simulate --visits N --rig RIG --rigs K`: K rigs, each its own vehicle, in the one room
/// the visits see (DIR/rig-01/ … rig-K/); rig-01 is the rig that `--rigs` left out writes to
/// DIR/rig/. `--rigs` without `--visits` and `--rig` is exit 2.
#[test]
fn several_rigs_are_new_vehicles_in_the_visited_room() {
    let (room, rig) = (config("room.toml"), config("rig.toml"));
    let simulate = |dir: &Path, more: &[&str]| {
        let d = dir.to_string_lossy().into_owned();
        let args = ["simulate", "--room", &room, "--rig", &rig, "--visits", "2", "--out", &d];
        let (code, _, stderr) =
            roomcal(&[&args[..], &["--seed", "7", "--supersample", "1"], more].concat());
        assert_eq!(code, 0, "{stderr}");
    };
    let (one, two) = (Scratch::new("rig-one-rig"), Scratch::new("rig-two-rigs"));
    simulate(&one, &[]);
    simulate(&two, &["--rigs", "2"]);
    let read = |path: PathBuf| -> serde_json::Value {
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
        serde_json::from_str(&text).unwrap()
    };
    let (first, second) =
        (read(two.join("rig-01/rig-truth.json")), read(two.join("rig-02/rig-truth.json")));
    assert_eq!(first, read(one.join("rig/rig-truth.json")), "rig-01 is the single rig");
    for file in ["front.png", "top.pcd"] {
        let bytes = |d: PathBuf| std::fs::read(d.join(file)).unwrap();
        assert_eq!(bytes(two.join("rig-01")), bytes(one.join("rig")), "{file}");
    }
    let room_truth = |d: &str| read(two.join(d).join("room-truth.json"));
    assert_eq!(room_truth("rig-01"), room_truth("rig-02"), "one room");
    assert_ne!(first["vehicle_to_room"], second["vehicle_to_room"], "own parking");
    assert_ne!(first["sensors"]["wide"], second["sensors"]["wide"], "own sensors");

    let alone = Scratch::new("rig-rigs-alone");
    let d = alone.to_string_lossy().into_owned();
    let (code, _, stderr) = roomcal(&["simulate", "--room", &room, "--rigs", "2", "--out", &d]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("--visits") && stderr.contains("--rig"), "{stderr}");
}

/// `simulate --rig --frames 3`: a standing vehicle, every camera's `NAME-2.png`,
/// `NAME-3.png` and every LiDAR's `NAME-2.pcd`, `NAME-3.pcd` beside the first frame, which
/// is the one-frame simulation's byte for byte; `calibrate --rig` given every frame per name
/// (averaged, accumulated) is within its σ of the truth, and its corners are quieter than
/// the one frame's.
#[test]
fn a_standing_rig_is_calibrated_from_all_its_frames() {
    let (room, rig) = (config("room.toml"), config("rig.toml"));
    let simulate = |dir: &Path, frames: &str| {
        let d = dir.to_string_lossy().into_owned();
        let args = ["simulate", "--room", &room, "--rig", &rig, "--out", &d, "--seed", "3"];
        let (code, _, stderr) =
            roomcal(&[&args[..], &["--supersample", "1", "--frames", frames]].concat());
        assert_eq!(code, 0, "{stderr}");
    };
    let (one, three) = (Scratch::new("rig-standing-one"), Scratch::new("rig-standing-three"));
    simulate(&one, "1");
    simulate(&three, "3");
    let bytes = |d: &Path, file: &str| {
        std::fs::read(d.join(file)).unwrap_or_else(|e| panic!("{}: {e}", d.join(file).display()))
    };
    for file in ["front.png", "wide.png", "top.pcd", "bumper.pcd"] {
        assert_eq!(bytes(&one, file), bytes(&three, file), "{file}: the first frame");
    }
    assert!(!one.join("front-2.png").exists());
    for file in ["front-2.png", "front-3.png", "wide-3.png", "top-2.pcd", "bumper-3.pcd"] {
        let (name, extension) = file.split_once('-').unwrap();
        let first = format!("{name}.{}", extension.split('.').nth(1).unwrap());
        assert_ne!(bytes(&three, file), bytes(&three, &first), "{file}: its own noise");
    }

    let text = std::fs::read_to_string(three.join("room.toml")).unwrap();
    let wide_room = three.join("wide-room.toml");
    std::fs::write(&wide_room, text.replace("min_coverage = 0.35", "min_coverage = 0.2")).unwrap();
    let wide_room = wide_room.to_string_lossy().into_owned();
    let mut inputs = Vec::new();
    for (flag, name, extension) in
        [("--image", "front", "png"), ("--image", "wide", "png"), ("--cloud", "top", "pcd")]
            .into_iter()
            .chain([("--cloud", "bumper", "pcd")])
    {
        for k in 1..=3 {
            let file = if k == 1 {
                format!("{name}.{extension}")
            } else {
                format!("{name}-{k}.{extension}")
            };
            inputs.push(flag.to_string());
            inputs.push(format!("{name}={}", three.join(file).display()));
        }
    }
    let run = |inputs: &[String], out: &Path| -> serde_json::Value {
        let inputs: Vec<&str> = inputs.iter().map(String::as_str).collect();
        let (code, stdout, stderr) = calibrate_in(&wide_room, &inputs, out);
        println!("{stdout}{stderr}");
        assert!(code == 0 || code == 3, "{stderr}");
        serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap()
    };
    let standing = run(&inputs, &three.join("standing.json"));
    let first_only: Vec<String> =
        inputs.chunks(6).flat_map(|sensor| sensor[..2].to_vec()).collect();
    let single = run(&first_only, &three.join("single.json"));
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(three.join("rig-truth.json")).unwrap())
            .unwrap();
    assert_extrinsics_within_their_sigma(&standing, &truth);
    let rms = |r: &serde_json::Value| r["quality"]["corner_rms_px"].as_f64().unwrap();
    println!("corner RMS: standing {:.4} px, one frame {:.4} px", rms(&standing), rms(&single));
    assert!(rms(&standing) < rms(&single), "averaged frames have quieter corners");
}
