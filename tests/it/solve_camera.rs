//! The solver with the real camera models of `geometry` (pinhole-radtan and fisheye):
//! residual Jacobians against central differences, board pose from pixels, and the joint
//! LM converging from a perturbed start (fisheye: 8 intrinsics, the 9th held fixed).

use crate::common::solve_common;

use nalgebra::SVector;
use roomcal::geometry::{Camera, CameraModel, Vec2, Vec3};
use roomcal::solve::lm::{apply_step, Step};
use roomcal::solve::{
    board_pose, covariance, hole_sigma_px, initialise, BoardObservation, IntrinsicsSeed,
    JointParams, JointProblem, LmOptions, Loss, ParamMask, Termination, SHARED,
};
use solve_common::*;

const B: usize = 16;

fn cameras() -> [Camera; 2] {
    let radtan = Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx: 1400.0,
        fy: 1395.0,
        cx: 962.0,
        cy: 603.0,
        distortion: [-0.12, 0.05, 0.001, -0.0008, 0.01],
    };
    let fisheye = Camera {
        model: CameraModel::Fisheye,
        width: 1920,
        height: 1200,
        fx: 900.0,
        fy: 902.0,
        cx: 955.0,
        cy: 598.0,
        distortion: [0.05, -0.01, 0.002, -0.0005, 0.0],
    };
    [radtan, fisheye]
}

fn problem<'a>(s: &'a Scene<Camera>) -> JointProblem<'a, B> {
    let hole_sigma = s.camera.fx * 0.01 / 3.3;
    let mut p = JointProblem::new(0.3, hole_sigma, Loss::Huber(3.0));
    for ((corners, lidar), pose) in s.corners.iter().zip(&s.holes_lidar).zip(&s.poses) {
        // Per-board σ from the depth (1 cm LiDAR hole centres), as a caller would.
        let sigma = hole_sigma_px(s.camera.fx, 0.01, pose.translation.z);
        let obs = BoardObservation {
            object: &s.object,
            corners,
            holes_board: &s.holes,
            holes_lidar: lidar,
            hole_sigma_px: Some(sigma),
            plane: None,
        };
        p.add_board(obs).unwrap();
    }
    p
}

fn perturbed(s: &Scene<Camera>) -> JointParams<Camera, B> {
    let mut camera = s.camera;
    camera.fx *= 1.03;
    camera.fy *= 0.98;
    camera.cx += 12.0;
    camera.cy -= 9.0;
    camera.distortion = [0.0; 5];
    let mut ext = s.extrinsic;
    ext.rotation = rot(&Vec3::new(0.02, -0.01, 0.02)) * ext.rotation;
    ext.translation += Vec3::new(0.04, -0.03, 0.05);
    let mut rng = Rng(5);
    let board_poses = s
        .poses
        .iter()
        .map(|p| {
            let mut p = *p;
            p.rotation = rot(&rng.vec3(0.02)) * p.rotation;
            p.translation += rng.vec3(0.04);
            p
        })
        .collect();
    JointParams { camera, lidar_to_camera: ext, board_poses }
}

#[test]
fn residual_jacobians_match_central_differences_for_both_models() {
    for cam in cameras() {
        let s = scene_with(cam, 3, 0.3, 0.01, 8);
        let p = problem(&s);
        let params = {
            let mut q = perturbed(&s);
            q.camera.distortion = s.camera.distortion;
            q
        };
        let collect = |q: &JointParams<Camera, B>| {
            let mut v = Vec::new();
            p.for_each_residual(q, |r| v.push(*r)).unwrap();
            v
        };
        let base = collect(&params);
        let mut worst: f64 = 0.0;
        for col in 0..SHARED + 18 {
            let h = if col < 4 { 1e-3 } else { 1e-6 };
            let step = |sign: f64| {
                let mut st = Step { shared: SVector::zeros(), boards: [SVector::zeros(); B] };
                if col < SHARED {
                    st.shared[col] = sign * h;
                } else {
                    st.boards[(col - SHARED) / 6][(col - SHARED) % 6] = sign * h;
                }
                collect(&apply_step(&params, &st))
            };
            let (plus, minus) = (step(1.0), step(-1.0));
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
                assert!(err < 1e-5, "{:?} column {col}: {analytic} vs {numeric}", cam.model);
                worst = worst.max(err);
            }
        }
        println!("{:?}: worst relative Jacobian error {worst:.2e}", cam.model);
    }
}

#[test]
fn board_pose_from_pixels_for_both_models() {
    for cam in cameras() {
        let s = scene_with(cam, 6, 0.0, 0.0, 2);
        for (truth, px) in s.poses.iter().zip(&s.corners) {
            let got = board_pose(&s.camera, &s.object, px).unwrap();
            assert!(rot_angle(&got.rotation, &truth.rotation) < 1e-7, "{:?}", cam.model);
            assert!((got.translation - truth.translation).norm() < 1e-6, "{:?}", cam.model);
        }
    }
}

#[test]
fn joint_lm_converges_for_both_models() {
    for cam in cameras() {
        let s = scene_with(cam, 6, 0.3, 0.01, 31);
        let p = problem(&s);
        let mut params = perturbed(&s);
        let report = p.solve(&mut params, &LmOptions::default()).unwrap();
        let cov = covariance(&p, &params, ParamMask::free()).unwrap();
        let u = cov.uncertainty();
        let est = params.camera.params();
        let truth = s.camera.params();
        println!("{:?}: {report:?}", cam.model);
        println!(
            "  Δ[fx fy cx cy] {:.3?} px, σ [{:.3} {:.3} {:.3} {:.3}]",
            [est[0] - truth[0], est[1] - truth[1], est[2] - truth[2], est[3] - truth[3]],
            u.fx,
            u.fy,
            u.cx,
            u.cy
        );
        for i in 0..4 {
            assert!((est[i] - truth[i]).abs() < 4.0 * cov.sigma(i), "{:?} param {i}", cam.model);
        }
        let rot_err =
            rot_angle(&params.lidar_to_camera.rotation, &s.extrinsic.rotation).to_degrees();
        let t_err = (params.lidar_to_camera.translation - s.extrinsic.translation).norm();
        println!(
            "  rot {rot_err:.4}° (σ {:.4}), t {t_err:.4} m (σ {:.4})",
            u.rotation_deg, u.translation_m
        );
        assert!(rot_err < 4.0 * 3f64.sqrt() * u.rotation_deg);
        assert!(t_err < 4.0 * 3f64.sqrt() * u.translation_m);
        assert!((cov.residual_variance - 1.0).abs() < 0.3, "σ̂² {}", cov.residual_variance);
        if cam.model == CameraModel::Fisheye {
            assert_eq!(report.free_parameters, 8 + 6 + 36);
            assert_eq!(params.camera.distortion[4], 0.0);
            assert_eq!(cov.sigma(8), 0.0);
        }
    }
}

#[test]
fn fisheye_from_a_nominal_fov_camera_converges() {
    let truth = cameras()[1];
    let s = scene_with(truth, 6, 0.3, 0.01, 12);
    let p = problem(&s);
    // What the room file gives: the model, the size and a rough field of view.
    let hfov = 2.0 * (0.5 * 1920.0 / truth.fx).to_degrees() * 1.05;
    let nominal = Camera::from_fov(CameraModel::Fisheye, 1920, 1200, hfov, [0.0; 5]);
    let (mut params, init) = initialise(&p, nominal, IntrinsicsSeed::Given).unwrap();
    assert!(init.zhang.is_none() && init.zhang_error.is_none());
    let report = p.solve(&mut params, &LmOptions::default()).unwrap();
    let cov = covariance(&p, &params, ParamMask::free()).unwrap();
    let (est, tru) = (params.camera.params(), truth.params());
    println!("fisheye from FOV {hfov:.1}°: pose rms {:.2} px; {report:?}", init.pose_rms_px);
    for i in 0..4 {
        let e = (est[i] - tru[i]).abs();
        println!("  param {i}: error {e:.3} σ {:.3}", cov.sigma(i));
        assert!(e < 4.0 * cov.sigma(i), "param {i}: {} vs {}", est[i], tru[i]);
    }
    assert!(report.corner_rms_px < 0.6, "{report:?}");
    assert_ne!(report.termination, Termination::MaxIterations);
}
