//! The free-board model: every board observation has its own pose. Intrinsics start from
//! several seeds on the corners, then the joint solve over corners, holes and board faces.

use super::association::{associate, lidar_nominal};
use super::faces::{expected_face, EXPECTED_FACE_CUT_M};
use super::register::register_by_faces;
use super::{
    default_fov, fov_guesses, median, nominal_camera, CalibrateOptions, Calibration, CameraBoard,
    FrameDetections, MisplacedHoles, SolveFailure, UsedBoard, MAX_OBSERVATIONS,
};
use crate::geometry::{Camera, CameraModel, Se3, Vec3};
use crate::lidar::Point;
use crate::result::{
    BoardDetection, CalibrationResult, CameraResult, Extrinsic, Quality, Status, Uncertainty,
};
use crate::solve::{
    covariance, covariance::with_fixed_intrinsics, hole_sigma_px, initialise, BoardObservation,
    IntrinsicsSeed, JointParams, JointProblem, LmOptions, Loss, ParamMask, PlanePoints,
    SharedCovariance, SolveReport,
};
use crate::target::Room;

/// A board's hole RMS this many times the median of the others' marks its LiDAR
/// placement as wrong (a board placed with its holes turned in its plane)…
pub const HOLE_OUTLIER_RATIO: f64 = 5.0;
/// …when it is also above this (px): below it every board agrees well enough.
pub const HOLE_OUTLIER_FLOOR_PX: f64 = 1.0;

/// The free-board run: [`solve_all`], then, when one board's hole residuals are far
/// above the others' ([`HOLE_OUTLIER_RATIO`]), that board's LiDAR placement is named,
/// left out, and the run solved again (once).
pub(super) fn solve_free(
    room: &Room,
    frames: &[FrameDetections],
    clouds: &[&[Point]],
    options: &CalibrateOptions,
) -> Result<Calibration, SolveFailure> {
    let first = solve_all(room, frames, clouds, options)?;
    let Some((index, worst, median)) = hole_outlier(room, &first) else {
        return Ok(first);
    };
    let board = &first.boards[index];
    let frame = board.frame as usize;
    let misplaced = MisplacedHoles {
        frame: board.frame,
        board: first.boards[..index].iter().filter(|b| b.frame == board.frame).count(),
        surveyed: false,
        rms_px: worst,
        median_px: median,
    };
    tracing::warn!("{misplaced}");
    let mut without = frames.to_vec();
    without[frame].lidar.retain(|l| !same_holes(&l.holes, &board.holes_lidar));
    let mut second = solve_all(room, &without, clouds, options).map_err(|e| {
        SolveFailure::AfterLeavingOut { error: Box::new(e), misplaced: misplaced.clone() }
    })?;
    second.notes.push(misplaced.to_string());
    Ok(second)
}

/// The used board whose hole RMS stands out, with it and the others' median (px).
pub(super) fn hole_outlier(room: &Room, run: &Calibration) -> Option<(usize, f64, f64)> {
    let rms: Vec<(usize, f64)> = run
        .boards
        .iter()
        .enumerate()
        .filter_map(|(i, b)| run.board_rms(&room.board, b).1.map(|h| (i, h)))
        .collect();
    if rms.len() < 3 {
        return None; // with two boards, which one is wrong is not decidable
    }
    let (index, worst) = rms.iter().copied().max_by(|a, b| a.1.total_cmp(&b.1))?;
    let median = median(rms.iter().filter(|(i, _)| *i != index).map(|(_, h)| *h));
    (worst > HOLE_OUTLIER_FLOOR_PX && worst > HOLE_OUTLIER_RATIO * median)
        .then_some((index, worst, median))
}

/// Whether two hole sets are the same points in any order.
fn same_holes(a: &[Vec3], b: &[Vec3]) -> bool {
    a.len() == b.len() && a.iter().all(|p| b.iter().any(|q| (p - q).norm() < 1e-12))
}

pub(super) fn solve_all(
    room: &Room,
    frames: &[FrameDetections],
    clouds: &[&[Point]],
    options: &CalibrateOptions,
) -> Result<Calibration, SolveFailure> {
    let CameraStart {
        object,
        holes_board,
        boards: camera_boards,
        corner_sigma,
        start: CornerStart { camera, poses, mut iterations, .. },
    } = camera_start(room, frames, options.corner_start.as_ref())?;

    let pairs = match &room.lidar {
        Some(lidar) => {
            associate(&lidar_nominal(lidar), frames, &camera_boards, &poses, &holes_board)
        }
        None => vec![None; camera_boards.len()],
    };
    // A LiDAR that placed no board by its holes (a VLP-16) is placed by the boards' faces.
    let faces = match &room.lidar {
        Some(lidar) if pairs.iter().all(Option::is_none) && !options.without_planes => {
            FacesOnly::register(room, &lidar_nominal(lidar), &camera_boards, &poses, clouds)
        }
        _ => None,
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
    for (i, (((_, board), pair), sigma)) in
        camera_boards.iter().zip(&pairs).zip(&hole_sigmas).enumerate()
    {
        let (hb, hl): (&[Vec3], &[Vec3]) = match pair {
            Some(p) => (&holes_board, &p.holes_lidar),
            None => (&[], &[]),
        };
        problem.add_board(BoardObservation {
            object: &object,
            corners: &board.corners,
            holes_board: hb,
            holes_lidar: hl,
            hole_sigma_px: *sigma,
            plane: match &faces {
                Some(f) => f.faces[i],
                None => pair.as_ref().and_then(|p| p.plane).filter(|_| !options.without_planes),
            },
        })?;
    }
    let (mut params, _) = initialise(&problem, camera, IntrinsicsSeed::Given)?;
    if let Some(f) = &faces {
        params.lidar_to_camera = f.start; // no hole pairs to start it from
    }
    let mut mask = ParamMask::free();
    if options.two_stage {
        mask = mask.fix_intrinsics();
    }
    let lm = LmOptions { mask, ..LmOptions::default() };
    let report = problem.solve(&mut params, &lm)?;
    iterations += report.iterations;
    // Once more with each kind's σ from its own residuals (corners, holes, faces): the
    // detector's corner σ and the LiDAR's nominal σ are guesses, and the face points,
    // thousands of them, would otherwise outweigh corners that fit better than guessed.
    let variances = covariance(&problem, &params, mask)?.kind_variances;
    problem.rescale_sigmas(variances);
    let report = problem.solve(&mut params, &lm)?;
    iterations += report.iterations;
    let sigma = if options.two_stage && problem.has_holes() {
        // The intrinsics came from the corners alone: their σ is that stage's, and it
        // carries into the extrinsic the second stage solved with them held.
        let corners_only = corner_covariance(&problem, &params)?;
        with_fixed_intrinsics(&problem, &params, &corners_only)
    } else {
        covariance(&problem, &params, mask)
    }?;
    let pose_covariance = lidar_pose_covariance(&sigma);
    let shared_covariance = sigma.matrix;
    let sigma = sigma.uncertainty();
    let with_lidar = room.lidar.is_some() && (problem.has_holes() || faces.is_some());
    if room.lidar.is_some() && !with_lidar {
        return Err(SolveFailure::NoLidarPair);
    }
    let boards: Vec<UsedBoard> = camera_boards
        .iter()
        .zip(&pairs)
        .zip(params.board_poses.iter())
        .enumerate()
        .map(|(i, (((frame, board), pair), pose))| UsedBoard {
            frame: *frame,
            corners: board.corners.clone(),
            holes_lidar: pair.as_ref().map_or(Vec::new(), |p| p.holes_lidar.clone()),
            hole_sigma_m: pair.as_ref().map_or(0.0, |p| p.sigma_m),
            lidar_face: pair.as_ref().is_some_and(|p| p.plane.is_some())
                || faces.as_ref().is_some_and(|f| f.faces[i].is_some()),
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
        notes: faces.iter().map(FacesOnly::note).collect(),
        pose_covariance: Some(pose_covariance),
        shared_covariance: Some(shared_covariance),
        lidar_planes: 0,
    })
}

/// A LiDAR placed by the boards' faces alone: the registration's start
/// ([`register_by_faces`]) and every camera board's face cut at it (index by index).
struct FacesOnly {
    start: Se3,
    faces: Vec<Option<PlanePoints>>,
}

impl FacesOnly {
    /// From the first frame whose faces place the LiDAR; `None` without sweeps, or when no
    /// frame's do (fewer than three faces, or points that do not lie on them).
    fn register(
        room: &Room,
        nominal: &Se3,
        camera_boards: &[(u32, &CameraBoard)],
        poses: &[Se3],
        clouds: &[&[Point]],
    ) -> Option<FacesOnly> {
        let start = clouds.iter().enumerate().find_map(|(f, cloud)| {
            let frame_poses: Vec<Se3> = (camera_boards.iter().zip(poses))
                .filter(|((frame, _), _)| *frame as usize == f)
                .map(|(_, pose)| *pose)
                .collect();
            register_by_faces(&room.board, &frame_poses, cloud, nominal)
        })?;
        let camera_to_lidar = start.inverse();
        let faces = (camera_boards.iter().zip(poses))
            .map(|((frame, _), pose)| {
                let cloud = clouds.get(*frame as usize)?;
                let board_to_lidar = camera_to_lidar.compose(pose);
                expected_face(&room.board, &board_to_lidar, EXPECTED_FACE_CUT_M, cloud)
            })
            .collect();
        Some(FacesOnly { start, faces })
    }

    fn note(&self) -> String {
        format!(
            "the LiDAR resolved no board's holes: it was placed by {} board faces alone (its σ say how well they hold it)",
            self.faces.iter().flatten().count()
        )
    }
}

/// The extrinsic's 6×6 block of the shared covariance, as [`Calibration::pose_covariance`]
/// holds it (no room pose in the free-board model).
fn lidar_pose_covariance(
    shared: &crate::solve::covariance::SharedCovariance,
) -> super::PoseCovariance {
    let mut out = super::PoseCovariance::zeros();
    let block =
        shared.matrix.fixed_view::<6, 6>(crate::solve::EXT_ROTATION, crate::solve::EXT_ROTATION);
    out.fixed_view_mut::<6, 6>(0, 0).copy_from(&block);
    out
}

/// The covariance of the intrinsics that the corners of `problem`'s boards alone give at
/// `params`.
fn corner_covariance(
    problem: &JointProblem<'_, MAX_OBSERVATIONS>,
    params: &JointParams<Camera, MAX_OBSERVATIONS>,
) -> Result<SharedCovariance, SolveFailure> {
    let mut corners: JointProblem<'_, MAX_OBSERVATIONS> =
        JointProblem::new(problem.corner_sigma_px, problem.hole_sigma_px, problem.loss);
    for board in problem.boards() {
        let only =
            BoardObservation { object: board.object, corners: board.corners, ..Default::default() };
        corners.add_board(only)?;
    }
    covariance(&corners, params, ParamMask::free()).map_err(SolveFailure::Solver)
}

/// Two starts whose final costs agree within this fraction reached the same minimum.
const SAME_MINIMUM: f64 = 1e-9;

/// What both models (free boards, surveyed room) start a run from: the board's corner and
/// hole points, the frames' complete camera boards (frame index, board; at most
/// [`MAX_OBSERVATIONS`]), their median corner σ (at least 0.02 px), and the intrinsics,
/// board poses and corner noise from the corners alone ([`intrinsics_start`]).
pub(super) struct CameraStart<'f> {
    pub object: Vec<Vec3>,
    pub holes_board: Vec<Vec3>,
    pub boards: Vec<(u32, &'f CameraBoard)>,
    pub corner_sigma: f64,
    pub start: CornerStart,
}

/// A camera's intrinsics and board poses from its corners alone ([`intrinsics_start`]),
/// made once and given to every run of the same camera's detections
/// ([`CalibrateOptions::corner_start`]: a rig's pair runs of one camera): it is the costliest
/// part of a run's start (several full solves from several seeds).
#[derive(Clone, Debug, PartialEq)]
pub struct CornerStart {
    pub camera: Camera,
    /// Board → camera of each complete board, in the frames' order.
    pub poses: Vec<Se3>,
    /// The corners' noise per axis (px) the fit shows ([`corner_noise_px`]; the detector's
    /// median σ where the fit cannot show it).
    pub corner_noise_px: f64,
    pub iterations: usize,
}

/// The [`CornerStart`] of `frames` in `room` (its camera and board); an error when no
/// image holds a complete checkerboard.
pub fn corner_start(room: &Room, frames: &[FrameDetections]) -> Result<CornerStart, SolveFailure> {
    Ok(camera_start(room, frames, None)?.start)
}

/// The [`CameraStart`] of `frames`, from `given` when it is these frames' (as many poses
/// as complete boards); an error when no image holds a complete checkerboard.
pub(super) fn camera_start<'f>(
    room: &Room,
    frames: &'f [FrameDetections],
    given: Option<&CornerStart>,
) -> Result<CameraStart<'f>, SolveFailure> {
    let object: Vec<Vec3> = (0..room.board.corner_count()).map(|i| room.board.corner(i)).collect();
    let holes_board: Vec<Vec3> = (0..room.board.holes.len()).map(|h| room.board.hole(h)).collect();
    let boards: Vec<(u32, &CameraBoard)> = frames
        .iter()
        .enumerate()
        .flat_map(|(f, d)| d.camera.iter().map(move |b| (f as u32, b)))
        .filter(|(_, b)| b.corners.len() == object.len())
        .take(MAX_OBSERVATIONS)
        .collect();
    if boards.is_empty() {
        return Err(SolveFailure::NoCompleteBoard);
    }
    let corner_sigma = median(boards.iter().map(|(_, b)| b.sigma_px)).max(0.02);
    let start = match given.filter(|g| g.poses.len() == boards.len()) {
        Some(g) => g.clone(),
        None => intrinsics_start(room, &object, &boards, corner_sigma)?,
    };
    Ok(CameraStart { object, holes_board, boards, corner_sigma, start })
}

/// The corners' noise per axis (px) that a fit leaving `rms_px` (the 2-D RMS over
/// `corners` corners) with a pose for each of `boards` boards and the 9 intrinsics shows:
/// the residuals' sum of squares over their degrees of freedom, at least
/// [`MIN_CORNER_NOISE_PX`]; `None` where the fit has no redundancy to show it.
///
/// This, not the detector's σ, is what corners are weighted by where the relative weight of
/// corners and other information matters (the survey's bundle against the LiDAR, a surveyed
/// calibration against the survey's priors). The detector's σ are about twice the corners'
/// actual error (simulated renders: it reports 0.031–0.035 px per axis, the
/// residuals show 0.014–0.016 px, the truth 0.012–0.02 px), which weighed the corners 4–5×
/// too lightly and made every surveyed σ 1.6–2× its bound.
pub(super) fn corner_noise_px(rms_px: f64, corners: usize, boards: usize) -> Option<f64> {
    let residuals = 2 * corners;
    let parameters = 9 + 6 * boards;
    if residuals <= parameters || !rms_px.is_finite() {
        return None;
    }
    let sum_of_squares = rms_px * rms_px * corners as f64;
    Some((sum_of_squares / (residuals - parameters) as f64).sqrt().max(MIN_CORNER_NOISE_PX))
}

/// [`corner_noise_px`] of a run's corners (a pose per board counted, as the free-board
/// model has; the surveyed room's priors hold its boards little against the corners).
pub(super) fn run_corner_noise_px(run: &Calibration) -> Option<f64> {
    let corners = run.boards.iter().map(|b| b.corners.len()).sum();
    corner_noise_px(run.result.quality.corner_rms_px, corners, run.boards.len())
}

/// The least corner noise (px per axis) a fit is taken to show: below this a fit's
/// residuals say more about a too-good render than about the corners.
pub(super) const MIN_CORNER_NOISE_PX: f64 = 0.005;

/// Intrinsics and board poses from the corners alone, from the best of several starts,
/// tried in order until two of them reach the same lowest minimum. (One start fitting the
/// corners nearly as well as their noise allows is not enough: on a 90° lens the closed
/// form's own minimum lay 1.4 % off in focal length and 14 px in cx.)
fn intrinsics_start(
    room: &Room,
    object: &[Vec3],
    boards: &[(u32, &CameraBoard)],
    corner_sigma: f64,
) -> Result<CornerStart, SolveFailure> {
    let mut problem: JointProblem<'_, MAX_OBSERVATIONS> =
        JointProblem::new(corner_sigma, 1.0, Loss::Huber(3.0));
    for (_, board) in boards {
        problem.add_board(BoardObservation {
            object,
            corners: &board.corners,
            ..BoardObservation::default()
        })?;
    }
    let seeds = intrinsics_seeds(room);
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
        Some((_, params)) => {
            let (rms_px, _) = problem.rms_px(&params)?;
            Ok(CornerStart {
                camera: params.camera,
                poses: params.board_poses.to_vec(),
                corner_noise_px: corner_noise_px(rms_px, object.len() * boards.len(), boards.len())
                    .unwrap_or(corner_sigma),
                iterations,
            })
        }
        None => Err(SolveFailure::NoStart(last_error)),
    }
}

/// The starts [`intrinsics_start`] tries, in order: Zhang's closed form, the room's
/// intrinsics when it gives a focal length, then the fields of view. With a focal length
/// those are tried nearest it first (in ratio), and a guess within 5 % of it is left out: it
/// is the room's start again, which would confirm nothing. (A 90° lens with the fields of
/// view from the narrowest spent 394 LM iterations on its start, 200 of them on the 45° and
/// 60° guesses, which never converged; nearest first, 194.)
fn intrinsics_seeds(room: &Room) -> Vec<(Camera, IntrinsicsSeed)> {
    let model = room.camera.model;
    let zhang = (model == CameraModel::PinholeRadtan).then(|| {
        let seed = IntrinsicsSeed::Zhang { width: room.camera.width, height: room.camera.height };
        (nominal_camera(room, default_fov(model)), seed)
    });
    let mut guesses: Vec<(Camera, IntrinsicsSeed)> = fov_guesses(model)
        .iter()
        .map(|&fov| {
            let mut guess = nominal_camera(room, fov);
            let plain =
                Camera::from_fov(model, room.camera.width, room.camera.height, fov, [0.0; 5]);
            (guess.fx, guess.fy) = (plain.fx, plain.fy);
            (guess, IntrinsicsSeed::Given)
        })
        .collect();
    let Some(fx) = room.camera.fx else {
        return zhang.into_iter().chain(guesses).collect();
    };
    // How far a guess's focal length is from the room's, as a ratio either way.
    let off = |c: &Camera| libm::log(c.fx / fx).abs();
    guesses.retain(|(c, _)| off(c) > libm::log(1.05));
    guesses.sort_by(|a, b| off(&a.0).total_cmp(&off(&b.0)));
    let given = (nominal_camera(room, default_fov(model)), IntrinsicsSeed::Given);
    zhang.into_iter().chain(std::iter::once(given)).chain(guesses).collect()
}

pub(super) fn accepted(
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
                ..BoardDetection::default()
            })
            .collect(),
        camera_in_room: None,
        projection_uncertainty: None,
    }
}

pub(super) fn rejected(
    camera: &Camera,
    reason: &SolveFailure,
    with_lidar: bool,
) -> CalibrationResult {
    CalibrationResult {
        status: Status::Rejected,
        reason: Some(reason.to_string()),
        camera: CameraResult::from_camera(camera),
        lidar_to_camera: with_lidar.then(|| Extrinsic::from_se3(&Se3::identity())),
        uncertainty: Uncertainty::default(),
        quality: Quality::default(),
        boards: Vec::new(),
        camera_in_room: None,
        projection_uncertainty: None,
    }
}
