//! The LiDAR board detector against the simulator's truth: every placeable board found,
//! hole centres within millimetres, no false boards; figures per LiDAR model printed
//! (`cargo test --test holes_sim -- --nocapture`).

use std::path::Path;

use roomcal::detect::holes::{HoleConfig, HoleDetector, LidarBoard};
use roomcal::geometry::Vec3;
use roomcal::sim::{simulate, BoardTruth, ImageNoise, SimOptions};
use roomcal::target::{LidarModel, Room};

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

fn run(model: LidarModel, seeds: &[u64]) -> Figures {
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

/// The truth board this detection is, with the per-hole errors (m), when its holes are
/// within 10 cm of a truth board's.
fn best_truth(board: &LidarBoard, truth: &[BoardTruth]) -> Option<(usize, Vec<f64>)> {
    truth.iter().enumerate().find_map(|(i, t)| {
        let err: Vec<f64> = board
            .holes
            .iter()
            .zip(&t.holes_lidar)
            .map(|(h, th)| (h - Vec3::new(th[0], th[1], th[2])).norm())
            .collect();
        (err.iter().all(|&e| e < 0.1)).then_some((i, err))
    })
}

fn report(name: &str, f: &Figures) -> f64 {
    let n = f.errors_mm.len().max(1) as f64;
    let mean = f.errors_mm.iter().sum::<f64>() / n;
    let max = f.errors_mm.iter().cloned().fold(0.0, f64::max);
    let rms_norm = (f.normalised.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    println!(
        "{name}: boards {}, placeable {}, found {} of the placeable + {} others, false {}, \
         hole error mean {mean:.2} mm max {max:.2} mm, RMS(error/σ) {rms_norm:.2}",
        f.boards, f.placeable, f.found_placeable, f.found_other, f.false_boards
    );
    mean
}

#[test]
fn pandar64_places_every_placeable_board() {
    let f = run(LidarModel::Pandar64, &[1, 2, 3, 7]);
    let mean = report("Pandar64", &f);
    assert_eq!(f.false_boards, 0);
    assert_eq!(f.found_placeable, f.placeable);
    assert!(f.placeable >= 8, "too few placeable boards to judge: {}", f.placeable);
    assert!(mean <= 5.0, "mean hole error {mean} mm");
}

#[test]
fn vlp32c_and_vlp16_figures() {
    for (name, model) in [("VLP-32C", LidarModel::Vlp32c), ("VLP-16", LidarModel::Vlp16)] {
        let f = run(model, &[1, 2]);
        let mean = report(name, &f);
        assert_eq!(f.false_boards, 0, "{name}");
        if !f.errors_mm.is_empty() {
            assert!(mean <= 10.0, "{name}: mean hole error {mean} mm");
        }
    }
}
