//! One calibration run from detections to a gated result, no I/O: associate the camera's
//! boards with the LiDAR's, start from a closed form, refine everything jointly, measure
//! the uncertainty and let the quality gate decide.
//!
//! 1. **Intrinsics start**: several seeds (Zhang's closed form from the boards'
//!    homographies, the room's nominal intrinsics, a range of fields of view) are each
//!    refined on the corners alone; the lowest cost wins. Nothing is hard-coded.
//! 2. **Association**: every LiDAR board is paired with a camera board of the same frame
//!    by carrying its hole centres into the camera with the room's nominal mounting;
//!    the pairing is redone with the extrinsic re-estimated (Kabsch) from the pairs found,
//!    under a tightening gate, so a nominal mounting 5° and 20 cm off is tolerated. The
//!    LiDAR's hole order is resolved through the camera board's pose.
//! 3. **Joint solve** (`solve::JointProblem`): corners and the paper's hole term, each
//!    weighted by its σ, Huber loss. `two_stage` solves the intrinsics from the corners
//!    first and then the extrinsic with them fixed (the paper's ablation).
//! 4. **Gate** (`target::QualitySpec`): residuals, boards, coverage, σ, the change from
//!    the calibration in force, and in a surveyed room the parking box.
//!
//! In a surveyed room (`[survey]`, unless `free_boards`) steps 2–3 are `surveyed.rs`: the
//! boards identified against the survey (`identify.rs`) and the room solved as one rigid
//! target (`solve::room`), then held by the survey's joint covariance when the room file
//! has one (`modes.rs`, `solve::room_modes`). Files: `detectors.rs`, `association.rs`,
//! `free.rs` (the free-board model), `identify.rs`, `surveyed.rs`, `modes.rs`, `gate.rs`;
//! `frame_report.rs` is `roomcal detect`'s report of one frame. Why a run was refused is a
//! [`Rejection`] (the gate's) or a [`SolveFailure`] (the solve's); their Display is the
//! result file's `reason`.

mod association;
mod detections;
mod detectors;
mod faces;
mod frame_report;
mod free;
pub use frame_report::{detect_frame, FrameReport, Identification};
pub use free::{corner_start, CornerStart};
mod gate;
pub mod identify;
mod modes;
pub mod projection_map;
pub mod register;
mod rejection;
pub mod rig;
mod solve_failure;
pub mod survey;
mod surveyed;

pub use detections::{
    frames_from_detections, DetectionsError, DEFAULT_CORNER_SIGMA_PX, DEFAULT_HOLE_SIGMA_M,
};
pub use detectors::{expected_in_rig_lidars, Detectors, RigDetectors, RigExpectation};
pub use faces::plane_points;
pub use gate::coverage;
pub use rejection::{MovedPose, Rejection};
pub use solve_failure::{MisplacedHoles, SolveFailure};
pub use surveyed::{identify_detections, FrameIdentities};

use crate::detect::holes::RefusedBoard;
use crate::geometry::{Camera, CameraModel, Se3, Vec2, Vec3};
use crate::result::{CalibrationResult, Status};
use crate::solve::PlanePoints;
use crate::target::{BoardSpec, Room};

/// Most board observations (boards × frames) in one run.
pub const MAX_OBSERVATIONS: usize = 32;

/// A checkerboard the camera saw completely, corners in the board model's order.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraBoard {
    pub corners: Vec<Vec2>,
    /// Typical 1σ of a corner (px).
    pub sigma_px: f64,
}

/// A board the LiDAR saw: its hole centres (LiDAR frame, m), in any order.
#[derive(Clone, Debug, PartialEq)]
pub struct LidarBoard {
    pub holes: Vec<Vec3>,
    /// Typical 1σ of a hole centre (m).
    pub sigma_m: f64,
    /// The LiDAR's points on the board face, for the point-to-plane term.
    pub plane: Option<PlanePoints>,
}

/// Everything detected in one image/cloud pair.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameDetections {
    pub camera: Vec<CameraBoard>,
    pub lidar: Vec<LidarBoard>,
}

/// How to run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CalibrateOptions {
    /// Intrinsics from the corners first, then the extrinsic with them fixed.
    pub two_stage: bool,
    /// The calibration in force, for the gate's change limits.
    pub current: Option<CalibrationResult>,
    /// The rig in force, for a rig's change limits (each camera's intrinsics, each
    /// sensor's mounting; a rig's pair runs take neither this nor `current`).
    pub current_rig: Option<crate::result::RigResult>,
    /// Leaves the LiDAR's board-plane points out of the joint solve (the paper's cost
    /// alone; for comparisons).
    pub without_planes: bool,
    /// Ignores the room's `[survey]`: every board observation gets its own pose.
    pub free_boards: bool,
    /// The camera's start from these detections' corners, made once beforehand (a rig's
    /// pair runs of one camera share it; given to [`calibrate_rig`], the first camera's,
    /// as [`RigExpectation::first_start`] made it); `None`: the run makes it. It must be of
    /// these frames in this room's camera: a start whose pose count differs from the
    /// complete boards is not used.
    pub corner_start: Option<CornerStart>,
    /// Where the LiDARs' beam angles came from: a run that places a LiDAR by board faces
    /// alone is refused when they are the model's nominal ones ([`LidarAngles::Nominal`]).
    pub lidar_angles: LidarAngles,
}

/// Where a LiDAR's beam angles (its elevation and azimuth table) came from.
///
/// The table is the LiDAR's own intrinsic calibration and the extrinsic rests on it. A
/// board placed by its holes checks it (a wrong table scatters the scan lines over the
/// holes, or puts them where the camera does not); a board's face does not: a table whose
/// azimuths are off on average turns the whole sweep, faces and all, and the solve turns
/// the mounting with it, with σ as small as ever.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LidarAngles {
    /// The unit's own table (its angle file or metadata), or a cloud decoded elsewhere.
    #[default]
    Unit,
    /// The model's nominal table: a packet capture decoded without the unit's file.
    Nominal,
}

impl LidarAngles {
    /// The table of points decoded from packets here (`decoded_here`, not a cloud file
    /// decoded elsewhere), with or without the unit's angle file.
    pub fn of(decoded_here: bool, unit_file: bool) -> Self {
        match decoded_here && !unit_file {
            true => LidarAngles::Nominal,
            false => LidarAngles::Unit,
        }
    }
}

/// One board observation as the solver used it.
#[derive(Clone, Debug, PartialEq)]
pub struct UsedBoard {
    pub frame: u32,
    pub corners: Vec<Vec2>,
    /// The LiDAR's hole centres in the room's hole order (empty when unpaired).
    pub holes_lidar: Vec<Vec3>,
    /// The 1σ of each of those centres, in 3D (m; the detector's, its median over the
    /// board's holes; 0 when unpaired).
    pub hole_sigma_m: f64,
    /// Whether the LiDAR's points on its face entered the solve (with its holes, or in a
    /// surveyed room on their own, where the survey says where the face is).
    pub lidar_face: bool,
    /// Board → camera, as solved.
    pub pose: Se3,
}

impl UsedBoard {
    /// Seen by the LiDAR too: its holes placed, or its face's points used.
    pub fn seen_by_lidar(&self) -> bool {
        !self.holes_lidar.is_empty() || self.lidar_face
    }
}

/// The outcome of a run: the result file and what the report needs to draw it.
#[derive(Clone, Debug)]
pub struct Calibration {
    pub result: CalibrationResult,
    pub camera: Camera,
    /// LiDAR → camera (rooms with a LiDAR).
    pub lidar_to_camera: Option<Se3>,
    pub boards: Vec<UsedBoard>,
    /// The room's hole centres in the board frame (m).
    pub holes_board: Vec<Vec3>,
    /// Solver iterations over all stages.
    pub iterations: usize,
    /// What the run decided on its own (e.g. a board left out), for the operator.
    pub notes: Vec<String>,
    /// Covariance of the poses' left perturbations `[δω; δt]`: LiDAR → camera (rows
    /// 0–5) and, in a surveyed room, room → camera (rows 6–11; zero otherwise), for
    /// composing a rig's extrinsics (`rig.rs`). `None` for a failed run.
    pub pose_covariance: Option<PoseCovariance>,
    /// Covariance of the shared parameters `[fx fy cx cy d0..d4 | δω δt]` (the extrinsic
    /// as a left perturbation), for the projection map ([`projection_map`]). `None` for a
    /// failed run.
    pub shared_covariance: Option<SharedMatrix>,
    /// Surveyed planes whose LiDAR points entered the solve (0 with free boards).
    pub lidar_planes: usize,
}

/// See [`Calibration::pose_covariance`].
pub type PoseCovariance = nalgebra::SMatrix<f64, 12, 12>;

/// See [`Calibration::shared_covariance`].
pub type SharedMatrix = nalgebra::SMatrix<f64, { crate::solve::SHARED }, { crate::solve::SHARED }>;

impl Calibration {
    /// Boards the run placed with the LiDAR by their holes (0 without an extrinsic).
    pub fn hole_boards(&self) -> usize {
        match self.lidar_to_camera {
            Some(_) => self.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count(),
            None => 0,
        }
    }

    /// How far off a projection can be over the image, its point held at `range_m`
    /// ([`projection_map`]); `None` for a failed run.
    pub fn projection_map(&self, range_m: f64) -> Option<crate::result::ProjectionMap> {
        let covariance = self.shared_covariance.as_ref()?;
        let lidar = self.lidar_to_camera.as_ref();
        Some(projection_map::projection_map(&self.camera, covariance, lidar, range_m))
    }

    /// A used board's hole centres in the camera frame, placed by its solved pose.
    pub fn holes_in_camera(&self, board: &UsedBoard) -> Vec<Vec3> {
        self.holes_board.iter().map(|h| board.pose.act(h)).collect()
    }

    /// A used board's residuals as the solution leaves them: the RMS (px) of its corners
    /// against the board model seen through its pose, and of its LiDAR hole centres seen
    /// through the extrinsic against the board's holes (`None` without LiDAR holes).
    pub fn board_rms(&self, spec: &BoardSpec, board: &UsedBoard) -> (f64, Option<f64>) {
        let corners = board.corners.iter().enumerate().map(|(i, seen)| {
            let model = board.pose.act(&spec.corner(i));
            self.camera.project(&model).map(|px| (px - seen).norm_squared())
        });
        let holes = self.lidar_to_camera.filter(|_| !board.holes_lidar.is_empty()).map(|t| {
            let pairs = board.holes_lidar.iter().zip(self.holes_in_camera(board));
            rms(pairs.map(|(l, b)| {
                let (seen, model) = (self.camera.project(&t.act(l)), self.camera.project(&b));
                seen.zip(model).map(|(s, m)| (s - m).norm_squared())
            }))
        });
        (rms(corners), holes)
    }
}

/// Runs association, start, joint solve and gate on one set of detections.
pub fn calibrate(
    room: &Room,
    frames: &[FrameDetections],
    options: &CalibrateOptions,
) -> Calibration {
    calibrate_with_clouds(room, frames, &[], options)
}

/// [`calibrate`] with each frame's sweep (`clouds[f]`, may be empty): in a surveyed room
/// (unless `free_boards`) the room model is solved as one rigid target, and the LiDAR's
/// points on the surveyed planes enter it.
pub fn calibrate_with_clouds(
    room: &Room,
    frames: &[FrameDetections],
    clouds: &[&[crate::lidar::Point]],
    options: &CalibrateOptions,
) -> Calibration {
    let solved = match surveyed_room(room, options) {
        Some(survey) => {
            let given = options.corner_start.as_ref();
            surveyed::solve_surveyed(room, survey, frames, clouds, None, given)
        }
        None => free::solve_free(room, frames, clouds, options),
    };
    gated(room, frames, options, solved)
}

/// [`calibrate_with_clouds`] that finds the LiDAR's boards itself (`frames[f].lidar` is
/// replaced by what it found in `clouds[f]`): in a surveyed room (unless `free_boards`)
/// only where the room expects them, each identified camera board carried into the sweep
/// by the camera's room pose and the nominal mounting (no global search; a sweep where
/// that places fewer than two boards is searched globally); otherwise by global search.
/// Also returns, per cloud, why boards were refused (for the operator).
pub fn calibrate_detecting(
    room: &Room,
    frames: &mut [FrameDetections],
    clouds: &[&[crate::lidar::Point]],
    detectors: &mut Detectors,
    options: &CalibrateOptions,
) -> (Calibration, Vec<Vec<RefusedBoard>>) {
    let mut finder = SweepFinder {
        detectors,
        clouds,
        found: vec![Vec::new(); frames.len()],
        searched: vec![false; frames.len()],
        refused: vec![Vec::new(); clouds.len()],
    };
    let solved = match surveyed_room(room, options) {
        Some(survey) => {
            let given = options.corner_start.as_ref();
            let solved =
                surveyed::solve_surveyed(room, survey, frames, clouds, Some(&mut finder), given);
            // A run that stopped before looking (no identified camera board) still reports
            // what the sweeps hold, as a run without survey would.
            for f in 0..frames.len().min(clouds.len()) {
                if !finder.searched[f] {
                    finder.everywhere(f);
                }
            }
            for (frame, found) in frames.iter_mut().zip(finder.found) {
                frame.lidar = found;
            }
            solved
        }
        None => {
            for (f, frame) in frames.iter_mut().enumerate().take(clouds.len()) {
                frame.lidar = finder.everywhere(f);
            }
            free::solve_free(room, frames, clouds, options)
        }
    };
    (gated(room, frames, options, solved), finder.refused)
}

/// Where a run that detects its own LiDAR boards finds them ([`calibrate_detecting`]).
pub(crate) trait FindLidarBoards {
    /// The boards of frame `frame`'s sweep expected at `expected` (board → LiDAR): one
    /// entry per pose.
    fn expected(&mut self, frame: usize, expected: &[Se3]) -> Vec<Option<LidarBoard>>;
    /// Every board frame `frame`'s sweep places (global search).
    fn everywhere(&mut self, frame: usize) -> Vec<LidarBoard>;
}

/// A sweep where the room's expectation places fewer boards than this is searched
/// globally (a nominal mounting far off, a room that changed), in the one-pair run and a
/// rig's alike.
pub(crate) const MIN_EXPECTED_PLACED: usize = 2;

/// Two refused planes whose centroids are this close (m) are one board seen twice.
const SAME_PLANE_M: f64 = 0.3;

/// The room's detectors over a run's sweeps, keeping what they found and refused.
struct SweepFinder<'a, 'c> {
    detectors: &'a mut Detectors,
    clouds: &'a [&'c [crate::lidar::Point]],
    /// Per frame, every board found in its sweep (all rounds).
    found: Vec<Vec<LidarBoard>>,
    /// Per frame, whether its sweep was searched.
    searched: Vec<bool>,
    refused: Vec<Vec<RefusedBoard>>,
}

impl FindLidarBoards for SweepFinder<'_, '_> {
    fn expected(&mut self, frame: usize, expected: &[Se3]) -> Vec<Option<LidarBoard>> {
        let Some(cloud) = self.clouds.get(frame) else { return vec![None; expected.len()] };
        self.searched[frame] = true;
        let boards = self.detectors.detect_expected(cloud, expected);
        // A board predicted again (a second round) is refused once, as the last round saw it.
        let again = self.detectors.refused_in_cloud();
        let near =
            |a: &RefusedBoard, b: &RefusedBoard| (a.centroid - b.centroid).norm() < SAME_PLANE_M;
        self.refused[frame].retain(|r| !again.iter().any(|a| near(a, r)));
        self.refused[frame].extend_from_slice(again);
        self.found[frame].extend(boards.iter().flatten().cloned());
        boards
    }

    fn everywhere(&mut self, frame: usize) -> Vec<LidarBoard> {
        let Some(cloud) = self.clouds.get(frame) else { return Vec::new() };
        self.searched[frame] = true;
        let boards = self.detectors.detect_cloud(cloud);
        self.refused[frame] = self.detectors.refused_in_cloud().to_vec();
        self.found[frame] = boards.clone();
        boards
    }
}

/// The survey the run uses: the room's, unless the options ask for free boards.
pub(crate) fn surveyed_room<'r>(
    room: &'r Room,
    options: &CalibrateOptions,
) -> Option<&'r crate::target::SurveySpec> {
    room.survey.as_ref().filter(|_| !options.free_boards)
}

/// The run's outcome through the quality gate (a solve that failed is a rejected run).
fn gated(
    room: &Room,
    frames: &[FrameDetections],
    options: &CalibrateOptions,
    solved: Result<Calibration, SolveFailure>,
) -> Calibration {
    let fallback_camera = nominal_camera(room, default_fov(room.camera.model));
    match solved {
        Ok(mut calibration) => {
            calibration.result.projection_uncertainty =
                calibration.projection_map(room.quality.projection_range_m);
            if let Err(reason) = gate::gate(room, frames, options, &calibration) {
                calibration.result.status = Status::Rejected;
                let notes = calibration.notes.iter().map(|n| format!("; {n}"));
                calibration.result.reason = Some(notes.fold(reason.to_string(), |r, n| r + &n));
            }
            calibration
        }
        Err(reason) => Calibration {
            result: free::rejected(&fallback_camera, &reason, room.lidar.is_some()),
            camera: fallback_camera,
            lidar_to_camera: None,
            boards: Vec::new(),
            holes_board: Vec::new(),
            iterations: 0,
            notes: Vec::new(),
            pose_covariance: None,
            shared_covariance: None,
            lidar_planes: 0,
        },
    }
}

/// The room's nominal camera: its intrinsics where the room gives them, else a centred
/// lens of `hfov_deg`.
pub fn nominal_camera(room: &Room, hfov_deg: f64) -> Camera {
    let spec = &room.camera;
    let mut camera = Camera::from_fov(spec.model, spec.width, spec.height, hfov_deg, [0.0; 5]);
    if let Some(fx) = spec.fx {
        camera.fx = fx;
        camera.fy = spec.fy.unwrap_or(fx);
    }
    camera.cx = spec.cx.unwrap_or(camera.cx);
    camera.cy = spec.cy.unwrap_or(camera.cy);
    if let Some(d) = &spec.distortion {
        camera.distortion[..d.len()].copy_from_slice(d);
    }
    camera
}

fn default_fov(model: CameraModel) -> f64 {
    match model {
        CameraModel::PinholeRadtan => 70.0,
        CameraModel::Fisheye => 120.0,
    }
}

/// Fields of view tried as starts besides Zhang and the nominal intrinsics.
fn fov_guesses(model: CameraModel) -> &'static [f64] {
    match model {
        CameraModel::PinholeRadtan => &[45.0, 60.0, 75.0, 90.0, 110.0],
        CameraModel::Fisheye => &[90.0, 120.0, 150.0, 180.0],
    }
}

/// RMS of squared residuals; a point that does not project counts as infinitely off.
fn rms(squares: impl Iterator<Item = Option<f64>>) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for sq in squares {
        sum += sq.unwrap_or(f64::INFINITY);
        n += 1;
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64).sqrt()
    }
}

fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}
