//! A synthetic rig in a surveyed room for the rig solver's tests (`solve::rig`): two
//! cameras (60° and 90°), two LiDARs (roof, bumper), two parkings of the vehicle, four
//! boards and three room planes. Include with
//! `use crate::common::rig_scene;`.
//!
//! Observations: every camera sees every board in every frame; the roof LiDAR's holes
//! and face points of every board are seen in the first camera, the bumper's of boards
//! 2 and 3 in the second camera, its face points of board 0 alone (no camera); both
//! LiDARs see the three planes. With noise, the survey's priors are drawn off the truth
//! by their σ too.

#![allow(dead_code)]

use roomcal::geometry::se3::so3_exp;
use roomcal::geometry::{Camera, CameraModel, Se3, Vec2, Vec3};
use roomcal::solve::rig::{plane_frame, BlockPrior};
use roomcal::solve::rig::{rig_shared, RigObservation, RigParams, RigProblem};
use roomcal::solve::{hole_sigma_px, BoardObservation, Loss, PlanePoints};

pub const C: usize = 2;
pub const L: usize = 2;
pub const F: usize = 2;
pub const B: usize = 8;
pub const O: usize = 48;
pub const N: usize = rig_shared(C, L, F);

pub type Problem<'a> = RigProblem<'a, C, L, F, B, O, N>;
pub type Params = RigParams<Camera, C, L, F, B>;

/// What one observation measured (owned; the problem borrows it).
pub struct Measured {
    pub frame: usize,
    pub block: usize,
    pub camera: Option<usize>,
    pub lidar: Option<usize>,
    pub corners: Vec<Vec2>,
    pub holes_lidar: Vec<Vec3>,
    pub plane: Option<PlanePoints>,
}

pub struct Scene {
    pub truth: Params,
    pub priors: Vec<BlockPrior>,
    pub object: Vec<Vec3>,
    pub holes: Vec<Vec3>,
    pub measured: Vec<Measured>,
}

/// A tiny deterministic normal generator (noise for the σ study).
pub struct Rng(pub u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    pub fn normal(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (2.0 * std::f64::consts::PI * self.uniform()).cos()
    }
}

fn camera(fx: f64, cx: f64, cy: f64, k1: f64) -> Camera {
    Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx,
        fy: fx * 0.999,
        cx,
        cy,
        distortion: [k1, 0.03, 0.0005, -0.0003, 0.0],
    }
}

fn pose(omega: [f64; 3], t: [f64; 3]) -> Se3 {
    Se3 { rotation: so3_exp(&Vec3::from(omega)), translation: Vec3::from(t) }
}

/// The scene; `noise`: corner σ (px), hole σ (m) and plane-point σ (m) drawn from `rng`
/// (`None`: exact measurements).
pub fn scene(mut noise: Option<(f64, f64, f64, &mut Rng)>) -> Scene {
    // LiDAR axes: x forward, y left, z up; camera axes x right, y down, z forward.
    let r_lc = nalgebra::Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    let lidar = |omega: [f64; 3], t: [f64; 3]| Se3 {
        rotation: so3_exp(&Vec3::from(omega)) * r_lc,
        translation: Vec3::from(t),
    };
    let truth = Params {
        cameras: [camera(1400.0, 958.0, 604.0, -0.1), camera(960.0, 965.0, 597.0, -0.2)],
        first_to_camera: [Se3::identity(), pose([0.004, 0.14, -0.003], [0.25, 0.01, -0.02])],
        lidar_to_first: [
            lidar([0.005, 0.01, -0.007], [0.05, -0.42, -0.28]),
            lidar([-0.004, 0.006, 0.01], [0.04, 1.1, 0.7]),
        ],
        room_to_first: [
            pose([0.01, -0.02, 0.015], [0.05, -0.02, 0.1]),
            pose([-0.005, 0.03, 0.0], [-0.1, 0.01, 0.3]),
        ],
        blocks: heapless::Vec::new(),
    };
    let boards: Vec<Se3> = [
        (-1.0, -0.3, 4.5, 0.3),
        (0.0, 0.0, 4.8, 0.0),
        (1.0, 0.2, 4.4, -0.3),
        (-0.5, 0.5, 3.5, 0.15),
    ]
    .iter()
    .map(|&(x, y, z, yaw)| pose([0.1, yaw, 0.05], [x, y, z]))
    .collect();
    // Floor (y = 1.6, y down), the far wall (z = 6), a side wall (x = −3).
    let planes: Vec<Se3> = [
        (Vec3::new(0.0, 1.0, 0.0), 1.6),
        (Vec3::new(0.0, 0.0, 1.0), 6.0),
        (Vec3::new(-1.0, 0.0, 0.0), 3.0),
    ]
    .iter()
    .map(|(n, d)| plane_frame(n, *d))
    .collect();
    let mut priors: Vec<BlockPrior> = boards
        .iter()
        .map(|b| BlockPrior { pose: *b, sigma_m: 0.0005, sigma_rad: 0.01f64.to_radians() })
        .collect();
    priors.extend(planes.iter().map(|p| BlockPrior {
        pose: *p,
        sigma_m: 0.002,
        sigma_rad: 0.02f64.to_radians(),
    }));
    let object: Vec<Vec3> = (0..35)
        .map(|i| Vec3::new(((i % 7) as f64 - 3.0) * 0.1, ((i / 7) as f64 - 2.0) * 0.1, 0.0))
        .collect();
    let holes: Vec<Vec3> = [(-0.3, -0.2), (0.3, -0.2), (-0.3, 0.2), (0.3, 0.2)]
        .iter()
        .map(|&(x, y)| Vec3::new(x, y, 0.0))
        .collect();
    let (corner_s, hole_s, point_s) = noise.as_ref().map_or((0.0, 0.0, 0.0), |n| (n.0, n.1, n.2));
    let mut normal = |s: f64| match noise.as_mut() {
        Some((_, _, _, rng)) => s * rng.normal(),
        None => 0.0,
    };
    let mut measured = Vec::new();
    for f in 0..F {
        let first = truth.room_to_first[f];
        let in_first = |k: usize, all: &[Se3]| first.compose(&all[k]);
        for c in 0..C {
            let to_camera = truth.first_to_camera[c];
            for k in 0..boards.len() {
                let board_to_camera = to_camera.compose(&in_first(k, &boards));
                let corners = object
                    .iter()
                    .map(|x| {
                        let u = truth.cameras[c].project(&board_to_camera.act(x)).unwrap();
                        u + Vec2::new(normal(corner_s), normal(corner_s))
                    })
                    .collect();
                measured.push(Measured {
                    frame: f,
                    block: k,
                    camera: Some(c),
                    lidar: None,
                    corners,
                    holes_lidar: Vec::new(),
                    plane: None,
                });
            }
        }
        for l in 0..L {
            let first_to_lidar = truth.lidar_to_first[l].inverse();
            let lidar_points = |to_first: Se3, spacing: f64, normal: &mut dyn FnMut(f64) -> f64| {
                let pts: Vec<Vec3> = (0..48)
                    .map(|i| {
                        let p = Vec3::new(
                            ((i % 8) as f64 - 3.5) * spacing,
                            ((i / 8) as f64 - 2.5) * spacing,
                            normal(point_s),
                        );
                        first_to_lidar.act(&to_first.act(&p))
                    })
                    .collect();
                PlanePoints::from_points(pts, point_s.max(0.002)).unwrap()
            };
            for k in 0..boards.len() {
                let (camera, holes_seen) = match (l, k) {
                    (0, _) => (Some(0), true),
                    (1, 2) | (1, 3) => (Some(1), true),
                    (1, 0) => (None, false),
                    _ => continue,
                };
                let to_first = in_first(k, &boards);
                let holes_lidar = if holes_seen {
                    holes
                        .iter()
                        .map(|h| {
                            let e = Vec3::new(normal(hole_s), normal(hole_s), normal(hole_s));
                            first_to_lidar.act(&to_first.act(h)) + e
                        })
                        .collect()
                } else {
                    Vec::new()
                };
                let plane = Some(lidar_points(to_first, 0.08, &mut normal));
                measured.push(Measured {
                    frame: f,
                    block: k,
                    camera,
                    lidar: Some(l),
                    corners: Vec::new(),
                    holes_lidar,
                    plane,
                });
            }
            for p in 0..planes.len() {
                let plane = Some(lidar_points(in_first(p, &planes), 0.4, &mut normal));
                measured.push(Measured {
                    frame: f,
                    block: boards.len() + p,
                    camera: None,
                    lidar: Some(l),
                    corners: Vec::new(),
                    holes_lidar: Vec::new(),
                    plane,
                });
            }
        }
    }
    let mut truth = truth;
    truth.blocks = priors.iter().map(|p| p.pose).collect();
    // A noisy scene's survey is off the truth by its own σ, as a real one is.
    for prior in priors.iter_mut() {
        let (r, t) = (prior.sigma_rad, prior.sigma_m);
        let d = nalgebra::SVector::<f64, 6>::from_fn(|i, _| normal(if i < 3 { r } else { t }));
        prior.pose = prior.pose.perturb_left(&d);
    }
    Scene { truth, priors, object, holes, measured }
}

/// The problem over the scene's measurements: corner σ (px), hole σ (m, seen in pixels at
/// each board's true depth in its camera) and loss.
pub fn problem(s: &Scene, corner_sigma_px: f64, hole_sigma_m: f64, loss: Loss) -> Problem<'_> {
    let mut p = Problem::new([corner_sigma_px; C], 1.0, loss);
    for prior in &s.priors {
        p.add_block(*prior).unwrap();
    }
    add_measured(&mut p, s, hole_sigma_m, |_| true);
    p
}

/// The same scene without a survey: the four boards free (started at their truth), the
/// room's planes and everything measured of them left out.
pub fn free_problem(s: &Scene, corner_sigma_px: f64, hole_sigma_m: f64, loss: Loss) -> Problem<'_> {
    let mut p = Problem::new([corner_sigma_px; C], 1.0, loss);
    for k in 0..BOARDS {
        p.add_block(BlockPrior::free(s.truth.blocks[k])).unwrap();
    }
    add_measured(&mut p, s, hole_sigma_m, |m| m.block < BOARDS);
    p
}

/// Boards of the scene (blocks `0..BOARDS`; the room's planes follow).
pub const BOARDS: usize = 4;

/// The free-board problem's params: `params` with the planes' blocks dropped.
pub fn boards_only(params: &Params) -> Params {
    let mut p = params.clone();
    p.blocks.truncate(BOARDS);
    p
}

fn add_measured<'a>(
    p: &mut Problem<'a>,
    s: &'a Scene,
    hole_sigma_m: f64,
    keep: impl Fn(&Measured) -> bool,
) {
    for m in s.measured.iter().filter(|m| keep(m)) {
        let has_holes = !m.holes_lidar.is_empty();
        let observation = BoardObservation {
            object: if m.corners.is_empty() { &[] } else { &s.object },
            corners: &m.corners,
            holes_board: if has_holes { &s.holes } else { &[] },
            holes_lidar: &m.holes_lidar,
            hole_sigma_px: m.camera.filter(|_| has_holes).map(|c| {
                let t = &s.truth;
                let to_camera = t.first_to_camera[c]
                    .compose(&t.room_to_first[m.frame])
                    .compose(&t.blocks[m.block]);
                hole_sigma_px(t.cameras[c].fx, hole_sigma_m, to_camera.translation.z)
            }),
            plane: m.plane,
        };
        let o = RigObservation {
            frame: m.frame,
            block: m.block,
            camera: m.camera,
            lidar: m.lidar,
            observation,
        };
        p.add_observation(o).unwrap();
    }
}

/// A start away from the truth in every unknown.
pub fn perturbed(s: &Scene) -> Params {
    let mut p = s.truth.clone();
    p.cameras[0].fx *= 1.01;
    p.cameras[0].cx += 4.0;
    p.cameras[1].fy *= 0.99;
    p.cameras[1].cy -= 3.0;
    let nudge = |pose: &mut Se3, w: [f64; 3], t: [f64; 3]| {
        pose.rotation = so3_exp(&Vec3::from(w)) * pose.rotation;
        pose.translation += Vec3::from(t);
    };
    nudge(&mut p.first_to_camera[1], [0.0, 0.01, 0.005], [0.02, -0.01, 0.0]);
    nudge(&mut p.lidar_to_first[0], [0.0, 0.01, 0.0], [0.0, 0.03, 0.0]);
    nudge(&mut p.lidar_to_first[1], [0.01, 0.0, -0.01], [0.02, 0.0, -0.03]);
    nudge(&mut p.room_to_first[0], [0.0, 0.0, 0.01], [0.04, 0.0, 0.0]);
    nudge(&mut p.room_to_first[1], [0.005, -0.01, 0.0], [0.0, 0.02, -0.03]);
    p.blocks[1].translation.z += 0.001;
    p
}
