//! The joint solve of a rig in a surveyed room: every camera's boards, every LiDAR's placed
//! boards and surveyed planes, intrinsics, mountings, the room pose, boards and planes solved
//! at once from the composition's start, σ from its normal equations.

use std::collections::BTreeMap;

use super::super::identify::{half_turn_symmetric, oriented, GATE_DEG, GATE_M};
use super::super::surveyed::MOVED_BOARD_CHI2;
use super::super::{median, Calibration, CameraBoard, LidarBoard, MAX_OBSERVATIONS};
use super::{LidarInput, RigFailure};

use crate::geometry::{se3::so3_log, Camera, Se3, Vec2, Vec3};
use crate::lidar::Point;
use crate::result::Extrinsic;
use crate::rig::Rig;
use crate::solve::rig::{
    plane_frame, rig_covariance, rig_shared, solve_rig, BlockPrior, RigCovariance, RigObservation,
    RigParams, RigProblem, RigReport,
};
use crate::solve::{hole_sigma_px, BoardObservation, Loss, PlanePoints};
use crate::target::{Room, SurveySpec};

/// Capacities of the joint solve; a rig beyond them keeps the composition.
pub(super) const JOINT_CAMERAS: usize = 4;
pub(super) const JOINT_LIDARS: usize = 4;
const JOINT_OBSERVATIONS: usize = 96;
const JOINT_SHARED: usize = rig_shared(JOINT_CAMERAS, JOINT_LIDARS, 1);

type JointProblem<'a> = RigProblem<
    'a,
    JOINT_CAMERAS,
    JOINT_LIDARS,
    1,
    MAX_OBSERVATIONS,
    JOINT_OBSERVATIONS,
    JOINT_SHARED,
>;
type JointParams = RigParams<Camera, JOINT_CAMERAS, JOINT_LIDARS, 1, MAX_OBSERVATIONS>;

/// The joint solution: the estimate, its covariance and the solve's residuals.
pub(super) struct Joint {
    pub(super) params: JointParams,
    pub(super) covariance: RigCovariance<JOINT_SHARED>,
    pub(super) report: RigReport<JOINT_CAMERAS, JOINT_LIDARS>,
    pub(super) iterations: usize,
    /// What the solve measured of each sensor (the joint gate's evidence).
    pub(super) evidence: Evidence,
}

/// What the joint solve measured of each sensor: per camera the boards it saw, per LiDAR
/// the boards it placed by their holes (seen in a camera), the boards it has only face
/// points of, and the surveyed planes it has points on; with free boards, whether the
/// shared boards tie each sensor to the first camera (in a surveyed room the room does).
#[derive(Clone, Debug, Default)]
pub(super) struct Evidence {
    pub(super) free: bool,
    pub(super) camera_boards: Vec<usize>,
    pub(super) lidar_hole_boards: Vec<usize>,
    pub(super) lidar_face_boards: Vec<usize>,
    pub(super) lidar_planes: Vec<usize>,
    pub(super) camera_tied: Vec<bool>,
    pub(super) lidar_tied: Vec<bool>,
}

/// What the joint solve's boards are held to.
#[derive(Clone, Copy, Debug)]
pub(super) enum Targets<'a> {
    /// The room's survey: its boards and planes, their σ the priors.
    Surveyed(&'a SurveySpec),
    /// No survey: the boards the cameras see, free, in the first camera's frame (the
    /// room frame is the first camera's; frame 0's room pose is held at the identity).
    Free,
}

/// The starting mountings from the composition (`None` where it failed: the nominal
/// mounting is used), and each LiDAR's composition camera.
pub(super) struct Start {
    pub(super) camera_to_first: Vec<Option<Se3>>,
    pub(super) lidar_to_first: Vec<Option<Se3>>,
    pub(super) lidar_cameras: Vec<Option<usize>>,
}

/// One camera's boards as its pair run identified them: (survey board, corners in the
/// survey's order).
type CameraMeasurements = Vec<(usize, Vec<Vec2>)>;

/// One LiDAR board placed on a surveyed board: its holes paired with the board model's,
/// the camera the hole term is seen in, and its face points.
struct LidarMeasurement {
    pub(super) lidar: usize,
    pub(super) board: usize,
    pub(super) camera: Option<usize>,
    pub(super) holes_board: Vec<Vec3>,
    pub(super) holes_lidar: Vec<Vec3>,
    pub(super) hole_sigma_px: f64,
    pub(super) plane: Option<PlanePoints>,
}

/// Which survey entry a block of the joint problem is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Block {
    Board(usize),
    Plane(usize),
}

/// Solves every sensor of the rig jointly, from the pair runs' intrinsics (and, in a
/// surveyed room, room pose) and the composed mountings. As in the one-pair run, a board
/// the solution puts outside its survey σ is named, left out and the rig solved again; a
/// second one rejects the rig. With free boards, a sensor the shared boards do not tie to
/// the first camera is left out of the solve (its verdict says so).
pub(super) fn solve_jointly(
    room: &Room,
    targets: Targets<'_>,
    rig: &Rig,
    runs: &BTreeMap<(usize, Option<usize>), Calibration>,
    camera_runs: &[(usize, Option<usize>)],
    inputs: (&[Vec<CameraBoard>], &[LidarInput<'_>]),
    start: &Start,
) -> Result<Joint, RigFailure> {
    let (camera_inputs, lidar_inputs) = inputs;
    // One input per rig LiDAR (a caller's extra inputs have no sensor).
    let lidar_inputs = &lidar_inputs[..lidar_inputs.len().min(rig.lidars.len())];
    let spec = &room.board;
    let model_holes: Vec<Vec3> = (0..spec.holes.len()).map(|h| spec.hole(h)).collect();
    let (surveyed, cameras, params) = match targets {
        Targets::Surveyed(survey) => {
            let surveyed: Vec<Se3> = survey.boards.iter().map(|b| b.pose()).collect();
            let room_to_first = room_to_first(rig, &runs[&camera_runs[0]])?;
            let params = start_params(rig, runs, camera_runs, start, room_to_first);
            let cameras: Vec<CameraMeasurements> = (0..rig.cameras.len())
                .map(|c| camera_measurements(&runs[&camera_runs[c]], &surveyed))
                .collect();
            (surveyed, cameras, params)
        }
        Targets::Free => {
            let params = start_params(rig, runs, camera_runs, start, Se3::identity());
            let (boards, cameras) = free_boards(spec, rig, runs, camera_runs, &params);
            (boards, cameras, params)
        }
    };
    let mut lidars = Vec::new();
    for (l, input) in lidar_inputs.iter().enumerate() {
        let (preferred, boards) = (start.lidar_cameras[l], input.boards);
        let placed =
            lidar_measurements(l, boards, &params, &surveyed, &model_holes, &cameras, preferred);
        lidars.extend(placed);
    }
    let mut measured = Measured {
        object: (0..spec.corner_count()).map(|i| spec.corner(i)).collect(),
        cameras,
        lidars,
        corner_sigma: core::array::from_fn(|c| {
            let boards = camera_inputs.get(c);
            boards.map_or(1.0, |b| median(b.iter().map(|b| b.sigma_px)).max(0.02))
        }),
    };
    let tied = match targets {
        Targets::Surveyed(_) => None,
        Targets::Free => Some(tie_to_first(&mut measured, rig.cameras.len(), rig.lidars.len())),
    };
    let clouds: Vec<&[Point]> = lidar_inputs.iter().map(|i| i.cloud).collect();
    let mut left_out = None;
    loop {
        let (mut joint, moved) =
            solve_passes(targets, &surveyed, &clouds, &measured, params.clone())?;
        if let Some((cameras, lidars)) = &tied {
            joint.evidence.free = true;
            joint.evidence.camera_tied.clone_from(cameras);
            joint.evidence.lidar_tied.clone_from(lidars);
        }
        match (moved, left_out) {
            (None, _) => return Ok(joint),
            (Some((board, _)), None) => {
                tracing::warn!(
                    board,
                    "board disagrees with the survey in the joint rig solve; left out"
                );
                left_out = Some(board);
                measured.leave_out(board);
            }
            (Some((board, chi2)), Some(first)) => {
                return Err(RigFailure::BoardMoved { board, chi2, after: first })
            }
        }
    }
}

/// The joint solve's measurements, owned (the problem borrows them).
struct Measured {
    pub(super) object: Vec<Vec3>,
    pub(super) cameras: Vec<CameraMeasurements>,
    pub(super) lidars: Vec<LidarMeasurement>,
    pub(super) corner_sigma: [f64; JOINT_CAMERAS],
}

impl Measured {
    /// Drops every measurement of surveyed board `board`.
    fn leave_out(&mut self, board: usize) {
        for seen in self.cameras.iter_mut() {
            seen.retain(|(k, _)| *k != board);
        }
        self.lidars.retain(|m| m.board != board);
    }
}

impl Evidence {
    fn of(m: &Measured, planes: &[Vec<(usize, PlanePoints)>]) -> Evidence {
        let lidars = planes.len();
        let count = |holes: bool| -> Vec<usize> {
            (0..lidars)
                .map(|l| {
                    let of_l = m.lidars.iter().filter(|b| b.lidar == l);
                    of_l.filter(|b| b.holes_lidar.is_empty() != holes).count()
                })
                .collect()
        };
        Evidence {
            free: false,
            camera_boards: m.cameras.iter().map(Vec::len).collect(),
            lidar_hole_boards: count(true),
            lidar_face_boards: count(false),
            lidar_planes: planes.iter().map(Vec::len).collect(),
            camera_tied: vec![true; m.cameras.len()],
            lidar_tied: vec![true; lidars],
        }
    }
}

/// The two passes of the joint solve (surveyed-plane points selected from the start, then
/// from the first solution; free boards have no planes and one pass), and the board
/// farthest outside its survey σ if any is beyond [`MOVED_BOARD_CHI2`] (survey index, χ²).
/// `boards` are the surveyed boards, or the free boards' starts.
fn solve_passes(
    targets: Targets<'_>,
    boards: &[Se3],
    clouds: &[&[Point]],
    m: &Measured,
    start: JointParams,
) -> Result<(Joint, Option<(usize, f64)>), RigFailure> {
    let select = |params: &JointParams, previous: Option<&[Vec<(usize, PlanePoints)>]>| {
        let planes = clouds.iter().enumerate().map(|(l, cloud)| match targets {
            Targets::Surveyed(survey) => super::super::surveyed::room_planes(
                survey,
                boards,
                &[*cloud],
                &params.room_to_first[0],
                &params.lidar_to_first[l],
                previous.map(|p| p[l].as_slice()),
            ),
            Targets::Free => Vec::new(),
        });
        planes.collect::<Vec<_>>()
    };
    let start_blocks = |problem: &JointProblem<'_>, p: &JointParams| {
        problem.params_at_priors(p.cameras, p.first_to_camera, p.lidar_to_first, p.room_to_first)
    };
    let mut planes = select(&start, None);
    let (mut problem, mut blocks) = joint_problem(targets, boards, m, &planes)?;
    let mut p = start_blocks(&problem, &start);
    let mut report = solve_rig(&problem, &mut p, 100)?;
    let mut iterations = report.iterations;
    if let Targets::Surveyed(_) = targets {
        planes = select(&p, Some(&planes));
        (problem, blocks) = joint_problem(targets, boards, m, &planes)?;
        p = start_blocks(&problem, &p);
        report = solve_rig(&problem, &mut p, 100)?;
        iterations += report.iterations;
    }
    let moved = moved_board(&problem, &p, &blocks);
    let covariance = rig_covariance(&problem, &p)?;
    let evidence = Evidence::of(m, &planes);
    Ok((Joint { params: p, covariance, report, iterations, evidence }, moved))
}

/// The surveyed board the solution puts farthest outside its survey σ, if any is beyond
/// [`MOVED_BOARD_CHI2`] (the one-pair run's rule): (survey index, χ²).
fn moved_board(
    problem: &JointProblem<'_>,
    params: &JointParams,
    blocks: &[Block],
) -> Option<(usize, f64)> {
    let mut worst: Option<(usize, f64)> = None;
    problem.for_each_prior(params, |k, r, _| {
        let chi2 = r.norm_squared();
        if let (Some(Block::Board(board)), true) = (blocks.get(k), chi2 > MOVED_BOARD_CHI2) {
            if worst.is_none_or(|(_, w)| chi2 > w) {
                worst = Some((*board, chi2));
            }
        }
    });
    worst
}

/// The first camera's room → camera pose from its run (surveyed rooms).
pub(super) fn room_to_first(rig: &Rig, first: &Calibration) -> Result<Se3, RigFailure> {
    let in_room = first.result.camera_in_room.as_ref();
    let in_room = in_room
        .ok_or_else(|| RigFailure::NoRoomPose { camera: rig.cameras[0].name.to_string() })?;
    Ok(in_room.to_se3().inverse())
}

/// The start: every camera's intrinsics from its run, the room pose given, the mountings
/// composed (nominal where the composition failed). Unused slots hold copies nothing
/// observes (the solve fixes them).
fn start_params(
    rig: &Rig,
    runs: &BTreeMap<(usize, Option<usize>), Calibration>,
    camera_runs: &[(usize, Option<usize>)],
    start: &Start,
    room_to_first: Se3,
) -> JointParams {
    let first = &runs[&camera_runs[0]];
    let cameras =
        core::array::from_fn(|c| camera_runs.get(c).map_or(first.camera, |key| runs[key].camera));
    let first_to_camera = core::array::from_fn(|c| match (c, rig.cameras.get(c)) {
        (0, _) | (_, None) => Se3::identity(),
        (_, Some(camera)) => start.camera_to_first[c].unwrap_or(camera.to_reference).inverse(),
    });
    let lidar_to_first = core::array::from_fn(|l| match rig.lidars.get(l) {
        Some(lidar) => start.lidar_to_first[l].unwrap_or(lidar.to_reference),
        None => Se3::identity(),
    });
    RigParams {
        cameras,
        first_to_camera,
        lidar_to_first,
        room_to_first: [room_to_first],
        blocks: heapless::Vec::new(),
    }
}

/// Without a survey: one board per physical board the cameras see, in the first camera's
/// frame (each camera's solved board poses carried there by its start mounting), and each
/// camera's boards on them. A board lands on one another camera saw already when it is
/// within the identification gate of it (either way round on a half-turn symmetric board:
/// its corners are then reversed into that board's order); else it is a new board.
pub(super) fn free_boards(
    spec: &crate::target::BoardSpec,
    rig: &Rig,
    runs: &BTreeMap<(usize, Option<usize>), Calibration>,
    camera_runs: &[(usize, Option<usize>)],
    start: &JointParams,
) -> (Vec<Se3>, Vec<CameraMeasurements>) {
    let turns: &[bool] = if half_turn_symmetric(spec) { &[false, true] } else { &[false] };
    let mut boards: Vec<Se3> = Vec::new();
    let mut cameras = Vec::new();
    for (c, key) in camera_runs.iter().enumerate().take(rig.cameras.len()) {
        let to_first = start.first_to_camera[c].inverse();
        let mut seen: CameraMeasurements = Vec::new();
        for b in &runs[key].boards {
            let in_first = to_first.compose(&b.pose);
            let same = |k: usize, turned: bool| {
                let (board, got) = (&boards[k], oriented(&in_first, turned));
                let shift = (board.translation - got.translation).norm();
                let angle = so3_log(&(board.rotation * got.rotation.transpose())).norm();
                shift <= GATE_M && angle.to_degrees() <= GATE_DEG
            };
            let taken = |k: usize| seen.iter().any(|(j, _)| *j == k);
            let pairs = (0..boards.len()).flat_map(|k| turns.iter().map(move |&t| (k, t)));
            let found = pairs.filter(|&(k, t)| !taken(k) && same(k, t)).min_by(|a, b| {
                let d = |k: usize| (boards[k].translation - in_first.translation).norm();
                d(a.0).total_cmp(&d(b.0))
            });
            let (k, turned) = found.unwrap_or_else(|| {
                boards.push(in_first);
                (boards.len() - 1, false)
            });
            let mut corners = b.corners.clone();
            if turned {
                corners.reverse();
            }
            seen.push((k, corners));
        }
        cameras.push(seen);
    }
    (boards, cameras)
}

/// With free boards, which sensors the measurements tie to the first camera: through the
/// boards two cameras see, and a LiDAR through the boards it places by their holes (a
/// face alone leaves it free to slide and turn in the board's plane). Measurements of a
/// sensor that is not tied are dropped (they would leave the solve singular); returns
/// (cameras tied, LiDARs tied).
fn tie_to_first(m: &mut Measured, cameras: usize, lidars: usize) -> (Vec<bool>, Vec<bool>) {
    let blocks = m.cameras.iter().flatten().map(|(k, _)| k + 1).max().unwrap_or(0);
    // Union–find over [cameras | LiDARs | boards].
    let mut parent: Vec<usize> = (0..cameras + lidars + blocks).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut join = |a: usize, b: usize| {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        parent[ra] = rb;
    };
    for (c, seen) in m.cameras.iter().enumerate() {
        for (k, _) in seen {
            join(c, cameras + lidars + k);
        }
    }
    for b in m.lidars.iter().filter(|b| !b.holes_lidar.is_empty()) {
        join(cameras + b.lidar, cameras + lidars + b.board);
    }
    let first = root(&mut parent, 0);
    let mut tied = |i: usize| root(&mut parent, i) == first;
    let camera_tied: Vec<bool> = (0..cameras).map(&mut tied).collect();
    let lidar_tied: Vec<bool> = (0..lidars).map(|l| tied(cameras + l)).collect();
    for (c, seen) in m.cameras.iter_mut().enumerate() {
        if !camera_tied[c] {
            seen.clear();
        }
    }
    m.lidars.retain(|b| lidar_tied[b.lidar] && camera_tied[b.camera.unwrap_or(0)]);
    (camera_tied, lidar_tied)
}

/// A camera's boards as its run used them, each on the surveyed board its solved pose
/// puts it on (board → room = camera → room ∘ board → camera, within the identification
/// gate).
fn camera_measurements(run: &Calibration, surveyed: &[Se3]) -> CameraMeasurements {
    let Some(camera_in_room) = run.result.camera_in_room.as_ref().map(Extrinsic::to_se3) else {
        return Vec::new();
    };
    run.boards
        .iter()
        .filter_map(|b| {
            let at = camera_in_room.compose(&b.pose).translation;
            nearest(surveyed.iter().map(|s| s.translation), &at, GATE_M)
                .map(|k| (k, b.corners.clone()))
        })
        .collect()
}

/// The index of the point nearest `to`, if within `gate`.
fn nearest(points: impl Iterator<Item = Vec3>, to: &Vec3, gate: f64) -> Option<usize> {
    points
        .enumerate()
        .map(|(i, p)| (i, (p - to).norm()))
        .filter(|(_, d)| *d <= gate)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

/// LiDAR `l`'s boards placed on the surveyed boards through the start (LiDAR → room), each
/// hole paired with the nearest of the board model's; the hole term is seen in the
/// LiDAR's composition camera when it sees that board, else in the first camera that
/// does (none: the face points alone).
fn lidar_measurements(
    l: usize,
    boards: &[LidarBoard],
    start: &JointParams,
    surveyed: &[Se3],
    model_holes: &[Vec3],
    seen: &[CameraMeasurements],
    preferred: Option<usize>,
) -> Vec<LidarMeasurement> {
    let to_room = start.room_to_first[0].inverse().compose(&start.lidar_to_first[l]);
    let centre = model_holes.iter().sum::<Vec3>() / model_holes.len().max(1) as f64;
    let spacing = (0..model_holes.len())
        .flat_map(|i| (0..i).map(move |j| (i, j)))
        .map(|(i, j)| (model_holes[i] - model_holes[j]).norm())
        .fold(f64::INFINITY, f64::min);
    let mut out: Vec<LidarMeasurement> = Vec::new();
    for board in boards.iter().filter(|b| !b.holes.is_empty()) {
        let mean = board.holes.iter().sum::<Vec3>() / board.holes.len() as f64;
        let centres = surveyed.iter().map(|s| s.act(&centre));
        let Some(k) = nearest(centres, &to_room.act(&mean), GATE_M) else { continue };
        if out.iter().any(|m| m.board == k) {
            continue;
        }
        let model: Vec<Vec3> = model_holes.iter().map(|h| surveyed[k].act(h)).collect();
        let mut pairs: Vec<(usize, Vec3)> = Vec::new();
        for p in &board.holes {
            let i = nearest(model.iter().copied(), &to_room.act(p), 0.5 * spacing);
            if let Some(i) = i.filter(|i| pairs.iter().all(|(j, _)| j != i)) {
                pairs.push((i, *p));
            }
        }
        pairs.sort_by_key(|(i, _)| *i);
        let sees = |c: usize| seen[c].iter().any(|(b, _)| *b == k);
        let camera = preferred.filter(|&c| sees(c)).or_else(|| (0..seen.len()).find(|&c| sees(c)));
        let hole_sigma_px = camera.map_or(1.0, |c| {
            let to_camera =
                start.first_to_camera[c].compose(&start.room_to_first[0]).compose(&surveyed[k]);
            hole_sigma_px(start.cameras[c].fx, board.sigma_m, to_camera.translation.z)
        });
        let with_holes = camera.is_some() && pairs.len() >= 2;
        if !with_holes && board.plane.is_none() {
            continue;
        }
        out.push(LidarMeasurement {
            lidar: l,
            board: k,
            camera: camera.filter(|_| with_holes),
            holes_board: if with_holes {
                pairs.iter().map(|(i, _)| model_holes[*i]).collect()
            } else {
                Vec::new()
            },
            holes_lidar: if with_holes {
                pairs.iter().map(|(_, p)| *p).collect()
            } else {
                Vec::new()
            },
            hole_sigma_px,
            plane: board.plane,
        });
    }
    out
}

/// The joint problem over the measurements: one block per board anything sees and per
/// surveyed plane a LiDAR has points on, with the survey's priors (free boards: none,
/// started at `boards`).
fn joint_problem<'a>(
    targets: Targets<'_>,
    boards: &[Se3],
    m: &'a Measured,
    planes: &[Vec<(usize, PlanePoints)>],
) -> Result<(JointProblem<'a>, Vec<Block>), RigFailure> {
    let (object, cameras, lidars) = (&m.object, &m.cameras, &m.lidars);
    let mut problem = JointProblem::new(m.corner_sigma, 2.0, Loss::Huber(3.0));
    let mut blocks: Vec<Block> = Vec::new();
    let mut block = |problem: &mut JointProblem<'a>, which: Block| -> Result<usize, RigFailure> {
        if let Some(i) = blocks.iter().position(|b| *b == which) {
            return Ok(i);
        }
        let prior = match (targets, which) {
            (Targets::Free, Block::Board(k)) => BlockPrior::free(boards[k]),
            (Targets::Surveyed(survey), Block::Board(k)) => {
                let s = &survey.boards[k];
                BlockPrior {
                    pose: s.pose(),
                    sigma_m: s.sigma_m,
                    sigma_rad: s.sigma_deg.to_radians(),
                }
            }
            (Targets::Free, Block::Plane(_)) => return Err(RigFailure::FreePlanes),
            (Targets::Surveyed(survey), Block::Plane(i)) => {
                let s = &survey.planes[i];
                BlockPrior {
                    pose: plane_frame(&Vec3::from(s.normal), s.offset),
                    sigma_m: s.sigma_m,
                    sigma_rad: s.sigma_deg.to_radians(),
                }
            }
        };
        blocks.push(which);
        problem.add_block(prior).map_err(RigFailure::Solver)
    };
    let add = |problem: &mut JointProblem<'a>, o: RigObservation<'a>| {
        problem.add_observation(o).map(|_| ()).map_err(RigFailure::Solver)
    };
    for (c, seen) in cameras.iter().enumerate() {
        for (k, corners) in seen {
            let observation = BoardObservation { object, corners, ..BoardObservation::default() };
            let b = block(&mut problem, Block::Board(*k))?;
            add(
                &mut problem,
                RigObservation { frame: 0, block: b, camera: Some(c), lidar: None, observation },
            )?;
        }
    }
    for m in lidars {
        let observation = BoardObservation {
            holes_board: &m.holes_board,
            holes_lidar: &m.holes_lidar,
            hole_sigma_px: Some(m.hole_sigma_px),
            plane: m.plane,
            ..BoardObservation::default()
        };
        let b = block(&mut problem, Block::Board(m.board))?;
        let o = RigObservation {
            frame: 0,
            block: b,
            camera: m.camera,
            lidar: Some(m.lidar),
            observation,
        };
        add(&mut problem, o)?;
    }
    for (l, planes) in planes.iter().enumerate() {
        for (i, points) in planes {
            let observation =
                BoardObservation { plane: Some(*points), ..BoardObservation::default() };
            let b = block(&mut problem, Block::Plane(*i))?;
            add(
                &mut problem,
                RigObservation { frame: 0, block: b, camera: None, lidar: Some(l), observation },
            )?;
        }
    }
    Ok((problem, blocks))
}
