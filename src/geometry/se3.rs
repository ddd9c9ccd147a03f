//! Rigid motions in 3-D parameterised by a rotation vector (axis × angle) and a
//! translation: `p' = exp(ω) p + t`. API contract; bodies are filled by the geometry work.

use super::{Mat3, Vec3};

/// Rotation matrix of a rotation vector (Rodrigues), stable near zero.
pub fn so3_exp(omega: &Vec3) -> Mat3 {
    let _ = omega;
    todo!("geometry core")
}

/// Rotation vector of a rotation matrix, angle in [0, π], stable near 0 and π.
pub fn so3_log(r: &Mat3) -> Vec3 {
    let _ = r;
    todo!("geometry core")
}

/// The skew-symmetric matrix `[v]×` with `[v]× u = v × u`.
pub fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// A rigid motion: `p' = rotation · p + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Se3 {
    pub rotation: Mat3,
    pub translation: Vec3,
}

impl Se3 {
    /// The identity motion.
    pub fn identity() -> Self {
        Se3 { rotation: Mat3::identity(), translation: Vec3::zeros() }
    }
}
