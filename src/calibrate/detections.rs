//! The detections file both ways: a run's boards as `roomcal detect` writes them
//! ([`CameraBoard::detection`], [`LidarBoard::detection`]), and a detections file, ours or
//! another tool's, read back into the frames a calibration solves
//! ([`frames_from_detections`], `roomcal calibrate --detections`).
//!
//! A board's σ travels with it (`corner_sigma_px`, `hole_sigma_m`); a file without them
//! gets [`DEFAULT_CORNER_SIGMA_PX`] and [`DEFAULT_HOLE_SIGMA_M`], which only weigh the
//! kinds against each other at the start: each kind's variance factor is then taken from
//! its own residuals. A detections file holds no LiDAR points, so the solve has no
//! board-face term.

use crate::geometry::{Vec2, Vec3};
use crate::result::{BoardDetection, Detections};
use crate::target::Room;

use super::{CameraBoard, FrameDetections, LidarBoard, MAX_OBSERVATIONS};

/// A corner's 1σ (px) when the detections file does not give it.
pub const DEFAULT_CORNER_SIGMA_PX: f64 = 0.1;
/// A hole centre's 1σ (m) when the detections file does not give it.
pub const DEFAULT_HOLE_SIGMA_M: f64 = 0.003;

/// Why a detections file cannot be solved; `board` is the index into its `boards`.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DetectionsError {
    #[error("boards[{board}] has neither corners_px nor holes_lidar")]
    Empty { board: usize },
    #[error("boards[{board}]: {got} corners_px, the room's board has {expected} inner corners")]
    CornerCount { board: usize, got: usize, expected: usize },
    #[error("boards[{board}]: {got} holes_lidar, the room's board has {expected} holes")]
    HoleCount { board: usize, got: usize, expected: usize },
    #[error("boards[{board}]: holes_lidar given but the room has no [lidar] table")]
    NoLidar { board: usize },
    #[error("boards[{board}]: {field} holds a value that is not a finite number")]
    NotFinite { board: usize, field: &'static str },
    #[error("boards[{board}]: {field} must be a positive number")]
    NotPositive { board: usize, field: &'static str },
    #[error("boards[{board}]: frame {frame}, at most {most} frames are solved together")]
    FrameTooLarge { board: usize, frame: u32, most: usize },
    #[error("no board in the file")]
    NoBoards,
}

/// The frames of a detections file for `room`: each board in the frame it names, its
/// corners and its holes checked against the room's board.
pub fn frames_from_detections(
    room: &Room,
    detections: &Detections,
) -> Result<Vec<FrameDetections>, DetectionsError> {
    if detections.boards.is_empty() {
        return Err(DetectionsError::NoBoards);
    }
    let mut frames: Vec<FrameDetections> = Vec::new();
    for (board, d) in detections.boards.iter().enumerate() {
        check(room, board, d)?;
        let f = d.frame as usize;
        if frames.len() <= f {
            frames.resize(f + 1, FrameDetections::default());
        }
        if !d.corners_px.is_empty() {
            let corners = d.corners_px.iter().map(|c| Vec2::new(c[0], c[1])).collect();
            let sigma_px = d.corner_sigma_px.unwrap_or(DEFAULT_CORNER_SIGMA_PX);
            frames[f].camera.push(CameraBoard { corners, sigma_px });
        }
        if !d.holes_lidar.is_empty() {
            let holes = d.holes_lidar.iter().map(|h| Vec3::new(h[0], h[1], h[2])).collect();
            let sigma_m = d.hole_sigma_m.unwrap_or(DEFAULT_HOLE_SIGMA_M);
            frames[f].lidar.push(LidarBoard { holes, sigma_m, plane: None });
        }
    }
    Ok(frames)
}

/// One board of the file checked against `room`.
fn check(room: &Room, board: usize, d: &BoardDetection) -> Result<(), DetectionsError> {
    if d.corners_px.is_empty() && d.holes_lidar.is_empty() {
        return Err(DetectionsError::Empty { board });
    }
    if d.frame as usize >= MAX_OBSERVATIONS {
        return Err(DetectionsError::FrameTooLarge {
            board,
            frame: d.frame,
            most: MAX_OBSERVATIONS,
        });
    }
    let [columns, rows] = room.board.inner_corners;
    let expected = (columns * rows) as usize;
    if !d.corners_px.is_empty() && d.corners_px.len() != expected {
        return Err(DetectionsError::CornerCount { board, got: d.corners_px.len(), expected });
    }
    let expected = room.board.holes.len();
    if !d.holes_lidar.is_empty() {
        if room.lidar.is_none() {
            return Err(DetectionsError::NoLidar { board });
        }
        if d.holes_lidar.len() != expected {
            return Err(DetectionsError::HoleCount { board, got: d.holes_lidar.len(), expected });
        }
    }
    let corners = d.corners_px.iter().flatten();
    let holes = d.holes_lidar.iter().flatten();
    for (field, finite) in [
        ("corners_px", corners.copied().all(f64::is_finite)),
        ("holes_lidar", holes.copied().all(f64::is_finite)),
    ] {
        if !finite {
            return Err(DetectionsError::NotFinite { board, field });
        }
    }
    for (field, sigma) in [("corner_sigma_px", d.corner_sigma_px), ("hole_sigma_m", d.hole_sigma_m)]
    {
        if sigma.is_some_and(|s| !(s.is_finite() && s > 0.0)) {
            return Err(DetectionsError::NotPositive { board, field });
        }
    }
    Ok(())
}

impl CameraBoard {
    /// The board as the detections file holds it: its corners (px), in the detector's
    /// order, and their σ.
    pub fn detection(&self) -> BoardDetection {
        let corners_px = self.corners.iter().map(|c| [c.x, c.y]).collect();
        let corner_sigma_px = Some(self.sigma_px);
        BoardDetection { corners_px, corner_sigma_px, ..BoardDetection::default() }
    }
}

impl LidarBoard {
    /// The board as the detections file holds it: its hole centres (LiDAR frame, m) and
    /// their σ.
    pub fn detection(&self) -> BoardDetection {
        let holes_lidar = self.holes.iter().map(|h| [h.x, h.y, h.z]).collect();
        let hole_sigma_m = Some(self.sigma_m);
        BoardDetection { holes_lidar, hole_sigma_m, ..BoardDetection::default() }
    }
}
