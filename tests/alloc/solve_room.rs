//! The surveyed room seen by one camera and one LiDAR (`solve::room`: the rig problem with
//! one of each and one frame): its analytic Jacobians against central differences, its
//! solve recovering a perturbed start on exact data, no heap allocation inside the solve
//! and the covariance (counting allocator), and its solution, σ and block costs on a noisy
//! scene equal to the former one-pair room solver's (`tests/solve_data/room_one_pair.txt`).
//! The same for the room moved by the survey's modes (`solve::room_modes`): its condensed
//! equations against the numeric gradient and Hessian of its cost, and its solution equal
//! to the per-block priors' when every mode moves one axis of one block by that block's σ.

use crate::common::stack::Stacker;
use crate::counting_alloc::count_allocations;
use nalgebra::{SMatrix, SVector};
use roomcal::geometry::se3::so3_exp;
use roomcal::geometry::{Camera, CameraModel, Se3, Vec2, Vec3};
use roomcal::solve::rig::{apply_rig_step, plane_frame, rig_covariance, solve_rig, BlockPrior};
use roomcal::solve::room::{pair_observation, RoomParams, RoomProblem, ROOM_SHARED};
use roomcal::solve::room_modes::{
    modes_covariance, solve_modes, ModeBasis, ModesParams, ModesProblem, MAX_MODES, MODES_SHARED,
};
use roomcal::solve::schur::{SchurProblem, SchurSystem};
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
    let mut p = RoomProblem::new([0.1], 1.0, Loss::Huber(3.0));
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
        p.add_observation(pair_observation(k, obs)).unwrap();
    }
    for (frame, pts) in &s.planes {
        let k = p
            .add_block(BlockPrior { pose: *frame, sigma_m: 0.002, sigma_rad: 0.01f64.to_radians() })
            .unwrap();
        let obs = BoardObservation { plane: Some(*pts), ..Default::default() };
        p.add_observation(pair_observation(k, obs)).unwrap();
    }
    p
}

/// A start away from the truth in every parameter.
fn perturbed(s: &Scene, p: &RoomProblem<'_, B>) -> RoomParams<Camera, B> {
    let mut params = at_truth(s, p);
    params.cameras[0].fx *= 1.01;
    params.cameras[0].cx += 4.0;
    let ext = &mut params.lidar_to_first[0];
    ext.translation.y += 0.03;
    ext.rotation = so3_exp(&Vec3::new(0.0, 0.01, 0.0)) * ext.rotation;
    let room = &mut params.room_to_first[0];
    room.translation.x += 0.04;
    room.rotation = so3_exp(&Vec3::new(0.0, 0.0, 0.01)) * room.rotation;
    params.blocks[1].translation.z += 0.001;
    params
}

/// The scene's camera, extrinsic and room pose, every block at its prior.
fn at_truth(s: &Scene, p: &RoomProblem<'_, B>) -> RoomParams<Camera, B> {
    p.params_at_priors([s.camera], [Se3::identity()], [s.extrinsic], [s.room_to_camera])
}

/// The scene with noisy corners, so that the priors matter: a fixed pattern of ±0.3 px.
fn noisy(s: Scene) -> Scene {
    let corners = s
        .corners
        .iter()
        .enumerate()
        .map(|(b, cs)| {
            cs.iter()
                .enumerate()
                .map(|(i, c)| {
                    c + 0.3
                        * Vec2::new(
                            ((b * 31 + i * 7) as f64).sin(),
                            ((b * 17 + i * 11) as f64).cos(),
                        )
                })
                .collect()
        })
        .collect();
    Scene { corners, ..s }
}

/// All whitened residuals (measurements then priors) as one vector, and the analytic
/// Jacobian over [shared | blocks] (`common::stack`).
fn stacked(
    p: &RoomProblem<'_, B>,
    params: &RoomParams<Camera, B>,
    blocks: usize,
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let mut s = Stacker::new(ROOM_SHARED, blocks);
    p.for_each_residual(params, |k, _, res, js, jb, _| s.measurement(k, res, js, jb)).unwrap();
    p.for_each_prior(params, |k, res, jp| s.prior(k, res, jp));
    s.finish()
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
            stacked(&p, &apply_rig_step(&params, &shared, &steps), blocks).0
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
        let report = solve_rig(&p, &mut params, 50);
        let cov = rig_covariance(&p, &params);
        (report, cov)
    });
    let report = report.unwrap();
    assert_eq!(count, 0, "the room solve and covariance allocated {count} times");
    assert!(
        report.iterations > 1 && report.final_cost < 1e-6 * report.initial_cost.max(1.0),
        "{report:?}"
    );
    let fx = params.cameras[0].fx;
    assert!((fx - s.camera.fx).abs() < 1e-3, "fx {fx}");
    assert!((params.lidar_to_first[0].translation - s.extrinsic.translation).norm() < 1e-5);
    assert!((params.room_to_first[0].translation - s.room_to_camera.translation).norm() < 1e-5);
    let cov: SMatrix<f64, ROOM_SHARED, ROOM_SHARED> = cov.unwrap().matrix;
    assert!((0..ROOM_SHARED).all(|i| cov[(i, i)] >= 0.0));
}

/// Modes that each move one axis of one block by that block's prior σ: the joint prior
/// of a survey whose errors are independent, block by block.
fn independent_modes(p: &RoomProblem<'_, B>) -> (SVector<f64, MAX_MODES>, Vec<ModeBasis>) {
    let mut sigma = SVector::<f64, MAX_MODES>::zeros();
    let mut basis = vec![ModeBasis::zeros(); p.priors().len()];
    for (k, prior) in p.priors().iter().enumerate() {
        for axis in 0..6 {
            let mode = 6 * k + axis;
            sigma[mode] = if axis < 3 { prior.sigma_rad } else { prior.sigma_m };
            basis[k][(axis, mode)] = 1.0;
        }
    }
    (sigma, basis)
}

/// Modes that move every block at once (a dense, deterministic basis).
fn correlated_modes(p: &RoomProblem<'_, B>) -> (SVector<f64, MAX_MODES>, Vec<ModeBasis>) {
    let sigma =
        SVector::<f64, MAX_MODES>::from_fn(|i, _| if i < 20 { 1.0 + 0.1 * i as f64 } else { 0.0 });
    let basis = (0..p.priors().len())
        .map(|k| ModeBasis::from_fn(|r, c| 1e-3 * ((1 + k * 7 + r * 13 + c * 29) as f64).sin()))
        .collect();
    (sigma, basis)
}

/// `params ⊕ h eᵢ` over the modes problem's shared parameters.
fn stepped(
    problem: &ModesProblem<'_, '_, B>,
    params: &ModesParams<Camera, B>,
    i: usize,
    h: f64,
) -> ModesParams<Camera, B> {
    let mut step = SVector::<f64, MODES_SHARED>::zeros();
    step[i] = h;
    problem.apply(params, &step, &[])
}

/// The step of every shared parameter for central differences: pixels for fx..cy; the
/// modes move blocks by 10⁻³ of their amplitude.
fn step_of(i: usize) -> f64 {
    if i < 4 {
        1e-3
    } else if i < 9 {
        1e-6
    } else if i < ROOM_SHARED {
        1e-7
    } else {
        1e-4
    }
}

#[test]
fn condensed_modes_equations_are_the_gradient_and_hessian_of_their_cost() {
    let s = scene();
    let p = problem(&s);
    let (sigma, basis) = correlated_modes(&p);
    let modes = ModesProblem::new(&p, sigma, &basis).unwrap();
    let truth = ModesParams { room: at_truth(&s, &p), amplitudes: SVector::zeros() };
    let skip = |i: usize| (4 + s.camera.num_params()..9).contains(&i) || i >= ROOM_SHARED + 20;
    // The gradient, away from the truth (residuals and amplitudes not zero).
    let mut away = stepped(&modes, &truth, ROOM_SHARED + 3, 0.5);
    away.room.cameras[0].cx += 2.0;
    away.room.lidar_to_first[0].translation.y += 0.01;
    let ne: SchurSystem<MODES_SHARED, 0> = modes.normal_equations(&away).unwrap();
    for i in (0..MODES_SHARED).filter(|&i| !skip(i)) {
        let h = step_of(i);
        let cost = |sign: f64| modes.cost(&stepped(&modes, &away, i, sign * h)).unwrap();
        let numeric = (cost(1.0) - cost(-1.0)) / (2.0 * h);
        let scale = numeric.abs().max(ne.g_shared[i].abs()).max(1.0);
        assert!(
            (numeric - ne.g_shared[i]).abs() / scale < 1e-5,
            "∂cost/∂x{i}: {numeric} vs {}",
            ne.g_shared[i]
        );
    }
    // The Hessian at the truth (exact data: Gauss–Newton is exact there).
    let at_truth: SchurSystem<MODES_SHARED, 0> = modes.normal_equations(&truth).unwrap();
    let mut worst: f64 = 0.0;
    for i in (0..MODES_SHARED).filter(|&i| !skip(i)) {
        let h = step_of(i);
        let gradient = |sign: f64| {
            let ne: SchurSystem<MODES_SHARED, 0> =
                modes.normal_equations(&stepped(&modes, &truth, i, sign * h)).unwrap();
            ne.g_shared
        };
        let column = (gradient(1.0) - gradient(-1.0)) / (2.0 * h);
        for r in (0..MODES_SHARED).filter(|&r| !skip(r)) {
            let scale = column[r].abs().max(at_truth.v[(r, i)].abs()).max(1.0);
            worst = worst.max((column[r] - at_truth.v[(r, i)]).abs() / scale);
        }
    }
    assert!(worst < 1e-3, "worst relative Hessian error {worst:e}");
}

#[test]
fn independent_modes_solve_as_the_blocks_own_priors_without_heap_allocation() {
    let scene_noisy = noisy(scene());
    let p_noisy = problem(&scene_noisy);
    let mut blocks = perturbed(&scene_noisy, &p_noisy);
    solve_rig(&p_noisy, &mut blocks, 50).unwrap();
    let blocks_cov = rig_covariance(&p_noisy, &blocks).unwrap().matrix;
    let (sigma, basis) = independent_modes(&p_noisy);
    let modes = ModesProblem::new(&p_noisy, sigma, &basis).unwrap();
    let mut params =
        ModesParams { room: perturbed(&scene_noisy, &p_noisy), amplitudes: SVector::zeros() };
    // The start's block 1 is off its prior: in the modes problem that is where the prior is.
    params.room.blocks[1] = p_noisy.priors()[1].pose;
    let ((iterations, cov), count) = count_allocations(|| {
        let iterations = solve_modes(&modes, &mut params, 50);
        let cov = modes_covariance(&modes, &params);
        (iterations, cov)
    });
    assert_eq!(count, 0, "the modes solve and covariance allocated {count} times");
    assert!(iterations.unwrap() > 1);
    let cov = cov.unwrap();
    let got = &params.room;
    let (fx, want) = (got.cameras[0].fx, blocks.cameras[0].fx);
    assert!((fx - want).abs() < 1e-6 * want, "fx {fx} vs {want}");
    let ext = |p: &RoomParams<Camera, B>| p.lidar_to_first[0].translation;
    let room = |p: &RoomParams<Camera, B>| p.room_to_first[0].translation;
    assert!((ext(got) - ext(&blocks)).norm() < 1e-7);
    assert!((room(got) - room(&blocks)).norm() < 1e-7);
    for (a, b) in got.blocks.iter().zip(&blocks.blocks) {
        assert!((a.translation - b.translation).norm() < 1e-7);
    }
    for i in 0..ROOM_SHARED {
        let (x, y) = (cov[(i, i)], blocks_cov[(i, i)]);
        assert!((x - y).abs() <= 1e-4 * y.max(1e-30), "σ² of parameter {i}: {x:e} vs {y:e}");
    }
}

/// Every number of a solve as `tests/solve_data/room_one_pair.txt` lists them: label, values.
fn figures(p: &RoomProblem<'_, B>, start: &RoomParams<Camera, B>) -> Vec<(String, Vec<f64>)> {
    let pose = |s: &Se3| s.rotation.iter().chain(s.translation.iter()).copied().collect();
    let mut params = start.clone();
    let r = solve_rig(p, &mut params, 100).unwrap();
    let mut out: Vec<(String, Vec<f64>)> = vec![
        (
            "REPORT".into(),
            vec![
                r.iterations as f64,
                r.initial_cost,
                r.final_cost,
                r.residuals as f64,
                r.corner_rms_px[0],
                r.hole_rms_px[0],
            ],
        ),
        ("CAMERA".into(), params.cameras[0].params().to_vec()),
        ("EXT".into(), pose(&params.lidar_to_first[0])),
        ("ROOM".into(), pose(&params.room_to_first[0])),
    ];
    out.extend(params.blocks.iter().map(|b| ("BLOCK".to_string(), pose(b))));
    let cov = rig_covariance(p, &params).unwrap().matrix;
    out.push(("COV".into(), cov.iter().copied().collect()));
    let costs = p.block_costs(&params).unwrap();
    out.push(("COSTS".into(), costs.iter().flat_map(|&(m, q)| [m, q]).collect()));
    let (sigma, basis) = correlated_modes(p);
    let modes = ModesProblem::new(p, sigma, &basis).unwrap();
    let room = p.params_at_priors(
        params.cameras,
        [Se3::identity()],
        params.lidar_to_first,
        params.room_to_first,
    );
    let mut joint = ModesParams { room, amplitudes: SVector::zeros() };
    let iterations = solve_modes(&modes, &mut joint, 100).unwrap();
    let mcov = modes_covariance(&modes, &joint).unwrap();
    let mut head = vec![iterations as f64];
    head.extend(joint.room.cameras[0].params());
    head.extend(joint.amplitudes.iter());
    out.push(("MODES".into(), head));
    out.push(("MEXT".into(), pose(&joint.room.lidar_to_first[0])));
    out.push(("MROOM".into(), pose(&joint.room.room_to_first[0])));
    out.push(("MCOV".into(), mcov.iter().copied().collect()));
    out
}

/// The rig problem with one camera, one LiDAR and one frame is the former one-pair room
/// solver: from the same noisy scene and start, every figure it gave (the solve's report,
/// intrinsics, extrinsic, room pose, blocks, the 21×21 covariance, each block's measurement
/// and prior cost, and the room modes' solve from that solution with their covariance)
/// agrees to 1e-12 relative.
#[test]
fn the_one_pair_rig_solve_is_the_former_room_solve() {
    let text = include_str!("../solve_data/room_one_pair.txt");
    let recorded: Vec<(String, Vec<f64>)> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let mut words = l.split_whitespace();
            let label = words.next().unwrap().to_string();
            (label, words.map(|w| w.parse().unwrap()).collect())
        })
        .collect();
    let s = noisy(scene());
    let p = problem(&s);
    let got = figures(&p, &perturbed(&s, &p));
    assert_eq!(got.len(), recorded.len(), "lines");
    let mut worst: (f64, String) = (0.0, String::new());
    for ((label, values), (want_label, want)) in got.iter().zip(&recorded) {
        assert_eq!(label, want_label);
        assert_eq!(values.len(), want.len(), "{label}");
        for (i, (a, b)) in values.iter().zip(want).enumerate() {
            let difference = (a - b).abs() / a.abs().max(b.abs()).max(1e-300);
            if difference > worst.0 {
                worst = (difference, format!("{label}[{i}]: {a:e} vs {b:e}"));
            }
        }
    }
    println!("largest relative difference {:e} ({})", worst.0, worst.1);
    assert!(worst.0 <= 1e-12, "largest relative difference {:e} at {}", worst.0, worst.1);
}
