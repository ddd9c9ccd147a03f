//! The LiDAR sweep: every laser of the sensor's angle table fired into the room at every
//! 0.2° of rotation, each ray cast exactly where the packet decoder will place its return
//! (the firing azimuth with the laser's azimuth offset and elevation, from
//! `lidar::calibration`, the single source of the beam geometry), with Gaussian range noise
//! and ranges quantised to the packets' resolution, and what each hole let through.

use crate::geometry::Vec3;
use crate::lidar::calibration::{self, Calibration};
use crate::lidar::{beam_direction, firing_azimuth, range_resolution, Model, Point, SimReturn};

use super::rng::Rng;
use super::world::{Surface, World, BLACK};

/// Rotation between firing sequences (0.01°): 0.2°, as the units fire at 10 Hz.
pub const AZIMUTH_STEP: u16 = 20;
/// Azimuth (0.01°, clockwise from forward) of the first firing: straight behind, where
/// sweeps are cut, so the sweep is one whole turn of the sensor.
pub const START_AZIMUTH: u16 = 18000;
/// The same step in degrees.
pub const AZIMUTH_STEP_DEG: f64 = AZIMUTH_STEP as f64 / 100.0;
/// Sweep period (s): 10 Hz.
const SWEEP_PERIOD_S: f64 = 0.1;
const MIN_RANGE_M: f64 = 0.3;
const MAX_RANGE_M: f64 = 200.0;

/// The angle table the simulated unit of `model` has: for the Pandar64 a real unit's
/// elevations ([`calibration::PANDAR64_UNIT_ELEVATION`]; decoding its packets needs the
/// angle file the capture comes with) with every azimuth offset 0, as the simulator has
/// always cast it (the fixtures' truth depends on it; tests/it/sim_capture.rs also casts and
/// decodes the unit's real offsets); the nominal tables, offsets included, for the VLP-32C,
/// VLP-16 and Pandar40P.
pub fn calibration(model: Model) -> Option<Calibration> {
    match model {
        Model::Pandar64 => Calibration::from_degrees(
            Model::Pandar64,
            &calibration::PANDAR64_UNIT_ELEVATION,
            &[0.0; 64],
        )
        .ok(),
        Model::Vlp32c | Model::Vlp16 | Model::Pandar40p => Some(Calibration::nominal(model)),
        _ => None,
    }
}

/// Elevation of every laser (degrees, in laser order) of the simulated unit of `model`: the
/// elevations of [`calibration`]'s table, for code that reasons about the beams' spacing.
pub fn beam_elevations(model: Model) -> Option<&'static [f64]> {
    match model {
        Model::Pandar64 => Some(&PANDAR64_DEG),
        Model::Vlp32c => Some(&VLP32C_DEG),
        Model::Vlp16 => Some(&VLP16_DEG),
        Model::Pandar40p => Some(&PANDAR40P_DEG),
        _ => None,
    }
}

/// The degree tables of `lidar::calibration` widened to f64 at compile time.
const fn widen<const N: usize>(table: &[f32; N]) -> [f64; N] {
    let mut out = [0.0; N];
    let mut i = 0;
    while i < N {
        out[i] = table[i] as f64;
        i += 1;
    }
    out
}
static PANDAR64_DEG: [f64; 64] = widen(&calibration::PANDAR64_UNIT_ELEVATION);
static VLP32C_DEG: [f64; 32] = widen(&calibration::VLP32C_ELEVATION);
static VLP16_DEG: [f64; 16] = widen(&calibration::VLP16_ELEVATION);
static PANDAR40P_DEG: [f64; 40] = widen(&calibration::PANDAR40P_ELEVATION);

/// What one sweep saw of the boards.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SweepTruth {
    /// Per board: returns on the board.
    pub board_points: Vec<usize>,
    /// Per board, per hole: distinct rings whose beams went through the hole.
    pub hole_rings: Vec<Vec<usize>>,
}

/// The sweep as the sensor reports it, ready for `lidar::encode_sweep`.
#[derive(Clone, Debug, PartialEq)]
pub struct Firings {
    /// The unit's angle table (what the decoder must be given).
    pub calibration: Calibration,
    /// Every laser of every firing sequence in firing order, `azimuth` the sequence's
    /// (0.01°, clockwise), `range` 0 for no return.
    pub returns: Vec<SimReturn>,
}

/// One cast sweep: the points (LiDAR frame, with ring = laser number, intensity and time),
/// the same returns as the sensor would send them, and the truth about the boards.
#[derive(Clone, Debug)]
pub struct CastSweep {
    pub points: Vec<Point>,
    pub firings: Firings,
    pub truth: SweepTruth,
}

/// Casts one sweep of the unit `cal` describes, its firings `phase` (0.01°, less than
/// [`AZIMUTH_STEP`]) after the room's zero: a spinning LiDAR is not phase-locked to the
/// room, so the sweeps of a standing vehicle cross the boards at slightly different places.
pub fn sweep(
    world: &World,
    cal: &Calibration,
    range_noise_m: f64,
    phase: u16,
    rng: &mut Rng,
) -> CastSweep {
    let lasers = cal.model.lasers();
    let sequences = usize::from(36000 / AZIMUTH_STEP);
    let boards = world.boards.len();
    let holes = world.board.holes.len();
    let mut truth =
        SweepTruth { board_points: vec![0; boards], hole_rings: vec![vec![0; holes]; boards] };
    let mut crossed = vec![vec![vec![false; lasers]; holes]; boards];
    let mut points = Vec::with_capacity(sequences * lasers);
    let mut returns = Vec::with_capacity(sequences * lasers);
    let resolution = range_resolution(cal);
    let origin = Vec3::zeros();
    for sequence in 0..sequences {
        let step = (sequence * usize::from(AZIMUTH_STEP)) as u32;
        let azimuth = ((u32::from(START_AZIMUTH) + u32::from(phase) + step) % 36000) as u16;
        let time = sequence as f64 / sequences as f64 * SWEEP_PERIOD_S;
        for laser in 0..lasers {
            let mut ret = SimReturn { laser: laser as u16, azimuth, range: 0.0, intensity: 0 };
            let fired = firing_azimuth(cal, laser, sequence, azimuth, AZIMUTH_STEP);
            let [x, y, z] = beam_direction(cal, laser, fired);
            let dir = Vec3::new(x, y, z);
            if let Some(hit) = world.cast(&origin, &dir) {
                mark_holes_crossed(world, &dir, hit.distance, laser, &mut crossed);
                let range = hit.distance + range_noise_m * rng.normal();
                if (MIN_RANGE_M..=MAX_RANGE_M).contains(&range) {
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
                    // The sensor reports whole range counts; so does the simulated one.
                    let counts = (range / f64::from(resolution)).round() as f32;
                    ret.range = counts * resolution;
                    ret.intensity = intensity as u8;
                    let p = dir * f64::from(ret.range);
                    points.push(Point {
                        x: p.x as f32,
                        y: p.y as f32,
                        z: p.z as f32,
                        intensity: intensity as f32,
                        ring: laser as u16,
                        time,
                    });
                }
            }
            returns.push(ret);
        }
    }
    for (b, per_hole) in crossed.iter().enumerate() {
        for (h, rings) in per_hole.iter().enumerate() {
            truth.hole_rings[b][h] = rings.iter().filter(|&&c| c).count();
        }
    }
    CastSweep { points, firings: Firings { calibration: *cal, returns }, truth }
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
