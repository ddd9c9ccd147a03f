//! Matching LiDAR detections to the simulator's truth, shared by the hole-detector tests.

use roomcal::detect::holes::LidarBoard;
use roomcal::geometry::Vec3;
use roomcal::sim::BoardTruth;

/// The truth board this detection is, with the per-hole errors (m), when every one of
/// its holes is within 10 cm of that board's.
pub fn best_truth(board: &LidarBoard, truth: &[BoardTruth]) -> Option<(usize, Vec<f64>)> {
    truth.iter().enumerate().find_map(|(i, t)| {
        let err: Vec<f64> = board
            .holes
            .iter()
            .zip(&t.holes_lidar)
            .map(|(h, th)| (h - Vec3::new(th[0], th[1], th[2])).norm())
            .collect();
        err.iter().all(|&e| e < 0.1).then_some((i, err))
    })
}
