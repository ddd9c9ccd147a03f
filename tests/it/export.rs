//! The exports for other stacks (camera_info, Autoware's sensor_kit_calibration.yaml,
//! KITTI calib.txt) read back with an independent YAML parser (yaml-rust2) or a plain
//! split, every number compared to the result's JSON to 1e-9; the frame convention of the
//! Autoware file (camera_link, not the optical frame) checked on a mounting whose answer
//! is known; and both writers: the store beside current.json and `calibrate --export`.

use std::path::Path;
use std::process::Command;

use roomcal::geometry::CameraModel;
use roomcal::result::{CalibrationResult, Extrinsic, RigResult};
use serde_json::Value;
use yaml_rust2::{Yaml, YamlLoader};

use crate::common::fixture;
use crate::common::results;
use results::{result, rig_result};

use crate::common::scratch::Scratch;

const TOLERANCE: f64 = 1e-9;

fn json(result: &CalibrationResult) -> Value {
    serde_json::to_value(result).unwrap()
}

fn yaml(text: &str) -> Yaml {
    YamlLoader::load_from_str(text).expect("valid YAML").remove(0)
}

fn export(result: &CalibrationResult, name: &str) -> String {
    let files = roomcal::export::files(result);
    files.into_iter().find(|f| f.name == name).unwrap_or_else(|| panic!("no {name}")).text
}

fn close(a: f64, b: f64, what: &str) {
    assert!((a - b).abs() <= TOLERANCE, "{what}: {a} vs {b}");
}

fn yaml_numbers(node: &Yaml) -> Vec<f64> {
    node.as_vec().expect("a list").iter().map(|v| v.as_f64().expect("a float")).collect()
}

fn yaml_matrix(doc: &Yaml, key: &str, rows: i64, cols: i64) -> Vec<f64> {
    assert_eq!(doc[key]["rows"].as_i64(), Some(rows), "{key}.rows");
    assert_eq!(doc[key]["cols"].as_i64(), Some(cols), "{key}.cols");
    let data = yaml_numbers(&doc[key]["data"]);
    assert_eq!(data.len() as i64, rows * cols, "{key}.data");
    data
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// 3×3 rotation and translation of the JSON's `lidar_to_camera`.
fn json_extrinsic(j: &Value) -> ([[f64; 3]; 3], [f64; 3]) {
    let e = &j["lidar_to_camera"];
    let r = |i: usize, k: usize| f(&e["rotation"][i][k]);
    let t = |i: usize| f(&e["translation"][i]);
    (
        [[r(0, 0), r(0, 1), r(0, 2)], [r(1, 0), r(1, 1), r(1, 2)], [r(2, 0), r(2, 1), r(2, 2)]],
        [t(0), t(1), t(2)],
    )
}

fn check_camera_info(result: &CalibrationResult) {
    let j = json(result);
    check_camera_info_of(&export(result, "camera.camera_info.yaml"), &j["camera"], "camera");
}

/// A camera_info file against the result JSON's camera block `c` named `name`.
fn check_camera_info_of(text: &str, c: &Value, name: &str) {
    let doc = yaml(text);
    assert_eq!(doc["image_width"].as_i64(), c["width"].as_i64());
    assert_eq!(doc["image_height"].as_i64(), c["height"].as_i64());
    assert_eq!(doc["camera_name"].as_str(), Some(name));
    let model = match c["model"].as_str() {
        Some("fisheye") => "equidistant",
        _ => "plumb_bob",
    };
    assert_eq!(doc["distortion_model"].as_str(), Some(model));
    let (fx, fy, cx, cy) = (f(&c["fx"]), f(&c["fy"]), f(&c["cx"]), f(&c["cy"]));
    let k = yaml_matrix(&doc, "camera_matrix", 3, 3);
    for (got, want) in k.iter().zip([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]) {
        close(*got, want, "camera_matrix");
    }
    let d: Vec<f64> = c["distortion"].as_array().unwrap().iter().map(f).collect();
    let got = yaml_matrix(&doc, "distortion_coefficients", 1, d.len() as i64);
    for (g, w) in got.iter().zip(&d) {
        close(*g, *w, "distortion_coefficients");
    }
    let rect = yaml_matrix(&doc, "rectification_matrix", 3, 3);
    for (g, w) in rect.iter().zip([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]) {
        close(*g, w, "rectification_matrix");
    }
    let p = yaml_matrix(&doc, "projection_matrix", 3, 4);
    for (g, w) in p.iter().zip([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]) {
        close(*g, w, "projection_matrix");
    }
}

#[test]
fn camera_info_reads_back_as_the_json_for_both_models() {
    check_camera_info(&result(CameraModel::PinholeRadtan));
    check_camera_info(&result(CameraModel::Fisheye));
}

/// URDF roll-pitch-yaw, written here independently of roomcal: Rz(yaw)·Ry(pitch)·Rx(roll).
fn rpy_matrix(roll: f64, pitch: f64, yaw: f64) -> [[f64; 3]; 3] {
    let (sr, cr, sp, cp, sy, cy) =
        (roll.sin(), roll.cos(), pitch.sin(), pitch.cos(), yaw.sin(), yaw.cos());
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

fn transpose(a: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in a.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            out[j][i] = *v;
        }
    }
    out
}

/// `p_optical = OPTICAL_FROM_LINK · p_link`, as REP 103 / REP 105 define the two frames.
const OPTICAL_FROM_LINK: [[f64; 3]; 3] = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];

/// An Autoware entry: (rotation, translation) of p_parent = R p_child + t.
fn autoware_pose(entry: &Yaml) -> ([[f64; 3]; 3], [f64; 3]) {
    let v = |k: &str| entry[k].as_f64().unwrap_or_else(|| panic!("{k} is not a float"));
    (rpy_matrix(v("roll"), v("pitch"), v("yaw")), [v("x"), v("y"), v("z")])
}

#[test]
fn sensor_kit_gives_the_camera_link_in_the_lidar_frame() {
    let result = result(CameraModel::PinholeRadtan);
    let doc = yaml(&export(&result, "sensor_kit_calibration.yaml"));
    let kit = &doc["sensor_kit_base_link"];
    let (lidar_r, lidar_t) = autoware_pose(&kit["lidar"]);
    for (i, (row, t)) in lidar_r.iter().zip(lidar_t).enumerate() {
        close(t, 0.0, "lidar position");
        for (k, v) in row.iter().enumerate() {
            close(*v, if i == k { 1.0 } else { 0.0 }, "lidar rotation");
        }
    }
    // p_lidar = A p_link + b  ⇒  p_optical = M p_link = M Aᵀ (p_lidar − b):
    // lidar → optical is R = M Aᵀ, t = −M Aᵀ b.
    let (a, b) = autoware_pose(&kit["camera/camera_link"]);
    let r = mul(&OPTICAL_FROM_LINK, &transpose(&a));
    let (want_r, want_t) = json_extrinsic(&json(&result));
    for ((row, want_row), want_t) in r.iter().zip(&want_r).zip(want_t) {
        let t: f64 = -row.iter().zip(&b).map(|(r, b)| r * b).sum::<f64>();
        close(t, want_t, "translation");
        for (v, want) in row.iter().zip(want_row) {
            close(*v, *want, "rotation");
        }
    }
}

#[test]
fn a_lidar_mounted_along_the_camera_body_has_zero_angles_in_the_sensor_kit() {
    // LiDAR x forward, y left, z up exactly along camera_link, 0.3 m ahead of and 0.2 m
    // below the camera: camera_link in the LiDAR frame is then rpy 0 at (−0.3, 0, +0.2).
    // Written for the optical frame instead, the angles would be (−90°, 0, −90°).
    let mut result = result(CameraModel::PinholeRadtan);
    let ahead_below = [0.0, 0.2, 0.3]; // optical: x right, y down, z forward
    result.lidar_to_camera =
        Some(Extrinsic { rotation: OPTICAL_FROM_LINK, translation: ahead_below });
    let doc = yaml(&export(&result, "sensor_kit_calibration.yaml"));
    let camera = &doc["sensor_kit_base_link"]["camera/camera_link"];
    for (key, want) in
        [("x", -0.3), ("y", 0.0), ("z", 0.2), ("roll", 0.0), ("pitch", 0.0), ("yaw", 0.0)]
    {
        close(camera[key].as_f64().unwrap(), want, key);
    }
    assert!(export(&result, "sensor_kit_calibration.yaml")
        .contains("camera_link is a camera's BODY frame"));
}

/// `KEY: n n n ...` lines of a KITTI calib.txt.
fn kitti(text: &str) -> Vec<(String, Vec<f64>)> {
    text.lines()
        .map(|line| {
            let (key, values) = line.split_once(':').expect("KEY: values");
            let numbers = values.split_whitespace().map(|v| v.parse().expect("a number")).collect();
            (key.to_string(), numbers)
        })
        .collect()
}

#[test]
fn kitti_calib_reads_back_as_the_json() {
    let result = result(CameraModel::PinholeRadtan);
    let lines = kitti(&export(&result, "calib.txt"));
    let keys: Vec<&str> = lines.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(keys, ["P0", "Tr_velo_to_cam"]);
    let j = json(&result);
    let c = &j["camera"];
    let (fx, fy, cx, cy) = (f(&c["fx"]), f(&c["fy"]), f(&c["cx"]), f(&c["cy"]));
    let p0 = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0];
    assert_eq!(lines[0].1.len(), 12);
    for (g, w) in lines[0].1.iter().zip(p0) {
        close(*g, w, "P0");
    }
    let (r, t) = json_extrinsic(&j);
    let tr: Vec<f64> = (0..3).flat_map(|i| [r[i][0], r[i][1], r[i][2], t[i]]).collect();
    assert_eq!(lines[1].1.len(), 12);
    for (g, w) in lines[1].1.iter().zip(tr) {
        close(*g, w, "Tr_velo_to_cam");
    }
    // An intrinsics-only result has no LiDAR: P0 alone, no Autoware file.
    let mut camera_only = result.clone();
    camera_only.lidar_to_camera = None;
    let names: Vec<String> =
        roomcal::export::files(&camera_only).into_iter().map(|f| f.name).collect();
    assert_eq!(names, ["camera.camera_info.yaml", "calib.txt"]);
    assert_eq!(kitti(&export(&camera_only, "calib.txt")).len(), 1);
}

/// The three files in `dir` are exactly the exports of `result`.
fn assert_exports_of(dir: &Path, result: &CalibrationResult) {
    for file in roomcal::export::files(result) {
        let on_disk = std::fs::read_to_string(dir.join(&file.name)).unwrap();
        assert_eq!(on_disk, file.text, "{}", file.name);
    }
}

#[test]
fn the_store_writes_the_exports_beside_current_json() {
    let dir = Scratch::new("export-store");
    let store = roomcal::store::Store::open(dir.path(), 4).unwrap();
    let first = result(CameraModel::PinholeRadtan);
    store.commit(&first.clone().into(), 1_700_000_000).unwrap();
    assert_exports_of(&dir, &first);
    let mut second = first.clone();
    second.camera.fx += 1.5;
    store.commit(&second.clone().into(), 1_700_000_100).unwrap();
    assert_exports_of(&dir, &second);
    // A rollback puts the first calibration's exports back.
    store.rollback(1_700_000_200).unwrap();
    assert_exports_of(&dir, &first);
}

#[test]
fn calibrate_exports_accepted_runs_only() {
    let dir = Scratch::new("export-cli");
    let run = |room: &str, out: &Path, export: &Path| {
        Command::new(crate::common::BIN)
            .args([
                "calibrate",
                "--room",
                room,
                "--image",
                fixture("six-boards-pandar64/image.png").to_str().unwrap(),
            ])
            .args([
                "--cloud",
                fixture("six-boards-pandar64/cloud.pcd").to_str().unwrap(),
                "--quiet",
                "--out",
            ])
            .arg(out)
            .arg("--export")
            .arg(export)
            .status()
            .unwrap()
            .code()
    };
    let (out, exported) = (dir.join("result.json"), dir.join("exports"));
    assert_eq!(
        run(fixture("six-boards-pandar64/room.toml").to_str().unwrap(), &out, &exported),
        Some(0)
    );
    let result: CalibrationResult = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_exports_of(&exported, &result);
    check_camera_info(&result);

    let room = std::fs::read_to_string(fixture("six-boards-pandar64/room.toml"))
        .unwrap()
        .replace("count = 6", "count = 7");
    let seven = dir.join("seven.toml");
    std::fs::write(&seven, room).unwrap();
    let not_exported = dir.join("rejected-exports");
    assert_eq!(run(seven.to_str().unwrap(), &dir.join("rejected.json"), &not_exported), Some(3));
    assert!(!not_exported.exists(), "a rejected calibration was exported");
}

fn rig_export(rig: &RigResult, name: &str) -> String {
    let files = roomcal::export::rig_files(rig);
    files.into_iter().find(|f| f.name == name).unwrap_or_else(|| panic!("no {name}")).text
}

/// (rotation, translation) of a JSON extrinsic block.
fn json_motion(e: &Value) -> ([[f64; 3]; 3], [f64; 3]) {
    let r = |i: usize, k: usize| f(&e["rotation"][i][k]);
    let t = |i: usize| f(&e["translation"][i]);
    (
        [[r(0, 0), r(0, 1), r(0, 2)], [r(1, 0), r(1, 1), r(1, 2)], [r(2, 0), r(2, 1), r(2, 2)]],
        [t(0), t(1), t(2)],
    )
}

fn apply(r: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| (0..3).map(|k| r[i][k] * v[k]).sum())
}

#[test]
fn a_rigs_exports_place_every_sensor_as_its_extrinsics_say() {
    let rig = rig_result();
    let names: Vec<String> = roomcal::export::rig_files(&rig).into_iter().map(|f| f.name).collect();
    assert_eq!(
        names,
        [
            "front.camera_info.yaml",
            "wide.camera_info.yaml",
            "sensor_kit_calibration.yaml",
            "calib.txt"
        ]
    );
    let j = serde_json::to_value(&rig).unwrap();
    for name in ["front", "wide"] {
        let text = rig_export(&rig, &format!("{name}.camera_info.yaml"));
        check_camera_info_of(&text, &j["sensors"][name]["camera"], name);
    }

    // Autoware: parent = the first LiDAR (`top`); every sensor composed with top → front
    // gives its extrinsic back (a camera's entry is its camera_link: p_top = A p_link + b,
    // so optical → top is A Mᵀ, b).
    let doc = yaml(&rig_export(&rig, "sensor_kit_calibration.yaml"));
    let kit = &doc["sensor_kit_base_link"];
    let extrinsics = j["extrinsics"].as_array().unwrap();
    let (top_r, top_t) = json_motion(&extrinsics[1]);
    let mut expected = vec![("front".to_string(), true, rpy_matrix(0.0, 0.0, 0.0), [0.0; 3])];
    for e in extrinsics {
        let name = e["from"].as_str().unwrap();
        let (r, t) = json_motion(e);
        expected.push((name.into(), j["sensors"][name].get("camera").is_some(), r, t));
    }
    for (name, camera, want_r, want_t) in expected {
        let key = if camera { format!("{name}/camera_link") } else { name.clone() };
        let (mut a, b) = autoware_pose(&kit[key.as_str()]);
        if camera {
            a = mul(&a, &transpose(&OPTICAL_FROM_LINK));
        }
        let r = mul(&top_r, &a);
        let rb = apply(&top_r, &b);
        for i in 0..3 {
            close(rb[i] + top_t[i], want_t[i], &format!("{name} translation"));
            for k in 0..3 {
                close(r[i][k], want_r[i][k], &format!("{name} rotation"));
            }
        }
    }

    // KITTI: P0 = [K_front | 0], P1 = K_wide [Rᵀ | −Rᵀ t] (front → wide), Tr = top → front.
    let lines = kitti(&rig_export(&rig, "calib.txt"));
    let keys: Vec<&str> = lines.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(keys, ["P0", "P1", "Tr_velo_to_cam"]);
    let k_of = |c: &Value| {
        [[f(&c["fx"]), 0.0, f(&c["cx"])], [0.0, f(&c["fy"]), f(&c["cy"])], [0.0, 0.0, 1.0]]
    };
    let (wide_r, wide_t) = json_motion(&extrinsics[0]);
    let front_to_wide = transpose(&wide_r);
    let minus_t = apply(&front_to_wide, &wide_t).map(|v| -v);
    let (k0, k1) = (k_of(&j["sensors"]["front"]["camera"]), k_of(&j["sensors"]["wide"]["camera"]));
    let kr = mul(&k1, &front_to_wide);
    let kt = apply(&k1, &minus_t);
    let p1: Vec<f64> = (0..3).flat_map(|i| [kr[i][0], kr[i][1], kr[i][2], kt[i]]).collect();
    let p0: Vec<f64> = (0..3).flat_map(|i| [k0[i][0], k0[i][1], k0[i][2], 0.0]).collect();
    let tr: Vec<f64> =
        (0..3).flat_map(|i| [top_r[i][0], top_r[i][1], top_r[i][2], top_t[i]]).collect();
    for ((key, want), (_, got)) in [("P0", p0), ("P1", p1), ("Tr", tr)].iter().zip(&lines) {
        assert_eq!(got.len(), 12, "{key}");
        for (g, w) in got.iter().zip(want) {
            close(*g, *w, key);
        }
    }
}

#[test]
fn the_store_keeps_a_rig_with_its_views_and_rolls_it_back_whole() {
    let dir = Scratch::new("export-store-rig");
    let store = roomcal::store::Store::open(dir.path(), 4).unwrap();
    let first = rig_result();
    store.commit(&first, 1_700_000_000).unwrap();
    let on_disk = |name: &str| std::fs::read_to_string(dir.join(name)).unwrap();
    let assert_views_of = |rig: &RigResult| {
        for file in roomcal::export::rig_files(rig) {
            assert_eq!(on_disk(&file.name), file.text, "{}", file.name);
        }
        for (name, camera) in [("front", &rig.sensors["front"]), ("wide", &rig.sensors["wide"])] {
            let fx = camera.camera.as_ref().unwrap().fx;
            assert_eq!(
                on_disk(&format!("camera-{name}.yaml")),
                roomcal::store::camera_yaml(camera.camera.as_ref().unwrap()),
                "camera-{name}.yaml (fx {fx})"
            );
        }
        assert_eq!(on_disk("extrinsics.yaml"), roomcal::store::rig_extrinsics_yaml(rig));
    };
    assert_views_of(&first);
    let text = on_disk("extrinsics.yaml");
    assert!(text.starts_with("%YAML:1.0\n---\n") && text.contains("first_camera: \"front\""));
    for e in &first.extrinsics {
        assert!(text.contains(&format!("from: \"{}\"", e.from)), "{}", e.from);
    }
    // One-pair consumers keep reading the first camera and first LiDAR.
    assert_eq!(on_disk("camera.yaml"), roomcal::store::camera_yaml(&first.pair.camera));
    let in_force =
        || roomcal::store::Store::open(dir.path(), 4).unwrap().current().unwrap().unwrap();
    assert_eq!(in_force().rig(), Some(&first.clone()));

    let mut second = first.clone();
    second.sensors.get_mut("wide").unwrap().camera.as_mut().unwrap().fx += 1.5;
    second.extrinsics[2].translation[0] += 0.01;
    store.commit(&second, 1_700_000_100).unwrap();
    assert_views_of(&second);
    assert_eq!(in_force().rig(), Some(&second.clone()));
    store.rollback(1_700_000_200).unwrap();
    assert_views_of(&first);
    assert_eq!(in_force().rig(), Some(&first.clone()));

    // A rig record whose extrinsic is no rotation is never in force.
    let generation = in_force().generation;
    let mut bad = first.clone();
    bad.extrinsics[1].rotation[0][0] = 2.0;
    store.commit(&bad, 1_700_000_300).unwrap();
    let current = in_force();
    assert_eq!(current.generation, generation, "an invalid rig record went in force");
    assert_eq!(current.rig(), Some(&first));
}

/// `RigResult::between`: sensor → sensor through the first camera, as the rig's report draws
/// a LiDAR in a camera: `between(a, b)` maps a's points to b's frame, so composing it with
/// b → first gives a → first; the first camera is the identity; an unknown name is `None`.
#[test]
fn between_two_sensors_goes_through_the_first_camera() {
    let rig = rig_result();
    let first = rig.first_camera().unwrap().to_string();
    let to_first =
        |name: &str| rig.extrinsics.iter().find(|e| e.from == name).map(|e| e.to_se3()).unwrap();
    let p = roomcal::geometry::Vec3::new(1.5, -0.4, 7.0);
    for e in &rig.extrinsics {
        for f in &rig.extrinsics {
            let a_to_b = rig.between(&e.from, &f.from).unwrap();
            let via = to_first(&f.from).act(&a_to_b.act(&p));
            assert!((via - to_first(&e.from).act(&p)).norm() < 1e-12, "{} → {}", e.from, f.from);
        }
        let to_camera = rig.between(&e.from, &first).unwrap();
        assert!((to_camera.act(&p) - to_first(&e.from).act(&p)).norm() < 1e-12);
    }
    assert!(rig.between(&first, &first).unwrap().act(&p) == p);
    assert!(rig.between("nobody", &first).is_none());
}
