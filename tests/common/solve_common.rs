//! Shared fixtures for the solver tests: a reference pinhole-radtan camera written here
//! (an oracle independent of `geometry`), a seeded RNG, and a synthetic room with known
//! camera, extrinsic and board poses.
#![allow(dead_code)]

use nalgebra::{Matrix3, SMatrix, Vector3};
use roomcal::geometry::{Mat3, Se3, Vec2, Vec3};
use roomcal::solve::{PlanePoints, Projection, Projector, INTRINSICS};

/// Pinhole with OpenCV's k1 k2 p1 p2 k3, analytic Jacobians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadtanCam {
    pub k: [f64; INTRINSICS],
}

impl Projector for RadtanCam {
    fn num_params(&self) -> usize {
        INTRINSICS
    }
    fn params(&self) -> [f64; INTRINSICS] {
        self.k
    }
    fn set_params(&mut self, params: &[f64; INTRINSICS]) {
        self.k = *params;
    }
    fn project_with_jacobians(&self, p: &Vec3) -> Option<Projection> {
        if p.z <= 1e-9 {
            return None;
        }
        let [fx, fy, _cx, _cy, k1, k2, p1, p2, k3] = self.k;
        let (x, y) = (p.x / p.z, p.y / p.z);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let drad = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2; // d radial / d r2
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        let u = Vec2::new(fx * xd + self.k[2], fy * yd + self.k[3]);
        let dxd_dx = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x;
        let dxd_dy = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y;
        let dyd_dx = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y;
        let dyd_dy = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x;
        let dn = SMatrix::<f64, 2, 3>::new(
            1.0 / p.z,
            0.0,
            -p.x / (p.z * p.z),
            0.0,
            1.0 / p.z,
            -p.y / (p.z * p.z),
        );
        let dd = nalgebra::Matrix2::new(fx * dxd_dx, fx * dxd_dy, fy * dyd_dx, fy * dyd_dy);
        let jp = dd * dn;
        let mut jk = SMatrix::<f64, 2, INTRINSICS>::zeros();
        jk[(0, 0)] = xd;
        jk[(1, 1)] = yd;
        jk[(0, 2)] = 1.0;
        jk[(1, 3)] = 1.0;
        let (r4, r6) = (r2 * r2, r2 * r2 * r2);
        for (c, (a, b)) in [
            (x * r2, y * r2),
            (x * r4, y * r4),
            (2.0 * x * y, r2 + 2.0 * y * y),
            (r2 + 2.0 * x * x, 2.0 * x * y),
            (x * r6, y * r6),
        ]
        .into_iter()
        .enumerate()
        {
            jk[(0, 4 + c)] = fx * a;
            jk[(1, 4 + c)] = fy * b;
        }
        Some((u, jp, jk))
    }
    fn unproject(&self, px: &Vec2) -> Option<Vec3> {
        let [fx, fy, cx, cy, ..] = self.k;
        let d = Vec2::new((px.x - cx) / fx, (px.y - cy) / fy);
        // Fixed-point undistortion: enough for the test's mild distortion.
        let mut n = d;
        for _ in 0..50 {
            let (x, y) = (n.x, n.y);
            let [_, _, _, _, k1, k2, p1, p2, k3] = self.k;
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let tx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let ty = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            n = Vec2::new((d.x - tx) / radial, (d.y - ty) / radial);
        }
        Some(Vector3::new(n.x, n.y, 1.0).normalize())
    }
}

/// The ground-truth camera of the synthetic room (1920×1200).
pub fn truth_camera() -> RadtanCam {
    RadtanCam { k: [1400.0, 1395.0, 962.0, 603.0, -0.12, 0.05, 0.001, -0.0008, 0.01] }
}

/// xorshift64* with Box–Muller normals: deterministic, dependency-free noise.
pub struct Rng(pub u64);

impl Rng {
    pub fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    pub fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
    pub fn vec3(&mut self, s: f64) -> Vec3 {
        Vec3::new(self.normal() * s, self.normal() * s, self.normal() * s)
    }
}

/// Rodrigues, written here so fixtures do not depend on the code under test.
pub fn rot(w: &Vec3) -> Mat3 {
    let th = w.norm();
    if th < 1e-12 {
        return Mat3::identity();
    }
    let k = w / th;
    let kx = Matrix3::new(0.0, -k.z, k.y, k.z, 0.0, -k.x, -k.y, k.x, 0.0);
    Mat3::identity() + kx * th.sin() + kx * kx * (1.0 - th.cos())
}

/// Angle (rad) of `a · bᵀ`.
pub fn rot_angle(a: &Mat3, b: &Mat3) -> f64 {
    let c = ((a * b.transpose()).trace() - 1.0) / 2.0;
    c.clamp(-1.0, 1.0).acos()
}

/// The room's board: 7×5 inner corners of 8 cm centred on the origin, four holes.
pub fn board_corners() -> Vec<Vec3> {
    let mut v = Vec::new();
    for r in 0..5 {
        for c in 0..7 {
            v.push(Vec3::new((c as f64 - 3.0) * 0.08, (r as f64 - 2.0) * 0.08, 0.0));
        }
    }
    v
}

pub fn board_holes() -> Vec<Vec3> {
    [(-0.45, -0.35), (0.45, -0.35), (-0.45, 0.35), (0.45, 0.35)]
        .iter()
        .map(|&(x, y)| Vec3::new(x, y, 0.0))
        .collect()
}

/// The nominal LiDAR→camera mounting of DESIGN.md, slightly rotated (truth).
pub fn truth_extrinsic() -> Se3 {
    let nominal = Mat3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    Se3 {
        rotation: rot(&Vec3::new(0.01, -0.02, 0.015)) * nominal,
        translation: Vec3::new(0.05, 0.42, -0.28),
    }
}

/// `n` boards spread over the field of view at 2.5–4.5 m, tilted 20–40°.
pub fn truth_board_poses(n: usize) -> Vec<Se3> {
    let spots = [
        (-1.1, -0.5, 3.0, 0.5, 0.3),
        (1.1, -0.5, 3.2, -0.45, 0.35),
        (0.0, 0.0, 4.0, 0.1, -0.6),
        (-1.2, 0.6, 3.5, -0.4, -0.3),
        (1.2, 0.6, 3.3, 0.45, -0.35),
        (0.1, 0.7, 2.6, -0.6, 0.1),
        (-0.5, -0.9, 4.4, 0.3, 0.5),
        (0.6, -0.2, 2.8, -0.3, -0.55),
    ];
    (0..n)
        .map(|i| {
            let (x, y, z, a, b) = spots[i % spots.len()];
            let depth = z + 0.4 * (i / spots.len()) as f64;
            Se3 {
                rotation: rot(&Vec3::new(a, b, 0.1 * i as f64)),
                translation: Vec3::new(x * depth / 3.0, y * depth / 3.0, depth),
            }
        })
        .collect()
}

/// A synthetic room: measurements with noise plus the truth they came from.
pub struct Scene<C = RadtanCam> {
    pub camera: C,
    pub extrinsic: Se3,
    pub poses: Vec<Se3>,
    pub object: Vec<Vec3>,
    pub holes: Vec<Vec3>,
    pub corners: Vec<Vec<Vec2>>,
    pub holes_lidar: Vec<Vec<Vec3>>,
    /// Each board's LiDAR points (a grid over the board, [`PLANE_SIGMA_M`] along the
    /// normal) summarised for the point-to-plane term.
    pub planes: Vec<PlanePoints>,
}

/// Point-to-plane noise of the synthetic LiDAR board points (m).
pub const PLANE_SIGMA_M: f64 = 0.02;

pub fn scene(n: usize, pixel_sigma: f64, lidar_sigma_m: f64, seed: u64) -> Scene {
    scene_with(truth_camera(), n, pixel_sigma, lidar_sigma_m, seed)
}

/// [`scene`] seen through any camera model.
pub fn scene_with<C: Projector>(
    camera: C,
    n: usize,
    pixel_sigma: f64,
    lidar_sigma_m: f64,
    seed: u64,
) -> Scene<C> {
    let extrinsic = truth_extrinsic();
    let poses = truth_board_poses(n);
    let object = board_corners();
    let holes = board_holes();
    let mut rng = Rng(seed);
    let ext_inv_r = extrinsic.rotation.transpose();
    let mut corners = Vec::new();
    let mut holes_lidar = Vec::new();
    for pose in &poses {
        corners.push(
            object
                .iter()
                .map(|x| {
                    let u = camera.project(&(pose.rotation * x + pose.translation)).unwrap();
                    assert!(u.x > 0.0 && u.x < 1920.0 && u.y > 0.0 && u.y < 1200.0, "{u:?}");
                    u + Vec2::new(rng.normal(), rng.normal()) * pixel_sigma
                })
                .collect(),
        );
        holes_lidar.push(
            holes
                .iter()
                .map(|h| {
                    let pc = pose.rotation * h + pose.translation;
                    ext_inv_r * (pc - extrinsic.translation) + rng.vec3(lidar_sigma_m)
                })
                .collect(),
        );
    }
    // A separate stream, so that adding the planes left the other draws unchanged.
    let mut plane_rng = Rng(seed ^ 0x9e37_79b9_7f4a_7c15);
    let planes = poses
        .iter()
        .map(|pose| {
            let points: Vec<Vec3> = (0..15 * 12)
                .map(|k| {
                    let board = Vec3::new(
                        -0.56 + 0.08 * (k % 15) as f64,
                        -0.44 + 0.08 * (k / 15) as f64,
                        PLANE_SIGMA_M * plane_rng.normal(),
                    );
                    ext_inv_r * (pose.act(&board) - extrinsic.translation)
                })
                .collect();
            PlanePoints::from_points(points, PLANE_SIGMA_M).expect("a plane")
        })
        .collect();
    Scene { camera, extrinsic, poses, object, holes, corners, holes_lidar, planes }
}
