//! The simulator's board layouts: the band layout puts the boards where a Pandar64's
//! dense 8° band places their holes (at least two holes crossed by two or more scan
//! lines), which the grid layout mostly does not, and a band layout without a LiDAR is
//! a clear error.

use std::path::Path;

use roomcal::sim::{simulate, ImageNoise, Layout, SimError, SimOptions};

fn room() -> roomcal::target::Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

fn placeable(layout: Layout, seed: u64) -> usize {
    let options = SimOptions {
        seed,
        layout,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let scene = simulate(&room(), &options).unwrap();
    assert_eq!(scene.truth.boards.len(), 6);
    let complete = scene.truth.boards.iter().all(|b| b.corners_px.len() == 35);
    assert!(complete, "seed {seed}: every board is in the image");
    scene
        .truth
        .boards
        .iter()
        .filter(|b| b.hole_scan_lines.iter().filter(|&&n| n >= 2).count() >= 2)
        .count()
}

#[test]
fn band_layout_places_most_boards_in_the_lidar_band() {
    let (mut band, mut grid) = (0, 0);
    for seed in [1, 2, 3] {
        let (b, g) = (placeable(Layout::Band, seed), placeable(Layout::Grid, seed));
        println!("seed {seed}: placeable boards, band {b}, grid {g}");
        assert!(b >= 4, "seed {seed}: only {b} boards placeable in the band layout");
        band += b;
        grid += g;
    }
    assert!(band > grid, "band {band} vs grid {grid}");
}

#[test]
fn band_layout_needs_a_lidar() {
    let mut room = room();
    room.lidar = None;
    let options = SimOptions { layout: Layout::Band, ..SimOptions::default() };
    let err = simulate(&room, &options).unwrap_err();
    assert!(matches!(err, SimError::BandWithoutLidar));
    assert!(err.to_string().contains("no [lidar]"), "{err}");
}

/// A room for a rig whose cameras' fields differ (`SimOptions::ring`, `simulate
/// --ring-boards 6 --inner-fov 60 --ring-turn 8`, config/wide-room.toml surveyed by 90°
/// cameras): the rig's 60° camera sees the room's six boards whole (a ring board may reach
/// into its view), its 90° camera, turned 8° left, every board whole but the ring's column
/// the parking pushed off an edge; a visit's 90° camera the same.
#[test]
fn a_ring_room_shows_the_narrow_camera_its_boards_and_the_wide_one_the_ring_too() {
    use roomcal::sim::rig::simulate_rig_in;
    use roomcal::sim::visits::simulate_visits;
    use roomcal::sim::Ring;
    let path = |p: &str| Path::new(env!("CARGO_MANIFEST_DIR")).join(p);
    let room = roomcal::room::load(&path("config/wide-room.toml")).unwrap();
    let rig = roomcal::rig::load(&path("config/rig.toml")).unwrap();
    let whole = |corners: &[[f64; 2]]| {
        corners.len() == 35
            && corners
                .iter()
                .all(|p| (0.0..1920.0).contains(&p[0]) && (0.0..1200.0).contains(&p[1]))
    };
    for seed in 1..=4 {
        let options = SimOptions {
            seed,
            image: ImageNoise { supersample: 1, ..ImageNoise::default() },
            ring: Some(Ring { boards: 6, inner_hfov_deg: 60.0, turn_left_deg: 8.0 }),
            ..SimOptions::default()
        };
        let visits = simulate_visits(&room, &options, 1).unwrap();
        assert_eq!(visits.room.board.count, 12, "the room file written counts the ring");
        let sim = simulate_rig_in(&room, &rig, &options, Some(&visits.layout)).unwrap();
        let seen = |name: &str| -> Vec<bool> {
            sim.truth.sensors[name].boards.iter().map(|b| whole(&b.corners_px)).collect()
        };
        let (front, wide) = (seen("front"), seen("wide"));
        let visit = &visits.visits[0].scene.truth.boards;
        let in_visit: Vec<bool> = visit.iter().map(|b| whole(&b.corners_px)).collect();
        println!("seed {seed}: front {front:?}\n        wide  {wide:?}, visit {in_visit:?}");
        assert_eq!(front.len(), 12);
        assert!(front[..6].iter().all(|&w| w), "seed {seed}: the 60° camera sees the room's");
        // The ring reaches the edges of the 90° camera's view: a vehicle parked off
        // (±0.3 m, ±5°) loses the column on one side.
        assert!(wide[..6].iter().all(|&w| w), "seed {seed}: the 90° camera, the room's");
        assert!(wide[6..].iter().filter(|&&w| w).count() >= 3, "seed {seed}: the ring");
        // The visits look straight ahead, the ring 8° left of it: a visit parked off may
        // lose the ring's left column, which the other visits of a survey see.
        assert!(in_visit[..6].iter().all(|&w| w), "seed {seed}: the visit's 90° camera");
        assert!(in_visit[6..].iter().filter(|&&w| w).count() >= 3, "seed {seed}: the ring");
    }
}

/// A ring is laid out around a room's vehicles or a rig; a single scene refuses it.
#[test]
fn a_single_scene_refuses_a_ring() {
    let options = SimOptions {
        ring: Some(roomcal::sim::Ring { boards: 4, inner_hfov_deg: 60.0, turn_left_deg: 0.0 }),
        ..SimOptions::default()
    };
    let err = simulate(&room(), &options).unwrap_err();
    assert!(matches!(err, SimError::RingWithoutVehicles), "{err}");
    assert!(err.to_string().contains("--visits or --rig"), "{err}");
}
