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

/// A ray-cast sweep of a floor 2 m below the sensor (range noise `sigma` along the beam),
/// with a wall 8 m ahead meeting it and a box's front face standing on it 4 m ahead: what
/// the plane finder sees where things stand on a floor.
fn floor_with_things_on_it(sigma: f64, seed: u64) -> Vec<Point> {
    let mut rng = roomcal::sim::rng::Rng::new(seed);
    let mut cloud = Vec::new();
    for line in 0..24 {
        let elevation = (-2.0 - 1.5 * line as f64).to_radians();
        for step in 0..1800 {
            let azimuth = (step as f64 * 0.2 - 180.0).to_radians();
            let d = Vec3::new(
                elevation.cos() * azimuth.cos(),
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
            );
            // First hit among the floor (z = −2), the wall (x = 8) and the front faces of
            // two boxes (x = 4 and x = −4, |y| < 3, z < −1.5).
            let mut range = -2.0 / d.z;
            if d.x > 1e-6 {
                range = range.min(8.0 / d.x);
            }
            for face in [4.0, -4.0] {
                let at = face / d.x;
                let p = d * at;
                if at > 0.0 && at < range && p.y.abs() < 3.0 && p.z < -1.5 {
                    range = at;
                }
            }
            if range > 40.0 {
                continue;
            }
            let p = d * (range + sigma * rng.normal());
            cloud.push(point(p.x as f32, p.y as f32, p.z as f32));
        }
    }
    cloud
}

#[test]
fn a_floor_is_measured_where_it_is_whatever_stands_on_it() {
    let (floor_normal, floor_offset) = (Vec3::new(0.0, 0.0, -1.0), 2.0);
    let cloud = floor_with_things_on_it(0.02, 7);
    let found = find_planes(&cloud, &PlaneConfig::default());
    let floor =
        found.iter().find(|p| p.normal.dot(&floor_normal) > 0.99).expect("the floor is found");
    // The term's own plane (its weighted fit), not only the reported one.
    let (n, d) = floor.points.fitted_plane_towards(&floor_normal);
    let offset_error = d - floor_offset;
    let tilt = n.dot(&floor_normal).clamp(-1.0, 1.0).acos().to_degrees();
    println!(
        "floor: offset off {:.3} mm, turned {tilt:.4}°, {} points",
        offset_error * 1e3,
        floor.points.count
    );
    assert!(offset_error.abs() < 0.1e-3, "floor offset off by {:.3} mm", offset_error * 1e3);
    assert!(tilt < 0.01, "floor turned by {tilt:.4}°");
    // What the test guards against: the wall's and the boxes' feet in the floor's 6 cm band
    // pull a plain fit of the band up by several times that.
    let band: Vec<Vec3> = (cloud.iter())
        .map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64))
        .filter(|p| (floor_normal.dot(p) - floor_offset).abs() < PlaneConfig::default().inlier_m)
        .collect();
    let plain =
        band.iter().map(|p| floor_normal.dot(p) - floor_offset).sum::<f64>() / band.len() as f64;
    println!("a plain fit of the band: offset off {:.3} mm", plain * 1e3);
    assert!(
        plain.abs() > 0.4e-3,
        "the scene no longer shows the feet's pull ({:.3} mm)",
        plain * 1e3
    );
}

#[test]
fn each_floor_point_counts_by_its_own_noise_along_the_normal() {
    use roomcal::solve::PlanePoints;
    // Range noise 2 cm along the beam: a floor point seen at incidence cosine c is c·2 cm off.
    let cloud = floor_with_things_on_it(0.02, 8);
    let normal = Vec3::new(0.0, 0.0, -1.0);
    let floor: Vec<Vec3> = (cloud.iter())
        .map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64))
        .filter(|p| p.z < -1.9 && p.x.abs() < 3.8)
        .collect();
    let summary = PlanePoints::along_beams(floor.iter().copied(), &normal, 2.0, 1e-4).unwrap();
    // The weight-1 σ is the range noise (normal incidence, with the 0.1 mm floor) …
    assert!((summary.sigma_m - 0.02).abs() < 0.002, "σ_r estimated {:.4} m", summary.sigma_m);
    // … and each point weighs σ₀² / (σ_r² cos² + floor²): the total is their sum.
    let reference2 = summary.sigma_m.powi(2);
    let range2 = reference2 - 1e-8;
    let expected: f64 = floor
        .iter()
        .map(|p| reference2 / (range2 * normal.dot(p).powi(2) / p.norm_squared() + 1e-8))
        .sum();
    assert!((summary.weight / expected - 1.0).abs() < 1e-9);
    assert!(summary.weight > 2.0 * floor.len() as f64, "grazing points should weigh more");
    // Points alike: every weight 1.
    let alike = PlanePoints::from_points(floor.iter().copied(), 0.02).unwrap();
    assert_eq!(alike.weight, floor.len() as f64);
}
