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
