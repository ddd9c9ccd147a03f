//! The LiDAR board detector's workspace: after the first sweep of a size, detecting again
//! makes no heap allocation (a counting global allocator, enabled only on this test's
//! thread while the detector runs), and after `release_workspace` it finds the same boards
//! again. Also: a board-sized plane without holes (a crate face,
//! a door) is refused, not placed.

use std::path::Path;

use crate::counting_alloc::count_allocations;
use roomcal::detect::holes::{HoleConfig, HoleDetector, Refusal};
use roomcal::lidar::Point;
use roomcal::sim::{simulate, ImageNoise, SimOptions};

fn room() -> roomcal::target::Room {
    roomcal::room::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")))
        .unwrap()
}

#[test]
fn second_sweep_allocates_nothing() {
    let room = room();
    let options = SimOptions {
        seed: 7,
        image: ImageNoise { supersample: 1, ..ImageNoise::default() },
        ..SimOptions::default()
    };
    let cloud = simulate(&room, &options).unwrap().cloud.unwrap();
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut boards = Vec::new();
    detector.detect(&cloud, &mut boards);
    let first = boards.clone();
    assert!(!first.is_empty());
    let ((), n) = count_allocations(|| detector.detect(&cloud, &mut boards));
    println!("allocations in the second detect: {n}");
    assert_eq!(n, 0);
    assert_eq!(boards, first, "the same sweep gives the same boards");
    // Released (as the daemon does after a run), the workspace grows again on the next
    // sweep and the detector finds the same boards.
    detector.release_workspace();
    let ((), n) = count_allocations(|| detector.detect(&cloud, &mut boards));
    println!("allocations after a release: {n}");
    assert!(n > 0, "the released buffers are made again");
    assert_eq!(boards, first, "a released detector gives the same boards");
}

/// A solid 1.2 × 1.0 m plane 4 m ahead, no holes, covered by 80 rings 0.2° apart.
fn solid_plane() -> Vec<Point> {
    let mut points = Vec::new();
    for ring in 0..80 {
        let elevation = (-9.0 + 0.2 * ring as f64).to_radians();
        for k in -200..=200 {
            let azimuth = (0.2 * k as f64).to_radians();
            let dir =
                [elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin()];
            // The plane x = 4 m, its outline |y| ≤ 0.6, |z + 0.1| ≤ 0.5.
            let s = 4.0 / dir[0];
            let (y, z) = (s * dir[1], s * dir[2]);
            if y.abs() <= 0.6 && (z + 0.1).abs() <= 0.5 {
                points.push(Point {
                    x: 4.0,
                    y: y as f32,
                    z: z as f32,
                    ring: ring as u16,
                    ..Point::default()
                });
            }
        }
    }
    points
}

#[test]
fn a_plane_without_holes_is_refused() {
    let room = room();
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut boards = Vec::new();
    detector.detect(&solid_plane(), &mut boards);
    assert!(boards.is_empty(), "no board without holes");
    let refused = detector.refused();
    println!("refused: {refused:?}");
    assert_eq!(refused.len(), 1);
    assert!(matches!(
        refused[0].reason,
        Refusal::NoHolePattern { .. } | Refusal::NoHoleGaps { .. }
    ));
}
