//! A rig's calibration: every sensor through the one-pair solves, the extrinsics composed
//! with their σ propagated; in a surveyed room that composition is the start of ONE joint
//! solve of the whole rig ([`crate::solve::rig`]), which gives the result.
//!
//! Every camera is solved with every LiDAR (the one-pair run, [`super::calibrate_with_clouds`],
//! on [`Rig::pair_room`]). A camera's run is its run with the LiDAR that places most of
//! its boards (or its intrinsics-only run when none does); a LiDAR's is its run with the
//! camera it shares most boards with.
//!
//! - **Surveyed room**: each camera's run gives its intrinsics and its pose in the room;
//!   camera → first camera = `room→first ∘ (room→camera)⁻¹`; LiDAR → first camera =
//!   `room→first ∘ (room→c)⁻¹ ∘ LiDAR→c` through its camera `c`'s run (just `LiDAR→first`
//!   when `c` is the first camera). Then the joint solve: every camera's boards as its run
//!   identified them, every LiDAR's boards placed on the surveyed boards through the
//!   composed start (holes paired with the model's), every LiDAR's points on the surveyed
//!   planes; intrinsics, mountings, the room pose, boards and planes solved at once, σ from
//!   its normal equations. Sensors whose views never overlap are tied through the room.
//! - **Free boards** (the composition is the result): LiDAR → first camera from its run with
//!   the first camera, else through the camera it shares boards with; camera → first camera
//!   through a LiDAR that places boards in both cameras' runs: `LiDAR→first ∘ (LiDAR→camera)⁻¹`.
//!
//! Composition σ: first-order propagation of each run's pose covariance
//! ([`Calibration::pose_covariance`], left perturbations), runs taken as independent (over
//! ten simulated vehicles the LiDAR translations' σ came out 1.8× optimistic; the joint σ are
//! honest, docs/rigs.md).
//!
//! Gate: each run is gated by the room's `[quality]`; a rig is accepted only when every
//! sensor is (docs/rigs.md: one failing sensor rejects the whole run and is named).
//! A joint solve that fails, or puts a board outside its survey σ, rejects the rig
//! ([`RigFailure`]); a sensor's verdict is a [`SensorRejection`].

mod failure;
mod joint;
mod verdict;

pub use failure::RigFailure;
pub use verdict::SensorRejection;

use std::collections::BTreeMap;

use nalgebra::{DMatrix, Matrix3};

use super::projection_map::projection_map;
use super::{
    calibrate_with_clouds, corner_start, gate, CalibrateOptions, Calibration, CameraBoard,
    FrameDetections, LidarAngles, LidarBoard, MovedPose, Rejection,
};
use crate::geometry::{se3::so3_log, Se3, Vec3};
use crate::lidar::Point;
use crate::result::{
    CameraResult, Extrinsic, ProjectionMap, RigExtrinsic, RigResult, SensorResult, Status,
    Uncertainty,
};
use crate::rig::{Rig, SensorKind};
use crate::solve::linalg::max_eigenvalue3;
use crate::solve::rig::worst_axis_sigma;
use crate::target::{QualitySpec, Room};

use joint::*;

/// What one LiDAR saw: its boards and its sweep (accumulated for a standing vehicle).
#[derive(Clone, Copy, Debug)]
pub struct LidarInput<'a> {
    pub boards: &'a [LidarBoard],
    pub cloud: &'a [Point],
}

/// A rig's calibration: the result file and the pair runs it came from.
#[derive(Clone, Debug)]
pub struct RigCalibration {
    pub result: RigResult,
    /// The first camera's run with the first LiDAR (the one-pair fields' source with free
    /// boards; the joint solve's start in a surveyed room).
    pub first: Calibration,
    /// Every pair run: (camera, LiDAR or `None` for intrinsics only) → run.
    pub runs: BTreeMap<(usize, Option<usize>), Calibration>,
    /// The result as the pair runs composed it, before the joint solve replaced its
    /// values (for comparisons; `None` for a rig beyond the joint solve's capacity, whose
    /// result it is).
    pub composition: Option<RigResult>,
}

/// Calibrates every sensor of `rig` in `room` from each camera's boards (`cameras[c]`) and
/// each LiDAR's boards and sweep (`lidars[l]`), one frame per sensor.
pub fn calibrate_rig(
    room: &Room,
    rig: &Rig,
    cameras: &[Vec<CameraBoard>],
    lidars: &[LidarInput<'_>],
    options: &CalibrateOptions,
) -> RigCalibration {
    let surveyed = room.survey.is_some() && !options.free_boards;
    let in_force = options.current_rig.as_ref();
    // The pair runs are gated per sensor; the change limits are the rig's (below).
    let options = &CalibrateOptions { current: None, current_rig: None, ..options.clone() };
    // Each camera's start from its corners, once: every pair run of the camera starts
    // from it (it is the costliest part of a run's start). The first camera's may be
    // given (made to find the LiDARs' boards).
    let starts: Vec<CalibrateOptions> = crate::parallel::map(&rig.cameras, |c, _| {
        let given = options.corner_start.clone().filter(|_| c == 0);
        let start = given.or_else(|| {
            let camera = cameras.get(c).cloned().unwrap_or_default();
            let frame = FrameDetections { camera, lidar: Vec::new() };
            corner_start(&rig.pair_room(room, c, None), std::slice::from_ref(&frame)).ok()
        });
        CalibrateOptions { corner_start: start, ..options.clone() }
    });
    // Every camera with every LiDAR: independent runs, spread over the cores.
    let keys: Vec<(usize, Option<usize>)> = (0..rig.cameras.len())
        .flat_map(|c| (0..rig.lidars.len()).map(move |l| (c, Some(l))))
        .collect();
    let solved = crate::parallel::map(&keys, |_, &key| {
        pair_run(room, rig, cameras, lidars, key, surveyed, &starts[key.0])
    });
    let mut runs: BTreeMap<_, _> = keys.into_iter().zip(solved).collect();
    let counts: Vec<Vec<usize>> = (0..rig.cameras.len())
        .map(|c| (0..rig.lidars.len()).map(|l| runs[&(c, Some(l))].hole_boards()).collect())
        .collect();
    let placed = |c: usize, l: usize| counts[c][l];
    // Each camera's run: the LiDAR that places most of its boards, else intrinsics only.
    let camera_runs: Vec<(usize, Option<usize>)> =
        (0..rig.cameras.len()).map(|c| (c, best(rig.lidars.len(), |l| placed(c, l)))).collect();
    for &key in &camera_runs {
        if key.1.is_none() {
            let run = pair_run(room, rig, cameras, lidars, key, surveyed, &starts[key.0]);
            runs.insert(key, run);
        }
    }
    let lidar_cameras: Vec<Option<usize>> =
        (0..rig.lidars.len()).map(|l| best(rig.cameras.len(), |c| placed(c, l))).collect();
    let composer =
        Composer { rig, runs: &runs, surveyed, camera_runs: &camera_runs, placed: &placed };
    let mut sensors = BTreeMap::new();
    let mut extrinsics = Vec::new();
    let mut failures = Vec::new();
    let mut start = Start {
        camera_to_first: vec![None; rig.cameras.len()],
        lidar_to_first: vec![None; rig.lidars.len()],
        lidar_cameras: lidar_cameras.clone(),
    };
    for (c, camera) in rig.cameras.iter().enumerate() {
        let run = &runs[&camera_runs[c]];
        let mut entry = sensor_entry(run, camera_runs[c].1.map(|l| rig.lidars[l].name.to_string()));
        entry.camera = Some(run.result.camera.clone());
        entry.uncertainty = Some(run.result.uncertainty.clone());
        entry.camera_in_room = run.result.camera_in_room.clone();
        entry.projection_uncertainty = run.result.projection_uncertainty.clone();
        if let (true, Some(in_room), Some(_)) =
            (surveyed, &run.result.camera_in_room, rig.lidars.first())
        {
            let reference = rig.pair_room(room, c, Some(0));
            if let Some(lidar) = &reference.lidar {
                if let Err(reason) = super::gate::check_parking(&room.quality, lidar, in_room) {
                    reject(&mut entry, &reason);
                }
            }
        }
        if c > 0 {
            match composer.camera_to_first(c) {
                Ok(ext) => {
                    start.camera_to_first[c] = Some(ext.pose);
                    extrinsics.push(ext.named(camera.name.as_str(), rig));
                }
                Err(reason) => reject(&mut entry, &reason),
            }
        }
        note_failure(&mut failures, "camera", camera.name.as_str(), &entry);
        sensors.insert(camera.name.to_string(), entry);
    }
    for (l, lidar) in rig.lidars.iter().enumerate() {
        let mut entry = match lidar_cameras[l] {
            Some(c) => sensor_entry(&runs[&(c, Some(l))], Some(rig.cameras[c].name.to_string())),
            None => SensorResult {
                camera: None,
                uncertainty: None,
                lidar: true,
                camera_in_room: None,
                status: Status::Rejected,
                reason: Some(SensorRejection::NoBoardSeen.to_string()),
                solved_with: None,
                projection_uncertainty: None,
            },
        };
        entry.lidar = true;
        if let Some(c) = lidar_cameras[l] {
            match composer.lidar_to_first(l, c) {
                Ok(ext) => {
                    start.lidar_to_first[l] = Some(ext.pose);
                    extrinsics.push(ext.named(lidar.name.as_str(), rig));
                }
                Err(reason) => reject(&mut entry, &reason),
            }
        }
        note_failure(&mut failures, "lidar", lidar.name.as_str(), &entry);
        sensors.insert(lidar.name.to_string(), entry);
    }
    let first_key = if rig.lidars.is_empty() { camera_runs[0] } else { (0, Some(0)) };
    let first = runs[&first_key].clone();
    let mut pair = first.result.clone();
    if !failures.is_empty() {
        pair.status = Status::Rejected;
        pair.reason = Some(failures.join("; "));
    } else {
        pair.status = Status::Accepted;
        pair.reason = None;
    }
    let composition = RigResult { pair, sensors, extrinsics };
    let mut result = composition.clone();
    let fits = rig.cameras.len() <= JOINT_CAMERAS && rig.lidars.len() <= JOINT_LIDARS;
    let targets = match (surveyed, &room.survey) {
        (true, Some(survey)) => Targets::Surveyed(survey),
        _ => Targets::Free,
    };
    if !fits {
        tracing::warn!("a rig beyond the joint solve's capacity keeps the composition");
    } else {
        let inputs = (cameras, lidars);
        match solve_jointly(room, targets, rig, &runs, &camera_runs, inputs, &start) {
            Ok(joint) => {
                apply_joint(&mut result, &joint, rig, targets);
                let lidar_runs =
                    Runs { runs: &runs, cameras: &camera_runs, lidars: &lidar_cameras };
                judge_jointly(&mut result, &joint, room, rig, &lidar_runs, options.lidar_angles);
            }
            Err(reason) => reject_rig(&mut result.pair, &reason),
        }
    }
    if let Some(current) = in_force {
        judge_changes(&mut result, current, &room.quality, rig);
    }
    let composition = fits.then_some(composition);
    RigCalibration { result, first, runs, composition }
}

/// The change limits against the rig in force: every camera's intrinsics and every
/// sensor's mounting (its extrinsic to the first camera) against the same sensor's there.
/// A sensor the rig in force lacks has nothing to change from. A sensor beyond a limit is
/// rejected, named, and the rig with it.
fn judge_changes(result: &mut RigResult, current: &RigResult, q: &QualitySpec, rig: &Rig) {
    let mounting = |r: &RigResult, name: &str| {
        let e = r.extrinsics.iter().find(|e| e.from == name)?;
        Some(Extrinsic { rotation: e.rotation, translation: e.translation })
    };
    let change = |name: &str| -> Result<(), Rejection> {
        let camera = |r: &RigResult| r.sensors.get(name).and_then(|s| s.camera.clone());
        if let (Some(a), Some(b)) = (camera(current), camera(result)) {
            gate::intrinsics_within_change(q, &a, &b)?;
        }
        match (mounting(current, name), mounting(result, name)) {
            (Some(x), Some(y)) => gate::extrinsic_within_change(q, MovedPose::Mounting, &x, &y),
            _ => Ok(()),
        }
    };
    let cameras = rig.cameras.iter().map(|c| ("camera", c.name.as_str()));
    let sensors = cameras.chain(rig.lidars.iter().map(|l| ("lidar", l.name.as_str())));
    let changed: Vec<_> =
        sensors.filter_map(|(kind, name)| change(name).err().map(|r| (kind, name, r))).collect();
    let mut failures = Vec::new();
    for (kind, name, reason) in changed {
        let Some(entry) = result.sensors.get_mut(name) else { continue };
        reject(entry, &reason);
        note_failure(&mut failures, kind, name, entry);
    }
    if !failures.is_empty() {
        reject_rig(&mut result.pair, &failures.join("; "));
    }
}

/// The joint solution written into the result: every camera's intrinsics, σ and pose in
/// the room, every extrinsic and its σ, the one-pair fields (first camera, first LiDAR).
/// The sensors' verdicts are [`judge_jointly`]'s. With free boards there is no room frame,
/// so no camera has a pose in the room, and a sensor the boards do not tie to the first
/// camera was not solved: a camera keeps its pair run's values, and no extrinsic is given.
fn apply_joint(result: &mut RigResult, joint: &Joint, rig: &Rig, targets: Targets<'_>) {
    let (p, cov) = (&joint.params, &joint.covariance);
    let e = &joint.evidence;
    let lidar_of = |name: &Option<String>| match name.as_deref().and_then(|n| rig.find(n)) {
        Some((SensorKind::Lidar, l)) => Some(l),
        _ => None,
    };
    for (c, camera) in rig.cameras.iter().enumerate().filter(|(c, _)| e.camera_tied[*c]) {
        let Some(entry) = result.sensors.get_mut(camera.name.as_str()) else { continue };
        let lidar = lidar_of(&entry.solved_with);
        entry.camera = Some(CameraResult::from_camera(&p.cameras[c]));
        entry.uncertainty = Some(joint_uncertainty(joint, c, lidar));
        let room_to_camera = p.first_to_camera[c].compose(&p.room_to_first[0]);
        entry.camera_in_room = match targets {
            Targets::Surveyed(_) => Some(Extrinsic::from_se3(&room_to_camera.inverse())),
            Targets::Free => None,
        };
    }
    // Every sensor but the first camera, in the rig's order: the joint solve has each
    // mounting, also where the composition had none (a LiDAR no camera shares a board with
    // starts at its nominal mounting and is tied to the room by its planes).
    let first = rig.cameras[0].name.as_str();
    let cameras = (1..rig.cameras.len()).filter(|&c| e.camera_tied[c]).map(|c| {
        let a = &p.first_to_camera[c];
        (rig.cameras[c].name.as_str(), a.inverse(), cov.camera_to_first(c, a))
    });
    let lidars = rig
        .lidars
        .iter()
        .enumerate()
        .filter(|(l, _)| e.lidar_tied[*l])
        .map(|(l, lidar)| (lidar.name.as_str(), p.lidar_to_first[l], cov.lidar_to_first(l)));
    result.extrinsics = cameras
        .chain(lidars)
        .map(|(from, pose, covariance)| {
            let (rotation, translation) = worst_axis_sigma(&covariance);
            let x = Extrinsic::from_se3(&pose);
            RigExtrinsic {
                from: from.to_string(),
                to: first.to_string(),
                rotation: x.rotation,
                translation: x.translation,
                sigma_rotation_deg: rotation.to_degrees(),
                sigma_translation_m: translation,
            }
        })
        .collect();
    let pair = &mut result.pair;
    if let Some(entry) = result.sensors.get(first) {
        pair.camera = entry.camera.clone().unwrap_or(pair.camera.clone());
        pair.camera_in_room = entry.camera_in_room.clone();
    }
    let with_lidar = pair.lidar_to_camera.is_some() && !rig.lidars.is_empty();
    pair.uncertainty = joint_uncertainty(joint, 0, with_lidar.then_some(0));
    if with_lidar {
        pair.lidar_to_camera = Some(Extrinsic::from_se3(&p.lidar_to_first[0]));
        pair.quality.hole_rms_px = joint.report.hole_rms_px[0];
    }
    pair.quality.corner_rms_px = joint.report.corner_rms_px[0];
    tracing::debug!(iterations = joint.iterations, "rig solved jointly");
}

/// The pair runs a rig's sensors were solved with: each camera's, each LiDAR's camera.
struct Runs<'a> {
    runs: &'a BTreeMap<(usize, Option<usize>), Calibration>,
    cameras: &'a [(usize, Option<usize>)],
    lidars: &'a [Option<usize>],
}

/// In a surveyed room the sensors' verdicts are the joint solve's, not their pair runs'
/// (a pair run sees only the boards both of its sensors see; the joint solve ties every
/// sensor to the room). A camera: the surveyed boards it sees (`min_boards`), its corners'
/// RMS, its coverage, its intrinsics' σ and its parking box. A LiDAR: the surveyed targets
/// it registers against, boards (holes or face) and planes alike (`min_lidar_boards`: the
/// survey gives each its pose, so a LiDAR whose holes no camera sees is still tied to the
/// room), its hole term's RMS, and the σ of its mounting relative to its camera. The rig is
/// accepted only when every sensor is.
///
/// With free boards the same, but nothing is surveyed: a camera counts the boards it sees,
/// a LiDAR the boards it places by their holes in a camera (a board's face alone leaves
/// the LiDAR three ways to move), and a sensor the shared boards do not tie to the first
/// camera (directly or through a LiDAR) is rejected by name.
fn judge_jointly(
    result: &mut RigResult,
    joint: &Joint,
    room: &Room,
    rig: &Rig,
    runs: &Runs<'_>,
    angles: LidarAngles,
) {
    let q = &room.quality;
    let mut failures = Vec::new();
    for (c, camera) in rig.cameras.iter().enumerate() {
        let Some(entry) = result.sensors.get_mut(camera.name.as_str()) else { continue };
        let lidar = runs.cameras[c].1;
        entry.projection_uncertainty = Some(joint_map(joint, c, lidar, q.projection_range_m));
        let verdict = judge_camera(joint, room, rig, c, &runs.runs[&runs.cameras[c]], entry);
        set_verdict(entry, verdict);
        note_failure(&mut failures, "camera", camera.name.as_str(), entry);
    }
    for (l, lidar) in rig.lidars.iter().enumerate() {
        let Some(entry) = result.sensors.get_mut(lidar.name.as_str()) else { continue };
        let c = runs.lidars[l].unwrap_or(0);
        let verdict = judge_lidar(joint, q, l, c, angles);
        entry.solved_with.get_or_insert_with(|| rig.cameras[c].name.to_string());
        set_verdict(entry, verdict);
        note_failure(&mut failures, "lidar", lidar.name.as_str(), entry);
    }
    let pair = &mut result.pair;
    (pair.status, pair.reason) = match failures.is_empty() {
        true => (Status::Accepted, None),
        false => (Status::Rejected, Some(failures.join("; "))),
    };
}

/// LiDAR `l`'s joint verdict (see [`judge_jointly`]); `c` is the camera it was solved with.
fn judge_lidar(
    joint: &Joint,
    q: &QualitySpec,
    l: usize,
    c: usize,
    angles: LidarAngles,
) -> Result<(), SensorRejection> {
    let e = &joint.evidence;
    untied(e.lidar_tied[l])?;
    let count = match e.free {
        false => e.lidar_hole_boards[l] + e.lidar_face_boards[l] + e.lidar_planes[l],
        true => e.lidar_hole_boards[l],
    };
    gate::check(count >= q.min_lidar_boards as usize, || SensorRejection::TooFewLidarTargets {
        count,
        surveyed: !e.free,
        needed: q.min_lidar_boards,
    })?;
    gate::angles_checked(angles, e.lidar_hole_boards[l])?;
    if e.lidar_hole_boards[l] > 0 {
        gate::holes_fit(q, joint.report.hole_rms_px[l])?;
    }
    Ok(gate::extrinsic_certain(q, &joint_uncertainty(joint, c, Some(l)))?)
}

/// Camera `c`'s joint verdict (see [`judge_jointly`]); `run` is its pair run (its
/// detections' coverage) and `entry` holds the joint values.
fn judge_camera(
    joint: &Joint,
    room: &Room,
    rig: &Rig,
    c: usize,
    run: &Calibration,
    entry: &SensorResult,
) -> Result<(), SensorRejection> {
    let q = &room.quality;
    let min_boards = q.min_boards.unwrap_or(room.board.count) as usize;
    let e = &joint.evidence;
    untied(e.camera_tied[c])?;
    let seen = e.camera_boards[c];
    gate::check(seen >= min_boards, || SensorRejection::TooFewBoards {
        seen,
        surveyed: !e.free,
        needed: min_boards,
    })?;
    gate::corners_fit(q, joint.report.corner_rms_px[c])?;
    gate::covers(q, gate::coverage(&run.camera, &run.boards))?;
    if let Some(map) = &entry.projection_uncertainty {
        let region = rig.cameras[c].region.unwrap_or(q.region);
        gate::projection_certain(&crate::target::QualitySpec { region, ..q.clone() }, map)?;
    }
    if let (Some(camera), Some(u)) = (&entry.camera, &entry.uncertainty) {
        gate::intrinsics_certain(q, camera, u)?;
    }
    let reference = rig.pair_room(room, c, Some(0));
    match (&entry.camera_in_room, &reference.lidar) {
        (Some(in_room), Some(lidar)) if !rig.lidars.is_empty() => {
            Ok(gate::check_parking(q, lidar, in_room)?)
        }
        _ => Ok(()),
    }
}

/// Camera `c`'s projection map from the joint solve: its intrinsics and, with `lidar`, that
/// LiDAR's pose to it, under the joint covariance.
fn joint_map(joint: &Joint, c: usize, lidar: Option<usize>, range_m: f64) -> ProjectionMap {
    let p = &joint.params;
    let pose = |l: usize| (l, &p.first_to_camera[c], &p.lidar_to_first[l]);
    let covariance = joint.covariance.camera_shared(c, lidar.map(pose));
    let to_camera = lidar.map(|l| p.first_to_camera[c].compose(&p.lidar_to_first[l]));
    projection_map(&p.cameras[c], &covariance, to_camera.as_ref(), range_m)
}

/// A sensor the free boards do not tie to the first camera: nothing places it.
fn untied(tied: bool) -> Result<(), SensorRejection> {
    gate::check(tied, || SensorRejection::Untied)
}

fn set_verdict(entry: &mut SensorResult, verdict: Result<(), SensorRejection>) {
    (entry.status, entry.reason) = match verdict {
        Ok(()) => (Status::Accepted, None),
        Err(reason) => (Status::Rejected, Some(reason.to_string())),
    };
}

/// Camera `c`'s σ from the joint covariance: intrinsics, and LiDAR `lidar` → camera `c`
/// (zero without a LiDAR).
fn joint_uncertainty(joint: &Joint, c: usize, lidar: Option<usize>) -> Uncertainty {
    let (p, cov) = (&joint.params, &joint.covariance);
    let k = cov.intrinsics_sigma(c);
    let (rotation, translation) = lidar.map_or((0.0, 0.0), |l| {
        let lc = cov.lidar_to_camera(l, c, &p.first_to_camera[c], &p.lidar_to_first[l]);
        worst_axis_sigma(&lc)
    });
    Uncertainty {
        fx: k[0],
        fy: k[1],
        cx: k[2],
        cy: k[3],
        rotation_deg: rotation.to_degrees(),
        translation_m: translation,
    }
}

/// One pair run: camera `c`'s boards with LiDAR `l`'s (or none), in the pair's room. In a
/// surveyed room the parking box is the first LiDAR's nominal frame, so a run with another
/// LiDAR leaves it to [`calibrate_rig`].
fn pair_run(
    room: &Room,
    rig: &Rig,
    cameras: &[Vec<CameraBoard>],
    lidars: &[LidarInput<'_>],
    (c, l): (usize, Option<usize>),
    surveyed: bool,
    options: &CalibrateOptions,
) -> Calibration {
    let mut pair = rig.pair_room(room, c, l);
    if surveyed && l != Some(0) {
        pair.quality.max_parking_offset_m = f64::MAX;
        pair.quality.max_parking_yaw_deg = f64::MAX;
    }
    let frame = FrameDetections {
        camera: cameras.get(c).cloned().unwrap_or_default(),
        lidar: l.and_then(|l| lidars.get(l)).map_or(Vec::new(), |i| i.boards.to_vec()),
    };
    // In a surveyed room a pair run is the joint solve's start: its sweep's points on the
    // surveyed planes, which the joint solve selects again for every LiDAR, are left out
    // (selecting and trimming them in every pair's two passes was an eighth of a rig's CPU).
    let clouds: Vec<&[Point]> = match surveyed {
        true => Vec::new(),
        false => l.and_then(|l| lidars.get(l)).map(|i| i.cloud).into_iter().collect(),
    };
    calibrate_with_clouds(&pair, std::slice::from_ref(&frame), &clouds, options)
}

/// The index in `0..n` with the largest positive score, the first of equals.
fn best(n: usize, score: impl Fn(usize) -> usize) -> Option<usize> {
    (0..n).filter(|&i| score(i) > 0).fold(None, |b: Option<usize>, i| match b {
        Some(j) if score(j) >= score(i) => Some(j),
        _ => Some(i),
    })
}

fn sensor_entry(run: &Calibration, solved_with: Option<String>) -> SensorResult {
    SensorResult {
        camera: None,
        uncertainty: None,
        lidar: false,
        camera_in_room: None,
        status: run.result.status,
        reason: run.result.reason.clone(),
        solved_with,
        projection_uncertainty: None,
    }
}

/// Rejects a sensor, `reason` added to any it already has.
fn reject(entry: &mut SensorResult, reason: &dyn core::fmt::Display) {
    entry.status = Status::Rejected;
    entry.reason = Some(joined(entry.reason.take(), reason));
}

/// Rejects the whole rig, `reason` added to any it already has.
fn reject_rig(pair: &mut crate::result::CalibrationResult, reason: &dyn core::fmt::Display) {
    pair.status = Status::Rejected;
    pair.reason = Some(joined(pair.reason.take(), reason));
}

/// A result's reason with `reason` added (`"; "` between them).
fn joined(before: Option<String>, reason: &dyn core::fmt::Display) -> String {
    match before {
        Some(r) => format!("{r}; {reason}"),
        None => reason.to_string(),
    }
}

fn note_failure(failures: &mut Vec<String>, kind: &str, name: &str, entry: &SensorResult) {
    if entry.status == Status::Rejected {
        let reason = entry.reason.as_deref().unwrap_or("rejected");
        failures.push(format!("{kind} `{name}`: {reason}"));
    }
}

/// Which pose of a run a factor is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    LidarToCamera,
    RoomToCamera,
}

/// One factor of a composition: a run's pose, maybe inverted.
#[derive(Clone, Copy, Debug)]
struct Factor {
    run: (usize, Option<usize>),
    slot: Slot,
    inverted: bool,
}

/// A composed extrinsic and its worst-axis σ.
struct Composed {
    pose: Se3,
    sigma_rotation_deg: f64,
    sigma_translation_m: f64,
}

impl Composed {
    fn named(&self, from: &str, rig: &Rig) -> RigExtrinsic {
        let e = Extrinsic::from_se3(&self.pose);
        RigExtrinsic {
            from: from.to_string(),
            to: rig.cameras[0].name.to_string(),
            rotation: e.rotation,
            translation: e.translation,
            sigma_rotation_deg: self.sigma_rotation_deg,
            sigma_translation_m: self.sigma_translation_m,
        }
    }
}

/// Composes extrinsics from the pair runs.
struct Composer<'a, F: Fn(usize, usize) -> usize> {
    rig: &'a Rig,
    runs: &'a BTreeMap<(usize, Option<usize>), Calibration>,
    surveyed: bool,
    camera_runs: &'a [(usize, Option<usize>)],
    placed: &'a F,
}

impl<F: Fn(usize, usize) -> usize> Composer<'_, F> {
    /// Camera `c` → first camera.
    fn camera_to_first(&self, c: usize) -> Result<Composed, RigFailure> {
        self.compose(&self.camera_factors(c)?)
    }

    /// LiDAR `l` → first camera, tied through camera `c` (the one it shares most boards with).
    fn lidar_to_first(&self, l: usize, c: usize) -> Result<Composed, RigFailure> {
        let own = Factor { run: (c, Some(l)), slot: Slot::LidarToCamera, inverted: false };
        if c == 0 {
            return self.compose(&[own]);
        }
        if !self.surveyed && (self.placed)(0, l) > 0 {
            let direct = Factor { run: (0, Some(l)), slot: Slot::LidarToCamera, inverted: false };
            return self.compose(&[direct]);
        }
        let mut factors = self.camera_factors(c)?;
        if self.surveyed {
            // camera_factors ends with (room→c)⁻¹ from c's own run; tie through this run's.
            factors.pop();
            factors.push(Factor { run: (c, Some(l)), slot: Slot::RoomToCamera, inverted: true });
        }
        factors.push(own);
        self.compose(&factors)
    }

    /// The factors of camera `c` → first camera.
    fn camera_factors(&self, c: usize) -> Result<Vec<Factor>, RigFailure> {
        if self.surveyed {
            let (first, own) = (self.camera_runs[0], self.camera_runs[c]);
            for key in [first, own] {
                if self.runs[&key].result.camera_in_room.is_none() {
                    let camera = self.rig.cameras[key.0].name.to_string();
                    return Err(RigFailure::NoRoomPose { camera });
                }
            }
            return Ok(vec![
                Factor { run: first, slot: Slot::RoomToCamera, inverted: false },
                Factor { run: own, slot: Slot::RoomToCamera, inverted: true },
            ]);
        }
        // Free boards: through the LiDAR that places most boards in both cameras' runs.
        let shared = best(self.rig.lidars.len(), |l| (self.placed)(0, l).min((self.placed)(c, l)));
        let Some(l) = shared else {
            let first_camera = self.rig.cameras[0].name.to_string();
            return Err(RigFailure::NoSharedLidarBoard { first_camera });
        };
        Ok(vec![
            Factor { run: (0, Some(l)), slot: Slot::LidarToCamera, inverted: false },
            Factor { run: (c, Some(l)), slot: Slot::LidarToCamera, inverted: true },
        ])
    }

    fn pose(&self, f: &Factor, delta: &[f64]) -> Result<Se3, RigFailure> {
        let run = &self.runs[&f.run];
        let pose = match f.slot {
            Slot::LidarToCamera => run.lidar_to_camera.ok_or(RigFailure::PairRunNoExtrinsic)?,
            Slot::RoomToCamera => run
                .result
                .camera_in_room
                .as_ref()
                .ok_or(RigFailure::PairRunNoRoomPose)?
                .to_se3()
                .inverse(),
        };
        let d = crate::geometry::Vec6::from_column_slice(delta);
        let pose = pose.perturb_left(&d);
        Ok(if f.inverted { pose.inverse() } else { pose })
    }

    /// The product of `factors` at the solution, and its σ by central differences of the
    /// left perturbations of every run's poses.
    fn compose(&self, factors: &[Factor]) -> Result<Composed, RigFailure> {
        let mut keys: Vec<(usize, Option<usize>)> = Vec::new();
        for f in factors {
            if !keys.contains(&f.run) {
                keys.push(f.run);
            }
        }
        let n = 12 * keys.len();
        let product = |x: &[f64]| -> Result<Se3, RigFailure> {
            let mut out = Se3::identity();
            for f in factors {
                let k = keys.iter().position(|k| *k == f.run).unwrap_or(0);
                let at = 12 * k + if f.slot == Slot::LidarToCamera { 0 } else { 6 };
                out = out.compose(&self.pose(f, &x[at..at + 6])?);
            }
            Ok(out)
        };
        let zero = vec![0.0; n];
        let pose = product(&zero)?;
        let mut covariance = DMatrix::<f64>::zeros(n, n);
        for (k, key) in keys.iter().enumerate() {
            let c = self.runs[key].pose_covariance.ok_or(RigFailure::PairRunFailed)?;
            covariance.view_mut((12 * k, 12 * k), (12, 12)).copy_from(&c);
        }
        let mut jacobian = DMatrix::<f64>::zeros(6, n);
        const H: f64 = 1e-6;
        for i in 0..n {
            let (mut plus, mut minus) = (zero.clone(), zero.clone());
            plus[i] = H;
            minus[i] = -H;
            let (a, b) = (product(&plus)?, product(&minus)?);
            let diff = left_difference(&a, &pose) - left_difference(&b, &pose);
            jacobian.column_mut(i).copy_from(&(diff / (2.0 * H)));
        }
        let out = &jacobian * covariance * jacobian.transpose();
        let worst = |at: usize| {
            let block: Matrix3<f64> = out.fixed_view::<3, 3>(at, at).into_owned();
            max_eigenvalue3(&block).max(0.0).sqrt()
        };
        Ok(Composed {
            pose,
            sigma_rotation_deg: worst(0).to_degrees(),
            sigma_translation_m: worst(3),
        })
    }
}

/// `a` relative to `b` as a left perturbation: `[log(R_a R_bᵀ); t_a − t_b]`.
fn left_difference(a: &Se3, b: &Se3) -> nalgebra::SVector<f64, 6> {
    let w: Vec3 = so3_log(&(a.rotation * b.rotation.transpose()));
    let t = a.translation - b.translation;
    nalgebra::SVector::<f64, 6>::new(w.x, w.y, w.z, t.x, t.y, t.z)
}
