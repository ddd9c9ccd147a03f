//! The detector on the simulator's rooms (`roomcal::sim`): 1920×1200, six boards, textured
//! walls, vignetting, blur and noise at the simulator's defaults; a 70° radtan lens, a 90°
//! lens with strong barrel distortion, and a 120° fisheye. Every board must be found,
//! complete and in the order the truth numbers its corners (0.05 px mean, 0.3 px worst),
//! or — where a stand in front of it hides part of it, as the simulator draws them —
//! incomplete with only true corners.

use roomcal::detect::{Board, ChessboardDetector};
use roomcal::geometry::CameraModel;
use roomcal::sim::{simulate, SimOptions};
use roomcal::target::Room;

const ROOM: &str = include_str!("../../config/room.toml");

/// Corner errors of the complete boards against the truth, in truth order (`symmetric`
/// patterns may come half-turned); checks that every truth board was found, and that an
/// incomplete one carries only true corners. Returns (errors, complete boards).
fn errors(
    boards: &[Board],
    truth: &[Vec<[f64; 2]>],
    symmetric: bool,
    what: &str,
) -> (Vec<f64>, usize) {
    let mut all = Vec::new();
    let mut complete = 0;
    for (n, t) in truth.iter().enumerate() {
        let found =
            boards.iter().filter(|b| b.complete && b.corners.len() == t.len()).find_map(|b| {
                let err = |rev: bool| -> Vec<f64> {
                    (0..t.len())
                        .map(|i| {
                            let c = &b.corners[i];
                            let p = t[if rev { t.len() - 1 - i } else { i }];
                            ((c.x - p[0]).powi(2) + (c.y - p[1]).powi(2)).sqrt()
                        })
                        .collect()
                };
                let direct = err(false);
                if direct.iter().all(|&e| e < 1.0) {
                    return Some(direct);
                }
                let reversed = err(true);
                (symmetric && reversed.iter().all(|&e| e < 1.0)).then_some(reversed)
            });
        if let Some(e) = found {
            all.extend(e);
            complete += 1;
            continue;
        }
        let near = |c: &roomcal::detect::Corner| {
            t.iter().any(|p| ((c.x - p[0]).powi(2) + (c.y - p[1]).powi(2)).sqrt() < 0.5)
        };
        let partial = boards.iter().filter(|b| !b.complete).find(|b| b.corners.iter().any(&near));
        let Some(partial) = partial else { panic!("{what}: board {n} not found") };
        assert!(partial.corners.iter().all(near), "{what}: board {n} has a wrong corner");
        eprintln!(
            "{what}: board {n} partly hidden, {} of {} corners",
            partial.corners.len(),
            t.len()
        );
    }
    (all, complete)
}

fn run(options: SimOptions, what: &str) -> (f64, f64) {
    let room: Room = toml::from_str(ROOM).unwrap();
    let scene = simulate(&room, &options).unwrap();
    let (w, h) = (scene.truth.camera.width, scene.truth.camera.height);
    let mut det = ChessboardDetector::new(w, h, &scene.room.board).unwrap();
    let mut boards = Vec::new();
    det.detect(&scene.image, &mut boards).unwrap();
    let truth: Vec<Vec<[f64; 2]>> =
        scene.truth.boards.iter().map(|b| b.corners_px.clone()).collect();
    assert_eq!(boards.len(), truth.len(), "{what}: every board and no other");
    let [cols, rows] = scene.room.board.inner_corners;
    let (e, complete) = errors(&boards, &truth, (cols + rows) % 2 == 0, what);
    assert!(complete + 2 >= truth.len(), "{what}: only {complete} boards complete");
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    let max = e.iter().cloned().fold(0.0, f64::max);
    // Sigma estimates should be of the size of the errors (within a factor of a few).
    let sigma =
        boards.iter().flat_map(|b| b.corners.iter().map(|c| c.sigma)).sum::<f64>() / e.len() as f64;
    eprintln!("{what}: {} boards ({complete} complete), mean {mean:.4} px, max {max:.4} px, mean sigma {sigma:.4} px", boards.len());
    assert!(sigma > 0.3 * mean && sigma < 3.0 * mean, "{what}: sigma {sigma} vs mean error {mean}");
    (mean, max)
}

#[test]
fn sim_default_room() {
    let (mean, max) = run(SimOptions { seed: 1, ..SimOptions::default() }, "default room");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn sim_wide_strong_distortion() {
    let options = SimOptions {
        seed: 3,
        hfov_deg: Some(90.0),
        distortion: Some(vec![-0.4, 0.15, 0.0005, -0.0004, -0.02]),
        ..SimOptions::default()
    };
    let (mean, max) = run(options, "90° radtan k1=-0.4");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn sim_fisheye_120() {
    let options = SimOptions {
        seed: 4,
        camera_model: Some(CameraModel::Fisheye),
        hfov_deg: Some(120.0),
        ..SimOptions::default()
    };
    let (mean, max) = run(options, "fisheye 120°");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}
