//! The surveyed room's simulator (`sim::visits`): the room stays put while vehicles come
//! and go — every visit's truth is the room's truth seen through that visit's parking
//! pose and mounting, the floor stays where the room put it, and a seed fixes the bytes.

use std::path::Path;

use roomcal::geometry::{Se3, Vec3};
use roomcal::sim::visits::{simulate_visits, simulate_visits_from, write_visits, Visits};
use roomcal::sim::{ImageNoise, SimOptions};

use crate::common::scratch::Scratch;

/// The design's room with a small camera, so that rendering stays cheap.
fn small_room() -> roomcal::target::Room {
    let mut room =
        roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
            .unwrap();
    room.camera.width = 640;
    room.camera.height = 400;
    room
}

fn options(seed: u64) -> SimOptions {
    SimOptions {
        seed,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    }
}

fn visits(seed: u64, count: usize) -> Visits {
    simulate_visits(&small_room(), &options(seed), count).unwrap()
}

fn assert_same_motion(a: &Se3, b: &Se3, what: &str) {
    let rot = (a.rotation - b.rotation).abs().max();
    let shift = (a.translation - b.translation).norm();
    assert!(
        rot < 1e-9 && shift < 1e-9,
        "{what}: rotation off {rot:e}, translation off {shift:e} m"
    );
}

#[test]
fn every_visit_sees_the_one_room_through_its_own_parking_pose() {
    let sim = visits(5, 3);
    let spec = &sim.room.board;
    for (k, visit) in sim.visits.iter().enumerate() {
        let truth = &visit.scene.truth;
        let lidar_to_camera = truth.lidar_to_camera.as_ref().unwrap().to_se3();
        for (b, board) in truth.boards.iter().enumerate() {
            let in_room = sim.truth.boards[b].to_se3();
            let expected = visit.room_to_camera.compose(&in_room);
            assert_same_motion(
                &board.board_to_camera.to_se3(),
                &expected,
                &format!("visit {k} board {b}"),
            );
            // Hole centres in the LiDAR frame follow from the same chain.
            let to_lidar = lidar_to_camera.inverse().compose(&expected);
            for (h, seen) in board.holes_lidar.iter().enumerate() {
                let d = (Vec3::from(*seen) - to_lidar.act(&spec.hole(h))).norm();
                assert!(d < 1e-9, "visit {k} board {b} hole {h} off by {d} m");
            }
        }
    }
    let parked: Vec<Vec3> =
        sim.visits.iter().map(|v| v.room_to_camera.inverse().translation).collect();
    assert!(
        (parked[0] - parked[1]).norm() > 1e-3 && (parked[1] - parked[2]).norm() > 1e-3,
        "{parked:?}"
    );
}

#[test]
fn the_floor_stays_where_the_room_put_it() {
    let sim = visits(6, 2);
    let floor = sim.truth.planes.iter().find(|p| p.name == "floor").unwrap();
    let normal = Vec3::from(floor.normal);
    for (k, visit) in sim.visits.iter().enumerate() {
        let truth = &visit.scene.truth;
        let lidar_to_room = visit
            .room_to_camera
            .inverse()
            .compose(&truth.lidar_to_camera.as_ref().unwrap().to_se3());
        let cloud = visit.scene.cloud.as_ref().unwrap();
        // Points well below the boards' lowest edge are floor (or crates standing on it).
        let on_floor = cloud
            .iter()
            .map(|p| lidar_to_room.act(&Vec3::new(p.x as f64, p.y as f64, p.z as f64)))
            .filter(|p| (normal.dot(p) - floor.offset).abs() < 0.08)
            .count();
        assert!(on_floor > 2000, "visit {k}: only {on_floor} points on the room's floor");
    }
}

#[test]
fn the_same_seed_writes_the_same_bytes() {
    let dir = Scratch::new("survey-sim");
    let (a, b) = (dir.join("a"), dir.join("b"));
    write_visits(&visits(7, 2), &a).unwrap();
    write_visits(&visits(7, 2), &b).unwrap();
    for file in [
        "room-truth.json",
        "room.toml",
        "visit-01/image.png",
        "visit-02/cloud.pcd",
        "visit-02/truth.json",
    ] {
        let (x, y) = (std::fs::read(a.join(file)).unwrap(), std::fs::read(b.join(file)).unwrap());
        assert!(x == y, "{file} differs between two runs of one seed");
    }
    let other = visits(8, 1);
    assert_ne!(other.truth.boards, visits(7, 1).truth.boards, "another seed, another room");
}

#[test]
fn later_visits_alone_are_the_same_visits_a_longer_run_makes() {
    let all = visits(11, 3);
    let mut later = Vec::new();
    let sim = simulate_visits_from(&small_room(), &options(11), 1, 2, |k, visit| {
        later.push((k, visit));
        Ok(())
    })
    .unwrap();
    assert_eq!(sim.truth.boards, all.truth.boards, "the same room");
    assert_eq!(later.iter().map(|(k, _)| *k).collect::<Vec<_>>(), [1, 2], "numbered as in the run");
    for (k, visit) in &later {
        let whole = &all.visits[*k];
        assert_same_motion(&visit.room_to_camera, &whole.room_to_camera, &format!("visit {k}"));
        assert!(visit.scene.image == whole.scene.image, "visit {k}: the same image");
        assert!(visit.scene.cloud == whole.scene.cloud, "visit {k}: the same sweep");
    }
    let err =
        simulate_visits_from(&small_room(), &options(11), 990, 20, |_, _| Ok(())).unwrap_err();
    assert!(err.to_string().contains("--first-visit 991"), "{err}");
}

#[test]
fn zero_visits_is_an_error_that_says_so() {
    let err = simulate_visits(&small_room(), &options(1), 0).unwrap_err();
    assert!(err.to_string().contains("visits"), "{err}");
}

#[test]
fn a_standing_visit_has_its_further_frames_and_the_same_first_frame() {
    let one = visits(9, 2);
    let standing =
        simulate_visits(&small_room(), &SimOptions { standing_frames: 3, ..options(9) }, 2)
            .unwrap();
    for (a, b) in one.visits.iter().zip(&standing.visits) {
        assert!(a.scene.more.is_empty());
        assert_eq!(b.scene.more.len(), 2, "frames 2 and 3");
        assert_eq!(a.scene.image, b.scene.image, "the first frame does not depend on the others");
        assert_eq!(a.scene.cloud, b.scene.cloud);
        for more in &b.scene.more {
            // The same scene with new sensor noise: not the same bytes, nearly the same picture.
            assert_ne!(more.image, b.scene.image);
            let mean_diff = more
                .image
                .iter()
                .zip(&b.scene.image)
                .map(|(x, y)| (*x as f64 - *y as f64).abs())
                .sum::<f64>()
                / more.image.len() as f64;
            assert!(mean_diff < 5.0, "mean grey difference {mean_diff:.2}");
            let cloud = more.cloud.as_ref().unwrap();
            assert!(cloud.len() * 10 > b.scene.cloud.as_ref().unwrap().len() * 9);
        }
    }
}
