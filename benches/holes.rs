//! Timing of the LiDAR board detector: one simulated Pandar64 sweep (≈115k points, six
//! boards, floor, walls, clutter), detected repeatedly with one reused workspace; the
//! mean is printed next to the sensor's 100 ms sweep period. Plain timed loop
//! (`cargo bench --bench holes`).

use std::path::Path;
use std::time::Instant;

use roomcal::detect::holes::{HoleConfig, HoleDetector};
use roomcal::sim::{simulate, ImageNoise, SimOptions};

fn main() {
    let room =
        roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
            .expect("config/room.toml");
    let options = SimOptions {
        seed: 7,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let scene = simulate(&room, &options).expect("simulate");
    let cloud = scene.cloud.expect("a LiDAR sweep");
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut boards = Vec::new();
    detector.detect(&cloud, &mut boards); // warm-up: buffers grow to size here
    let runs = 20;
    let start = Instant::now();
    for _ in 0..runs {
        detector.detect(&cloud, &mut boards);
    }
    let ms = start.elapsed().as_secs_f64() * 1e3 / runs as f64;
    println!(
        "holes: {} points, {} boards placed, {} refused: {ms:.1} ms per sweep ({:.0}% of the 100 ms sweep period)",
        cloud.len(),
        boards.len(),
        detector.refused().len(),
        ms
    );
}
