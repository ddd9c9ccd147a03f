//! The simulator against itself: the rendered image agrees with the camera model and the
//! truth (a saddle-point fit at every rendered inner corner lands on the truth's projected
//! corner), the sweep sees the boards and their holes, and a seed fixes the scene.

use std::path::Path;

use roomcal::geometry::{Camera, Vec2, Vec3};
use roomcal::sim::{simulate, ImageNoise, Scene, SimOptions};

fn room() -> roomcal::target::Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

fn noiseless(seed: u64) -> SimOptions {
    SimOptions {
        seed,
        image: ImageNoise { noise_grey: 0.0, supersample: 8, ..ImageNoise::default() },
        ..SimOptions::default()
    }
}

/// Largest half width of the fitting window (px); smaller where the squares are small,
/// so that the window never reaches the neighbouring corners.
const FIT_RADIUS: i64 = 5;

/// Sub-pixel corner of the grey image near `start`: a least-squares fit of the blurred
/// saddle model `m + h·erf(d₁/s₁)·erf(d₂/s₂)` (d₁, d₂ the signed distances to the two
/// edge lines through the corner, s₁, s₂ their blur widths) over a window of up to 11×11 pixels. A plain quadratic fit of the saddle
/// carries a sub-pixel-phase bias of up to 0.08 px at this blur (measured), which would
/// hide what this test looks for; the edge model has none of it. The pixels are placed
/// in the camera's undistorted plane (scaled by fx), where the edges are straight lines
/// even under strong distortion; the fitted corner is projected back into the image.
/// The edge directions start from the neighbouring corners.
fn fit_corner(
    image: &[u8],
    camera: &Camera,
    start: [f64; 2],
    neighbours: [[f64; 2]; 2],
) -> [f64; 2] {
    let width = camera.width as usize;
    let straighten = |x: f64, y: f64| {
        let ray = camera.unproject(&Vec2::new(x, y)).expect("pixels near a corner invert");
        [camera.fx * ray.x / ray.z, camera.fx * ray.y / ray.z]
    };
    let (cx, cy) = (start[0].round() as i64, start[1].round() as i64);
    let spacing = neighbours
        .iter()
        .map(|n| ((n[0] - start[0]).powi(2) + (n[1] - start[1]).powi(2)).sqrt())
        .fold(f64::MAX, f64::min);
    let radius = ((0.4 * spacing) as i64).clamp(2, FIT_RADIUS);
    let pixels: Vec<(f64, f64, f64)> = (-radius..=radius)
        .flat_map(|dy| (-radius..=radius).map(move |dx| (cx + dx, cy + dy)))
        .map(|(x, y)| {
            let [u, v] = straighten(x as f64, y as f64);
            (u, v, image[y as usize * width + x as usize] as f64)
        })
        .collect();
    let origin = straighten(start[0], start[1]);
    let angle = |n: [f64; 2]| {
        let q = straighten(n[0], n[1]);
        (q[1] - origin[1]).atan2(q[0] - origin[0])
    };
    let (along_row, along_col) = (angle(neighbours[0]), angle(neighbours[1]));
    let model = |p: &[f64; 8], x: f64, y: f64| {
        let (dx, dy) = (x - p[0], y - p[1]);
        let d1 = -p[2].sin() * dx + p[2].cos() * dy;
        let d2 = -p[3].sin() * dx + p[3].cos() * dy;
        p[4] + p[5] * libm::erf(d1 / p[6]) * libm::erf(d2 / p[7])
    };
    let cost =
        |p: &[f64; 8]| pixels.iter().map(|&(x, y, v)| (v - model(p, x, y)).powi(2)).sum::<f64>();
    // Which quadrants are dark is unknown: start from both signs of the contrast.
    let mut p = [100.0, -100.0]
        .map(|h| [origin[0], origin[1], along_row, along_col, 110.0, h, 1.5, 1.5])
        .into_iter()
        .min_by(|a, b| cost(a).total_cmp(&cost(b)))
        .unwrap();
    let mut lambda = 1e-3;
    for _ in 0..200 {
        let mut jtj = nalgebra::SMatrix::<f64, 8, 8>::zeros();
        let mut jtr = nalgebra::SVector::<f64, 8>::zeros();
        for &(x, y, v) in &pixels {
            let mut j = nalgebra::SVector::<f64, 8>::zeros();
            for k in 0..8 {
                let e = 1e-6 * (1.0 + p[k].abs());
                let (mut up, mut down) = (p, p);
                up[k] += e;
                down[k] -= e;
                j[k] = (model(&up, x, y) - model(&down, x, y)) / (2.0 * e);
            }
            jtj += j * j.transpose();
            jtr += j * (v - model(&p, x, y));
        }
        let mut damped = jtj;
        for k in 0..8 {
            damped[(k, k)] *= 1.0 + lambda;
        }
        let Some(step) = damped.lu().solve(&jtr) else { break };
        let mut next = p;
        for k in 0..8 {
            next[k] += step[k];
        }
        if cost(&next) < cost(&p) {
            p = next;
            lambda *= 0.3;
            if step.norm() < 1e-9 {
                break;
            }
        } else {
            lambda *= 10.0;
        }
    }
    let back = camera
        .project(&Vec3::new(p[0] / camera.fx, p[1] / camera.fx, 1.0))
        .expect("corner projects");
    [back.x, back.y]
}

fn mean_and_worst(errors: &[f64]) -> (f64, f64) {
    (errors.iter().sum::<f64>() / errors.len() as f64, errors.iter().cloned().fold(0.0, f64::max))
}

fn corner_errors(scene: &Scene) -> Vec<f64> {
    let camera = scene.truth.camera.to_camera();
    let (cols, _) = scene.room.board.grid();
    let mut errors = Vec::new();
    for board in &scene.truth.boards {
        let c = &board.corners_px;
        for (i, corner) in c.iter().enumerate() {
            // Directions to a neighbour along the row and along the column.
            let row_mate = if i % cols + 1 < cols { i + 1 } else { i - 1 };
            let col_mate = if i + cols < c.len() { i + cols } else { i - cols };
            let fit = fit_corner(&scene.image, &camera, *corner, [c[row_mate], c[col_mate]]);
            let e = ((fit[0] - corner[0]).powi(2) + (fit[1] - corner[1]).powi(2)).sqrt();
            errors.push(e);
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
        assert!(
            scene.truth.boards.iter().all(|b| b.occluded_corners == 0),
            "{name}: a corner is hidden"
        );
        let errors = corner_errors(&scene);
        let (mean, worst) = mean_and_worst(&errors);
        println!(
            "{name}: {} corners, saddle vs truth mean {mean:.4} px, worst {worst:.4} px",
            errors.len()
        );
        assert!(worst < 0.05, "{name}: worst corner {worst} px");
    }
}

/// One sample per pixel (the fixtures' and the tests' renders) integrates the checker over
/// the pixel, so its corners are as true as eight-by-eight supersampling's (a point sample
/// per pixel put them 0.3 px off, the same way over each board).
#[test]
fn one_sample_per_pixel_renders_true_corners() {
    for seed in [3, 4] {
        let options = SimOptions {
            seed,
            image: ImageNoise { noise_grey: 0.0, supersample: 1, ..ImageNoise::default() },
            ..SimOptions::default()
        };
        let scene = simulate(&room(), &options).expect("scene");
        let errors = corner_errors(&scene);
        let (mean, worst) = mean_and_worst(&errors);
        println!(
            "seed {seed}: {} corners, saddle vs truth mean {mean:.4} px, worst {worst:.4} px",
            errors.len()
        );
        assert!(mean < 0.02 && worst < 0.06, "seed {seed}: mean {mean} px, worst {worst} px");
    }
}

#[test]
fn the_same_seed_gives_the_same_scene() {
    let options = SimOptions {
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
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
    let options = SimOptions {
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    for seed in 20..24 {
        let scene = simulate(&room(), &SimOptions { seed, ..options.clone() }).unwrap();
        let (w, h) = (scene.truth.camera.width as f64, scene.truth.camera.height as f64);
        let all: Vec<[f64; 2]> =
            scene.truth.boards.iter().flat_map(|b| b.corners_px.clone()).collect();
        // Each image quadrant's outer third holds corners: the corners of the image are covered.
        for (qx, qy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
            let near =
                all.iter().any(|c| (c[0] / w - qx).abs() < 0.3 && (c[1] / h - qy).abs() < 0.3);
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
    let options = SimOptions {
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
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
    let options = SimOptions {
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    for seed in 30..36 {
        let scene = simulate(&room(), &SimOptions { seed, ..options.clone() }).unwrap();
        for (i, board) in scene.truth.boards.iter().enumerate() {
            assert_eq!(board.occluded_corners, 0, "seed {seed}: board {i} partly hidden");
        }
    }
}
