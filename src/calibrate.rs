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
//! 4. **Gate** (`target::QualitySpec`): residuals, boards, coverage, σ, and the change from
//!    the calibration in force.

use crate::detect::holes::{HoleConfig, HoleDetector};
use crate::detect::{ChessboardDetector, DetectError, GreyImage};
use crate::geometry::{Camera, CameraModel, Se3, Vec2, Vec3};
use crate::result::{
    BoardDetection, CalibrationResult, CameraResult, Extrinsic, Quality, Status, Uncertainty,
};
use crate::solve::{
    covariance, covariance::with_fixed_intrinsics, hole_sigma_px, init::kabsch_from_pairs,
    initialise, BoardObservation, IntrinsicsSeed, JointParams, JointProblem, LmOptions, Loss,
    ParamMask, PlanePoints, SharedCovariance, SolveError, SolveReport,
};
use crate::target::{BoardSpec, Room};

pub mod survey;

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
    /// Leaves the LiDAR's board-plane points out of the joint solve (the paper's cost
    /// alone; for comparisons).
    pub without_planes: bool,
}

/// One board observation as the solver used it.
#[derive(Clone, Debug, PartialEq)]
pub struct UsedBoard {
    pub frame: u32,
    pub corners: Vec<Vec2>,
    /// The LiDAR's hole centres in the room's hole order (empty when unpaired).
    pub holes_lidar: Vec<Vec3>,
    /// Board → camera, as solved.
    pub pose: Se3,
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
}

impl Calibration {
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

/// The detectors of a room, with their workspaces (made once, reused for every frame).
pub struct Detectors {
    spec: BoardSpec,
    chess: ChessboardDetector,
    holes: HoleDetector,
    found_holes: Vec<crate::detect::holes::LidarBoard>,
}

impl Detectors {
    /// Detectors for the room's board and camera.
    pub fn new(room: &Room) -> Result<Self, DetectError> {
        Ok(Detectors {
            spec: room.board.clone(),
            chess: ChessboardDetector::new(room.camera.width, room.camera.height, &room.board)?,
            holes: HoleDetector::new(&room.board, HoleConfig::default()),
            found_holes: Vec::new(),
        })
    }

    /// Every board the LiDAR places in the cloud, with its hole centres.
    pub fn detect_cloud(&mut self, points: &[crate::lidar::Point]) -> Vec<LidarBoard> {
        self.holes.detect(points, &mut self.found_holes);
        self.found_holes
            .iter()
            .map(|b| LidarBoard {
                holes: b.holes.to_vec(),
                sigma_m: median(b.hole_sigma_m.iter().copied()),
                plane: plane_points(
                    &self.spec,
                    &b.pose,
                    PLANE_CUT_SIGMAS * b.plane_rms_m.max(PLANE_MIN_SIGMA_M),
                    points.iter().map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64)),
                ),
            })
            .collect()
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

/// Points farther than this many plane σ from a board's plane are not its face.
const PLANE_CUT_SIGMAS: f64 = 3.0;
/// Floor of the per-point plane σ (m): no LiDAR ranges better than this.
const PLANE_MIN_SIGMA_M: f64 = 0.002;
/// Points this close to the board's outline or a hole's rim are left out of the plane
/// term (m): beams there hit partly the board, partly what is behind it.
const PLANE_EDGE_MARGIN_M: f64 = 0.03;

/// The points on the face of a board placed at `board_to_lidar`: within `cut_m` of its
/// plane, inside its outline and outside its holes (with a margin), summarised with their
/// own RMS distance from the plane as σ. `None` when too few remain.
pub fn plane_points(
    spec: &BoardSpec,
    board_to_lidar: &Se3,
    cut_m: f64,
    points: impl Iterator<Item = Vec3>,
) -> Option<PlanePoints> {
    let to_board = board_to_lidar.inverse();
    let (half_w, half_h) =
        (spec.width / 2.0 - PLANE_EDGE_MARGIN_M, spec.height / 2.0 - PLANE_EDGE_MARGIN_M);
    let keep_out = spec.hole_radius + PLANE_EDGE_MARGIN_M;
    let on_face = |p: &Vec3| {
        let b = to_board.act(p);
        b.z.abs() <= cut_m
            && b.x.abs() <= half_w
            && b.y.abs() <= half_h
            && (0..spec.holes.len())
                .all(|h| (spec.hole(h) - Vec3::new(b.x, b.y, 0.0)).norm() >= keep_out)
    };
    let face: Vec<Vec3> = points.filter(on_face).collect();
    let normal = board_to_lidar.rotation.column(2).into_owned();
    let origin = board_to_lidar.translation;
    let sum_sq: f64 = face.iter().map(|p| normal.dot(&(p - origin)).powi(2)).sum();
    let sigma = (sum_sq / face.len().max(1) as f64).sqrt().max(PLANE_MIN_SIGMA_M);
    PlanePoints::from_points(face, sigma)
}

/// Runs association, start, joint solve and gate on one set of detections.
pub fn calibrate(
    room: &Room,
    frames: &[FrameDetections],
    options: &CalibrateOptions,
) -> Calibration {
    let fallback_camera = nominal_camera(room, default_fov(room.camera.model));
    match solve_all(room, frames, options) {
        Ok(mut calibration) => {
            if let Err(reason) = gate(room, frames, options, &calibration) {
                calibration.result.status = Status::Rejected;
                calibration.result.reason = Some(reason);
            }
            calibration
        }
        Err(reason) => Calibration {
            result: rejected(&fallback_camera, reason, room.lidar.is_some()),
            camera: fallback_camera,
            lidar_to_camera: None,
            boards: Vec::new(),
            holes_board: Vec::new(),
            iterations: 0,
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

fn solve_all(
    room: &Room,
    frames: &[FrameDetections],
    options: &CalibrateOptions,
) -> Result<Calibration, String> {
    let object: Vec<Vec3> = (0..room.board.corner_count()).map(|i| room.board.corner(i)).collect();
    let holes_board: Vec<Vec3> = (0..room.board.holes.len()).map(|h| room.board.hole(h)).collect();
    let camera_boards: Vec<(u32, &CameraBoard)> = frames
        .iter()
        .enumerate()
        .flat_map(|(f, d)| d.camera.iter().map(move |b| (f as u32, b)))
        .filter(|(_, b)| b.corners.len() == object.len())
        .take(MAX_OBSERVATIONS)
        .collect();
    if camera_boards.is_empty() {
        return Err("no complete checkerboard was detected in any image".into());
    }
    let corner_sigma = median(camera_boards.iter().map(|(_, b)| b.sigma_px)).max(0.02);
    let (camera, poses, mut iterations) =
        intrinsics_start(room, &object, &camera_boards, corner_sigma)?;

    let pairs = match &room.lidar {
        Some(lidar) => {
            associate(&lidar_nominal(lidar), frames, &camera_boards, &poses, &holes_board)
        }
        None => vec![None; camera_boards.len()],
    };
    let hole_sigmas: Vec<Option<f64>> = pairs
        .iter()
        .zip(&poses)
        .map(|(pair, pose)| {
            pair.as_ref().map(|p| hole_sigma_px(camera.fx, p.sigma_m, pose.translation.z))
        })
        .collect();
    let mut problem: JointProblem<'_, MAX_OBSERVATIONS> =
        JointProblem::new(corner_sigma, 2.0, Loss::Huber(3.0));
    for (((_, board), pair), sigma) in camera_boards.iter().zip(&pairs).zip(&hole_sigmas) {
        let (hb, hl): (&[Vec3], &[Vec3]) = match pair {
            Some(p) => (&holes_board, &p.holes_lidar),
            None => (&[], &[]),
        };
        problem
            .add_board(BoardObservation {
                object: &object,
                corners: &board.corners,
                holes_board: hb,
                holes_lidar: hl,
                hole_sigma_px: *sigma,
                plane: pair.as_ref().and_then(|p| p.plane).filter(|_| !options.without_planes),
            })
            .map_err(solver_reason)?;
    }
    let (mut params, _) =
        initialise(&problem, camera, IntrinsicsSeed::Given).map_err(solver_reason)?;
    let mut mask = ParamMask::free();
    if options.two_stage {
        mask = mask.fix_intrinsics();
    }
    let report = problem
        .solve(&mut params, &LmOptions { mask, ..LmOptions::default() })
        .map_err(solver_reason)?;
    iterations += report.iterations;
    let sigma = if options.two_stage && problem.has_holes() {
        // The intrinsics came from the corners alone: their σ is that stage's, and it
        // carries into the extrinsic the second stage solved with them held.
        let corners_only = corner_covariance(&problem, &params)?;
        with_fixed_intrinsics(&problem, &params, &corners_only)
    } else {
        covariance(&problem, &params, mask)
    }
    .map_err(solver_reason)?
    .uncertainty();
    let with_lidar = room.lidar.is_some() && problem.has_holes();
    if room.lidar.is_some() && !with_lidar {
        return Err("no LiDAR board could be paired with a camera board".into());
    }
    let boards: Vec<UsedBoard> = camera_boards
        .iter()
        .zip(&pairs)
        .zip(params.board_poses.iter())
        .map(|(((frame, board), pair), pose)| UsedBoard {
            frame: *frame,
            corners: board.corners.clone(),
            holes_lidar: pair.as_ref().map_or(Vec::new(), |p| p.holes_lidar.clone()),
            pose: *pose,
        })
        .collect();
    let result = accepted(&params, &report, &sigma, &boards, with_lidar);
    Ok(Calibration {
        result,
        camera: params.camera,
        lidar_to_camera: with_lidar.then_some(params.lidar_to_camera),
        boards,
        holes_board: holes_board.clone(),
        iterations,
    })
}

/// The covariance of the intrinsics that the corners of `problem`'s boards alone give at
/// `params`.
fn corner_covariance(
    problem: &JointProblem<'_, MAX_OBSERVATIONS>,
    params: &JointParams<Camera, MAX_OBSERVATIONS>,
) -> Result<SharedCovariance, String> {
    let mut corners: JointProblem<'_, MAX_OBSERVATIONS> =
        JointProblem::new(problem.corner_sigma_px, problem.hole_sigma_px, problem.loss);
    for board in problem.boards() {
        let only =
            BoardObservation { object: board.object, corners: board.corners, ..Default::default() };
        corners.add_board(only).map_err(solver_reason)?;
    }
    covariance(&corners, params, ParamMask::free()).map_err(solver_reason)
}

/// Two starts whose final costs agree within this fraction reached the same minimum.
const SAME_MINIMUM: f64 = 1e-9;

/// Intrinsics and board poses from the corners alone, from the best of several starts,
/// tried in order until two of them reach the same lowest minimum. (One start fitting the
/// corners nearly as well as their noise allows is not enough: on a 90° lens the closed
/// form's own minimum lay 1.4 % off in focal length and 14 px in cx.)
fn intrinsics_start(
    room: &Room,
    object: &[Vec3],
    boards: &[(u32, &CameraBoard)],
    corner_sigma: f64,
) -> Result<(Camera, Vec<Se3>, usize), String> {
    let mut problem: JointProblem<'_, MAX_OBSERVATIONS> =
        JointProblem::new(corner_sigma, 1.0, Loss::Huber(3.0));
    for (_, board) in boards {
        problem
            .add_board(BoardObservation {
                object,
                corners: &board.corners,
                ..BoardObservation::default()
            })
            .map_err(solver_reason)?;
    }
    let model = room.camera.model;
    let mut seeds: Vec<(Camera, IntrinsicsSeed)> = Vec::new();
    let zhang = IntrinsicsSeed::Zhang { width: room.camera.width, height: room.camera.height };
    if model == CameraModel::PinholeRadtan {
        seeds.push((nominal_camera(room, default_fov(model)), zhang));
    }
    if room.camera.fx.is_some() {
        seeds.push((nominal_camera(room, default_fov(model)), IntrinsicsSeed::Given));
    }
    for &fov in fov_guesses(model) {
        let mut guess = nominal_camera(room, fov);
        let plain = Camera::from_fov(model, room.camera.width, room.camera.height, fov, [0.0; 5]);
        (guess.fx, guess.fy) = (plain.fx, plain.fy);
        seeds.push((guess, IntrinsicsSeed::Given));
    }
    let mut best: Option<(f64, JointParams<Camera, MAX_OBSERVATIONS>)> = None;
    let mut iterations = 0;
    let mut last_error = None;
    for (camera, seed) in seeds {
        let attempt = initialise(&problem, camera, seed).and_then(|(mut params, _)| {
            let report = problem.solve(&mut params, &LmOptions::default())?;
            Ok((report, params))
        });
        match attempt {
            Ok((report, params)) => {
                iterations += report.iterations;
                let cost = report.final_cost;
                let confirmed = best.as_ref().is_some_and(|(best_cost, _)| {
                    (cost - best_cost).abs() <= SAME_MINIMUM * best_cost.abs().max(1.0)
                });
                if best.as_ref().is_none_or(|(best_cost, _)| cost < *best_cost) {
                    best = Some((cost, params));
                }
                if confirmed {
                    break;
                }
            }
            Err(e) => last_error = Some(e),
        }
    }
    match best {
        Some((_, params)) => Ok((params.camera, params.board_poses.to_vec(), iterations)),
        None => Err(format!(
            "no start for the intrinsics converged ({})",
            last_error.map_or("no seed".into(), solver_reason)
        )),
    }
}

/// A LiDAR board paired with camera board observation, holes in the room's order.
#[derive(Clone, Debug, PartialEq)]
struct Pair {
    holes_lidar: Vec<Vec3>,
    sigma_m: f64,
    plane: Option<PlanePoints>,
}

fn lidar_nominal(lidar: &crate::target::LidarSpec) -> Se3 {
    Se3 { rotation: lidar.rotation_matrix(), translation: lidar.translation_vector() }
}

/// Gates (m) between a LiDAR board's hole centroid carried into the camera and the
/// camera board's: loose for the nominal mounting, then tight once re-estimated.
const ASSOCIATION_GATES_M: [f64; 3] = [1.0, 0.3, 0.1];

/// Pairs LiDAR boards with camera boards (per frame) and orders their holes; returns,
/// per camera board observation, its pair if any.
fn associate(
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
        let correspondences = pairs.iter().zip(poses).flat_map(|(pair, pose)| {
            pair.iter().flat_map(move |p: &Pair| {
                p.holes_lidar.iter().zip(holes_board).map(move |(l, h)| (*l, pose.act(h)))
            })
        });
        match kabsch_from_pairs(correspondences) {
            Ok(better) => extrinsic = better,
            Err(_) => break,
        }
    }
    pairs
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
            pairs[c] = Some(Pair { holes_lidar, sigma_m: lidar.sigma_m, plane: lidar.plane });
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

fn accepted(
    params: &JointParams<Camera, MAX_OBSERVATIONS>,
    report: &SolveReport,
    sigma: &crate::solve::Uncertainty,
    boards: &[UsedBoard],
    with_lidar: bool,
) -> CalibrationResult {
    CalibrationResult {
        status: Status::Accepted,
        reason: None,
        camera: CameraResult::from_camera(&params.camera),
        lidar_to_camera: with_lidar.then(|| Extrinsic::from_se3(&params.lidar_to_camera)),
        uncertainty: Uncertainty {
            fx: sigma.fx,
            fy: sigma.fy,
            cx: sigma.cx,
            cy: sigma.cy,
            rotation_deg: if with_lidar { sigma.rotation_deg } else { 0.0 },
            translation_m: if with_lidar { sigma.translation_m } else { 0.0 },
        },
        quality: Quality {
            corner_rms_px: report.corner_rms_px,
            hole_rms_px: report.hole_rms_px,
            boards: boards.len() as u32,
        },
        boards: boards
            .iter()
            .map(|b| BoardDetection {
                frame: b.frame,
                corners_px: b.corners.iter().map(|c| [c.x, c.y]).collect(),
                holes_lidar: if with_lidar {
                    b.holes_lidar.iter().map(|h| [h.x, h.y, h.z]).collect()
                } else {
                    Vec::new()
                },
            })
            .collect(),
    }
}

fn rejected(camera: &Camera, reason: String, with_lidar: bool) -> CalibrationResult {
    CalibrationResult {
        status: Status::Rejected,
        reason: Some(reason),
        camera: CameraResult::from_camera(camera),
        lidar_to_camera: with_lidar.then(|| Extrinsic::from_se3(&Se3::identity())),
        uncertainty: Uncertainty::default(),
        quality: Quality::default(),
        boards: Vec::new(),
    }
}

/// The quality gate: `Err(reason)` names the first threshold the run fails.
fn gate(
    room: &Room,
    frames: &[FrameDetections],
    options: &CalibrateOptions,
    run: &Calibration,
) -> Result<(), String> {
    let q = &room.quality;
    let r = &run.result;
    let min_boards = q.min_boards.unwrap_or(room.board.count) as usize;
    for (f, frame) in frames.iter().enumerate() {
        let complete = run.boards.iter().filter(|b| b.frame as usize == f).count();
        if complete < min_boards {
            return Err(format!(
                "frame {f}: {complete} complete boards seen by the camera, the room needs {min_boards} ({} detected in all)",
                frame.camera.len()
            ));
        }
    }
    check(r.quality.corner_rms_px <= q.max_corner_rms_px, || {
        format!("corner RMS {:.3} px exceeds {} px", r.quality.corner_rms_px, q.max_corner_rms_px)
    })?;
    let coverage = coverage(&run.camera, &run.boards);
    check(coverage >= q.min_coverage, || {
        format!(
            "corners cover {:.0} % of the image, at least {:.0} % needed",
            coverage * 100.0,
            q.min_coverage * 100.0
        )
    })?;
    let u = &r.uncertainty;
    let c = &r.camera;
    check(u.fx <= q.max_sigma_focal_rel * c.fx && u.fy <= q.max_sigma_focal_rel * c.fy, || {
        format!(
            "focal length uncertain: σ fx {:.2} px, fy {:.2} px (limit {} %)",
            u.fx,
            u.fy,
            q.max_sigma_focal_rel * 100.0
        )
    })?;
    check(u.cx <= q.max_sigma_principal_px && u.cy <= q.max_sigma_principal_px, || {
        format!(
            "principal point uncertain: σ cx {:.2} px, cy {:.2} px (limit {} px)",
            u.cx, u.cy, q.max_sigma_principal_px
        )
    })?;
    if run.lidar_to_camera.is_some() {
        let lidar_boards = run.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count();
        check(lidar_boards >= q.min_lidar_boards as usize, || {
            format!(
                "{lidar_boards} boards seen by both sensors, at least {} needed",
                q.min_lidar_boards
            )
        })?;
        check(r.quality.hole_rms_px <= q.max_hole_rms_px, || {
            format!("hole RMS {:.3} px exceeds {} px", r.quality.hole_rms_px, q.max_hole_rms_px)
        })?;
        check(
            u.rotation_deg <= q.max_sigma_rotation_deg
                && u.translation_m <= q.max_sigma_translation_m,
            || {
                format!(
                    "extrinsic uncertain: σ {:.3}° / {:.1} mm (limits {}° / {} mm)",
                    u.rotation_deg,
                    u.translation_m * 1000.0,
                    q.max_sigma_rotation_deg,
                    q.max_sigma_translation_m * 1000.0
                )
            },
        )?;
    }
    if let Some(current) = &options.current {
        check_change(q, current, r)?;
    }
    Ok(())
}

/// The change limits against the calibration in force.
fn check_change(
    q: &crate::target::QualitySpec,
    current: &CalibrationResult,
    new: &CalibrationResult,
) -> Result<(), String> {
    let (a, b) = (&current.camera, &new.camera);
    let focal = ((b.fx - a.fx) / a.fx).abs().max(((b.fy - a.fy) / a.fy).abs());
    check(focal <= q.max_change_focal_rel, || {
        format!(
            "focal length moved {:.2} % from the current calibration (limit {} %)",
            focal * 100.0,
            q.max_change_focal_rel * 100.0
        )
    })?;
    let principal = (b.cx - a.cx).hypot(b.cy - a.cy);
    check(principal <= q.max_change_principal_px, || {
        format!(
            "principal point moved {principal:.1} px from the current calibration (limit {} px)",
            q.max_change_principal_px
        )
    })?;
    if let (Some(x), Some(y)) = (&current.lidar_to_camera, &new.lidar_to_camera) {
        let (angle, shift) = x.difference(y);
        check(angle <= q.max_change_rotation_deg && shift <= q.max_change_translation_m, || {
            format!(
                "extrinsic moved {angle:.2}° / {:.0} mm from the current calibration (limits {}° / {} mm)",
                shift * 1000.0,
                q.max_change_rotation_deg,
                q.max_change_translation_m * 1000.0
            )
        })?;
    }
    Ok(())
}

fn check(ok: bool, reason: impl FnOnce() -> String) -> Result<(), String> {
    if ok {
        Ok(())
    } else {
        Err(reason())
    }
}

/// Fraction of a 4×4 grid of image cells that hold at least one used corner.
pub fn coverage(camera: &Camera, boards: &[UsedBoard]) -> f64 {
    let mut cells = [false; 16];
    for c in boards.iter().flat_map(|b| &b.corners) {
        let i = ((c.x / camera.width as f64 * 4.0).floor() as usize).min(3);
        let j = ((c.y / camera.height as f64 * 4.0).floor() as usize).min(3);
        cells[j * 4 + i] = true;
    }
    cells.iter().filter(|&&c| c).count() as f64 / 16.0
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

fn solver_reason(e: SolveError) -> String {
    format!("the solver failed: {e}")
}
