//! A rig's calibration, first slice: every sensor through the one-pair solves, the
//! extrinsics composed with their σ propagated.
//!
//! Every camera is solved with every LiDAR (the one-pair run, [`super::calibrate_with_clouds`],
//! on [`Rig::pair_room`]). A camera's result is its run with the LiDAR that places most of
//! its boards (or its intrinsics-only run when none does); a LiDAR's is its run with the
//! camera it shares most boards with.
//!
//! - **Surveyed room**: each camera's run gives its intrinsics and its pose in the room;
//!   camera → first camera = `room→first ∘ (room→camera)⁻¹`; LiDAR → first camera =
//!   `room→first ∘ (room→c)⁻¹ ∘ LiDAR→c` through its camera `c`'s run (just `LiDAR→first`
//!   when `c` is the first camera). Sensors whose views never overlap are tied through
//!   the room.
//! - **Free boards**: LiDAR → first camera from its run with the first camera, else through
//!   the camera it shares boards with; camera → first camera through a LiDAR that places
//!   boards in both cameras' runs: `LiDAR→first ∘ (LiDAR→camera)⁻¹`.
//!
//! σ: first-order propagation of each run's pose covariance ([`Calibration::pose_covariance`],
//! left perturbations) through the composition, runs taken as independent (they share
//! the survey's boards, whose σ each run's room solve already carries).
//!
//! Gate: each run is gated by the room's `[quality]`; a rig is accepted only when every
//! sensor is (see README, "Rigs": one failing sensor rejects the whole run and is named).

use std::collections::BTreeMap;

use nalgebra::{DMatrix, Matrix3};

use super::{
    calibrate_with_clouds, CalibrateOptions, Calibration, CameraBoard, FrameDetections, LidarBoard,
};
use crate::geometry::{se3::so3_log, Se3, Vec3};
use crate::lidar::Point;
use crate::result::{Extrinsic, RigExtrinsic, RigResult, SensorResult, Status};
use crate::rig::Rig;
use crate::solve::linalg::max_eigenvalue3;
use crate::target::Room;

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
    /// The run whose result is the one-pair fields (first camera with the first LiDAR).
    pub first: Calibration,
    /// Every pair run: (camera, LiDAR or `None` for intrinsics only) → run.
    pub runs: BTreeMap<(usize, Option<usize>), Calibration>,
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
    let mut runs = BTreeMap::new();
    for c in 0..rig.cameras.len() {
        for l in 0..rig.lidars.len() {
            runs.insert(
                (c, Some(l)),
                pair_run(room, rig, cameras, lidars, (c, Some(l)), surveyed, options),
            );
        }
    }
    let counts: Vec<Vec<usize>> = (0..rig.cameras.len())
        .map(|c| (0..rig.lidars.len()).map(|l| lidar_boards(&runs[&(c, Some(l))])).collect())
        .collect();
    let placed = |c: usize, l: usize| counts[c][l];
    // Each camera's run: the LiDAR that places most of its boards, else intrinsics only.
    let camera_runs: Vec<(usize, Option<usize>)> =
        (0..rig.cameras.len()).map(|c| (c, best(rig.lidars.len(), |l| placed(c, l)))).collect();
    for &key in &camera_runs {
        if key.1.is_none() {
            runs.insert(key, pair_run(room, rig, cameras, lidars, key, surveyed, options));
        }
    }
    let lidar_cameras: Vec<Option<usize>> =
        (0..rig.lidars.len()).map(|l| best(rig.cameras.len(), |c| placed(c, l))).collect();
    let composer =
        Composer { rig, runs: &runs, surveyed, camera_runs: &camera_runs, placed: &placed };
    let mut sensors = BTreeMap::new();
    let mut extrinsics = Vec::new();
    let mut failures = Vec::new();
    for (c, camera) in rig.cameras.iter().enumerate() {
        let run = &runs[&camera_runs[c]];
        let mut entry = sensor_entry(run, camera_runs[c].1.map(|l| rig.lidars[l].name.to_string()));
        entry.camera = Some(run.result.camera.clone());
        entry.uncertainty = Some(run.result.uncertainty.clone());
        entry.camera_in_room = run.result.camera_in_room.clone();
        if let (true, Some(in_room), Some(_)) =
            (surveyed, &run.result.camera_in_room, rig.lidars.first())
        {
            let reference = rig.pair_room(room, c, Some(0));
            if let Some(lidar) = &reference.lidar {
                if let Err(reason) = super::gate::check_parking(&room.quality, lidar, in_room) {
                    reject(&mut entry, reason);
                }
            }
        }
        if c > 0 {
            match composer.camera_to_first(c) {
                Ok(ext) => extrinsics.push(ext.named(camera.name.as_str(), rig)),
                Err(reason) => reject(&mut entry, reason),
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
                reason: Some("it places no board that a camera sees".into()),
                solved_with: None,
            },
        };
        entry.lidar = true;
        if let Some(c) = lidar_cameras[l] {
            match composer.lidar_to_first(l, c) {
                Ok(ext) => extrinsics.push(ext.named(lidar.name.as_str(), rig)),
                Err(reason) => reject(&mut entry, reason),
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
    RigCalibration { result: RigResult { pair, sensors, extrinsics }, first, runs }
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
    let clouds: Vec<&[Point]> =
        l.and_then(|l| lidars.get(l)).map(|i| i.cloud).into_iter().collect();
    calibrate_with_clouds(&pair, std::slice::from_ref(&frame), &clouds, options)
}

/// Boards a run placed with the LiDAR (0 without an extrinsic).
fn lidar_boards(run: &Calibration) -> usize {
    match run.lidar_to_camera {
        Some(_) => run.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count(),
        None => 0,
    }
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
    }
}

fn reject(entry: &mut SensorResult, reason: String) {
    entry.status = Status::Rejected;
    entry.reason = Some(match entry.reason.take() {
        Some(r) => format!("{r}; {reason}"),
        None => reason,
    });
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
    fn camera_to_first(&self, c: usize) -> Result<Composed, String> {
        self.compose(&self.camera_factors(c)?)
    }

    /// LiDAR `l` → first camera, tied through camera `c` (the one it shares most boards with).
    fn lidar_to_first(&self, l: usize, c: usize) -> Result<Composed, String> {
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
    fn camera_factors(&self, c: usize) -> Result<Vec<Factor>, String> {
        if self.surveyed {
            let (first, own) = (self.camera_runs[0], self.camera_runs[c]);
            for key in [first, own] {
                if self.runs[&key].result.camera_in_room.is_none() {
                    let name = &self.rig.cameras[key.0].name;
                    return Err(format!("camera `{name}` has no pose in the room"));
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
            return Err(format!(
                "it shares no LiDAR-placed board with camera `{}` (without a survey, sensors are tied through boards both see)",
                self.rig.cameras[0].name
            ));
        };
        Ok(vec![
            Factor { run: (0, Some(l)), slot: Slot::LidarToCamera, inverted: false },
            Factor { run: (c, Some(l)), slot: Slot::LidarToCamera, inverted: true },
        ])
    }

    fn pose(&self, f: &Factor, delta: &[f64]) -> Result<Se3, String> {
        let run = &self.runs[&f.run];
        let pose = match f.slot {
            Slot::LidarToCamera => run.lidar_to_camera.ok_or("a pair run has no extrinsic")?,
            Slot::RoomToCamera => run
                .result
                .camera_in_room
                .as_ref()
                .ok_or("a pair run has no room pose")?
                .to_se3()
                .inverse(),
        };
        let d = crate::geometry::Vec6::from_column_slice(delta);
        let pose = pose.perturb_left(&d);
        Ok(if f.inverted { pose.inverse() } else { pose })
    }

    /// The product of `factors` at the solution, and its σ by central differences of the
    /// left perturbations of every run's poses.
    fn compose(&self, factors: &[Factor]) -> Result<Composed, String> {
        let mut keys: Vec<(usize, Option<usize>)> = Vec::new();
        for f in factors {
            if !keys.contains(&f.run) {
                keys.push(f.run);
            }
        }
        let n = 12 * keys.len();
        let product = |x: &[f64]| -> Result<Se3, String> {
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
            let c = self.runs[key].pose_covariance.ok_or("a pair run failed")?;
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
