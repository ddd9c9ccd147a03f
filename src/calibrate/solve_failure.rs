//! Why a one-pair run could not be solved (a rejected run with no result values), and the
//! note naming a board whose LiDAR placement was left out. Display is the text the result
//! file's `reason` and the operator see.

use core::fmt;

use super::identify::IdentifyError;
use super::surveyed::MOVED_BOARD_CHI2;
use crate::solve::SolveError;

/// Why a run's solve (the free-board model's or the surveyed room's) gave no calibration.
#[derive(Clone, Debug, PartialEq)]
pub enum SolveFailure {
    /// No image holds a complete checkerboard.
    NoCompleteBoard,
    /// The one image of a frame holds no complete checkerboard.
    NoCompleteBoardInImage,
    /// A solver step failed.
    Solver(SolveError),
    /// No start for the intrinsics converged: the last seed's error (`None`: no seed).
    NoStart(Option<SolveError>),
    /// The room has a LiDAR and none of its boards paired with a camera board.
    NoLidarPair,
    /// A frame's camera boards could not be identified against the survey.
    Unidentified { frame: u32, error: IdentifyError },
    /// No frame had a board to identify.
    NoBoardIdentified,
    /// A surveyed board's solved pose lies beyond [`MOVED_BOARD_CHI2`] of its survey σ
    /// (`after`: the board already left out for the same reason).
    BoardMoved { board: usize, chi2: f64, after: Option<usize> },
    /// The solved mounting pairs more of the LiDAR's hole-placed boards (`pairs`) than the
    /// run used (`used`), after the run was solved again with them once.
    MountingDisagrees { pairs: usize, used: usize },
    /// The run solved again without a board's LiDAR placement failed.
    AfterLeavingOut { error: Box<SolveFailure>, misplaced: MisplacedHoles },
}

/// A board whose LiDAR hole RMS stands out from the other boards' (its placement was left
/// out and the run solved again): the note the run gives the operator.
#[derive(Clone, Debug, PartialEq)]
pub struct MisplacedHoles {
    pub frame: u32,
    /// The board's index among its frame's used boards, or its surveyed board (`surveyed`).
    pub board: usize,
    pub surveyed: bool,
    /// Its LiDAR hole RMS and the other boards' median (px).
    pub rms_px: f64,
    pub median_px: f64,
}

impl fmt::Display for SolveFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SolveFailure::NoCompleteBoard => {
                f.write_str("no complete checkerboard was detected in any image")
            }
            SolveFailure::NoCompleteBoardInImage => {
                f.write_str("no complete checkerboard was detected in the image")
            }
            SolveFailure::Solver(e) => write!(f, "the solver failed: {e}"),
            SolveFailure::NoStart(None) => {
                f.write_str("no start for the intrinsics converged (no seed)")
            }
            SolveFailure::NoStart(Some(e)) => {
                write!(f, "no start for the intrinsics converged (the solver failed: {e})")
            }
            SolveFailure::NoLidarPair => {
                f.write_str("no LiDAR board could be paired with a camera board")
            }
            SolveFailure::Unidentified { frame, error } => write!(f, "frame {frame}: {error}"),
            SolveFailure::NoBoardIdentified => f.write_str("no board could be identified"),
            SolveFailure::BoardMoved { board, chi2, after } => {
                write!(
                    f,
                    "board {board} disagrees with the survey (χ² {chi2:.0} over its 6 survey σ, limit {MOVED_BOARD_CHI2})"
                )?;
                if let Some(first) = after {
                    write!(f, " after leaving out board {first}")?;
                }
                f.write_str(": it has moved, or the survey is stale")
            }
            SolveFailure::MountingDisagrees { pairs, used } => write!(
                f,
                "the solved mounting pairs {pairs} of the LiDAR's hole-placed boards with the camera's, the run used {used}: the LiDAR and the camera disagree; is the room's nominal LiDAR mounting right?"
            ),
            SolveFailure::AfterLeavingOut { error, misplaced } => write!(f, "{error}; {misplaced}"),
        }
    }
}

impl fmt::Display for MisplacedHoles {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let MisplacedHoles { frame, board, surveyed, rms_px, median_px } = self;
        let kind = if *surveyed { "surveyed board" } else { "board" };
        write!(
            f,
            "frame {frame} {kind} {board}: its LiDAR hole RMS {rms_px:.2} px is {:.0}× the other boards' median ({median_px:.2} px); its LiDAR placement was left out",
            rms_px / median_px.max(1e-9)
        )
    }
}

impl From<SolveError> for SolveFailure {
    fn from(e: SolveError) -> Self {
        SolveFailure::Solver(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texts the solves gave as format strings, figures rounded as they were.
    #[test]
    fn display_is_the_operators_text() {
        let misplaced =
            MisplacedHoles { frame: 0, board: 3, surveyed: false, rms_px: 7.5, median_px: 0.5 };
        let cases = [
            (SolveFailure::NoCompleteBoard, "no complete checkerboard was detected in any image"),
            (SolveFailure::NoStart(None), "no start for the intrinsics converged (no seed)"),
            (
                SolveFailure::NoLidarPair,
                "no LiDAR board could be paired with a camera board",
            ),
            (
                SolveFailure::Unidentified {
                    frame: 2,
                    error: IdentifyError::Ambiguous { explained: 3 },
                },
                "frame 2: board identification is ambiguous: two different assignments each explain 3 boards",
            ),
            (
                SolveFailure::BoardMoved { board: 4, chi2: 120.4, after: None },
                "board 4 disagrees with the survey (χ² 120 over its 6 survey σ, limit 36): it has moved, or the survey is stale",
            ),
            (
                SolveFailure::BoardMoved { board: 4, chi2: 120.6, after: Some(1) },
                "board 4 disagrees with the survey (χ² 121 over its 6 survey σ, limit 36) after leaving out board 1: it has moved, or the survey is stale",
            ),
            (
                SolveFailure::MountingDisagrees { pairs: 5, used: 3 },
                "the solved mounting pairs 5 of the LiDAR's hole-placed boards with the camera's, the run used 3: the LiDAR and the camera disagree; is the room's nominal LiDAR mounting right?",
            ),
            (
                SolveFailure::AfterLeavingOut {
                    error: Box::new(SolveFailure::NoLidarPair),
                    misplaced: misplaced.clone(),
                },
                "no LiDAR board could be paired with a camera board; frame 0 board 3: its LiDAR hole RMS 7.50 px is 15× the other boards' median (0.50 px); its LiDAR placement was left out",
            ),
        ];
        for (failure, text) in cases {
            assert_eq!(failure.to_string(), text);
        }
        let surveyed = MisplacedHoles { surveyed: true, median_px: 0.0, ..misplaced };
        assert_eq!(
            surveyed.to_string(),
            "frame 0 surveyed board 3: its LiDAR hole RMS 7.50 px is 7500000000× the other boards' median (0.00 px); its LiDAR placement was left out"
        );
    }
}
