//! The survey's bundle adjustment (`calibrate::survey`): analytic Jacobians against
//! numeric ones; a survey of synthetic visits (projected corners, LiDAR holes, board-face
//! and room-plane points with their noise) recovers the room within its σ, and the σ are
//! honest over many noise draws; the error cases name the visit and the board; and a
//! survey of 8 rendered, ray-cast visits recovers every board and plane within 3σ.

use std::path::Path;

use nalgebra::{DVector, SVector};
use roomcal::calibrate::survey::bundle::{
    BundleBoard, BundleVisit, RoomPlane, SurveyProblem, SurveyState, VisitState, VISIT,
};
use roomcal::calibrate::survey::chain::half_turn;
use roomcal::calibrate::survey::gauge::mean_pose;
use roomcal::calibrate::survey::{
    prepare_visit, survey, Survey, SurveyError, SurveyVisit, VisitBoard,
};
use roomcal::calibrate::{Detectors, FrameDetections};
use roomcal::detect::planes::FoundPlane;
use roomcal::geometry::{se3::so3_exp, Camera, CameraModel, Se3, Vec2, Vec3};
use roomcal::solve::PlanePoints;
use roomcal::target::{BoardSpec, Room};

fn room() -> Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

/// Deterministic normal noise (SplitMix64 + Box–Muller).
struct Noise(u64);

impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
    fn vec3(&mut self, s: f64) -> Vec3 {
        Vec3::new(self.normal() * s, self.normal() * s, self.normal() * s)
    }
}

/// A synthetic room in a frame where the cameras look along +z: six boards 4–6 m ahead,
/// a floor, two side walls and a wall ahead.
struct Synthetic {
    boards: Vec<Se3>,
    planes: Vec<RoomPlane>,
}

fn synthetic_room() -> Synthetic {
    let boards = (0..6)
        .map(|b| {
            let (col, row) = ((b % 3) as f64, (b / 3) as f64);
            Se3 {
                rotation: so3_exp(&Vec3::new(0.25 - 0.1 * row, 0.4 * (col - 1.0), 0.05 * col)),
                translation: Vec3::new(
                    1.6 * (col - 1.0),
                    1.3 * row - 0.7,
                    4.5 + 0.6 * col - 0.4 * row,
                ),
            }
        })
        .collect();
    let planes = vec![
        RoomPlane { normal: Vec3::new(0.0, 1.0, 0.0), offset: 1.6 }, // floor (y down)
        RoomPlane { normal: Vec3::new(1.0, 0.0, 0.0), offset: 3.5 }, // right wall
        RoomPlane { normal: Vec3::new(-1.0, 0.0, 0.0), offset: 3.2 }, // left wall
        RoomPlane { normal: Vec3::new(0.0, 0.0, 1.0), offset: 8.0 }, // wall ahead
    ];
    Synthetic { boards, planes }
}

const CORNER_SIGMA_PX: f64 = 0.1;
const HOLE_SIGMA_M: f64 = 0.01;
const RANGE_SIGMA_M: f64 = 0.02;

/// Visit `v`'s truth: its camera, mounting and parking pose.
fn visit_truth(v: usize) -> VisitState {
    let k = v as f64;
    let mut camera =
        Camera::from_fov(CameraModel::PinholeRadtan, 1920, 1200, 70.0, [-0.1, 0.03, 0.0, 0.0, 0.0]);
    camera.fx *= 1.0 + 0.01 * (k * 1.3).sin();
    camera.fy = camera.fx * (1.0 + 1e-4 * k.cos());
    camera.cx += 8.0 * (k * 0.7).cos();
    camera.cy += 6.0 * (k * 1.9).sin();
    let lidar_to_camera = Se3 {
        rotation: so3_exp(&Vec3::new(0.01 * k.sin(), 0.02 * (2.0 * k).cos(), 0.01)),
        translation: Vec3::new(0.05, 0.4 + 0.01 * k.sin(), -0.3),
    };
    let room_to_camera = Se3 {
        rotation: so3_exp(&Vec3::new(
            0.005 * k.cos(),
            (5.0f64 * (k * 2.1).sin()).to_radians(),
            0.004 * k.sin(),
        )),
        translation: Vec3::new(0.3 * (k * 1.7).sin(), 0.01 * k.cos(), 0.3 * (k * 0.9).cos()),
    };
    VisitState { camera, lidar_to_camera, room_to_camera }
}

/// One synthetic visit's measurements, with noise from `noise`: every board (the LiDAR's
/// holes and face points on `lidar_boards` of them) and every room plane.
fn synthetic_visit(
    spec: &BoardSpec,
    room: &Synthetic,
    truth: &VisitState,
    noise: &mut Noise,
    lidar_boards: &[usize],
) -> (Vec<VisitBoard>, Vec<(usize, PlanePoints)>) {
    let camera_to_lidar = truth.lidar_to_camera.inverse();
    let mut boards = Vec::new();
    for (b, in_room) in room.boards.iter().enumerate() {
        let pose = truth.room_to_camera.compose(in_room);
        let corners = (0..spec.corner_count())
            .map(|i| {
                let px = truth.camera.project(&pose.act(&spec.corner(i))).unwrap();
                px + Vec2::new(noise.normal(), noise.normal()) * CORNER_SIGMA_PX
            })
            .collect();
        let with_lidar = lidar_boards.contains(&b);
        let holes_lidar = if with_lidar {
            (0..spec.holes.len())
                .map(|h| {
                    camera_to_lidar.act(&pose.act(&spec.hole(h)))
                        + noise.vec3(HOLE_SIGMA_M / 3f64.sqrt())
                })
                .collect()
        } else {
            Vec::new()
        };
        let face = (0..200).map(|_| {
            let (x, y) = ((noise.uniform() - 0.5) * 1.0, (noise.uniform() - 0.5) * 0.8);
            let on = pose.act(&Vec3::new(x, y, noise.normal() * RANGE_SIGMA_M));
            camera_to_lidar.act(&on)
        });
        let plane = if with_lidar {
            PlanePoints::from_points(face.collect::<Vec<_>>(), RANGE_SIGMA_M)
        } else {
            None
        };
        // The free-board start: the truth a little off.
        let start =
            pose.perturb_left(&nalgebra::Vector6::new(0.002, -0.001, 0.002, 0.01, -0.01, 0.02));
        let hole_sigma_px = truth.camera.fx * HOLE_SIGMA_M / pose.translation.z;
        boards.push(VisitBoard { corners, holes_lidar, hole_sigma_px, plane, pose: start });
    }
    let room_to_lidar = camera_to_lidar.compose(&truth.room_to_camera);
    let lidar_to_room = room_to_lidar.inverse();
    let mut planes = Vec::new();
    for (p, plane) in room.planes.iter().enumerate() {
        // 2000 points on a 4 m patch of the plane near the room's middle.
        let (u, w) = {
            let a = if plane.normal.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
            let u = plane.normal.cross(&a).normalize();
            (u, plane.normal.cross(&u))
        };
        let centre = plane.normal * plane.offset;
        let points: Vec<Vec3> = (0..2000)
            .map(|_| {
                let on =
                    centre + u * (noise.uniform() - 0.5) * 4.0 + w * (noise.uniform() - 0.5) * 4.0;
                room_to_lidar.act(&(on + plane.normal * noise.normal() * RANGE_SIGMA_M))
            })
            .collect();
        let _ = lidar_to_room;
        planes.push((p, PlanePoints::from_points(points, RANGE_SIGMA_M).unwrap()));
    }
    (boards, planes)
}

/// Synthetic visits as `survey` takes them (planes as the plane finder reports them).
fn synthetic_visits(count: usize, seed: u64) -> (Synthetic, Vec<VisitState>, Vec<SurveyVisit>) {
    let spec = room().board;
    let synthetic = synthetic_room();
    let mut noise = Noise(seed);
    let truths: Vec<VisitState> = (0..count).map(visit_truth).collect();
    let visits = truths
        .iter()
        .enumerate()
        .map(|(v, truth)| {
            let lidar: Vec<usize> = (0..6).filter(|b| (b + v) % 3 != 0).collect();
            let (boards, planes) = synthetic_visit(&spec, &synthetic, truth, &mut noise, &lidar);
            let camera_to_lidar = truth.lidar_to_camera.inverse();
            let room_to_lidar = camera_to_lidar.compose(&truth.room_to_camera);
            let found = planes
                .iter()
                .map(|(p, points)| {
                    let plane = &synthetic.planes[*p];
                    let normal = room_to_lidar.rotation * plane.normal;
                    let offset = plane.offset + normal.dot(&room_to_lidar.translation);
                    FoundPlane { normal, offset, points: *points, spread_m: [1.2, 1.2] }
                })
                .collect();
            let mut camera = truth.camera;
            camera.fx *= 1.002;
            camera.cx += 1.0;
            SurveyVisit {
                camera,
                lidar_to_camera: Some(
                    truth
                        .lidar_to_camera
                        .perturb_left(&nalgebra::Vector6::new(0.003, 0.0, -0.002, 0.01, 0.0, 0.01)),
                ),
                corner_sigma_px: CORNER_SIGMA_PX,
                boards,
                planes: found,
            }
        })
        .collect();
    (synthetic, truths, visits)
}

/// `truth` (board → truth room) in the survey's gauge (board 0's frame).
fn in_gauge(truth: &[Se3], b: usize) -> Se3 {
    truth[0].inverse().compose(&truth[b])
}

/// The error of survey board `b` against the truth: (largest axis of position error m,
/// largest axis of rotation error deg).
fn board_error(found: &Se3, truth: &Se3) -> (f64, f64) {
    let dt = (found.translation - truth.translation).abs().max();
    let dr =
        roomcal::geometry::se3::so3_log(&(found.rotation * truth.rotation.transpose())).abs().max();
    (dt, dr.to_degrees())
}

/// `truth` (board → truth room) in the frame the survey gives its boards in: the boards'
/// mean (`gauge::mean_pose`).
fn in_mean_frame(truth: &[Se3], b: usize) -> Se3 {
    mean_pose(truth).inverse().compose(&truth[b])
}

/// A truth-room plane in the gauge: `n · (R0 p + t0) = d`.
fn plane_in_gauge(gauge_to_truth: &Se3, plane: &RoomPlane) -> RoomPlane {
    let normal = gauge_to_truth.rotation.transpose() * plane.normal;
    RoomPlane { normal, offset: plane.offset - plane.normal.dot(&gauge_to_truth.translation) }
}

fn plane_error(found: &RoomPlane, truth: &RoomPlane) -> (f64, f64) {
    (
        (found.offset - truth.offset).abs(),
        found.normal.dot(&truth.normal).clamp(-1.0, 1.0).acos().to_degrees(),
    )
}

#[test]
fn analytic_jacobians_match_numeric_ones() {
    let spec = room().board;
    let synthetic = synthetic_room();
    let mut noise = Noise(3);
    let truths: Vec<VisitState> = (0..2).map(visit_truth).collect();
    let visits: Vec<BundleVisit> = truths
        .iter()
        .map(|truth| {
            let (boards, planes) =
                synthetic_visit(&spec, &synthetic, truth, &mut noise, &[0, 2, 4]);
            let boards = boards
                .into_iter()
                .enumerate()
                .map(|(b, board)| BundleBoard {
                    room_board: b,
                    corners: board.corners,
                    holes_lidar: board.holes_lidar,
                    hole_sigma_px: board.hole_sigma_px,
                    plane: board.plane,
                })
                .collect();
            BundleVisit { corner_sigma_px: CORNER_SIGMA_PX, boards, planes }
        })
        .collect();
    let object: Vec<Vec3> = (0..spec.corner_count()).map(|i| spec.corner(i)).collect();
    let holes: Vec<Vec3> = (0..spec.holes.len()).map(|h| spec.hole(h)).collect();
    let problem = SurveyProblem::new(&object, &holes, &visits, 6, 4).unwrap();
    // Away from the truth, so that residuals (and the plane terms' lever arms) are not zero.
    let gauge = |v: &VisitState| VisitState {
        room_to_camera: v.room_to_camera.compose(&synthetic.boards[0]),
        ..v.clone()
    };
    let base = SurveyState {
        visits: truths.iter().map(gauge).collect(),
        boards: (0..6).map(|b| in_gauge(&synthetic.boards, b)).collect(),
        planes: synthetic.planes.iter().map(|p| plane_in_gauge(&synthetic.boards[0], p)).collect(),
    };
    let zero_visits = vec![SVector::<f64, VISIT>::zeros(); 2];
    let zero_global = DVector::<f64>::zeros(problem.global_len());
    let mut shift = DVector::<f64>::zeros(problem.global_len());
    for i in 0..shift.len() {
        shift[i] = 1e-3 * ((i as f64) * 0.7).sin();
    }
    let state = base.updated(&zero_visits, &shift);
    let mut analytic = Vec::new();
    problem.for_each_block(&state, |b| analytic.push(*b)).unwrap();
    let residuals = |s: &SurveyState| {
        let mut r = Vec::new();
        problem.for_each_block(s, |b| r.push(b.r)).unwrap();
        r
    };
    let mut worst = 0.0f64;
    let mut compare = |numeric: &[Vec2],
                       column: &dyn Fn(&roomcal::calibrate::survey::bundle::Block) -> Vec2,
                       what: &str| {
        for (k, (n, blk)) in numeric.iter().zip(&analytic).enumerate() {
            let a = column(blk);
            let scale = 1.0 + n.norm().max(a.norm());
            let err = (n - a).norm() / scale;
            worst = worst.max(err);
            assert!(err < 1e-5, "{what}, block {k}: numeric {n:?} vs analytic {a:?}");
        }
    };
    let eps = 1e-6;
    for v in 0..2 {
        for i in 0..VISIT {
            // Intrinsics are in pixels; a relative step keeps the difference meaningful.
            let h = if i < 4 { eps * 1e3 } else { eps };
            let mut plus = zero_visits.clone();
            let mut minus = zero_visits.clone();
            plus[v][i] = h;
            minus[v][i] = -h;
            let (rp, rm) = (
                residuals(&state.updated(&plus, &zero_global)),
                residuals(&state.updated(&minus, &zero_global)),
            );
            let numeric: Vec<Vec2> = rp.iter().zip(&rm).map(|(p, m)| (p - m) / (2.0 * h)).collect();
            compare(
                &numeric,
                &|b| if b.visit == v { b.j_visit.column(i).into_owned() } else { Vec2::zeros() },
                &format!("visit {v} parameter {i}"),
            );
        }
    }
    for c in 0..problem.global_len() {
        let mut plus = zero_global.clone();
        let mut minus = zero_global.clone();
        plus[c] = eps;
        minus[c] = -eps;
        let (rp, rm) = (
            residuals(&state.updated(&zero_visits, &plus)),
            residuals(&state.updated(&zero_visits, &minus)),
        );
        let numeric: Vec<Vec2> = rp.iter().zip(&rm).map(|(p, m)| (p - m) / (2.0 * eps)).collect();
        let column = |b: &roomcal::calibrate::survey::bundle::Block| {
            if let Some((board, j)) = &b.board {
                let at = problem.board_column(*board).unwrap();
                if (at..at + 6).contains(&c) {
                    return j.column(c - at).into_owned();
                }
            }
            if let Some((plane, j)) = &b.plane {
                let at = problem.plane_column(*plane);
                if (at..at + 3).contains(&c) {
                    return j.column(c - at).into_owned();
                }
            }
            Vec2::zeros()
        };
        compare(&numeric, &column, &format!("global parameter {c}"));
    }
    println!("worst relative Jacobian difference {worst:.2e} over {} blocks", analytic.len());
}

/// Checks a survey against the synthetic truth in the survey's frame (the boards' mean):
/// every board and plane within 3σ (each axis of the error against the σ of the largest
/// axis); returns the errors in σ.
fn check_within_3_sigma(found: &Survey, synthetic: &Synthetic) -> Vec<f64> {
    let mut normalised = Vec::new();
    let mean = mean_pose(&synthetic.boards);
    for (b, board) in found.spec.boards.iter().enumerate() {
        let truth = in_mean_frame(&synthetic.boards, b);
        let (dt, dr) = board_error(&board.pose(), &truth);
        assert!(
            dt <= 3.0 * board.sigma_m,
            "board {b}: position off {:.3} mm, σ {:.3} mm",
            dt * 1e3,
            board.sigma_m * 1e3
        );
        assert!(
            dr <= 3.0 * board.sigma_deg,
            "board {b}: rotation off {dr:.4}°, σ {:.4}°",
            board.sigma_deg
        );
        normalised.extend([dt / board.sigma_m, dr / board.sigma_deg]);
    }
    for (p, plane) in found.spec.planes.iter().enumerate() {
        let mine = RoomPlane { normal: Vec3::from(plane.normal), offset: plane.offset };
        let truth = synthetic
            .planes
            .iter()
            .map(|t| plane_in_gauge(&mean, t))
            .min_by(|a, b| plane_error(&mine, a).1.total_cmp(&plane_error(&mine, b).1))
            .unwrap();
        let (dd, dn) = plane_error(&mine, &truth);
        assert!(
            dd <= 3.0 * plane.sigma_m,
            "plane {p}: offset off {:.3} mm, σ {:.3} mm",
            dd * 1e3,
            plane.sigma_m * 1e3
        );
        assert!(
            dn <= 3.0 * plane.sigma_deg,
            "plane {p}: normal off {dn:.4}°, σ {:.4}°",
            plane.sigma_deg
        );
        normalised.extend([dd / plane.sigma_m, dn / plane.sigma_deg]);
    }
    normalised
}

#[test]
fn a_synthetic_survey_recovers_the_room_within_its_sigma_and_the_sigma_are_honest() {
    let room = room();
    let mut all = Vec::new();
    for seed in 1..=6 {
        let (synthetic, _, visits) = synthetic_visits(8, seed);
        let found = survey(&room, &visits).unwrap();
        assert_eq!(found.spec.boards.len(), 6);
        assert_eq!(found.spec.planes.len(), 4, "every room plane is surveyed");
        assert!(found.board_visits.iter().all(|&n| n == 8));
        all.extend(check_within_3_sigma(&found, &synthetic));
    }
    // Honest σ: the errors are about as large as the σ say (each entry is the largest
    // axis of an error over the largest-axis σ, so its RMS is at most about 1; σ ten times
    // too large would put it near 0.1).
    let rms = (all.iter().map(|e| e * e).sum::<f64>() / all.len() as f64).sqrt();
    println!("error / σ over {} board and plane axes: RMS {rms:.2}", all.len());
    assert!((0.25..=1.5).contains(&rms), "error / σ RMS {rms:.2}: the σ are not honest");
}

#[test]
fn a_half_turned_detection_is_relabelled_into_the_room_board() {
    let room = room();
    let (synthetic, _, mut visits) = synthetic_visits(4, 11);
    // Visit 3 reads board 2 from the other corner: corners reversed, holes swapped.
    let board = &mut visits[2].boards[2];
    board.corners.reverse();
    board.holes_lidar = board.holes_lidar.iter().rev().copied().collect();
    board.pose = board.pose.compose(&half_turn());
    let found = survey(&room, &visits).unwrap();
    assert!(found.labels[2][2].half_turned);
    assert_eq!(found.labels[2][2].room_board, 2);
    check_within_3_sigma(&found, &synthetic);
}

#[test]
fn mistakes_name_the_visit_and_the_board() {
    let room = room();
    let (_, _, visits) = synthetic_visits(3, 5);
    let message = |visits: &[SurveyVisit]| survey(&room, visits).unwrap_err().to_string();

    let again = vec![visits[0].clone(), visits[1].clone(), visits[0].clone()];
    let text = message(&again);
    assert!(text.contains("visit 3 is visit 1 again"), "{text}");

    // Board 5 only in visit 1.
    let mut once = visits.clone();
    for v in &mut once[1..] {
        v.boards.truncate(5);
    }
    let err = survey(&room, &once).unwrap_err();
    assert!(matches!(err, SurveyError::BoardSeenOnce { board: 5, visit: 1, index: 5 }), "{err:?}");
    assert!(
        err.to_string().contains("room board 5") && err.to_string().contains("visit 1"),
        "{err}"
    );

    // Visit 2 shares only board 0 with visit 1 (its other boards moved, each its own way).
    let mut apart = visits.clone();
    for (i, board) in apart[1].boards.iter_mut().enumerate().skip(1) {
        board.pose.translation += Vec3::new(0.3 * i as f64, 0.5 * i as f64, 0.0);
    }
    let text = message(&apart);
    assert!(text.contains("visit 2") && text.contains("only 1 of its boards"), "{text}");

    assert!(message(&visits[..1]).contains("at least 2 visits"));
}

// On supersample-1 renders (seed 4). Before the renderer integrated the checker over each
// sample's footprint their corners were 0.3 px off the true ones, the same way over each
// board, and the walls and floor came out at 3.1–3.2σ.
#[test]
fn a_survey_of_8_simulated_visits_recovers_every_board_and_plane_within_3_sigma() {
    let sim = rendered_visits(8);
    let room = &sim.room;
    let visits: Vec<SurveyVisit> = sim
        .visits
        .iter()
        .enumerate()
        .map(|(v, visit)| {
            let cloud = visit.scene.cloud.as_ref().unwrap();
            prepare_visit(room, v, &detected(room, visit), cloud).unwrap()
        })
        .collect();
    let found = survey(room, &visits).unwrap();
    // The truth in the survey's gauge: which truth board is room board b, from visit 1.
    let truth_boards: Vec<Se3> = sim.truth.boards.iter().map(|b| b.to_se3()).collect();
    let first = &found.state.visits[0];
    let mut truth_of = Vec::new();
    for board in &found.state.boards {
        let in_camera = first.room_to_camera.compose(board);
        let (k, truth) = truth_boards
            .iter()
            .enumerate()
            .map(|(k, t)| (k, sim.visits[0].room_to_camera.compose(t)))
            .min_by(|a, b| {
                (a.1.translation - in_camera.translation)
                    .norm()
                    .total_cmp(&(b.1.translation - in_camera.translation).norm())
            })
            .unwrap();
        let turned = (truth.rotation.transpose() * in_camera.rotation).trace() < 1.0;
        truth_of.push(if turned { truth_boards[k].compose(&half_turn()) } else { truth_boards[k] });
    }
    // The survey's frame is its boards' mean: the truth's, over the same boards.
    let gauge = mean_pose(&truth_of);
    let mut worst: (f64, f64) = (0.0, 0.0);
    for (b, board) in found.spec.boards.iter().enumerate() {
        let truth = gauge.inverse().compose(&truth_of[b]);
        let (dt, dr) = board_error(&board.pose(), &truth);
        println!(
            "board {b}: off {:.3} mm (σ {:.3}), {dr:.4}° (σ {:.4})",
            dt * 1e3,
            board.sigma_m * 1e3,
            board.sigma_deg
        );
        assert!(
            dt <= 3.0 * board.sigma_m,
            "board {b}: position off {:.3} mm, σ {:.3} mm",
            dt * 1e3,
            board.sigma_m * 1e3
        );
        assert!(
            dr <= 3.0 * board.sigma_deg,
            "board {b}: rotation off {dr:.4}°, σ {:.4}°",
            board.sigma_deg
        );
        worst = (worst.0.max(dt), worst.1.max(dr));
    }
    assert!(!found.spec.planes.is_empty(), "no room plane was surveyed");
    for plane in &found.spec.planes {
        let mine = RoomPlane { normal: Vec3::from(plane.normal), offset: plane.offset };
        let truth = sim
            .truth
            .planes
            .iter()
            .map(|t| {
                plane_in_gauge(
                    &gauge,
                    &RoomPlane { normal: Vec3::from(t.normal), offset: t.offset },
                )
            })
            .min_by(|a, b| plane_error(&mine, a).1.total_cmp(&plane_error(&mine, b).1))
            .unwrap();
        let (dd, dn) = plane_error(&mine, &truth);
        println!(
            "plane {}: off {:.3} mm (σ {:.3}), {dn:.4}° (σ {:.4})",
            plane.name,
            dd * 1e3,
            plane.sigma_m * 1e3,
            plane.sigma_deg
        );
        assert!(
            dd <= 3.0 * plane.sigma_m,
            "plane {}: offset off {:.3} mm, σ {:.3} mm",
            plane.name,
            dd * 1e3,
            plane.sigma_m * 1e3
        );
        assert!(
            dn <= 3.0 * plane.sigma_deg,
            "plane {}: normal off {dn:.4}°, σ {:.4}°",
            plane.name,
            plane.sigma_deg
        );
    }
    println!("worst board: {:.3} mm, {:.4}°", worst.0 * 1e3, worst.1);
}

/// The survey takes "every board face the LiDAR hits", not only the faces of
/// the boards whose holes it placed. A visit whose LiDAR placed two boards by their holes
/// (its other placements removed here) still gives every other calibrated board's face,
/// cut where the camera and the free-board start's extrinsic put it; each such face lies on
/// its true board (centroid within 3σ of the range noise over its points, points within 1.5×
/// the range noise RMS). Before, those boards entered the bundle with corners only.
#[test]
fn a_survey_visit_gives_the_faces_of_boards_whose_holes_were_not_placed() {
    let sim = rendered_visits(1);
    let (room, visit) = (&sim.room, &sim.visits[0]);
    let cloud = visit.scene.cloud.as_ref().unwrap();
    let mut frame = detected(room, visit);
    assert!(frame.lidar.len() >= 3, "{} LiDAR boards placed", frame.lidar.len());
    frame.lidar.truncate(2);
    let prepared = prepare_visit(room, 0, &frame, cloud).unwrap();
    assert!(prepared.lidar_to_camera.is_some(), "the start has no extrinsic");
    let truth = &visit.scene.truth;
    let camera_to_lidar = truth.lidar_to_camera.as_ref().unwrap().to_se3().inverse();
    let mut unplaced_faces = 0;
    for board in prepared.boards.iter().filter(|b| b.holes_lidar.is_empty()) {
        let face = board.plane.expect("a board the camera calibrated has no face points");
        let nearest = truth
            .boards
            .iter()
            .map(|b| b.board_to_camera.to_se3())
            .min_by(|a, b| {
                (a.translation - board.pose.translation)
                    .norm()
                    .total_cmp(&(b.translation - board.pose.translation).norm())
            })
            .unwrap();
        let true_pose = camera_to_lidar.compose(&nearest);
        // Distances from the true plane: the centroid's, and the points' RMS (a face a few
        // scan lines cross has no plane of its own to compare).
        let n = true_pose.rotation.column(2).into_owned();
        let off = n.dot(&(face.centroid - true_pose.translation));
        let rms = ((face.spread * n).norm_squared() / face.weight + off * off).sqrt();
        println!(
            "face of {} points: centroid {:.2} mm off, RMS {:.1} mm",
            face.count,
            off * 1e3,
            rms * 1e3
        );
        let centroid_sigma = truth.range_noise_m / (face.count as f64).sqrt();
        assert!(off.abs() < 3.0 * centroid_sigma, "centroid {:.2} mm off its board", off * 1e3);
        assert!(rms < 1.5 * truth.range_noise_m, "RMS {:.1} mm off its board", rms * 1e3);
        unplaced_faces += 1;
    }
    assert!(unplaced_faces >= 1, "no board was left without its holes");
}

/// `n` visits of the design's room rendered at one sample per pixel (seed 4).
fn rendered_visits(n: usize) -> roomcal::sim::visits::Visits {
    use roomcal::sim::{ImageNoise, SimOptions};
    let options = SimOptions {
        seed: 4,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    roomcal::sim::visits::simulate_visits(&room(), &options, n).unwrap()
}

/// A rendered visit's camera and LiDAR detections.
fn detected(room: &Room, visit: &roomcal::sim::visits::Visit) -> FrameDetections {
    let mut detectors = Detectors::new(room).unwrap();
    let cloud = visit.scene.cloud.as_ref().unwrap();
    FrameDetections {
        camera: detectors.detect_pixels(&visit.scene.image).unwrap(),
        lidar: detectors.detect_cloud(cloud),
    }
}
