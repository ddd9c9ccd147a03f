//! The result file (JSON) and `roomcal detect`'s detections, exactly as DESIGN.md
//! specifies them.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::{Camera, CameraModel, Vec2};
use crate::target::{CameraSpec, RoomError};

/// Why a result file (or the store's `current.json`) read back cannot be used; names the file.
#[derive(Debug, thiserror::Error)]
pub enum ResultFileError {
    #[error("calibration {path}: cannot read: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("calibration {path}: not a calibration result: {message}")]
    Parse { path: PathBuf, message: String },
    /// A rig's result was asked for and the file holds a one-pair room's.
    #[error("calibration {path}: a one-pair room's result, not a rig's (it names no `sensors`)")]
    NotRig { path: PathBuf },
    /// A field outside the range a calibration can have (the room file's ranges).
    #[error("calibration {path}: {source}")]
    Invalid { path: PathBuf, source: RoomError },
}

/// Reads a result file (or the store's `current.json`) and validates the calibration in
/// it ([`CalibrationResult::validate`]): the one loader for calibrations read back.
pub fn load(path: &Path) -> Result<CalibrationResult, ResultFileError> {
    let result: CalibrationResult = parse(path)?;
    result
        .validate()
        .map_err(|source| ResultFileError::Invalid { path: path.to_owned(), source })?;
    Ok(result)
}

/// Reads a rig's result file (or a rig store's `current.json`): [`load`]'s checks on its
/// one-pair fields, and its sensors required.
pub fn load_rig(path: &Path) -> Result<RigResult, ResultFileError> {
    let result: RigResult = parse(path)?;
    if !result.is_rig() {
        return Err(ResultFileError::NotRig { path: path.to_owned() });
    }
    result
        .pair
        .validate()
        .map_err(|source| ResultFileError::Invalid { path: path.to_owned(), source })?;
    Ok(result)
}

fn parse<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, ResultFileError> {
    let text = read_json_text(path)
        .map_err(|source| ResultFileError::Read { path: path.to_owned(), source })?;
    serde_json::from_str(&text)
        .map_err(|e| ResultFileError::Parse { path: path.to_owned(), message: e.to_string() })
}

/// Most bytes of a result or detections file read back: a run's largest is a few hundred
/// KiB (32 frames of 16 boards of 35 corners, with the projection map).
pub const MAX_JSON_BYTES: u64 = 16 << 20;

/// Why a detections file cannot be read; names the file.
#[derive(Debug, thiserror::Error)]
pub enum DetectionsFileError {
    #[error("detections {path}: cannot read: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("detections {path}: not a detections file: {message}")]
    Parse { path: PathBuf, message: String },
}

/// Reads a detections file (`roomcal detect`'s form); whether it fits a room is
/// `calibrate::frames_from_detections`'s to say.
pub fn load_detections(path: &Path) -> Result<Detections, DetectionsFileError> {
    let text = read_json_text(path)
        .map_err(|source| DetectionsFileError::Read { path: path.to_owned(), source })?;
    serde_json::from_str(&text)
        .map_err(|e| DetectionsFileError::Parse { path: path.to_owned(), message: e.to_string() })
}

/// A JSON file's text, refused above [`MAX_JSON_BYTES`] before more is read (a device or
/// a pipe included).
fn read_json_text(path: &Path) -> std::io::Result<String> {
    use std::io::Read;
    let mut text = String::new();
    std::fs::File::open(path)?.take(MAX_JSON_BYTES + 1).read_to_string(&mut text)?;
    if text.len() as u64 > MAX_JSON_BYTES {
        let message = format!("larger than {} MiB", MAX_JSON_BYTES >> 20);
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidData, message));
    }
    Ok(text)
}

/// Whether the quality gate accepted the calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Accepted,
    Rejected,
}

/// The camera block of a result: model, size, intrinsics and distortion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraResult {
    pub model: CameraModel,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// 5 coefficients (pinhole-radtan) or 4 (fisheye).
    pub distortion: Vec<f64>,
}

/// LiDAR → camera: `p_camera = rotation · p_lidar + translation`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Extrinsic {
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
}

/// One-sigma uncertainties of the main parameters.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub rotation_deg: f64,
    pub translation_m: f64,
}

/// Residual figures of the solution.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    pub corner_rms_px: f64,
    pub hole_rms_px: f64,
    pub boards: u32,
}

/// One board's measurements: its camera corners and/or its LiDAR hole centres.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BoardDetection {
    /// Index of the image/cloud pair the board was seen in.
    pub frame: u32,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub corners_px: Vec<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub holes_lidar: Vec<[f64; 3]>,
    /// A corner's 1σ (px), as the detector judged it (`roomcal detect` writes it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corner_sigma_px: Option<f64>,
    /// A hole centre's 1σ (m), as the detector judged it (`roomcal detect` writes it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hole_sigma_m: Option<f64>,
    /// In a surveyed room (`roomcal detect`): which surveyed board (index into
    /// `[[survey.boards]]`) this detection is; absent when unidentified or not surveyed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surveyed_board: Option<u32>,
    /// The camera's corners (in the detector's order) are the surveyed board's turned by
    /// 180° about its normal (a symmetric board); written only when true.
    #[serde(default, skip_serializing_if = "is_false")]
    pub half_turned: bool,
}

fn is_false(value: &bool) -> bool {
    !*value
}

/// `roomcal detect`'s output.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Detections {
    pub boards: Vec<BoardDetection>,
}

/// `roomcal calibrate`'s output (and, with `generation` and `time`, the store's record).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationResult {
    pub status: Status,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    pub camera: CameraResult,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar_to_camera: Option<Extrinsic>,
    pub uncertainty: Uncertainty,
    pub quality: Quality,
    pub boards: Vec<BoardDetection>,
    /// Surveyed rooms: the camera's pose in the room frame (camera → room).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_in_room: Option<Extrinsic>,
    /// How far off a projection can be over the image (a solved run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub projection_uncertainty: Option<ProjectionMap>,
}

impl CameraResult {
    /// Checks the camera as the room file's `[camera]` is checked (the same keys:
    /// `camera.fx` …): size, focal lengths within the image's scale, principal point in
    /// the image, distortion of the model's length, finite and bounded.
    pub fn validate(&self) -> Result<(), RoomError> {
        let distortion = heapless::Vec::from_slice(&self.distortion)
            .map_err(|_| RoomError::DistortionLength { expected: 5, got: self.distortion.len() })?;
        CameraSpec {
            model: self.model,
            width: self.width,
            height: self.height,
            fx: Some(self.fx),
            fy: Some(self.fy),
            cx: Some(self.cx),
            cy: Some(self.cy),
            distortion: Some(distortion),
        }
        .validate()
    }

    /// The result block of a camera.
    pub fn from_camera(camera: &Camera) -> Self {
        let n = match camera.model {
            CameraModel::PinholeRadtan => 5,
            CameraModel::Fisheye => 4,
        };
        CameraResult {
            model: camera.model,
            width: camera.width,
            height: camera.height,
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            distortion: camera.distortion[..n].to_vec(),
        }
    }

    /// The camera this block describes (missing coefficients are zero).
    pub fn to_camera(&self) -> Camera {
        let mut distortion = [0.0; 5];
        for (d, v) in distortion.iter_mut().zip(&self.distortion) {
            *d = *v;
        }
        Camera {
            model: self.model,
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            distortion,
        }
    }
}

impl Extrinsic {
    /// The record of a rigid motion.
    pub fn from_se3(motion: &crate::geometry::Se3) -> Self {
        let r = &motion.rotation;
        Extrinsic {
            rotation: [
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ],
            translation: motion.translation.into(),
        }
    }

    /// The rigid motion this record describes.
    pub fn to_se3(&self) -> crate::geometry::Se3 {
        let r = &self.rotation;
        crate::geometry::Se3 {
            rotation: crate::geometry::Mat3::new(
                r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
            ),
            translation: self.translation.into(),
        }
    }

    /// How far `other` is from this motion: the angle of the rotation between them
    /// (degrees) and the distance between the translations (metres).
    pub fn difference(&self, other: &Extrinsic) -> (f64, f64) {
        let (a, b) = (self.to_se3(), other.to_se3());
        let angle = crate::geometry::se3::so3_log(&(b.rotation * a.rotation.transpose()))
            .norm()
            .to_degrees();
        (angle, (b.translation - a.translation).norm())
    }
}

impl CalibrationResult {
    /// Checks the calibration itself: the camera ([`CameraResult::validate`]) and the
    /// extrinsic, a rotation with a translation within the vehicle's size (the room
    /// file's `[lidar]` rules, keys `lidar_to_camera.rotation` / `.translation`).
    pub fn validate(&self) -> Result<(), RoomError> {
        self.camera.validate()?;
        if let Some(e) = &self.lidar_to_camera {
            crate::target::validate_mounting(
                "lidar_to_camera.rotation",
                &e.rotation,
                "lidar_to_camera.translation",
                &e.translation,
            )?;
        }
        if let Some(e) = &self.camera_in_room {
            crate::target::validate_mounting(
                "camera_in_room.rotation",
                &e.rotation,
                "camera_in_room.translation",
                &e.translation,
            )?;
        }
        Ok(())
    }
}

/// The projection uncertainty over a camera's image, as the result file carries it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProjectionMap {
    /// Range along each pixel's ray (m) at which the point is held.
    pub range_m: f64,
    /// Whether the LiDAR → camera extrinsic's uncertainty is included (a run with a
    /// LiDAR) or the intrinsics' alone.
    pub lidar: bool,
    /// Pixel columns (u) of the grid, left to right.
    pub columns: Vec<f64>,
    /// Pixel rows (v) of the grid, top to bottom.
    pub rows: Vec<f64>,
    /// `sigma_px[row][column]`: 1σ of the projection in its worst direction (px);
    /// `null` where the camera model does not invert.
    pub sigma_px: Vec<Vec<Option<f64>>>,
}

/// The worst grid value over a region of the image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Worst {
    pub sigma_px: f64,
    /// The grid pixel where it is.
    pub at_px: Vec2,
}

impl ProjectionMap {
    /// The largest value at the grid pixels inside `region` (fractions of the image's
    /// width and height: u0, v0, u1, v1, borders included); `None` when no grid pixel
    /// there has a value.
    pub fn worst_in(&self, region: [f64; 4]) -> Option<Worst> {
        let (w, h) = (self.columns.last().copied()?, self.rows.last().copied()?);
        let inside = |x: f64, lo: f64, hi: f64, extent: f64| {
            // Half a pixel of slack so a region's border on a grid pixel includes it.
            x >= lo * extent - 0.5 && x <= hi * extent + 0.5
        };
        let mut worst: Option<Worst> = None;
        for (r, &v) in self.rows.iter().enumerate() {
            for (c, &u) in self.columns.iter().enumerate() {
                let Some(sigma_px) = self.sigma_px[r][c] else { continue };
                if !inside(u, region[0], region[2], w) || !inside(v, region[1], region[3], h) {
                    continue;
                }
                if worst.is_none_or(|x| sigma_px > x.sigma_px) {
                    worst = Some(Worst { sigma_px, at_px: Vec2::new(u, v) });
                }
            }
        }
        worst
    }
}

/// A run's result file: the one-pair fields for the (first) camera and (first) LiDAR and,
/// for a rig (DESIGN.md "Vehicles with several sensors"), every sensor and every
/// extrinsic to the first camera. A one-pair room's run has neither, and its file is the
/// one-pair fields alone, as a [`CalibrationResult`] writes them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigResult {
    #[serde(flatten)]
    pub pair: CalibrationResult,
    /// Per sensor name (empty for a one-pair room).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub sensors: std::collections::BTreeMap<String, SensorResult>,
    /// One per sensor other than the first camera, `from` it `to` the first camera.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extrinsics: Vec<RigExtrinsic>,
}

impl From<CalibrationResult> for RigResult {
    /// A one-pair room's run: no sensors, no extrinsics beyond the pair's.
    fn from(pair: CalibrationResult) -> Self {
        RigResult { pair, sensors: Default::default(), extrinsics: Vec::new() }
    }
}

/// One sensor of a rig's result: a camera's intrinsics with their σ, or `"lidar": true`;
/// its own gate's verdict.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorResult {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraResult>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<Uncertainty>,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub lidar: bool,
    /// Surveyed rooms, cameras: camera → room.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_in_room: Option<Extrinsic>,
    pub status: Status,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The camera (for a LiDAR) or LiDAR (for a camera) whose pair solve gave this sensor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solved_with: Option<String>,
    /// Cameras: how far off a projection can be over the image (the joint solve's map, with
    /// the LiDAR of its pair run; the pair run's where the rig was composed from pairs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub projection_uncertainty: Option<ProjectionMap>,
}

/// One extrinsic of a rig: `p_to = rotation · p_from + translation`, with worst-axis 1σ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigExtrinsic {
    pub from: String,
    pub to: String,
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
    pub sigma_rotation_deg: f64,
    pub sigma_translation_m: f64,
}

impl RigExtrinsic {
    /// The rigid motion `from` → `to`.
    pub fn to_se3(&self) -> crate::geometry::Se3 {
        Extrinsic { rotation: self.rotation, translation: self.translation }.to_se3()
    }
}

/// One sensor of a rig result with its pose on the vehicle: [`RigResult::in_order`].
#[derive(Clone, Debug)]
pub struct RigSensor<'a> {
    pub name: &'a str,
    /// The intrinsics, for a camera; `None` for a LiDAR.
    pub camera: Option<&'a CameraResult>,
    /// This sensor → the first camera (the identity for the first camera).
    pub to_first: crate::geometry::Se3,
}

impl RigResult {
    /// Whether this is a rig's result (it names its sensors), not a one-pair room's.
    pub fn is_rig(&self) -> bool {
        !self.sensors.is_empty()
    }

    /// The first camera's name: every extrinsic's `to`, or the only camera of a rig
    /// without extrinsics.
    pub fn first_camera(&self) -> Option<&str> {
        match self.extrinsics.first() {
            Some(e) => Some(e.to.as_str()),
            None => self.sensors.iter().find(|(_, s)| s.camera.is_some()).map(|(n, _)| n.as_str()),
        }
    }

    /// Every sensor placed on the vehicle, in the rig file's order (the first camera, then
    /// the extrinsics' order: the other cameras, then the LiDARs); a sensor without an
    /// extrinsic (rejected) is left out.
    pub fn in_order(&self) -> Vec<RigSensor<'_>> {
        let Some(first) = self.first_camera() else { return Vec::new() };
        let camera = |name: &str| self.sensors.get(name).and_then(|s| s.camera.as_ref());
        let mut out = vec![RigSensor {
            name: first,
            camera: camera(first),
            to_first: crate::geometry::Se3::identity(),
        }];
        out.extend(self.extrinsics.iter().map(|e| RigSensor {
            name: e.from.as_str(),
            camera: camera(&e.from),
            to_first: e.to_se3(),
        }));
        out
    }

    /// Sensor `from` → sensor `to` through the first camera, `None` when either has no
    /// extrinsic (the first camera needs none).
    pub fn between(&self, from: &str, to: &str) -> Option<crate::geometry::Se3> {
        let to_first = |name: &str| match self.first_camera() {
            Some(first) if first == name => Some(crate::geometry::Se3::identity()),
            _ => self.extrinsics.iter().find(|e| e.from == name).map(RigExtrinsic::to_se3),
        };
        Some(to_first(to)?.inverse().compose(&to_first(from)?))
    }
}
