//! Why one sensor of a rig was rejected: a check of the room's `[quality]` as the one-pair
//! gate words it, its composition's failure, or a check only a rig has. Display is the
//! sensor's `reason` in the rig's result file.

use core::fmt;

use super::super::Rejection;
use super::RigFailure;

/// Why one sensor of a rig was rejected.
#[derive(Clone, Debug, PartialEq)]
pub enum SensorRejection {
    /// A check of the room's `[quality]`, as the one-pair gate words it.
    Gate(Rejection),
    /// Its pose relative to the first camera could not be composed.
    Composition(RigFailure),
    /// A camera sees fewer boards (surveyed ones in a surveyed room) than the room needs.
    TooFewBoards { seen: usize, surveyed: bool, needed: usize },
    /// A LiDAR registers against fewer targets than `min_lidar_boards`: surveyed boards and
    /// planes (`surveyed`), else boards a camera sees placed by their holes.
    TooFewLidarTargets { count: usize, surveyed: bool, needed: u32 },
    /// The free boards do not tie it to the first camera.
    Untied,
    /// A LiDAR that places no board a camera sees.
    NoBoardSeen,
}

impl fmt::Display for SensorRejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SensorRejection::Gate(r) => r.fmt(f),
            SensorRejection::Composition(r) => r.fmt(f),
            SensorRejection::TooFewBoards { seen, surveyed, needed } => {
                let kind = if *surveyed { "surveyed " } else { "" };
                write!(f, "it sees {seen} {kind}boards, the room needs {needed}")
            }
            SensorRejection::TooFewLidarTargets { count, surveyed: true, needed } => write!(
                f,
                "it registers against {count} surveyed boards and planes, at least {needed} needed"
            ),
            SensorRejection::TooFewLidarTargets { count, surveyed: false, needed } => write!(
                f,
                "it places {count} boards a camera sees by their holes, at least {needed} needed"
            ),
            SensorRejection::Untied => f.write_str(
                "it shares no board with the first camera, directly or through another sensor",
            ),
            SensorRejection::NoBoardSeen => f.write_str("it places no board that a camera sees"),
        }
    }
}

impl From<Rejection> for SensorRejection {
    fn from(r: Rejection) -> Self {
        SensorRejection::Gate(r)
    }
}

impl From<RigFailure> for SensorRejection {
    fn from(r: RigFailure) -> Self {
        SensorRejection::Composition(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texts the rig's verdicts gave as format strings.
    #[test]
    fn display_is_the_operators_text() {
        let cases = [
            (
                SensorRejection::TooFewBoards { seen: 1, surveyed: true, needed: 3 },
                "it sees 1 surveyed boards, the room needs 3",
            ),
            (
                SensorRejection::TooFewBoards { seen: 1, surveyed: false, needed: 3 },
                "it sees 1 boards, the room needs 3",
            ),
            (
                SensorRejection::TooFewLidarTargets { count: 1, surveyed: true, needed: 2 },
                "it registers against 1 surveyed boards and planes, at least 2 needed",
            ),
            (
                SensorRejection::TooFewLidarTargets { count: 0, surveyed: false, needed: 2 },
                "it places 0 boards a camera sees by their holes, at least 2 needed",
            ),
            (
                SensorRejection::Untied,
                "it shares no board with the first camera, directly or through another sensor",
            ),
            (SensorRejection::NoBoardSeen, "it places no board that a camera sees"),
            (
                SensorRejection::Gate(Rejection::HoleRms { rms_px: 5.4321, limit_px: 5.0 }),
                "hole RMS 5.432 px exceeds 5 px",
            ),
            (
                SensorRejection::Composition(RigFailure::PairRunNoRoomPose),
                "a pair run has no room pose",
            ),
        ];
        for (verdict, text) in cases {
            assert_eq!(verdict.to_string(), text);
        }
    }
}
