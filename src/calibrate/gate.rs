//! The quality gate (`target::QualitySpec`): residuals, boards, coverage, σ, and the change
//! from the calibration in force.

use super::{
    CalibrateOptions, Calibration, FrameDetections, LidarAngles, MovedPose, Rejection, UsedBoard,
};
use crate::geometry::Camera;
use crate::result::{CalibrationResult, CameraResult, Extrinsic, ProjectionMap, Uncertainty};
use crate::target::{QualitySpec, Room};

/// The quality gate: `Err` is the first threshold the run fails.
pub(super) fn gate(
    room: &Room,
    frames: &[FrameDetections],
    options: &CalibrateOptions,
    run: &Calibration,
) -> Result<(), Rejection> {
    let q = &room.quality;
    let r = &run.result;
    let min_boards = q.min_boards.unwrap_or(room.board.count) as usize;
    for (f, frame) in frames.iter().enumerate() {
        let complete = run.boards.iter().filter(|b| b.frame as usize == f).count();
        if complete < min_boards {
            return Err(Rejection::TooFewBoards {
                frame: f,
                complete,
                needed: min_boards,
                detected: frame.camera.len(),
            });
        }
    }
    corners_fit(q, r.quality.corner_rms_px)?;
    covers(q, coverage(&run.camera, &run.boards))?;
    intrinsics_certain(q, &r.camera, &r.uncertainty)?;
    if let Some(map) = &r.projection_uncertainty {
        projection_certain(q, map)?;
    }
    if room.lidar.is_some() {
        // As the free-board solve refuses a run whose LiDAR pairs no board: accepted as
        // intrinsics only, it would put a calibration without the extrinsic in force.
        check(run.lidar_to_camera.is_some(), || Rejection::LidarUncalibrated {
            needed: q.min_lidar_boards,
        })?;
        angles_checked(options.lidar_angles, run.hole_boards())?;
        // In a surveyed room the survey gives every target its pose: the LiDAR registers
        // against boards (by their holes or their face) and planes alike, as a rig's does.
        let lidar_boards = run.boards.iter().filter(|b| b.seen_by_lidar()).count();
        let surveyed = r.camera_in_room.is_some();
        let count = if surveyed { lidar_boards + run.lidar_planes } else { lidar_boards };
        check(count >= q.min_lidar_boards as usize, || Rejection::TooFewLidarTargets {
            count,
            surveyed,
            needed: q.min_lidar_boards,
        })?;
        holes_fit(q, r.quality.hole_rms_px)?;
        if let Some(ext) = &run.lidar_to_camera {
            holes_agree(&run.boards, &run.holes_board, ext, r.quality.corner_rms_px)?;
        }
        extrinsic_certain(q, &r.uncertainty)?;
    }
    if let (Some(in_room), Some(lidar)) = (&r.camera_in_room, &room.lidar) {
        check_parking(q, lidar, in_room)?;
    }
    if let (Some(survey), Some(in_room), Some(ext)) =
        (super::surveyed_room(room, options), &r.camera_in_room, &run.lidar_to_camera)
    {
        lidar_boards_on_survey(survey, frames, &run.holes_board, &in_room.to_se3().compose(ext))?;
    }
    if let Some(current) = &options.current {
        check_change(q, current, r)?;
    }
    Ok(())
}

/// The corners' RMS reprojection error within `max_corner_rms_px`.
pub(super) fn corners_fit(q: &QualitySpec, rms_px: f64) -> Result<(), Rejection> {
    check(rms_px <= q.max_corner_rms_px, || Rejection::CornerRms {
        rms_px,
        limit_px: q.max_corner_rms_px,
    })
}

/// The used corners cover at least `min_coverage` of the image, unless the room judges the
/// projection map instead (`max_projection_sigma_px`).
pub(super) fn covers(q: &QualitySpec, coverage: f64) -> Result<(), Rejection> {
    if q.max_projection_sigma_px.is_some() {
        return Ok(());
    }
    check(coverage >= q.min_coverage, || Rejection::Coverage { coverage, min: q.min_coverage })
}

/// The focal lengths' and the principal point's σ within their limits.
pub(super) fn intrinsics_certain(
    q: &QualitySpec,
    c: &CameraResult,
    u: &Uncertainty,
) -> Result<(), Rejection> {
    check(u.fx <= q.max_sigma_focal_rel * c.fx && u.fy <= q.max_sigma_focal_rel * c.fy, || {
        Rejection::FocalUncertain { fx_px: u.fx, fy_px: u.fy, limit_rel: q.max_sigma_focal_rel }
    })?;
    check(u.cx <= q.max_sigma_principal_px && u.cy <= q.max_sigma_principal_px, || {
        Rejection::PrincipalUncertain {
            cx_px: u.cx,
            cy_px: u.cy,
            limit_px: q.max_sigma_principal_px,
        }
    })
}

/// The projection uncertainty over the room's `region` within `max_projection_sigma_px`.
pub(super) fn projection_certain(q: &QualitySpec, map: &ProjectionMap) -> Result<(), Rejection> {
    let Some(limit_px) = q.max_projection_sigma_px else { return Ok(()) };
    let Some(worst) = map.worst_in(q.region) else { return Ok(()) };
    check(worst.sigma_px <= limit_px, || Rejection::ProjectionUncertain {
        sigma_px: worst.sigma_px,
        at_px: [worst.at_px.x, worst.at_px.y],
        range_m: map.range_m,
        limit_px,
        region: q.region,
    })
}

/// The hole term's RMS within `max_hole_rms_px`.
pub(super) fn holes_fit(q: &QualitySpec, rms_px: f64) -> Result<(), Rejection> {
    check(rms_px <= q.max_hole_rms_px, || Rejection::HoleRms {
        rms_px,
        limit_px: q.max_hole_rms_px,
    })
}

/// A LiDAR placed without a board's holes (by faces and planes alone) rests on its angle
/// table unchecked ([`LidarAngles`]): refused when that table is the model's nominal one.
pub(super) fn angles_checked(angles: LidarAngles, hole_boards: usize) -> Result<(), Rejection> {
    check(hole_boards > 0 || angles == LidarAngles::Unit, || Rejection::NominalAngles)
}

/// The LiDAR's hole centres, carried into the camera by the solved extrinsic, against the
/// same holes of the camera's boards in 3D: a χ² test of their differences against the
/// holes' own σ (the detector's, checked against the truth by `tests/it/holes_sim.rs`),
/// 6 degrees of freedom taken by the extrinsic. The solve weighs holes by their pixels,
/// which hardly see depth; a board printed at the wrong scale, or a LiDAR table that
/// stretches its ranges, puts the camera's boards centimetres off the LiDAR's along the
/// line of sight, and the joint solve bends the intrinsics and the mounting to hide it.
/// Refused beyond the χ² quantile a right run passes with probability 10⁻³.
pub(super) fn holes_agree(
    boards: &[UsedBoard],
    holes_board: &[crate::geometry::Vec3],
    lidar_to_camera: &crate::geometry::Se3,
    corner_sigma_px: f64,
) -> Result<(), Rejection> {
    let (mut chi2, mut rows, mut worst) = (0.0, 0usize, 0.0f64);
    for b in boards.iter().filter(|b| !b.holes_lidar.is_empty() && b.hole_sigma_m > 0.0) {
        // Joint σ: the LiDAR's hole and the camera's board, whose depth is the less
        // certain part of its pose (taken on every axis: the test only loosens).
        let variance = b.hole_sigma_m.powi(2) + depth_sigma_m(b, corner_sigma_px).powi(2);
        for (lidar, model) in b.holes_lidar.iter().zip(holes_board) {
            let apart = lidar_to_camera.act(lidar) - b.pose.act(model);
            chi2 += apart.norm_squared() / variance;
            rows += 3;
            worst = worst.max(apart.norm());
        }
    }
    let dof = rows.saturating_sub(6);
    if dof == 0 {
        return Ok(());
    }
    let limit = chi2_quantile(dof as f64, HOLES_CHI2_Z);
    check(chi2 <= limit, || Rejection::HolesDisagree { chi2, dof, limit, worst_m: worst })
}

/// The σ of a board's depth from its corners: its image scale `s` (the corners' RMS
/// distance from their mean, px) sets the depth `Z ∝ 1/s`, and `N` corners of σ `σ_px`
/// pin `s` to about `σ_px·√(2/N)`, so `σ_Z ≈ Z·σ_px·√(2/N)/s`.
fn depth_sigma_m(board: &UsedBoard, corner_sigma_px: f64) -> f64 {
    let n = board.corners.len();
    if n < 2 {
        return 0.0;
    }
    let mean = board.corners.iter().sum::<crate::geometry::Vec2>() / n as f64;
    let spread =
        (board.corners.iter().map(|c| (c - mean).norm_squared()).sum::<f64>() / n as f64).sqrt();
    let depth = board.pose.translation.norm();
    depth * corner_sigma_px * (2.0 / n as f64).sqrt() / spread.max(1.0)
}

/// The standard normal quantile of `1 − 10⁻³`: a right run fails [`holes_agree`] this
/// rarely.
const HOLES_CHI2_Z: f64 = 3.090_232;

/// The χ² quantile of `dof` degrees of freedom at the normal quantile `z` (Wilson and
/// Hilferty's cube-root approximation, within 1 % from 10 degrees of freedom).
fn chi2_quantile(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).powi(3)
}

/// A board the LiDAR placed by its holes lies farther than this (m) from every surveyed
/// board when carried into the room by the solved mounting and parking: the run and the
/// LiDAR disagree. Right runs put them within a few centimetres (the holes' σ ≈ 1 cm, the
/// mounting's a few millimetres at the boards).
pub(super) const OFF_SURVEY_M: f64 = 0.10;

/// Every board the LiDAR placed by its holes sits on a surveyed board under the solved
/// LiDAR → room motion `lidar_to_room`. A run whose mounting rests on surfaces taken for
/// boards through a wrong nominal mounting leaves the LiDAR's own boards where the room
/// has none: refused.
pub(super) fn lidar_boards_on_survey(
    survey: &crate::target::SurveySpec,
    frames: &[FrameDetections],
    holes_board: &[crate::geometry::Vec3],
    lidar_to_room: &crate::geometry::Se3,
) -> Result<(), Rejection> {
    let centre =
        holes_board.iter().sum::<crate::geometry::Vec3>() / holes_board.len().max(1) as f64;
    let surveyed: Vec<_> = survey.boards.iter().map(|b| b.pose().act(&centre)).collect();
    let off_survey = |centre: &crate::geometry::Vec3| {
        let at = lidar_to_room.act(centre);
        surveyed.iter().map(|s| (s - at).norm()).fold(f64::INFINITY, f64::min)
    };
    let placed = frames.iter().flat_map(|f| &f.lidar).filter(|b| !b.holes.is_empty());
    let (count, off) = placed
        .map(|b| {
            off_survey(&(b.holes.iter().sum::<crate::geometry::Vec3>() / b.holes.len() as f64))
        })
        .filter(|&d| d > OFF_SURVEY_M)
        .fold((0, 0.0f64), |(n, worst), d| (n + 1, worst.max(d)));
    check(count == 0, || Rejection::OffSurvey { count, worst_m: off })
}

/// The LiDAR→camera σ (`u.rotation_deg`, `u.translation_m`) within their limits.
pub(super) fn extrinsic_certain(q: &QualitySpec, u: &Uncertainty) -> Result<(), Rejection> {
    check(
        u.rotation_deg <= q.max_sigma_rotation_deg && u.translation_m <= q.max_sigma_translation_m,
        || Rejection::ExtrinsicUncertain {
            rotation_deg: u.rotation_deg,
            translation_m: u.translation_m,
            limit_deg: q.max_sigma_rotation_deg,
            limit_m: q.max_sigma_translation_m,
        },
    )
}

/// The parking box of a surveyed room: the camera's pose in the room against the nominal
/// parking, which is the room's nominal mounting read as room → camera (the survey's room
/// frame is the nominal LiDAR frame at the nominal spot). The angle is the whole rotation
/// between the two (on a level floor, the yaw).
pub(super) fn check_parking(
    q: &QualitySpec,
    lidar: &crate::target::LidarSpec,
    camera_in_room: &crate::result::Extrinsic,
) -> Result<(), Rejection> {
    let nominal = super::association::lidar_nominal(lidar).inverse();
    let (angle, shift) = crate::result::Extrinsic::from_se3(&nominal).difference(camera_in_room);
    check(shift <= q.max_parking_offset_m && angle <= q.max_parking_yaw_deg, || Rejection::Parked {
        shift_m: shift,
        angle_deg: angle,
        limit_m: q.max_parking_offset_m,
        limit_deg: q.max_parking_yaw_deg,
    })
}

/// The change limits against the calibration in force.
fn check_change(
    q: &QualitySpec,
    current: &CalibrationResult,
    new: &CalibrationResult,
) -> Result<(), Rejection> {
    intrinsics_within_change(q, &current.camera, &new.camera)?;
    if let (Some(x), Some(y)) = (&current.lidar_to_camera, &new.lidar_to_camera) {
        extrinsic_within_change(q, MovedPose::Extrinsic, x, y)?;
    }
    Ok(())
}

/// The focal lengths and the principal point within the change limits from `a` (in force).
pub(super) fn intrinsics_within_change(
    q: &QualitySpec,
    a: &CameraResult,
    b: &CameraResult,
) -> Result<(), Rejection> {
    let focal = ((b.fx - a.fx) / a.fx).abs().max(((b.fy - a.fy) / a.fy).abs());
    check(focal <= q.max_change_focal_rel, || Rejection::FocalMoved {
        change_rel: focal,
        limit_rel: q.max_change_focal_rel,
    })?;
    let principal = (b.cx - a.cx).hypot(b.cy - a.cy);
    check(principal <= q.max_change_principal_px, || Rejection::PrincipalMoved {
        shift_px: principal,
        limit_px: q.max_change_principal_px,
    })
}

/// A pose (a run's extrinsic, a rig sensor's mounting) within the change limits from `x`
/// (in force).
pub(super) fn extrinsic_within_change(
    q: &QualitySpec,
    pose: MovedPose,
    x: &Extrinsic,
    y: &Extrinsic,
) -> Result<(), Rejection> {
    let (angle, shift) = x.difference(y);
    check(angle <= q.max_change_rotation_deg && shift <= q.max_change_translation_m, || {
        Rejection::PoseMoved {
            pose,
            angle_deg: angle,
            shift_m: shift,
            limit_deg: q.max_change_rotation_deg,
            limit_m: q.max_change_translation_m,
        }
    })
}

/// `Err(reason())` unless `ok` (the reason made only when needed).
pub(super) fn check<E>(ok: bool, reason: impl FnOnce() -> E) -> Result<(), E> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Se3, Vec3};

    /// Wilson–Hilferty against tabulated 0.999 quantiles of χ² (18: 42.312, 30: 59.703,
    /// 120: 173.617).
    #[test]
    fn chi2_quantile_meets_the_tables() {
        for (dof, table) in [(18.0, 42.312), (30.0, 59.703), (120.0, 173.617)] {
            let q = chi2_quantile(dof, HOLES_CHI2_Z);
            assert!((q / table - 1.0).abs() < 0.01, "dof {dof}: {q} against {table}");
        }
    }

    /// Two boards 6 m ahead whose LiDAR holes are where the camera's are, then 5σ farther
    /// along the line of sight (a board printed larger than the room file says).
    #[test]
    fn holes_agree_refuses_holes_off_by_five_sigma_and_passes_holes_on_the_boards() {
        let holes_board = [
            Vec3::new(-0.45, -0.35, 0.0),
            Vec3::new(0.45, -0.35, 0.0),
            Vec3::new(-0.45, 0.35, 0.0),
            Vec3::new(0.45, 0.35, 0.0),
        ];
        let sigma = 0.005;
        let board = |x: f64, depth_error: f64| {
            let pose = Se3 {
                rotation: crate::geometry::Mat3::identity(),
                translation: Vec3::new(x, 0.0, 6.0),
            };
            let holes_lidar = holes_board
                .iter()
                .map(|h| pose.act(h) + Vec3::new(0.0, 0.0, depth_error))
                .collect();
            UsedBoard {
                frame: 0,
                corners: Vec::new(),
                holes_lidar,
                hole_sigma_m: sigma,
                lidar_face: true,
                pose,
            }
        };
        let identity = Se3::identity();
        let right = [board(-1.5, 0.0), board(1.5, 0.0)];
        assert_eq!(holes_agree(&right, &holes_board, &identity, 0.0), Ok(()));
        // One board off: a common shift would be the extrinsic's, a differing one is not.
        let wrong = [board(-1.5, 0.0), board(1.5, 5.0 * sigma)];
        let reason = holes_agree(&wrong, &holes_board, &identity, 0.0).unwrap_err();
        let Rejection::HolesDisagree { chi2, dof, limit, worst_m } = reason else {
            panic!("{reason:?}")
        };
        // Two boards of four holes, 3 rows each, less the extrinsic's 6.
        assert_eq!(dof, 18);
        assert!(chi2 > limit, "χ² {chi2} within {limit}");
        assert!((worst_m - 5.0 * sigma).abs() < 1e-9, "{worst_m}");
    }
}
