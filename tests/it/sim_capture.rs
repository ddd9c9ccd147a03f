//! The whole LiDAR path through the wire: simulate a room, write its sweep as a packet
//! capture (`roomcal simulate --capture`), read the capture back (pcap reader →
//! `SweepAssembler`, with the angle file the simulator wrote), and check that the decoded
//! points are the cast points (within 1 mm) and that the hole detector finds the same boards
//! and hole centres in them as in the PCD the simulator wrote, matching the truth.
//! Figures printed with `cargo test --test it sim_capture:: -- --nocapture`.

use crate::common::truth;

use std::path::{Path, PathBuf};

use roomcal::detect::holes::{HoleConfig, HoleDetector, LidarBoard};
use roomcal::geometry::{Mat3, Se3, Vec3};
use roomcal::lidar::{calibration, pcap, pcd, Calibration, Model, Point};
use roomcal::lidar::{SweepAssembler, SweepConfig};
use roomcal::sim::rng::Rng;
use roomcal::sim::world::World;
use roomcal::sim::{
    raycast, simulate, write_capture, write_scene, BoardTruth, ImageNoise, SimOptions,
};
use roomcal::target::Room;
use truth::best_truth;

fn room() -> Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

/// A scratch directory under the target dir, fresh for each call.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// One scene through both paths.
struct Run {
    truth: Vec<BoardTruth>,
    cast: Vec<Point>,
    from_pcd: Vec<Point>,
    from_packets: Vec<Point>,
    packets: u64,
    sweeps: usize,
}

fn run(model: Model, seed: u64) -> Run {
    let options = SimOptions {
        seed,
        lidar: Some(model),
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let scene = simulate(&room(), &options).unwrap();
    let dir = scratch(&format!("sim-capture-{model:?}-{seed}"));
    write_scene(&scene, &dir).unwrap();
    let files = write_capture(&scene, &dir).unwrap();
    assert_eq!(files.capture, dir.join("cloud.pcap"));

    let cal = match &files.calibration {
        Some(path) => calibration::load(model, path).unwrap(),
        None => Calibration::nominal(model),
    };
    // The file holds exactly the table the rays were cast with.
    assert_eq!(cal, scene.firings.as_ref().unwrap().calibration);

    let capture = pcap::Capture::open(&files.capture).unwrap();
    let mut buffer = vec![Point::default(); 2 * model.lasers() * 1800];
    let mut assembler = SweepAssembler::new(cal, SweepConfig::for_calibration(&cal), &mut buffer);
    let (mut from_packets, mut sweeps) = (Vec::new(), 0);
    let mut collect = |s: roomcal::lidar::Sweep<'_>| {
        assert_eq!((s.lost, s.overflow), (0, 0));
        from_packets.extend_from_slice(s.points);
        sweeps += 1;
    };
    for d in capture.datagrams().unwrap() {
        let d = d.unwrap();
        assembler.push(d.dst.port(), d.payload, &mut collect);
    }
    assembler.flush(&mut collect);
    let stats = assembler.stats();
    assert_eq!(stats.dropped() + stats.lost + stats.position, 0, "{stats:?}");
    // `roomcal decode --calibration angles.csv cloud.pcap` decodes the same points.
    let (decoded, _, _) =
        roomcal::lidar::decode_capture(model, files.calibration.as_deref(), &files.capture)
            .unwrap();
    assert_eq!(decoded, from_packets);
    Run {
        truth: scene.truth.boards.clone(),
        cast: scene.cloud.clone().unwrap(),
        from_pcd: pcd::read(dir.join("cloud.pcd")).unwrap(),
        from_packets,
        packets: stats.packets,
        sweeps,
    }
}

/// A board the points can place: two holes crossed by two scan lines, many points (as
/// tests/it/holes_sim.rs).
fn placeable(t: &BoardTruth) -> bool {
    t.hole_scan_lines.iter().filter(|&&l| l >= 2).count() >= 2 && t.lidar_points >= 200
}

/// Largest distance between the decoded and the cast points, paired in firing order (both
/// list every return laser by laser, sequence by sequence), m.
fn max_point_error(run: &Run) -> f64 {
    assert_eq!(run.from_packets.len(), run.cast.len(), "decoded vs cast point count");
    run.from_packets
        .iter()
        .zip(&run.cast)
        .map(|(d, c)| {
            assert_eq!((d.ring, d.intensity), (c.ring, c.intensity));
            let e = Vec3::new(f64::from(d.x - c.x), f64::from(d.y - c.y), f64::from(d.z - c.z));
            e.norm()
        })
        .fold(0.0, f64::max)
}

/// Boards found in both clouds, hole errors against the truth (mm) for the packet path, and
/// the largest distance between the two paths' hole centres (mm).
struct Detections {
    pcd: Vec<LidarBoard>,
    packets: Vec<LidarBoard>,
    errors_mm: Vec<f64>,
    paths_apart_mm: f64,
}

fn detect_both(run: &Run) -> Detections {
    let mut detector = HoleDetector::new(&room().board, HoleConfig::default());
    let (mut pcd, mut packets) = (Vec::new(), Vec::new());
    detector.detect(&run.from_pcd, &mut pcd);
    detector.detect(&run.from_packets, &mut packets);
    let mut errors_mm = Vec::new();
    for b in &packets {
        let (_, err) = best_truth(b, &run.truth).expect("a detected board is a true board");
        errors_mm.extend(err.iter().map(|e| e * 1e3));
    }
    let mut paths_apart_mm: f64 = 0.0;
    for (a, b) in pcd.iter().zip(&packets) {
        for (ha, hb) in a.holes.iter().zip(&b.holes) {
            paths_apart_mm = paths_apart_mm.max((ha - hb).norm() * 1e3);
        }
    }
    Detections { pcd, packets, errors_mm, paths_apart_mm }
}

fn report(name: &str, run: &Run, d: &Detections) -> f64 {
    let mean = d.errors_mm.iter().sum::<f64>() / d.errors_mm.len().max(1) as f64 + 0.0;
    println!(
        "{name}: {} packets, {} sweep(s), {} points, max |decoded - cast| {:.3} mm; boards \
         {} truth ({} placeable), {} from PCD, {} from packets; hole error mean {mean:.2} mm; \
         PCD vs packet hole centres at most {:.3} mm apart",
        run.packets,
        run.sweeps,
        run.from_packets.len(),
        max_point_error(run) * 1e3,
        run.truth.len(),
        run.truth.iter().filter(|t| placeable(t)).count(),
        d.pcd.len(),
        d.packets.len(),
        d.paths_apart_mm
    );
    mean
}

/// Detects in the decoded and in the cast cloud: both find the same boards, at least every
/// placeable one (two or more), with hole centres within 1 mm of each other; returns the
/// packet path's mean hole error against the truth (mm).
fn packets_and_pcd_place_every_board(name: &str, run: &Run) -> f64 {
    let d = detect_both(run);
    let mean = report(name, run, &d);
    let placeable = run.truth.iter().filter(|t| placeable(t)).count();
    assert!(placeable >= 2, "too few placeable boards to judge: {placeable}");
    assert!(
        d.packets.len() >= placeable,
        "{} boards found, {placeable} placeable",
        d.packets.len()
    );
    assert_eq!(d.packets.len(), d.pcd.len(), "packets and PCD find different boards");
    assert!(d.paths_apart_mm < 1.0, "{} mm", d.paths_apart_mm);
    mean
}

#[test]
fn pandar64_capture_decodes_to_the_cast_points_and_the_boards() {
    let run = run(Model::Pandar64, 7);
    assert_eq!(run.sweeps, 1, "one turn from the cut to the cut");
    assert!(max_point_error(&run) < 1e-3);
    let mean = packets_and_pcd_place_every_board("Pandar64", &run);
    // The same tolerance as the PCD path in tests/it/holes_sim.rs.
    assert!(mean <= 5.0, "mean hole error {mean} mm");
}

#[test]
fn vlp32c_capture_decodes_to_the_cast_points_and_the_same_detections() {
    let run = run(Model::Vlp32c, 8);
    assert_eq!(run.sweeps, 1);
    assert!(max_point_error(&run) < 1e-3);
    let mean = packets_and_pcd_place_every_board("VLP-32C", &run);
    // The same tolerance as the VLP-32C PCD path in tests/it/holes_sim.rs.
    assert!(mean <= 10.0, "mean hole error {mean} mm");
}

#[test]
fn vlp16_capture_decodes_to_the_cast_points() {
    // Two firings per block: the second's azimuth is only implied by interpolation.
    let run = run(Model::Vlp16, 3);
    assert!(max_point_error(&run) < 1e-3);
    assert_eq!(run.packets, 1800 / 24);
}

#[test]
fn real_pandar64_azimuth_offsets_decode_in_place() {
    // The scenes' Pandar64 casts with zero azimuth offsets; the unit's real table has them
    // (±1.042° … ±5.208°): cast a room with it, encode, decode, compare.
    let board = room().board;
    let facing = Mat3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
    let poses = vec![Se3 { rotation: facing, translation: Vec3::new(5.0, 0.5, -0.5) }];
    let world = World::new(&board, poses, &mut Rng::new(4));
    let cal = Calibration::from_degrees(
        Model::Pandar64,
        &calibration::PANDAR64_UNIT_ELEVATION,
        &calibration::PANDAR64_AZIMUTH,
    )
    .unwrap();
    let cast = raycast::sweep(&world, &cal, 0.02, 0, &mut Rng::new(5));
    assert!(cast.truth.board_points[0] > 500);
    let packets = roomcal::sim::capture::packets(&cast.firings).unwrap();
    let (decoded, stats) =
        roomcal::lidar::decode_payloads(&cal, packets.iter().map(|p| p.payload.as_slice()));
    assert_eq!((stats.packets, decoded.len()), (300, cast.points.len()));
    let worst = decoded
        .iter()
        .zip(&cast.points)
        .map(|(d, c)| {
            (Vec3::new(f64::from(d.x - c.x), f64::from(d.y - c.y), f64::from(d.z - c.z))).norm()
        })
        .fold(0.0, f64::max);
    println!(
        "Pandar64 with the unit's azimuth offsets: max |decoded - cast| {:.3} mm",
        worst * 1e3
    );
    assert!(worst < 1e-3);
    // Without the offsets the decoder would put them centimetres away: they matter.
    let nominal_azimuths = Calibration::from_degrees(
        Model::Pandar64,
        &calibration::PANDAR64_UNIT_ELEVATION,
        &[0.0; 64],
    )
    .unwrap();
    let (wrong, _) = roomcal::lidar::decode_payloads(
        &nominal_azimuths,
        packets.iter().map(|p| p.payload.as_slice()),
    );
    let far = wrong.iter().zip(&cast.points).filter(|(d, c)| (d.y - c.y).abs() > 0.05).count();
    assert!(far > decoded.len() / 4, "{far}");
}

#[test]
fn hesai_angle_file_round_trips_exactly() {
    let cal = roomcal::sim::raycast::calibration(Model::Pandar64).unwrap();
    let text = calibration::to_hesai_csv(&cal);
    let back = calibration::parse_hesai_csv(Model::Pandar64, &text, Path::new("angles.csv"));
    assert_eq!(back.unwrap(), cal);
    assert!(text.starts_with("Laser id,Elevation,Azimuth\n1,14.9,0\n"), "{text}");
    // The unit's table is not the nominal one: decoding needs the file.
    assert_ne!(cal, Calibration::nominal(Model::Pandar64));
}

#[test]
fn beam_elevations_are_the_angle_tables() {
    for model in [Model::Pandar64, Model::Vlp32c, Model::Vlp16] {
        let cal = raycast::calibration(model).unwrap();
        let degrees = raycast::beam_elevations(model).unwrap();
        assert_eq!(degrees.len(), cal.model.lasers());
        for (d, c) in degrees.iter().zip(cal.active()) {
            assert!((d.to_radians() - f64::from(c.elevation)).abs() < 1e-6, "{model:?} {d}");
        }
    }
}
