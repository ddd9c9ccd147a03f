//! The surveyed-room problem: the room as one rigid target. Unknowns are the intrinsics,
//! the LiDAR→camera extrinsic, ONE room→camera pose (the vehicle's parking; a standing
//! vehicle's frames share it) and one pose per room *block* — a surveyed board or a
//! surveyed plane — in the room frame, held near the survey by a prior of the survey's σ.
//!
//! Every measurement is a [`BoardObservation`] of the free-board problem
//! ([`super::JointProblem`]) whose board→camera pose is `T_rc ∘ T_kr` (block `k` → room →
//! camera), so the corner, hole and point-to-plane blocks and their analytic Jacobians
//! are the free-board ones, carried by the chain rule of the left perturbation
//! (`R ← exp(δω) R`, `t ← t + δt`) of `C = A ∘ B`:
//! - `δA` moves `C` by `δω_C = δω_A`, `δt_C = δt_A − [R_A t_B]× δω_A`;
//! - `δB` moves `C` by `δω_C = R_A δω_B`, `δt_C = R_A δt_B`.
//!
//! A surveyed plane `n · p_room = d` is a block whose frame has its z axis along `n` and
//! its origin at `d n` ([`plane_frame`]): the LiDAR points near it are a board-face term
//! with that pose. Its in-plane rotation and shift are seen by nothing but their prior.
//!
//! Shared parameters (21): intrinsics (9), extrinsic `[δω δt]` (6), room→camera `[δω δt]`
//! (6). Blocks are eliminated by the Schur complement ([`super::schur`]). Fixed size:
//! nothing here allocates.

use nalgebra::{SMatrix, SVector};

use super::covariance::kinds_covariance;
use super::minimize::Settings;
use super::problem::{BoardObservation, JointParams, JointProblem, Loss, ResidualKind};
use super::schur;
pub use super::schur::{SchurProblem, SchurSystem};
use super::{Projector, SolveError, EXT_ROTATION, EXT_TRANSLATION, INTRINSICS, SHARED};
use crate::geometry::se3::{skew, so3_left_jacobian_inv, so3_log};
use crate::geometry::{Mat3, Se3, Vec3};

/// Shared parameters of the room problem: intrinsics, extrinsic, room→camera pose.
pub const ROOM_SHARED: usize = SHARED + 6;
/// Index of the room→camera rotation in the shared vector (translation follows).
pub const ROOM_ROTATION: usize = SHARED;

/// Smallest prior σ used (m, rad): an exact survey (σ = 0) holds its block this tightly.
pub const PRIOR_FLOOR: f64 = 1e-6;

/// What the survey says about one block: its pose (block → room) and its 1σ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlockPrior {
    pub pose: Se3,
    /// Position σ (m), every axis.
    pub sigma_m: f64,
    /// Orientation σ (rad), every axis.
    pub sigma_rad: f64,
}

impl BlockPrior {
    /// A block nothing holds (a free board of the rig problem, [`super::rig`]): infinite
    /// σ, so its prior rows weigh nothing; `pose` is only the start.
    pub fn free(pose: Se3) -> BlockPrior {
        BlockPrior { pose, sigma_m: f64::INFINITY, sigma_rad: f64::INFINITY }
    }

    /// Whether nothing holds the block ([`BlockPrior::free`]).
    pub fn is_free(&self) -> bool {
        self.sigma_m == f64::INFINITY && self.sigma_rad == f64::INFINITY
    }

    /// Scalar residuals the prior adds: 6, none for a free block.
    pub fn rows(&self) -> usize {
        if self.is_free() {
            0
        } else {
            6
        }
    }
}

/// The estimate of a room problem.
#[derive(Clone, Debug)]
pub struct RoomParams<C, const B: usize> {
    pub camera: C,
    pub lidar_to_camera: Se3,
    /// Room → camera: `p_camera = R p_room + t`.
    pub room_to_camera: Se3,
    /// Block → room, one per block in the problem's order.
    pub blocks: heapless::Vec<Se3, B>,
}

/// Observations by reference, the blocks they see and the blocks' priors.
#[derive(Clone, Debug)]
pub struct RoomProblem<'a, const B: usize> {
    inner: JointProblem<'a, B>,
    block_of: heapless::Vec<usize, B>,
    priors: heapless::Vec<BlockPrior, B>,
}

/// What a room solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoomReport {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Scalar residuals (measurements and prior rows).
    pub residuals: usize,
    pub corner_rms_px: f64,
    pub hole_rms_px: f64,
}

/// The frame of the plane `normal · p = offset`: z along the (unit) normal, origin at
/// `offset · normal`; x, y any orthonormal completion.
pub fn plane_frame(normal: &Vec3, offset: f64) -> Se3 {
    let z = normal.normalize();
    let helper = if z.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
    let x = helper.cross(&z).normalize();
    let y = z.cross(&x);
    Se3 { rotation: Mat3::from_columns(&[x, y, z]), translation: z * offset }
}

impl<'a, const B: usize> RoomProblem<'a, B> {
    /// An empty problem with these measurement σ and loss (as [`JointProblem::new`]).
    pub fn new(corner_sigma_px: f64, hole_sigma_px: f64, loss: Loss) -> Self {
        RoomProblem {
            inner: JointProblem::new(corner_sigma_px, hole_sigma_px, loss),
            block_of: heapless::Vec::new(),
            priors: heapless::Vec::new(),
        }
    }

    /// Adds a block (board or plane) with its survey prior; returns its index.
    pub fn add_block(&mut self, prior: BlockPrior) -> Result<usize, SolveError> {
        let positive = |v: f64| v.is_finite() && v >= 0.0;
        if !positive(prior.sigma_m) || !positive(prior.sigma_rad) {
            return Err(SolveError::BadSetting("survey σ must be non-negative"));
        }
        self.priors.push(prior).map_err(|_| SolveError::TooManyBoards { capacity: B })?;
        Ok(self.priors.len() - 1)
    }

    /// Adds what one frame measured of block `block`; returns the observation's index.
    pub fn add_observation(
        &mut self,
        block: usize,
        observation: BoardObservation<'a>,
    ) -> Result<usize, SolveError> {
        if block >= self.priors.len() {
            return Err(SolveError::BadBoard { board: block, what: "no such block" });
        }
        let index = self.inner.add_board(observation)?;
        self.block_of.push(block).map_err(|_| SolveError::TooManyBoards { capacity: B })?;
        Ok(index)
    }

    /// The blocks' priors, in order.
    pub fn priors(&self) -> &[BlockPrior] {
        &self.priors
    }

    /// The observations (as the free-board problem holds them) and their blocks.
    pub fn observations(&self) -> (&[BoardObservation<'a>], &[usize]) {
        (self.inner.boards(), &self.block_of)
    }

    /// Params starting every block at its prior.
    pub fn params_at_priors<C>(
        &self,
        camera: C,
        lidar_to_camera: Se3,
        room_to_camera: Se3,
    ) -> RoomParams<C, B> {
        let blocks = self.priors.iter().map(|p| p.pose).collect();
        RoomParams { camera, lidar_to_camera, room_to_camera, blocks }
    }

    /// The free-board parameters these room parameters imply (one board→camera pose per
    /// observation).
    pub fn joint_params<C: Clone>(&self, params: &RoomParams<C, B>) -> JointParams<C, B> {
        let board_poses = self
            .block_of
            .iter()
            .map(|&k| params.room_to_camera.compose(&params.blocks[k]))
            .collect();
        JointParams {
            camera: params.camera.clone(),
            lidar_to_camera: params.lidar_to_camera,
            board_poses,
        }
    }

    /// Calls `f(block, whitened prior residual, its Jacobian)` for every block.
    pub fn for_each_prior<C>(
        &self,
        params: &RoomParams<C, B>,
        mut f: impl FnMut(usize, &SVector<f64, 6>, &SMatrix<f64, 6, 6>),
    ) {
        for (k, (prior, pose)) in self.priors.iter().zip(params.blocks.iter()).enumerate() {
            let (r, j) = prior_residual(prior, pose);
            f(k, &r, &j);
        }
    }

    /// Calls `f(block, residual, ∂r/∂shared (2×21), ∂r/∂block (2×6))` for every
    /// measurement block (corners, holes, planes), whitened.
    pub fn for_each_residual<C: Projector + Clone>(
        &self,
        params: &RoomParams<C, B>,
        mut f: impl FnMut(
            usize,
            ResidualKind,
            &SVector<f64, 2>,
            &SMatrix<f64, 2, ROOM_SHARED>,
            &SMatrix<f64, 2, 6>,
            usize,
        ),
    ) -> Result<(), SolveError> {
        self.check(params)?;
        let joint = self.joint_params(params);
        let a = &params.room_to_camera;
        self.inner.for_each_residual(&joint, |res| {
            let k = self.block_of[res.board];
            let (to_room, to_block) = chain(a, &params.blocks[k]);
            let mut j = SMatrix::<f64, 2, ROOM_SHARED>::zeros();
            j.fixed_view_mut::<2, SHARED>(0, 0).copy_from(&res.j_shared);
            j.fixed_view_mut::<2, 6>(0, ROOM_ROTATION).copy_from(&(res.j_board * to_room));
            f(k, res.kind, &res.r, &j, &(res.j_board * to_block), res.rows);
        })
    }

    /// The normal equations of the measurements alone (no prior), `prior_rows` scalar
    /// prior residuals counted for whoever adds them.
    pub fn measurement_equations<C: Projector + Clone>(
        &self,
        params: &RoomParams<C, B>,
        prior_rows: usize,
    ) -> Result<RoomNormalEquations<B>, SolveError> {
        let mut ne = SchurSystem::new(self.priors.len(), prior_rows);
        self.for_each_residual(params, |k, kind, r, js, jb, rows| {
            ne.add(k, self.inner.loss_for(kind), r, js, jb, rows);
        })?;
        Ok(ne)
    }

    /// Robust cost of the measurements alone, as the free-board problem counts them.
    pub fn measurement_cost<C: Projector + Clone>(
        &self,
        params: &RoomParams<C, B>,
    ) -> Result<f64, SolveError> {
        self.check(params)?;
        self.inner.cost(&self.joint_params(params))
    }

    /// The loss a measurement kind is weighed with.
    pub fn loss_for(&self, kind: ResidualKind) -> Loss {
        self.inner.loss_for(kind)
    }

    /// Robust cost: measurements as the free-board problem counts them, plus ½|prior|².
    pub fn cost<C: Projector + Clone>(&self, params: &RoomParams<C, B>) -> Result<f64, SolveError> {
        let mut cost = self.measurement_cost(params)?;
        self.for_each_prior(params, |_, r, _| cost += 0.5 * r.norm_squared());
        if cost.is_finite() {
            Ok(cost)
        } else {
            Err(SolveError::NonFinite)
        }
    }

    /// Whether any hole or LiDAR plane term exists (otherwise the extrinsic is unseen).
    pub fn sees_lidar(&self) -> bool {
        self.inner.boards().iter().any(|b| !b.holes_lidar.is_empty() || b.plane.is_some())
    }

    /// Scalar residuals: measurements and 6 prior rows per block.
    pub fn residual_count(&self) -> usize {
        self.inner.residual_count() + 6 * self.priors.len()
    }

    /// Per block, `(measurement cost, prior cost)` at `params` (`½ Σ ρ` of its whitened
    /// blocks), for naming a block that disagrees with the survey.
    pub fn block_costs<C: Projector + Clone>(
        &self,
        params: &RoomParams<C, B>,
    ) -> Result<heapless::Vec<(f64, f64), B>, SolveError> {
        let mut out: heapless::Vec<(f64, f64), B> =
            self.priors.iter().map(|_| (0.0, 0.0)).collect();
        self.for_each_residual(params, |k, kind, r, _, _, _| {
            out[k].0 += 0.5 * self.inner.loss_for(kind).eval(r.norm_squared()).0;
        })?;
        self.for_each_prior(params, |k, r, _| out[k].1 += 0.5 * r.norm_squared());
        Ok(out)
    }

    /// Plain RMS pixel error of the corners and of the hole term.
    pub fn rms_px<C: Projector + Clone>(
        &self,
        params: &RoomParams<C, B>,
    ) -> Result<(f64, f64), SolveError> {
        self.inner.rms_px(&self.joint_params(params))
    }

    fn check<C>(&self, params: &RoomParams<C, B>) -> Result<(), SolveError> {
        if params.blocks.len() != self.priors.len() {
            return Err(SolveError::LengthMismatch {
                left: self.priors.len(),
                right: params.blocks.len(),
            });
        }
        Ok(())
    }

    /// Shared parameters nothing moves: unused intrinsics; the extrinsic without LiDAR.
    pub(crate) fn structural_mask<C: Projector>(&self, camera: &C) -> [bool; ROOM_SHARED] {
        let mut fixed = [false; ROOM_SHARED];
        for f in fixed.iter_mut().take(INTRINSICS).skip(camera.num_params().min(INTRINSICS)) {
            *f = true;
        }
        if !self.sees_lidar() {
            for f in fixed.iter_mut().skip(EXT_ROTATION).take(6) {
                *f = true;
            }
        }
        fixed
    }
}

/// The whitened prior residual `[log(R R₀ᵀ)/σ_r; (t − t₀)/σ_t]` of a block pose and its
/// Jacobian under the left perturbation (`J_l⁻¹` of the rotation error).
pub(crate) fn prior_residual(
    prior: &BlockPrior,
    pose: &Se3,
) -> (SVector<f64, 6>, SMatrix<f64, 6, 6>) {
    let (wr, wt) = (1.0 / prior.sigma_rad.max(PRIOR_FLOOR), 1.0 / prior.sigma_m.max(PRIOR_FLOOR));
    let phi = so3_log(&(pose.rotation * prior.pose.rotation.transpose()));
    let dt = pose.translation - prior.pose.translation;
    let r =
        SVector::<f64, 6>::new(phi.x * wr, phi.y * wr, phi.z * wr, dt.x * wt, dt.y * wt, dt.z * wt);
    let mut j = SMatrix::<f64, 6, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(so3_left_jacobian_inv(&phi) * wr));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Mat3::identity() * wt));
    (r, j)
}

/// The maps from the left perturbations of `A` (e.g. room→camera) and `B` (block→room)
/// to that of `A ∘ B` (block→camera), see the module doc.
pub(crate) fn chain(a: &Se3, b: &Se3) -> (SMatrix<f64, 6, 6>, SMatrix<f64, 6, 6>) {
    let mut to_a = SMatrix::<f64, 6, 6>::identity();
    to_a.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-skew(&(a.rotation * b.translation))));
    let mut to_b = SMatrix::<f64, 6, 6>::zeros();
    to_b.fixed_view_mut::<3, 3>(0, 0).copy_from(&a.rotation);
    to_b.fixed_view_mut::<3, 3>(3, 3).copy_from(&a.rotation);
    (to_a, to_b)
}

/// The room problem's normal equations (21 shared parameters).
pub type RoomNormalEquations<const B: usize> = SchurSystem<ROOM_SHARED, B>;

impl<C: Projector + Clone, const B: usize> SchurProblem<RoomParams<C, B>, ROOM_SHARED, B>
    for RoomProblem<'_, B>
{
    fn normal_equations(
        &self,
        params: &RoomParams<C, B>,
    ) -> Result<RoomNormalEquations<B>, SolveError> {
        let mut ne = self.measurement_equations(params, 6 * self.priors.len())?;
        self.for_each_prior(params, |k, r, j| ne.add_prior(k, r, j));
        ne.finite()
    }

    fn cost(&self, params: &RoomParams<C, B>) -> Result<f64, SolveError> {
        RoomProblem::cost(self, params)
    }

    fn apply(
        &self,
        params: &RoomParams<C, B>,
        shared: &SVector<f64, ROOM_SHARED>,
        blocks: &[SVector<f64, 6>; B],
    ) -> RoomParams<C, B> {
        apply_room_step(params, shared, blocks)
    }

    fn structural_mask(&self, params: &RoomParams<C, B>) -> [bool; ROOM_SHARED] {
        RoomProblem::structural_mask(self, &params.camera)
    }
}

/// How the room, rig and room-modes problems are solved: Marquardt's schedule; stop when
/// an accepted step lowers the cost by at most 10⁻⁹ of it, the tolerance the surveyed-room
/// and rig results were validated with. No gradient or step test: the cost test and the λ
/// cap end every solve.
pub const SETTINGS: Settings = Settings { cost_tolerance: 1e-9, ..Settings::MARQUARDT };

/// Levenberg–Marquardt ([`SETTINGS`]) on the room problem from `params` (updated in place).
pub fn solve_room<C: Projector + Clone, const B: usize>(
    problem: &RoomProblem<'_, B>,
    params: &mut RoomParams<C, B>,
    max_iterations: usize,
) -> Result<RoomReport, SolveError> {
    let (report, residuals) =
        schur::solve(problem, params, &SETTINGS.with_max_iterations(max_iterations))?;
    let (corner_rms_px, hole_rms_px) = problem.rms_px(params)?;
    Ok(RoomReport {
        iterations: report.iterations,
        initial_cost: report.initial_cost,
        final_cost: report.final_cost,
        residuals,
        corner_rms_px,
        hole_rms_px,
    })
}

/// Covariance of the 21 shared parameters at `params` (normally the solution), each
/// measurement kind (corners, holes, board faces and surveyed planes) scaled by its own
/// variance factor as the free-board covariance is ([`super::covariance::covariance`]);
/// the survey's priors keep their σ. Fixed parameters have zero rows and columns.
pub fn room_covariance<C: Projector + Clone, const B: usize>(
    problem: &RoomProblem<'_, B>,
    params: &RoomParams<C, B>,
) -> Result<SMatrix<f64, ROOM_SHARED, ROOM_SHARED>, SolveError> {
    kinds_covariance(
        problem,
        params,
        |each| {
            problem.for_each_residual(params, |k, kind, r, js, jb, rows| {
                each(k, kind, problem.loss_for(kind), r, js, jb, rows)
            })
        },
        |each| problem.for_each_prior(params, |k, r, j| each(k, r, j)),
    )
}

/// `params ⊕ step`: additive intrinsics, left-perturbed extrinsic, room pose and blocks.
pub fn apply_room_step<C: Projector + Clone, const B: usize>(
    params: &RoomParams<C, B>,
    shared: &SVector<f64, ROOM_SHARED>,
    blocks: &[SVector<f64, 6>; B],
) -> RoomParams<C, B> {
    let mut out = params.clone();
    let mut k = params.camera.params();
    for (i, v) in k.iter_mut().enumerate() {
        *v += shared[i];
    }
    out.camera.set_params(&k);
    out.lidar_to_camera =
        params.lidar_to_camera.perturb_left(&shared.fixed_rows::<6>(EXT_ROTATION).into_owned());
    out.room_to_camera =
        params.room_to_camera.perturb_left(&shared.fixed_rows::<6>(ROOM_ROTATION).into_owned());
    for (pose, d) in out.blocks.iter_mut().zip(blocks.iter()) {
        *pose = pose.perturb_left(d);
    }
    out
}

// The shared layout: intrinsics, extrinsic rotation, translation, then the room pose.
const _: () = assert!(EXT_TRANSLATION + 3 == ROOM_ROTATION);
