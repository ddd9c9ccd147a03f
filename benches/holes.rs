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
    real_frame();
}

/// The same on the real OpenCalib frame (`../shared/data/holeboard-real`) when present.
fn real_frame() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/data/holeboard-real/2022-01-18-15-25-03-449.pcd"
    );
    let Ok(points) = roomcal::lidar::pcd::read(path) else {
        println!("holes (real): skipped, {path} is absent");
        return;
    };
    let mut holes = heapless::Vec::new();
    for h in [[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [0.3, 0.3]] {
        let _ = holes.push(h);
    }
    let spec = roomcal::target::BoardSpec {
        width: 1.2,
        height: 1.2,
        inner_corners: [2, 2],
        square: 0.05,
        hole_radius: 0.11,
        holes,
        count: 1,
        checker_offset: [0.0, 0.0],
    };
    let mut detector = HoleDetector::new(&spec, HoleConfig::default());
    let mut boards = Vec::new();
    detector.detect(&points, &mut boards);
    let runs = 20;
    let start = Instant::now();
    for _ in 0..runs {
        detector.detect(&points, &mut boards);
    }
    let ms = start.elapsed().as_secs_f64() * 1e3 / runs as f64;
    println!(
        "holes (real OpenCalib frame): {} points, {} board(s), {} refused: {ms:.1} ms per sweep",
        points.len(),
        boards.len(),
        detector.refused().len()
    );
}
