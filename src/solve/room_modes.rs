//! The surveyed room held by the survey's *joint* covariance instead of each block's own σ.
//!
//! A survey's errors go together: its planes turn as one against its boards, its boards
//! share the errors of the visits that saw them. A calibration that holds every board and
//! plane by its own σ (the rig problem's priors, [`super::rig::BlockPrior`]) cannot know
//! that, and pays for it: over ten new vehicles in a 16-visit survey the Cramér–Rao
//! analysis puts one frame's translation at 2.4 mm RMS with per-block priors against
//! 1.8 mm with the joint covariance, the rotation at 0.029° against 0.020°
//! (`studies/crb_bound.py --survey-visits`, `per_block_prior_errors`).
//!
//! The joint prior couples every block, which the Schur complement over blocks cannot
//! carry; so the room is moved by **modes** instead. The covariance `C = Σ σᵢ² vᵢ vᵢᵀ`
//! (its eigenvectors, at most [`MAX_MODES`] of them, the largest) says every block's
//! perturbation is `δ_k = V_k a` with independent amplitudes `aᵢ ~ N(0, σᵢ²)`. The
//! amplitudes join the 21 shared parameters; no block has parameters of its own. The
//! measurements are still accumulated block by block as the room problem does (a 21×21
//! `V`, per block `U_k`, `W_k`, `g_k`) and then *condensed*:
//! `H_aa = Σ V_kᵀ U_k V_k + diag(σ⁻²)`, `H_sa = Σ W_k V_k`, `g_a = Σ V_kᵀ g_k + a/σ²`,
//! which costs per block, not per measurement. The covariance's null directions (the
//! room's frame, a plane's turn about its own normal) are not modes: the room→camera pose
//! carries the frame, and nothing else moves along them.
//!
//! A mode slot with σ = 0 is unused (held fixed). Fixed size: nothing here allocates; the
//! per-block bases are the caller's.

use nalgebra::{SMatrix, SVector};

use super::covariance::{pooled_variance, reduced_inverse, variance_factor};
use super::problem::ResidualKind;
use super::rig::{apply_rig_step, SETTINGS};
use super::room::{RoomParams, RoomProblem, ROOM_SHARED};
use super::schur::{self, SchurProblem, SchurSystem};
use super::{Projector, SolveError};

/// Most modes a room is moved by (the largest of the survey's covariance; the rest,
/// the best known combinations, are held exact).
pub const MAX_MODES: usize = 48;
/// Shared parameters of the modes problem: the room problem's 21, then the amplitudes.
pub const MODES_SHARED: usize = ROOM_SHARED + MAX_MODES;

/// One block's perturbation (`[δω δt]`, the room problem's left perturbation of the
/// block → room pose) per unit amplitude of every mode.
pub type ModeBasis = SMatrix<f64, 6, MAX_MODES>;

/// The room problem with its blocks moved by the survey's modes.
#[derive(Clone, Copy, Debug)]
pub struct ModesProblem<'p, 'a, const B: usize> {
    /// The measurements (its per-block priors are not used).
    pub room: &'p RoomProblem<'a, B>,
    /// σ of every mode's amplitude (0: an unused slot).
    pub sigma: SVector<f64, MAX_MODES>,
    /// Per block of `room`, in its order: the block's [`ModeBasis`].
    pub basis: &'p [ModeBasis],
}

/// The estimate: the room problem's parameters and the modes' amplitudes.
#[derive(Clone, Debug)]
pub struct ModesParams<C, const B: usize> {
    pub room: RoomParams<C, B>,
    pub amplitudes: SVector<f64, MAX_MODES>,
}

impl<'p, 'a, const B: usize> ModesProblem<'p, 'a, B> {
    /// The problem, or an error when a σ is negative or not finite or the bases are not
    /// one per block.
    pub fn new(
        room: &'p RoomProblem<'a, B>,
        sigma: SVector<f64, MAX_MODES>,
        basis: &'p [ModeBasis],
    ) -> Result<Self, SolveError> {
        if !sigma.iter().all(|s| s.is_finite() && *s >= 0.0) {
            return Err(SolveError::BadSetting("mode σ must be finite and non-negative"));
        }
        if basis.len() != room.priors().len() {
            return Err(SolveError::LengthMismatch {
                left: room.priors().len(),
                right: basis.len(),
            });
        }
        Ok(ModesProblem { room, sigma, basis })
    }

    /// The modes' prior cost `½ Σ (aᵢ/σᵢ)²`.
    fn prior_cost(&self, amplitudes: &SVector<f64, MAX_MODES>) -> f64 {
        self.used().map(|i| 0.5 * squared(amplitudes[i] / self.sigma[i])).sum()
    }

    /// The mode slots in use.
    fn used(&self) -> impl Iterator<Item = usize> + '_ {
        (0..MAX_MODES).filter(|&i| self.sigma[i] > 0.0)
    }

    /// How many modes move the room (each one prior row).
    pub fn mode_count(&self) -> usize {
        self.used().count()
    }

    /// The room's equations condensed onto the shared parameters and amplitudes (see the
    /// module doc), with the modes' prior at `amplitudes` when given.
    fn condense(
        &self,
        room: &SchurSystem<ROOM_SHARED, B>,
        amplitudes: Option<&SVector<f64, MAX_MODES>>,
    ) -> SchurSystem<MODES_SHARED, 0> {
        let mut out = SchurSystem::<MODES_SHARED, 0>::new(0, room.residuals);
        out.cost = room.cost;
        out.v.fixed_view_mut::<ROOM_SHARED, ROOM_SHARED>(0, 0).copy_from(&room.v);
        out.g_shared.fixed_rows_mut::<ROOM_SHARED>(0).copy_from(&room.g_shared);
        for (k, basis) in self.basis.iter().enumerate().take(room.blocks) {
            let cross = room.w[k] * basis;
            let modes = basis.transpose() * room.u[k] * basis;
            let mut v = out.v.fixed_view_mut::<ROOM_SHARED, MAX_MODES>(0, ROOM_SHARED);
            v += cross;
            let mut v = out.v.fixed_view_mut::<MAX_MODES, ROOM_SHARED>(ROOM_SHARED, 0);
            v += cross.transpose();
            let mut v = out.v.fixed_view_mut::<MAX_MODES, MAX_MODES>(ROOM_SHARED, ROOM_SHARED);
            v += modes;
            let mut g = out.g_shared.fixed_rows_mut::<MAX_MODES>(ROOM_SHARED);
            g += basis.transpose() * room.g_block[k];
        }
        let Some(amplitudes) = amplitudes else { return out };
        for i in self.used() {
            let weight = 1.0 / squared(self.sigma[i]);
            out.v[(ROOM_SHARED + i, ROOM_SHARED + i)] += weight;
            out.g_shared[ROOM_SHARED + i] += weight * amplitudes[i];
            out.residuals += 1;
        }
        out.cost += self.prior_cost(amplitudes);
        out
    }
}

impl<C: Projector + Clone, const B: usize> SchurProblem<ModesParams<C, B>, MODES_SHARED, 0>
    for ModesProblem<'_, '_, B>
{
    fn normal_equations(
        &self,
        params: &ModesParams<C, B>,
    ) -> Result<SchurSystem<MODES_SHARED, 0>, SolveError> {
        let mut room = SchurSystem::new(self.room.priors().len(), 0);
        self.room.add_measurements(&params.room, &mut room)?;
        self.condense(&room, Some(&params.amplitudes)).finite()
    }

    fn cost(&self, params: &ModesParams<C, B>) -> Result<f64, SolveError> {
        let cost = self.room.measurement_cost(&params.room)? + self.prior_cost(&params.amplitudes);
        if cost.is_finite() {
            Ok(cost)
        } else {
            Err(SolveError::NonFinite)
        }
    }

    fn apply(
        &self,
        params: &ModesParams<C, B>,
        shared: &SVector<f64, MODES_SHARED>,
        _: &[SVector<f64, 6>; 0],
    ) -> ModesParams<C, B> {
        let step = shared.fixed_rows::<MAX_MODES>(ROOM_SHARED).into_owned();
        let mut blocks = [SVector::<f64, 6>::zeros(); B];
        for (block, basis) in blocks.iter_mut().zip(self.basis) {
            *block = basis * step;
        }
        let room_step = shared.fixed_rows::<ROOM_SHARED>(0).into_owned();
        ModesParams {
            room: apply_rig_step(&params.room, &room_step, &blocks),
            amplitudes: params.amplitudes + step,
        }
    }

    fn structural_mask(&self, params: &ModesParams<C, B>) -> [bool; MODES_SHARED] {
        let room = self.room.structural_mask(&params.room);
        core::array::from_fn(|i| match i {
            i if i < ROOM_SHARED => room[i],
            i => self.sigma[i - ROOM_SHARED] <= 0.0,
        })
    }
}

/// Levenberg–Marquardt on the modes problem from `params` (updated in place); the
/// iterations done.
pub fn solve_modes<C: Projector + Clone, const B: usize>(
    problem: &ModesProblem<'_, '_, B>,
    params: &mut ModesParams<C, B>,
    max_iterations: usize,
) -> Result<usize, SolveError> {
    let settings = SETTINGS.with_max_iterations(max_iterations);
    Ok(schur::solve(problem, params, &settings)?.0.iterations)
}

/// Covariance of the 21 shared parameters at `params` (normally the solution), every
/// mode marginalised: `H⁻¹ (Σₖ fₖ Hₖ + H_p) H⁻¹` with each measurement kind scaled by its
/// own variance factor ([`variance_factor`]) as the per-block room covariance is, and the
/// modes' prior as it is. Each kind's `Hₖ` is accumulated block by block as the solve's
/// equations are and condensed onto the modes, so a measurement costs what it costs the
/// solve. Fixed parameters have zero rows and columns.
pub fn modes_covariance<C: Projector + Clone, const B: usize>(
    problem: &ModesProblem<'_, '_, B>,
    params: &ModesParams<C, B>,
) -> Result<SMatrix<f64, ROOM_SHARED, ROOM_SHARED>, SolveError> {
    let ne = problem.normal_equations(params)?;
    let fixed = ne.mask(&problem.structural_mask(params));
    let pooled = pooled_variance(&ne, &fixed)?;
    let inverse = reduced_inverse(&ne, &fixed)?;
    let kinds = kind_systems(problem, &params.room)?;
    let mut middle = SMatrix::<f64, MODES_SHARED, MODES_SHARED>::zeros();
    for system in &kinds {
        let part = problem.condense(system, None);
        // tr(H⁻¹ Hₖ): both symmetric, so the sum of their elementwise products.
        let determined = inverse.dot(&part.v);
        let factor = variance_factor(system.residuals as f64, system.cost, determined, pooled);
        middle.zip_apply(&part.v, |m, h| *m += factor * h);
    }
    for i in problem.used() {
        middle[(ROOM_SHARED + i, ROOM_SHARED + i)] += 1.0 / squared(problem.sigma[i]);
    }
    Ok(sandwiched_shared(&inverse, &middle))
}

/// The room's measurement equations split by kind (corners, holes, planes), each with its
/// rows and robust cost, in one pass over the measurements.
#[inline(never)]
fn kind_systems<C: Projector + Clone, const B: usize>(
    problem: &ModesProblem<'_, '_, B>,
    room: &RoomParams<C, B>,
) -> Result<[SchurSystem<ROOM_SHARED, B>; 3], SolveError> {
    let blocks = problem.room.priors().len();
    let mut kinds: [SchurSystem<ROOM_SHARED, B>; 3] =
        core::array::from_fn(|_| SchurSystem::new(blocks, 0));
    problem.room.for_each_residual(room, |k, kind, r, js, jb, rows| {
        let at = match kind {
            ResidualKind::Corner(_) => 0,
            ResidualKind::Hole(_) => 1,
            ResidualKind::Plane(_) => 2,
        };
        kinds[at].add(k, problem.room.loss_for(kind), r, js, jb, rows);
    })?;
    Ok(kinds)
}

/// `x²` (`f64::powi` needs `std`; this module does not).
fn squared(x: f64) -> f64 {
    x * x
}

/// The shared 21×21 corner of `H⁻¹ M H⁻¹`.
#[inline(never)]
fn sandwiched_shared(
    inverse: &SMatrix<f64, MODES_SHARED, MODES_SHARED>,
    middle: &SMatrix<f64, MODES_SHARED, MODES_SHARED>,
) -> SMatrix<f64, ROOM_SHARED, ROOM_SHARED> {
    let left = inverse.fixed_rows::<ROOM_SHARED>(0);
    let product = left * middle;
    product * left.transpose()
}
