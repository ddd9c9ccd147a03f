//! Proves the joint solve and its covariance make no heap allocation, for one pair and
//! for a whole rig: a counting global allocator, enabled only on this test's thread while
//! the solver runs.

use crate::common::rig_scene;
use crate::common::solve_common;

use crate::counting_alloc::count_allocations;

use roomcal::geometry::{Camera, CameraModel};
use roomcal::solve::ParamMask;
use roomcal::solve::{covariance, BoardObservation, JointParams, JointProblem, LmOptions, Loss};
use solve_common::*;

#[test]
fn joint_solve_makes_no_heap_allocation() {
    let camera = Camera {
        model: CameraModel::PinholeRadtan,
        width: 1920,
        height: 1200,
        fx: 1400.0,
        fy: 1395.0,
        cx: 962.0,
        cy: 603.0,
        distortion: [-0.12, 0.05, 0.001, -0.0008, 0.01],
    };
    let s = scene_with(camera, 6, 0.3, 0.01, 99);
    let mut p: JointProblem<'_, 16> = JointProblem::new(0.3, 4.0, Loss::Huber(3.0));
    for ((corners, lidar), plane) in s.corners.iter().zip(&s.holes_lidar).zip(&s.planes) {
        let obs = BoardObservation {
            object: &s.object,
            corners,
            holes_board: &s.holes,
            holes_lidar: lidar,
            hole_sigma_px: None,
            plane: Some(*plane),
        };
        p.add_board(obs).unwrap();
    }
    let mut params: JointParams<Camera, 16> = JointParams {
        camera: s.camera,
        lidar_to_camera: s.extrinsic,
        board_poses: s.poses.iter().copied().collect(),
    };
    params.camera.fx *= 1.03;
    params.lidar_to_camera.translation.x += 0.05;
    let options = LmOptions::default();

    // Sanity: the counter works on this thread.
    let ((), sanity) = count_allocations(|| drop(std::hint::black_box(vec![1u8; 16])));
    assert_eq!(sanity, 1);

    let ((report, cov), count) = count_allocations(|| {
        let report = p.solve(&mut params, &options);
        (report, covariance(&p, &params, ParamMask::free()))
    });

    let report = report.unwrap();
    assert!(report.iterations > 1, "the solve must actually iterate: {report:?}");
    assert!(cov.unwrap().uncertainty().fx > 0.0);
    assert_eq!(count, 0, "heap allocations inside the solve");
}

#[test]
fn rig_solve_makes_no_heap_allocation() {
    use roomcal::solve::rig::{rig_covariance, solve_rig};
    let s = rig_scene::scene(None);
    let p = rig_scene::problem(&s, 0.1, 0.003, Loss::Huber(3.0));
    let mut params = rig_scene::perturbed(&s);
    let ((report, cov), count) = count_allocations(|| {
        let report = solve_rig(&p, &mut params, 50);
        (report, rig_covariance(&p, &params))
    });
    let report = report.unwrap();
    assert!(report.iterations > 1, "the solve must actually iterate: {report:?}");
    assert!(cov.unwrap().intrinsics_sigma(1)[0] > 0.0);
    assert_eq!(count, 0, "heap allocations inside the rig solve");
}
