//! Ouster LEGACY and RNG19_RFL8_SIG16_NIR16_DUAL packets against Ouster's own digests in
//! `../shared/data/pcap/ouster-*` (see its README for what is hashed, over which layout):
//! every md5 of `*_digest.json` rebuilt from roomcal's packet view, and every decoded point
//! against the manual's range-to-xyz worked in f64 here from the metadata json. Skips with a
//! message when `../shared` (or `$ROOMCAL_SHARED`) is absent.

use std::collections::BTreeMap;
use std::path::Path;

use roomcal::lidar::ouster::{OusterGeometry, Packet, Profile};
use roomcal::lidar::{calibration, decode_packet, Calibration, Model};

use crate::common::md5;
use crate::common::pcap_data;
use md5::Md5;
use pcap_data::{data_dir, file_with};

/// The capture's lidar packets (IMU packets and anything else left out), in capture order.
fn lidar_packets(capture: &Path, g: &OusterGeometry) -> Vec<Vec<u8>> {
    let (datagrams, _) = roomcal::lidar::pcap::read_udp(capture).unwrap();
    datagrams
        .into_iter()
        .filter(|d| d.dst.port() == Model::Ouster.data_port())
        .map(|d| d.payload)
        .inspect(|p| {
            let packet =
                Packet::new_checked(&p[..], g).unwrap_or_else(|e| panic!("{} B: {e}", p.len()));
            // What the sweep assembler asks of a live stream holds for the real unit's packets.
            assert_eq!(packet.check_consistency(), Ok(()));
        })
        .collect()
}

/// Per-column fields: name, bytes hashed per value, and the value of (packet, column).
type ColumnField = (&'static str, usize, fn(&Packet<&[u8]>, usize) -> u64);

/// Per-pixel fields: name, bytes hashed per value, and the value of (packet, column, beam).
type PixelField = (&'static str, usize, fn(&Packet<&[u8]>, usize, usize) -> u64);

fn pixel_fields(profile: Profile) -> Vec<PixelField> {
    let mut f: Vec<PixelField> = vec![
        ("RANGE", 4, |p, c, b| p.range(c, b, 0).into()),
        ("SIGNAL", 2, |p, c, b| p.signal(c, b, 0).into()),
        ("REFLECTIVITY", 1, |p, c, b| p.reflectivity(c, b, 0).into()),
        ("NEAR_IR", 2, |p, c, b| p.near_ir(c, b).into()),
        ("FLAGS", 1, |p, c, b| p.flags(c, b, 0).into()),
    ];
    if profile == Profile::Dual {
        f.extend::<[PixelField; 4]>([
            ("RANGE2", 4, |p, c, b| p.range(c, b, 1).into()),
            ("SIGNAL2", 2, |p, c, b| p.signal(c, b, 1).into()),
            ("REFLECTIVITY2", 1, |p, c, b| p.reflectivity(c, b, 1).into()),
            ("FLAGS2", 1, |p, c, b| p.flags(c, b, 1).into()),
        ]);
    }
    let words = if profile == Profile::Dual { 4 } else { 3 };
    for n in 0..words {
        let name: &'static str = ["RAW32_WORD1", "RAW32_WORD2", "RAW32_WORD3", "RAW32_WORD4"][n];
        let get: fn(&Packet<&[u8]>, usize, usize) -> u64 = match n {
            0 => |p, c, b| p.raw_word(c, b, 0).into(),
            1 => |p, c, b| p.raw_word(c, b, 1).into(),
            2 => |p, c, b| p.raw_word(c, b, 2).into(),
            _ => |p, c, b| p.raw_word(c, b, 3).into(),
        };
        f.push((name, 4, get));
    }
    f
}

fn feed(h: &mut Md5, value: u64, bytes: usize) {
    h.update(&value.to_le_bytes()[..bytes]);
}

/// `packet_hash`: one running md5 per key over every packet.
fn packet_hashes(packets: &[Vec<u8>], g: &OusterGeometry) -> BTreeMap<String, String> {
    let fields = pixel_fields(g.profile);
    let columns = usize::from(g.columns_per_packet);
    let beams = usize::from(g.pixels_per_column);
    let mut hashes: BTreeMap<&str, Md5> = BTreeMap::new();
    for bytes in packets {
        let p = Packet::new_checked(&bytes[..], g).unwrap();
        let column_fields: [ColumnField; 5] = [
            ("TIMESTAMP", 8, |p, c| p.timestamp(c)),
            ("ENCODER_COUNT", 4, |p, c| p.encoder_count(c).into()),
            ("MEASUREMENT_ID", 2, |p, c| p.measurement_id(c).into()),
            ("STATUS", 4, |p, c| p.status(c).into()),
            ("FRAME_ID", 2, |p, c| p.column_frame_id(c).into()),
        ];
        for (name, width, get) in column_fields {
            let h = hashes.entry(name).or_insert_with(Md5::new);
            (0..columns).for_each(|c| feed(h, get(&p, c), width));
        }
        for (name, width, get) in &fields {
            let h = hashes.entry(name).or_insert_with(Md5::new);
            for b in 0..beams {
                (0..columns).for_each(|c| feed(h, get(&p, c, b), *width));
            }
        }
    }
    hashes.into_iter().map(|(k, h)| (k.to_owned(), h.hex())).collect()
}

/// `scans[0]`: the staggered image of the one frame, indexed by measurement id.
fn scan_hashes(packets: &[Vec<u8>], g: &OusterGeometry) -> BTreeMap<String, String> {
    let (w, beams) = (usize::from(g.columns_per_frame), usize::from(g.pixels_per_column));
    let fields = pixel_fields(g.profile);
    let mut columns: BTreeMap<&str, Vec<u64>> = BTreeMap::new();
    let mut images: Vec<Vec<u64>> = vec![vec![0; w * beams]; fields.len()];
    let mut frame_id = None;
    for bytes in packets {
        let p = Packet::new_checked(&bytes[..], g).unwrap();
        frame_id = Some(p.packet_frame_id());
        for c in (0..usize::from(g.columns_per_packet)).filter(|c| p.column_valid(*c)) {
            let m = usize::from(p.measurement_id(c));
            let values = [
                ("TIMESTAMP", p.timestamp(c)),
                ("STATUS", p.status(c).into()),
                ("MEASUREMENT_ID", p.measurement_id(c).into()),
                ("ENCODER_COUNT", p.encoder_count(c).into()),
            ];
            for (name, v) in values {
                columns.entry(name).or_insert_with(|| vec![0; w])[m] = v;
            }
            for (image, (_, _, get)) in images.iter_mut().zip(&fields) {
                (0..beams).for_each(|b| image[b * w + m] = get(&p, c, b));
            }
        }
    }
    let mut out = BTreeMap::new();
    out.insert("FRAME_ID".to_owned(), frame_id.unwrap().to_string());
    for (name, values) in columns {
        let width = if name == "MEASUREMENT_ID" { 2 } else { 8 };
        let mut h = Md5::new();
        values.iter().for_each(|v| feed(&mut h, *v, width));
        out.insert(name.to_owned(), h.hex());
    }
    for (image, (name, width, _)) in images.iter().zip(&fields) {
        let mut h = Md5::new();
        image.iter().for_each(|v| feed(&mut h, *v, *width));
        out.insert((*name).to_owned(), h.hex());
    }
    out
}

/// Compares every key of `expected` (an object of strings) with ours; returns how many.
fn compare(what: &str, expected: &serde_json::Value, ours: &BTreeMap<String, String>) -> usize {
    let expected = expected.as_object().unwrap();
    for (key, want) in expected {
        assert_eq!(ours.get(key).map(String::as_str), want.as_str(), "{what} {key}");
    }
    expected.len()
}

/// Every point decoded against the manual's formula in f64: returns (points, max error m).
fn xyz_against_manual(
    cal: &Calibration,
    packets: &[Vec<u8>],
    metadata: &serde_json::Value,
) -> (usize, f64) {
    let angles = |k: &str| -> Vec<f64> {
        metadata[k].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
    };
    let (altitude, azimuth) = (angles("beam_altitude_angles"), angles("beam_azimuth_angles"));
    let n = metadata["lidar_origin_to_beam_origin_mm"].as_f64().unwrap();
    let t = angles("lidar_to_sensor_transform");
    let w = f64::from(cal.ouster.columns_per_frame);
    let g = cal.ouster;
    let (mut count, mut worst) = (0, 0.0f64);
    for bytes in packets {
        let p = Packet::new_checked(&bytes[..], &g).unwrap();
        let mut points = Vec::new();
        decode_packet(cal, bytes, &mut |r| points.push(r)).unwrap();
        let mut it = points.iter();
        for c in (0..usize::from(g.columns_per_packet)).filter(|c| p.column_valid(*c)) {
            let theta_e = 2.0 * std::f64::consts::PI * (1.0 - f64::from(p.measurement_id(c)) / w);
            for b in 0..usize::from(g.pixels_per_column) {
                for echo in 0..if g.profile == Profile::Dual { 2 } else { 1 } {
                    let r = f64::from(p.range(c, b, echo));
                    if r == 0.0 {
                        continue;
                    }
                    let theta = theta_e - azimuth[b].to_radians();
                    let phi = altitude[b].to_radians();
                    let lidar = [
                        (r - n) * theta.cos() * phi.cos() + n * theta_e.cos(),
                        (r - n) * theta.sin() * phi.cos() + n * theta_e.sin(),
                        (r - n) * phi.sin(),
                    ];
                    let sensor: Vec<f64> = (0..3)
                        .map(|i| {
                            (0..3).map(|j| t[4 * i + j] * lidar[j]).sum::<f64>() + t[4 * i + 3]
                        })
                        .map(|mm| mm * 1e-3)
                        .collect();
                    let got = it.next().expect("a decoded point per non-zero range").point;
                    assert_eq!(usize::from(got.ring), b);
                    let e = [got.x, got.y, got.z]
                        .iter()
                        .zip(&sensor)
                        .map(|(a, b)| (f64::from(*a) - b).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    worst = worst.max(e);
                    count += 1;
                }
            }
        }
        assert!(it.next().is_none(), "no extra points");
    }
    (count, worst)
}

fn check(folder: &str, profile: Profile) {
    md5::self_test();
    let Some(dir) = data_dir(folder) else { return };
    let json_path = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            p.extension().is_some_and(|e| e == "json")
                && !p.to_string_lossy().ends_with("_digest.json")
        })
        .unwrap();
    let digest_path = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.to_string_lossy().ends_with("_digest.json"))
        .unwrap();
    let cal = calibration::load(Model::Ouster, &json_path).unwrap();
    assert_eq!(cal.ouster.profile, profile);
    assert_eq!((cal.ouster.pixels_per_column, cal.ouster.columns_per_frame), (32, 1024));
    let packets = lidar_packets(&file_with(&dir, "pcap"), &cal.ouster);
    let digest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&digest_path).unwrap()).unwrap();
    let packet_keys =
        compare("packet_hash", &digest["packet_hash"], &packet_hashes(&packets, &cal.ouster));
    let scans = digest["scans"].as_array().unwrap();
    assert_eq!(scans.len(), 1);
    let scan_keys = compare("scans[0]", &scans[0], &scan_hashes(&packets, &cal.ouster));
    let metadata: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let (points, worst) = xyz_against_manual(&cal, &packets, &metadata);
    println!(
        "{folder}: {} lidar packets; {packet_keys} packet md5s and {scan_keys} scan md5s \
         (ENCODER_COUNT included) reproduced; {points} points, max {:.4} mm from the manual's \
         range-to-xyz in f64",
        packets.len(),
        worst * 1e3
    );
    assert!(worst < 1e-4, "{folder}: {worst} m");
}

#[test]
fn os1_legacy_digest_and_xyz() {
    check("ouster-os1-legacy", Profile::Legacy);
}

#[test]
fn os0_dual_digest_and_xyz() {
    check("ouster-os0-rng19-dual", Profile::Dual);
}

#[test]
fn decode_capture_reads_the_metadata_and_skips_imu_packets() {
    let Some(dir) = data_dir("ouster-os0-rng19-dual") else { return };
    let json = dir.join("OS-0-32-U1_v2.2.0_1024x10.json");
    let (points, stats, _) =
        roomcal::lidar::decode_capture(Model::Ouster, Some(&json), &file_with(&dir, "pcap"))
            .unwrap();
    assert_eq!(stats.packets, 64);
    assert_eq!((stats.position, stats.dropped()), (10, 0), "10 IMU packets: {stats:?}");
    assert!(!points.is_empty() && points.iter().all(|p| p.x.is_finite() && p.ring < 32));
}
