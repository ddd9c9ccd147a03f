//! The simulated room as geometry: boards on stands, floor, ceiling, walls and clutter,
//! all in the LiDAR frame (x forward, y left, z up). The camera renderer and the LiDAR
//! ray caster both ask the same question of it: what does this ray hit first?

use crate::geometry::{Se3, Vec3};
use crate::target::BoardSpec;

use super::rng::{texture, Rng};

/// Where the LiDAR's origin stands above the floor (m).
pub const LIDAR_HEIGHT: f64 = 2.0;
/// Where the ceiling is above the LiDAR's origin (m).
pub const CEILING_Z: f64 = 3.2;
/// Radius of the pole each board stands or hangs on (m).
const POLE_RADIUS: f64 = 0.03;
/// Albedo of the board's white (paper) and black (print).
pub const WHITE: f64 = 0.86;
pub const BLACK: f64 = 0.06;

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Surface {
    /// Board `index` at board-plane point (x, y).
    Board { index: usize, x: f64, y: f64 },
    /// Anything else, with its albedo in [0, 1].
    Background { albedo: f64 },
}

/// The first hit along a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, m.
    pub distance: f64,
    pub surface: Surface,
}

/// An axis-aligned box standing on the floor.
#[derive(Clone, Copy, Debug)]
struct Crate {
    min: Vec3,
    max: Vec3,
}

/// The room in the LiDAR frame.
#[derive(Clone, Debug)]
pub struct World {
    pub board: BoardSpec,
    /// Board → LiDAR frame for every board.
    pub boards: Vec<Se3>,
    /// LiDAR frame → the frame the floor, walls, ceiling, clutter and poles stand in
    /// (identity for a single scene; a parked vehicle's pose for [`super::visits`]).
    shell: Se3,
    /// Board → shell frame, where the poles stand.
    boards_in_shell: Vec<Se3>,
    texture_seed: u64,
    crates: Vec<Crate>,
    floor_z: f64,
    ceiling_z: f64,
    front_x: f64,
    back_x: f64,
    side_y: f64,
}

impl World {
    /// A room around `boards` (board → LiDAR poses), with clutter drawn from `rng`.
    pub fn new(board: &BoardSpec, boards: Vec<Se3>, rng: &mut Rng) -> Self {
        let texture_seed = rng.next_u64();
        let mut crates = Vec::new();
        for side in [-1.0, 1.0] {
            let x = rng.range(2.0, 7.0);
            let y = side * rng.range(3.5, 5.5);
            let (dx, dy, h) = (rng.range(0.3, 0.8), rng.range(0.3, 0.8), rng.range(0.4, 1.2));
            let z0 = -LIDAR_HEIGHT;
            crates.push(Crate {
                min: Vec3::new(x - dx, y - dy, z0),
                max: Vec3::new(x + dx, y + dy, z0 + h),
            });
        }
        World {
            board: board.clone(),
            boards_in_shell: boards.clone(),
            boards,
            shell: Se3::identity(),
            texture_seed,
            crates,
            floor_z: -LIDAR_HEIGHT,
            ceiling_z: CEILING_Z,
            front_x: 10.0,
            back_x: -8.0,
            side_y: 7.0,
        }
    }

    /// The same room with its shell moved: the floor `floor_z` and the ceiling
    /// `ceiling_z` (LiDAR frame, so the floor's depth is the sensor's mounting height), the
    /// front wall at `front_x` and the side walls at ±`side_y` (randomised rooms).
    pub fn with_shell(mut self, floor_z: f64, ceiling_z: f64, front_x: f64, side_y: f64) -> Self {
        (self.floor_z, self.ceiling_z, self.front_x, self.side_y) =
            (floor_z, ceiling_z, front_x, side_y);
        self
    }

    /// Adds an axis-aligned box (a person, a stand, a cabinet) between `min` and `max`.
    pub fn add_box(&mut self, min: Vec3, max: Vec3) {
        self.crates.push(Crate { min, max });
    }

    /// The same room seen from a sensor whose frame sits at `lidar_to_shell` in the
    /// frame the room (floor, walls, ceiling, clutter) was made in; `boards` stay board →
    /// LiDAR frame.
    pub fn placed(mut self, lidar_to_shell: Se3) -> Self {
        self.boards_in_shell = self.boards.iter().map(|b| lidar_to_shell.compose(b)).collect();
        self.shell = lidar_to_shell;
        self
    }

    /// Floor, ceiling and the four walls in the shell's frame: name, unit normal pointing
    /// out of the room, and offset (`normal · p = offset`, the distance from the origin).
    pub fn shell_planes(&self) -> [(&'static str, Vec3, f64); 6] {
        [
            ("floor", -Vec3::z(), -self.floor_z),
            ("ceiling", Vec3::z(), self.ceiling_z),
            ("front wall", Vec3::x(), self.front_x),
            ("back wall", -Vec3::x(), -self.back_x),
            ("left wall", Vec3::y(), self.side_y),
            ("right wall", -Vec3::y(), self.side_y),
        ]
    }

    /// The first surface along the unit ray `origin + s·dir`, s > 0.
    pub fn cast(&self, origin: &Vec3, dir: &Vec3) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut consider = |hit: Option<Hit>| {
            if let Some(h) = hit {
                if best.is_none_or(|b| h.distance < b.distance) {
                    best = Some(h);
                }
            }
        };
        // The shell's frame is a rigid motion away: distances along the ray are the same.
        let (shell_origin, shell_dir) = (self.shell.act(origin), self.shell.rotation * dir);
        for (index, (pose, in_shell)) in self.boards.iter().zip(&self.boards_in_shell).enumerate() {
            consider(self.cast_board(index, pose, origin, dir));
            consider(self.cast_pole(in_shell, &shell_origin, &shell_dir));
        }
        for c in &self.crates {
            consider(self.cast_crate(c, &shell_origin, &shell_dir));
        }
        consider(self.cast_shell(&shell_origin, &shell_dir));
        best
    }

    /// The albedo of a board at board-plane point (x, y): checker squares or white border.
    pub fn board_albedo(&self, x: f64, y: f64) -> f64 {
        let spec = &self.board;
        let (hx, hy) = spec.checker_half_extent();
        let (u, v) = (x - spec.checker_offset[0] + hx, y - spec.checker_offset[1] + hy);
        if u < 0.0 || v < 0.0 || u >= 2.0 * hx || v >= 2.0 * hy {
            return WHITE;
        }
        let (col, row) = ((u / spec.square).floor() as i64, (v / spec.square).floor() as i64);
        // The top-left square is black (target.rs).
        if (col + row) % 2 == 0 {
            BLACK
        } else {
            WHITE
        }
    }

    /// The mean albedo of a board over the box `width × height` (board-plane metres)
    /// centred on (x, y): what a camera sample whose footprint covers that box integrates.
    ///
    /// A point sample per pixel aliases the checker's edges: the rendered corners then sit
    /// off the true ones by a third of a pixel, the same way over a whole board. The black
    /// print is inside(u)·inside(v)·(1 + s(u)·s(v))/2, s the ±1 square wave of the squares,
    /// so its box mean is separable into 1-D means, each a difference of antiderivatives
    /// (of the checker's extent, and of the square wave: a triangle wave). Any box centred
    /// on the sample is point-symmetric, so it moves no corner (a saddle is point-symmetric).
    pub fn board_albedo_over(&self, x: f64, y: f64, width: f64, height: f64) -> f64 {
        let spec = &self.board;
        let (hx, hy) = spec.checker_half_extent();
        let (u, v) = (x - spec.checker_offset[0] + hx, y - spec.checker_offset[1] + hy);
        let (inside_u, wave_u) = box_means(u, width, 2.0 * hx, spec.square);
        let (inside_v, wave_v) = box_means(v, height, 2.0 * hy, spec.square);
        let black = 0.5 * (inside_u * inside_v + wave_u * wave_v);
        WHITE - (WHITE - BLACK) * black
    }

    fn cast_board(&self, index: usize, pose: &Se3, origin: &Vec3, dir: &Vec3) -> Option<Hit> {
        let normal = pose.rotation.column(2).into_owned();
        let denom = normal.dot(dir);
        if denom.abs() < 1e-12 {
            return None;
        }
        let s = normal.dot(&(pose.translation - origin)) / denom;
        if s <= 1e-6 {
            return None;
        }
        let local = pose.rotation.transpose() * (origin + dir * s - pose.translation);
        self.board.is_solid(local.x, local.y).then_some(Hit {
            distance: s,
            surface: Surface::Board { index, x: local.x, y: local.y },
        })
    }

    /// The vertical pole a board hangs on: from the middle of its upper edge to the
    /// ceiling for boards above the LiDAR, from its lower edge to the floor otherwise, so
    /// that no pole crosses in front of a board below or above it.
    fn cast_pole(&self, pose: &Se3, origin: &Vec3, dir: &Vec3) -> Option<Hit> {
        let hanging = pose.translation.z > 0.0;
        let edge_y = if hanging { -self.board.height / 2.0 } else { self.board.height / 2.0 };
        let end = pose.act(&Vec3::new(0.0, edge_y, 0.0));
        let (z_lo, z_hi) = if hanging { (end.z, self.ceiling_z) } else { (self.floor_z, end.z) };
        let (ox, oy) = (origin.x - end.x, origin.y - end.y);
        let a = dir.x * dir.x + dir.y * dir.y;
        if a < 1e-12 {
            return None;
        }
        let b = ox * dir.x + oy * dir.y;
        let c = ox * ox + oy * oy - POLE_RADIUS * POLE_RADIUS;
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let s = (-b - disc.sqrt()) / a;
        let z = origin.z + s * dir.z;
        (s > 1e-6 && z >= z_lo && z <= z_hi)
            .then_some(Hit { distance: s, surface: Surface::Background { albedo: 0.25 } })
    }

    fn cast_crate(&self, c: &Crate, origin: &Vec3, dir: &Vec3) -> Option<Hit> {
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for k in 0..3 {
            if dir[k].abs() < 1e-12 {
                if origin[k] < c.min[k] || origin[k] > c.max[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((c.min[k] - origin[k]) / dir[k], (c.max[k] - origin[k]) / dir[k]);
            lo = lo.max(a.min(b));
            hi = hi.min(a.max(b));
        }
        (lo <= hi && lo > 1e-6).then(|| {
            let p = origin + dir * lo;
            let albedo =
                0.2 + 0.5 * texture(self.texture_seed ^ 0xC, p.x * 3.0 + p.z, p.y * 3.0 + p.z);
            Hit { distance: lo, surface: Surface::Background { albedo } }
        })
    }

    /// Floor, ceiling and the four walls, each textured.
    fn cast_shell(&self, origin: &Vec3, dir: &Vec3) -> Option<Hit> {
        let planes = [
            (2, self.floor_z, 1u64),
            (2, self.ceiling_z, 2),
            (0, self.front_x, 3),
            (0, self.back_x, 4),
            (1, self.side_y, 5),
            (1, -self.side_y, 6),
        ];
        let mut best: Option<Hit> = None;
        for (axis, level, id) in planes {
            if dir[axis].abs() < 1e-12 {
                continue;
            }
            let s = (level - origin[axis]) / dir[axis];
            if s <= 1e-6 || best.is_some_and(|b| b.distance <= s) {
                continue;
            }
            let p = origin + dir * s;
            let (u, v) = match axis {
                0 => (p.y, p.z),
                1 => (p.x, p.z),
                _ => (p.x, p.y),
            };
            let albedo = 0.15 + 0.6 * texture(self.texture_seed ^ id, u, v);
            best = Some(Hit { distance: s, surface: Surface::Background { albedo } });
        }
        best
    }
}

/// The means over [t − w/2, t + w/2] of the indicator of [0, `length`] and of the ±1
/// square wave of period 2·`square` (+1 on the first square) cut to that interval; the
/// point values when `w` is too small to integrate.
fn box_means(t: f64, w: f64, length: f64, square: f64) -> (f64, f64) {
    if w < 1e-9 * square {
        if !(0.0..length).contains(&t) {
            return (0.0, 0.0);
        }
        let wave = if (t / square).floor() as i64 % 2 == 0 { 1.0 } else { -1.0 };
        return (1.0, wave);
    }
    let (lo, hi) = ((t - w / 2.0).clamp(0.0, length), (t + w / 2.0).clamp(0.0, length));
    let triangle = |t: f64| {
        let phase = t.rem_euclid(2.0 * square);
        if phase < square {
            phase
        } else {
            2.0 * square - phase
        }
    };
    ((hi - lo) / w, (triangle(hi) - triangle(lo)) / w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world() -> World {
        // A 1.4 × 1.1 m board with four 0.1 m holes and a 5 × 3 checker off its centre.
        let holes = [[-0.55, -0.38], [0.55, -0.38], [-0.55, 0.38], [0.55, 0.38]];
        let board = BoardSpec {
            width: 1.4,
            height: 1.1,
            inner_corners: [5, 3],
            square: 0.1,
            hole_radius: 0.1,
            holes: holes.into_iter().collect(),
            count: 1,
            checker_offset: [0.013, -0.021],
        };
        board.validate().expect("a valid board");
        World::new(&board, Vec::new(), &mut Rng::new(1))
    }

    /// Without a footprint the mean is the point value, on every square and off the checker.
    #[test]
    fn a_vanishing_footprint_gives_the_point_albedo() {
        let (world, mut rng) = (world(), Rng::new(7));
        for _ in 0..10_000 {
            let (x, y) = (rng.range(-0.6, 0.6), rng.range(-0.6, 0.6));
            let (over, point) = (world.board_albedo_over(x, y, 0.0, 0.0), world.board_albedo(x, y));
            assert!((over - point).abs() < 1e-12, "({x}, {y}): {over} vs {point}");
        }
    }

    /// The closed form against a dense average of point values over the same box, for
    /// boxes inside one square, across edges and corners, and over the checker's rim.
    #[test]
    fn the_footprint_mean_is_the_average_of_the_points_it_covers() {
        let (world, mut rng) = (world(), Rng::new(8));
        let square = world.board.square;
        for _ in 0..300 {
            let (x, y) = (rng.range(-0.6, 0.6), rng.range(-0.6, 0.6));
            let (w, h) = (rng.range(0.01, 1.5) * square, rng.range(0.01, 1.5) * square);
            let k = 200;
            let mut sum = 0.0;
            for i in 0..k {
                for j in 0..k {
                    let px = x + w * ((i as f64 + 0.5) / k as f64 - 0.5);
                    let py = y + h * ((j as f64 + 0.5) / k as f64 - 0.5);
                    sum += world.board_albedo(px, py);
                }
            }
            let dense = sum / (k * k) as f64;
            let closed = world.board_albedo_over(x, y, w, h);
            assert!((closed - dense).abs() < 0.01, "({x}, {y}) {w}×{h}: {closed} vs {dense}");
        }
    }
}
