//! PandarXT32 and PandarQT64 against tier4/nebula's reference clouds in
//! `../shared/data/pcap/hesai-pandarxt32` and `-pandarqt64` (see its README): roomcal decodes
//! every return, this test applies nebula's own choices on top (its range limits, its 0.1 m
//! dual-return rule, its scan cut at azimuth 0 by each point's corrected azimuth) and then
//! demands the reference's point count, in the reference's order, every point within 1 mm.
//! Skips with a message when `../shared` (or `$ROOMCAL_SHARED`) is absent.

use std::path::Path;

use roomcal::lidar::{calibration, decode_packet, Calibration, Model, Return};

use crate::common::pcap_data;
use pcap_data::{data_dir, file_with};

/// nebula's decoder settings for one sensor (README: its test's TEST_CONFIGS).
struct Nebula {
    min_range: f32,
    max_range: f32,
    /// dual_return_distance_threshold, m.
    dual_threshold: f32,
}

/// nebula's scans, rebuilt: every point goes to the scan its corrected azimuth (the block
/// azimuth plus the channel offset) falls in, the cut at 0°; a scan is complete once a block
/// has passed the cut by more than every channel's negative offset (no later point can
/// still belong to it).
struct Scans {
    scans: Vec<Vec<[f32; 3]>>,
    /// Index of the scan the current block belongs to by its own azimuth.
    current: usize,
    last_azimuth: Option<u16>,
    complete: usize,
}

impl Scans {
    fn push_block(&mut self, azimuth: u16, max_negative_offset: f32) {
        if self.last_azimuth.is_some_and(|last| azimuth < last) {
            self.current += 1;
        }
        self.last_azimuth = Some(azimuth);
        if f32::from(azimuth) / 100.0 > max_negative_offset {
            self.complete = self.current;
        }
    }

    fn push_point(&mut self, corrected_azimuth_deg: f32, p: [f32; 3]) {
        let scan = match corrected_azimuth_deg {
            a if a >= 360.0 => self.current + 1,
            a if a < 0.0 => self.current.wrapping_sub(1),
            _ => self.current,
        };
        if scan == usize::MAX {
            return;
        }
        if self.scans.len() <= scan {
            self.scans.resize(scan + 1, Vec::new());
        }
        self.scans[scan].push(p);
    }
}

/// Decodes the capture and returns nebula's last complete scan in nebula's frame (x right,
/// y forward, z up) with the number of packets decoded.
fn nebula_scan(cal: &Calibration, capture: &Path, nebula: &Nebula) -> (Vec<[f32; 3]>, usize) {
    let (datagrams, _) = roomcal::lidar::pcap::read_udp(capture).unwrap();
    let offsets: Vec<f32> = cal.active().iter().map(|c| c.azimuth_offset.to_degrees()).collect();
    let max_negative = offsets.iter().fold(0.0f32, |m, o| m.max(-o));
    let mut scans = Scans { scans: vec![Vec::new()], current: 0, last_azimuth: None, complete: 0 };
    let mut packets = 0;
    for d in &datagrams {
        let mut returns: Vec<Return> = Vec::new();
        let summary = decode_packet(cal, &d.payload, &mut |r| returns.push(r)).unwrap();
        packets += 1;
        let echoes = summary.return_mode.returns();
        // Returns come block group by block group, channel by channel, echo by echo.
        let mut i = 0;
        while i < returns.len() {
            let group = returns[i].block as usize / echoes;
            let first_of_group = i;
            let azimuth = returns[i].azimuth;
            scans.push_block(azimuth, max_negative);
            while i < returns.len() && returns[i].block as usize / echoes == group {
                let r = returns[i];
                let twins = returns[first_of_group..]
                    .iter()
                    .take_while(|o| o.block as usize / echoes == group)
                    .filter(|o| o.point.ring == r.point.ring && o.echo != r.echo);
                let last_echo = usize::from(r.echo) == echoes - 1;
                let close =
                    twins.clone().any(|o| (o.distance - r.distance).abs() < nebula.dual_threshold);
                i += 1;
                if r.distance < nebula.min_range || r.distance > nebula.max_range {
                    continue;
                }
                if !last_echo && close {
                    continue;
                }
                let corrected = f32::from(r.azimuth) / 100.0 + offsets[usize::from(r.point.ring)];
                // Ours is x forward, y left; nebula leaves Hesai points x right, y forward.
                scans.push_point(corrected, [-r.point.y, r.point.x, r.point.z]);
            }
        }
    }
    // The last scan whose every point has been seen, completed before the capture ends.
    let last_complete = scans.complete.saturating_sub(1);
    (scans.scans.swap_remove(last_complete), packets)
}

fn check(folder: &str, model: Model, csv: &str, nebula: Nebula) {
    let Some(dir) = data_dir(folder) else { return };
    let cal = calibration::load(model, &dir.join(csv)).unwrap();
    let (decoded, packets) = nebula_scan(&cal, &file_with(&dir, "pcap"), &nebula);
    let reference: Vec<[f32; 3]> = roomcal::lidar::pcd::read(file_with(&dir, "pcd"))
        .unwrap()
        .iter()
        .map(|p| [p.x, p.y, p.z])
        .collect();
    let errors: Vec<f32> = decoded
        .iter()
        .zip(&reference)
        .map(|(a, b)| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        })
        .collect();
    let mut sorted = errors.clone();
    sorted.sort_by(f32::total_cmp);
    let max = sorted.last().copied().unwrap_or(f32::NAN);
    let p99 = sorted.get(sorted.len() * 99 / 100).copied().unwrap_or(f32::NAN);
    println!(
        "{folder}: {packets} packets; scan of {} points vs {} reference points; point by point \
         in order: max {:.4} mm, p99 {:.4} mm",
        decoded.len(),
        reference.len(),
        max * 1e3,
        p99 * 1e3
    );
    assert_eq!(decoded.len(), reference.len(), "{folder}: point count");
    let first_bad = errors.iter().position(|e| *e > 0.001);
    assert_eq!(first_bad, None, "{folder}: first point off by more than 1 mm");
}

#[test]
fn pandarxt32_matches_nebula_point_for_point() {
    let nebula = Nebula { min_range: 0.05, max_range: 120.0, dual_threshold: 0.1 };
    check("hesai-pandarxt32", Model::PandarXt32, "PandarXT32.csv", nebula);
}

#[test]
fn pandarqt64_matches_nebula_point_for_point() {
    let nebula = Nebula { min_range: 0.1, max_range: 60.0, dual_threshold: 0.1 };
    check("hesai-pandarqt64", Model::PandarQt64, "PandarQT64.csv", nebula);
}

#[test]
fn nominal_tables_match_the_shipped_calibrations() {
    for (model, folder, csv, limit_deg) in [
        (Model::PandarXt32, "hesai-pandarxt32", "PandarXT32.csv", 0.2),
        (Model::PandarQt64, "hesai-pandarqt64", "PandarQT64.csv", 1e-4),
    ] {
        let Some(dir) = data_dir(folder) else { return };
        let file = calibration::load(model, &dir.join(csv)).unwrap();
        let nominal = Calibration::nominal(model);
        let worst = file
            .active()
            .iter()
            .zip(nominal.active())
            .map(|(a, b)| {
                (a.elevation - b.elevation).abs().max((a.azimuth_offset - b.azimuth_offset).abs())
            })
            .fold(0.0f32, f32::max)
            .to_degrees();
        println!("{folder}: nominal table within {worst:.5}° of {csv}");
        assert!(worst < limit_deg, "{folder}: {worst}°");
    }
}

#[test]
fn every_capture_packet_decodes_and_return_modes_are_read() {
    for (model, folder, mode) in [
        (Model::PandarXt32, "hesai-pandarxt32", 0x39u8),
        (Model::PandarQt64, "hesai-pandarqt64", 0x3b),
    ] {
        let Some(dir) = data_dir(folder) else { return };
        let (datagrams, _) = roomcal::lidar::pcap::read_udp(file_with(&dir, "pcap")).unwrap();
        let cal = Calibration::nominal(model);
        for d in &datagrams {
            let p = roomcal::lidar::hesai::Packet::new_checked(&d.payload[..], model).unwrap();
            assert_eq!(p.return_mode_byte(), mode);
            assert_eq!(roomcal::lidar::detect_model(&d.payload), Some(model));
            decode_packet(&cal, &d.payload, &mut |r| assert!(r.point.x.is_finite())).unwrap();
        }
    }
}
