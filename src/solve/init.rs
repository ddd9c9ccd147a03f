//! Closed-form starting points for the joint solve (no heap): plane homographies by the
//! normalised DLT, Zhang's intrinsics from several homographies (zero skew), a board pose
//! from a homography and its Gauss–Newton/LM refinement (PnP), and the rigid alignment
//! of paired 3-D points (Kabsch, no scale) that gives the first LiDAR→camera extrinsic.

use nalgebra::{SMatrix, SVector, SymmetricEigen};

use super::linalg::{nearest_rotation, Cholesky};
use super::minimize::{damp, minimize, Problem, Settings, StepTest};
use super::problem::{JointParams, JointProblem};
use super::{Projector, SolveError};
use crate::geometry::se3::point_jacobian;
use crate::geometry::{Mat3, Se3, Vec2, Vec3};

/// Intrinsics from Zhang's closed form, with how well the homographies determined them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZhangIntrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Second-smallest over largest eigenvalue of the (normalised) constraint matrix:
    /// near 0 when the boards' tilts do not fix the intrinsics. Below
    /// [`ZHANG_MIN_CONDITION`] the call fails instead.
    pub condition: f64,
}

/// Smallest [`ZhangIntrinsics::condition`] accepted by [`zhang_intrinsics`].
pub const ZHANG_MIN_CONDITION: f64 = 1e-9;

/// Homography `H` with `image ~ H · [plane; 1]` from at least 4 correspondences by the
/// normalised DLT (Hartley). Use undistorted normalised coordinates for `image` when the
/// distortion is known, pixels otherwise. `H[(2, 2)]` is scaled to 1 when it is not ~0.
pub fn homography(plane: &[Vec2], image: &[Vec2]) -> Result<Mat3, SolveError> {
    if plane.len() != image.len() {
        return Err(SolveError::LengthMismatch { left: plane.len(), right: image.len() });
    }
    homography_from_pairs(plane.iter().copied().zip(image.iter().copied()))
}

/// [`homography`] over any re-iterable sequence of `(plane, image)` pairs (two passes:
/// normalisation, then accumulation of the 9×9 `AᵀA`), so callers can filter without
/// copying into a buffer.
pub fn homography_from_pairs<I>(pairs: I) -> Result<Mat3, SolveError>
where
    I: Iterator<Item = (Vec2, Vec2)> + Clone,
{
    let n = pairs.clone().count();
    if n < 4 {
        return Err(SolveError::TooFewPoints { needed: 4, got: n });
    }
    let t_plane = hartley(pairs.clone().map(|(x, _)| x), n)?;
    let t_image = hartley(pairs.clone().map(|(_, u)| u), n)?;
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (x, u) in pairs {
        let x = t_plane * x.push(1.0);
        let u = t_image * u.push(1.0);
        let (x, y, uu, vv) = (x.x / x.z, x.y / x.z, u.x / u.z, u.y / u.z);
        let r1 = SVector::<f64, 9>::from([-x, -y, -1.0, 0.0, 0.0, 0.0, uu * x, uu * y, uu]);
        let r2 = SVector::<f64, 9>::from([0.0, 0.0, 0.0, -x, -y, -1.0, vv * x, vv * y, vv]);
        ata.ger(1.0, &r1, &r1, 1.0);
        ata.ger(1.0, &r2, &r2, 1.0);
    }
    let (h, _, second, largest) = null_vector(&ata);
    // A second (near-)null direction means collinear or repeated points.
    if second.is_nan() || second <= 1e-10 * largest {
        return Err(SolveError::Degenerate("homography: points collinear or repeated"));
    }
    let hn = Mat3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    // A homography is invertible; a singular fit maps the plane onto a line (the image
    // points are collinear), which the null-space test above cannot see.
    if hn.determinant().abs() <= 1e-9 {
        return Err(SolveError::Degenerate("homography: image points collinear"));
    }
    let inv_image = t_image.try_inverse().ok_or(SolveError::NonFinite)?;
    let hm = inv_image * hn * t_plane;
    let s = if hm[(2, 2)].abs() > 1e-12 * hm.norm() { hm[(2, 2)] } else { hm.norm() };
    let hm = hm / s;
    if hm.iter().all(|v| v.is_finite()) {
        Ok(hm)
    } else {
        Err(SolveError::NonFinite)
    }
}

/// Zhang's closed-form `fx fy cx cy` (zero skew) from homographies `pixel ~ H · [X; Y; 1]`
/// of at least two differently tilted boards. Pixels are first normalised with the image
/// size so the constraint matrix is well scaled. Fails with `Degenerate` when the tilts do
/// not determine the intrinsics (parallel boards, pure in-plane rotation, one board).
pub fn zhang_intrinsics(
    homographies: &[Mat3],
    width: u32,
    height: u32,
) -> Result<ZhangIntrinsics, SolveError> {
    if homographies.len() < 2 {
        return Err(SolveError::TooFewPoints { needed: 2, got: homographies.len() });
    }
    let norm = image_normaliser(width, height);
    let mut m = SMatrix::<f64, 5, 5>::zeros();
    for h in homographies {
        let hn = norm * h;
        let hn = hn / hn.norm();
        let v12 = zhang_row(&hn, 0, 1);
        let d = zhang_row(&hn, 0, 0) - zhang_row(&hn, 1, 1);
        m.ger(1.0, &v12, &v12, 1.0);
        m.ger(1.0, &d, &d, 1.0);
    }
    let (b, _, second, largest) = null_vector(&m);
    let condition = if largest > 0.0 { second / largest } else { 0.0 };
    if condition.is_nan() || condition < ZHANG_MIN_CONDITION {
        return Err(SolveError::Degenerate("Zhang: board tilts do not determine the intrinsics"));
    }
    // b = (B11, B22, B13, B23, B33) of B ∝ K⁻ᵀK⁻¹; its sign is arbitrary.
    let b = if b[0] < 0.0 { -b } else { b };
    let (b11, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4]);
    if b11 <= 0.0 || b22 <= 0.0 {
        return Err(SolveError::Degenerate("Zhang: image of the absolute conic not definite"));
    }
    let cx = -b13 / b11;
    let cy = -b23 / b22;
    let lambda = b33 - (b13 * b13 / b11 + b23 * b23 / b22);
    if !(lambda / b11 > 0.0 && lambda / b22 > 0.0) {
        return Err(SolveError::Degenerate("Zhang: negative focal length squared"));
    }
    let (fx, fy) = (libm::sqrt(lambda / b11), libm::sqrt(lambda / b22));
    // Undo the normalisation: K = N⁻¹ K'.
    let s = norm[(0, 0)];
    let out = ZhangIntrinsics {
        fx: fx / s,
        fy: fy / s,
        cx: (cx - norm[(0, 2)]) / s,
        cy: (cy - norm[(1, 2)]) / s,
        condition,
    };
    if [out.fx, out.fy, out.cx, out.cy].iter().all(|v| v.is_finite()) {
        Ok(out)
    } else {
        Err(SolveError::NonFinite)
    }
}

/// Focal length (fx = fy) from homographies when the principal point `(cx, cy)` is
/// known or assumed (e.g. the image centre): works from a single tilted board, where
/// [`zhang_intrinsics`] cannot.
pub fn focal_from_homographies(homographies: &[Mat3], cx: f64, cy: f64) -> Result<f64, SolveError> {
    if homographies.is_empty() {
        return Err(SolveError::TooFewPoints { needed: 1, got: 0 });
    }
    // Move the principal point to the origin; B ∝ diag(1/f², 1/f², 1) then.
    let shift = Mat3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
    let mut m = SMatrix::<f64, 2, 2>::zeros();
    let mut scale = 0.0f64;
    for h in homographies {
        let hn = shift * h;
        scale = scale.max(hn.fixed_view::<2, 2>(0, 0).norm() / hn.row(2).norm().max(1e-300));
    }
    for h in homographies {
        let mut hn = shift * h;
        // Scale pixel rows so both unknowns are of similar size.
        hn.row_mut(0).scale_mut(1.0 / scale);
        hn.row_mut(1).scale_mut(1.0 / scale);
        let hn = hn / hn.norm();
        let (a, b) = (hn.column(0), hn.column(1));
        let v12 = SVector::<f64, 2>::new(a[0] * b[0] + a[1] * b[1], a[2] * b[2]);
        let d = SVector::<f64, 2>::new(
            a[0] * a[0] + a[1] * a[1] - b[0] * b[0] - b[1] * b[1],
            a[2] * a[2] - b[2] * b[2],
        );
        m.ger(1.0, &v12, &v12, 1.0);
        m.ger(1.0, &d, &d, 1.0);
    }
    // Rows are of unit scale, so a board tilted by a few degrees gives `second` ≳ 1e-4.
    let (v, _, second, _) = null_vector(&m);
    if second.is_nan() || second <= 1e-9 {
        return Err(SolveError::Degenerate("focal: board is parallel to the image plane"));
    }
    let f2 = v[1] / v[0];
    if !(f2 > 0.0 && f2.is_finite()) {
        return Err(SolveError::Degenerate("focal: negative focal length squared"));
    }
    Ok(libm::sqrt(f2) * scale)
}

/// Board pose (board → camera) from `image ~ H · [X; Y; 1]` and the camera matrix `k`
/// (the identity when `H` maps to normalised coordinates). The rotation is the nearest
/// orthonormal matrix to `[r1 r2 r1×r2]`; the board is put in front of the camera.
pub fn pose_from_homography(h: &Mat3, k: &Mat3) -> Result<Se3, SolveError> {
    let k_inv = k.try_inverse().ok_or(SolveError::Degenerate("camera matrix not invertible"))?;
    let m = k_inv * h;
    let (m1, m2, m3) = (m.column(0).into_owned(), m.column(1).into_owned(), m.column(2));
    let scale = 0.5 * (m1.norm() + m2.norm());
    if scale.is_nan() || scale <= 0.0 {
        return Err(SolveError::Degenerate("homography has no rotation part"));
    }
    let lambda = if m3[2] < 0.0 { -1.0 / scale } else { 1.0 / scale };
    let (r1, r2) = (m1 * lambda, m2 * lambda);
    let r0 = Mat3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let rotation = nearest_rotation(&r0).ok_or(SolveError::NonFinite)?;
    Ok(Se3 { rotation, translation: m3 * lambda })
}

/// Pose of a planar board (object points on its `z = 0` plane) from its pixels: the
/// pixels are unprojected with the camera (so distortion is removed), a homography to
/// normalised coordinates gives the first pose, [`refine_pose`] polishes it.
pub fn board_pose<P: Projector>(
    camera: &P,
    object: &[Vec3],
    pixels: &[Vec2],
) -> Result<Se3, SolveError> {
    if object.len() != pixels.len() {
        return Err(SolveError::LengthMismatch { left: object.len(), right: pixels.len() });
    }
    let extent = object.iter().map(|p| p.xy().norm()).fold(0.0, f64::max);
    if object.iter().any(|p| p.z.abs() > 1e-9 * extent.max(1.0)) {
        return Err(SolveError::Degenerate("board pose: object points not on the z = 0 plane"));
    }
    let normalised = |px: &Vec2| {
        camera
            .unproject(px)
            .filter(|ray| ray.z > 1e-9)
            .map(|ray| Vec2::new(ray.x / ray.z, ray.y / ray.z))
    };
    let pairs = object.iter().zip(pixels).filter_map(|(o, px)| normalised(px).map(|u| (o.xy(), u)));
    let h = homography_from_pairs(pairs)?;
    let mut pose = pose_from_homography(&h, &Mat3::identity())?;
    refine_pose(camera, object, pixels, &mut pose, 20)?;
    Ok(pose)
}

/// Levenberg–Marquardt ([`minimize`], [`POSE_SETTINGS`] with `max_iterations`)
/// refinement of a pose (object → camera) on the pixel reprojection error, with
/// left-perturbation updates. Returns the final RMS pixel error.
pub fn refine_pose<P: Projector>(
    camera: &P,
    object: &[Vec3],
    pixels: &[Vec2],
    pose: &mut Se3,
    max_iterations: usize,
) -> Result<f64, SolveError> {
    if object.len() != pixels.len() {
        return Err(SolveError::LengthMismatch { left: object.len(), right: pixels.len() });
    }
    if object.len() < 3 {
        return Err(SolveError::TooFewPoints { needed: 3, got: object.len() });
    }
    let mut fit = PoseFit {
        camera,
        object,
        pixels,
        jtj: SMatrix::zeros(),
        jtr: SVector::zeros(),
        delta: SVector::zeros(),
    };
    let report = minimize(&mut fit, pose, &POSE_SETTINGS.with_max_iterations(max_iterations))?;
    Ok(libm::sqrt(report.final_cost / object.len() as f64))
}

/// How a board pose is refined: Marquardt's schedule, but λ kept between 10⁻¹² and below
/// 10¹⁰ (the cap is the largest double under 10¹⁰), a relative cost decrease of 10⁻¹²
/// and an accepted step of at most 10⁻¹² (rad, m; [`StepTest::OnAcceptance`] with
/// `|x| = 0`): six parameters and a few dozen corners make an iteration cheap, and the pose
/// seeds the joint solve, so it is polished to rounding.
pub const POSE_SETTINGS: Settings = Settings {
    max_iterations: 20,
    cost_tolerance: 1e-12,
    step_tolerance: Some(1e-6),
    step_test: StepTest::OnAcceptance,
    max_lambda: 9_999_999_999.999_998,
    min_lambda: 1e-12,
    ..Settings::MARQUARDT
};

/// One board's pose fit as [`minimize`] drives it: the pixels' `JᵀJ`, `Jᵀr` and the step.
struct PoseFit<'a, P> {
    camera: &'a P,
    object: &'a [Vec3],
    pixels: &'a [Vec2],
    jtj: SMatrix<f64, 6, 6>,
    jtr: SVector<f64, 6>,
    delta: SVector<f64, 6>,
}

impl<P: Projector> Problem for PoseFit<'_, P> {
    type Params = Se3;

    fn linearize(&mut self, pose: &Se3) -> Result<f64, SolveError> {
        let cost = self.cost(pose)?;
        (self.jtj, self.jtr) = pose_normal(self.camera, self.object, self.pixels, pose);
        Ok(cost)
    }

    fn solve_step(&mut self, lambda: f64) -> Result<(), SolveError> {
        let mut a = self.jtj;
        damp(&mut a, lambda);
        self.delta = -Cholesky::new(&a)?.solve(&self.jtr);
        Ok(())
    }

    fn apply(&self, pose: &Se3) -> Se3 {
        pose.perturb_left(&self.delta)
    }

    /// Sum of squared pixel errors.
    fn cost(&self, pose: &Se3) -> Result<f64, SolveError> {
        pose_cost(self.camera, self.object, self.pixels, pose)
            .ok_or(SolveError::NotProjectable { board: 0 })
    }

    /// `(|δ|, 0)`: the pose's step test is absolute (`|δ| ≤ tol²`).
    fn step_size(&self, _: &Se3) -> (f64, f64) {
        (self.delta.norm(), 0.0)
    }
}

/// Rigid motion `to ≈ R · from + t` (no scale) from paired 3-D points by Kabsch's SVD
/// method. Needs 3 points not on one line; fails with `Degenerate` otherwise.
pub fn kabsch(from: &[Vec3], to: &[Vec3]) -> Result<Se3, SolveError> {
    if from.len() != to.len() {
        return Err(SolveError::LengthMismatch { left: from.len(), right: to.len() });
    }
    kabsch_from_pairs(from.iter().copied().zip(to.iter().copied()))
}

/// [`kabsch`] over any re-iterable sequence of `(from, to)` pairs (two passes: centroids,
/// then the cross-covariance), so callers need no buffer.
pub fn kabsch_from_pairs<I>(pairs: I) -> Result<Se3, SolveError>
where
    I: Iterator<Item = (Vec3, Vec3)> + Clone,
{
    let n = pairs.clone().count();
    if n < 3 {
        return Err(SolveError::TooFewPoints { needed: 3, got: n });
    }
    let (sf, st) =
        pairs.clone().fold((Vec3::zeros(), Vec3::zeros()), |(a, b), (f, t)| (a + f, b + t));
    let (cf, ct) = (sf / n as f64, st / n as f64);
    let mut cov = Mat3::zeros();
    for (f, t) in pairs {
        cov.ger(1.0, &(t - ct), &(f - cf), 1.0);
    }
    let svd =
        nalgebra::SVD::try_new(cov, true, true, f64::EPSILON, 200).ok_or(SolveError::NonFinite)?;
    let mut sv = svd.singular_values;
    sv.as_mut_slice().sort_unstable_by(|a, b| b.total_cmp(a));
    // Rank ≥ 2 is needed: one direction (collinear) leaves a free rotation about the line.
    if sv[1].is_nan() || sv[1] <= 1e-9 * sv[0] {
        return Err(SolveError::Degenerate("Kabsch: points collinear or coincident"));
    }
    let rotation = nearest_rotation(&cov).ok_or(SolveError::NonFinite)?;
    Ok(Se3 { rotation, translation: ct - rotation * cf })
}

/// How [`initialise`] seeds the intrinsics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntrinsicsSeed {
    /// Keep the camera's intrinsics as given (nominal, or `Camera::from_fov`).
    Given,
    /// Zhang's closed form from the boards' pixel homographies when it is well
    /// conditioned (≥ 2 tilted boards); the given intrinsics otherwise. Distortion is
    /// kept as given. Meant for pinhole cameras with moderate distortion.
    Zhang { width: u32, height: u32 },
}

/// What [`initialise`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InitReport {
    /// Zhang's result when it was tried and succeeded.
    pub zhang: Option<ZhangIntrinsics>,
    /// Why Zhang was not used, when it was tried and failed.
    pub zhang_error: Option<SolveError>,
    /// RMS pixel error of the corners after the per-board pose refinement.
    pub pose_rms_px: f64,
    /// The board with the largest RMS after its pose refinement, and that RMS: a board
    /// far above the others is likely a wrong detection.
    pub worst_board: Option<(usize, f64)>,
}

/// The whole closed-form start for a [`JointProblem`]: intrinsics (see
/// [`IntrinsicsSeed`]), every board pose from its pixels ([`board_pose`]), and the
/// LiDAR→camera extrinsic by Kabsch over all holes (board holes carried into the camera
/// by their board's pose, against the LiDAR's). Without holes the extrinsic is the
/// identity (and the solver leaves it alone). A board whose pose cannot be found fails
/// the call with [`SolveError::BadBoard`] (or `NotProjectable`) naming it, so the caller
/// can drop it and retry.
pub fn initialise<C: Projector, const B: usize>(
    problem: &JointProblem<'_, B>,
    mut camera: C,
    seed: IntrinsicsSeed,
) -> Result<(JointParams<C, B>, InitReport), SolveError> {
    let mut report =
        InitReport { zhang: None, zhang_error: None, pose_rms_px: 0.0, worst_board: None };
    if let IntrinsicsSeed::Zhang { width, height } = seed {
        match zhang_for(problem, width, height) {
            Ok(z) => {
                let mut k = camera.params();
                k[..4].copy_from_slice(&[z.fx, z.fy, z.cx, z.cy]);
                camera.set_params(&k);
                report.zhang = Some(z);
            }
            Err(e) => report.zhang_error = Some(e),
        }
    }
    let mut board_poses = heapless::Vec::<Se3, B>::new();
    let (mut sq, mut n) = (0.0, 0usize);
    for (b, obs) in problem.boards().iter().enumerate() {
        let in_board = |e: SolveError| match e {
            SolveError::NotProjectable { .. } => SolveError::NotProjectable { board: b },
            other => SolveError::BadBoard { board: b, what: other.what() },
        };
        let mut pose = board_pose(&camera, obs.object, obs.corners).map_err(in_board)?;
        let rms = refine_pose(&camera, obs.object, obs.corners, &mut pose, 0).map_err(in_board)?;
        if report.worst_board.is_none_or(|(_, worst)| rms > worst) {
            report.worst_board = Some((b, rms));
        }
        sq += rms * rms * obs.corners.len() as f64;
        n += obs.corners.len();
        // Capacity is the problem's, so this cannot overflow.
        let _ = board_poses.push(pose);
    }
    report.pose_rms_px = if n > 0 { libm::sqrt(sq / n as f64) } else { 0.0 };
    let lidar_to_camera = if problem.has_holes() {
        let pairs = problem.boards().iter().zip(board_poses.iter()).flat_map(|(obs, pose)| {
            obs.holes_lidar
                .iter()
                .zip(obs.holes_board)
                .map(move |(l, h)| (*l, pose.rotation * h + pose.translation))
        });
        kabsch_from_pairs(pairs)?
    } else {
        Se3::identity()
    };
    Ok((JointParams { camera, lidar_to_camera, board_poses }, report))
}

/// Zhang over the pixel homographies of every board with at least 4 corners.
fn zhang_for<const B: usize>(
    problem: &JointProblem<'_, B>,
    width: u32,
    height: u32,
) -> Result<ZhangIntrinsics, SolveError> {
    let mut hs = heapless::Vec::<Mat3, B>::new();
    for obs in problem.boards() {
        let pairs = obs.object.iter().map(|o| o.xy()).zip(obs.corners.iter().copied());
        if let Ok(h) = homography_from_pairs(pairs) {
            let _ = hs.push(h);
        }
    }
    zhang_intrinsics(&hs, width, height)
}

/// Sum of squared pixel errors; `None` if a point does not project.
fn pose_cost<P: Projector>(
    camera: &P,
    object: &[Vec3],
    pixels: &[Vec2],
    pose: &Se3,
) -> Option<f64> {
    let mut cost = 0.0;
    for (o, px) in object.iter().zip(pixels) {
        cost += (camera.project(&(pose.rotation * o + pose.translation))? - px).norm_squared();
    }
    Some(cost)
}

/// `JᵀJ` and `Jᵀr` of the pixel errors with respect to the pose perturbation.
fn pose_normal<P: Projector>(
    camera: &P,
    object: &[Vec3],
    pixels: &[Vec2],
    pose: &Se3,
) -> (SMatrix<f64, 6, 6>, SVector<f64, 6>) {
    let mut jtj = SMatrix::<f64, 6, 6>::zeros();
    let mut jtr = SVector::<f64, 6>::zeros();
    for (o, px) in object.iter().zip(pixels) {
        let rotated = pose.rotation * o;
        if let Some((u, jp, _)) = camera.project_with_jacobians(&(rotated + pose.translation)) {
            let j = jp * point_jacobian(&rotated);
            jtj.gemm_tr(1.0, &j, &j, 1.0);
            jtr.gemv_tr(1.0, &j, &(u - px), 1.0);
        }
    }
    (jtj, jtr)
}

/// Hartley's similarity: centroid to the origin, mean distance √2.
fn hartley(points: impl Iterator<Item = Vec2> + Clone, n: usize) -> Result<Mat3, SolveError> {
    let c = points.clone().fold(Vec2::zeros(), |a, p| a + p) / n as f64;
    let d = points.map(|p| (p - c).norm()).sum::<f64>() / n as f64;
    if !(d > 0.0 && d.is_finite()) {
        return Err(SolveError::Degenerate("homography: all points coincide"));
    }
    let s = core::f64::consts::SQRT_2 / d;
    Ok(Mat3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0))
}

/// Pixel normaliser for Zhang: image centre to the origin, half the mean side to 1.
fn image_normaliser(width: u32, height: u32) -> Mat3 {
    let s = 4.0 / (width as f64 + height as f64).max(1.0);
    let (cx, cy) = (0.5 * width as f64, 0.5 * height as f64);
    Mat3::new(s, 0.0, -s * cx, 0.0, s, -s * cy, 0.0, 0.0, 1.0)
}

/// Zhang's `v_ij` for zero skew: `h_iᵀ B h_j = v_ij · (B11, B22, B13, B23, B33)`.
fn zhang_row(h: &Mat3, i: usize, j: usize) -> SVector<f64, 5> {
    let (a, b) = (h.column(i), h.column(j));
    SVector::<f64, 5>::new(
        a[0] * b[0],
        a[1] * b[1],
        a[2] * b[0] + a[0] * b[2],
        a[2] * b[1] + a[1] * b[2],
        a[2] * b[2],
    )
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric matrix, with the smallest,
/// second-smallest and largest eigenvalues.
fn null_vector<const N: usize>(m: &SMatrix<f64, N, N>) -> (SVector<f64, N>, f64, f64, f64)
where
    SMatrix<f64, N, N>: SymmetricEigenOf<N>,
{
    let (values, vectors) = m.eigen();
    let mut order = [0usize; N];
    for (i, o) in order.iter_mut().enumerate() {
        *o = i;
    }
    order.sort_unstable_by(|&a, &b| values[a].total_cmp(&values[b]));
    let v = vectors.column(order[0]).into_owned();
    (v, values[order[0]], values[order[1]], values[order[N - 1]])
}

/// Symmetric eigen-decomposition for the concrete sizes used here (nalgebra's bounds
/// are not expressible for a generic `N`).
trait SymmetricEigenOf<const N: usize> {
    fn eigen(&self) -> (SVector<f64, N>, SMatrix<f64, N, N>);
}

macro_rules! symmetric_eigen_of {
    ($($n:literal),*) => {$(
        impl SymmetricEigenOf<$n> for SMatrix<f64, $n, $n> {
            fn eigen(&self) -> (SVector<f64, $n>, SMatrix<f64, $n, $n>) {
                let e = SymmetricEigen::new(*self);
                (e.eigenvalues, e.eigenvectors)
            }
        }
    )*};
}

symmetric_eigen_of!(2, 5, 9);
