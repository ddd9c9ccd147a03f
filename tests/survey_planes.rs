//! The plane finder (`detect::planes`) on simulated sweeps of a visited room: every room
//! surface the sweep really covers (floor, walls, ceiling) is found where the room truth
//! puts it, nothing board-sized is reported, and no cloud makes it panic.

use std::path::Path;

use roomcal::detect::planes::{find_planes, FoundPlane, PlaneConfig};
use roomcal::geometry::Vec3;
use roomcal::lidar::Point;
use roomcal::sim::visits::simulate_visits;
use roomcal::sim::{ImageNoise, SimOptions};

/// A truth plane carried into the LiDAR frame: unit normal away from the sensor, offset.
fn in_lidar(normal: Vec3, offset: f64, lidar_to_room: &roomcal::geometry::Se3) -> (Vec3, f64) {
    let n = lidar_to_room.rotation.transpose() * normal;
    let d = offset - normal.dot(&lidar_to_room.translation);
    if d < 0.0 {
        (-n, -d)
    } else {
        (n, d)
    }
}

fn matches(found: &FoundPlane, (n, d): (Vec3, f64), degrees: f64, metres: f64) -> bool {
    found.normal.dot(&n).clamp(-1.0, 1.0).acos().to_degrees() <= degrees
        && (found.offset - d).abs() <= metres
}

#[test]
fn every_room_surface_the_sweep_covers_is_found_and_no_board() {
    let mut room =
        roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
            .unwrap();
    (room.camera.width, room.camera.height) = (640, 400);
    let options = SimOptions {
        seed: 11,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let sim = simulate_visits(&room, &options, 3).unwrap();
    let mut checked = 0;
    for (k, visit) in sim.visits.iter().enumerate() {
        let truth = &visit.scene.truth;
        let lidar_to_camera = truth.lidar_to_camera.as_ref().unwrap().to_se3();
        let lidar_to_room = visit.room_to_camera.inverse().compose(&lidar_to_camera);
        let cloud = visit.scene.cloud.as_ref().unwrap();
        let found = find_planes(cloud, &PlaneConfig::default());
        let points: Vec<Vec3> =
            cloud.iter().map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64)).collect();
        let shell: Vec<(String, (Vec3, f64))> = sim
            .truth
            .planes
            .iter()
            .map(|p| (p.name.clone(), in_lidar(Vec3::from(p.normal), p.offset, &lidar_to_room)))
            .collect();
        for (name, (n, d)) in &shell {
            let covered = points.iter().filter(|p| (n.dot(p) - d).abs() < 0.05).count();
            if covered < 3000 {
                continue;
            }
            checked += 1;
            let hit = found.iter().find(|f| matches(f, (*n, *d), 0.3, 0.01));
            assert!(
                hit.is_some(),
                "visit {k}: the {name} ({covered} points) was not found: {found:?}"
            );
        }
        for f in &found {
            assert!(
                shell.iter().any(|(_, plane)| matches(f, *plane, 0.3, 0.01)),
                "visit {k}: a plane that is no room surface: {f:?}"
            );
            assert!(
                f.points.sigma_m < 0.03,
                "visit {k}: plane σ {} m for 2 cm range noise",
                f.points.sigma_m
            );
        }
        for (b, board) in truth.boards.iter().enumerate() {
            let to_lidar = lidar_to_camera.inverse().compose(&board.board_to_camera.to_se3());
            let plane =
                in_lidar(to_lidar.rotation.column(2).into_owned(), 0.0, &to_lidar.inverse());
            assert!(
                !found.iter().any(|f| matches(f, plane, 2.0, 0.1)),
                "visit {k}: board {b} reported as a room plane"
            );
        }
    }
    // The floor and at least the front and side walls in every visit.
    assert!(checked >= 9, "only {checked} room surfaces were covered by the sweeps");
}

fn point(x: f32, y: f32, z: f32) -> Point {
    Point { x, y, z, intensity: 0.0, ring: 0, time: 0.0 }
}

#[test]
fn no_cloud_makes_it_panic_and_junk_holds_no_plane() {
    let config = PlaneConfig::default();
    let same = vec![point(1.0, 2.0, 3.0); 5000];
    let line: Vec<Point> = (0..5000).map(|i| point(i as f32 * 0.01, 0.0, 0.0)).collect();
    let junk: Vec<Point> = (0..5000)
        .map(|i| match i % 4 {
            0 => point(f32::NAN, 1.0, 1.0),
            1 => point(f32::INFINITY, 0.0, 0.0),
            2 => point(0.0, 0.0, 0.0),
            _ => point(f32::MAX, -f32::MAX, 1.0),
        })
        .collect();
    for (what, cloud) in
        [("empty", Vec::new()), ("one point", same.clone()), ("a line", line), ("junk", junk)]
    {
        assert!(find_planes(&cloud, &config).is_empty(), "{what}: a plane in a cloud without one");
    }
    // Board-sized: a dense 1.2 × 1.0 m patch is not a room surface.
    let board: Vec<Point> = (0..6000)
        .map(|i| point(4.0, (i % 100) as f32 * 0.012 - 0.6, (i / 100) as f32 * 0.0167 - 0.5))
        .collect();
    assert!(find_planes(&board, &config).is_empty(), "a board reported as a room plane");
    // A 6 × 3 m wall is.
    let wall: Vec<Point> = (0..6000)
        .map(|i| point(5.0, (i % 100) as f32 * 0.06 - 3.0, (i / 100) as f32 * 0.05 - 1.5))
        .collect();
    let found = find_planes(&wall, &config);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        (found[0].normal.x - 1.0).abs() < 1e-9 && (found[0].offset - 5.0).abs() < 1e-5,
        "{:?}",
        found[0]
    );
}
