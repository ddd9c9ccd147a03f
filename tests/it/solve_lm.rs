//! The joint problem and its LM: analytic Jacobians of every residual block against
//! central differences, the Schur-complement step against a dense solve of the full
//! system, and convergence to the truth on synthetic rooms (noise, perturbed start,
//! closed-form start, two-stage and intrinsics-only modes, robust loss against outliers).

use crate::common::solve_common;

use nalgebra::{DMatrix, DVector, SVector};
use roomcal::geometry::{Se3, Vec2, Vec3};
use roomcal::solve::lm::{apply_step, NormalEquations, Step};
use roomcal::solve::problem::Residual;
use roomcal::solve::{
    board_pose, covariance, initialise, kabsch, BoardObservation, IntrinsicsSeed, JointParams,
    JointProblem, LmOptions, Loss, ParamMask, Projector, SharedCovariance, SolveError, Termination,
    EXT_ROTATION, SHARED,
};
use solve_common::*;

const B: usize = 16;

/// Pixel σ of the corners and LiDAR σ of the hole centres used by the scenes here.
const PIXEL_SIGMA: f64 = 0.3;
const LIDAR_SIGMA: f64 = 0.01;
/// The hole σ seen in the image: LiDAR σ at ~3.3 m through f ≈ 1400 px.
const HOLE_SIGMA_PX: f64 = 1400.0 * LIDAR_SIGMA / 3.3;

fn problem<'a>(s: &'a Scene, loss: Loss, with_holes: bool) -> JointProblem<'a, B> {
    let mut p = JointProblem::new(PIXEL_SIGMA, HOLE_SIGMA_PX, loss);
    for ((corners, lidar), plane) in s.corners.iter().zip(&s.holes_lidar).zip(&s.planes) {
        let (hb, hl): (&[Vec3], &[Vec3]) = if with_holes { (&s.holes, lidar) } else { (&[], &[]) };
        p.add_board(BoardObservation {
            object: &s.object,
            corners,
            holes_board: hb,
            holes_lidar: hl,
            hole_sigma_px: None,
            plane: with_holes.then_some(*plane),
        })
        .unwrap();
    }
    p
}

fn truth_params(s: &Scene) -> JointParams<RadtanCam, B> {
    JointParams {
        camera: s.camera,
        lidar_to_camera: s.extrinsic,
        board_poses: s.poses.iter().copied().collect(),
    }
}

/// The truth moved by a few per cent / degrees / centimetres, distortion zeroed.
fn perturbed(s: &Scene, seed: u64) -> JointParams<RadtanCam, B> {
    let mut rng = Rng(seed);
    let mut p = truth_params(s);
    let k = &mut p.camera.k;
    k[0] *= 1.04;
    k[1] *= 0.97;
    k[2] += 15.0;
    k[3] -= 12.0;
    k[4..].fill(0.0);
    let e = &mut p.lidar_to_camera;
    e.rotation = rot(&Vec3::new(0.02, -0.03, 0.025)) * e.rotation;
    e.translation += Vec3::new(0.05, -0.04, 0.06);
    for pose in p.board_poses.iter_mut() {
        pose.rotation = rot(&rng.vec3(0.02)) * pose.rotation;
        pose.translation += rng.vec3(0.05);
    }
    p
}

fn residuals(p: &JointProblem<'_, B>, params: &JointParams<RadtanCam, B>) -> Vec<Residual> {
    let mut v = Vec::new();
    p.for_each_residual(params, |r| v.push(*r)).unwrap();
    v
}

fn unit_step(index: usize, h: f64) -> Step<B> {
    let mut st = Step { shared: SVector::zeros(), boards: [SVector::zeros(); B] };
    if index < SHARED {
        st.shared[index] = h;
    } else {
        let (b, i) = ((index - SHARED) / 6, (index - SHARED) % 6);
        st.boards[b][i] = h;
    }
    st
}

#[test]
fn residual_jacobians_match_central_differences() {
    let s = scene(3, PIXEL_SIGMA, LIDAR_SIGMA, 5);
    let p = problem(&s, Loss::Squared, true);
    let mut params = perturbed(&s, 9);
    params.camera.k[4..].copy_from_slice(&[-0.1, 0.04, 0.002, -0.001, 0.01]);
    let base = residuals(&p, &params);
    assert_eq!(base.len(), 3 * (35 + 4 + 2), "corner, hole and two plane blocks per board");
    let n = SHARED + 6 * s.poses.len();
    let mut worst: f64 = 0.0;
    for col in 0..n {
        // Steps of ~1e-6 relative to each parameter's scale.
        let h = match col {
            0..=3 => 1e-3,
            _ => 1e-6,
        };
        let plus = residuals(&p, &apply_step(&params, &unit_step(col, h)));
        let minus = residuals(&p, &apply_step(&params, &unit_step(col, -h)));
        for ((r, rp), rm) in base.iter().zip(&plus).zip(&minus) {
            let numeric = (rp.r - rm.r) / (2.0 * h);
            let analytic = if col < SHARED {
                Vec2::new(r.j_shared[(0, col)], r.j_shared[(1, col)])
            } else if (col - SHARED) / 6 == r.board {
                let c = (col - SHARED) % 6;
                Vec2::new(r.j_board[(0, c)], r.j_board[(1, c)])
            } else {
                Vec2::zeros()
            };
            let err = (numeric - analytic).norm() / (1.0 + analytic.norm());
            assert!(
                err < 1e-5,
                "column {col} {:?} board {}: {analytic} vs {numeric}",
                r.kind,
                r.board
            );
            worst = worst.max(err);
        }
    }
    println!("worst relative Jacobian error: {worst:.2e}");
}

/// The full damped system `(JᵀWJ + λD) δ = −JᵀWr`, fixed columns removed, solved densely.
fn dense_step(
    p: &JointProblem<'_, B>,
    params: &JointParams<RadtanCam, B>,
    lambda: f64,
    mask: ParamMask,
) -> DVector<f64> {
    let res = residuals(p, params);
    let nb = params.board_poses.len();
    let n = SHARED + 6 * nb;
    let mut j = DMatrix::<f64>::zeros(2 * res.len(), n);
    let mut r = DVector::<f64>::zeros(2 * res.len());
    for (k, block) in res.iter().enumerate() {
        let w = p.loss_for(block.kind).eval(block.r.norm_squared()).1.sqrt();
        for row in 0..2 {
            r[2 * k + row] = w * block.r[row];
            for c in 0..SHARED {
                j[(2 * k + row, c)] = w * block.j_shared[(row, c)];
            }
            for c in 0..6 {
                j[(2 * k + row, SHARED + 6 * block.board + c)] = w * block.j_board[(row, c)];
            }
        }
    }
    let free: Vec<usize> = (0..n).filter(|&c| c >= SHARED || !mask.is_fixed(c)).collect();
    let jf = j.select_columns(&free);
    let mut a = jf.transpose() * &jf;
    for i in 0..free.len() {
        a[(i, i)] += lambda * a[(i, i)].max(roomcal::solve::lm::DIAG_FLOOR);
    }
    let g = jf.transpose() * &r;
    let x = a.cholesky().expect("dense system positive definite").solve(&(-g));
    let mut full = DVector::zeros(n);
    for (i, &c) in free.iter().enumerate() {
        full[c] = x[i];
    }
    full
}

#[test]
fn schur_step_equals_dense_solve() {
    let s = scene(3, PIXEL_SIGMA, LIDAR_SIGMA, 21);
    for (loss, lambda, mask) in [
        (Loss::Squared, 0.0, ParamMask::free()),
        (Loss::Huber(1.0), 1e-3, ParamMask::free().fix(8)),
        (Loss::Cauchy(2.0), 10.0, ParamMask::free().fix_intrinsics()),
    ] {
        let p = problem(&s, loss, true);
        let params = perturbed(&s, 4);
        let ne = NormalEquations::build(&p, &params).unwrap();
        let step = ne.step(lambda, mask).unwrap();
        let dense = dense_step(&p, &params, lambda, mask);
        let mut schur = DVector::zeros(dense.len());
        for i in 0..SHARED {
            schur[i] = step.shared[i];
        }
        for b in 0..s.poses.len() {
            for i in 0..6 {
                schur[SHARED + 6 * b + i] = step.boards[b][i];
            }
        }
        let err = (&schur - &dense).norm() / dense.norm();
        println!("{loss:?} λ={lambda}: |schur − dense| / |dense| = {err:.2e}");
        assert!(err < 1e-7, "{loss:?} λ={lambda}: {schur} vs {dense}");
        assert!(dense.norm() > 1e-3, "the step must not be trivially zero");
    }
}

/// Errors of an estimate against the truth: (|Δfx|, |Δfy|, |Δcx|, |Δcy|) px, rotation
/// (deg), translation (m).
fn errors(s: &Scene, p: &JointParams<RadtanCam, B>) -> ([f64; 4], f64, f64) {
    let k = p.camera.k;
    let t = s.camera.k;
    let dk = [(k[0] - t[0]).abs(), (k[1] - t[1]).abs(), (k[2] - t[2]).abs(), (k[3] - t[3]).abs()];
    let rot_err = rot_angle(&p.lidar_to_camera.rotation, &s.extrinsic.rotation).to_degrees();
    let t_err = (p.lidar_to_camera.translation - s.extrinsic.translation).norm();
    (dk, rot_err, t_err)
}

/// Asserts the estimate is within `n` σ of the truth (σ from the covariance at the
/// estimate; rotation and translation errors are 3-D norms against worst-axis σ, so
/// they get a further √3).
fn assert_within_sigma(s: &Scene, p: &JointParams<RadtanCam, B>, cov: &SharedCovariance, n: f64) {
    let (dk, rot_err, t_err) = errors(s, p);
    let u = cov.uncertainty();
    let sig = [u.fx, u.fy, u.cx, u.cy];
    println!("error: Δk {dk:.3?} px, rot {rot_err:.4}°, t {t_err:.4} m");
    println!("σ:     k {sig:.3?} px, rot {:.4}°, t {:.4} m", u.rotation_deg, u.translation_m);
    for i in 0..4 {
        if !cov.mask.is_fixed(i) {
            assert!(dk[i] < n * sig[i], "param {i}: error {} vs σ {}", dk[i], sig[i]);
        }
    }
    if !cov.mask.is_fixed(EXT_ROTATION) {
        assert!(
            rot_err < n * 3f64.sqrt() * u.rotation_deg,
            "rotation {rot_err}° vs σ {}",
            u.rotation_deg
        );
        assert!(
            t_err < n * 3f64.sqrt() * u.translation_m,
            "translation {t_err} vs σ {}",
            u.translation_m
        );
    }
}

/// Asserts two estimates are the same optimum: shared parameters within 10 % of their σ
/// (the default stopping rule, 1e-6 relative cost change, stops that close on this
/// flat cost surface).
fn assert_same_optimum(
    a: &JointParams<RadtanCam, B>,
    b: &JointParams<RadtanCam, B>,
    cov: &SharedCovariance,
) {
    for i in 0..9 {
        let d = (a.camera.k[i] - b.camera.k[i]).abs();
        assert!(d <= 0.1 * cov.sigma(i), "param {i}: {:?} vs {:?}", a.camera.k, b.camera.k);
    }
    let u = cov.uncertainty();
    let (ea, eb) = (&a.lidar_to_camera, &b.lidar_to_camera);
    assert!(rot_angle(&ea.rotation, &eb.rotation).to_degrees() <= 0.1 * u.rotation_deg);
    assert!((ea.translation - eb.translation).norm() <= 0.1 * u.translation_m);
}

/// The optimum reached from the truth itself.
fn optimum_from_truth(
    s: &Scene,
    p: &JointProblem<'_, B>,
    o: &LmOptions,
) -> JointParams<RadtanCam, B> {
    let mut t = truth_params(s);
    p.solve(&mut t, o).unwrap();
    t
}

#[test]
fn lm_converges_to_truth_within_noise() {
    let s = scene(6, PIXEL_SIGMA, LIDAR_SIGMA, 42);
    let p = problem(&s, Loss::Huber(3.0), true);
    let mut params = perturbed(&s, 8);
    let (dk0, r0, t0) = errors(&s, &params);
    let options = LmOptions::default();
    let report = p.solve(&mut params, &options).unwrap();
    println!("start: Δk {dk0:.2?} px, rot {r0:.3}°, t {t0:.4} m");
    println!("{report:?}");
    // The plane term keeps its points' noise (~one unit of cost per point) at the optimum.
    assert!(report.final_cost < report.initial_cost * 5e-2);
    assert!(report.iterations < 60, "{report:?}");
    assert!(matches!(report.termination, Termination::CostConverged | Termination::StepConverged));
    // At the optimum the residuals are the noise: corner RMS ≈ σ·√2 per block.
    assert!(report.corner_rms_px < 2.0 * PIXEL_SIGMA, "{report:?}");
    let cov = covariance(&p, &params, ParamMask::free()).unwrap();
    assert_same_optimum(&params, &optimum_from_truth(&s, &p, &options), &cov);
    assert!((cov.residual_variance - 1.0).abs() < 0.3, "σ̂² {}", cov.residual_variance);
    assert_within_sigma(&s, &params, &cov, 4.0);
    for (i, (d, t)) in params.camera.k[4..].iter().zip(&s.camera.k[4..]).enumerate() {
        assert!((d - t).abs() < 4.0 * cov.sigma(4 + i), "distortion {i}: {d} vs {t}");
    }
}

#[test]
fn low_noise_room_reaches_tight_absolute_accuracy() {
    // 0.05 px corners and 2 mm hole centres: the same room, six times less noise.
    let s = scene(6, 0.05, 0.002, 17);
    let mut p = problem(&s, Loss::Squared, true);
    p.corner_sigma_px = 0.05;
    p.hole_sigma_px = 1400.0 * 0.002 / 3.3;
    let mut params = perturbed(&s, 3);
    let report = p.solve(&mut params, &LmOptions::default()).unwrap();
    let (dk, rot_err, t_err) = errors(&s, &params);
    println!("low noise: Δk {dk:.3?} px, rot {rot_err:.4}°, t {t_err:.4} m; {report:?}");
    let cov = covariance(&p, &params, ParamMask::free()).unwrap();
    assert_within_sigma(&s, &params, &cov, 4.0);
    assert!(dk.iter().all(|d| *d < 15.0) && rot_err < 0.5 && t_err < 0.03);
}

#[test]
fn closed_form_start_then_lm_reaches_truth() {
    let s = scene(6, PIXEL_SIGMA, LIDAR_SIGMA, 77);
    let p = problem(&s, Loss::Huber(3.0), true);
    // Start from a camera that knows nothing but the model: Zhang seeds the intrinsics.
    let blank = RadtanCam { k: [1000.0, 1000.0, 960.0, 600.0, 0.0, 0.0, 0.0, 0.0, 0.0] };
    let seed = IntrinsicsSeed::Zhang { width: 1920, height: 1200 };
    let (mut params, init) = initialise(&p, blank, seed).unwrap();
    let z = init.zhang.expect("Zhang used");
    assert!(init.zhang_error.is_none());
    assert_eq!(&params.camera.k[..4], &[z.fx, z.fy, z.cx, z.cy]);
    let (dk0, r0, t0) = errors(&s, &params);
    println!("closed form: Δk {dk0:.2?} px, rot {r0:.3}°, t {t0:.4} m; {init:?}");
    assert!(dk0.iter().all(|d| *d < 150.0) && r0 < 5.0 && t0 < 0.5);
    let options = LmOptions::default();
    let report = p.solve(&mut params, &options).unwrap();
    println!("{report:?}");
    let cov = covariance(&p, &params, ParamMask::free()).unwrap();
    assert_same_optimum(&params, &optimum_from_truth(&s, &p, &options), &cov);
    assert_within_sigma(&s, &params, &cov, 4.0);

    // The manual chain gives the same start: Kabsch over camera-frame holes.
    let mut from = Vec::new();
    let mut to = Vec::new();
    let (start, _) = initialise(&p, blank, seed).unwrap();
    for (pose, lidar) in start.board_poses.iter().zip(&s.holes_lidar) {
        for (h, l) in s.holes.iter().zip(lidar) {
            from.push(*l);
            to.push(pose.rotation * h + pose.translation);
        }
    }
    let ext = kabsch(&from, &to).unwrap();
    assert!((ext.rotation - start.lidar_to_camera.rotation).norm() < 1e-12);
    let pose0 = board_pose(&start.camera, &s.object, &s.corners[0]).unwrap();
    assert!((pose0.translation - start.board_poses[0].translation).norm() < 1e-12);

    // Parallel boards: Zhang refuses, the given intrinsics are kept.
    let mut flat = scene(3, PIXEL_SIGMA, LIDAR_SIGMA, 5);
    for (pose, corners) in flat.poses.iter_mut().zip(flat.corners.iter_mut()) {
        pose.rotation = rot(&Vec3::new(0.0, 0.0, 0.2));
        *corners = s
            .object
            .iter()
            .map(|x| s.camera.project(&(pose.rotation * x + pose.translation)).unwrap())
            .collect();
    }
    let pf = problem(&flat, Loss::Squared, false);
    let (q, init) = initialise(&pf, s.camera, seed).unwrap();
    assert!(matches!(init.zhang_error, Some(SolveError::Degenerate(_))), "{init:?}");
    assert_eq!(q.camera, s.camera);
    assert_eq!(q.lidar_to_camera, Se3::identity());
    assert!(init.pose_rms_px < 1e-6);

    // A board with too few corners cannot be posed: the error names it.
    let mut bad = problem(&flat, Loss::Squared, false);
    let few = BoardObservation {
        object: &s.object[..3],
        corners: &s.corners[0][..3],
        ..Default::default()
    };
    bad.add_board(few).unwrap();
    let err = initialise(&bad, s.camera, IntrinsicsSeed::Given).unwrap_err();
    assert!(matches!(err, SolveError::BadBoard { board: 3, .. }), "{err}");
    assert_eq!(err.to_string(), "board 3: too few correspondences");
    // A wrong detection (corners shuffled along a line) stands out as the worst board.
    let line: Vec<Vec2> =
        (0..35).map(|i| Vec2::new(100.0 + 10.0 * i as f64, 300.0 + i as f64)).collect();
    let mut odd = problem(&flat, Loss::Squared, false);
    odd.add_board(BoardObservation { object: &s.object, corners: &line, ..Default::default() })
        .unwrap();
    if let Ok((_, init)) = initialise(&odd, s.camera, IntrinsicsSeed::Given) {
        let (b, rms) = init.worst_board.unwrap();
        assert_eq!(b, 3);
        assert!(rms > 1.0, "{rms}");
    }
}

#[test]
fn two_stage_and_intrinsics_only_modes() {
    let s = scene(6, PIXEL_SIGMA, LIDAR_SIGMA, 3);
    // Stage 2: intrinsics fixed at the truth, only extrinsic and poses move.
    let p = problem(&s, Loss::Squared, true);
    let mut params = perturbed(&s, 2);
    params.camera = s.camera;
    let options = LmOptions { mask: ParamMask::free().fix_intrinsics(), ..LmOptions::default() };
    let report = p.solve(&mut params, &options).unwrap();
    assert_eq!(params.camera, s.camera, "fixed intrinsics must not move");
    assert_eq!(report.free_parameters, 6 + 6 * 6);
    let cov = covariance(&p, &params, options.mask).unwrap();
    assert_eq!(cov.sigma(0), 0.0);
    assert_within_sigma(&s, &params, &cov, 4.0);

    // Intrinsics only: no hole term, the extrinsic is not touched.
    let p = problem(&s, Loss::Squared, false);
    let mut params = perturbed(&s, 2);
    let ext0 = params.lidar_to_camera;
    let report = p.solve(&mut params, &LmOptions::default()).unwrap();
    assert_eq!(params.lidar_to_camera, ext0);
    assert_eq!(report.hole_rms_px, 0.0);
    assert_eq!(report.free_parameters, 9 + 6 * 6);
    let cov = covariance(&p, &params, ParamMask::free()).unwrap();
    let u = cov.uncertainty();
    assert_eq!((u.rotation_deg, u.translation_m), (0.0, 0.0));
    assert_within_sigma(&s, &params, &cov, 4.0);
}

#[test]
fn robust_loss_resists_outlier_corners() {
    let clean = scene(6, PIXEL_SIGMA, LIDAR_SIGMA, 13);
    let mut s = scene(6, PIXEL_SIGMA, LIDAR_SIGMA, 13);
    // Mis-detected corners: tens of pixels off.
    for (b, c) in [(0, 3), (1, 17), (2, 30), (4, 8), (5, 20)] {
        s.corners[b][c] += Vec2::new(25.0, -18.0);
    }
    let options = LmOptions::default();
    let reference = optimum_from_truth(&clean, &problem(&clean, Loss::Squared, true), &options);
    let cov =
        covariance(&problem(&clean, Loss::Squared, true), &reference, ParamMask::free()).unwrap();
    // Distance from the clean optimum in units of σ, over fx fy cx cy.
    let shift = |loss| {
        let p = problem(&s, loss, true);
        let mut params = perturbed(&s, 6);
        p.solve(&mut params, &options).unwrap();
        (0..4)
            .map(|i| (params.camera.k[i] - reference.camera.k[i]).abs() / cov.sigma(i))
            .fold(0.0, f64::max)
    };
    let (squared, cauchy, huber) =
        (shift(Loss::Squared), shift(Loss::Cauchy(3.0)), shift(Loss::Huber(2.0)));
    println!("largest shift from the clean optimum: squared {squared:.3}σ, Huber {huber:.3}σ, Cauchy {cauchy:.3}σ");
    assert!(cauchy < 0.5 && cauchy < 0.2 * squared, "{cauchy} vs {squared}");
    assert!(huber < squared);
}

#[test]
fn bad_inputs_are_reported() {
    let s = scene(2, PIXEL_SIGMA, LIDAR_SIGMA, 1);
    let p = problem(&s, Loss::Squared, true);
    let mut params = truth_params(&s);
    params.board_poses.pop();
    assert!(matches!(
        p.solve(&mut params, &LmOptions::default()),
        Err(SolveError::LengthMismatch { .. })
    ));
    let mut params = truth_params(&s);
    params.board_poses[1].translation.z = -3.0;
    assert_eq!(
        p.solve(&mut params, &LmOptions::default()).unwrap_err(),
        SolveError::NotProjectable { board: 1 }
    );
    let mut zero_sigma = problem(&s, Loss::Huber(0.0), true);
    let mut params = truth_params(&s);
    let err = zero_sigma.solve(&mut params, &LmOptions::default()).unwrap_err();
    assert_eq!(err, SolveError::BadSetting("robust loss scale must be positive"));
    zero_sigma.loss = Loss::Squared;
    zero_sigma.corner_sigma_px = 0.0;
    assert!(matches!(
        zero_sigma.solve(&mut params, &LmOptions::default()),
        Err(SolveError::BadSetting(_))
    ));
    let mut small: JointProblem<'_, 1> = JointProblem::new(1.0, 1.0, Loss::Squared);
    let obs = BoardObservation { object: &s.object, corners: &s.corners[0], ..Default::default() };
    small.add_board(obs).unwrap();
    assert_eq!(small.add_board(obs), Err(SolveError::TooManyBoards { capacity: 1 }));
    let bad = BoardObservation { object: &s.object[..3], corners: &s.corners[0], ..obs };
    let mut p2: JointProblem<'_, 2> = JointProblem::new(1.0, 1.0, Loss::Squared);
    assert!(matches!(p2.add_board(bad), Err(SolveError::LengthMismatch { .. })));
    // Truth is already optimal up to noise: the solver stops quickly without harm.
    let mut params = truth_params(&s);
    let r = p.solve(&mut params, &LmOptions::default()).unwrap();
    assert!(r.final_cost <= r.initial_cost);
    let _ = params.camera.project(&Vec3::new(0.0, 0.0, 1.0));
}

/// The plane term's fixed-size summary is exact: for any board pose and extrinsic, the
/// squared norm of its two blocks equals the sum of the squared point-to-plane distances
/// (over σ²) of every point it summarises.
#[test]
fn plane_summary_equals_the_sum_over_its_points() {
    let s = scene(2, PIXEL_SIGMA, LIDAR_SIGMA, 3);
    let mut rng = Rng(77);
    let points: Vec<Vec3> = (0..500).map(|_| Vec3::new(4.0, 0.5, -0.3) + rng.vec3(0.6)).collect();
    let sigma = 0.02;
    let plane = roomcal::solve::PlanePoints::from_points(points.iter().copied(), sigma).unwrap();
    assert_eq!(plane.count, 500);
    let mut p: JointProblem<'_, B> = JointProblem::new(PIXEL_SIGMA, HOLE_SIGMA_PX, Loss::Squared);
    p.add_board(BoardObservation {
        object: &s.object,
        corners: &s.corners[0],
        plane: Some(plane),
        ..Default::default()
    })
    .unwrap();
    for seed in 0..5 {
        let mut params = perturbed(&s, seed);
        params.board_poses.truncate(1);
        let pose = params.board_poses[0];
        let ext = params.lidar_to_camera;
        let normal = pose.rotation.column(2).into_owned();
        let direct: f64 = points
            .iter()
            .map(|q| (normal.dot(&(ext.act(q) - pose.translation)) / sigma).powi(2))
            .sum();
        let mut summary = 0.0;
        p.for_each_residual(&params, |r| {
            if matches!(r.kind, roomcal::solve::problem::ResidualKind::Plane(_)) {
                summary += r.r.norm_squared();
            }
        })
        .unwrap();
        let rel = (summary - direct).abs() / direct;
        assert!(rel < 1e-9, "seed {seed}: summary {summary} vs points {direct}");
    }
    // Too few points, or a σ that is not positive, make no plane.
    assert!(roomcal::solve::PlanePoints::from_points(points[..5].iter().copied(), sigma).is_none());
    assert!(roomcal::solve::PlanePoints::from_points(points.iter().copied(), 0.0).is_none());
}

/// Each residual kind's variance from its own residuals: corners drawn at 0.06 px but
/// declared at 0.3 px, beside hole centres and face points drawn as declared. The kind
/// factors find the corners' 0.04 and the others' ≈ 1; the covariance is the estimate's
/// own (weighted wrongly, the holes pull the intrinsics: σ fx 2.6 px against 1.8); the
/// problem re-weighted by the factors and solved again reaches the σ of the problem told
/// the truth.
#[test]
fn each_residual_kind_is_scaled_by_its_own_variance() {
    let s = scene(8, 0.06, LIDAR_SIGMA, 23);
    let mut told_wrong = problem(&s, Loss::Squared, true);
    let mut told_right = problem(&s, Loss::Squared, true);
    told_right.corner_sigma_px = 0.06;
    let options = LmOptions::default();
    let mut params = truth_params(&s);
    let solve = |p: &JointProblem<'_, B>, params: &mut JointParams<RadtanCam, B>| {
        p.solve(params, &options).unwrap();
        let cov = covariance(p, params, ParamMask::free()).unwrap();
        let u = cov.uncertainty();
        println!(
            "σ̂² corners {:.3}, holes {:.3}, planes {:.3}; σ fx {:.3} cx {:.3} px, rotation {:.4}°, translation {:.2} mm",
            cov.kind_variances.corner,
            cov.kind_variances.hole,
            cov.kind_variances.plane,
            u.fx,
            u.cx,
            u.rotation_deg,
            1e3 * u.translation_m
        );
        (cov, [u.fx, u.fy, u.cx, u.cy, u.rotation_deg, u.translation_m])
    };
    let (wrong, first) = solve(&told_wrong, &mut params);
    let (right, optimal) = solve(&told_right, &mut truth_params(&s));
    let k = wrong.kind_variances;
    assert!((k.corner / 0.04 - 1.0).abs() < 0.2, "{k:?}");
    assert!((0.6..1.4).contains(&k.hole) && (0.8..1.2).contains(&k.plane), "{k:?}");
    assert!((right.kind_variances.corner - 1.0).abs() < 0.2, "{:?}", right.kind_variances);
    assert!(first[0] > 1.2 * optimal[0], "the wrongly weighted estimate is the worse: {first:?}");

    told_wrong.rescale_sigmas(k);
    let (_, reweighted) = solve(&told_wrong, &mut params);
    for (a, b) in reweighted.iter().zip(&optimal) {
        assert!((a / b - 1.0).abs() < 0.1, "{reweighted:?} vs {optimal:?}");
    }
}
