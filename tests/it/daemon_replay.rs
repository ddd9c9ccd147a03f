//! The daemon end to end in replay mode (the binary, real detectors and solver): it
//! notices the fixture room, calibrates, writes `current.json` matching the truth — from
//! the PCD cloud and from the sensor's own packets (the capture replayed at its pace,
//! decoded with the unit's angle file); a room that expects one board more is rejected
//! and leaves `current.json` untouched; packets of another model than the room's are
//! named at once, and `--once` gives up saying what it waited for.

use std::path::{Path, PathBuf};
use std::process::Command;

use roomcal::sim::Truth;

use crate::common::fixture;
use crate::common::scratch::Scratch;

/// A replay configuration in `dir` for `room`, its store in `dir/store`, the LiDAR
/// replaying the fixture's PCD cloud; the trigger fires on six boards whatever the room
/// expects.
fn config(dir: &Path, room: &Path) -> PathBuf {
    let lidar =
        format!("source = \"replay:{}\"", fixture("six-boards-pandar64/cloud.pcd").display());
    config_with_lidar(dir, room, &lidar)
}

fn config_with_lidar(dir: &Path, room: &Path, lidar: &str) -> PathBuf {
    let text = format!(
        "room = {:?}\nstore = {:?}\n[camera]\nsource = \"replay:{}\"\n[lidar]\n{lidar}\n[trigger]\nmode = \"auto\"\nsettle_s = 1.0\nsweeps = 1\nmin_boards = 6\n",
        room,
        dir.join("store"),
        fixture("six-boards-pandar64/image.png").display(),
    );
    let path = dir.join("roomcal.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn run_once(config: &Path) -> String {
    let out = Command::new(crate::common::BIN)
        .args(["daemon", "--config", config.to_str().unwrap(), "--once"])
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    text
}

/// The store's current calibration is accepted, generation 1, and within 4σ of the truth.
fn assert_current_matches_truth(current_path: &Path) {
    let current: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(current_path).unwrap()).unwrap();
    assert_eq!(current["status"], "accepted");
    assert_eq!(current["generation"], 1);
    let truth: Truth = serde_json::from_str(
        &std::fs::read_to_string(fixture("six-boards-pandar64/truth.json")).unwrap(),
    )
    .unwrap();
    let fx = current["camera"]["fx"].as_f64().unwrap();
    let sigma_fx = current["uncertainty"]["fx"].as_f64().unwrap();
    println!("daemon fx {fx:.2} (truth {:.2}, σ {sigma_fx:.2})", truth.camera.fx);
    assert!((fx - truth.camera.fx).abs() < 4.0 * sigma_fx + 0.5);
    let t = &current["lidar_to_camera"]["translation"];
    let want = truth.lidar_to_camera.as_ref().unwrap().translation;
    let shift: f64 = (0..3).map(|i| (t[i].as_f64().unwrap() - want[i]).powi(2)).sum::<f64>().sqrt();
    let sigma_t = current["uncertainty"]["translation_m"].as_f64().unwrap();
    println!("translation off by {:.1} mm (σ {:.1} mm)", shift * 1000.0, sigma_t * 1000.0);
    assert!(shift < 4.0 * sigma_t + 0.002, "translation off by {shift} m (σ {sigma_t})");
}

#[test]
fn replay_daemon_calibrates_from_the_sensors_packets() {
    let dir = Scratch::new("daemon-pcap");
    let lidar = format!(
        "source = \"replay:{}\"\ncalibration = {:?}",
        fixture("six-boards-pandar64/cloud.pcap").display(),
        fixture("six-boards-pandar64/angles.csv")
    );
    let text =
        run_once(&config_with_lidar(&dir, &fixture("six-boards-pandar64/room.toml"), &lidar));
    assert!(text.contains("1 accepted"), "{text}");
    assert_current_matches_truth(&dir.join("store/current.json"));
    // The end summary gives the calibration in force in a line, and where it is.
    let line = |head: &str| text.lines().find(|l| l.trim_start().starts_with(head)).unwrap_or("");
    let in_force = line("in force");
    let current: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("store/current.json")).unwrap())
            .unwrap();
    let fx = format!("fx {:.2}", current["camera"]["fx"].as_f64().unwrap());
    assert!(in_force.contains(&fx) && in_force.contains("LiDAR roll"), "{text}");
    let store = line("store");
    assert!(store.ends_with(&format!("{}", dir.join("store/current.json").display())), "{text}");
}

#[test]
fn replay_daemon_calibrates_and_a_short_room_is_rejected() {
    let dir = Scratch::new("daemon-replay");
    let text = run_once(&config(&dir, &fixture("six-boards-pandar64/room.toml")));
    assert!(text.contains("1 accepted"), "{text}");
    let current_path = dir.join("store/current.json");
    assert_current_matches_truth(&current_path);
    // Beside current.json: the exports for other stacks and the run's report picture.
    let store = dir.join("store");
    for file in ["camera.camera_info.yaml", "sensor_kit_calibration.yaml", "calib.txt"] {
        assert!(store.join(file).is_file(), "{file} missing from the store");
    }
    let picture = image::open(store.join("last-run.png")).expect("the run's report picture");
    assert!(picture.width() == 1920 && picture.height() > 1200);

    // The same store, a room that expects seven boards while six stand in the scene: the
    // run starts (the trigger is set to six) and the gate rejects it; current.json stays.
    let before = std::fs::read(&current_path).unwrap();
    let exports_before = std::fs::read(store.join("calib.txt")).unwrap();
    let seven = dir.join("room7.toml");
    std::fs::write(
        &seven,
        std::fs::read_to_string(fixture("six-boards-pandar64/room.toml"))
            .unwrap()
            .replace("count = 6", "count = 7"),
    )
    .unwrap();
    let text = run_once(&config(&dir, &seven));
    assert!(text.contains("0 accepted"), "{text}");
    assert_eq!(
        std::fs::read(&current_path).unwrap(),
        before,
        "a rejected run replaced current.json"
    );
    let exports = std::fs::read(store.join("calib.txt")).unwrap();
    assert_eq!(exports, exports_before, "a rejected run changed the exports");
}

#[test]
fn packets_of_another_model_are_named_and_once_gives_up_on_them() {
    let dir = Scratch::new("daemon-foreign");
    let room = dir.join("room-vlp16.toml");
    let text = std::fs::read_to_string(fixture("six-boards-pandar64/room.toml")).unwrap();
    assert!(text.contains("model = \"pandar64\""));
    std::fs::write(&room, text.replace("model = \"pandar64\"", "model = \"vlp16\"")).unwrap();
    let lidar =
        format!("source = \"replay:{}\"", fixture("six-boards-pandar64/cloud.pcap").display());
    let config = config_with_lidar(&dir, &room, &lidar);
    let out = Command::new(crate::common::BIN)
        .args(["daemon", "--config", config.to_str().unwrap(), "--once", "--give-up-after", "4"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(
        text.contains("its packets are a `pandar64`'s")
            && text.contains("not the configured `vlp16`'s"),
        "{text}"
    );
    assert_eq!(text.matches("its packets are").count(), 1, "said once: {text}");
    assert!(text.contains("gave up after 4 s without a calibration run"), "{text}");
    assert!(text.contains("no LiDAR sweep arrived"), "the reason says what was missing: {text}");
    assert!(!dir.join("store/current.json").exists());
}
