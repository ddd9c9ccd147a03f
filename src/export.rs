//! Exports for other stacks (DESIGN.md "Exports for other stacks"): the calibration as the
//! files ROS, Autoware and KITTI-style pipelines read, written by `roomcal calibrate
//! --export DIR` and by the store beside `current.json`.
//!
//! - `camera.camera_info.yaml`: ROS `camera_info` as camera_calibration_parsers writes it
//!   (`plumb_bob` = k1 k2 p1 p2 k3, `equidistant` = Kannala-Brandt k1..k4); no
//!   rectification (identity R), `P = [K | 0]` from the calibrated K.
//! - `sensor_kit_calibration.yaml`: Autoware's shape, parent `sensor_kit_base_link` taken
//!   to be the LiDAR frame (roomcal measures the camera against the LiDAR, not against the
//!   vehicle); the camera entry is its `camera_link` (x forward, y left, z up), not the
//!   optical frame the result file uses (see [`OPTICAL_FROM_LINK`]).
//! - `calib.txt`: KITTI, `P0:` (3×4) and `Tr_velo_to_cam:` (3×4, LiDAR → optical camera
//!   frame), row-major.
//!
//! Numbers are written with Rust's shortest round-trip formatting, so a reader gets back
//! exactly the `f64` of the result file.

use std::path::{Path, PathBuf};

use crate::geometry::se3::{rotation_to_rpy, Se3};
use crate::geometry::{CameraModel, Mat3};
use crate::result::{CalibrationResult, CameraResult, Extrinsic, RigResult};

/// The camera's name in the exports for a one-camera room.
pub const CAMERA_NAME: &str = "camera";

/// The LiDAR's name in `sensor_kit_calibration.yaml` for a one-LiDAR room.
pub const LIDAR_NAME: &str = "lidar";

pub use crate::geometry::body::{optical_from_link, OPTICAL_FROM_LINK};

/// One export file: its name in the export directory and its text.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportFile {
    pub name: String,
    pub text: String,
}

/// Why the exports could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(
        "export {path}: cannot write it ({source}); check the directory exists and is writable"
    )]
    Io { path: PathBuf, source: std::io::Error },
    #[error("export {path}: {problem}")]
    NotADirectory { path: PathBuf, problem: NotADirectory },
}

/// Why a path that should be a directory (the store, an export directory) is not one and
/// cannot be made one.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum NotADirectory {
    /// A file (or a link to one) is in the way.
    #[error("is a file, not a directory")]
    File,
    /// A symbolic link to nothing: its target is not created, since a missing target is
    /// usually a partition that is not mounted, and writing beneath the mount point would
    /// hide the data from it.
    #[error(
        "is a symbolic link to {}, which does not exist (create it, mount it, or fix the link)",
        target.display()
    )]
    DanglingLink { target: PathBuf },
}

/// Why `path` can neither be used as a directory nor created as one; `None` when it is a
/// directory (or a link to one) or does not exist yet.
pub fn directory_problem(path: &Path) -> Option<NotADirectory> {
    let meta = std::fs::symlink_metadata(path).ok()?;
    if meta.is_symlink() {
        return match std::fs::metadata(path) {
            Ok(target) if target.is_dir() => None,
            Ok(_) => Some(NotADirectory::File),
            Err(_) => {
                let target = std::fs::read_link(path).unwrap_or_default();
                Some(NotADirectory::DanglingLink { target })
            }
        };
    }
    (!meta.is_dir()).then_some(NotADirectory::File)
}

/// Every export of a result: the camera_info always, the Autoware and KITTI files as far
/// as the result has a LiDAR (`calib.txt` then carries `P0:` alone).
pub fn files(result: &CalibrationResult) -> Vec<ExportFile> {
    let mut out = vec![ExportFile {
        name: format!("{CAMERA_NAME}.camera_info.yaml"),
        text: camera_info_yaml(&result.camera, CAMERA_NAME),
    }];
    if let Some(e) = &result.lidar_to_camera {
        out.push(ExportFile {
            name: "sensor_kit_calibration.yaml".into(),
            text: sensor_kit_yaml(e, CAMERA_NAME, LIDAR_NAME),
        });
    }
    out.push(ExportFile { name: "calib.txt".into(), text: kitti_calib(result) });
    out
}

/// Writes `files` ([`files`] or [`rig_files`]) into `dir` through `write` (the store
/// passes its atomic writer), stopping at the first error.
pub fn write_each<E>(
    dir: &Path,
    files: &[ExportFile],
    mut write: impl FnMut(&Path, &[u8]) -> Result<(), E>,
) -> Result<(), E> {
    for file in files {
        write(&dir.join(&file.name), file.text.as_bytes())?;
    }
    Ok(())
}

/// Creates `dir` if needed and writes the exports there; returns the paths written.
pub fn write_dir(dir: &Path, files: &[ExportFile]) -> Result<Vec<PathBuf>, ExportError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ExportError::Io { path, source }
    };
    if let Some(problem) = directory_problem(dir) {
        return Err(ExportError::NotADirectory { path: dir.to_path_buf(), problem });
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut written = Vec::new();
    write_each(dir, files, |path, bytes| {
        written.push(path.to_path_buf());
        std::fs::write(path, bytes).map_err(io(path))
    })?;
    Ok(written)
}

/// The pose of the camera's `camera_link` in the LiDAR frame: `p_lidar = rotation ·
/// p_link + translation` (what `sensor_kit_calibration.yaml` holds for the camera).
pub fn camera_link_in_lidar(lidar_to_camera: &Extrinsic) -> Se3 {
    let camera_to_lidar = lidar_to_camera.to_se3().inverse();
    camera_to_lidar.compose(&Se3 { rotation: optical_from_link(), translation: Default::default() })
}

/// ROS `camera_info` YAML (camera_calibration_parsers' keys and layout).
pub fn camera_info_yaml(camera: &CameraResult, camera_name: &str) -> String {
    let c = camera;
    let model = match c.model {
        CameraModel::PinholeRadtan => "plumb_bob",
        CameraModel::Fisheye => "equidistant",
    };
    let k = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
    let rect = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    format!(
        "image_width: {}\nimage_height: {}\ncamera_name: {camera_name}\n{}distortion_model: {model}\n{}{}{}",
        c.width,
        c.height,
        ros_matrix("camera_matrix", 3, 3, &k),
        ros_matrix("distortion_coefficients", 1, c.distortion.len(), &c.distortion),
        ros_matrix("rectification_matrix", 3, 3, &rect),
        ros_matrix("projection_matrix", 3, 4, &projection(camera, &Se3::identity())),
    )
}

/// Autoware's `sensor_kit_calibration.yaml`: the LiDAR as the parent frame (identity) and
/// the camera's `camera_link` in it.
pub fn sensor_kit_yaml(lidar_to_camera: &Extrinsic, camera_name: &str, lidar_name: &str) -> String {
    sensor_kit_text(
        lidar_name,
        &[
            (lidar_name.to_string(), Se3::identity()),
            (format!("{camera_name}/camera_link"), camera_link_in_lidar(lidar_to_camera)),
        ],
    )
}

/// `sensor_kit_calibration.yaml` with `entries` (child frame name, pose in the parent) under
/// `sensor_kit_base_link`, which is `parent`'s frame.
fn sensor_kit_text(parent: &str, entries: &[(String, Se3)]) -> String {
    let mut text = format!(
        "# roomcal: the sensors' extrinsics in Autoware's sensor_kit_calibration.yaml shape.\n\
         # Each entry is the pose of a child frame in the parent: p_parent = R * p_child + [x, y, z],\n\
         # R = Rz(yaw) * Ry(pitch) * Rx(roll) (URDF fixed-axis roll-pitch-yaw); metres and radians.\n\
         # The parent sensor_kit_base_link is {parent}'s own frame: roomcal measures the sensors\n\
         # against each other, not against the vehicle.\n\
         # NAME/camera_link is a camera's BODY frame (x forward, y left, z up), NOT the optical\n\
         # frame (x right, y down, z forward) of camera_info, calib.txt and result.json:\n\
         # p_optical = [[0,-1,0],[0,0,-1],[1,0,0]] * p_link, i.e. camera_link -> camera_optical_link\n\
         # is rpy(-pi/2, 0, -pi/2) as in Autoware's sensor kit descriptions.\n\
         sensor_kit_base_link:\n"
    );
    for (name, pose) in entries {
        text += &autoware_entry(name, pose);
    }
    text
}

/// Every export of a rig's result: `NAME.camera_info.yaml` per camera;
/// `sensor_kit_calibration.yaml` with every sensor, its parent the first LiDAR's frame
/// (the first camera's `camera_link` for a rig without LiDARs); `calib.txt` with `Pi:`
/// for the i-th camera (`K_i [R | t]` from the first camera's frame, KITTI's convention:
/// `P0` is the first camera's `[K | 0]`) and `Tr_velo_to_cam:` for the first LiDAR.
/// Sensors without an extrinsic (a rejected rig's) are left out.
pub fn rig_files(result: &RigResult) -> Vec<ExportFile> {
    let sensors = result.in_order();
    let mut out: Vec<ExportFile> = sensors
        .iter()
        .filter_map(|s| {
            Some(ExportFile {
                name: format!("{}.camera_info.yaml", s.name),
                text: camera_info_yaml(s.camera?, s.name),
            })
        })
        .collect();
    let link = Se3 { rotation: optical_from_link(), translation: Default::default() };
    let first_lidar = sensors.iter().find(|s| s.camera.is_none());
    let (parent, parent_to_first) = match first_lidar {
        Some(l) => (l.name.to_string(), l.to_first),
        None => (format!("{}/camera_link", sensors.first().map_or("camera", |s| s.name)), link),
    };
    let first_to_parent = parent_to_first.inverse();
    let entries: Vec<(String, Se3)> = sensors
        .iter()
        .map(|s| match s.camera {
            Some(_) => (
                format!("{}/camera_link", s.name),
                first_to_parent.compose(&s.to_first).compose(&link),
            ),
            None => (s.name.to_string(), first_to_parent.compose(&s.to_first)),
        })
        .collect();
    out.push(ExportFile {
        name: "sensor_kit_calibration.yaml".into(),
        text: sensor_kit_text(&parent, &entries),
    });
    let mut kitti = String::new();
    for (i, s) in sensors.iter().filter(|s| s.camera.is_some()).enumerate() {
        let camera = s.camera.expect("filtered: a camera");
        kitti += &format!("P{i}: {}\n", numbers(&projection(camera, &s.to_first.inverse())));
    }
    if let Some(l) = first_lidar {
        kitti += &format!("Tr_velo_to_cam: {}\n", numbers(&row_major(&l.to_first)));
    }
    out.push(ExportFile { name: "calib.txt".into(), text: kitti });
    out
}

/// KITTI `calib.txt`: `P0:` = `[K | 0]`, `Tr_velo_to_cam:` = `[R | t]` (LiDAR → optical
/// camera frame), both row-major.
pub fn kitti_calib(result: &CalibrationResult) -> String {
    let mut text = format!("P0: {}\n", numbers(&projection(&result.camera, &Se3::identity())));
    if let Some(e) = &result.lidar_to_camera {
        text += &format!("Tr_velo_to_cam: {}\n", numbers(&row_major(&e.to_se3())));
    }
    text
}

/// `[R | t]`, row-major.
fn row_major(motion: &Se3) -> [f64; 12] {
    let (r, t) = (&motion.rotation, &motion.translation);
    [
        r[(0, 0)],
        r[(0, 1)],
        r[(0, 2)],
        t.x,
        r[(1, 0)],
        r[(1, 1)],
        r[(1, 2)],
        t.y,
        r[(2, 0)],
        r[(2, 1)],
        r[(2, 2)],
        t.z,
    ]
}

/// `K · [R | t]`, row-major: the projection of a point given in another frame (the
/// first camera's, through `to_camera` = that frame → this camera) into the calibrated
/// (distorted) camera; `[K | 0]` for the identity.
fn projection(camera: &CameraResult, to_camera: &Se3) -> [f64; 12] {
    let c = camera;
    let k = Mat3::new(c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0);
    row_major(&Se3 { rotation: k * to_camera.rotation, translation: k * to_camera.translation })
}

fn ros_matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    let values: Vec<String> = data.iter().map(|v| number(*v)).collect();
    format!("{name}:\n  rows: {rows}\n  cols: {cols}\n  data: [{}]\n", values.join(", "))
}

fn autoware_entry(name: &str, pose: &Se3) -> String {
    let [roll, pitch, yaw] = rotation_to_rpy(&pose.rotation);
    let t = &pose.translation;
    let mut text = format!("  {name}:\n");
    for (key, value) in
        [("x", t.x), ("y", t.y), ("z", t.z), ("roll", roll), ("pitch", pitch), ("yaw", yaw)]
    {
        text += &format!("    {key}: {}\n", number(value));
    }
    text
}

fn numbers(values: &[f64]) -> String {
    values.iter().map(|v| number(*v)).collect::<Vec<_>>().join(" ")
}

/// A float every YAML reader takes as one: shortest round-trip digits, always with a
/// decimal point (YAML 1.1 readers such as PyYAML read `1` as an integer and `1e-5` as a
/// string; Rust's `Display` never writes an exponent).
fn number(v: f64) -> String {
    if v.is_nan() {
        return ".nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { ".inf".into() } else { "-.inf".into() };
    }
    // Adding zero turns −0 into 0 (an identity's pitch reads `0.0`, not `-0.0`).
    let text = format!("{}", v + 0.0);
    if text.contains('.') {
        text
    } else {
        text + ".0"
    }
}

/// The camera as an OpenCV FileStorage YAML (`cv::FileStorage` / `cv2.FileStorage` read it):
/// image size, `camera_model`, `camera_matrix`, `distortion_coefficients`. The one writer of
/// this form: the result file's YAML, the store's `camera.yaml`, a rig's `camera-NAME.yaml`.
pub fn camera_yaml(camera: &CameraResult) -> String {
    let c = camera;
    let model = c.model.name();
    let k = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
    format!(
        "%YAML:1.0\n---\nimage_width: {}\nimage_height: {}\ncamera_model: \"{model}\"\n{}{}",
        c.width,
        c.height,
        opencv_matrix("camera_matrix", 3, 3, &k, ""),
        opencv_matrix("distortion_coefficients", 1, c.distortion.len(), &c.distortion, ""),
    )
}

/// The camera and its LiDAR → camera transform (as `lidar_to_camera`, 4×4) in one OpenCV
/// FileStorage YAML: what `roomcal calibrate` writes beside the result file.
pub fn result_yaml(result: &CalibrationResult) -> String {
    let mut yaml = camera_yaml(&result.camera);
    if let Some(e) = &result.lidar_to_camera {
        yaml +=
            &opencv_matrix("lidar_to_camera", 4, 4, &homogeneous(&e.rotation, &e.translation), "");
    }
    yaml
}

/// The LiDAR → camera transform as OpenCV FileStorage YAML (the 4×4 matrix, and its rotation
/// and translation apart); `None` without one.
pub fn extrinsic_yaml(result: &CalibrationResult) -> Option<String> {
    let e = result.lidar_to_camera.as_ref()?;
    let rotation: Vec<f64> = e.rotation.iter().flatten().copied().collect();
    Some(format!(
        "%YAML:1.0\n---\n# p_camera = R * p_lidar + t\n{}{}{}",
        opencv_matrix("lidar_to_camera", 4, 4, &homogeneous(&e.rotation, &e.translation), ""),
        opencv_matrix("rotation", 3, 3, &rotation, ""),
        opencv_matrix("translation", 3, 1, &e.translation, ""),
    ))
}

/// A rig's extrinsics as OpenCV FileStorage YAML: `first_camera` and a sequence of maps
/// (`from`, `to`, the 4×4 `transform` with `p_to = R · p_from + t`, worst-axis σ).
pub fn rig_extrinsics_yaml(rig: &RigResult) -> String {
    let mut text = format!(
        "%YAML:1.0\n---\n# every sensor's pose on the vehicle: p_to = R * p_from + t (to = the first camera)\n\
         first_camera: \"{}\"\nextrinsics:\n",
        rig.first_camera().unwrap_or("")
    );
    for e in &rig.extrinsics {
        text += &format!(
            "   -\n      from: \"{}\"\n      to: \"{}\"\n{}      sigma_rotation_deg: {:e}\n      sigma_translation_m: {:e}\n",
            e.from,
            e.to,
            opencv_matrix("transform", 4, 4, &homogeneous(&e.rotation, &e.translation), "      "),
            e.sigma_rotation_deg,
            e.sigma_translation_m
        );
    }
    text
}

/// `[R t; 0 0 0 1]`, row-major.
fn homogeneous(r: &[[f64; 3]; 3], t: &[f64; 3]) -> [f64; 16] {
    [
        r[0][0], r[0][1], r[0][2], t[0], r[1][0], r[1][1], r[1][2], t[1], r[2][0], r[2][1],
        r[2][2], t[2], 0.0, 0.0, 0.0, 1.0,
    ]
}

/// One `!!opencv-matrix` entry (doubles, in `{:e}` so they read back exactly), `indent`ed.
fn opencv_matrix(name: &str, rows: usize, cols: usize, data: &[f64], indent: &str) -> String {
    let values: Vec<String> = data.iter().map(|v| format!("{v:e}")).collect();
    format!(
        "{indent}{name}: !!opencv-matrix\n{indent}   rows: {rows}\n{indent}   cols: {cols}\n\
         {indent}   dt: d\n{indent}   data: [ {} ]\n",
        values.join(", ")
    )
}
