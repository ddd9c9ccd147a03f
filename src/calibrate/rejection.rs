//! Why the quality gate refused a solved run: one variant per check, its figures typed.
//! Display is the text the result file's `reason` and the operator see.

use core::fmt;

use super::gate::OFF_SURVEY_M;

/// A threshold of the room's `[quality]` (`target::QualitySpec`) that a solved run fails.
#[derive(Clone, Debug, PartialEq)]
pub enum Rejection {
    /// A frame's camera saw fewer complete boards than the room needs.
    TooFewBoards { frame: usize, complete: usize, needed: usize, detected: usize },
    /// The corners' RMS reprojection error over `max_corner_rms_px`.
    CornerRms { rms_px: f64, limit_px: f64 },
    /// The used corners cover less of the image than `min_coverage` (fractions).
    Coverage { coverage: f64, min: f64 },
    /// A focal length's σ over `max_sigma_focal_rel` of it.
    FocalUncertain { fx_px: f64, fy_px: f64, limit_rel: f64 },
    /// The principal point's σ over `max_sigma_principal_px`.
    PrincipalUncertain { cx_px: f64, cy_px: f64, limit_px: f64 },
    /// A projection over the room's `region` more uncertain than `max_projection_sigma_px`:
    /// the worst grid pixel `at_px`, its point held `range_m` along the ray.
    ProjectionUncertain {
        sigma_px: f64,
        at_px: [f64; 2],
        range_m: f64,
        limit_px: f64,
        region: [f64; 4],
    },
    /// The room has a LiDAR and nothing placed it.
    LidarUncalibrated { needed: u32 },
    /// No board placed by its holes, and the LiDAR's angle table is the model's nominal one.
    NominalAngles,
    /// Fewer LiDAR targets than `min_lidar_boards`: surveyed boards and planes (`surveyed`),
    /// else boards seen by both sensors.
    TooFewLidarTargets { count: usize, surveyed: bool, needed: u32 },
    /// The hole term's RMS over `max_hole_rms_px`.
    HoleRms { rms_px: f64, limit_px: f64 },
    /// The LiDAR's holes and the camera's boards fail the χ² test in 3D.
    HolesDisagree { chi2: f64, dof: usize, limit: f64, worst_m: f64 },
    /// Boards the LiDAR placed by their holes lie off every surveyed board.
    OffSurvey { count: usize, worst_m: f64 },
    /// The LiDAR → camera σ over its limits.
    ExtrinsicUncertain { rotation_deg: f64, translation_m: f64, limit_deg: f64, limit_m: f64 },
    /// The camera's pose in the room outside the parking box.
    Parked { shift_m: f64, angle_deg: f64, limit_m: f64, limit_deg: f64 },
    /// The focal length moved beyond `max_change_focal_rel` from the calibration in force.
    FocalMoved { change_rel: f64, limit_rel: f64 },
    /// The principal point moved beyond `max_change_principal_px`.
    PrincipalMoved { shift_px: f64, limit_px: f64 },
    /// A pose moved beyond the change limits from the calibration in force.
    PoseMoved { pose: MovedPose, angle_deg: f64, shift_m: f64, limit_deg: f64, limit_m: f64 },
}

/// Which pose a change limit was applied to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MovedPose {
    /// A one-pair run's LiDAR → camera.
    Extrinsic,
    /// A rig sensor's pose relative to the first camera.
    Mounting,
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rejection::TooFewBoards { frame, complete, needed, detected } => write!(
                f,
                "frame {frame}: {complete} complete boards seen by the camera, the room needs {needed} ({detected} detected in all)"
            ),
            Rejection::CornerRms { rms_px, limit_px } => {
                write!(f, "corner RMS {rms_px:.3} px exceeds {limit_px} px")
            }
            Rejection::Coverage { coverage, min } => write!(
                f,
                "corners cover {:.0} % of the image, at least {:.0} % needed",
                coverage * 100.0,
                min * 100.0
            ),
            Rejection::FocalUncertain { fx_px, fy_px, limit_rel } => write!(
                f,
                "focal length uncertain: σ fx {fx_px:.2} px, fy {fy_px:.2} px (limit {} %)",
                limit_rel * 100.0
            ),
            Rejection::PrincipalUncertain { cx_px, cy_px, limit_px } => write!(
                f,
                "principal point uncertain: σ cx {cx_px:.2} px, cy {cy_px:.2} px (limit {limit_px} px)"
            ),
            Rejection::ProjectionUncertain { sigma_px, at_px, range_m, limit_px, region } => {
                let over = match region {
                    [0.0, 0.0, 1.0, 1.0] => "the image".to_string(),
                    [u0, v0, u1, v1] => format!("the room's region [{u0}, {v0}, {u1}, {v1}]"),
                };
                write!(
                    f,
                    "a projection is uncertain by {sigma_px:.2} px (1σ, a point {range_m} m away) at pixel ({:.0}, {:.0}), at most {limit_px} px allowed over {over}: add boards that cover that part of the image, or narrow `[quality] region` to the part the camera is used in",
                    at_px[0], at_px[1]
                )
            }
            Rejection::LidarUncalibrated { needed } => write!(
                f,
                "the LiDAR was not calibrated: no board or surveyed plane placed it (the room has a \
                 LiDAR; at least {needed} boards seen by both sensors needed)"
            ),
            Rejection::NominalAngles => f.write_str(
                "no board placed by its holes, and the LiDAR's packets were decoded with the model's \
                 nominal angle table, which nothing in the run checks: is the unit's angle file given \
                 (`--lidar-calibration`, or `calibration` in the daemon's [lidar])?",
            ),
            Rejection::TooFewLidarTargets { count, surveyed: true, needed } => write!(
                f,
                "the LiDAR registers against {count} surveyed boards and planes, at least {needed} needed"
            ),
            Rejection::TooFewLidarTargets { count, surveyed: false, needed } => {
                write!(f, "{count} boards seen by both sensors, at least {needed} needed")
            }
            Rejection::HoleRms { rms_px, limit_px } => {
                write!(f, "hole RMS {rms_px:.3} px exceeds {limit_px} px")
            }
            Rejection::HolesDisagree { chi2, dof, limit, worst_m } => write!(
                f,
                "the LiDAR's holes and the camera's boards disagree: χ² {chi2:.0} over {dof} degrees of freedom (limit {limit:.0}), holes up to {:.0} mm apart in 3D; check the room file's board (square, holes) against the boards, and the LiDAR's angle file",
                worst_m * 1e3
            ),
            Rejection::OffSurvey { count, worst_m } => write!(
                f,
                "{count} board(s) the LiDAR placed by their holes lie up to {worst_m:.2} m from every surveyed board under the solved mounting (limit {OFF_SURVEY_M} m): the LiDAR and the run disagree; is the room's nominal LiDAR mounting right?"
            ),
            Rejection::ExtrinsicUncertain { rotation_deg, translation_m, limit_deg, limit_m } => {
                write!(
                    f,
                    "extrinsic uncertain: σ {rotation_deg:.3}° / {:.1} mm (limits {limit_deg}° / {} mm)",
                    translation_m * 1000.0,
                    limit_m * 1000.0
                )
            }
            Rejection::Parked { shift_m, angle_deg, limit_m, limit_deg } => write!(
                f,
                "parked {:.0} mm / {angle_deg:.1}° from the nominal spot (limits {:.0} mm / {limit_deg}°)",
                shift_m * 1000.0,
                limit_m * 1000.0
            ),
            Rejection::FocalMoved { change_rel, limit_rel } => write!(
                f,
                "focal length moved {:.2} % from the current calibration (limit {} %)",
                change_rel * 100.0,
                limit_rel * 100.0
            ),
            Rejection::PrincipalMoved { shift_px, limit_px } => write!(
                f,
                "principal point moved {shift_px:.1} px from the current calibration (limit {limit_px} px)"
            ),
            Rejection::PoseMoved { pose, angle_deg, shift_m, limit_deg, limit_m } => write!(
                f,
                "{pose} moved {angle_deg:.2}° / {:.0} mm from the current calibration (limits {limit_deg}° / {} mm)",
                shift_m * 1000.0,
                limit_m * 1000.0
            ),
        }
    }
}

impl fmt::Display for MovedPose {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            MovedPose::Extrinsic => "extrinsic",
            MovedPose::Mounting => "mounting",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texts the gate's checks gave as format strings, figures rounded as they were.
    #[test]
    fn display_is_the_operators_text() {
        let cases = [
            (
                Rejection::TooFewBoards { frame: 1, complete: 3, needed: 6, detected: 4 },
                "frame 1: 3 complete boards seen by the camera, the room needs 6 (4 detected in all)",
            ),
            (
                Rejection::CornerRms { rms_px: 0.61234, limit_px: 0.5 },
                "corner RMS 0.612 px exceeds 0.5 px",
            ),
            (
                Rejection::Coverage { coverage: 0.3125, min: 0.4 },
                "corners cover 31 % of the image, at least 40 % needed",
            ),
            (
                Rejection::ProjectionUncertain {
                    sigma_px: 8.4249,
                    at_px: [1919.0, 0.0],
                    range_m: 10.0,
                    limit_px: 3.0,
                    region: [0.0, 0.0, 1.0, 1.0],
                },
                "a projection is uncertain by 8.42 px (1σ, a point 10 m away) at pixel (1919, 0), at most 3 px allowed over the image: add boards that cover that part of the image, or narrow `[quality] region` to the part the camera is used in",
            ),
            (
                Rejection::ProjectionUncertain {
                    sigma_px: 4.41,
                    at_px: [119.9375, 599.5],
                    range_m: 5.0,
                    limit_px: 2.5,
                    region: [0.05, 0.0, 0.95, 1.0],
                },
                "a projection is uncertain by 4.41 px (1σ, a point 5 m away) at pixel (120, 600), at most 2.5 px allowed over the room's region [0.05, 0, 0.95, 1]: add boards that cover that part of the image, or narrow `[quality] region` to the part the camera is used in",
            ),
            (
                Rejection::FocalUncertain { fx_px: 12.346, fy_px: 9.0, limit_rel: 0.01 },
                "focal length uncertain: σ fx 12.35 px, fy 9.00 px (limit 1 %)",
            ),
            (
                Rejection::NominalAngles,
                "no board placed by its holes, and the LiDAR's packets were decoded with the model's nominal angle table, which nothing in the run checks: is the unit's angle file given (`--lidar-calibration`, or `calibration` in the daemon's [lidar])?",
            ),
            (
                Rejection::TooFewLidarTargets { count: 1, surveyed: true, needed: 2 },
                "the LiDAR registers against 1 surveyed boards and planes, at least 2 needed",
            ),
            (
                Rejection::TooFewLidarTargets { count: 0, surveyed: false, needed: 2 },
                "0 boards seen by both sensors, at least 2 needed",
            ),
            (
                Rejection::HolesDisagree { chi2: 512.4, dof: 18, limit: 42.3, worst_m: 0.0251 },
                "the LiDAR's holes and the camera's boards disagree: χ² 512 over 18 degrees of freedom (limit 42), holes up to 25 mm apart in 3D; check the room file's board (square, holes) against the boards, and the LiDAR's angle file",
            ),
            (
                Rejection::OffSurvey { count: 2, worst_m: 0.4567 },
                "2 board(s) the LiDAR placed by their holes lie up to 0.46 m from every surveyed board under the solved mounting (limit 0.1 m): the LiDAR and the run disagree; is the room's nominal LiDAR mounting right?",
            ),
            (
                Rejection::ExtrinsicUncertain {
                    rotation_deg: 0.61234,
                    translation_m: 0.01234,
                    limit_deg: 0.5,
                    limit_m: 0.05,
                },
                "extrinsic uncertain: σ 0.612° / 12.3 mm (limits 0.5° / 50 mm)",
            ),
            (
                Rejection::Parked { shift_m: 0.7, angle_deg: 3.26, limit_m: 0.5, limit_deg: 10.0 },
                "parked 700 mm / 3.3° from the nominal spot (limits 500 mm / 10°)",
            ),
            (
                Rejection::PoseMoved {
                    pose: MovedPose::Mounting,
                    angle_deg: 2.5,
                    shift_m: 0.0123,
                    limit_deg: 2.0,
                    limit_m: 0.1,
                },
                "mounting moved 2.50° / 12 mm from the current calibration (limits 2° / 100 mm)",
            ),
        ];
        for (rejection, text) in cases {
            assert_eq!(rejection.to_string(), text);
        }
    }
}
