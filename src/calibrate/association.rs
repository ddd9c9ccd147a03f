//! Association: every LiDAR board paired with a camera board of the same frame by carrying
//! its hole centres into the camera with the nominal mounting, re-estimated under a
//! tightening gate; the LiDAR's hole order resolved through the camera board's pose.

use super::{CameraBoard, FrameDetections};
use crate::geometry::{Se3, Vec3};
use crate::solve::{init::kabsch_from_pairs, PlanePoints};

/// A LiDAR board paired with camera board observation, holes in the room's order.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Pair {
    pub(super) holes_lidar: Vec<Vec3>,
    pub(super) sigma_m: f64,
    pub(super) plane: Option<PlanePoints>,
    /// Which of its frame's LiDAR boards it is.
    pub(super) lidar_index: usize,
}

pub(super) fn lidar_nominal(lidar: &crate::target::LidarSpec) -> Se3 {
    Se3 { rotation: lidar.rotation_matrix(), translation: lidar.translation_vector() }
}

/// Gates (m) between a LiDAR board's hole centroid carried into the camera and the
/// camera board's: loose for the nominal mounting, then tight once re-estimated.
const ASSOCIATION_GATES_M: [f64; 3] = [1.0, 0.3, 0.1];

/// Pairs LiDAR boards with camera boards (per frame) and orders their holes; returns,
/// per camera board observation, its pair if any.
pub(super) fn associate(
    nominal: &Se3,
    frames: &[FrameDetections],
    camera_boards: &[(u32, &CameraBoard)],
    poses: &[Se3],
    holes_board: &[Vec3],
) -> Vec<Option<Pair>> {
    let centroid_board = holes_board.iter().sum::<Vec3>() / holes_board.len().max(1) as f64;
    let mut extrinsic = *nominal;
    let mut pairs = vec![None; camera_boards.len()];
    for gate in ASSOCIATION_GATES_M {
        pairs = match_boards(
            &extrinsic,
            frames,
            camera_boards,
            poses,
            holes_board,
            &centroid_board,
            gate,
        );
        match paired_extrinsic(&pairs, poses, holes_board) {
            Some(better) => extrinsic = better,
            None => break,
        }
    }
    pairs
}

/// LiDAR → camera from the paired boards' holes (Kabsch; `poses[i]` is camera board `i`'s
/// board → camera), `None` when they do not fix it.
pub(super) fn paired_extrinsic(
    pairs: &[Option<Pair>],
    poses: &[Se3],
    holes_board: &[Vec3],
) -> Option<Se3> {
    let correspondences = pairs.iter().zip(poses).flat_map(|(pair, pose)| {
        pair.iter()
            .flat_map(|p| p.holes_lidar.iter().zip(holes_board).map(|(l, h)| (*l, pose.act(h))))
    });
    kabsch_from_pairs(correspondences).ok()
}

/// One round of pairing under `extrinsic`: greedy, nearest centroids first, within `gate`.
fn match_boards(
    extrinsic: &Se3,
    frames: &[FrameDetections],
    camera_boards: &[(u32, &CameraBoard)],
    poses: &[Se3],
    holes_board: &[Vec3],
    centroid_board: &Vec3,
    gate: f64,
) -> Vec<Option<Pair>> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (c, ((frame, _), pose)) in camera_boards.iter().zip(poses).enumerate() {
        let expected = pose.act(centroid_board);
        for (l, lidar) in frames[*frame as usize].lidar.iter().enumerate() {
            if lidar.holes.len() != holes_board.len() {
                continue;
            }
            let seen = lidar.holes.iter().map(|h| extrinsic.act(h)).sum::<Vec3>()
                / lidar.holes.len() as f64;
            let distance = (seen - expected).norm();
            if distance <= gate {
                candidates.push((distance, c, l));
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut pairs: Vec<Option<Pair>> = vec![None; camera_boards.len()];
    let mut lidar_taken: Vec<(u32, usize)> = Vec::new();
    for (_, c, l) in candidates {
        let frame = camera_boards[c].0;
        if pairs[c].is_some() || lidar_taken.contains(&(frame, l)) {
            continue;
        }
        let lidar = &frames[frame as usize].lidar[l];
        if let Some(holes_lidar) = order_holes(extrinsic, &poses[c], &lidar.holes, holes_board) {
            pairs[c] = Some(Pair {
                holes_lidar,
                sigma_m: lidar.sigma_m,
                plane: lidar.plane,
                lidar_index: l,
            });
            lidar_taken.push((frame, l));
        }
    }
    pairs
}

/// The LiDAR's holes in the room's order: each carried into the board frame and given
/// to the nearest model hole; `None` unless that is one-to-one.
fn order_holes(
    extrinsic: &Se3,
    pose: &Se3,
    holes: &[Vec3],
    holes_board: &[Vec3],
) -> Option<Vec<Vec3>> {
    let to_board = pose.inverse();
    let mut ordered = vec![None; holes_board.len()];
    for h in holes {
        let in_board = to_board.act(&extrinsic.act(h));
        let nearest = (0..holes_board.len()).min_by(|&a, &b| {
            (holes_board[a] - in_board).norm().total_cmp(&(holes_board[b] - in_board).norm())
        })?;
        if ordered[nearest].replace(*h).is_some() {
            return None;
        }
    }
    ordered.into_iter().collect()
}
