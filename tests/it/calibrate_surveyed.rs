//! Calibration in a surveyed room (`calibrate::calibrate_with_clouds` with `[survey]`):
//! a new vehicle (a visit the survey was not made from) in a seven-board Pandar64 room,
//! the survey built from the simulator's room truth — exact, and with noise drawn at the
//! stated σ (boards ±0.5 mm / 0.01°, planes ±2 mm / 0.01°) — against the free-board model
//! on the same detections; identification over random parkings, missing and half-turned
//! boards; a moved board named and left out; the parking box.
//!
//! Detections are the simulator's truth with noise (corners 0.025 px, holes 3 mm) and
//! the rendered sweep (2 cm ranges), so the test measures the model, not the detectors.

use std::path::Path;

use roomcal::calibrate::identify::{identify, Identity};
use roomcal::calibrate::{
    calibrate_detecting, calibrate_with_clouds, corner_start, plane_points, CalibrateOptions,
    Calibration, CameraBoard, Detectors, FrameDetections, LidarBoard,
};
use roomcal::geometry::se3::so3_exp;
use roomcal::geometry::{Se3, Vec2, Vec3};
use roomcal::lidar::{Model, Point};
use roomcal::result::Status;
use roomcal::sim::visits::{simulate_visits, RoomTruth, Visit};
use roomcal::sim::{ImageNoise, Layout, SimOptions};
use roomcal::target::{Room, SurveySpec, SurveyedBoard, SurveyedPlane};

const CORNER_NOISE_PX: f64 = 0.025;
const HOLE_NOISE_M: f64 = 0.003;

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (2.0 * std::f64::consts::PI * self.uniform()).cos()
    }
    fn vec3(&mut self, s: f64) -> Vec3 {
        Vec3::new(self.normal(), self.normal(), self.normal()) * s
    }
}

fn base_room() -> Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

fn options(seed: u64, hfov_deg: f64, layout: Layout) -> SimOptions {
    SimOptions {
        seed,
        boards: Some(7),
        lidar: Some(Model::Pandar64),
        hfov_deg: Some(hfov_deg),
        layout,
        range_noise_m: 0.02,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    }
}

/// The survey a perfect (σ = 0) or a noisy survey would write.
fn survey(truth: &RoomTruth, noise: Option<(&mut Rng, f64, f64, f64, f64)>) -> SurveySpec {
    let (mut rng, bm, bdeg, pm, pdeg) = match noise {
        Some((r, a, b, c, d)) => (Some(r), a, b, c, d),
        None => (None, 0.0, 0.0, 0.0, 0.0),
    };
    let mut boards = heapless::Vec::new();
    for b in &truth.boards {
        let mut pose = b.to_se3();
        if let Some(r) = rng.as_deref_mut() {
            pose.rotation = so3_exp(&r.vec3(bdeg.to_radians())) * pose.rotation;
            pose.translation += r.vec3(bm);
        }
        let e = roomcal::result::Extrinsic::from_se3(&pose);
        let board = SurveyedBoard {
            rotation: e.rotation,
            translation: e.translation,
            sigma_m: bm,
            sigma_deg: bdeg,
        };
        boards.push(board).unwrap();
    }
    let mut planes = heapless::Vec::new();
    for p in &truth.planes {
        let (mut n, mut d) = (Vec3::from(p.normal), p.offset);
        if let Some(r) = rng.as_deref_mut() {
            n = so3_exp(&r.vec3(pdeg.to_radians())) * n;
            d += pm * r.normal();
        }
        let plane = SurveyedPlane {
            name: heapless::String::try_from(p.name.as_str()).unwrap(),
            normal: [n.x, n.y, n.z],
            offset: d,
            sigma_m: pm,
            sigma_deg: pdeg,
        };
        if planes.push(plane).is_err() {
            break;
        }
    }
    SurveySpec {
        visits: 16,
        frame: heapless::String::try_from("sim").unwrap(),
        boards,
        planes,
        covariance: Default::default(),
    }
}

/// `spec.covariance` of its own σ, every board and plane independent (a turn about a
/// plane's own normal has no variance); and, when `common_deg > 0`, every plane turned
/// together about the room's axes by that σ on top (one rotation for all of them).
fn with_covariance(mut spec: SurveySpec, common_deg: f64) -> SurveySpec {
    let n = spec.covariance_size();
    let mut c = nalgebra::DMatrix::<f64>::zeros(n, n);
    for (b, board) in spec.boards.iter().enumerate() {
        for i in 0..3 {
            c[(6 * b + i, 6 * b + i)] = board.sigma_deg.to_radians().powi(2);
            c[(6 * b + 3 + i, 6 * b + 3 + i)] = board.sigma_m.powi(2);
        }
    }
    let at = 6 * spec.boards.len();
    let across = |normal: [f64; 3]| {
        let n = Vec3::from(normal);
        nalgebra::Matrix3::identity() - n * n.transpose()
    };
    for (p, plane) in spec.planes.iter().enumerate() {
        let a = at + 4 * p;
        let turn = across(plane.normal) * plane.sigma_deg.to_radians().powi(2);
        for i in 0..3 {
            for j in 0..3 {
                c[(a + i, a + j)] += turn[(i, j)];
            }
        }
        c[(a + 3, a + 3)] = plane.sigma_m.powi(2);
        for (q, other) in spec.planes.iter().enumerate() {
            // Cov(P_p u, P_q u) = P_p σ² P_q for the common rotation u.
            let common =
                across(plane.normal) * across(other.normal) * common_deg.to_radians().powi(2);
            let b = at + 4 * q;
            for i in 0..3 {
                for j in 0..3 {
                    c[(a + i, b + j)] += common[(i, j)];
                }
            }
        }
    }
    spec.covariance = (0..n).map(|i| (0..=i).map(|j| c[(i, j)]).collect()).collect();
    spec
}

/// Perfect detectors with the stated noise; the LiDAR's holes of placeable boards.
fn detections(visit: &Visit, room: &Room, rng: &mut Rng) -> FrameDetections {
    let scene = &visit.scene;
    let lidar_to_camera = scene.truth.lidar_to_camera.as_ref().unwrap().to_se3();
    let cloud = scene.cloud.as_ref().unwrap();
    let mut frame = FrameDetections::default();
    for board in &scene.truth.boards {
        let corners = board
            .corners_px
            .iter()
            .map(|c| {
                Vec2::new(
                    c[0] + CORNER_NOISE_PX * rng.normal(),
                    c[1] + CORNER_NOISE_PX * rng.normal(),
                )
            })
            .collect();
        frame.camera.push(CameraBoard { corners, sigma_px: CORNER_NOISE_PX });
        if board.hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2 {
            let holes =
                board.holes_lidar.iter().map(|h| Vec3::from(*h) + rng.vec3(HOLE_NOISE_M)).collect();
            let to_lidar = lidar_to_camera.inverse().compose(&board.board_to_camera.to_se3());
            let points = cloud.iter().map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64));
            let plane = plane_points(&room.board, &to_lidar, 0.06, points);
            frame.lidar.push(LidarBoard { holes, sigma_m: HOLE_NOISE_M, plane });
        }
    }
    frame
}

struct Errors {
    fx_pct: f64,
    cx_px: f64,
    cy_px: f64,
    rot_deg: f64,
    t_mm: f64,
}

fn errors(run: &Calibration, visit: &Visit) -> Errors {
    let truth = &visit.scene.truth;
    let t = truth.lidar_to_camera.as_ref().unwrap();
    let got = run.result.lidar_to_camera.as_ref().unwrap();
    let (rot_deg, t_m) = t.difference(got);
    Errors {
        fx_pct: ((run.camera.fx - truth.camera.fx) / truth.camera.fx).abs() * 100.0,
        cx_px: (run.camera.cx - truth.camera.cx).abs(),
        cy_px: (run.camera.cy - truth.camera.cy).abs(),
        rot_deg,
        t_mm: t_m * 1000.0,
    }
}

fn line(what: &str, e: &Errors, run: &Calibration) {
    let u = &run.result.uncertainty;
    println!(
        "{what:<28} fx {:.4} % (σ {:.4}) cx {:.2} px (σ {:.2}) cy {:.2} px (σ {:.2}) rot {:.4}° (σ {:.4}) t {:.2} mm (σ {:.2})",
        e.fx_pct,
        u.fx / run.camera.fx * 100.0,
        e.cx_px,
        u.cx,
        e.cy_px,
        u.cy,
        e.rot_deg,
        u.rotation_deg,
        e.t_mm,
        u.translation_m * 1000.0
    );
}

fn within_3_sigma(e: &Errors, run: &Calibration, what: &str) {
    let u = &run.result.uncertainty;
    let fx_sigma = u.fx / run.camera.fx * 100.0;
    // Rotation and translation σ are worst-axis; errors are norms over 3 axes: 3σ·√3.
    let checks = [
        ("fx", e.fx_pct, 3.0 * fx_sigma),
        ("cx", e.cx_px, 3.0 * u.cx),
        ("cy", e.cy_px, 3.0 * u.cy),
        ("rotation", e.rot_deg, 3.0 * 3f64.sqrt() * u.rotation_deg),
        ("translation", e.t_mm, 3.0 * 3f64.sqrt() * u.translation_m * 1000.0),
    ];
    for (name, err, bound) in checks {
        assert!(err <= bound, "{what}: {name} error {err:.4} outside 3σ ({bound:.4})");
    }
}

fn run(room: &Room, frame: &FrameDetections, cloud: &[Point], free: bool) -> Calibration {
    let options = CalibrateOptions { free_boards: free, ..CalibrateOptions::default() };
    calibrate_with_clouds(room, std::slice::from_ref(frame), &[cloud], &options)
}

/// One simulated room, its survey visits' parkings aside, and a new vehicle: visit 1 of
/// a run whose seed did not make the survey (the survey is the room's truth).
fn new_vehicle() -> (Room, RoomTruth, Visit) {
    vehicle(2026)
}

/// [`new_vehicle`] in the room (and with the vehicle) simulator seed `seed` makes.
fn vehicle(seed: u64) -> (Room, RoomTruth, Visit) {
    // Seven boards leave the parking margin only on a wide enough lens: the first lens
    // and layout they fit on (printed).
    for hfov in [60.0, 65.0, 70.0, 80.0] {
        for layout in [Layout::Grid, Layout::Band] {
            if let Ok(sim) = simulate_visits(&base_room(), &options(seed, hfov, layout), 1) {
                println!("room: 7 boards, Pandar64, {hfov}° lens, {layout:?} layout");
                return (sim.room, sim.truth, sim.visits.into_iter().next().unwrap());
            }
        }
    }
    panic!("seven boards fit on no lens tried");
}

/// The surveyed solve weighs corners by the noise their own fit shows, not by the σ the
/// detector claims (about twice the corners' actual error on renders): a start from
/// corners with 0.025 px of noise reports 0.025 px, whatever σ the detections carry.
#[test]
fn a_start_reports_the_noise_its_corners_have_not_the_sigma_they_claim() {
    let (room, _, visit) = new_vehicle();
    for (claimed, seed) in [(CORNER_NOISE_PX, 1), (0.1, 2), (0.005, 3)] {
        let mut frame = detections(&visit, &room, &mut Rng(seed));
        for board in &mut frame.camera {
            board.sigma_px = claimed;
        }
        let start = corner_start(&room, std::slice::from_ref(&frame)).unwrap();
        let ratio = start.corner_noise_px / CORNER_NOISE_PX;
        println!("claimed σ {claimed} px: noise {:.4} px", start.corner_noise_px);
        // 7 boards × 35 corners leave 439 degrees of freedom: the estimate's own spread is
        // 3.4 %, so 15 % is 4σ.
        assert!(
            (ratio - 1.0).abs() < 0.15,
            "claimed {claimed}: noise {} px",
            start.corner_noise_px
        );
    }
}

#[test]
fn a_new_vehicle_in_the_surveyed_room_beats_free_boards() {
    let (mut room, truth, visit) = new_vehicle();
    let mut rng = Rng(7);
    let frame = detections(&visit, &room, &mut rng);
    let cloud = visit.scene.cloud.clone().unwrap();
    let free = run(&room, &frame, &cloud, true);
    assert_eq!(free.result.status, Status::Accepted, "{:?}", free.result.reason);
    let free_e = errors(&free, &visit);
    line("free boards", &free_e, &free);

    room.survey = Some(survey(&truth, None));
    let exact = run(&room, &frame, &cloud, false);
    assert_eq!(exact.result.status, Status::Accepted, "{:?}", exact.result.reason);
    assert!(exact.result.camera_in_room.is_some());
    let exact_e = errors(&exact, &visit);
    line("surveyed (exact)", &exact_e, &exact);

    let mut noise = Rng(11);
    room.survey = Some(survey(&truth, Some((&mut noise, 0.0005, 0.01, 0.002, 0.01))));
    let noisy = run(&room, &frame, &cloud, false);
    assert_eq!(noisy.result.status, Status::Accepted, "{:?}", noisy.result.reason);
    let noisy_e = errors(&noisy, &visit);
    line("surveyed (±0.5 mm/0.01°)", &noisy_e, &noisy);

    // The camera's pose in the room against the truth (room → camera inverted).
    let cir = exact.result.camera_in_room.as_ref().unwrap().to_se3();
    let truth_cir = visit.room_to_camera.inverse();
    let shift = (cir.translation - truth_cir.translation).norm();
    println!("camera_in_room (exact survey) off by {:.2} mm", shift * 1000.0);
    assert!(shift < 0.005, "camera_in_room off by {shift} m");

    within_3_sigma(&exact_e, &exact, "exact survey");
    within_3_sigma(&noisy_e, &noisy, "noisy survey");
    // The one-frame targets, on the exact survey (its bound is 5–10× below them).
    assert!(exact_e.rot_deg <= 0.03, "rotation {:.4}°", exact_e.rot_deg);
    assert!(exact_e.t_mm <= 3.0, "translation {:.2} mm", exact_e.t_mm);
    assert!(exact_e.fx_pct <= 0.05, "fx {:.4} %", exact_e.fx_pct);
    assert!(
        exact_e.cx_px <= 0.7 && exact_e.cy_px <= 0.7,
        "cx {:.2} cy {:.2}",
        exact_e.cx_px,
        exact_e.cy_px
    );
    // The survey's information shows: the surveyed model's reported σ is below the free one's.
    let (s, f) = (&noisy.result.uncertainty, &free.result.uncertainty);
    assert!(s.rotation_deg < f.rotation_deg && s.translation_m < f.translation_m);
}

/// In a room with a LiDAR, a surveyed run whose LiDAR places nothing (no board, no
/// surveyed plane: a sweep that saw none of them) is rejected naming the LiDAR, as a
/// free-board run is: accepted as intrinsics only it would put a calibration without the
/// extrinsic in force.
#[test]
fn a_surveyed_run_whose_lidar_places_nothing_is_rejected() {
    let (mut room, truth, visit) = new_vehicle();
    room.survey = Some(survey(&truth, None));
    let mut frame = detections(&visit, &room, &mut Rng(7));
    frame.lidar.clear();
    let nothing = run(&room, &frame, &[], false);
    assert_eq!(nothing.result.status, Status::Rejected);
    let reason = nothing.result.reason.unwrap();
    assert!(reason.contains("the LiDAR was not calibrated"), "{reason}");
    // Without a LiDAR in the room the same images are an intrinsics-only run, accepted.
    room.lidar = None;
    let camera_only = run(&room, &frame, &[], false);
    assert_eq!(camera_only.result.status, Status::Accepted, "{:?}", camera_only.result.reason);
    assert!(camera_only.result.lidar_to_camera.is_none());
}

/// A LiDAR that places no board by its holes (a VLP-16's lines are too sparse to resolve
/// them) still sees the boards' faces: the faces of the boards the camera sees, cut where
/// the survey puts them, and the room's planes place it, within 3σ of the truth; the gate
/// counts those targets against `min_lidar_boards` and, asked for more than there are,
/// refuses naming them.
#[test]
fn a_lidar_without_holes_is_placed_by_the_surveyed_faces_and_planes() {
    let (mut room, truth, visit) = new_vehicle();
    room.survey = Some(survey(&truth, None));
    let mut frame = detections(&visit, &room, &mut Rng(7));
    frame.lidar.clear();
    let cloud = visit.scene.cloud.clone().unwrap();
    let placed = run(&room, &frame, &cloud, false);
    assert_eq!(placed.result.status, Status::Accepted, "{:?}", placed.result.reason);
    assert!(placed.boards.iter().all(|b| b.holes_lidar.is_empty()));
    let faces = placed.boards.iter().filter(|b| b.seen_by_lidar()).count();
    assert!(
        faces >= 2 && placed.lidar_planes >= 1,
        "{faces} faces, {} planes",
        placed.lidar_planes
    );
    let e = errors(&placed, &visit);
    line("faces and planes, no holes", &e, &placed);
    let u = &placed.result.uncertainty;
    let root3 = 3f64.sqrt();
    assert!(e.rot_deg <= 3.0 * root3 * u.rotation_deg, "rotation {:.4}°", e.rot_deg);
    assert!(e.t_mm <= 3.0 * root3 * u.translation_m * 1e3, "translation {:.2} mm", e.t_mm);

    let targets = faces + placed.lidar_planes;
    room.quality.min_lidar_boards = targets as u32 + 1;
    let refused = run(&room, &frame, &cloud, false);
    assert_eq!(refused.result.status, Status::Rejected);
    let reason = refused.result.reason.unwrap();
    let expected = format!("the LiDAR registers against {targets} surveyed boards and planes");
    assert!(reason.contains(&expected), "{reason}");
}

/// A survey whose planes all turned together (the error a survey's planes share: each
/// visit's LiDAR places them, and its orientation against the boards is what a visit
/// knows least). Its covariance says so; its per-plane σ cannot. Held by the covariance,
/// the run finds the one turn in its own sweep and leaves the extrinsic's rotation less
/// pulled than when each plane is held by its own σ, and reports σ that cover the error.
#[test]
fn a_survey_covariance_holds_the_planes_common_turn_as_one() {
    let (mut room, truth, visit) = new_vehicle();
    let mut rng = Rng(5);
    let frame = detections(&visit, &room, &mut rng);
    let cloud = visit.scene.cloud.clone().unwrap();
    let turn = so3_exp(&Vec3::new(0.03, -0.02, 0.015).map(f64::to_radians));
    let mut spec = survey(&truth, None);
    for b in spec.boards.iter_mut() {
        (b.sigma_m, b.sigma_deg) = (0.0002, 0.003);
    }
    for p in spec.planes.iter_mut() {
        p.normal = (turn * Vec3::from(p.normal)).into();
        // Independent σ of 0.005°, 0.5 mm, and the common turn's 0.03° per axis on top.
        (p.sigma_m, p.sigma_deg) = (0.0005, (0.005f64.powi(2) + 0.03f64.powi(2)).sqrt());
    }
    room.survey = Some(spec.clone());
    let apart = run(&room, &frame, &cloud, false);
    let mut joint_spec = spec;
    for p in joint_spec.planes.iter_mut() {
        p.sigma_deg = 0.005;
    }
    joint_spec = with_covariance(joint_spec, 0.03);
    for (p, q) in joint_spec.planes.iter_mut().zip(&room.survey.as_ref().unwrap().planes) {
        p.sigma_deg = q.sigma_deg; // the file's σ are the marginals, as `roomcal survey` writes
    }
    room.survey = Some(joint_spec);
    let together = run(&room, &frame, &cloud, false);
    for (what, r) in [("planes apart", &apart), ("planes as one", &together)] {
        assert_eq!(r.result.status, Status::Accepted, "{what}: {:?}", r.result.reason);
        let e = errors(r, &visit);
        line(what, &e, r);
        within_3_sigma(&e, r, what);
    }
    let (a, t) = (errors(&apart, &visit), errors(&together, &visit));
    assert!(
        t.rot_deg < a.rot_deg,
        "rotation {:.4}° held as one, {:.4}° apart",
        t.rot_deg,
        a.rot_deg
    );
}

/// A covariance that says nothing sensible (hand-edited: variances of 10²⁰⁰ beside 10⁻³⁰⁰,
/// every entry valid on its own) loses no run: the result is finite and accepted, from the
/// joint solve or, when that cannot use it, from the per-block one with a note saying so.
#[test]
fn a_wild_survey_covariance_loses_no_run() {
    let (mut room, truth, visit) = new_vehicle();
    let mut rng = Rng(9);
    let frame = detections(&visit, &room, &mut rng);
    let cloud = visit.scene.cloud.clone().unwrap();
    let mut spec = survey(&truth, Some((&mut Rng(13), 0.0005, 0.01, 0.002, 0.01)));
    for b in spec.boards.iter_mut() {
        (b.sigma_m, b.sigma_deg) = (0.0005, 0.01);
    }
    for p in spec.planes.iter_mut() {
        (p.sigma_m, p.sigma_deg) = (0.002, 0.01);
    }
    let n = spec.covariance_size();
    spec.covariance = (0..n)
        .map(|i| {
            (0..=i)
                .map(|j| {
                    if i != j {
                        0.0
                    } else if i % 2 == 0 {
                        1e200
                    } else {
                        1e-300
                    }
                })
                .collect()
        })
        .collect();
    room.survey = Some(spec);
    let run = run(&room, &frame, &cloud, false);
    println!("status {:?} reason {:?} notes {:?}", run.result.status, run.result.reason, run.notes);
    assert_eq!(run.result.status, Status::Accepted, "{:?}", run.result.reason);
    let e = errors(&run, &visit);
    line("wild covariance", &e, &run);
    assert!(e.t_mm.is_finite() && e.rot_deg.is_finite() && run.camera.fx.is_finite());
    assert!(run.result.uncertainty.translation_m.is_finite());
}

#[test]
fn a_moved_board_is_named_and_left_out() {
    let (mut room, truth, visit) = new_vehicle();
    let mut rng = Rng(3);
    let frame = detections(&visit, &room, &mut rng);
    let cloud = visit.scene.cloud.clone().unwrap();
    // The survey says board 2 stands where it no longer is: shifted 2 cm, turned 1°,
    // knocked over (lying 0.6 m lower, turned 90° about its x axis).
    let cases: [(&str, Se3); 3] = [
        (
            "shifted 2 cm",
            Se3 { rotation: so3_exp(&Vec3::zeros()), translation: Vec3::new(0.02, 0.0, 0.0) },
        ),
        (
            "turned 1°",
            Se3 {
                rotation: so3_exp(&Vec3::new(0.0, 0.0, 1f64.to_radians())),
                translation: Vec3::zeros(),
            },
        ),
        (
            "knocked over",
            Se3 {
                rotation: so3_exp(&Vec3::new(std::f64::consts::FRAC_PI_2, 0.0, 0.0)),
                translation: Vec3::new(0.0, 0.0, -0.6),
            },
        ),
    ];
    // With the survey's covariance too: the run that names the board is the per-block one
    // before the joint solve.
    for ((what, moved), joint) in cases.iter().flat_map(|c| [(c, false), (c, true)]) {
        let (what, moved) = (*what, *moved);
        let mut spec = survey(&truth, None);
        for b in spec.boards.iter_mut() {
            (b.sigma_m, b.sigma_deg) = (0.0005, 0.01);
        }
        if joint {
            spec = with_covariance(spec, 0.0);
        }
        let b = &mut spec.boards[2];
        let pose = b.pose();
        // The move about the board's own centre (the room's vertical is z).
        let new = Se3 {
            rotation: moved.rotation * pose.rotation,
            translation: pose.translation + moved.translation,
        };
        let e = roomcal::result::Extrinsic::from_se3(&new);
        (b.rotation, b.translation) = (e.rotation, e.translation);
        room.survey = Some(spec);
        let run = run(&room, &frame, &cloud, false);
        let what = &format!("{what}{}", if joint { " (survey covariance)" } else { "" });
        println!(
            "{what}: status {:?} reason {:?} notes {:?}",
            run.result.status, run.result.reason, run.notes
        );
        let named = run.notes.iter().chain(run.result.reason.iter()).any(|n| n.contains("board 2"));
        assert!(
            named,
            "{what}: the moved board is not named: {:?} {:?}",
            run.notes, run.result.reason
        );
        if run.result.status == Status::Accepted {
            let e = errors(&run, &visit);
            line(what, &e, &run);
            within_3_sigma(&e, &run, what);
        }
    }
}

#[test]
fn identification_survives_parking_missing_and_half_turned_boards() {
    let (room, truth, visit) = new_vehicle();
    let surveyed: Vec<Se3> = truth.boards.iter().map(|b| b.to_se3()).collect();
    let spec = &room.board;
    assert!(roomcal::calibrate::identify::half_turn_symmetric(spec));
    let mut rng = Rng(99);
    let mut trials = 0;
    for _ in 0..200 {
        // A parking ±0.3 m / ±5° off this visit's, boards dropped and half-turned at random.
        let offset = Se3 {
            rotation: so3_exp(&Vec3::new(0.0, (rng.uniform() - 0.5) * 10f64.to_radians(), 0.0)),
            translation: Vec3::new(rng.uniform() - 0.5, 0.0, rng.uniform() - 0.5) * 0.6,
        };
        let room_to_camera = offset.compose(&visit.room_to_camera);
        let mut seen = Vec::new();
        let mut expected = Vec::new();
        for (k, b) in surveyed.iter().enumerate() {
            if rng.uniform() < 0.25 {
                continue;
            }
            let mut pose = room_to_camera.compose(b);
            // Corner-only poses are good to a few cm and a fraction of a degree.
            pose.translation += rng.vec3(0.01);
            pose.rotation = so3_exp(&rng.vec3(0.3f64.to_radians())) * pose.rotation;
            let turned = rng.uniform() < 0.3;
            if turned {
                pose = roomcal::calibrate::identify::oriented(&pose, true);
            }
            seen.push(pose);
            expected.push(Some(Identity { board: k, half_turned: turned }));
        }
        if seen.len() < 2 {
            continue;
        }
        trials += 1;
        match identify(spec, &surveyed, &seen) {
            Ok((ids, pose)) => {
                assert_eq!(ids, expected, "wrong identification");
                let off = (pose.translation - room_to_camera.translation).norm();
                let turn = (pose.rotation.transpose() * room_to_camera.rotation).trace();
                // A start for the solver: board poses noisy by 1 cm / 0.3° per axis carry
                // a few centimetres into it with three boards.
                assert!(
                    off < 0.1,
                    "room pose off by {off} m (trace {turn}), {} boards",
                    seen.len()
                );
            }
            // Refusing is allowed only where the arrangement is honestly ambiguous.
            Err(e) => panic!("refused with {} of 7 boards: {e}", seen.len()),
        }
    }
    assert!(trials > 150);
    // One board alone cannot be placed in a room of seven: refused, not guessed.
    assert!(identify(spec, &surveyed, &[room_to_camera_of(&visit).compose(&surveyed[0])]).is_err());
}

fn room_to_camera_of(visit: &Visit) -> Se3 {
    visit.room_to_camera
}

#[test]
fn the_gate_rejects_a_parking_outside_the_box() {
    let (mut room, truth, visit) = new_vehicle();
    let mut rng = Rng(5);
    let frame = detections(&visit, &room, &mut rng);
    let cloud = visit.scene.cloud.clone().unwrap();
    room.survey = Some(survey(&truth, None));
    room.quality.max_parking_offset_m = 0.001;
    let run = run(&room, &frame, &cloud, false);
    assert_eq!(run.result.status, Status::Rejected);
    let reason = run.result.reason.unwrap();
    assert!(reason.contains("from the nominal spot"), "{reason}");
}

/// The free-board model: one LiDAR board placed wrong (its holes turned
/// 20° in the board's plane about their centre, ~20 cm at the holes) is named, left out,
/// and the run solved again from the others.
#[test]
fn a_wrongly_placed_lidar_board_is_named_and_left_out() {
    wrongly_placed_board_left_out(true);
}

/// The same in the surveyed room: the board is named by its surveyed board, its LiDAR
/// placement left out (its corners still hold it) and the room solved again.
#[test]
fn in_a_surveyed_room_a_wrongly_placed_lidar_board_is_named_and_left_out() {
    wrongly_placed_board_left_out(false);
}

fn wrongly_placed_board_left_out(free: bool) {
    let (mut room, truth, visit) = new_vehicle();
    if !free {
        room.survey = Some(survey(&truth, None));
    }
    let mut rng = Rng(21);
    let mut frame = detections(&visit, &room, &mut rng);
    let cloud = visit.scene.cloud.clone().unwrap();
    assert!(frame.lidar.len() >= 4, "{} LiDAR boards", frame.lidar.len());
    let clean = run(&room, &frame, &cloud, free);
    assert!(clean.notes.is_empty(), "a clean run names no board: {:?}", clean.notes);
    let bad = &mut frame.lidar[1];
    let centre = bad.holes.iter().sum::<Vec3>() / bad.holes.len() as f64;
    let normal = (bad.holes[1] - bad.holes[0]).cross(&(bad.holes[2] - bad.holes[0])).normalize();
    let turn = so3_exp(&(normal * 20f64.to_radians()));
    for h in bad.holes.iter_mut() {
        *h = centre + turn * (*h - centre);
    }
    let run = run(&room, &frame, &cloud, free);
    println!("status {:?} reason {:?} notes {:?}", run.result.status, run.result.reason, run.notes);
    assert_eq!(run.notes.len(), 1, "{:?}", run.notes);
    // LiDAR board 1 is the second placeable board; camera boards follow the truth's order,
    // and so do the surveyed boards (the survey is the room's truth).
    let placeable: Vec<usize> = (0..visit.scene.truth.boards.len())
        .filter(|&b| {
            visit.scene.truth.boards[b].hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2
        })
        .collect();
    let expected = match free {
        true => format!("frame 0 board {}:", placeable[1]),
        false => format!("frame 0 surveyed board {}:", placeable[1]),
    };
    assert!(
        run.notes[0].contains(&expected) && run.notes[0].contains("left out"),
        "{:?}",
        run.notes
    );
    assert_eq!(run.result.status, Status::Accepted, "{:?}", run.result.reason);
    let e = errors(&run, &visit);
    let what = if free { "free, wrong board left out" } else { "surveyed, wrong board left out" };
    line(what, &e, &run);
    within_3_sigma(&e, &run, what);
}

/// The visit's camera boards (noise from `seed`, no LiDAR boards), its sweep, the room's
/// detectors, and the same frame with the LiDAR boards the global search places in the
/// sweep (the detectors' refusals are that search's).
fn global_search(
    room: &Room,
    visit: &Visit,
    seed: u64,
) -> (FrameDetections, Vec<Point>, Detectors, FrameDetections) {
    let mut frame = detections(visit, room, &mut Rng(seed));
    frame.lidar.clear();
    let cloud = visit.scene.cloud.clone().unwrap();
    let mut detectors = Detectors::new(room).unwrap();
    let mut global_frame = frame.clone();
    global_frame.lidar = detectors.detect_cloud(&cloud);
    (frame, cloud, detectors, global_frame)
}

/// Used boards with LiDAR holes.
fn lidar_boards(run: &Calibration) -> usize {
    run.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count()
}

/// The room's nominal mounting turned by `degrees` about a slanted axis and moved by `m`
/// along each axis.
fn mounting_off(room: &Room, degrees: f64, m: f64) -> Room {
    let mut room = room.clone();
    let lidar = room.lidar.as_mut().unwrap();
    let axis = Vec3::new(1.0, -2.0, 0.5).normalize();
    let r = so3_exp(&(axis * degrees.to_radians())) * lidar.rotation_matrix();
    for (i, row) in lidar.rotation.iter_mut().enumerate() {
        *row = [r[(i, 0)], r[(i, 1)], r[(i, 2)]];
    }
    for t in lidar.translation.iter_mut() {
        *t += m;
    }
    room
}

/// The calibration finding the LiDAR's boards itself where the surveyed room expects them
/// (`calibrate_detecting`: each identified camera board carried into the sweep by the
/// camera's room pose and the nominal mounting), against the global detector's boards
/// on the same sweeps: over eight rooms, each with a new vehicle (its mounting up to
/// 1.5° / 4 cm per axis off the nominal), and again with the room file's nominal mounting
/// 4° and 3 × 10 cm off (the boards the nominal misses are looked for again at the mounting
/// the found ones give). As many boards placed and paired as the global search, none
/// wrong (every result within 3σ of the truth).
#[test]
fn lidar_boards_are_found_where_the_survey_expects_them() {
    let (mut global_total, mut expected_total, mut off_total) = (0, 0, 0);
    for seed in 2026..2034 {
        let (mut room, truth, visit) = vehicle(seed);
        room.survey = Some(survey(&truth, None));
        let (frame, cloud, mut detectors, global_frame) = global_search(&room, &visit, seed);
        let global = run(&room, &global_frame, &cloud, false);
        let options = CalibrateOptions::default();
        let clouds: [&[Point]; 1] = [&cloud];
        let mut frames = [frame.clone()];
        let (expected, _) =
            calibrate_detecting(&room, &mut frames, &clouds, &mut detectors, &options);
        let off_room = mounting_off(&room, 4.0, 0.10);
        let mut frames_off = [frame.clone()];
        let (off, _) =
            calibrate_detecting(&off_room, &mut frames_off, &clouds, &mut detectors, &options);
        let counts = [lidar_boards(&global), lidar_boards(&expected), lidar_boards(&off)];
        println!(
            "seed {seed}: LiDAR boards paired: global {}, expected {}, nominal 4° / 17 cm off {}",
            counts[0], counts[1], counts[2]
        );
        (global_total, expected_total, off_total) =
            (global_total + counts[0], expected_total + counts[1], off_total + counts[2]);
        assert!(
            counts[1] >= counts[0],
            "seed {seed}: expected search placed fewer boards than the global one"
        );
        assert!(counts[2] >= counts[1], "seed {seed}: a nominal mounting 4° off lost boards");
        assert!(frames[0].lidar.len() >= counts[1], "seed {seed}: paired boards not reported");
        for (what, r) in [("expected", &expected), ("nominal off", &off)] {
            if global.result.status == Status::Accepted {
                assert_eq!(
                    r.result.status,
                    Status::Accepted,
                    "seed {seed} {what}: {:?}",
                    r.result.reason
                );
            } else {
                println!(
                    "seed {seed}: global search rejected: {:?}; {what}: {:?}",
                    global.result.reason, r.result.status
                );
            }
            if r.result.status == Status::Accepted {
                let e = errors(r, &visit);
                line(what, &e, r);
                within_3_sigma(&e, r, &format!("seed {seed} {what}"));
            }
        }
    }
    println!("LiDAR boards paired over 8 rooms: global {global_total}, expected {expected_total}, nominal off {off_total}");
    assert!(expected_total > 0);
}

/// Without a survey `calibrate_detecting` is the global detector and the free-board run.
#[test]
fn detecting_in_a_room_without_survey_is_the_global_search() {
    let (room, _, visit) = new_vehicle();
    let (frame, cloud, mut detectors, global_frame) = global_search(&room, &visit, 5);
    let refused = detectors.refused_in_cloud().to_vec();
    let global = run(&room, &global_frame, &cloud, true);
    let mut frames = [frame];
    let clouds: [&[Point]; 1] = [&cloud];
    let (detected, refused_here) = calibrate_detecting(
        &room,
        &mut frames,
        &clouds,
        &mut detectors,
        &CalibrateOptions::default(),
    );
    assert_eq!(frames[0].lidar, global_frame.lidar);
    assert_eq!(refused_here, vec![refused]);
    assert_eq!(detected.result, global.result);
}

/// A surveyed run that stops before it can carry a board into the sweep (no camera board)
/// still reports what the sweep holds: the global search's boards and refusals.
#[test]
fn a_surveyed_run_without_camera_boards_still_reports_the_sweeps_boards() {
    let (mut room, truth, visit) = new_vehicle();
    room.survey = Some(survey(&truth, None));
    let (mut frame, cloud, mut detectors, global_frame) = global_search(&room, &visit, 5);
    let refused = detectors.refused_in_cloud().to_vec();
    frame.camera.clear();
    let mut frames = [frame];
    let clouds: [&[Point]; 1] = [&cloud];
    let options = CalibrateOptions::default();
    let (run, refused_here) =
        calibrate_detecting(&room, &mut frames, &clouds, &mut detectors, &options);
    assert_eq!(run.result.status, roomcal::result::Status::Rejected);
    assert!(!global_frame.lidar.is_empty());
    assert_eq!(frames[0].lidar, global_frame.lidar);
    assert_eq!(refused_here, vec![refused]);
}
