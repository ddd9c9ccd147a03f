//! The numeric core of a calibration run (no_std, no heap): closed-form initialisation
//! (homography, Zhang, board pose, Kabsch), the joint Levenberg–Marquardt problem over
//! intrinsics, the LiDAR→camera extrinsic and every board pose reduced with the Schur
//! complement, and the covariance of the shared parameters; a whole rig of cameras and
//! LiDARs in a surveyed room, the room one rigid target ([`rig`]), of which the calibration
//! of one camera and one LiDAR there is the rig of one of each ([`room`]).
//!
//! One solver: every problem implements [`minimize::Problem`] and is solved by the one
//! [`minimize::minimize`] (one damping, one termination rule; each problem states its
//! [`minimize::Settings`]); the problems with pose blocks share the one Schur system
//! ([`schur`]). Each module imports only modules before it in `linalg`, `minimize`,
//! `problem`, `schur`, `lm`, `covariance`, `rig`, `room`, `room_modes` (no import
//! circle); `init` (closed forms and pose refinement) imports `linalg`, `minimize` and
//! `problem`, and no module imports it.
//!
//! Everything here works on fixed-size `nalgebra` matrices and caller-owned slices;
//! capacities are const generics (`B`: most board observations in one problem). Memory
//! does not grow with the number of corners: residuals are streamed from the caller's
//! measurement slices into 6×6, 15×6 and 15×15 blocks of the normal equations.
//!
//! Parameterisation (shared by the residual Jacobians, the LM update and the covariance):
//! intrinsics are updated additively; every rigid motion `p ↦ R p + t` (extrinsic and
//! board poses) by the left perturbation `R ← exp(δω) R`, `t ← t + δt` (the rotation
//! manifold of [`crate::geometry::se3::so3_plus`] and [`crate::geometry::Se3::perturb_left`],
//! written once), so the rotation covariance is that of a small rotation vector applied
//! on the left (camera/target side).
//!
//! A run, from detections to uncertainties:
//!
//! ```no_run
//! use roomcal::geometry::{Camera, Vec2, Vec3};
//! use roomcal::solve::{
//!     covariance, hole_sigma_px, initialise, BoardObservation, IntrinsicsSeed, JointProblem,
//!     LmOptions, Loss, ParamMask, SolveError,
//! };
//!
//! /// `corners[i]` / `holes_lidar[i]`: board observation `i` (camera pixels, LiDAR metres).
//! fn calibrate(
//!     nominal: Camera,
//!     object: &[Vec3],
//!     holes_board: &[Vec3],
//!     corners: &[&[Vec2]],
//!     holes_lidar: &[&[Vec3]],
//! ) -> Result<(), SolveError> {
//!     let mut problem: JointProblem<'_, 16> = JointProblem::new(0.3, 3.0, Loss::Huber(3.0));
//!     for (c, h) in corners.iter().zip(holes_lidar) {
//!         let obs =
//!             BoardObservation { object, corners: c, holes_board, holes_lidar: h, hole_sigma_px: None, plane: None };
//!         problem.add_board(obs)?;
//!     }
//!     let seed = IntrinsicsSeed::Zhang { width: nominal.width, height: nominal.height };
//!     let (mut params, _init) = initialise(&problem, nominal, seed)?;
//!     // Optional: per-board hole σ from the board depth (1 cm LiDAR hole centres) would
//!     // be set on the observations with `hole_sigma_px(fx, 0.01, pose.translation.z)`.
//!     let _ = hole_sigma_px(params.camera.fx, 0.01, params.board_poses[0].translation.z);
//!     let options = LmOptions { mask: ParamMask::free().fix(8), ..LmOptions::default() };
//!     let report = problem.solve(&mut params, &options)?;
//!     let sigma = covariance(&problem, &params, options.mask)?.uncertainty();
//!     let _ = (report.corner_rms_px, report.hole_rms_px, sigma.fx, sigma.rotation_deg);
//!     Ok(())
//! }
//! ```
//!
//! Stack use: a solve keeps [`lm::NormalEquations`] (1056 bytes per board of capacity
//! `B` plus 2 kB: 18.8 kB for `B = 16`) and a few copies of [`JointParams`]; nothing
//! depends on the number of corners.

pub mod covariance;
pub mod init;
pub mod linalg;
pub mod lm;
pub mod minimize;
pub mod problem;
pub mod rig;
pub mod room;
pub mod room_modes;
pub mod schur;

use core::fmt;

use nalgebra::SMatrix;

use crate::geometry::{Camera, Vec2, Vec3};

pub use covariance::{covariance, SharedCovariance, Uncertainty};
pub use init::{
    board_pose, homography, initialise, kabsch, pose_from_homography, refine_pose,
    zhang_intrinsics, InitReport, IntrinsicsSeed, ZhangIntrinsics,
};
pub use lm::{solve, LmOptions, SolveReport};
pub use minimize::{minimize, Problem, Settings, StepTest, Termination};
pub use problem::{
    hole_sigma_px, BoardObservation, JointParams, JointProblem, Loss, Noise, ParamMask, PlanePoints,
};

/// Intrinsic parameters the solver handles: fx fy cx cy + up to 5 distortion terms.
pub const INTRINSICS: usize = 9;
/// Shared (non-board) parameters: intrinsics then the extrinsic `[δω; δt]`.
pub const SHARED: usize = INTRINSICS + 6;
/// Index of the first extrinsic rotation parameter in the shared vector.
pub const EXT_ROTATION: usize = INTRINSICS;
/// Index of the first extrinsic translation parameter in the shared vector.
pub const EXT_TRANSLATION: usize = INTRINSICS + 3;

/// Pixel, its Jacobian with respect to the camera-frame point, and with respect to the
/// intrinsics `[fx fy cx cy d0..d4]`.
pub type Projection = (Vec2, SMatrix<f64, 2, 3>, SMatrix<f64, 2, INTRINSICS>);

/// What the solver needs from a camera model: its parameter vector and a projection with
/// analytic Jacobians. `geometry::Camera` implements it; tests may use their own models.
pub trait Projector {
    /// Intrinsic parameters in use (9 pinhole-radtan, 8 fisheye); later ones stay fixed.
    fn num_params(&self) -> usize;
    /// `[fx fy cx cy d0..d4]` (unused trailing entries are zero).
    fn params(&self) -> [f64; INTRINSICS];
    /// Sets `[fx fy cx cy d0..d4]`.
    fn set_params(&mut self, params: &[f64; INTRINSICS]);
    /// Pixel and Jacobians of a camera-frame point; `None` outside the model's domain.
    fn project_with_jacobians(&self, p: &Vec3) -> Option<Projection>;
    /// Unit ray seen by a pixel; `None` where the model does not invert.
    fn unproject(&self, px: &Vec2) -> Option<Vec3>;
    /// Pixel of a camera-frame point.
    fn project(&self, p: &Vec3) -> Option<Vec2> {
        self.project_with_jacobians(p).map(|(px, _, _)| px)
    }
}

impl Projector for Camera {
    fn num_params(&self) -> usize {
        Camera::num_params(self)
    }
    fn params(&self) -> [f64; INTRINSICS] {
        Camera::params(self)
    }
    fn set_params(&mut self, params: &[f64; INTRINSICS]) {
        Camera::set_params(self, params)
    }
    fn project_with_jacobians(&self, p: &Vec3) -> Option<Projection> {
        Camera::project_with_jacobians(self, p)
    }
    fn unproject(&self, px: &Vec2) -> Option<Vec3> {
        Camera::unproject(self, px)
    }
    fn project(&self, p: &Vec3) -> Option<Vec2> {
        Camera::project(self, p)
    }
}

/// Why an initialisation or a solve failed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SolveError {
    /// Fewer correspondences (or homographies, boards) than the method needs.
    TooFewPoints { needed: usize, got: usize },
    /// Two slices that must pair up have different lengths.
    LengthMismatch { left: usize, right: usize },
    /// The configuration does not determine the solution (named in the message).
    Degenerate(&'static str),
    /// A normal matrix is not positive definite at this pivot (unobservable parameters).
    NotPositiveDefinite { pivot: usize },
    /// A point lies behind the camera or outside the model's domain at the start.
    NotProjectable { board: usize },
    /// More boards than the problem's capacity.
    TooManyBoards { capacity: usize },
    /// A number became NaN or infinite.
    NonFinite,
    /// Board observation `board` could not be used (its pose could not be found).
    BadBoard { board: usize, what: &'static str },
    /// A setting (σ, loss scale, tolerance) is not a positive finite number.
    BadSetting(&'static str),
}

impl SolveError {
    /// A short description without numbers (for [`SolveError::BadBoard`]).
    pub fn what(&self) -> &'static str {
        match self {
            SolveError::TooFewPoints { .. } => "too few correspondences",
            SolveError::LengthMismatch { .. } => "paired inputs differ in length",
            SolveError::Degenerate(what) => what,
            SolveError::NotPositiveDefinite { .. } => "normal matrix not positive definite",
            SolveError::NotProjectable { .. } => "a point does not project into the camera",
            SolveError::TooManyBoards { .. } => "more boards than the solver's capacity",
            SolveError::NonFinite => "a value became NaN or infinite",
            SolveError::BadBoard { what, .. } => what,
            SolveError::BadSetting(what) => what,
        }
    }
}

impl fmt::Display for SolveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SolveError::TooFewPoints { needed, got } => {
                write!(f, "too few correspondences: need {needed}, got {got}")
            }
            SolveError::LengthMismatch { left, right } => {
                write!(f, "paired inputs differ in length: {left} vs {right}")
            }
            SolveError::Degenerate(what) => write!(f, "degenerate configuration: {what}"),
            SolveError::NotPositiveDefinite { pivot } => {
                write!(f, "normal matrix not positive definite at pivot {pivot}")
            }
            SolveError::NotProjectable { board } => {
                write!(f, "board {board}: a point does not project into the camera")
            }
            SolveError::TooManyBoards { capacity } => {
                write!(f, "more boards than the solver's capacity of {capacity}")
            }
            SolveError::NonFinite => write!(f, "a value became NaN or infinite"),
            SolveError::BadBoard { board, what } => write!(f, "board {board}: {what}"),
            SolveError::BadSetting(what) => write!(f, "bad solver setting: {what}"),
        }
    }
}

impl From<linalg::NotPositiveDefinite> for SolveError {
    fn from(e: linalg::NotPositiveDefinite) -> Self {
        SolveError::NotPositiveDefinite { pivot: e.pivot }
    }
}
