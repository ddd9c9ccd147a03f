//! Geometry core (no_std, no heap): rigid motions on rotation vectors and the camera
//! models, each with the analytic Jacobians the solver needs.

pub mod body;
pub mod camera;
pub mod se3;

pub use camera::{Camera, CameraModel, MAX_INTRINSICS};
pub use se3::Se3;

/// 2-vector of `f64` (pixels, normalised image coordinates, in-plane board coordinates).
pub type Vec2 = nalgebra::Vector2<f64>;
/// 3-vector of `f64` (points, rotation vectors, translations).
pub type Vec3 = nalgebra::Vector3<f64>;
/// 6-vector of `f64` (SE(3) twists, rotation first).
pub type Vec6 = nalgebra::Vector6<f64>;
/// 2×2 matrix of `f64` (distortion Jacobians).
pub type Mat2 = nalgebra::Matrix2<f64>;
/// 3×3 matrix of `f64` (rotations, skew matrices).
pub type Mat3 = nalgebra::Matrix3<f64>;
