//! The rig problem (`solve::rig`): its analytic Jacobians against central differences,
//! the pose-inverse Jacobian its σ goes through, a solve recovering a perturbed start on
//! exact data, and its σ against the spread of solves on noisy data (σ honest: error/σ
//! RMS near 1). The no-heap check is in `tests/alloc/solve_alloc.rs`.

use crate::common::rig_scene;
use crate::common::stack::Stacker;

use nalgebra::SVector;
use rig_scene::*;
use roomcal::geometry::se3::so3_log;
use roomcal::geometry::Se3;
use roomcal::solve::rig::{
    apply_rig_step, inverse_jacobian, rig_covariance, solve_rig, BlockPrior,
};
use roomcal::solve::Loss;

/// All whitened residuals (measurements then priors) and the analytic Jacobian over
/// [shared | blocks] (`common::stack`).
fn stacked(p: &Problem<'_>, params: &Params) -> (Vec<f64>, Vec<Vec<f64>>) {
    let mut s = Stacker::new(N, params.blocks.len());
    p.for_each_residual(params, |k, _, res, js, jb, _| s.measurement(k, res, js, jb)).unwrap();
    p.for_each_prior(params, |k, res, jp| s.prior(k, res, jp));
    s.finish()
}

#[test]
fn analytic_jacobians_match_central_differences() {
    let s = scene(None);
    let p = problem(&s, 0.1, 0.003, Loss::Huber(3.0));
    let params = perturbed(&s);
    let blocks = params.blocks.len();
    let (_, analytic) = stacked(&p, &params);
    let n = N + 6 * blocks;
    let at = Problem::LAYOUT;
    let mut worst: f64 = 0.0;
    let mut nonzero_columns = 0;
    for col in 0..n {
        // Pixel-scale steps for fx..cy, small ones for distortion and motions.
        let in_camera = (0..C).find(|&c| (at.intrinsics(c)..at.intrinsics(c) + 9).contains(&col));
        let h = match in_camera.map(|c| col - at.intrinsics(c)) {
            Some(i) if i < 4 => 1e-3,
            Some(_) => 1e-6,
            None => 1e-7,
        };
        let shifted = |sign: f64| {
            let mut shared = SVector::<f64, N>::zeros();
            let mut steps = [SVector::<f64, 6>::zeros(); B];
            if col < N {
                shared[col] = sign * h;
            } else {
                steps[(col - N) / 6][(col - N) % 6] = sign * h;
            }
            stacked(&p, &apply_rig_step(&params, &shared, &steps)).0
        };
        let (plus, minus) = (shifted(1.0), shifted(-1.0));
        let mut touched = false;
        for (row, line) in analytic.iter().enumerate() {
            let numeric = (plus[row] - minus[row]) / (2.0 * h);
            let scale = line[col].abs().max(numeric.abs()).max(1.0);
            worst = worst.max((numeric - line[col]).abs() / scale);
            touched |= line[col] != 0.0;
        }
        nonzero_columns += touched as usize;
    }
    // Every unknown is measured: 2 × 9 intrinsics, 1 mounting, 2 LiDARs, 2 frames, 7 blocks.
    assert_eq!(nonzero_columns, n, "some unknown is seen by no residual");
    assert!(worst < 1e-4, "worst relative Jacobian error {worst:e}");
}

/// `a` relative to `b` as a left perturbation `[log(R_a R_bᵀ); t_a − t_b]`.
fn left_difference(a: &Se3, b: &Se3) -> SVector<f64, 6> {
    let w = so3_log(&(a.rotation * b.rotation.transpose()));
    let t = a.translation - b.translation;
    SVector::<f64, 6>::new(w.x, w.y, w.z, t.x, t.y, t.z)
}

#[test]
fn the_inverse_jacobian_matches_central_differences() {
    let s = scene(None);
    let pose = s.truth.lidar_to_first[1];
    let analytic = inverse_jacobian(&pose);
    for i in 0..6 {
        let h = 1e-6;
        let mut d = SVector::<f64, 6>::zeros();
        d[i] = h;
        let plus = pose.perturb_left(&d).inverse();
        let minus = pose.perturb_left(&(-d)).inverse();
        let numeric = (left_difference(&plus, &pose.inverse())
            - left_difference(&minus, &pose.inverse()))
            / (2.0 * h);
        let error = (numeric - analytic.column(i)).amax();
        assert!(error < 1e-6, "column {i}: {numeric} vs {}", analytic.column(i));
    }
}

#[test]
fn solve_recovers_the_truth_from_a_perturbed_start() {
    let s = scene(None);
    let p = problem(&s, 0.1, 0.003, Loss::Huber(3.0));
    let mut params = perturbed(&s);
    let report = solve_rig(&p, &mut params, 50).unwrap();
    assert_recovers_the_rig(&report, &params, &s.truth);
    for f in 0..F {
        assert!(close(&params.room_to_first[f], &s.truth.room_to_first[f]), "frame {f}");
    }
    assert!(report.corner_rms_px.iter().all(|&e| e < 1e-6), "{report:?}");
}

/// Poses agree to 1e-7 (rad, m) on every axis.
fn close(a: &Se3, b: &Se3) -> bool {
    left_difference(a, b).amax() < 1e-7
}

/// The solve converged from its perturbed start onto the truth's intrinsics and mountings.
fn assert_recovers_the_rig(
    report: &roomcal::solve::rig::RigReport<C, L>,
    params: &Params,
    t: &Params,
) {
    assert!(report.iterations > 1 && report.final_cost < 1e-8 * report.initial_cost, "{report:?}");
    for c in 0..C {
        assert!((params.cameras[c].fx - t.cameras[c].fx).abs() < 1e-4, "camera {c} fx");
        assert!((params.cameras[c].cy - t.cameras[c].cy).abs() < 1e-4, "camera {c} cy");
    }
    assert!(close(&params.first_to_camera[1], &t.first_to_camera[1]));
    for l in 0..L {
        assert!(close(&params.lidar_to_first[l], &t.lidar_to_first[l]), "LiDAR {l}");
    }
}

/// The solver's σ against the spread of its own solutions over noisy scenes: for every
/// mounting and focal length, the RMS over trials of error/σ must be near 1 (with 40
/// trials an honest σ gives 1 ± 0.23 at 2σ).
#[test]
fn sigma_matches_the_spread_over_noisy_solves() {
    sigma_study(false);
}

/// Without a survey (free boards, frame 0's room pose held), the σ are as honest.
#[test]
fn free_board_sigma_matches_the_spread_over_noisy_solves() {
    sigma_study(true);
}

/// Free boards: the solve holds frame 0's room pose where it starts (the gauge) and finds
/// every intrinsic, every mounting and frame 1 relative to frame 0.
#[test]
fn free_boards_recover_the_rig_from_a_perturbed_start() {
    let s = scene(None);
    let p = free_problem(&s, 0.1, 0.003, Loss::Huber(3.0));
    assert!(p.holds_first_frame());
    let mut params = boards_only(&perturbed(&s));
    let held = params.room_to_first[0];
    let report = solve_rig(&p, &mut params, 50).unwrap();
    assert_eq!(params.room_to_first[0], held, "frame 0 is the gauge");
    let t = &s.truth;
    assert_recovers_the_rig(&report, &params, t);
    let between = |p: &Params| p.room_to_first[1].compose(&p.room_to_first[0].inverse());
    assert!(close(&between(&params), &between(t)), "frame 1 relative to frame 0");
}

/// Surveyed and free blocks do not mix, and a free block has infinite σ on both axes.
#[test]
fn blocks_are_all_surveyed_or_all_free() {
    let s = scene(None);
    let mut p = problem(&s, 0.1, 0.003, Loss::Squared);
    assert!(!p.holds_first_frame());
    assert!(p.add_block(BlockPrior::free(Se3::identity())).is_err());
    let mut q = free_problem(&s, 0.1, 0.003, Loss::Squared);
    assert!(q.add_block(s.priors[0]).is_err());
    let half = BlockPrior { sigma_m: f64::INFINITY, ..s.priors[0] };
    assert!(q.add_block(half).is_err(), "σ infinite on one axis only");
    assert_eq!(q.residual_count() + 6 * 7, problem_rows(&s), "free blocks add no prior rows");
}

/// Rows of the surveyed problem over the same boards' measurements, planes' left out.
fn problem_rows(s: &Scene) -> usize {
    let p = problem(s, 0.1, 0.003, Loss::Squared);
    let planes: usize = s
        .measured
        .iter()
        .filter(|m| m.block >= BOARDS)
        .map(|m| m.plane.map_or(0, |pl| pl.count))
        .sum();
    p.residual_count() - planes
}

fn sigma_study(free: bool) {
    const TRIALS: usize = 40;
    let (corner_px, hole_m, point_m) = (0.15, 0.003, 0.01);
    // Per quantity: Σ (error/σ)² over trials.
    let names = [
        "fx front",
        "fx wide",
        "wide→front rot",
        "wide→front t",
        "top rot",
        "top t",
        "bumper rot",
        "bumper t",
        "top→wide rot",
        "top→wide t",
    ];
    let mut sums = [0.0f64; 10];
    let mut rng = Rng(2026);
    for _ in 0..TRIALS {
        let s = scene(Some((corner_px, hole_m, point_m, &mut rng)));
        let (p, mut params) = match free {
            false => (problem(&s, corner_px, hole_m, Loss::Squared), perturbed(&s)),
            true => {
                (free_problem(&s, corner_px, hole_m, Loss::Squared), boards_only(&perturbed(&s)))
            }
        };
        solve_rig(&p, &mut params, 100).unwrap();
        let cov = rig_covariance(&p, &params).unwrap();
        let t = &s.truth;
        for (c, sum) in sums.iter_mut().enumerate().take(C) {
            let sigma = cov.intrinsics_sigma(c)[0];
            *sum += ((params.cameras[c].fx - t.cameras[c].fx) / sigma).powi(2);
        }
        // Per pose: the error projected on each axis, whitened by its own variance,
        // averaged over the three axes (the full 6×6 is checked through its diagonal).
        let mut pose_terms =
            |slot: usize, got: &Se3, truth: &Se3, cov: &nalgebra::SMatrix<f64, 6, 6>| {
                let d = left_difference(got, truth);
                for (half, at) in [(0, 0), (1, 3)] {
                    let z: f64 = (0..3).map(|i| d[at + i].powi(2) / cov[(at + i, at + i)]).sum();
                    sums[slot + half] += z / 3.0;
                }
            };
        let wide = params.first_to_camera[1].inverse();
        pose_terms(
            2,
            &wide,
            &t.first_to_camera[1].inverse(),
            &cov.camera_to_first(1, &params.first_to_camera[1]),
        );
        for l in 0..L {
            pose_terms(
                4 + 2 * l,
                &params.lidar_to_first[l],
                &t.lidar_to_first[l],
                &cov.lidar_to_first(l),
            );
        }
        // A LiDAR → camera product (its cross terms included).
        let (a, e) = (params.first_to_camera[1], params.lidar_to_first[0]);
        let truth = t.first_to_camera[1].compose(&t.lidar_to_first[0]);
        pose_terms(8, &a.compose(&e), &truth, &cov.lidar_to_camera(0, 1, &a, &e));
    }
    for (name, sum) in names.iter().zip(sums) {
        let ratio = (sum / TRIALS as f64).sqrt();
        println!("{name:<16} RMS error/σ {ratio:.2}");
        assert!(
            (0.7..1.35).contains(&ratio),
            "{name}: RMS error/σ {ratio:.2} over {TRIALS} trials"
        );
    }
}

/// A camera's shared covariance as the projection map takes it (its intrinsics, then
/// LiDAR → camera with their cross terms) against the joint covariance carried through a
/// numeric Jacobian: the second camera's mounting and the LiDAR's perturbed on the left
/// as the solver does, their composition's perturbation read back by `so3_log`.
#[test]
fn a_cameras_shared_covariance_is_the_joint_one_carried_through_its_lidar_pose() {
    use nalgebra::SMatrix;
    use roomcal::geometry::se3::so3_exp;
    use roomcal::geometry::Vec3;
    use roomcal::solve::rig::{RigCovariance, RigLayout};
    const N: usize = 36;
    let layout = RigLayout { cameras: 2, lidars: 1, frames: 1 };
    assert_eq!(layout.len(), N);
    // A covariance with every cross term: M Mᵀ of a fixed pseudo-random M.
    let mut seed = 7u64;
    let m = SMatrix::<f64, N, N>::from_fn(|_, _| {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    });
    let covariance = RigCovariance { layout, matrix: m * m.transpose() * 1e-4 };
    let first_to_camera = Se3 {
        rotation: so3_exp(&Vec3::new(0.02, 0.14, -0.01)),
        translation: Vec3::new(-0.25, 0.01, 0.02),
    };
    let lidar_to_first = Se3 {
        rotation: so3_exp(&Vec3::new(1.2, -1.1, 1.2)),
        translation: Vec3::new(0.05, 0.42, -0.28),
    };
    let got = covariance.camera_shared(1, Some((0, &first_to_camera, &lidar_to_first)));

    let (a, e, k) = (layout.camera_pose(1), layout.lidar_pose(0), layout.intrinsics(1));
    let nominal = first_to_camera.compose(&lidar_to_first);
    let shared = |x: &SVector<f64, N>| -> SVector<f64, 15> {
        let perturbed = |pose: &Se3, at: usize| Se3 {
            rotation: so3_exp(&Vec3::new(x[at], x[at + 1], x[at + 2])) * pose.rotation,
            translation: pose.translation + Vec3::new(x[at + 3], x[at + 4], x[at + 5]),
        };
        let pose = perturbed(&first_to_camera, a).compose(&perturbed(&lidar_to_first, e));
        let w = so3_log(&(pose.rotation * nominal.rotation.transpose()));
        let t = pose.translation - nominal.translation;
        SVector::<f64, 15>::from_fn(|i, _| match i {
            0..=8 => x[k + i],
            9..=11 => w[i - 9],
            _ => t[i - 12],
        })
    };
    let mut j = SMatrix::<f64, 15, N>::zeros();
    for i in 0..N {
        let mut step = SVector::<f64, N>::zeros();
        step[i] = 1e-6;
        j.set_column(i, &((shared(&step) - shared(&-step)) / 2e-6));
    }
    let expected = j * covariance.matrix * j.transpose();
    let scale = expected.amax();
    assert!((got - expected).amax() < 1e-6 * scale, "{}", (got - expected).amax() / scale);
    let without = covariance.camera_shared(1, None);
    assert_eq!(without.fixed_view::<9, 9>(0, 0), got.fixed_view::<9, 9>(0, 0));
    assert_eq!(without.fixed_view::<6, 15>(9, 0).amax(), 0.0);
}
