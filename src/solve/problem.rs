//! The joint calibration problem: what is measured (board corners in the image, hole
//! centres in the LiDAR frame, both held by reference), what is estimated (intrinsics,
//! the LiDAR→camera extrinsic, one pose per board observation), and the residual blocks
//! with their analytic Jacobians, streamed one at a time so memory does not grow with
//! the number of corners.
//!
//! Residual blocks (2-vectors, divided by their σ):
//! - corner: `project(T_BC · X) − x_measured` — intrinsics and board `b`;
//! - hole (the paper's term): `project(T_LC · P_lidar) − project(T_BC · H_board)` —
//!   intrinsics, extrinsic and board `b`;
//! - plane (optional, [`PlanePoints`]): the LiDAR's board points carried into the board
//!   frame should lie on its plane `z = 0`. The sum of their squared distances is a
//!   quadratic form in the plane, so it is streamed as two 2-row blocks built from the
//!   points' centroid and scatter — exactly the per-point normal equations, in fixed
//!   size — for the extrinsic and board `b`. It ties the board's depth and tilt, which
//!   the image measures only through the focal length, to the LiDAR's ranges.
//!
//! Jacobians use the module's parameterisation (see [`crate::solve`]): additive
//! intrinsics, left-perturbed rigid motions.

use nalgebra::SMatrix;

use super::linalg::Cholesky;
use super::{Projector, SolveError, EXT_ROTATION, INTRINSICS, SHARED};
use crate::geometry::se3::{point_jacobian, skew};
use crate::geometry::{Mat3, Se3, Vec2, Vec3};

/// What one board observation (one board in one frame) measured. Slices are the
/// caller's: corners pair with `object`, LiDAR hole centres with `holes_board`.
#[derive(Clone, Copy, Debug, Default)]
pub struct BoardObservation<'a> {
    /// Checkerboard corners in the board frame (m), the detector's order.
    pub object: &'a [Vec3],
    /// Measured corner pixels, paired with `object`.
    pub corners: &'a [Vec2],
    /// Hole centres in the board frame (m); empty for intrinsics-only runs.
    pub holes_board: &'a [Vec3],
    /// The same holes measured in the LiDAR frame (m), paired with `holes_board`.
    pub holes_lidar: &'a [Vec3],
    /// This board's hole-term σ (px), when it differs from the problem's: a LiDAR
    /// hole-centre error of `σ_m` at depth `z` shows as about `fx · σ_m / z` pixels, so
    /// far boards deserve a smaller σ ([`hole_sigma_px`] computes it).
    pub hole_sigma_px: Option<f64>,
    /// The LiDAR's points on this board, for the point-to-plane term (LiDAR frame).
    pub plane: Option<PlanePoints>,
}

/// The σ of a board observation's corner and hole terms (px), where the observation does
/// not set its own (the plane term carries its σ in [`PlanePoints`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    pub corner_px: f64,
    pub hole_px: f64,
}

impl BoardObservation<'_> {
    /// Streams this observation's whitened residual blocks (numbered `board`) seen by
    /// `camera`, the LiDAR at `ext` (LiDAR → camera) and the board at `pose` (board →
    /// camera), with their Jacobians. Every problem built of board observations (free
    /// boards, the surveyed room, rigs) evaluates its measurements here.
    pub fn for_each_residual<C: Projector>(
        &self,
        board: usize,
        cam: &C,
        ext: &Se3,
        pose: &Se3,
        noise: Noise,
        f: &mut impl FnMut(&Residual),
    ) -> Result<(), SolveError> {
        let ws = 1.0 / noise.corner_px;
        let wh = 1.0 / self.hole_sigma_px.unwrap_or(noise.hole_px);
        let fail = SolveError::NotProjectable { board };
        for (i, (x, meas)) in self.object.iter().zip(self.corners).enumerate() {
            let rx = pose.rotation * x;
            let (u, jp, jk) = cam.project_with_jacobians(&(rx + pose.translation)).ok_or(fail)?;
            let mut j_shared = SMatrix::<f64, 2, SHARED>::zeros();
            j_shared.fixed_view_mut::<2, INTRINSICS>(0, 0).copy_from(&(jk * ws));
            f(&Residual {
                board,
                kind: ResidualKind::Corner(i),
                r: (u - meas) * ws,
                j_shared,
                j_board: jp * point_jacobian(&rx) * ws,
                rows: 2,
            });
        }
        for (i, (h, p)) in self.holes_board.iter().zip(self.holes_lidar).enumerate() {
            let rp = ext.rotation * p;
            let (u1, jq, jk1) = cam.project_with_jacobians(&(rp + ext.translation)).ok_or(fail)?;
            let rh = pose.rotation * h;
            let (u2, jp, jk2) = cam.project_with_jacobians(&(rh + pose.translation)).ok_or(fail)?;
            let mut j_shared = SMatrix::<f64, 2, SHARED>::zeros();
            j_shared.fixed_view_mut::<2, INTRINSICS>(0, 0).copy_from(&((jk1 - jk2) * wh));
            j_shared
                .fixed_view_mut::<2, 6>(0, EXT_ROTATION)
                .copy_from(&(jq * point_jacobian(&rp) * wh));
            f(&Residual {
                board,
                kind: ResidualKind::Hole(i),
                r: (u1 - u2) * wh,
                j_shared,
                j_board: -(jp * point_jacobian(&rh)) * wh,
                rows: 2,
            });
        }
        if let Some(plane) = &self.plane {
            plane_blocks(board, plane, pose, ext, f);
        }
        Ok(())
    }

    /// Calls `f(kind, error)` for every block as [`Self::for_each_residual`] streams them,
    /// without Jacobians or σ (pixels; metres·√points for the plane term).
    pub fn for_each_error<C: Projector>(
        &self,
        board: usize,
        cam: &C,
        ext: &Se3,
        pose: &Se3,
        f: &mut impl FnMut(ResidualKind, Vec2),
    ) -> Result<(), SolveError> {
        let fail = SolveError::NotProjectable { board };
        for (i, (x, meas)) in self.object.iter().zip(self.corners).enumerate() {
            let u = cam.project(&(pose.rotation * x + pose.translation)).ok_or(fail)?;
            f(ResidualKind::Corner(i), u - meas);
        }
        for (i, (h, p)) in self.holes_board.iter().zip(self.holes_lidar).enumerate() {
            let u1 = cam.project(&(ext.rotation * p + ext.translation)).ok_or(fail)?;
            let u2 = cam.project(&(pose.rotation * h + pose.translation)).ok_or(fail)?;
            f(ResidualKind::Hole(i), u1 - u2);
        }
        if let Some(plane) = &self.plane {
            let (a, offset, _) = plane_geometry(plane, pose, ext);
            let r = plane.residual(&a, offset);
            f(ResidualKind::Plane(0), Vec2::new(r[0], r[1]));
            f(ResidualKind::Plane(1), Vec2::new(r[2], r[3]));
        }
        Ok(())
    }

    /// The σ dividing this observation's blocks of `kind` (px, or m for the plane term).
    pub fn sigma(&self, kind: ResidualKind, noise: Noise) -> f64 {
        match kind {
            ResidualKind::Corner(_) => noise.corner_px,
            ResidualKind::Hole(_) => self.hole_sigma_px.unwrap_or(noise.hole_px),
            ResidualKind::Plane(_) => self.plane.map_or(1.0, |p| p.sigma_m),
        }
    }

    /// Scalar measurements (2 per corner and per hole, 1 per plane point).
    pub fn residual_count(&self) -> usize {
        2 * (self.corners.len() + self.holes_lidar.len()) + self.plane.map_or(0, |p| p.count)
    }

    /// Checks that the paired slices pair up.
    pub fn check(&self) -> Result<(), SolveError> {
        if self.object.len() != self.corners.len() {
            return Err(SolveError::LengthMismatch {
                left: self.object.len(),
                right: self.corners.len(),
            });
        }
        if self.holes_board.len() != self.holes_lidar.len() {
            return Err(SolveError::LengthMismatch {
                left: self.holes_board.len(),
                right: self.holes_lidar.len(),
            });
        }
        Ok(())
    }
}

/// The LiDAR points of one board summarised for the point-to-plane term: with
/// `a = R_LCᵀ n` (the board normal in the LiDAR frame) and `b` the plane's offset at the
/// centroid `c`, `Σ wᵢ (aᵀ(pᵢ − c) + b)² = |Lᵀ a|² + W · b²` where `L Lᵀ` is the points'
/// weighted scatter about their weighted centroid `c` and `W = Σ wᵢ`. Each point's σ is
/// `sigma_m / √wᵢ` (all `wᵢ = 1` for points alike). Fixed size whatever the number of points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanePoints {
    /// Weighted centroid of the points (LiDAR frame, m).
    pub centroid: Vec3,
    /// `Lᵀ`, the transposed Cholesky factor of the scatter `Σ wᵢ (pᵢ − c)(pᵢ − c)ᵀ` (m).
    pub spread: Mat3,
    /// Points summarised (the term's scalar measurements).
    pub count: usize,
    /// `W = Σ wᵢ`, the points' weights (`count` when they are alike).
    pub weight: f64,
    /// Point-to-plane σ of a point of weight 1 (m).
    pub sigma_m: f64,
}

impl PlanePoints {
    /// Fewest points worth a plane term.
    pub const MIN_POINTS: usize = 10;

    /// Summarises `points` (LiDAR frame, m) with one per-point σ; `None` for fewer than
    /// [`Self::MIN_POINTS`] points, a σ that is not positive, or non-finite points.
    pub fn from_points<I: IntoIterator<Item = Vec3>>(points: I, sigma_m: f64) -> Option<Self> {
        Self::from_weighted_points(points.into_iter().map(|p| (p, 1.0)), sigma_m)
    }

    /// Summarises points with weights `(p, wᵢ)`: point `i`'s σ is `sigma_m / √wᵢ`. `None`
    /// as [`Self::from_points`], or for a weight that is not positive and finite.
    pub fn from_weighted_points<I: IntoIterator<Item = (Vec3, f64)>>(
        points: I,
        sigma_m: f64,
    ) -> Option<Self> {
        // Moments about the first point, then shifted to the centroid: no cancellation
        // for points far from the sensor.
        let mut iter = points.into_iter();
        let (origin, w0) = iter.next()?;
        let (mut sum, mut outer, mut weight, mut count) = (Vec3::zeros(), [0.0; 6], w0, 1usize);
        let mut weights_valid = w0.is_finite() && w0 > 0.0;
        for (p, w) in iter {
            weights_valid &= w.is_finite() && w > 0.0;
            let d = p - origin;
            sum += d * w;
            // The outer product's six distinct entries (a floor is 10⁵ points, twice per fit).
            let [x, y, z] = [d.x, d.y, d.z];
            let products = [x * x, x * y, x * z, y * y, y * z, z * z];
            for (o, product) in outer.iter_mut().zip(products) {
                *o += product * w;
            }
            weight += w;
            count += 1;
        }
        let [xx, xy, xz, yy, yz, zz] = outer;
        let outer = Mat3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz);
        let scatter = outer - sum * sum.transpose() / weight;
        let positive = sigma_m.is_finite() && sigma_m > 0.0;
        if count < Self::MIN_POINTS
            || !positive
            || !weights_valid
            || !scatter.iter().all(|v| v.is_finite())
        {
            return None;
        }
        // A ridge far below any real spread keeps points on one scan line factorable.
        let ridge = 1e-12 * (scatter.trace() + 1e-12);
        let l = Cholesky::new(&(scatter + Mat3::identity() * ridge)).ok()?;
        let centroid = origin + sum / weight;
        Some(PlanePoints { centroid, spread: l.l().transpose(), count, weight, sigma_m })
    }

    /// Summarises the points a range sensor at the origin saw on the plane `n·p = d`,
    /// each weighted by its own noise along the normal: range noise `σ_r` along the beam
    /// moves a point by `σ_r·|cos θ|` off the plane (θ the beam's incidence), and no point
    /// is trusted below `floor_m` (beam angle, footprint, a plane that is not quite flat).
    /// `σ_r` is estimated from the points' own residuals; the weight-1 σ is the normal
    /// incidence one, `√(σ_r² + floor²)`. `None` as [`Self::from_points`].
    pub fn along_beams(
        points: impl Iterator<Item = Vec3> + Clone,
        normal: &Vec3,
        offset: f64,
        floor_m: f64,
    ) -> Option<Self> {
        let seen = points.map(|p| BeamSample::of(p, normal, offset));
        Self::from_beam_samples(seen, floor_m)
    }

    /// [`Self::along_beams`] of points already measured against the plane (each its
    /// residual and incidence, [`BeamSample::of`]): a caller that filters points by those
    /// (a trimmed fit) measures each point once instead of once per pass.
    pub fn from_beam_samples(
        samples: impl Iterator<Item = BeamSample> + Clone,
        floor_m: f64,
    ) -> Option<Self> {
        let floor2 = floor_m * floor_m;
        let (mut excess, mut cos2) = (0.0f64, 0.0f64);
        for s in samples.clone() {
            excess += s.residual * s.residual - floor2;
            cos2 += s.cos2;
        }
        let range2 = if cos2 > 0.0 { (excess / cos2).max(0.0) } else { 0.0 };
        let reference2 = range2 + floor2;
        let weighted = samples.map(|s| (s.point, reference2 / (range2 * s.cos2 + floor2)));
        Self::from_weighted_points(weighted, libm::sqrt(reference2))
    }

    /// The weighted scatter of the points about their centroid, `L Lᵀ`.
    pub fn scatter(&self) -> Mat3 {
        self.spread.transpose() * self.spread
    }

    /// The same points with `correction` taken out of their scatter (an expected part of it
    /// that is noise, not geometry); `None` when what is left is not a scatter (not positive
    /// definite).
    pub fn less_scatter(self, correction: &Mat3) -> Option<Self> {
        let l = Cholesky::new(&(self.scatter() - correction)).ok()?;
        Some(PlanePoints { spread: l.l().transpose(), ..self })
    }

    /// The plane through the points, `normal · p = offset`: the weighted least-squares fit
    /// (the scatter's smallest eigenvector through the centroid).
    pub fn fitted_plane(&self) -> (Vec3, f64) {
        let scatter = self.scatter();
        let eigen = nalgebra::SymmetricEigen::new(scatter);
        let smallest = eigen.eigenvalues.imin();
        let normal = eigen.eigenvectors.column(smallest).into_owned();
        (normal, normal.dot(&self.centroid))
    }

    /// [`Self::fitted_plane`] with its normal on the side of `towards`.
    pub fn fitted_plane_towards(&self, towards: &Vec3) -> (Vec3, f64) {
        let (normal, offset) = self.fitted_plane();
        if normal.dot(towards) < 0.0 {
            (-normal, -offset)
        } else {
            (normal, offset)
        }
    }

    /// `√W`, the offset row's factor.
    pub fn root_weight(&self) -> f64 {
        libm::sqrt(self.weight)
    }

    /// The unwhitened residual 4-vector (m·√weight) for a board whose normal in the
    /// LiDAR frame is `a` and whose plane passes `offset` from the centroid along it.
    fn residual(&self, a: &Vec3, offset: f64) -> nalgebra::Vector4<f64> {
        let top = self.spread * a;
        nalgebra::Vector4::new(top.x, top.y, top.z, self.root_weight() * offset)
    }
}

/// One point as a range sensor at the origin saw it on a plane `normal · p = offset`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeamSample {
    pub point: Vec3,
    /// `normal · p − offset`, metres.
    pub residual: f64,
    /// [`incidence2`] of the point's beam against the plane.
    pub cos2: f64,
}

impl BeamSample {
    /// The point measured against the plane.
    pub fn of(point: Vec3, normal: &Vec3, offset: f64) -> Self {
        let along = normal.dot(&point);
        BeamSample {
            point,
            residual: along - offset,
            cos2: incidence2_of(along, point.norm_squared()),
        }
    }
}

/// `cos²θ` of the beam from a sensor at the origin to `p` against the unit `normal` (1 for
/// a point at the origin, which no beam reaches).
pub fn incidence2(normal: &Vec3, p: &Vec3) -> f64 {
    incidence2_of(normal.dot(p), p.norm_squared())
}

/// [`incidence2`] from `normal · p` and `|p|²`, for a caller that has them already (the
/// residual needs the one, every plane a point is tried against the other).
pub fn incidence2_of(along: f64, r2: f64) -> f64 {
    if r2 > 0.0 {
        along * along / r2
    } else {
        1.0
    }
}

/// The pixel σ of a LiDAR hole centre known to `lidar_sigma_m` at `depth_m` in front of
/// a camera of focal length `fx` (px): `fx · σ / z`.
pub fn hole_sigma_px(fx: f64, lidar_sigma_m: f64, depth_m: f64) -> f64 {
    fx * lidar_sigma_m / depth_m.max(1e-3)
}

/// Robust loss on the squared whitened norm `s` of a residual block; the scale is in
/// units of σ (e.g. `Huber(2.0)`: blocks beyond 2σ count linearly).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loss {
    /// Plain least squares.
    Squared,
    /// Quadratic up to `scale`, linear beyond.
    Huber(f64),
    /// `scale² · ln(1 + s / scale²)`: strongly down-weights outliers.
    Cauchy(f64),
}

impl Loss {
    /// `ρ(s)` and `ρ'(s)` (the IRLS weight) for a squared whitened norm `s`.
    pub fn eval(&self, s: f64) -> (f64, f64) {
        match *self {
            Loss::Squared => (s, 1.0),
            Loss::Huber(c) => {
                let c2 = c * c;
                if s <= c2 {
                    (s, 1.0)
                } else {
                    let r = libm::sqrt(s);
                    (2.0 * c * r - c2, c / r)
                }
            }
            Loss::Cauchy(c) => {
                let c2 = c * c;
                (c2 * libm::log1p(s / c2), 1.0 / (1.0 + s / c2))
            }
        }
    }
}

/// A factor per residual kind (corners, holes, board planes) for
/// [`super::lm::NormalEquations::build_weighted`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KindWeights {
    pub corner: f64,
    pub hole: f64,
    pub plane: f64,
}

impl KindWeights {
    /// Every kind as the problem weights it.
    pub const ALL: Self = KindWeights { corner: 1.0, hole: 1.0, plane: 1.0 };
    /// Every kind left out (zero for each).
    pub const NONE: Self = KindWeights { corner: 0.0, hole: 0.0, plane: 0.0 };
    /// One kind alone (the kind of `kind`; its index is ignored).
    pub fn only(kind: ResidualKind) -> Self {
        let mut w = KindWeights { corner: 0.0, hole: 0.0, plane: 0.0 };
        *w.of_mut(kind) = 1.0;
        w
    }

    /// The factor of `kind`.
    pub fn of(&self, kind: ResidualKind) -> f64 {
        match kind {
            ResidualKind::Corner(_) => self.corner,
            ResidualKind::Hole(_) => self.hole,
            ResidualKind::Plane(_) => self.plane,
        }
    }

    /// The factor of `kind`, to set.
    pub fn of_mut(&mut self, kind: ResidualKind) -> &mut f64 {
        match kind {
            ResidualKind::Corner(_) => &mut self.corner,
            ResidualKind::Hole(_) => &mut self.hole,
            ResidualKind::Plane(_) => &mut self.plane,
        }
    }
}

/// Which shared parameters (`[fx fy cx cy d0..d4 | δω δt]`, indices 0..15) stay fixed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ParamMask {
    fixed: u16,
}

impl ParamMask {
    /// Everything free.
    pub const fn free() -> Self {
        ParamMask { fixed: 0 }
    }

    /// Also holds shared parameter `i` fixed.
    pub const fn fix(self, i: usize) -> Self {
        ParamMask { fixed: self.fixed | (1 << i) }
    }

    /// Also holds shared parameters `range` fixed.
    pub const fn fix_range(self, start: usize, end: usize) -> Self {
        let mut m = self;
        let mut i = start;
        while i < end {
            m = m.fix(i);
            i += 1;
        }
        m
    }

    /// Holds all intrinsics fixed (the two-stage mode's second stage).
    pub const fn fix_intrinsics(self) -> Self {
        self.fix_range(0, INTRINSICS)
    }

    /// Holds the extrinsic fixed (intrinsics-only runs fix it automatically).
    pub const fn fix_extrinsic(self) -> Self {
        self.fix_range(EXT_ROTATION, SHARED)
    }

    /// Whether shared parameter `i` is fixed.
    pub const fn is_fixed(&self, i: usize) -> bool {
        self.fixed & (1 << i) != 0
    }

    /// Parameters fixed by either mask.
    pub const fn union(self, other: ParamMask) -> Self {
        ParamMask { fixed: self.fixed | other.fixed }
    }

    /// Number of free shared parameters.
    pub const fn free_count(&self) -> usize {
        SHARED - (self.fixed & ((1 << SHARED) - 1)).count_ones() as usize
    }
}

/// The estimate: camera, LiDAR→camera extrinsic (`p_camera = R p_lidar + t`) and one
/// board→camera pose per board observation, in the problem's order.
#[derive(Clone, Debug)]
pub struct JointParams<C, const B: usize> {
    pub camera: C,
    pub lidar_to_camera: Se3,
    pub board_poses: heapless::Vec<Se3, B>,
}

/// Which measurement a residual block comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResidualKind {
    /// Corner `index` of the board's checkerboard.
    Corner(usize),
    /// Hole `index` of the board.
    Hole(usize),
    /// Rows `2·index, 2·index + 1` of the board's point-to-plane block (metres, not
    /// pixels; never robustified: it already sums every point).
    Plane(usize),
}

impl ResidualKind {
    /// The loss for a block of this kind under a problem's `loss`: the plane term sums
    /// many points already and stays plain least squares.
    pub fn loss(self, loss: Loss) -> Loss {
        match self {
            ResidualKind::Plane(_) => Loss::Squared,
            _ => loss,
        }
    }
}

/// One whitened residual block and its Jacobians (shared parameters; its board's pose).
#[derive(Clone, Copy, Debug)]
pub struct Residual {
    pub board: usize,
    pub kind: ResidualKind,
    /// Residual divided by its σ.
    pub r: Vec2,
    /// `∂r/∂[intrinsics | extrinsic]` (2×15).
    pub j_shared: SMatrix<f64, 2, SHARED>,
    /// `∂r/∂(board pose)` (2×6, `[δω δt]`).
    pub j_board: SMatrix<f64, 2, 6>,
    /// Scalar measurements the block stands for (2, or the points of a plane half).
    pub rows: usize,
}

/// Boards (by reference), measurement noise and loss: everything the solver reads.
#[derive(Clone, Debug)]
pub struct JointProblem<'a, const B: usize> {
    boards: heapless::Vec<BoardObservation<'a>, B>,
    /// Corner measurement σ (px).
    pub corner_sigma_px: f64,
    /// Hole-term σ (px): the LiDAR hole centres' uncertainty seen in the image (boards
    /// may override it, see [`BoardObservation::hole_sigma_px`]).
    pub hole_sigma_px: f64,
    /// Robust loss applied to every whitened block.
    pub loss: Loss,
}

impl<'a, const B: usize> JointProblem<'a, B> {
    /// An empty problem with these noise levels and loss.
    pub fn new(corner_sigma_px: f64, hole_sigma_px: f64, loss: Loss) -> Self {
        JointProblem { boards: heapless::Vec::new(), corner_sigma_px, hole_sigma_px, loss }
    }

    /// Adds a board observation; returns its index (the index of its pose).
    pub fn add_board(&mut self, board: BoardObservation<'a>) -> Result<usize, SolveError> {
        board.check()?;
        self.boards.push(board).map_err(|_| SolveError::TooManyBoards { capacity: B })?;
        Ok(self.boards.len() - 1)
    }

    /// Every σ of each residual kind multiplied by the square root of that kind's factor
    /// in `variances` (a covariance's [`super::covariance::SharedCovariance::kind_variances`]):
    /// the problem re-weighted so that each kind's residuals fit as their σ says. The
    /// corners' σ comes from the detector and the LiDAR's from its data sheet; weighted
    /// by wrong ones the kinds pull the estimate in the wrong proportions.
    pub fn rescale_sigmas(&mut self, variances: KindWeights) {
        let scale = |v: f64| if v.is_finite() && v > 0.0 { libm::sqrt(v) } else { 1.0 };
        let (corner, hole, plane) =
            (scale(variances.corner), scale(variances.hole), scale(variances.plane));
        self.corner_sigma_px *= corner;
        self.hole_sigma_px *= hole;
        for board in self.boards.iter_mut() {
            if let Some(sigma) = board.hole_sigma_px.as_mut() {
                *sigma *= hole;
            }
            if let Some(points) = board.plane.as_mut() {
                points.sigma_m *= plane;
            }
        }
    }

    /// The board observations in order.
    pub fn boards(&self) -> &[BoardObservation<'a>] {
        &self.boards
    }

    /// Whether any hole residual exists (otherwise the extrinsic is not observed).
    pub fn has_holes(&self) -> bool {
        self.boards.iter().any(|b| !b.holes_lidar.is_empty())
    }

    /// Number of scalar measurements (2 per corner and per hole, 1 per plane point).
    pub fn residual_count(&self) -> usize {
        self.boards.iter().map(BoardObservation::residual_count).sum()
    }

    /// Checks the settings (positive finite σ and loss scale) and that `params` has one
    /// pose per board.
    pub fn check_params<C>(&self, params: &JointParams<C, B>) -> Result<(), SolveError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.corner_sigma_px) {
            return Err(SolveError::BadSetting("corner σ must be positive"));
        }
        let board_sigmas = self.boards.iter().filter_map(|b| b.hole_sigma_px);
        if !positive(self.hole_sigma_px) || !board_sigmas.clone().all(positive) {
            return Err(SolveError::BadSetting("hole σ must be positive"));
        }
        if let Loss::Huber(c) | Loss::Cauchy(c) = self.loss {
            if !positive(c) {
                return Err(SolveError::BadSetting("robust loss scale must be positive"));
            }
        }
        if params.board_poses.len() != self.boards.len() {
            return Err(SolveError::LengthMismatch {
                left: self.boards.len(),
                right: params.board_poses.len(),
            });
        }
        Ok(())
    }

    /// Calls `f` with every residual block and its Jacobians. Fails (naming the board)
    /// if a point does not project.
    pub fn for_each_residual<C: Projector>(
        &self,
        params: &JointParams<C, B>,
        mut f: impl FnMut(&Residual),
    ) -> Result<(), SolveError> {
        self.check_params(params)?;
        let (cam, ext, noise) = (&params.camera, &params.lidar_to_camera, self.noise());
        for (b, (obs, pose)) in self.boards.iter().zip(params.board_poses.iter()).enumerate() {
            obs.for_each_residual(b, cam, ext, pose, noise, &mut f)?;
        }
        Ok(())
    }

    /// Calls `f(board, kind, pixel error)` for every block, without Jacobians or σ.
    pub fn for_each_error<C: Projector>(
        &self,
        params: &JointParams<C, B>,
        mut f: impl FnMut(usize, ResidualKind, Vec2),
    ) -> Result<(), SolveError> {
        self.check_params(params)?;
        let (cam, ext) = (&params.camera, &params.lidar_to_camera);
        for (b, (obs, pose)) in self.boards.iter().zip(params.board_poses.iter()).enumerate() {
            obs.for_each_error(b, cam, ext, pose, &mut |kind, e| f(b, kind, e))?;
        }
        Ok(())
    }

    /// The problem-wide σ of the corner and hole terms.
    pub fn noise(&self) -> Noise {
        Noise { corner_px: self.corner_sigma_px, hole_px: self.hole_sigma_px }
    }

    /// The loss applied to a block of this kind: the problem's, except for the plane
    /// term, which sums many points already and stays plain least squares.
    pub fn loss_for(&self, kind: ResidualKind) -> Loss {
        kind.loss(self.loss)
    }

    /// The σ dividing a block of board `b` of this kind (px, or m for the plane term).
    fn sigma_for(&self, b: usize, kind: ResidualKind) -> f64 {
        self.boards[b].sigma(kind, self.noise())
    }

    /// Robust cost `½ Σ ρ(|r/σ|²)`.
    pub fn cost<C: Projector>(&self, params: &JointParams<C, B>) -> Result<f64, SolveError> {
        let mut cost = 0.0;
        self.for_each_error(params, |b, kind, e| {
            let whitened = e / self.sigma_for(b, kind);
            cost += 0.5 * self.loss_for(kind).eval(whitened.norm_squared()).0;
        })?;
        if cost.is_finite() {
            Ok(cost)
        } else {
            Err(SolveError::NonFinite)
        }
    }

    /// RMS pixel error of the corners and of the hole term (0 when there are none):
    /// `sqrt(mean |e|²)` over blocks, plain (no σ, no loss).
    pub fn rms_px<C: Projector>(
        &self,
        params: &JointParams<C, B>,
    ) -> Result<(f64, f64), SolveError> {
        let (mut sc, mut nc, mut sh, mut nh) = (0.0, 0usize, 0.0, 0usize);
        self.for_each_error(params, |_, kind, e| match kind {
            ResidualKind::Corner(_) => {
                sc += e.norm_squared();
                nc += 1;
            }
            ResidualKind::Hole(_) => {
                sh += e.norm_squared();
                nh += 1;
            }
            ResidualKind::Plane(_) => {}
        })?;
        let rms = |s: f64, n: usize| if n == 0 { 0.0 } else { libm::sqrt(s / n as f64) };
        Ok((rms(sc, nc), rms(sh, nh)))
    }

    /// Shared parameters the data cannot move: the unused intrinsics of the model, and
    /// the extrinsic when no LiDAR term holds it (no hole and no board face: faces alone
    /// place a LiDAR that resolves no hole, three of them turned differently).
    pub fn structural_mask<C: Projector>(&self, camera: &C) -> ParamMask {
        let mut m = ParamMask::free().fix_range(camera.num_params().min(INTRINSICS), INTRINSICS);
        if !self.has_holes() && self.boards.iter().all(|b| b.plane.is_none()) {
            m = m.fix_extrinsic();
        }
        m
    }
}

/// The plane term's geometry at an estimate: the board normal in the LiDAR frame
/// `a = R_LCᵀ n`, the plane's offset at the points' centroid, and the centroid carried
/// into the camera frame minus the board origin (`m`, for the Jacobians).
fn plane_geometry(plane: &PlanePoints, pose: &Se3, ext: &Se3) -> (Vec3, f64, Vec3) {
    let n = pose.rotation.column(2).into_owned();
    let m = ext.rotation * plane.centroid + ext.translation - pose.translation;
    (ext.rotation.transpose() * n, n.dot(&m), m)
}

/// Streams the two whitened 2-row blocks of a board's point-to-plane term.
///
/// With `w = [a; b]` (normal in the LiDAR frame, offset at the centroid) the residual is
/// `G w / σ`, `G = diag(Lᵀ, √W)`, and under the left perturbations
/// - board `δω`: `δa = −R_LCᵀ [n]× δω`, `δb = (n × m)ᵀ δω`;  board `δt`: `δb = −nᵀ δt`;
/// - extrinsic `δω`: `δa = R_LCᵀ [n]× δω`, `δb = (R_LC c × n)ᵀ δω`;  extrinsic `δt`: `δb = nᵀ δt`.
fn plane_blocks(
    board: usize,
    plane: &PlanePoints,
    pose: &Se3,
    ext: &Se3,
    f: &mut impl FnMut(&Residual),
) {
    let (a, offset, m) = plane_geometry(plane, pose, ext);
    let n = pose.rotation.column(2).into_owned();
    let w = 1.0 / plane.sigma_m;
    let r = plane.residual(&a, offset) * w;
    let rt_nx = ext.rotation.transpose() * skew(&n);
    // ∂w/∂[board δω δt | extrinsic δω δt] (4×12).
    let mut dw = SMatrix::<f64, 4, 12>::zeros();
    dw.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-rt_nx));
    dw.fixed_view_mut::<3, 3>(0, 6).copy_from(&rt_nx);
    dw.fixed_view_mut::<1, 3>(3, 0).copy_from(&n.cross(&m).transpose());
    dw.fixed_view_mut::<1, 3>(3, 3).copy_from(&(-n.transpose()));
    dw.fixed_view_mut::<1, 3>(3, 6)
        .copy_from(&(ext.rotation * plane.centroid).cross(&n).transpose());
    dw.fixed_view_mut::<1, 3>(3, 9).copy_from(&n.transpose());
    let mut g = SMatrix::<f64, 4, 4>::zeros();
    g.fixed_view_mut::<3, 3>(0, 0).copy_from(&plane.spread);
    g[(3, 3)] = plane.root_weight();
    let j = g * dw * w;
    let half = plane.count / 2;
    for k in 0..2 {
        let mut j_shared = SMatrix::<f64, 2, SHARED>::zeros();
        j_shared.fixed_view_mut::<2, 6>(0, EXT_ROTATION).copy_from(&j.fixed_view::<2, 6>(2 * k, 6));
        f(&Residual {
            board,
            kind: ResidualKind::Plane(k),
            r: Vec2::new(r[2 * k], r[2 * k + 1]),
            j_shared,
            j_board: j.fixed_view::<2, 6>(2 * k, 0).into_owned(),
            rows: if k == 0 { plane.count - half } else { half },
        });
    }
}
