//! The LiDAR board detector against the simulator's truth: every placeable board found,
//! hole centres within millimetres, no false boards; figures per LiDAR model printed
//! (`cargo test --release --test holes_sim -- --nocapture`). Also: several sweeps of a
//! static scene given together reduce the hole error; and (ignored, about a minute) the
//! hole σ against the actual errors over 12 scenes per LiDAR model.

use crate::common::truth;

use std::collections::BTreeMap;
use std::path::Path;

use roomcal::detect::holes::{HoleConfig, HoleDetector};
use roomcal::geometry::{Se3, Vec3};
use roomcal::lidar::{Model, Point};
use roomcal::sim::raycast::{beam_elevations, AZIMUTH_STEP_DEG};
use roomcal::sim::rng::Rng;
use roomcal::sim::world::World;
use roomcal::sim::{simulate, BoardTruth, ImageNoise, Scene, SimOptions};
use roomcal::target::Room;
use truth::best_truth;

fn room() -> Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

/// A board the points can place: two holes crossed by two scan lines, many points.
fn placeable(t: &BoardTruth) -> bool {
    t.hole_scan_lines.iter().filter(|&&l| l >= 2).count() >= 2 && t.lidar_points >= 200
}

/// Figures over several seeds for one LiDAR model.
#[derive(Debug, Default)]
struct Figures {
    boards: usize,
    placeable: usize,
    found_placeable: usize,
    found_other: usize,
    false_boards: usize,
    errors_mm: Vec<f64>,
    /// Per detected hole: error / claimed σ.
    normalised: Vec<f64>,
}

fn run(model: Model, seeds: &[u64]) -> Figures {
    let room = room();
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut found = Vec::new();
    let mut f = Figures::default();
    for &seed in seeds {
        let options = SimOptions {
            seed,
            lidar: Some(model),
            image: ImageNoise { supersample: 1, ..ImageNoise::default() },
            ..SimOptions::default()
        };
        let scene = simulate(&room, &options).unwrap();
        let cloud = scene.cloud.as_ref().unwrap();
        detector.detect(cloud, &mut found);
        for r in detector.refused() {
            println!(
                "  seed {seed}: refused plane at {:?} ({} points, lines {:?}): {}",
                r.centroid.as_slice(),
                r.points,
                r.hole_scan_lines,
                r.reason
            );
            if let Some(g) = r.best_guess {
                // The nearest truth board, to tell a bad guess from no board.
                let guess_error = |t: &BoardTruth| -> Vec<f64> {
                    room.board
                        .holes
                        .iter()
                        .zip(&t.holes_lidar)
                        .map(|(h, th)| {
                            (g.act(&Vec3::new(h[0], h[1], 0.0)) - Vec3::new(th[0], th[1], th[2]))
                                .norm()
                                * 1e3
                        })
                        .collect()
                };
                let nearest = scene
                    .truth
                    .boards
                    .iter()
                    .map(guess_error)
                    .min_by(|a, b| a.iter().sum::<f64>().total_cmp(&b.iter().sum::<f64>()));
                if let Some(e) = nearest.filter(|e| e.iter().all(|&x| x < 1000.0)) {
                    println!("     its guess is off by {e:.1?} mm");
                }
            }
        }
        let mut matched = vec![false; scene.truth.boards.len()];
        for board in &found {
            let Some((i, err)) = best_truth(board, &scene.truth.boards) else {
                f.false_boards += 1;
                println!("  seed {seed}: FALSE board at {:?}", board.pose.translation.as_slice());
                continue;
            };
            matched[i] = true;
            let t = &scene.truth.boards[i];
            if placeable(t) {
                f.found_placeable += 1;
            } else {
                f.found_other += 1;
            }
            for (k, e) in err.iter().enumerate() {
                f.errors_mm.push(e * 1e3);
                f.normalised.push(e / board.hole_sigma_m[k]);
            }
            println!(
                "  seed {seed} board {i}: lines {:?} err mm {:?} sigma mm {:?}",
                board.hole_scan_lines,
                err.iter().map(|e| (e * 1e4).round() / 10.0).collect::<Vec<_>>(),
                board.hole_sigma_m.iter().map(|e| (e * 1e4).round() / 10.0).collect::<Vec<_>>()
            );
        }
        for (i, t) in scene.truth.boards.iter().enumerate() {
            f.boards += 1;
            if placeable(t) {
                f.placeable += 1;
                if !matched[i] {
                    println!(
                        "  seed {seed} board {i}: MISSED (truth lines {:?}, {} points, holes {:?})",
                        t.hole_scan_lines, t.lidar_points, t.holes_lidar
                    );
                }
            }
        }
    }
    f
}

/// Prints the figures; returns the mean hole error (mm) and RMS(error / σ).
fn report(name: &str, f: &Figures) -> (f64, f64) {
    let n = f.errors_mm.len().max(1) as f64;
    let mean = f.errors_mm.iter().sum::<f64>() / n;
    let max = f.errors_mm.iter().cloned().fold(0.0, f64::max);
    let rms_norm = (f.normalised.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    println!(
        "{name}: boards {}, placeable {}, found {} of the placeable + {} others, false {}, \
         hole error mean {mean:.2} mm max {max:.2} mm, RMS(error/σ) {rms_norm:.2}",
        f.boards, f.placeable, f.found_placeable, f.found_other, f.false_boards
    );
    (mean, rms_norm)
}

#[test]
fn pandar64_places_every_placeable_board() {
    let f = run(Model::Pandar64, &[1, 2, 3, 7]);
    let (mean, rms_norm) = report("Pandar64", &f);
    assert_eq!(f.false_boards, 0);
    assert_eq!(f.found_placeable, f.placeable);
    assert!(f.placeable >= 8, "too few placeable boards to judge: {}", f.placeable);
    assert!(mean <= 5.0, "mean hole error {mean} mm");
    // The solver weighs holes by their σ: it must be neither far too small nor too large.
    assert!((0.6..1.6).contains(&rms_norm), "RMS(error/σ) {rms_norm}");
}

#[test]
fn vlp32c_and_vlp16_figures() {
    for (name, model) in [("VLP-32C", Model::Vlp32c), ("VLP-16", Model::Vlp16)] {
        let f = run(model, &[1, 2]);
        let (mean, _) = report(name, &f);
        assert_eq!(f.false_boards, 0, "{name}");
        assert_eq!(f.found_placeable, f.placeable, "{name}");
        if !f.errors_mm.is_empty() {
            assert!(mean <= 10.0, "{name}: mean hole error {mean} mm");
        }
    }
}

/// `n` sweeps of the static scene of `scene`, concatenated: each fired at azimuths offset
/// by a fraction of the 0.2° step (a spinning LiDAR is not phase-locked to the room) and
/// with its own range noise, ray-cast through the scene's own board poses.
fn sweeps(scene: &Scene, model: Model, n: usize, noise_seed: u64) -> Vec<Point> {
    let camera_in_lidar = scene.truth.lidar_to_camera.as_ref().unwrap().to_se3().inverse();
    let poses: Vec<Se3> = scene
        .truth
        .boards
        .iter()
        .map(|b| camera_in_lidar.compose(&b.board_to_camera.to_se3()))
        .collect();
    let world = World::new(&scene.room.board, poses, &mut Rng::new(scene.truth.seed));
    let elevations = beam_elevations(model).unwrap();
    let mut rng = Rng::new(noise_seed);
    let columns = (360.0 / AZIMUTH_STEP_DEG).round() as usize;
    let mut points = Vec::new();
    for s in 0..n {
        let phase = s as f64 / n as f64 * AZIMUTH_STEP_DEG;
        for column in 0..columns {
            let azimuth = (column as f64 * AZIMUTH_STEP_DEG + phase).to_radians();
            for (ring, elevation) in elevations.iter().enumerate() {
                let e = elevation.to_radians();
                let dir = Vec3::new(e.cos() * azimuth.cos(), e.cos() * azimuth.sin(), e.sin());
                let Some(hit) = world.cast(&Vec3::zeros(), &dir) else { continue };
                let p = dir * (hit.distance + scene.truth.range_noise_m * rng.normal());
                let (x, y, z) = (p.x as f32, p.y as f32, p.z as f32);
                points.push(Point { x, y, z, ring: ring as u16, ..Point::default() });
            }
        }
    }
    points
}

/// Hole errors (mm) per (seed, board) found from `n` sweeps of each scene of `seeds`;
/// asserts every placeable board is found.
fn errors_from_sweeps(seeds: &[u64], n: usize) -> BTreeMap<(u64, usize), Vec<f64>> {
    let room = room();
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut found = Vec::new();
    let mut errors = BTreeMap::new();
    for &seed in seeds {
        let options = SimOptions {
            seed,
            image: ImageNoise { supersample: 1, ..ImageNoise::default() },
            ..SimOptions::default()
        };
        let scene = simulate(&room, &options).unwrap();
        let cloud = sweeps(&scene, Model::Pandar64, n, 1000 + seed);
        let start = std::time::Instant::now();
        detector.detect(&cloud, &mut found);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        println!("seed {seed}, {n} sweep(s): {} points in {ms:.0} ms", cloud.len());
        for (i, t) in scene.truth.boards.iter().enumerate() {
            let hit = found.iter().find_map(|b| best_truth(b, &scene.truth.boards[i..=i]));
            match hit {
                Some((_, err)) => {
                    errors.insert((seed, i), err.iter().map(|e| e * 1e3).collect());
                }
                None if placeable(t) => {
                    for r in detector.refused() {
                        println!("  refused at {:?}: {}", r.centroid.as_slice(), r.reason);
                    }
                    panic!("seed {seed}, {n} sweep(s): board {i} missed: {:?}", t.holes_lidar)
                }
                None => {}
            }
        }
    }
    errors
}

/// Mean and largest error over the boards of `errors` that `common` also holds.
fn mean_max(
    errors: &BTreeMap<(u64, usize), Vec<f64>>,
    common: &BTreeMap<(u64, usize), Vec<f64>>,
) -> (f64, f64, usize) {
    let all: Vec<f64> = errors
        .iter()
        .filter(|(k, _)| common.contains_key(k))
        .flat_map(|(_, e)| e.iter().copied())
        .collect();
    let mean = all.iter().sum::<f64>() / all.len() as f64;
    (mean, all.iter().cloned().fold(0.0, f64::max), all.len())
}

#[test]
fn several_sweeps_reduce_the_hole_error() {
    let seeds = [1, 2, 3];
    let one = errors_from_sweeps(&seeds, 1);
    let four = errors_from_sweeps(&seeds, 4);
    let (mean1, max1, holes) = mean_max(&one, &four);
    let (mean4, max4, _) = mean_max(&four, &one);
    println!("{holes} holes found in both: 1 sweep: error mean {mean1:.2} mm, max {max1:.2} mm");
    println!("{holes} holes found in both: 4 sweeps: error mean {mean4:.2} mm, max {max4:.2} mm");
    assert!(holes >= 16, "too few boards to compare");
    // Measured 1.73 → 1.40 mm (1.81 → 1.40 before a line's occluded ends lost their
    // returns in front of the plane, which helped the single sweep): the sweeps repeat the
    // scan pattern, so what the lines' spacing leaves unknown does not average out.
    assert!(mean4 < 0.85 * mean1, "4 sweeps: {mean4:.2} mm vs 1 sweep: {mean1:.2} mm");
}

/// The hole σ against the actual errors over many scenes (`cargo test --release --test
/// holes_sim sigma -- --ignored --nocapture`): RMS(error / σ) near 1 means the solver's
/// weights are right.
#[test]
#[ignore = "about a minute: many scenes"]
fn sigma_calibration_over_many_scenes() {
    let seeds: Vec<u64> = (1..=12).collect();
    let models =
        [("Pandar64", Model::Pandar64), ("VLP-32C", Model::Vlp32c), ("VLP-16", Model::Vlp16)];
    for (name, model) in models {
        let f = run(model, &seeds);
        report(name, &f);
    }
}
