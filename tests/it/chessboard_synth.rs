//! Synthetic frames with known corners: several boards, tilt, barrel distortion, blur,
//! noise, uneven light, textured background, occlusion. Checks that every board is found,
//! ordered as the board model numbers its corners, and sub-pixel accurate.

use crate::common::render;

use render::{grid_boards, rotation, six_boards, BoardPose, Scene};
use roomcal::detect::{Board, ChessboardDetector};
use roomcal::target::BoardSpec;

fn spec(cols: u32, rows: u32) -> BoardSpec {
    BoardSpec {
        width: 1.2,
        height: 1.0,
        inner_corners: [cols, rows],
        square: 0.08,
        hole_radius: 0.0,
        holes: heapless::Vec::new(),
        count: 6,
        checker_offset: [0.0, 0.0],
    }
}

fn detect(scene: &Scene, cols: u32, rows: u32) -> Vec<Board> {
    let img = scene.render();
    if let Ok(dir) = std::env::var("ROOMCAL_DUMP") {
        let name = format!("{dir}/synth-{}-{}.png", scene.seed, scene.boards.len());
        image::GrayImage::from_raw(scene.w as u32, scene.h as u32, img.clone())
            .unwrap()
            .save(name)
            .unwrap();
    }
    let mut det =
        ChessboardDetector::new(scene.w as u32, scene.h as u32, &spec(cols, rows)).unwrap();
    let mut out = Vec::new();
    det.detect(&img, &mut out).unwrap();
    out
}

/// Corner errors (px) of the detected board matching each truth board, in truth order;
/// `symmetric` accepts the half-turned numbering too. Panics when a board is missing.
fn errors(boards: &[Board], truth: &[Vec<[f64; 2]>], symmetric: bool) -> Vec<f64> {
    let mut all = Vec::new();
    for (n, t) in truth.iter().enumerate() {
        let found = boards.iter().filter(|b| b.complete).find_map(|b| {
            let err = |rev: bool| -> Vec<f64> {
                b.corners
                    .iter()
                    .enumerate()
                    .map(|(i, c)| {
                        let p = t[if rev { t.len() - 1 - i } else { i }];
                        ((c.x - p[0]).powi(2) + (c.y - p[1]).powi(2)).sqrt()
                    })
                    .collect()
            };
            if b.corners.len() != t.len() {
                return None;
            }
            let direct = err(false);
            if direct.iter().all(|&e| e < 1.0) {
                return Some(direct);
            }
            let reversed = err(true);
            (symmetric && reversed.iter().all(|&e| e < 1.0)).then_some(reversed)
        });
        match found {
            Some(e) => all.extend(e),
            None => panic!(
                "truth board {n} not found complete and in order ({} boards found)",
                boards.len()
            ),
        }
    }
    all
}

fn summary(errors: &[f64]) -> (f64, f64) {
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    (mean, errors.iter().cloned().fold(0.0, f64::max))
}

#[test]
fn six_boards_tilted() {
    let scene = six_boards(1280, 800, 900.0, 0.0, 40.0, 1, 3.0);
    let boards = detect(&scene, 7, 5);
    assert_eq!(boards.len(), 6, "exactly the six boards, no false ones");
    let e = errors(&boards, &scene.truth(), true);
    let (mean, max) = summary(&e);
    eprintln!("six boards tilted 40°: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn six_boards_barrel_distortion() {
    let mut scene = six_boards(1280, 800, 600.0, 0.35, 35.0, 2, 1.6);
    scene.blur = 1.2;
    let boards = detect(&scene, 7, 5);
    assert_eq!(boards.len(), 6);
    let e = errors(&boards, &scene.truth(), true);
    let (mean, max) = summary(&e);
    eprintln!("barrel k=0.35: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn heavy_blur_and_noise() {
    let mut scene = six_boards(1280, 800, 900.0, 0.1, 30.0, 3, 3.0);
    scene.blur = 1.5;
    scene.noise = 5.0;
    let boards = detect(&scene, 7, 5);
    assert_eq!(boards.len(), 6);
    let e = errors(&boards, &scene.truth(), true);
    let (mean, max) = summary(&e);
    eprintln!("blur 1.5 noise 5: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.1 && max <= 0.4, "mean {mean}, max {max}");
}

#[test]
fn steep_tilt_small_squares() {
    // 60° tilt, squares about 20 px across before foreshortening.
    let r = rotation(0.0, 60f64.to_radians(), 0.2);
    let b = BoardPose { r, t: [0.0, 0.0, 3.5], cols: 7, rows: 5, square: 0.08 };
    let scene = Scene {
        w: 640,
        h: 480,
        f: 900.0,
        k: 0.0,
        boards: vec![b],
        blur: 0.8,
        noise: 2.0,
        seed: 4,
        texture: 1.0,
        occluder: None,
    };
    let boards = detect(&scene, 7, 5);
    assert_eq!(boards.len(), 1);
    let (mean, max) = summary(&errors(&boards, &scene.truth(), true));
    eprintln!("60° tilt, ~20 px squares: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.08 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn asymmetric_pattern_is_ordered_by_colour() {
    // 8 × 5 inner corners: a half turn maps black squares to white, so the order is unique.
    for (seed, turn) in [(5u64, 0.3), (6, 3.4), (7, 1.7)] {
        let r = rotation(0.3, -0.4, turn);
        let b = BoardPose { r, t: [0.0, 0.0, 2.5], cols: 8, rows: 5, square: 0.06 };
        let scene = Scene {
            w: 800,
            h: 600,
            f: 800.0,
            k: 0.05,
            boards: vec![b],
            blur: 0.8,
            noise: 2.0,
            seed,
            texture: 1.0,
            occluder: None,
        };
        let boards = detect(&scene, 8, 5);
        assert_eq!(boards.len(), 1, "seed {seed}");
        let (mean, max) = summary(&errors(&boards, &scene.truth(), false));
        assert!(mean <= 0.05 && max <= 0.3, "seed {seed}: mean {mean}, max {max}");
    }
}

#[test]
fn textured_background_gives_no_board() {
    let mut scene = six_boards(1280, 800, 900.0, 0.0, 30.0, 8, 3.0);
    scene.boards.clear();
    scene.texture = 2.0;
    let boards = detect(&scene, 7, 5);
    assert!(
        boards.is_empty(),
        "false boards: {:?}",
        boards.iter().map(|b| (b.cols, b.rows)).collect::<Vec<_>>()
    );
}

#[test]
fn occluded_board_is_incomplete_with_true_corners() {
    let mut scene = six_boards(1280, 800, 900.0, 0.0, 20.0, 9, 3.0);
    let truth = scene.truth();
    // Hide the right third of board 0.
    let xs: Vec<f64> = truth[0].iter().map(|p| p[0]).collect();
    let (x0, x1) =
        (xs.iter().cloned().fold(f64::MAX, f64::min), xs.iter().cloned().fold(0.0, f64::max));
    let ys: Vec<f64> = truth[0].iter().map(|p| p[1]).collect();
    let cut = x0 + 0.6 * (x1 - x0);
    let (y0, y1) =
        (ys.iter().cloned().fold(f64::MAX, f64::min), ys.iter().cloned().fold(0.0, f64::max));
    scene.occluder = Some([cut, y0 - 60.0, x1 + 80.0, y1 + 60.0]);
    let boards = detect(&scene, 7, 5);
    let complete = boards.iter().filter(|b| b.complete).count();
    assert_eq!(complete, 5, "the five unhidden boards stay complete");
    let partial: Vec<_> = boards.iter().filter(|b| !b.complete).collect();
    assert!(partial.len() <= 1);
    for b in partial {
        assert!(b.corners.len() < 35);
        for c in &b.corners {
            let near =
                truth[0].iter().any(|p| ((c.x - p[0]).powi(2) + (c.y - p[1]).powi(2)).sqrt() < 0.5);
            assert!(
                near,
                "incomplete board has a corner at ({}, {}) that is no true corner",
                c.x, c.y
            );
            assert!(c.x < cut, "corner behind the occluder");
        }
    }
}

#[test]
fn sixteen_boards() {
    let scene = grid_boards(1600, 1000, 1000.0, 0.05, 30.0, 12, 4.2, 4, 4);
    let boards = detect(&scene, 7, 5);
    assert_eq!(boards.len(), 16);
    let (mean, max) = summary(&errors(&boards, &scene.truth(), true));
    eprintln!("16 boards: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn large_squares() {
    // About 120 px squares, close up and a little tilted.
    let r = rotation(0.2, -0.25, 0.1);
    let b = BoardPose { r, t: [0.0, 0.0, 0.6], cols: 7, rows: 5, square: 0.08 };
    let scene = Scene {
        w: 1280,
        h: 800,
        f: 900.0,
        k: 0.0,
        boards: vec![b],
        blur: 1.5,
        noise: 2.0,
        seed: 13,
        texture: 1.0,
        occluder: None,
    };
    let boards = detect(&scene, 7, 5);
    assert_eq!(boards.len(), 1);
    let (mean, max) = summary(&errors(&boards, &scene.truth(), true));
    eprintln!("120 px squares: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.05 && max <= 0.3, "mean {mean}, max {max}");
}

#[test]
fn errors_name_the_problem() {
    let err = ChessboardDetector::new(640, 480, &spec(1, 5)).err().expect("1 column refused");
    assert!(err.to_string().contains("inner_corners"), "{err}");
    let err = ChessboardDetector::new(8, 8, &spec(7, 5)).err().expect("tiny image refused");
    assert!(err.to_string().contains("8x8"), "{err}");
    let mut det = ChessboardDetector::new(64, 48, &spec(7, 5)).unwrap();
    let err = det.detect(&[0u8; 100], &mut Vec::new()).unwrap_err();
    assert!(err.to_string().contains("100 bytes") && err.to_string().contains("64x48"), "{err}");
    // A flat frame holds no board.
    let mut out = Vec::new();
    det.detect(&[128u8; 64 * 48], &mut out).unwrap();
    assert!(out.is_empty());
}
