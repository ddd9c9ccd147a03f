//! The surveyed-room problem (`solve::room`): its analytic Jacobians against central
//! differences, its solve recovering a perturbed start on exact data, and no heap
//! allocation inside the solve and the covariance (counting allocator).

#[path = "common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::count_allocations;
use nalgebra::{SMatrix, SVector};
use roomcal::geometry::se3::so3_exp;
use roomcal::geometry::{Camera, CameraModel, Se3, Vec2, Vec3};
use roomcal::solve::room::{
    apply_room_step, plane_frame, room_covariance, solve_room, BlockPrior, RoomParams, RoomProblem,
    ROOM_SHARED,
};
use roomcal::solve::{BoardObservation, Loss, PlanePoints};

const B: usize = 16;

struct Scene {
    camera: Camera,
    extrinsic: Se3,
    room_to_camera: Se3,
    boards: Vec<Se3>,
    object: Vec<Vec3>,
    holes: Vec<Vec3>,
    corners: Vec<Vec<Vec2>>,
    holes_lidar: Vec<Vec<Vec3>>,
    board_planes: Vec<PlanePoints>,
    /// Room planes: frame (plane → room) and the LiDAR's points on it.
    planes: Vec<(Se3, PlanePoints)>,
}

fn scene() -> Scene {
    let camera = Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx: 1400.0,
        fy: 1398.0,
        cx: 958.0,
        cy: 604.0,
        distortion: [-0.1, 0.03, 0.0005, -0.0003, 0.0],
    };
    // Room frame: x right, y down, z forward (as the camera, parked at the origin).
    let room_to_camera = Se3 {
        rotation: so3_exp(&Vec3::new(0.01, -0.02, 0.015)),
        translation: Vec3::new(0.05, -0.02, 0.1),
    };
    // LiDAR: x forward, y left, z up, 0.3 m above the camera.
    let r_lc = nalgebra::Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    let extrinsic = Se3 {
        rotation: so3_exp(&Vec3::new(0.005, 0.01, -0.007)) * r_lc,
        translation: Vec3::new(0.02, -0.3, -0.05),
    };
    let boards: Vec<Se3> = [
        (-1.2, -0.3, 4.5, 0.3),
        (0.0, 0.0, 4.8, 0.0),
        (1.2, 0.2, 4.4, -0.3),
        (-0.6, 0.5, 3.5, 0.15),
    ]
    .iter()
    .map(|&(x, y, z, yaw)| Se3 {
        rotation: so3_exp(&Vec3::new(0.1, yaw, 0.05)),
        translation: Vec3::new(x, y, z),
    })
    .collect();
    let object: Vec<Vec3> = (0..35)
        .map(|i| Vec3::new(((i % 7) as f64 - 3.0) * 0.1, ((i / 7) as f64 - 2.0) * 0.1, 0.0))
        .collect();
    let holes: Vec<Vec3> = [(-0.3, -0.2), (0.3, -0.2), (-0.3, 0.2), (0.3, 0.2)]
        .iter()
        .map(|&(x, y)| Vec3::new(x, y, 0.0))
        .collect();
    let to_lidar = extrinsic.inverse();
    let mut corners = Vec::new();
    let mut holes_lidar = Vec::new();
    let mut board_planes = Vec::new();
    for b in &boards {
        let to_cam = room_to_camera.compose(b);
        corners.push(object.iter().map(|x| camera.project(&to_cam.act(x)).unwrap()).collect());
        holes_lidar.push(holes.iter().map(|h| to_lidar.act(&to_cam.act(h))).collect());
        let face = (0..40).map(|i| {
            let p = Vec3::new(((i % 8) as f64 - 3.5) * 0.08, ((i / 8) as f64 - 2.0) * 0.1, 0.0);
            to_lidar.act(&to_cam.act(&p))
        });
        board_planes.push(PlanePoints::from_points(face, 0.02).unwrap());
    }
    // Floor (y = 1.6 down), a wall (z = 6), a side wall (x = -3).
    let planes = [
        (Vec3::new(0.0, 1.0, 0.0), 1.6),
        (Vec3::new(0.0, 0.0, 1.0), 6.0),
        (Vec3::new(-1.0, 0.0, 0.0), 3.0),
    ]
    .iter()
    .map(|&(n, d)| {
        let frame = plane_frame(&n, d);
        let to_cam = room_to_camera.compose(&frame);
        let pts = (0..60).map(|i| {
            let p = Vec3::new(((i % 10) as f64 - 4.5) * 0.4, ((i / 10) as f64 - 2.5) * 0.4, 0.0);
            to_lidar.act(&to_cam.act(&p))
        });
        (frame, PlanePoints::from_points(pts, 0.02).unwrap())
    })
    .collect();
    Scene {
        camera,
        extrinsic,
        room_to_camera,
        boards,
        object,
        holes,
        corners,
        holes_lidar,
        board_planes,
        planes,
    }
}

fn problem(s: &Scene) -> RoomProblem<'_, B> {
    let mut p = RoomProblem::new(0.1, 1.0, Loss::Huber(3.0));
    for (i, b) in s.boards.iter().enumerate() {
        let k = p
            .add_block(BlockPrior { pose: *b, sigma_m: 0.0005, sigma_rad: 0.01f64.to_radians() })
            .unwrap();
        let obs = BoardObservation {
            object: &s.object,
            corners: &s.corners[i],
            holes_board: &s.holes,
            holes_lidar: &s.holes_lidar[i],
            hole_sigma_px: None,
            plane: Some(s.board_planes[i]),
        };
        p.add_observation(k, obs).unwrap();
    }
    for (frame, pts) in &s.planes {
        let k = p
            .add_block(BlockPrior { pose: *frame, sigma_m: 0.002, sigma_rad: 0.01f64.to_radians() })
            .unwrap();
        p.add_observation(k, BoardObservation { plane: Some(*pts), ..Default::default() }).unwrap();
    }
    p
}

/// A start away from the truth in every parameter.
fn perturbed(s: &Scene, p: &RoomProblem<'_, B>) -> RoomParams<Camera, B> {
    let mut params = p.params_at_priors(s.camera, s.extrinsic, s.room_to_camera);
    params.camera.fx *= 1.01;
    params.camera.cx += 4.0;
    params.lidar_to_camera.translation.y += 0.03;
    params.lidar_to_camera.rotation =
        so3_exp(&Vec3::new(0.0, 0.01, 0.0)) * params.lidar_to_camera.rotation;
    params.room_to_camera.translation.x += 0.04;
    params.room_to_camera.rotation =
        so3_exp(&Vec3::new(0.0, 0.0, 0.01)) * params.room_to_camera.rotation;
    params.blocks[1].translation.z += 0.001;
    params
}

/// All whitened residuals (measurements then priors) as one vector, and the analytic
/// Jacobian over [shared | blocks].
fn stacked(
    p: &RoomProblem<'_, B>,
    params: &RoomParams<Camera, B>,
    blocks: usize,
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = ROOM_SHARED + 6 * blocks;
    let (mut r, mut j) = (Vec::new(), Vec::new());
    p.for_each_residual(params, |k, _, res, js, jb, _| {
        for row in 0..2 {
            r.push(res[row]);
            let mut line = vec![0.0; n];
            for c in 0..ROOM_SHARED {
                line[c] = js[(row, c)];
            }
            for c in 0..6 {
                line[ROOM_SHARED + 6 * k + c] = jb[(row, c)];
            }
            j.push(line);
        }
    })
    .unwrap();
    p.for_each_prior(params, |k, res, jp| {
        for row in 0..6 {
            r.push(res[row]);
            let mut line = vec![0.0; n];
            for c in 0..6 {
                line[ROOM_SHARED + 6 * k + c] = jp[(row, c)];
            }
            j.push(line);
        }
    });
    (r, j)
}

#[test]
fn analytic_jacobians_match_central_differences() {
    let s = scene();
    let p = problem(&s);
    let params = perturbed(&s, &p);
    let blocks = params.blocks.len();
    let (_, analytic) = stacked(&p, &params, blocks);
    let n = ROOM_SHARED + 6 * blocks;
    let mut worst: f64 = 0.0;
    for col in 0..n {
        if (4 + s.camera.num_params()..9).contains(&col) {
            continue;
        }
        // Pixels-scale steps for fx..cy, small ones for distortion and motions.
        let h = if col < 4 {
            1e-3
        } else if col < 9 {
            1e-6
        } else {
            1e-7
        };
        let shifted = |sign: f64| {
            let mut shared = SVector::<f64, ROOM_SHARED>::zeros();
            let mut steps = [SVector::<f64, 6>::zeros(); B];
            if col < ROOM_SHARED {
                shared[col] = sign * h;
            } else {
                steps[(col - ROOM_SHARED) / 6][(col - ROOM_SHARED) % 6] = sign * h;
            }
            stacked(&p, &apply_room_step(&params, &shared, &steps), blocks).0
        };
        let (plus, minus) = (shifted(1.0), shifted(-1.0));
        for (row, line) in analytic.iter().enumerate() {
            let numeric = (plus[row] - minus[row]) / (2.0 * h);
            let scale = line[col].abs().max(numeric.abs()).max(1.0);
            worst = worst.max((numeric - line[col]).abs() / scale);
        }
    }
    assert!(worst < 1e-4, "worst relative Jacobian error {worst:e}");
}

#[test]
fn solve_recovers_the_truth_without_heap_allocation() {
    let s = scene();
    let p = problem(&s);
    let mut params = perturbed(&s, &p);
    let ((report, cov), count) = count_allocations(|| {
        let report = solve_room(&p, &mut params, 50);
        let cov = room_covariance(&p, &params);
        (report, cov)
    });
    let report = report.unwrap();
    assert_eq!(count, 0, "the room solve and covariance allocated {count} times");
    assert!(
        report.iterations > 1 && report.final_cost < 1e-6 * report.initial_cost.max(1.0),
        "{report:?}"
    );
    assert!((params.camera.fx - s.camera.fx).abs() < 1e-3, "fx {}", params.camera.fx);
    assert!((params.lidar_to_camera.translation - s.extrinsic.translation).norm() < 1e-5);
    assert!((params.room_to_camera.translation - s.room_to_camera.translation).norm() < 1e-5);
    let cov: SMatrix<f64, ROOM_SHARED, ROOM_SHARED> = cov.unwrap();
    assert!((0..ROOM_SHARED).all(|i| cov[(i, i)] >= 0.0));
}
