//! `roomcal survey` without I/O: the room as one rigid target, solved from several visits
//! (each its own vehicle: own intrinsics, LiDAR mounting and parking pose).
//!
//! 1. **Per visit** ([`prepare_visit`]): today's free-board calibration gives its
//!    intrinsics, extrinsic and every board's board→camera pose (a LiDAR that placed no
//!    board by its holes is placed by the boards' faces, [`super::register`]); every board's face
//!    is cut from its sweep where that start puts it, and the room's big planes are found
//!    in it ([`crate::detect::planes`]).
//! 2. **Chaining** ([`chain`]): every visit's boards are labelled as room boards (the
//!    symmetric checkerboard's half-turn resolved) and every visit placed in the room.
//! 3. **Planes** ([`planes`]): each visit's planes carried into the room by its start
//!    pose and associated across visits.
//! 4. **Bundle adjustment** ([`bundle`]): boards, planes and every visit's parameters
//!    jointly, Schur over the visits; σ of boards and planes from the reduced normal
//!    equations.
//! 5. **Gauge** ([`gauge`]): the bundle fixes the frame on board 0 (the first board of the
//!    first visit); the solution and its σ are then re-expressed in the boards' mean frame
//!    ([`FRAME`]), so that no board's σ carries another board's error.

pub mod bundle;
pub mod chain;
pub mod gauge;
pub mod planes;

use crate::detect::planes::{find_planes, FoundPlane, PlaneConfig};
use crate::geometry::{Camera, Mat3, Se3, Vec2, Vec3};
use crate::lidar::Point;
use crate::solve::{hole_sigma_px, PlanePoints, SolveError};
use crate::target::{BoardSpec, Room, SurveySpec, SurveyedBoard, SurveyedPlane, MAX_BOARDS};

use super::faces::{expected_face, EXPECTED_FACE_CUT_M};
use super::free::run_corner_noise_px;
use super::{calibrate, CalibrateOptions, FrameDetections};
use bundle::{BundleBoard, BundleVisit, Sigma, SurveyProblem, SurveyState, VisitState};
use chain::{chain_boards, half_turn, ChainError};

pub use bundle::MAX_VISITS;

/// How the survey's room frame is defined (`survey.frame`, before [`Survey::in_parking_frame`]).
pub const FRAME: &str = gauge::MEAN_FRAME;

/// Most bundle iterations.
const MAX_ITERATIONS: usize = 60;

/// What one visit contributes: its free-board calibration and the planes in its sweep.
#[derive(Clone, Debug)]
pub struct SurveyVisit {
    pub camera: Camera,
    /// LiDAR → camera (`None`: the visit's LiDAR placed no board by its holes and its
    /// faces did not place it, [`super::register::register_by_faces`]).
    pub lidar_to_camera: Option<Se3>,
    /// Corner σ (px): the noise the visit's own corner residuals show
    /// ([`super::free::corner_noise_px`]), the detector's median σ where they cannot.
    pub corner_sigma_px: f64,
    pub boards: Vec<VisitBoard>,
    /// The room's big planes in the sweep (LiDAR frame).
    pub planes: Vec<FoundPlane>,
}

/// How a visit's LiDAR was placed for the survey's start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LidarPlacement {
    /// By the holes of the boards it placed (its free-board calibration).
    Holes,
    /// By the boards' faces alone ([`super::register::register_by_faces`]): it placed no hole.
    Faces,
    /// Not placed: its sweep adds nothing to the survey.
    Unplaced,
}

impl SurveyVisit {
    /// How this visit's LiDAR was placed: the free-board start places it only by holes,
    /// so an extrinsic without a board's holes came from the faces.
    pub fn lidar_placement(&self) -> LidarPlacement {
        match self.lidar_to_camera {
            None => LidarPlacement::Unplaced,
            Some(_) if self.boards.iter().any(|b| !b.holes_lidar.is_empty()) => {
                LidarPlacement::Holes
            }
            Some(_) => LidarPlacement::Faces,
        }
    }
}

/// One board of a visit as its free-board calibration used it.
#[derive(Clone, Debug, PartialEq)]
pub struct VisitBoard {
    pub corners: Vec<Vec2>,
    /// The LiDAR's hole centres in the board's hole order (empty when unpaired).
    pub holes_lidar: Vec<Vec3>,
    /// The hole term's σ (px).
    pub hole_sigma_px: f64,
    /// The LiDAR's points on the board face.
    pub plane: Option<PlanePoints>,
    /// Board → camera.
    pub pose: Se3,
}

/// A solved survey.
#[derive(Clone, Debug)]
pub struct Survey {
    /// The `[survey]` table.
    pub spec: SurveySpec,
    /// Every estimate (boards, planes, visits).
    pub state: SurveyState,
    /// Visits that saw each room board and each plane.
    pub board_visits: Vec<usize>,
    pub plane_visits: Vec<usize>,
    /// The covariance of every board and plane in the boards' mean frame
    /// ([`gauge::mean_frame_covariance`]): a plane's offset σ moves with the frame's
    /// origin, and the file's `survey.covariance` is this in the file's frame.
    pub covariance: nalgebra::DMatrix<f64>,
    /// `labels[v][i]`: the room board of visit `v`'s board `i`.
    pub labels: Vec<Vec<chain::ChainedBoard>>,
    pub report: bundle::BundleReport,
    /// Corner RMS over every visit at the solution (px).
    pub corner_rms_px: f64,
}

/// Why a survey could not be made. Visits are numbered from 1, as given.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SurveyError {
    #[error("a survey needs at least 2 visits, got {0}")]
    TooFewVisits(usize),
    #[error("{visits} visits: at most {max} can be surveyed at once")]
    TooManyVisits { visits: usize, max: usize },
    #[error("visit {visit}: its free-board calibration failed: {reason}")]
    Calibration { visit: usize, reason: String },
    #[error(
        "visit {visit}: only {boards} board(s) calibrated, 2 are needed to place it in the room"
    )]
    TooFewBoards { visit: usize, boards: usize },
    #[error("visit {again} is visit {first} again (identical detections): give each visit once")]
    DuplicateVisit { first: usize, again: usize },
    #[error("visit {visit}: only {matched} of its boards match boards of the earlier visits (2 needed to chain it into the room)")]
    Unchained { visit: usize, matched: usize },
    #[error("the visits show {found} different boards, the room file has board.count = {expected}{}",
            match first_extra {
                Some((v, i)) => format!(" (visit {v}'s board {i} is near no board the earlier visits saw)"),
                // Fewer: the camera saw some board whole in no visit (another board or a
                // post in front of part of it); only whole boards can be surveyed.
                None if *found < *expected as usize => " (no visit's camera saw the others whole: survey the boards it sees with board.count set to them, or clear their view)".to_string(),
                None => String::new(),
            })]
    BoardCount { found: usize, expected: u32, first_extra: Option<(usize, usize)> },
    #[error("room board {board} (visit {visit}'s board {index}) is seen by that visit alone: every board needs at least 2 visits")]
    BoardSeenOnce { board: usize, visit: usize, index: usize },
    #[error("the bundle adjustment failed: {0}")]
    Solve(SolveError),
}

impl From<SolveError> for SurveyError {
    fn from(e: SolveError) -> Self {
        SurveyError::Solve(e)
    }
}

/// Visit `index` (0-based) from its detections and sweep: its free-board calibration
/// (used even when the gate rejects it: it is only a start; camera only when none of its
/// LiDAR boards pairs) and the planes in its sweep.
pub fn prepare_visit(
    room: &Room,
    index: usize,
    frame: &FrameDetections,
    cloud: &[Point],
) -> Result<SurveyVisit, SurveyError> {
    let mut run = calibrate(room, core::slice::from_ref(frame), &CalibrateOptions::default());
    if run.boards.is_empty() && room.lidar.is_some() {
        // No LiDAR board paired (or none found): the visit still measures the boards
        // through its camera; its LiDAR then adds nothing.
        let camera_only = Room { lidar: None, ..room.clone() };
        let frame = FrameDetections { camera: frame.camera.clone(), lidar: Vec::new() };
        run = calibrate(&camera_only, core::slice::from_ref(&frame), &CalibrateOptions::default());
    }
    if run.boards.is_empty() {
        let reason = run.result.reason.clone().unwrap_or_else(|| "no board was used".into());
        return Err(SurveyError::Calibration { visit: index + 1, reason });
    }
    if run.boards.len() < 2 {
        return Err(SurveyError::TooFewBoards { visit: index + 1, boards: run.boards.len() });
    }
    // The noise the visit's own corner residuals show, not the detector's σ (about twice
    // that): honest σ for the survey need honest measurement σ, and the weight of the
    // corners against the LiDAR's terms sets where the boards end up. With the detector's
    // σ a 16-visit survey's boards were 0.46 mm / 0.0127° (σ, against a bound of 0.28 mm /
    // 0.0062°); with the residuals' 0.31 mm / 0.0072°, errors alike (0.19–0.26 mm,
    // 0.006–0.007°; seed 4, `studies/crb_bound.py --survey-visits`).
    let corner_sigma_px = run_corner_noise_px(&run)
        .unwrap_or_else(|| median(&frame.camera.iter().map(|b| b.sigma_px).collect::<Vec<_>>()));
    let hole_scale = hole_noise_scale(&run, frame);
    // A LiDAR that placed no board by its holes is placed by the boards' faces, from the
    // nominal mounting: its faces and its sweep's planes then enter the bundle too.
    let lidar_to_camera = run.lidar_to_camera.or_else(|| {
        let nominal = super::association::lidar_nominal(room.lidar.as_ref()?);
        let poses: Vec<Se3> = run.boards.iter().map(|b| b.pose).collect();
        super::register::register_by_faces(&room.board, &poses, cloud, &nominal)
    });
    let board_to_lidar =
        |used: &super::UsedBoard| lidar_to_camera.map(|e| e.inverse().compose(&used.pose));
    let boards = run
        .boards
        .iter()
        .map(|used| {
            // The LiDAR board this camera board was paired with: the same hole centres.
            let lidar = frame.lidar.iter().find(|l| same_points(&l.holes, &used.holes_lidar));
            let hole_sigma_m = lidar.map_or(0.01, |l| l.sigma_m);
            VisitBoard {
                corners: used.corners.clone(),
                holes_lidar: used.holes_lidar.clone(),
                hole_sigma_px: hole_scale
                    * hole_sigma_px(run.camera.fx, hole_sigma_m, used.pose.translation.z),
                // A board whose holes the LiDAR did not place still shows its face where
                // the camera and the start's extrinsic put it: every face the LiDAR hits
                // enters the bundle, as in a surveyed calibration.
                plane: match lidar {
                    Some(l) => l.plane,
                    None => board_to_lidar(used).and_then(|pose| {
                        expected_face(&room.board, &pose, EXPECTED_FACE_CUT_M, cloud)
                    }),
                },
                pose: used.pose,
            }
        })
        .collect();
    let planes = match lidar_to_camera {
        Some(_) => find_planes(cloud, &PlaneConfig::default()),
        None => Vec::new(),
    };
    Ok(SurveyVisit { camera: run.camera, lidar_to_camera, corner_sigma_px, boards, planes })
}

/// How much larger the hole term's noise is than the hole detector's σ say, from the
/// visit's own hole residuals (at least 1).
fn hole_noise_scale(run: &super::Calibration, frame: &FrameDetections) -> f64 {
    let predicted: Vec<f64> = run
        .boards
        .iter()
        .filter(|b| !b.holes_lidar.is_empty())
        .filter_map(|b| {
            let lidar = frame.lidar.iter().find(|l| same_points(&l.holes, &b.holes_lidar))?;
            Some(hole_sigma_px(run.camera.fx, lidar.sigma_m, b.pose.translation.z))
        })
        .collect();
    let typical = median(&predicted);
    let measured = run.result.quality.hole_rms_px / 2f64.sqrt();
    if typical > 0.0 && measured.is_finite() {
        (measured / typical).max(1.0)
    } else {
        1.0
    }
}

/// Surveys the room from `visits` (in the order given).
pub fn survey(room: &Room, visits: &[SurveyVisit]) -> Result<Survey, SurveyError> {
    if visits.len() < 2 {
        return Err(SurveyError::TooFewVisits(visits.len()));
    }
    if visits.len() > MAX_VISITS {
        return Err(SurveyError::TooManyVisits { visits: visits.len(), max: MAX_VISITS });
    }
    check_distinct(visits)?;
    let poses: Vec<Vec<Se3>> =
        visits.iter().map(|v| v.boards.iter().map(|b| b.pose).collect()).collect();
    let chained = chain_boards(&poses).map_err(|e| match e {
        ChainError::Unchained { visit, matched } => {
            SurveyError::Unchained { visit: visit + 1, matched }
        }
    })?;
    let board_visits = check_boards(room, &chained)?;
    let reference = chained.boards[0];
    let mut boards: Vec<Se3> =
        chained.boards.iter().map(|b| reference.inverse().compose(b)).collect();
    // The gauge exactly: board 0 is the room frame.
    boards[0] = Se3::identity();
    let mut state = SurveyState {
        visits: visits
            .iter()
            .zip(&chained.visit_to_reference)
            .map(|(v, motion)| VisitState {
                camera: v.camera,
                lidar_to_camera: v.lidar_to_camera.unwrap_or_else(Se3::identity),
                room_to_camera: motion.inverse().compose(&reference),
            })
            .collect(),
        boards,
        planes: Vec::new(),
    };
    let lidar_to_room: Vec<Option<Se3>> = visits
        .iter()
        .zip(&state.visits)
        .map(|(v, s)| v.lidar_to_camera.map(|l| s.room_to_camera.inverse().compose(&l)))
        .collect();
    let found: Vec<&[FoundPlane]> = visits.iter().map(|v| v.planes.as_slice()).collect();
    let room_planes = planes::associate(&lidar_to_room, &found);
    state.planes = room_planes.planes.iter().map(|p| p.start).collect();
    let spec = &room.board;
    let bundle_visits: Vec<BundleVisit> = visits
        .iter()
        .zip(&chained.labels)
        .zip(&room_planes.per_visit)
        .map(|((visit, labels), planes)| bundle_visit(spec, visit, labels, planes))
        .collect();
    let object: Vec<Vec3> = (0..spec.corner_count()).map(|i| spec.corner(i)).collect();
    let holes: Vec<Vec3> = (0..spec.holes.len()).map(|h| spec.hole(h)).collect();
    let problem = SurveyProblem::new(
        &object,
        &holes,
        &bundle_visits,
        state.boards.len(),
        state.planes.len(),
    )?;
    let report = bundle::solve(&problem, &mut state, MAX_ITERATIONS)?;
    let mut workspace = bundle::Workspace::new(&problem);
    workspace.build(&problem, &state)?;
    let covariance = gauge::mean_frame_covariance(&state, &workspace.global_covariance()?);
    let (board_sigma, plane_sigma) = gauge::mean_frame_sigmas(state.boards.len(), &covariance);
    let corner_rms_px = problem.corner_rms_px(&state)?;
    let state = gauge::in_mean_frame(&state);
    let names: Vec<&str> = room_planes.planes.iter().map(|p| p.name.as_str()).collect();
    let spec = survey_spec(visits.len(), &state, &board_sigma, &plane_sigma, &names);
    Ok(Survey {
        spec,
        state,
        board_visits,
        plane_visits: room_planes.planes.iter().map(|p| p.visits).collect(),
        covariance,
        labels: chained.labels,
        report,
        corner_rms_px,
    })
}

/// How the written room file's frame is defined (see [`Survey::in_parking_frame`]).
pub const PARKING_FRAME: &str = "the nominal LiDAR frame at the visits' mean parking spot (every \
visit's room→camera pose is the room's [lidar] mounting, on average); σ are relative to the boards' mean frame, a plane's offset σ at this frame's origin";

impl Survey {
    /// The survey in the frame the room file holds: the room's nominal LiDAR frame at the
    /// visits' mean parking spot, so that a vehicle parked as the surveyed ones were has the
    /// room's `[lidar]` mounting as its room→camera pose — the reference of the quality
    /// gate's parking box. The survey's frame (the boards' mean, [`gauge`]) only fixes the
    /// frame; this is one rigid motion `G` of the whole solution (boards `G⁻¹ B`, planes
    /// carried along), which leaves every relative pose, and so every measurement,
    /// unchanged. The σ stay those of the boards' mean frame, except a plane's offset σ,
    /// which is its offset's at the new origin ([`gauge::plane_offset_sigma_at`]): the
    /// calibration holds each plane's offset and turn apart, at the file's origin, where the
    /// vehicle stands.
    pub fn in_parking_frame(&self, lidar: &crate::target::LidarSpec) -> SurveySpec {
        let nominal = super::association::lidar_nominal(lidar);
        let g = mean_motion(
            self.state.visits.iter().map(|v| v.room_to_camera.inverse().compose(&nominal)),
        );
        let to_new = g.inverse();
        let mut spec = self.spec.clone();
        spec.frame.clear();
        let _ = spec
            .frame
            .push_str(&PARKING_FRAME[..PARKING_FRAME.len().min(crate::target::MAX_SURVEY_TEXT)]);
        for board in spec.boards.iter_mut() {
            let pose = to_new.compose(&board.pose());
            board.rotation = rows(&pose.rotation);
            board.translation = pose.translation.into();
        }
        let boards = spec.boards.len();
        for (p, plane) in spec.planes.iter_mut().enumerate() {
            // n · p_room = d with p_room = G p_new: (R_Gᵀ n) · p_new = d − n · t_G.
            let n = Vec3::from(plane.normal);
            let mean_frame = bundle::RoomPlane { normal: n, offset: plane.offset };
            let block = gauge::plane_block(boards, &self.covariance, p);
            plane.sigma_m = gauge::plane_offset_sigma_at(&mean_frame, &block, &g.translation);
            plane.normal = (g.rotation.transpose() * n).into();
            plane.offset -= n.dot(&g.translation);
        }
        spec.covariance = gauge::file_covariance(&self.state, &self.covariance, &g);
        spec
    }

    /// The room file `roomcal survey` writes: `room` with this survey as its `[survey]`
    /// table, checked against the room's `board.count`. In a room with a LiDAR the survey
    /// is first moved into the parking frame ([`Survey::in_parking_frame`], the parking
    /// box's reference, not the survey's own frame, the boards' mean); `self.spec` becomes
    /// the table written, so that what is reported is what the file holds.
    pub fn surveyed_room(&mut self, room: Room) -> Result<Room, crate::target::RoomError> {
        if let Some(lidar) = &room.lidar {
            self.spec = self.in_parking_frame(lidar);
        }
        self.spec.validate(room.board.count)?;
        Ok(Room { survey: Some(self.spec.clone()), ..room })
    }
}

/// The mean of rigid motions: rotations averaged in the tangent space of the first, then
/// translations averaged. The visits' parking differs by centimetres and degrees, where
/// this is the Karcher mean to far below the survey's σ.
fn mean_motion(motions: impl Iterator<Item = Se3>) -> Se3 {
    let all: Vec<Se3> = motions.collect();
    let Some(first) = all.first() else { return Se3::identity() };
    let n = all.len() as f64;
    let omega = all
        .iter()
        .map(|m| crate::geometry::se3::so3_log(&(m.rotation * first.rotation.transpose())))
        .fold(Vec3::zeros(), |a, w| a + w)
        / n;
    let translation = all.iter().fold(Vec3::zeros(), |a, m| a + m.translation) / n;
    Se3 { rotation: crate::geometry::se3::so3_exp(&omega) * first.rotation, translation }
}

/// Two visits with identical camera detections are one visit given twice.
fn check_distinct(visits: &[SurveyVisit]) -> Result<(), SurveyError> {
    for (again, later) in visits.iter().enumerate() {
        for (first, earlier) in visits[..again].iter().enumerate() {
            let same = later.boards.len() == earlier.boards.len()
                && later.boards.iter().zip(&earlier.boards).all(|(a, b)| a.corners == b.corners);
            if same {
                return Err(SurveyError::DuplicateVisit { first: first + 1, again: again + 1 });
            }
        }
    }
    Ok(())
}

/// The room's board count is what the visits show, and every board is seen twice;
/// returns the visits per board.
fn check_boards(room: &Room, chained: &chain::Chain) -> Result<Vec<usize>, SurveyError> {
    let found = chained.boards.len();
    if found != room.board.count as usize || found > MAX_BOARDS {
        let expected = room.board.count;
        let first_extra = chained.labels.iter().enumerate().find_map(|(v, ls)| {
            ls.iter().position(|l| l.room_board >= expected as usize).map(|i| (v + 1, i))
        });
        return Err(SurveyError::BoardCount { found, expected, first_extra });
    }
    let mut seen = vec![0usize; found];
    for labels in &chained.labels {
        for l in labels {
            seen[l.room_board] += 1;
        }
    }
    if let Some(board) = seen.iter().position(|&n| n < 2) {
        let (visit, index) = chained
            .labels
            .iter()
            .enumerate()
            .find_map(|(v, ls)| ls.iter().position(|l| l.room_board == board).map(|i| (v, i)))
            .unwrap_or((0, 0));
        return Err(SurveyError::BoardSeenOnce { board, visit: visit + 1, index });
    }
    Ok(seen)
}

/// A visit's measurements relabelled to the room's boards: a half-turned detection's
/// corners and holes are re-indexed into the room board's frame.
fn bundle_visit(
    spec: &BoardSpec,
    visit: &SurveyVisit,
    labels: &[chain::ChainedBoard],
    planes: &[(usize, PlanePoints)],
) -> BundleVisit {
    let boards = visit
        .boards
        .iter()
        .zip(labels)
        .map(|(board, label)| {
            let (corners, holes_lidar) = if label.half_turned {
                half_turned(spec, board)
            } else {
                (board.corners.clone(), board.holes_lidar.clone())
            };
            BundleBoard {
                room_board: label.room_board,
                corners,
                holes_lidar,
                hole_sigma_px: board.hole_sigma_px,
                plane: board.plane,
            }
        })
        .collect();
    BundleVisit { corner_sigma_px: visit.corner_sigma_px, boards, planes: planes.to_vec() }
}

/// A half-turned detection's corners and holes in the room board's order: what it calls
/// point `i` (at `X_i` in its frame) is the room board's point at `H X_i`.
fn half_turned(spec: &BoardSpec, board: &VisitBoard) -> (Vec<Vec2>, Vec<Vec3>) {
    let turn = half_turn();
    let corner_model: Vec<Vec3> = (0..spec.corner_count()).map(|i| spec.corner(i)).collect();
    let hole_model: Vec<Vec3> = (0..spec.holes.len()).map(|h| spec.hole(h)).collect();
    let mut corners = board.corners.clone();
    for (i, c) in board.corners.iter().enumerate() {
        corners[nearest(&corner_model, &turn.act(&corner_model[i]))] = *c;
    }
    let mut holes = board.holes_lidar.clone();
    for (i, h) in board.holes_lidar.iter().enumerate() {
        holes[nearest(&hole_model, &turn.act(&hole_model[i]))] = *h;
    }
    (corners, holes)
}

fn nearest(points: &[Vec3], p: &Vec3) -> usize {
    (0..points.len())
        .min_by(|&a, &b| (points[a] - p).norm().total_cmp(&(points[b] - p).norm()))
        .unwrap_or(0)
}

/// The `[survey]` table of a solution.
fn survey_spec(
    visits: usize,
    state: &SurveyState,
    board_sigma: &[Sigma],
    plane_sigma: &[Sigma],
    names: &[&str],
) -> SurveySpec {
    let mut spec = SurveySpec {
        visits: visits as u32,
        frame: heapless::String::new(),
        boards: heapless::Vec::new(),
        planes: heapless::Vec::new(),
        covariance: Vec::new(),
    };
    let _ = spec.frame.push_str(&FRAME[..FRAME.len().min(crate::target::MAX_SURVEY_TEXT)]);
    for (pose, sigma) in state.boards.iter().zip(board_sigma) {
        let _ = spec.boards.push(SurveyedBoard {
            rotation: rows(&pose.rotation),
            translation: pose.translation.into(),
            sigma_m: sigma.m,
            sigma_deg: sigma.deg,
        });
    }
    for ((plane, sigma), name) in state.planes.iter().zip(plane_sigma).zip(names) {
        let mut text = heapless::String::new();
        let _ = text.push_str(&name[..name.len().min(crate::target::MAX_PLANE_NAME)]);
        let _ = spec.planes.push(SurveyedPlane {
            name: text,
            normal: plane.normal.into(),
            offset: plane.offset,
            sigma_m: sigma.m,
            sigma_deg: sigma.deg,
        });
    }
    spec
}

fn rows(m: &Mat3) -> [[f64; 3]; 3] {
    core::array::from_fn(|i| core::array::from_fn(|j| m[(i, j)]))
}

fn same_points(a: &[Vec3], b: &[Vec3]) -> bool {
    a.len() == b.len() && !a.is_empty() && a.iter().all(|p| b.contains(p))
}

fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}
