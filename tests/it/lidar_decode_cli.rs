//! `roomcal decode --lidar pandarxt32|pandarqt64|ouster` on the shared captures, the room
//! file's `[lidar] model` names, and the clear error for an Ouster capture without metadata.
//! The capture checks skip with a message when `../shared` (or `$ROOMCAL_SHARED`) is absent.

use std::process::Command;

use crate::common::pcap_data;
use pcap_data::{data_dir, file_with};

use crate::common::scratch::Scratch;

fn decode(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(crate::common::BIN).arg("decode").args(args).output().unwrap()
}

#[test]
fn decodes_the_new_models_to_pcd() {
    let out_dir = Scratch::new("decode-cli");
    for (model, folder, calibration) in [
        ("pandarxt32", "hesai-pandarxt32", "PandarXT32.csv"),
        ("pandarqt64", "hesai-pandarqt64", "PandarQT64.csv"),
        ("ouster", "ouster-os1-legacy", "OS-1-32-G_v2.1.1_1024x10.json"),
        ("ouster", "ouster-os0-rng19-dual", "OS-0-32-U1_v2.2.0_1024x10.json"),
    ] {
        let Some(dir) = data_dir(folder) else { return };
        let pcd = out_dir.join(format!("{folder}.pcd"));
        let capture = file_with(&dir, "pcap");
        let cal = dir.join(calibration);
        let out = decode(&[
            "--lidar".as_ref(),
            model.as_ref(),
            "--calibration".as_ref(),
            cal.as_os_str(),
            capture.as_os_str(),
            "--out".as_ref(),
            pcd.as_os_str(),
        ]);
        assert!(out.status.success(), "{folder}: {}", String::from_utf8_lossy(&out.stderr));
        let points = roomcal::lidar::pcd::read(&pcd).unwrap();
        println!("{folder}: {}", String::from_utf8_lossy(&out.stdout).trim());
        assert!(points.len() > 20_000, "{folder}: {} points", points.len());
    }
    // Ouster without its metadata: exit 2, naming the capture and what is missing.
    let Some(dir) = data_dir("ouster-os1-legacy") else { return };
    let capture = file_with(&dir, "pcap");
    let pcd = out_dir.join("x.pcd");
    let out = decode(&[
        "--lidar".as_ref(),
        "ouster".as_ref(),
        capture.as_os_str(),
        "--out".as_ref(),
        pcd.as_os_str(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("metadata json") && err.contains("OS-1-32-G"), "{err}");
}

#[test]
fn unknown_model_lists_the_known_ones() {
    let out = decode(&[
        "--lidar".as_ref(),
        "hdl64e".as_ref(),
        "x.pcap".as_ref(),
        "--out".as_ref(),
        "x.pcd".as_ref(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("pandarxt32") && err.contains("ouster"), "{err}");
}

#[test]
fn room_file_names_the_new_models() {
    #[derive(serde::Deserialize)]
    struct Lidar {
        #[serde(with = "roomcal::lidar::common::model_or_pcd")]
        model: Option<roomcal::lidar::Model>,
    }
    for (name, model) in [
        ("pandarxt32", roomcal::lidar::Model::PandarXt32),
        ("pandarqt64", roomcal::lidar::Model::PandarQt64),
        ("ouster", roomcal::lidar::Model::Ouster),
    ] {
        let lidar: Lidar = toml::from_str(&format!("model = \"{name}\"")).unwrap();
        assert_eq!(lidar.model, Some(model));
        assert_eq!(model.name(), name);
    }
}
