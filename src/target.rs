//! The room: board geometry and the room file's types (no_std, no heap).
//!
//! The board frame has its origin at the board centre, x right, y down, z into the
//! board. The checkerboard is centred on `checker_offset` (default the origin). Inner
//! corners are numbered row-major: index `row * cols + col`, row 0 at the top (smallest
//! y), column 0 at the left (smallest x). The checkerboard has `cols + 1` × `rows + 1`
//! squares; the top-left square is **black** (the simulator draws it so, and the
//! detector uses it to resolve the orientation of asymmetric patterns).

use core::fmt;

use serde::{Deserialize, Serialize};

use crate::geometry::{CameraModel, Mat3, Vec3};

/// Most holes a board may carry.
pub const MAX_HOLES: usize = 8;
/// Most boards a room may hold (the solver's capacity per frame).
pub const MAX_BOARDS: usize = 16;
/// How far `lidar.rotation` may be from orthonormal (max |RᵀR − I| and |det R − 1|).
pub const ROTATION_TOLERANCE: f64 = 1e-6;
/// Most big planes (floor, walls, ceiling, …) a survey records.
pub const MAX_SURVEY_PLANES: usize = 16;
/// Longest `survey.frame` text and plane name (bytes).
pub const MAX_SURVEY_TEXT: usize = 256;
pub const MAX_PLANE_NAME: usize = 32;
/// How far a surveyed plane's normal may be from unit length.
pub const NORMAL_TOLERANCE: f64 = 1e-6;

/// A calibration board: outline, checkerboard and holes (room file `[board]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardSpec {
    /// Outline width (m, along board x).
    pub width: f64,
    /// Outline height (m, along board y).
    pub height: f64,
    /// Inner corners: columns (along x), rows (along y).
    pub inner_corners: [u32; 2],
    /// Side of one square (m).
    pub square: f64,
    /// Radius of every hole (m).
    pub hole_radius: f64,
    /// Hole centres in the board plane (m).
    pub holes: heapless::Vec<[f64; 2], MAX_HOLES>,
    /// Boards standing in the room.
    pub count: u32,
    /// Centre of the checkerboard in the board frame (m).
    #[serde(default)]
    pub checker_offset: [f64; 2],
}

/// The camera as the room file describes it (`[camera]`): model, size, and optional
/// nominal intrinsics that seed the solver when the boards' tilts do not.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub model: CameraModel,
    pub width: u32,
    pub height: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    /// Nominal distortion (k1 k2 p1 p2 k3, or fisheye k1..k4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<heapless::Vec<f64, 5>>,
}

/// The LiDAR kinds roomcal knows (`lidar.model`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LidarModel {
    Pandar64,
    Pandar40p,
    Vlp16,
    Vlp32c,
    Hdl32e,
    /// Points come as files, not packets.
    Pcd,
}

impl LidarModel {
    /// The packet format this model speaks; `None` for point files.
    pub fn packet_model(self) -> Option<crate::lidar::Model> {
        use crate::lidar::Model;
        match self {
            LidarModel::Pandar64 => Some(Model::Pandar64),
            LidarModel::Pandar40p => Some(Model::Pandar40p),
            LidarModel::Vlp16 => Some(Model::Vlp16),
            LidarModel::Vlp32c => Some(Model::Vlp32c),
            LidarModel::Hdl32e => Some(Model::Hdl32e),
            LidarModel::Pcd => None,
        }
    }
}

/// The LiDAR and its nominal mounting (`[lidar]`): `p_camera = rotation · p_lidar + translation`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LidarSpec {
    pub model: LidarModel,
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
}

/// The quality gate's thresholds (`[quality]`, every key optional).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QualitySpec {
    /// Largest RMS corner reprojection error (px).
    pub max_corner_rms_px: f64,
    /// Largest RMS of the hole term (px).
    pub max_hole_rms_px: f64,
    /// Fewest complete boards the camera must see in every frame (default: `board.count`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_boards: Option<u32>,
    /// Fewest boards seen by both sensors, over all frames (LiDAR rooms).
    pub min_lidar_boards: u32,
    /// Smallest fraction of the image (a 4×4 grid of cells) holding detected corners.
    pub min_coverage: f64,
    /// Largest 1σ of fx and fy relative to their value.
    pub max_sigma_focal_rel: f64,
    /// Largest 1σ of cx and cy (px).
    pub max_sigma_principal_px: f64,
    /// Largest 1σ of the extrinsic rotation (degrees) and translation (m).
    pub max_sigma_rotation_deg: f64,
    pub max_sigma_translation_m: f64,
    /// Largest change from the calibration in force (focal relative, principal point px,
    /// rotation degrees, translation m).
    pub max_change_focal_rel: f64,
    pub max_change_principal_px: f64,
    pub max_change_rotation_deg: f64,
    pub max_change_translation_m: f64,
}

impl Default for QualitySpec {
    fn default() -> Self {
        QualitySpec {
            max_corner_rms_px: 0.5,
            max_hole_rms_px: 5.0,
            min_boards: None,
            min_lidar_boards: 2,
            min_coverage: 0.35,
            max_sigma_focal_rel: 0.01,
            max_sigma_principal_px: 10.0,
            max_sigma_rotation_deg: 0.5,
            max_sigma_translation_m: 0.05,
            max_change_focal_rel: 0.03,
            max_change_principal_px: 25.0,
            max_change_rotation_deg: 2.0,
            max_change_translation_m: 0.1,
        }
    }
}

/// A whole room file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Room {
    pub board: BoardSpec,
    pub camera: CameraSpec,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar: Option<LidarSpec>,
    #[serde(default)]
    pub quality: QualitySpec,
    /// The room as one rigid target, solved by `roomcal survey` (absent until surveyed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub survey: Option<SurveySpec>,
}

/// A surveyed room (`[survey]`): every board's pose and the big planes in one room frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurveySpec {
    /// Visits the survey was solved from.
    pub visits: u32,
    /// How the room frame is defined (free text).
    pub frame: heapless::String<MAX_SURVEY_TEXT>,
    /// One per board (`board.count` of them), any order.
    pub boards: heapless::Vec<SurveyedBoard, MAX_BOARDS>,
    /// The room's big planes, any number up to [`MAX_SURVEY_PLANES`].
    #[serde(default)]
    pub planes: heapless::Vec<SurveyedPlane, MAX_SURVEY_PLANES>,
}

/// One board of a survey: board → room, `p_room = rotation · p_board + translation`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurveyedBoard {
    pub rotation: [[f64; 3]; 3],
    /// m.
    pub translation: [f64; 3],
    /// 1σ of the position, largest axis (m).
    pub sigma_m: f64,
    /// 1σ of the orientation, largest axis (deg).
    pub sigma_deg: f64,
}

/// One big plane of a survey: `normal · p_room = offset`, the normal a unit vector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurveyedPlane {
    pub name: heapless::String<MAX_PLANE_NAME>,
    pub normal: [f64; 3],
    /// m.
    pub offset: f64,
    /// 1σ of the offset (m).
    pub sigma_m: f64,
    /// 1σ of the normal's direction (deg).
    pub sigma_deg: f64,
}

/// What is wrong with a room; every variant names the key it is about.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RoomError {
    /// A size that must be positive is not.
    NonPositive { key: &'static str, value: f64 },
    /// Fewer than two inner corners along a direction.
    TooFewInnerCorners { cols: u32, rows: u32 },
    /// The checkerboard does not fit inside the board outline.
    CheckerOutsideBoard,
    /// A hole reaches outside the board outline.
    HoleOutsideBoard { index: usize },
    /// A hole cuts into the checkerboard.
    HoleOverlapsChecker { index: usize },
    /// Two holes overlap.
    HolesOverlap { first: usize, second: usize },
    /// More boards than the solver holds.
    TooManyBoards { count: u32 },
    /// `lidar.rotation` is not a rotation.
    RotationNotOrthonormal { deviation: f64 },
    /// A `[lidar]` table with a board that has no holes to see.
    LidarWithoutHoles,
    /// A nominal distortion with the wrong number of coefficients.
    DistortionLength { expected: usize, got: usize },
    /// `survey.boards` does not hold one entry per board.
    SurveyBoardCount { expected: u32, got: usize },
    /// A survey from fewer than two visits.
    SurveyVisits { visits: u32 },
    /// A surveyed number is NaN or infinite (`key` names the field, `index` the entry).
    SurveyNotFinite { key: &'static str, index: usize },
    /// A surveyed board's rotation is not a rotation.
    SurveyRotation { index: usize, deviation: f64 },
    /// A surveyed plane's normal is not a unit vector.
    SurveyNormal { index: usize, length: f64 },
    /// A surveyed σ is negative.
    SurveyNegativeSigma { key: &'static str, index: usize },
}

impl fmt::Display for RoomError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            RoomError::NonPositive { key, value } => {
                write!(f, "`{key}` must be positive, got {value}")
            }
            RoomError::TooFewInnerCorners { cols, rows } => write!(
                f,
                "`board.inner_corners` must be at least 2 in each direction, got [{cols}, {rows}]"
            ),
            RoomError::CheckerOutsideBoard => write!(
                f,
                "`board.square`: the checkerboard with its outer squares does not fit inside the board outline"
            ),
            RoomError::HoleOutsideBoard { index } => {
                write!(f, "`board.holes[{index}]`: the hole reaches outside the board outline")
            }
            RoomError::HoleOverlapsChecker { index } => {
                write!(f, "`board.holes[{index}]`: the hole overlaps the checkerboard")
            }
            RoomError::HolesOverlap { first, second } => {
                write!(f, "`board.holes[{first}]` and `board.holes[{second}]` overlap")
            }
            RoomError::TooManyBoards { count } => {
                write!(f, "`board.count` is {count}, at most {MAX_BOARDS} boards are supported")
            }
            RoomError::RotationNotOrthonormal { deviation } => write!(
                f,
                "`lidar.rotation` is not orthonormal with determinant +1 (off by {deviation:.3e}, tolerance {ROTATION_TOLERANCE:e})"
            ),
            RoomError::LidarWithoutHoles => {
                write!(f, "`lidar`: a LiDAR calibration needs `board.holes`, and the list is empty")
            }
            RoomError::DistortionLength { expected, got } => write!(
                f,
                "`camera.distortion` needs {expected} coefficients for this model, got {got}"
            ),
            RoomError::SurveyBoardCount { expected, got } => write!(
                f,
                "`survey.boards` has {got} entries, the room has {expected} boards (`board.count`)"
            ),
            RoomError::SurveyVisits { visits } => {
                write!(f, "`survey.visits` is {visits}: a survey is solved from at least 2 visits")
            }
            RoomError::SurveyNotFinite { key, index } => {
                write!(f, "`{key}` of entry {index} is not a finite number")
            }
            RoomError::SurveyRotation { index, deviation } => write!(
                f,
                "`survey.boards[{index}].rotation` is not orthonormal with determinant +1 (off by {deviation:.3e}, tolerance {ROTATION_TOLERANCE:e})"
            ),
            RoomError::SurveyNormal { index, length } => write!(
                f,
                "`survey.planes[{index}].normal` must be a unit vector, its length is {length}"
            ),
            RoomError::SurveyNegativeSigma { key, index } => {
                write!(f, "`{key}` of entry {index} must not be negative")
            }
        }
    }
}

impl BoardSpec {
    /// Inner corners along x (columns) and y (rows).
    pub fn grid(&self) -> (usize, usize) {
        (self.inner_corners[0] as usize, self.inner_corners[1] as usize)
    }

    /// Number of inner corners.
    pub fn corner_count(&self) -> usize {
        let (cols, rows) = self.grid();
        cols * rows
    }

    /// Inner corner `index` (row-major) in the board frame (z = 0).
    pub fn corner(&self, index: usize) -> Vec3 {
        let (cols, rows) = self.grid();
        let (row, col) = (index / cols, index % cols);
        let x = self.checker_offset[0] + (col as f64 - (cols as f64 - 1.0) / 2.0) * self.square;
        let y = self.checker_offset[1] + (row as f64 - (rows as f64 - 1.0) / 2.0) * self.square;
        Vec3::new(x, y, 0.0)
    }

    /// Centre of hole `index` in the board frame (z = 0).
    pub fn hole(&self, index: usize) -> Vec3 {
        let [x, y] = self.holes[index];
        Vec3::new(x, y, 0.0)
    }

    /// Half extents (x, y) of the checkerboard including its outer squares.
    pub fn checker_half_extent(&self) -> (f64, f64) {
        let (cols, rows) = self.grid();
        ((cols as f64 + 1.0) * self.square / 2.0, (rows as f64 + 1.0) * self.square / 2.0)
    }

    /// Whether the board material is present at board-plane point (x, y): inside the
    /// outline and outside every hole.
    pub fn is_solid(&self, x: f64, y: f64) -> bool {
        let inside = x.abs() <= self.width / 2.0 && y.abs() <= self.height / 2.0;
        let r2 = self.hole_radius * self.hole_radius;
        inside && self.holes.iter().all(|h| (x - h[0]) * (x - h[0]) + (y - h[1]) * (y - h[1]) > r2)
    }

    /// Checks sizes, the checkerboard and the holes against the outline.
    pub fn validate(&self) -> Result<(), RoomError> {
        positive("board.width", self.width)?;
        positive("board.height", self.height)?;
        positive("board.square", self.square)?;
        if !self.holes.is_empty() {
            positive("board.hole_radius", self.hole_radius)?;
        }
        if self.count == 0 {
            return Err(RoomError::NonPositive { key: "board.count", value: 0.0 });
        }
        if self.count as usize > MAX_BOARDS {
            return Err(RoomError::TooManyBoards { count: self.count });
        }
        let [cols, rows] = self.inner_corners;
        if cols < 2 || rows < 2 {
            return Err(RoomError::TooFewInnerCorners { cols, rows });
        }
        let (hx, hy) = self.checker_half_extent();
        let [ox, oy] = self.checker_offset;
        if ox.abs() + hx > self.width / 2.0 || oy.abs() + hy > self.height / 2.0 {
            return Err(RoomError::CheckerOutsideBoard);
        }
        self.validate_holes()
    }

    fn validate_holes(&self) -> Result<(), RoomError> {
        let r = self.hole_radius;
        let (hx, hy) = self.checker_half_extent();
        let [ox, oy] = self.checker_offset;
        for (index, &[x, y]) in self.holes.iter().enumerate() {
            if x.abs() + r > self.width / 2.0 || y.abs() + r > self.height / 2.0 {
                return Err(RoomError::HoleOutsideBoard { index });
            }
            // Distance from the hole centre to the checker rectangle.
            let dx = ((x - ox).abs() - hx).max(0.0);
            let dy = ((y - oy).abs() - hy).max(0.0);
            if dx * dx + dy * dy < r * r {
                return Err(RoomError::HoleOverlapsChecker { index });
            }
            for (second, &[x2, y2]) in self.holes.iter().enumerate().skip(index + 1) {
                if (x - x2) * (x - x2) + (y - y2) * (y - y2) < 4.0 * r * r {
                    return Err(RoomError::HolesOverlap { first: index, second });
                }
            }
        }
        Ok(())
    }
}

impl CameraSpec {
    /// Checks the image size and the nominal intrinsics.
    pub fn validate(&self) -> Result<(), RoomError> {
        if self.width == 0 {
            return Err(RoomError::NonPositive { key: "camera.width", value: 0.0 });
        }
        if self.height == 0 {
            return Err(RoomError::NonPositive { key: "camera.height", value: 0.0 });
        }
        if let Some(fx) = self.fx {
            positive("camera.fx", fx)?;
        }
        if let Some(fy) = self.fy {
            positive("camera.fy", fy)?;
        }
        if let Some(d) = &self.distortion {
            let expected = match self.model {
                CameraModel::PinholeRadtan => 5,
                CameraModel::Fisheye => 4,
            };
            if d.len() != expected {
                return Err(RoomError::DistortionLength { expected, got: d.len() });
            }
        }
        Ok(())
    }
}

impl LidarSpec {
    /// The nominal rotation as a matrix.
    pub fn rotation_matrix(&self) -> Mat3 {
        matrix_of(&self.rotation)
    }

    /// The nominal translation.
    pub fn translation_vector(&self) -> Vec3 {
        Vec3::new(self.translation[0], self.translation[1], self.translation[2])
    }

    /// Checks that the rotation is orthonormal with determinant +1.
    pub fn validate(&self) -> Result<(), RoomError> {
        let deviation = rotation_deviation(&self.rotation_matrix());
        if deviation.is_nan() || deviation > ROTATION_TOLERANCE {
            return Err(RoomError::RotationNotOrthonormal { deviation });
        }
        Ok(())
    }
}

/// A row-major 3×3 array as a matrix.
pub fn matrix_of(r: &[[f64; 3]; 3]) -> Mat3 {
    Mat3::new(r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2])
}

/// How far `r` is from a rotation: max |RᵀR − I| and |det R − 1| (NaN for NaN entries).
pub fn rotation_deviation(r: &Mat3) -> f64 {
    let orth = (r.transpose() * r - Mat3::identity()).abs().max();
    orth.max((r.determinant() - 1.0).abs())
}

impl SurveyedBoard {
    /// Board → room as a rigid motion.
    pub fn pose(&self) -> crate::geometry::Se3 {
        crate::geometry::Se3 {
            rotation: matrix_of(&self.rotation),
            translation: Vec3::from(self.translation),
        }
    }
}

impl SurveySpec {
    /// Checks the visit count, that every number is finite, every rotation a rotation,
    /// every normal a unit vector and every σ non-negative; `boards` is the room's
    /// `board.count`.
    pub fn validate(&self, boards: u32) -> Result<(), RoomError> {
        if self.visits < 2 {
            return Err(RoomError::SurveyVisits { visits: self.visits });
        }
        if self.boards.len() != boards as usize {
            return Err(RoomError::SurveyBoardCount { expected: boards, got: self.boards.len() });
        }
        for (index, b) in self.boards.iter().enumerate() {
            finite("survey.boards.rotation", index, b.rotation.iter().flatten())?;
            finite("survey.boards.translation", index, b.translation.iter())?;
            sigma("survey.boards.sigma_m", index, b.sigma_m)?;
            sigma("survey.boards.sigma_deg", index, b.sigma_deg)?;
            let deviation = rotation_deviation(&matrix_of(&b.rotation));
            if deviation > ROTATION_TOLERANCE {
                return Err(RoomError::SurveyRotation { index, deviation });
            }
        }
        for (index, p) in self.planes.iter().enumerate() {
            finite("survey.planes.normal", index, p.normal.iter())?;
            finite("survey.planes.offset", index, [p.offset].iter())?;
            sigma("survey.planes.sigma_m", index, p.sigma_m)?;
            sigma("survey.planes.sigma_deg", index, p.sigma_deg)?;
            let length = Vec3::from(p.normal).norm();
            if (length - 1.0).abs() > NORMAL_TOLERANCE {
                return Err(RoomError::SurveyNormal { index, length });
            }
        }
        Ok(())
    }
}

fn finite<'a>(
    key: &'static str,
    index: usize,
    mut values: impl Iterator<Item = &'a f64>,
) -> Result<(), RoomError> {
    if values.all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(RoomError::SurveyNotFinite { key, index })
    }
}

fn sigma(key: &'static str, index: usize, value: f64) -> Result<(), RoomError> {
    if !value.is_finite() {
        return Err(RoomError::SurveyNotFinite { key, index });
    }
    if value < 0.0 {
        return Err(RoomError::SurveyNegativeSigma { key, index });
    }
    Ok(())
}

impl Room {
    /// Checks every table; the first problem found is returned.
    pub fn validate(&self) -> Result<(), RoomError> {
        self.board.validate()?;
        self.camera.validate()?;
        if let Some(lidar) = &self.lidar {
            if self.board.holes.is_empty() {
                return Err(RoomError::LidarWithoutHoles);
            }
            lidar.validate()?;
        }
        if let Some(survey) = &self.survey {
            survey.validate(self.board.count)?;
        }
        Ok(())
    }

    /// Whether this room calibrates the camera only (no `[lidar]`).
    pub fn intrinsics_only(&self) -> bool {
        self.lidar.is_none()
    }
}

fn positive(key: &'static str, value: f64) -> Result<(), RoomError> {
    if value.is_nan() || value <= 0.0 || !value.is_finite() {
        return Err(RoomError::NonPositive { key, value });
    }
    Ok(())
}
