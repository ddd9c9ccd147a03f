//! Camera models: projection, analytic Jacobians (point and intrinsics) and iterative
//! inversion, exactly as OpenCV defines them.
//!
//! * `pinhole-radtan`: OpenCV `projectPoints` with `k1 k2 p1 p2 k3` (no rational or
//!   thin-prism terms). Accepted domain: `z > 1e-12·|p|` and a normalised radius
//!   `r = |(x/z, y/z)|` below the first radius where the radial map `r(1 + k1 r² + k2 r⁴ +
//!   k3 r⁶)` stops increasing ([`Camera::max_valid_radius`]; infinite when it never does).
//!   Beyond it barrel distortion folds back and a pixel would have two rays. The 2×2
//!   Jacobian of the distortion must also have a positive determinant at the point
//!   (tangential terms move the fold a little off the radial one).
//! * `fisheye`: OpenCV `fisheye::projectPoints` (Kannala–Brandt, skew 0) with
//!   `θ = atan2(√(x²+y²), z)`, so points behind the image plane project too. Accepted
//!   domain: `θ ≤ min(θ_fold, FISHEYE_MAX_THETA = 110°)` where `θ_fold` is the first angle at
//!   which `θ_d(θ)` stops increasing. For `z > 0` this is OpenCV's formula (which uses
//!   `atan(r)` and so cannot see past 90°).
//!
//! Pixel coordinates follow OpenCV: the centre of pixel (0, 0) is at (0, 0).
//! No heap, `no_std`: maths through `libm`.

use nalgebra::SMatrix;

use super::{Mat2, Vec2, Vec3};

/// Most intrinsic parameters any model has: fx fy cx cy + 5 distortion coefficients.
pub const MAX_INTRINSICS: usize = 9;

/// Largest incidence angle (radians, 110°) a fisheye camera accepts (220° lenses).
pub const FISHEYE_MAX_THETA: f64 = 110.0 * core::f64::consts::PI / 180.0;

/// A pinhole point must satisfy `z > PINHOLE_MIN_Z_RATIO · |p|` (about 90° − 1e-12 rad).
pub const PINHOLE_MIN_Z_RATIO: f64 = 1e-12;

/// ∂pixel/∂point (camera frame).
pub type PointJacobian = SMatrix<f64, 2, 3>;
/// ∂pixel/∂intrinsics in [`Camera::params`] order; columns past `num_params` are zero.
pub type IntrinsicsJacobian = SMatrix<f64, 2, MAX_INTRINSICS>;

/// Largest squared normalised radius searched for the radtan fold (r = 10⁴, 89.994°).
const RADTAN_MAX_R2: f64 = 1e8;
/// Newton iterations allowed when inverting the distortion.
const MAX_NEWTON_ITERS: usize = 60;
/// Residual (normalised image units) below which the 2-D Newton stops early.
const UNDISTORT_TOL: f64 = 1e-15;
/// Residual (normalised image units) a converged inversion must reach.
const UNDISTORT_ACCEPT: f64 = 1e-11;

/// The projection model of a camera (the room file's `camera.model`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum CameraModel {
    /// Pinhole with OpenCV's radial-tangential distortion k1 k2 p1 p2 k3.
    #[serde(rename = "pinhole-radtan")]
    PinholeRadtan,
    /// Kannala–Brandt k1..k4 as OpenCV's fisheye module defines it.
    #[serde(rename = "fisheye")]
    Fisheye,
}

impl CameraModel {
    /// The name the room and result files use (as the serde names above).
    pub fn name(self) -> &'static str {
        match self {
            CameraModel::PinholeRadtan => "pinhole-radtan",
            CameraModel::Fisheye => "fisheye",
        }
    }
}

/// A calibrated camera: model, image size, intrinsics and distortion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub model: CameraModel,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1 k2 p1 p2 k3 (pinhole-radtan) or k1 k2 k3 k4 and a zero (fisheye).
    pub distortion: [f64; 5],
}

impl Camera {
    /// A camera with the principal point at the image centre (`(w−1)/2, (h−1)/2`), square
    /// pixels, and the focal length that puts the horizontal half-FOV ray exactly on the
    /// image's left/right border (`w/2` from the centre), distortion included (for a
    /// fisheye without distortion that is the equidistant `f = (w/2)/θ_half`).
    /// When [`Camera::try_from_fov`] refuses (empty image, a FOV the model cannot see,
    /// or past the distortion's fold) the focal length ignores the distortion and the
    /// half-FOV is clamped into the model's range, so this never fails or panics.
    pub fn from_fov(
        model: CameraModel,
        width: u32,
        height: u32,
        hfov_deg: f64,
        distortion: [f64; 5],
    ) -> Camera {
        if let Some(cam) = Camera::try_from_fov(model, width, height, hfov_deg, distortion) {
            return cam;
        }
        let half = 0.5 * hfov_deg.to_radians();
        let half = if half.is_nan() { 1e-3 } else { half };
        let edge = match model {
            CameraModel::PinholeRadtan => libm::tan(half.clamp(1e-3, 1.55)),
            CameraModel::Fisheye => half.clamp(1e-3, FISHEYE_MAX_THETA),
        };
        Camera::centred(model, width, height, 0.5 * f64::from(width.max(1)) / edge, distortion)
    }

    /// [`Camera::from_fov`], or `None` for an empty image, a FOV the model cannot see
    /// (radtan ≥ 180°, fisheye > 2·[`FISHEYE_MAX_THETA`]) or one past the distortion's fold.
    pub fn try_from_fov(
        model: CameraModel,
        width: u32,
        height: u32,
        hfov_deg: f64,
        distortion: [f64; 5],
    ) -> Option<Camera> {
        let half = 0.5 * hfov_deg.to_radians();
        if width == 0 || height == 0 || half.is_nan() || half <= 0.0 {
            return None;
        }
        let mut cam = Camera::centred(model, width, height, 1.0, distortion);
        let edge = match model {
            CameraModel::PinholeRadtan => {
                if half >= 0.5 * core::f64::consts::PI {
                    return None;
                }
                let r = libm::tan(half);
                if r >= cam.max_valid_radius() {
                    return None;
                }
                r * cam.radtan_radial(r * r)
            }
            CameraModel::Fisheye => {
                if half > cam.max_valid_radius() {
                    return None;
                }
                cam.fisheye_theta_d(half)
            }
        };
        if !(edge > 0.0 && edge.is_finite()) {
            return None;
        }
        cam.fx = 0.5 * f64::from(width) / edge;
        cam.fy = cam.fx;
        Some(cam)
    }

    /// Number of intrinsic parameters: 9 (radtan) or 8 (fisheye).
    pub fn num_params(&self) -> usize {
        match self.model {
            CameraModel::PinholeRadtan => 9,
            CameraModel::Fisheye => 8,
        }
    }

    /// Intrinsics `fx fy cx cy` then the distortion in storage order; unused slots zero.
    pub fn params(&self) -> [f64; MAX_INTRINSICS] {
        let mut p = [0.0; MAX_INTRINSICS];
        p[..4].copy_from_slice(&[self.fx, self.fy, self.cx, self.cy]);
        let n = self.num_params();
        p[4..n].copy_from_slice(&self.distortion[..n - 4]);
        p
    }

    /// Sets the intrinsics from [`Camera::params`] order. Takes the first
    /// `min(p.len(), num_params())` values; the rest keep their value.
    pub fn set_params(&mut self, p: &[f64]) {
        let n = self.num_params().min(p.len());
        for (i, &v) in p.iter().enumerate().take(n) {
            match i {
                0 => self.fx = v,
                1 => self.fy = v,
                2 => self.cx = v,
                3 => self.cy = v,
                _ => self.distortion[i - 4] = v,
            }
        }
    }

    /// Pixel of a point in the camera frame; `None` behind the camera or outside the
    /// model's valid domain (see the module doc).
    pub fn project(&self, p: &Vec3) -> Option<Vec2> {
        let d = match self.model {
            CameraModel::PinholeRadtan => {
                let xy = self.radtan_normalize(p)?;
                self.radtan_distort(&xy)
            }
            CameraModel::Fisheye => {
                let f = self.fisheye_angles(p)?;
                Vec2::new(p.x, p.y) * (f.q * f.poly)
            }
        };
        Some(self.to_pixel(&d))
    }

    /// Pixel, `∂pixel/∂point` and `∂pixel/∂params` (in [`Camera::params`] order, unused
    /// columns zero), all analytic; same domain as [`Camera::project`].
    pub fn project_with_jacobians(
        &self,
        p: &Vec3,
    ) -> Option<(Vec2, PointJacobian, IntrinsicsJacobian)> {
        let (d, dd_dp, dd_dk) = match self.model {
            CameraModel::PinholeRadtan => self.radtan_with_jacobians(p)?,
            CameraModel::Fisheye => self.fisheye_with_jacobians(p)?,
        };
        let mut jp = dd_dp;
        jp.row_mut(0).scale_mut(self.fx);
        jp.row_mut(1).scale_mut(self.fy);
        let mut jk = IntrinsicsJacobian::zeros();
        jk[(0, 0)] = d.x;
        jk[(1, 1)] = d.y;
        jk[(0, 2)] = 1.0;
        jk[(1, 3)] = 1.0;
        for i in 0..self.num_params() - 4 {
            jk[(0, 4 + i)] = self.fx * dd_dk[(0, i)];
            jk[(1, 4 + i)] = self.fy * dd_dk[(1, i)];
        }
        Some((self.to_pixel(&d), jp, jk))
    }

    /// Unit ray (camera frame) seen by a pixel; `None` where the model does not invert
    /// (past the fold, past [`FISHEYE_MAX_THETA`], or no convergence). Fisheye rays may
    /// point behind the image plane (`z ≤ 0`).
    pub fn unproject(&self, px: &Vec2) -> Option<Vec3> {
        let d = self.to_normalized(px)?;
        match self.model {
            CameraModel::PinholeRadtan => {
                let xy = self.undistort(&d)?;
                Some(Vec3::new(xy.x, xy.y, 1.0).normalize())
            }
            CameraModel::Fisheye => {
                let theta_d = d.norm();
                if theta_d == 0.0 {
                    return Some(Vec3::new(0.0, 0.0, 1.0));
                }
                let theta = self.fisheye_theta(theta_d)?;
                let s = libm::sin(theta) / theta_d;
                Some(Vec3::new(d.x * s, d.y * s, libm::cos(theta)))
            }
        }
    }

    /// Distorts normalised pinhole coordinates `(x/z, y/z)` into distorted normalised
    /// coordinates (pixel = `fx·d.x + cx`, …). No domain check.
    pub fn distort(&self, xy: &Vec2) -> Vec2 {
        match self.model {
            CameraModel::PinholeRadtan => self.radtan_distort(xy),
            CameraModel::Fisheye => {
                let r = xy.norm();
                if r == 0.0 {
                    return *xy;
                }
                let theta = libm::atan(r);
                xy * (self.fisheye_theta_d(theta) / r)
            }
        }
    }

    /// [`Camera::distort`] with its 2×2 Jacobian `∂d/∂(x, y)`.
    pub fn distort_with_jacobian(&self, xy: &Vec2) -> (Vec2, Mat2) {
        match self.model {
            CameraModel::PinholeRadtan => self.radtan_distort_jacobian(xy),
            CameraModel::Fisheye => {
                let (d, j, _) = self.fisheye_with_jacobians_unchecked(&Vec3::new(xy.x, xy.y, 1.0));
                (d, j.fixed_view::<2, 2>(0, 0).into_owned())
            }
        }
    }

    /// Inverse of [`Camera::distort`]: undistorted normalised coordinates, or `None`
    /// past the fold / no convergence (fisheye: also for rays at or past 90°).
    pub fn undistort(&self, d: &Vec2) -> Option<Vec2> {
        match self.model {
            CameraModel::PinholeRadtan => self.radtan_undistort(d),
            CameraModel::Fisheye => {
                let theta_d = d.norm();
                if theta_d == 0.0 {
                    return Some(*d);
                }
                let theta = self.fisheye_theta(theta_d)?;
                if theta >= 0.5 * core::f64::consts::PI {
                    return None;
                }
                Some(d * (libm::tan(theta) / theta_d))
            }
        }
    }

    /// Where the model stops being invertible: radtan, the normalised undistorted radius
    /// `r = |(x/z, y/z)|` of the radial fold (`f64::INFINITY` if none); fisheye, the
    /// largest accepted incidence angle θ in radians (fold or [`FISHEYE_MAX_THETA`]).
    pub fn max_valid_radius(&self) -> f64 {
        match self.model {
            CameraModel::PinholeRadtan => {
                let c = self.radtan_slope_coeffs();
                match first_root(&c, 3, RADTAN_MAX_R2) {
                    Some(s) => libm::sqrt(s),
                    None => f64::INFINITY,
                }
            }
            CameraModel::Fisheye => {
                let c = self.fisheye_slope_coeffs();
                let limit = FISHEYE_MAX_THETA * FISHEYE_MAX_THETA;
                match first_root(&c, 4, limit) {
                    Some(t) => libm::sqrt(t),
                    None => FISHEYE_MAX_THETA,
                }
            }
        }
    }

    /// Distorted normalised coordinates → pixel.
    pub fn to_pixel(&self, d: &Vec2) -> Vec2 {
        Vec2::new(d.x * self.fx + self.cx, d.y * self.fy + self.cy)
    }

    /// Pixel → distorted normalised coordinates; `None` for a zero focal length.
    pub fn to_normalized(&self, px: &Vec2) -> Option<Vec2> {
        if self.fx == 0.0 || self.fy == 0.0 {
            return None;
        }
        Some(Vec2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy))
    }

    /// Fisheye `θ_d(θ) = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸)`.
    pub fn fisheye_theta_d(&self, theta: f64) -> f64 {
        let t2 = theta * theta;
        theta * self.fisheye_poly(t2)
    }

    /// Inverse of [`Camera::fisheye_theta_d`] on `[0, max_valid_radius()]`; `None` past it.
    pub fn fisheye_theta(&self, theta_d: f64) -> Option<f64> {
        let theta_max = self.max_valid_radius();
        if theta_d.is_nan() || theta_d < 0.0 || theta_d > self.fisheye_theta_d(theta_max) {
            return None;
        }
        let k = &self.distortion;
        let f = |t: f64| {
            let t2 = t * t;
            let slope =
                1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
            (self.fisheye_theta_d(t), slope)
        };
        solve_increasing(f, theta_d, 0.0, theta_max, theta_d.min(theta_max))
    }
}

/// Fisheye intermediate values of one point.
struct FisheyeAngles {
    theta: f64,
    /// `θ/ρ` with ρ = |(x, y)| (→ 1/z on the axis).
    q: f64,
    /// `1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸`.
    poly: f64,
    rho: f64,
}

type ModelJacobians = (Vec2, PointJacobian, SMatrix<f64, 2, 5>);

impl Camera {
    /// Square pixels, principal point at the image centre; fisheye's unused fifth
    /// distortion slot zeroed.
    fn centred(model: CameraModel, width: u32, height: u32, f: f64, d: [f64; 5]) -> Camera {
        let mut distortion = d;
        if model == CameraModel::Fisheye {
            distortion[4] = 0.0;
        }
        Camera {
            model,
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * (f64::from(width) - 1.0),
            cy: 0.5 * (f64::from(height) - 1.0),
            distortion,
        }
    }

    fn radtan_radial(&self, r2: f64) -> f64 {
        let k = &self.distortion;
        let r4 = r2 * r2;
        1.0 + k[0] * r2 + k[1] * r4 + k[4] * r4 * r2
    }

    /// Coefficients in `s = r²` of `d/dr [r · radial(r)]`.
    fn radtan_slope_coeffs(&self) -> [f64; 5] {
        let k = &self.distortion;
        [1.0, 3.0 * k[0], 5.0 * k[1], 7.0 * k[4], 0.0]
    }

    /// Coefficients in `t = θ²` of `dθ_d/dθ`.
    fn fisheye_slope_coeffs(&self) -> [f64; 5] {
        let k = &self.distortion;
        [1.0, 3.0 * k[0], 5.0 * k[1], 7.0 * k[2], 9.0 * k[3]]
    }

    fn fisheye_poly(&self, t2: f64) -> f64 {
        let k = &self.distortion;
        1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
    }

    /// `(x/z, y/z)` if the point is in the radtan domain.
    fn radtan_normalize(&self, p: &Vec3) -> Option<Vec2> {
        if !p.iter().all(|v| v.is_finite()) || p.z <= PINHOLE_MIN_Z_RATIO * p.norm() {
            return None;
        }
        let inv_z = 1.0 / p.z;
        let xy = Vec2::new(p.x * inv_z, p.y * inv_z);
        let c = self.radtan_slope_coeffs();
        if !increasing_up_to(&c, 3, xy.norm_squared()) {
            return None;
        }
        // Tangential terms move the fold slightly off the radial one: the map must also
        // keep its orientation at the point itself.
        let (_, j) = self.radtan_distort_jacobian(&xy);
        (j.determinant() > 0.0).then_some(xy)
    }

    /// OpenCV's radial-tangential map, in OpenCV's operation order.
    fn radtan_distort(&self, xy: &Vec2) -> Vec2 {
        let k = &self.distortion;
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let r6 = r4 * r2;
        let a1 = 2.0 * x * y;
        let a2 = r2 + 2.0 * x * x;
        let a3 = r2 + 2.0 * y * y;
        let cdist = 1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6;
        Vec2::new(x * cdist + k[2] * a1 + k[3] * a2, y * cdist + k[2] * a3 + k[3] * a1)
    }

    fn radtan_distort_jacobian(&self, xy: &Vec2) -> (Vec2, Mat2) {
        let k = &self.distortion;
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let radial = self.radtan_radial(r2);
        let dradial = k[0] + r2 * (2.0 * k[1] + 3.0 * k[4] * r2);
        let (p1, p2) = (k[2], k[3]);
        let cross = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y;
        let j = Mat2::new(
            radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x,
            cross,
            cross,
            radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x,
        );
        (self.radtan_distort(xy), j)
    }

    fn radtan_with_jacobians(&self, p: &Vec3) -> Option<ModelJacobians> {
        let xy = self.radtan_normalize(p)?;
        let (d, dd_dxy) = self.radtan_distort_jacobian(&xy);
        let inv_z = 1.0 / p.z;
        let dxy_dp = PointJacobian::new(inv_z, 0.0, -xy.x * inv_z, 0.0, inv_z, -xy.y * inv_z);
        let (x, y) = (xy.x, xy.y);
        let r2 = x * x + y * y;
        let (r4, a1) = (r2 * r2, 2.0 * x * y);
        let dd_dk = SMatrix::<f64, 2, 5>::new(
            x * r2,
            x * r4,
            a1,
            r2 + 2.0 * x * x,
            x * r4 * r2,
            y * r2,
            y * r4,
            r2 + 2.0 * y * y,
            a1,
            y * r4 * r2,
        );
        Some((d, dd_dxy * dxy_dp, dd_dk))
    }

    /// θ, θ/ρ and the distortion polynomial if the point is in the fisheye domain.
    fn fisheye_angles(&self, p: &Vec3) -> Option<FisheyeAngles> {
        let f = self.fisheye_angles_unchecked(p);
        let c = self.fisheye_slope_coeffs();
        let ok = f.theta.is_finite()
            && f.q.is_finite()
            && f.theta <= FISHEYE_MAX_THETA
            && increasing_up_to(&c, 4, f.theta * f.theta);
        ok.then_some(f)
    }

    fn fisheye_angles_unchecked(&self, p: &Vec3) -> FisheyeAngles {
        let rho = libm::hypot(p.x, p.y);
        let theta = libm::atan2(rho, p.z);
        // θ/ρ → 1/z on the axis; the relative error of the limit there is θ² < 1e-24.
        let q = if rho <= 1e-12 * p.z { 1.0 / p.z } else { theta / rho };
        FisheyeAngles { theta, q, poly: self.fisheye_poly(theta * theta), rho }
    }

    fn fisheye_with_jacobians(&self, p: &Vec3) -> Option<ModelJacobians> {
        self.fisheye_angles(p)?;
        Some(self.fisheye_with_jacobians_unchecked(p))
    }

    fn fisheye_with_jacobians_unchecked(&self, p: &Vec3) -> ModelJacobians {
        let f = self.fisheye_angles_unchecked(p);
        let k = &self.distortion;
        let t2 = f.theta * f.theta;
        let slope =
            1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
        let r3_sq = f.rho * f.rho + p.z * p.z;
        // d = b·(x, y) with b = θ_d/ρ; radially it changes at a = θ_d'(θ)·z/|p|².
        let b = f.q * f.poly;
        let a = slope * p.z / r3_sq;
        let mut dxy = Mat2::identity() * b;
        if f.rho > 1e-12 * p.z {
            let n = Vec2::new(p.x, p.y) / f.rho;
            dxy += n * n.transpose() * (a - b);
        }
        let dz = -slope / r3_sq;
        let jp = PointJacobian::new(
            dxy[(0, 0)],
            dxy[(0, 1)],
            dz * p.x,
            dxy[(1, 0)],
            dxy[(1, 1)],
            dz * p.y,
        );
        let mut jk = SMatrix::<f64, 2, 5>::zeros();
        let mut pow = t2;
        for i in 0..4 {
            jk[(0, i)] = f.q * p.x * pow;
            jk[(1, i)] = f.q * p.y * pow;
            pow *= t2;
        }
        (Vec2::new(p.x, p.y) * b, jp, jk)
    }

    /// Newton with the analytic 2×2 Jacobian and backtracking, started from the exact
    /// radial-only inverse so it stays on the monotonic branch.
    fn radtan_undistort(&self, d: &Vec2) -> Option<Vec2> {
        let rd = d.norm();
        if !rd.is_finite() {
            return None;
        }
        if rd == 0.0 && self.distortion[2] == 0.0 && self.distortion[3] == 0.0 {
            return Some(*d);
        }
        let r_max = self.max_valid_radius();
        let r2_max = r_max * r_max;
        let mut xy = self.radtan_initial_guess(d, r_max)?;
        let mut res = self.radtan_distort(&xy) - d;
        let scale = 1.0 + rd;
        for _ in 0..MAX_NEWTON_ITERS {
            if res.norm() <= UNDISTORT_TOL * scale {
                break;
            }
            let (_, j) = self.radtan_distort_jacobian(&xy);
            let step = match j.try_inverse() {
                Some(inv) => -(inv * res),
                None => -res,
            };
            let mut t = 1.0;
            let mut accepted = false;
            while t > 1e-6 {
                let cand = xy + step * t;
                if cand.norm_squared() < r2_max {
                    let cand_res = self.radtan_distort(&cand) - d;
                    if cand_res.norm() < res.norm() {
                        // A step at rounding level means Newton has converged.
                        accepted = (cand - xy).norm() > 1e-15 * (1.0 + xy.norm());
                        xy = cand;
                        res = cand_res;
                        break;
                    }
                }
                t *= 0.5;
            }
            if !accepted {
                break;
            }
        }
        let (_, j) = self.radtan_distort_jacobian(&xy);
        let ok = res.norm() <= UNDISTORT_ACCEPT * scale
            && xy.norm_squared() < r2_max
            && j.determinant() > 0.0;
        ok.then_some(xy)
    }

    /// Start for the 2-D Newton: the exact radial inverse of `d` minus the tangential
    /// shift, the shift re-evaluated a few times (it is small and smooth).
    fn radtan_initial_guess(&self, d: &Vec2, r_max: f64) -> Option<Vec2> {
        let mut xy = *d;
        let (p1, p2) = (self.distortion[2], self.distortion[3]);
        let passes = if p1 == 0.0 && p2 == 0.0 { 1 } else { 3 };
        for _ in 0..passes {
            let (x, y) = (xy.x, xy.y);
            let r2 = x * x + y * y;
            let tangential = Vec2::new(
                2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
            );
            let target = d - tangential;
            let rt = target.norm();
            if rt == 0.0 {
                return Some(target);
            }
            // Past the radial fold the tangential shift may still bring it back: start
            // just inside the fold and let Newton decide.
            let r = self.radtan_radial_inverse(rt, r_max).unwrap_or(r_max * (1.0 - 1e-9));
            if !r.is_finite() {
                return None;
            }
            xy = target * (r / rt);
        }
        Some(xy)
    }

    /// Undistorted radius of a distorted radius, tangential terms ignored.
    fn radtan_radial_inverse(&self, rd: f64, r_max: f64) -> Option<f64> {
        let f = |r: f64| {
            let s = r * r;
            let k = &self.distortion;
            let slope = 1.0 + s * (3.0 * k[0] + s * (5.0 * k[1] + s * 7.0 * k[4]));
            (r * self.radtan_radial(s), slope)
        };
        let mut hi = rd.max(1e-3).min(r_max);
        while f(hi).0 < rd {
            if hi >= r_max || hi > 1e4 {
                return None;
            }
            hi = (hi * 2.0).min(r_max);
        }
        let hi = hi.min(r_max);
        solve_increasing(f, rd, 0.0, hi, rd.min(hi))
    }
}

/// Solves `f(x) = target` for increasing `f` on `[lo, hi]` (`f` returns value and slope):
/// Newton from `x0`, falling back to bisection whenever a step leaves the bracket.
fn solve_increasing(
    f: impl Fn(f64) -> (f64, f64),
    target: f64,
    mut lo: f64,
    mut hi: f64,
    x0: f64,
) -> Option<f64> {
    let mut x = x0;
    for _ in 0..200 {
        let (v, slope) = f(x);
        let r = v - target;
        if libm::fabs(r) <= 1e-16 * (1.0 + libm::fabs(target)) {
            return Some(x);
        }
        if r > 0.0 {
            hi = x;
        } else {
            lo = x;
        }
        let newton = x - r / slope;
        let next = if slope > 0.0 && newton > lo && newton < hi { newton } else { 0.5 * (lo + hi) };
        if next == x || hi - lo <= 4.0 * f64::EPSILON * hi {
            return Some(next);
        }
        x = next;
    }
    let (v, _) = f(x);
    (libm::fabs(v - target) <= 1e-12 * (1.0 + libm::fabs(target))).then_some(x)
}

/// Whether the polynomial `c[0] + c[1] s + … + c[deg] s^deg` (with `c[0] > 0`) stays
/// positive on `[0, s]`.
fn increasing_up_to(c: &[f64; 5], deg: usize, s: f64) -> bool {
    if !s.is_finite() {
        return false;
    }
    // Cheap sufficient test: the negative terms alone cannot outweigh c[0] before s.
    let mut lower = c[0];
    let mut pow = 1.0;
    for &ci in c.iter().take(deg + 1).skip(1) {
        pow *= s;
        if ci < 0.0 {
            lower += ci * pow;
        }
    }
    if lower > 0.0 {
        return true;
    }
    // Exact test: positive at s and at every critical point inside (0, s) (between
    // them the polynomial is monotonic). The critical points of the radtan cubic come in
    // closed form; only the fisheye quartic needs bisection.
    let mut dc = [0.0; 5];
    for i in 1..=deg {
        dc[i - 1] = c[i] * i as f64;
    }
    let (crit, n) = roots_in(&dc, deg - 1, 0.0, s);
    poly_eval(c, deg, s) > 0.0 && crit[..n].iter().all(|&x| poly_eval(c, deg, x) > 0.0)
}

/// Smallest root of the polynomial in `(0, hi]`.
fn first_root(c: &[f64; 5], deg: usize, hi: f64) -> Option<f64> {
    let (roots, n) = roots_in(c, deg, 0.0, hi);
    (n > 0).then(|| roots[0])
}

fn poly_eval(c: &[f64; 5], deg: usize, s: f64) -> f64 {
    c[..=deg].iter().rev().fold(0.0, |acc, &ci| acc * s + ci)
}

/// Sorted real roots in `(lo, hi]` of a polynomial of degree ≤ 4 (no heap): the roots of
/// its derivative split the interval into monotonic pieces, each bisected.
fn roots_in(c: &[f64; 5], deg: usize, lo: f64, hi: f64) -> ([f64; 4], usize) {
    let mut out = ([0.0; 4], 0);
    let mut deg = deg;
    while deg > 0 && c[deg] == 0.0 {
        deg -= 1;
    }
    if deg == 0 || hi.is_nan() || hi <= lo {
        return out;
    }
    // Cauchy's bound: every root has |s| ≤ 1 + max |c_i / c_deg|; searching past it only
    // costs iterations.
    let bound = 1.0 + c[..deg].iter().fold(0.0, |m: f64, ci| m.max(libm::fabs(ci / c[deg])));
    let hi = hi.min(bound);
    let push = |r: f64, out: &mut ([f64; 4], usize)| {
        if out.1 < 4 && (out.1 == 0 || r > out.0[out.1 - 1]) {
            out.0[out.1] = r;
            out.1 += 1;
        }
    };
    if deg == 1 {
        let r = -c[0] / c[1];
        if r > lo && r <= hi {
            push(r, &mut out);
        }
        return out;
    }
    if deg == 2 {
        // Closed form, with the cancellation-free pair q/a and c/q.
        let (a, b, c0) = (c[2], c[1], c[0]);
        let disc = b * b - 4.0 * a * c0;
        if disc < 0.0 {
            return out;
        }
        let q = -0.5 * (b + libm::copysign(libm::sqrt(disc), b));
        let (mut r1, mut r2) = (q / a, if q != 0.0 { c0 / q } else { q / a });
        if r1 > r2 {
            core::mem::swap(&mut r1, &mut r2);
        }
        for r in [r1, r2] {
            if r > lo && r <= hi {
                push(r, &mut out);
            }
        }
        return out;
    }
    let mut dc = [0.0; 5];
    for i in 1..=deg {
        dc[i - 1] = c[i] * i as f64;
    }
    let (crit, nc) = roots_in(&dc, deg - 1, lo, hi);
    let mut a = lo;
    for b in crit.iter().take(nc).copied().chain(core::iter::once(hi)) {
        let (fa, fb) = (poly_eval(c, deg, a), poly_eval(c, deg, b));
        if fb == 0.0 {
            if b > lo {
                push(b, &mut out);
            }
        } else if fa != 0.0 && (fa < 0.0) != (fb < 0.0) {
            push(bisect(c, deg, a, b, fa), &mut out);
        }
        a = b;
    }
    out
}

/// The root in `[a, b]` where the polynomial changes sign (monotonic there): Newton
/// steps while they stay inside the shrinking bracket, bisection otherwise.
fn bisect(c: &[f64; 5], deg: usize, mut a: f64, mut b: f64, fa: f64) -> f64 {
    let neg_a = fa < 0.0;
    let mut x = 0.5 * (a + b);
    for _ in 0..200 {
        let (v, slope) = poly_eval_slope(c, deg, x);
        if v == 0.0 {
            return x;
        }
        if (v < 0.0) == neg_a {
            a = x;
        } else {
            b = x;
        }
        let newton = x - v / slope;
        let next = if newton > a && newton < b { newton } else { 0.5 * (a + b) };
        if next == x || next <= a || next >= b {
            break;
        }
        x = next;
    }
    x
}

/// Value and derivative of the polynomial (Horner).
fn poly_eval_slope(c: &[f64; 5], deg: usize, s: f64) -> (f64, f64) {
    c[..=deg].iter().rev().fold((0.0, 0.0), |(v, d), &ci| (v * s + ci, d * s + v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// splitmix64, so failures reproduce.
    fn next(state: &mut u64) -> f64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn roots_of_known_polynomials() {
        // (s − 1)(s − 2)(s − 3)(s − 4) = s⁴ − 10s³ + 35s² − 50s + 24.
        let (r, n) = roots_in(&[24.0, -50.0, 35.0, -10.0, 1.0], 4, 0.0, 10.0);
        assert_eq!(n, 4);
        for (got, want) in r.iter().zip([1.0, 2.0, 3.0, 4.0]) {
            assert!((got - want).abs() < 1e-12, "{r:?}");
        }
        // Only the roots in (lo, hi] count.
        let (r, n) = roots_in(&[24.0, -50.0, 35.0, -10.0, 1.0], 4, 1.5, 3.0);
        assert_eq!(n, 2);
        assert!((r[0] - 2.0).abs() < 1e-12 && (r[1] - 3.0).abs() < 1e-12, "{r:?}");
        // k1 = −0.4 alone: 1 − 1.2 s has its root at s = 1/1.2.
        assert!(
            (first_root(&[1.0, -1.2, 0.0, 0.0, 0.0], 3, 1e8).unwrap() - 1.0 / 1.2).abs() < 1e-15
        );
        // 1 − 1.2 s + 0.75 s² never vanishes (k1 = −0.4, k2 = 0.15).
        assert_eq!(first_root(&[1.0, -1.2, 0.75, 0.0, 0.0], 3, 1e8), None);
        assert_eq!(first_root(&[1.0, 0.0, 0.0, 0.0, 0.0], 4, 1e8), None);
    }

    #[test]
    fn monotonic_test_agrees_with_dense_sampling() {
        let mut st = 11u64;
        for _ in 0..3000 {
            let deg = 3 + usize::from(next(&mut st) < 0.5);
            let mut c = [1.0, 0.0, 0.0, 0.0, 0.0];
            for ci in c.iter_mut().take(deg + 1).skip(1) {
                *ci = 4.0 * next(&mut st) - 2.0;
            }
            let s = 4.0 * next(&mut st);
            let sampled_positive =
                (0..=4000).all(|i| poly_eval(&c, deg, s * i as f64 / 4000.0) > 0.0);
            let exact = increasing_up_to(&c, deg, s);
            if exact {
                assert!(sampled_positive, "{c:?} up to {s}: said positive, sampling disagrees");
            } else if sampled_positive {
                // Only a dip between two samples may escape the sampling.
                let root = first_root(&c, deg, s).expect("a root when not positive");
                assert!(poly_eval(&c, deg, root).abs() < 1e-9, "{c:?}: bogus root {root}");
            }
            if let Some(root) = first_root(&c, deg, s) {
                let below =
                    (0..1000).all(|i| poly_eval(&c, deg, root * i as f64 / 1000.0) > -1e-12);
                assert!(below, "{c:?}: a root before {root}");
            }
        }
    }
}
