//! The simulator against itself: the rendered image agrees with the camera model and the
//! truth (a saddle-point fit at every rendered inner corner lands on the truth's projected
//! corner), the sweep sees the boards and their holes, and a seed fixes the scene.

use std::path::Path;

use roomcal::sim::{simulate, ImageNoise, Scene, SimOptions};

fn room() -> roomcal::target::Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml"))).unwrap()
}

fn noiseless(seed: u64) -> SimOptions {
    SimOptions {
        seed,
        image: ImageNoise { noise_grey: 0.0, ..ImageNoise::default() },
        ..SimOptions::default()
    }
}

/// Sub-pixel saddle point of the grey image near `start`: a weighted quadratic fit
/// around the current estimate, re-centred until it settles.
fn saddle(image: &[u8], width: usize, start: [f64; 2]) -> [f64; 2] {
    let (mut x0, mut y0) = (start[0], start[1]);
    for _ in 0..6 {
        let (cx, cy) = (x0.round() as i64, y0.round() as i64);
        // Normal equations of I ≈ a x² + b xy + c y² + d x + e y + f around (x0, y0).
        let mut ata = nalgebra::SMatrix::<f64, 6, 6>::zeros();
        let mut atb = nalgebra::SVector::<f64, 6>::zeros();
        for dy in -3..=3 {
            for dx in -3..=3 {
                let (px, py) = (cx + dx, cy + dy);
                let (x, y) = (px as f64 - x0, py as f64 - y0);
                let w = (-(x * x + y * y) / (2.0 * 1.5 * 1.5)).exp();
                let row = nalgebra::SVector::<f64, 6>::from([x * x, x * y, y * y, x, y, 1.0]);
                let value = image[py as usize * width + px as usize] as f64;
                ata += row * row.transpose() * w;
                atb += row * (value * w);
            }
        }
        let p = ata.lu().solve(&atb).expect("well-posed fit");
        let h = nalgebra::Matrix2::new(2.0 * p[0], p[1], p[1], 2.0 * p[2]);
        let step = -h.lu().solve(&nalgebra::Vector2::new(p[3], p[4])).expect("saddle has a Hessian");
        x0 += step.x;
        y0 += step.y;
        if step.norm() < 1e-4 {
            break;
        }
    }
    [x0, y0]
}

fn corner_errors(scene: &Scene) -> Vec<f64> {
    let width = scene.truth.camera.width as usize;
    let mut errors = Vec::new();
    for board in &scene.truth.boards {
        for c in &board.corners_px {
            let fit = saddle(&scene.image, width, *c);
            errors.push(((fit[0] - c[0]).powi(2) + (fit[1] - c[1]).powi(2)).sqrt());
        }
    }
    errors
}

#[test]
fn rendered_corners_match_the_camera_model() {
    for (name, options) in [
        ("radtan 70°", noiseless(3)),
        (
            "radtan 90° strong barrel",
            SimOptions {
                hfov_deg: Some(90.0),
                distortion: Some(vec![-0.32, 0.11, 0.0005, -0.0004, -0.015]),
                ..noiseless(4)
            },
        ),
        (
            "fisheye 120°",
            SimOptions {
                camera_model: Some(roomcal::geometry::CameraModel::Fisheye),
                hfov_deg: Some(120.0),
                ..noiseless(5)
            },
        ),
    ] {
        let scene = simulate(&room(), &options).expect("scene");
        assert_eq!(scene.truth.boards.len(), 6);
        let errors = corner_errors(&scene);
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let worst = errors.iter().cloned().fold(0.0, f64::max);
        println!("{name}: {} corners, saddle vs truth mean {mean:.4} px, worst {worst:.4} px", errors.len());
        assert!(worst < 0.05, "{name}: worst corner {worst} px");
    }
}

#[test]
fn the_same_seed_gives_the_same_scene() {
    let options = SimOptions { image: ImageNoise { supersample: 1, ..ImageNoise::default() }, ..SimOptions::default() };
    let a = simulate(&room(), &SimOptions { seed: 11, ..options.clone() }).unwrap();
    let b = simulate(&room(), &SimOptions { seed: 11, ..options.clone() }).unwrap();
    let c = simulate(&room(), &SimOptions { seed: 12, ..options }).unwrap();
    assert_eq!(a.image, b.image);
    assert_eq!(a.truth, b.truth);
    assert_eq!(a.cloud, b.cloud);
    assert_ne!(a.truth, c.truth);
}

#[test]
fn boards_cover_the_image_and_stand_in_range() {
    let options = SimOptions { image: ImageNoise { supersample: 1, ..ImageNoise::default() }, ..SimOptions::default() };
    for seed in 20..24 {
        let scene = simulate(&room(), &SimOptions { seed, ..options.clone() }).unwrap();
        let (w, h) = (scene.truth.camera.width as f64, scene.truth.camera.height as f64);
        let all: Vec<[f64; 2]> = scene.truth.boards.iter().flat_map(|b| b.corners_px.clone()).collect();
        // Each image quadrant's outer third holds corners: the corners of the image are covered.
        for (qx, qy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
            let near = all.iter().any(|c| {
                (c[0] / w - qx).abs() < 0.3 && (c[1] / h - qy).abs() < 0.3
            });
            assert!(near, "seed {seed}: no board corner near image corner ({qx}, {qy})");
        }
        for board in &scene.truth.boards {
            let t = board.board_to_camera.translation;
            let d = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
            assert!((2.9..=6.1).contains(&d), "seed {seed}: board at {d} m");
            let r = board.board_to_camera.rotation;
            // Tilt: angle between the board normal and the line of sight.
            let normal = [r[0][2], r[1][2], r[2][2]];
            let cos = (normal[0] * t[0] + normal[1] * t[1] + normal[2] * t[2]) / d;
            let tilt = cos.clamp(-1.0, 1.0).acos().to_degrees();
            assert!((14.0..=36.0).contains(&tilt), "seed {seed}: tilt {tilt}°");
        }
    }
}

#[test]
fn the_sweep_sees_boards_and_their_holes() {
    let options = SimOptions { image: ImageNoise { supersample: 1, ..ImageNoise::default() }, ..SimOptions::default() };
    let scene = simulate(&room(), &options).unwrap();
    let cloud = scene.cloud.as_ref().expect("the room has a LiDAR");
    // 1800 azimuths × 64 beams, nearly all hit something inside the room.
    assert!(cloud.len() > 100_000, "{} points", cloud.len());
    let seen: Vec<_> = scene.truth.boards.iter().filter(|b| b.lidar_points > 50).collect();
    assert!(seen.len() >= 2, "the LiDAR sees {} boards", seen.len());
    // The truth's hole centres lie where the LiDAR's beams pass through: beams through a
    // hole hit something farther than the hole.
    let crossed: usize = scene.truth.boards.iter().flat_map(|b| b.hole_scan_lines.iter()).sum();
    assert!(crossed > 0, "no beam went through any hole");
    let t = scene.truth.lidar_to_camera.as_ref().unwrap().to_se3();
    for board in &scene.truth.boards {
        let pose = board.board_to_camera.to_se3();
        for (h, hole) in board.holes_lidar.iter().enumerate() {
            let in_camera = t.act(&roomcal::geometry::Vec3::new(hole[0], hole[1], hole[2]));
            let expected = pose.act(&scene.room.board.hole(h));
            assert!((in_camera - expected).norm() < 1e-9);
        }
    }
}

#[test]
fn no_board_hides_another() {
    let options = SimOptions { image: ImageNoise { supersample: 1, ..ImageNoise::default() }, ..SimOptions::default() };
    for seed in 30..36 {
        let scene = simulate(&room(), &SimOptions { seed, ..options.clone() }).unwrap();
        for (i, board) in scene.truth.boards.iter().enumerate() {
            assert_eq!(board.occluded_corners, 0, "seed {seed}: board {i} partly hidden");
        }
    }
}
