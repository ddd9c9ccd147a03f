//! Calibration in a surveyed room (the room file has a `[survey]`): the room is one rigid
//! target. The camera boards are identified against the survey ([`super::identify`]),
//! which also gives the vehicle's room→camera pose; the LiDAR's boards are paired as in
//! the free model; the LiDAR's points near every surveyed plane are selected with the
//! room pose and the extrinsic (registration against the room model, no global search);
//! then the rig problem with one camera and one LiDAR (`solve::room`) refines intrinsics,
//! extrinsic, ONE room→camera pose (frames are a standing vehicle) and every seen board
//! and plane within its survey σ.
//!
//! A board whose solved pose lies far outside its survey σ (moved, knocked over) is
//! named, left out, and the room solved again; two such boards reject the run. When the
//! survey has its joint covariance the room is then solved once more, every block moved
//! by the covariance's modes ([`super::modes`], [`crate::solve::room_modes`]): the result
//! and its σ are that solve's.

use super::association::{associate, lidar_nominal, paired_extrinsic};
use super::faces::expected_face;
use super::free::{accepted, camera_start, hole_outlier, CameraStart, CornerStart};
use super::identify::{identify, oriented, Identity};
use super::modes::{SurveyEntry, SurveyModes};
use super::{
    Calibration, CameraBoard, FindLidarBoards, FrameDetections, LidarBoard, MisplacedHoles,
    SolveFailure, UsedBoard, MAX_OBSERVATIONS,
};
use crate::detect::holes::EXPECTED_REACH_M;
use crate::detect::planes::{
    select_plane_points, trimmed_plane_points, PlaneCut, PlaneSelection, PLANE_FLOOR_SIGMA_M,
};
use crate::geometry::{Camera, Se3, Vec3};
use crate::lidar::Point;
use crate::result::Extrinsic;
use crate::solve::rig::{plane_frame, rig_covariance, solve_rig, BlockPrior};
use crate::solve::room::{pair_observation, RoomParams, RoomProblem, RoomReport, ROOM_SHARED};
use crate::solve::room_modes::{
    modes_covariance, solve_modes, ModeBasis, ModesParams, ModesProblem,
};
use crate::solve::schur::SchurProblem;
use crate::solve::{
    covariance::SharedCovariance, hole_sigma_px, BoardObservation, JointParams, Loss, ParamMask,
    PlanePoints, SolveReport, Termination, SHARED,
};
use crate::target::{Room, SurveySpec};

/// A board disagrees with the survey when `|prior residual|²` (6 rows, whitened by the
/// survey's σ) exceeds this: χ²₆ passes 36 with probability 5·10⁻⁶.
pub const MOVED_BOARD_CHI2: f64 = 36.0;
/// Points within this distance (m) of a surveyed plane predicted from the start are
/// its candidates; later selections are 3σ of each point's own noise ([`room_planes`]).
const PLANE_START_CUT_M: f64 = 0.10;
/// Points closer than this to a board's centre (m, in the room) are its face, not a plane.
const PLANE_BOARD_CLEARANCE_M: f64 = 1.0;

type Problem<'a> = RoomProblem<'a, MAX_OBSERVATIONS>;
type Params = RoomParams<Camera, MAX_OBSERVATIONS>;

/// One calibration in the surveyed room; `clouds[f]` is frame `f`'s sweep (may be empty).
pub(super) fn solve_surveyed(
    room: &Room,
    survey: &SurveySpec,
    frames: &[FrameDetections],
    clouds: &[&[Point]],
    finder: Option<&mut dyn FindLidarBoards>,
    given: Option<&super::free::CornerStart>,
) -> Result<Calibration, SolveFailure> {
    let spec = &room.board;
    let CameraStart {
        object,
        holes_board,
        boards: seen,
        start: CornerStart { camera, poses, corner_noise_px: corner_noise, mut iterations },
        ..
    } = camera_start(room, frames, given)?;
    let surveyed: Vec<Se3> = survey.boards.iter().map(|b| b.pose()).collect();

    let (identified, room_to_camera, unmatched) =
        identify_frames(spec, &surveyed, frames.len(), &seen, &poses)?;
    let lidar = room.lidar.as_ref();
    let camera_boards: Vec<(u32, &CameraBoard)> =
        identified.iter().map(|(f, b, _, _)| (*f, b)).collect();
    let board_poses: Vec<Se3> = identified.iter().map(|(_, _, _, p)| *p).collect();
    let found;
    let lidar_frames = match (finder, lidar) {
        (Some(finder), Some(l)) => {
            let expected = Expected {
                identified: &identified,
                camera_boards: &camera_boards,
                poses: &board_poses,
                room_to_camera,
                surveyed: &surveyed,
            };
            found = expected.find(finder, &lidar_nominal(l), frames.len(), clouds, &holes_board);
            &found
        }
        _ => frames,
    };
    let mut pairs = match lidar {
        Some(l) => {
            associate(&lidar_nominal(l), lidar_frames, &camera_boards, &board_poses, &holes_board)
        }
        None => vec![None; camera_boards.len()],
    };
    // The association starts from the room's nominal mounting; a run whose solved mounting
    // pairs more of the LiDAR's hole-placed boards (a nominal mounting degrees off leaves
    // them unpaired, and faces found through it may be another surface's) is solved
    // again with those pairs, once.
    let mut reassociated = false;
    // Boards whose LiDAR placement was left out (their holes misfit): not paired again.
    let mut dropped: Vec<usize> = Vec::new();
    'association: loop {
        let extrinsic = lidar.map(|l| {
            paired_extrinsic(&pairs, &board_poses, &holes_board).unwrap_or_else(|| lidar_nominal(l))
        });

        let mut left_out: Vec<usize> = Vec::new();
        // A LiDAR placement whose holes fit far worse than the other boards' (as in the
        // free-board run) is named, left out, and the room solved again, once.
        let mut misplaced: Option<MisplacedHoles> = None;
        loop {
            let (mut unpair, mut regroup) = (None, None);
            let keep: Vec<usize> =
                (0..identified.len()).filter(|&i| !left_out.contains(&identified[i].2)).collect();
            let ext = extrinsic.unwrap_or_else(Se3::identity);
            // Plane points from the start, then again from the first solve; without a sweep
            // (a rig's pair run) there is nothing to select again, and one solve is the run.
            let mut planes = room_planes(survey, &surveyed, clouds, &room_to_camera, &ext, None);
            let unpaired = |i: usize| pairs[i].is_none();
            let mut faces = unpaired_faces(
                spec,
                &surveyed,
                &identified,
                unpaired,
                clouds,
                &room_to_camera,
                &ext,
            );
            let mut params = None;
            let passes = if clouds.iter().any(|c| !c.is_empty()) { 2 } else { 1 };
            for pass in 2 - passes..2 {
                // The corners weighed by the noise the start's fit shows, not by the detector's
                // σ (twice that): against the survey's priors the weight is what matters. Ten
                // new vehicles in a 16-visit survey (seed 4), with the survey weighted the same
                // way: σ/bound 1.18–1.21 → 1.02–1.10, errors alike (`studies/surveyed_study.py`).
                let mut problem: Problem<'_> =
                    RoomProblem::new([corner_noise], 2.0, Loss::Huber(3.0));
                let blocks = add_observations(
                    &mut problem,
                    survey,
                    &object,
                    &holes_board,
                    &identified,
                    &pairs,
                    &keep,
                    &planes,
                    &faces,
                    camera.fx,
                )?;
                let mut p =
                    problem.params_at_priors([camera], [Se3::identity()], [ext], [room_to_camera]);
                if let Some(previous) = &params {
                    let previous: &Params = previous;
                    (p.cameras, p.lidar_to_first, p.room_to_first) =
                        (previous.cameras, previous.lidar_to_first, previous.room_to_first);
                }
                let report = solve_rig(&problem, &mut p, 100)?;
                iterations += report.iterations;
                if pass == 0 {
                    planes = room_planes(
                        survey,
                        &surveyed,
                        clouds,
                        &p.room_to_first[0],
                        &p.lidar_to_first[0],
                        Some(&planes),
                    );
                    faces = unpaired_faces(
                        spec,
                        &surveyed,
                        &identified,
                        unpaired,
                        clouds,
                        &p.room_to_first[0],
                        &p.lidar_to_first[0],
                    );
                    params = Some(p);
                    continue;
                }
                if let Some((board, chi2)) = worst_moved(&problem, &p, &blocks)? {
                    if left_out.is_empty() && keep.len() > 2 {
                        tracing::warn!(board, chi2, "board disagrees with the survey; left out");
                        left_out.push(board);
                        break;
                    }
                    let after = left_out.first().copied();
                    return Err(SolveFailure::BoardMoved { board, chi2, after });
                }
                // No second solve re-weighted by the kinds' variance factors here (the
                // free-board solve has one): over ten new vehicles in a 16-visit surveyed
                // room it moved the overlay at 10 m from 0.44 to 0.64 px RMS and the rotation
                // from 0.016 to 0.020° (`studies/surveyed_study.py`). The σ are
                // still each kind's own (`rig_covariance`).
                // Held by the survey's joint covariance when it has one. A covariance the solve
                // cannot use (a hand-edited file, σ far beyond any measurement) leaves the
                // per-block solution, said in the notes: the run is not lost to it.
                let mut joint_note = None;
                let joint = SurveyModes::of(survey).and_then(|modes| {
                let basis = modes.basis(survey, &blocks);
                jointly(&problem, &modes, &basis, &p)
                    .map_err(|reason| {
                        joint_note = Some(format!("the survey's covariance was not used ({reason}); each board and plane is held by its own σ"));
                    })
                    .ok()
            });
                let (p, report, sigma) = match joint {
                    Some((p, joint, sigma)) => {
                        iterations += joint.iterations;
                        (p, joint, sigma)
                    }
                    None => {
                        let sigma = rig_covariance(&problem, &p)?.matrix;
                        (p, report, sigma)
                    }
                };
                let mut run = calibration(
                    room,
                    &problem,
                    &p,
                    &report,
                    &sigma,
                    &identified,
                    &pairs,
                    &faces,
                    planes.len(),
                    &keep,
                    &holes_board,
                    iterations,
                    &left_out,
                )?;
                if let (None, Some((j, worst, median))) = (&misplaced, hole_outlier(room, &run)) {
                    let (frame, _, board, _) = &identified[keep[j]];
                    let name = MisplacedHoles {
                        frame: *frame,
                        board: *board,
                        surveyed: true,
                        rms_px: worst,
                        median_px: median,
                    };
                    tracing::warn!("{name}");
                    misplaced = Some(name);
                    unpair = Some(keep[j]);
                    break;
                }
                if let Some(solved) = run.lidar_to_camera {
                    let mut again = associate(
                        &solved,
                        lidar_frames,
                        &camera_boards,
                        &board_poses,
                        &holes_board,
                    );
                    dropped.iter().for_each(|&i| again[i] = None);
                    if paired(&again) > paired(&pairs) {
                        if reassociated {
                            return Err(SolveFailure::MountingDisagrees {
                                pairs: paired(&again),
                                used: paired(&pairs),
                            });
                        }
                        tracing::info!(
                        before = paired(&pairs),
                        after = paired(&again),
                        "the solved mounting pairs more LiDAR boards than the nominal one; solved again"
                    );
                        regroup = Some(again);
                        break;
                    }
                }
                run.notes.extend(misplaced.take().map(|m| m.to_string()));
                run.notes.extend(unmatched);
                run.notes.extend(joint_note);
                return Ok(run);
            }
            if let Some(again) = regroup {
                (pairs, reassociated) = (again, true);
                continue 'association;
            }
            if let Some(i) = unpair {
                pairs[i] = None;
                dropped.push(i);
            }
        }
    }
}

/// Camera boards paired with a LiDAR board.
fn paired(pairs: &[Option<super::association::Pair>]) -> usize {
    pairs.iter().filter(|p| p.is_some()).count()
}

/// A board whose prediction under the re-estimated mounting lies farther than this (m)
/// from its prediction under the nominal one is looked for again: closer, the first search
/// (within [`EXPECTED_REACH_M`] of the prediction) already covered where it is.
const REPREDICT_SHIFT_M: f64 = EXPECTED_REACH_M / 2.0;

/// The LiDAR boards where the surveyed room expects them: every identified camera board
/// carried into its frame's sweep by the camera's room pose and a mounting.
struct Expected<'a> {
    identified: &'a [(u32, CameraBoard, usize, Se3)],
    /// `identified`'s (frame, board) and board → camera, as the association takes them.
    camera_boards: &'a [(u32, &'a CameraBoard)],
    poses: &'a [Se3],
    room_to_camera: Se3,
    surveyed: &'a [Se3],
}

impl Expected<'_> {
    /// Per frame, the LiDAR boards found: at the nominal mounting's predictions first; in a
    /// sweep where that places fewer than two of two or more expected boards, by global
    /// search; then again for each board still missing whose prediction under the mounting
    /// re-estimated from what was found moved by more than [`REPREDICT_SHIFT_M`].
    fn find(
        &self,
        finder: &mut dyn FindLidarBoards,
        nominal: &Se3,
        frame_count: usize,
        clouds: &[&[Point]],
        holes_board: &[Vec3],
    ) -> Vec<FrameDetections> {
        let mut frames = vec![FrameDetections::default(); frame_count];
        let with_cloud = |f: usize| clouds.get(f).is_some_and(|c| !c.is_empty());
        for (f, frame) in frames.iter_mut().enumerate().filter(|(f, _)| with_cloud(*f)) {
            let boards = self.in_frame(f, |_| true);
            let placed: Vec<LidarBoard> = finder
                .expected(f, &self.predicted(nominal, &boards))
                .into_iter()
                .flatten()
                .collect();
            let fewer = placed.len() < super::MIN_EXPECTED_PLACED;
            frame.lidar = match fewer && boards.len() >= super::MIN_EXPECTED_PLACED {
                true => finder.everywhere(f),
                false => placed,
            };
        }
        let pairs = associate(nominal, &frames, self.camera_boards, self.poses, holes_board);
        let Some(mounting) = paired_extrinsic(&pairs, self.poses, holes_board) else {
            return frames;
        };
        for (f, frame) in frames.iter_mut().enumerate().filter(|(f, _)| with_cloud(*f)) {
            let missing = self.in_frame(f, |i| pairs[i].is_none());
            let moved: Vec<usize> = (missing.iter().copied())
                .zip(self.predicted(&mounting, &missing))
                .zip(self.predicted(nominal, &missing))
                .filter(|((_, now), before)| {
                    (now.translation - before.translation).norm() > REPREDICT_SHIFT_M
                })
                .map(|((i, _), _)| i)
                .collect();
            if !moved.is_empty() {
                let placed = finder.expected(f, &self.predicted(&mounting, &moved));
                frame.lidar.extend(placed.into_iter().flatten());
            }
        }
        frames
    }

    /// The identified boards of frame `f` (indices into `identified`) that `keep` keeps.
    fn in_frame(&self, f: usize, keep: impl Fn(usize) -> bool) -> Vec<usize> {
        (0..self.identified.len())
            .filter(|&i| self.identified[i].0 as usize == f && keep(i))
            .collect()
    }

    /// Where each of `boards` (indices into `identified`) lies in the LiDAR frame under
    /// `lidar_to_camera`: board → LiDAR from its surveyed pose and the camera's room pose.
    fn predicted(&self, lidar_to_camera: &Se3, boards: &[usize]) -> Vec<Se3> {
        let camera_to_lidar = lidar_to_camera.inverse();
        boards
            .iter()
            .map(|&i| {
                let board_to_camera =
                    self.room_to_camera.compose(&self.surveyed[self.identified[i].2]);
                camera_to_lidar.compose(&board_to_camera)
            })
            .collect()
    }
}

/// Every complete camera board of a frame identified against the survey, and every LiDAR
/// board (what `roomcal detect` reports in a surveyed room).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameIdentities {
    /// Per camera board of the frame, in its order: its surveyed identity (`None`: an
    /// incomplete board, or one that lands on no surveyed board).
    pub camera: Vec<Option<Identity>>,
    /// Per LiDAR board of the frame, in its order: the surveyed board it is.
    pub lidar: Vec<Option<usize>>,
    /// Room → camera from the identified boards (start intrinsics, corners only).
    pub room_to_camera: Se3,
    /// Why a seen board matched nothing (as the calibration's notes say it).
    pub notes: Vec<String>,
}

/// Identifies one frame's detections against the survey, as the surveyed calibration
/// does before it solves: the camera boards from the arrangement (start intrinsics from
/// the corners), the LiDAR boards through their camera pair (association under the
/// nominal mounting, re-estimated), and a LiDAR board without a pair by carrying its hole
/// centroid into the room with the re-estimated extrinsic onto the nearest surveyed board
/// within [`super::identify::GATE_M`].
pub fn identify_detections(
    room: &Room,
    survey: &SurveySpec,
    frame: &FrameDetections,
) -> Result<FrameIdentities, SolveFailure> {
    identify_from(room, survey, frame, None)
}

/// [`identify_detections`] from `given`, the frame's [`super::CornerStart`] when it was
/// made already (a rig's first camera: [`super::expected_in_rig_lidars`]).
pub(super) fn identify_from(
    room: &Room,
    survey: &SurveySpec,
    frame: &FrameDetections,
    given: Option<&super::CornerStart>,
) -> Result<FrameIdentities, SolveFailure> {
    let spec = &room.board;
    let complete: Vec<usize> = (0..frame.camera.len())
        .filter(|&i| frame.camera[i].corners.len() == spec.corner_count())
        .take(MAX_OBSERVATIONS)
        .collect();
    if complete.is_empty() {
        return Err(SolveFailure::NoCompleteBoardInImage);
    }
    // The start's boards are these complete ones, in this order.
    let CameraStart { holes_board, start: CornerStart { poses, .. }, .. } =
        camera_start(room, core::slice::from_ref(frame), given)?;
    let surveyed: Vec<Se3> = survey.boards.iter().map(|b| b.pose()).collect();
    let (ids, room_to_camera) = identify(spec, &surveyed, &poses)
        .map_err(|error| SolveFailure::Unidentified { frame: 0, error })?;
    let mut camera = vec![None; frame.camera.len()];
    let mut notes = Vec::new();
    for ((&i, id), pose) in complete.iter().zip(&ids).zip(&poses) {
        camera[i] = *id;
        if id.is_none() {
            notes.push(unmatched_note(0, pose, &room_to_camera, &surveyed));
        }
    }
    let mut lidar = vec![None; frame.lidar.len()];
    let Some(spec_lidar) = room.lidar.as_ref() else {
        return Ok(FrameIdentities { camera, lidar, room_to_camera, notes });
    };
    // The identified camera boards, oriented as the survey's, paired with the LiDAR's.
    let matched: Vec<(Identity, CameraBoard, Se3)> = complete
        .iter()
        .zip(&ids)
        .zip(&poses)
        .filter_map(|((&i, id), pose)| {
            id.map(|id| (id, in_survey_order(&frame.camera[i], id), oriented(pose, id.half_turned)))
        })
        .collect();
    let boards: Vec<(u32, &CameraBoard)> = matched.iter().map(|(_, b, _)| (0, b)).collect();
    let board_poses: Vec<Se3> = matched.iter().map(|(_, _, p)| *p).collect();
    let frames = core::slice::from_ref(frame);
    let pairs = associate(&lidar_nominal(spec_lidar), frames, &boards, &board_poses, &holes_board);
    for (pair, (id, _, _)) in pairs.iter().zip(&matched) {
        if let Some(pair) = pair {
            lidar[pair.lidar_index] = Some(id.board);
        }
    }
    let extrinsic = paired_extrinsic(&pairs, &board_poses, &holes_board)
        .unwrap_or_else(|| lidar_nominal(spec_lidar));
    let lidar_to_room = room_to_camera.inverse().compose(&extrinsic);
    let centre_board = holes_board.iter().sum::<Vec3>() / holes_board.len().max(1) as f64;
    for (l, board) in frame.lidar.iter().enumerate() {
        if lidar[l].is_some() || board.holes.is_empty() {
            continue;
        }
        let centre =
            lidar_to_room.act(&(board.holes.iter().sum::<Vec3>() / board.holes.len() as f64));
        let taken = |k: usize| lidar.contains(&Some(k));
        lidar[l] = surveyed
            .iter()
            .enumerate()
            .filter(|(k, _)| !taken(*k))
            .map(|(k, b)| (k, (b.act(&centre_board) - centre).norm()))
            .filter(|(_, d)| *d <= super::identify::GATE_M)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(k, _)| k);
    }
    Ok(FrameIdentities { camera, lidar, room_to_camera, notes })
}

/// Identification, frame by frame (a standing vehicle's frames share one parking pose):
/// every identified board (frame, corners in the survey's orientation, surveyed board,
/// board → camera), the room → camera pose, and a note per board that matched nothing.
#[allow(clippy::type_complexity)]
fn identify_frames(
    spec: &crate::target::BoardSpec,
    surveyed: &[Se3],
    frame_count: usize,
    seen: &[(u32, &CameraBoard)],
    poses: &[Se3],
) -> Result<(Vec<(u32, CameraBoard, usize, Se3)>, Se3, Vec<String>), SolveFailure> {
    let mut identified: Vec<(u32, CameraBoard, usize, Se3)> = Vec::new();
    let mut room_to_camera = None;
    let mut unmatched: Vec<String> = Vec::new();
    for f in 0..frame_count as u32 {
        let in_frame: Vec<usize> = (0..seen.len()).filter(|&i| seen[i].0 == f).collect();
        if in_frame.is_empty() {
            continue;
        }
        let frame_poses: Vec<Se3> = in_frame.iter().map(|&i| poses[i]).collect();
        let (ids, pose) = identify(spec, surveyed, &frame_poses)
            .map_err(|error| SolveFailure::Unidentified { frame: f, error })?;
        room_to_camera.get_or_insert(pose);
        for (&i, id) in in_frame.iter().zip(&ids) {
            let Some(id) = id else {
                unmatched.push(unmatched_note(f, &poses[i], &pose, surveyed));
                continue;
            };
            let board = in_survey_order(seen[i].1, *id);
            identified.push((f, board, id.board, oriented(&poses[i], id.half_turned)));
        }
    }
    let room_to_camera = room_to_camera.ok_or(SolveFailure::NoBoardIdentified)?;
    Ok((identified, room_to_camera, unmatched))
}

/// The board with its corners in the surveyed board's order (reversed when the detector
/// read it half-turned).
fn in_survey_order(board: &CameraBoard, id: Identity) -> CameraBoard {
    let mut board = board.clone();
    if id.half_turned {
        board.corners.reverse();
    }
    board
}

/// What to tell the operator about a seen board that lands on no surveyed board: the
/// nearest surveyed board and how far off it is (it may have been knocked over or moved).
fn unmatched_note(frame: u32, seen: &Se3, room_to_camera: &Se3, surveyed: &[Se3]) -> String {
    let nearest = surveyed
        .iter()
        .enumerate()
        .map(|(k, b)| (k, (room_to_camera.compose(b).translation - seen.translation).norm()))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    match nearest {
        Some((k, d)) => format!(
            "frame {frame}: a board the camera sees matches no surveyed board (nearest: board {k}, {:.0} mm away); it was left out: board {k} may have moved",
            d * 1000.0
        ),
        None => format!("frame {frame}: a board the camera sees matches no surveyed board"),
    }
}

/// Adds one block per seen surveyed board and per surveyed plane with points, and the
/// observations; returns the survey index of every block (`None` for planes).
#[allow(clippy::too_many_arguments)]
fn add_observations<'a>(
    problem: &mut Problem<'a>,
    survey: &SurveySpec,
    object: &'a [Vec3],
    holes_board: &'a [Vec3],
    identified: &'a [(u32, CameraBoard, usize, Se3)],
    pairs: &'a [Option<super::association::Pair>],
    keep: &[usize],
    planes: &[(usize, PlanePoints)],
    faces: &[Option<PlanePoints>],
    fx: f64,
) -> Result<Vec<SurveyEntry>, SolveFailure> {
    let mut blocks: Vec<SurveyEntry> = Vec::new();
    for &i in keep {
        let (_, board, k, pose) = &identified[i];
        let block = match blocks.iter().position(|b| *b == SurveyEntry::Board(*k)) {
            Some(b) => b,
            None => {
                let s = &survey.boards[*k];
                let prior = BlockPrior {
                    pose: s.pose(),
                    sigma_m: s.sigma_m,
                    sigma_rad: s.sigma_deg.to_radians(),
                };
                blocks.push(SurveyEntry::Board(*k));
                problem.add_block(prior)?
            }
        };
        let pair = pairs[i].as_ref();
        let (hb, hl): (&[Vec3], &[Vec3]) = match pair {
            Some(p) => (holes_board, &p.holes_lidar),
            None => (&[], &[]),
        };
        let observation = BoardObservation {
            object,
            corners: &board.corners,
            holes_board: hb,
            holes_lidar: hl,
            hole_sigma_px: pair.map(|p| hole_sigma_px(fx, p.sigma_m, pose.translation.z)),
            plane: face_of(pairs, faces, i),
        };
        problem.add_observation(pair_observation(block, observation))?;
    }
    for (index, points) in planes {
        let s = &survey.planes[*index];
        let prior = BlockPrior {
            pose: plane_frame(&Vec3::from(s.normal), s.offset),
            sigma_m: s.sigma_m,
            sigma_rad: s.sigma_deg.to_radians(),
        };
        let block = problem.add_block(prior)?;
        blocks.push(SurveyEntry::Plane(*index));
        let observation = BoardObservation { plane: Some(*points), ..BoardObservation::default() };
        problem.add_observation(pair_observation(block, observation))?;
    }
    Ok(blocks)
}

/// Identified board `i`'s face points as the solve takes them: its LiDAR board's when the
/// holes paired it, else [`unpaired_faces`]'.
fn face_of(
    pairs: &[Option<super::association::Pair>],
    faces: &[Option<PlanePoints>],
    i: usize,
) -> Option<PlanePoints> {
    pairs[i].as_ref().and_then(|p| p.plane).or(faces[i])
}

/// The LiDAR's points on the face of every identified board whose holes it did not place
/// (`unpaired(i)`), index by index (`None` for the others): the survey says where the board
/// is, the room pose and the extrinsic carry it into the board's frame's sweep, and
/// [`expected_face`] takes what lies on its face, first within [`PLANE_START_CUT_M`] of it
/// (the start's extrinsic may be the nominal mounting, off by a degree or two). A LiDAR whose
/// lines are too sparse to resolve a hole (a VLP-16) still sees the faces, and the faces with
/// the room's planes place it.
fn unpaired_faces(
    spec: &crate::target::BoardSpec,
    surveyed: &[Se3],
    identified: &[(u32, CameraBoard, usize, Se3)],
    unpaired: impl Fn(usize) -> bool,
    clouds: &[&[Point]],
    room_to_camera: &Se3,
    extrinsic: &Se3,
) -> Vec<Option<PlanePoints>> {
    let room_to_lidar = extrinsic.inverse().compose(room_to_camera);
    identified
        .iter()
        .enumerate()
        .map(|(i, (frame, _, board, _))| {
            let cloud = clouds.get(*frame as usize).filter(|c| !c.is_empty() && unpaired(i))?;
            expected_face(spec, &room_to_lidar.compose(&surveyed[*board]), PLANE_START_CUT_M, cloud)
        })
        .collect()
}

/// The LiDAR's points on every surveyed plane, over all clouds: those within a cut of
/// the plane carried into the LiDAR frame by `room_to_camera` and `extrinsic`, not near a
/// board and not within the cut of a second plane (where two planes meet, a point could be
/// either's). The cut is [`PLANE_START_CUT_M`] at first, then 3σ of each point's own noise
/// along the normal as the previous selection of that plane measured it
/// ([`PlanePoints::along_beams`]); each plane's points are then trimmed of what stands on
/// it and summarised with those weights ([`trimmed_plane_points`]).
pub(super) fn room_planes(
    survey: &SurveySpec,
    surveyed: &[Se3],
    clouds: &[&[Point]],
    room_to_camera: &Se3,
    extrinsic: &Se3,
    previous: Option<&[(usize, PlanePoints)]>,
) -> Vec<(usize, PlanePoints)> {
    let lidar_to_room = room_to_camera.inverse().compose(extrinsic);
    // Planes and board centres are moved into the LiDAR's frame once, and the sweep is read
    // once for all planes: each point costs one dot product per plane (distances are the
    // same in both frames).
    let room_to_lidar = lidar_to_room.inverse();
    let boards: Vec<Vec3> = surveyed.iter().map(|b| room_to_lidar.act(&b.translation)).collect();
    let (indices, selections): (Vec<usize>, Vec<PlaneSelection>) = (survey
        .planes
        .iter()
        .enumerate())
    .filter_map(|(index, plane)| {
        let cut = match previous {
            Some(prev) => {
                PlaneCut::measured(&prev.iter().find(|(i, _)| *i == index)?.1, PLANE_FLOOR_SIGMA_M)
            }
            None => PlaneCut::band(PLANE_START_CUT_M),
        };
        let normal = Vec3::from(plane.normal);
        let offset = plane.offset - normal.dot(&lidar_to_room.translation);
        Some((
            index,
            PlaneSelection { normal: lidar_to_room.rotation.transpose() * normal, offset, cut },
        ))
    })
    .unzip();
    let clearance2 = PLANE_BOARD_CLEARANCE_M * PLANE_BOARD_CLEARANCE_M;
    let clear_of_boards = |q: &Vec3| boards.iter().all(|b| (b - q).norm_squared() > clearance2);
    let selected =
        select_plane_points(clouds.iter().flat_map(|c| c.iter()), &selections, clear_of_boards);
    (indices.into_iter().zip(&selections).zip(selected))
        .filter_map(|((index, s), points)| {
            Some((index, trimmed_plane_points(&points, &s.normal, s.offset, PLANE_FLOOR_SIGMA_M)?))
        })
        .collect()
}

/// The room solved again held by the survey's joint covariance ([`SurveyModes`]) from the
/// per-block solution `start` (its intrinsics, extrinsic and room pose; the blocks back at
/// the survey, where the modes' prior is centred): the solution, what the solve did, and
/// the covariance of the shared parameters. The per-block solve before it named any board
/// that moved; the modes cannot (a moved board would pull the whole room).
fn jointly(
    problem: &Problem<'_>,
    modes: &SurveyModes,
    basis: &[ModeBasis],
    start: &Params,
) -> Result<(Params, RoomReport, nalgebra::SMatrix<f64, ROOM_SHARED, ROOM_SHARED>), SolveFailure> {
    let joint = ModesProblem::new(problem, modes.sigma, basis)?;
    let mut params = ModesParams {
        room: problem.params_at_priors(
            start.cameras,
            [Se3::identity()],
            start.lidar_to_first,
            start.room_to_first,
        ),
        amplitudes: nalgebra::SVector::zeros(),
    };
    let initial_cost = joint.cost(&params)?;
    let iterations = solve_modes(&joint, &mut params, 100)?;
    let sigma = modes_covariance(&joint, &params)?;
    let (corner_rms_px, hole_rms_px) = problem.rms_px(&params.room)?;
    let report = RoomReport {
        iterations,
        initial_cost,
        final_cost: joint.cost(&params)?,
        residuals: problem.residual_count() - 6 * problem.priors().len() + joint.mode_count(),
        corner_rms_px,
        hole_rms_px,
    };
    Ok((params.room, report, sigma))
}

/// The board block farthest outside its survey σ, if any is beyond [`MOVED_BOARD_CHI2`]:
/// (survey index, χ²).
fn worst_moved(
    problem: &Problem<'_>,
    params: &Params,
    blocks: &[SurveyEntry],
) -> Result<Option<(usize, f64)>, SolveFailure> {
    let costs = problem.block_costs(params)?;
    Ok(costs
        .iter()
        .zip(blocks)
        .filter_map(|((_, prior), entry)| match entry {
            SurveyEntry::Board(b) => Some((*b, 2.0 * prior)),
            SurveyEntry::Plane(_) => None,
        })
        .filter(|(_, chi2)| *chi2 > MOVED_BOARD_CHI2)
        .max_by(|a, b| a.1.total_cmp(&b.1)))
}

/// The run's outcome from the solved room problem (an error only for `params` that are not
/// the problem's).
#[allow(clippy::too_many_arguments)]
fn calibration(
    room: &Room,
    problem: &Problem<'_>,
    params: &Params,
    report: &RoomReport,
    sigma: &nalgebra::SMatrix<f64, ROOM_SHARED, ROOM_SHARED>,
    identified: &[(u32, CameraBoard, usize, Se3)],
    pairs: &[Option<super::association::Pair>],
    faces: &[Option<PlanePoints>],
    planes: usize,
    keep: &[usize],
    holes_board: &[Vec3],
    iterations: usize,
    left_out: &[usize],
) -> Result<Calibration, SolveFailure> {
    let joint: JointParams<Camera, MAX_OBSERVATIONS> = JointParams {
        camera: params.cameras[0],
        lidar_to_camera: params.lidar_to_first[0],
        board_poses: problem.board_poses(params)?,
    };
    let with_lidar = room.lidar.is_some() && problem.sees_lidar(0);
    let boards: Vec<UsedBoard> = keep
        .iter()
        .zip(joint.board_poses.iter())
        .map(|(&i, pose)| UsedBoard {
            frame: identified[i].0,
            corners: identified[i].1.corners.clone(),
            holes_lidar: pairs[i].as_ref().map_or(Vec::new(), |p| p.holes_lidar.clone()),
            hole_sigma_m: pairs[i].as_ref().map_or(0.0, |p| p.sigma_m),
            lidar_face: face_of(pairs, faces, i).is_some(),
            pose: *pose,
        })
        .collect();
    let shared = SharedCovariance {
        matrix: sigma.fixed_view::<SHARED, SHARED>(0, 0).into_owned(),
        residual_variance: 1.0,
        dof: report.residuals,
        mask: ParamMask::free(),
        // `rig_covariance` applied each kind's factor; this summary does not carry them.
        kind_variances: crate::solve::lm::KindWeights::ALL,
    };
    let solve_report = SolveReport {
        iterations: report.iterations,
        initial_cost: report.initial_cost,
        final_cost: report.final_cost,
        termination: Termination::CostConverged,
        residuals: report.residuals,
        free_parameters: ROOM_SHARED,
        corner_rms_px: report.corner_rms_px[0],
        hole_rms_px: report.hole_rms_px[0],
        final_lambda: 0.0,
    };
    let mut result = accepted(&joint, &solve_report, &shared.uncertainty(), &boards, with_lidar);
    result.camera_in_room = Some(Extrinsic::from_se3(&params.room_to_first[0].inverse()));
    let notes = left_out
        .iter()
        .map(|b| format!("board {b} disagrees with the survey and was left out"))
        .collect();
    Ok(Calibration {
        result,
        camera: params.cameras[0],
        lidar_to_camera: with_lidar.then_some(params.lidar_to_first[0]),
        boards,
        holes_board: holes_board.to_vec(),
        iterations,
        notes,
        pose_covariance: Some(pose_covariance(sigma)),
        shared_covariance: Some(shared.matrix),
        lidar_planes: if with_lidar { planes } else { 0 },
    })
}

/// LiDAR → camera and room → camera blocks of the room covariance (with their cross
/// terms), as [`Calibration::pose_covariance`] holds them.
fn pose_covariance(
    sigma: &nalgebra::SMatrix<f64, ROOM_SHARED, ROOM_SHARED>,
) -> super::PoseCovariance {
    use crate::solve::{room::ROOM_ROTATION, EXT_ROTATION};
    let mut out = super::PoseCovariance::zeros();
    for (i, a) in [EXT_ROTATION, ROOM_ROTATION].into_iter().enumerate() {
        for (j, b) in [EXT_ROTATION, ROOM_ROTATION].into_iter().enumerate() {
            out.fixed_view_mut::<6, 6>(6 * i, 6 * j).copy_from(&sigma.fixed_view::<6, 6>(a, b));
        }
    }
    out
}
