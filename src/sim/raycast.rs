//! The LiDAR sweep: every beam of the sensor's elevation table fired at every 0.2° of
//! azimuth into the room, with Gaussian range noise, and what each hole let through.

use crate::geometry::Vec3;
use crate::lidar::Point;
use crate::target::LidarModel;

use super::rng::Rng;
use super::world::{Surface, World, BLACK};

/// Azimuth step between firings (degrees).
pub const AZIMUTH_STEP_DEG: f64 = 0.2;
/// Sweep period (s): 10 Hz.
const SWEEP_PERIOD_S: f64 = 0.1;
const MIN_RANGE_M: f64 = 0.3;
const MAX_RANGE_M: f64 = 200.0;

/// Elevation of every laser (degrees), in the sensor's ring order.
pub fn beam_elevations(model: LidarModel) -> Option<&'static [f64]> {
    match model {
        LidarModel::Pandar64 => Some(&PANDAR64_ELEVATION_DEG),
        LidarModel::Vlp32c => Some(&VLP32C_ELEVATION_DEG),
        LidarModel::Vlp16 => Some(&VLP16_ELEVATION_DEG),
        _ => None,
    }
}

/// What one sweep saw of the boards.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SweepTruth {
    /// Per board: returns on the board.
    pub board_points: Vec<usize>,
    /// Per board, per hole: distinct rings whose beams went through the hole.
    pub hole_rings: Vec<Vec<usize>>,
}

/// Casts one sweep; points in the LiDAR frame with ring, intensity and time.
pub fn sweep(
    world: &World,
    elevations: &[f64],
    range_noise_m: f64,
    rng: &mut Rng,
) -> (Vec<Point>, SweepTruth) {
    let columns = (360.0 / AZIMUTH_STEP_DEG).round() as usize;
    let boards = world.boards.len();
    let holes = world.board.holes.len();
    let mut truth =
        SweepTruth { board_points: vec![0; boards], hole_rings: vec![vec![0; holes]; boards] };
    let mut crossed = vec![vec![vec![false; elevations.len()]; holes]; boards];
    let mut points = Vec::with_capacity(columns * elevations.len());
    let origin = Vec3::zeros();
    for column in 0..columns {
        let azimuth = (column as f64 * AZIMUTH_STEP_DEG).to_radians();
        let time = column as f64 / columns as f64 * SWEEP_PERIOD_S;
        for (ring, elevation) in elevations.iter().enumerate() {
            let e = elevation.to_radians();
            let dir = Vec3::new(e.cos() * azimuth.cos(), e.cos() * azimuth.sin(), e.sin());
            let Some(hit) = world.cast(&origin, &dir) else { continue };
            mark_holes_crossed(world, &dir, hit.distance, ring, &mut crossed);
            let range = hit.distance + range_noise_m * rng.normal();
            if !(MIN_RANGE_M..=MAX_RANGE_M).contains(&range) {
                continue;
            }
            let intensity = match hit.surface {
                Surface::Board { index, x, y } => {
                    truth.board_points[index] += 1;
                    if world.board_albedo(x, y) == BLACK {
                        20.0
                    } else {
                        200.0
                    }
                }
                Surface::Background { albedo } => (albedo * 150.0).round(),
            };
            let p = dir * range;
            points.push(Point {
                x: p.x as f32,
                y: p.y as f32,
                z: p.z as f32,
                intensity: intensity as f32,
                ring: ring as u16,
                time,
            });
        }
    }
    for (b, per_hole) in crossed.iter().enumerate() {
        for (h, rings) in per_hole.iter().enumerate() {
            truth.hole_rings[b][h] = rings.iter().filter(|&&c| c).count();
        }
    }
    (points, truth)
}

/// Marks the holes this beam passed through before it hit something at `distance`.
fn mark_holes_crossed(
    world: &World,
    dir: &Vec3,
    distance: f64,
    ring: usize,
    crossed: &mut [Vec<Vec<bool>>],
) {
    let r2 = world.board.hole_radius * world.board.hole_radius;
    for (b, pose) in world.boards.iter().enumerate() {
        let normal = pose.rotation.column(2).into_owned();
        let denom = normal.dot(dir);
        if denom.abs() < 1e-12 {
            continue;
        }
        let s = normal.dot(&pose.translation) / denom;
        if s <= 0.0 || s >= distance {
            continue;
        }
        let local = pose.rotation.transpose() * (dir * s - pose.translation);
        for (h, centre) in world.board.holes.iter().enumerate() {
            let (dx, dy) = (local.x - centre[0], local.y - centre[1]);
            if dx * dx + dy * dy < r2 {
                crossed[b][h][ring] = true;
            }
        }
    }
}

/// Hesai Pandar64: the elevation table of a real unit (64 lasers, +14.9° to −24.9°,
/// dense 0.17° band from +2° to −6°).
const PANDAR64_ELEVATION_DEG: [f64; 64] = [
    14.9, 11.05, 8.077, 5.075, 3.058, 2.046, 1.878, 1.706, 1.54, 1.369, 1.202, 1.031, 0.864, 0.693,
    0.526, 0.355, 0.187, 0.018, -0.151, -0.319, -0.49, -0.657, -0.827, -0.995, -1.166, -1.333,
    -1.504, -1.67, -1.842, -2.01, -2.18, -2.347, -2.518, -2.682, -2.855, -3.022, -3.192, -3.357,
    -3.53, -3.694, -3.866, -4.032, -4.203, -4.367, -4.54, -4.702, -4.874, -5.039, -5.211, -5.373,
    -5.547, -5.708, -5.88, -6.043, -7.045, -8.041, -9.042, -10.027, -11.014, -11.988, -12.956,
    -13.912, -18.871, -24.879,
];

/// Velodyne VLP-32C nominal vertical angles in channel order (VLP-32C manual).
const VLP32C_ELEVATION_DEG: [f64; 32] = [
    -25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148,
    -5.333, 1.333, 0.667, -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0,
    7.0, 4.667, -2.333, -2.0, 15.0, 10.333, -1.333,
];

/// Velodyne VLP-16 vertical angles in channel order (VLP-16 manual).
const VLP16_ELEVATION_DEG: [f64; 16] =
    [-15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0];
