//! Closed-form initialisation and small linear algebra against exact synthetic data:
//! Cholesky, homography (DLT), Zhang, pose from homography, PnP refinement, Kabsch.

use crate::common::solve_common;

use nalgebra::{SMatrix, SVector};
use roomcal::geometry::{Mat3, Se3, Vec2, Vec3};
use roomcal::solve::init::{focal_from_homographies, homography, kabsch, pose_from_homography};
use roomcal::solve::linalg::{nearest_rotation, spd_inverse, Cholesky};
use roomcal::solve::{board_pose, refine_pose, zhang_intrinsics, Projector, SolveError};
use solve_common::*;

fn k_matrix(k: &[f64]) -> Mat3 {
    Mat3::new(k[0], 0.0, k[2], 0.0, k[1], k[3], 0.0, 0.0, 1.0)
}

fn pinhole(c: &RadtanCam) -> RadtanCam {
    let mut k = c.k;
    k[4..].fill(0.0);
    RadtanCam { k }
}

#[test]
fn cholesky_solves_inverts_and_rejects_indefinite() {
    let mut rng = Rng(7);
    let a = SMatrix::<f64, 8, 8>::from_fn(|_, _| rng.normal());
    let spd = a * a.transpose() + SMatrix::<f64, 8, 8>::identity() * 0.1;
    let b = SVector::<f64, 8>::from_fn(|_, _| rng.normal());
    let ch = Cholesky::new(&spd).unwrap();
    let x = ch.solve(&b);
    assert!((spd * x - b).norm() < 1e-10 * b.norm());
    let inv = spd_inverse(&spd).unwrap();
    assert!((inv * spd - SMatrix::<f64, 8, 8>::identity()).norm() < 1e-9);
    let l = ch.l();
    assert!((l * l.transpose() - spd).norm() < 1e-10 * spd.norm());

    let mut indefinite = spd;
    indefinite[(5, 5)] = -1.0;
    assert!(Cholesky::new(&indefinite).is_err());
    // Rank-deficient (a zero direction) is also refused, at the right pivot.
    let v = SVector::<f64, 3>::new(1.0, 2.0, 3.0);
    let rank1 = v * v.transpose();
    assert_eq!(Cholesky::new(&rank1).unwrap_err().pivot, 1);
    let e: SolveError = Cholesky::new(&rank1).unwrap_err().into();
    assert!(e.to_string().contains("pivot 1"));
}

#[test]
fn nearest_rotation_is_orthonormal_and_fixes_reflections() {
    let r = rot(&Vec3::new(0.3, -0.2, 1.1));
    let noisy = r + Mat3::from_fn(|i, j| 1e-3 * ((i * 3 + j) as f64 - 4.0));
    let n = nearest_rotation(&noisy).unwrap();
    assert!((n.transpose() * n - Mat3::identity()).norm() < 1e-12);
    assert!((n.determinant() - 1.0).abs() < 1e-12);
    assert!(rot_angle(&n, &r) < 5e-3);
    let reflected = -Mat3::identity();
    assert!((nearest_rotation(&reflected).unwrap().determinant() - 1.0).abs() < 1e-12);
}

/// Exact pixels of the board (no distortion) and the plane coordinates.
fn exact_views(cam: &RadtanCam, poses: &[Se3]) -> Vec<(Vec<Vec2>, Vec<Vec2>)> {
    poses
        .iter()
        .map(|p| {
            let obj = board_corners();
            let px = obj.iter().map(|x| cam.project(&(p.rotation * x + p.translation)).unwrap());
            (obj.iter().map(|x| x.xy()).collect(), px.collect())
        })
        .collect()
}

#[test]
fn homography_is_exact_on_exact_data_and_refuses_collinear_points() {
    let cam = pinhole(&truth_camera());
    for (i, pose) in truth_board_poses(6).iter().enumerate() {
        let (plane, px) = &exact_views(&cam, std::slice::from_ref(pose))[0];
        let h = homography(plane, px).unwrap();
        // H ∝ K [r1 r2 t].
        let expect = k_matrix(&cam.k)
            * Mat3::from_columns(&[
                pose.rotation.column(0).into_owned(),
                pose.rotation.column(1).into_owned(),
                pose.translation,
            ]);
        let expect = expect / expect[(2, 2)];
        assert!((h - expect).norm() < 1e-8 * expect.norm(), "board {i}: {h} vs {expect}");
        for (x, u) in plane.iter().zip(px) {
            let m = h * x.push(1.0);
            assert!((m.xy() / m.z - u).norm() < 1e-7);
        }
    }
    let line: Vec<Vec2> = (0..6).map(|i| Vec2::new(i as f64, 2.0 * i as f64)).collect();
    let img: Vec<Vec2> = (0..6).map(|i| Vec2::new(3.0 * i as f64, 1.0)).collect();
    assert!(matches!(homography(&line, &img), Err(SolveError::Degenerate(_))));
    // Good plane points, collinear image points: the fit would be singular.
    let grid: Vec<Vec2> = board_corners().iter().map(|p| p.xy()).collect();
    let flat: Vec<Vec2> = (0..grid.len()).map(|i| Vec2::new(10.0 * i as f64, 5.0)).collect();
    assert!(matches!(homography(&grid, &flat), Err(SolveError::Degenerate(_))));
    assert_eq!(
        homography(&line[..3], &img[..3]),
        Err(SolveError::TooFewPoints { needed: 4, got: 3 })
    );
    assert!(matches!(homography(&line, &img[..5]), Err(SolveError::LengthMismatch { .. })));
}

#[test]
fn zhang_recovers_exact_intrinsics_and_flags_parallel_boards() {
    let cam = pinhole(&truth_camera());
    for n in [2, 3, 6] {
        let hs: Vec<Mat3> = exact_views(&cam, &truth_board_poses(n))
            .iter()
            .map(|(plane, px)| homography(plane, px).unwrap())
            .collect();
        let z = zhang_intrinsics(&hs, 1920, 1200).unwrap();
        let got = [z.fx, z.fy, z.cx, z.cy];
        for (g, t) in got.iter().zip(&cam.k[..4]) {
            assert!((g - t).abs() < 1e-4, "{n} boards: {got:?} vs {:?}", &cam.k[..4]);
        }
        assert!(z.condition > 1e-6, "{n} boards: condition {}", z.condition);
    }
    // All boards facing the camera squarely, only translated: focal length unobservable.
    let parallel: Vec<Se3> = truth_board_poses(4)
        .into_iter()
        .map(|p| Se3 { rotation: rot(&Vec3::new(0.0, 0.0, 0.3)), translation: p.translation })
        .collect();
    let hs: Vec<Mat3> = exact_views(&cam, &parallel)
        .iter()
        .map(|(plane, px)| homography(plane, px).unwrap())
        .collect();
    assert!(matches!(zhang_intrinsics(&hs, 1920, 1200), Err(SolveError::Degenerate(_))));
    assert!(matches!(zhang_intrinsics(&hs[..1], 1920, 1200), Err(SolveError::TooFewPoints { .. })));
}

#[test]
fn focal_from_one_tilted_board_with_known_centre() {
    let mut cam = pinhole(&truth_camera());
    cam.k[1] = cam.k[0]; // square pixels, as the method assumes
    let pose = truth_board_poses(1);
    let (plane, px) = &exact_views(&cam, &pose)[0];
    let h = homography(plane, px).unwrap();
    let f = focal_from_homographies(&[h], cam.k[2], cam.k[3]).unwrap();
    assert!((f - cam.k[0]).abs() < 1e-4, "{f}");
    let flat = Se3 { rotation: Mat3::identity(), translation: Vec3::new(0.1, 0.0, 3.0) };
    let (plane, px) = &exact_views(&cam, &[flat])[0];
    let h = homography(plane, px).unwrap();
    assert!(matches!(
        focal_from_homographies(&[h], cam.k[2], cam.k[3]),
        Err(SolveError::Degenerate(_))
    ));
}

#[test]
fn pose_from_homography_is_exact() {
    let cam = pinhole(&truth_camera());
    for pose in truth_board_poses(6) {
        let (plane, px) = &exact_views(&cam, std::slice::from_ref(&pose))[0];
        let h = homography(plane, px).unwrap();
        let got = pose_from_homography(&h, &k_matrix(&cam.k)).unwrap();
        assert!(rot_angle(&got.rotation, &pose.rotation) < 1e-8);
        assert!((got.translation - pose.translation).norm() < 1e-7);
        // The sign of H does not matter: the board stays in front.
        let got = pose_from_homography(&(-h), &k_matrix(&cam.k)).unwrap();
        assert!((got.translation - pose.translation).norm() < 1e-7);
    }
}

#[test]
fn board_pose_with_distortion_and_refinement() {
    let cam = truth_camera();
    let s = scene(6, 0.0, 0.0, 1);
    for (pose, px) in s.poses.iter().zip(&s.corners) {
        let got = board_pose(&cam, &s.object, px).unwrap();
        assert!(rot_angle(&got.rotation, &pose.rotation) < 1e-7);
        assert!((got.translation - pose.translation).norm() < 1e-6);
        // Refinement from a perturbed pose converges back.
        let mut start = Se3 {
            rotation: rot(&Vec3::new(0.03, -0.02, 0.04)) * pose.rotation,
            translation: pose.translation + Vec3::new(0.05, -0.04, 0.1),
        };
        let rms = refine_pose(&cam, &s.object, px, &mut start, 50).unwrap();
        assert!(rms < 1e-6, "rms {rms}");
        assert!(rot_angle(&start.rotation, &pose.rotation) < 1e-8);
    }
    let bent: Vec<Vec3> = s.object.iter().map(|p| Vec3::new(p.x, p.y, 0.1 * p.x)).collect();
    assert!(matches!(board_pose(&cam, &bent, &s.corners[0]), Err(SolveError::Degenerate(_))));
}

#[test]
fn kabsch_recovers_exact_motion_and_refuses_collinear_points() {
    let truth = truth_extrinsic();
    let s = scene(6, 0.0, 0.0, 3);
    let lidar: Vec<Vec3> = s.holes_lidar.iter().flatten().copied().collect();
    let cam: Vec<Vec3> = lidar.iter().map(|p| truth.rotation * p + truth.translation).collect();
    let got = kabsch(&lidar, &cam).unwrap();
    assert!(rot_angle(&got.rotation, &truth.rotation) < 1e-10);
    assert!((got.translation - truth.translation).norm() < 1e-10);
    // One board: its 4 holes are coplanar, still enough.
    let got = kabsch(&lidar[..4], &cam[..4]).unwrap();
    assert!(rot_angle(&got.rotation, &truth.rotation) < 1e-9);
    let line: Vec<Vec3> = (0..5).map(|i| Vec3::new(i as f64, 0.5 * i as f64, 0.0)).collect();
    let moved: Vec<Vec3> = line.iter().map(|p| truth.rotation * p + truth.translation).collect();
    assert!(matches!(kabsch(&line, &moved), Err(SolveError::Degenerate(_))));
    assert!(matches!(kabsch(&line[..2], &moved[..2]), Err(SolveError::TooFewPoints { .. })));
}

#[test]
fn zhang_with_noise_is_close_enough_to_start_lm() {
    let s = scene(6, 0.3, 0.0, 11);
    let hs: Vec<Mat3> = s
        .corners
        .iter()
        .map(|px| {
            let plane: Vec<Vec2> = s.object.iter().map(|x| x.xy()).collect();
            homography(&plane, px).unwrap()
        })
        .collect();
    let z = zhang_intrinsics(&hs, 1920, 1200).unwrap();
    let t = &s.camera.k;
    // Distortion (k1 = −0.12) is ignored here, so several per cent are expected.
    assert!((z.fx / t[0] - 1.0).abs() < 0.08 && (z.fy / t[1] - 1.0).abs() < 0.08, "{z:?}");
    assert!((z.cx - t[2]).abs() < 60.0 && (z.cy - t[3]).abs() < 80.0, "{z:?}");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]

    /// Any rigid motion is recovered exactly from ≥ 3 random non-collinear points.
    #[test]
    fn kabsch_recovers_random_motions(
        w in proptest::array::uniform3(-3.0f64..3.0),
        t in proptest::array::uniform3(-5.0f64..5.0),
        seed in 1u64..u64::MAX,
        n in 3usize..30,
    ) {
        let truth = Se3 { rotation: rot(&Vec3::from(w)), translation: Vec3::from(t) };
        let mut rng = Rng(seed);
        let from: Vec<Vec3> = (0..n).map(|_| rng.vec3(1.0)).collect();
        let to: Vec<Vec3> = from.iter().map(|p| truth.rotation * p + truth.translation).collect();
        match kabsch(&from, &to) {
            Ok(got) => {
                // The turn about the points' best line is pinned by their spread across it:
                // nearly collinear draws that kabsch accepts (6.8 mm across, a proptest
                // case) are exact to 1e-7, not 1e-8 (rounding grows as 1 / spread).
                let tol = 1e-8f64.max(2e-9 / second_spread(&from));
                proptest::prop_assert!((got.rotation - truth.rotation).norm() < tol);
                proptest::prop_assert!((got.translation - truth.translation).norm() < 10.0 * tol);
            }
            // Only nearly collinear random draws may be refused.
            Err(e) => proptest::prop_assert!(matches!(e, SolveError::Degenerate(_)) && n == 3),
        }
    }

    /// A board seen from random poses in front of the camera: the homography maps every
    /// plane point onto its pixel.
    #[test]
    fn homography_maps_random_views(
        w in proptest::array::uniform3(-0.8f64..0.8),
        x in -1.0f64..1.0,
        y in -1.0f64..1.0,
        z in 2.0f64..8.0,
    ) {
        let cam = pinhole(&truth_camera());
        let pose = Se3 { rotation: rot(&Vec3::from(w)), translation: Vec3::new(x, y, z) };
        let (plane, px) = &exact_views(&cam, &[pose])[0];
        let h = homography(plane, px).unwrap();
        for (p, u) in plane.iter().zip(px) {
            let m = h * p.push(1.0);
            proptest::prop_assert!((m.xy() / m.z - u).norm() < 1e-6);
        }
    }
}

/// The points' spread (RMS distance, m) across the line that fits them best: how well
/// three or more points pin a rotation about that line.
fn second_spread(points: &[Vec3]) -> f64 {
    let centre = points.iter().fold(Vec3::zeros(), |a, p| a + p) / points.len() as f64;
    let scatter =
        points.iter().fold(Mat3::zeros(), |m, p| m + (p - centre) * (p - centre).transpose());
    let mut ev: Vec<f64> = scatter.symmetric_eigenvalues().iter().copied().collect();
    ev.sort_by(f64::total_cmp);
    (ev[1].max(0.0) / points.len() as f64).sqrt()
}
