//! The detectors of a room (chessboards in the image, hole boards in the cloud), made once
//! and reused for every frame; a rig's, one per camera.

use super::faces::{plane_points, PLANE_CUT_SIGMAS, PLANE_MIN_SIGMA_M};
use super::{median, CameraBoard, LidarBoard};
use crate::detect::holes::{HoleConfig, HoleDetector};
use crate::detect::{ChessboardDetector, DetectError, GreyImage};
use crate::geometry::{Se3, Vec2};
use crate::lidar::Point;
use crate::target::{BoardSpec, Room};

/// The detectors of a room, with their workspaces (made once, reused for every frame).
pub struct Detectors {
    spec: BoardSpec,
    chess: ChessboardDetector,
    holes: HoleDetector,
    found_holes: Vec<crate::detect::holes::LidarBoard>,
    found_expected: Vec<Option<crate::detect::holes::LidarBoard>>,
}

/// The detectors of a rig: one per camera (its own image size, in its pair room); the
/// LiDARs' boards are the room's, so every LiDAR is detected by the first camera's
/// hole detector (no chessboard workspace per LiDAR).
pub struct RigDetectors {
    pub cameras: Vec<Detectors>,
}

impl RigDetectors {
    /// Detectors for every camera of `rig` in `room`.
    pub fn new(room: &Room, rig: &crate::rig::Rig) -> Result<Self, DetectError> {
        let cameras = (0..rig.cameras.len())
            .map(|c| Detectors::new(&rig.pair_room(room, c, None)))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(RigDetectors { cameras })
    }

    /// The first camera's detectors (whose hole detector serves every LiDAR).
    pub fn first(&mut self) -> &mut Detectors {
        // A rig has at least one camera (crate::rig checks it).
        &mut self.cameras[0]
    }

    /// The boards of a rig LiDAR's sweep: where `expected` says (from
    /// [`expected_in_rig_lidars`]), else every board a global search places.
    pub fn detect_lidar(&mut self, points: &[Point], expected: Option<&[Se3]>) -> Vec<LidarBoard> {
        self.first().detect_where_expected(points, expected)
    }
}

/// What a surveyed room expects a rig's LiDARs to see ([`expected_in_rig_lidars`]).
#[derive(Clone, Debug)]
pub struct RigExpectation {
    /// Per LiDAR, every surveyed board's expected pose (board → LiDAR).
    pub lidars: Vec<Vec<Se3>>,
    /// The first camera's start from its corners that identified its boards: the rig's
    /// calibration takes it as [`super::CalibrateOptions::corner_start`] instead of making
    /// it again.
    pub first_start: super::CornerStart,
}

/// Where each LiDAR of `rig` should see the surveyed boards: the first camera's boards
/// identified against the survey give its room pose (start intrinsics, corners only), and
/// each LiDAR's nominal mounting carries the surveyed boards into it, as the one-pair run
/// carries its camera's boards ([`super::calibrate_detecting`]). `None` outside a surveyed
/// room, with `free_boards`, or when the first camera's boards identify nothing (the
/// LiDARs are then searched globally).
pub fn expected_in_rig_lidars(
    room: &Room,
    rig: &crate::rig::Rig,
    first_camera: &[CameraBoard],
    free_boards: bool,
) -> Option<RigExpectation> {
    let survey = room.survey.as_ref().filter(|_| !free_boards)?;
    let frame = super::FrameDetections { camera: first_camera.to_vec(), lidar: Vec::new() };
    let pair = rig.pair_room(room, 0, None);
    let first_start = super::corner_start(&pair, std::slice::from_ref(&frame)).ok()?;
    let first = super::surveyed::identify_from(&pair, survey, &frame, Some(&first_start)).ok()?;
    let lidars = rig.lidars.iter().map(|lidar| {
        let room_to_lidar = lidar.to_reference.inverse().compose(&first.room_to_camera);
        survey.boards.iter().map(|b| room_to_lidar.compose(&b.pose())).collect()
    });
    Some(RigExpectation { lidars: lidars.collect(), first_start })
}

impl Detectors {
    /// Detectors for the room's board and camera.
    pub fn new(room: &Room) -> Result<Self, DetectError> {
        Ok(Detectors {
            spec: room.board.clone(),
            chess: ChessboardDetector::new(room.camera.width, room.camera.height, &room.board)?,
            holes: HoleDetector::new(&room.board, HoleConfig::default()),
            found_holes: Vec::new(),
            found_expected: Vec::new(),
        })
    }

    /// Frees the chessboard detector's frame-sized workspace until its next frame.
    pub fn release_chessboard(&mut self) {
        self.chess.release_workspace();
    }

    /// Frees the hole detector's sweep-sized workspaces until its next sweep.
    pub fn release_holes(&mut self) {
        self.holes.release_workspace();
    }

    /// The boards at `expected` (board → LiDAR) when that places at least two, else every
    /// board a global search places (the one-pair run's rule, [`super::calibrate_detecting`]);
    /// without `expected`, the global search.
    pub fn detect_where_expected(
        &mut self,
        points: &[Point],
        expected: Option<&[Se3]>,
    ) -> Vec<LidarBoard> {
        if let Some(expected) = expected {
            let placed: Vec<LidarBoard> =
                self.detect_expected(points, expected).into_iter().flatten().collect();
            if placed.len() >= super::MIN_EXPECTED_PLACED {
                return placed;
            }
        }
        self.detect_cloud(points)
    }

    /// Every board the LiDAR places in the cloud, with its hole centres.
    pub fn detect_cloud(&mut self, points: &[Point]) -> Vec<LidarBoard> {
        self.holes.detect(points, &mut self.found_holes);
        let found = core::mem::take(&mut self.found_holes);
        let boards = found.iter().map(|b| self.lidar_board(b, points)).collect();
        self.found_holes = found;
        boards
    }

    /// The boards expected at `expected` (board → LiDAR, e.g. predicted from the surveyed
    /// room): one entry per expected pose, `None` where no board was placed there
    /// ([`HoleDetector::detect_expected`]).
    pub fn detect_expected(
        &mut self,
        points: &[Point],
        expected: &[Se3],
    ) -> Vec<Option<LidarBoard>> {
        let mut found = core::mem::take(&mut self.found_expected);
        self.holes.detect_expected(points, expected, &mut found);
        let boards =
            found.iter().map(|b| b.as_ref().map(|b| self.lidar_board(b, points))).collect();
        self.found_expected = found;
        boards
    }

    /// A placed board as the calibration uses it: its holes, their typical σ, and its
    /// face points for the point-to-plane term.
    fn lidar_board(
        &self,
        board: &crate::detect::holes::LidarBoard,
        points: &[Point],
    ) -> LidarBoard {
        LidarBoard {
            holes: board.holes.to_vec(),
            sigma_m: median(board.hole_sigma_m.iter().copied()),
            plane: plane_points(
                &self.spec,
                &board.pose,
                PLANE_CUT_SIGMAS * board.plane_rms_m.max(PLANE_MIN_SIGMA_M),
                points.iter().map(Point::position),
            ),
        }
    }

    /// Why boards seen in the last cloud were not placed (for the operator).
    pub fn refused_in_cloud(&self) -> &[crate::detect::holes::RefusedBoard] {
        self.holes.refused()
    }

    /// Every complete board in the frame (incomplete ones are not used).
    pub fn detect_image(&mut self, image: &GreyImage) -> Result<Vec<CameraBoard>, DetectError> {
        self.detect_pixels(&image.data)
    }

    /// Every complete board in a grey frame of the room camera's size (row-major).
    pub fn detect_pixels(&mut self, pixels: &[u8]) -> Result<Vec<CameraBoard>, DetectError> {
        let mut found = Vec::new();
        self.chess.detect(pixels, &mut found)?;
        Ok(found
            .iter()
            .filter(|b| b.complete)
            .map(|b| CameraBoard {
                corners: b.corners.iter().map(|c| Vec2::new(c.x, c.y)).collect(),
                sigma_px: median(b.corners.iter().map(|c| c.sigma)),
            })
            .collect())
    }
}
