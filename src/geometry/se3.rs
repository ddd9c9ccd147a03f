//! Rigid motions in 3-D parameterised by a rotation vector (axis × angle) and a
//! translation: `p' = exp(ω) p + t`, with the SO(3)/SE(3) exponential and logarithm,
//! their Jacobians, quaternion and roll-pitch-yaw conversions and the point-action Jacobians the solver needs.
//!
//! Conventions: a twist `ξ ∈ ℝ⁶` is rotation first, translation second (`ξ = [ω; ρ]`);
//! `Se3::exp(ξ) = (exp(ω), J_l(ω) ρ)` (the standard SE(3) `V` matrix is the SO(3) left
//! Jacobian). Quaternions are `[w, x, y, z]`, Hamilton, returned with `w ≥ 0`.
//! Everything is `no_std` and allocation-free; the transcendental functions come from `libm`.

use super::{Mat3, Vec3, Vec6};

/// Below this squared angle the closed forms are replaced by their Taylor series.
const SMALL_ANGLE_SQ: f64 = 1e-8;

/// Rotation matrix of a rotation vector (Rodrigues), stable near zero.
pub fn so3_exp(omega: &Vec3) -> Mat3 {
    let theta_sq = omega.norm_squared();
    let (a, b) = if theta_sq < SMALL_ANGLE_SQ {
        (1.0 - theta_sq / 6.0 + theta_sq * theta_sq / 120.0, 0.5 - theta_sq / 24.0)
    } else {
        let theta = libm::sqrt(theta_sq);
        (libm::sin(theta) / theta, (1.0 - libm::cos(theta)) / theta_sq)
    };
    let k = skew(omega);
    Mat3::identity() + k * a + k * k * b
}

/// Rotation vector of a rotation matrix, angle in [0, π], stable near 0 and π.
///
/// The input should be a rotation; a slightly non-orthonormal matrix gives the rotation
/// vector of a nearby rotation.
pub fn so3_log(r: &Mat3) -> Vec3 {
    // v = sin θ · axis, c = cos θ: atan2 keeps the angle accurate over the whole range.
    let v = Vec3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]) * 0.5;
    let c = 0.5 * (r.trace() - 1.0);
    let s = v.norm();
    let theta = libm::atan2(s, c);
    if c > 0.0 {
        // θ < π/2: ω = θ / sin θ · v, with the series of θ/sin θ near zero.
        let theta_sq = theta * theta;
        let scale = if theta_sq < SMALL_ANGLE_SQ {
            1.0 + theta_sq / 6.0 + 7.0 * theta_sq * theta_sq / 360.0
        } else {
            theta / s
        };
        return v * scale;
    }
    // θ ≥ π/2: sin θ may vanish, so read the axis from the symmetric part
    // (R + Rᵀ)/2 = c I + (1 − c) a aᵀ, and its sign from v.
    let sym = (r + r.transpose()) * 0.5;
    let one_minus_c = 1.0 - c;
    let mut best = 0;
    for i in 1..3 {
        if sym[(i, i)] > sym[(best, best)] {
            best = i;
        }
    }
    let aa_diag = ((sym[(best, best)] - c) / one_minus_c).max(0.0);
    let a_best = libm::sqrt(aa_diag);
    let mut axis = Vec3::zeros();
    for i in 0..3 {
        axis[i] = if i == best { a_best } else { sym[(i, best)] / (one_minus_c * a_best) };
    }
    let axis = axis.normalize();
    let sign = if axis.dot(&v) < 0.0 { -1.0 } else { 1.0 };
    axis * (sign * theta)
}

/// The rotation manifold's update, the one every solver uses: `R ⊞ δ = exp(δ) R`, a
/// small rotation vector applied on the left (camera/target side). Its tangent at `δ = 0`
/// moves a rotated point `R p` by `−[R p]× δ` ([`act_jacobian_local`]).
pub fn so3_plus(rotation: &Mat3, delta: &Vec3) -> Mat3 {
    so3_exp(delta) * rotation
}

/// `∂(R p + t)/∂[δω; δt]` under [`Se3::perturb_left`] at `δ = 0`, given the rotated point
/// `R p`: `[−[R p]×  I]`.
pub fn point_jacobian(rotated: &Vec3) -> nalgebra::SMatrix<f64, 3, 6> {
    let mut j = nalgebra::SMatrix::<f64, 3, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(rotated)));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&Mat3::identity());
    j
}

/// The skew-symmetric matrix `[v]×` with `[v]× u = v × u`.
pub fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// SO(3) left Jacobian `J_l(ω)`: `exp(ω + δ) ≈ exp(J_l(ω) δ) exp(ω)`. It is also the
/// `V` matrix of the SE(3) exponential.
pub fn so3_left_jacobian(omega: &Vec3) -> Mat3 {
    let theta_sq = omega.norm_squared();
    let (b, c) = if theta_sq < SMALL_ANGLE_SQ {
        (0.5 - theta_sq / 24.0 + theta_sq * theta_sq / 720.0, 1.0 / 6.0 - theta_sq / 120.0)
    } else {
        let theta = libm::sqrt(theta_sq);
        ((1.0 - libm::cos(theta)) / theta_sq, (theta - libm::sin(theta)) / (theta_sq * theta))
    };
    let k = skew(omega);
    Mat3::identity() + k * b + k * k * c
}

/// Inverse of the SO(3) left Jacobian (defined for |ω| < 2π).
pub fn so3_left_jacobian_inv(omega: &Vec3) -> Mat3 {
    let theta_sq = omega.norm_squared();
    // Coefficient 1/θ² − cot(θ/2)/(2θ), written with cot so that θ = π is exact.
    let d = if theta_sq < SMALL_ANGLE_SQ {
        1.0 / 12.0 + theta_sq / 720.0 + theta_sq * theta_sq / 30240.0
    } else {
        let theta = libm::sqrt(theta_sq);
        let half = 0.5 * theta;
        1.0 / theta_sq - libm::cos(half) / (2.0 * theta * libm::sin(half))
    };
    let k = skew(omega);
    Mat3::identity() - k * 0.5 + k * k * d
}

/// SO(3) right Jacobian `J_r(ω) = J_l(−ω) = J_l(ω)ᵀ`: `exp(ω + δ) ≈ exp(ω) exp(J_r(ω) δ)`.
pub fn so3_right_jacobian(omega: &Vec3) -> Mat3 {
    so3_left_jacobian(&(-omega))
}

/// Inverse of the SO(3) right Jacobian.
pub fn so3_right_jacobian_inv(omega: &Vec3) -> Mat3 {
    so3_left_jacobian_inv(&(-omega))
}

/// `∂(exp(ω) p)/∂ω = −[exp(ω) p]× J_l(ω)`: how a rotated point moves with the rotation
/// vector itself (the solver's global parameterisation).
pub fn act_jacobian_rvec(omega: &Vec3, p: &Vec3) -> Mat3 {
    let rp = so3_exp(omega) * p;
    -skew(&rp) * so3_left_jacobian(omega)
}

/// `∂(exp(δ) R p + t)/∂δ` at `δ = 0`, i.e. `−[R p]×`: the local (left) perturbation form
/// used with [`Se3::perturb_left`].
pub fn act_jacobian_local(r: &Mat3, p: &Vec3) -> Mat3 {
    -skew(&(r * p))
}

/// Rotation matrix of a unit quaternion `[w, x, y, z]`; `None` if it is zero or not finite.
/// The quaternion is normalised first.
pub fn quaternion_to_rotation(q: &[f64; 4]) -> Option<Mat3> {
    let n = libm::sqrt(q.iter().map(|v| v * v).sum::<f64>());
    if !n.is_finite() || n <= 0.0 {
        return None;
    }
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    Some(Mat3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ))
}

/// Unit quaternion `[w, x, y, z]` (with `w ≥ 0`) of a rotation matrix (Shepperd's method).
pub fn rotation_to_quaternion(r: &Mat3) -> [f64; 4] {
    let tr = r.trace();
    let mut q = if tr > r[(0, 0)] && tr > r[(1, 1)] && tr > r[(2, 2)] {
        let s = 2.0 * libm::sqrt((1.0 + tr).max(0.0));
        [
            0.25 * s,
            (r[(2, 1)] - r[(1, 2)]) / s,
            (r[(0, 2)] - r[(2, 0)]) / s,
            (r[(1, 0)] - r[(0, 1)]) / s,
        ]
    } else if r[(0, 0)] >= r[(1, 1)] && r[(0, 0)] >= r[(2, 2)] {
        let s = 2.0 * libm::sqrt((1.0 + r[(0, 0)] - r[(1, 1)] - r[(2, 2)]).max(0.0));
        [
            (r[(2, 1)] - r[(1, 2)]) / s,
            0.25 * s,
            (r[(0, 1)] + r[(1, 0)]) / s,
            (r[(0, 2)] + r[(2, 0)]) / s,
        ]
    } else if r[(1, 1)] >= r[(2, 2)] {
        let s = 2.0 * libm::sqrt((1.0 + r[(1, 1)] - r[(0, 0)] - r[(2, 2)]).max(0.0));
        [
            (r[(0, 2)] - r[(2, 0)]) / s,
            (r[(0, 1)] + r[(1, 0)]) / s,
            0.25 * s,
            (r[(1, 2)] + r[(2, 1)]) / s,
        ]
    } else {
        let s = 2.0 * libm::sqrt((1.0 + r[(2, 2)] - r[(0, 0)] - r[(1, 1)]).max(0.0));
        [
            (r[(1, 0)] - r[(0, 1)]) / s,
            (r[(0, 2)] + r[(2, 0)]) / s,
            (r[(1, 2)] + r[(2, 1)]) / s,
            0.25 * s,
        ]
    };
    let n = libm::sqrt(q.iter().map(|v| v * v).sum::<f64>());
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    for v in q.iter_mut() {
        *v *= sign / n;
    }
    q
}

/// Roll, pitch, yaw (rad) of a rotation in the URDF / ROS convention: fixed axes x, y,
/// z in that order, `R = Rz(yaw) · Ry(pitch) · Rx(roll)`; pitch in [−π/2, π/2]. At
/// gimbal lock (|pitch| = π/2) roll is set to 0 and yaw takes the whole turn.
pub fn rotation_to_rpy(r: &Mat3) -> [f64; 3] {
    let pitch = libm::asin((-r[(2, 0)]).clamp(-1.0, 1.0));
    if r[(2, 0)].abs() < 1.0 - 1e-12 {
        let roll = libm::atan2(r[(2, 1)], r[(2, 2)]);
        let yaw = libm::atan2(r[(1, 0)], r[(0, 0)]);
        [roll, pitch, yaw]
    } else {
        [0.0, pitch, libm::atan2(-r[(0, 1)], r[(1, 1)])]
    }
}

/// The rotation of roll, pitch, yaw (rad): `Rz(yaw) · Ry(pitch) · Rx(roll)`.
pub fn rpy_to_rotation(rpy: &[f64; 3]) -> Mat3 {
    let axis = |i: usize, angle: f64| {
        let mut v = Vec3::zeros();
        v[i] = angle;
        so3_exp(&v)
    };
    axis(2, rpy[2]) * axis(1, rpy[1]) * axis(0, rpy[0])
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

    /// The motion `p ↦ exp(rvec) p + t`.
    pub fn from_rvec_t(rvec: &Vec3, t: &Vec3) -> Self {
        Se3 { rotation: so3_exp(rvec), translation: *t }
    }

    /// Rotation vector of the rotation part (angle in [0, π]).
    pub fn rvec(&self) -> Vec3 {
        so3_log(&self.rotation)
    }

    /// `self ∘ other`: apply `other` first, then `self`.
    pub fn compose(&self, other: &Se3) -> Se3 {
        Se3 {
            rotation: self.rotation * other.rotation,
            translation: self.rotation * other.translation + self.translation,
        }
    }

    /// The inverse motion.
    pub fn inverse(&self) -> Se3 {
        let rt = self.rotation.transpose();
        Se3 { rotation: rt, translation: -(rt * self.translation) }
    }

    /// Image of a point: `R p + t`.
    pub fn act(&self, p: &Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// SE(3) exponential of a twist `[ω; ρ]`: rotation `exp(ω)`, translation `J_l(ω) ρ`.
    pub fn exp(xi: &Vec6) -> Se3 {
        let omega = Vec3::new(xi[0], xi[1], xi[2]);
        let rho = Vec3::new(xi[3], xi[4], xi[5]);
        Se3 { rotation: so3_exp(&omega), translation: so3_left_jacobian(&omega) * rho }
    }

    /// SE(3) logarithm `[ω; ρ]` with `ρ = J_l(ω)⁻¹ t` (inverse of [`Se3::exp`] for |ω| ≤ π).
    pub fn log(&self) -> Vec6 {
        let omega = so3_log(&self.rotation);
        let rho = so3_left_jacobian_inv(&omega) * self.translation;
        Vec6::new(omega.x, omega.y, omega.z, rho.x, rho.y, rho.z)
    }

    /// Motion from a quaternion `[w, x, y, z]` (normalised here) and a translation;
    /// `None` for a zero or non-finite quaternion.
    pub fn from_quaternion(q: &[f64; 4], translation: &Vec3) -> Option<Se3> {
        Some(Se3 { rotation: quaternion_to_rotation(q)?, translation: *translation })
    }

    /// The rotation as a unit quaternion `[w, x, y, z]` with `w ≥ 0`.
    pub fn to_quaternion(&self) -> [f64; 4] {
        rotation_to_quaternion(&self.rotation)
    }

    /// The left-perturbed motion `(exp(δω) R, t + δt)` for `δ = [δω; δt]`; its point
    /// Jacobian at `δ = 0` is `[−[R p]×  I]` ([`act_jacobian_local`], identity).
    pub fn perturb_left(&self, delta: &Vec6) -> Se3 {
        let dw = Vec3::new(delta[0], delta[1], delta[2]);
        let dt = Vec3::new(delta[3], delta[4], delta[5]);
        Se3 { rotation: so3_plus(&self.rotation, &dw), translation: self.translation + dt }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_jacobian_matches_central_differences_of_the_left_perturbation() {
        let pose = Se3::from_rvec_t(&Vec3::new(0.3, -1.1, 0.7), &Vec3::new(0.2, -0.4, 2.5));
        let p = Vec3::new(0.45, -0.35, 0.1);
        let analytic = point_jacobian(&(pose.rotation * p));
        let h = 1e-6;
        for c in 0..6 {
            let mut d = Vec6::zeros();
            d[c] = h;
            let numeric =
                (pose.perturb_left(&d).act(&p) - pose.perturb_left(&(-d)).act(&p)) / (2.0 * h);
            let err = (numeric - analytic.column(c)).norm();
            assert!(err < 1e-8, "column {c}: {numeric} vs {}", analytic.column(c));
        }
    }
}
