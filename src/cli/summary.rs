//! What `roomcal calibrate` prints: the status line (all `--quiet` prints), and the
//! summary a person reads — intrinsics with σ, the LiDAR's pose as roll/pitch/yaw and
//! position in the camera's body frame with σ and its change from the room's nominal
//! mounting, the residuals, and one line per board.

use roomcal::calibrate::{Calibration, FrameDetections};
use roomcal::geometry::body::BodyPose;
use roomcal::geometry::se3::rotation_to_rpy;
use roomcal::geometry::{CameraModel, Se3};
use roomcal::result::{CalibrationResult, Extrinsic, Status};
use roomcal::target::Room;

/// The one line saying how the run ended.
pub fn status_line(result: &CalibrationResult) -> String {
    let q = &result.quality;
    match result.status {
        Status::Accepted => {
            let lidar = result.boards.iter().filter(|b| !b.holes_lidar.is_empty()).count();
            let (with_lidar, holes) = match result.lidar_to_camera {
                Some(_) => (
                    format!(", {lidar} with LiDAR holes"),
                    format!(", holes {:.3} px RMS", q.hole_rms_px),
                ),
                None => (String::new(), String::new()),
            };
            format!(
                "roomcal calibrate: accepted ({} boards used{with_lidar}; corners {:.3} px RMS{holes})",
                q.boards, q.corner_rms_px
            )
        }
        Status::Rejected => format!(
            "roomcal calibrate: rejected: {}",
            result.reason.as_deref().unwrap_or("no reason given")
        ),
    }
}

/// The calibration in one line, as people read it everywhere: the camera's intrinsics and
/// the LiDAR's pose in the camera's body frame (x forward, y left, z up; roll, pitch, yaw
/// as [`lines`] gives them), with their largest-axis σ.
pub fn calibration_line(result: &CalibrationResult) -> String {
    let (c, u) = (&result.camera, &result.uncertainty);
    let camera = format!(
        "{} {}×{}: fx {:.2} fy {:.2} cx {:.2} cy {:.2} px",
        c.model.name(),
        c.width,
        c.height,
        c.fx,
        c.fy,
        c.cx,
        c.cy
    );
    let Some(e) = &result.lidar_to_camera else { return format!("camera {camera}") };
    format!(
        "camera {camera}; LiDAR {} in the camera's body frame (σ {:.3}°, {:.1} mm)",
        BodyPose::of(&e.to_se3(), false),
        u.rotation_deg,
        u.translation_m * 1e3
    )
}

/// The summary's lines, status line first.
pub fn lines(
    room: &Room,
    frames: &[FrameDetections],
    run: &Calibration,
    refused: usize,
    written: &[String],
) -> Vec<String> {
    let r = &run.result;
    let seen: usize = frames.iter().map(|f| f.camera.len()).sum();
    let placed: usize = frames.iter().map(|f| f.lidar.len()).sum();
    let mut out = vec![status_line(r)];
    let lidar = match room.lidar.is_some() && placed + refused > 0 {
        true => format!(", {placed} placed by the LiDAR, {refused} LiDAR plane(s) refused"),
        false => String::new(),
    };
    out.push(format!(
        "  input       {} frame(s): {seen} complete boards in the image(s){lidar}",
        frames.len()
    ));
    if never_solved(run) {
        // Its result carries the room's nominal camera and an identity extrinsic (the
        // result file's fields are not optional); printed, they would read as a LiDAR
        // found 120° and half a metre off its mounting.
        out.push(
            "  solved      nothing: the run stopped before the solve (the result file's camera is \
             the room's nominal one and its extrinsic a placeholder, not measurements)"
                .to_string(),
        );
    } else {
        out.extend(solution_lines(room, run));
    }
    out.extend(board_lines(room, frames, run));
    for path in written {
        out.push(format!("  written     {path}"));
    }
    out
}

/// The solved camera, distortion, LiDAR pose and residuals.
fn solution_lines(room: &Room, run: &Calibration) -> Vec<String> {
    let r = &run.result;
    let (c, u) = (&r.camera, &r.uncertainty);
    let mut out = Vec::new();
    out.push(format!(
        "  camera      {} {}×{}: fx {:.3} fy {:.3} px (σ {:.3} {:.3}), cx {:.3} cy {:.3} px (σ {:.3} {:.3})",
        c.model.name(),
        c.width,
        c.height,
        c.fx,
        c.fy,
        u.fx,
        u.fy,
        c.cx,
        c.cy,
        u.cx,
        u.cy
    ));
    out.push(format!("  distortion  {}", distortion(c.model, &c.distortion)));
    if let (Some(e), Some(spec)) = (&r.lidar_to_camera, &room.lidar) {
        let nominal = Extrinsic::from_se3(&Se3 {
            rotation: spec.rotation_matrix(),
            translation: spec.translation_vector(),
        });
        out.extend(extrinsic_lines(e, &nominal, u.rotation_deg, u.translation_m));
    }
    // A LiDAR placed by faces (and a surveyed room's planes) alone has no hole residual.
    let holes = match (room.lidar.is_some(), run.boards.iter().any(|b| !b.holes_lidar.is_empty())) {
        (false, _) => String::new(),
        (true, true) => format!(", holes {:.3} px RMS", r.quality.hole_rms_px),
        (true, false) => ", no hole placed".to_string(),
    };
    out.push(format!(
        "  residuals   corners {:.3} px RMS{holes}, {} boards used, {} solver iterations",
        r.quality.corner_rms_px, r.quality.boards, run.iterations
    ));
    out
}

/// A run rejected before its solve (nothing to pair, too few boards): no board used, no
/// iteration made.
fn never_solved(run: &Calibration) -> bool {
    run.boards.is_empty() && run.iterations == 0
}

/// The LiDAR's pose in the camera's body frame and its change from the nominal mounting.
fn extrinsic_lines(
    e: &Extrinsic,
    nominal: &Extrinsic,
    sigma_deg: f64,
    sigma_m: f64,
) -> Vec<String> {
    let BodyPose { rpy_deg: [roll, pitch, yaw], position_m: t } = BodyPose::of(&e.to_se3(), false);
    let expected = BodyPose::of(&nominal.to_se3(), false);
    // The turn about the LiDAR's own axes, nominal → solved (the optical → body turn
    // cancels in it).
    let (solved, mounted) = (e.to_se3().rotation, nominal.to_se3().rotation);
    let turn = rotation_to_rpy(&(mounted.transpose() * solved)).map(f64::to_degrees);
    let shift = (t - expected.position_m) * 1e3;
    let (angle, distance) = nominal.difference(e);
    vec![
        "  LiDAR       pose in the camera's body frame (x forward, y left, z up), \
         R = Rz(yaw)·Ry(pitch)·Rx(roll):"
            .to_string(),
        format!(
            "    rotation    roll {roll:.3}° pitch {pitch:.3}° yaw {yaw:.3}° (σ {sigma_deg:.3}°, largest axis)"
        ),
        format!(
            "    position    x {:.4} y {:.4} z {:.4} m (σ {:.1} mm, largest axis)",
            t.x,
            t.y,
            t.z,
            sigma_m * 1e3
        ),
        format!(
            "    vs nominal  turned roll {:+.3}° pitch {:+.3}° yaw {:+.3}° (about the LiDAR's axes), \
             moved x {:+.1} y {:+.1} z {:+.1} mm: {angle:.3}° and {:.1} mm from the room's mounting",
            turn[0],
            turn[1],
            turn[2],
            shift.x,
            shift.y,
            shift.z,
            distance * 1e3
        ),
    ]
}

/// One line per board used, then the LiDAR boards no image board took.
fn board_lines(room: &Room, frames: &[FrameDetections], run: &Calibration) -> Vec<String> {
    let mut out = Vec::new();
    let with_lidar = run.lidar_to_camera.is_some();
    for (k, board) in run.boards.iter().enumerate() {
        let (corner_rms, hole_rms) = run.board_rms(&room.board, board);
        let lidar = match (with_lidar, hole_rms) {
            (false, _) => String::new(),
            (true, Some(rms)) => {
                format!("; LiDAR: {} hole centres, {rms:.3} px RMS", board.holes_lidar.len())
            }
            (true, None) if board.lidar_face => match run.result.camera_in_room {
                Some(_) => "; LiDAR: its face where the survey puts it (no hole placed)",
                None => "; LiDAR: its face, the LiDAR placed by the faces alone (no hole placed)",
            }
            .to_string(),
            (true, None) => "; LiDAR: not found or not paired".to_string(),
        };
        out.push(format!(
            "  board {k:<5} frame {}: image: {} corners, {corner_rms:.3} px RMS{lidar}",
            board.frame,
            board.corners.len()
        ));
    }
    for (f, frame) in frames.iter().enumerate() {
        let paired = run
            .boards
            .iter()
            .filter(|b| b.frame as usize == f && !b.holes_lidar.is_empty())
            .count();
        let unpaired = frame.lidar.len().saturating_sub(paired);
        if with_lidar && unpaired > 0 {
            out.push(format!(
                "  frame {f}     {unpaired} board(s) placed by the LiDAR matched no board in the image \
                 (outside the picture, or the nominal mounting is far off)"
            ));
        }
    }
    if run.boards.is_empty() {
        out.push("  boards      none used: see the status line".to_string());
    }
    out
}

/// The coefficients with their names (OpenCV's order).
fn distortion(model: CameraModel, values: &[f64]) -> String {
    let names: &[&str] = match model {
        CameraModel::PinholeRadtan => &["k1", "k2", "p1", "p2", "k3"],
        CameraModel::Fisheye => &["k1", "k2", "k3", "k4"],
    };
    names.iter().zip(values).map(|(n, v)| format!("{n} {v:.6}")).collect::<Vec<_>>().join(", ")
}
