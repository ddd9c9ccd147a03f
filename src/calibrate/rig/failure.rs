//! Why a rig's composition or joint solve gave no result: a sensor the pair runs cannot
//! place relative to the first camera, or a joint solve that failed. Display is the text
//! the rig's result file and the operator see.

use core::fmt;

use super::super::surveyed::MOVED_BOARD_CHI2;
use crate::solve::SolveError;

/// Why the pair runs could not be composed, or the joint solve failed.
#[derive(Clone, Debug, PartialEq)]
pub enum RigFailure {
    /// A camera's run has no pose in the surveyed room.
    NoRoomPose { camera: String },
    /// Without a survey, a camera shares no LiDAR-placed board with the first camera.
    NoSharedLidarBoard { first_camera: String },
    /// A composed pair run has no LiDAR → camera.
    PairRunNoExtrinsic,
    /// A composed pair run has no room pose.
    PairRunNoRoomPose,
    /// A composed pair run failed (it has no covariance).
    PairRunFailed,
    /// A step of the joint solve failed.
    Solver(SolveError),
    /// A surveyed board beyond the survey's σ in the joint solve, after `after` was left out.
    BoardMoved { board: usize, chi2: f64, after: usize },
    /// A free-board joint problem was given a plane.
    FreePlanes,
}

impl fmt::Display for RigFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RigFailure::NoRoomPose { camera } => {
                write!(f, "camera `{camera}` has no pose in the room")
            }
            RigFailure::NoSharedLidarBoard { first_camera } => write!(
                f,
                "it shares no LiDAR-placed board with camera `{first_camera}` (without a survey, sensors are tied through boards both see)"
            ),
            RigFailure::PairRunNoExtrinsic => f.write_str("a pair run has no extrinsic"),
            RigFailure::PairRunNoRoomPose => f.write_str("a pair run has no room pose"),
            RigFailure::PairRunFailed => f.write_str("a pair run failed"),
            RigFailure::Solver(e) => write!(f, "the joint rig solve failed: {e}"),
            RigFailure::BoardMoved { board, chi2, after } => write!(
                f,
                "board {board} disagrees with the survey in the joint rig solve (χ² {chi2:.0} over its 6 survey σ, limit {MOVED_BOARD_CHI2}) after leaving out board {after}: it has moved, or the survey is stale"
            ),
            RigFailure::FreePlanes => f.write_str("free boards have no planes"),
        }
    }
}

impl From<SolveError> for RigFailure {
    fn from(e: SolveError) -> Self {
        RigFailure::Solver(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texts the rig's composition and joint solve gave as format strings.
    #[test]
    fn display_is_the_operators_text() {
        let cases = [
            (
                RigFailure::NoRoomPose { camera: "front".into() },
                "camera `front` has no pose in the room",
            ),
            (
                RigFailure::NoSharedLidarBoard { first_camera: "front".into() },
                "it shares no LiDAR-placed board with camera `front` (without a survey, sensors are tied through boards both see)",
            ),
            (
                RigFailure::BoardMoved { board: 2, chi2: 99.5, after: 5 },
                "board 2 disagrees with the survey in the joint rig solve (χ² 100 over its 6 survey σ, limit 36) after leaving out board 5: it has moved, or the survey is stale",
            ),
            (RigFailure::PairRunFailed, "a pair run failed"),
        ];
        for (failure, text) in cases {
            assert_eq!(failure.to_string(), text);
        }
    }
}
