//! The surveyed room seen by one camera and one LiDAR: the rig problem ([`super::rig`])
//! with one camera, one LiDAR and one frame. Its unknowns are the intrinsics, the LiDAR →
//! camera extrinsic (the LiDAR's mounting to the first camera, which is the camera), ONE
//! room → camera pose (the vehicle's parking; a standing vehicle's frames share it) and
//! one pose per room *block* — a surveyed board or a surveyed plane — held near the survey
//! by a prior of the survey's σ. The rig problem solves it ([`super::rig::solve_rig`]) and
//! gives its σ ([`super::rig::rig_covariance`]); nothing here is a second solver.
//!
//! Shared parameters (21, the rig's order): intrinsics (9), extrinsic `[δω δt]` (6),
//! room → camera `[δω δt]` (6).

use super::problem::BoardObservation;
use super::rig::{rig_shared, RigLayout, RigObservation, RigParams, RigProblem, RigReport};
use super::{EXT_ROTATION, SHARED};

/// Where the pair's unknowns sit: one camera, one LiDAR, one frame.
pub const ROOM_LAYOUT: RigLayout = RigLayout { cameras: 1, lidars: 1, frames: 1 };
/// Shared parameters of the room problem: intrinsics, extrinsic, room → camera pose.
pub const ROOM_SHARED: usize = rig_shared(1, 1, 1);
/// Index of the room → camera rotation in the shared vector (translation follows).
pub const ROOM_ROTATION: usize = ROOM_LAYOUT.frame_pose(0);

/// The surveyed room seen by one camera and one LiDAR (`B`: most blocks and observations).
pub type RoomProblem<'a, const B: usize> = RigProblem<'a, 1, 1, 1, B, B, ROOM_SHARED>;
/// The room problem's estimate: `cameras[0]`, `lidar_to_first[0]` (LiDAR → camera),
/// `room_to_first[0]` (room → camera) and the blocks.
pub type RoomParams<K, const B: usize> = RigParams<K, 1, 1, 1, B>;
/// What a room solve did.
pub type RoomReport = RigReport<1, 1>;

/// What one frame measured of block `block`, as the room problem takes it: corners and
/// holes are the camera's, holes and points the LiDAR's.
pub fn pair_observation(block: usize, observation: BoardObservation<'_>) -> RigObservation<'_> {
    let seen = !observation.corners.is_empty() || !observation.holes_lidar.is_empty();
    let measured = !observation.holes_lidar.is_empty() || observation.plane.is_some();
    RigObservation {
        frame: 0,
        block,
        camera: seen.then_some(0),
        lidar: measured.then_some(0),
        observation,
    }
}

// The pair's layout is the free-board problem's shared vector followed by the room pose.
const _: () = assert!(
    ROOM_LAYOUT.intrinsics(0) == 0
        && ROOM_LAYOUT.lidar_pose(0) == EXT_ROTATION
        && ROOM_ROTATION == SHARED
        && ROOM_SHARED == SHARED + 6
);
