//! Randomised calibration rooms for the LiDAR board detector's study (`tests/it/holes_study.rs`,
//! docs/accuracy.md): rooms the detector was not tuned on, drawn from a seed.
//!
//! A room draws its board (size 0.8–1.6 m and one of five hole layouts: the design's room
//! file, the paper's board with the holes in its corners, OpenCalib's 1.2 m board with
//! holes on a 0.6 m square, the issue's 1.4 × 1.1 m board, or a random symmetric one), its
//! LiDAR's mounting height and the room's shell, then 3–7 boards 2–8 m away, each turned
//! up to 40° about its vertical and horizontal axes (45° together at most) and rolled up to
//! 20°, standing where the sensor's beams are; then clutter: people-sized boxes, thin
//! stands, and now and then a second board partly behind another. One sweep is ray-cast
//! with the simulator's own caster ([`super::raycast::sweep`]), so the truth carries, per
//! board, the scan lines through each hole and so whether the board is *placeable* (two
//! holes crossed by at least [`PLACEABLE_LINES`] scan lines each).
//!
//! [`issue_room`] is the study's fixed room (seven 1.4 × 1.1 m boards, the middle row
//! in a Pandar64's band, 4.4–4.6 m away).

use crate::geometry::{Mat3, Se3, Vec3};
use crate::lidar::{Model, Point};
use crate::target::BoardSpec;

use super::raycast;
use super::rng::Rng;
use super::structures::{self, Site, Structure};
use super::world::World;
use super::SimError;

/// Scan lines a hole needs for a board to count as placeable (two such holes).
pub const PLACEABLE_LINES: usize = 3;

/// Where a room's board and its holes come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum HoleLayout {
    /// The design's room file (1.2 × 1.0 m, 0.08 m holes at (±0.45, ±0.35)), resized.
    Design,
    /// The paper's board: the holes in the outline's corners.
    Corners,
    /// OpenCalib's 1.2 m square board, 0.11 m holes on a 0.6 m square.
    OpenCalib,
    /// The fixed room's 1.4 × 1.1 m board, 0.1 m holes at (±0.55, ±0.38).
    Issue,
    /// Any size, any hole radius, holes on a random rectangle.
    Random,
}

/// One randomised room and its sweep.
#[derive(Clone, Debug)]
pub struct RandomRoom {
    pub seed: u64,
    pub layout: HoleLayout,
    pub board: BoardSpec,
    pub lidar: Model,
    /// The LiDAR's origin above the floor (m).
    pub lidar_height_m: f64,
    pub range_noise_m: f64,
    /// One sweep (LiDAR frame).
    pub cloud: Vec<Point>,
    pub boards: Vec<RandomBoard>,
}

/// The truth about one board of a randomised room.
#[derive(Clone, Debug)]
pub struct RandomBoard {
    /// Board → LiDAR.
    pub pose: Se3,
    /// Hole centres in the LiDAR frame, in the room's hole order.
    pub holes: Vec<Vec3>,
    /// Per hole: distinct scan lines whose beams went through it.
    pub hole_scan_lines: Vec<usize>,
    /// Returns on the board.
    pub points: usize,
    /// Distance of the board's centre from the sensor (m).
    pub range_m: f64,
    /// Turn about the board's vertical and horizontal axes and roll about its normal, away
    /// from facing the sensor upright (degrees).
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    /// Stands partly behind another board (from the sensor).
    pub behind_another: bool,
}

impl RandomBoard {
    /// Two holes crossed by at least [`PLACEABLE_LINES`] scan lines each: the evidence can
    /// place the board.
    pub fn placeable(&self) -> bool {
        self.hole_scan_lines.iter().filter(|&&l| l >= PLACEABLE_LINES).count() >= 2
    }
}

/// The randomised room of `seed` swept by `lidar` with Gaussian range noise σ `range_noise_m`.
pub fn random_room(seed: u64, lidar: Model, range_noise_m: f64) -> Result<RandomRoom, SimError> {
    room_of(seed, lidar, range_noise_m, false)
}

/// The randomised room of `seed` ([`random_room`]: the same boards and clutter) with one to
/// three [`Structure`]s more, 2.5–9 m away, none hiding a board: what is no board but has
/// a board's flatness and a hole's gaps.
pub fn random_room_among_structures(
    seed: u64,
    lidar: Model,
    range_noise_m: f64,
) -> Result<RandomRoom, SimError> {
    room_of(seed, lidar, range_noise_m, true)
}

fn room_of(
    seed: u64,
    lidar: Model,
    range_noise_m: f64,
    structures: bool,
) -> Result<RandomRoom, SimError> {
    let mut rng = Rng::new(seed ^ 0x5EED_0014);
    let (layout, board) = random_board(&mut rng.fork(1));
    let elevations = raycast::beam_elevations(lidar).ok_or(SimError::NoBeamTable(Some(lidar)))?;
    let mut shape = rng.fork(2);
    let lidar_height_m = shape.range(1.0, 2.2);
    let room = Shell {
        floor_z: -lidar_height_m,
        ceiling_z: shape.range(3.0, 4.0) - lidar_height_m,
        front_x: 0.0,
        side_y: 8.0,
    };
    let mut place = rng.fork(3);
    let count = 3 + (place.uniform() * 5.0) as usize;
    let mut placed: Vec<Placed> = Vec::new();
    for _ in 0..count {
        if let Some(p) =
            (0..200).find_map(|_| draw_board(&board, elevations, &room, &placed, &mut place))
        {
            placed.push(p);
        }
    }
    if !placed.is_empty() && place.uniform() < 0.35 {
        let front = (place.uniform() * placed.len() as f64) as usize;
        if let Some(p) =
            (0..50).find_map(|_| behind(&board, &placed[front], &room, &placed, &mut place))
        {
            placed.push(p);
        }
    }
    let far = placed.iter().map(|p| p.pose.translation.x).fold(4.0, f64::max);
    let room = Shell { front_x: far + shape.range(1.0, 3.0), ..room };
    let poses: Vec<Se3> = placed.iter().map(|p| p.pose).collect();
    let mut world = World::new(&board, poses, &mut rng.fork(4)).with_shell(
        room.floor_z,
        room.ceiling_z,
        room.front_x,
        room.side_y,
    );
    add_clutter(&mut world, &room, &mut rng.fork(5));
    if structures {
        add_structures(&mut world, &board, &room, &placed, &mut rng.fork(7));
    }
    Ok(sweep_room(
        seed,
        layout,
        board,
        lidar,
        lidar_height_m,
        range_noise_m,
        &world,
        &placed,
        &mut rng.fork(6),
    ))
}

/// The study's fixed room: seven 1.4 × 1.1 m boards (0.1 m squares, 0.1 m holes at
/// (±0.55, ±0.38)), the middle row of three in a Pandar64's band, tilted up to 30° about
/// their vertical axis and 20° about their horizontal one, 4.4–4.6 m away, walls, floor
/// and ceiling around; `noise_seed` draws the range noise (σ `range_noise_m`).
pub fn issue_room(noise_seed: u64, range_noise_m: f64) -> RandomRoom {
    let board = issue_board();
    let lidar_height_m = 1.6;
    let room = Shell {
        floor_z: -lidar_height_m,
        ceiling_z: 3.4 - lidar_height_m,
        front_x: 7.5,
        side_y: 6.0,
    };
    // (azimuth, elevation of the centre, range, yaw, pitch) in degrees and metres: the
    // middle row at −2° (the Pandar64's fine beams span about −6° to +2°).
    let layout: [(f64, f64, f64, f64, f64); 7] = [
        (24.0, 12.0, 4.5, 20.0, -15.0),
        (-24.0, 12.0, 4.6, -25.0, 10.0),
        (19.0, -2.0, 4.4, 30.0, 20.0),
        (0.0, -2.5, 4.5, -22.0, -18.0),
        (-19.0, -1.5, 4.6, 28.0, 12.0),
        (24.0, -15.0, 4.5, -15.0, 20.0),
        (-24.0, -15.0, 4.4, 18.0, -20.0),
    ];
    let placed: Vec<Placed> = layout
        .iter()
        .map(|&(az, el, range, yaw, pitch)| Placed::new(az, el, range, yaw, pitch, 0.0, false))
        .collect();
    let poses = placed.iter().map(|p| p.pose).collect();
    let mut rng = Rng::new(noise_seed);
    let world = World::new(&board, poses, &mut rng.fork(4)).with_shell(
        room.floor_z,
        room.ceiling_z,
        room.front_x,
        room.side_y,
    );
    let lidar = Model::Pandar64;
    sweep_room(
        0,
        HoleLayout::Issue,
        board,
        lidar,
        lidar_height_m,
        range_noise_m,
        &world,
        &placed,
        &mut rng.fork(6),
    )
}

/// OpenCalib's board: 1.2 m square, 0.11 m holes on a 0.6 m square about its centre.
pub fn opencalib_board() -> BoardSpec {
    board_with(1.2, 1.2, 0.11, &[[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [0.3, 0.3]])
}

/// The fixed room's board: 1.4 × 1.1 m, 0.1 m holes at (±0.55, ±0.38).
pub fn issue_board() -> BoardSpec {
    board_with(1.4, 1.1, 0.1, &[[-0.55, -0.38], [0.55, -0.38], [-0.55, 0.38], [0.55, 0.38]])
}

/// The room's floor, ceiling and walls (LiDAR frame).
#[derive(Clone, Copy, Debug)]
struct Shell {
    floor_z: f64,
    ceiling_z: f64,
    front_x: f64,
    side_y: f64,
}

/// A board pose with how it was drawn.
#[derive(Clone, Copy, Debug)]
struct Placed {
    pose: Se3,
    azimuth: f64,
    elevation: f64,
    range: f64,
    yaw: f64,
    pitch: f64,
    roll: f64,
    behind: bool,
}

impl Placed {
    /// A board whose centre is `range` m away at (`azimuth`, `elevation`) degrees, facing
    /// the sensor upright and then turned by `yaw` about its y axis, `pitch` about its x
    /// axis and `roll` about its normal (degrees).
    fn new(
        azimuth: f64,
        elevation: f64,
        range: f64,
        yaw: f64,
        pitch: f64,
        roll: f64,
        behind: bool,
    ) -> Self {
        let (a, e) = (azimuth.to_radians(), elevation.to_radians());
        let towards = Vec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
        // Board frame facing the sensor: z along the line of sight, y down, x = y × z.
        let down = Vec3::new(0.0, 0.0, -1.0);
        let y = (down - towards * towards.dot(&down)).normalize();
        let x = y.cross(&towards);
        let facing = Mat3::from_columns(&[x, y, towards]);
        let turn = axis_angle(&Vec3::y(), yaw)
            * axis_angle(&Vec3::x(), pitch)
            * axis_angle(&Vec3::z(), roll);
        let pose = Se3 { rotation: facing * turn, translation: towards * range };
        Placed { pose, azimuth, elevation, range, yaw, pitch, roll, behind }
    }

    /// Half the angle the board subtends seen from the sensor, with a margin (radians).
    fn angular_radius(&self, spec: &BoardSpec) -> f64 {
        (0.5 * spec.width.hypot(spec.height) / self.range).atan() + 0.03
    }

    fn direction(&self) -> Vec3 {
        self.pose.translation / self.range
    }
}

/// Rotation by `deg` degrees about the unit `axis`.
fn axis_angle(axis: &Vec3, deg: f64) -> Mat3 {
    crate::geometry::se3::so3_exp(&(axis * deg.to_radians()))
}

/// The room's board: one of the layouts, sized within the room files' range.
fn random_board(rng: &mut Rng) -> (HoleLayout, BoardSpec) {
    let pick = (rng.uniform() * 5.0) as usize;
    match pick {
        0 => {
            let s = rng.range(0.8, 1.3);
            let holes: Vec<[f64; 2]> = [[-0.45, -0.35], [0.45, -0.35], [-0.45, 0.35], [0.45, 0.35]]
                .iter()
                .map(|h| [h[0] * s, h[1] * s])
                .collect();
            (HoleLayout::Design, board_with(1.2 * s, 1.0 * s, 0.08 * s.max(0.9), &holes))
        }
        1 => {
            let (w, h) = (rng.range(1.0, 1.6), rng.range(0.7, 1.2));
            let r = rng.range(0.07, 0.11);
            let (x, y) = (w / 2.0 - r - 0.03, h / 2.0 - r - 0.03);
            (HoleLayout::Corners, board_with(w, h, r, &[[-x, -y], [x, -y], [-x, y], [x, y]]))
        }
        2 => (HoleLayout::OpenCalib, opencalib_board()),
        3 => (HoleLayout::Issue, issue_board()),
        _ => {
            let (w, h) = (rng.range(0.8, 1.6), rng.range(0.6, 1.2));
            let r = rng.range(0.06, 0.12).min(0.12 * h);
            let x = rng.range(2.0 * r, w / 2.0 - r - 0.03).max(1.2 * r);
            let y = rng.range(1.2 * r, h / 2.0 - r - 0.03).max(1.1 * r);
            (HoleLayout::Random, board_with(w, h, r, &[[-x, -y], [x, -y], [-x, y], [x, y]]))
        }
    }
}

/// A board of this outline and these holes, with the largest checkerboard of 0.1 m
/// squares or smaller that the holes leave room for (the LiDAR study does not need it,
/// but the spec stays a valid room file's).
fn board_with(width: f64, height: f64, hole_radius: f64, holes: &[[f64; 2]]) -> BoardSpec {
    let mut spec = BoardSpec {
        width,
        height,
        inner_corners: [5, 3],
        square: 0.1,
        hole_radius,
        holes: holes.iter().copied().collect(),
        count: 1,
        checker_offset: [0.0, 0.0],
    };
    for _ in 0..40 {
        if spec.validate().is_ok() {
            break;
        }
        spec.square *= 0.9;
    }
    spec
}

/// One board drawn where the sensor's beams are, clear of the others; `None` when this
/// draw collides or leaves the room.
fn draw_board(
    spec: &BoardSpec,
    elevations: &[f64],
    room: &Shell,
    placed: &[Placed],
    rng: &mut Rng,
) -> Option<Placed> {
    let range = rng.range(2.0, 8.0);
    let azimuth = rng.range(-55.0, 55.0);
    // Mostly at one of the lasers' elevations (rooms are built for their sensor), now and
    // then anywhere in its field.
    let (lo, hi) = elevations.iter().fold((f64::MAX, f64::MIN), |(a, b), &e| (a.min(e), b.max(e)));
    let elevation = if rng.uniform() < 0.7 {
        elevations[(rng.uniform() * elevations.len() as f64) as usize % elevations.len()]
    } else {
        rng.range(lo, hi)
    };
    let (yaw, pitch) = (rng.range(-40.0, 40.0), rng.range(-40.0, 40.0));
    if yaw.hypot(pitch) > 45.0 {
        return None;
    }
    let roll = rng.range(-20.0, 20.0);
    let p = Placed::new(azimuth, elevation, range, yaw, pitch, roll, false);
    let clear = placed.iter().all(|q| {
        let apart = p.direction().dot(&q.direction()).clamp(-1.0, 1.0).acos();
        apart > p.angular_radius(spec) + q.angular_radius(spec)
    });
    (clear && inside(spec, &p.pose, room)).then_some(p)
}

/// A board 0.8–2 m behind `front`, turned aside so that a third to two thirds of it hides
/// behind `front`.
fn behind(
    spec: &BoardSpec,
    front: &Placed,
    room: &Shell,
    placed: &[Placed],
    rng: &mut Rng,
) -> Option<Placed> {
    let range = front.range + rng.range(0.8, 2.0);
    let side = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
    let shift = side * rng.range(0.35, 0.7) * spec.width / front.range;
    let (yaw, pitch, roll) =
        (rng.range(-25.0, 25.0), rng.range(-20.0, 20.0), rng.range(-10.0, 10.0));
    let p = Placed::new(
        front.azimuth + shift.to_degrees(),
        front.elevation,
        range,
        yaw,
        pitch,
        roll,
        true,
    );
    let clear = placed.iter().filter(|q| !core::ptr::eq(*q, front)).all(|q| {
        let apart = p.direction().dot(&q.direction()).clamp(-1.0, 1.0).acos();
        apart > p.angular_radius(spec) + q.angular_radius(spec) || q.range > p.range + 0.5
    });
    (clear && inside(spec, &p.pose, room)).then_some(p)
}

/// Whether the board's outline keeps 10 cm from the floor and ceiling and 0.5 m from the
/// side walls.
fn inside(spec: &BoardSpec, pose: &Se3, room: &Shell) -> bool {
    let (hw, hh) = (spec.width / 2.0, spec.height / 2.0);
    [(-hw, -hh), (hw, -hh), (-hw, hh), (hw, hh)].iter().all(|&(x, y)| {
        let p = pose.act(&Vec3::new(x, y, 0.0));
        p.z > room.floor_z + 0.1 && p.z < room.ceiling_z - 0.1 && p.y.abs() < room.side_y - 0.5
    })
}

/// People-sized boxes (0–3) and thin stands (0–3) anywhere ahead, 1.5–9 m out.
fn add_clutter(world: &mut World, room: &Shell, rng: &mut Rng) {
    let people = (rng.uniform() * 4.0) as usize;
    let stands = (rng.uniform() * 4.0) as usize;
    for k in 0..people + stands {
        let (range, azimuth) = (rng.range(1.5, 9.0), rng.range(-70.0, 70.0).to_radians());
        let (x, y) = (range * azimuth.cos(), range * azimuth.sin());
        let (dx, dy, h) = if k < people {
            (rng.range(0.2, 0.3), rng.range(0.15, 0.25), rng.range(1.6, 1.9))
        } else {
            (0.025, 0.025, rng.range(1.0, 1.8))
        };
        let z0 = room.floor_z;
        world.add_box(Vec3::new(x - dx, y - dy, z0), Vec3::new(x + dx, y + dy, z0 + h));
    }
}

/// One to three structures ([`Structure::ALL`]), each clear of the boards (its footprint
/// at least half a board's diagonal and 0.3 m from every board's centre, and behind any
/// board it shares directions with: the study is of what is no board, not of boards
/// hidden) and inside the room; a structure that finds no such site in 50 draws is left
/// out.
fn add_structures(
    world: &mut World,
    board: &BoardSpec,
    room: &Shell,
    placed: &[Placed],
    rng: &mut Rng,
) {
    let count = 1 + (rng.uniform() * 3.0) as usize;
    let clearance = 0.5 * board.width.hypot(board.height) + 0.3;
    for _ in 0..count {
        let kind = Structure::ALL[(rng.uniform() * Structure::ALL.len() as f64) as usize];
        let mut sizes = rng.fork(2);
        for _ in 0..50 {
            let (range, azimuth) = (rng.range(2.5, 9.0), rng.range(-60.0, 60.0).to_radians());
            let site =
                Site { x: range * azimuth.cos(), y: range * azimuth.sin(), floor_z: room.floor_z };
            // Sizes are drawn once per site tried, in a world that keeps only the one kept.
            let mut trial = world.clone();
            let footprint = structures::add(&mut trial, kind, board, site, &mut sizes.fork(1));
            let clear = placed.iter().all(|p| {
                let c = p.pose.translation;
                let dx = (c.x - (site.x + footprint.depth / 2.0)).abs() - footprint.depth / 2.0;
                let dy = (c.y - site.y).abs() - footprint.half_width;
                let apart = dx.max(0.0).hypot(dy.max(0.0)) > clearance;
                // Nothing stands between the sensor and a board: a structure seen in the
                // board's directions stands behind it.
                let ends = [site.y - footprint.half_width, site.y + footprint.half_width];
                let (a0, a1) = (ends[0].atan2(site.x), ends[1].atan2(site.x));
                let (centre, radius) = (p.azimuth.to_radians(), p.angular_radius(board));
                let in_view = a0 < centre + radius && a1 > centre - radius;
                apart && (!in_view || site.x > p.pose.translation.norm() + 0.5)
            });
            let inside = site.y.abs() + footprint.half_width < room.side_y - 0.3
                && site.x + footprint.depth < room.front_x - 0.3;
            if clear && inside {
                *world = trial;
                break;
            }
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn sweep_room(
    seed: u64,
    layout: HoleLayout,
    board: BoardSpec,
    lidar: Model,
    lidar_height_m: f64,
    range_noise_m: f64,
    world: &World,
    placed: &[Placed],
    rng: &mut Rng,
) -> RandomRoom {
    let cal = raycast::calibration(lidar).expect("every model with elevations has a table");
    let cast = raycast::sweep(world, &cal, range_noise_m, 0, rng);
    let boards = placed
        .iter()
        .enumerate()
        .map(|(i, p)| RandomBoard {
            pose: p.pose,
            holes: (0..board.holes.len()).map(|h| p.pose.act(&board.hole(h))).collect(),
            hole_scan_lines: cast.truth.hole_rings[i].clone(),
            points: cast.truth.board_points[i],
            range_m: p.range,
            yaw_deg: p.yaw,
            pitch_deg: p.pitch,
            roll_deg: p.roll,
            behind_another: p.behind,
        })
        .collect();
    RandomRoom {
        seed,
        layout,
        board,
        lidar,
        lidar_height_m,
        range_noise_m,
        cloud: cast.points,
        boards,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rooms_are_deterministic_and_boards_valid() {
        let a = random_room(3, Model::Vlp32c, 0.02).unwrap();
        let b = random_room(3, Model::Vlp32c, 0.02).unwrap();
        assert_eq!(a.cloud, b.cloud);
        assert!(a.board.validate().is_ok(), "{:?}", a.board);
        assert!(!a.boards.is_empty());
    }

    #[test]
    fn every_layout_is_drawn_and_valid() {
        let mut seen = std::collections::BTreeSet::new();
        for seed in 0..60 {
            let (layout, spec) = random_board(&mut Rng::new(seed));
            assert!(spec.validate().is_ok(), "seed {seed}: {layout:?} {spec:?}");
            seen.insert(layout);
        }
        assert_eq!(seen.len(), 5, "{seen:?}");
    }

    #[test]
    fn a_board_faces_the_sensor_when_untilted() {
        let p = Placed::new(30.0, -2.0, 5.0, 0.0, 0.0, 0.0, false);
        let normal = p.pose.rotation.column(2).into_owned();
        assert!((normal.dot(&p.direction()) - 1.0).abs() < 1e-12);
        // Board y points down, x to the sensor's right.
        assert!(p.pose.rotation.column(1).z < -0.99);
    }
}
