//! The quality gate (`target::QualitySpec`): residuals, boards, coverage, σ, and the change
//! from the calibration in force.

use super::{CalibrateOptions, Calibration, FrameDetections, UsedBoard};
use crate::geometry::Camera;
use crate::result::{CalibrationResult, CameraResult, Extrinsic, Uncertainty};
use crate::target::{QualitySpec, Room};

/// The quality gate: `Err(reason)` names the first threshold the run fails.
pub(super) fn gate(
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
    corners_fit(q, r.quality.corner_rms_px)?;
    covers(q, coverage(&run.camera, &run.boards))?;
    intrinsics_certain(q, &r.camera, &r.uncertainty)?;
    if room.lidar.is_some() {
        // As the free-board solve refuses a run whose LiDAR pairs no board: accepted as
        // intrinsics only, it would put a calibration without the extrinsic in force.
        check(run.lidar_to_camera.is_some(), || {
            format!(
                "the LiDAR was not calibrated: no board or surveyed plane placed it (the room has a \
                 LiDAR; at least {} boards seen by both sensors needed)",
                q.min_lidar_boards
            )
        })?;
        // In a surveyed room the survey gives every target its pose: the LiDAR registers
        // against boards (by their holes or their face) and planes alike, as a rig's does.
        let lidar_boards = run.boards.iter().filter(|b| b.seen_by_lidar()).count();
        let (targets, seen) = match r.camera_in_room {
            Some(_) => {
                let n = lidar_boards + run.lidar_planes;
                (n, format!("the LiDAR registers against {n} surveyed boards and planes"))
            }
            None => (lidar_boards, format!("{lidar_boards} boards seen by both sensors")),
        };
        check(targets >= q.min_lidar_boards as usize, || {
            format!("{seen}, at least {} needed", q.min_lidar_boards)
        })?;
        holes_fit(q, r.quality.hole_rms_px)?;
        extrinsic_certain(q, &r.uncertainty)?;
    }
    if let (Some(in_room), Some(lidar)) = (&r.camera_in_room, &room.lidar) {
        check_parking(q, lidar, in_room)?;
    }
    if let Some(current) = &options.current {
        check_change(q, current, r)?;
    }
    Ok(())
}

/// The corners' RMS reprojection error within `max_corner_rms_px`.
pub(super) fn corners_fit(q: &QualitySpec, rms_px: f64) -> Result<(), String> {
    check(rms_px <= q.max_corner_rms_px, || {
        format!("corner RMS {rms_px:.3} px exceeds {} px", q.max_corner_rms_px)
    })
}

/// The used corners cover at least `min_coverage` of the image.
pub(super) fn covers(q: &QualitySpec, coverage: f64) -> Result<(), String> {
    check(coverage >= q.min_coverage, || {
        format!(
            "corners cover {:.0} % of the image, at least {:.0} % needed",
            coverage * 100.0,
            q.min_coverage * 100.0
        )
    })
}

/// The focal lengths' and the principal point's σ within their limits.
pub(super) fn intrinsics_certain(
    q: &QualitySpec,
    c: &CameraResult,
    u: &Uncertainty,
) -> Result<(), String> {
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
    })
}

/// The hole term's RMS within `max_hole_rms_px`.
pub(super) fn holes_fit(q: &QualitySpec, rms_px: f64) -> Result<(), String> {
    check(rms_px <= q.max_hole_rms_px, || {
        format!("hole RMS {rms_px:.3} px exceeds {} px", q.max_hole_rms_px)
    })
}

/// The LiDAR→camera σ (`u.rotation_deg`, `u.translation_m`) within their limits.
pub(super) fn extrinsic_certain(q: &QualitySpec, u: &Uncertainty) -> Result<(), String> {
    check(
        u.rotation_deg <= q.max_sigma_rotation_deg && u.translation_m <= q.max_sigma_translation_m,
        || {
            format!(
                "extrinsic uncertain: σ {:.3}° / {:.1} mm (limits {}° / {} mm)",
                u.rotation_deg,
                u.translation_m * 1000.0,
                q.max_sigma_rotation_deg,
                q.max_sigma_translation_m * 1000.0
            )
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
) -> Result<(), String> {
    let nominal = super::association::lidar_nominal(lidar).inverse();
    let (angle, shift) = crate::result::Extrinsic::from_se3(&nominal).difference(camera_in_room);
    check(shift <= q.max_parking_offset_m && angle <= q.max_parking_yaw_deg, || {
        format!(
            "parked {:.0} mm / {angle:.1}° from the nominal spot (limits {:.0} mm / {}°)",
            shift * 1000.0,
            q.max_parking_offset_m * 1000.0,
            q.max_parking_yaw_deg
        )
    })
}

/// The change limits against the calibration in force.
fn check_change(
    q: &QualitySpec,
    current: &CalibrationResult,
    new: &CalibrationResult,
) -> Result<(), String> {
    intrinsics_within_change(q, &current.camera, &new.camera)?;
    if let (Some(x), Some(y)) = (&current.lidar_to_camera, &new.lidar_to_camera) {
        extrinsic_within_change(q, "extrinsic", x, y)?;
    }
    Ok(())
}

/// The focal lengths and the principal point within the change limits from `a` (in force).
pub(super) fn intrinsics_within_change(
    q: &QualitySpec,
    a: &CameraResult,
    b: &CameraResult,
) -> Result<(), String> {
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
    })
}

/// A mounting (`what`: "extrinsic", "mounting") within the change limits from `x` (in force).
pub(super) fn extrinsic_within_change(
    q: &QualitySpec,
    what: &str,
    x: &Extrinsic,
    y: &Extrinsic,
) -> Result<(), String> {
    let (angle, shift) = x.difference(y);
    check(angle <= q.max_change_rotation_deg && shift <= q.max_change_translation_m, || {
        format!(
            "{what} moved {angle:.2}° / {:.0} mm from the current calibration (limits {}° / {} mm)",
            shift * 1000.0,
            q.max_change_rotation_deg,
            q.max_change_translation_m * 1000.0
        )
    })
}

pub(super) fn check(ok: bool, reason: impl FnOnce() -> String) -> Result<(), String> {
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
