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
use crate::lidar::Model;

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

// Physical ranges of the room file's numbers (docs/limits.md). Every number outside its
// range is refused by [`Room::validate`] with its key, before anything is sized from it.

/// Largest board outline side (m): calibration boards are a metre or two; a few metres
/// at most fit a room and a camera's view.
pub const MAX_BOARD_SIDE_M: f64 = 5.0;
/// Smallest checkerboard square (m): below 5 mm no detector finds the corners at room distance.
pub const MIN_SQUARE_M: f64 = 0.005;
/// Smallest and largest camera image side (px): the chessboard detector needs 32, and
/// 16384 is beyond any vehicle camera.
pub const MIN_IMAGE_SIDE: u32 = 32;
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Most pixels of a camera image (16 Mi px: 4096 × 4096, twice a 4K camera): bounds every
/// buffer sized from an image, and image files are refused above it from their header,
/// before decoding. With the decoders' byte limit it keeps a run within the memory budget
/// of docs/limits.md (a frame, the detector's response and the report take ~8 B a pixel).
pub const MAX_IMAGE_PIXELS: u64 = 16 << 20;
/// Focal lengths (px) must lie within these multiples of the image's larger side: 0.05×
/// is wider than any fisheye, 50× narrower than any vehicle telephoto lens.
pub const MIN_FOCAL_PER_SIDE: f64 = 0.05;
pub const MAX_FOCAL_PER_SIDE: f64 = 50.0;
/// Largest magnitude of a distortion coefficient: real lenses fit well below 10.
pub const MAX_DISTORTION: f64 = 100.0;
/// Largest magnitude of a translation component between sensors on one vehicle (m).
pub const MAX_TRANSLATION_M: f64 = 10.0;

/// A calibration board: outline, checkerboard and holes (room file `[board]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardSpec {
    /// Outline width (m, along board x).
    pub width: f64,
    /// Outline height (m, along board y).
    pub height: f64,
    /// Inner corners: columns (along x), rows (along y).
    #[serde(deserialize_with = "exact::array")]
    pub inner_corners: [u32; 2],
    /// Side of one square (m).
    pub square: f64,
    /// Radius of every hole (m).
    pub hole_radius: f64,
    /// Hole centres in the board plane (m).
    #[serde(deserialize_with = "exact::points")]
    pub holes: heapless::Vec<[f64; 2], MAX_HOLES>,
    /// Boards standing in the room.
    pub count: u32,
    /// Centre of the checkerboard in the board frame (m).
    #[serde(default, deserialize_with = "exact::array")]
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
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "lists::distortion"
    )]
    pub distortion: Option<heapless::Vec<f64, 5>>,
}

/// The LiDAR and its nominal mounting (`[lidar]`): `p_camera = rotation · p_lidar + translation`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LidarSpec {
    /// The packet model the LiDAR speaks; `None`: its points come as files (`pcd`).
    #[serde(with = "crate::lidar::common::model_or_pcd")]
    pub model: Option<Model>,
    #[serde(deserialize_with = "exact::matrix")]
    pub rotation: [[f64; 3]; 3],
    #[serde(deserialize_with = "exact::array")]
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
    /// Fewest boards seen by both sensors, over all frames (LiDAR rooms); in a surveyed
    /// room, fewest surveyed targets the LiDAR registers against (boards by their holes or
    /// their face, and planes).
    pub min_lidar_boards: u32,
    /// Smallest fraction of the image (a 4×4 grid of cells) holding detected corners; not
    /// applied where `max_projection_sigma_px` is given (the map then judges what the
    /// boards cover).
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
    /// Surveyed rooms: largest distance (m) and yaw (deg, about the room's vertical — the
    /// rotation angle of the parking pose) of the camera from its nominal parking pose,
    /// the room's nominal LiDAR mounting read as room → camera (the survey's room frame is
    /// the nominal LiDAR frame at the nominal spot). Defaults 0.5 m and 10°.
    pub max_parking_offset_m: f64,
    pub max_parking_yaw_deg: f64,
    /// The part of the image the camera is used in, as fractions of its width and height
    /// (u0, v0, u1, v1): the gate judges the projection uncertainty over it.
    pub region: [f64; 4],
    /// Largest 1σ (px) of a projection over `region`, its point held at
    /// `projection_range_m` along the ray (`calibrate::projection_map`); not judged unless
    /// given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_projection_sigma_px: Option<f64>,
    pub projection_range_m: f64,
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
            max_parking_offset_m: 0.5,
            max_parking_yaw_deg: 10.0,
            region: [0.0, 0.0, 1.0, 1.0],
            max_projection_sigma_px: None,
            projection_range_m: 10.0,
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
    #[serde(deserialize_with = "lists::boards")]
    pub boards: heapless::Vec<SurveyedBoard, MAX_BOARDS>,
    /// The room's big planes, any number up to [`MAX_SURVEY_PLANES`].
    #[serde(default, deserialize_with = "lists::planes")]
    pub planes: heapless::Vec<SurveyedPlane, MAX_SURVEY_PLANES>,
    /// The survey's joint covariance (optional): the lower triangle by rows, row `i`
    /// holding `i + 1` numbers, over every board's `[δω δt]` in `boards` order (6: rad and
    /// m in the room frame, `R ← exp(δω) R`, `t ← t + δt`), then every plane's `[δω δd]` in
    /// `planes` order (4: the normal turned `n ← exp(δω) n`, `δω` across it, rad; the
    /// offset at the frame's origin, m); relative to the boards' mean frame, as the σ are.
    /// The σ say how well each board and plane is known; this also says how their errors
    /// go together (the planes turn as one against the boards), which a calibration holding
    /// each by its own σ cannot know. Read only with `std` (the solver's calibration).
    #[cfg(feature = "std")]
    #[serde(default, skip_serializing_if = "std::vec::Vec::is_empty")]
    pub covariance: std::vec::Vec<std::vec::Vec<f64>>,
    /// Without `std` the covariance is accepted and ignored.
    #[cfg(not(feature = "std"))]
    #[serde(default, skip_serializing)]
    pub covariance: serde::de::IgnoredAny,
}

/// Parameters per surveyed board and per surveyed plane in [`SurveySpec::covariance`].
pub const COVARIANCE_PER_BOARD: usize = 6;
pub const COVARIANCE_PER_PLANE: usize = 4;

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
    /// A number outside its physical range, NaN and infinities included.
    OutOfRange { key: &'static str, index: Index, value: f64, range: Range },
    /// `camera.width × camera.height` above [`MAX_IMAGE_PIXELS`].
    ImageTooLarge { width: u32, height: u32 },
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
    RotationNotOrthonormal { key: &'static str, deviation: f64 },
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
    /// `quality.region` holds no pixel: its right (bottom) edge is not past its left (top).
    EmptyRegion { key: &'static str, region: [f64; 4] },
    /// `survey.covariance` is not the lower triangle of a covariance over every surveyed
    /// board and plane (`row` the first wrong row; `what` says how).
    SurveyCovariance { row: usize, what: &'static str },
}

/// Which entry of a list- or matrix-valued key a number is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Index {
    /// The key is a single number.
    None,
    /// `key[i]`.
    One(u8),
    /// `key[i][j]`.
    Two(u8, u8),
}

/// The closed range `[min, max]` (or `(min, max]` when `min_open`) a number must lie in,
/// and its unit for messages; `max = ∞` means unbounded above (the number must still be
/// finite).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    pub min: f64,
    pub min_open: bool,
    pub max: f64,
    pub unit: &'static str,
}

impl Range {
    /// `(0, max]`.
    pub const fn positive(max: f64, unit: &'static str) -> Range {
        Range { min: 0.0, min_open: true, max, unit }
    }

    /// `[min, max]`.
    pub const fn closed(min: f64, max: f64, unit: &'static str) -> Range {
        Range { min, min_open: false, max, unit }
    }

    /// Whether `value` is finite and inside the range (NaN never is).
    pub fn contains(&self, value: f64) -> bool {
        let above_min = if self.min_open { value > self.min } else { value >= self.min };
        value.is_finite() && above_min && value <= self.max
    }

    /// `Ok` if `value` is in the range, else the error naming `key`.
    pub fn check(&self, key: &'static str, index: Index, value: f64) -> Result<(), RoomError> {
        match self.contains(value) {
            true => Ok(()),
            false => Err(RoomError::OutOfRange { key, index, value, range: *self }),
        }
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let unit = self.unit;
        let space = if unit.is_empty() { "" } else { " " };
        if self.min == f64::NEG_INFINITY && self.max == f64::INFINITY {
            return write!(f, "must be a finite number");
        }
        match (self.min_open && self.min == 0.0, self.max.is_finite()) {
            (true, true) => write!(f, "must be positive and at most {}{space}{unit}", self.max),
            (true, false) => write!(f, "must be a positive finite number"),
            (false, false) => {
                write!(f, "must be a finite number of at least {}{space}{unit}", self.min)
            }
            (false, true) => {
                let open = if self.min_open { '(' } else { '[' };
                write!(
                    f,
                    "must be a finite number in {open}{}, {}]{space}{unit}",
                    self.min, self.max
                )
            }
        }
    }
}

/// A number as a person writes it: plain, or in exponent form when very large or small
/// (`1e308`, not 309 digits).
struct Number(f64);

impl fmt::Display for Number {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        match v.is_finite() && v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
            true => write!(f, "{v:e}"),
            false => write!(f, "{v}"),
        }
    }
}

impl fmt::Display for Index {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Index::None => Ok(()),
            Index::One(i) => write!(f, "[{i}]"),
            Index::Two(i, j) => write!(f, "[{i}][{j}]"),
        }
    }
}

impl fmt::Display for RoomError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            RoomError::NonPositive { key, value } => {
                write!(f, "`{key}` must be positive, got {value}")
            }
            RoomError::OutOfRange { key, index, value, range } => {
                write!(f, "`{key}{index}` = {}: {range}", Number(value))
            }
            RoomError::ImageTooLarge { width, height } => write!(
                f,
                "`camera.width` × `camera.height` = {width} × {height}: more than {MAX_IMAGE_PIXELS} pixels"
            ),
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
            RoomError::RotationNotOrthonormal { key, deviation } => write!(
                f,
                "`{key}` is not orthonormal with determinant +1 (off by {deviation:.3e}, tolerance {ROTATION_TOLERANCE:e})"
            ),
            RoomError::EmptyRegion { key, region: [u0, v0, u1, v1] } => write!(
                f,
                "`{key}`: [{u0}, {v0}, {u1}, {v1}] is empty: it is (u0, v0, u1, v1), \
                 fractions of the image's width and height, with u0 < u1 and v0 < v1"
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
            RoomError::SurveyCovariance { row, what } => {
                write!(f, "`survey.covariance` row {row}: {what}")
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

    /// Checks every number's range, then the checkerboard and the holes against the
    /// outline.
    pub fn validate(&self) -> Result<(), RoomError> {
        let side = Range::positive(MAX_BOARD_SIDE_M, "m");
        side.check("board.width", Index::None, self.width)?;
        side.check("board.height", Index::None, self.height)?;
        Range::closed(MIN_SQUARE_M, MAX_BOARD_SIDE_M, "m").check(
            "board.square",
            Index::None,
            self.square,
        )?;
        let offset = Range::closed(-MAX_BOARD_SIDE_M, MAX_BOARD_SIDE_M, "m");
        for (i, &v) in self.checker_offset.iter().enumerate() {
            offset.check("board.checker_offset", Index::One(i as u8), v)?;
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
        if !self.holes.is_empty() {
            side.check("board.hole_radius", Index::None, self.hole_radius)?;
        }
        for (i, hole) in self.holes.iter().enumerate() {
            for (j, &v) in hole.iter().enumerate() {
                offset.check("board.holes", Index::Two(i as u8, j as u8), v)?;
            }
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
    /// Checks the image size and the nominal intrinsics: focal lengths within the image's
    /// scale, the principal point inside the image, distortion finite and bounded.
    pub fn validate(&self) -> Result<(), RoomError> {
        let side = Range::closed(MIN_IMAGE_SIDE as f64, MAX_IMAGE_SIDE as f64, "px");
        side.check("camera.width", Index::None, f64::from(self.width))?;
        side.check("camera.height", Index::None, f64::from(self.height))?;
        if u64::from(self.width) * u64::from(self.height) > MAX_IMAGE_PIXELS {
            return Err(RoomError::ImageTooLarge { width: self.width, height: self.height });
        }
        let scale = f64::from(self.width.max(self.height));
        let focal = Range::closed(MIN_FOCAL_PER_SIDE * scale, MAX_FOCAL_PER_SIDE * scale, "px");
        let optional = [
            ("camera.fx", self.fx, focal),
            ("camera.fy", self.fy, focal),
            ("camera.cx", self.cx, Range::closed(0.0, f64::from(self.width), "px")),
            ("camera.cy", self.cy, Range::closed(0.0, f64::from(self.height), "px")),
        ];
        for (key, value, range) in optional {
            if let Some(v) = value {
                range.check(key, Index::None, v)?;
            }
        }
        if let Some(d) = &self.distortion {
            let expected = match self.model {
                CameraModel::PinholeRadtan => 5,
                CameraModel::Fisheye => 4,
            };
            if d.len() != expected {
                return Err(RoomError::DistortionLength { expected, got: d.len() });
            }
            let bound = Range::closed(-MAX_DISTORTION, MAX_DISTORTION, "");
            for (i, &v) in d.iter().enumerate() {
                bound.check("camera.distortion", Index::One(i as u8), v)?;
            }
        }
        Ok(())
    }
}

/// Checks a sensor mounting: `rotation` (named `rotation_key`) a rotation — finite,
/// orthonormal with determinant +1 within [`ROTATION_TOLERANCE`] — and `translation`
/// finite and within [`MAX_TRANSLATION_M`]. Used for the room's nominal mounting and for
/// the extrinsic of a result file read back.
pub fn validate_mounting(
    rotation_key: &'static str,
    rotation: &[[f64; 3]; 3],
    translation_key: &'static str,
    translation: &[f64; 3],
) -> Result<(), RoomError> {
    // Finite first (NaN slips through the orthonormality test's comparisons), then a rotation.
    let entry = Range::closed(f64::NEG_INFINITY, f64::INFINITY, "");
    for (i, row) in rotation.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            entry.check(rotation_key, Index::Two(i as u8, j as u8), v)?;
        }
    }
    let deviation = rotation_deviation(&matrix_of(rotation));
    if deviation.is_nan() || deviation > ROTATION_TOLERANCE {
        return Err(RoomError::RotationNotOrthonormal { key: rotation_key, deviation });
    }
    let shift = Range::closed(-MAX_TRANSLATION_M, MAX_TRANSLATION_M, "m");
    for (i, &v) in translation.iter().enumerate() {
        shift.check(translation_key, Index::One(i as u8), v)?;
    }
    Ok(())
}

impl QualitySpec {
    /// Checks that every limit is a finite number that makes sense: residual, σ and
    /// change limits positive (a zero limit would reject every run), the coverage a
    /// fraction, board counts within what a room holds.
    pub fn validate(&self) -> Result<(), RoomError> {
        let positive = Range::positive(f64::INFINITY, "");
        let limits = [
            ("quality.max_corner_rms_px", self.max_corner_rms_px),
            ("quality.max_hole_rms_px", self.max_hole_rms_px),
            ("quality.max_sigma_focal_rel", self.max_sigma_focal_rel),
            ("quality.max_sigma_principal_px", self.max_sigma_principal_px),
            ("quality.max_sigma_rotation_deg", self.max_sigma_rotation_deg),
            ("quality.max_sigma_translation_m", self.max_sigma_translation_m),
            ("quality.max_change_focal_rel", self.max_change_focal_rel),
            ("quality.max_change_principal_px", self.max_change_principal_px),
            ("quality.max_change_rotation_deg", self.max_change_rotation_deg),
            ("quality.max_change_translation_m", self.max_change_translation_m),
            ("quality.max_parking_offset_m", self.max_parking_offset_m),
            ("quality.max_parking_yaw_deg", self.max_parking_yaw_deg),
            ("quality.max_projection_sigma_px", self.max_projection_sigma_px.unwrap_or(1.0)),
            ("quality.projection_range_m", self.projection_range_m),
        ];
        for (key, value) in limits {
            positive.check(key, Index::None, value)?;
        }
        Range::closed(0.0, 1.0, "").check(
            "quality.min_coverage",
            Index::None,
            self.min_coverage,
        )?;
        validate_region("quality.region", &self.region)?;
        if let Some(n) = self.min_boards {
            let boards = Range::closed(0.0, MAX_BOARDS as f64, "boards");
            boards.check("quality.min_boards", Index::None, f64::from(n))?;
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

    /// Checks the nominal mounting (see [`validate_mounting`]).
    pub fn validate(&self) -> Result<(), RoomError> {
        validate_mounting("lidar.rotation", &self.rotation, "lidar.translation", &self.translation)
    }
}

/// Checks a part of the image given as fractions of its width and height (u0, v0, u1,
/// v1): each in [0, 1], and holding pixels (u0 < u1, v0 < v1).
pub fn validate_region(key: &'static str, region: &[f64; 4]) -> Result<(), RoomError> {
    for (i, value) in region.iter().enumerate() {
        Range::closed(0.0, 1.0, "").check(key, Index::One(i as u8), *value)?;
    }
    let [u0, v0, u1, v1] = *region;
    if u1 <= u0 || v1 <= v0 {
        return Err(RoomError::EmptyRegion { key, region: *region });
    }
    Ok(())
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
        #[cfg(feature = "std")]
        self.validate_covariance()?;
        Ok(())
    }

    /// Size of [`Self::covariance`]: 6 per board, 4 per plane.
    pub fn covariance_size(&self) -> usize {
        COVARIANCE_PER_BOARD * self.boards.len() + COVARIANCE_PER_PLANE * self.planes.len()
    }

    /// An empty covariance, or one row per parameter, row `i` of `i + 1` finite numbers
    /// with a non-negative diagonal.
    #[cfg(feature = "std")]
    fn validate_covariance(&self) -> Result<(), RoomError> {
        if self.covariance.is_empty() {
            return Ok(());
        }
        let size = self.covariance_size();
        if self.covariance.len() != size {
            let row = self.covariance.len().min(size);
            return Err(RoomError::SurveyCovariance {
                row,
                what: "rows ≠ 6 per board + 4 per plane",
            });
        }
        for (row, values) in self.covariance.iter().enumerate() {
            let what = if values.len() != row + 1 {
                "row i must hold i + 1 numbers (the lower triangle)"
            } else if !values.iter().all(|v| v.is_finite()) {
                "a number is not finite"
            } else if values[row] < 0.0 {
                "a variance (the diagonal) is negative"
            } else {
                continue;
            };
            return Err(RoomError::SurveyCovariance { row, what });
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
        self.quality.validate()?;
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

/// Lists of a fixed capacity read from a file. heapless's own deserialiser refuses a longer
/// list as "invalid length 9, expected a sequence", which names neither the list nor its
/// maximum; [`capped`] says what the list holds, how many the file gives and how many
/// roomcal takes (toml adds the key and the line).
pub fn capped<'de, D, T, const N: usize>(
    d: D,
    what: &'static str,
) -> Result<heapless::Vec<T, N>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    use serde::de::{Error, IgnoredAny, SeqAccess, Visitor};
    struct V<T, const N: usize>(&'static str, core::marker::PhantomData<T>);
    impl<'de, T: Deserialize<'de>, const N: usize> Visitor<'de> for V<T, N> {
        type Value = heapless::Vec<T, N>;
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            write!(f, "a list of at most {N} {}", self.0)
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
            let mut out = heapless::Vec::new();
            while let Some(item) = seq.next_element()? {
                if out.push(item).is_err() {
                    let mut given = N + 1;
                    while seq.next_element::<IgnoredAny>()?.is_some() {
                        given += 1;
                    }
                    return Err(A::Error::custom(format_args!(
                        "{given} {}, more than the {N} roomcal takes",
                        self.0
                    )));
                }
            }
            Ok(out)
        }
    }
    d.deserialize_seq(V::<T, N>(what, core::marker::PhantomData))
}

/// The capped lists of the room and rig files (see [`capped`]).
pub(crate) mod lists {
    use serde::Deserializer;

    use super::{capped, SurveyedBoard, SurveyedPlane, MAX_BOARDS, MAX_SURVEY_PLANES};

    pub fn boards<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<heapless::Vec<SurveyedBoard, MAX_BOARDS>, D::Error> {
        capped(d, "surveyed boards")
    }

    pub fn planes<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<heapless::Vec<SurveyedPlane, MAX_SURVEY_PLANES>, D::Error> {
        capped(d, "surveyed planes")
    }

    pub fn distortion<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<heapless::Vec<f64, 5>>, D::Error> {
        capped(d, "distortion coefficients").map(Some)
    }
}

/// Strict-length deserialisers: serde's `[T; N]` takes the first N elements of a longer
/// array and drops the rest silently, so `inner_corners = [7, 5, 3]` would be read as
/// `[7, 5]`. These refuse any array that has not exactly N elements (toml names the key).
mod exact {
    use core::fmt;
    use core::marker::PhantomData;

    use serde::de::{Deserialize, Deserializer, Error, SeqAccess, Visitor};

    /// `[T; N]` from an array of exactly N elements.
    struct Exact<T, const N: usize>([T; N]);

    impl<'de, T: Deserialize<'de> + Copy + Default, const N: usize> Deserialize<'de> for Exact<T, N> {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct V<T, const N: usize>(PhantomData<T>);
            impl<'de, T: Deserialize<'de> + Copy + Default, const N: usize> Visitor<'de> for V<T, N> {
                type Value = Exact<T, N>;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    write!(f, "an array of exactly {N} elements")
                }
                fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                    let mut out = [T::default(); N];
                    for (i, slot) in out.iter_mut().enumerate() {
                        *slot = seq
                            .next_element()?
                            .ok_or_else(|| A::Error::invalid_length(i, &self))?;
                    }
                    if seq.next_element::<serde::de::IgnoredAny>()?.is_some() {
                        return Err(A::Error::invalid_length(N + 1, &self));
                    }
                    Ok(Exact(out))
                }
            }
            d.deserialize_seq(V::<T, N>(PhantomData))
        }
    }

    pub fn array<'de, D, T, const N: usize>(d: D) -> Result<[T; N], D::Error>
    where
        D: Deserializer<'de>,
        T: Deserialize<'de> + Copy + Default,
    {
        Ok(Exact::<T, N>::deserialize(d)?.0)
    }

    pub fn matrix<'de, D: Deserializer<'de>>(d: D) -> Result<[[f64; 3]; 3], D::Error> {
        let rows = Exact::<Exact3, 3>::deserialize(d)?.0;
        Ok([rows[0].0, rows[1].0, rows[2].0])
    }

    /// A matrix row (named so that `Exact` of it is `Copy + Default`).
    #[derive(Clone, Copy, Default)]
    struct Exact3([f64; 3]);

    impl<'de> Deserialize<'de> for Exact3 {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            Ok(Exact3(array(d)?))
        }
    }

    /// A point list: each point exactly two coordinates.
    pub fn points<'de, D, const M: usize>(d: D) -> Result<heapless::Vec<[f64; 2], M>, D::Error>
    where
        D: Deserializer<'de>,
    {
        let pts: heapless::Vec<Exact2, M> = super::capped(d, "holes")?;
        Ok(pts.iter().map(|p| p.0).collect())
    }

    #[derive(Clone, Copy, Default)]
    struct Exact2([f64; 2]);

    impl<'de> Deserialize<'de> for Exact2 {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            Ok(Exact2(array(d)?))
        }
    }
}

#[cfg(all(test, feature = "std"))]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::lidar::common::FILE_NAMES;

    /// Every spelling `lidar.model` has in the room, rig and result files, written out here
    /// so that renaming a model (or its serde) fails this test.
    const SPELLINGS: [(&str, Option<Model>); 9] = [
        ("pandar64", Some(Model::Pandar64)),
        ("pandar40p", Some(Model::Pandar40p)),
        ("vlp16", Some(Model::Vlp16)),
        ("vlp32c", Some(Model::Vlp32c)),
        ("hdl32e", Some(Model::Hdl32e)),
        ("pandarxt32", Some(Model::PandarXt32)),
        ("pandarqt64", Some(Model::PandarQt64)),
        ("ouster", Some(Model::Ouster)),
        ("pcd", None),
    ];

    /// The room file's expected list, as serde reports an unknown model.
    const EXPECTED: &str = "expected one of `pandar64`, `pandar40p`, `vlp16`, `vlp32c`, \
                            `hdl32e`, `pandarxt32`, `pandarqt64`, `ouster`, `pcd`";

    fn room_with_model(value: &str) -> String {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml");
        let text = std::fs::read_to_string(path).unwrap();
        assert!(text.contains("model = \"pandar64\""), "config/room.toml changed");
        text.replacen("model = \"pandar64\"", &format!("model = {value}"), 1)
    }

    #[test]
    fn every_lidar_model_spelling_round_trips_through_the_room_file() {
        assert_eq!(FILE_NAMES, SPELLINGS.map(|(name, _)| name));
        for (name, model) in SPELLINGS {
            let text = room_with_model(&format!("\"{name}\""));
            let room = crate::room::parse(&text, Path::new("room.toml")).unwrap();
            let lidar = room.lidar.clone().unwrap();
            assert_eq!(lidar.model, model, "{name}");
            assert_eq!(Model::file_name(model), name);
            let emitted = crate::room::to_toml(&room);
            assert!(emitted.contains(&format!("\nmodel = \"{name}\"\n")), "{name}: {emitted}");
            assert_eq!(crate::room::parse(&emitted, Path::new("emitted")).unwrap(), room);
            let json = serde_json::to_value(&lidar).unwrap();
            assert_eq!(json["model"], name);
            assert_eq!(serde_json::from_value::<LidarSpec>(json).unwrap(), lidar);
            rig_round_trips(name, model);
        }
    }

    /// The rig file's `[[lidar]] model` takes the room file's spellings.
    fn rig_round_trips(name: &str, model: Option<Model>) {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/rig.toml");
        let text = std::fs::read_to_string(path).unwrap();
        assert!(text.contains("model = \"vlp32c\""), "config/rig.toml changed");
        let text = text.replacen("model = \"vlp32c\"", &format!("model = \"{name}\""), 1);
        let rig = crate::rig::parse(&text, Path::new("rig.toml")).unwrap();
        assert_eq!(rig.lidars[1].model, model, "{name}");
        let file: crate::rig::RigFile = toml::from_str(&text).unwrap();
        let emitted = toml::to_string(&file).unwrap();
        assert!(emitted.contains(&format!("\nmodel = \"{name}\"\n")), "{name}: {emitted}");
    }

    #[test]
    fn other_lidar_model_spellings_are_refused_with_the_list() {
        // `Model::from_name`'s aliases and other cases are for the command line only.
        for bad in ["Pandar64", "PANDAR64", "pandar-64", "pandar_xt32", "xt32", "vlp32", "pcap", ""]
        {
            let text = room_with_model(&format!("\"{bad}\""));
            let e = crate::room::parse(&text, Path::new("room.toml")).unwrap_err().to_string();
            assert!(e.contains(&format!("unknown variant `{bad}`, expected one of")), "{e}");
            let json = format!(
                "{{\"model\": \"{bad}\", \"rotation\": [[1,0,0],[0,1,0],[0,0,1]], \
                                \"translation\": [0,0,0]}}"
            );
            let e = serde_json::from_str::<LidarSpec>(&json).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("unknown variant `{bad}`, {EXPECTED} at line 1")),
                "{e}"
            );
        }
        let e = crate::room::parse(&room_with_model("5"), Path::new("room.toml")).unwrap_err();
        assert!(e.to_string().ends_with("wanted string or table"), "{e}");
    }

    #[test]
    fn a_packet_model_field_refuses_pcd() {
        assert_eq!(serde_json::from_str::<Model>("\"vlp16\"").unwrap(), Model::Vlp16);
        assert_eq!(serde_json::to_string(&Model::PandarXt32).unwrap(), "\"pandarxt32\"");
        assert!(serde_json::from_str::<Model>("\"pcd\"").is_err());
    }
}
